"""The ``softjig`` Typer app and what every command shares (``DESIGN.md`` §1, command-line contract).

Commands live in their own modules of :mod:`softjig.cli` and only parse arguments and print; the work
is done in the library. Every command is wrapped in :func:`handle_errors`, which turns softjig's
exceptions into a one-line message on stderr and the contract's exit codes: 2 for bad usage or input
(:class:`~softjig.errors.InputError`, :class:`~softjig.errors.ConfigError`), 3 when the input was valid
but no estimate could be made (:class:`~softjig.errors.EstimationError`).

A command's module is imported only when that command runs, so that ``softjig --help`` and a single
estimate start fast. A new command is two steps:

1. its module ``softjig/cli/<module>.py`` registers it on :data:`app`::

       @app.command()
       @handle_errors
       def estimate(...): ...

   (a command group: ``app.add_typer(sub_app, name="jig")``);
2. one line in :data:`COMMANDS` names the command, its module and its one-line help (the first line of
   its docstring; ``tests/test_cli_app.py`` checks they agree), which ``--help`` lists without importing
   the module.

This module stays light (no NumPy, no softjig internals at import time): every command pays for it.
"""

from __future__ import annotations

import functools
import importlib
import json
import math
import os
import sys
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, NoReturn, TypeVar

import typer
import typer.core
import typer.main

from softjig import __version__
from softjig.cli import coercion
from softjig.errors import EstimationError, InputError, SoftjigError
from softjig.io.workers import Terminated, signals_unwrapped, terminate_raises

if TYPE_CHECKING:
    import numpy as np
    from rich.console import Console

EXIT_OK = 0
EXIT_BAD_INPUT = 2
EXIT_NO_ESTIMATE = 3
EXIT_INTERRUPTED = 130

#: Every command of ``softjig`` in the order ``--help`` lists them: name -> (module, one-line help).
COMMANDS: dict[str, tuple[str, str]] = {
    "align-jig": (
        "softjig.cli.align",
        "Find the jig's pose in the robot base frame (T_robot_jig) by PnP on its four white circles.",
    ),
    "calibrate": (
        "softjig.cli.calibrate",
        "Fit the paper's tilt calibration (offsets Ox, Oy and scale S) to a tilt sweep and write it as JSON.",
    ),
    "calibrate-stereo": (
        "softjig.cli.calibrate_stereo",
        "Calibrate the stereo pair (intrinsics, distortion, baseline, rectification); write the rig config.",
    ),
    "compare": (
        "softjig.cli.compare",
        "RMSE of the paper's method (calibrated) beside ours (uncalibrated and calibrated), held out.",
    ),
    "config": ("softjig.cli.config_cmd", "Write the default (nominal) jig config, to edit for your own jig."),
    "demo": (
        "softjig.cli.demo",
        "Run the paper's experiments on the simulated jig: sweep, calibration, RMSE grid, cube, report.",
    ),
    "estimate": (
        "softjig.cli.estimate",
        "Estimate the part's principal normal, tilt angles and push depth from a stereo pair or a dataset.",
    ),
    "mocap": (
        "softjig.cli.mocap",
        "Compare a dataset's normals with motion capture (T_d = inv(T_j) T_o, n_d = R_d z): RMSE, bias.",
    ),
    "live": (
        "softjig.cli.live",
        "Capture, estimate and publish at camera rate until the replay ends, --max-frames, or Ctrl-C.",
    ),
    "serve": (
        "softjig.cli.serve",
        "Answer estimate, settled, fix, release and health requests (JSON over ZeroMQ REP) until Ctrl-C.",
    ),
    "convert": (
        "softjig.cli.convert",
        "Convert a dataset to a ROS 2 bag folder (what `ros2 bag play` plays), or a bag back to a dataset.",
    ),
    "simulate": (
        "softjig.cli.simulate",
        "Render a simulated dataset: the paper's sweep, the cube experiment, a single frame or a jig zoo.",
    ),
    "study": ("softjig.cli.study", "Run a design study: render and estimate every design; Parquet results."),
    "survey": (
        "softjig.cli.survey",
        "Survey the unloaded jig: write a rig whose marker layout and rest shape are the measured ones.",
    ),
    "sweep-plan": (
        "softjig.cli.sweep_plan",
        "Write the tilt sweep's poses (position, quaternion x,y,z,w) in J and the robot frame, in order.",
    ),
    "fiducials": (
        "softjig.cli.fiducials_cmd",
        "The ArUco fiducials on the base plate: a sheet to print at scale, and a check from a stereo pair.",
    ),
    "jig": (
        "softjig.cli.jig_cmd",
        "Jamming control: fix (jam), hold, release or stop the jig, or read its state, through the pump "
        "controller.",
    ),
}

_HELP_LISTING = "softjig.help_listing"  # ctx.meta key: set while a group formats its --help


def _plain_flags(params: list) -> list:
    """Show boolean flags as plain ``--flag`` / ``--flag/--no-flag`` in help, without Typer's ``<bool>``."""
    for param in params:
        if getattr(param, "is_flag", False) and param.metavar is None:
            param.metavar = ""
    return params


def _finite_numbers(command: Any) -> None:
    """Make ``command`` refuse NaN and inf in every number option or argument (exit 2, naming it).

    Typer and click parse ``nan`` and ``inf`` as floats, and a range (``min=``/``max=``) lets NaN through
    (every comparison with NaN is false): no command of softjig has a use for them.
    """
    inner = command.callback
    if inner is None or getattr(inner, "_softjig_finite", False):
        return
    hints = {p.name: (max(p.opts, key=len) if p.opts else p.name) for p in command.params}

    @functools.wraps(inner)
    def checked(*args: Any, **kwargs: Any) -> Any:
        for key, value in kwargs.items():
            for item in value if isinstance(value, list | tuple) else (value,):
                if isinstance(item, float) and not math.isfinite(item):
                    message = f"must be a finite number, got {item}"
                    raise typer.BadParameter(message, param_hint=hints.get(key))
        return inner(*args, **kwargs)

    checked._softjig_finite = True  # type: ignore[attr-defined]
    command.callback = checked


def _plain_command(command: Any, ctx: Any) -> Any:
    """:func:`_plain_flags`, :func:`_finite_numbers` and the plain values' coercion without pydantic
    (:mod:`softjig.cli.coercion`) on a command, its help option and, for a group, its subcommands."""
    help_option = command.get_help_option(ctx)
    params = [*command.params, *([help_option] if help_option is not None else [])]
    _plain_flags(params)
    _finite_numbers(command)
    coercion.install(params)
    for sub in getattr(command, "commands", {}).values():
        _plain_command(sub, ctx)
    return command


class LazyGroup(typer.core.TyperGroup):
    """The top-level group: commands of :data:`COMMANDS` are imported on first use.

    ``--help`` lists every command from :data:`COMMANDS` without importing any; running a command
    imports its module, which registers it on :data:`app`, and builds its click command from there.
    Commands registered on :data:`app` but missing from :data:`COMMANDS` are listed after them.
    """

    def list_commands(self, ctx: Any) -> list[str]:
        return [*COMMANDS, *(name for name in self.commands if name not in COMMANDS)]

    def get_params(self, ctx: Any) -> list:
        params = _plain_flags(super().get_params(ctx))
        coercion.install(params)
        return params

    def format_help(self, ctx: Any, formatter: Any) -> None:
        ctx.meta[_HELP_LISTING] = True
        try:
            super().format_help(ctx, formatter)
        finally:
            ctx.meta.pop(_HELP_LISTING, None)

    def get_command(self, ctx: Any, cmd_name: str) -> Any:
        if cmd_name not in self.commands and cmd_name in COMMANDS:
            module, short_help = COMMANDS[cmd_name]
            if ctx.meta.get(_HELP_LISTING):  # the listing needs only the name and the one-line help
                return typer.core.TyperCommand(name=cmd_name, help=short_help, short_help=short_help)
            importlib.import_module(module)
            self.commands[cmd_name] = _click_command(cmd_name)
        command = self.commands.get(cmd_name)
        return None if command is None else _plain_command(command, ctx)

    def resolve_command(self, ctx: Any, args: list[str]) -> Any:
        try:
            return super().resolve_command(ctx, args)
        except typer.core._click.exceptions.UsageError as exc:
            import difflib

            if args and "Did you mean" not in exc.message:
                matches = difflib.get_close_matches(args[0], self.list_commands(ctx))
                if matches:
                    suggestions = ", ".join(map(repr, matches))
                    exc.message = f"{exc.message.rstrip('.')}. Did you mean {suggestions}?"
            raise


def _click_command(name: str) -> Any:
    """The click command (or group) named ``name`` registered on :data:`app`."""
    options = {
        "pretty_exceptions_short": app.pretty_exceptions_short,
        "rich_markup_mode": app.rich_markup_mode,
    }
    for info in app.registered_commands:
        if (info.name or typer.main.get_command_name(info.callback.__name__)) == name:
            return typer.main.get_command_from_info(info, **options)
    for group in app.registered_groups:
        if group.name == name:
            return typer.main.get_group_from_info(group, suggest_commands=app.suggest_commands, **options)
    module = COMMANDS[name][0]
    raise LookupError(f"{module} does not register a command named {name!r} on softjig.cli.app.app")


app = typer.Typer(
    name="softjig",
    cls=LazyGroup,
    help="Sensing soft jig: simulate, estimate a part's principal normal, calibrate.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)

_F = TypeVar("_F", bound=Callable[..., Any])


def stderr_console() -> Console:
    from rich.console import Console

    # Created per call so it follows sys.stderr (tests swap it); soft wrap keeps messages on one line.
    return Console(stderr=True, soft_wrap=True, highlight=False)


def error(message: str, code: int = EXIT_BAD_INPUT) -> NoReturn:
    """Print ``error: message`` on stderr (red prefix) and exit with ``code``."""
    from rich.text import Text

    stderr_console().print(Text("error: ", style="bold red") + Text(str(message)))
    raise typer.Exit(code)


def _exit_after_signal(message: str, code: int) -> NoReturn:
    """Print ``error: message`` and end the process at once with ``code`` (128 + the signal's number).

    Every ``finally`` of the command has run (temporary files removed, worker pools stopped); what is
    skipped are the interpreter's exit handlers, as the signal's default action skips them too. Those can
    wait for ever on threads the signal interrupted (``concurrent.futures`` joins its pools' manager
    threads at exit: seen as a ``softjig demo`` still running after its "terminated" message)."""
    from rich.text import Text

    stderr_console().print(Text("error: ", style="bold red") + Text(str(message)))
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)


def warn(message: str) -> None:
    """Print ``warning: message`` on stderr (yellow prefix)."""
    from rich.text import Text

    stderr_console().print(Text("warning: ", style="bold yellow") + Text(str(message)))


def handle_errors(func: _F) -> _F:
    """Map softjig's exceptions to the contract's exit codes, with a message and no traceback.

    ``InputError`` (and ``ConfigError``) -> 2, ``EstimationError`` -> 3, any other ``SoftjigError`` -> 2,
    Ctrl-C -> 130, SIGTERM -> 143 (raised as :class:`~softjig.io.workers.Terminated`).
    """

    @functools.wraps(func)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        try:
            # SIGTERM: an exception, so every `finally` runs; a signal inside a compiled kernel's callback
            # arrives as a SystemError (io.workers)
            with terminate_raises(), signals_unwrapped():
                return func(*args, **kwargs)
        except EstimationError as exc:
            error(str(exc), EXIT_NO_ESTIMATE)
        except InputError as exc:
            error(str(exc), EXIT_BAD_INPUT)
        except SoftjigError as exc:
            error(str(exc), EXIT_BAD_INPUT)
        except Terminated as exc:
            _exit_after_signal(str(exc), exc.exit_code)
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


def load_config(config: Path | None):
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
    version: Annotated[
        bool,
        typer.Option(
            "--version", callback=_version_callback, is_eager=True, help="Print the version and exit."
        ),
    ] = False,
) -> None:
    """Sensing soft jig: simulate, estimate a part's principal normal, calibrate."""


def read_json_file(path: Path, what: str) -> dict:
    """A JSON object from a file named by an option (``what``); InputError if missing or malformed."""
    from softjig.files import read_text_file

    try:
        data = json.loads(read_text_file(path, what))
    except json.JSONDecodeError as exc:
        raise InputError(f"cannot read {what} file {path}: {exc}") from None
    if not isinstance(data, dict):
        raise InputError(f"{what} file {path} must hold a JSON object")
    return data


def pose_from_json(data: dict, key: str, path: Path) -> np.ndarray:
    """A 4x4 pose from ``{key: 4x4}`` or ``{"position_mm": [..], "quaternion_xyzw": [..]}``.

    Every number must be finite and a quaternion of unit norm (within 1e-3); whether the matrix is a
    rigid pose is for the command to check (:func:`softjig.calibration.alignment.check_pose`).
    """
    import numpy as np
    from scipy.spatial.transform import Rotation

    def numbers(value: Any, shape: tuple[int, ...], what: str) -> np.ndarray:
        try:
            array = np.asarray(value, dtype=float)
        except (TypeError, ValueError):
            array = np.zeros(0)
        if array.shape != shape:
            raise InputError(f"{path}: {what} must be {' x '.join(map(str, shape))} numbers, got {value!r}")
        if not np.all(np.isfinite(array)):
            raise InputError(f"{path}: {what} contains NaN or inf")
        return array

    if key in data:
        T = numbers(data[key], (4, 4), f"{key} (a 4x4 homogeneous matrix, mm)")
        if not np.allclose(T[3], [0, 0, 0, 1]):
            raise InputError(f"{path}: {key} must be a 4x4 homogeneous matrix (mm): its last row is 0 0 0 1")
        return T
    if "position_mm" in data and "quaternion_xyzw" in data:
        q = numbers(data["quaternion_xyzw"], (4,), "quaternion_xyzw")
        if abs(float(np.linalg.norm(q)) - 1.0) > 1e-3:
            raise InputError(
                f"{path}: quaternion_xyzw must have unit norm (x, y, z, w), got norm {np.linalg.norm(q):.6g}"
            )
        T = np.eye(4)
        T[:3, :3] = Rotation.from_quat(q).as_matrix()
        T[:3, 3] = numbers(data["position_mm"], (3,), "position_mm")
        return T
    raise InputError(f"{path}: give {key} (a 4x4 matrix) or position_mm and quaternion_xyzw (x, y, z, w)")
