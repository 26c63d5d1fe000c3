"""The jig's work cycle as a pure state machine: release, place, fix, sense, (hold), release.

The paper's cycle: the jig is soft (oil in), a part is placed and pushed in, the oil is pumped out so the
beads jam and the part is held, the cameras sense its orientation, the robot works on it, and the jig
releases it. Each state has one *command* for the I/O layer (:func:`softjig.hardware.pump.run_cycle`) to
carry out; the outcome comes back as an *event*; :func:`step` gives the next state and its command. Any
fault, from any state, goes to ``FAULT`` with the command ``SAFE`` (``STOP``: pump off, valve closed, so
a held part stays held -- see :mod:`softjig.hardware.protocol` for why); only ``RESET`` leaves ``FAULT``,
by releasing, the deliberate step that frees the part.

::

    IDLE --START--> RELEASING --RELEASED--> AWAIT_PART --PART_PLACED--> FIXING --FIXED--> SENSING
      SENSING --SENSED--> HOLDING --WORK_DONE--> RELEASING ...
      any --FAULT--> FAULT --RESET--> RELEASING          any --STOP--> IDLE (command SAFE)
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

from softjig.errors import InputError

__all__ = ["Command", "CycleEvent", "CycleState", "JigCycle", "Transition", "step"]


class CycleState(enum.Enum):
    """Where the cycle is."""

    IDLE = "idle"
    RELEASING = "releasing"
    AWAIT_PART = "await_part"
    FIXING = "fixing"
    SENSING = "sensing"
    HOLDING = "holding"
    FAULT = "fault"


class CycleEvent(enum.Enum):
    """What happened."""

    START = "start"
    RELEASED = "released"
    PART_PLACED = "part_placed"
    FIXED = "fixed"
    SENSED = "sensed"
    WORK_DONE = "work_done"
    FAULT = "fault"
    RESET = "reset"
    STOP = "stop"


class Command(enum.Enum):
    """What the I/O layer must do on entering a state."""

    RELEASE = "release"
    WAIT_FOR_PART = "wait_for_part"
    FIX = "fix"
    SENSE = "sense"
    REPORT = "report"
    SAFE = "safe"


@dataclass(frozen=True)
class Transition:
    """The state entered and the command to carry out there."""

    state: CycleState
    command: Command


S, E, C = CycleState, CycleEvent, Command
_TABLE: dict[tuple[CycleState, CycleEvent], Transition] = {
    (S.IDLE, E.START): Transition(S.RELEASING, C.RELEASE),
    (S.RELEASING, E.RELEASED): Transition(S.AWAIT_PART, C.WAIT_FOR_PART),
    (S.AWAIT_PART, E.PART_PLACED): Transition(S.FIXING, C.FIX),
    (S.FIXING, E.FIXED): Transition(S.SENSING, C.SENSE),
    (S.SENSING, E.SENSED): Transition(S.HOLDING, C.REPORT),
    (S.HOLDING, E.WORK_DONE): Transition(S.RELEASING, C.RELEASE),
    (S.FAULT, E.RESET): Transition(S.RELEASING, C.RELEASE),
}


def step(state: CycleState, event: CycleEvent) -> Transition:
    """The transition taken by ``event`` in ``state`` (pure).

    Raises
    ------
    InputError
        ``event`` cannot happen in ``state``; the message lists the events that can.
    """
    if event is E.FAULT:
        return Transition(S.FAULT, C.SAFE)
    if event is E.STOP:
        return Transition(S.IDLE, C.SAFE)
    try:
        return _TABLE[(state, event)]
    except KeyError:
        valid = [e.value for (s, e) in _TABLE if s is state] + [E.FAULT.value, E.STOP.value]
        raise InputError(
            f"event {event.value!r} cannot happen in state {state.value!r}; valid there: {', '.join(valid)}"
        ) from None


class JigCycle:
    """A cycle's current state and its history (the only mutable part; :func:`step` does the logic)."""

    def __init__(self, state: CycleState = CycleState.IDLE) -> None:
        self.state = state
        self.history: list[tuple[CycleState, CycleEvent, CycleState]] = []

    def handle(self, event: CycleEvent) -> Command:
        """Apply ``event``; returns the command of the new state."""
        transition = step(self.state, event)
        self.history.append((self.state, event, transition.state))
        self.state = transition.state
        return transition.command
