"""`softjig convert SRC OUT`: a dataset to a ROS 2 bag, a bag to a dataset, a truncated bag repaired."""

from __future__ import annotations

import warnings
from pathlib import Path
from typing import Annotated

import typer
from rich.progress import Progress

from softjig.cli.app import app, handle_errors, load_config, stderr_console, warn
from softjig.cli.choices import DEFAULT_METHOD, Method
from softjig.cli.options import (
    DEFAULT_STAMP_TOLERANCE_S,
    ConfigOption,
    LeftTopicOption,
    MethodOption,
    RightTopicOption,
    StampToleranceOption,
)
from softjig.errors import InputError


@app.command()
@handle_errors
def convert(
    src: Annotated[
        Path,
        typer.Argument(help="DATASET (a folder with frames.jsonl) or BAG (a ROS 2 bag's folder or .mcap)."),
    ],
    out: Annotated[
        Path, typer.Argument(help="The bag folder (from a DATASET) or the dataset folder (from a BAG).")
    ],
    config: ConfigOption = None,
    estimate: Annotated[
        bool,
        typer.Option(
            help="DATASET: estimate every loaded frame and write /softjig/part_pose, /softjig/normal, "
            "/softjig/markers and /softjig/estimate (what softjig measures; the truth stays in "
            "/softjig/frame)."
        ),
    ] = True,
    method: MethodOption = DEFAULT_METHOD,
    start_time: Annotated[
        float | None,
        typer.Option(
            help="DATASET: stamp (Unix s) of time_s = 0 for frames without a recorded wall-clock time.",
            show_default="now",
        ),
    ] = None,
    left_topic: LeftTopicOption = None,
    right_topic: RightTopicOption = None,
    stamp_tolerance: StampToleranceOption = DEFAULT_STAMP_TOLERANCE_S,
    repair: Annotated[
        bool,
        typer.Option(
            "--repair",
            help="BAG: rewrite a truncated bag (a killed recorder) up to its last complete chunk into the "
            "new bag folder OUT, as `ros2 bag reindex` would; BAG is left as it is.",
        ),
    ] = False,
    overwrite: Annotated[
        bool, typer.Option(help="Replace a simulation's bag or dataset in OUT (never a recording).")
    ] = False,
    progress: Annotated[bool, typer.Option(help="Show a progress bar on stderr.")] = True,
) -> None:
    """Convert a dataset to a ROS 2 bag folder (what `ros2 bag play` plays), or a bag back to a dataset."""
    from softjig.io.rosbag import is_bag

    if not src.exists():
        raise InputError(f"{src} does not exist: give a dataset folder or a ROS 2 bag")
    if Path(out).resolve() == Path(src).resolve():
        raise InputError("OUT must differ from SRC: convert writes a new folder and never replaces its input")
    from softjig.io.outputs import check_output

    check_output(out, "OUT", [src, config])  # nor writes inside it, nor replaces a folder holding it
    jig = load_config(config) if config else None
    if is_bag(src):
        if repair:
            from softjig.io.rosbag import repair_bag

            kept = repair_bag(src, out)
            typer.echo(f"repaired {src}: kept {kept} messages in complete chunks; wrote {out}")
            return
        from softjig.io.bag_convert import bag_to_dataset
        from softjig.io.rosbag import BagTruncationWarning

        with (
            warnings.catch_warnings(),  # a truncated bag's note is shown below, once, as a warning line
            Progress(console=stderr_console(), disable=not progress, transient=True) as bar,
        ):
            warnings.simplefilter("ignore", BagTruncationWarning)
            task = bar.add_task("converting", total=None)
            summary = bag_to_dataset(
                src,
                out,
                jig=jig,
                left_topic=left_topic,
                right_topic=right_topic,
                tolerance_s=stamp_tolerance,
                overwrite=overwrite,
                on_frame=lambda _i: bar.advance(task),
            )
        for note in summary.notes:
            warn(note)
        typer.echo(f"wrote {summary.n_frames} stereo pairs of {summary.topics} to the dataset {out}")
        if summary.unpaired:
            warn(f"{summary.unpaired} images found no partner within {stamp_tolerance * 1000:g} ms; skipped")
        return
    if repair:
        raise InputError("--repair applies to a ROS 2 bag; a dataset is read as it is")
    if left_topic is not None or right_topic is not None:
        raise InputError("--left-topic and --right-topic apply to a bag, not to a dataset")
    from softjig.io.bag_convert import dataset_to_bag
    from softjig.io.dataset import Dataset

    dataset = Dataset.open(src)
    with Progress(console=stderr_console(), disable=not progress, transient=True) as bar:
        task = bar.add_task("converting", total=len(dataset))
        summary = dataset_to_bag(
            dataset,
            out,
            jig=jig,
            estimate=estimate,
            method=Method(method).value,
            overwrite=overwrite,
            start_unix_s=start_time,
            on_frame=lambda _i: bar.advance(task),
        )
    typer.echo(
        f"wrote {summary.n_frames} stereo pairs"
        + (f" and {summary.n_estimated} estimates" if estimate else "")
        + f" to the ROS 2 bag {out} (play it with `ros2 bag play {out}`)"
    )
    if summary.n_failed:
        warn(f"{summary.n_failed} loaded frames gave no estimate; e.g. {summary.notes[0]}")
