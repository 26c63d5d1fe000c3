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
) -> None:
    """Write the default (nominal) jig config, to edit for your own jig."""
    from softjig.config import default_jig, save_jig

    if out.exists() and not overwrite:
        raise InputError(f"{out} already exists: choose another --out or pass --overwrite")
    if out.exists() and out.is_dir():
        raise InputError(f"{out} is a folder: give a file name such as {out / 'rig.toml'}")
    save_jig(default_jig(), out)
    typer.echo(f"wrote the default jig to {out}")
