"""Benchmark of two stages on their own: marker detection on a full frame and stereo matching of ~400 markers.

The timings the unit tests used to print (``test_detection_timing``, ``test_matching_timing_400_markers``)
without asserting anything; the tests now check only what the stages return. Run:
``python benchmarks/bench_stages.py [--repeats 50]``. One thread; prints the median and inter-quartile
range of each case (ms).
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import time  # noqa: E402
from collections.abc import Callable  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402

from softjig.config import CylinderPart, default_jig  # noqa: E402
from softjig.sensing.detect import detect_markers  # noqa: E402
from softjig.sensing.pipeline import sensing_setup  # noqa: E402
from softjig.sensing.stereo import disparity_window_px, match_rectified  # noqa: E402
from softjig.sim.asbuilt import draw_as_built  # noqa: E402
from softjig.sim.parts import PartPose  # noqa: E402
from softjig.sim.render import render_pair  # noqa: E402

FX_PX, CX_PX, CY_PX, BASELINE_MM = 925.0, 639.5, 359.5, 30.0
ROW_TOLERANCE_PX = 2.5


def _project(points_mm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A rectified pinhole pair (the cameras at x = 0 and x = baseline) looking up +z."""
    x, y, z = points_mm.T
    v = FX_PX * y / z + CY_PX
    return (
        np.column_stack([FX_PX * x / z + CX_PX, v]),
        np.column_stack([FX_PX * (x - BASELINE_MM) / z + CX_PX, v]),
    )


def matching_cases(rng: np.random.Generator) -> dict[str, tuple]:
    """A 416-marker grid 185 mm away (a 20 px disparity window, rows jittered 1.5 px, right shuffled)
    and a 400-point random cloud 150-250 mm away (a 120 px window)."""
    x, y = np.meshgrid(np.arange(-100.0, 101.0, 8.0), np.arange(-60.0, 61.0, 8.0))
    grid = np.column_stack([x.ravel(), y.ravel(), 185.0 + 0.02 * x.ravel() + rng.normal(0, 0.3, x.size)])
    left, right = _project(grid)
    right[:, 1] += rng.uniform(-1.5, 1.5, len(right))
    right = right[rng.permutation(len(right))]
    cloud_left, cloud_right = _project(rng.uniform([-70, -40, 150], [70, 40, 250], (400, 3)))
    return {
        f"match_rectified {len(left)} markers, grid": (
            left,
            right,
            *disparity_window_px(FX_PX, BASELINE_MM, 175.0, 195.0),
        ),
        "match_rectified 400 points, random cloud": (
            cloud_left,
            cloud_right,
            *disparity_window_px(FX_PX, BASELINE_MM, 150.0, 250.0),
        ),
    }


def _time_ms(run: Callable[[], object], repeats: int) -> np.ndarray:
    run()  # compile and warm caches
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        run()
        times.append((time.perf_counter() - start) * 1e3)
    return np.array(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--repeats", type=int, default=50)
    args = parser.parse_args()
    cv2.setNumThreads(1)
    jig = default_jig()
    pair = render_pair(
        draw_as_built(jig, rng=0), CylinderPart(50.0), PartPose(np.radians(10), 0.0, 3.0), rng=0
    )
    setup = sensing_setup(jig)
    cases: dict[str, Callable[[], object]] = {
        f"detect_markers {pair.left.shape[1]}x{pair.left.shape[0]}, default pair's left image": (
            lambda: detect_markers(pair.left, sigma_px=setup.sigma_px, model=setup.marker)
        )
    }
    for name, (left, right, lo, hi) in matching_cases(np.random.default_rng(3)).items():
        cases[name] = lambda a=left, b=right, lo=lo, hi=hi: match_rectified(
            a, b, row_tolerance_px=ROW_TOLERANCE_PX, min_disparity_px=lo, max_disparity_px=hi
        )
    print(f"softjig stages, {args.repeats} runs each, 1 thread")
    print(f"{'case':<62} {'median ms':>10} {'IQR ms':>16}")
    for name, run in cases.items():
        q1, median, q3 = np.percentile(_time_ms(run, args.repeats), [25, 50, 75])
        print(f"{name:<62} {median:>10.2f} {q1:>7.2f} - {q3:<7.2f}")


if __name__ == "__main__":
    main()
