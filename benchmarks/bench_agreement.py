"""Fast against straightforward implementation on a whole sweep: the normals must agree within 0.05 deg.

Run: ``python benchmarks/bench_agreement.py SWEEP [--method refractive|paper] [--workers N]``, with SWEEP a
dataset from ``softjig simulate --scenario paper-sweep`` (the default sweep: ``--seed 0``). Every loaded
frame is estimated twice, by the standard :class:`~softjig.sensing.estimator.Estimator` (pyramid
candidates, fiducials read near their expected place, the sparse matching, closed-form refracted rays) and
by one composed of the straightforward stages of ``tests/oracles/stages.py`` (full-resolution LoG, full
ArUco detection, the dense assignment, rays traced interface by interface), and the angle between the two
normals is reported: its maximum, 99th percentile and median, and the frames above 0.05 deg. The two
implementations' markers are compared too (each fast marker with the nearest straightforward one in the
same image): the largest distance between markers found by both (within 1 px), and the markers found by one
only.
"""

from __future__ import annotations

import argparse
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from softjig.geometry import angle_between
from softjig.io.batch import dataset_reference
from softjig.io.dataset import Dataset, Frame
from softjig.sensing.estimator import Estimator

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from oracles.stages import straightforward_estimator

LIMIT_DEG = 0.05
_STATE: dict = {}


def _init(path: str, method: str) -> None:
    import cv2

    cv2.setNumThreads(1)
    dataset = Dataset.open(path)
    reference = dataset_reference(dataset, dataset.jig) if method == "refractive" else None
    standard = Estimator(dataset.jig, method=method, reference=reference)
    _STATE.update(estimators=(standard, straightforward_estimator(standard)))


def _both(frame: Frame) -> tuple[int, float | None, float, int]:
    """One frame: the angle (deg) between the fast and the straightforward normal (None: no estimate), the
    largest distance (px) between their markers found by both, and the number found by one only."""
    left, right = frame.load_left(), frame.load_right()
    diameter = None if frame.part is None else float(frame.part.diameter_mm)
    results = []
    for estimator in _STATE["estimators"]:
        try:
            results.append(estimator.estimate(left, right, part_diameter_mm=diameter))
        except Exception:  # a frame either implementation cannot estimate is counted, not compared
            return frame.index, None, 0.0, 0
    normals = [np.asarray(result.estimate.normal) for result in results]
    worst, alone = 0.0, 0
    for side in ("left", "right"):
        a, b = (getattr(result, side).xy_px for result in results)
        if len(a) == 0 or len(b) == 0:
            alone += len(a) + len(b)
            continue
        d_ab = cKDTree(b).query(a)[0]
        d_ba = cKDTree(a).query(b)[0]
        worst = max(worst, float(d_ab[d_ab < 1.0].max(initial=0.0)))
        alone += int(np.sum(d_ab >= 1.0) + np.sum(d_ba >= 1.0))
    return frame.index, float(np.degrees(angle_between(normals[0], normals[1]))), worst, alone


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("sweep")
    parser.add_argument("--method", choices=("refractive", "paper"), default="refractive")
    parser.add_argument("--workers", type=int, default=None)
    args = parser.parse_args()
    frames = [frame for frame in Dataset.open(args.sweep) if not frame.reference]
    with ProcessPoolExecutor(args.workers, initializer=_init, initargs=(args.sweep, args.method)) as pool:
        results = list(pool.map(_both, frames, chunksize=8))
    angles = np.array([a for _, a, _, _ in results if a is not None])
    failed = [i for i, a, _, _ in results if a is None]
    above = [(i, a) for i, a, _, _ in results if a is not None and a > LIMIT_DEG]
    print(f"{args.method}: {len(angles)} frames compared, {len(failed)} without an estimate")
    print(
        f"fast vs straightforward normal: within {LIMIT_DEG} deg on {len(angles) - len(above)} of "
        f"{len(angles)} frames; max {angles.max():.5f} deg, 99th percentile {np.percentile(angles, 99):.5f}, "
        f"median {np.median(angles):.6f}; above {LIMIT_DEG} deg: {len(above)}"
    )
    alone = [(i, n) for i, _, _, n in results if n > 0]
    print(
        f"markers: found by both within {max(w for _, _, w, _ in results):.2g} px of each other; "
        f"{sum(n for _, n in alone)} found by one implementation only, on {len(alone)} frames "
        f"{[i for i, _ in alone[:10]]}{' ...' if len(alone) > 10 else ''}"
    )
    for index, angle in above[:20]:
        print(f"  frame {index}: {angle:.4f} deg")


if __name__ == "__main__":
    main()
