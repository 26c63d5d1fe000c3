"""Throughput and memory of ``softjig estimate DATASET``: speed-up over workers, peak memory on long replays.

Run (one command, one report; about 10 minutes on a quiet 2-core machine)::

    python benchmarks/bench_throughput.py [--method refractive|paper] [--speedup-frames 400 1000]
                                          [--repeats 3] [--frames 1000 10000]

It renders a few dozen default pairs once (``--pairs``, as-built jig, default physics), then writes replay
datasets whose ``frames.jsonl`` lists N distinct frames (index 0 the unloaded reference, then the loaded
pairs over and over) whose PNGs are **hard links** to the rendered ones, so a 10,000-frame dataset costs
no disk. Every figure comes from the real command line (``softjig estimate DATASET --no-progress``) run
in a subprocess, except the steady state (below). It prints:

1. **Per frame**, one process: PNG decoding (both images) vs. each stage of ``estimate_pair`` (median ms).
2. **Whole command**: wall time of ``softjig estimate`` on each of ``--speedup-frames`` frames with 1
   worker and with ``cpu_count()`` workers, start-up included, the two interleaved ``--repeats`` times (so
   both see the same load); the speed-up of the medians and the median of the per-repeat ratios. Beside
   it, the command's *start-up* (the same command on a 2-frame dataset: imports, opening, Numba caches,
   one frame, exit) and the speed-up that start-up allows at best (Amdahl, from CPU times: the start-up
   serial, the rest divided by the cores), so what is lost to start-up and what to the parallel part can
   be told apart.
3. **Steady state**: frames per second of :func:`softjig.io.batch.estimate_dataset` in this process,
   rows of the first and last 10 % excluded (start-up and the tail do not count), 1 vs. ``cpu_count()``
   workers, interleaved, medians.
4. **Memory**: ``softjig estimate --workers cpu_count()`` on each of ``--frames`` while this process samples
   the command's process tree every 50 ms from ``/proc``: peak of the summed resident set sizes (RSS;
   pages shared by the forked workers counted in each), peak of the summed proportional set sizes (PSS:
   shared pages split between the processes, the honest total), and the largest single process's peak
   RSS. Flat memory means the same figures at 1,000 and 10,000 frames.

The machine may be shared: each run records the 1-minute load average when it starts and the CPU time the
command used (``cpu s``: user + system of the whole tree; ``cpu/wall`` shows how many cores it kept busy),
so a figure taken under load can be recognised, and its *critical-path CPU* (the command's own process's
CPU time plus its busiest worker's): the wall time it would take with a core per process, which other
jobs on the machine change much less than the wall time. Scratch data lives under ``--scratch`` (default
``/tmp/softjig-throughput``) and is deleted at the end unless ``--keep``.
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
from softjig.io.simulated import simulate_dataset
from softjig.sim.scenarios import paper_sweep

THREAD_VARIABLES = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS")
SOFTJIG = str(Path(sys.executable).with_name("softjig"))


@dataclass(frozen=True)
class RunStats:
    """One ``softjig estimate`` run.

    Attributes
    ----------
    frames, workers : the dataset's length and the ``--workers`` given.
    wall_s : wall time of the command (s), start-up included.
    cpu_s : user + system CPU time of the command's whole process tree (s).
    critical_cpu_s : CPU time of the command's own process plus that of its busiest worker (s): the wall
        time the run would take on idle cores (each process on a core of its own), so a load-independent
        figure on a shared machine (workers' CPU sampled every 50 ms from ``/proc``).
    load : 1-minute load average when the run started.
    peak_rss_mib, peak_pss_mib : peaks of the tree's summed RSS and PSS (MiB), sampled every 50 ms.
    max_process_rss_mib : the largest single process's sampled peak RSS (MiB).
    """

    frames: int
    workers: int
    wall_s: float
    cpu_s: float
    critical_cpu_s: float
    load: float
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
    with open(folder / FRAMES_NAME, "w") as fh:
        for i in range(n_frames):
            source = reference if i == 0 else loaded[(i - 1) % len(loaded)]
            record = {k: v for k, v in source.meta.items() if k not in ("truth",)}
            record.update(index=i, left=f"left/{i:06d}.png", right=f"right/{i:06d}.png")
            os.link(source.left_path, folder / record["left"])
            os.link(source.right_path, folder / record["right"])
            fh.write(json.dumps(record) + "\n")
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


CLOCK_TICKS = os.sysconf("SC_CLK_TCK")


def _cpu_s(pid: int) -> float:
    """User + system CPU time of one process so far (s), 0 if it is gone."""
    try:
        with open(f"/proc/{pid}/stat") as fh:
            fields = fh.read().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / CLOCK_TICKS  # utime, stime: fields 14 and 15
    except (OSError, IndexError, ValueError):
        return 0.0


def _children_cpu_s() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def run_estimate(dataset: Dataset, workers: int, out: Path, method: str = "refractive") -> RunStats:
    """Run ``softjig estimate`` on the dataset and sample its process tree's memory every 50 ms."""
    cmd = [SOFTJIG, "estimate", str(dataset.root), "--out", str(out), "--method", method]
    cmd += ["--workers", str(workers), "--no-progress"]
    load = os.getloadavg()[0]
    cpu0 = _children_cpu_s()
    t0 = time.perf_counter()
    # One BLAS/OpenMP/Numba thread in every process, workers=1 included: the processes are the parallelism.
    env = {**os.environ, **dict.fromkeys(THREAD_VARIABLES, "1")}
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, env=env)
    peak_rss = peak_pss = peak_one = 0
    worker_cpu: dict[int, float] = {}
    while proc.poll() is None:
        tree = _tree(proc.pid)
        sizes = [_memory_kib(p) for p in tree]
        peak_rss = max(peak_rss, sum(s[0] for s in sizes))
        peak_pss = max(peak_pss, sum(s[1] for s in sizes))
        peak_one = max(peak_one, max((s[0] for s in sizes), default=0))
        for pid in tree[1:]:
            worker_cpu[pid] = max(worker_cpu.get(pid, 0.0), _cpu_s(pid))
        time.sleep(0.05)
    wall = time.perf_counter() - t0
    output = proc.stdout.read().decode() if proc.stdout else ""
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed ({proc.returncode}):\n{output}")
    with open(out, "rb") as fh:
        rows = sum(1 for _ in fh)
    if rows != len(dataset):
        raise RuntimeError(f"{out}: {rows} rows for {len(dataset)} frames")
    cpu = _children_cpu_s() - cpu0
    own = cpu - sum(worker_cpu.values())  # the command's own process (exact total minus the workers)
    critical = own + max(worker_cpu.values(), default=0.0)
    return RunStats(
        len(dataset), workers, wall, cpu, critical, load, peak_rss / 1024, peak_pss / 1024, peak_one / 1024
    )


def steady_rate(dataset: Dataset, workers: int, method: str) -> float:
    """Frames per second in steady state: :func:`estimate_dataset` in this process, timed between the
    rows of the first and the last 10 % of the dataset (worker start-up and Numba cache loading excluded)."""
    from softjig.io.batch import BatchSettings, dataset_reference, estimate_dataset

    reference = dataset_reference(dataset, dataset.jig) if method == "refractive" else None
    settings = BatchSettings(jig=dataset.jig, method=method, reference=reference)
    stamps = [time.perf_counter() for _row in estimate_dataset(dataset, settings, workers=workers)]
    first, last = len(stamps) // 10, len(stamps) - 1 - len(stamps) // 10
    return (last - first) / (stamps[last] - stamps[first])


def frame_breakdown(dataset: Dataset, n: int = 12, method: str = "refractive") -> dict[str, float]:
    """Median ms per loaded frame in one process: PNG decoding (both images) and each estimate stage."""
    import cv2

    from softjig.io.batch import dataset_reference
    from softjig.sensing.estimator import Estimator

    cv2.setNumThreads(1)
    reference = dataset_reference(dataset, dataset.jig) if method == "refractive" else None
    estimator = Estimator(dataset.jig, method=method, reference=reference)  # once, as estimate_dataset does
    records: dict[str, list[float]] = {}
    loaded = [f for f in dataset if not f.reference][:n]
    for frame in [loaded[0], *loaded]:  # the first one warms the caches
        t0 = time.perf_counter()
        left, right = frame.load_left(), frame.load_right()
        decode = time.perf_counter() - t0
        timings: dict[str, float] = {}
        diameter = frame.part.diameter_mm if frame.part else None
        estimator.estimate(left, right, part_diameter_mm=diameter, timings=timings)
        timings = {"PNG decode (2 images)": decode, **timings}
        for stage, seconds in timings.items():
            records.setdefault(stage, []).append(seconds * 1e3)
    return {stage: float(np.median(values[1:])) for stage, values in records.items()}


def _runs(values: list[RunStats]) -> str:
    return ", ".join(f"{r.wall_s:.1f} (load {r.load:.1f})" for r in values)


def _median(values: list[float]) -> float:
    return float(np.median(values))


def whole_command(base: Dataset, scratch: Path, lengths: list[int], repeats: int, method: str) -> None:
    """Section 2: the command's wall time on 1 and on every CPU, interleaved, and its start-up."""
    cpus = os.cpu_count() or 1
    counts = sorted({1, cpus})
    tiny = write_replay(base, scratch / "startup", 2)
    out = scratch / "speedup.jsonl"
    startups = [run_estimate(tiny, 1, out, method) for _ in range(repeats)]
    start_s = _median([r.wall_s for r in startups])
    start_cpu_s = _median([r.critical_cpu_s for r in startups])
    shutil.rmtree(tiny.root)
    print(
        f"\n2. whole command, `softjig estimate`, start-up included ({repeats} interleaved repeats, medians):"
    )
    print(
        f"  {'frames':>6} {'workers':>7} {'wall s':>7} {'frames/s':>9} {'cpu s':>7} {'cpu/wall':>8} "
        f"{'critical cpu s':>14}   runs: wall s (load)"
    )
    speedups = []
    for n_frames in lengths:
        replay = write_replay(base, scratch / f"speedup{n_frames}", n_frames)
        walls: dict[int, list[RunStats]] = {w: [] for w in counts}
        for _ in range(repeats):
            for workers in counts:
                walls[workers].append(run_estimate(replay, workers, out, method))
        for workers, runs in walls.items():
            wall, cpu = _median([r.wall_s for r in runs]), _median([r.cpu_s for r in runs])
            critical = _median([r.critical_cpu_s for r in runs])
            print(
                f"  {n_frames:>6} {workers:>7} {wall:>7.2f} {n_frames / wall:>9.1f} {cpu:>7.1f} "
                f"{cpu / wall:>8.2f} {critical:>14.2f}   {_runs(runs)}",
                flush=True,
            )
        if cpus > 1:
            one, many = (_median([r.wall_s for r in walls[w]]) for w in (1, cpus))
            paired = _median([a.wall_s / b.wall_s for a, b in zip(walls[1], walls[cpus], strict=True)])
            c_one, c_many = (_median([r.critical_cpu_s for r in walls[w]]) for w in (1, cpus))
            amdahl = c_one / (start_cpu_s + (c_one - start_cpu_s) / cpus)  # from CPU times: load-proof
            speedups.append((n_frames, one / many, paired, c_one / c_many, amdahl))
    print(
        f"  start-up (the command on 2 frames, 1 worker): {start_s:.2f} s wall, {start_cpu_s:.2f} s CPU; "
        f"runs {_runs(startups)}"
    )
    for n_frames, medians, paired, critical, amdahl in speedups:
        print(
            f"  speed-up {cpus} vs 1 workers on {n_frames} frames: wall {medians:.2f}x (medians), "
            f"{paired:.2f}x (paired runs); critical-path CPU {critical:.2f}x; at best {amdahl:.2f}x with "
            "the start-up's CPU serial"
        )


def steady_state(scratch: Path, n_frames: int, repeats: int, method: str) -> None:
    """Section 3: in-process steady-state rates on 1 and on every CPU, interleaved (on the replay of
    ``n_frames`` frames section 2 wrote)."""
    cpus = os.cpu_count() or 1
    short = Dataset.open(scratch / f"speedup{n_frames}")
    rates: dict[int, list[tuple[float, float]]] = {w: [] for w in sorted({1, cpus})}
    for _ in range(repeats):
        for workers in rates:
            load = os.getloadavg()[0]
            rates[workers].append((steady_rate(short, workers, method), load))
    print(
        f"\n3. steady state, {n_frames} frames (in-process estimate_dataset; rows of the first and last "
        "10 % excluded):"
    )
    for workers, values in rates.items():
        runs = ", ".join(f"{v:.1f} (load {load:.1f})" for v, load in values)
        print(f"  workers={workers}: median {_median([v for v, _ in values]):.1f} frames/s; runs {runs}")
    if cpus > 1:
        ratio = _median([v for v, _ in rates[cpus]]) / _median([v for v, _ in rates[1]])
        print(f"  steady-state speed-up {cpus} vs 1 workers: {ratio:.2f}x (medians)")


def memory(base: Dataset, scratch: Path, lengths: list[int], method: str) -> None:
    """Section 4: peak memory of the command's process tree on long replays."""
    cpus = os.cpu_count() or 1
    print(f"\n4. memory of the process tree (parent + {cpus} workers), `softjig estimate --workers {cpus}`:")
    head = f"  {'frames':>7} {'wall s':>8} {'frames/s':>9} {'cpu s':>7} {'load':>5} {'peak RSS MiB':>13} "
    print(head + f"{'peak PSS MiB':>13} {'largest process MiB':>20}")
    for n in lengths:
        replay = write_replay(base, scratch / f"replay{n}", n)
        stats = run_estimate(replay, cpus, scratch / f"replay{n}.jsonl", method)
        print(
            f"  {n:>7} {stats.wall_s:>8.1f} {n / stats.wall_s:>9.1f} {stats.cpu_s:>7.1f} {stats.load:>5.1f} "
            f"{stats.peak_rss_mib:>13.1f} {stats.peak_pss_mib:>13.1f} {stats.max_process_rss_mib:>20.1f}",
            flush=True,
        )
        shutil.rmtree(replay.root)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, nargs="+", default=[1000, 10000], help="replay lengths")
    parser.add_argument("--pairs", type=int, default=24, help="distinct rendered pairs")
    parser.add_argument(
        "--speedup-frames", type=int, nargs="+", default=[400, 1000], help="lengths of the speed-up runs"
    )
    parser.add_argument("--repeats", type=int, default=3, help="runs per worker count (medians quoted)")
    parser.add_argument("--scratch", type=Path, default=Path("/tmp/softjig-throughput"))
    parser.add_argument("--method", choices=("refractive", "paper"), default="refractive")
    parser.add_argument("--skip-memory", action="store_true", help="no memory runs")
    parser.add_argument("--skip-steady", action="store_true", help="no steady-state runs")
    parser.add_argument("--keep", action="store_true", help="keep the scratch data")
    args = parser.parse_args()
    try:
        base = render_base(args.scratch / "base", args.pairs)
        print(
            f"machine: {os.cpu_count()} CPUs; load average {os.getloadavg()[0]:.2f} at start; "
            f"method {args.method}"
        )
        print("\n1. per loaded frame, one process, one OpenCV thread (median ms):")
        breakdown = frame_breakdown(base, method=args.method)
        for stage, ms in breakdown.items():
            print(f"  {stage:<24} {ms:8.2f}")
        print(f"  {'total':<24} {sum(breakdown.values()):8.2f}", flush=True)
        whole_command(base, args.scratch, args.speedup_frames, args.repeats, args.method)
        if not args.skip_steady:
            steady_state(args.scratch, args.speedup_frames[0], args.repeats, args.method)
        if not args.skip_memory:
            memory(base, args.scratch, args.frames, args.method)
        print(f"\nload average {os.getloadavg()[0]:.2f} at the end (other jobs share these cores)")
    finally:
        if not args.keep:
            shutil.rmtree(args.scratch, ignore_errors=True)


if __name__ == "__main__":
    main()
