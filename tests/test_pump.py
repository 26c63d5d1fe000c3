"""Jamming control against a simulated controller on a real pseudo-terminal pair, and the pure cycle."""

from __future__ import annotations

import json
import time

import pytest
from typer.testing import CliRunner

from softjig.cli import app
from softjig.errors import InputError
from softjig.hardware.cycle import Command, CycleEvent, CycleState, JigCycle, step
from softjig.hardware.pump import (
    PumpController,
    PumpError,
    SimulatedPumpController,
    format_request,
    parse_reply,
    parse_status,
    run_cycle,
)

runner = CliRunner()
FAST = {"fix_time_s": 0.1, "release_time_s": 0.1}


@pytest.fixture()
def sim():
    simulator, port = SimulatedPumpController.on_pty(**FAST)
    simulator.port = port
    with simulator:
        yield simulator


# ---------------------------------------------------------------------------------------- protocol


def test_protocol_lines():
    assert format_request("FIX") == b"FIX\n"
    with pytest.raises(PumpError, match="valid"):
        format_request("EXPLODE")
    assert parse_reply(b"OK state=fixed pressure_kpa=-60.5 fault=none\r\n") == {
        "state": "fixed",
        "pressure_kpa": "-60.5",
        "fault": "none",
    }
    assert parse_reply("OK softjig-pump 2") == {"0": "softjig-pump", "1": "2"}
    with pytest.raises(PumpError, match="refused to FIX: pressure sensor"):
        parse_reply("ERR pressure sensor", "FIX")
    with pytest.raises(PumpError, match="garbled"):
        parse_reply("\x00\xffOK", "STATUS")
    status = parse_status({"state": "fixed", "pressure_kpa": "-60.5", "fault": "none"})
    assert (status.state, status.pressure_kpa, status.fault) == ("fixed", -60.5, None)
    with pytest.raises(PumpError, match="unknown state"):
        parse_status({"state": "melting"})


# ------------------------------------------------------------------------------------------ driver


def test_fix_status_pressure_release(sim):
    with PumpController(sim.port, timeout_s=1.0) as pump:
        assert pump.status().state == "released"
        fixed = pump.fix(timeout_s=5.0)
        assert (fixed.state, fixed.pressure_kpa) == ("fixed", -60.0)
        assert pump.pressure_kpa() == -60.0
        assert pump.release(timeout_s=5.0).state == "released"
    assert sim.requests[0] == "HELLO"
    assert "FIX" in sim.requests and "RELEASE" in sim.requests


def test_a_controller_that_stops_answering_is_a_fault_and_goes_safe(sim):
    with PumpController(sim.port, timeout_s=0.3) as pump:
        pump.fix(timeout_s=5.0)
        sim.silent = True
        t0 = time.monotonic()
        with pytest.raises(PumpError, match=r"did not answer STATUS.*safe state is NOT confirmed"):
            pump.status()
        assert time.monotonic() - t0 < 10.0  # a time-out, not a hang
        assert sim.requests[-1] == "STOP"  # the safe state was asked for
        sim.silent = False
        with pytest.raises(PumpError, match="had a fault"):
            pump.fix()
        assert pump.reset().state == "released"
        assert pump.fix(timeout_s=5.0).state == "fixed"


def test_a_set_point_not_reached_in_time_goes_safe():
    simulator, port = SimulatedPumpController.on_pty(fix_time_s=60.0)
    with simulator, PumpController(port, timeout_s=1.0, poll_period_s=0.02) as pump:
        with pytest.raises(PumpError, match="did not reach 'fixed'"):
            pump.fix(timeout_s=0.3)
        assert simulator.state == "safe"


class _Faulty(SimulatedPumpController):
    def reply(self, request):
        if request == "FIX":
            return "ERR pressure sensor disconnected"
        if request == "PRESSURE":
            return "#@!"
        return super().reply(request)


def test_err_and_garbled_replies_go_safe():
    simulator, port = _Faulty.on_pty(**FAST)
    with simulator, PumpController(port, timeout_s=1.0) as pump:
        with pytest.raises(PumpError, match="pressure sensor disconnected"):
            pump.fix()
        assert simulator.state == "safe"
        pump.reset()
        with pytest.raises(PumpError, match="garbled"):
            pump.pressure_kpa()
        assert simulator.requests[-1] == "STOP"


def test_a_device_that_is_not_a_pump_controller():
    class Other(SimulatedPumpController):
        def reply(self, request):
            return "OK something-else 7"

    simulator, port = Other.on_pty()
    with simulator, pytest.raises(PumpError, match="not a softjig pump controller"):
        PumpController(port, timeout_s=1.0)


def test_a_missing_port_says_what_to_check(tmp_path):
    with pytest.raises(PumpError, match="cannot open"):
        PumpController(str(tmp_path / "ttyNONE"))


# ------------------------------------------------------------------------------------------- cycle


def test_the_papers_cycle_as_a_state_machine():
    cycle = JigCycle()
    commands = [
        cycle.handle(e)
        for e in (
            CycleEvent.START,
            CycleEvent.RELEASED,
            CycleEvent.PART_PLACED,
            CycleEvent.FIXED,
            CycleEvent.SENSED,
            CycleEvent.WORK_DONE,
        )
    ]
    assert commands == [
        Command.RELEASE,
        Command.WAIT_FOR_PART,
        Command.FIX,
        Command.SENSE,
        Command.REPORT,
        Command.RELEASE,
    ]
    assert cycle.state is CycleState.RELEASING
    assert len(cycle.history) == 6


@pytest.mark.parametrize("state", list(CycleState))
def test_a_fault_anywhere_goes_to_the_safe_state(state):
    assert step(state, CycleEvent.FAULT).command is Command.SAFE
    assert step(state, CycleEvent.FAULT).state is CycleState.FAULT


def test_impossible_events_are_refused_with_the_valid_ones():
    with pytest.raises(InputError, match="valid there: part_placed"):
        step(CycleState.AWAIT_PART, CycleEvent.FIXED)
    assert step(CycleState.FAULT, CycleEvent.RESET).command is Command.RELEASE


def test_run_cycle_against_the_simulator(sim):
    parts = iter([True, True, False])
    with PumpController(sim.port, timeout_s=1.0) as pump:
        results = run_cycle(
            pump,
            wait_for_part=lambda: next(parts),
            sense=lambda: {"tilt_x_deg": 1.0},
            cycles=2,
            fix_timeout_s=5.0,
            release_timeout_s=5.0,
        )
    assert results == [{"tilt_x_deg": 1.0}] * 2
    actions = [r for r in sim.requests if r in ("FIX", "RELEASE")]
    assert actions == ["RELEASE", "FIX", "RELEASE", "FIX", "RELEASE"]


def test_run_cycle_goes_safe_when_sensing_fails(sim):
    def sense():
        raise RuntimeError("camera unplugged")

    with PumpController(sim.port, timeout_s=1.0) as pump, pytest.raises(RuntimeError, match="unplugged"):
        run_cycle(pump, wait_for_part=lambda: True, sense=sense, fix_timeout_s=5.0)
    assert sim.requests[-1] == "STOP" and sim.state == "safe"


# --------------------------------------------------------------------------------------------- CLI


def test_cli_jig_fix_status_release(sim):
    result = runner.invoke(app, ["jig", "status", "--port", sim.port, "--json"])
    assert result.exit_code == 0, result.output
    assert json.loads(result.stdout) == {"state": "released", "pressure_kpa": 0.0, "fault": None}
    result = runner.invoke(app, ["jig", "fix", "--port", sim.port, "--wait", "5"])
    assert result.exit_code == 0, result.output
    assert result.stdout.startswith("fixed: -60 kPa")
    result = runner.invoke(app, ["jig", "release", "--port", sim.port, "--json"])
    assert result.exit_code == 0 and json.loads(result.stdout)["state"] == "released"


def test_cli_jig_with_a_silent_controller_exits_2(sim):
    sim.silent = True
    result = runner.invoke(app, ["jig", "status", "--port", sim.port, "--timeout", "0.2"])
    assert result.exit_code == 2
    assert "did not answer" in result.output
