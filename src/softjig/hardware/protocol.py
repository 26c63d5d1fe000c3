"""The pump controller's line protocol (version 2), as pure functions: request lines and reply parsing.

The jig jams by pumping oil *out* of the membrane (the beads pack and hold the part) and softens by
letting it back in (Sakuma et al., "Design of soft-jig"). A small controller (a microcontroller driving
the pump and a valve, reading a pressure sensor) talks to the host over a serial line.

The safe state of the jig
-------------------------
**Pump off, valve closed (de-energised; a normally-closed valve): the oil stays where it is, so the jig
keeps what it has** -- a jammed part stays held (passively, for as long as the membrane holds its
vacuum), a soft jig stays soft. Only an explicit ``RELEASE`` lets the oil back and frees the part.

Why: in a robot cell the part is held *because* a robot is working on it. Releasing on a fault, a host
crash or a Ctrl-C can let a part drop or shift under a tool that is still moving -- a crash, a scrapped
part, a hazard. The only active hazard of the jig itself is the pump (heat, over-pressure, a burst line),
and stopping its motor removes it. Holding what we have is also what the hardware does when it loses
power (a normally-closed valve closes, the motor stops), so "safe", "unpowered" and "watchdog expired" are
the same state, and freeing the part stays a decision of whoever knows the tool is clear (``softjig jig
release``).

The three ways to the safe state agree:

* ``STOP`` (sent by the host on every fault, on Ctrl-C, SIGTERM and any exception while a command runs);
* the controller's **watchdog**: hearing no request for :data:`WATCHDOG_MIN_S` s or more (the firmware's
  own setting, at least that long), it goes to the safe state by itself;
* the host's **heartbeat** (``softjig jig hold``) sends ``STATUS`` every :data:`HEARTBEAT_PERIOD_S` s
  while a part is meant to stay *actively* fixed (the pump regulating the set-point) and ends with
  ``STOP``. Without a heartbeat (after ``softjig jig fix`` returns) the watchdog stops the pump within
  seconds and the part stays held passively: the controller then reports ``state=safe``.

The safe state (and the controller's own ``fault`` state) is **latched until** ``RELEASE``: the
controller answers ``FIX`` there with ``ERR``, and the host refuses ``FIX`` whenever ``STATUS`` reports
``safe`` or ``fault``. The latch lives in the controller because the controller is what every host
process, every later invocation of the command line and every other machine sees the same way; a host
process forgets, and a file on one host is wrong for another host, another user or after someone
released the jig by other means.

Requests and replies
--------------------
Serial, 115200 baud 8N1 by default; ASCII; one request per line, one reply per line, lines end in
``\\n`` (a ``\\r`` before it is ignored), a reply at most :data:`MAX_REPLY_BYTES` bytes with its newline.
The host waits for each reply (the whole line, within its timeout) before sending the next request.

=============  ===============================================  ============================================
request        reply                                            effect
=============  ===============================================  ============================================
``HELLO``      ``OK softjig-pump 2``                            names the protocol and its version
``FIX``        ``OK state=fixing``                              pump oil out; ``fixed`` once at set-point
                                                                (the pump keeps regulating while it hears
                                                                the host); ``ERR`` in ``safe``/``fault``
``RELEASE``    ``OK state=releasing``                           pump off, valve open: oil flows back;
                                                                ``released`` once at ambient pressure;
                                                                the only way out of ``safe`` and ``fault``
``STOP``       ``OK state=safe`` (``OK state=fault`` when       the safe state: pump off, valve closed;
               the controller is in its own fault)              the jig keeps what it holds
``STATUS``     ``OK state=S pressure_kpa=P fault=F``            ``S`` one of :data:`STATES`; ``P`` the oil's
                                                                gauge pressure, kPa (negative when drawn
                                                                out); ``F`` ``none`` or a word
``PRESSURE``   ``OK pressure_kpa=P``                            the pressure alone
=============  ===============================================  ============================================

A refused or failed request is answered ``ERR <text>``. A pressure that is missing or not a finite number
is a fault (a sensor problem), like a garbled reply.

Version 2 differs from version 1 in meaning, not in syntax: ``STOP`` closes the valve (version 1 opened
it and the jig softened), the watchdog goes to that same state, ``safe`` and ``fault`` are latched until
``RELEASE`` (``FIX`` there is ``ERR``), replies are bounded to :data:`MAX_REPLY_BYTES`. A version-1
controller is refused at ``HELLO``: it would drop the part on a fault.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from softjig.errors import SoftjigError

__all__ = [
    "DEFAULT_BAUDRATE",
    "HEARTBEAT_PERIOD_S",
    "MAX_REPLY_BYTES",
    "PROTOCOL_NAME",
    "PROTOCOL_VERSION",
    "REQUESTS",
    "SAFE_STATES",
    "STATES",
    "WATCHDOG_MIN_S",
    "PumpError",
    "PumpStatus",
    "format_request",
    "parse_pressure",
    "parse_reply",
    "parse_status",
]

PROTOCOL_VERSION = 2
PROTOCOL_NAME = "softjig-pump"
REQUESTS = ("HELLO", "FIX", "RELEASE", "STOP", "STATUS", "PRESSURE")
#: The controller's states.
STATES = ("released", "fixing", "fixed", "releasing", "safe", "fault")
#: States with the pump off and the valve closed; both are latched until ``RELEASE``.
SAFE_STATES = ("safe", "fault")
DEFAULT_BAUDRATE = 115200
#: The longest reply line accepted, newline included (bytes); a longer one is a fault.
MAX_REPLY_BYTES = 256
#: The shortest watchdog a controller may use (s): silent this long, it goes to its safe state.
WATCHDOG_MIN_S = 2.0
#: The host's heartbeat period while it holds a part (s): a quarter of the shortest watchdog.
HEARTBEAT_PERIOD_S = WATCHDOG_MIN_S / 4


class PumpError(SoftjigError):
    """The pump controller failed, refused, or could not be reached; the message says what to check.

    Attributes
    ----------
    stop_attempted : ``True`` when the host already tried to send the jig to its safe state for this
        error (or found it there), so the caller need not do it again.
    """

    def __init__(self, message: str, *, stop_attempted: bool = False) -> None:
        super().__init__(message)
        self.stop_attempted = stop_attempted


@dataclass(frozen=True)
class PumpStatus:
    """The controller's state.

    Attributes
    ----------
    state : one of :data:`STATES`.
    pressure_kpa : gauge pressure of the oil in the membrane (kPa; negative when oil is drawn out);
        always finite (a controller reporting anything else is a fault).
    fault : the controller's fault word, or ``None``.
    """

    state: str
    pressure_kpa: float
    fault: str | None = None

    def to_dict(self) -> dict[str, Any]:
        return {"state": self.state, "pressure_kpa": self.pressure_kpa, "fault": self.fault}


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
            f"garbled reply{what} from the pump controller: {text[:80]!r} (wrong baud rate, or "
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


def parse_pressure(fields: dict[str, str]) -> float:
    """The finite ``pressure_kpa`` of a reply (kPa).

    Raises
    ------
    PumpError
        Missing, not a number, NaN or infinite: the pressure sensor (or the controller) is faulty.
    """
    text = fields.get("pressure_kpa")
    try:
        pressure = float(text) if text is not None else math.nan
    except ValueError:
        pressure = math.nan
    if not math.isfinite(pressure):
        raise PumpError(
            f"the pump controller reported no valid pressure (pressure_kpa={text!r}): check the "
            "pressure sensor and its wiring"
        )
    return pressure


def parse_status(fields: dict[str, str]) -> PumpStatus:
    """A :class:`PumpStatus` from the fields of a ``STATUS`` reply.

    Raises
    ------
    PumpError
        An unknown state, or a missing or non-finite pressure.
    """
    state = fields.get("state")
    if state not in STATES:
        raise PumpError(
            f"the pump controller reported an unknown state {state!r}; expected one of {', '.join(STATES)}"
        )
    pressure = parse_pressure(fields)
    fault = fields.get("fault", "none")
    return PumpStatus(state=state, pressure_kpa=pressure, fault=None if fault == "none" else fault)
