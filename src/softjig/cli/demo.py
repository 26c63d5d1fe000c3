"""`softjig demo`: the paper's experiments on the simulated jig, end to end."""

from __future__ import annotations

import math
import time
from pathlib import Path
from typing import Annotated

import typer

from softjig.cli.app import app, handle_errors, stderr_console, warn


def _grid_table(grid, title: str):
    from rich.table import Table

    table = Table(title=title)
    table.add_column("D (mm) \\ alpha (deg)", justify="right")
    for a in grid.alphas_deg:
        table.add_column(f"{a:g}", justify="right")
    for i, d in enumerate(grid.diameters_mm):
        cells = []
        for j in range(len(grid.alphas_deg)):
            v = grid.rmse_deg[i, j]
            text = "n/a" if not math.isfinite(v) else f"{v:.2f}"
            if grid.failed[i, j]:
                text += f" ({grid.failed[i, j]} failed)"
            cells.append(text)
        table.add_row(f"{d:g}", *cells)
    return table


@app.command()
@handle_errors
def demo(
    out: Annotated[
        Path, typer.Option(help="Folder for the report, figures, calibration and datasets.")
    ] = Path("out/demo"),
    quick: Annotated[
        bool,
        typer.Option("--quick", help="A small run (D 30/50/80 mm, alpha 10/20, theta step 30): < 1 min."),
    ] = False,
    seed: Annotated[int, typer.Option(min=0, help="Seed of the as-built jig and of every frame.")] = 0,
    holdout: Annotated[
        bool,
        typer.Option(
            help="Calibrate on the even theta steps and evaluate on the odd ones; --no-holdout uses every "
            "frame for both (optimistic)."
        ),
    ] = True,
    cube_frames: Annotated[
        int | None,
        typer.Option(min=0, help="Cube frames (motion-capture experiment).", show_default="60, quick 10"),
    ] = None,
    workers: Annotated[int | None, typer.Option(min=1, help="Processes.", show_default="all CPUs")] = None,
    progress: Annotated[bool, typer.Option(help="Show progress bars on stderr.")] = True,
    keep_data: Annotated[
        bool,
        typer.Option(
            "--keep-data",
            help="Keep every rendered image (the full demo: about 850 MB); by default they are deleted "
            "once estimated, and only what the report needs is kept.",
        ),
    ] = False,
    overwrite: Annotated[
        bool,
        typer.Option(
            "--overwrite",
            help="Replace a finished run in --out (or an unfinished one with other options). An "
            "unfinished run with the same options is always resumed.",
        ),
    ] = False,
) -> None:
    """Run the paper's experiments on the simulated jig: sweep, calibration, RMSE grid, cube, report.

    The paper's method and softjig's default (refractive) side by side, in report.md and a
    self-contained report.html. Interrupted (Ctrl-C), the same command resumes where it stopped.
    """
    from rich.console import Console

    from softjig.evaluation.experiment import ExperimentSettings, quick_settings
    from softjig.experiments.paper import run_experiment

    extra: dict = {
        "split": "alternate" if holdout else "none",
        "workers": workers,
        "progress": progress,
        "keep_data": keep_data,
        "overwrite": overwrite,
    }
    if cube_frames is not None:
        extra["cube_frames"] = cube_frames
    settings = (
        quick_settings(out, seed=seed, **extra)
        if quick
        else ExperimentSettings(out_dir=out, seed=seed, **extra)
    )
    err = stderr_console()
    t0 = time.perf_counter()
    try:
        result = run_experiment(settings, on_stage=lambda text: err.print(f"[bold]>[/bold] {text}"))
    except KeyboardInterrupt:
        err.print(f"interrupted: the finished chunks are kept in {out}; the same command resumes the run")
        raise
    if result.resumed:
        err.print(f"resumed: {result.chunks_now} chunks rendered now, the others by the interrupted run")
    elapsed = time.perf_counter() - t0

    console = Console()
    ev, c = result.evaluation, result.calibration.pooled
    which = (
        f"held out: calibrated on the {result.calibration.selection} theta steps, evaluated on the "
        f"{ev.selection} ones"
        if ev.selection != result.calibration.selection
        else "calibrated and evaluated on every frame"
    )
    console.print(
        f"calibration (pooled): Ox = {math.degrees(c.offset_x_rad):+.3f} deg, "
        f"Oy = {math.degrees(c.offset_y_rad):+.3f} deg, S = {c.scale:.4f} "
        f"({len(result.calibration.frames)} frames)"
    )
    console.print(f"RMSE grids over {ev.n_frames} frames; {which}")
    console.print(_grid_table(ev.calibrated, "RMSE (deg), calibrated (pooled Ox, Oy, S)"))
    console.print(_grid_table(ev.uncalibrated, "RMSE (deg), uncalibrated, same frames"))
    dm = result.default_method
    if dm is not None:
        console.print(
            _grid_table(dm.evaluation.uncalibrated, f"RMSE (deg), {dm.method} (default), uncalibrated")
        )
        console.print(_grid_table(dm.evaluation.calibrated, f"RMSE (deg), {dm.method}, its own calibration"))
    if result.cube is not None:
        cb = result.cube
        text = (
            f"cube vs motion capture ({cb.calibrated.n} frames): paper RMSE {cb.raw.rmse_deg:.2f} deg "
            f"uncalibrated, {cb.calibrated.rmse_deg:.2f} deg calibrated"
        )
        if dm is not None and dm.cube is not None:
            text += (
                f"; {dm.method} {dm.cube.raw.rmse_deg:.2f} deg uncalibrated, "
                f"{dm.cube.calibrated.rmse_deg:.2f} deg with its own calibration"
            )
        console.print(text)
    n_failed = result.samples.n_failed + (result.cube.n_failed if result.cube is not None else 0)
    if n_failed:
        warn(f"{n_failed} frames gave no estimate (listed in the report)")
    console.print(f"report: {result.paths['report']} and {result.paths['report_html']}  ({elapsed:.1f} s)")
    if result.disk is not None:
        rendered = result.rendered
        kept = (
            "all kept (--keep-data)"
            if settings.keep_data
            else "the images deleted once estimated (--keep-data keeps them)"
        )
        console.print(
            f"disk: {out} holds {result.disk.files} files, {result.disk.mb:.1f} MB (measured); the frames "
            f"rendered took {rendered.files if rendered else 0} files, "
            f"{rendered.mb if rendered else 0.0:.1f} MB, {kept}"
        )
