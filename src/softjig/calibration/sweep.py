"""The paper's tilt calibration (``Ox, Oy, S``) from a sweep dataset's estimates.

A *sweep* is a dataset whose loaded frames carry the commanded tilt ``alpha_deg``, its azimuth
``theta_deg`` and the ``part`` pressed in (as ``softjig simulate --scenario paper-sweep`` writes, or a robot
recording). Each frame is estimated without calibration (or its row is read from a results file written
by ``softjig estimate DATASET --out r.jsonl``: the uncalibrated ``raw_tilt_x_deg``, ``raw_tilt_y_deg``
are used, whatever calibration the row was made with), and the paper's formulas
(:func:`softjig.calibration.tilt.fit_tilt_calibration`, ``DESIGN.md`` §1) are applied to:

- ``pooled`` (the paper: "all data were corrected using the same offsets and scales"): every frame of
  every diameter and tilt at once, ``alpha`` in the scale's formula being the RMS of the frames' tilts;
- ``per-diameter`` on request: one ``(Ox, Oy, S)`` per part diameter, pooled over its tilts; the pooled
  values are computed as well.

Frames that gave no estimate are left out and counted. The formulas assume each ``(diameter, alpha)``
sweep covers a full turn of ``theta`` evenly; a sweep that does not (failed frames leave gaps) biases the
offsets, and :attr:`SweepCalibration.warnings` says which.

The JSON file (:func:`save_sweep_calibration`) is the one ``softjig estimate --calibration`` reads
(:func:`softjig.calibration.tilt.load_tilt_calibration`): ``format``, ``version`` 1, the pooled
``offset_x_deg``, ``offset_y_deg``, ``scale`` at the top level, then ``mode``, ``per_diameter`` (a list of
``{"diameter_mm", "offset_x_deg", "offset_y_deg", "scale", "n_frames"}``, empty when pooled) and ``source``:
the dataset's path, the results file (if any), the frames used, the frames that failed, the frame
selection, the estimation method, the formula, the date and softjig's version.
"""

from __future__ import annotations

import csv
import datetime as _dt
import json
import math
import os
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import IO, Any

import numpy as np

from softjig.calibration.tilt import (
    TiltCalibration,
    fit_tilt_calibration,
    read_calibration_json,
    tilt_calibration_from_dict,
    tilt_calibration_to_dict,
)
from softjig.errors import InputError
from softjig.files import write_text_atomic

__all__ = [
    "MIN_THETAS",
    "MODES",
    "SELECTIONS",
    "SweepCalibration",
    "SweepSamples",
    "alternate_theta_mask",
    "calibrate_from_rows",
    "check_sweep_design",
    "fit_sweep_calibration",
    "load_result_rows",
    "load_sweep_calibration",
    "save_sweep_calibration",
    "sweep_calibration_to_dict",
    "sweep_design",
    "sweep_samples",
]

MODES = ("pooled", "per-diameter")
#: Frame selections: every frame, or the even / odd theta steps of each (diameter, alpha) sweep.
SELECTIONS = ("all", "even", "odd")
_DECIMALS = 6  # diameters and tilts are grouped after rounding to this many decimals


# ------------------------------------------------------------------------------------------ samples


@dataclass(frozen=True, eq=False)
class SweepSamples:
    """The sweep frames of a dataset joined with their estimates; angles in degrees (the files' unit).

    Attributes
    ----------
    index : (n,) frame indices of the frames that gave an estimate.
    diameter_mm, alpha_deg, theta_deg : (n,) their part diameter (mm), commanded tilt and azimuth (deg).
    raw_x_deg, raw_y_deg : (n,) their uncalibrated tilt angles ``Ax, Ay`` (deg, ``DESIGN.md`` §1).
    failed_index, failed_diameter_mm, failed_alpha_deg, failed_theta_deg : (m,) the sweep frames that gave
        no estimate.
    failed_errors : (m,) why each failed (the estimator's message).
    n_skipped : frames that are not sweep frames (reference frames, frames without alpha/theta/part).
    method : the estimation method of the rows (their ``method``), ``None`` if they do not say.
    """

    index: np.ndarray
    diameter_mm: np.ndarray
    alpha_deg: np.ndarray
    theta_deg: np.ndarray
    raw_x_deg: np.ndarray
    raw_y_deg: np.ndarray
    failed_index: np.ndarray = field(default_factory=lambda: np.zeros(0, int))
    failed_diameter_mm: np.ndarray = field(default_factory=lambda: np.zeros(0))
    failed_alpha_deg: np.ndarray = field(default_factory=lambda: np.zeros(0))
    failed_theta_deg: np.ndarray = field(default_factory=lambda: np.zeros(0))
    failed_errors: tuple[str, ...] = ()
    n_skipped: int = 0
    method: str | None = None

    def __len__(self) -> int:
        return len(self.index)

    @property
    def n_failed(self) -> int:
        """How many sweep frames gave no estimate."""
        return len(self.failed_index)

    def select(self, which: str) -> SweepSamples:
        """The frames of one selection of :data:`SELECTIONS` (failed frames follow the same split).

        ``"even"`` and ``"odd"``: the even or odd steps of ``theta`` within each (diameter, alpha) sweep,
        failed frames included when numbering the steps (:func:`alternate_theta_mask`), so a held-out
        half is again an even sweep.
        """
        if which not in SELECTIONS:
            raise InputError(f"unknown frame selection {which!r}; valid: {', '.join(SELECTIONS)}")
        if which == "all":
            return self
        n = len(self.index)
        even = alternate_theta_mask(
            np.concatenate([self.diameter_mm, self.failed_diameter_mm]),
            np.concatenate([self.alpha_deg, self.failed_alpha_deg]),
            np.concatenate([self.theta_deg, self.failed_theta_deg]),
        )
        keep = even if which == "even" else ~even
        ok, bad = keep[:n], keep[n:]
        return SweepSamples(
            index=self.index[ok],
            diameter_mm=self.diameter_mm[ok],
            alpha_deg=self.alpha_deg[ok],
            theta_deg=self.theta_deg[ok],
            raw_x_deg=self.raw_x_deg[ok],
            raw_y_deg=self.raw_y_deg[ok],
            failed_index=self.failed_index[bad],
            failed_diameter_mm=self.failed_diameter_mm[bad],
            failed_alpha_deg=self.failed_alpha_deg[bad],
            failed_theta_deg=self.failed_theta_deg[bad],
            failed_errors=tuple(e for e, k in zip(self.failed_errors, bad, strict=True) if k),
            n_skipped=self.n_skipped,
            method=self.method,
        )

    def check_design(self, selection: str = "all") -> None:
        """:func:`check_sweep_design` on every sweep frame, those that gave no estimate included."""
        check_sweep_design(
            np.concatenate([self.diameter_mm, self.failed_diameter_mm]),
            np.concatenate([self.alpha_deg, self.failed_alpha_deg]),
            np.concatenate([self.theta_deg, self.failed_theta_deg]),
            selection=selection,
        )

    def diameters(self) -> np.ndarray:
        """The distinct part diameters (mm), ascending, failed frames included."""
        return np.unique(np.round(np.concatenate([self.diameter_mm, self.failed_diameter_mm]), _DECIMALS))

    def alphas(self) -> np.ndarray:
        """The distinct commanded tilts (deg), ascending, failed frames included."""
        return np.unique(np.round(np.concatenate([self.alpha_deg, self.failed_alpha_deg]), _DECIMALS))


def alternate_theta_mask(diameter_mm, alpha_deg, theta_deg) -> np.ndarray:
    """True for the even steps of ``theta`` within each (diameter, alpha) sweep, False for the odd ones.

    The frames of one sweep are numbered in ascending ``theta`` (mod 360); steps 0, 2, 4, ... are
    "even". For a sweep of ``theta = 0, 10, ..., 350`` the two halves are the sweeps ``0, 20, ..., 340`` and
    ``10, 30, ..., 350``, each a full turn evenly spaced, as the calibration's formulas assume.
    """
    d = np.round(np.asarray(diameter_mm, dtype=float), _DECIMALS)
    a = np.round(np.asarray(alpha_deg, dtype=float), _DECIMALS)
    t = np.mod(np.asarray(theta_deg, dtype=float), 360.0)
    mask = np.zeros(d.shape, bool)
    for dv, av in {(float(x), float(y)) for x, y in zip(d, a, strict=True)}:
        members = np.flatnonzero((d == dv) & (a == av))
        order = members[np.argsort(t[members], kind="stable")]
        mask[order[0::2]] = True
    return mask


#: Tilt directions (distinct ``theta``) a sweep at one (diameter, alpha) needs at the least: for N >= 3
#: directions evenly spaced over a turn, the mean of ``sin(theta)`` is 0 and its population variance 1/2
#: exactly, which the paper's ``Ox, Oy, S`` assume; with 2 (``theta`` = 0, 180) one tilt angle does not vary
#: and ``S`` is off by sqrt(2), with 1 nothing is determined.
MIN_THETAS = 3


def check_sweep_design(diameter_mm, alpha_deg, theta_deg, *, selection: str = "all") -> None:
    """Refuse a sweep whose design cannot determine ``Ox, Oy, S``, before anything is estimated.

    Parameters
    ----------
    diameter_mm, alpha_deg, theta_deg : (n,) every sweep frame's part diameter (mm), commanded tilt and
        azimuth (deg).
    selection : the frames the calibration is fitted to (:data:`SELECTIONS`); ``"even"`` and ``"odd"``
        keep every other ``theta`` step of each sweep (a held-out evaluation fits on one half).

    Raises
    ------
    InputError
        No frame tilted (every ``alpha = 0``: no scale), or a sweep at ``alpha > 0`` with fewer than
        :data:`MIN_THETAS` tilt directions in the selection, naming it and the theta step needed.
    """
    if selection not in SELECTIONS:
        raise InputError(f"unknown frame selection {selection!r}; valid: {', '.join(SELECTIONS)}")
    d = np.round(np.asarray(diameter_mm, dtype=float), _DECIMALS)
    a = np.round(np.asarray(alpha_deg, dtype=float), _DECIMALS)
    t = np.round(np.mod(np.asarray(theta_deg, dtype=float), 360.0), _DECIMALS)
    if len(d) and not np.any(a != 0):
        raise InputError(
            "every sweep frame has alpha_deg = 0 (the part not tilted): the scale S compares measured tilts "
            "with commanded ones and cannot be fitted; record the sweep at alpha > 0 "
            "(e.g. `softjig simulate --scenario paper-sweep --alphas 5,10,15,20`)"
        )
    keep = np.ones(len(d), bool) if selection == "all" else alternate_theta_mask(d, a, t)
    if selection == "odd":
        keep = ~keep
    halves = 1 if selection == "all" else 2
    for dv, av in sorted({(float(x), float(y)) for x, y in zip(d, a, strict=True) if y != 0}):
        members = (d == dv) & (a == av)
        n_all = len(np.unique(t[members]))
        n_used = len(np.unique(t[members & keep]))
        if n_used < MIN_THETAS:
            step = 360.0 / (MIN_THETAS * halves)
            which = (
                "" if selection == "all" else f" in its {selection} theta steps (the half it is fitted to)"
            )
            raise InputError(
                f"the sweep at D = {dv:g} mm, alpha = {av:g} deg has {n_used} tilt direction(s){which}, "
                f"of {n_all} in all: the tilt calibration needs at least {MIN_THETAS} evenly spaced over a "
                f"turn{' in each half' if halves == 2 else ''}, so at least {MIN_THETAS * halves} per turn: "
                f"record it with a theta step of at most {step:g} deg (--theta-step {step:g})"
            )


def _finite(value: Any) -> float | None:
    if value is None or isinstance(value, bool):
        return None
    try:
        number = float(value)
    except (TypeError, ValueError):
        return None
    return number if math.isfinite(number) else None


def sweep_design(frames: Iterable[Any]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(diameter_mm, alpha_deg, theta_deg) of a dataset's sweep frames (those :func:`sweep_samples`
    joins), from the frames alone: the design :func:`check_sweep_design` checks before any estimate."""
    design = [
        (float(f.part.diameter_mm), float(f.alpha_deg), float(f.theta_deg))
        for f in frames
        if not f.reference and f.alpha_deg is not None and f.theta_deg is not None and f.part is not None
    ]
    if not design:
        raise InputError(
            "the dataset has no sweep frame (frames with alpha_deg, theta_deg and a part): a tilt "
            "calibration needs a sweep such as `softjig simulate --scenario paper-sweep`"
        )
    d, a, t = (np.asarray(c, dtype=float) for c in zip(*design, strict=True))
    return d, a, t


def sweep_samples(frames: Iterable[Any], rows: Iterable[dict]) -> SweepSamples:
    """Join a dataset's sweep frames with their estimate rows (matched by ``index``).

    Parameters
    ----------
    frames : the dataset's frames (:class:`softjig.io.dataset.Frame`: ``index``, ``alpha_deg``,
        ``theta_deg``, ``part``, ``reference``). Frames without ``alpha_deg``, ``theta_deg`` or ``part``,
        and reference frames, are skipped (counted in ``n_skipped``).
    rows : one row per frame as :mod:`softjig.io.batch` writes them: ``index`` and
        ``raw_tilt_x_deg``, ``raw_tilt_y_deg``, or ``index`` and ``error`` for a frame that gave none.

    Raises
    ------
    InputError
        A sweep frame without a row (a results file of another dataset, or a partial one), a row with
        neither raw tilt angles nor an error, or no sweep frame at all.
    """
    # Only what the join needs is kept of each row (rows may be a stream of whole estimate rows).
    by_index: dict[int, tuple[float | None, float | None, Any]] = {}
    methods: set[str] = set()
    for row in rows:
        if not isinstance(row, dict) or not isinstance(row.get("index"), int):
            raise InputError(f"an estimate row lacks an integer 'index': {str(row)[:120]}")
        ax, ay = _finite(row.get("raw_tilt_x_deg")), _finite(row.get("raw_tilt_y_deg"))
        by_index[row["index"]] = (ax, ay, row.get("error"))
        if isinstance(row.get("method"), str):
            methods.add(row["method"])
    if len(methods) > 1:
        raise InputError(
            f"the estimate rows mix the methods {', '.join(sorted(methods))}: a calibration applies to one; "
            "estimate the dataset again with one --method"
        )
    ok: list[tuple[int, float, float, float, float, float]] = []
    bad: list[tuple[int, float, float, float, str]] = []
    skipped = 0
    for frame in frames:
        if frame.reference or frame.alpha_deg is None or frame.theta_deg is None or frame.part is None:
            skipped += 1
            continue
        joined = by_index.get(frame.index)
        if joined is None:
            raise InputError(
                f"frame {frame.index} has no estimate row: the results file is not of this dataset or is "
                "incomplete; re-run `softjig estimate DATASET --out RESULTS.jsonl` (or omit --results)"
            )
        diameter = float(frame.part.diameter_mm)
        ax, ay, error = joined
        if error or ax is None or ay is None:
            if not error:
                raise InputError(
                    f"the estimate row of frame {frame.index} has neither raw_tilt_x_deg/raw_tilt_y_deg nor "
                    "an error: write it with `softjig estimate DATASET --out RESULTS.jsonl`"
                )
            bad.append((frame.index, diameter, frame.alpha_deg, frame.theta_deg, str(error)))
            continue
        ok.append((frame.index, diameter, frame.alpha_deg, frame.theta_deg, ax, ay))
    if not ok and not bad:
        raise InputError(
            "the dataset has no sweep frame (frames with alpha_deg, theta_deg and a part): a tilt "
            "calibration needs a sweep such as `softjig simulate --scenario paper-sweep`"
        )
    cols = list(zip(*ok, strict=True)) if ok else [()] * 6
    fcols = list(zip(*bad, strict=True)) if bad else [()] * 5
    return SweepSamples(
        index=np.asarray(cols[0], dtype=int),
        diameter_mm=np.asarray(cols[1], dtype=float),
        alpha_deg=np.asarray(cols[2], dtype=float),
        theta_deg=np.asarray(cols[3], dtype=float),
        raw_x_deg=np.asarray(cols[4], dtype=float),
        raw_y_deg=np.asarray(cols[5], dtype=float),
        failed_index=np.asarray(fcols[0], dtype=int),
        failed_diameter_mm=np.asarray(fcols[1], dtype=float),
        failed_alpha_deg=np.asarray(fcols[2], dtype=float),
        failed_theta_deg=np.asarray(fcols[3], dtype=float),
        failed_errors=tuple(fcols[4]),
        n_skipped=skipped,
        method=next(iter(methods), None),
    )


# -------------------------------------------------------------------------------------- the fit


@dataclass(frozen=True)
class SweepCalibration:
    """A tilt calibration fitted to a sweep.

    Attributes
    ----------
    pooled : ``(Ox, Oy, S)`` over every frame used (what ``softjig estimate --calibration`` applies).
    mode : ``"pooled"`` or ``"per-diameter"``.
    per_diameter : ``((diameter_mm, calibration, n_frames), ...)`` ascending; empty when pooled.
    frames : indices of the frames used.
    failed_frames : indices of the sweep frames left out because they gave no estimate.
    selection : which frames were used (:data:`SELECTIONS`).
    warnings : things to know, e.g. sweeps that do not cover a full turn evenly.
    """

    pooled: TiltCalibration
    mode: str = "pooled"
    per_diameter: tuple[tuple[float, TiltCalibration, int], ...] = ()
    frames: tuple[int, ...] = ()
    failed_frames: tuple[int, ...] = ()
    selection: str = "all"
    warnings: tuple[str, ...] = ()

    def for_diameter(self, diameter_mm: float) -> TiltCalibration:
        """The calibration to apply to a part of this diameter: its own when per-diameter and fitted,
        else the pooled one."""
        for d, cal, _ in self.per_diameter:
            if math.isclose(d, diameter_mm, abs_tol=1e-6):
                return cal
        return self.pooled


def _coverage_warnings(samples: SweepSamples) -> list[str]:
    notes = []
    d = np.round(samples.diameter_mm, _DECIMALS)
    a = np.round(samples.alpha_deg, _DECIMALS)
    for dv in np.unique(d):
        for av in np.unique(a[d == dv]):
            theta = np.radians(samples.theta_deg[(d == dv) & (a == av)])
            if av == 0:
                continue
            resultant = float(np.hypot(np.mean(np.cos(theta)), np.mean(np.sin(theta))))
            if len(theta) < 3 or resultant > 0.1:
                notes.append(
                    f"the sweep at D = {dv:g} mm, alpha = {av:g} deg does not cover a full turn of theta "
                    f"evenly ({len(theta)} frames with an estimate): its offsets are biased"
                )
    return notes


def fit_sweep_calibration(
    samples: SweepSamples, *, mode: str = "pooled", selection: str = "all"
) -> SweepCalibration:
    """Fit the paper's ``(Ox, Oy, S)`` to a sweep's uncalibrated tilt angles.

    Parameters
    ----------
    samples : the sweep (:func:`sweep_samples`).
    mode : ``"pooled"`` (one calibration for every part, as the paper) or ``"per-diameter"`` (one per
        part diameter, pooled over its tilts, plus the pooled one).
    selection : which frames to fit (:data:`SELECTIONS`): all, or the even / odd steps of ``theta`` (to
        keep the other half for evaluation).

    Returns
    -------
    SweepCalibration

    Raises
    ------
    InputError
        An unknown mode or selection; a sweep design that cannot determine the calibration
        (:func:`check_sweep_design`); fewer than 3 frames with an estimate (in a diameter, per diameter);
        a fit that is not credible (:func:`~softjig.calibration.tilt.fit_tilt_calibration`).

    The calibration records the rows' estimation method (:attr:`SweepSamples.method`).
    """
    if mode not in MODES:
        raise InputError(f"unknown calibration mode {mode!r}; valid: {', '.join(MODES)}")
    samples.check_design(selection)
    used = samples.select(selection)
    if len(used) < 3:
        raise InputError(
            f"only {len(used)} sweep frames of the selection '{selection}' gave an estimate "
            f"({used.n_failed} failed); a tilt calibration needs at least 3: check the failed frames' errors"
        )

    def fit(sel: np.ndarray) -> TiltCalibration:
        cal = fit_tilt_calibration(
            np.radians(used.raw_x_deg[sel]), np.radians(used.raw_y_deg[sel]), np.radians(used.alpha_deg[sel])
        )
        return replace(cal, method=samples.method)

    pooled = fit(np.ones(len(used), bool))
    per: list[tuple[float, TiltCalibration, int]] = []
    if mode == "per-diameter":
        d = np.round(used.diameter_mm, _DECIMALS)
        for dv in np.unique(d):
            sel = d == dv
            try:
                per.append((float(dv), fit(sel), int(sel.sum())))
            except InputError as exc:
                raise InputError(f"part diameter {dv:g} mm: {exc}") from None
    return SweepCalibration(
        pooled=pooled,
        mode=mode,
        per_diameter=tuple(per),
        frames=tuple(int(i) for i in used.index),
        failed_frames=tuple(int(i) for i in used.failed_index),
        selection=selection,
        warnings=tuple(_coverage_warnings(used)),
    )


# ------------------------------------------------------------------------------------ the files


def _calibration_entry(cal: TiltCalibration) -> dict[str, float]:
    return {
        "offset_x_deg": float(np.degrees(cal.offset_x_rad)),
        "offset_y_deg": float(np.degrees(cal.offset_y_rad)),
        "scale": float(cal.scale),
    }


def sweep_calibration_to_dict(calibration: SweepCalibration, *, source: dict[str, Any] | None = None) -> dict:
    """The versioned JSON form (see the module docstring); ``source`` is merged into the recorded source."""
    from softjig import __version__

    recorded = {
        "frames": list(calibration.frames),
        "n_frames": len(calibration.frames),
        "failed_frames": list(calibration.failed_frames),
        "selection": calibration.selection,
        "formula": "Ox = mean(Ax), Oy = mean(Ay), S = 2 alpha / (sqrt(2) (sigma_x + sigma_y)), "
        "alpha = RMS of the frames' commanded tilts; A' = S (A - O)",
        "created": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
        "softjig_version": __version__,
        "warnings": list(calibration.warnings),
        **(source or {}),
    }
    data = tilt_calibration_to_dict(calibration.pooled, source=recorded)
    data.pop("source")
    data["mode"] = calibration.mode
    data["per_diameter"] = [
        {"diameter_mm": d, **_calibration_entry(cal), "n_frames": n} for d, cal, n in calibration.per_diameter
    ]
    data["source"] = recorded
    return data


def save_sweep_calibration(
    calibration: SweepCalibration, path: str | os.PathLike[str], *, source: dict[str, Any] | None = None
) -> dict:
    """Write the calibration JSON atomically; returns what was written."""
    data = sweep_calibration_to_dict(calibration, source=source)
    write_text_atomic(path, json.dumps(data, indent=2) + "\n")
    return data


def load_sweep_calibration(path: str | os.PathLike[str]) -> SweepCalibration:
    """Read a calibration file written by :func:`save_sweep_calibration` (or any file
    :func:`~softjig.calibration.tilt.load_tilt_calibration` reads: then pooled, without a source).

    Raises
    ------
    InputError
        A missing, unreadable or invalid file, naming the problem.
    """
    path = Path(path)
    data = read_calibration_json(path)
    if not isinstance(data, dict):
        raise InputError(f"{path}: expected a JSON object with offset_x_deg, offset_y_deg and scale")
    pooled = tilt_calibration_from_dict(data, where=str(path))
    entries = data.get("per_diameter") or []
    if not isinstance(entries, list):
        raise InputError(f"{path}: 'per_diameter' must be a list of objects")
    per = []
    for k, entry in enumerate(entries):
        where = f"{path}: per_diameter[{k}]"
        diameter = _finite(entry.get("diameter_mm")) if isinstance(entry, dict) else None
        if diameter is None or diameter <= 0:
            raise InputError(f"{where}: 'diameter_mm' must be a positive number")
        entry_cal = tilt_calibration_from_dict(entry, where=where, default_method=pooled.method)
        per.append((diameter, entry_cal, int(entry.get("n_frames", 0))))
    source = data.get("source") if isinstance(data.get("source"), dict) else {}
    mode = data.get("mode", "per-diameter" if per else "pooled")
    if mode not in MODES:
        raise InputError(f"{path}: unknown mode {mode!r}; valid: {', '.join(MODES)}")
    return SweepCalibration(
        pooled=pooled,
        mode=mode,
        per_diameter=tuple(per),
        frames=tuple(int(i) for i in source.get("frames", [])),
        failed_frames=tuple(int(i) for i in source.get("failed_frames", [])),
        selection=str(source.get("selection", "all")),
        warnings=tuple(str(w) for w in source.get("warnings", [])),
    )


def load_result_rows(path: str | os.PathLike[str]) -> list[dict]:
    """Read a results file of ``softjig estimate DATASET --out``: JSON Lines, or CSV (``.csv``).

    Raises
    ------
    InputError
        A missing or unreadable file, or a line that is not a JSON object.
    """
    path = Path(path)
    try:
        # newline="": the csv module handles line ends itself (a quoted field may hold one).
        with open(path, encoding="utf-8", newline="") as fh:
            return _read_rows(fh, path)
    except FileNotFoundError:
        raise InputError(
            f"results file {path} does not exist: write it with `softjig estimate DATASET --out {path}`"
        ) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"cannot read results file {path}: {exc}") from None


def _read_rows(fh: IO[str], path: Path) -> list[dict]:
    """The rows of an open results file, read line by line (:func:`load_result_rows`)."""
    rows: list[dict] = []
    if path.suffix.lower() == ".csv":
        for n, raw in enumerate(csv.DictReader(fh), start=2):
            row: dict[str, Any] = {k: v for k, v in raw.items() if v not in (None, "")}
            try:
                row["index"] = int(row["index"])
            except (KeyError, ValueError):
                raise InputError(f"{path}, line {n}: no integer 'index'") from None
            rows.append(row)
        return rows
    for n, line in enumerate(fh, start=1):
        if not line.strip():
            continue
        try:
            obj = json.loads(line)
        except json.JSONDecodeError as exc:
            raise InputError(f"{path}, line {n}: not valid JSON ({exc})") from None
        if not isinstance(obj, dict):
            raise InputError(f"{path}, line {n}: expected a JSON object")
        rows.append(obj)
    return rows


# ------------------------------------------------------------------------------------ end to end


def calibrate_from_rows(
    dataset: Any,
    rows: Sequence[dict],
    *,
    mode: str = "pooled",
    selection: str = "all",
    method: str = "paper",
) -> tuple[SweepCalibration, SweepSamples]:
    """Calibrate from a sweep dataset's estimate rows (one per frame, all of ``method``).

    Parameters
    ----------
    dataset : an open :class:`softjig.io.dataset.Dataset` (its frames' commanded tilts).
    rows : estimate rows of this dataset (:func:`load_result_rows`, or
        :func:`softjig.io.batch.calibrate_dataset`, which estimates them first).
    method : the estimation method the rows were made with (the calibration is only valid for it).
    mode, selection : see :func:`fit_sweep_calibration`.

    Returns
    -------
    (SweepCalibration, SweepSamples)
        The fit, and the sweep it was fitted to (every frame, before the selection).

    Raises
    ------
    InputError
        Rows of another method, or a sweep that cannot be calibrated.
    """
    used = {row.get("method") for row in rows if "method" in row}
    if used and used != {method}:
        raise InputError(
            f"the results were estimated with {', '.join(sorted(used))}, not with the method to calibrate "
            f"({method}): pass --method {sorted(used)[0]}"
        )
    samples = sweep_samples(dataset, rows)
    fit = fit_sweep_calibration(samples, mode=mode, selection=selection)
    pooled = replace(fit.pooled, method=method)
    per = tuple((d, replace(cal, method=method), n) for d, cal, n in fit.per_diameter)
    return replace(fit, pooled=pooled, per_diameter=per), samples
