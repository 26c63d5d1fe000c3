"""Scale of ``softjig study``: tasks/s and speed-up on 1 and 2 local workers and on a local Ray cluster of 2
workers, Ray's overhead per task against the local pool, and the projected time of a 10,000-design study on
100 cores.

Run: ``python benchmarks/bench_study.py [--tasks 6] [--frames-per-task 12] [--repeats 3]
[--write benchmarks/RESULTS.md]`` (about 3 minutes with the defaults on a quiet 2-core machine). Needs Ray
(``pip install 'softjig[ray]'``).

What it measures
----------------
A **study task** is what ``softjig study`` runs (:func:`softjig.study.run.run_task`): one design's as-built
jig, its unloaded reference frame and ``--frames-per-task`` loaded frames (paper-sweep cylinders, 50 and
60 mm, tilts 5 and 15 deg, azimuths every 360 / (frames / 4) deg) rendered in memory and estimated with
the refractive method. Each task is a different design (``markers.pitch_mm`` a little different), so no
worker ever reuses a previous task's per-jig tables: every task pays what a new design costs.

1. **Backends.** The same ``--tasks`` tasks run on: the local pool with 1 worker (in this process),
   the local pool with 2 forked workers, and a local Ray cluster of 2 workers started by this benchmark
   (``ray.init(num_cpus=2)``, warmed up first with one task per worker: its start-up, about 10-20 s, is
   reported separately, as a study pays it once). The order alternates over ``--repeats`` rounds, each
   round with new designs; figures are medians over rounds. For each: **tasks/s** (tasks / wall time),
   **speed-up** against 1 worker, and **overhead per task**: ``(workers x wall - sum of the tasks' own
   compute time) / tasks``, the time a worker was not running a task (dispatch, pickling, the rows'
   return, idling at the end); its share of a task's compute time is the **scheduling share** (the
   issue's goal: under 5 %).
2. **Dispatch cost.** ``--empty`` tasks that do nothing (no frame, no method) on the 2-worker pool and on
   Ray: the pure cost of one task's round trip, without the tail of the last tasks.
3. **The driver.** Writing one task's part file (Parquet, atomic, fsynced) and consolidating the tables,
   per task and per row: how many tasks/s one driver process sustains.
4. **The estimator's set-up** per task: what :func:`run_task` pays before its first timed estimate (one
   Estimator per method, the reference frame's markers, an untimed first estimate), and the warm estimate
   after it (what a row's ``estimate_ms`` times), on new designs in this (warm) process.
5. **Projection** of a 10,000-design study on 100 cores (see the assumptions printed with it).

The machine is shared (several sessions on 2 cores): timings are noisy, so they are medians of rounds
run alternately, and the speed-ups are those of this machine's load, not of idle cores.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import platform  # noqa: E402
import statistics  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from collections.abc import Callable, Iterable, Sequence  # noqa: E402
from dataclasses import dataclass, replace  # noqa: E402
from pathlib import Path  # noqa: E402

from softjig.study.results import open_study_folder, part_table  # noqa: E402
from softjig.study.run import (  # noqa: E402
    TaskInput,
    TaskResult,
    local_results,
    make_tasks,
    ray_results,
    run_task,
    task_inputs,
)
from softjig.study.spec import Study, build_designs, parse_study  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from results_section import replace_section  # noqa: E402

SECTION = "## Design studies at scale (benchmarks/bench_study.py)"
PROJECTED_DESIGNS = 10_000
PROJECTED_CORES = 100
#: The issue's default study's frames per design: diameters (40, 60) x tilts (5, 10, 20) x 12 azimuths.
PROJECTED_FRAMES = 72
#: Pairs rendered and estimated, one thread, for an idle core's cost of a pair (:func:`idle_pair_cost`):
#: the fastest of them is the one the other sessions on this machine disturbed least.
IDLE_PAIRS = 12
#: New designs whose estimator set-up is timed.
SETUP_DESIGNS = 5
BACKENDS = ("local, 1 worker", "local, 2 workers", "Ray local, 2 workers")


@dataclass(frozen=True)
class Timing:
    """One backend's run of a batch of tasks."""

    backend: str
    workers: int
    tasks: int
    wall_s: float
    compute_s: float
    render_s: float

    @property
    def tasks_per_s(self) -> float:
        return self.tasks / self.wall_s

    @property
    def overhead_per_task_s(self) -> float:
        return (self.workers * self.wall_s - self.compute_s) / self.tasks

    @property
    def scheduling_share(self) -> float:
        return self.overhead_per_task_s / (self.compute_s / self.tasks)


def make_study(n_designs: int, frames_per_task: int) -> Study:
    """``n_designs`` designs (distinct pitches) of ``frames_per_task`` loaded frames, one task each."""
    n_theta = max(1, frames_per_task // 4)
    spec = parse_study(
        {
            "study": {"name": "bench", "seeds": [0], "frames_per_task": frames_per_task},
            "vary": {"markers.pitch_mm": {"start": 7.0, "stop": 9.0, "num": n_designs}},
            "frames": {"diameters_mm": [50, 60], "alphas_deg": [5, 15], "theta_step_deg": 360.0 / n_theta},
            "estimate": {"methods": ["refractive"]},
        }
    )
    return Study(spec, build_designs(spec))


def batches(study: Study, size: int) -> list[list[TaskInput]]:
    """The study's task inputs in consecutive batches of ``size`` (each a different set of designs)."""
    inputs = list(task_inputs(study, make_tasks(study)))
    return [inputs[k : k + size] for k in range(0, len(inputs) - size + 1, size)]


def timed(
    backend: str, workers: int, run: Callable[[list[TaskInput]], Iterable[TaskResult]], batch
) -> Timing:
    t0 = time.perf_counter()
    results = list(run(batch))
    wall = time.perf_counter() - t0
    return Timing(
        backend,
        workers,
        len(results),
        wall,
        sum(r.compute_s for r in results),
        sum(r.render_s for r in results),
    )


def empty_inputs(batch: Sequence[TaskInput], n: int) -> list[TaskInput]:
    """``n`` tasks that render and estimate nothing: the cost of a task's round trip alone."""
    inp = batch[0]
    return [TaskInput(replace(inp.task, stop=inp.task.first), inp.jig, inp.frames[:1], ()) for _ in range(n)]


def driver_costs(study: Study, batch: Sequence[TaskInput]) -> tuple[float, float]:
    """Median time to write one task's part file, and to read it back when consolidating (s)."""
    result = run_task(batch[0])
    values = study.designs[result.task.design_id].values
    table = part_table(study.spec, values, result.columns)
    with tempfile.TemporaryDirectory() as tmp:
        folder = open_study_folder(Path(tmp) / "out", study.spec, resume=False, n_tasks=1)
        times = []
        for k in range(20):
            t0 = time.perf_counter()
            folder.write_part(f"d{k:06d}-s0-c0000", part_table(study.spec, values, result.columns))
            times.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        folder.read_results()
        consolidate_per_task = (time.perf_counter() - t0) / len(times)
    del table
    return statistics.median(times), consolidate_per_task


def setup_costs(study: Study) -> tuple[float, float]:
    """Median per-task set-up of a new design's estimator, as :func:`run_task` pays it (the Estimator's
    build, the reference frame's markers, the refractive estimator on them, the untimed first estimate),
    and the median warm estimate after it (s); this process is warm (a worker's start-up is not in it)."""
    import numpy as np

    from softjig.sensing.estimator import Estimator
    from softjig.sim.asbuilt import draw_as_built
    from softjig.sim.render import render_pair

    setups, warm = [], []
    for inp in list(task_inputs(study, make_tasks(study)))[-SETUP_DESIGNS:]:
        as_built = draw_as_built(inp.jig, np.random.default_rng(0))
        unloaded, loaded = (
            render_pair(as_built, f.part, f.pose, np.random.default_rng(k))
            for k, f in enumerate(inp.frames[:2])
        )
        diameter = inp.frames[1].part.diameter_mm
        t0 = time.perf_counter()
        base = Estimator(inp.jig)
        reference = base.reference_from_pair(unloaded.left, unloaded.right)
        estimator = Estimator(inp.jig, reference=reference, model=base.model)
        estimator.estimate(loaded.left, loaded.right, part_diameter_mm=diameter)
        t1 = time.perf_counter()
        estimator.estimate(loaded.left, loaded.right, part_diameter_mm=diameter)
        setups.append(t1 - t0)
        warm.append(time.perf_counter() - t1)
    return statistics.median(setups), statistics.median(warm)


def idle_pair_cost(study: Study) -> tuple[float, float]:
    """An idle core's CPU seconds to render a pair and to estimate it, measured here: the fastest of
    :data:`IDLE_PAIRS` frames of one design, each rendered with the design's one
    :class:`~softjig.sim.render.Renderer` (as :func:`run_task` renders them) and estimated warm, in one
    thread (the process's CPU time, so other sessions' load slows it only through shared caches)."""
    import numpy as np

    from softjig.sensing.estimator import Estimator
    from softjig.sim.asbuilt import draw_as_built
    from softjig.sim.render import Renderer

    inp = next(iter(task_inputs(study, make_tasks(study))))
    renderer = Renderer(draw_as_built(inp.jig, np.random.default_rng(0)))
    frame = inp.frames[1]
    estimator = Estimator(inp.jig)
    renders, estimates = [], []
    for k in range(IDLE_PAIRS + 2):  # the first two warm the caches
        t0 = time.process_time()
        pair = renderer.render_pair(frame.part, frame.pose, np.random.default_rng(k))
        t1 = time.process_time()
        estimator.estimate(pair.left, pair.right, part_diameter_mm=frame.part.diameter_mm)
        renders.append(t1 - t0)
        estimates.append(time.process_time() - t1)
    return min(renders[2:]), min(estimates[2:])


def run_rounds(study: Study, args: argparse.Namespace) -> tuple[dict[str, list[Timing]], dict[str, float]]:
    import ray

    rounds = batches(study, args.tasks)
    warm, rounds = rounds[0], rounds[1:]
    t0 = time.perf_counter()
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    list(ray_results(warm[:2], "local"))  # each Ray worker imports softjig and loads the Numba caches once
    extra = {"ray_start_s": time.perf_counter() - t0}
    run_task(warm[-1])  # this process too (the forked pool's workers inherit it)
    extra["setup_s"], extra["warm_estimate_s"] = setup_costs(study)
    extra["idle_render_s"], extra["idle_estimate_s"] = idle_pair_cost(study)
    runners = {
        BACKENDS[0]: (1, lambda b: local_results(b, 1)),
        BACKENDS[1]: (2, lambda b: local_results(b, 2)),
        BACKENDS[2]: (2, lambda b: ray_results(b, "local")),
    }
    timings: dict[str, list[Timing]] = {name: [] for name in BACKENDS}
    try:
        for k in range(args.repeats):
            order = BACKENDS if k % 2 == 0 else BACKENDS[::-1]
            for j, name in enumerate(order):
                workers, run = runners[name]
                batch = rounds[(k * len(BACKENDS) + j) % len(rounds)]
                timings[name].append(timed(name, workers, run, batch))
                print(f"round {k}: {name}: {timings[name][-1].tasks_per_s:.3f} tasks/s", flush=True)
        for name in BACKENDS[1:]:
            workers, run = runners[name]
            empty = empty_inputs(warm, args.empty)
            extra[f"empty {name}"] = statistics.median(
                (workers * timed(name, workers, run, empty).wall_s) / args.empty for _ in range(3)
            )
    finally:
        ray.shutdown()
    return timings, extra


def _median(values: Iterable[float]) -> float:
    return statistics.median(list(values))


def _platform(args: argparse.Namespace) -> str:
    return (
        f"{platform.node()}, {os.cpu_count()} CPUs shared with other sessions, Python "
        f"{platform.python_version()}; `python benchmarks/bench_study.py --tasks {args.tasks} "
        f"--frames-per-task {args.frames_per_task} --repeats {args.repeats}`. A task: one new design, its "
        f"reference frame and {args.frames_per_task} loaded frames rendered in memory and estimated "
        "(refractive). Medians over rounds run alternately."
    )


def _row(name: str, ts: list[Timing], base: float) -> str:
    rate = _median(t.tasks_per_s for t in ts)
    cells = (
        name,
        f"{rate:.3f}",
        f"{rate / base:.2f}x",
        f"{_median(t.compute_s / t.tasks for t in ts):.2f}",
        f"{_median(t.render_s / t.tasks for t in ts):.2f}",
        f"{1e3 * _median(t.overhead_per_task_s for t in ts):.0f}",
        f"{100 * _median(t.scheduling_share for t in ts):.1f} %",
    )
    return "| " + " | ".join(cells) + " |"


def report(timings: dict[str, list[Timing]], extra: dict[str, float], args: argparse.Namespace) -> list[str]:
    base = _median(t.tasks_per_s for t in timings[BACKENDS[0]])
    lines = [
        _platform(args),
        "",
        "| backend | tasks/s | speed-up | task compute (s) | of which render (s) | overhead/task (ms) "
        "| scheduling share |",
        "|---|---|---|---|---|---|---|",
        *(_row(name, timings[name], base) for name in BACKENDS),
    ]
    local = _median(t.overhead_per_task_s for t in timings[BACKENDS[1]])
    on_ray = _median(t.overhead_per_task_s for t in timings[BACKENDS[2]])
    empty_pool, empty_ray = extra[f"empty {BACKENDS[1]}"], extra[f"empty {BACKENDS[2]}"]
    lines += [
        "",
        "- Ray's overhead per task against the local pool (2 workers each): "
        f"{1e3 * (on_ray - local):+.0f} ms (Ray {1e3 * on_ray:.0f} ms, pool {1e3 * local:.0f} ms, from the "
        "table: the idle tail of the last tasks included). Round trip of an empty task, per worker: pool "
        f"{1e3 * empty_pool:.1f} ms, Ray {1e3 * empty_ray:.1f} ms.",
        "- Starting the local Ray cluster and warming its 2 workers (once per study): "
        f"{extra['ray_start_s']:.1f} s.",
        f"- The driver: a task's part file written in {1e3 * extra['write_part_s']:.1f} ms (atomic, "
        f"fsynced) and read back in {1e3 * extra['consolidate_per_task_s']:.1f} ms when consolidating.",
        "- A task's estimator set-up (one Estimator per method built for the task, the reference frame's "
        f"markers, the untimed first estimate): {1e3 * extra['setup_s']:.0f} ms; then a warm estimate "
        f"{1e3 * extra['warm_estimate_s']:.1f} ms (what a row's `estimate_ms` times), medians of "
        f"{SETUP_DESIGNS} new designs in a warm process.",
    ]
    return lines + projection(timings, extra, args)


def projection(
    timings: dict[str, list[Timing]], extra: dict[str, float], args: argparse.Namespace
) -> list[str]:
    ts = timings[BACKENDS[2]]
    per_task = _median(t.compute_s / t.tasks for t in ts)
    per_frame = per_task / (args.frames_per_task + 1)  # the reference frame is one more render
    task_s = per_frame * (PROJECTED_FRAMES + 1)
    overhead = _median(t.overhead_per_task_s for t in ts)
    share = overhead / task_s
    n_tasks = PROJECTED_DESIGNS
    compute = n_tasks * (task_s + overhead) / PROJECTED_CORES
    consolidate = n_tasks * extra["consolidate_per_task_s"]
    total = compute + extra["ray_start_s"] + consolidate
    idle_pair_s = extra["idle_render_s"] + extra["idle_estimate_s"]
    idle_task_s = extra["setup_s"] + (PROJECTED_FRAMES + 1) * idle_pair_s
    idle_total = n_tasks * (idle_task_s + overhead) / PROJECTED_CORES + extra["ray_start_s"] + consolidate
    return [
        "",
        f"**Projection: {PROJECTED_DESIGNS:,} designs on {PROJECTED_CORES} cores (Ray): about "
        f"{total / 3600:.1f} h** ({total / 60:.0f} min). Assumptions: the issue's default frames "
        f"({PROJECTED_FRAMES} loaded frames a design, 1 seed, 1 method: one task of "
        f"{PROJECTED_FRAMES + 1} renders and {PROJECTED_FRAMES} estimates, {task_s:.1f} s from the "
        f"{per_frame:.3f} s a frame measured here on Ray, a new design's per-jig set-up spread over the "
        "frames as measured); cores as fast as these shared ones; Ray's overhead per task as measured "
        f"here ({1e3 * overhead:.0f} ms, idle tail included: {100 * share:.1f} % of a "
        f"{PROJECTED_FRAMES}-frame task); no node lost; the cluster's start-up as here "
        f"({extra['ray_start_s']:.0f} s; a real "
        f"cluster's is longer, once). The driver must take {PROJECTED_CORES / task_s:.1f} tasks/s and "
        f"writes {1.0 / extra['write_part_s']:.0f} part files a second, so it is not the bottleneck; "
        f"consolidating the {n_tasks * PROJECTED_FRAMES:,} rows at the end takes {consolidate:.0f} s. "
        "Each worker holds a few hundred MB (one 1280 x 720 pair rendered and estimated: ~260 MB peak, "
        "config.py), so 100 workers need ~30 GB across the cluster.",
        "",
        f"**On idle cores: about {idle_total / 60:.0f} min**, with the same overheads and a task of "
        f"{idle_task_s:.1f} s ({PROJECTED_FRAMES + 1} pairs at {1e3 * idle_pair_s:.0f} ms: the fastest of "
        f"{IDLE_PAIRS} pairs rendered ({1e3 * extra['idle_render_s']:.1f} ms, one Renderer) and estimated "
        f"({1e3 * extra['idle_estimate_s']:.1f} ms) here in CPU time, plus the estimator's set-up once a "
        f"task, {1e3 * extra['setup_s']:.0f} ms as measured here): this machine's cores were shared by "
        "several sessions when measured, so its per-frame time is an upper bound.",
    ]


def write_section(path: Path, lines: Iterable[str]) -> None:
    """Replace this benchmark's section of ``path``, or append it."""
    replace_section(path, SECTION, lines)


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tasks", type=int, default=6, help="tasks per backend and round")
    parser.add_argument("--frames-per-task", type=int, default=12, help="loaded frames per task")
    parser.add_argument("--repeats", type=int, default=3, help="rounds (backends alternate)")
    parser.add_argument("--empty", type=int, default=100, help="empty tasks for the dispatch cost")
    parser.add_argument("--write", type=Path, default=None, help="write this section into a RESULTS.md")
    args = parser.parse_args(argv)
    for name in ("tasks", "frames_per_task", "repeats", "empty"):
        if getattr(args, name) < 1:
            parser.error(f"--{name.replace('_', '-')} must be at least 1, got {getattr(args, name)}")
    study = make_study(args.tasks * (1 + args.repeats * len(BACKENDS)), args.frames_per_task)
    timings, extra = run_rounds(study, args)
    extra["write_part_s"], extra["consolidate_per_task_s"] = driver_costs(study, batches(study, 1)[0])
    lines = report(timings, extra, args)
    print("\n".join(lines))
    if args.write is not None:
        write_section(args.write, lines)


if __name__ == "__main__":
    main()
