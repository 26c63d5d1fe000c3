"""A pump that always stops: the issue's rows against a simulated firmware on a real pseudo-terminal pair.

Each test drives the real driver or the real command line (in-process, or as a subprocess receiving real
signals) against :class:`SimulatedPumpController`, a firmware speaking the line protocol on a pty.
"""

from __future__ import annotations

import json
import os
import select
import signal
import subprocess
import sys
import threading
import time

import pytest
from typer.testing import CliRunner

from softjig.cli import app
from softjig.hardware.protocol import MAX_REPLY_BYTES, PumpError, parse_status
from softjig.hardware.pump import PumpController, run_cycle
from softjig.hardware.simulator import SimulatedPumpController

runner = CliRunner()
FAST = {"fix_time_s": 0.1, "release_time_s": 0.1}


def wait_until(predicate, timeout_s: float = 30.0, what: str = "condition") -> None:
    deadline = time.monotonic() + timeout_s
    while not predicate():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.02)


def start(cls=SimulatedPumpController, **kwargs):
    simulator, port = cls.on_pty(**{**FAST, **kwargs})
    simulator.port = port
    return simulator.start()


@pytest.fixture()
def sim():
    simulator = start()
    yield simulator
    simulator.stop()


def jig(*args: str):
    return runner.invoke(app, ["jig", *args])


def after(requests: list[str], request: str) -> list[str]:
    """The requests after the last ``request``."""
    last = len(requests) - 1 - requests[::-1].index(request)
    return requests[last + 1 :]


# ------------------------------------------------------------------ replies: a deadline per line, a bound


class Dribbler(SimulatedPumpController):
    """Answers STATUS one byte every 50 ms, never a newline, until the next request (8 s at most)."""

    def respond(self, request):
        if request != "STATUS":
            return super().respond(request)
        for _ in range(160):
            if self._stop.is_set() or select.select([self.fd], [], [], 0.05)[0]:
                return
            self.write(b"O")


class Spewer(SimulatedPumpController):
    """Answers STATUS with bytes and no newline, 1 KiB at a time, until the next request (64 KiB at most)."""

    def respond(self, request):
        if request != "STATUS":
            return super().respond(request)
        os.set_blocking(self.fd, False)  # a full line drops bytes: the firmware must hear the next request
        for _ in range(64):
            if self._stop.is_set() or select.select([self.fd], [], [], 0.001)[0]:
                return
            self.write(b"X" * 1024)


def test_a_dribbling_pump_times_out_per_reply_not_per_byte():
    simulator = start(Dribbler)
    try:
        with PumpController(simulator.port, timeout_s=0.5) as pump:
            t0 = time.monotonic()
            with pytest.raises(PumpError, match=r"did not answer STATUS within 0.5 s \(only \d+ bytes"):
                pump.status()
            assert time.monotonic() - t0 < 3.0  # the old per-byte timeout waited the whole 8 s
        wait_until(lambda: "STOP" in simulator.requests, 10.0, "STOP")
    finally:
        simulator.stop()


def test_a_spewing_pump_is_a_fault_reply_too_long():
    simulator = start(Spewer)
    try:
        with PumpController(simulator.port, timeout_s=5.0) as pump:
            t0 = time.monotonic()
            with pytest.raises(PumpError, match=f"reply too long.*over {MAX_REPLY_BYTES} bytes"):
                pump.status()
            assert time.monotonic() - t0 < 3.0  # not the 5 s timeout, nor for ever
        wait_until(lambda: "STOP" in simulator.requests, 10.0, "STOP")
    finally:
        simulator.stop()


def test_a_reply_of_exactly_the_bound_is_accepted_and_one_more_byte_is_not():
    class Padded(SimulatedPumpController):
        pad = 0

        def reply(self, request):
            line = super().reply(request)
            if request == "PRESSURE":
                line += " x=" + "y" * (self.pad - len(line) - 3)
            return line

    simulator = start(Padded)
    try:
        with PumpController(simulator.port, timeout_s=1.0) as pump:
            Padded.pad = MAX_REPLY_BYTES - 1  # + the newline: exactly the bound
            assert pump.pressure_kpa() == 0.0
            Padded.pad = MAX_REPLY_BYTES
            with pytest.raises(PumpError, match="too long"):
                pump.pressure_kpa()
    finally:
        simulator.stop()


# ------------------------------------------------------------------------------ NaN or missing pressure


@pytest.mark.parametrize("value", ["nan", "inf", "-inf", None, "lots"])
def test_a_pressure_that_is_not_a_finite_number_is_a_fault(value):
    fields = {"state": "fixed", "fault": "none"}
    if value is not None:
        fields["pressure_kpa"] = value
    with pytest.raises(PumpError, match="no valid pressure"):
        parse_status(fields)


class NanPump(SimulatedPumpController):
    def reply(self, request):
        line = super().reply(request)
        return line.replace(f"pressure_kpa={self.pressure():.2f}", "pressure_kpa=nan")


@pytest.mark.parametrize("json_flag", [[], ["--json"]])
def test_cli_fix_with_a_nan_pressure_is_a_fault_and_prints_no_nan(json_flag):
    simulator = start(NanPump)
    try:
        result = jig("fix", "--port", simulator.port, "--wait", "5", *json_flag)
    finally:
        simulator.stop()
    assert result.exit_code == 2, result.output
    assert "nan" not in result.stdout.lower()
    assert "no valid pressure" in result.stderr and "confirmed its safe state" in result.stderr
    assert "FIX" not in simulator.requests  # the first STATUS already failed: nothing was jammed
    assert simulator.requests[-1] == "STOP"


def test_cli_json_is_always_strict_json(sim):
    for command in (["status"], ["fix", "--wait", "5"], ["stop"], ["release", "--wait", "5"]):
        result = jig(*command, "--port", sim.port, "--json")
        assert result.exit_code == 0, result.output
        json.loads(result.stdout, parse_constant=lambda c: pytest.fail(f"not JSON: {c}"))


# ---------------------------------------------------------------------- faults latched until release


def test_a_fault_then_status_then_fix_is_refused_until_release():
    simulator = start(fix_time_s=60.0)  # the set-point is never reached in time: a fault
    try:
        result = jig("fix", "--port", simulator.port, "--wait", "0.3")
        assert result.exit_code == 2 and "did not reach 'fixed'" in result.stderr
        assert simulator.requests[-1] == "STOP" and simulator.state == "safe"
        result = jig("status", "--port", simulator.port)  # a new controller, as a new process would be
        assert result.exit_code == 0 and result.stdout.startswith("safe:")
        n = len(simulator.requests)
        result = jig("fix", "--port", simulator.port)
        assert result.exit_code == 2, result.output
        assert "FIX refused" in result.stderr and "softjig jig release" in result.stderr
        assert "FIX" not in simulator.requests[n:]  # refused by the host: nothing sent
        simulator.fix_time_s = 0.1
        assert jig("release", "--port", simulator.port, "--wait", "5").exit_code == 0
        result = jig("fix", "--port", simulator.port, "--wait", "5")
        assert result.exit_code == 0 and result.stdout.startswith("fixed: -60 kPa")
    finally:
        simulator.stop()


def test_the_host_enforces_the_latch_even_if_the_firmware_would_accept_fix():
    class Forgetful(SimulatedPumpController):
        def reply(self, request):
            if request == "FIX" and self.state == "safe":
                self._enter("fixing")
                return "OK state=fixing"
            return super().reply(request)

    simulator = start(Forgetful)
    try:
        assert jig("stop", "--port", simulator.port).exit_code == 0
        result = jig("fix", "--port", simulator.port, "--wait", "5")
        assert result.exit_code == 2 and "FIX refused" in result.stderr
        assert simulator.state == "safe"
    finally:
        simulator.stop()


def test_the_simulated_firmware_latches_too(sim):
    with PumpController(sim.port, timeout_s=1.0) as pump:
        pump.safe()
        assert sim.reply("FIX").startswith("ERR safe state latched")


def test_a_controller_fault_is_reported_and_latched(sim):
    with PumpController(sim.port, timeout_s=1.0) as pump:
        pump.fix(timeout_s=5.0)
        sim.set_fault("overheat")
        with pytest.raises(PumpError, match=r"reports a fault \(overheat.*confirmed its safe state"):
            pump.status()
    result = jig("fix", "--port", sim.port)
    assert result.exit_code == 2 and "overheat" in result.stderr
    assert sim.state == "fault" and "FIX" not in after(sim.requests, "HELLO")
    assert jig("release", "--port", sim.port, "--wait", "5").exit_code == 0
    assert jig("fix", "--port", sim.port, "--wait", "5").exit_code == 0


# -------------------------------------------------------------- "safe state" only when it is confirmed


class NoStopReply(SimulatedPumpController):
    """Refuses FIX, then never answers STOP."""

    def respond(self, request):
        if request == "STOP":
            return
        if request == "FIX":
            return self.write(b"ERR pressure sensor disconnected\n")
        return super().respond(request)


def test_stop_unanswered_is_said_to_be_not_confirmed():
    simulator = start(NoStopReply)
    try:
        result = jig("fix", "--port", simulator.port, "--timeout", "0.3")
    finally:
        simulator.stop()
    assert result.exit_code == 2
    assert "pressure sensor disconnected" in result.stderr
    assert "NOT confirmed" in result.stderr and "pump may still be running" in result.stderr
    assert "confirmed its safe state" not in result.stderr and "sent to its safe state" not in result.stderr
    assert simulator.requests[-1] == "STOP"


def test_a_confirmed_stop_says_so_and_keeps_the_part_held(sim):
    assert jig("fix", "--port", sim.port, "--wait", "5").exit_code == 0
    result = jig("stop", "--port", sim.port, "--json")
    assert result.exit_code == 0 and "confirmed its safe state" in result.stderr
    assert json.loads(result.stdout) == {"state": "safe", "pressure_kpa": -60.0, "fault": None}
    assert "RELEASE" not in after(sim.requests, "FIX")  # safe is not released: the part stays held


# ------------------------------------------------------- every way out: exceptions, a port that vanishes


def test_an_exception_while_a_command_runs_sends_stop(sim):
    with pytest.raises(RuntimeError, match="robot program crashed"), PumpController(sim.port) as pump:
        pump.fix(wait=False)
        raise RuntimeError("robot program crashed")
    assert sim.requests[-1] == "STOP" and sim.state == "safe"
    assert pump.safe_confirmed is True


def test_a_keyboard_interrupt_in_the_cycle_sends_stop_not_release(sim):
    def work(_estimate):
        raise KeyboardInterrupt

    with PumpController(sim.port) as pump, pytest.raises(KeyboardInterrupt):
        run_cycle(pump, wait_for_part=lambda: True, sense=lambda: 1, work=work, fix_timeout_s=5.0)
    assert after(sim.requests, "FIX").count("STOP") == 1
    assert "RELEASE" not in after(sim.requests, "FIX") and sim.state == "safe"


def test_a_serial_port_that_disappears_mid_fix_is_a_fault_not_confirmed():
    simulator = start(fix_time_s=60.0)
    try:
        with PumpController(simulator.port, timeout_s=0.5) as pump:
            timer = threading.Timer(0.3, simulator.disconnect)
            timer.start()
            t0 = time.monotonic()
            with pytest.raises(PumpError, match=r"serial error.*unplugged.*NOT confirmed"):
                pump.fix(timeout_s=30.0)
            assert time.monotonic() - t0 < 5.0
            timer.join()
    finally:
        simulator.stop()


def test_cli_with_a_port_that_disappears_exits_2_without_a_traceback():
    simulator = start(fix_time_s=60.0)
    try:
        threading.Timer(0.5, simulator.disconnect).start()
        result = jig("fix", "--port", simulator.port, "--timeout", "0.5", "--wait", "30")
    finally:
        simulator.stop()
    assert result.exit_code == 2, result.output
    assert "serial error" in result.stderr and "NOT confirmed" in result.stderr
    assert "Traceback" not in result.output


def test_a_controller_fault_mid_fix_stops_and_says_so():
    simulator = start(fix_time_s=60.0)
    try:
        threading.Timer(0.5, simulator.set_fault, args=("overcurrent",)).start()
        result = jig("fix", "--port", simulator.port, "--wait", "30")
    finally:
        simulator.stop()
    assert result.exit_code == 2, result.output
    assert "reports a fault (overcurrent" in result.stderr and "confirmed its safe state" in result.stderr
    assert simulator.requests[-1] == "STOP" and simulator.state == "fault"


class HalfReplyThenGone(SimulatedPumpController):
    """Starts answering STATUS once fixing, then the line ends (EOF) mid-reply."""

    def respond(self, request):
        if request == "STATUS" and self.state == "fixing":
            self.write(b"OK state=fix")
            threading.Thread(target=self.disconnect).start()
            return
        return super().respond(request)


def test_eof_mid_reply_is_a_fault_not_confirmed():
    simulator = start(HalfReplyThenGone, fix_time_s=60.0)
    try:
        result = jig("fix", "--port", simulator.port, "--timeout", "0.5", "--wait", "30")
    finally:
        simulator.stop()
    assert result.exit_code == 2, result.output
    assert "NOT confirmed" in result.stderr and "Traceback" not in result.output
    assert "FIX" in simulator.requests


# ------------------------------------------------------------------------ watchdog and the heartbeat


def test_without_a_heartbeat_the_watchdog_stops_the_pump_and_the_part_stays_held():
    simulator = start(watchdog_s=0.5)
    try:
        assert jig("fix", "--port", simulator.port, "--wait", "5").exit_code == 0
        wait_until(lambda: simulator.state == "safe", 5.0, "the watchdog")
        assert simulator.watchdog_trips == 1
        assert simulator.pressure() == pytest.approx(-60.0)  # valve closed: still jammed
    finally:
        simulator.stop()


def test_jig_hold_keeps_the_watchdog_fed_then_stops_with_the_part_held():
    simulator = start(watchdog_s=1.0)
    try:
        result = jig("hold", "--port", simulator.port, "--period", "0.1", "--duration", "2.5")
        assert result.exit_code == 0, result.output
        assert result.stdout.startswith("fixed: -60 kPa")
        assert simulator.watchdog_trips == 0  # 2.5 s held with a 1 s watchdog
        assert after(simulator.requests, "FIX").count("STATUS") >= 10
        assert simulator.requests[-1] == "STOP"
        assert simulator.state == "safe" and simulator.pressure() == pytest.approx(-60.0)
        assert "confirmed its safe state" in result.stderr
    finally:
        simulator.stop()


def test_jig_hold_faults_when_the_jig_lets_go():
    simulator = start()
    try:
        threading.Timer(0.8, simulator.set_fault, args=("leak",)).start()
        result = jig("hold", "--port", simulator.port, "--period", "0.1", "--duration", "20")
        assert result.exit_code == 2 and "leak" in result.stderr
        assert simulator.requests[-1] == "STOP"
    finally:
        simulator.stop()


def test_hold_refuses_a_period_that_would_let_the_watchdog_expire(sim):
    with PumpController(sim.port) as pump, pytest.raises(PumpError, match="heartbeat period"):
        pump.hold(period_s=5.0, duration_s=1.0)


# ----------------------------------------------------- the real command, real signals, a real pty pair

CLI = (
    # An interactive shell's foreground job gets SIGINT with its default action, whatever pytest's is.
    "import signal; signal.signal(signal.SIGINT, signal.SIG_DFL); from softjig.cli import main; main()"
)


def run_and_signal(simulator, args, sig, ready):
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in sys.path if p)}
    proc = subprocess.Popen(
        [sys.executable, "-c", CLI, "jig", *args, "--port", simulator.port],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
    )
    try:
        wait_until(lambda: ready(simulator) or proc.poll() is not None, 60.0, "the command to start")
        assert proc.poll() is None, proc.communicate()
        proc.send_signal(sig)
        out, err = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    return proc.returncode, out, err


@pytest.mark.parametrize(("sig", "code"), [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_a_signal_during_jig_fix_sends_stop(sig, code):
    simulator = start(fix_time_s=60.0)
    try:
        rc, _out, err = run_and_signal(simulator, ["fix", "--wait", "60"], sig, lambda s: "FIX" in s.requests)
    finally:
        simulator.stop()
    assert rc == code, err
    assert "STOP" in after(simulator.requests, "FIX") and simulator.state == "safe"
    assert "Traceback" not in err
    assert "interrupted by" in err and "confirmed its safe state" in err


def test_sigterm_ends_jig_hold_with_stop_and_exit_0():
    simulator = start()
    try:
        rc, out, err = run_and_signal(
            simulator, ["hold", "--period", "0.1"], signal.SIGTERM, lambda s: s.requests.count("STATUS") > 5
        )
    finally:
        simulator.stop()
    assert rc == 0, err
    assert out.startswith("fixed: -60 kPa")
    assert "stopped by SIGTERM" in err and "confirmed its safe state" in err and "Traceback" not in err
    assert simulator.requests[-1] == "STOP" and simulator.state == "safe"


@pytest.mark.parametrize("option", ["--timeout", "--wait"])
@pytest.mark.parametrize("value", ["nan", "inf"])
def test_non_finite_times_are_refused_before_anything_moves(sim, option, value):
    result = jig("fix", "--port", sim.port, option, value)
    assert result.exit_code == 2, result.output
    assert "finite number of seconds" in result.stderr or "Invalid value" in result.output
    assert "FIX" not in sim.requests


def test_hold_with_a_non_finite_duration_is_refused_before_anything_moves(sim):
    result = jig("hold", "--port", sim.port, "--duration", "nan")
    assert result.exit_code == 2 and "FIX" not in sim.requests


def test_a_version_1_controller_is_refused_it_would_drop_the_part_on_stop():
    class Version1(SimulatedPumpController):
        def reply(self, request):
            return "OK softjig-pump 1" if request == "HELLO" else super().reply(request)

    simulator = start(Version1)
    try:
        result = jig("fix", "--port", simulator.port)
    finally:
        simulator.stop()
    assert result.exit_code == 2 and "another protocol version" in result.stderr
    assert simulator.requests == ["HELLO"]
