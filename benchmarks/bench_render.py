"""Speed of the stereo renderer: one default stereo pair, single process, one core.

Run ``python benchmarks/bench_render.py [--repeats 20]``. Renders the as-built default jig (seed 0) with
a 50 mm cylinder tilted by 10 degrees, prints the median and inter-quartile range of the time per pair
and the median time per stage (summed over both cameras). BLAS and OpenCV are limited to one thread, so
the figure is per core. Target: a median of at most 100 ms per pair.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import time  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402

from softjig.config import CylinderPart, default_jig  # noqa: E402
from softjig.sim.asbuilt import draw_as_built  # noqa: E402
from softjig.sim.parts import PartPose  # noqa: E402
from softjig.sim.render import _render_pair  # noqa: E402

TARGET_MS = 100.0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=20, help="timed renders (default 20)")
    parser.add_argument("--color", action="store_true", help="render RGB images")
    args = parser.parse_args()
    cv2.setNumThreads(1)

    as_built = draw_as_built(default_jig(), rng=0)
    part = CylinderPart(diameter_mm=50.0)
    pose = PartPose(alpha_rad=np.radians(10.0), theta_rad=np.radians(30.0))
    _render_pair(as_built, part, pose, 0, color=args.color, timings=None)  # warm caches

    wall, cpu, stages = [], [], []
    for i in range(args.repeats):
        timings: dict[str, float] = {}
        t0, c0 = time.perf_counter(), time.process_time()
        _render_pair(as_built, part, pose, i, color=args.color, timings=timings)
        wall.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
        stages.append(timings)

    print(f"render_pair (1280x720 x2, {args.repeats} renders, one thread):")
    for name, values in (("CPU time", cpu), ("wall time", wall)):
        ms = 1e3 * np.asarray(values)
        q1, med, q3 = np.percentile(ms, [25, 50, 75])
        print(
            f"  {name:9s}: median {med:6.1f} ms, IQR {q1:.1f}-{q3:.1f} ms ({q3 - q1:.1f}), "
            f"min {ms.min():.1f} ms"
        )
    med = float(np.median(1e3 * np.asarray(cpu)))
    print("per stage (CPU time, median over renders, both cameras):")
    for name in stages[0]:
        print(f"  {name:16s} {1e3 * np.median([s[name] for s in stages]):7.2f} ms")
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    verdict = "meets" if med <= TARGET_MS else "MISSES"
    print(f"target {TARGET_MS:.0f} ms per pair: {verdict} (1-min load average {load:.2f})")


if __name__ == "__main__":
    main()
