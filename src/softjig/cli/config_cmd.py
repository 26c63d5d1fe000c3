"""`softjig config`: write the default jig."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from softjig.cli.app import app, handle_errors
from softjig.errors import InputError


@app.command("config")
@handle_errors
def config_cmd(
    out: Annotated[Path, typer.Option(help="Where to write the jig's TOML.")] = Path("rig.toml"),
    overwrite: Annotated[bool, typer.Option(help="Replace an existing file.")] = False,
    from_realsense: Annotated[
        str | None,
        typer.Option(
            metavar="SERIAL|any",
            help="Read the cameras from a RealSense D4xx's infrared pair (its serial, or 'any' for the "
            "only one connected): intrinsics and baseline.",
        ),
    ] = None,
) -> None:
    """Write the default (nominal) jig config, to edit for your own jig."""
    from softjig.config import default_jig, save_jig

    if out.exists() and not overwrite:
        raise InputError(f"{out} already exists: choose another --out or pass --overwrite")
    if out.exists() and out.is_dir():
        raise InputError(f"{out} is a folder: give a file name such as {out / 'rig.toml'}")
    if from_realsense is not None:
        from softjig.io.realsense import config_from_realsense

        serial = None if from_realsense.lower() == "any" else from_realsense
        save_jig(config_from_realsense(default_jig(), serial), out)
        typer.echo(f"wrote the jig with RealSense {from_realsense}'s infrared pair to {out}")
        return
    save_jig(default_jig(), out)
    typer.echo(f"wrote the default jig to {out}")
