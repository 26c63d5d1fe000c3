"""The simulator's dataset writer: render frame specs on an as-built jig and write them with their truth.

:func:`simulate_dataset` draws an as-built jig from a seed (:func:`softjig.sim.asbuilt.draw_as_built`),
renders every :class:`~softjig.sim.scenarios.FrameSpec` with the jig's :class:`softjig.sim.render.Renderer`
(built once per task of up to :data:`FRAMES_PER_TASK` frames), in worker processes, and writes an
ordinary dataset (:class:`softjig.io.dataset.DatasetWriter`) with each frame's ground truth
(:func:`softjig.sim.scenarios.frame_truth`). It sits in ``io`` because it writes
files and runs processes; what it renders is pure and lives in :mod:`softjig.sim`.

Random numbers: the as-built jig is drawn from ``SeedSequence(seed, spawn_key=(0,))`` and frame ``i`` is
rendered with ``SeedSequence(seed, spawn_key=(1, i))``, so a dataset depends on the seed only, never on
the number of worker processes.
"""

from __future__ import annotations

import contextlib
import itertools
import os
from collections import deque
from collections.abc import Iterable, Iterator
from concurrent.futures import Future, ProcessPoolExecutor
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from softjig.config import JigConfig, validate_jig, validate_part
from softjig.errors import InputError
from softjig.io.dataset import DatasetWriter, encode_png
from softjig.io.workers import stderr_progress, worker_pool
from softjig.sim.asbuilt import AsBuiltJig, draw_as_built
from softjig.sim.scenarios import FrameSpec, check_reachable, frame_truth

if TYPE_CHECKING:  # the renderer (Numba kernels) is imported when a frame is rendered
    from softjig.sim.render import Renderer

__all__ = ["simulate_dataset"]

#: Frames rendered by one task: the task builds the jig's :class:`~softjig.sim.render.Renderer` once
#: (~12 ms of per-jig work) and renders its frames with it, so that cost is shared by this many frames.
FRAMES_PER_TASK = 8
#: Tasks in flight per worker process: enough queued work to absorb a stall in writing the frames.
TASKS_IN_FLIGHT_PER_WORKER = 2

_Frame = tuple[bytes, bytes, dict[str, np.ndarray]]


def _frame_seed(seed: int, index: int) -> np.random.SeedSequence:
    return np.random.SeedSequence(seed, spawn_key=(1, index))


def _render_one(renderer: Renderer, spec: FrameSpec, seed: int, index: int, color: bool) -> _Frame:
    """Render one frame with the jig's renderer and encode it: (left PNG, right PNG, truth arrays)."""
    rng = np.random.default_rng(_frame_seed(seed, index))
    pair = renderer.render_pair(spec.part, spec.pose, rng, color=color)
    m = pair.markers
    truth = {
        "xyz_mm": m.xyz_mm,
        "axis": m.axis,
        "in_contact": m.in_contact,
        "left_px": m.left_px,
        "right_px": m.right_px,
        "visible_left": m.visible_left,
        "visible_right": m.visible_right,
        "fiducial_corners_left_px": pair.fiducial_corners_left_px,
        "fiducial_corners_right_px": pair.fiducial_corners_right_px,
    }
    return encode_png(pair.left), encode_png(pair.right), {k: np.asarray(v) for k, v in truth.items()}


def _render_chunk(
    as_built: AsBuiltJig, chunk: list[tuple[int, FrameSpec]], seed: int, color: bool
) -> list[_Frame]:
    """Render a run of frames (each with its index in the run) with one renderer of the jig, in order.

    A worker's task: it carries the as-built jig (a few kB), so the workers hold no state of their own.
    """
    from softjig.sim.render import Renderer

    renderer = Renderer(as_built)
    return [_render_one(renderer, spec, seed, index, color) for index, spec in chunk]


def _warm_up() -> None:
    from softjig.sim import render  # noqa: F401 - import once per worker, before the first frame


def simulate_dataset(
    out_dir: str | os.PathLike[str],
    specs: Iterable[FrameSpec],
    nominal_jig: JigConfig,
    *,
    seed: int,
    workers: int | None = None,
    progress: bool = True,
    overwrite: bool = False,
    color: bool = False,
    first_index: int = 0,
) -> Path:
    """Render every spec on an as-built jig drawn from ``seed`` and write a dataset with ground truth.

    Parameters
    ----------
    out_dir : the dataset folder to write.
    specs : the frames (:mod:`softjig.sim.scenarios`: ``paper_sweep``, ``cube_experiment``, ``single``).
    nominal_jig : the jig as designed; written as ``rig.toml``. The images come from an as-built jig
        drawn from its tolerances (:func:`softjig.sim.asbuilt.draw_as_built`), stored as
        ``as_built.toml`` for analysis only.
    seed : the run's seed; the same seed gives the same dataset whatever ``workers`` is.
    workers : rendering processes (default: ``os.cpu_count()``); 1 renders in this process.
    progress : show a progress bar on stderr.
    overwrite : replace an existing dataset in ``out_dir``.
    color : render RGB images instead of gray.
    first_index : the first spec's number in a longer run (frame ``k`` draws its noise from the seed and
        ``first_index + k``): the run's frames written in parts (``softjig demo``'s chunks) are the
        frames of the whole run at once. The dataset still numbers its frames from 0.

    Returns
    -------
    Path
        ``out_dir``.

    Raises
    ------
    InputError
        An existing dataset without ``overwrite``, an invalid spec or seed.
    """
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or seed < 0:
        raise InputError(f"the seed must be a non-negative integer, got {seed!r}")
    seed = int(seed)
    validate_jig(nominal_jig)
    specs = list(specs)
    for spec in specs:
        if spec.part is not None:
            validate_part(spec.part, nominal_jig)
            check_reachable(nominal_jig, spec)
    n_workers = (os.cpu_count() or 1) if workers is None else int(workers)
    if n_workers < 1:
        raise InputError(f"the number of workers must be at least 1, got {workers}")
    n_workers = min(n_workers, max(1, len(specs)))
    from softjig.sim import render  # noqa: F401 - fail early; forked workers inherit the import

    as_built = draw_as_built(nominal_jig, np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(0,))))
    out = Path(out_dir)
    with contextlib.ExitStack() as stack:
        # A simulation can be rendered again from its seed: files are written atomically (a killed run
        # leaves only complete frames) but not fsynced, which would cost ~30 ms of disk per frame here.
        writer = stack.enter_context(
            DatasetWriter(out, nominal_jig, as_built=as_built, overwrite=overwrite, durable=False)
        )
        pool = None
        if n_workers > 1:
            # Workers die with this process; an exception (Ctrl-C, SIGTERM) ends them at once (io.workers).
            pool = stack.enter_context(worker_pool(n_workers))
            # Start every worker before the progress bar's thread exists (workers are forked).
            for f in [pool.submit(_warm_up) for _ in range(n_workers)]:
                f.result()
        advance = stack.enter_context(_progress_bar(progress, len(specs)))
        for index, (left, right, truth_markers) in enumerate(
            _rendered(as_built, specs, seed, pool, n_workers, color, int(first_index))
        ):
            spec = specs[index]
            meta = dict(spec.meta)
            if spec.pose is not None:
                meta["truth"] = frame_truth(as_built.jig, spec.pose)
            writer.add_frame(left, right, meta, truth_markers=truth_markers)
            advance()
    return out


def _rendered(
    as_built: AsBuiltJig,
    specs: list[FrameSpec],
    seed: int,
    pool: ProcessPoolExecutor | None,
    n_workers: int,
    color: bool,
    first_index: int = 0,
) -> Iterator[_Frame]:
    """The rendered frames, in order. In this process one renderer of the jig renders them all; in a
    pool, runs of up to :data:`FRAMES_PER_TASK` frames are tasks (:func:`_render_chunk`), a bounded window
    of them in flight."""
    if pool is None:
        from softjig.sim.render import Renderer

        renderer = Renderer(as_built)
        for index, spec in enumerate(specs, start=first_index):
            yield _render_one(renderer, spec, seed, index, color)
        return
    per_task = max(1, min(FRAMES_PER_TASK, -(-len(specs) // n_workers)))
    numbered = list(enumerate(specs, start=first_index))
    todo = iter([numbered[i : i + per_task] for i in range(0, len(numbered), per_task)])
    pending: deque[Future[list[_Frame]]] = deque(
        pool.submit(_render_chunk, as_built, chunk, seed, color)
        for chunk in itertools.islice(todo, TASKS_IN_FLIGHT_PER_WORKER * n_workers)
    )
    try:
        while pending:
            frames = pending.popleft().result()
            for chunk in itertools.islice(todo, 1):
                pending.append(pool.submit(_render_chunk, as_built, chunk, seed, color))
            yield from frames
    finally:
        for f in pending:
            f.cancel()


class _progress_bar:
    """A rich progress bar on stderr (or nothing); entering gives the ``advance()`` callable."""

    def __init__(self, enabled: bool, total: int) -> None:
        self.enabled, self.total = enabled, total
        self._progress: Any = None
        self._task: Any = None

    def __enter__(self):
        if not self.enabled:
            return lambda: None
        self._progress = stderr_progress("rendering")
        self._progress.start()
        self._task = self._progress.add_task("render", total=self.total)
        return lambda: self._progress.advance(self._task)

    def __exit__(self, *exc: object) -> None:
        if self._progress is not None:
            self._progress.stop()
