"""`softjig mocap`: a dataset's estimates against an OptiTrack Motive CSV export (the paper's cube
experiment, on its own)."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Annotated

import typer

from softjig.cli.app import app, handle_errors, stderr_console, warn
from softjig.errors import EstimationError, InputError
from softjig.sensing.pipeline import DEFAULT_METHOD, METHODS


def _summary_dict(e) -> dict:
    return {k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in e.__dict__.items()}


@app.command()
@handle_errors
def mocap(
    dataset: Annotated[
        Path,
        typer.Argument(
            help="A dataset of the object pressed in (e.g. softjig simulate --scenario cube).",
            show_default=False,
        ),
    ],
    csv: Annotated[
        Path | None,
        typer.Option(
            "--csv",
            help="The Motive CSV export (rigid bodies, quaternions); simulate --scenario cube writes "
            "DATASET/mocap.csv.",
            show_default="DATASET/mocap.csv",
        ),
    ] = None,
    calibration: Annotated[
        Path | None,
        typer.Option(
            help="Also compare after this tilt calibration (fitted to --method).", show_default=False
        ),
    ] = None,
    method: Annotated[
        str, typer.Option(help=f"The estimation method: {', '.join(METHODS)}.")
    ] = DEFAULT_METHOD,
    results: Annotated[
        Path | None,
        typer.Option(
            help="Use this results file of `softjig estimate DATASET --out` (of --method) instead of "
            "estimating again.",
            show_default="estimate every frame",
        ),
    ] = None,
    jig_body: Annotated[str, typer.Option(help="The jig's rigid body in the take.")] = "SoftJig",
    object_body: Annotated[str, typer.Option(help="The object's rigid body in the take.")] = "Cube",
    frame_offset: Annotated[int, typer.Option(help="Motive frame number = dataset frame index + this.")] = 0,
    workers: Annotated[
        int | None, typer.Option(min=1, help="Estimation processes.", show_default="all CPUs")
    ] = None,
    json_output: Annotated[bool, typer.Option("--json", help="Print one JSON object.")] = False,
    progress: Annotated[bool, typer.Option(help="Show a progress bar on stderr.")] = True,
) -> None:
    """Compare a dataset's normals with motion capture (T_d = inv(T_j) T_o, n_d = R_d z): RMSE, bias."""
    from rich.progress import Progress

    from softjig.calibration.sweep import load_result_rows
    from softjig.calibration.tilt import TiltCalibration, load_tilt_calibration
    from softjig.evaluation.experiment import compare_with_mocap
    from softjig.io.dataset import Dataset

    if method not in METHODS:
        raise InputError(f"--method must be one of {', '.join(METHODS)}, got {method!r}")
    csv_path = Path(dataset) / "mocap.csv" if csv is None else Path(csv)
    if not csv_path.is_file():
        raise InputError(f"the Motive CSV {csv_path} does not exist: give it with --csv MOCAP.csv")
    cal = load_tilt_calibration(calibration, method=method) if calibration is not None else None
    ds = Dataset.open(dataset)
    if results is not None:
        rows = list(load_result_rows(results))
        used = {row.get("method") for row in rows if isinstance(row.get("method"), str)}
        if used and used != {method}:
            raise InputError(
                f"{results} was estimated with {', '.join(sorted(used))}, not {method}: pass --method "
                f"{sorted(used)[0]}"
            )
    else:
        from softjig.io.batch import BatchSettings, dataset_reference, estimate_dataset

        reference = dataset_reference(ds, ds.jig) if method == "refractive" else None
        settings = BatchSettings(jig=ds.jig, method=method, reference=reference)
        with Progress(console=stderr_console(), disable=not progress, transient=True) as bar:
            task = bar.add_task(f"estimating ({method})", total=len(ds))
            rows = list(estimate_dataset(ds, settings, workers=workers, on_row=lambda _r: bar.advance(task)))
    loaded = [row for row in rows if row.get("reference") is not True]
    if loaded and all("error" in row for row in loaded):
        raise EstimationError(
            f"none of the {len(loaded)} loaded frames of {dataset} gave an estimate, e.g. frame "
            f"{loaded[0].get('index')}: {loaded[0].get('error')}"
        )
    found = compare_with_mocap(
        ds,
        rows,
        csv_path,
        cal or TiltCalibration(method=method),
        jig_body=jig_body,
        object_body=object_body,
        frame_offset=frame_offset,
    )
    if found.n_failed:
        warn(f"{found.n_failed} frames gave no estimate and were left out")
    if found.n_untracked:
        warn(f"{found.n_untracked} frames have no mocap sample (a body untracked, or no such frame number)")
    data = {
        "dataset": str(dataset),
        "csv": str(csv_path),
        "method": method,
        "n_frames": len(found.index),
        "n_failed": found.n_failed,
        "n_untracked": found.n_untracked,
        "uncalibrated": _summary_dict(found.raw),
        "calibrated": _summary_dict(found.calibrated) if cal is not None else None,
        "calibration": None if calibration is None else str(calibration),
    }
    if json_output:
        typer.echo(json.dumps(data, allow_nan=False))
        return
    from rich.console import Console
    from rich.table import Table

    table = Table(title=f"{method} against motion capture: {len(found.index)} frames of {dataset}")
    for name in ("estimate", "RMSE (deg)", "RMSE x / y (deg)", "bias x / y (deg)", "mean / max angle (deg)"):
        table.add_column(name, justify="left" if name == "estimate" else "right")
    entries = [("uncalibrated", found.raw)] + ([("calibrated", found.calibrated)] if cal is not None else [])
    for name, e in entries:
        table.add_row(
            name,
            f"{e.rmse_deg:.3f}",
            f"{e.rmse_x_deg:.3f} / {e.rmse_y_deg:.3f}",
            f"{e.bias_x_deg:+.3f} / {e.bias_y_deg:+.3f}",
            f"{e.mean_angle_deg:.3f} / {e.max_angle_deg:.3f}",
        )
    Console().print(table)
