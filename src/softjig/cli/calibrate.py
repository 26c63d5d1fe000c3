"""`softjig calibrate`: the paper's tilt calibration (Ox, Oy, S) from a sweep dataset."""

from __future__ import annotations

import math
import time
from pathlib import Path
from typing import Annotated

import typer

from softjig.cli.app import app, handle_errors, stderr_console, warn
from softjig.cli.choices import DEFAULT_METHOD, FrameSelection, Method


@app.command()
@handle_errors
def calibrate(
    dataset: Annotated[
        Path,
        typer.Argument(
            help="A sweep dataset: frames with alpha_deg, theta_deg and part.", show_default=False
        ),
    ],
    out: Annotated[Path, typer.Option(help="Calibration JSON to write.")] = Path("calibration.json"),
    results: Annotated[
        Path | None,
        typer.Option(
            help="Use this results file of `softjig estimate DATASET --out` instead of estimating again.",
            show_default="estimate every frame",
        ),
    ] = None,
    per_diameter: Annotated[
        bool,
        typer.Option(
            "--per-diameter",
            help="Also fit one Ox, Oy, S per part diameter (the top level stays the pooled one).",
        ),
    ] = False,
    frames: Annotated[
        FrameSelection,
        typer.Option(help="Frames to fit: all, or the even / odd theta steps (keep the rest to evaluate)."),
    ] = FrameSelection.all,
    workers: Annotated[
        int | None, typer.Option(min=1, help="Estimation processes.", show_default="all CPUs")
    ] = None,
    method: Annotated[
        Method,
        typer.Option(help="The estimation method to calibrate (the calibration applies to it only)."),
    ] = DEFAULT_METHOD,
    progress: Annotated[bool, typer.Option(help="Show a progress bar on stderr.")] = True,
) -> None:
    """Fit the paper's tilt calibration (offsets Ox, Oy and scale S) to a tilt sweep and write it as JSON."""
    from rich.progress import Progress

    from softjig.calibration.sweep import load_result_rows, save_sweep_calibration
    from softjig.io.batch import calibrate_dataset
    from softjig.io.dataset import Dataset

    method, frames = Method(method).value, FrameSelection(frames).value
    ds = Dataset.open(dataset)
    from softjig.io.outputs import check_output

    check_output(out, "--out", [results], datasets=(ds,))
    t0 = time.perf_counter()
    rows = load_result_rows(results) if results is not None else None
    with Progress(console=stderr_console(), disable=not progress or rows is not None, transient=True) as bar:
        task = bar.add_task("estimating", total=len(ds))
        cal, samples, _ = calibrate_dataset(
            ds,
            rows=rows,
            mode="per-diameter" if per_diameter else "pooled",
            selection=frames,
            method=method,
            workers=workers,
            on_row=lambda _row: bar.advance(task),
        )
    source = {
        "dataset": str(Path(dataset).resolve()),
        "results": None if results is None else str(results.resolve()),
        "method": method,
    }
    save_sweep_calibration(cal, out, source=source)
    c = cal.pooled
    typer.echo(
        f"Ox = {math.degrees(c.offset_x_rad):+.4f} deg, Oy = {math.degrees(c.offset_y_rad):+.4f} deg, "
        f"S = {c.scale:.5f} from {len(cal.frames)} frames ({frames}); wrote {out} in "
        f"{time.perf_counter() - t0:.1f} s"
    )
    for d, pc, n in cal.per_diameter:
        typer.echo(
            f"  D = {d:g} mm: Ox = {math.degrees(pc.offset_x_rad):+.4f} deg, "
            f"Oy = {math.degrees(pc.offset_y_rad):+.4f} deg, S = {pc.scale:.5f} ({n} frames)"
        )
    if cal.failed_frames:
        first = samples.failed_errors[0] if samples.failed_errors else ""
        warn(
            f"{len(cal.failed_frames)} sweep frames gave no estimate and were left out, e.g. frame "
            f"{cal.failed_frames[0]}: {first}"
        )
    for message in cal.warnings:
        warn(message)
