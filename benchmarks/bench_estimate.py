"""Benchmark of the paper's pipeline on one default stereo pair: time per stage and localisation error.

Run: ``python benchmarks/bench_estimate.py [--repeats 30]``. Single process, one thread for OpenCV, so
the figures are per core. Prints the median and inter-quartile range of each stage and of the whole
estimate, and the markers' localisation RMSE against the renderer's ground truth.
"""

from __future__ import annotations

import os

# One core: idle BLAS threads spinning after the fit's small SVDs slow the next frame's detection.
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import platform  # noqa: E402
import time  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402
from scipy.spatial import cKDTree  # noqa: E402

from softjig.config import CylinderPart, default_jig  # noqa: E402
from softjig.sensing.estimator import Estimator  # noqa: E402
from softjig.sensing.pipeline import estimate_pair  # noqa: E402
from softjig.sim.asbuilt import draw_as_built  # noqa: E402
from softjig.sim.parts import PartPose  # noqa: E402
from softjig.sim.render import render_pair  # noqa: E402

STAGES = ("checks", "frame", "detect", "match", "triangulate", "fit")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--repeats", type=int, default=30)
    parser.add_argument("--method", choices=("refractive", "paper"), default="refractive")
    args = parser.parse_args()
    cv2.setNumThreads(1)
    jig = default_jig()
    as_built = draw_as_built(jig, rng=0)
    pairs = [
        render_pair(as_built, CylinderPart(50.0), PartPose(np.radians(10), np.radians(36 * k), 3.0), rng=k)
        for k in range(5)
    ]
    estimate_pair(pairs[0].left, pairs[0].right, jig, part_diameter_mm=50)  # warm up (Numba, tables on disk)
    estimator = Estimator(jig, method=args.method)  # built once, as every caller estimating frames does
    records: dict[str, list[float]] = {stage: [] for stage in (*STAGES, "total")}
    errors = []
    for k in range(args.repeats):
        pair = pairs[k % len(pairs)]
        timings: dict[str, float] = {}
        result = estimator.estimate(pair.left, pair.right, part_diameter_mm=50, timings=timings)
        for stage in STAGES:
            records[stage].append(timings[stage] * 1e3)
        records["total"].append(sum(timings.values()) * 1e3)
        if k < len(pairs):
            for markers, px, visible in (
                (result.left, pair.markers.left_px, pair.markers.visible_left),
                (result.right, pair.markers.right_px, pair.markers.visible_right),
            ):
                distance, _ = cKDTree(markers.xy_px).query(px[visible])
                errors.append(distance[distance < 2.0])
    print(f"softjig estimate ({args.method}), one default 1280x720 pair, {args.repeats} runs, 1 thread")
    print(
        f"machine: {platform.processor() or platform.machine()}, Python {platform.python_version()}, "
        f"NumPy {np.__version__}, OpenCV {cv2.__version__}"
    )
    print(f"{'stage':<12} {'median ms':>10} {'IQR ms':>16}")
    for stage, values in records.items():
        q1, med, q3 = np.percentile(values, [25, 50, 75])
        print(f"{stage:<12} {med:>10.2f} {q1:>7.2f} - {q3:<7.2f}")
    one_shot = []
    for k in range(min(args.repeats, 10)):  # estimate_pair builds an Estimator per call
        pair = pairs[k % len(pairs)]
        t0 = time.perf_counter()
        estimate_pair(pair.left, pair.right, jig, part_diameter_mm=50, method=args.method)
        one_shot.append((time.perf_counter() - t0) * 1e3)
    print(f"{'one-shot':<12} {np.median(one_shot):>10.2f}   (estimate_pair: an Estimator built per call)")
    e = np.concatenate(errors)
    print(
        f"localisation: RMSE {np.sqrt(np.mean(e**2)):.3f} px, median {np.median(e):.3f} px "
        f"over {len(e)} markers (default physics, as-built jig)"
    )


if __name__ == "__main__":
    main()
