"""The host's driver for the pump/valve controller on a serial line, the heartbeat, and the jig's cycle.

The protocol, and the decision of what the jig's safe state is (pump off, valve closed: a held part stays
held; only ``RELEASE`` frees it), are in :mod:`softjig.hardware.protocol`.

Faults
------
:class:`PumpController` turns every fault -- no whole reply line within ``timeout_s``, a reply longer than
:data:`~softjig.hardware.protocol.MAX_REPLY_BYTES`, a garbled reply, ``ERR``, a missing or non-finite
pressure, a controller reporting ``state=fault``, a state left unexpectedly, a set-point not reached in
time, a serial error (a port that disappears) -- into the safe state: it sends ``STOP``, and raises
:class:`PumpError` saying what happened, whether the controller *confirmed* its safe state (``OK
state=safe``), and what to check. Used as a context manager it also sends ``STOP`` when the block ends by
any other exception, ``KeyboardInterrupt`` and :class:`~softjig.hardware.guard.Terminated` (SIGTERM)
included. ``FIX`` is refused while the controller reports ``safe`` or ``fault`` (the latch, kept by the
controller, so it holds across processes) and after a fault in this process, until :meth:`release`.

:class:`~softjig.hardware.simulator.SimulatedPumpController` answers the protocol on a pseudo-terminal.
"""

from __future__ import annotations

import contextlib
import math
import time
from collections.abc import Callable
from typing import Any, NoReturn

try:
    import termios
except ImportError:  # pragma: no cover - Windows
    termios = None  # type: ignore[assignment]

from softjig.errors import InputError
from softjig.hardware.cycle import Command, CycleEvent, JigCycle
from softjig.hardware.guard import signals_deferred
from softjig.hardware.protocol import (
    DEFAULT_BAUDRATE,
    HEARTBEAT_PERIOD_S,
    MAX_REPLY_BYTES,
    PROTOCOL_NAME,
    PROTOCOL_VERSION,
    SAFE_STATES,
    STATES,
    PumpError,
    PumpStatus,
    format_request,
    parse_pressure,
    parse_reply,
    parse_status,
)
from softjig.hardware.simulator import SimulatedPumpController

__all__ = [
    "PROTOCOL_VERSION",
    "STATES",
    "PumpController",
    "PumpError",
    "PumpStatus",
    "SimulatedPumpController",
    "format_request",
    "parse_reply",
    "parse_status",
    "run_cycle",
]

#: The longest a single serial read waits (s); the reply's deadline is enforced across reads.
_READ_SLICE_S = 0.05
#: Errors of the serial line besides pyserial's and OSError (termios.error is neither, on a vanished tty).
_PLATFORM_ERRORS: tuple[type[BaseException], ...] = (termios.error,) if termios is not None else ()
#: What the safe state means, for messages.
SAFE_MEANING = "pump off, valve closed: the jig keeps what it holds; `softjig jig release` frees the part"


def _seconds(name: str, value: float, *, zero_ok: bool = False) -> float:
    """``value`` as a finite, positive (or, with ``zero_ok``, non-negative) duration in s; else InputError."""
    seconds = float(value)
    if not math.isfinite(seconds) or seconds < 0 or (seconds == 0 and not zero_ok):
        bound = ">= 0" if zero_ok else "> 0"
        raise InputError(f"{name} must be a finite number of seconds {bound}, got {value!r}")
    return seconds


class PumpController:
    """The host's side of the line protocol.

    Parameters
    ----------
    port : the serial device (``/dev/ttyACM0``, ``COM3``), or an open pyserial-like object with ``write``,
        ``read``, ``in_waiting``, ``reset_input_buffer`` and ``close`` (whose read timeout should be short).
    baudrate : the line's speed.
    timeout_s : how long to wait for a whole reply line (s); a controller slower than that is a fault.
    poll_period_s : period of ``STATUS`` polls while waiting for a state (s).

    Attributes
    ----------
    fault : the fault met in this process, or ``None``; ``FIX`` is refused until :meth:`release`.
    safe_confirmed : after the last safe-state request, whether the controller confirmed it (``None``
        before any).
    """

    def __init__(
        self,
        port: str | Any,
        *,
        baudrate: int = DEFAULT_BAUDRATE,
        timeout_s: float = 1.0,
        poll_period_s: float = 0.05,
    ) -> None:
        self.timeout_s = _seconds("the reply timeout (--timeout)", timeout_s)
        self.poll_period_s = _seconds("the poll period", poll_period_s)
        self.fault: str | None = None
        self.safe_confirmed: bool | None = None
        self._stop_problem = ""
        if isinstance(port, str):
            import serial

            try:
                self._serial = serial.Serial(
                    port,
                    baudrate=baudrate,
                    timeout=min(self.timeout_s, _READ_SLICE_S),
                    write_timeout=self.timeout_s,
                )
            except (serial.SerialException, OSError, ValueError) as exc:
                raise PumpError(
                    f"cannot open the pump controller's serial port {port}: {exc} (check the "
                    "cable, the port name and your permission to use it, e.g. the dialout "
                    "group)"
                ) from None
            self.port = port
        else:
            self._serial = port
            self.port = getattr(port, "port", None) or repr(port)
        try:
            hello = self._exchange("HELLO")
            if hello.get("0") != PROTOCOL_NAME or hello.get("1") != str(PROTOCOL_VERSION):
                raise PumpError(
                    f"{self.port} answered HELLO with {hello} instead of {PROTOCOL_NAME} "
                    f"{PROTOCOL_VERSION}: not a softjig pump controller, or another protocol version"
                )
        except BaseException:
            # Nothing was commanded yet: do not send STOP to what may not be a pump at all.
            self.close()
            raise

    # ---------------------------------------------------------------------------------- the line
    def _read_reply(self, request: str) -> bytes:
        """One reply line, within ``timeout_s`` for the *whole* line and at most MAX_REPLY_BYTES long."""
        deadline = time.monotonic() + self.timeout_s
        line = bytearray()
        while True:
            want = max(1, min(getattr(self._serial, "in_waiting", 0) or 1, MAX_REPLY_BYTES + 1 - len(line)))
            chunk = self._serial.read(want)
            if chunk:
                line += chunk
                end = line.find(b"\n")
                if 0 <= end < MAX_REPLY_BYTES:
                    return bytes(line[: end + 1])
                if end >= 0 or len(line) > MAX_REPLY_BYTES:
                    raise PumpError(
                        f"the pump controller on {self.port} answered {request} with a reply too long "
                        f"(over {MAX_REPLY_BYTES} bytes, newline included: wrong baud rate, or not a "
                        "softjig pump controller?)"
                    )
            if time.monotonic() >= deadline:
                got = f" (only {len(line)} bytes of it)" if line else ""
                raise PumpError(
                    f"the pump controller on {self.port} did not answer {request} within "
                    f"{self.timeout_s:g} s{got} (powered? cable? right port?)"
                )

    def _exchange(self, request: str) -> dict[str, str]:
        """Send one request and read its reply; raises PumpError without going safe."""
        import serial

        try:
            self._serial.reset_input_buffer()  # a late reply to an earlier request must not be taken
            self._serial.write(format_request(request))
            line = self._read_reply(request)
        except (serial.SerialException, OSError, *_PLATFORM_ERRORS) as exc:
            raise PumpError(
                f"serial error talking to the pump controller on {self.port}: {exc} (unplugged? "
                "check the cable and the port)"
            ) from None
        return parse_reply(line, request)

    def _transact(self, request: str, parse: Callable[[dict[str, str]], Any] = lambda f: f) -> Any:
        """Send a request and parse its reply; on any fault go safe and raise (:meth:`fail`)."""
        try:
            return parse(self._exchange(request))
        except PumpError as exc:
            self.fail(str(exc))

    # ----------------------------------------------------------------------------- the safe state
    def go_safe(self, reason: str) -> bool:
        """Record ``reason`` as a fault and send ``STOP``; whether the controller confirmed its safe state.

        Never raises for the controller's sake (a dead line is reported in :meth:`safe_summary`);
        further Ctrl-C/SIGTERM are held back while ``STOP`` is on the wire.
        """
        self.fault = reason
        with signals_deferred():
            try:
                fields = self._exchange("STOP")
            except PumpError as exc:
                self.safe_confirmed, self._stop_problem = False, str(exc)
                return False
        state = fields.get("state")
        self.safe_confirmed = state in SAFE_STATES
        self._stop_problem = "" if self.safe_confirmed else f"it answered STOP with state={state!r}"
        return self.safe_confirmed

    def safe_summary(self) -> str:
        """What the last safe-state request achieved, and what to check when it was not confirmed."""
        if self.safe_confirmed is None:
            return "no safe-state request was sent"
        if self.safe_confirmed:
            return f"the pump controller confirmed its safe state ({SAFE_MEANING})"
        return (
            f"the safe state is NOT confirmed ({self._stop_problem}): the pump may still be running; "
            "check the controller's power, cable and port, switch the pump off at its supply if it "
            "runs, then check with `softjig jig status`"
        )

    def fail(self, reason: str) -> NoReturn:
        """Go safe because of ``reason`` and raise :class:`PumpError` with the outcome."""
        self.go_safe(reason)
        raise PumpError(f"{reason}; {self.safe_summary()}", stop_attempted=True)

    # ---------------------------------------------------------------------------------- requests
    def status(self) -> PumpStatus:
        """The controller's state and pressure (``STATUS``); the controller's own fault goes safe."""
        status: PumpStatus = self._transact("STATUS", parse_status)
        if status.state == "fault":
            self.fail(
                f"the pump controller on {self.port} reports a fault ({status.fault}, "
                f"{status.pressure_kpa:g} kPa): check the pump, the tubing and the sensor, then "
                "`softjig jig release`"
            )
        return status

    def pressure_kpa(self) -> float:
        """The oil's gauge pressure (kPa); a missing or non-finite pressure is a fault."""
        return self._transact("PRESSURE", parse_pressure)

    def fix(self, *, wait: bool = True, timeout_s: float = 10.0) -> PumpStatus:
        """Jam the jig (``FIX``); with ``wait``, until the controller reports ``fixed``.

        Refused (:class:`PumpError`, nothing sent) after a fault in this process, and while the
        controller reports its latched ``safe``/``fault`` state: release first.
        """
        if self.fault is not None:
            raise PumpError(
                f"the pump controller had a fault ({self.fault}): fix the cause, then release the jig "
                "(`softjig jig release`) before fixing again",
                stop_attempted=True,
            )
        current = self.status()
        if current.state in SAFE_STATES:
            raise PumpError(
                f"FIX refused: the jig is in its safe state (state {current.state}, "
                f"{current.pressure_kpa:g} kPa), latched after a fault, a STOP or the controller's "
                "watchdog; check why, then release it (`softjig jig release`) before fixing again",
                stop_attempted=True,
            )
        self._transact("FIX", self._expect("FIX", ("fixing", "fixed")))
        return self._wait_for("fixed", ("fixing",), timeout_s) if wait else self.status()

    def release(self, *, wait: bool = True, timeout_s: float = 10.0) -> PumpStatus:
        """Soften the jig (``RELEASE``); with ``wait``, until ``released``. Also the way out of a fault."""
        self.fault = None
        self._transact("RELEASE", self._expect("RELEASE", ("releasing", "released")))
        return self._wait_for("released", ("releasing",), timeout_s) if wait else self.status()

    def reset(self) -> PumpStatus:
        """Clear a fault by releasing the jig (the way out of the safe state)."""
        return self.release()

    def safe(self) -> None:
        """Send the safe state (``STOP``) at once; raises :class:`PumpError` unless it is confirmed."""
        if not self.go_safe("STOP requested"):
            raise PumpError(f"STOP requested; {self.safe_summary()}", stop_attempted=True)
        self.fault = None  # a requested STOP is no fault: the controller's latch still needs RELEASE

    def hold(
        self,
        *,
        period_s: float = HEARTBEAT_PERIOD_S,
        duration_s: float | None = None,
        on_status: Callable[[PumpStatus], None] | None = None,
    ) -> PumpStatus:
        """The heartbeat: poll ``STATUS`` every ``period_s`` while the jig must stay ``fixed``.

        Keeps the controller's watchdog fed (so the pump keeps regulating the set-point) and checks the
        jig stays ``fixed`` with a valid pressure; anything else is a fault (safe state, raise). Returns
        the last status after ``duration_s`` (``None``: until interrupted -- by Ctrl-C or SIGTERM, which
        the caller turns into the safe state). Does not ``STOP`` on a normal return: that is the caller's.
        """
        if duration_s is not None:
            _seconds("the hold duration (--duration)", duration_s, zero_ok=True)
        if not HEARTBEAT_PERIOD_S * 2 >= period_s > 0:
            raise PumpError(
                f"the heartbeat period must be in (0, {HEARTBEAT_PERIOD_S * 2:g}] s so the controller's "
                f"watchdog (at least {HEARTBEAT_PERIOD_S * 4:g} s) never expires; got {period_s:g}"
            )
        start = time.monotonic()
        beat = 0
        while True:
            status = self.status()
            if status.state != "fixed":
                self.fail(
                    f"the jig left 'fixed' while holding (state {status.state}, {status.pressure_kpa:g} kPa)"
                    ": check for a leak, the pump and the controller's watchdog setting"
                )
            if on_status is not None:
                on_status(status)
            beat += 1
            next_beat = start + beat * period_s
            if duration_s is not None and next_beat - start > duration_s:
                return status
            time.sleep(max(0.0, next_beat - time.monotonic()))

    def _expect(self, request: str, states: tuple[str, ...]) -> Callable[[dict[str, str]], dict[str, str]]:
        def check(fields: dict[str, str]) -> dict[str, str]:
            if fields.get("state") not in states:
                raise PumpError(
                    f"the pump controller answered {request} with state={fields.get('state')!r} "
                    f"instead of {' or '.join(states)}"
                )
            return fields

        return check

    def _wait_for(self, state: str, passing: tuple[str, ...], timeout_s: float) -> PumpStatus:
        deadline = time.monotonic() + _seconds("the wait (--wait)", timeout_s, zero_ok=True)
        while True:
            status = self.status()
            if status.state == state:
                return status
            if status.state not in passing:
                self.fail(
                    f"the jig went to {status.state!r} ({status.pressure_kpa:g} kPa) on its way to "
                    f"{state!r}: check the controller"
                )
            if time.monotonic() >= deadline:
                self.fail(
                    f"the jig did not reach {state!r} within {timeout_s:g} s (state {status.state!r}, "
                    f"{status.pressure_kpa:g} kPa): check for a leak, the pump and the filters"
                )
            time.sleep(self.poll_period_s)

    # ---------------------------------------------------------------------------- context manager
    def close(self) -> None:
        with contextlib.suppress(Exception):
            self._serial.close()

    def __enter__(self) -> PumpController:
        return self

    def __exit__(self, exc_type: object, exc: BaseException | None, tb: object) -> None:
        try:
            already = isinstance(exc, PumpError) and exc.stop_attempted
            if exc is not None and not already:
                self.go_safe(f"{type(exc).__name__}: {exc}" if str(exc) else type(exc).__name__)
        finally:
            self.close()


# ------------------------------------------------------------------------------------------ the cycle


def run_cycle(
    pump: PumpController,
    *,
    wait_for_part: Callable[[], bool],
    sense: Callable[[], Any],
    work: Callable[[Any], None] | None = None,
    cycles: int = 1,
    fix_timeout_s: float = 10.0,
    release_timeout_s: float = 10.0,
) -> list[Any]:
    """Run the paper's cycle ``cycles`` times: release, place, fix, sense, (work), release.

    Parameters
    ----------
    pump : the controller.
    wait_for_part : blocks until a part is placed; returns ``False`` to end (no more parts).
    sense : returns the part's estimate (e.g. one live frame's); it is what the cycle reports.
    work : the robot's work on the held part, given the estimate. It must return within the controller's
        watchdog (a few seconds), or the pump stops regulating and the part is held passively.
    cycles : how many parts.

    Returns
    -------
    list
        What ``sense`` returned for each part.

    Raises
    ------
    PumpError, or whatever a callback raised (KeyboardInterrupt included)
        After the cycle went to ``FAULT`` and the jig to its safe state (``STOP``: the part stays held).
    """
    cycle = JigCycle()
    results: list[Any] = []
    command = cycle.handle(CycleEvent.START)
    estimate = None
    try:
        while True:
            if command is Command.RELEASE:
                pump.release(timeout_s=release_timeout_s)
                if len(results) >= cycles:
                    cycle.handle(CycleEvent.STOP)
                    return results
                command = cycle.handle(CycleEvent.RELEASED)
            elif command is Command.WAIT_FOR_PART:
                if not wait_for_part():
                    cycle.handle(CycleEvent.STOP)
                    return results
                command = cycle.handle(CycleEvent.PART_PLACED)
            elif command is Command.FIX:
                pump.fix(timeout_s=fix_timeout_s)
                command = cycle.handle(CycleEvent.FIXED)
            elif command is Command.SENSE:
                estimate = sense()
                results.append(estimate)
                command = cycle.handle(CycleEvent.SENSED)
            elif command is Command.REPORT:
                if work is not None:
                    work(estimate)
                command = cycle.handle(CycleEvent.WORK_DONE)
            else:  # pragma: no cover - SAFE only follows FAULT/STOP, handled below
                raise PumpError(f"unexpected command {command}")
    except BaseException as exc:
        cycle.handle(CycleEvent.FAULT)
        if not (isinstance(exc, PumpError) and exc.stop_attempted):
            pump.go_safe(f"{type(exc).__name__}: {exc}")
        raise
