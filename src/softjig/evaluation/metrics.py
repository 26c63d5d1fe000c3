"""Error metrics of tilt estimates against commanded or true tilts: the paper's RMSE grid, pure.

Definitions (degrees at this edge, as the paper reports them)
---------------------------------------------------------------
For a frame ``i`` with estimated tilt angles ``(Ax_i, Ay_i)`` and reference ones ``(Ax*_i, Ay*_i)`` (the
commanded tilt's, ``geometry.tilt_angles(geometry.normal_from_tilt(alpha, theta))``, or the ground truth's),
the errors are ``ex_i = Ax_i - Ax*_i`` and ``ey_i = Ay_i - Ay*_i``. The RMSE of a cell (one part diameter
``D`` and one tilt ``alpha``, over the ``n`` frames of its ``theta`` sweep) pools both axes::

    RMSE = sqrt( sum_i (ex_i^2 + ey_i^2) / (2 n) )

i.e. the root mean square of the ``2 n`` per-axis errors: for errors of equal spread on both axes it is
the per-axis RMSE. The per-axis RMSEs ``sqrt(mean(ex^2))`` and ``sqrt(mean(ey^2))`` are kept too, and the
angle between the estimated and the reference normal (a different, frame-free measure).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from softjig.errors import InputError
from softjig.geometry import angle_between, normal_from_tilt, tilt_angles

__all__ = [
    "RmseGrid",
    "TiltErrorSummary",
    "commanded_tilt_angles_deg",
    "rmse_deg",
    "rmse_grid",
    "tilt_error_summary",
]


def commanded_tilt_angles_deg(alpha_deg, theta_deg) -> tuple[np.ndarray, np.ndarray]:
    """The tilt angles ``(Ax, Ay)`` (deg) of a part tilted by ``alpha`` towards azimuth ``theta`` (deg).

    Exactly ``tilt_angles(normal_from_tilt(alpha, theta))`` (``DESIGN.md`` §1): ``Ax = atan2(-n_y, n_z)``,
    ``Ay = atan2(n_x, n_z)``. Scalars or arrays of one shape; returns two arrays of that shape.
    """
    alpha = np.radians(np.asarray(alpha_deg, dtype=float))
    theta = np.radians(np.asarray(theta_deg, dtype=float))
    alpha, theta = np.broadcast_arrays(alpha, theta)
    normals = np.array([normal_from_tilt(a, t) for a, t in zip(alpha.ravel(), theta.ravel(), strict=True)])
    ax, ay = tilt_angles(normals.reshape(-1, 3))
    return np.degrees(ax).reshape(alpha.shape), np.degrees(ay).reshape(alpha.shape)


def rmse_deg(err_x_deg, err_y_deg) -> float:
    """RMSE over both axes, ``sqrt(sum(ex^2 + ey^2) / (2 n))`` (deg); NaN for no frame."""
    ex, ey = np.asarray(err_x_deg, dtype=float), np.asarray(err_y_deg, dtype=float)
    if ex.shape != ey.shape:
        raise InputError(f"the x and y errors must have one shape, got {ex.shape} and {ey.shape}")
    if ex.size == 0:
        return float("nan")
    return float(np.sqrt((np.sum(ex**2) + np.sum(ey**2)) / (2 * ex.size)))


@dataclass(frozen=True, eq=False)
class RmseGrid:
    """The paper's RMSE grid: one cell per (part diameter, tilt alpha); rows diameters, columns tilts.

    Attributes
    ----------
    diameters_mm : (R,) the part diameters, ascending (rows, top to bottom as in the paper).
    alphas_deg : (C,) the commanded tilts, ascending (columns, left to right).
    rmse_deg : (R, C) RMSE over both axes (see the module docstring), deg; NaN where no frame.
    rmse_x_deg, rmse_y_deg : (R, C) per-axis RMSE, deg.
    count : (R, C) frames evaluated in each cell.
    failed : (R, C) frames of each cell that gave no estimate (not in ``count``).
    """

    diameters_mm: np.ndarray
    alphas_deg: np.ndarray
    rmse_deg: np.ndarray
    rmse_x_deg: np.ndarray
    rmse_y_deg: np.ndarray
    count: np.ndarray
    failed: np.ndarray

    def cell(self, diameter_mm: float, alpha_deg: float) -> float:
        """The RMSE (deg) of one cell; :class:`KeyError` if the grid has no such cell."""
        r = np.flatnonzero(np.isclose(self.diameters_mm, diameter_mm))
        c = np.flatnonzero(np.isclose(self.alphas_deg, alpha_deg))
        if not len(r) or not len(c):
            raise KeyError((diameter_mm, alpha_deg))
        return float(self.rmse_deg[r[0], c[0]])

    def to_dict(self) -> dict:
        """JSON form: lists, ``null`` for empty cells."""

        def clean(a: np.ndarray) -> list:
            return [[None if not np.isfinite(v) else float(v) for v in row] for row in np.asarray(a, float)]

        return {
            "diameters_mm": [float(d) for d in self.diameters_mm],
            "alphas_deg": [float(a) for a in self.alphas_deg],
            "rmse_deg": clean(self.rmse_deg),
            "rmse_x_deg": clean(self.rmse_x_deg),
            "rmse_y_deg": clean(self.rmse_y_deg),
            "count": self.count.astype(int).tolist(),
            "failed": self.failed.astype(int).tolist(),
        }


def rmse_grid(
    diameters_mm: Sequence[float] | np.ndarray,
    alphas_deg: Sequence[float] | np.ndarray,
    err_x_deg: Sequence[float] | np.ndarray,
    err_y_deg: Sequence[float] | np.ndarray,
    *,
    failed_diameters_mm: Sequence[float] | np.ndarray = (),
    failed_alphas_deg: Sequence[float] | np.ndarray = (),
    decimals: int = 6,
) -> RmseGrid:
    """Group per-frame tilt errors by (diameter, alpha) and compute each cell's RMSE.

    Parameters
    ----------
    diameters_mm, alphas_deg : (n,) each frame's part diameter (mm) and commanded tilt (deg).
    err_x_deg, err_y_deg : (n,) each frame's error ``A - A*`` about x and about y (deg).
    failed_diameters_mm, failed_alphas_deg : (m,) the cells of frames that gave no estimate, counted in
        :attr:`RmseGrid.failed` (their cell appears even if no frame of it succeeded).
    decimals : diameters and tilts are grouped after rounding to this many decimals.

    Returns
    -------
    RmseGrid

    Raises
    ------
    InputError
        Arrays of different lengths, non-finite errors, or no frame at all.
    """
    d = np.round(np.asarray(diameters_mm, dtype=float), decimals)
    a = np.round(np.asarray(alphas_deg, dtype=float), decimals)
    ex, ey = np.asarray(err_x_deg, dtype=float), np.asarray(err_y_deg, dtype=float)
    fd = np.round(np.asarray(failed_diameters_mm, dtype=float), decimals)
    fa = np.round(np.asarray(failed_alphas_deg, dtype=float), decimals)
    if not (d.shape == a.shape == ex.shape == ey.shape) or d.ndim != 1:
        raise InputError(
            f"diameters, alphas and errors must be 1-D arrays of one length, got {d.shape}, {a.shape}, "
            f"{ex.shape}, {ey.shape}"
        )
    if fd.shape != fa.shape or fd.ndim != 1:
        raise InputError(f"failed diameters and alphas must match, got {fd.shape} and {fa.shape}")
    if not (np.all(np.isfinite(ex)) and np.all(np.isfinite(ey))):
        raise InputError("tilt errors contain NaN or inf: drop the frames that gave no estimate first")
    if d.size + fd.size == 0:
        raise InputError("no frame to evaluate: the RMSE grid needs at least one frame")
    rows = np.unique(np.concatenate([d, fd]))
    cols = np.unique(np.concatenate([a, fa]))
    shape = (len(rows), len(cols))
    rmse, rx, ry = np.full(shape, np.nan), np.full(shape, np.nan), np.full(shape, np.nan)
    count, failed = np.zeros(shape, int), np.zeros(shape, int)
    for i, dv in enumerate(rows):
        for j, av in enumerate(cols):
            sel = (d == dv) & (a == av)
            failed[i, j] = int(np.sum((fd == dv) & (fa == av)))
            count[i, j] = int(sel.sum())
            if count[i, j]:
                rmse[i, j] = rmse_deg(ex[sel], ey[sel])
                rx[i, j] = float(np.sqrt(np.mean(ex[sel] ** 2)))
                ry[i, j] = float(np.sqrt(np.mean(ey[sel] ** 2)))
    return RmseGrid(rows, cols, rmse, rx, ry, count, failed)


@dataclass(frozen=True)
class TiltErrorSummary:
    """Errors of a set of normals against reference normals (deg).

    Attributes
    ----------
    n : frames compared.
    rmse_deg : RMSE of the tilt angles over both axes.
    rmse_x_deg, rmse_y_deg : per-axis RMSE.
    bias_x_deg, bias_y_deg : mean error per axis.
    mean_angle_deg, max_angle_deg : mean and largest angle between estimated and reference normals.
    """

    n: int
    rmse_deg: float
    rmse_x_deg: float
    rmse_y_deg: float
    bias_x_deg: float
    bias_y_deg: float
    mean_angle_deg: float
    max_angle_deg: float


def tilt_error_summary(estimated_normals: np.ndarray, reference_normals: np.ndarray) -> TiltErrorSummary:
    """Compare ``(n, 3)`` estimated normals with ``(n, 3)`` reference normals (both in J, unit, ``n_z > 0``).

    Raises
    ------
    InputError
        Shapes that are not ``(n, 3)`` and equal, or ``n == 0``.
    """
    est = np.asarray(estimated_normals, dtype=float)
    ref = np.asarray(reference_normals, dtype=float)
    if est.shape != ref.shape or est.ndim != 2 or est.shape[1] != 3:
        raise InputError(f"normals must be two (n, 3) arrays of one shape, got {est.shape} and {ref.shape}")
    if len(est) == 0:
        raise InputError("no normal to compare")
    ax, ay = (np.degrees(v) for v in tilt_angles(est))
    rx, ry = (np.degrees(v) for v in tilt_angles(ref))
    ex, ey = ax - rx, ay - ry
    unit_est = est / np.linalg.norm(est, axis=1, keepdims=True)
    unit_ref = ref / np.linalg.norm(ref, axis=1, keepdims=True)
    angle = np.degrees(angle_between(unit_est, unit_ref))
    return TiltErrorSummary(
        n=len(est),
        rmse_deg=rmse_deg(ex, ey),
        rmse_x_deg=float(np.sqrt(np.mean(ex**2))),
        rmse_y_deg=float(np.sqrt(np.mean(ey**2))),
        bias_x_deg=float(np.mean(ex)),
        bias_y_deg=float(np.mean(ey)),
        mean_angle_deg=float(np.mean(angle)),
        max_angle_deg=float(np.max(angle)),
    )
