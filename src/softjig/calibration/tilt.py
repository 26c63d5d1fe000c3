"""The paper's tilt calibration (section "Jig Coordinate Calibration"): offsets ``Ox, Oy`` and scale ``S``.

For a sweep in which the tilt direction turns through 360 degrees at a fixed tilt ``alpha``, the measured
tilt angles ``Ax_i, Ay_i`` are sine waves; their means are the offsets and their spread gives the scale:

.. math::
    O_x = \\overline{Ax}, \\quad O_y = \\overline{Ay}, \\quad
    S = \\frac{2 \\alpha}{\\sqrt{2} (\\sigma_x + \\sigma_y)},

with population standard deviations ``sigma``; a corrected angle is ``A' = S (A - O)``
(``DESIGN.md`` §1). ``S = 1`` and ``O = 0`` for a perfect sensor.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from softjig.errors import InputError
from softjig.files import write_text_atomic
from softjig.tilt_calibration import TiltCalibration

#: Plausible scales ``S``. A pinhole triangulation that ignores the plate and the oil compresses depth by
#: about their refractive index (1.5), so the paper's method needs ``S`` near 1.5 and a metric method near
#: 1; a scale ten times off means the commanded tilts are not those of the frames (``alpha_deg`` written
#: in radians, another part's frames), and applying it would scale every tilt by that error.
SCALE_RANGE = (0.1, 10.0)
_MIN_SPREAD_RAD = 1e-9  # tilt angles spread less than this (rad) do not vary (rounding only)


def fit_tilt_calibration(
    ax_rad: np.ndarray, ay_rad: np.ndarray, alpha_rad: float | np.ndarray
) -> TiltCalibration:
    """The paper's ``Ox, Oy, S`` from one sweep's tilt angles at a commanded tilt ``alpha``.

    Parameters
    ----------
    ax_rad, ay_rad : (n,) measured tilt angles over a full turn of the tilt direction (rad), evenly spaced
        in azimuth (the formulas assume a full period).
    alpha_rad : the commanded tilt (rad): a scalar, or (n,) when sweeps at several tilts are pooled (as
        the paper does: "all data were corrected using the same offsets and scales"). Pooled, ``alpha``
        in the formula is the RMS of the frames' tilts: a sine of amplitude ``alpha`` has a population
        standard deviation ``alpha / sqrt(2)``, so pooled sines have ``sqrt(mean(alpha^2) / 2)``; for a
        single tilt this is the paper's formula exactly.

    Raises
    ------
    InputError
        Fewer than 3 samples, mismatched lengths, non-finite values, no tilt (every ``alpha = 0``), no
        spread (sigma = 0), or a scale outside :data:`SCALE_RANGE`.
    """
    ax = np.asarray(ax_rad, dtype=float)
    ay = np.asarray(ay_rad, dtype=float)
    alpha = np.broadcast_to(np.asarray(alpha_rad, dtype=float), ax.shape)
    if ax.shape != ay.shape or ax.ndim != 1:
        raise InputError(f"tilt angles must be two 1-D arrays of one length, got {ax.shape} and {ay.shape}")
    if len(ax) < 3:
        raise InputError(f"a tilt calibration needs a sweep of at least 3 frames, got {len(ax)}")
    if not (np.all(np.isfinite(ax)) and np.all(np.isfinite(ay)) and np.all(np.isfinite(alpha))):
        raise InputError("tilt angles contain NaN or inf")
    ox, oy = float(ax.mean()), float(ay.mean())
    sigma_x, sigma_y = float(ax.std()), float(ay.std())
    rms_alpha = float(np.sqrt(np.mean(alpha**2)))
    if not rms_alpha > 0:
        raise InputError(
            "every frame of the sweep has alpha = 0 (the part not tilted): the scale S compares the measured "
            "tilts with the commanded ones and cannot be fitted; record the sweep at alpha > 0 "
            "(e.g. `softjig simulate --scenario paper-sweep --alphas 5,10,15,20`)"
        )
    if sigma_x + sigma_y <= _MIN_SPREAD_RAD:
        raise InputError(
            "the tilt angles do not vary: the sweep did not tilt the part, no scale can be fitted"
        )
    scale = 2.0 * rms_alpha / (np.sqrt(2.0) * (sigma_x + sigma_y))
    if not (np.isfinite(scale) and SCALE_RANGE[0] <= scale <= SCALE_RANGE[1]):
        raise InputError(
            f"the fitted scale S = {scale:.4g} is outside {SCALE_RANGE[0]:g}-{SCALE_RANGE[1]:g}: the "
            f"measured tilts vary {1 / scale:.3g} times as much as the commanded ones (RMS "
            f"{np.degrees(rms_alpha):.4g} deg), which no working jig does; check the sweep's alpha_deg "
            "(degrees, not radians) and that its frames are of this part"
        )
    return TiltCalibration(offset_x_rad=ox, offset_y_rad=oy, scale=float(scale))


CALIBRATION_FORMAT = "softjig-tilt-calibration"
CALIBRATION_VERSION = 1


#: How to make a calibration file, for the messages that refuse one.
REDO_HINT = "softjig calibrate DATASET --method {method} --out CAL.json"


def _method_of(calibration: TiltCalibration, source: dict | None) -> str:
    """The method a calibration was fitted to: its own, else the ``source``'s; an error if neither says."""
    method = calibration.method or (source or {}).get("method")
    if not isinstance(method, str) or not method:
        raise InputError(
            "a tilt calibration must record the estimation method it was fitted to (TiltCalibration.method "
            "or source['method']): it corrects that method's tilt angles only"
        )
    if calibration.method is not None and method != calibration.method:
        raise InputError(
            f"the calibration was fitted to the {calibration.method} method, but its source says "
            f"{(source or {}).get('method')!r}"
        )
    return method


def tilt_calibration_to_dict(calibration: TiltCalibration, *, source: dict | None = None) -> dict:
    """The JSON form: ``method`` (always: a calibration applies to one estimation method), ``offset_x_deg``,
    ``offset_y_deg``, ``scale`` (``DESIGN.md``), versioned, with what it was computed from (``source``:
    dataset, frames, ...).

    Raises
    ------
    InputError
        Neither the calibration nor ``source`` names the method it was fitted to.
    """
    method = _method_of(calibration, source)
    return {
        "format": CALIBRATION_FORMAT,
        "version": CALIBRATION_VERSION,
        "method": method,
        "offset_x_deg": float(np.degrees(calibration.offset_x_rad)),
        "offset_y_deg": float(np.degrees(calibration.offset_y_rad)),
        "scale": float(calibration.scale),
        "source": source or {},
    }


def tilt_calibration_from_dict(
    data: dict, *, where: str = "calibration", default_method: str | None = None
) -> TiltCalibration:
    """Parse :func:`tilt_calibration_to_dict`'s form; raises :class:`InputError` naming the problem.

    ``method`` is required (``default_method`` stands in for it in a nested entry that inherits its file's
    method, such as a per-diameter calibration): a file without it was written by an older softjig, and
    applying it to another method's estimates silently gives wrong tilts (the paper method's scale nearly
    doubles the refractive method's tilts), so it is refused with how to redo it.
    """
    if not isinstance(data, dict):
        raise InputError(f"{where}: expected a JSON object with method, offset_x_deg, offset_y_deg and scale")
    if data.get("version", CALIBRATION_VERSION) != CALIBRATION_VERSION:
        raise InputError(f"{where}: version {data.get('version')} is not supported (this softjig reads 1)")
    values = []
    for key in ("offset_x_deg", "offset_y_deg", "scale"):
        value = data.get(key)
        if not isinstance(value, int | float) or isinstance(value, bool) or not np.isfinite(value):
            raise InputError(f"{where}: '{key}' must be a finite number, got {value!r}")
        values.append(float(value))
    if values[2] <= 0:
        raise InputError(f"{where}: 'scale' must be positive, got {values[2]}")
    method = data.get("method", default_method)
    if method is None:
        source = data.get("source") if isinstance(data.get("source"), dict) else {}
        named = source.get("method")
        hint = (
            f'; its source says it was fitted to the {named} method: if so, add "method": "{named}" at '
            "the top level"
            if isinstance(named, str)
            else ""
        )
        raise InputError(
            f"{where} does not say which estimation method it was fitted to (no top-level 'method': "
            f"written by an older softjig), and a calibration applies to one method only. Redo it with "
            f"`{REDO_HINT.format(method='METHOD')}` (METHOD: the --method you estimate with){hint}"
        )
    if not isinstance(method, str) or not method:
        raise InputError(f"{where}: 'method' must be the name of an estimation method, got {method!r}")
    return TiltCalibration(np.radians(values[0]), np.radians(values[1]), values[2], method)


def check_calibration_for(
    calibration: TiltCalibration | None, method: str, *, where: str = "the tilt calibration"
) -> None:
    """Refuse a calibration fitted to another estimation method than ``method`` (:class:`InputError`).

    ``None`` (no calibration) passes. A calibration that does not record its method is refused too: it
    cannot be checked (files are refused when read, :func:`tilt_calibration_from_dict`).
    """
    if calibration is None:
        return
    if calibration.method is None:
        raise InputError(
            f"{where} does not record the estimation method it was fitted to; redo it with "
            f"`{REDO_HINT.format(method=method)}`"
        )
    if calibration.method != method:
        raise InputError(
            f"{where} was fitted to the {calibration.method} method's estimates and does not apply to the "
            f"{method} method's: estimate with --method {calibration.method}, or make one for {method} with "
            f"`{REDO_HINT.format(method=method)}`"
        )


def read_calibration_json(path: str | os.PathLike[str]) -> dict:
    """The JSON object of a calibration file; :class:`InputError` if missing or unreadable."""
    path = Path(path)
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise InputError(
            f"calibration file {path} does not exist (make one with `softjig calibrate`)"
        ) from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(f"cannot read calibration file {path}: {exc}") from None
    return data


def load_tilt_calibration(path: str | os.PathLike[str], *, method: str | None = None) -> TiltCalibration:
    """Read a calibration JSON file; :class:`InputError` if missing, unreadable or invalid, or (``method``
    given) fitted to another estimation method (:func:`check_calibration_for`)."""
    calibration = tilt_calibration_from_dict(read_calibration_json(path), where=str(path))
    if method is not None:
        check_calibration_for(calibration, method, where=str(path))
    return calibration


def save_tilt_calibration(
    calibration: TiltCalibration, path: str | os.PathLike[str], *, source: dict | None = None
) -> None:
    """Write a calibration JSON file atomically."""
    write_text_atomic(path, json.dumps(tilt_calibration_to_dict(calibration, source=source), indent=2) + "\n")
