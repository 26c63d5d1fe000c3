"""`softjig survey`: measure the unloaded jig and write a rig with its real markers and rest shape."""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import numpy as np
import typer

from softjig.cli.app import app, handle_errors, load_config, warn
from softjig.cli.options import ConfigOption
from softjig.errors import InputError

if TYPE_CHECKING:
    from softjig.sensing.survey import Survey


def _same_file(a: Path, b: Path) -> bool:
    try:
        return a.resolve() == b.resolve()
    except OSError:
        return False


def _check_out(path: Path, inputs: list[Path], overwrite: bool, what: str) -> None:
    if path.exists() and path.is_dir():
        raise InputError(f"{what} {path} is a folder: give a file name")
    for source in inputs:
        if _same_file(path, source) and not overwrite:
            raise InputError(
                f"{what} {path} is the rig the survey reads: write the surveyed rig elsewhere, or pass "
                "--overwrite to replace it"
            )
    if path.exists() and not overwrite:
        raise InputError(f"{path} already exists: choose another {what} or pass --overwrite")


def _print_report(survey, source: str) -> None:
    typer.echo(f"survey of {source}: each marker's offset from the nominal rig (mm, J)")
    typer.echo(
        f"{'marker':>6}  {'nominal x':>9} {'y':>8} {'z':>7}  {'measured x':>10} {'y':>8} {'z':>7}  "
        f"{'dx':>6} {'dy':>6} {'dz':>6} {'lateral':>7}"
    )
    for i, nom, mea, off in zip(
        survey.nominal_index, survey.nominal_xyz_mm, survey.measured_xyz_mm, survey.offset_mm, strict=True
    ):
        typer.echo(
            f"{int(i):>6}  {nom[0]:>9.3f} {nom[1]:>8.3f} {nom[2]:>7.3f}  {mea[0]:>10.3f} {mea[1]:>8.3f} "
            f"{mea[2]:>7.3f}  {off[0]:>+6.3f} {off[1]:>+6.3f} {off[2]:>+6.3f} "
            f"{float(np.hypot(off[0], off[1])):>7.3f}"
        )
    s = survey.summary()
    typer.echo(
        f"markers: {s['markers_surveyed']} surveyed of {s['markers_nominal']} nominal "
        f"({s['markers_not_seen']} not seen, {s['points_unmatched']} triangulated points matched no "
        "nominal marker)"
    )
    typer.echo(
        f"offset from the nominal rig: lateral median {s['lateral_median_mm']:.3f} mm, max "
        f"{s['lateral_max_mm']:.3f} mm; vertical median {s['vertical_median_mm']:.3f} mm, max "
        f"{s['vertical_max_mm']:.3f} mm; 3-D median {s['offset_median_mm']:.3f} mm, max "
        f"{s['offset_max_mm']:.3f} mm"
    )
    typer.echo(f"height noise of one frame: {s['noise_mm']:.3f} mm")


#: What the first frame's ``frame_source`` was, by how its reference measured the head (``None``: not).
_FRAME_SOURCE = {"reference fiducials": "fiducials", "membrane": "membrane", None: "config"}


def _warn_about_the_pose(survey: Survey, level_note: str | None) -> None:
    """Say where the cameras' pose came from when the fiducials were not seen: levelled on the membrane
    (and how far the head was off), or the config's (and why it was not levelled)."""
    level = survey.head_level
    if level is not None and level.source == "membrane":
        shift = ", ".join(f"{v:+.2f}" for v in level.shift_mm)
        warn(
            "the fiducials were not seen, so the stereo head was levelled on the unloaded membrane: it "
            f"sits rotated by {level.rotation_deg:.2f} deg and shifted by ({shift}) mm from the config's "
            f"poses (uncertainty {level.tilt_sigma_deg:.3f} deg), and the surveyed rig's cameras are the "
            "levelled ones. The level takes the rest shape's tilt and centre to be the config's; to "
            "measure the membrane in the jig frame itself, make the fiducials visible to both cameras"
        )
    elif level is None:
        why = level_note or "sensing.extrinsics is 'config'"
        warn(
            f"the fiducials were not seen and {why}, so the cameras' poses come from the config: the "
            "markers are measured in the cameras' nominal pose and the offsets above include the stereo "
            "head's own placement error (a head tilted by 1 deg reads as a membrane shifted by a few mm). "
            "The surveyed rig is consistent with these cameras for the estimator; to measure the membrane "
            "in the jig frame itself, make the fiducials visible to both cameras"
        )


@app.command("survey")
@handle_errors
def survey_cmd(
    inputs: Annotated[
        list[Path],
        typer.Argument(
            help='A dataset folder (its frames marked "reference": true are surveyed; several are '
            "combined, each marker at its median position), or the LEFT and RIGHT images of one pair of "
            "the unloaded jig (then --config is required)."
        ),
    ],
    out: Annotated[Path, typer.Option(help="Where to write the surveyed rig's TOML.")],
    config: ConfigOption = None,
    overwrite: Annotated[
        bool, typer.Option(help="Replace an existing --out (or --markers-csv), even the input rig.")
    ] = False,
    json_output: Annotated[bool, typer.Option("--json", help="Print the report as JSON on stdout.")] = False,
    markers_csv: Annotated[
        Path | None, typer.Option(help="Also write the surveyed markers as CSV (x_mm,y_mm,z_mm).")
    ] = None,
    max_deviation: Annotated[
        float,
        typer.Option(
            help="Accept departures from the nominal rest shape up to this depth (mm) as the jig's own: "
            "without it, markers pushed in beyond 5 noise sigmas (at least 0.5 mm) over a patch are taken "
            "for a part pressed in, and the frame is refused."
        ),
    ] = 0.0,
    raw_heights: Annotated[
        bool,
        typer.Option(
            help="Write each marker's own triangulated height instead of the local fit of its neighbours "
            "(which halves the noise)."
        ),
    ] = False,
    keep_profile: Annotated[
        bool,
        typer.Option(
            help="Keep the nominal dome profile instead of fitting a measured (r, h) table to the markers."
        ),
    ] = False,
) -> None:
    """Survey the unloaded jig: write a rig whose marker layout and rest shape are the measured ones.

    The estimator then uses the surveyed markers and heights as its rest shape. A frame with a part
    pressed in is refused (exit 2).
    """
    from softjig.config import marker_csv_text, save_jig
    from softjig.files import write_text_atomic
    from softjig.io.dataset import Dataset, load_image
    from softjig.sensing.estimator import Estimator
    from softjig.sensing.survey import survey_markers

    if not (np.isfinite(max_deviation) and 0 <= max_deviation <= 50):
        raise InputError(f"--max-deviation must be between 0 and 50 mm, got {max_deviation}")
    if len(inputs) == 1:
        root = inputs[0]
        dataset = Dataset.open(root)
        nominal = load_config(config) if config is not None else dataset.jig
        rig_sources = [root / "rig.toml", *([config] if config is not None else [])]
        frames = [f for f in dataset if f.reference]
        if not frames:
            raise InputError(
                f'{root} has no frame marked "reference": true in frames.jsonl: a survey needs the unloaded '
                "jig; record a pair with no part pressed and survey it (softjig survey LEFT RIGHT --config "
                "RIG.toml --out RIG.toml)"
            )
        pairs = [(f.load_left(), f.load_right()) for f in frames]
        source = f"{root}, frame{'s' if len(frames) > 1 else ''} {', '.join(str(f.index) for f in frames)}"
    elif len(inputs) == 2:
        if config is None:
            raise InputError("surveying a pair needs the nominal rig: pass --config RIG.toml")
        nominal = load_config(config)
        rig_sources = [config]
        pairs = [(load_image(inputs[0]), load_image(inputs[1]))]
        source = f"{inputs[0]} + {inputs[1]}"
    else:
        raise InputError(
            "give a dataset folder, or the LEFT and RIGHT images of one unloaded pair; "
            f"got {len(inputs)} paths"
        )
    _check_out(out, rig_sources, overwrite, "--out")
    if markers_csv is not None:
        _check_out(markers_csv, [*rig_sources, out], overwrite, "--markers-csv")
    from softjig.io.outputs import check_output

    images = inputs if len(inputs) == 2 else []  # the images, and a dataset's files: never, even --overwrite
    for option, path in (("--out", out), ("--markers-csv", markers_csv)):
        if path is not None:
            check_output(path, option, images, datasets=[dataset] if len(inputs) == 1 else [])
    estimator = Estimator(nominal)
    references = [estimator.reference_from_pair(left, right) for left, right in pairs]
    survey = survey_markers(
        references,
        nominal,
        fit_profile=not keep_profile,
        smooth=not raw_heights,
        max_deviation_mm=max_deviation,
    )
    level = survey.head_level
    frame_source = _FRAME_SOURCE[None if level is None else level.source]
    save_jig(survey.jig, out)
    if markers_csv is not None:
        write_text_atomic(
            markers_csv, marker_csv_text(survey.measured_xyz_mm[:, :2], survey.measured_xyz_mm[:, 2])
        )
    if json_output:
        typer.echo(
            json.dumps({"source": source, "out": str(out), "frame_source": frame_source, **survey.to_dict()})
        )
    else:
        _print_report(survey, source)
    _warn_about_the_pose(survey, references[0].level_note)
    typer.echo(f"wrote the surveyed rig to {out}", err=True)
