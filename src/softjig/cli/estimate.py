"""`softjig estimate`: a stereo pair or a whole dataset to estimates."""

from __future__ import annotations

import gc
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from softjig.cli.app import app, handle_errors, load_config, stderr_console, warn
from softjig.cli.choices import DEFAULT_METHOD
from softjig.cli.options import (
    DEFAULT_STAMP_TOLERANCE_S,
    CalibrationOption,
    ConfigOption,
    LeftTopicOption,
    MethodOption,
    PartDiameterOption,
    RightTopicOption,
    StampToleranceOption,
)
from softjig.errors import InputError

if TYPE_CHECKING:
    from softjig.calibration.tilt import TiltCalibration


def _print_estimate_table(estimate: dict) -> None:
    from rich.table import Table

    table = Table(title="softjig estimate", show_header=False)
    nx, ny, nz = estimate["normal"]
    rows = [
        ("normal (J)", f"({nx:+.5f}, {ny:+.5f}, {nz:+.5f})"),
        (
            "tilt Ax / Ay",
            f"{estimate['tilt_x_deg']:+.3f} deg / {estimate['tilt_y_deg']:+.3f} deg"
            + ("" if estimate["calibrated"] else "  (uncalibrated)"),
        ),
        ("push depth", f"{estimate['push_depth_mm']:.3f} mm"),
        ("points / rms residual", f"{estimate['n_points']} / {estimate['rms_residual_mm']:.3f} mm"),
        (
            "markers L / R / matched",
            f"{estimate['n_markers_left']} / {estimate['n_markers_right']} / {estimate['n_matches']}",
        ),
        ("frame source", estimate["frame_source"]),
        ("quality", _quality_text(estimate)),
        *(
            [
                (
                    "tilt 1-sigma x / y",
                    f"{estimate['tilt_sigma_x_deg']:.3f} deg / {estimate['tilt_sigma_y_deg']:.3f} deg",
                ),
                ("contact centroid", "({:+.2f}, {:+.2f}) mm".format(*estimate["contact_centroid_xy_mm"])),
                (
                    "contact area",
                    f"{estimate['contact_area_mm2']:.0f} mm^2"
                    + ("  (partial)" if estimate["contact_partial"] else ""),
                ),
                ("indentations against", estimate["indentation_reference"]),
            ]
            if estimate.get("tilt_sigma_x_deg") is not None
            else []
        ),
        ("method", estimate["method"]),
    ]
    for name, value in rows:
        table.add_row(name, value)
    from rich.console import Console

    console = Console()
    console.print(table)
    for message in estimate["warnings"]:
        if message.startswith(SUSPECT_PREFIX):
            console.print(f"SUSPECT: {message[len(SUSPECT_PREFIX) :]}", style="bold red", markup=False)
        else:
            warn(message)


# softjig.sensing.results.SUSPECT_PREFIX, not imported: the command line loads the estimator lazily
SUSPECT_PREFIX = "suspect: "


def _quality_text(estimate: dict) -> str:
    """``ok``, or ``SUSPECT`` (the reasons follow the table), with the tilt's 1-sigma when known."""
    quality = estimate.get("quality", "ok")
    sigma = estimate.get("tilt_sigma_deg")
    text = "SUSPECT (see below)" if quality == "suspect" else str(quality)
    return text + ("" if sigma is None else f"  (tilt 1-sigma {sigma:.2f} deg)")


@app.command()
@handle_errors
def estimate(
    inputs: Annotated[
        list[Path],
        typer.Argument(
            help="LEFT.png RIGHT.png (one stereo pair), DATASET (a folder with frames.jsonl) or BAG (a "
            "ROS 2 bag's folder or .mcap).",
            show_default=False,
        ),
    ],
    config: ConfigOption = None,
    part_diameter: PartDiameterOption = None,
    calibration: CalibrationOption = None,
    method: MethodOption = DEFAULT_METHOD,
    reference_left: Annotated[
        Path | None, typer.Option(help="PAIR: left image of the unloaded jig (a reference frame).")
    ] = None,
    reference_right: Annotated[
        Path | None, typer.Option(help="PAIR: right image of the unloaded jig (a reference frame).")
    ] = None,
    use_reference: Annotated[
        bool,
        typer.Option(
            "--reference/--no-reference",
            help="DATASET: measure indentations against its unloaded reference frame (else the rest shape).",
        ),
    ] = True,
    part_size: Annotated[
        bool,
        typer.Option(
            "--part-size/--no-part-size",
            help="DATASET: use each frame's recorded part size (--no-part-size: the size-free estimate of "
            "the refractive method, on the same data).",
        ),
    ] = True,
    displacements: Annotated[
        Path | None,
        typer.Option(help="PAIR: write every marker's id, position and 3-D displacement (.csv or .npz)."),
    ] = None,
    json_output: Annotated[bool, typer.Option("--json", help="Print one JSON object.")] = False,
    overlay: Annotated[
        Path | None, typer.Option(help="Write a PNG showing markers, matches, the crop and the normal.")
    ] = None,
    out: Annotated[
        Path | None,
        typer.Option(help="DATASET: results file (.jsonl, or .csv).", show_default="DATASET/estimates.jsonl"),
    ] = None,
    workers: Annotated[
        int | None, typer.Option(min=1, help="DATASET: processes.", show_default="all CPUs")
    ] = None,
    progress: Annotated[bool, typer.Option(help="DATASET: show a progress bar on stderr.")] = True,
    left_topic: LeftTopicOption = None,
    right_topic: RightTopicOption = None,
    stamp_tolerance: StampToleranceOption = DEFAULT_STAMP_TOLERANCE_S,
) -> None:
    """Estimate the part's principal normal, tilt angles and push depth from a stereo pair or a dataset."""

    cal = None
    if calibration is not None:
        from softjig.calibration.tilt import load_tilt_calibration

        cal = load_tilt_calibration(calibration, method=method.value)
    method_name = method.value
    if len(inputs) == 1:
        pair_only = {
            "--json": json_output,
            "--overlay": overlay,
            "--reference-left": reference_left,
            "--reference-right": reference_right,
            "--displacements": displacements,
        }
        _check_dataset_options(
            pair_only, part_size=part_size, part_diameter=part_diameter, method=method_name
        )
        from softjig.io.rosbag import is_bag

        if is_bag(inputs[0]):  # a ROS 2 bag: its folder or its .mcap (softjig.cli.estimate_bag)
            from softjig.cli.estimate_bag import estimate_bag
            from softjig.io.outputs import check_output

            if out is not None:
                check_output(out, "--out", [config, calibration])

            estimate_bag(
                inputs[0], config, part_diameter, cal, method_name, out, workers, progress, use_reference,
                left_topic, right_topic, stamp_tolerance, part_size=part_size,
            )  # fmt: skip
            return
        if left_topic is not None or right_topic is not None:
            raise InputError("--left-topic and --right-topic apply to a ROS 2 bag (a folder or .mcap)")
        _estimate_dataset(
            inputs[0], config, part_diameter, cal, method_name, out, workers, progress, use_reference,
            inputs=(config, calibration), part_size=part_size,
        )  # fmt: skip
        return
    _check_pair_options(
        inputs, config, reference_left, reference_right, out=out, workers=workers, part_size=part_size
    )
    with _collector_paused():
        _estimate_pair(
            inputs, config, cal, method_name, part_diameter, reference_left, reference_right,
            calibration, overlay=overlay, displacements=displacements, json_output=json_output,
        )  # fmt: skip


@contextmanager
def _collector_paused() -> Iterator[None]:
    """Pause Python's cyclic garbage collector for a bounded piece of work, then restore it.

    A single-pair estimate imports NumPy, SciPy, OpenCV and Numba and loads its compiled kernels: about
    10^5 long-lived objects, none of them garbage, that every collection pass walks again
    (``benchmarks/bench_startup.py``). One pair's work makes little cyclic garbage, and reference counting
    still frees everything else, so the collector waits until the work is done. The objects made
    meanwhile are then moved to the oldest generation (``gc.freeze`` and ``gc.unfreeze``) rather than
    left in the youngest, whose first pass after the pause would otherwise walk them all at once; a
    later full pass still collects any garbage among them.
    """
    was_enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        gc.freeze()
        gc.unfreeze()
        if was_enabled:
            gc.enable()


def _estimate_pair(
    inputs: list[Path],
    config: Path | None,
    cal: TiltCalibration | None,
    method_name: str,
    part_diameter: float | None,
    reference_left: Path | None,
    reference_right: Path | None,
    calibration: Path | None,
    *,
    overlay: Path | None,
    displacements: Path | None,
    json_output: bool,
) -> None:
    """Estimate one stereo pair (``inputs``: LEFT.png RIGHT.png) and print it; see :func:`estimate`."""
    import json

    from softjig.io.dataset import load_image
    from softjig.io.outputs import check_output
    from softjig.sensing.estimator import Estimator

    given = (*inputs, config, calibration, reference_left, reference_right)
    for option, path in (("--overlay", overlay), ("--displacements", displacements)):
        if path is not None:  # before any work: nothing the user recorded is overwritten
            check_output(path, option, given)
    jig = load_config(config)
    left, right = load_image(inputs[0]), load_image(inputs[1])
    estimator = Estimator(jig, method=method_name, calibration=cal)
    if reference_left is not None and reference_right is not None:  # checked unloaded, of this rig
        from softjig.io.reference import reference_from_pair

        reference = reference_from_pair(
            load_image(reference_left), load_image(reference_right), jig, estimator=estimator,
            where="--reference-left/--reference-right",
        )  # fmt: skip
        estimator = estimator.with_reference(reference)
    result = estimator.estimate(left, right, part_diameter_mm=part_diameter)
    if overlay is not None:
        from softjig.evaluation.overlay import draw_overlay
        from softjig.files import write_bytes_atomic
        from softjig.io.dataset import encode_png
        from softjig.sensing.rectify import rectify_pair

        left, right, used_jig = rectify_pair(left, right, jig)  # the markers' pixels are rectified ones
        write_bytes_atomic(overlay, encode_png(draw_overlay(left, right, result, used_jig)))
    if displacements is not None:
        from softjig.io.export import write_displacements

        write_displacements(result, displacements)
    data = result.estimate.to_dict()
    if json_output:
        typer.echo(json.dumps(data))
    else:
        _print_estimate_table(data)


def _check_dataset_options(
    pair_only: dict[str, object], *, part_size: bool, part_diameter: float | None, method: str
) -> None:
    """Refuse, for one DATASET or BAG, the options of a stereo pair and a size-less paper estimate."""
    given = [name for name, value in pair_only.items() if value]
    if given:
        raise InputError(f"{', '.join(given)} apply to a stereo pair; a DATASET's results go to --out")
    if not part_size and (part_diameter is not None or method == "paper"):
        raise InputError(
            "--no-part-size estimates without the part's size: it excludes --part-diameter and "
            "--method paper (which needs the size)"
        )


def _check_pair_options(
    inputs: list[Path],
    config: Path | None,
    reference_left: Path | None,
    reference_right: Path | None,
    *,
    out: Path | None,
    workers: int | None,
    part_size: bool,
) -> None:
    """Refuse, for a stereo pair, a wrong number of paths, a missing config and the DATASET options."""
    if len(inputs) != 2:
        raise InputError(f"give LEFT RIGHT (a stereo pair) or one DATASET folder, got {len(inputs)} paths")
    if config is None:
        raise InputError("estimating a stereo pair needs --config RIG.toml (the jig and its cameras)")
    if (reference_left is None) != (reference_right is None):
        raise InputError("give both --reference-left and --reference-right (one unloaded stereo pair)")
    if out is not None or workers is not None or not part_size:
        raise InputError(
            "--out, --workers and --no-part-size apply to a DATASET, not to a stereo pair (whose part size "
            "is --part-diameter, or none)"
        )


def _estimate_dataset(
    path: Path,
    config: Path | None,
    part_diameter: float | None,
    cal: TiltCalibration | None,
    method: str,
    out: Path | None,
    workers: int | None,
    progress: bool,
    use_reference: bool,
    inputs: tuple[Path | None, ...] = (),
    part_size: bool = True,
) -> None:
    """Estimate every frame of a dataset on ``workers`` processes, streaming the rows to ``out``.

    This process opens the dataset (one pass over ``frames.jsonl``, only line offsets kept), computes the
    reference markers (refractive method; this also loads the Numba caches) and estimates up to the first
    loaded frame; the workers it then forks inherit that warm state and read and decode their frames
    themselves (:func:`softjig.io.batch.estimate_dataset`).

    Refused before any frame is estimated (exit 2): a dataset without frames, an ``out`` that is one of the
    dataset's own files or one of the command's ``inputs`` (the rig, the calibration), a ``part_diameter``
    that is not a positive number of mm smaller than the membrane. A dataset of which no frame gave
    an estimate exits 3, after writing every frame's error to ``out``."""
    import warnings

    from rich.console import Console
    from rich.progress import Progress

    from softjig.errors import EstimationError
    from softjig.io.batch import BatchSettings, dataset_reference, estimate_dataset_to_file
    from softjig.io.dataset import Dataset, DatasetLineWarning

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DatasetLineWarning)  # shown below, once, as a warning line
        dataset = Dataset.open(path)
    for note in dataset.warnings:
        warn(note)
    if len(dataset) == 0:
        raise InputError(f"{path} has no frames (its frames.jsonl lists none): nothing to estimate")
    out = out or Path(path) / "estimates.jsonl"
    _refuse_to_overwrite_an_input(out, dataset, inputs)
    jig = load_config(config) if config else dataset.jig
    reference = dataset_reference(dataset, jig) if use_reference and method == "refractive" else None
    settings = BatchSettings(
        jig=jig,
        part_diameter_mm=part_diameter,
        calibration=cal,
        method=method,
        reference=reference,
        frame_part_size=part_size,
    )
    t0 = time.perf_counter()
    # Rows stream to a temporary file as they complete, in frame order; it replaces `out` only at the end.
    suspect: list[int] = []  # frame indices of the suspect estimates

    with Progress(console=stderr_console(), disable=not progress, transient=True) as bar:
        task = bar.add_task("estimating", total=len(dataset))

        def on_row(row: dict) -> None:
            bar.advance(task)
            if row.get("quality") == "suspect":
                suspect.append(row["index"])

        summary = estimate_dataset_to_file(dataset, settings, out, workers=workers, on_row=on_row)
    typer.echo(
        f"estimated {summary.n_loaded - summary.n_failed} of {summary.n_loaded} loaded frames in "
        f"{time.perf_counter() - t0:.1f} s ({method}"
        + (", indentations against the reference frame" if reference is not None else "")
        + f"); wrote {out}"
    )
    if suspect:
        Console(stderr=True).print(
            f'SUSPECT: {len(suspect)} estimates failed their self-check (quality "suspect", the reasons '
            f"among their warnings in {out}): frames {', '.join(map(str, suspect[:10]))}"
            + (" ..." if len(suspect) > 10 else ""),
            style="bold red",
            markup=False,
        )
    if summary.n_loaded == 0:
        raise EstimationError(
            f"{path} has only unloaded reference frames: no frame with a part pressed in to estimate"
        )
    if summary.first_failure is not None:
        first = summary.first_failure
        message = (
            f"{summary.n_failed} frames gave no estimate (see their 'error' in {out}), e.g. frame "
            f"{first['index']}: {first['error']}"
        )
        if summary.n_failed == summary.n_loaded:
            raise EstimationError(f"no frame of {path} gave an estimate: {message}")
        warn(message)


def _refuse_to_overwrite_an_input(out: Path, dataset, inputs: tuple[Path | None, ...]) -> None:
    """An InputError if ``out`` is not a results file name, is one of the dataset's (or another
    dataset's) own files, or one of the command's input files."""
    from softjig.io.outputs import check_output

    check_output(out, "--out", inputs, datasets=(dataset,))
    if Path(out).is_dir():
        raise InputError(f"cannot write {out}: it is a folder; give a file name inside it")
    if Path(out).suffix.lower() not in (".jsonl", ".json", ".ndjson", ".csv"):
        raise InputError(f"--out {out}: the results file must end in .jsonl or .csv")
