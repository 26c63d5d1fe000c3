"""A study's figures, as PNG files: accuracy against each varied parameter, the best designs' per-cell RMSE,
and the Pareto fronts of accuracy against cost.

Matplotlib with the Agg canvas and without ``pyplot`` (no global state, no window), as
:mod:`softjig.evaluation.figures`; each ``*_plot`` function draws one :class:`~matplotlib.figure.Figure`
from plain arrays (no tables, no files) and :func:`save_png` writes it atomically. Angles in degrees.
Methods keep one colour in every figure (:func:`method_colour`).
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from matplotlib.figure import Figure

from softjig.evaluation import figures as evaluation_figures
from softjig.evaluation.figures import rmse_grid_plot
from softjig.evaluation.metrics import RmseGrid

__all__ = [
    "DesignPoints",
    "accuracy_plot",
    "best_cells_plot",
    "method_colour",
    "pareto_plot",
    "save_png",
]

METHOD_COLOURS = {"refractive": "#1f77b4", "paper": "#ff7f0e"}
OTHER_COLOURS = ("#2ca02c", "#9467bd", "#8c564b", "#e377c2")
PANEL_IN = 3.6  # width of one panel (inches)
FIGURE_DPI = 110
#: Spread of the points of one category across the methods (fraction of the gap between categories).
CATEGORY_SPREAD = 0.3
MAX_LABELLED_FRONT = 25  # a front longer than this is drawn without design ids (they would overlap)


def method_colour(method: str, methods: Sequence[str]) -> str:
    """The colour of ``method`` in every figure of a study (``methods``: the study's, in order)."""
    if method in METHOD_COLOURS:
        return METHOD_COLOURS[method]
    others = [m for m in methods if m not in METHOD_COLOURS]
    return OTHER_COLOURS[others.index(method) % len(OTHER_COLOURS)] if method in others else "#7f7f7f"


def save_png(fig: Figure, path: str | os.PathLike[str], dpi: int = FIGURE_DPI) -> None:
    """Render ``fig`` to PNG and write it atomically, not fsynced (figures are derived: a study's report
    writes them again), through :func:`softjig.evaluation.figures.save_png`."""
    evaluation_figures.save_png(fig, path, dpi, durable=False)


@dataclass(frozen=True)
class DesignPoints:
    """One row per (design, method), as arrays: what the figures draw.

    Attributes
    ----------
    design_id : (N,) int.
    method : (N,) str.
    rmse_deg : (N,) RMSE of the design's estimates (deg); NaN for a design with none.
    values : per varied path, its (N,) values (float, or str for a categorical path), in file order.
    """

    design_id: np.ndarray
    method: np.ndarray
    rmse_deg: np.ndarray
    values: tuple[tuple[str, np.ndarray], ...]

    @property
    def methods(self) -> list[str]:
        """The methods, in order of first appearance."""
        return list(dict.fromkeys(self.method.tolist()))


def _positions(values: np.ndarray) -> tuple[np.ndarray, list[str] | None]:
    """x positions of a parameter's values: the numbers themselves, or category indices and labels."""
    if values.dtype.kind in "fiu":
        return values.astype(float), None
    labels = list(dict.fromkeys(str(v) for v in values))
    return np.array([labels.index(str(v)) for v in values], dtype=float), labels


def _accuracy_panel(ax, points: DesignPoints, path: str, values: np.ndarray) -> None:
    x, labels = _positions(values)
    methods = points.methods
    for k, method in enumerate(methods):
        mine = (points.method == method) & np.isfinite(points.rmse_deg)
        colour = method_colour(method, methods)
        shift = 0.0
        if labels is not None and len(methods) > 1:
            shift = CATEGORY_SPREAD * (k / (len(methods) - 1) - 0.5)
        ax.scatter(x[mine] + shift, points.rmse_deg[mine], s=14, alpha=0.4, color=colour, linewidths=0)
        xs = np.unique(x[mine])
        best = [np.min(points.rmse_deg[mine & (x == v)]) for v in xs]
        ax.plot(xs + shift, best, "-o", color=colour, markersize=4, label=f"{method} (best per value)")
    if labels is not None:
        ax.set_xticks(range(len(labels)), labels, rotation=20 if len(labels) > 3 else 0)
    ax.set_xlabel(path)
    ax.set_ylabel("RMSE (deg)")
    ax.set_ylim(bottom=0)
    ax.grid(alpha=0.3)


def accuracy_plot(points: DesignPoints, *, title: str | None = None) -> Figure:
    """RMSE of every design against each varied parameter: one panel per parameter (numbers on their
    own axis, strings as categories), each design a dot, the best design at each value joined by a line,
    one colour per method. Designs with no estimate (NaN RMSE) are left out and counted in the title."""
    n = max(len(points.values), 1)
    fig = Figure(figsize=(PANEL_IN * n + 0.6, 3.6), layout="constrained")
    axes = fig.subplots(1, n, squeeze=False)[0]
    for ax, (path, values) in zip(axes, points.values, strict=False):
        _accuracy_panel(ax, points, path, values)
    if points.values:
        axes[0].legend(fontsize=8)
    missing = int(np.count_nonzero(~np.isfinite(points.rmse_deg)))
    text = title or "accuracy of each design against each varied parameter"
    if missing:
        text += f" ({missing} design-method rows with no estimate not shown)"
    fig.suptitle(text, fontsize=10)
    return fig


def best_cells_plot(grids: Sequence[tuple[str, RmseGrid]], *, title: str | None = None) -> Figure:
    """The per-cell RMSE (rows part diameters, columns tilts) of the best design of each method, on one
    colour scale (:func:`softjig.evaluation.figures.rmse_grid_plot`, the paper's Fig. 14 layout)."""
    return rmse_grid_plot(grids, title=title)


def _front_line(ax, cost: np.ndarray, rmse: np.ndarray, colour: str) -> None:
    order = np.lexsort((rmse, cost))
    ax.step(cost[order], rmse[order], where="post", color=colour, alpha=0.8, linewidth=1.2)


def pareto_plot(
    points: DesignPoints, cost: np.ndarray, front: np.ndarray, *, cost_label: str, title: str | None = None
) -> Figure:
    """RMSE against a cost of every design, one colour per method, the Pareto front of each method ringed
    in black, joined by a staircase and labelled with its design ids.

    Parameters
    ----------
    points : the designs.
    cost : (N,) the cost of each row of ``points`` (e.g. its marker count).
    front : (N,) whether each row is on its method's front (:func:`softjig.study.pareto.pareto_front`).
    cost_label : the cost axis' label, with its unit.
    """
    fig = Figure(figsize=(6.4, 4.4), layout="constrained")
    ax = fig.subplots()
    methods = points.methods
    for method in methods:
        mine = (points.method == method) & np.isfinite(points.rmse_deg) & np.isfinite(cost)
        on = mine & front
        colour = method_colour(method, methods)
        ax.scatter(cost[mine], points.rmse_deg[mine], s=16, alpha=0.45, color=colour, linewidths=0)
        ax.scatter(
            cost[on], points.rmse_deg[on], s=42, color=colour, edgecolors="black", label=f"{method}: front"
        )
        _front_line(ax, cost[on], points.rmse_deg[on], colour)
        if np.count_nonzero(on) <= MAX_LABELLED_FRONT:
            for c, r, d in zip(cost[on], points.rmse_deg[on], points.design_id[on], strict=True):
                ax.annotate(f"{d:03d}", (c, r), textcoords="offset points", xytext=(4, 4), fontsize=7)
    ax.set_xlabel(cost_label)
    ax.set_ylabel("RMSE (deg)")
    ax.set_ylim(bottom=0)
    ax.grid(alpha=0.3)
    if methods:
        ax.legend(fontsize=8)
    fig.suptitle(title or f"Pareto front: accuracy against {cost_label}", fontsize=10)
    return fig
