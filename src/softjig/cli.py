"""The ``softjig`` command line (``DESIGN.md`` §1, command-line contract).

This module only parses arguments and prints; the work is done in the library. Every command is
wrapped in :func:`handle_errors`, which turns softjig's exceptions into a one-line message on stderr and
the contract's exit codes: 2 for bad usage or input (:class:`~softjig.errors.InputError`,
:class:`~softjig.errors.ConfigError`), 3 when the input was valid but no estimate could be made
(:class:`~softjig.errors.EstimationError`). New commands follow the same pattern::

    @app.command()
    @handle_errors
    def estimate(...): ...
"""

from __future__ import annotations

import functools
import time
from collections.abc import Callable
from enum import StrEnum
from pathlib import Path
from typing import Annotated, Any, NoReturn, TypeVar

import typer
from rich.console import Console
from rich.text import Text

from softjig import __version__
from softjig.errors import EstimationError, InputError, SoftjigError

EXIT_OK = 0
EXIT_BAD_INPUT = 2
EXIT_NO_ESTIMATE = 3
EXIT_INTERRUPTED = 130

app = typer.Typer(
    name="softjig",
    help="Sensing soft jig: simulate, estimate a part's principal normal, calibrate.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)

_F = TypeVar("_F", bound=Callable[..., Any])


def _stderr() -> Console:
    # Created per call so it follows sys.stderr (tests swap it); soft wrap keeps messages on one line.
    return Console(stderr=True, soft_wrap=True, highlight=False)


def error(message: str, code: int = EXIT_BAD_INPUT) -> NoReturn:
    """Print ``error: message`` on stderr (red prefix) and exit with ``code``."""
    _stderr().print(Text("error: ", style="bold red") + Text(str(message)))
    raise typer.Exit(code)


def warn(message: str) -> None:
    """Print ``warning: message`` on stderr (yellow prefix)."""
    _stderr().print(Text("warning: ", style="bold yellow") + Text(str(message)))


def handle_errors(func: _F) -> _F:
    """Map softjig's exceptions to the contract's exit codes, with a message and no traceback.

    ``InputError`` (and ``ConfigError``) -> 2, ``EstimationError`` -> 3, any other ``SoftjigError`` -> 2,
    Ctrl-C -> 130.
    """

    @functools.wraps(func)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        try:
            return func(*args, **kwargs)
        except EstimationError as exc:
            error(str(exc), EXIT_NO_ESTIMATE)
        except InputError as exc:
            error(str(exc), EXIT_BAD_INPUT)
        except SoftjigError as exc:
            error(str(exc), EXIT_BAD_INPUT)
        except KeyboardInterrupt:
            error("interrupted", EXIT_INTERRUPTED)

    return wrapper  # type: ignore[return-value]


def parse_numbers(text: str, option: str) -> list[float]:
    """``"30,40,50"`` -> ``[30.0, 40.0, 50.0]``; an InputError naming ``option`` otherwise."""
    try:
        values = [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        values = []
    if not values:
        raise InputError(f"{option} expects comma-separated numbers like 30,40,50, got {text!r}")
    return values


def _load_config(config: Path | None):
    from softjig.config import default_jig, load_jig
    from softjig.errors import ConfigError

    if config is None:
        return default_jig()
    try:
        return load_jig(config)
    except ConfigError as exc:  # name the file as well as the field
        raise ConfigError(str(exc) if str(config) in str(exc) else f"{config}: {exc}") from None


def _version_callback(value: bool) -> None:
    if value:
        typer.echo(f"softjig {__version__}")
        raise typer.Exit()


@app.callback()
def _main(
    version: Annotated[bool, typer.Option("--version", callback=_version_callback, is_eager=True,
                                          help="Print the version and exit.")] = False,
) -> None:
    """Sensing soft jig: simulate, estimate a part's principal normal, calibrate."""


# ------------------------------------------------------------------------------------------ simulate


class Scenario(StrEnum):
    paper_sweep = "paper-sweep"
    cube = "cube"
    single = "single"


@app.command()
@handle_errors
def simulate(
    scenario: Annotated[Scenario, typer.Option(help="What to render.")] = Scenario.paper_sweep,
    out: Annotated[Path | None, typer.Option(
        help="Dataset folder to write.", show_default="out/sim-SCENARIO")] = None,
    config: Annotated[Path | None, typer.Option(
        help="The nominal jig (rig.toml).", show_default="the paper's jig")] = None,
    seed: Annotated[int, typer.Option(min=0, help="Seed of the as-built jig and of every frame.")] = 0,
    diameters: Annotated[str | None, typer.Option(
        help="paper-sweep: cylinder diameters in mm.", show_default="30,40,50,60,70,80")] = None,
    alphas: Annotated[str | None, typer.Option(
        help="paper-sweep: tilts in degrees.", show_default="5,10,15,20")] = None,
    theta_step: Annotated[float | None, typer.Option(
        help="paper-sweep: azimuth step in degrees.", show_default="10")] = None,
    push_depth: Annotated[float, typer.Option(help="Push depth of the part in mm.")] = 3.0,
    part_diameter: Annotated[float | None, typer.Option(help="single: the cylinder's diameter in mm.")]
    = None,
    alpha: Annotated[float | None, typer.Option(
        help="single: tilt in degrees.", show_default="0")] = None,
    theta: Annotated[float | None, typer.Option(
        help="single: tilt azimuth in degrees.", show_default="0")] = None,
    frames: Annotated[int | None, typer.Option(
        help="cube: number of loaded frames.", show_default="60")] = None,
    workers: Annotated[int | None, typer.Option(
        min=1, help="Rendering processes.", show_default="all CPUs")] = None,
    color: Annotated[bool, typer.Option(help="Render colour (RGB) images instead of gray.")] = False,
    overwrite: Annotated[bool, typer.Option(help="Replace an existing dataset in --out.")] = False,
    progress: Annotated[bool, typer.Option(help="Show a progress bar on stderr.")] = True,
) -> None:
    """Render a simulated dataset: the paper's tilt sweep, the cube experiment or a single frame."""
    from softjig.config import CylinderPart
    from softjig.sim import scenarios

    given = {"--diameters": diameters, "--alphas": alphas, "--theta-step": theta_step,
             "--part-diameter": part_diameter, "--alpha": alpha, "--theta": theta, "--frames": frames}
    allowed = {
        Scenario.paper_sweep: {"--diameters", "--alphas", "--theta-step"},
        Scenario.cube: {"--frames"},
        Scenario.single: {"--part-diameter", "--alpha", "--theta"},
    }[scenario]
    stray = [name for name, value in given.items() if value is not None and name not in allowed]
    if stray:
        raise InputError(f"{', '.join(stray)} do(es) not apply to --scenario {scenario.value} "
                         f"(it takes {', '.join(sorted(allowed))})")
    jig = _load_config(config)
    if scenario is Scenario.paper_sweep:
        specs = list(scenarios.paper_sweep(
            diameters_mm=parse_numbers(diameters, "--diameters") if diameters else
            scenarios.PAPER_DIAMETERS_MM,
            alphas_deg=parse_numbers(alphas, "--alphas") if alphas else scenarios.PAPER_ALPHAS_DEG,
            theta_step_deg=10.0 if theta_step is None else theta_step,
            push_depth_mm=push_depth,
        ))
    elif scenario is Scenario.cube:
        specs = scenarios.cube_experiment(n_frames=60 if frames is None else frames,
                                          push_depth_mm=push_depth, rng=seed)
    else:
        if part_diameter is None:
            raise InputError("--scenario single needs --part-diameter MM "
                             "(and optionally --alpha, --theta)")
        specs = scenarios.single(CylinderPart(diameter_mm=part_diameter), alpha or 0.0, theta or 0.0,
                                 push_depth)
    out = out or Path("out") / f"sim-{scenario.value}"
    t0 = time.perf_counter()
    scenarios.simulate_dataset(out, specs, jig, seed=seed, workers=workers, progress=progress,
                               overwrite=overwrite, color=color)
    typer.echo(f"wrote {len(specs)} frames to {out} in {time.perf_counter() - t0:.1f} s")


# ------------------------------------------------------------------------------------------ estimate


def _print_estimate_table(estimate: dict) -> None:
    from rich.table import Table

    table = Table(title="softjig estimate", show_header=False)
    nx, ny, nz = estimate["normal"]
    rows = [
        ("normal (J)", f"({nx:+.5f}, {ny:+.5f}, {nz:+.5f})"),
        ("tilt Ax / Ay", f"{estimate['tilt_x_deg']:+.3f} deg / {estimate['tilt_y_deg']:+.3f} deg"
         + ("" if estimate["calibrated"] else "  (uncalibrated)")),
        ("push depth", f"{estimate['push_depth_mm']:.3f} mm"),
        ("points / rms residual", f"{estimate['n_points']} / {estimate['rms_residual_mm']:.3f} mm"),
        ("markers L / R / matched",
         f"{estimate['n_markers_left']} / {estimate['n_markers_right']} / {estimate['n_matches']}"),
        ("frame source", estimate["frame_source"]),
        ("method", estimate["method"]),
    ]
    for name, value in rows:
        table.add_row(name, value)
    Console().print(table)
    for message in estimate["warnings"]:
        warn(message)


@app.command()
@handle_errors
def estimate(
    inputs: Annotated[list[Path], typer.Argument(
        help="LEFT.png RIGHT.png (one stereo pair) or DATASET (a folder with frames.jsonl).",
        show_default=False)],
    config: Annotated[Path | None, typer.Option(
        help="The nominal jig (rig.toml); required for a pair, a dataset's own rig.toml by default.")]
    = None,
    part_diameter: Annotated[float | None, typer.Option(
        help="Diameter of the part's base in mm (the crop); a dataset's frames name their part.")] = None,
    calibration: Annotated[Path | None, typer.Option(
        help="Tilt calibration JSON (offset_x_deg, offset_y_deg, scale) to apply.")] = None,
    method: Annotated[str, typer.Option(help="Estimation method: paper (as published).")] = "paper",
    json_output: Annotated[bool, typer.Option("--json", help="Print one JSON object.")] = False,
    overlay: Annotated[Path | None, typer.Option(
        help="Write a PNG showing markers, matches, the crop and the normal.")] = None,
    out: Annotated[Path | None, typer.Option(
        help="DATASET: results file (.jsonl, or .csv).", show_default="DATASET/estimates.jsonl")] = None,
    workers: Annotated[int | None, typer.Option(
        min=1, help="DATASET: processes.", show_default="all CPUs")] = None,
    progress: Annotated[bool, typer.Option(help="DATASET: show a progress bar on stderr.")] = True,
) -> None:
    """Estimate the part's principal normal, tilt angles and push depth from a stereo pair or a dataset."""
    import json

    from softjig.calibration.tilt import load_tilt_calibration

    cal = load_tilt_calibration(calibration) if calibration else None
    if len(inputs) == 1:
        _estimate_dataset(inputs[0], config, part_diameter, cal, method, out, workers, progress)
        return
    if len(inputs) != 2:
        raise InputError(f"give LEFT RIGHT (a stereo pair) or one DATASET folder, got {len(inputs)} paths")
    if config is None:
        raise InputError("estimating a stereo pair needs --config RIG.toml (the jig and its cameras)")
    if part_diameter is None:
        raise InputError("estimating a stereo pair needs --part-diameter MM (the part's base diameter)")
    if out is not None or workers is not None:
        raise InputError("--out and --workers apply to a DATASET, not to a stereo pair")
    from softjig.io.dataset import load_image
    from softjig.sensing.pipeline import estimate_pair

    jig = _load_config(config)
    left, right = load_image(inputs[0]), load_image(inputs[1])
    result = estimate_pair(left, right, jig, part_diameter_mm=part_diameter, calibration=cal, method=method)
    if overlay is not None:
        from softjig.io.dataset import encode_png
        from softjig.io.files import write_bytes_atomic
        from softjig.sensing.overlay import draw_overlay

        picture = draw_overlay(left, right, result, jig.cameras.left.K)
        write_bytes_atomic(overlay, encode_png(picture))
    data = result.estimate.to_dict()
    if json_output:
        typer.echo(json.dumps(data))
    else:
        _print_estimate_table(data)


def _estimate_dataset(path, config, part_diameter, cal, method, out, workers, progress) -> None:
    from rich.progress import Progress

    from softjig.io.dataset import Dataset
    from softjig.sensing.batch import BatchSettings, estimate_dataset, write_rows

    dataset = Dataset.open(path)
    jig = _load_config(config) if config else dataset.jig
    settings = BatchSettings(jig=jig, part_diameter_mm=part_diameter, calibration=cal, method=method)
    out = out or Path(path) / "estimates.jsonl"
    t0 = time.perf_counter()
    with Progress(console=_stderr(), disable=not progress, transient=True) as bar:
        task = bar.add_task("estimating", total=len(dataset))
        rows = list(estimate_dataset(dataset, settings, workers=workers,
                                     on_row=lambda _row: bar.advance(task)))
    write_rows(rows, out)
    failed = [row for row in rows if "error" in row]
    typer.echo(f"estimated {len(rows) - len(failed)} of {len(rows)} frames in "
               f"{time.perf_counter() - t0:.1f} s; wrote {out}")
    if failed:
        warn(f"{len(failed)} frames gave no estimate (see their 'error' in {out}), e.g. frame "
             f"{failed[0]['index']}: {failed[0]['error']}")


# -------------------------------------------------------------------------------------------- config


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


def main() -> None:
    """Console-script entry point (``softjig``)."""
    app(prog_name="softjig")


if __name__ == "__main__":  # pragma: no cover
    main()
