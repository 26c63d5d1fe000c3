"""`softjig config`: write the default jig, or a jig with the markers of a CSV file."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from softjig.cli.app import app, handle_errors, load_config
from softjig.errors import InputError


@app.command("config")
@handle_errors
def config_cmd(
    out: Annotated[Path, typer.Option(help="Where to write the jig's TOML.")] = Path("rig.toml"),
    overwrite: Annotated[bool, typer.Option(help="Replace an existing file.")] = False,
    config: Annotated[
        Path | None, typer.Option(help="Start from this jig's TOML instead of the default jig.")
    ] = None,
    markers_csv: Annotated[
        Path | None,
        typer.Option(
            help="A CSV of marker centres (header x_mm,y_mm, optionally z_mm: measured heights) for a "
            "hand-made membrane: the jig gets an explicit marker layout, written inline in the TOML, and "
            "markers.pitch_mm becomes their median nearest-neighbour distance."
        ),
    ] = None,
    from_realsense: Annotated[
        str | None,
        typer.Option(
            metavar="SERIAL|any",
            help="Take the cameras from a RealSense D4xx's infrared pair (its serial, or 'any' for the "
            "only one connected): intrinsics and baseline, 848x480.",
        ),
    ] = None,
) -> None:
    """Write the default (nominal) jig config, to edit for your own jig.

    With --config, start from that jig; with --markers-csv, give it the explicit marker layout of a CSV
    file (a hand-made membrane). The file is complete: every section is named, as loading requires.
    """
    from softjig.config import load_marker_csv, save_jig, with_explicit_markers
    from softjig.io.outputs import check_output

    check_output(out, "--out", [markers_csv])  # --config itself may be replaced, with --overwrite
    if out.exists() and out.is_dir():
        raise InputError(f"{out} is a folder: give a file name such as {out / 'rig.toml'}")
    if out.exists() and not overwrite:
        raise InputError(f"{out} already exists: choose another --out or pass --overwrite")
    jig = load_config(config)
    what = f"the jig of {config}" if config is not None else "the default jig"
    if markers_csv is not None:
        centers, z = load_marker_csv(markers_csv)
        jig = with_explicit_markers(jig, centers, z)
        what += f" with the {len(centers)} markers of {markers_csv}"
    if from_realsense is not None:
        from softjig.io.realsense import config_from_realsense

        jig = config_from_realsense(jig, None if from_realsense.lower() == "any" else from_realsense)
        what += f" with the infrared pair of RealSense {from_realsense}"
    save_jig(jig, out)
    typer.echo(f"wrote {what} to {out}")
