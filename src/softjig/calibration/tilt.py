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
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from softjig.errors import InputError
from softjig.io.files import write_text_atomic


@dataclass(frozen=True)
class TiltCalibration:
    """Offsets (rad) and scale of the paper's tilt calibration; the identity by default.

    ``method`` is the estimation method whose tilt angles it was fitted to (``None``: not recorded): a
    calibration corrects one method's errors and must not be applied to another's.
    """

    offset_x_rad: float = 0.0
    offset_y_rad: float = 0.0
    scale: float = 1.0
    method: str | None = None

    def apply(self, ax_rad, ay_rad):
        """Corrected tilt angles ``S (A - O)`` (rad); scalars or arrays."""
        return self.scale * (np.asarray(ax_rad) - self.offset_x_rad), self.scale * (
            np.asarray(ay_rad) - self.offset_y_rad
        )

    def is_identity(self) -> bool:
        """True when applying it changes nothing."""
        return self.offset_x_rad == 0 and self.offset_y_rad == 0 and self.scale == 1


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
        Fewer than 3 samples, mismatched lengths, non-finite values, or no spread (sigma = 0).
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
    if sigma_x + sigma_y == 0:
        raise InputError(
            "the tilt angles do not vary: the sweep did not tilt the part, no scale can be fitted"
        )
    scale = 2.0 * float(np.sqrt(np.mean(alpha**2))) / (np.sqrt(2.0) * (sigma_x + sigma_y))
    return TiltCalibration(offset_x_rad=ox, offset_y_rad=oy, scale=scale)


CALIBRATION_FORMAT = "softjig-tilt-calibration"
CALIBRATION_VERSION = 1


def tilt_calibration_to_dict(calibration: TiltCalibration, *, source: dict | None = None) -> dict:
    """The JSON form: ``offset_x_deg``, ``offset_y_deg``, ``scale`` (``DESIGN.md``), versioned, with
    what it was computed from (``source``: dataset, frames, ...)."""
    data = {
        "format": CALIBRATION_FORMAT,
        "version": CALIBRATION_VERSION,
        "offset_x_deg": float(np.degrees(calibration.offset_x_rad)),
        "offset_y_deg": float(np.degrees(calibration.offset_y_rad)),
        "scale": float(calibration.scale),
        "source": source or {},
    }
    if calibration.method is not None:
        data["method"] = calibration.method
    return data


def tilt_calibration_from_dict(data: dict, *, where: str = "calibration") -> TiltCalibration:
    """Parse :func:`tilt_calibration_to_dict`'s form; raises :class:`InputError` naming the problem."""
    if not isinstance(data, dict):
        raise InputError(f"{where}: expected a JSON object with offset_x_deg, offset_y_deg and scale")
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
    method = data.get("method")
    if method is not None and not isinstance(method, str):
        raise InputError(f"{where}: 'method' must be the name of an estimation method, got {method!r}")
    return TiltCalibration(np.radians(values[0]), np.radians(values[1]), values[2], method)


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


def load_tilt_calibration(path: str | os.PathLike[str]) -> TiltCalibration:
    """Read a calibration JSON file; :class:`InputError` if missing, unreadable or invalid."""
    return tilt_calibration_from_dict(read_calibration_json(path), where=str(path))


def save_tilt_calibration(
    calibration: TiltCalibration, path: str | os.PathLike[str], *, source: dict | None = None
) -> None:
    """Write a calibration JSON file atomically."""
    write_text_atomic(path, json.dumps(tilt_calibration_to_dict(calibration, source=source), indent=2) + "\n")
