"""Jamming control: a driver for the pump/valve controller on a serial line, and the jig's work cycle.

The jig jams by pumping oil *out* of the membrane (the beads pack and hold the part) and softens by
letting it back in (Sakuma et al., "Design of soft-jig"). A small controller (a microcontroller driving
the pump and a valve, reading a pressure sensor) talks to the host over a serial line.

Line protocol (version 1)
-------------------------
Serial, 115200 baud 8N1 by default; ASCII; one request per line, one reply per line, lines end in
``\\n`` (a ``\\r`` before it is ignored). The host waits for each reply before sending the next request.

=============  ===============================================  ============================================
request        reply                                            effect
=============  ===============================================  ============================================
``HELLO``      ``OK softjig-pump 1``                            names the protocol and its version
``FIX``        ``OK state=fixing``                              pump oil out; ``fixed`` once at set-point
``RELEASE``    ``OK state=releasing``                           pump off, valve open: oil flows back;
                                                                ``released`` once at ambient pressure
``STOP``       ``OK state=safe``                                the safe state: pump off, valve
                                                                de-energised (open), the jig softens
``STATUS``     ``OK state=S pressure_kpa=P fault=F``            ``S`` one of :data:`STATES`; ``P`` the oil's
                                                                gauge pressure, kPa (negative when drawn
                                                                out); ``F`` ``none`` or a word
``PRESSURE``   ``OK pressure_kpa=P``                            the pressure alone
=============  ===============================================  ============================================

A refused or failed request is answered ``ERR <text>``. The controller must also go to its safe state by
itself when it hears nothing for a few seconds (its watchdog; the host polls ``STATUS`` while it waits).

Faults
------
:class:`PumpController` turns every fault -- no reply within ``timeout_s``, a garbled reply, ``ERR``, a
controller reporting ``state=fault``, a set-point not reached in time, a serial error -- into the safe
state: it sends ``STOP`` (best effort), remembers the fault (further ``FIX`` requests are refused until
:meth:`~PumpController.reset`) and raises :class:`PumpError` saying what happened and what to check.

:class:`SimulatedPumpController` answers this protocol on the master side of a pseudo-terminal, for the
tests and for dry runs; it can be told to stop answering.
"""

from __future__ import annotations

import contextlib
import os
import select
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from softjig.errors import SoftjigError
from softjig.hardware.cycle import Command, CycleEvent, JigCycle

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

PROTOCOL_VERSION = 1
PROTOCOL_NAME = "softjig-pump"
REQUESTS = ("HELLO", "FIX", "RELEASE", "STOP", "STATUS", "PRESSURE")
#: The controller's states.
STATES = ("released", "fixing", "fixed", "releasing", "safe", "fault")
DEFAULT_BAUDRATE = 115200


class PumpError(SoftjigError):
    """The pump controller failed or could not be reached; the jig was sent to its safe state."""


@dataclass(frozen=True)
class PumpStatus:
    """The controller's state.

    Attributes
    ----------
    state : one of :data:`STATES`.
    pressure_kpa : gauge pressure of the oil in the membrane (kPa; negative when oil is drawn out).
    fault : the controller's fault word, or ``None``.
    """

    state: str
    pressure_kpa: float
    fault: str | None = None

    def to_dict(self) -> dict[str, Any]:
        return {"state": self.state, "pressure_kpa": self.pressure_kpa, "fault": self.fault}


# ------------------------------------------------------------------------------------ pure protocol


def format_request(request: str) -> bytes:
    """The bytes of a request line."""
    if request not in REQUESTS:
        raise PumpError(f"unknown pump request {request!r}; valid: {', '.join(REQUESTS)}")
    return f"{request}\n".encode("ascii")


def parse_reply(line: bytes | str, request: str = "") -> dict[str, str]:
    """The ``key=value`` fields of an ``OK`` reply (a bare word is stored under its position, ``"0"``...).

    Raises
    ------
    PumpError
        An ``ERR`` reply, or a line that is neither ``OK ...`` nor ``ERR ...``.
    """
    text = line.decode("ascii", errors="replace") if isinstance(line, bytes) else line
    text = text.strip()
    what = f" to {request}" if request else ""
    if text.startswith("ERR"):
        raise PumpError(f"the pump controller refused{what}: {text[3:].strip() or 'no reason given'}")
    words = text.split()
    if not words or words[0] != "OK":
        raise PumpError(
            f"garbled reply{what} from the pump controller: {text!r} (wrong baud rate, or "
            "not a softjig pump controller?)"
        )
    fields: dict[str, str] = {}
    for i, word in enumerate(words[1:]):
        key, eq, value = word.partition("=")
        if eq:
            fields[key] = value
        else:
            fields[str(i)] = word
    return fields


def parse_status(fields: dict[str, str]) -> PumpStatus:
    """A :class:`PumpStatus` from the fields of a ``STATUS`` reply."""
    state = fields.get("state")
    if state not in STATES:
        raise PumpError(
            f"the pump controller reported an unknown state {state!r}; expected one of {', '.join(STATES)}"
        )
    try:
        pressure = float(fields.get("pressure_kpa", "nan"))
    except ValueError:
        raise PumpError(
            f"the pump controller reported a bad pressure {fields.get('pressure_kpa')!r}"
        ) from None
    fault = fields.get("fault", "none")
    return PumpStatus(state=state, pressure_kpa=pressure, fault=None if fault == "none" else fault)


# ------------------------------------------------------------------------------------------- driver


class PumpController:
    """The host's side of the line protocol.

    Parameters
    ----------
    port : the serial device (``/dev/ttyACM0``, ``COM3``), or an open serial-like object with ``write``,
        ``readline``, ``reset_input_buffer``, ``timeout`` and ``close`` (tests).
    baudrate : the line's speed.
    timeout_s : how long to wait for a reply (s); a controller silent longer is a fault.
    poll_period_s : period of ``STATUS`` polls while waiting for a state (s).
    """

    def __init__(
        self,
        port: str | Any,
        *,
        baudrate: int = DEFAULT_BAUDRATE,
        timeout_s: float = 1.0,
        poll_period_s: float = 0.05,
    ) -> None:
        self.timeout_s = float(timeout_s)
        self.poll_period_s = float(poll_period_s)
        self.fault: str | None = None
        if isinstance(port, str):
            import serial

            try:
                self._serial = serial.Serial(
                    port, baudrate=baudrate, timeout=timeout_s, write_timeout=timeout_s
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
            hello = self._request("HELLO")
        except PumpError:
            self.close()
            raise
        if hello.get("0") != PROTOCOL_NAME or hello.get("1") != str(PROTOCOL_VERSION):
            self.close()
            raise PumpError(
                f"{self.port} answered HELLO with {hello} instead of {PROTOCOL_NAME} "
                f"{PROTOCOL_VERSION}: not a softjig pump controller, or another protocol version"
            )

    # -- low level
    def _exchange(self, request: str) -> dict[str, str]:
        """Send one request and read its reply; raises PumpError without going safe."""
        import serial

        try:
            self._serial.reset_input_buffer()  # a late reply to an earlier request must not be taken
            self._serial.write(format_request(request))
            line = self._serial.readline()
        except (serial.SerialException, OSError) as exc:
            raise PumpError(f"serial error talking to the pump controller on {self.port}: {exc}") from None
        if not line.endswith(b"\n"):
            raise PumpError(
                f"the pump controller on {self.port} did not answer {request} within "
                f"{self.timeout_s:g} s (powered? cable? right port?)"
            )
        return parse_reply(line, request)

    def _request(self, request: str) -> dict[str, str]:
        try:
            return self._exchange(request)
        except PumpError as exc:
            self._go_safe(str(exc))
            raise PumpError(f"{exc}; the jig was sent to its safe state (pump off, valve open)") from None

    def _go_safe(self, reason: str) -> None:
        self.fault = reason
        with contextlib.suppress(Exception):
            self._exchange("STOP")

    # -- requests
    def status(self) -> PumpStatus:
        """The controller's state and pressure (``STATUS``)."""
        status = parse_status(self._request("STATUS"))
        if status.state == "fault":
            self._go_safe(f"controller fault {status.fault}")
            raise PumpError(
                f"the pump controller on {self.port} reports a fault ({status.fault}); the jig was "
                "sent to its safe state; check the pump and the tubing, then reset"
            )
        return status

    def pressure_kpa(self) -> float:
        """The oil's gauge pressure (kPa)."""
        fields = self._request("PRESSURE")
        try:
            return float(fields["pressure_kpa"])
        except (KeyError, ValueError):
            self._go_safe("bad PRESSURE reply")
            raise PumpError(f"the pump controller answered PRESSURE with {fields}") from None

    def fix(self, *, wait: bool = True, timeout_s: float = 10.0) -> PumpStatus:
        """Jam the jig (``FIX``); with ``wait``, until the controller reports ``fixed``."""
        if self.fault is not None:
            raise PumpError(
                f"the pump controller is in fault ({self.fault}): fix the cause, then reset "
                "(softjig jig release) before fixing again"
            )
        self._request("FIX")
        return self._wait_for("fixed", timeout_s) if wait else self.status()

    def release(self, *, wait: bool = True, timeout_s: float = 10.0) -> PumpStatus:
        """Soften the jig (``RELEASE``); with ``wait``, until the controller reports ``released``."""
        self._request("RELEASE")
        return self._wait_for("released", timeout_s) if wait else self.status()

    def safe(self) -> None:
        """Send the safe state (``STOP``: pump off, valve open) at once."""
        self._request("STOP")

    def reset(self) -> PumpStatus:
        """Clear a remembered fault by releasing the jig (the way out of the safe state)."""
        self.fault = None
        return self.release()

    def _wait_for(self, state: str, timeout_s: float) -> PumpStatus:
        deadline = time.monotonic() + timeout_s
        while True:
            status = self.status()
            if status.state == state:
                return status
            if time.monotonic() >= deadline:
                reason = (
                    f"the jig did not reach {state!r} within {timeout_s:g} s (state {status.state!r}, "
                    f"{status.pressure_kpa:g} kPa)"
                )
                self._go_safe(reason)
                raise PumpError(
                    f"{reason}; the jig was sent to its safe state: check for a leak, the "
                    "pump and the filters"
                )
            time.sleep(self.poll_period_s)

    def close(self) -> None:
        with contextlib.suppress(Exception):
            self._serial.close()

    def __enter__(self) -> PumpController:
        return self

    def __exit__(self, *exc: object) -> None:
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
    work : the robot's work on the held part, given the estimate.
    cycles : how many parts.

    Returns
    -------
    list
        What ``sense`` returned for each part.

    Raises
    ------
    PumpError, or whatever a callback raised
        After the cycle went to ``FAULT`` and the jig to its safe state.
    """
    cycle = JigCycle()
    results: list[Any] = []
    command = cycle.handle(CycleEvent.START)
    estimate = None
    try:
        while True:
            if command is Command.RELEASE:
                if len(results) >= cycles:
                    pump.release(timeout_s=release_timeout_s)
                    cycle.handle(CycleEvent.STOP)
                    return results
                pump.release(timeout_s=release_timeout_s)
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
    except BaseException:
        cycle.handle(CycleEvent.FAULT)
        with contextlib.suppress(Exception):
            pump.safe()
        raise


# -------------------------------------------------------------------------------------- simulation


class SimulatedPumpController:
    """A pump controller answering the line protocol on a file descriptor (a pseudo-terminal's master).

    Parameters
    ----------
    fd : the descriptor to serve (read requests, write replies).
    fix_time_s, release_time_s : how long jamming and releasing take (s).
    fixed_pressure_kpa : the pressure at set-point (kPa).

    Attributes
    ----------
    silent : set to stop answering (a controller that hangs); requests are still logged.
    requests : every request line received, in order.
    state : the simulated state.

    Examples
    --------
    >>> sim, port = SimulatedPumpController.on_pty()                   # doctest: +SKIP
    >>> with sim, PumpController(port) as pump:
    ...     pump.fix()
    """

    def __init__(
        self,
        fd: int,
        *,
        fix_time_s: float = 0.2,
        release_time_s: float = 0.2,
        fixed_pressure_kpa: float = -60.0,
    ) -> None:
        self.fd = fd
        self.fix_time_s, self.release_time_s = fix_time_s, release_time_s
        self.fixed_pressure_kpa = fixed_pressure_kpa
        self.silent = False
        self.requests: list[str] = []
        self.state = "released"
        self._since = time.monotonic()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, name="softjig-pump-sim", daemon=True)
        self._owned_fds: list[int] = []

    @classmethod
    def on_pty(cls, **kwargs: Any) -> tuple[SimulatedPumpController, str]:
        """A simulator on a new pseudo-terminal pair, and the path of the terminal to open as the port."""
        import tty

        master, slave = os.openpty()
        tty.setraw(slave)
        sim = cls(master, **kwargs)
        sim._owned_fds = [master, slave]  # the slave stays open so the master never sees a hang-up
        return sim, os.ttyname(slave)

    def _pressure(self) -> float:
        elapsed = time.monotonic() - self._since
        if self.state == "fixing":
            return self.fixed_pressure_kpa * min(1.0, elapsed / self.fix_time_s)
        if self.state == "fixed":
            return self.fixed_pressure_kpa
        if self.state == "releasing":
            return self.fixed_pressure_kpa * max(0.0, 1.0 - elapsed / self.release_time_s)
        return 0.0

    def _advance(self) -> None:
        elapsed = time.monotonic() - self._since
        if self.state == "fixing" and elapsed >= self.fix_time_s:
            self.state, self._since = "fixed", time.monotonic()
        elif self.state == "releasing" and elapsed >= self.release_time_s:
            self.state, self._since = "released", time.monotonic()

    def reply(self, request: str) -> str:
        """The reply line (without ``\\n``) to a request (pure but for the simulated clock)."""
        self._advance()
        if request == "HELLO":
            return f"OK {PROTOCOL_NAME} {PROTOCOL_VERSION}"
        if request == "FIX":
            if self.state not in ("fixing", "fixed"):
                self.state, self._since = "fixing", time.monotonic()
            return f"OK state={self.state}"
        if request == "RELEASE":
            if self.state not in ("releasing", "released"):
                self.state, self._since = "releasing", time.monotonic()
            return f"OK state={self.state}"
        if request == "STOP":
            self.state, self._since = "safe", time.monotonic()
            return "OK state=safe"
        if request == "STATUS":
            return f"OK state={self.state} pressure_kpa={self._pressure():.2f} fault=none"
        if request == "PRESSURE":
            return f"OK pressure_kpa={self._pressure():.2f}"
        return f"ERR unknown request {request!r}"

    def _serve(self) -> None:
        buffer = b""
        while not self._stop.is_set():
            ready, _, _ = select.select([self.fd], [], [], 0.05)
            if not ready:
                continue
            try:
                data = os.read(self.fd, 1024)
            except OSError:
                return
            buffer += data
            while b"\n" in buffer:
                line, buffer = buffer.split(b"\n", 1)
                request = line.decode("ascii", errors="replace").strip()
                self.requests.append(request)
                if not self.silent:
                    os.write(self.fd, (self.reply(request) + "\n").encode("ascii"))

    def start(self) -> SimulatedPumpController:
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=2.0)
        for fd in self._owned_fds:
            with contextlib.suppress(OSError):
                os.close(fd)
        self._owned_fds = []

    def __enter__(self) -> SimulatedPumpController:
        return self.start() if not self._thread.is_alive() else self

    def __exit__(self, *exc: object) -> None:
        self.stop()
