"""Running a study: its tasks, each rendered and estimated in memory, on a local process pool or on Ray.

A **task** is one design, one seed and a chunk of the design's loaded frames (all of them up to
``[study] frames_per_task``, 96 by default): :func:`run_task` draws the design's as-built jig from the
seed, renders the unloaded reference frame and the chunk's frames with one simulator
(:class:`softjig.sim.render.Renderer` of the as-built jig, built once for the task; images never touch
the disk) and estimates each frame with every method of the study. It builds one
:class:`~softjig.sensing.estimator.Estimator` per method for the task (the per-jig set-up paid once; the
methods share the jig's model), the refractive one against the reference frame's markers, and calls it
frame after frame. Frame ``k`` is rendered from ``SeedSequence(seed, spawn_key=(1, k + 1))`` and the
as-built jig from ``SeedSequence(seed, spawn_key=(0,))``, exactly as ``softjig simulate`` numbers a paper
sweep's frames after its reference: a study's frame is the frame ``softjig simulate --config
best/NNN.toml --seed S`` renders, whatever the chunking or the machine. Every design sees the same
seeds' noise (common random numbers: designs are compared on the same draws).

**Timing.** A row's ``estimate_ms`` is the wall time of that frame's ``Estimator.estimate`` alone, warm:
the estimators' build is not in it, and each estimator estimates the task's first frame once untimed
before its timed estimates (the first call's lazy tables and compiled kernels; its result is discarded,
an estimator's answer does not depend on what it estimated before). So ``latency_ms_median`` in
``designs.parquet`` is what one more frame costs a running estimator.

**Sizing.** A task of the default study is 73 renders and 72 estimates: about 3-6 s of work on one core
(about 45 ms a pair rendered, 5 ms an estimate), against about 1 ms to send it and its rows through a
local pool and a few ms through Ray (``benchmarks/bench_study.py`` measures both): scheduling stays far
below 5 % of the work. Chunking a design's frames costs one reference render per chunk (at most 1/96 of
a task), and keeps a design with many frames from holding one worker for minutes.

**Backends.** :func:`local_results` runs tasks in this process (``workers = 1``) or on a pool of forked
worker processes (:func:`softjig.io.workers.worker_pool`: they die with this process, SIGTERM ends them at
once), with a bounded number of tasks in flight. :func:`ray_results` submits the same function to a Ray
cluster (``address``: ``"auto"``, ``"ray://host:10001"``, ``"host:6379"``, or ``"local"`` to start one on
this machine with ``workers`` CPUs); every node needs softjig installed (``pip install softjig[ray]``).
Both yield :class:`TaskResult` as tasks finish; the study is the same either way.

"""

from __future__ import annotations

import contextlib
import math
import time
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from itertools import islice
from typing import Any

import numpy as np

from softjig.config import JigConfig
from softjig.errors import EstimationError, InputError
from softjig.study.spec import Study

__all__ = [
    "Task",
    "TaskInput",
    "TaskResult",
    "local_results",
    "make_tasks",
    "ray_connection",
    "ray_results",
    "run_task",
]

#: Tasks in flight per worker: one running, one queued, so no worker waits for the parent.
IN_FLIGHT_PER_WORKER = 2
_SUSPECT_PREFIX = "suspect: "  # softjig.sensing.results.SUSPECT_PREFIX (sensing is imported lazily)
_REASON_CHARS = 300  # a failure's message is kept to this length in the results


@dataclass(frozen=True)
class Task:
    """One unit of work: design ``design_id`` with ``seed``, its loaded frames ``first <= k < stop``."""

    design_id: int
    seed: int
    chunk: int
    first: int
    stop: int

    @property
    def name(self) -> str:
        """The task's name (its part file's stem): ``d<design>-s<seed>-c<chunk>``."""
        return f"d{self.design_id:06d}-s{self.seed}-c{self.chunk:04d}"

    @property
    def n_frames(self) -> int:
        """Loaded frames estimated by the task."""
        return self.stop - self.first


@dataclass(frozen=True)
class TaskInput:
    """What a worker needs for one task (sent with it: a jig and its frames are a few kB)."""

    task: Task
    jig: JigConfig
    frames: tuple[Any, ...] = field(repr=False)  # FrameSpec: the reference, then the task's frames
    methods: tuple[str, ...]


@dataclass(frozen=True)
class TaskResult:
    """A finished task: its rows (the columns of :data:`softjig.study.results.RESULT_FIELDS`) and times.

    Attributes
    ----------
    task : which task.
    columns : column name -> one value per row (rows: frames x methods).
    compute_s : wall time of :func:`run_task` in the worker (s).
    render_s : of which rendering (s).
    """

    task: Task
    columns: dict[str, list] = field(repr=False)
    compute_s: float
    render_s: float


def make_tasks(study: Study) -> list[Task]:
    """Every task of the study, design by design (then seed, then chunk), so that designs complete early."""
    spec = study.spec
    n = spec.n_frames
    n_chunks = max(1, math.ceil(n / spec.frames_per_task))
    bounds = [round(c * n / n_chunks) for c in range(n_chunks + 1)]
    return [
        Task(design.design_id, seed, c, bounds[c], bounds[c + 1])
        for design in study.designs
        for seed in spec.seeds
        for c in range(n_chunks)
    ]


def task_inputs(study: Study, tasks: Iterable[Task]) -> Iterator[TaskInput]:
    """The inputs of ``tasks``, made as they are needed (a study of many designs is never all in memory)."""
    by_seed = {seed: study.spec.frame_specs(seed) for seed in study.spec.seeds}  # zoo frames: per seed
    for task in tasks:
        specs = by_seed[task.seed]
        frames = (specs[0], *specs[1 + task.first : 1 + task.stop])
        yield TaskInput(task, study.designs[task.design_id].jig, frames, study.spec.methods)


# ------------------------------------------------------------------------------------------ one task


def _row(task: Task, method: str, k: int, spec: Any, truth: dict[str, Any]) -> dict[str, Any]:
    return {
        "design_id": task.design_id,
        "method": method,
        "seed": task.seed,
        "frame": k,
        "diameter_mm": float(spec.part.diameter_mm),
        "alpha_deg": math.degrees(spec.pose.alpha_rad),
        "theta_deg": math.degrees(spec.pose.theta_rad),
        "depth_mm": float(truth["push_depth_mm"]),
        **dict(zip(("true_nx", "true_ny", "true_nz"), (float(v) for v in truth["normal"]), strict=True)),
    }


def _estimated(row: dict[str, Any], estimate: Any, elapsed_ms: float) -> dict[str, Any]:
    n = np.asarray(estimate.normal, dtype=float)
    t = np.array([row["true_nx"], row["true_ny"], row["true_nz"]])
    cos = float(np.dot(n, t) / (np.linalg.norm(n) * np.linalg.norm(t)))
    suspect = [w[len(_SUSPECT_PREFIX) :] for w in estimate.warnings if w.startswith(_SUSPECT_PREFIX)]
    sigma = estimate.tilt_sigma_deg
    return {
        **row,
        "est_nx": float(n[0]),
        "est_ny": float(n[1]),
        "est_nz": float(n[2]),
        "error_deg": math.degrees(math.acos(min(1.0, max(-1.0, cos)))),
        "sigma_deg": math.nan if sigma is None else float(sigma),
        "quality": estimate.quality,
        "reason": "; ".join(suspect) if estimate.quality != "ok" else "",
        "markers_under_part": int(estimate.n_points),
        "estimate_ms": elapsed_ms,
    }


def _failed(row: dict[str, Any], reason: str, elapsed_ms: float) -> dict[str, Any]:
    nan = math.nan
    return {
        **row,
        **dict.fromkeys(("est_nx", "est_ny", "est_nz", "error_deg", "sigma_deg"), nan),
        "quality": "failed",
        "reason": reason[:_REASON_CHARS],
        "markers_under_part": 0,
        "estimate_ms": elapsed_ms,
    }


def _estimate_row(row: dict[str, Any], pair: Any, estimator: Any) -> dict[str, Any]:
    """One frame's row by one method: ``estimator`` an :class:`Estimator`, or why the method has none."""
    if isinstance(estimator, str):  # the reference frame failed: the refractive method has no reference
        return _failed(row, estimator, 0.0)
    t0 = time.perf_counter()
    try:
        estimate = estimator.estimate(pair.left, pair.right, part_diameter_mm=row["diameter_mm"]).estimate
    except (EstimationError, InputError) as exc:
        return _failed(row, str(exc), 1e3 * (time.perf_counter() - t0))
    return _estimated(row, estimate, 1e3 * (time.perf_counter() - t0))


def _estimators(jig: JigConfig, methods: tuple[str, ...], unloaded: Any) -> dict[str, Any]:
    """One :class:`Estimator` per method, sharing the jig's model; the refractive one against the
    ``unloaded`` pair's markers (or, when they cannot be had, the reason, as a string)."""
    from softjig.sensing.estimator import Estimator

    if not methods:
        return {}
    base = Estimator(jig, method=methods[0])
    out: dict[str, Any] = {}
    for method in methods:
        if method == "refractive":
            try:
                reference = base.reference_from_pair(unloaded.left, unloaded.right)
            except (EstimationError, InputError) as exc:
                out[method] = f"reference frame: {exc}"
                continue
            out[method] = Estimator(jig, method=method, reference=reference, model=base.model)
        else:
            out[method] = base if base.method == method else Estimator(jig, method=method, model=base.model)
    return out


def _warm(estimators: dict[str, Any], pair: Any, diameter_mm: float) -> None:
    """Estimate ``pair`` once with each estimator, untimed and discarded (the first call's warm-up)."""
    for estimator in estimators.values():
        if not isinstance(estimator, str):
            with contextlib.suppress(EstimationError, InputError):
                estimator.estimate(pair.left, pair.right, part_diameter_mm=diameter_mm)


def run_task(inp: TaskInput) -> TaskResult:
    """Render and estimate one task's frames in memory (see the module docstring); never raises for a
    frame: a frame without an estimate is a row of quality ``"failed"`` with the reason."""
    from softjig.sim.asbuilt import draw_as_built
    from softjig.sim.render import Renderer
    from softjig.sim.scenarios import frame_truth

    t_start = time.perf_counter()
    task, jig = inp.task, inp.jig
    as_built = draw_as_built(jig, np.random.default_rng(np.random.SeedSequence(task.seed, spawn_key=(0,))))
    render_s, renderer = 0.0, None

    def render(spec: Any, index: int) -> Any:
        nonlocal render_s, renderer
        t0 = time.perf_counter()
        renderer = renderer or Renderer(as_built)  # built at the first frame (a task may render none)
        rng = np.random.default_rng(np.random.SeedSequence(task.seed, spawn_key=(1, index)))
        pair = renderer.render_pair(spec.part, spec.pose, rng)
        render_s += time.perf_counter() - t0
        return pair

    unloaded = render(inp.frames[0], 0) if "refractive" in inp.methods else None
    estimators = _estimators(jig, inp.methods, unloaded)
    rows = []
    for k, spec in zip(range(task.first, task.stop), inp.frames[1:], strict=True):
        pair = render(spec, k + 1)
        base = _row(task, "", k, spec, frame_truth(as_built.jig, spec.pose))
        if k == task.first:
            _warm(estimators, pair, base["diameter_mm"])
        for method in inp.methods:
            rows.append(_estimate_row({**base, "method": method}, pair, estimators[method]))
    columns = {name: [r[name] for r in rows] for name in (rows[0] if rows else {})}
    return TaskResult(task, columns, time.perf_counter() - t_start, render_s)


# ------------------------------------------------------------------------------------------ backends


def _warm_up() -> None:
    """Import the renderer and the estimator once per worker, before its first task."""
    from softjig.sensing import estimator  # noqa: F401
    from softjig.sim import render  # noqa: F401


def local_results(inputs: Iterable[TaskInput], workers: int) -> Iterator[TaskResult]:
    """Run tasks in this process (``workers == 1``) or on ``workers`` forked processes; yield each result as
    its task finishes (not in order). Closing the generator early (an exception, Ctrl-C, SIGTERM) ends the
    workers at once."""
    if workers < 1:
        raise InputError(f"--workers must be at least 1, got {workers}")
    if workers == 1:
        for inp in inputs:
            yield run_task(inp)
        return
    import multiprocessing
    from concurrent.futures import FIRST_COMPLETED, wait

    from softjig.io.workers import one_thread_per_worker, worker_pool

    _warm_up()  # forked workers inherit the imports
    todo = iter(inputs)
    with (
        one_thread_per_worker(),
        worker_pool(workers, mp_context=multiprocessing.get_context("fork")) as pool,
    ):
        pending = {pool.submit(run_task, inp) for inp in islice(todo, IN_FLIGHT_PER_WORKER * workers)}
        while pending:
            done, pending = wait(pending, return_when=FIRST_COMPLETED)
            pending |= {pool.submit(run_task, inp) for inp in islice(todo, len(done))}
            for future in done:
                yield future.result()


def _ray() -> Any:
    try:
        import ray
    except ImportError:
        raise InputError(
            "--ray needs Ray: install it with `pip install 'softjig[ray]'` (or `pip install 'ray>=2.60,<3'`)"
        ) from None
    return ray


def _ray_init(ray: Any, address: str, workers: int | None) -> None:
    """Connect to (or start) the cluster, keeping this process's own SIGTERM and SIGINT handlers: Ray's
    C++ core installs a failure-signal handler that aborts the process on SIGTERM (exit 134, a stack
    dump), where softjig stops cleanly (:func:`softjig.io.workers.terminate_raises`, exit 143)."""
    from softjig.io.workers import THREAD_VARIABLES

    env = {"env_vars": dict.fromkeys(THREAD_VARIABLES, "1")}
    with _signal_handlers_kept():
        _connect(ray, address, workers, env)


@contextlib.contextmanager
def _signal_handlers_kept() -> Iterator[None]:
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    saved = {signum: signal.getsignal(signum) for signum in (signal.SIGTERM, signal.SIGINT)}
    try:
        yield
    finally:
        for signum, handler in saved.items():
            if handler is not None:
                signal.signal(signum, handler)


def _connect(ray: Any, address: str, workers: int | None, env: dict[str, Any]) -> None:
    try:
        if address == "local":
            ray.init(num_cpus=workers, include_dashboard=False, runtime_env=env, log_to_driver=False)
        else:
            ray.init(address=address, runtime_env=env, log_to_driver=False)
    except (ConnectionError, RuntimeError, ValueError) as exc:
        raise InputError(
            f"cannot connect to the Ray cluster at {address!r}: {exc}; give its address (`ray status` "
            "prints it), `auto` for the cluster this machine belongs to, or `local` to start one here"
        ) from None


@contextlib.contextmanager
def ray_connection(address: str, workers: int | None = None) -> Iterator[None]:
    """Inside: this process is connected to the Ray cluster at ``address`` (see :func:`ray_results`);
    disconnected after (a local cluster is shut down). A connection already open is used and left open.

    Raises
    ------
    InputError
        Ray is not installed, or nothing answers at ``address``.
    """
    ray = _ray()
    if ray.is_initialized():
        yield
        return
    _check_reachable(address)
    _ray_init(ray, address, workers)
    try:
        yield
    finally:
        ray.shutdown()


#: Seconds to wait for a cluster's address to answer before saying so (Ray itself retries for minutes).
RAY_CONNECT_TIMEOUT_S = 10.0


def _check_reachable(address: str) -> None:
    """A ``host:port`` (or ``ray://host:port``) address must accept a TCP connection."""
    import socket

    if address in ("auto", "local"):
        return
    host, _, port = address.removeprefix("ray://").rpartition(":")
    if not host or not port.isdigit():
        raise InputError(
            f"--ray {address!r}: give a cluster's address as host:port (or ray://host:port), auto, or local"
        )
    try:
        socket.create_connection((host, int(port)), timeout=RAY_CONNECT_TIMEOUT_S).close()
    except OSError as exc:
        raise InputError(
            f"--ray {address}: nothing answers there ({exc.strerror or exc}): is the cluster running "
            "(`ray status` on its head node prints its address)?"
        ) from None


def ray_results(
    inputs: Iterable[TaskInput], address: str, workers: int | None = None
) -> Iterator[TaskResult]:
    """Run tasks on a Ray cluster (see the module docstring); yield each result as its task finishes.

    ``workers`` is the local cluster's CPUs (``address == "local"``; default: every CPU); a running
    cluster's size is its own. Tasks in flight are bounded by twice the cluster's CPUs. Closing the
    generator disconnects (a local cluster is shut down, ending its tasks in flight; a running cluster's
    finish and are dropped). If this process
    is connected to Ray already (:func:`ray_connection`, a notebook, a benchmark), that connection is used
    and left open."""
    ray = _ray()
    with ray_connection(address, workers):
        yield from _ray_stream(ray, inputs)


def _ray_stream(ray: Any, inputs: Iterable[TaskInput]) -> Iterator[TaskResult]:
    remote = ray.remote(num_cpus=1, max_retries=2)(run_task)
    cpus = max(1, int(ray.cluster_resources().get("CPU", 1)))
    todo = iter(inputs)
    pending = [remote.remote(inp) for inp in islice(todo, IN_FLIGHT_PER_WORKER * cpus)]
    # Tasks still in flight when the study stops are not cancelled: ray.cancel races with the task's reply
    # in Ray's core and can abort this process ("Tried to complete task that was not pending",
    # ray-project/ray#54738), losing the results written so far. Shutting a local cluster down ends its
    # workers; a running cluster finishes them and their results are dropped (--resume recomputes them).
    while pending:
        done, pending = ray.wait(pending, num_returns=1)
        pending += [remote.remote(inp) for inp in islice(todo, len(done))]
        for ref in done:
            yield ray.get(ref)
