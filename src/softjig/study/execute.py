"""``softjig study``'s work: open the output folder, run the tasks not yet finished, stream each task's
rows to disk as it finishes, show progress with an ETA, then consolidate the tables and write the report.

The order is fixed so that nothing is lost and nothing is done twice: the study file and every design are
validated first (:func:`softjig.study.spec.load_study`, before this), then the folder is opened
(:func:`softjig.study.results.open_study_folder`: another study's folder is refused), the finished tasks
are read from ``DIR/parts/``, and only the others run (:mod:`softjig.study.run`). A run stopped by
Ctrl-C or SIGTERM consolidates what has finished before it ends (up to
:data:`MAX_PARTS_CONSOLIDATED_ON_STOP` tasks, so that it ends within seconds); one killed outright keeps
its parts, which ``--resume`` consolidates.
"""

from __future__ import annotations

import contextlib
import os
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pyarrow as pa

from softjig.io.workers import stderr_progress
from softjig.study.results import StudyFolder, check_study_folder, open_study_folder, part_table
from softjig.study.run import (
    Task,
    TaskResult,
    local_results,
    make_tasks,
    ray_connection,
    ray_results,
    task_inputs,
)
from softjig.study.spec import Study

__all__ = ["StudyRun", "run_study"]

#: A stopped run consolidates its tables only up to this many finished tasks (reading a part takes ~1-3
#: ms), so that Ctrl-C or SIGTERM end the command within a second or two; beyond, the parts are the record
#: and ``--resume`` consolidates them.
MAX_PARTS_CONSOLIDATED_ON_STOP = 500


@dataclass(frozen=True)
class StudyRun:
    """What a run did.

    Attributes
    ----------
    folder : the output folder.
    results, designs : the consolidated tables (as written to results.parquet and designs.parquet).
    n_tasks : tasks of the study.
    skipped : tasks already finished before this run (``--resume``), not run again.
    ran : tasks this run finished.
    wall_s : this run's wall time (s).
    compute_s : the tasks' summed compute time in the workers (s).
    outputs : what the report wrote (:class:`softjig.study.report.StudyOutputs`), or ``None``.
    """

    folder: StudyFolder
    results: pa.Table
    designs: pa.Table
    n_tasks: int
    skipped: int
    ran: int
    wall_s: float
    compute_s: float
    outputs: Any = None


class _Progress:
    """A Rich progress bar on stderr (frames estimated, tasks, elapsed time, ETA), or nothing."""

    def __init__(self, enabled: bool, total_frames: int, done_frames: int, total_tasks: int) -> None:
        self.enabled = enabled
        self.total, self.done, self.tasks = total_frames, done_frames, total_tasks
        self._bar: Any = None
        self._id: Any = None

    def __enter__(self) -> _Progress:
        if not self.enabled:
            return self
        self._bar = stderr_progress("study", "frames, {task.fields[tasks]}", eta="ETA")
        self._bar.start()
        self._id = self._bar.add_task("study", total=self.total, completed=self.done, tasks="")
        return self

    def advance(self, frames: int, tasks_done: int) -> None:
        if self._bar is not None:
            self._bar.update(self._id, advance=frames, tasks=f"{tasks_done}/{self.tasks} tasks")

    def __exit__(self, *exc: object) -> None:
        if self._bar is not None:
            self._bar.stop()


def _results(study: Study, todo: list[Task], workers: int, ray: str | None) -> Iterator[TaskResult]:
    inputs = task_inputs(study, todo)
    if ray is not None:
        return ray_results(inputs, ray, workers)
    return local_results(inputs, min(workers, max(1, len(todo))))  # no idle worker forked, as simulate


def _complete_designs(study: Study, tasks: list[Task], finished: set[str]) -> set[int]:
    missing = {t.design_id for t in tasks if t.name not in finished}
    return {d.design_id for d in study.designs} - missing


def run_study(
    study: Study,
    out_dir: str | os.PathLike[str],
    *,
    workers: int | None = None,
    ray: str | None = None,
    resume: bool = False,
    progress: bool = True,
    report: bool = True,
) -> StudyRun:
    """Run a study into ``out_dir`` (see the module docstring and :mod:`softjig.study.results`).

    Parameters
    ----------
    study : the validated study and its designs.
    out_dir : the output folder (new or empty; or this study's, with ``resume``).
    workers : local worker processes (default: every CPU); with ``ray == "local"``, the local cluster's
        CPUs.
    ray : a Ray cluster's address, ``"auto"``, or ``"local"``; ``None`` runs on the local pool.
    resume : continue this study's folder, running only the tasks not finished.
    progress : show a progress bar on stderr.
    report : write the report, figures and best rigs at the end (:mod:`softjig.study.report`).

    Raises
    ------
    InputError
        The folder is refused (another study's, this one's without ``resume``, not a study's), or Ray is
        missing or unreachable.
    """
    t0 = time.perf_counter()
    tasks = make_tasks(study)
    check_study_folder(out_dir, study.spec, resume=resume)  # before a cluster is started for nothing
    # then Ray: a cluster that cannot be reached is an error before the folder is started
    with ray_connection(ray, workers) if ray is not None else contextlib.nullcontext():
        folder = open_study_folder(out_dir, study.spec, resume=resume, n_tasks=len(tasks))
        n_workers = (os.cpu_count() or 1) if workers is None else int(workers)
        finished = folder.finished() & {t.name for t in tasks}
        skipped = len(finished)
        ran, compute_s = _execute(
            study, folder, tasks, finished, lambda todo: _results(study, todo, n_workers, ray), progress
        )
        results, designs = folder.consolidate(study, _complete_designs(study, tasks, finished))
    outputs = _write_report(study, folder.path, results, designs) if report else None
    return StudyRun(
        folder, results, designs, len(tasks), skipped, ran, time.perf_counter() - t0, compute_s, outputs
    )


def _execute(
    study: Study,
    folder: StudyFolder,
    tasks: list[Task],
    finished: set[str],
    results_of: Callable[[list[Task]], Iterator[TaskResult]],
    progress: bool,
) -> tuple[int, float]:
    """Run the tasks not in ``finished`` (which grows as they finish), writing each one's part at once;
    returns the tasks run and their summed compute time (s)."""
    todo = [t for t in tasks if t.name not in finished]
    done_frames = sum(t.n_frames for t in tasks if t.name in finished)
    total_frames = sum(t.n_frames for t in tasks)
    ran, compute_s, stopped = 0, 0.0, True
    try:
        with _Progress(progress, total_frames, done_frames, len(tasks)) as bar:
            stream = results_of(todo) if todo else (r for r in ())
            with contextlib.closing(stream):  # an exception ends the workers (or Ray's tasks) at once
                for result in stream:
                    values = study.designs[result.task.design_id].values
                    folder.write_part(result.task.name, part_table(study.spec, values, result.columns))
                    finished.add(result.task.name)
                    ran, compute_s = ran + 1, compute_s + result.compute_s
                    bar.advance(result.task.n_frames, len(finished))
        stopped = False
    finally:
        # Ctrl-C, SIGTERM, an error: what has finished is consolidated before the exit, if that is quick
        if stopped and len(finished) <= MAX_PARTS_CONSOLIDATED_ON_STOP:
            folder.consolidate(study, _complete_designs(study, tasks, finished))
    return ran, compute_s


def _write_report(study: Study, out: Path, results: pa.Table, designs: pa.Table) -> Any:
    """The report, figures and best rigs (:func:`softjig.study.report.write_study_outputs`), each front
    design's rig the study's own jig of that design."""
    from softjig.study.report import write_study_outputs

    return write_study_outputs(
        out, study.spec, results, designs, config_for=lambda design_id: study.designs[design_id].jig
    )
