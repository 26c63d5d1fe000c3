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
from softjig.files import write_bytes_atomic
from softjig.geometry import tilt_angles

__all__ = [
    "methods_figure",
    "methods_plot",
    "normal_projection_figure",
    "rmse_grid_figure",
    "rmse_grid_plot",
    "save_png",
    "shared_colour_limits",
    "tilt_methods_figure",
    "tilt_sweep_figure",
]

RED, GREEN = "#d62728", "#2ca02c"
BAR_COLOURS = ["#7f7f7f", "#1f77b4", "#ff7f0e", "#9467bd", "#8c564b"]


def save_png(fig: Figure, path: str | os.PathLike[str], dpi: int = 110, *, durable: bool = True) -> None:
    """Render ``fig`` to PNG and write it atomically (:func:`softjig.files.write_bytes_atomic`; ``durable``:
    fsynced before it is renamed into place)."""
    FigureCanvasAgg(fig)
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=dpi)
    write_bytes_atomic(path, buffer.getvalue(), durable=durable)


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
    save_png(fig, path)


def shared_colour_limits(grids: Sequence[RmseGrid]) -> tuple[float, float]:
    """One colour scale for several RMSE grids (deg): from 0 to the largest finite cell of any of them,
    so a colour means the same error in every panel."""
    finite = [g.rmse_deg[np.isfinite(g.rmse_deg)] for g in grids]
    top = max((float(v.max()) for v in finite if v.size), default=1.0)
    return 0.0, max(top, 1e-6)


def _heat_maps(fig: Figure, axes: Sequence, grids: Sequence[tuple[str, RmseGrid]]) -> None:
    """Each grid as an annotated heat map on ``axes``, all on one colour scale with one colour bar."""
    vmin, vmax = shared_colour_limits([g for _, g in grids])
    middle = (vmin + vmax) / 2
    image = None
    for panel, (name, grid) in zip(axes, grids, strict=True):
        values = np.ma.masked_invalid(grid.rmse_deg)
        image = panel.imshow(values, cmap="viridis", aspect="auto", vmin=vmin, vmax=vmax)
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
    if image is not None:
        fig.colorbar(image, ax=list(axes), label="RMSE (deg), one scale for every panel", shrink=0.9)


def rmse_grid_plot(grids: Sequence[tuple[str, RmseGrid]], *, title: str | None = None) -> Figure:
    """The paper's Fig. 14 as a :class:`~matplotlib.figure.Figure`: each RMSE grid an annotated heat map
    (rows diameters, columns tilts), side by side on one colour scale (:func:`shared_colour_limits`)."""
    fig = Figure(figsize=(3.9 * len(grids) + 1.3, 4.4), layout="constrained")
    axes = fig.subplots(1, len(grids), squeeze=False)[0]
    _heat_maps(fig, axes, grids)
    if title:
        fig.suptitle(title, fontsize=11)
    return fig


def rmse_grid_figure(
    grids: Sequence[tuple[str, RmseGrid]], path: str | os.PathLike[str], *, title: str | None = None
) -> None:
    """Write :func:`rmse_grid_plot` as a PNG.

    Parameters
    ----------
    grids : ``(panel title, grid)`` pairs, drawn side by side on one colour scale.
    path : the PNG to write.
    """
    save_png(rmse_grid_plot(grids, title=title), path)


def methods_plot(
    grids: Sequence[tuple[str, RmseGrid]],
    cube: Sequence[tuple[str, float]] = (),
    *,
    title: str | None = None,
) -> Figure:
    """The methods at a glance: their RMSE grids side by side on one colour scale (one colour bar), and,
    if given, their RMSE against motion capture on the cube as bars (deg).

    Parameters
    ----------
    grids : ``(method, grid)`` pairs, e.g. the paper's calibrated, ours uncalibrated, ours calibrated.
    cube : ``(method, RMSE in deg)`` pairs of the cube experiment (NaN: no estimate).
    """
    n = len(grids) + (1 if cube else 0)
    fig = Figure(figsize=(3.6 * n + 1.3, 4.4), layout="constrained")
    widths = [1.0] * len(grids) + ([0.8] if cube else [])
    axes = fig.subplots(1, n, squeeze=False, gridspec_kw={"width_ratios": widths})[0]
    _heat_maps(fig, axes[: len(grids)], grids)
    if cube:
        panel = axes[-1]
        labels = [name for name, _ in cube]
        values = [v if np.isfinite(v) else 0.0 for _, v in cube]
        bars = panel.bar(range(len(cube)), values, color=BAR_COLOURS[: len(cube)])
        for bar, (_, v) in zip(bars, cube, strict=True):
            panel.text(
                bar.get_x() + bar.get_width() / 2,
                bar.get_height(),
                "n/a" if not np.isfinite(v) else f"{v:.2f}",
                ha="center",
                va="bottom",
                fontsize=8,
            )
        panel.set_xticks(range(len(cube)), labels, rotation=30, ha="right", fontsize=8)
        panel.set_ylabel("RMSE against motion capture (deg)")
        panel.set_title("cube experiment", fontsize=10)
        panel.grid(axis="y", alpha=0.3)
    if title:
        fig.suptitle(title, fontsize=11)
    return fig


def methods_figure(
    grids: Sequence[tuple[str, RmseGrid]],
    path: str | os.PathLike[str],
    cube: Sequence[tuple[str, float]] = (),
    *,
    title: str | None = None,
) -> None:
    """Write :func:`methods_plot` as a PNG."""
    save_png(methods_plot(grids, cube, title=title), path)


def tilt_methods_figure(
    series: Sequence[tuple[str, SweepSamples, SweepCalibration | TiltCalibration | None]],
    path: str | os.PathLike[str],
    *,
    title: str | None = None,
) -> None:
    """Tilt angles over the sweep of several methods overlaid, one panel per (diameter, alpha): the
    commanded ``Ax`` (red) and ``Ay`` (green) translucent and thick, each method's in its own line style
    (legend), ``theta`` on the horizontal axis.

    Parameters
    ----------
    series : ``(label, samples, calibration)`` per method (``calibration`` applied, ``None``: raw).
    path : the PNG to write.
    """
    first = series[0][1]
    diameters, alphas = first.diameters(), first.alphas()
    styles = ["--", "-", ":", "-."]
    fig = Figure(figsize=(2.9 * len(alphas) + 0.8, 1.9 * len(diameters) + 1.4), layout="constrained")
    axes = fig.subplots(len(diameters), len(alphas), squeeze=False, sharex=True, sharey=True)
    limit = 1.0
    for m, (_label, samples, calibration) in enumerate(series):
        ax_deg, ay_deg = corrected_tilts_deg(samples, calibration)
        cmd_x, cmd_y = commanded_tilt_angles_deg(samples.alpha_deg, samples.theta_deg)
        every = np.abs(np.concatenate([ax_deg, ay_deg, cmd_x, cmd_y]))
        limit = max(limit, float(every.max()) if every.size else 1.0)
        d, a = np.round(samples.diameter_mm, 6), np.round(samples.alpha_deg, 6)
        for i, dv in enumerate(diameters):
            for j, av in enumerate(alphas):
                panel = axes[i, j]
                sel = np.flatnonzero((d == dv) & (a == av))
                sel = sel[np.argsort(np.mod(samples.theta_deg[sel], 360.0))]
                theta = np.mod(samples.theta_deg[sel], 360.0)
                if m == 0:
                    panel.plot(theta, cmd_x[sel], color=RED, alpha=0.25, lw=4)
                    panel.plot(theta, cmd_y[sel], color=GREEN, alpha=0.25, lw=4)
                style = styles[m % len(styles)]
                panel.plot(theta, ax_deg[sel], color=RED, ls=style, lw=1, marker=".", ms=2)
                panel.plot(theta, ay_deg[sel], color=GREEN, ls=style, lw=1, marker=".", ms=2)
                if m == 0:
                    panel.set_xticks([0, 90, 180, 270, 360])
                    panel.grid(alpha=0.3)
                    panel.tick_params(labelsize=7)
                    if i == 0:
                        panel.set_title(f"alpha = {av:g} deg", fontsize=9)
                    if j == 0:
                        panel.set_ylabel(f"D = {dv:g} mm\nangle (deg)", fontsize=8)
                    if i == len(diameters) - 1:
                        panel.set_xlabel("theta (deg)", fontsize=8)
    for panel in axes.flat:
        panel.set_ylim(-1.15 * limit, 1.15 * limit)
    from matplotlib.lines import Line2D

    handles = [
        Line2D([], [], color=RED, alpha=0.25, lw=4, label="commanded Ax"),
        Line2D([], [], color=GREEN, alpha=0.25, lw=4, label="commanded Ay"),
    ] + [
        Line2D([], [], color="black", ls=styles[m % len(styles)], lw=1, label=f"{label} (Ax red, Ay green)")
        for m, (label, _, _) in enumerate(series)
    ]
    fig.legend(handles=handles, loc="outside lower center", ncol=2, fontsize=8)
    fig.suptitle(title or "Tilt angles over the sweep, the methods overlaid", fontsize=10)
    save_png(fig, path)


def normal_projection_figure(
    estimated: Sequence[tuple[str, np.ndarray]],
    truth_normals: np.ndarray,
    path: str | os.PathLike[str],
    *,
    index: np.ndarray | None = None,
    title: str | None = None,
) -> None:
    """The paper's Fig. "angle-error": estimated and true normals projected on the YZ and XZ planes,
    i.e. their tilt angles ``Ax`` and ``Ay`` (deg), frame by frame.

    Parameters
    ----------
    estimated : ``(label, (n, 3) normals in J)`` pairs (e.g. uncalibrated and calibrated).
    truth_normals : (n, 3) the true (motion-capture) normals in J.
    path : the PNG to write.
    index : (n,) the frames' numbers on the horizontal axis (default ``0 .. n-1``).
    """
    truth = np.asarray(truth_normals, dtype=float)
    tx, ty = (np.degrees(v) for v in tilt_angles(truth))
    x = np.arange(len(truth)) if index is None else np.asarray(index)
    fig = Figure(figsize=(9.0, 5.5), layout="constrained")
    axes = fig.subplots(2, 1, sharex=True)
    styles = ["--", "-", ":", "-."]
    colours = {"Ax": [RED, "#8c1a1a", "#ff9896", "#e377c2"], "Ay": [GREEN, "#1a5e1a", "#98df8a", "#bcbd22"]}
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
                color=colours[name[:2]][m % 4] if len(estimated) > 2 else colour,
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
    save_png(fig, path)
