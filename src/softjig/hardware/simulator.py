"""A simulated pump controller speaking the line protocol on a pseudo-terminal (tests and dry runs).

It behaves as :mod:`softjig.hardware.protocol` requires of a firmware: ``STOP`` and its watchdog put it in
the safe state (pump off, valve closed: the pressure stays where it was, the part stays held); ``safe``
and ``fault`` are latched until ``RELEASE`` (``FIX`` there is answered ``ERR``).
"""

from __future__ import annotations

import contextlib
import os
import select
import threading
import time
from typing import Any

from softjig.hardware.protocol import PROTOCOL_NAME, PROTOCOL_VERSION, SAFE_STATES, WATCHDOG_MIN_S

__all__ = ["SimulatedPumpController"]


class SimulatedPumpController:
    """A pump controller answering the line protocol on a file descriptor (a pseudo-terminal's master).

    Parameters
    ----------
    fd : the descriptor to serve (read requests, write replies).
    fix_time_s, release_time_s : how long jamming and releasing take (s).
    fixed_pressure_kpa : the pressure at set-point (kPa).
    watchdog_s : silent this long (s) while the pump or valve is active (``fixing``, ``fixed``,
        ``releasing``), the controller goes to its safe state by itself; ``None``: no watchdog (a
        non-compliant firmware).

    Attributes
    ----------
    silent : set to stop answering (a controller that hangs); requests are still logged.
    requests : every request line received, in order.
    state : the simulated state.
    watchdog_trips : how often the watchdog sent the controller to its safe state.

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
        watchdog_s: float | None = WATCHDOG_MIN_S,
    ) -> None:
        self.fd = fd
        self.fix_time_s, self.release_time_s = fix_time_s, release_time_s
        self.fixed_pressure_kpa = fixed_pressure_kpa
        self.watchdog_s = watchdog_s
        self.silent = False
        self.requests: list[str] = []
        self.state = "released"
        self.fault_word: str | None = None
        self.watchdog_trips = 0
        self._held_kpa = 0.0  # the pressure frozen by the safe state
        self._since = time.monotonic()
        self._last_request = time.monotonic()
        self._lock = threading.Lock()
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

    # -- the simulated plant
    def pressure(self) -> float:
        """The oil's gauge pressure now (kPa)."""
        elapsed = time.monotonic() - self._since
        if self.state == "fixing":
            start = self._held_kpa
            return start + (self.fixed_pressure_kpa - start) * min(1.0, elapsed / self.fix_time_s)
        if self.state == "fixed":
            return self.fixed_pressure_kpa
        if self.state == "releasing":
            return self._held_kpa * max(0.0, 1.0 - elapsed / self.release_time_s)
        if self.state in SAFE_STATES:
            return self._held_kpa
        return 0.0

    def _enter(self, state: str) -> None:
        self._held_kpa = self.pressure()
        self.state, self._since = state, time.monotonic()

    def _advance(self) -> None:
        elapsed = time.monotonic() - self._since
        if self.state == "fixing" and elapsed >= self.fix_time_s:
            self._enter("fixed")
        elif self.state == "releasing" and elapsed >= self.release_time_s:
            self._enter("released")
        if (
            self.watchdog_s is not None
            and self.state in ("fixing", "fixed", "releasing")
            and time.monotonic() - self._last_request > self.watchdog_s
        ):
            self._enter("safe")
            self.watchdog_trips += 1

    def set_fault(self, word: str) -> None:
        """The controller detects a fault of its own (``state=fault``: pump off, valve closed)."""
        with self._lock:
            self._enter("fault")
            self.fault_word = word

    def reply(self, request: str) -> str:
        """The reply line (without ``\\n``) to a request (pure but for the simulated clock)."""
        self._advance()
        if request == "HELLO":
            return f"OK {PROTOCOL_NAME} {PROTOCOL_VERSION}"
        if request == "FIX":
            if self.state in SAFE_STATES:
                return f"ERR {self.state} state latched: send RELEASE first"
            if self.state not in ("fixing", "fixed"):
                self._enter("fixing")
            return f"OK state={self.state}"
        if request == "RELEASE":
            if self.state not in ("releasing", "released"):
                self._enter("releasing")
                self.fault_word = None
            return f"OK state={self.state}"
        if request == "STOP":
            if self.state != "fault":
                self._enter("safe")
            return f"OK state={self.state}"
        if request == "STATUS":
            return (
                f"OK state={self.state} pressure_kpa={self.pressure():.2f} fault={self.fault_word or 'none'}"
            )
        if request == "PRESSURE":
            return f"OK pressure_kpa={self.pressure():.2f}"
        return f"ERR unknown request {request!r}"

    # -- the serial line
    def write(self, data: bytes) -> None:
        """Write raw bytes to the line (for controllers that misbehave)."""
        with contextlib.suppress(OSError):
            os.write(self.fd, data)

    def respond(self, request: str) -> None:
        """Answer one request on the line (a subclass may dribble, spew or say nothing)."""
        self.write((self.reply(request) + "\n").encode("ascii"))

    def _serve(self) -> None:
        buffer = b""
        while not self._stop.is_set():
            with self._lock:
                self._advance()  # the watchdog runs whether or not requests come
            try:
                ready, _, _ = select.select([self.fd], [], [], 0.02)
                if not ready:
                    continue
                data = os.read(self.fd, 1024)
            except (OSError, ValueError):
                return
            buffer += data
            while b"\n" in buffer:
                line, buffer = buffer.split(b"\n", 1)
                request = line.decode("ascii", errors="replace").strip()
                with self._lock:
                    self.requests.append(request)
                    self._last_request = time.monotonic()
                    if not self.silent:
                        self.respond(request)

    def disconnect(self) -> None:
        """The serial device disappears (unplugged): the host's reads and writes fail from now on."""
        self._stop.set()
        if self._thread.is_alive() and self._thread is not threading.current_thread():
            self._thread.join(timeout=2.0)
        if self._owned_fds:
            with contextlib.suppress(OSError):
                os.close(self._owned_fds[0])
            self._owned_fds = self._owned_fds[1:]

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
