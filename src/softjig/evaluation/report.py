"""The experiment's report: Markdown with the figures and tables, the same as one self-contained HTML page
(figures inline), a JSON summary, and the paper's findings checked against a grid (text making only;
:mod:`softjig.experiments.paper` writes the files)."""

from __future__ import annotations

import base64
import datetime as _dt
import html
import math
import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from softjig.evaluation.metrics import RmseGrid

if TYPE_CHECKING:
    from softjig.calibration.sweep import SweepCalibration
    from softjig.evaluation.experiment import ExperimentResult

__all__ = [
    "Finding",
    "experiment_report_html",
    "experiment_report_markdown",
    "experiment_summary",
    "grid_markdown",
    "paper_findings",
]

STABLE_FROM_MM = 50.0  # the paper: "larger than 50 mm ... the RMSE was stabilized", "< 3 deg"
PAPER_BOUND_DEG = 3.0


def _fmt(value: float, digits: int = 2) -> str:
    return "n/a" if value is None or not math.isfinite(value) else f"{value:.{digits}f}"


def grid_markdown(grid: RmseGrid, *, digits: int = 2) -> str:
    """A Markdown table of an RMSE grid: rows diameters, columns tilts; failed frames noted per cell."""
    head = "| D (mm) \\ alpha (deg) | " + " | ".join(f"{a:g}" for a in grid.alphas_deg) + " |"
    rule = "|---|" + "---|" * len(grid.alphas_deg)
    lines = [head, rule]
    for i, d in enumerate(grid.diameters_mm):
        cells = []
        for j in range(len(grid.alphas_deg)):
            text = _fmt(grid.rmse_deg[i, j], digits)
            if grid.failed[i, j]:
                text += f" ({grid.failed[i, j]} failed)"
            cells.append(text)
        lines.append(f"| {d:g} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


@dataclass(frozen=True)
class Finding:
    """One of the paper's findings, checked on a grid: what the paper says, what we measured, whether it
    holds here."""

    claim: str
    measured: str
    holds: bool | None


def paper_findings(grid: RmseGrid) -> list[Finding]:
    """Check the paper's three findings about its RMSE grid (calibrated) on ``grid``.

    1. RMSE falls as the diameter grows: the mean over tilts of the smallest diameter's row exceeds that of
       the rows ``D >= 50 mm``.
    2. From ``D >= 50 mm`` it is stable and below 3 deg: every such cell ``< 3`` deg.
    3. The largest errors sit in the lower right (large ``D``, large ``alpha``): among the rows
       ``D >= 50 mm``, the largest cell is in the largest tilt's column.
    """
    rmse, d = grid.rmse_deg, grid.diameters_mm
    rows = np.nanmean(np.where(np.isfinite(rmse), rmse, np.nan), axis=1) if rmse.size else np.zeros(0)
    big = d >= STABLE_FROM_MM
    out = []
    if len(d) >= 2 and big.any() and not big[0]:
        small, large = rows[0], float(np.nanmean(rows[big]))
        out.append(
            Finding(
                "RMSE falls as the diameter grows (noisy with few markers under small parts)",
                f"mean RMSE over tilts: D = {d[0]:g} mm: {_fmt(small)} deg; D >= 50 mm: {_fmt(large)} deg; "
                "by D: " + ", ".join(f"{dv:g}: {_fmt(r)}" for dv, r in zip(d, rows, strict=True)),
                bool(small > large),
            )
        )
    else:
        out.append(
            Finding("RMSE falls as the diameter grows", "needs a diameter below and above 50 mm", None)
        )
    if big.any():
        worst = float(np.nanmax(rmse[big])) if np.isfinite(rmse[big]).any() else math.nan
        out.append(
            Finding(
                "for D >= 50 mm the RMSE is stable and below 3 deg",
                f"largest RMSE at D >= 50 mm: {_fmt(worst)} deg; spread of the row means "
                f"{_fmt(float(np.nanmax(rows[big]) - np.nanmin(rows[big])))} deg",
                bool(worst < PAPER_BOUND_DEG) if math.isfinite(worst) else None,
            )
        )
        sub = np.where(np.isfinite(rmse[big]), rmse[big], -np.inf)
        if len(grid.alphas_deg) >= 2 and np.isfinite(sub).any():
            i, j = np.unravel_index(int(np.argmax(sub)), sub.shape)
            out.append(
                Finding(
                    "the largest errors are at large D and large alpha (part of the face lifts off)",
                    f"largest cell of the rows D >= 50 mm: D = {d[big][i]:g} mm, "
                    f"alpha = {grid.alphas_deg[j]:g} deg "
                    f"({_fmt(sub[i, j])} deg)",
                    bool(j == len(grid.alphas_deg) - 1),
                )
            )
    return out


def _rel(path: Path, root: Path) -> str:
    return Path(os.path.relpath(path, root)).as_posix()


# ------------------------------------------------------------------------------ the report's blocks
#
# The report is built once as a list of blocks, then written as Markdown and as self-contained HTML.
# Text may carry two inline marks, **bold** and `code`; everything else is literal.


@dataclass(frozen=True)
class _Block:
    kind: str  # "h1", "h2", "h3", "p", "quote", "list", "table", "img"
    text: str = ""
    items: tuple = ()  # list: the items; table: (header, *rows), each a tuple of cells
    path: Path | None = None  # img


def _h(level: int, text: str) -> _Block:
    return _Block(f"h{level}", text)


def _p(text: str) -> _Block:
    return _Block("p", text)


def _table(header: list[str], rows: list[list[str]]) -> _Block:
    return _Block("table", items=(tuple(header), *(tuple(r) for r in rows)))


def _grid_table(grid: RmseGrid, digits: int = 2) -> _Block:
    header = ["D (mm) \\ alpha (deg)", *(f"{a:g}" for a in grid.alphas_deg)]
    rows = []
    for i, d in enumerate(grid.diameters_mm):
        cells = []
        for j in range(len(grid.alphas_deg)):
            text = _fmt(grid.rmse_deg[i, j], digits)
            if grid.failed[i, j]:
                text += f" ({grid.failed[i, j]} failed)"
            cells.append(text)
        rows.append([f"{d:g}", *cells])
    return _table(header, rows)


def _calibration_table(cal: SweepCalibration) -> _Block:
    c = cal.pooled
    rows = [
        [
            "all (pooled)",
            f"{math.degrees(c.offset_x_rad):+.3f}",
            f"{math.degrees(c.offset_y_rad):+.3f}",
            f"{c.scale:.4f}",
            str(len(cal.frames)),
        ]
    ]
    for d, pc, n in cal.per_diameter:
        rows.append(
            [
                f"D = {d:g} mm",
                f"{math.degrees(pc.offset_x_rad):+.3f}",
                f"{math.degrees(pc.offset_y_rad):+.3f}",
                f"{pc.scale:.4f}",
                str(n),
            ]
        )
    return _table(["parts", "Ox (deg)", "Oy (deg)", "S", "frames"], rows)


def _grid_mean(grid: RmseGrid) -> float:
    finite = grid.rmse_deg[np.isfinite(grid.rmse_deg)]
    return float(finite.mean()) if finite.size else math.nan


def _grid_max(grid: RmseGrid) -> float:
    finite = grid.rmse_deg[np.isfinite(grid.rmse_deg)]
    return float(finite.max()) if finite.size else math.nan


def _cube_row(name: str, e: Any) -> list[str]:
    return [
        name,
        str(e.n),
        _fmt(e.rmse_deg),
        f"{_fmt(e.rmse_x_deg)} / {_fmt(e.rmse_y_deg)}",
        f"{e.bias_x_deg:+.2f} / {e.bias_y_deg:+.2f}",
        f"{_fmt(e.mean_angle_deg)} / {_fmt(e.max_angle_deg)}",
    ]


def _report_blocks(result: ExperimentResult, stereo_pairs: dict[str, int | None]) -> list[_Block]:
    """The report's blocks, section by section (Markdown and HTML render the same blocks)."""
    return [
        *_intro_blocks(result),
        *_glance_blocks(result),
        *_data_blocks(result),
        *_calibration_blocks(result),
        *_grid_blocks(result),
        *_tilt_blocks(result),
        *_cube_blocks(result),
        *_pair_blocks(result, stereo_pairs),
    ]


def _intro_blocks(result: ExperimentResult) -> list[_Block]:
    """The title, the run (date, seed, timings) and what the experiment compares."""
    s = result.settings
    t = result.timings_s
    out: list[_Block] = [_h(1, "softjig: the paper's experiments on the simulated jig")]
    out.append(
        _p(
            f"Run {_dt.datetime.now().astimezone().isoformat(timespec='seconds')}, seed {s.seed}"
            f"{', quick run (a subset of the paper sweep)' if s.quick else ''}"
            f"{', resumed after an interruption' if result.resumed else ''}; total "
            f"{_fmt(t.get('total', math.nan), 1)} s (render and estimate "
            f"{_fmt(t.get('simulate_estimate', math.nan), 1)} s, calibrate and evaluate "
            f"{_fmt(t.get('calibrate_evaluate', math.nan), 1)} s, "
            f"figures {_fmt(t.get('figures', math.nan), 1)} s)."
        )
    )
    out.append(
        _p(
            "The images are rendered from an **as-built** jig drawn from the seed (cameras and plate off "
            "their drawing within the tolerances, refraction through the plate and the oil); the estimators "
            "know only the **nominal** jig. The paper's method (pinhole triangulation that ignores "
            "refraction, SVD plane fit) needs its calibration to absorb what that leaves: offsets from "
            "the misalignment, a scale from refraction. softjig's default method (`refractive`: "
            "triangulation through the plate and the oil, the contact found from each marker's "
            "indentation against the unloaded reference frame, a robust plane fit) is shown beside it, "
            "uncalibrated and with its own calibration fitted on the same frames."
        )
    )
    return out


def _glance_blocks(result: ExperimentResult) -> list[_Block]:
    """Both methods' RMSE side by side (and against motion capture), the default's calibration."""
    ev, cal, dm = result.evaluation, result.calibration, result.default_method
    if dm is None:
        return []
    root, paths, samples = Path(result.settings.out_dir), result.paths, result.samples
    fit_on, eval_on = cal.selection, ev.selection
    held_out = fit_on != eval_on
    out: list[_Block] = []
    out.append(_h(2, "At a glance: the paper's method and softjig's default"))
    rows = [
        [
            "paper, calibrated (pooled Ox, Oy, S)",
            _fmt(_grid_mean(ev.calibrated)),
            _fmt(_grid_max(ev.calibrated)),
        ],
        ["paper, uncalibrated", _fmt(_grid_mean(ev.uncalibrated)), _fmt(_grid_max(ev.uncalibrated))],
        [
            f"{dm.method} (default), uncalibrated",
            _fmt(_grid_mean(dm.evaluation.uncalibrated)),
            _fmt(_grid_max(dm.evaluation.uncalibrated)),
        ],
        [
            f"{dm.method}, its own calibration",
            _fmt(_grid_mean(dm.evaluation.calibrated)),
            _fmt(_grid_max(dm.evaluation.calibrated)),
        ],
    ]
    header = ["method", "mean RMSE over the grid (deg)", "worst cell (deg)"]
    if result.cube is not None or dm.cube is not None:
        header.append("cube vs motion capture, RMSE (deg)")
        cubes = [
            result.cube.calibrated if result.cube else None,
            result.cube.raw if result.cube else None,
            dm.cube.raw if dm.cube else None,
            dm.cube.calibrated if dm.cube else None,
        ]
        for row, e in zip(rows, cubes, strict=True):
            row.append("n/a" if e is None else _fmt(e.rmse_deg))
    out.append(
        _p(
            f"RMSE of the tilt angles on the **{eval_on}** theta steps"
            + (" (held out from every calibration)" if held_out else " (the calibration frames: optimistic)")
            + "; the grids below on one colour scale."
        )
    )
    out.append(_table(header, rows))
    dc = dm.calibration.pooled
    out.append(
        _p(
            f"The default method's own calibration (fitted like the paper's on the {fit_on} frames, "
            f"`{_rel(paths['calibration_default'], root)}`): Ox = {math.degrees(dc.offset_x_rad):+.3f} "
            f"deg, Oy = {math.degrees(dc.offset_y_rad):+.3f} deg, S = {dc.scale:.4f} (a sensor that "
            f"needs no calibration: 0, 0, 1). Frames without an estimate: paper {samples.n_failed}, "
            f"{dm.method} {dm.samples.n_failed}."
        )
    )
    if "methods" in paths:
        out.append(_Block("img", "the methods side by side", path=paths["methods"]))
    return out


def _data_blocks(result: ExperimentResult) -> list[_Block]:
    """The frames of each experiment, those that failed, and what the run folder keeps."""
    s, root = result.settings, Path(result.settings.out_dir)
    samples = result.samples
    n_frames_sweep = len(samples) + samples.n_failed
    out: list[_Block] = []
    out.append(_h(2, "Data"))
    items = [
        f"Tilt sweep: D = {', '.join(f'{d:g}' for d in s.diameters_mm)} mm, alpha = "
        f"{', '.join(f'{a:g}' for a in s.alphas_deg)} deg, theta every {s.theta_step_deg:g} deg, push "
        f"{s.push_depth_mm:g} mm: {n_frames_sweep} loaded frames (+ the unloaded reference); "
        f"**{samples.n_failed} gave no estimate** (paper's method)."
    ]
    if result.cube is not None:
        items.append(
            f"Cube experiment (50 mm cube, random tilt up to 15 deg, yaw and offset): "
            f"{s.cube_frames} loaded frames; **{result.cube.n_failed} gave no estimate**."
        )
    kept = (
        "every rendered image is kept (`--keep-data`)"
        if s.keep_data
        else (
            "the rendered images were deleted once estimated, but those of the reference frames and the "
            "example pairs (`--keep-data` keeps them all)"
        )
    )
    items.append(f"Datasets and per-frame estimates of both methods: `{_rel(root / 'data', root)}/`; {kept}.")
    if result.rendered is not None:
        items.append(
            f"Rendered: {result.rendered.files} files, {result.rendered.mb:.1f} MB (measured; in chunks "
            f"of {s.chunk_frames} frames, recorded in `manifest.json`)."
        )
    out.append(_Block("list", items=tuple(items)))
    if result.failed_examples:
        out.append(_p("Frames without an estimate (first ones):"))
        out.append(_Block("list", items=tuple(f"frame {i}: {e}" for i, e in result.failed_examples)))
    return out


def _calibration_blocks(result: ExperimentResult) -> list[_Block]:
    """The calibration's formula and the fitted offsets and scale, pooled and per diameter."""
    root, paths, cal = Path(result.settings.out_dir), result.paths, result.calibration
    fit_on, c = cal.selection, cal.pooled
    out: list[_Block] = []
    out.append(_h(2, "Calibration (Ox, Oy, S)"))
    out.append(
        _p(
            "`Ox = mean(Ax)`, `Oy = mean(Ay)`, `S = 2 alpha / (sqrt(2) (sigma_x + sigma_y))` (population "
            "standard deviations; pooled over tilts, alpha is the RMS of the frames' tilts); corrected "
            "`A' = S (A - O)`."
        )
    )
    out.append(
        _p(
            f"Fitted on the **{fit_on}** theta steps of every (D, alpha) sweep ({len(cal.frames)} frames). "
            f'Pooled over all parts as the paper ("all data were corrected using the same offsets and '
            f'scales"): **Ox = {math.degrees(c.offset_x_rad):+.3f} deg, Oy = '
            f"{math.degrees(c.offset_y_rad):+.3f} deg, S = {c.scale:.4f}** "
            f"(`{_rel(paths['calibration'], root)}`, for `softjig estimate --method paper --calibration`). "
            "Per diameter, for comparison:"
        )
    )
    out.append(_calibration_table(result.per_diameter))
    out += [_Block("quote", f"warning: {w}") for w in cal.warnings]
    return out


def _grid_blocks(result: ExperimentResult) -> list[_Block]:
    """The RMSE grids of both methods, on held-out frames or not, and the paper's findings."""
    ev, cal, dm, paths = result.evaluation, result.calibration, result.default_method, result.paths
    eval_on = ev.selection
    held_out = cal.selection != eval_on
    out: list[_Block] = []
    out.append(_h(2, "RMSE grid"))
    out.append(
        _p(
            "RMSE of the tilt angles against the commanded ones, per cell over both axes: "
            "`sqrt(sum_i (ex_i^2 + ey_i^2) / (2 n))`, `ex = Ax - Ax*`, `ey = Ay - Ay*`, with "
            "`(Ax*, Ay*) = tilt_angles(normal_from_tilt(alpha, theta))`, in degrees."
        )
    )
    if held_out:
        out.append(
            _p(
                f"Evaluated on the **{eval_on}** theta steps ({ev.n_frames} frames; {ev.n_failed} failed), "
                "**held out**: no frame used for the calibration is evaluated."
            )
        )
    else:
        out.append(
            _p(
                f"Evaluated on **the same frames** as the calibration ({ev.n_frames} frames; "
                f"{ev.n_failed} failed): optimistic."
            )
        )
    out += [_h(3, "Paper's method, calibrated (pooled Ox, Oy, S)"), _grid_table(ev.calibrated)]
    out += [_h(3, "Paper's method, uncalibrated"), _grid_table(ev.uncalibrated)]
    out += [
        _h(3, "Paper's method, calibrated per diameter"),
        _grid_table(result.per_diameter_evaluation.calibrated),
    ]
    if dm is not None:
        out += [_h(3, f"{dm.method} (default), uncalibrated"), _grid_table(dm.evaluation.uncalibrated)]
        out += [_h(3, f"{dm.method}, its own calibration"), _grid_table(dm.evaluation.calibrated)]
    out.append(_Block("img", "RMSE grid", path=paths["rmse_grid"]))
    out.append(_h(3, "The paper's findings, checked on the paper's calibrated grid"))
    out.append(
        _table(
            ["paper", "here", "holds"],
            [
                [f.claim, f.measured, "n/a" if f.holds is None else ("yes" if f.holds else "no")]
                for f in paper_findings(ev.calibrated)
            ],
        )
    )
    return out


def _tilt_blocks(result: ExperimentResult) -> list[_Block]:
    """The tilt angles over the sweep: the methods overlaid, the paper's before and after calibration."""
    paths = result.paths
    out: list[_Block] = []
    out.append(_h(2, "Tilt angles over the sweep"))
    if "tilt_methods" in paths:
        out.append(
            _p(
                "Both methods overlaid (the legend says which line is which; Ax red, Ay green, the "
                "commanded angles translucent):"
            )
        )
        out.append(_Block("img", "tilt angles, the methods overlaid", path=paths["tilt_methods"]))
    out.append(
        _p(
            "The paper's method on every frame (both halves), before and after the pooled calibration; "
            "opaque: the jig's Ax (red) and Ay (green); translucent: the commanded ones."
        )
    )
    out.append(_Block("img", "before calibration", path=paths["tilt_before"]))
    out.append(_Block("img", "after calibration", path=paths["tilt_after"]))
    return out


def _cube_blocks(result: ExperimentResult) -> list[_Block]:
    """The cube experiment against motion capture (nothing without cube frames)."""
    if result.cube is None:
        return []
    root, paths, dm = Path(result.settings.out_dir), result.paths, result.default_method
    out: list[_Block] = []
    cb = result.cube
    out.append(_h(2, "Cube against motion capture"))
    out.append(
        _p(
            "The cube's true poses were exported as an OptiTrack Motive CSV (rigid bodies `SoftJig` "
            f"and `Cube`, quaternions, meters, y-up; `{_rel(paths['mocap'], root)}`), read back, and "
            "`n_d = R_d z` with `T_d = inv(T_j) T_o` compared with the jig's estimates (the same "
            "comparison runs alone: `softjig mocap DATASET --csv MOCAP.csv`). The simulated mocap is "
            "exact: the errors are the jig's alone."
        )
    )
    rows = [
        _cube_row("paper, uncalibrated", cb.raw),
        _cube_row("paper, calibrated (pooled)", cb.calibrated),
    ]
    if dm is not None and dm.cube is not None:
        rows += [
            _cube_row(f"{dm.method} (default), uncalibrated", dm.cube.raw),
            _cube_row(f"{dm.method}, its own calibration", dm.cube.calibrated),
        ]
    out.append(
        _table(
            [
                "estimate",
                "frames",
                "RMSE (deg)",
                "RMSE x / y (deg)",
                "bias x / y (deg)",
                "mean / max angle (deg)",
            ],
            rows,
        )
    )
    if "cube_methods" in paths:
        out.append(_Block("img", "cube, the methods", path=paths["cube_methods"]))
    if "cube_normals" in paths:
        out.append(_Block("img", "cube normals", path=paths["cube_normals"]))
    return out


def _pair_blocks(result: ExperimentResult, stereo_pairs: dict[str, int | None]) -> list[_Block]:
    """The example stereo pair of each method, with what its overlay shows."""
    paths = result.paths
    out: list[_Block] = []
    for method, key in (("paper", "stereo_pair"), ("refractive", "stereo_pair_default")):
        if key not in paths:
            continue
        out.append(_h(2, f"An example stereo pair ({method} method)"))
        out.append(
            _p(
                f"Frame {stereo_pairs.get(method)} of the sweep: detected markers circled (green matched, "
                "red not), yellow dots fitted (orange: in contact but rejected), the crop or the contact "
                "in cyan, the normal as a magenta arrow with its tilt exaggerated (the legend on the "
                "image says how much)."
            )
        )
        out.append(_Block("img", f"stereo pair, {method} method", path=paths[key]))
    return out


def _md_cell(value: Any) -> str:
    return str(value).replace("|", "\\|").replace("\n", " ")


def _to_markdown(blocks: list[_Block], root: Path) -> str:
    md: list[str] = []
    for b in blocks:
        if b.kind in ("h1", "h2", "h3"):
            md.append("#" * int(b.kind[1]) + " " + b.text + "\n")
        elif b.kind == "p":
            md.append(b.text + "\n")
        elif b.kind == "quote":
            md.append(f"> {b.text}\n")
        elif b.kind == "list":
            md += [f"- {item}" for item in b.items]
            md.append("")
        elif b.kind == "table":
            header, *rows = b.items
            md.append("| " + " | ".join(_md_cell(h) for h in header) + " |")
            md.append("|" + "---|" * len(header))
            md += ["| " + " | ".join(_md_cell(v) for v in row) + " |" for row in rows]
            md.append("")
        elif b.kind == "img" and b.path is not None:
            md.append(f"![{b.text}]({_rel(b.path, root)})\n")
    return "\n".join(md)


_NUMBER = re.compile(r"^\s*([+-]?\d[\d.]*|n/a)(\s*/\s*[+-]?\d[\d.]*)*(\s*\(\d+ failed\))?\s*$")
_INLINE = re.compile(r"\*\*(.+?)\*\*|`([^`]+)`")


def _html_text(text: str) -> str:
    """Escape ``text`` for HTML, then turn its **bold** and `code` marks into tags."""
    parts, last = [], 0
    for m in _INLINE.finditer(text):
        parts.append(html.escape(text[last : m.start()]))
        if m.group(1) is not None:
            parts.append(f"<strong>{_html_text(m.group(1))}</strong>")
        else:
            parts.append(f"<code>{html.escape(m.group(2))}</code>")
        last = m.end()
    parts.append(html.escape(text[last:]))
    return "".join(parts)


_CSS = """
body { font-family: system-ui, -apple-system, "Segoe UI", Helvetica, Arial, sans-serif; max-width: 1150px;
       margin: 2em auto; padding: 0 1em; color: #222; line-height: 1.45; }
h1 { border-bottom: 2px solid #ddd; padding-bottom: .2em; }
h2 { border-bottom: 1px solid #eee; padding-bottom: .15em; margin-top: 1.6em; }
table { border-collapse: collapse; margin: .6em 0 1em; font-size: 0.92em; }
th, td { border: 1px solid #ccc; padding: .25em .6em; text-align: left; vertical-align: top; }
th { background: #f3f3f3; } td.num { text-align: right; font-variant-numeric: tabular-nums; }
code { background: #f4f4f4; padding: 0 .2em; border-radius: 3px; font-size: 0.92em; }
img { max-width: 100%; border: 1px solid #ddd; margin: .4em 0 1em; }
blockquote { border-left: 4px solid #e6a700; margin: .5em 0; padding: .2em .8em; background: #fff8e1; }
"""


#: Figures wider than this are scaled down (area average) before they are inlined: the page shows them at
#: most ~1150 px wide, and a full-resolution stereo pair would weigh 3 MB of base64.
HTML_MAX_WIDTH_PX = 1600


def _png_for_html(path: Path) -> bytes:
    """The PNG of ``path``, scaled down to :data:`HTML_MAX_WIDTH_PX` wide if wider."""
    import cv2

    data = path.read_bytes()
    image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    if image is None or image.shape[1] <= HTML_MAX_WIDTH_PX:
        return data
    height = round(image.shape[0] * HTML_MAX_WIDTH_PX / image.shape[1])
    small = cv2.resize(image, (HTML_MAX_WIDTH_PX, height), interpolation=cv2.INTER_AREA)
    ok, encoded = cv2.imencode(".png", small)
    return encoded.tobytes() if ok else data


def _to_html(blocks: list[_Block], title: str) -> str:
    """A self-contained HTML page: styles inline, every figure a ``data:image/png;base64`` URI."""
    body: list[str] = []
    for b in blocks:
        if b.kind in ("h1", "h2", "h3"):
            body.append(f"<{b.kind}>{_html_text(b.text)}</{b.kind}>")
        elif b.kind == "p":
            body.append(f"<p>{_html_text(b.text)}</p>")
        elif b.kind == "quote":
            body.append(f"<blockquote>{_html_text(b.text)}</blockquote>")
        elif b.kind == "list":
            body.append("<ul>" + "".join(f"<li>{_html_text(i)}</li>" for i in b.items) + "</ul>")
        elif b.kind == "table":
            header, *rows = b.items
            head = "".join(f"<th>{_html_text(str(h))}</th>" for h in header)
            lines = ["<table>", f"<thead><tr>{head}</tr></thead>", "<tbody>"]
            for row in rows:
                cells = "".join(
                    f'<td class="{"num" if _NUMBER.match(str(v)) else "text"}">{_html_text(str(v))}</td>'
                    for v in row
                )
                lines.append(f"<tr>{cells}</tr>")
            lines.append("</tbody></table>")
            body.append("\n".join(lines))
        elif b.kind == "img" and b.path is not None and Path(b.path).is_file():
            data = base64.b64encode(_png_for_html(Path(b.path))).decode("ascii")
            alt = html.escape(b.text, quote=True)
            body.append(f'<figure><img alt="{alt}" src="data:image/png;base64,{data}"></figure>')
    return (
        '<!DOCTYPE html>\n<html lang="en">\n<head>\n<meta charset="utf-8">\n'
        f"<title>{html.escape(title)}</title>\n<style>{_CSS}</style>\n</head>\n<body>\n"
        + "\n".join(body)
        + "\n</body>\n</html>\n"
    )


def experiment_report_markdown(
    result: ExperimentResult,
    *,
    stereo_pair_index: int | None = None,
    stereo_pairs: dict[str, int | None] | None = None,
) -> str:
    """The Markdown report of a run of :func:`softjig.experiments.paper.run_experiment` (figures as
    links to the PNGs beside it); ``stereo_pairs``: the example pair's frame per method."""
    pairs = {"paper": stereo_pair_index, **(stereo_pairs or {})}
    return _to_markdown(_report_blocks(result, pairs), Path(result.settings.out_dir))


def experiment_report_html(
    result: ExperimentResult, *, stereo_pairs: dict[str, int | None] | None = None
) -> str:
    """The same report as one self-contained HTML page: the figures inline (base64 PNG), the tables as
    HTML tables, every text escaped; nothing is fetched from anywhere."""
    blocks = _report_blocks(result, stereo_pairs or {})
    return _to_html(blocks, "softjig: the paper's experiments on the simulated jig")


def _cal_dict(c: Any) -> dict[str, float]:
    return {
        "offset_x_deg": math.degrees(c.offset_x_rad),
        "offset_y_deg": math.degrees(c.offset_y_rad),
        "scale": float(c.scale),
    }


def experiment_summary(result: ExperimentResult) -> dict:
    """A JSON-able summary of a run: calibration, grids, cube errors, failures, timings."""
    ev = result.evaluation
    summary: dict[str, Any] = {
        "seed": result.settings.seed,
        "quick": result.settings.quick,
        "calibration": {
            **_cal_dict(result.calibration.pooled),
            "selection": result.calibration.selection,
            "n_frames": len(result.calibration.frames),
        },
        "calibration_per_diameter": [
            {"diameter_mm": d, **_cal_dict(c), "n_frames": n} for d, c, n in result.per_diameter.per_diameter
        ],
        "evaluation": {
            "selection": ev.selection,
            "n_frames": ev.n_frames,
            "n_failed": ev.n_failed,
            "calibrated": ev.calibrated.to_dict(),
            "uncalibrated": ev.uncalibrated.to_dict(),
            "calibrated_per_diameter": result.per_diameter_evaluation.calibrated.to_dict(),
        },
        "sweep_failed_frames": [int(i) for i in result.samples.failed_index],
        "paper_findings": [f.__dict__ for f in paper_findings(ev.calibrated)],
        "timings_s": result.timings_s,
    }
    if result.cube is not None:
        summary["cube"] = {
            "raw": result.cube.raw.__dict__,
            "calibrated": result.cube.calibrated.__dict__,
            "n_failed": result.cube.n_failed,
        }
    dm = result.default_method
    if dm is not None:
        summary["default_method"] = {
            "method": dm.method,
            "calibration": {
                **_cal_dict(dm.calibration.pooled),
                "selection": dm.calibration.selection,
                "n_frames": len(dm.calibration.frames),
            },
            "evaluation": {
                "selection": dm.evaluation.selection,
                "n_frames": dm.evaluation.n_frames,
                "n_failed": dm.evaluation.n_failed,
                "calibrated": dm.evaluation.calibrated.to_dict(),
                "uncalibrated": dm.evaluation.uncalibrated.to_dict(),
            },
            "sweep_failed_frames": [int(i) for i in dm.samples.failed_index],
        }
        if dm.cube is not None:
            summary["default_method"]["cube"] = {
                "raw": dm.cube.raw.__dict__,
                "calibrated": dm.cube.calibrated.__dict__,
                "n_failed": dm.cube.n_failed,
            }
    if result.rendered is not None:
        summary["rendered"] = {"files": result.rendered.files, "bytes": result.rendered.bytes}
    summary["resumed"] = result.resumed
    return summary
