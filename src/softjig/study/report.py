"""A study's report: the ranking table for the terminal, ``DIR/report.html``, the figures under
``DIR/figures/`` and the Pareto front designs' rigs under ``DIR/best/``.

It reads only the two tables of the study contract (``results.parquet``: one row per estimate;
``designs.parquet``: one row per design and method; ``/work/wt/study-contract.md``, DESIGN.md §1) and the
study's spec (its name, its varied paths in file order, its methods). Contract, as used here: every
column of ``designs.parquet`` the contract lists is required (:data:`DESIGN_COLUMNS`; a missing one is an
:class:`~softjig.errors.InputError` naming it); the ``cells`` JSON's ``n`` is the estimates of a cell that
exist, and the failed attempts of a cell come from ``results.parquet`` (``quality == "failed"``). Two
keyword arguments extend :func:`write_study_outputs` compatibly: ``config_for`` (a design id's full
jig; by default :func:`softjig.study.spec.design_jig` of the design's values in the study's product) and
``costs`` (the cost axes of the Pareto fronts, :func:`cost_columns` by default).

The cost of a design, for the Pareto fronts: accuracy is the design's RMSE (deg, minimised) and the cost
is, by default, its marker count (``marker_count``: markers to make and to track, a larger membrane
pattern) and, when the study varies them, the camera distance (``cameras.distance_mm``: a taller jig)
and the camera baseline (``cameras.baseline_mm``: a wider one), each minimised on its own front. A
front is taken per method; every design on some front has its rig written to ``DIR/best/NNN.toml``.
"""

from __future__ import annotations

import base64
import datetime as _dt
import html
import json
import math
import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
from rich import box
from rich.table import Table

from softjig.config import JigConfig
from softjig.errors import InputError
from softjig.evaluation.metrics import RmseGrid
from softjig.files import write_text_atomic
from softjig.study.best import best_rig_name, write_best_rigs
from softjig.study.figures import DesignPoints, accuracy_plot, best_cells_plot, pareto_plot, save_png
from softjig.study.pareto import pareto_front
from softjig.study.results import frame_cells

if TYPE_CHECKING:
    from softjig.study.spec import StudySpec

__all__ = [
    "COST_LIKE_PATHS",
    "DESIGN_COLUMNS",
    "StudyOutputs",
    "cost_columns",
    "ranked_designs",
    "summary_table",
    "write_study_outputs",
]

#: The columns of ``designs.parquet`` besides the varied paths (the study contract).
DESIGN_COLUMNS = (
    "design_id",
    "method",
    "n_estimates",
    "rmse_deg",
    "cells",
    "worst_cell",
    "worst_cell_rmse_deg",
    "recall",
    "suspect_fraction",
    "silent",
    "median_markers_under_part",
    "latency_ms_median",
    "marker_count",
)
MARKER_COUNT = "marker_count"
#: Varied paths that are a cost when the study varies them (see the module docstring).
COST_LIKE_PATHS = ("cameras.distance_mm", "cameras.baseline_mm")
COST_LABELS = {
    MARKER_COUNT: "markers on the membrane",
    "cameras.distance_mm": "camera distance to the plate, cameras.distance_mm (mm)",
    "cameras.baseline_mm": "camera baseline, cameras.baseline_mm (mm)",
}
SUMMARY_ROWS = 20  # designs shown in the terminal's table
REPORT_ROWS = 50  # designs shown in report.html's ranking
FIGURES = "figures"
BEST = "best"
_RIG_LINK = re.compile(rf"{BEST}/\d{{3,}}\.toml")


@dataclass(frozen=True)
class StudyOutputs:
    """What :func:`write_study_outputs` wrote.

    Attributes
    ----------
    report_html : ``DIR/report.html``.
    figures : the PNGs under ``DIR/figures/``.
    best_rigs : the front designs' rigs, ``DIR/best/NNN.toml``, in ascending design id.
    front_design_ids : the designs on at least one Pareto front, ascending.
    """

    report_html: Path
    figures: tuple[Path, ...]
    best_rigs: tuple[Path, ...]
    front_design_ids: tuple[int, ...]


# ------------------------------------------------------------------------------------------ the table


def _varied(designs: pa.Table, paths: Sequence[str] | None) -> tuple[str, ...]:
    """The varied paths: the spec's, or the columns of ``designs`` that are not the contract's."""
    missing = [c for c in DESIGN_COLUMNS if c not in designs.column_names]
    if missing:
        raise InputError(
            f"designs table lacks the column(s) {', '.join(missing)}: it was not written by this version of "
            "softjig study; run the study again into a new --out folder"
        )
    if paths is None:
        return tuple(c for c in designs.column_names if c not in DESIGN_COLUMNS)
    absent = [p for p in paths if p not in designs.column_names]
    if absent:
        raise InputError(f"designs table lacks the varied path column(s) {', '.join(absent)}")
    return tuple(paths)


def _rank_key(row: dict[str, Any]) -> tuple[float, int, str]:
    rmse = row["rmse_deg"]
    return (rmse if rmse is not None and math.isfinite(rmse) else math.inf, row["design_id"], row["method"])


def ranked_designs(designs: pa.Table) -> list[dict[str, Any]]:
    """The rows of ``designs`` as dicts, best (smallest RMSE) first; designs with no RMSE last, then by
    design id and method."""
    return sorted(designs.to_pylist(), key=_rank_key)


def _num(value: Any, digits: int = 2) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "n/a"
    return f"{value:.{digits}f}"


def _value(value: Any) -> str:
    return f"{value:g}" if isinstance(value, float) else str(value)


SUMMARY_HEADER = (
    "rank",
    "design",
    "method",
    "RMSE (deg)",
    "worst cell (deg)",
    "recall",
    "suspect",
    "silent",
    "latency (ms)",
    "markers",
)


def _summary_row(rank: int, row: dict[str, Any], paths: Sequence[str]) -> list[str]:
    worst = f"{row['worst_cell']} {_num(row['worst_cell_rmse_deg'])}" if row["worst_cell"] else "n/a"
    return [
        str(rank),
        f"{row['design_id']:03d}",
        row["method"],
        *(_value(row[p]) for p in paths),
        _num(row["rmse_deg"]),
        worst,
        _num(row["recall"]),
        _num(row["suspect_fraction"]),
        str(row["silent"]),
        _num(row["latency_ms_median"], 1),
        str(row["marker_count"]),
    ]


def _narrow(name: str) -> str:
    """A header in lines, for narrow terminals: a path broken after its last dot, a unit on its own line."""
    head, dot, tail = name.rpartition(".")
    return (f"{head}{dot}\n{tail}" if dot and " " not in name else name).replace(" (", "\n(")


def _header(paths: Sequence[str]) -> list[str]:
    return [*SUMMARY_HEADER[:3], *paths, *SUMMARY_HEADER[3:]]


def summary_table(
    designs: pa.Table, *, paths: Sequence[str] | None = None, rows: int | None = SUMMARY_ROWS
) -> Table:
    """The designs ranked by RMSE, for the terminal: each with its varied values, worst cell, recall,
    suspect fraction, silent failures (red when any), median estimate latency and marker count.

    Parameters
    ----------
    designs : ``designs.parquet``'s table (the study contract).
    paths : the varied paths in file order (default: the columns that are not the contract's).
    rows : the best ``rows`` designs are shown (``None``: all); the caption says how many are not.
    """
    paths = _varied(designs, paths)
    ranked = ranked_designs(designs)
    shown = ranked if rows is None else ranked[:rows]
    table = Table(
        title="designs by RMSE (deg), best first",
        title_justify="left",
        box=box.SIMPLE_HEAD,
        show_edge=False,
        collapse_padding=True,
    )
    cells = [_summary_row(rank, row, paths) for rank, row in enumerate(shown, start=1)]
    for k, name in enumerate(_header(paths)):
        column = [c[k] for c in cells]
        # a narrow terminal shrinks the text columns and the headers, never a number
        numeric = all(_is_number_text(v) for v in column)
        width = max(map(len, column), default=0) if numeric else None
        table.add_column(_narrow(name), justify="right" if numeric else "left", min_width=width)
    for row, texts in zip(shown, cells, strict=True):
        table.add_row(*texts, style="red" if row["silent"] else None)
    if len(shown) < len(ranked):
        table.caption = f"{len(ranked) - len(shown)} more rows in designs.parquet"
    return table


# ---------------------------------------------------------------------------------------- the fronts


def cost_columns(designs: pa.Table, paths: Sequence[str]) -> tuple[str, ...]:
    """The default cost axes of the Pareto fronts: ``marker_count``, then each of :data:`COST_LIKE_PATHS`
    the study varies with numbers (see the module docstring)."""
    numeric = [
        p for p in paths if p in COST_LIKE_PATHS and pa.types.is_floating(designs.schema.field(p).type)
    ]
    return (MARKER_COUNT, *numeric)


def _points(designs: pa.Table, paths: Sequence[str]) -> DesignPoints:
    values = []
    for p in paths:
        column = designs.column(p)
        kind = float if pa.types.is_floating(column.type) or pa.types.is_integer(column.type) else str
        values.append((p, np.array(column.to_pylist(), dtype=kind)))
    rmse = np.array([math.nan if v is None else v for v in designs.column("rmse_deg").to_pylist()])
    return DesignPoints(
        design_id=np.array(designs.column("design_id").to_pylist(), dtype=np.int64),
        method=np.array(designs.column("method").to_pylist(), dtype=str),
        rmse_deg=rmse.astype(float),
        values=tuple(values),
    )


def _fronts(points: DesignPoints, cost: np.ndarray) -> np.ndarray:
    """Per row, whether it is on its own method's front of (cost, RMSE)."""
    front = np.zeros(len(cost), dtype=bool)
    for method in points.methods:
        mine = np.flatnonzero(points.method == method)
        front[mine] = pareto_front(cost[mine], points.rmse_deg[mine])
    return front


def _cost(designs: pa.Table, column: str) -> np.ndarray:
    if column not in designs.column_names:
        raise InputError(f"no cost column {column!r} in the designs table; it has {designs.column_names}")
    values = designs.column(column)
    if not (pa.types.is_floating(values.type) or pa.types.is_integer(values.type)):
        raise InputError(f"cost column {column!r} holds {values.type}, not numbers")
    return np.array([math.nan if v is None else v for v in values.to_pylist()], dtype=float)


# ------------------------------------------------------------------------------- the best design's cells


def _failed_cells(
    spec: StudySpec, results: pa.Table, design_id: int, method: str
) -> list[tuple[float, float]]:
    """The (diameter, alpha) cell of each failed attempt of one design and method (as in ``cells``)."""
    mask = pc.and_(
        pc.and_(pc.equal(results.column("design_id"), design_id), pc.equal(results.column("method"), method)),
        pc.equal(results.column("quality"), "failed"),
    )
    failed = results.filter(mask)
    d, a = frame_cells(spec, failed.column("diameter_mm").to_numpy(), failed.column("alpha_deg").to_numpy())
    return list(zip(d.tolist(), a.tolist(), strict=True))


def cell_grid(cells_json: str, failed: Sequence[tuple[float, float]] = ()) -> RmseGrid:
    """A design's per-cell RMSE as an :class:`~softjig.evaluation.metrics.RmseGrid` (rows diameters,
    columns tilts) from ``designs.parquet``'s ``cells`` JSON and the ``(diameter_mm, alpha_deg)`` of each
    failed attempt; the per-axis RMSE are not in the study's tables and are NaN.

    Raises
    ------
    InputError
        ``cells`` is not the contract's JSON list.
    """
    try:
        cells = json.loads(cells_json or "[]")
        entries = [
            (float(c["diameter_mm"]), float(c["alpha_deg"]), c["rmse_deg"], int(c["n"])) for c in cells
        ]
    except (ValueError, TypeError, KeyError) as exc:
        raise InputError(f"designs table: a cells entry is not a JSON list of cells ({exc})") from None
    diameters = sorted({e[0] for e in entries} | {float(d) for d, _ in failed})
    alphas = sorted({e[1] for e in entries} | {float(a) for _, a in failed})
    shape = (len(diameters), len(alphas))
    rmse, count, n_failed = np.full(shape, math.nan), np.zeros(shape, int), np.zeros(shape, int)
    for d, a, value, n in entries:
        i, j = diameters.index(d), alphas.index(a)
        rmse[i, j] = math.nan if value is None else float(value)
        count[i, j] = n
    for d, a in failed:
        n_failed[diameters.index(float(d)), alphas.index(float(a))] += 1
    return RmseGrid(
        diameters_mm=np.array(diameters),
        alphas_deg=np.array(alphas),
        rmse_deg=rmse,
        rmse_x_deg=np.full(shape, math.nan),
        rmse_y_deg=np.full(shape, math.nan),
        count=count,
        failed=n_failed,
    )


def _best_per_method(ranked: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """The best row of each method that has an RMSE (ranked order: the first of each)."""
    best: dict[str, dict[str, Any]] = {}
    for row in ranked:
        if row["method"] not in best and math.isfinite(_rank_key(row)[0]):
            best[row["method"]] = row
    return list(best.values())


# ------------------------------------------------------------------------------------------ the page

_CSS = """
body { font-family: system-ui, -apple-system, "Segoe UI", Helvetica, Arial, sans-serif; max-width: 1150px;
       margin: 2em auto; padding: 0 1em; color: #222; line-height: 1.45; }
h1 { border-bottom: 2px solid #ddd; padding-bottom: .2em; }
h2 { border-bottom: 1px solid #eee; padding-bottom: .15em; margin-top: 1.6em; }
table { border-collapse: collapse; margin: .6em 0 1em; font-size: 0.9em; }
th, td { border: 1px solid #ccc; padding: .2em .5em; text-align: right; white-space: nowrap; }
th { background: #f3f3f3; } td.text { text-align: left; } tr.silent td { background: #fde8e8; }
img { max-width: 100%; border: 1px solid #ddd; margin: .4em 0 1em; }
code { background: #f4f4f4; padding: 0 .2em; border-radius: 3px; }
"""


def _p(text: str) -> str:
    return f"<p>{html.escape(text)}</p>"


def _html_table(header: Sequence[str], rows: Sequence[Sequence[str]], classes: Sequence[str] = ()) -> str:
    """An HTML table, every cell escaped; ``classes``: per row, a CSS class (or "")."""
    head = "".join(f"<th>{html.escape(h)}</th>" for h in header)
    body = []
    for k, row in enumerate(rows):
        cls = f' class="{classes[k]}"' if k < len(classes) and classes[k] else ""
        cells = "".join(
            f'<td class="{"text" if not _is_number_text(v) else "num"}">{_cell_html(v)}</td>' for v in row
        )
        body.append(f"<tr{cls}>{cells}</tr>")
    return f"<table><thead><tr>{head}</tr></thead><tbody>{''.join(body)}</tbody></table>"


def _cell_html(text: str) -> str:
    """A cell's text, escaped; a rig's path (``best/NNN.toml``) as a relative link to the file."""
    if _RIG_LINK.fullmatch(text):
        return f'<a href="{html.escape(text, quote=True)}">{html.escape(text)}</a>'
    return html.escape(text)


def _is_number_text(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return text == "n/a"
    return True


def _img(path: Path, caption: str) -> str:
    data = base64.b64encode(path.read_bytes()).decode("ascii")
    alt = html.escape(caption, quote=True)
    return (
        f'<figure><img alt="{alt}" src="data:image/png;base64,{data}">'
        f"<figcaption>{html.escape(caption)}</figcaption></figure>"
    )


def _page(title: str, body: Sequence[str]) -> str:
    """A self-contained page: styles inline, no script, nothing fetched."""
    return (
        '<!DOCTYPE html>\n<html lang="en">\n<head>\n<meta charset="utf-8">\n'
        f"<title>{html.escape(title)}</title>\n<style>{_CSS}</style>\n</head>\n<body>\n"
        + "\n".join(body)
        + "\n</body>\n</html>\n"
    )


# --------------------------------------------------------------------------------------- the outputs


@dataclass(frozen=True)
class _Front:
    """One Pareto front: of RMSE against ``column``, per method (``on``: per designs row)."""

    column: str
    label: str
    cost: np.ndarray
    on: np.ndarray


def _slug(name: str) -> str:
    return "".join(c if c.isalnum() or c in "._-" else "_" for c in name)


def _spec_config_for(spec: StudySpec) -> Callable[[int], JigConfig]:
    """A design id's jig from the study's spec: its values in the product of ``[vary]`` (row-major, the
    last path fastest), through :func:`softjig.study.spec.design_jig`."""
    from softjig.study.spec import design_jig

    lists = [values for _, values in spec.vary]

    def config_for(design_id: int) -> JigConfig:
        index = np.unravel_index(design_id, [len(v) for v in lists]) if lists else ()
        return design_jig(spec, [values[int(i)] for values, i in zip(lists, index, strict=True)])

    return config_for


def _write_figures(
    folder: Path,
    spec: StudySpec,
    points: DesignPoints,
    ranked: list[dict[str, Any]],
    results: pa.Table,
    fronts: list[_Front],
) -> list[tuple[Path, str]]:
    """Every figure of the report, written under ``folder``: ``(path, caption)`` in report order."""
    out: list[tuple[Path, str]] = []
    if not np.isfinite(points.rmse_deg).any():
        return out  # no design has an estimate: nothing to draw
    if points.values:
        path = folder / "accuracy.png"
        save_png(accuracy_plot(points), path)
        out.append((path, "RMSE of each design against each varied parameter"))
    best = _best_per_method(ranked)
    if best:
        grids = [
            (
                f"design {r['design_id']:03d}, {r['method']}",
                cell_grid(r["cells"], _failed_cells(spec, results, r["design_id"], r["method"])),
            )
            for r in best
        ]
        if any(g.rmse_deg.size for _, g in grids):
            path = folder / "best-cells.png"
            save_png(best_cells_plot(grids, title="RMSE per part diameter and tilt, best design"), path)
            out.append((path, "per-cell RMSE (deg) of the best design of each method"))
    for f in fronts:
        path = folder / f"pareto-{_slug(f.column)}.png"
        save_png(pareto_plot(points, f.cost, f.on, cost_label=f.label), path)
        out.append((path, f"Pareto front of RMSE against {f.label}, per method"))
    return out


def _note(design_id: int, rows: list[dict[str, Any]], paths: Sequence[str], methods: Sequence[str]) -> str:
    """The comment lines at the top of a front design's rig (its methods in the study's order)."""
    order = {m: k for k, m in enumerate(methods)}
    mine = sorted((r for r in rows if r["design_id"] == design_id), key=lambda r: order.get(r["method"], -1))
    lines = [f"design {design_id:03d}: " + "; ".join(f"{p} = {_value(mine[0][p])}" for p in paths)]
    for r in mine:
        lines.append(
            f"{r['method']}: RMSE {_num(r['rmse_deg'])} deg (worst cell {r['worst_cell'] or 'n/a'} "
            f"{_num(r['worst_cell_rmse_deg'])} deg), recall {_num(r['recall'])}, "
            f"{r['marker_count']} markers"
        )
    return "\n".join(lines)


def _simulate_command(spec: StudySpec, design_id: int) -> str:
    """The command that renders a design's study frames again (its first seed), from ``DIR``."""
    f = spec.frames
    if f.zoo is not None:  # random frames only the study draws: the rig on the paper sweep
        return (
            f"softjig simulate --scenario paper-sweep --config best/{best_rig_name(design_id)} "
            f"--seed {spec.seeds[0]}"
        )
    if f.poses:  # the first pose (softjig simulate renders one explicit pose at a time)
        p = f.poses[0]
        return (
            f"softjig simulate --scenario single --config best/{best_rig_name(design_id)} "
            f"--part-diameter {p.diameter_mm:g} --alpha {p.alpha_deg:g} --theta {p.theta_deg:g} "
            f"--push-depth {p.push_depth_mm:g} --seed {spec.seeds[0]}"
        )
    return (
        f"softjig simulate --scenario paper-sweep --config best/{best_rig_name(design_id)} "
        f"--diameters {','.join(f'{d:g}' for d in f.diameters_mm)} "
        f"--alphas {','.join(f'{a:g}' for a in f.alphas_deg)} --theta-step {f.theta_step_deg:g} "
        f"--push-depth {f.push_depth_mm:g} --seed {spec.seeds[0]}"
    )


def _make_fronts(designs: pa.Table, points: DesignPoints, costs: Sequence[str]) -> list[_Front]:
    out = []
    for column in costs:
        cost = _cost(designs, column)
        out.append(_Front(column, COST_LABELS.get(column, column), cost, _fronts(points, cost)))
    return out


def _frames_note(spec: StudySpec) -> str:
    """What :func:`_simulate_command` renders again."""
    if spec.frames.zoo is not None:
        return "the paper sweep on it (its study's random zoo frames are drawn by softjig study itself)"
    if spec.frames.poses:
        return "its study's first pose (the others: their own --part-diameter, --alpha, --theta)"
    return "its study frames"


def _frames_text(f: Any) -> str:
    """What the study's frames are, in words."""
    if f.zoo is not None:
        r = f.zoo.ranges()
        return (
            f"{f.zoo.count} random parts and poses per seed, the same for every design "
            f"({', '.join(r.part_kinds)} {r.part_size_mm[0]:g}-{r.part_size_mm[1]:g} mm across, tilted "
            f"{r.tilt_deg[0]:g}-{r.tilt_deg[1]:g} deg towards any azimuth, up to {r.max_offset_mm:g} mm "
            f"off-centre, pushed {r.push_mm[0]:g}-{r.push_mm[1]:g} mm)"
        )
    if f.poses:
        return (
            f"{len(f.poses)} explicit poses of parts of diameter "
            f"{', '.join(sorted({f'{p.diameter_mm:g}' for p in f.poses}, key=float))} mm tilted by "
            f"{', '.join(sorted({f'{p.alpha_deg:g}' for p in f.poses}, key=float))} deg"
        )
    return (
        f"parts of diameter {', '.join(f'{d:g}' for d in f.diameters_mm)} mm tilted by "
        f"{', '.join(f'{a:g}' for a in f.alphas_deg)} deg every {f.theta_step_deg:g} deg of azimuth, "
        f"pushed {f.push_depth_mm:g} mm"
    )


def _overview(spec: StudySpec, results: pa.Table, ranked: list[dict[str, Any]]) -> str:
    quality = results.column("quality").to_pylist() if "quality" in results.column_names else []
    n_designs = len({r["design_id"] for r in ranked})
    return (
        f"Written {_dt.datetime.now().astimezone().isoformat(timespec='seconds')}. {n_designs} designs "
        f"(of {spec.n_designs}) x methods {', '.join(spec.methods)}; "
        f"seeds {', '.join(map(str, spec.seeds))}; "
        f"frames: {_frames_text(spec.frames)}. {len(quality)} estimates: {quality.count('ok')} ok, "
        f"{quality.count('suspect')} suspect, {quality.count('failed')} failed; "
        f"{sum(r['silent'] for r in ranked)} silent failures (error > 3 deg and > 4 sigma, quality ok)."
    )


def _front_table(f: _Front, rows: list[dict[str, Any]], methods: Sequence[str]) -> str:
    """A front's designs: per method (the study's order), by cost; rows with silent failures marked."""
    order = {m: k for k, m in enumerate(methods)}
    picked = [(c, r) for c, r, on in zip(f.cost, rows, f.on, strict=True) if on]
    picked.sort(key=lambda cr: (order.get(cr[1]["method"], len(order)), cr[0], _rank_key(cr[1])))
    header = ["design", "method", f.label, "RMSE (deg)", "recall", "silent", "rig"]
    body = [
        [
            f"{r['design_id']:03d}",
            r["method"],
            _value(float(c)),
            _num(r["rmse_deg"]),
            _num(r["recall"]),
            str(r["silent"]),
            f"best/{best_rig_name(r['design_id'])}",
        ]
        for c, r in picked
    ]
    return _html_table(header, body, ["silent" if r["silent"] else "" for _, r in picked])


def _report_body(
    spec: StudySpec,
    results: pa.Table,
    ranked: list[dict[str, Any]],
    paths: Sequence[str],
    figures: list[tuple[Path, str]],
    fronts: list[_Front],
    rows: list[dict[str, Any]],
) -> list[str]:
    shown = ranked[:REPORT_ROWS]
    body = [f"<h1>softjig study: {html.escape(spec.name)}</h1>", _p(_overview(spec, results, ranked))]
    body += ["<h2>Designs by RMSE</h2>", _p(f"The best {len(shown)} of {len(ranked)} design-method rows.")]
    body.append(
        _html_table(
            _header(paths),
            [_summary_row(k, r, paths) for k, r in enumerate(shown, start=1)],
            ["silent" if r["silent"] else "" for r in shown],
        )
    )
    body.append("<h2>Figures</h2>")
    body += [_img(path, caption) for path, caption in figures]
    body.append("<h2>Pareto fronts</h2>")
    body.append(
        _p(
            "Accuracy (RMSE, deg) against a cost, both minimised, per method: the marker count (markers to "
            "make and track) and, when the study varies them, the camera distance (a taller jig) and the "
            "baseline (a wider one). A design is on a front when no other design of its method is as good "
            "in both and better in one; designs with no estimate are left out. Each front design's full "
            "rig is in best/NNN.toml, ready for softjig simulate --config; a row in red "
            "had silent failures (error > 3 deg and > 4 sigma with quality ok): do not build it unchecked."
        )
    )
    for f in fronts:
        body += [f"<h3>RMSE against {html.escape(f.label)}</h3>", _front_table(f, rows, spec.methods)]
    return body


def write_study_outputs(
    out_dir: Path,
    spec: StudySpec,
    results: pa.Table,
    designs: pa.Table,
    *,
    config_for: Callable[[int], JigConfig] | None = None,
    costs: Sequence[str] | None = None,
) -> StudyOutputs:
    """Write a study's figures (``DIR/figures/``), its front designs' rigs (``DIR/best/NNN.toml``) and
    ``DIR/report.html`` (self-contained: the figures inline as base64 PNG, no script, nothing fetched).

    Parameters
    ----------
    out_dir : the study's output folder.
    spec : the study (its name, varied paths in file order, methods, seeds, frames).
    results, designs : the tables of ``results.parquet`` and ``designs.parquet`` (the study contract).
    config_for : a design id's full jig (default: built from ``spec``, see the module docstring).
    costs : the cost columns of the Pareto fronts (default :func:`cost_columns`).

    Raises
    ------
    InputError
        A table lacks a contract column, a cost column is not numeric, a file cannot be written.
    ConfigError
        A front design's config is invalid.
    """
    out_dir = Path(out_dir)
    paths = _varied(designs, spec.paths)
    points = _points(designs, paths)
    rows = designs.to_pylist()
    ranked = sorted(rows, key=_rank_key)
    fronts = _make_fronts(designs, points, cost_columns(designs, paths) if costs is None else costs)
    on_any = np.any([f.on for f in fronts], axis=0) if fronts else np.zeros(len(rows), bool)
    front_ids = tuple(sorted({int(i) for i in points.design_id[on_any]}))
    figures = _write_figures(out_dir / FIGURES, spec, points, ranked, results, fronts)
    rigs = write_best_rigs(
        out_dir / BEST,
        front_ids,
        config_for or _spec_config_for(spec),
        notes={
            i: f'study "{spec.name}"\n{_note(i, rows, paths, spec.methods)}\n'
            f"{_frames_note(spec)}, from the study's folder:\n  {_simulate_command(spec, i)}"
            for i in front_ids
        },
    )
    report = out_dir / "report.html"
    body = _report_body(spec, results, ranked, paths, figures, fronts, rows)
    write_text_atomic(report, _page(f"softjig study: {spec.name}", body))
    return StudyOutputs(report, tuple(p for p, _ in figures), rigs, front_ids)
