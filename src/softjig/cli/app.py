"""The ``softjig`` Typer app and what every command shares (``DESIGN.md`` §1, command-line contract).

Commands live in their own modules of :mod:`softjig.cli` and only parse arguments and print; the work
is done in the library. Every command is wrapped in :func:`handle_errors`, which turns softjig's
exceptions into a one-line message on stderr and the contract's exit codes: 2 for bad usage or input
(:class:`~softjig.errors.InputError`, :class:`~softjig.errors.ConfigError`), 3 when the input was valid
but no estimate could be made (:class:`~softjig.errors.EstimationError`). New commands, each in its
own module imported by :mod:`softjig.cli`, follow the same pattern::

    @app.command()
    @handle_errors
    def estimate(...): ...
"""

from __future__ import annotations

import functools
import json
from collections.abc import Callable
from pathlib import Path
from typing import Annotated, Any, NoReturn, TypeVar

import numpy as np
import typer
from rich.console import Console
from rich.text import Text

from softjig import __version__
from softjig.errors import EstimationError, InputError, SoftjigError
from softjig.io.workers import Terminated, terminate_raises

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


def stderr_console() -> Console:
    # Created per call so it follows sys.stderr (tests swap it); soft wrap keeps messages on one line.
    return Console(stderr=True, soft_wrap=True, highlight=False)


def error(message: str, code: int = EXIT_BAD_INPUT) -> NoReturn:
    """Print ``error: message`` on stderr (red prefix) and exit with ``code``."""
    stderr_console().print(Text("error: ", style="bold red") + Text(str(message)))
    raise typer.Exit(code)


def warn(message: str) -> None:
    """Print ``warning: message`` on stderr (yellow prefix)."""
    stderr_console().print(Text("warning: ", style="bold yellow") + Text(str(message)))


def handle_errors(func: _F) -> _F:
    """Map softjig's exceptions to the contract's exit codes, with a message and no traceback.

    ``InputError`` (and ``ConfigError``) -> 2, ``EstimationError`` -> 3, any other ``SoftjigError`` -> 2,
    Ctrl-C -> 130, SIGTERM -> 143 (raised as :class:`~softjig.io.workers.Terminated`).
    """

    @functools.wraps(func)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        try:
            with terminate_raises():  # SIGTERM: an exception, so every `finally` runs (io.workers)
                return func(*args, **kwargs)
        except EstimationError as exc:
            error(str(exc), EXIT_NO_ESTIMATE)
        except InputError as exc:
            error(str(exc), EXIT_BAD_INPUT)
        except SoftjigError as exc:
            error(str(exc), EXIT_BAD_INPUT)
        except Terminated as exc:
            error(str(exc), exc.exit_code)
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
    try:
        data = json.loads(Path(path).read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise InputError(f"{what} file {path} does not exist") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(f"cannot read {what} file {path}: {exc}") from None
    if not isinstance(data, dict):
        raise InputError(f"{what} file {path} must hold a JSON object")
    return data


def pose_from_json(data: dict, key: str, path: Path) -> np.ndarray:
    """A 4x4 pose from ``{key: 4x4}`` or ``{"position_mm": [..], "quaternion_xyzw": [..]}``."""
    from scipy.spatial.transform import Rotation

    if key in data:
        T = np.asarray(data[key], dtype=float)
        if T.shape != (4, 4) or not np.allclose(T[3], [0, 0, 0, 1]):
            raise InputError(f"{path}: {key} must be a 4x4 homogeneous matrix (mm)")
        return T
    if "position_mm" in data and "quaternion_xyzw" in data:
        T = np.eye(4)
        T[:3, :3] = Rotation.from_quat(np.asarray(data["quaternion_xyzw"], float)).as_matrix()
        T[:3, 3] = np.asarray(data["position_mm"], float)
        return T
    raise InputError(f"{path}: give {key} (a 4x4 matrix) or position_mm and quaternion_xyzw (x, y, z, w)")
