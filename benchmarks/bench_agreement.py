"""Fast against straightforward implementation on a whole sweep: the normals must agree within 0.05 deg.

Run: ``python benchmarks/bench_agreement.py SWEEP [--method refractive|paper] [--workers N]``, with SWEEP a
dataset from ``softjig simulate --scenario paper-sweep`` (the default sweep: ``--seed 0``). Every loaded
frame is estimated twice, with ``estimate_pair(fast=True)`` (pyramid candidates, fiducials read near their
expected place, Numba matching and closed-form triangulation) and ``fast=False`` (full-resolution LoG, full
ArUco detection, the reference matching, Newton triangulation), and the angle between the two normals is
reported: its maximum, 99th percentile and median, and the frames above 0.05 deg.
"""

from __future__ import annotations

import argparse
from concurrent.futures import ProcessPoolExecutor

import numpy as np

from softjig.geometry import angle_between
from softjig.io.dataset import Dataset, Frame
from softjig.sensing.batch import dataset_reference
from softjig.sensing.pipeline import estimate_pair

LIMIT_DEG = 0.05
_STATE: dict = {}


def _init(path: str, method: str) -> None:
    import cv2

    cv2.setNumThreads(1)
    dataset = Dataset.open(path)
    _STATE.update(
        jig=dataset.jig,
        method=method,
        reference=dataset_reference(dataset, dataset.jig) if method == "refractive" else None,
    )


def _both(frame: Frame) -> tuple[int, float | None]:
    """The angle (deg) between the fast and the straightforward normal of one frame (None: no estimate)."""
    left, right = frame.load_left(), frame.load_right()
    diameter = None if frame.part is None else float(frame.part.diameter_mm)
    normals = []
    for fast in (True, False):
        try:
            result = estimate_pair(
                left,
                right,
                _STATE["jig"],
                part_diameter_mm=diameter,
                method=_STATE["method"],
                reference=_STATE["reference"],
                fast=fast,
            )
        except Exception:  # a frame either implementation cannot estimate is counted, not compared
            return frame.index, None
        normals.append(np.asarray(result.estimate.normal))
    return frame.index, float(np.degrees(angle_between(normals[0], normals[1])))


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
    angles = np.array([a for _, a in results if a is not None])
    failed = [i for i, a in results if a is None]
    above = [(i, a) for i, a in results if a is not None and a > LIMIT_DEG]
    print(f"{args.method}: {len(angles)} frames compared, {len(failed)} without an estimate")
    print(
        f"fast vs straightforward normal: max {angles.max():.5f} deg, 99th percentile "
        f"{np.percentile(angles, 99):.5f}, median {np.median(angles):.6f}; "
        f"above {LIMIT_DEG} deg: {len(above)}"
    )
    for index, angle in above[:20]:
        print(f"  frame {index}: {angle:.4f} deg")


if __name__ == "__main__":
    main()
