"""`softjig live`: the live sensing loop on cameras or a replay, publishing to a robot (``docs/live.md``)."""

from __future__ import annotations

import signal
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated

import typer

from softjig.cli.app import EXIT_BAD_INPUT, EXIT_NO_ESTIMATE, app, error, handle_errors, load_config, warn
from softjig.cli.choices import DEFAULT_METHOD, Method, ReplayRate
from softjig.cli.options import (
    DEFAULT_FPS,
    CalibrationOption,
    ConfigOption,
    FpsOption,
    MethodOption,
    PartDiameterOption,
    ReplayOption,
    ReplayRateOption,
    SourceOption,
)
from softjig.cli.reference import (
    ReferenceFromOption,
    ReferenceLeftOption,
    ReferenceRightOption,
    UseReferenceOption,
)
from softjig.errors import InputError


@app.command()
@handle_errors
def live(
    replay: ReplayOption = None,
    source: SourceOption = None,
    publish: Annotated[
        str | None,
        typer.Option(
            help="Publish estimates and health on this ZeroMQ endpoint, e.g. tcp://127.0.0.1:5555.",
            show_default=False,
        ),
    ] = None,
    record: Annotated[
        Path | None,
        typer.Option(help="Record every captured pair to this dataset folder.", show_default=False),
    ] = None,
    record_bag: Annotated[
        Path | None,
        typer.Option(
            help="Record every captured pair and its estimate to this ROS 2 bag folder (ros2 bag play).",
            show_default=False,
        ),
    ] = None,
    overwrite: Annotated[
        bool,
        typer.Option(
            help="Replace an --mcap file, or a simulation in --record/--record-bag (never a recording)."
        ),
    ] = False,
    max_frames: Annotated[
        int | None, typer.Option(min=1, help="Stop after this many captured pairs.", show_default="no limit")
    ] = None,
    config: ConfigOption = None,
    part_diameter: PartDiameterOption = None,
    calibration: CalibrationOption = None,
    method: MethodOption = DEFAULT_METHOD,
    reference_left: ReferenceLeftOption = None,
    reference_right: ReferenceRightOption = None,
    reference_from: ReferenceFromOption = None,
    use_reference: UseReferenceOption = True,
    rate: ReplayRateOption = ReplayRate.recorded,
    fps: FpsOption = DEFAULT_FPS,
    mcap: Annotated[
        Path | None,
        typer.Option(
            help="Log images, markers, points, plane, normal and estimates to this MCAP file "
            "(Foxglove, ROS 2).",
            show_default=False,
        ),
    ] = None,
    view: Annotated[
        bool, typer.Option(help="Serve a live 3-D view to the Foxglove app (WebSocket).")
    ] = False,
    view_port: Annotated[int, typer.Option(min=0, max=65535, help="Port of the live view.")] = 8765,
    allow_remote: Annotated[
        bool,
        typer.Option(help="Allow --publish and --view on a non-loopback address (trusted networks only)."),
    ] = False,
    health_period: Annotated[float, typer.Option(min=0.05, help="Seconds between health messages.")] = 1.0,
    rerun: Annotated[bool, typer.Option("--rerun", help="Spawn a Rerun viewer and stream to it.")] = False,
    rerun_save: Annotated[
        Path | None,
        typer.Option(help="Log images, markers, contact, normal and estimates to this Rerun .rrd file."),
    ] = None,
    jsonl: Annotated[bool, typer.Option("--jsonl", help="Print each estimate message on stdout.")] = False,
) -> None:
    """Capture, estimate and publish at camera rate until the replay ends, --max-frames, or Ctrl-C."""
    from softjig.calibration.tilt import load_tilt_calibration
    from softjig.io.stream import TOPIC_ESTIMATE, encode_message
    from softjig.live.loop import LiveLoop, LiveSettings
    from softjig.live.serve import first_loaded_pair, warm_up

    method = Method(method).value
    rate = ReplayRate(rate).value
    if (replay is None) == (source is None):
        raise InputError("give either --replay DATASET or --source CAMERAS (e.g. --source opencv:0,1)")
    if record is not None and record_bag is not None:
        raise InputError(
            "give --record DIR or --record-bag OUT, not both (softjig convert turns one into the other)"
        )
    from softjig.io.outputs import check_output

    given = [config, calibration, reference_left, reference_right, reference_from]  # the replay: below
    for option, path in (("--record", record), ("--record-bag", record_bag), ("--mcap", mcap),
                         ("--rerun-save", rerun_save)):  # fmt: skip
        if path is not None:
            check_output(path, option, given)
    cal = load_tilt_calibration(calibration) if calibration else None
    if replay is not None:
        cameras, jig = _open_replay(replay, rate=rate, fps=fps, config=config, record=record)
    else:
        cameras, jig = open_cameras(
            source, rate=rate, fps=fps, config=config, method=method, part_diameter=part_diameter
        )
    from softjig.cli.reference import announced_reference

    reference = announced_reference(
        jig, method, left=reference_left, right=reference_right, from_dataset=reference_from,
        replay=cameras.dataset if replay is not None else None, use_reference=use_reference,
    )  # fmt: skip
    settings = LiveSettings(
        jig=jig,
        part_diameter_mm=part_diameter,
        calibration=cal,
        method=method,
        reference=reference,
        max_frames=max_frames,
        health_period_s=health_period,
    )
    outputs = _Outputs(
        publish=publish,
        record=record,
        record_bag=record_bag,
        mcap=mcap,
        view=view,
        view_port=view_port,
        allow_remote=allow_remote,
        rerun=rerun,
        rerun_save=rerun_save,
        overwrite=overwrite,
    )
    sinks, recorder = _open_outputs(outputs, jig, part_diameter)

    def on_outcome(_outcome, message) -> None:
        if jsonl:  # exactly what goes on the wire: with schema and version
            typer.echo(encode_message(TOPIC_ESTIMATE, message)[1].decode("utf-8"))

    loop = LiveLoop(cameras, settings, sinks=sinks, recorder=recorder, on_outcome=on_outcome)

    def on_sigterm(_signum, _frame) -> None:
        raise KeyboardInterrupt

    # Before the cameras open (loop.run opens them): the first pair is estimated as fast as the hundredth.
    first_pair = first_loaded_pair(cameras.dataset) if replay is not None else None
    typer.echo(str(warm_up(loop, first_pair)), err=True)
    previous = signal.signal(signal.SIGTERM, on_sigterm)
    try:
        summary = loop.run()
    finally:
        signal.signal(signal.SIGTERM, previous)
    _report(summary, record or record_bag)


def _open_replay(replay: Path, *, rate: str, fps: float, config: Path | None, record: Path | None):
    """The replayed dataset as the cameras, and the jig (``--config``, else the dataset's)."""
    import warnings

    from softjig.io.cameras import ReplaySource
    from softjig.io.dataset import DatasetLineWarning

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DatasetLineWarning)  # shown below, once, as a warning line
        cameras = ReplaySource(replay, rate=rate, fps=fps)
    for note in cameras.dataset.warnings:
        warn(note)
    if len(cameras.dataset) == 0:
        raise InputError(f"{replay} has no frames (its frames.jsonl lists none): nothing to replay")
    if record is not None and record.resolve().is_relative_to(cameras.dataset.root.resolve()):
        raise InputError(
            f"--record {record} is inside the replayed dataset {replay}: recording there would "
            "replace what is replayed; record to another folder"
        )
    return cameras, (load_config(config) if config else cameras.dataset.jig)


def open_cameras(
    source: str, *, rate: str, fps: float, config: Path | None, method: str, part_diameter: float | None
):
    """The cameras of ``--source``, and the jig (``--config``, else the default one, with a warning); of
    ``softjig live`` and ``softjig serve`` alike."""
    from softjig.io.cameras import open_source

    if rate != "recorded":
        raise InputError("--rate applies to --replay, not to cameras")
    if config is None:
        warn("no --config: using the default (the paper's) jig; pass the rig.toml of your cameras")
    jig = load_config(config)
    if part_diameter is None and method == "paper":
        raise InputError(
            "the paper's method on live cameras needs --part-diameter MM (the part's base diameter), "
            "or use --method refractive"
        )
    cam = jig.cameras.left
    return open_source(source, width_px=cam.width_px, height_px=cam.height_px, fps=fps), jig


@dataclass(frozen=True)
class _Outputs:
    """Where the loop's pairs and estimates go (the options of the same names)."""

    publish: str | None
    record: Path | None
    record_bag: Path | None
    mcap: Path | None
    view: bool
    view_port: int
    allow_remote: bool
    rerun: bool
    rerun_save: Path | None
    overwrite: bool


def _open_outputs(out: _Outputs, jig, part_diameter: float | None) -> tuple[list, object | None]:
    """Open the sinks (Rerun, the publisher, Foxglove) and the recorder; everything opened is closed again
    if one fails to open."""
    from softjig.config import CylinderPart, part_to_dict
    from softjig.live.loop import PublisherSink, Recorder

    sinks: list = []
    recorder = None
    default_part = part_to_dict(CylinderPart(part_diameter)) if part_diameter else None
    try:
        if out.rerun or out.rerun_save is not None:
            from softjig.live.rerun_viewer import RerunViewer

            sinks.append(RerunViewer(save_path=out.rerun_save, spawn=out.rerun, overwrite=out.overwrite))
        if out.publish is not None:
            from softjig.io.stream import Publisher

            publisher = Publisher(out.publish, allow_remote=out.allow_remote)
            sinks.append(PublisherSink(publisher))
            typer.echo(f"publishing on {publisher.endpoint}", err=True)
        if out.mcap is not None or out.view:
            from softjig.live.viewer import FoxgloveViewer

            viewer = FoxgloveViewer(
                mcap_path=out.mcap,
                serve=out.view,
                port=out.view_port,
                allow_remote=out.allow_remote,
                host="0.0.0.0" if out.allow_remote else "127.0.0.1",
                overwrite=out.overwrite,
            )
            sinks.append(viewer)
            if out.view:
                typer.echo(f"live view: open ws://127.0.0.1:{viewer.port} in the Foxglove app", err=True)
        if out.record is not None:
            recorder = Recorder(out.record, jig, default_part=default_part, overwrite=out.overwrite)
        if (
            out.record_bag is not None
        ):  # a recorder of pairs and a sink of estimates (softjig.live.record_bag)
            from softjig.live.record_bag import BagRecorder

            recorder = BagRecorder(out.record_bag, jig, default_part=default_part, overwrite=out.overwrite)
            sinks.append(recorder)
    except BaseException:
        for sink in sinks:
            sink.close()
        raise
    return sinks, recorder


def _report(summary, recorded_to: Path | None) -> None:
    """Print the run's summary on stderr; exit 2 or 3 when it gave nothing (an interrupted run only warns)."""
    final = summary.final
    median = "-" if final.latency_median_s is None else f"{1000 * final.latency_median_s:.0f} ms"
    p95 = "-" if final.latency_p95_s is None else f"{1000 * final.latency_p95_s:.0f} ms"
    typer.echo(
        f"{'stopped' if summary.interrupted else 'done'}: {final.captured} pairs captured, "
        f"{final.processed} estimated ({final.estimated} with an estimate, {final.failed} without), "
        f"{final.dropped} dropped while busy, latency median {median} / p95 {p95}, "
        f"{summary.throughput_hz:.1f} frames/s"
        + (f", {final.recorded} recorded to {recorded_to}" if recorded_to else "")
        + (f" ({final.not_recorded} not recorded)" if final.not_recorded else "")
        + (f", {final.camera_errors} camera errors" if final.camera_errors else "")
        + (f", {final.bad_frames} unreadable frames skipped" if final.bad_frames else ""),
        err=True,
    )
    for note in summary.sink_errors:
        warn(note)
    if final.bad_frames:
        if not final.captured and not summary.interrupted:
            error(f"no frame of the replay could be read ({final.bad_frames} tried); the first: "
                  f"{summary.first_bad_frame}", EXIT_BAD_INPUT)  # fmt: skip
        warn(f"{final.bad_frames} frames of the replay could not be read and were skipped; the first: "
             f"{summary.first_bad_frame}")  # fmt: skip
    if final.processed and not final.estimated:
        message = f"no frame gave an estimate; the last: {summary.last_error}"
        if summary.interrupted:  # stopped by the user: a clean stop, not a failure of this run
            warn(message)
            return
        code = EXIT_BAD_INPUT if summary.last_exit_code == EXIT_BAD_INPUT else EXIT_NO_ESTIMATE
        error(message, code)
