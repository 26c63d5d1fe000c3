"""`softjig jig fix|hold|release|stop|status`: jamming control through the pump controller (``docs/live.md``).

Every command ends with the pump in its safe state on every way out but success: a fault, Ctrl-C,
SIGTERM, SIGHUP or any exception sends ``STOP`` (pump off, valve closed: the jig keeps what it holds), and
the message says whether the controller confirmed it. Ctrl-C exits 130, SIGTERM 143 (``hold``, whose
normal end is a signal, exits 0 once the safe state is confirmed).
"""

from __future__ import annotations

import json
from collections.abc import Callable
from typing import TYPE_CHECKING, Annotated

import typer

from softjig.cli.app import EXIT_BAD_INPUT, app, error, handle_errors
from softjig.hardware.protocol import HEARTBEAT_PERIOD_S

if TYPE_CHECKING:
    from softjig.hardware.pump import PumpController, PumpStatus

jig_app = typer.Typer(
    name="jig",
    help="Jamming control: fix (jam), hold, release or stop the jig, or read its state, through the pump "
    "controller.",
    no_args_is_help=True,
)
app.add_typer(jig_app, name="jig")

PortOption = Annotated[
    str,
    typer.Option(
        "--port", envvar="SOFTJIG_PUMP_PORT", help="Serial port of the pump controller.", show_default=False
    ),
]
BaudOption = Annotated[int, typer.Option(min=1, help="Baud rate of the serial line.")]
TimeoutOption = Annotated[
    float, typer.Option(min=0.01, max=60.0, help="Seconds to wait for each whole reply line.")
]
WaitOption = Annotated[
    float,
    typer.Option(min=0.0, max=600.0, help="Seconds to wait for the jig to reach the state (0: do not wait)."),
]
JsonOption = Annotated[bool, typer.Option("--json", help="Print one JSON object.")]


def _print(status: PumpStatus, json_output: bool) -> None:
    if json_output:
        typer.echo(json.dumps(status.to_dict(), allow_nan=False))
    else:
        fault = f", fault {status.fault}" if status.fault else ""
        typer.echo(f"{status.state}: {status.pressure_kpa:g} kPa{fault}")


def _session(
    port: str, baud: int, timeout: float, action: Callable[[PumpController], None], *, hold: bool = False
) -> None:
    """Run ``action`` on a connected controller; every way out but success sends ``STOP``.

    SIGTERM and SIGHUP become exceptions for the duration, so the controller's context manager runs.
    """
    from softjig.hardware.guard import Terminated, exit_code_for, signals_as_exceptions
    from softjig.hardware.pump import PumpController

    pump: PumpController | None = None
    with signals_as_exceptions():
        try:
            pump = PumpController(port, baudrate=baud, timeout_s=timeout)
            with pump:
                action(pump)
        except (KeyboardInterrupt, Terminated) as exc:
            by = "Ctrl-C" if isinstance(exc, KeyboardInterrupt) else str(exc)
            if pump is None:
                message = f"interrupted by {by} while connecting: nothing was sent to the pump"
                error(message, exit_code_for(exc))
            if hold and pump.safe_confirmed:
                typer.echo(f"stopped by {by}: {pump.safe_summary()}", err=True)
                return
            code = EXIT_BAD_INPUT if hold else exit_code_for(exc)
            error(f"interrupted by {by}: {pump.safe_summary()}", code)


@jig_app.command()
@handle_errors
def fix(
    port: PortOption,
    baud: BaudOption = 115200,
    timeout: TimeoutOption = 1.0,
    wait: WaitOption = 10.0,
    json_output: JsonOption = False,
) -> None:
    """Jam the jig (pump the oil out) and wait until it holds.

    Refused while the jig is in its (latched) safe state: release first. On any fault, Ctrl-C or SIGTERM
    the pump goes to its safe state. Without a heartbeat afterwards the controller's watchdog stops the pump
    within seconds and the part stays held passively; `softjig jig hold` keeps the pump regulating.
    """

    def action(pump: PumpController) -> None:
        _print(pump.fix(wait=wait > 0, timeout_s=wait), json_output)

    _session(port, baud, timeout, action)


@jig_app.command()
@handle_errors
def hold(
    port: PortOption,
    baud: BaudOption = 115200,
    timeout: TimeoutOption = 1.0,
    wait: Annotated[
        float, typer.Option(min=0.01, max=600.0, help="Seconds to wait for the jig to reach 'fixed'.")
    ] = 10.0,
    period: Annotated[
        float,
        typer.Option(min=0.01, max=2 * HEARTBEAT_PERIOD_S, help="Seconds between heartbeats (STATUS polls)."),
    ] = HEARTBEAT_PERIOD_S,
    duration: Annotated[
        float,
        typer.Option(min=0.0, max=1e7, help="Seconds to hold, then stop (0: until Ctrl-C or SIGTERM)."),
    ] = 0.0,
    json_output: JsonOption = False,
) -> None:
    """Jam the jig and keep it actively fixed: a heartbeat until Ctrl-C, SIGTERM or --duration, then STOP.

    The heartbeat keeps the controller's watchdog fed so the pump keeps regulating the set-point, and
    checks the jig stays fixed (anything else is a fault: STOP, exit 2). The end is STOP -- pump off, valve
    closed, the part stays held -- and exit 0 once confirmed; `softjig jig release` frees the part.
    """

    def action(pump: PumpController) -> None:
        _print(pump.fix(wait=True, timeout_s=wait), json_output)
        typer.echo("holding (Ctrl-C or SIGTERM to stop; the part stays held)", err=True)
        pump.hold(period_s=period, duration_s=duration if duration > 0 else None)
        pump.safe()
        typer.echo(f"stopped: {pump.safe_summary()}", err=True)

    _session(port, baud, timeout, action, hold=True)


@jig_app.command()
@handle_errors
def release(
    port: PortOption,
    baud: BaudOption = 115200,
    timeout: TimeoutOption = 1.0,
    wait: WaitOption = 10.0,
    json_output: JsonOption = False,
) -> None:
    """Release the jig (let the oil back) and wait until it is soft; also the way out of the safe state."""

    def action(pump: PumpController) -> None:
        _print(pump.release(wait=wait > 0, timeout_s=wait), json_output)

    _session(port, baud, timeout, action)


@jig_app.command()
@handle_errors
def stop(
    port: PortOption, baud: BaudOption = 115200, timeout: TimeoutOption = 1.0, json_output: JsonOption = False
) -> None:
    """Send the jig to its safe state now: pump off, valve closed, the part stays held.

    Exits 2 when the controller does not confirm it.
    """

    def action(pump: PumpController) -> None:
        pump.safe()
        _print(pump.status(), json_output)
        typer.echo(f"stopped: {pump.safe_summary()}", err=True)

    _session(port, baud, timeout, action)


@jig_app.command()
@handle_errors
def status(
    port: PortOption, baud: BaudOption = 115200, timeout: TimeoutOption = 1.0, json_output: JsonOption = False
) -> None:
    """Print the jig's state and the oil's pressure (kPa, negative when oil is drawn out)."""

    def action(pump: PumpController) -> None:
        current = pump.status()
        _print(current, json_output)
        if current.state == "safe":
            typer.echo(
                "note: the jig is in its safe state (pump off, valve closed: it keeps what it holds); "
                "FIX is refused until `softjig jig release`",
                err=True,
            )

    _session(port, baud, timeout, action)
