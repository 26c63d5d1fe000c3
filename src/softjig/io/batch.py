"""Estimate every frame of a dataset, in order, on every core, streaming the rows to a results file.

Each frame becomes one JSON-able row: the :class:`~softjig.sensing.pipeline.Estimate`'s fields plus the
frame's ``index``, or, when no estimate could be made, ``index``, ``error`` and ``exit_code`` (2 bad
input, 3 no estimate), so one bad frame never stops a long run; an unloaded reference frame gives
``{"index": i, "reference": true}``. The part's size comes from each frame's ``part`` entry unless a
diameter is given for all. The refractive method measures indentations against the dataset's reference
frame when it has one (:func:`dataset_reference`).

**Throughput and memory.** :func:`estimate_dataset` estimates the first frames in this process (until
one loaded frame has been estimated: that loads the Numba caches and builds the per-jig tables), then
forks the worker processes, which inherit all of it: a worker starts estimating within milliseconds
instead of each spending about a second on the same warm-up, and the warm-up is paid once, not once
per core. The rest of the frames go to the workers in chunks whose size shrinks towards the end (guided
scheduling: up to :data:`MAX_CHUNK_FRAMES`, down to one frame for the last ones, so no worker idles while
another finishes a long last chunk), with a bounded number of chunks in flight, so the parent holds at
most a few dozen rows however long the dataset. For a :class:`~softjig.io.dataset.Dataset` only the
range of a chunk's frame positions travels to a worker: the worker reads those frames' lines and images
itself, and the parent never parses a frame it does not estimate. Each worker receives the settings
(jig, reference, calibration) once, at start, and runs one OpenCV thread: the processes are the
parallelism. :class:`RowsWriter` streams the rows to a temporary file next to the target and renames it
into place only when every row is written, so a crash, a kill or a failed run never leaves a half-written
file where a good one was (:func:`estimate_dataset_to_file` joins the two).

Measured (``benchmarks/bench_throughput.py``, refractive method, 2 workers): the command's process tree
peaks at the same memory on 1,000 and on 10,000 frames (215-238 MiB PSS, 541-543 MiB summed RSS, against
260 and 298 MiB PSS before the dataset was read lazily and the warm-up shared); a forked worker's own
memory is ~9 MiB, the rest it shares with the parent (freezing the garbage collector's objects before
forking, :func:`gc.freeze`, changed nothing measurable, so it is not done).
"""

from __future__ import annotations

import contextlib
import csv
import io
import json
import multiprocessing
import multiprocessing.context
import os
from collections import deque
from collections.abc import Callable, Iterable, Iterator, Sequence
from concurrent.futures import Future
from dataclasses import dataclass, field, replace
from itertools import islice
from pathlib import Path
from types import TracebackType
from typing import IO, Protocol

from softjig.calibration.sweep import (
    SweepCalibration,
    SweepSamples,
    calibrate_from_rows,
    check_sweep_design,
    sweep_design,
)
from softjig.calibration.tilt import TiltCalibration
from softjig.config import JigConfig
from softjig.errors import EstimationError, InputError
from softjig.files import fsync_folder, remove_stale_temporaries, temp_file_beside
from softjig.io.dataset import Dataset, Frame
from softjig.io.workers import one_thread_per_worker, worker_pool
from softjig.sensing.estimator import DEFAULT_METHOD, Estimator, check_part_diameter
from softjig.sensing.identities import ReferenceMarkers

__all__ = [
    "CSV_COLUMNS",
    "BatchSettings",
    "BatchSummary",
    "RowsWriter",
    "dataset_reference",
    "estimate_dataset",
    "estimate_dataset_to_file",
    "estimate_frame",
    "frame_part_diameter_mm",
    "rows_to_text",
    "write_rows",
]

#: Frames per chunk handed to a worker at most (fewer for short datasets and for the last frames of any,
#: so every worker gets some and all finish together): enough frames that a task's overhead (about a
#: millisecond, pool start included) is negligible against its work.
MAX_CHUNK_FRAMES = 8
#: Chunks in flight per worker: enough to keep every worker busy while the parent writes rows.
CHUNKS_IN_FLIGHT_PER_WORKER = 3


class SizedFrames(Protocol):
    """What :func:`estimate_dataset` estimates: a :class:`~softjig.io.dataset.Dataset`, or any sized
    iterable of frames (a list, a filtered view)."""

    def __len__(self) -> int: ...

    def __iter__(self) -> Iterator[Frame]: ...


@dataclass(frozen=True)
class BatchSettings:
    """What every frame of a batch shares (``frame_part_size``: use each frame's recorded part size).

    ``estimator`` is the :class:`~softjig.sensing.estimator.Estimator` of these settings, once built
    (:meth:`with_estimator`; :func:`estimate_dataset` and each worker build it once).

    Raises :class:`~softjig.errors.InputError` for a ``part_diameter_mm`` that is not a positive number of
    mm smaller than the jig's membrane (:func:`~softjig.sensing.estimator.check_part_diameter`)."""

    jig: JigConfig
    part_diameter_mm: float | None = None
    calibration: TiltCalibration | None = None
    method: str = DEFAULT_METHOD
    reference: ReferenceMarkers | None = None
    frame_part_size: bool = True
    estimator: Estimator | None = field(default=None, compare=False, repr=False)

    def __post_init__(self) -> None:
        check_part_diameter(self.part_diameter_mm, self.jig)  # refused once, not frame after frame

    def with_estimator(self) -> BatchSettings:
        """These settings with their estimator built (as they are when it is, or when the settings do not
        make one: each frame's row then reports why, as :func:`estimate_frame` does)."""
        if self.estimator is not None:
            return self
        try:
            estimator = Estimator(
                self.jig, method=self.method, reference=self.reference, calibration=self.calibration
            )
        except InputError:
            return self
        return replace(self, estimator=estimator)


def frame_part_diameter_mm(frame: Frame, settings: BatchSettings) -> float | None:
    """The part's base diameter for a frame (mm): the one given for all, else the frame's part's (unless
    ``settings.frame_part_size`` is false: ours then finds the contact without it), else ``None`` (the
    refractive method needs none; the paper's method then reports an error for the frame)."""
    if settings.part_diameter_mm is not None:
        return settings.part_diameter_mm
    if frame.part is None or not settings.frame_part_size:
        return None
    return float(frame.part.diameter_mm)  # a box's is its inscribed circle's


def estimate_frame(frame: Frame, settings: BatchSettings) -> dict:
    """One frame's row (see the module docstring)."""
    if frame.reference and settings.part_diameter_mm is None:
        return {"index": frame.index, "reference": True}
    try:
        diameter = frame_part_diameter_mm(frame, settings)
        estimator = settings.estimator
        if estimator is None:  # built here for one frame: estimate_dataset builds it once for all
            estimator = Estimator(
                settings.jig,
                method=settings.method,
                reference=settings.reference,
                calibration=settings.calibration,
            )
        result = estimator.estimate(frame.load_left(), frame.load_right(), part_diameter_mm=diameter)
    except EstimationError as exc:
        return {"index": frame.index, "error": str(exc), "exit_code": 3}
    except InputError as exc:
        return {"index": frame.index, "error": str(exc), "exit_code": 2}
    return {"index": frame.index, **result.estimate.to_dict()}


# ------------------------------------------------------------------------------------------ workers

_WORKER_SETTINGS: BatchSettings | None = None
_WORKER_DATASET: Dataset | None = None


def _init_worker(settings: BatchSettings, dataset: Dataset | None) -> None:
    """Per-worker state, set once: the settings, the dataset whose frames the chunks name (or ``None``
    when chunks carry their frames), one OpenCV thread (the workers are the parallelism) and the
    settings' estimator (built once for the worker's life; a forked worker inherits the parent's).

    A forked worker inherits one OpenCV thread from :func:`~softjig.io.workers.one_thread_per_worker`
    and must not call ``cv2.setNumThreads`` itself: in a forked copy of a parent whose OpenCV thread pool
    ran, it can wait forever on threads that were not forked. A spawned worker is fresh and sets it here."""
    global _WORKER_SETTINGS, _WORKER_DATASET
    import cv2

    if cv2.getNumThreads() != 1:
        cv2.setNumThreads(1)
    _WORKER_SETTINGS, _WORKER_DATASET = settings.with_estimator(), dataset


def _pool_context() -> multiprocessing.context.BaseContext:
    """Where workers come from: forked from this process where the platform can (they start in
    milliseconds, with everything imported and warmed up), else spawned."""
    if "fork" in multiprocessing.get_all_start_methods():
        return multiprocessing.get_context("fork")
    return multiprocessing.get_context("spawn")


def _estimate_chunk(frames: list[Frame]) -> list[dict]:
    """A worker's task: the rows of frames sent with it."""
    assert _WORKER_SETTINGS is not None
    return [estimate_frame(frame, _WORKER_SETTINGS) for frame in frames]


def _estimate_span(start: int, stop: int) -> list[dict]:
    """A worker's task: the rows of the worker's dataset's frames ``start <= i < stop``, read here."""
    assert _WORKER_SETTINGS is not None and _WORKER_DATASET is not None
    return [estimate_frame(frame, _WORKER_SETTINGS) for frame in _WORKER_DATASET.iter_frames(start, stop)]


def _chunk_size(remaining: int, workers: int) -> int:
    """Frames of the next chunk when ``remaining`` frames are left: a quarter of a fair share, at most
    :data:`MAX_CHUNK_FRAMES`, shrinking to one frame at the end (guided scheduling)."""
    return max(1, min(MAX_CHUNK_FRAMES, remaining // (4 * workers)))


#: Frames estimated in the parent at most before the workers are forked (the warm-up stops at the first
#: loaded frame; unloaded reference frames cost nothing and may come first).
MAX_LEAD_FRAMES = 4


def _warms_up(frame: Frame, settings: BatchSettings) -> bool:
    """Whether estimating this frame runs the estimator (and so warms this process up)."""
    return not (frame.reference and settings.part_diameter_mm is None)


def dataset_reference(dataset: Dataset, jig: JigConfig) -> ReferenceMarkers | None:
    """The reference markers from the dataset's first frame marked reference, if it has one, checked to be
    of this rig and unloaded (:func:`softjig.io.reference.dataset_reference`)."""
    from softjig.io.reference import dataset_reference as reference_of

    return reference_of(dataset, jig)


def estimate_dataset(
    dataset: SizedFrames,
    settings: BatchSettings,
    *,
    workers: int | None = None,
    on_row: Callable[[dict], None] | None = None,
    chunk_frames: int | None = None,
) -> Iterator[dict]:
    """Yield every frame's row in dataset order, computed on ``workers`` processes (default: every CPU).

    Parameters
    ----------
    dataset : the frames to estimate: a :class:`~softjig.io.dataset.Dataset` (the workers read its
        frames themselves), or any sized iterable of frames (sent to the workers).
    settings : what every frame shares; sent to each worker once, when it starts.
    workers : processes; 1 estimates in this process. Default ``os.cpu_count()``.
    on_row : called with each row, in order, before it is yielded (e.g. to advance a progress bar).
    chunk_frames : frames per task handed to a worker (default: guided, from :data:`MAX_CHUNK_FRAMES`
        down to 1 for the last frames).

    Notes
    -----
    The first frames, up to the first loaded one, are estimated in this process before the workers are
    forked (see the module docstring). At most ``CHUNKS_IN_FLIGHT_PER_WORKER * workers`` chunks are
    submitted and not yet yielded, so the memory of a run does not grow with the dataset's length (the
    rows are yielded, never accumulated). Stopping the iteration early (or an exception in ``on_row``)
    cancels the chunks not yet started.
    """
    workers = workers or os.cpu_count() or 1
    if workers < 1:
        raise InputError(f"workers must be at least 1, got {workers}")
    settings = settings.with_estimator()
    n_frames = len(dataset)
    in_process = workers == 1 or n_frames <= 1
    # Lead: estimate here up to the first loaded frame, so the forked workers inherit a warm process
    # (spawned workers could not inherit it: they warm up themselves).
    if in_process:
        lead_max = n_frames
    else:
        lead_max = MAX_LEAD_FRAMES if _pool_context().get_start_method() == "fork" else 0
    from_file = dataset.iter_frames() if isinstance(dataset, Dataset) else None
    frames = from_file if from_file is not None else iter(dataset)
    done = 0
    while done < lead_max:
        frame = next(frames, None)
        if frame is None:
            break
        row = estimate_frame(frame, settings)
        done += 1
        if on_row:
            on_row(row)
        yield row
        if not in_process and _warms_up(frame, settings):
            break
    if in_process or done >= n_frames:
        return
    if from_file is not None:
        from_file.close()  # the workers read the rest of the dataset's file themselves
    yield from _estimate_in_workers(dataset, frames, done, n_frames, settings, workers, on_row, chunk_frames)


def _estimate_in_workers(
    dataset: SizedFrames,
    frames: Iterator[Frame],
    done: int,
    n_frames: int,
    settings: BatchSettings,
    workers: int,
    on_row: Callable[[dict], None] | None,
    chunk_frames: int | None,
) -> Iterator[dict]:
    """The rows of frames ``done`` to ``n_frames`` computed by a pool of ``workers`` processes, in order.

    ``frames`` continues the iteration of a dataset that is not a :class:`Dataset` (its frames are sent
    with the chunks); a :class:`Dataset`'s chunks name their frames' positions."""
    by_position = isinstance(dataset, Dataset)
    limit = CHUNKS_IN_FLIGHT_PER_WORKER * workers
    pending: deque[Future[list[dict]]] = deque()
    submitted = done

    def submit() -> None:
        nonlocal submitted
        while len(pending) < limit and submitted < n_frames:
            size = chunk_frames or _chunk_size(n_frames - submitted, workers)
            if by_position:
                stop = min(n_frames, submitted + size)
                pending.append(pool.submit(_estimate_span, submitted, stop))
                submitted = stop
            else:
                batch = list(islice(frames, size))
                if not batch:
                    submitted = n_frames
                    return
                pending.append(pool.submit(_estimate_chunk, batch))
                submitted += len(batch)

    with contextlib.ExitStack() as stack:
        # Workers die with this process, whatever kills it; an exception (Ctrl-C, SIGTERM, the caller
        # closing this generator) ends them at once rather than after their chunks (io.workers).
        with one_thread_per_worker():  # the first submission starts (forks) the workers
            pool = stack.enter_context(
                worker_pool(
                    workers,
                    mp_context=_pool_context(),
                    initializer=_init_worker,
                    initargs=(settings, dataset if by_position else None),
                )
            )
            submit()
        try:
            while pending:
                for row in pending.popleft().result():
                    if on_row:
                        on_row(row)
                    yield row
                submit()
        finally:
            for future in pending:
                future.cancel()


# ------------------------------------------------------------------------------------------ output

CSV_COLUMNS = (
    "index", "normal_x", "normal_y", "normal_z", "tilt_x_deg", "tilt_y_deg", "push_depth_mm", "n_points",
    "rms_residual_mm", "frame_source", "calibrated", "raw_tilt_x_deg", "raw_tilt_y_deg", "part_diameter_mm",
    "method", "tilt_sigma_x_deg", "tilt_sigma_y_deg", "tilt_sigma_deg", "quality", "contact_area_mm2",
    "contact_x_mm", "contact_y_mm",
    "contact_partial", "part_x_mm", "part_y_mm", "warnings", "indentation_reference", "reference", "error",
    "exit_code",
)  # fmt: skip


def _is_csv(path: str | os.PathLike[str]) -> bool:
    return Path(path).suffix.lower() == ".csv"


def _csv_record(row: dict) -> dict:
    """A row flattened to :data:`CSV_COLUMNS` (normal and contact centroid split, warnings joined)."""
    flat = dict(row)
    if "normal" in row:
        flat["normal_x"], flat["normal_y"], flat["normal_z"] = row["normal"]
    if row.get("contact_centroid_xy_mm"):
        flat["contact_x_mm"], flat["contact_y_mm"] = row["contact_centroid_xy_mm"]
    if row.get("part_centre_xy_mm"):
        flat["part_x_mm"], flat["part_y_mm"] = row["part_centre_xy_mm"]
    flat["warnings"] = "; ".join(row.get("warnings", []))
    return flat


def rows_to_text(rows: Iterable[dict], path: str | os.PathLike[str]) -> str:
    """The rows as JSON Lines, or CSV when ``path`` ends in ``.csv`` (the text :class:`RowsWriter` writes)."""
    if not _is_csv(path):
        return "".join(json.dumps(row) + "\n" for row in rows)
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, CSV_COLUMNS, extrasaction="ignore")
    writer.writeheader()
    for row in rows:
        writer.writerow(_csv_record(row))
    return buffer.getvalue()


class RowsWriter:
    """Stream rows to a results file atomically: JSON Lines, or CSV when the path ends in ``.csv``.

    A context manager. Rows go to a temporary file in the target's folder as they are written; on a
    clean exit the file is flushed, fsynced and renamed over ``path`` (and the folder fsynced), so readers
    see the old file or the complete new one. On an exception (a failed run, Ctrl-C) the temporary file
    is deleted and ``path`` is left as it was.

    Parameters
    ----------
    path : the results file (``.jsonl``/``.json`` or ``.csv``).

    Raises
    ------
    InputError
        The path is a folder or its folder cannot be written.

    Examples
    --------
    >>> with RowsWriter("out/estimates.jsonl") as out:            # doctest: +SKIP
    ...     for row in estimate_dataset(dataset, settings):
    ...         out.write(row)
    """

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.path = Path(path)
        self.n_rows = 0  #: rows written so far
        self._fh: IO[str] | None = None
        self._tmp: Path | None = None
        self._csv: csv.DictWriter | None = None

    def __enter__(self) -> RowsWriter:
        path = self.path
        if not path.is_dir():
            remove_stale_temporaries(path)  # a killed earlier run's (SIGKILL: nothing ran to remove it)
        fd, self._tmp = temp_file_beside(path)
        # newline="": the text is written byte for byte as rows_to_text makes it (CSV's \r\n kept).
        self._fh = open(fd, "w", encoding="utf-8", newline="")
        if _is_csv(path):
            self._csv = csv.DictWriter(self._fh, CSV_COLUMNS, extrasaction="ignore")
            self._csv.writeheader()
        return self

    def write(self, row: dict) -> None:
        """Append one row."""
        if self._fh is None:
            raise RuntimeError("RowsWriter.write outside its `with` block")
        if self._csv is not None:
            self._csv.writerow(_csv_record(row))
        else:
            self._fh.write(json.dumps(row) + "\n")
        self.n_rows += 1

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        assert self._fh is not None and self._tmp is not None
        fh, tmp = self._fh, self._tmp
        self._fh = self._tmp = self._csv = None
        if exc_type is not None:
            fh.close()
            tmp.unlink(missing_ok=True)
            return
        try:
            fh.flush()
            os.fsync(fh.fileno())
            fh.close()
            os.replace(tmp, self.path)
        except OSError as err:
            fh.close()
            tmp.unlink(missing_ok=True)
            message = f"cannot write {self.path}: {err.strerror or err}; choose another path"
            raise InputError(message) from None
        fsync_folder(self.path.parent)


def write_rows(rows: Iterable[dict], path: str | os.PathLike[str]) -> int:
    """Write the rows atomically, streaming (a crash never leaves a half-written results file).

    Returns the number of rows written.
    """
    with RowsWriter(path) as out:
        for row in rows:
            out.write(row)
    return out.n_rows


@dataclass(frozen=True)
class BatchSummary:
    """What a batch run wrote.

    Attributes
    ----------
    n_rows : rows written (every frame of the dataset).
    n_loaded : rows of loaded frames (all but the unloaded reference frames).
    n_failed : rows with an ``error`` (no estimate for that frame).
    first_failure : the first failed row, if any.
    """

    n_rows: int
    n_loaded: int
    n_failed: int
    first_failure: dict | None = None


def estimate_dataset_to_file(
    dataset: Dataset,
    settings: BatchSettings,
    path: str | os.PathLike[str],
    *,
    workers: int | None = None,
    on_row: Callable[[dict], None] | None = None,
) -> BatchSummary:
    """Estimate every frame (:func:`estimate_dataset`) and stream the rows, in order, to ``path`` atomically
    (:class:`RowsWriter`): on any failure the target is left untouched.

    Raises
    ------
    InputError
        ``path`` cannot be written (a folder, no permission): raised before any frame is estimated.
    """
    n_loaded = n_failed = 0
    first_failure = None
    with RowsWriter(path) as out:
        for row in estimate_dataset(dataset, settings, workers=workers, on_row=on_row):
            out.write(row)
            if row.get("reference") is not True:
                n_loaded += 1
            if "error" in row:
                n_failed += 1
                first_failure = first_failure or row
    return BatchSummary(out.n_rows, n_loaded, n_failed, first_failure)


def calibrate_dataset(
    dataset: Dataset,
    *,
    rows: Sequence[dict] | None = None,
    mode: str = "pooled",
    selection: str = "all",
    method: str = "paper",
    workers: int | None = None,
    on_row: Callable[[dict], None] | None = None,
) -> tuple[SweepCalibration, SweepSamples, list[dict]]:
    """Calibrate from a sweep dataset: estimate its frames (unless ``rows`` are given), then fit.

    Parameters
    ----------
    dataset : an open sweep dataset.
    rows : estimate rows of this dataset (e.g. :func:`softjig.calibration.sweep.load_result_rows`); if
        ``None`` every frame is estimated with ``method`` on the dataset's nominal jig, without
        calibration, on ``workers`` processes (default: every CPU), ``on_row`` called after each.
    method : the estimation method to calibrate (the calibration is only valid for it).
    mode, selection : see :func:`softjig.calibration.sweep.fit_sweep_calibration`.

    Returns
    -------
    (SweepCalibration, SweepSamples, rows)
        The fit, the sweep it was fitted to (every frame, before the selection) and the estimate rows.
    """
    check_sweep_design(*sweep_design(dataset), selection=selection)  # before hours of estimation
    if rows is None:
        reference = dataset_reference(dataset, dataset.jig) if method == "refractive" else None
        settings = BatchSettings(jig=dataset.jig, method=method, reference=reference)
        rows = list(estimate_dataset(dataset, settings, workers=workers, on_row=on_row))
    fit, samples = calibrate_from_rows(dataset, rows, mode=mode, selection=selection, method=method)
    return fit, samples, list(rows)
