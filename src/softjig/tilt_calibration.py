"""The tilt calibration's value: offsets ``Ox, Oy`` (rad), scale ``S`` and the correction ``A' = S (A - O)``.

Core, below sensing: the estimator applies a calibration to every estimate it makes, and
:mod:`softjig.calibration.tilt` fits one from a sweep and reads and writes its file (``DESIGN.md`` §1).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from softjig.errors import InputError

__all__ = ["TiltCalibration"]


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

    def __post_init__(self) -> None:
        for name in ("offset_x_rad", "offset_y_rad", "scale"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | float | np.floating | np.integer):
                raise InputError(f"TiltCalibration.{name} must be a number, got {value!r}")
            if not np.isfinite(value):
                raise InputError(f"TiltCalibration.{name} must be finite, got {value}")
        if not self.scale > 0:
            raise InputError(f"TiltCalibration.scale must be positive, got {self.scale}")

    def apply(self, ax_rad, ay_rad):
        """Corrected tilt angles ``S (A - O)`` (rad); scalars or arrays."""
        return self.scale * (np.asarray(ax_rad) - self.offset_x_rad), self.scale * (
            np.asarray(ay_rad) - self.offset_y_rad
        )

    def is_identity(self) -> bool:
        """True when applying it changes nothing."""
        return self.offset_x_rad == 0 and self.offset_y_rad == 0 and self.scale == 1
