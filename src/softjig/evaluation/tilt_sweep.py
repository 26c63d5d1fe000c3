"""Evaluate a tilt calibration on a sweep: the paper's RMSE grid, calibrated and uncalibrated (pure).

Each frame's calibrated tilt angles are ``A' = S (A - O)`` of its uncalibrated ones (``DESIGN.md`` §1),
with the pooled calibration or, for a per-diameter one, its diameter's; the reference is the commanded
tilt's angles (:func:`softjig.evaluation.metrics.commanded_tilt_angles_deg`); the RMSE pools both axes
(:mod:`softjig.evaluation.metrics`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from softjig.calibration.sweep import SweepCalibration, SweepSamples
from softjig.calibration.tilt import TiltCalibration
from softjig.evaluation.metrics import RmseGrid, commanded_tilt_angles_deg, rmse_grid

__all__ = ["SweepEvaluation", "corrected_tilts_deg", "evaluate_sweep"]


def corrected_tilts_deg(
    samples: SweepSamples, calibration: SweepCalibration | TiltCalibration | None
) -> tuple[np.ndarray, np.ndarray]:
    """Each frame's tilt angles ``(Ax', Ay')`` (deg) after ``calibration`` (the raw ones for ``None``)."""
    ax, ay = np.radians(samples.raw_x_deg), np.radians(samples.raw_y_deg)
    if calibration is None:
        return samples.raw_x_deg.copy(), samples.raw_y_deg.copy()
    if isinstance(calibration, TiltCalibration):
        cx, cy = calibration.apply(ax, ay)
        return np.degrees(cx), np.degrees(cy)
    out_x, out_y = np.empty_like(ax), np.empty_like(ay)
    for k, d in enumerate(samples.diameter_mm):
        cx, cy = calibration.for_diameter(float(d)).apply(ax[k], ay[k])
        out_x[k], out_y[k] = float(cx), float(cy)
    return np.degrees(out_x), np.degrees(out_y)


@dataclass(frozen=True, eq=False)
class SweepEvaluation:
    """RMSE grids of one set of sweep frames.

    Attributes
    ----------
    calibrated : the grid of the calibrated tilts.
    uncalibrated : the grid of the raw tilts.
    selection : which frames were evaluated (``"all"``, ``"even"``, ``"odd"``).
    n_frames, n_failed : frames evaluated, and sweep frames of the selection that gave no estimate.
    """

    calibrated: RmseGrid
    uncalibrated: RmseGrid
    selection: str
    n_frames: int
    n_failed: int


def evaluate_sweep(
    samples: SweepSamples,
    calibration: SweepCalibration | TiltCalibration | None,
    *,
    selection: str = "all",
) -> SweepEvaluation:
    """The RMSE grids (diameter x alpha) of the ``selection`` of ``samples``, calibrated and not.

    Use a ``selection`` disjoint from the calibration's (``"odd"`` after fitting on ``"even"``) for a
    held-out evaluation. With ``calibration=None`` both grids are the uncalibrated one.
    """
    used = samples.select(selection)
    cmd_x, cmd_y = commanded_tilt_angles_deg(used.alpha_deg, used.theta_deg)
    grids = []
    for cal in (calibration, None):
        ax, ay = corrected_tilts_deg(used, cal)
        grids.append(
            rmse_grid(
                used.diameter_mm,
                used.alpha_deg,
                ax - cmd_x,
                ay - cmd_y,
                failed_diameters_mm=used.failed_diameter_mm,
                failed_alphas_deg=used.failed_alpha_deg,
            )
        )
    return SweepEvaluation(grids[0], grids[1], selection, len(used), used.n_failed)
