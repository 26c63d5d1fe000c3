"""Benchmark: the refractive method's fit stage against the number of markers in contact.

Run: ``python benchmarks/bench_fit_scaling.py [--repeats 15]``. A 1024x768 design with 2 mm markers on a
5 mm grid (the issue's: 175 contact markers for a 45 mm part), parts of 20-90 mm at 10 deg, size-free
and with the size. Single process, one thread. Prints, per part, the markers in contact and the median
and inter-quartile range of the CPU time of the refractive method after detection and matching
(triangulation, about 0.1 ms, then the fit stage: indentation, contact, robust planes, lift-off,
uncertainty, self-check, footprint), and that time per contact marker, which falls or stays flat when
the cost grows no faster than linearly.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import time  # noqa: E402
from dataclasses import replace  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402

from softjig.config import CameraConfig, CylinderPart, StereoConfig, default_jig  # noqa: E402
from softjig.sensing.estimator import Estimator  # noqa: E402
from softjig.sim.asbuilt import draw_as_built  # noqa: E402
from softjig.sim.parts import PartPose  # noqa: E402
from softjig.sim.render import render_pair  # noqa: E402

DIAMETERS_MM = (20, 30, 45, 60, 75, 90)


def fine_grid_jig():
    """1024x768 px, f = 740 px, 30 mm baseline 155 mm below the plate; 2 mm markers, 5 mm pitch."""
    jig = default_jig()

    def camera(x_mm: float) -> CameraConfig:
        return CameraConfig(
            width_px=1024, height_px=768, fx_px=740.0, fy_px=740.0, cx_px=511.5, cy_px=383.5,
            position_mm=(x_mm, 0.0, -155.0),
        )  # fmt: skip

    return jig.replace(
        cameras=StereoConfig(left=camera(-15.0), right=camera(15.0)),
        markers=replace(jig.markers, pitch_mm=5.0, diameter_mm=2.0),
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--repeats", type=int, default=15)
    args = parser.parse_args()
    cv2.setNumThreads(1)
    jig = fine_grid_jig()
    as_built = draw_as_built(jig, rng=0)
    estimator = Estimator(jig)
    print(f"{'part':>6} {'size':>5} {'contact':>7} {'CPU ms':>8} {'IQR':>13} {'us/marker':>9}")
    for diameter in DIAMETERS_MM:
        pose = PartPose(np.radians(10.0), np.radians(30.0), 4.0)
        pair = render_pair(as_built, CylinderPart(float(diameter)), pose, rng=diameter)
        observation = estimator.observe(pair.left, pair.right)
        for sized in (False, True):
            size = float(diameter) if sized else None

            def triangulate_and_fit(size=size, observation=observation):
                points = estimator.triangulator.triangulate(
                    observation.left_xy_px, observation.right_xy_px, observation.frame
                )
                return estimator.fitter.fit(observation, points, size)

            result = triangulate_and_fit()  # warm
            times = []
            for _ in range(args.repeats):
                # CPU time of this thread: on a shared machine, wall time counts the other processes'
                t0 = time.thread_time()
                result = triangulate_and_fit()
                times.append((time.thread_time() - t0) * 1e3)
            n_contact = result.estimate.n_points
            q1, med, q3 = np.percentile(times, [25, 50, 75])
            print(
                f"{diameter:>4}mm {'yes' if sized else 'no':>5} {n_contact:>7} {med:>8.2f} "
                f"{q1:>6.2f}-{q3:<6.2f} {1e3 * med / max(n_contact, 1):>9.1f}"
            )


if __name__ == "__main__":
    main()
