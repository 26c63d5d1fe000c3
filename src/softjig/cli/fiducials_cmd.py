"""`softjig fiducials`: print the fiducial layout (`sheet`) and check it from a stereo pair (`check`)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

import typer

from softjig.cli.app import app, handle_errors, load_config, parse_numbers, warn
from softjig.errors import EstimationError, InputError

fiducials_app = typer.Typer(
    help="The ArUco fiducials on the base plate: a sheet to print at scale, and a check from a stereo pair.",
    no_args_is_help=True,
)
app.add_typer(fiducials_app, name="fiducials")


def _centers(text: str) -> tuple[tuple[float, float], ...]:
    values = parse_numbers(text.replace(";", ","), "--centers")
    if len(values) % 2:
        raise InputError(
            f"--centers expects x,y pairs in mm, like '-72,-38;72,-38;72,38;-72,38', got {text!r}"
        )
    return tuple((values[k], values[k + 1]) for k in range(0, len(values), 2))


@fiducials_app.command("sheet")
@handle_errors
def sheet(
    out: Annotated[Path, typer.Option(help="The sheet to print: .pdf (exact page size) or .png.")] = Path(
        "fiducials.pdf"
    ),
    config: Annotated[Path | None, typer.Option(help="The jig (rig.toml).")] = None,
    ids: Annotated[str | None, typer.Option(help="Fiducial ids, e.g. 0,1,2,3.")] = None,
    centers: Annotated[str | None, typer.Option(help="Centres in J (mm): 'x,y;x,y;...'.")] = None,
    size_mm: Annotated[float | None, typer.Option(help="Side of each marker, border included (mm).")] = None,
    dictionary: Annotated[str | None, typer.Option(help="ArUco dictionary, e.g. DICT_4X4_50.")] = None,
    config_out: Annotated[
        Path | None, typer.Option(help="Write the jig with this fiducial layout (rig.toml).")
    ] = None,
    dpi: Annotated[int, typer.Option(min=72, max=2400, help="PNG resolution.")] = 600,
) -> None:
    """Write a sheet with the fiducials at exact scale (the view from the cameras) and their config."""
    from softjig.calibration.fiducial_layout import fiducial_sheet, projected_fiducials, with_fiducials
    from softjig.config import save_jig
    from softjig.files import write_bytes_atomic
    from softjig.io.outputs import check_output

    check_output(out, "--out", [config, config_out])
    if config_out is not None:
        check_output(config_out, "--config-out", [out])  # the input rig may be replaced, as asked
    jig = load_config(config)
    jig = with_fiducials(
        jig,
        ids=tuple(int(v) for v in parse_numbers(ids, "--ids")) if ids else None,
        centers_mm=_centers(centers) if centers else None,
        size_mm=size_mm,
        dictionary=dictionary,
    )
    fmt = out.suffix.lower().lstrip(".")
    if fmt not in ("pdf", "png"):
        raise InputError(f"--out must end in .pdf or .png, got {out.name!r}")
    write_bytes_atomic(out, fiducial_sheet(jig, fmt=fmt, dpi=dpi))  # type: ignore[arg-type]
    if config_out is not None:
        save_jig(jig, config_out)
    f = jig.fiducials
    typer.echo(f"wrote {out}: {len(f.ids)} {f.dictionary} markers of {f.size_mm:g} mm, print at 100 %")
    for i, (x, y) in zip(f.ids, f.centers_mm, strict=True):
        typer.echo(f"  id {i}: ({x:g}, {y:g}, {f.z_mm:g}) mm in J")
    if config_out is not None:
        typer.echo(f"wrote {config_out}")
    seen = projected_fiducials(jig)
    for side in ("left", "right"):
        hidden = [i for i, ok in zip(f.ids, seen[f"{side}_inside"], strict=True) if not ok]
        if hidden:
            warn(
                f"fiducials {hidden} fall outside the {side} camera's image per the config: move them inwards"
            )


@fiducials_app.command("check")
@handle_errors
def check(
    left: Annotated[Path, typer.Argument(help="Left image (raw or rectified, per the config).")],
    right: Annotated[Path, typer.Argument(help="Right image.")],
    config: Annotated[Path | None, typer.Option(help="The jig (rig.toml).")] = None,
    max_rms_px: Annotated[float, typer.Option(help="Largest acceptable reprojection RMS (px).")] = 1.0,
    json_output: Annotated[bool, typer.Option("--json", help="Print one JSON object.")] = False,
) -> None:
    """Check that the fiducials are found in a stereo pair and sit where the config says (exit 3 if not)."""
    from softjig.calibration.fiducial_layout import check_fiducials
    from softjig.io.dataset import load_image

    jig = load_config(config)
    images = {"left": load_image(left), "right": load_image(right)}
    for side, image in images.items():
        cam = getattr(jig.cameras, side)
        h, w = image.shape[:2]
        if (w, h) != (cam.width_px, cam.height_px):
            raise InputError(
                f"the {side} image ({left if side == 'left' else right}) is {w} x {h} px but the rig's "
                f"{side} camera is {cam.width_px} x {cam.height_px}: give the rig.toml of the cameras that "
                "took these images (--config), or images of this rig's cameras"
            )
    result = check_fiducials(images["left"], images["right"], jig, max_rms_px=max_rms_px)
    data = result.to_dict()
    if json_output:
        typer.echo(json.dumps(data))
    else:
        typer.echo(
            f"found left {list(result.found_left)}, right {list(result.found_right)}; "
            f"reprojection RMS {result.reprojection_rms_px:.3f} px"
        )
        for i, e in result.per_fiducial_rms_px.items():
            typer.echo(f"  id {i}: {e:.3f} px")
    if not result.ok:
        raise EstimationError("; ".join(result.problems))
