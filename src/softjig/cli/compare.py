"""`softjig compare`: the paper's method and ours side by side on a tilt sweep."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import numpy as np
import typer
from rich.console import Console
from rich.table import Table

from softjig.cli.app import app, handle_errors, stderr_console


def _grid_table(title: str, grids: list) -> Table:
    """One table: a row per diameter, for each tilt the cells of every grid side by side."""
    first = grids[0]
    table = Table(title=title)
    table.add_column("D (mm)", justify="right")
    for alpha in first.alphas_deg:
        table.add_column(f"a={alpha:g}: paper / ours / ours cal. / no size", justify="right")
    for i, diameter in enumerate(first.diameters_mm):
        cells = [" / ".join(f"{g.rmse_deg[i, j]:.2f}" for g in grids) for j in range(len(first.alphas_deg))]
        table.add_row(f"{diameter:g}", *cells)
    return table


@app.command()
@handle_errors
def compare(
    dataset: Annotated[Path, typer.Argument(help="A tilt-sweep dataset (e.g. from softjig simulate).")],
    workers: Annotated[int | None, typer.Option(min=1, help="Processes.", show_default="all CPUs")] = None,
    progress: Annotated[bool, typer.Option(help="Show a progress bar on stderr.")] = True,
) -> None:
    """RMSE of the paper's method (calibrated) beside ours (uncalibrated and calibrated), held out."""
    from rich.progress import Progress

    from softjig.experiments.compare import compare_methods
    from softjig.io.dataset import Dataset

    data = Dataset.open(dataset)
    with Progress(console=stderr_console(), disable=not progress, transient=True) as bar:
        task = bar.add_task("estimating (paper, ours, ours without the size)", total=3 * len(data))
        result = compare_methods(data, workers=workers, on_row=lambda _row: bar.advance(task))
    console = Console()
    console.print(
        _grid_table(
            f"RMSE (deg) on {result.n_frames} held-out frames: paper calibrated / ours uncalibrated / ours "
            "calibrated / ours uncalibrated without the part's size",
            [
                result.paper_calibrated,
                result.ours_uncalibrated,
                result.ours_calibrated,
                result.ours_without_part_size,
            ],
        )
    )
    cal = result.ours_calibration
    console.print(
        f"ours' own tilt calibration (even frames): Ox {np.degrees(cal.offset_x_rad):+.3f} deg, "
        f"Oy {np.degrees(cal.offset_y_rad):+.3f} deg, S {cal.scale:.4f} (a calibrated sensor: 0, 0, 1)"
    )
    console.print(
        f"ours: 1-sigma coverage {100 * result.coverage_x:.0f} % (Ax), {100 * result.coverage_y:.0f} % (Ay), "
        f"68 % expected; position RMS: contact centroid {result.contact_centroid_rms_mm:.2f} mm (vs the true "
        f"contact's), part centre {result.part_centre_rms_mm:.2f} mm (the contact's centroid is "
        f"{result.contact_to_part_centre_rms_mm:.2f} mm from it); frames without an estimate: paper "
        f"{result.n_failed_paper}, ours {result.n_failed_ours} ({result.n_failed_ours_without_part_size} "
        "without the part's size)"
    )
