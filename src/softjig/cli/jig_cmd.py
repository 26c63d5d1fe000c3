"""`softjig jig fix|release|status`: jamming control through the pump controller (``docs/live.md``)."""

from __future__ import annotations

import json
from typing import Annotated

import typer

from softjig.cli.app import app, handle_errors

jig_app = typer.Typer(
    name="jig",
    help="Jamming control: fix (jam) or release the jig, or read its state, through the pump controller.",
    no_args_is_help=True,
)
app.add_typer(jig_app, name="jig")

PortOption = Annotated[
    str,
    typer.Option(
        "--port", envvar="SOFTJIG_PUMP_PORT", help="Serial port of the pump controller.", show_default=False
    ),
]
BaudOption = Annotated[int, typer.Option(help="Baud rate of the serial line.")]
TimeoutOption = Annotated[float, typer.Option(min=0.01, help="Seconds to wait for each reply.")]
WaitOption = Annotated[float, typer.Option(min=0.0, help="Seconds to wait for the jig to reach the state.")]
JsonOption = Annotated[bool, typer.Option("--json", help="Print one JSON object.")]


def _print(status, json_output: bool) -> None:
    if json_output:
        typer.echo(json.dumps(status.to_dict()))
    else:
        fault = f", fault {status.fault}" if status.fault else ""
        typer.echo(f"{status.state}: {status.pressure_kpa:g} kPa{fault}")


def _controller(port: str, baud: int, timeout: float):
    from softjig.hardware.pump import PumpController

    return PumpController(port, baudrate=baud, timeout_s=timeout)


@jig_app.command()
@handle_errors
def fix(
    port: PortOption,
    baud: BaudOption = 115200,
    timeout: TimeoutOption = 1.0,
    wait: WaitOption = 10.0,
    json_output: JsonOption = False,
) -> None:
    """Jam the jig (pump the oil out) and wait until it holds; on any fault the jig goes to its safe state."""
    with _controller(port, baud, timeout) as pump:
        _print(pump.fix(wait=wait > 0, timeout_s=wait), json_output)


@jig_app.command()
@handle_errors
def release(
    port: PortOption,
    baud: BaudOption = 115200,
    timeout: TimeoutOption = 1.0,
    wait: WaitOption = 10.0,
    json_output: JsonOption = False,
) -> None:
    """Release the jig (let the oil back) and wait until it is soft; also the way out of a fault."""
    with _controller(port, baud, timeout) as pump:
        _print(pump.release(wait=wait > 0, timeout_s=wait), json_output)


@jig_app.command()
@handle_errors
def status(
    port: PortOption, baud: BaudOption = 115200, timeout: TimeoutOption = 1.0, json_output: JsonOption = False
) -> None:
    """Print the jig's state and the oil's pressure (kPa, negative when oil is drawn out)."""
    with _controller(port, baud, timeout) as pump:
        _print(pump.status(), json_output)
