"""`softjig serve`: a warm estimation service a robot asks over ZeroMQ REP (``docs/ros2.md``)."""

from __future__ import annotations

import signal
from typing import Annotated

import typer

from softjig.cli.app import app, handle_errors, load_config
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
    announced_reference,
)
from softjig.errors import InputError


@app.command()
@handle_errors
def serve(
    replay: ReplayOption = None,
    source: SourceOption = None,
    bind: Annotated[
        str, typer.Option(help="ZeroMQ REP endpoint to answer on (loopback unless --allow-remote).")
    ] = "tcp://127.0.0.1:5556",
    pump: Annotated[
        str | None,
        typer.Option(
            help="Serial port of the pump controller, for the fix and release requests.",
            envvar="SOFTJIG_PUMP_PORT",
            show_default=False,
        ),
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
    loop: Annotated[bool, typer.Option(help="Replay: start again at the first frame after the last.")] = True,
    fps: FpsOption = DEFAULT_FPS,
    settle_s: Annotated[
        float,
        typer.Option(min=0.0, help="settled: how long the estimate must stay within its sigma (s)."),
    ] = 0.5,
    settle_sigmas: Annotated[
        float, typer.Option(min=0.0, help="settled: the band, in the estimates' own 1-sigma uncertainties.")
    ] = 3.0,
    max_request_bytes: Annotated[int, typer.Option(min=1, help="Longer requests get an error reply.")] = 64
    * 1024,
    pump_timeout: Annotated[
        float, typer.Option(min=0.1, help="fix/release: how long to wait for the jig to hold (s).")
    ] = 10.0,
    allow_remote: Annotated[
        bool, typer.Option(help="Allow --bind on a non-loopback address (trusted networks only).")
    ] = False,
    warm: Annotated[
        bool,
        typer.Option(
            "--warm-up/--no-warm-up",
            help="Estimate one pair before the cameras open, so the first request is as fast as the rest "
            "(--no-warm-up only to measure what it saves).",
        ),
    ] = True,
) -> None:
    """Answer estimate, settled, fix, release and health requests (JSON over ZeroMQ REP) until Ctrl-C.

    A reference request, while the jig is empty, makes the next pair the reference frame."""
    from softjig.calibration.tilt import load_tilt_calibration
    from softjig.io.cameras import ReplaySource
    from softjig.io.dataset import Dataset
    from softjig.io.stream import check_endpoint
    from softjig.live.loop import LiveSettings
    from softjig.live.serve import (
        EstimationService,
        LoopingReplay,
        PumpAdapter,
        ServeSettings,
        first_loaded_pair,
    )

    method = Method(method).value
    rate = rate.value
    if (replay is None) == (source is None):
        raise InputError("give either --replay DATASET or --source CAMERAS (e.g. --source opencv:0,1)")
    check_endpoint(bind, allow_remote=allow_remote)
    settings = ServeSettings(
        endpoint=bind,
        allow_remote=allow_remote,
        settle_s=settle_s,
        settle_sigmas=settle_sigmas,
        max_request_bytes=max_request_bytes,
        pump_timeout_s=pump_timeout,
    )
    cal = load_tilt_calibration(calibration) if calibration else None
    first_pair = dataset = None
    if replay is not None:
        dataset = Dataset.open(replay)  # once: each lap of a looping replay starts on the same index

        def make() -> ReplaySource:
            return ReplaySource(dataset, rate=rate, fps=fps)

        cameras = LoopingReplay(make) if loop else make()
        jig = load_config(config) if config else dataset.jig
        first_pair = first_loaded_pair(dataset)  # warm up on the first loaded frame
    else:
        from softjig.cli.live import open_cameras

        cameras, jig = open_cameras(
            source, rate=rate, fps=fps, config=config, method=method, part_diameter=part_diameter
        )
    reference = announced_reference(
        jig, method, left=reference_left, right=reference_right, from_dataset=reference_from,
        replay=dataset, use_reference=use_reference,
    )  # fmt: skip
    live = LiveSettings(jig, part_diameter, cal, method, reference)
    pump_adapter = PumpAdapter(pump, timeout_s=pump_timeout) if pump else None
    try:
        service = EstimationService(
            cameras, live, settings, pump=pump_adapter
        )  # binds: a busy port fails here
    except BaseException:
        if pump_adapter is not None:
            pump_adapter.close()
        raise

    def on_signal(_signum, _frame) -> None:
        service.stop()

    previous = {sig: signal.signal(sig, on_signal) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        if warm:  # before the cameras open: no warm-up at the robot's expense
            typer.echo(str(service.warm_up(first_pair)), err=True)
        service.start()
        typer.echo(f"serving on {service.endpoint}", err=True)
        service.serve_forever()
    finally:
        service.close()
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    typer.echo(f"stopped: answered {service.answered} requests", err=True)
