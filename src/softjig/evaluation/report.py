"""The experiment's report: Markdown with the figures and tables, a JSON summary, and the paper's findings
checked against a grid (pure text making; :mod:`softjig.evaluation.experiment` writes the files)."""

from __future__ import annotations

import datetime as _dt
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from softjig.evaluation.metrics import RmseGrid

if TYPE_CHECKING:
    from softjig.calibration.sweep import SweepCalibration
    from softjig.evaluation.experiment import ExperimentResult

__all__ = ["Finding", "experiment_report_markdown", "experiment_summary", "grid_markdown", "paper_findings"]

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


def _calibration_table(cal: SweepCalibration) -> str:
    lines = ["| parts | Ox (deg) | Oy (deg) | S | frames |", "|---|---|---|---|---|"]
    c = cal.pooled
    lines.append(
        f"| all (pooled) | {math.degrees(c.offset_x_rad):+.3f} | {math.degrees(c.offset_y_rad):+.3f} "
        f"| {c.scale:.4f} | {len(cal.frames)} |"
    )
    for d, pc, n in cal.per_diameter:
        lines.append(
            f"| D = {d:g} mm | {math.degrees(pc.offset_x_rad):+.3f} | "
            f"{math.degrees(pc.offset_y_rad):+.3f} | {pc.scale:.4f} | {n} |"
        )
    return "\n".join(lines)


def experiment_report_markdown(result: ExperimentResult, *, stereo_pair_index: int | None = None) -> str:
    """The Markdown report of a run of :func:`softjig.evaluation.experiment.run_experiment`."""
    s, root = result.settings, Path(result.settings.out_dir)
    ev, cal = result.evaluation, result.calibration
    samples = result.samples
    n_frames_sweep = len(samples) + samples.n_failed
    fit_on, eval_on = cal.selection, ev.selection
    held_out = fit_on != eval_on
    c = cal.pooled
    t = result.timings_s
    md: list[str] = []
    md.append("# softjig: the paper's experiments on the simulated jig\n")
    md.append(
        f"Run {_dt.datetime.now().astimezone().isoformat(timespec='seconds')}, seed {s.seed}"
        f"{', quick run (a subset of the paper sweep)' if s.quick else ''}; total "
        f"{_fmt(t.get('total', math.nan), 1)} s (simulate {_fmt(t.get('simulate', math.nan), 1)} s, "
        f"estimate {_fmt(t.get('estimate', math.nan), 1)} s, calibrate and evaluate "
        f"{_fmt(t.get('calibrate_evaluate', math.nan), 1)} s, "
        f"figures {_fmt(t.get('figures', math.nan), 1)} s).\n"
    )
    md.append(
        "The images are rendered from an **as-built** jig drawn from the seed (cameras and plate off "
        "their drawing within the tolerances, refraction through the plate and the oil); the estimator "
        "knows only the **nominal** jig and uses the paper's method (pinhole triangulation that ignores "
        "refraction, SVD plane fit). The calibration has to absorb what that leaves: offsets from the "
        "misalignment, a scale from refraction.\n"
    )
    md.append("## Data\n")
    md.append(
        f"- Tilt sweep: D = {', '.join(f'{d:g}' for d in s.diameters_mm)} mm, alpha = "
        f"{', '.join(f'{a:g}' for a in s.alphas_deg)} deg, theta every {s.theta_step_deg:g} deg, push "
        f"{s.push_depth_mm:g} mm: {n_frames_sweep} loaded frames (+ the unloaded reference); "
        f"**{samples.n_failed} gave no estimate**."
    )
    if result.cube is not None:
        md.append(
            f"- Cube experiment (50 mm cube, random tilt up to 15 deg, yaw and offset): "
            f"{s.cube_frames} loaded frames; **{result.cube.n_failed} gave no estimate**."
        )
    md.append(f"- Datasets and per-frame estimates: `{_rel(root / 'data', root)}/`.\n")
    if result.failed_examples:
        md.append("Frames without an estimate (first ones):\n")
        md += [f"- frame {i}: {e}" for i, e in result.failed_examples]
        md.append("")
    md.append("## Calibration (Ox, Oy, S)\n")
    md.append(
        "`Ox = mean(Ax)`, `Oy = mean(Ay)`, `S = 2 alpha / (sqrt(2) (sigma_x + sigma_y))` (population "
        "standard deviations; pooled over tilts, alpha is the RMS of the frames' tilts); corrected "
        "`A' = S (A - O)`.\n"
    )
    md.append(
        f"Fitted on the **{fit_on}** theta steps of every (D, alpha) sweep ({len(cal.frames)} frames). "
        f'Pooled over all parts as the paper ("all data were corrected using the same offsets and '
        f'scales"): **Ox = {math.degrees(c.offset_x_rad):+.3f} deg, Oy = {math.degrees(c.offset_y_rad):+.3f} '
        f"deg, S = {c.scale:.4f}** (`{_rel(result.paths['calibration'], root)}`, applied by "
        "`softjig estimate --calibration`). Per diameter, for comparison:\n"
    )
    md.append(_calibration_table(result.per_diameter) + "\n")
    for w in cal.warnings:
        md.append(f"> warning: {w}\n")
    md.append("## RMSE grid\n")
    md.append(
        "RMSE of the tilt angles against the commanded ones, per cell over both axes: "
        "`sqrt(sum_i (ex_i^2 + ey_i^2) / (2 n))`, `ex = Ax - Ax*`, `ey = Ay - Ay*`, with "
        "`(Ax*, Ay*) = tilt_angles(normal_from_tilt(alpha, theta))`, in degrees.\n"
    )
    if held_out:
        md.append(
            f"Evaluated on the **{eval_on}** theta steps ({ev.n_frames} frames; {ev.n_failed} failed), "
            f"**held out**: no frame used for the calibration is evaluated.\n"
        )
    else:
        md.append(
            f"Evaluated on **the same frames** as the calibration ({ev.n_frames} frames; "
            f"{ev.n_failed} failed): optimistic.\n"
        )
    md.append("### Calibrated (pooled Ox, Oy, S)\n")
    md.append(grid_markdown(ev.calibrated) + "\n")
    md.append("### Uncalibrated\n")
    md.append(grid_markdown(ev.uncalibrated) + "\n")
    md.append("### Calibrated per diameter\n")
    md.append(grid_markdown(result.per_diameter_evaluation.calibrated) + "\n")
    md.append(f"![RMSE grid]({_rel(result.paths['rmse_grid'], root)})\n")
    md.append("### The paper's findings, checked on the calibrated grid\n")
    md.append("| paper | here | holds |\n|---|---|---|")
    for f in paper_findings(ev.calibrated):
        md.append(
            f"| {f.claim} | {f.measured} | {'n/a' if f.holds is None else ('yes' if f.holds else 'no')} |"
        )
    md.append("")
    md.append("## Tilt angles over the sweep\n")
    md.append(
        "Every frame (both halves), before and after the pooled calibration; opaque: the jig's Ax (red) "
        "and Ay (green); translucent: the commanded ones.\n"
    )
    md.append(f"![before calibration]({_rel(result.paths['tilt_before'], root)})\n")
    md.append(f"![after calibration]({_rel(result.paths['tilt_after'], root)})\n")
    if result.cube is not None:
        cb = result.cube
        md.append("## Cube against motion capture\n")
        md.append(
            "The cube's true poses were exported as an OptiTrack Motive CSV (rigid bodies `SoftJig` and "
            f"`Cube`, quaternions, meters, y-up; `{_rel(result.paths['mocap'], root)}`), read back, and "
            "`n_d = R_d z` with `T_d = inv(T_j) T_o` compared with the jig's estimates. The simulated "
            "mocap is exact: the errors are the jig's alone.\n"
        )
        md.append(
            "| estimate | frames | RMSE (deg) | RMSE x / y (deg) | bias x / y (deg) "
            "| mean / max angle (deg) |"
        )
        md.append("|---|---|---|---|---|---|")
        for name, e in (("uncalibrated", cb.raw), ("calibrated (pooled)", cb.calibrated)):
            md.append(
                f"| {name} | {e.n} | {_fmt(e.rmse_deg)} | {_fmt(e.rmse_x_deg)} / {_fmt(e.rmse_y_deg)} | "
                f"{e.bias_x_deg:+.2f} / {e.bias_y_deg:+.2f} | {_fmt(e.mean_angle_deg)} / "
                f"{_fmt(e.max_angle_deg)} |"
            )
        md.append("")
        if "cube_normals" in result.paths:
            md.append(f"![cube normals]({_rel(result.paths['cube_normals'], root)})\n")
    if "stereo_pair" in result.paths:
        md.append("## An example stereo pair\n")
        md.append(
            f"Frame {stereo_pair_index} of the sweep: detected markers circled (green matched, red not), "
            "yellow dots fitted, the crop in cyan, the normal in magenta.\n"
        )
        md.append(f"![stereo pair]({_rel(result.paths['stereo_pair'], root)})\n")
    return "\n".join(md)


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
    return summary
