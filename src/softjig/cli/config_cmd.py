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
) -> None:
    """Write a complete jig config (the default one, to edit for your own jig)."""
    from softjig.config import load_marker_csv, save_jig, with_explicit_markers

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
    save_jig(jig, out)
    typer.echo(f"wrote {what} to {out}")
