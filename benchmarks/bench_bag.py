"""Estimating a ROS 2 bag of mono8 pairs against the same frames as a PNG dataset, on one worker.

Simulates a paper sweep (1280x720 mono8, the default jig), converts it to a bag (``softjig convert``'s
:func:`~softjig.io.bag_convert.dataset_to_bag`, zstd chunks), then for each source times, per frame:

* ``read``: getting the pair's two images into memory (PNG decode; bag: zstd chunk, CDR, pairing),
* ``read + estimate``: that and one :class:`~softjig.sensing.estimator.Estimator`'s ``estimate`` (refractive
  method, against the reference frame), what ``softjig estimate --workers 1`` spends per frame.

One warm-up pass first (Numba caches, per-jig tables), then one timed run. Each figure is given as the
median over the loaded frames and as their mean (the total over the frames after the first, which pays
for opening the source, divided by the loaded frames): a bag's zstd chunk holds about two 1280x720 pairs,
so one frame in two or three pays for decompressing it and the median leaves that out; the mean is what
a recording costs. Target (issue 15): a bag's ``read + estimate`` at most 6 ms a frame.

Run: ``python benchmarks/bench_bag.py [--frames-per-alpha 12] [--out DIR]``. The numbers depend on the
machine's load (the shared development machine runs several sessions at once): quote medians and say so.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import statistics
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")


def timed_frames(frames, estimator, *, estimate: bool):
    """``(reference, wall s, CPU s)`` per frame of ``frames``: from asking for the frame to having its
    images (and, ``estimate``, the estimate of a loaded frame). Of this benchmark and bench_frame's."""
    from softjig.errors import SoftjigError

    it = iter(frames)
    while True:
        t0, c0 = time.perf_counter(), time.process_time()
        frame = next(it, None)
        if frame is None:
            return
        left, right = frame.load_left(), frame.load_right()
        if not frame.reference and estimate:
            with contextlib.suppress(SoftjigError):
                estimator.estimate(left, right)
        yield frame.reference, time.perf_counter() - t0, time.process_time() - c0


def _time_source(frames, jig, reference, *, estimate: bool) -> tuple[list[float], list[float], float]:
    """Wall and CPU seconds per loaded frame: from asking for the frame to having its images (and its
    estimate), and the mean CPU seconds a loaded frame. The source's opening (a bag's metadata and type
    definitions, ~0.1-0.3 s once) falls on the first frame, which the medians ignore and the mean leaves
    out; the reference frame's read counts towards the mean."""
    from softjig.sensing.estimator import Estimator

    estimator = Estimator(jig, reference=reference, method="refractive")  # once, as estimate_dataset does
    wall, cpu = [], []
    total = 0.0
    for k, (is_reference, spent_wall, spent) in enumerate(timed_frames(frames, estimator, estimate=estimate)):
        total += 0.0 if k == 0 else spent
        if not is_reference:
            wall.append(spent_wall)
            cpu.append(spent)
    return wall, cpu, total / max(len(cpu) - 1, 1)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames-per-alpha", type=int, default=12, help="theta steps per tilt (4 tilts)")
    parser.add_argument("--out", type=Path, default=None, help="keep the dataset and bag here")
    args = parser.parse_args()

    import cv2

    cv2.setNumThreads(1)
    from softjig.config import default_jig
    from softjig.io.bag_convert import dataset_to_bag
    from softjig.io.batch import dataset_reference
    from softjig.io.dataset import Dataset
    from softjig.io.rosbag import BagReader
    from softjig.io.simulated import simulate_dataset
    from softjig.sim.scenarios import paper_sweep

    root = args.out or Path(tempfile.mkdtemp(prefix="bench_bag_"))
    ds_path, bag_path = root / "dataset", root / "bag"
    step = 360.0 / args.frames_per_alpha
    if not (ds_path / "frames.jsonl").exists():
        specs = list(paper_sweep(diameters_mm=(50,), alphas_deg=(5, 10, 15, 20), theta_step_deg=step))
        simulate_dataset(ds_path, specs, default_jig(), seed=7, workers=os.cpu_count(), progress=False)
    dataset = Dataset.open(ds_path)
    jig = dataset.jig
    if not (bag_path / "metadata.yaml").exists():
        dataset_to_bag(dataset, bag_path, estimate=False, start_unix_s=1.7e9)
    reference = dataset_reference(dataset, jig)
    png_mb = sum(p.stat().st_size for p in (ds_path / "left").iterdir()) * 2 / 2**20
    bag_mb = sum(p.stat().st_size for p in bag_path.glob("*.mcap")) / 2**20

    def bag_frames():
        with BagReader(bag_path) as reader:
            yield from reader.pairs(reader.choose_topics())

    _time_source(dataset, jig, reference, estimate=True)  # warm-up: Numba, tables, page cache
    _time_source(bag_frames(), jig, reference, estimate=True)
    results = {}
    for name, source in (("PNG dataset", lambda: dataset), ("ROS 2 bag", bag_frames)):
        read, read_cpu, read_mean = _time_source(source(), jig, reference, estimate=False)
        full, full_cpu, full_mean = _time_source(source(), jig, reference, estimate=True)
        med = statistics.median
        results[name] = (med(read), med(read_cpu), read_mean, med(full), med(full_cpu), full_mean, len(full))
    print(f"{len(dataset)} frames, 1280x720 mono8, one worker, one OpenCV thread; PNG {png_mb:.0f} MiB, "
          f"bag {bag_mb:.0f} MiB (zstd chunks)")  # fmt: skip
    print(f"{'source':<12} {'read ms/frame':>28} {'read+estimate ms/frame':>30} {'frames':>7}")
    print(f"{'':<12} {'wall / CPU / CPU mean':>28} {'wall / CPU / CPU mean':>30}")
    for name, (read, read_cpu, read_mean, full, full_cpu, full_mean, n) in results.items():
        print(
            f"{name:<12} {1000 * read:>10.2f} / {1000 * read_cpu:>6.2f} / {1000 * read_mean:>6.2f} "
            f"{1000 * full:>12.2f} / {1000 * full_cpu:>6.2f} / {1000 * full_mean:>6.2f} {n:>7}"
        )
    print(
        "medians (and CPU means) of one run; wall times suffer from the shared machine's load (CPU time, "
        f"this process only, less so); load average now {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs"
    )


if __name__ == "__main__":
    main()
