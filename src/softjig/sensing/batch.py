"""Estimate every frame of a dataset, in order, on every core.

Each frame becomes one JSON-able row: the :class:`~softjig.sensing.pipeline.Estimate`'s fields plus the
frame's ``index``, or, when no estimate could be made, ``index``, ``error`` and ``exit_code`` (2 bad
input, 3 no estimate), so one bad frame never stops a long run; an unloaded reference frame gives
``{"index": i, "reference": true}``. The part's size comes from each frame's ``part`` entry unless a
diameter is given for all. The refractive method measures indentations against the dataset's reference
frame when it has one (:func:`dataset_reference`).
"""

from __future__ import annotations

import csv
import io
import json
import os
from collections.abc import Callable, Iterator
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path

from softjig.calibration.tilt import TiltCalibration
from softjig.config import JigConfig
from softjig.errors import EstimationError, InputError
from softjig.io.dataset import Dataset, Frame
from softjig.io.files import write_text_atomic
from softjig.sensing.identities import ReferenceMarkers
from softjig.sensing.pipeline import DEFAULT_METHOD, estimate_pair, reference_from_pair


@dataclass(frozen=True)
class BatchSettings:
    """What every frame of a batch shares."""

    jig: JigConfig
    part_diameter_mm: float | None = None
    calibration: TiltCalibration | None = None
    method: str = DEFAULT_METHOD
    reference: ReferenceMarkers | None = None


def frame_part_diameter_mm(frame: Frame, settings: BatchSettings) -> float | None:
    """The part's base diameter for a frame (mm): the one given for all, else the frame's part's, else
    ``None`` (the refractive method needs none; the paper's method then reports an error for the frame)."""
    if settings.part_diameter_mm is not None:
        return settings.part_diameter_mm
    if frame.part is None:
        return None
    return float(frame.part.diameter_mm)  # a box's is its inscribed circle's


def estimate_frame(frame: Frame, settings: BatchSettings) -> dict:
    """One frame's row (see the module docstring)."""
    if frame.reference and settings.part_diameter_mm is None:
        return {"index": frame.index, "reference": True}
    try:
        diameter = frame_part_diameter_mm(frame, settings)
        result = estimate_pair(
            frame.load_left(),
            frame.load_right(),
            settings.jig,
            part_diameter_mm=diameter,
            calibration=settings.calibration,
            method=settings.method,
            reference=settings.reference,
        )
    except EstimationError as exc:
        return {"index": frame.index, "error": str(exc), "exit_code": 3}
    except InputError as exc:
        return {"index": frame.index, "error": str(exc), "exit_code": 2}
    return {"index": frame.index, **result.estimate.to_dict()}


_WORKER_SETTINGS: BatchSettings | None = None


def _init_worker(settings: BatchSettings) -> None:
    global _WORKER_SETTINGS
    _WORKER_SETTINGS = settings


def _estimate_in_worker(frame: Frame) -> dict:
    assert _WORKER_SETTINGS is not None
    return estimate_frame(frame, _WORKER_SETTINGS)


def dataset_reference(dataset: Dataset, jig: JigConfig) -> ReferenceMarkers | None:
    """The reference markers from the dataset's first unloaded reference frame, if it has one."""
    for frame in dataset:
        if frame.reference:
            return reference_from_pair(frame.load_left(), frame.load_right(), jig)
    return None


def estimate_dataset(
    dataset: Dataset,
    settings: BatchSettings,
    *,
    workers: int | None = None,
    on_row: Callable[[dict], None] | None = None,
) -> Iterator[dict]:
    """Yield every frame's row in dataset order, computed on ``workers`` processes (default: every CPU).

    Frames are handed out in chunks; only paths travel between processes, each worker reads its own
    images, so memory stays flat however long the dataset.
    """
    workers = workers or os.cpu_count() or 1
    frames = list(dataset)
    if workers <= 1 or len(frames) <= 1:
        for frame in frames:
            row = estimate_frame(frame, settings)
            if on_row:
                on_row(row)
            yield row
        return
    chunk = max(1, min(16, len(frames) // (4 * workers)))
    with ProcessPoolExecutor(workers, initializer=_init_worker, initargs=(settings,)) as pool:
        for row in pool.map(_estimate_in_worker, frames, chunksize=chunk):
            if on_row:
                on_row(row)
            yield row


CSV_COLUMNS = (
    "index", "normal_x", "normal_y", "normal_z", "tilt_x_deg", "tilt_y_deg", "push_depth_mm", "n_points",
    "rms_residual_mm", "frame_source", "calibrated", "raw_tilt_x_deg", "raw_tilt_y_deg", "part_diameter_mm",
    "method", "tilt_sigma_x_deg", "tilt_sigma_y_deg", "contact_area_mm2", "contact_x_mm", "contact_y_mm",
    "contact_partial", "warnings", "indentation_reference", "reference", "error", "exit_code",
)  # fmt: skip


def rows_to_text(rows: list[dict], path: str | os.PathLike[str]) -> str:
    """The rows as JSON Lines, or CSV when ``path`` ends in ``.csv``."""
    if Path(path).suffix.lower() != ".csv":
        return "".join(json.dumps(row) + "\n" for row in rows)
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, CSV_COLUMNS, extrasaction="ignore")
    writer.writeheader()
    for row in rows:
        flat = dict(row)
        if "normal" in row:
            flat["normal_x"], flat["normal_y"], flat["normal_z"] = row["normal"]
        if row.get("contact_centroid_xy_mm"):
            flat["contact_x_mm"], flat["contact_y_mm"] = row["contact_centroid_xy_mm"]
        flat["warnings"] = "; ".join(row.get("warnings", []))
        writer.writerow(flat)
    return buffer.getvalue()


def write_rows(rows: list[dict], path: str | os.PathLike[str]) -> None:
    """Write the rows atomically (a crash never leaves a half-written results file)."""
    write_text_atomic(path, rows_to_text(rows, path))
