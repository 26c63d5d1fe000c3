"""`softjig calibrate-stereo`: stereo camera calibration from chessboard/ChArUco views."""

from __future__ import annotations

import glob
import json
from pathlib import Path
from typing import Annotated

import typer

from softjig.cli.app import app, handle_errors, load_config, warn
from softjig.errors import InputError


def _expand(pattern: str, what: str) -> list[Path]:
    paths = sorted(Path(p) for p in glob.glob(pattern))
    paths = [p for p in paths if p.is_file()]
    if not paths:
        raise InputError(
            f"{what} {pattern!r} matches no file: quote the pattern so the shell does not expand it, "
            "e.g. 'left/*.png'"
        )
    return paths


@app.command("calibrate-stereo")
@handle_errors
def calibrate_stereo(
    left_glob: Annotated[str, typer.Argument(help="Left images, a quoted glob ('calib/left*.png').")],
    right_glob: Annotated[str, typer.Argument(help="Right images, a quoted glob; paired in sorted order.")],
    board: Annotated[
        str,
        typer.Option(
            help="COLSxROWS: a chessboard's inner corners as OpenCV counts them (or, with --charuco, "
            "the ChArUco board's squares).",
            show_default=False,
        ),
    ],
    square_mm: Annotated[float, typer.Option(help="Side of a square (mm).", show_default=False)],
    out: Annotated[Path, typer.Option(help="The rig config to write (TOML).", show_default=False)],
    config: Annotated[
        Path | None,
        typer.Option(
            help="Base rig.toml whose cameras are replaced (default: the default jig); the left "
            "camera keeps its pose in J."
        ),
    ] = None,
    charuco: Annotated[bool, typer.Option(help="The board is a ChArUco board.")] = False,
    marker_mm: Annotated[
        float | None,
        typer.Option(help="ChArUco: side of the ArUco markers (mm).", show_default="0.75 square"),
    ] = None,
    dictionary: Annotated[str, typer.Option(help="ChArUco: the ArUco dictionary.")] = "DICT_4X4_50",
    legacy_pattern: Annotated[
        bool, typer.Option(help="ChArUco: the board has OpenCV's pre-4.6 pattern (even rows only).")
    ] = False,
    fix_k3: Annotated[bool, typer.Option(help="Hold k3 = 0 (few views, narrow lens).")] = False,
    drop_outliers: Annotated[bool, typer.Option(help="Calibrate again without the outlier views.")] = False,
    report: Annotated[
        Path | None,
        typer.Option(help="Also write the full calibration (per-view errors, rectification) as JSON."),
    ] = None,
    json_output: Annotated[bool, typer.Option("--json", help="Print one JSON object.")] = False,
    overwrite: Annotated[
        bool, typer.Option("--overwrite", help="Replace an existing --out (and --report) file.")
    ] = False,
) -> None:
    """Calibrate the stereo pair (intrinsics, distortion, baseline, rectification); write the rig config."""
    from softjig.calibration.stereo import Board, calibrate_stereo, parse_board_size, rig_from_calibration
    from softjig.config import save_jig
    from softjig.files import write_text_atomic
    from softjig.io.dataset import load_image

    for option, path in (("--out", out), ("--report", report)):
        if path is not None and path.is_dir():
            raise InputError(f"{option} {path} is a folder: give a file name")
        if path is not None and path.exists() and not overwrite:
            raise InputError(
                f"{option} {path} already exists (a calibrated rig is hard to redo): choose another name, or "
                "pass --overwrite to replace it"
            )
    cols, rows = parse_board_size(board)
    target = Board(
        cols,
        rows,
        square_mm,
        kind="charuco" if charuco else "chessboard",
        marker_mm=marker_mm,
        dictionary=dictionary,
        legacy=legacy_pattern,
    )
    base = load_config(config)
    lefts, rights = _expand(left_glob, "LEFT_GLOB"), _expand(right_glob, "RIGHT_GLOB")
    if len(lefts) != len(rights):
        raise InputError(
            f"LEFT_GLOB matches {len(lefts)} files but RIGHT_GLOB {len(rights)}: the images are paired in "
            "sorted order, so give one right image per left image"
        )
    from softjig.io.outputs import check_output

    for option, path in (("--out", out), ("--report", report)):
        if path is not None:  # a calibration photo is never overwritten
            check_output(path, option, [*lefts, *rights, config])
    cal = calibrate_stereo(
        [load_image(p) for p in lefts],
        [load_image(p) for p in rights],
        target,
        names=[f"{a.name}|{b.name}" for a, b in zip(lefts, rights, strict=True)],
        fix_k3=fix_k3,
        drop_outliers=drop_outliers,
    )
    jig = rig_from_calibration(base, cal)
    save_jig(jig, out)
    data = cal.to_dict()
    data["out"] = str(out)
    if report is not None:
        write_text_atomic(report, json.dumps(data, indent=2) + "\n")
    for message in cal.warnings():
        warn(message)
    if json_output:
        typer.echo(json.dumps(data))
        return
    from rich.console import Console
    from rich.table import Table

    table = Table(title=f"softjig calibrate-stereo ({len(cal.view_names)} pairs)", show_header=False)
    table.add_row("rms_px", f"{cal.rms_px:.4f}")
    table.add_row("fx_px / fy_px (left)", f"{data['fx_px']:.3f} / {data['fy_px']:.3f}")
    table.add_row("cx_px / cy_px (left)", f"{data['cx_px']:.3f} / {data['cy_px']:.3f}")
    table.add_row("fx_px / fy_px (right)", f"{data['right']['fx_px']:.3f} / {data['right']['fy_px']:.3f}")
    table.add_row("baseline_mm", f"{cal.baseline_mm:.3f}")
    table.add_row(
        "right in left (mm)", "({:+.2f}, {:+.2f}, {:+.2f})".format(*data["right_in_left_position_mm"])
    )
    table.add_row(
        "right in left (deg)", "({:+.3f}, {:+.3f}, {:+.3f})".format(*data["right_in_left_rotation_deg"])
    )
    for k, name in enumerate(cal.view_names):
        flag = "  OUTLIER" if k in cal.outliers else ""
        table.add_row(f"view {name}", f"{cal.view_rms_px[k]:.4f} px{flag}")
    table.add_row("wrote", str(out))
    Console().print(table)
