"""The paper's figures, as PNG files: tilt angles over the sweep, the RMSE grid, the cube's normals.

Matplotlib is imported only here, with the Agg backend and without ``pyplot`` (no global state, no
window): each function draws one :class:`~matplotlib.figure.Figure` and writes it atomically. Angles are
in degrees, as in the paper's figures; colours follow the paper: red for ``Ax`` (the normal projected on
the YZ plane), green for ``Ay`` (on the XZ plane), opaque for the jig's estimate and translucent for the
commanded (robot) or true (motion capture) angle.
"""

from __future__ import annotations

import io
import os
from collections.abc import Sequence

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from softjig.calibration.sweep import SweepCalibration, SweepSamples
from softjig.calibration.tilt import TiltCalibration
from softjig.evaluation.metrics import RmseGrid, commanded_tilt_angles_deg
from softjig.evaluation.tilt_sweep import corrected_tilts_deg
from softjig.geometry import tilt_angles
from softjig.io.files import write_bytes_atomic

__all__ = ["normal_projection_figure", "rmse_grid_figure", "tilt_sweep_figure"]

RED, GREEN = "#d62728", "#2ca02c"


def _save(fig: Figure, path: str | os.PathLike[str], dpi: int = 110) -> None:
    FigureCanvasAgg(fig)
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=dpi)
    write_bytes_atomic(path, buffer.getvalue())


def tilt_sweep_figure(
    samples: SweepSamples,
    calibration: SweepCalibration | TiltCalibration | None,
    path: str | os.PathLike[str],
    *,
    title: str | None = None,
) -> None:
    """The paper's Figs. 12/13: measured and commanded ``Ax``, ``Ay`` over each sweep, one panel per
    (diameter, alpha) (rows diameters, columns tilts), ``theta`` on the horizontal axis.

    Parameters
    ----------
    samples : the sweep's frames with an estimate.
    calibration : applied to the measured angles (``None``: before calibration).
    path : the PNG to write.
    """
    diameters, alphas = samples.diameters(), samples.alphas()
    ax_deg, ay_deg = corrected_tilts_deg(samples, calibration)
    cmd_x, cmd_y = commanded_tilt_angles_deg(samples.alpha_deg, samples.theta_deg)
    d = np.round(samples.diameter_mm, 6)
    a = np.round(samples.alpha_deg, 6)
    every = np.abs(np.concatenate([ax_deg, ay_deg, cmd_x, cmd_y]))
    limit = max(float(every.max()) if every.size else 1.0, 1.0)
    fig = Figure(figsize=(2.6 * len(alphas) + 0.8, 1.7 * len(diameters) + 1.0), layout="constrained")
    axes = fig.subplots(len(diameters), len(alphas), squeeze=False, sharex=True, sharey=True)
    for i, dv in enumerate(diameters):
        for j, av in enumerate(alphas):
            panel = axes[i, j]
            sel = np.flatnonzero((d == dv) & (a == av))
            sel = sel[np.argsort(np.mod(samples.theta_deg[sel], 360.0))]
            theta = np.mod(samples.theta_deg[sel], 360.0)
            panel.plot(theta, cmd_x[sel], color=RED, alpha=0.3, lw=3)
            panel.plot(theta, cmd_y[sel], color=GREEN, alpha=0.3, lw=3)
            panel.plot(theta, ax_deg[sel], color=RED, lw=1, marker=".", ms=3)
            panel.plot(theta, ay_deg[sel], color=GREEN, lw=1, marker=".", ms=3)
            panel.set_ylim(-1.15 * limit, 1.15 * limit)
            panel.set_xticks([0, 90, 180, 270, 360])
            panel.grid(alpha=0.3)
            if i == 0:
                panel.set_title(f"alpha = {av:g} deg", fontsize=9)
            if j == 0:
                panel.set_ylabel(f"D = {dv:g} mm\nangle (deg)", fontsize=8)
            if i == len(diameters) - 1:
                panel.set_xlabel("theta (deg)", fontsize=8)
            panel.tick_params(labelsize=7)
    fig.suptitle(
        title
        or ("Tilt angles after calibration" if calibration is not None else "Tilt angles before calibration")
        + "  (opaque: jig Ax red, Ay green; translucent: commanded)",
        fontsize=10,
    )
    _save(fig, path)


def rmse_grid_figure(
    grids: Sequence[tuple[str, RmseGrid]], path: str | os.PathLike[str], *, title: str | None = None
) -> None:
    """The paper's Fig. 14: each RMSE grid as an annotated heat map (rows diameters, columns tilts).

    Parameters
    ----------
    grids : ``(panel title, grid)`` pairs, drawn side by side, each with its own colour scale.
    path : the PNG to write.
    """
    fig = Figure(figsize=(4.2 * len(grids) + 0.5, 4.4), layout="constrained")
    axes = fig.subplots(1, len(grids), squeeze=False)[0]
    for panel, (name, grid) in zip(axes, grids, strict=True):
        values = np.ma.masked_invalid(grid.rmse_deg)
        image = panel.imshow(values, cmap="viridis", aspect="auto")
        fig.colorbar(image, ax=panel, label="RMSE (deg)", shrink=0.9)
        finite = grid.rmse_deg[np.isfinite(grid.rmse_deg)]
        middle = float((finite.min() + finite.max()) / 2) if finite.size else 0.0
        for i in range(grid.rmse_deg.shape[0]):
            for j in range(grid.rmse_deg.shape[1]):
                v = grid.rmse_deg[i, j]
                text = "n/a" if not np.isfinite(v) else f"{v:.2f}"
                if grid.failed[i, j]:
                    text += f"\n({grid.failed[i, j]} failed)"
                panel.text(
                    j,
                    i,
                    text,
                    ha="center",
                    va="center",
                    fontsize=8,
                    color="black" if np.isfinite(v) and v > middle else "white",
                )
        panel.set_xticks(range(len(grid.alphas_deg)), [f"{a:g}" for a in grid.alphas_deg])
        panel.set_yticks(range(len(grid.diameters_mm)), [f"{d:g}" for d in grid.diameters_mm])
        panel.set_xlabel("tilt alpha (deg)")
        panel.set_ylabel("diameter D (mm)")
        panel.set_title(name, fontsize=10)
    if title:
        fig.suptitle(title, fontsize=11)
    _save(fig, path)


def normal_projection_figure(
    estimated: Sequence[tuple[str, np.ndarray]],
    truth_normals: np.ndarray,
    path: str | os.PathLike[str],
    *,
    title: str | None = None,
) -> None:
    """The paper's Fig. "angle-error": estimated and true normals projected on the YZ and XZ planes,
    i.e. their tilt angles ``Ax`` and ``Ay`` (deg), frame by frame.

    Parameters
    ----------
    estimated : ``(label, (n, 3) normals in J)`` pairs (e.g. uncalibrated and calibrated).
    truth_normals : (n, 3) the true (motion-capture) normals in J.
    path : the PNG to write.
    """
    truth = np.asarray(truth_normals, dtype=float)
    tx, ty = (np.degrees(v) for v in tilt_angles(truth))
    x = np.arange(len(truth))
    fig = Figure(figsize=(9.0, 5.5), layout="constrained")
    axes = fig.subplots(2, 1, sharex=True)
    styles = ["--", "-", ":", "-."]
    for panel, k, name, colour, ref in (
        (axes[0], 0, "Ax (YZ plane)", RED, tx),
        (axes[1], 1, "Ay (XZ plane)", GREEN, ty),
    ):
        panel.plot(x, ref, color="black", alpha=0.35, lw=4, label="motion capture (truth)")
        for m, (label, normals) in enumerate(estimated):
            angles = np.degrees(tilt_angles(np.asarray(normals, dtype=float))[k])
            panel.plot(
                x,
                angles,
                color=colour,
                ls=styles[m % len(styles)],
                lw=1.2,
                marker=".",
                ms=4,
                label=f"jig, {label}",
            )
        panel.set_ylabel(f"{name} (deg)")
        panel.grid(alpha=0.3)
        panel.legend(fontsize=8, loc="upper right")
    axes[1].set_xlabel("cube frame")
    fig.suptitle(
        title or "Cube: estimated vs motion-capture normal, projected on the YZ and XZ planes", fontsize=10
    )
    _save(fig, path)
