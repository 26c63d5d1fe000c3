"""Throughput and memory of ``softjig estimate DATASET``: speed-up over workers, peak RSS over long replays.

Run: ``python benchmarks/bench_throughput.py [--frames 1000 10000] [--speedup-frames 400] [--repeats 2]
[--method paper]``.

It renders a few dozen default pairs once (``--pairs``, as-built jig, default physics), then writes replay
datasets whose ``frames.jsonl`` lists N distinct frames (index 0 the unloaded reference, then the loaded
pairs over and over) whose PNGs are **hard links** to the rendered ones, so a 10,000-frame dataset costs
no disk. Each replay is estimated by the real command line (``softjig estimate DATASET --no-progress``)
in a subprocess while this process samples the whole process tree every 50 ms from ``/proc``: the sum of
the resident set sizes (RSS; shared pages of forked workers counted in each) and the sum of the
proportional set sizes (PSS, shared pages split between processes: the honest total). After each run
``resource.getrusage(RUSAGE_CHILDREN).ru_maxrss`` gives the largest single process's peak. It also prints
the per-frame time breakdown in one process (PNG decoding vs. each stage of ``estimate_pair``), and the
speed-up of ``cpu_count()`` workers over one twice: the command's wall time (start-up included) and the
steady-state rate of :func:`softjig.sensing.batch.estimate_dataset` in this process (rows of the first
and last 10 % excluded, so worker start-up and Numba cache loading do not count).
Scratch data lives under ``--scratch`` (default ``/tmp/softjig-throughput``) and is deleted at the end
unless ``--keep``.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from softjig.config import default_jig
from softjig.io.dataset import FRAMES_NAME, RIG_NAME, Dataset
from softjig.sim.scenarios import paper_sweep, simulate_dataset

THREAD_VARIABLES = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS")
SOFTJIG = str(Path(sys.executable).with_name("softjig"))


@dataclass(frozen=True)
class RunStats:
    """One ``softjig estimate`` run: wall time (s), peak tree RSS and PSS (MiB), largest process (MiB)."""

    frames: int
    workers: int
    wall_s: float
    peak_rss_mib: float
    peak_pss_mib: float
    max_process_rss_mib: float


def render_base(folder: Path, n_pairs: int) -> Dataset:
    """A simulated dataset of the reference frame and ``n_pairs`` loaded pairs (50 mm, 10 deg tilt)."""
    if not (folder / FRAMES_NAME).exists():
        step = 360.0 / n_pairs
        specs = list(paper_sweep(diameters_mm=(50,), alphas_deg=(10,), theta_step_deg=step))
        simulate_dataset(folder, specs, default_jig(), seed=0, workers=os.cpu_count(), progress=False)
    return Dataset.open(folder)


def write_replay(base: Dataset, folder: Path, n_frames: int) -> Dataset:
    """A dataset of ``n_frames`` distinct frames hard-linking the base's images (frame 0: the reference)."""
    if folder.exists():
        shutil.rmtree(folder)
    (folder / "left").mkdir(parents=True)
    (folder / "right").mkdir()
    shutil.copy(base.root / RIG_NAME, folder / RIG_NAME)
    reference = next(f for f in base if f.reference)
    loaded = [f for f in base if not f.reference]
    lines = []
    for i in range(n_frames):
        source = reference if i == 0 else loaded[(i - 1) % len(loaded)]
        record = {k: v for k, v in source.meta.items() if k not in ("truth",)}
        record.update(index=i, left=f"left/{i:06d}.png", right=f"right/{i:06d}.png")
        os.link(source.left_path, folder / record["left"])
        os.link(source.right_path, folder / record["right"])
        lines.append(json.dumps(record))
    (folder / FRAMES_NAME).write_text("\n".join(lines) + "\n")
    return Dataset.open(folder)


def _tree(pid: int) -> list[int]:
    """``pid`` and its descendants (from ``/proc/*/stat``)."""
    children: dict[int, list[int]] = {}
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                with open(f"/proc/{entry}/stat") as fh:
                    ppid = int(fh.read().rsplit(")", 1)[1].split()[1])
            except (OSError, IndexError, ValueError):
                continue
            children.setdefault(ppid, []).append(int(entry))
    out, todo = [], [pid]
    while todo:
        p = todo.pop()
        out.append(p)
        todo.extend(children.get(p, []))
    return out


def _memory_kib(pid: int) -> tuple[int, int]:
    """(RSS, PSS) of one process in KiB, 0 if it is gone."""
    try:
        with open(f"/proc/{pid}/smaps_rollup") as fh:
            fields = dict(line.split(":", 1) for line in fh if ":" in line and not line.startswith("0"))
        return int(fields["Rss"].split()[0]), int(fields["Pss"].split()[0])
    except (OSError, KeyError, ValueError):
        return 0, 0


def run_estimate(dataset: Dataset, workers: int, out: Path, method: str = "refractive") -> RunStats:
    """Run ``softjig estimate`` on the dataset and sample its process tree's memory every 50 ms."""
    cmd = [
        SOFTJIG,
        "estimate",
        str(dataset.root),
        "--out",
        str(out),
        "--workers",
        str(workers),
        "--no-progress",
    ]
    before = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    t0 = time.perf_counter()
    env = {**os.environ, **dict.fromkeys(THREAD_VARIABLES, "1")}  # workers=1 is one core too
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, env=env)
    peak_rss = peak_pss = 0
    while proc.poll() is None:
        totals = np.sum([_memory_kib(p) for p in _tree(proc.pid)], axis=0)
        peak_rss, peak_pss = max(peak_rss, int(totals[0])), max(peak_pss, int(totals[1]))
        time.sleep(0.05)
    wall = time.perf_counter() - t0
    output = proc.stdout.read().decode() if proc.stdout else ""
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed ({proc.returncode}):\n{output}")
    after = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    return RunStats(len(dataset), workers, wall, peak_rss / 1024, peak_pss / 1024, max(after, before) / 1024)


def steady_rate(dataset: Dataset, workers: int, method: str) -> float:
    """Frames per second in steady state: :func:`estimate_dataset` in this process, timed between the
    rows of the first and the last 10 % of the dataset (worker start-up and Numba cache loading excluded)."""
    from softjig.sensing.batch import BatchSettings, dataset_reference, estimate_dataset

    reference = dataset_reference(dataset, dataset.jig) if method == "refractive" else None
    settings = BatchSettings(jig=dataset.jig, method=method, reference=reference)
    stamps = [time.perf_counter() for _row in estimate_dataset(dataset, settings, workers=workers)]
    first, last = len(stamps) // 10, len(stamps) - 1 - len(stamps) // 10
    return (last - first) / (stamps[last] - stamps[first])


def frame_breakdown(dataset: Dataset, n: int = 12, method: str = "refractive") -> dict[str, float]:
    """Median ms per loaded frame in one process: PNG decoding (both images) and each estimate stage."""
    import cv2

    from softjig.sensing.batch import dataset_reference
    from softjig.sensing.pipeline import estimate_pair

    cv2.setNumThreads(1)
    reference = dataset_reference(dataset, dataset.jig) if method == "refractive" else None
    records: dict[str, list[float]] = {}
    loaded = [f for f in dataset if not f.reference][:n]
    for frame in [loaded[0], *loaded]:  # the first one warms the caches
        t0 = time.perf_counter()
        left, right = frame.load_left(), frame.load_right()
        decode = time.perf_counter() - t0
        timings: dict[str, float] = {}
        diameter = frame.part.diameter_mm if frame.part else None
        estimate_pair(
            left,
            right,
            dataset.jig,
            part_diameter_mm=diameter,
            method=method,
            reference=reference,
            timings=timings,
        )
        timings = {"PNG decode (2 images)": decode, **timings}
        for stage, seconds in timings.items():
            records.setdefault(stage, []).append(seconds * 1e3)
    return {stage: float(np.median(values[1:])) for stage, values in records.items()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, nargs="+", default=[1000, 10000], help="replay lengths")
    parser.add_argument("--pairs", type=int, default=24, help="distinct rendered pairs")
    parser.add_argument("--speedup-frames", type=int, default=400, help="frames of the speed-up runs")
    parser.add_argument("--repeats", type=int, default=2, help="speed-up runs per worker count")
    parser.add_argument("--scratch", type=Path, default=Path("/tmp/softjig-throughput"))
    parser.add_argument("--method", choices=("refractive", "paper"), default="refractive")
    parser.add_argument("--skip-memory", action="store_true", help="only the breakdown and speed-up")
    parser.add_argument("--keep", action="store_true", help="keep the scratch data")
    args = parser.parse_args()
    cpus = os.cpu_count() or 1
    try:
        base = render_base(args.scratch / "base", args.pairs)
        print(f"machine: {cpus} CPUs; load average {os.getloadavg()[0]:.2f} at start; method {args.method}")
        print("\nper loaded frame, one process, one OpenCV thread (median ms):")
        breakdown = frame_breakdown(base, method=args.method)
        for stage, ms in breakdown.items():
            print(f"  {stage:<24} {ms:8.2f}")
        print(f"  {'total':<24} {sum(breakdown.values()):8.2f}")

        short = write_replay(base, args.scratch / "speedup", args.speedup_frames)
        print(f"\nspeed-up, {args.speedup_frames} frames, `softjig estimate` wall time incl. start-up:")
        walls: dict[int, list[float]] = {}
        for _ in range(args.repeats):
            for workers in sorted({1, cpus}):
                stats = run_estimate(short, workers, args.scratch / "speedup.jsonl", args.method)
                walls.setdefault(workers, []).append(stats.wall_s)
        for workers, values in walls.items():
            print(
                f"  workers={workers}: {', '.join(f'{v:.1f}' for v in values)} s "
                f"({args.speedup_frames / min(values):.1f} frames/s at best)"
            )
        if cpus > 1:
            best = min(walls[1]) / min(walls[cpus])
            median = float(np.median(walls[1]) / np.median(walls[cpus]))
            print(f"  speed-up {cpus} vs 1 workers: {best:.2f}x best of {args.repeats}, {median:.2f}x median")
        rates: dict[int, list[float]] = {}
        for _ in range(args.repeats):
            for workers in sorted({1, cpus}):
                rates.setdefault(workers, []).append(steady_rate(short, workers, args.method))
        print("  steady state (in-process estimate_dataset, first and last 10 % of rows excluded):")
        for workers, values in rates.items():
            print(f"  workers={workers}: {', '.join(f'{v:.1f}' for v in values)} frames/s")
        if cpus > 1:
            best = max(rates[cpus]) / max(rates[1])
            median = float(np.median(rates[cpus]) / np.median(rates[1]))
            print(f"  steady-state speed-up: {best:.2f}x best of {args.repeats}, {median:.2f}x median")
        shutil.rmtree(short.root)

        print(f"\nmemory of the process tree (parent + {cpus} workers), `softjig estimate --workers {cpus}`:")
        print(
            f"  {'frames':>7} {'wall s':>8} {'frames/s':>9} {'peak RSS MiB':>13} {'peak PSS MiB':>13} "
            f"{'largest process MiB':>20}"
        )
        for n in [] if args.skip_memory else args.frames:
            replay = write_replay(base, args.scratch / f"replay{n}", n)
            stats = run_estimate(replay, cpus, args.scratch / f"replay{n}.jsonl", args.method)
            rows = len((args.scratch / f"replay{n}.jsonl").read_text().splitlines())
            assert rows == n, f"{rows} rows for {n} frames"
            print(
                f"  {n:>7} {stats.wall_s:>8.1f} {n / stats.wall_s:>9.1f} {stats.peak_rss_mib:>13.1f} "
                f"{stats.peak_pss_mib:>13.1f} {stats.max_process_rss_mib:>20.1f}",
                flush=True,
            )
            shutil.rmtree(replay.root)
        print(f"load average {os.getloadavg()[0]:.2f} at the end (other jobs share these cores)")
    finally:
        if not args.keep:
            shutil.rmtree(args.scratch, ignore_errors=True)


if __name__ == "__main__":
    main()
