"""A study's output folder: its identity, the results streamed as tasks finish, and the per-design tables.

Layout (``DESIGN.md``'s study contract)::

    DIR/study.toml        the study as run (canonical form: the base jig's config written out in full)
    DIR/study.json        {"name", "study_hash", "softjig_version", "created", "n_designs", "n_tasks"}
    DIR/parts/NAME.parquet   one file per finished task: its rows of results.parquet
    DIR/results.parquet   one row per estimate (:data:`RESULT_FIELDS` plus a column per varied path)
    DIR/designs.parquet   one row per design and method (:func:`design_table`)

**Nothing finished is lost.** Each task's rows are written to ``parts/`` the moment the task ends, as one
Parquet file written to a temporary name and renamed (:func:`softjig.files.write_bytes_atomic`,
fsynced): a kill at any moment, ``SIGKILL`` included, loses at most the tasks that were running, and a
part that exists is complete. ``--resume`` lists ``parts/`` and runs only the tasks without a part, so
it recomputes nothing finished. ``results.parquet`` and ``designs.parquet`` are the parts consolidated
(sorted by design, method, seed and frame; ``designs.parquet`` only over designs whose every task has
finished); they are rewritten atomically at the end of a run and when a run is stopped by Ctrl-C or
``SIGTERM``. While a study runs, ``pyarrow.dataset.dataset(DIR / "parts")`` reads what has finished.

**One folder, one study.** :func:`open_study_folder` refuses a folder that holds another study's results
(its ``study.json`` names another ``study_hash``) whatever the options, a folder that holds this study's
results unless ``resume`` (so a second run never silently mixes with or replaces a first), and a
non-empty folder that is not a study's (never write over what softjig did not write).
"""

from __future__ import annotations

import io
import itertools
import json
import math
import os
import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from softjig import __version__
from softjig.errors import InputError
from softjig.files import remove_stale_temporaries, write_bytes_atomic, write_text_atomic
from softjig.study.spec import Study, StudySpec, Value

__all__ = [
    "RESULT_FIELDS",
    "StudyFolder",
    "check_study_folder",
    "design_table",
    "open_study_folder",
    "results_schema",
]

#: Columns of results.parquet besides the varied paths (which come after ``frame``), with their types.
RESULT_FIELDS: tuple[tuple[str, pa.DataType], ...] = (
    ("design_id", pa.int64()),
    ("method", pa.string()),
    ("seed", pa.int64()),
    ("frame", pa.int64()),
    ("diameter_mm", pa.float64()),
    ("alpha_deg", pa.float64()),
    ("theta_deg", pa.float64()),
    ("depth_mm", pa.float64()),
    ("true_nx", pa.float64()),
    ("true_ny", pa.float64()),
    ("true_nz", pa.float64()),
    ("est_nx", pa.float64()),
    ("est_ny", pa.float64()),
    ("est_nz", pa.float64()),
    ("error_deg", pa.float64()),
    ("sigma_deg", pa.float64()),
    ("quality", pa.string()),
    ("reason", pa.string()),
    ("markers_under_part", pa.int64()),
    ("estimate_ms", pa.float64()),
)
_KEY_COLUMNS = 4  # design_id, method, seed, frame: the varied paths follow them
#: A silent failure: an error above this (deg) and above :data:`SILENT_SIGMAS` times its own sigma, with
#: quality "ok" (as ``benchmarks/bench_zoo.py`` counts them).
SILENT_ERROR_DEG = 3.0
SILENT_SIGMAS = 4.0
STUDY_JSON = "study.json"
STUDY_TOML = "study.toml"
PARTS = "parts"
_PART_NAME = re.compile(r"(?P<name>d\d+-s\d+-c\d+)\.parquet")
_TEMPORARY = re.compile(r"\.(?P<target>.+)\.\d+-[0-9a-f]+\.tmp")


def _value_type(spec: StudySpec, path: str) -> pa.DataType:
    return pa.float64() if path in spec.numeric_paths else pa.string()


def results_schema(spec: StudySpec) -> pa.Schema:
    """results.parquet's schema: :data:`RESULT_FIELDS` with a column per varied path after ``frame``."""
    fields = [pa.field(n, t) for n, t in RESULT_FIELDS]
    varied = [pa.field(p, _value_type(spec, p)) for p in spec.paths]
    return pa.schema(fields[:_KEY_COLUMNS] + varied + fields[_KEY_COLUMNS:])


def value_cell(spec: StudySpec, path: str, value: Value) -> float | str:
    """A varied value as its column holds it: a float, or text (strings as they are, the rest as JSON)."""
    if path in spec.numeric_paths:
        return float(value)  # type: ignore[arg-type]
    return value if isinstance(value, str) else json.dumps(value)


def part_table(spec: StudySpec, values: Sequence[Value], columns: dict[str, list]) -> pa.Table:
    """One task's rows (``columns``: every :data:`RESULT_FIELDS` name) with the design's varied values."""
    n = len(columns["design_id"])
    data = dict(columns)
    for path, value in zip(spec.paths, values, strict=True):
        data[path] = [value_cell(spec, path, value)] * n
    schema = results_schema(spec)
    return pa.table({f.name: pa.array(data[f.name], type=f.type) for f in schema}, schema=schema)


def _table_bytes(table: pa.Table) -> bytes:
    sink = io.BytesIO()
    pq.write_table(table, sink, compression="zstd")
    return sink.getvalue()


# ------------------------------------------------------------------------------------------ the folder


@dataclass(frozen=True)
class StudyFolder:
    """An opened study output folder (:func:`open_study_folder`)."""

    path: Path
    spec: StudySpec

    @property
    def parts(self) -> Path:
        """Where each finished task's rows are."""
        return self.path / PARTS

    def finished(self) -> set[str]:
        """Names of the tasks whose part is written (and readable: a damaged part is run again)."""
        done = set()
        if not self.parts.is_dir():
            return done
        for entry in os.scandir(self.parts):
            match = _PART_NAME.fullmatch(entry.name)
            if match is None:
                continue
            try:
                pq.read_metadata(entry.path)
            except (OSError, pa.ArrowException):
                continue
            done.add(match["name"])
        return done

    def write_part(self, name: str, table: pa.Table) -> None:
        """Write one finished task's rows, atomically and durably."""
        write_bytes_atomic(self.parts / f"{name}.parquet", _table_bytes(table))

    def read_results(self, names: Iterable[str] | None = None) -> pa.Table:
        """The finished tasks' rows (all, or those of ``names``), sorted by design, method, seed, frame."""
        schema = results_schema(self.spec)
        wanted = None if names is None else set(names)
        tables = [
            pq.read_table(self.parts / f"{name}.parquet", schema=schema)
            for name in sorted(self.finished())
            if wanted is None or name in wanted
        ]
        table = pa.concat_tables(tables) if tables else schema.empty_table()
        order = [
            ("design_id", "ascending"),
            ("method", "ascending"),
            ("seed", "ascending"),
            ("frame", "ascending"),
        ]
        return table.sort_by(order)

    def consolidate(self, study: Study, complete: Iterable[int]) -> tuple[pa.Table, pa.Table]:
        """Write results.parquet (every finished task's rows) and designs.parquet (the designs of
        ``complete``, whose every task finished), atomically; returns both tables."""
        results = self.read_results()
        designs = design_table(study, results, set(complete))
        write_bytes_atomic(self.path / "results.parquet", _table_bytes(results))
        write_bytes_atomic(self.path / "designs.parquet", _table_bytes(designs))
        return results, designs


def _stamp(spec: StudySpec, n_tasks: int) -> dict[str, Any]:
    return {
        "name": spec.name,
        "study_hash": spec.study_hash,
        "softjig_version": __version__,
        "created": datetime.now(UTC).isoformat(timespec="seconds"),
        "n_designs": spec.n_designs,
        "n_tasks": n_tasks,
    }


def _read_stamp(path: Path) -> dict[str, Any]:
    try:
        data = json.loads((path / STUDY_JSON).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(
            f"{path / STUDY_JSON} cannot be read ({exc}): this folder's study is unknown; "
            "choose another --out"
        ) from None
    if not isinstance(data, dict) or not isinstance(data.get("study_hash"), str):
        raise InputError(f"{path / STUDY_JSON} has no study_hash: choose another --out")
    return data


def check_study_folder(path: str | os.PathLike[str], spec: StudySpec, *, resume: bool) -> None:
    """Refuse an output folder (see the module docstring), writing nothing.

    Raises
    ------
    InputError
        The folder holds another study's results, this study's without ``resume``, or files that are not
        a study's; or it is a file.
    """
    out = Path(path)
    if out.exists() and not out.is_dir():
        raise InputError(f"--out {out} is a file: give a folder")
    if (out / STUDY_JSON).exists():
        stamp = _read_stamp(out)
        if stamp["study_hash"] != spec.study_hash:
            raise InputError(
                f"{out} holds the results of another study ({stamp.get('name')!r}, study_hash "
                f"{stamp['study_hash'][:12]}...), not of this one ({spec.name!r}, "
                f"{spec.study_hash[:12]}...): choose another --out (--resume only continues the same study)"
            )
        if not resume:
            raise InputError(
                f"{out} already holds this study's results: pass --resume to finish it (nothing finished is "
                "recomputed), or choose another --out"
            )
    elif out.is_dir() and any(out.iterdir()):
        raise InputError(
            f"{out} is not empty and holds no study (no {STUDY_JSON}): choose a new or empty --out"
        )


def open_study_folder(
    path: str | os.PathLike[str], spec: StudySpec, *, resume: bool, n_tasks: int
) -> StudyFolder:
    """Open (or start) the output folder of ``spec``: refused as :func:`check_study_folder` says; a new
    folder gets ``study.toml`` and ``study.json``; temporary files of killed writers are removed.

    Raises
    ------
    InputError
        The folder is refused, or it cannot be written.
    """
    import tomli_w

    out = Path(path)
    check_study_folder(out, spec, resume=resume)
    if not (out / STUDY_JSON).exists():
        out.mkdir(parents=True, exist_ok=True)
        write_text_atomic(out / STUDY_TOML, tomli_w.dumps(spec.canonical()))
        write_text_atomic(out / STUDY_JSON, json.dumps(_stamp(spec, n_tasks), indent=2) + "\n")
    folder = StudyFolder(out, spec)
    _remove_stale_parts(folder.parts)
    return folder


def _remove_stale_temporaries_of(folder: Path) -> None:
    targets = set()
    with os.scandir(folder) as entries:
        for entry in entries:
            match = _TEMPORARY.fullmatch(entry.name)
            if match:
                targets.add(match["target"])
    for target in targets:
        remove_stale_temporaries(folder / target)


def _remove_stale_parts(parts: Path) -> None:
    """Temporary files of parts whose writer was killed (their pid is gone): removed."""
    if parts.is_dir():
        _remove_stale_temporaries_of(parts)
    if parts.parent.is_dir():
        _remove_stale_temporaries_of(parts.parent)


# ------------------------------------------------------------------------------------ per-design table


def designs_schema(spec: StudySpec) -> pa.Schema:
    """designs.parquet's schema (``DESIGN.md``'s study contract)."""
    head = [pa.field("design_id", pa.int64()), pa.field("method", pa.string())]
    varied = [pa.field(p, _value_type(spec, p)) for p in spec.paths]
    tail = [
        ("n_estimates", pa.int64()),
        ("rmse_deg", pa.float64()),
        ("cells", pa.string()),
        ("worst_cell", pa.string()),
        ("worst_cell_rmse_deg", pa.float64()),
        ("recall", pa.float64()),
        ("suspect_fraction", pa.float64()),
        ("silent", pa.int64()),
        ("median_markers_under_part", pa.float64()),
        ("latency_ms_median", pa.float64()),
        ("marker_count", pa.int64()),
    ]
    return pa.schema(head + varied + [pa.field(n, t) for n, t in tail])


def _rmse(errors: np.ndarray) -> float:
    errors = errors[np.isfinite(errors)]
    return float(np.sqrt(np.mean(errors**2))) if len(errors) else math.nan


def _median(values: np.ndarray) -> float:
    values = values[np.isfinite(values)]
    return float(np.median(values)) if len(values) else math.nan


#: Width of a cell of random zoo frames: their diameters and tilts are all different, so they are grouped
#: in bands (a band's centre names it: diameter 50 is 40-60 mm, tilt 7.5 is 5-10 deg).
ZOO_CELL_DIAMETER_MM = 20.0
ZOO_CELL_TILT_DEG = 5.0


def frame_cells(
    spec: StudySpec, diameter_mm: np.ndarray, alpha_deg: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The (diameter, tilt) cell of each frame: its own values for a sweep's or explicit poses, the centre
    of its band (:data:`ZOO_CELL_DIAMETER_MM` x :data:`ZOO_CELL_TILT_DEG`) for random zoo frames."""
    d, a = np.asarray(diameter_mm, float), np.asarray(alpha_deg, float)
    if spec.frames.zoo is None:
        return d, a
    return _band_centre(d, ZOO_CELL_DIAMETER_MM), _band_centre(a, ZOO_CELL_TILT_DEG)


def _band_centre(values: np.ndarray, width: float) -> np.ndarray:
    return (np.floor(values / width) + 0.5) * width


def _cells(d: np.ndarray, a: np.ndarray, err: np.ndarray) -> tuple[list[dict[str, Any]], str, float]:
    """Per (diameter, tilt) cell (``d``, ``a``: each frame's, see :func:`frame_cells`): its RMSE and
    estimates; the worst cell's label and RMSE."""
    cells = []
    worst, worst_rmse = "", math.nan
    for dv, av in sorted(set(zip(d.tolist(), a.tolist(), strict=True))):
        inside = (d == dv) & (a == av)
        rmse = _rmse(err[inside])
        n = int(np.sum(np.isfinite(err[inside])))
        cells.append(
            {"diameter_mm": dv, "alpha_deg": av, "rmse_deg": None if math.isnan(rmse) else rmse, "n": n}
        )
        if not math.isnan(rmse) and (math.isnan(worst_rmse) or rmse > worst_rmse):
            worst, worst_rmse = f"D{dv:g} a{av:g}", rmse
    return cells, worst, worst_rmse


def _design_row(spec: StudySpec, rows: dict[str, np.ndarray]) -> dict[str, Any]:
    """The aggregate columns of one design and method over its rows (numpy columns)."""
    err, sigma, quality = rows["error_deg"], rows["sigma_deg"], rows["quality"]
    n = len(err)
    made = quality != "failed"
    silent = (
        np.isfinite(err)
        & (quality == "ok")
        & (err > SILENT_ERROR_DEG)
        & (err > SILENT_SIGMAS * np.nan_to_num(sigma))
    )
    cells, worst, worst_rmse = _cells(*frame_cells(spec, rows["diameter_mm"], rows["alpha_deg"]), err)
    return {
        "n_estimates": n,
        "rmse_deg": _rmse(err),
        "cells": json.dumps(cells),
        "worst_cell": worst,
        "worst_cell_rmse_deg": worst_rmse,
        "recall": float(np.mean(made)) if n else math.nan,
        "suspect_fraction": float(np.mean(quality == "suspect")) if n else math.nan,
        "silent": int(np.sum(silent)),
        "median_markers_under_part": _median(rows["markers_under_part"][made].astype(float)),
        "latency_ms_median": _median(rows["estimate_ms"]),
    }


def design_table(study: Study, results: pa.Table, complete: set[int]) -> pa.Table:
    """designs.parquet: one row per (design, method) of the designs in ``complete``, over all their seeds
    and frames (``DESIGN.md``'s study contract; suspect_fraction and recall are fractions of the
    attempts, the medians over the estimates made, latency over every attempt)."""
    from softjig.jig_shape import marker_layout_xy

    spec = study.spec
    schema = designs_schema(spec)
    names = ("design_id", "method", "error_deg", "sigma_deg", "quality", "diameter_mm", "alpha_deg")
    cols = {
        n: results.column(n).to_numpy(zero_copy_only=False)
        for n in (*names, "markers_under_part", "estimate_ms")
    }
    out: dict[str, list] = {f.name: [] for f in schema}
    if len(results):
        keys = np.rec.fromarrays([cols["design_id"], cols["method"].astype(str)])
        order = np.argsort(keys, kind="stable")
        keys = keys[order]
        bounds = np.flatnonzero(np.r_[True, keys[1:] != keys[:-1], True])
        for lo, hi in itertools.pairwise(bounds):
            design_id, method = int(keys[lo][0]), str(keys[lo][1])
            if design_id not in complete:
                continue
            design = study.designs[design_id]
            rows = {n: c[order[lo:hi]] for n, c in cols.items()}
            row = {"design_id": design_id, "method": method, **_design_row(spec, rows)}
            row["marker_count"] = len(marker_layout_xy(design.jig))
            for path, value in zip(spec.paths, design.values, strict=True):
                row[path] = value_cell(spec, path, value)
            for name in out:
                out[name].append(row[name])
    return pa.table({f.name: pa.array(out[f.name], type=f.type) for f in schema}, schema=schema)
