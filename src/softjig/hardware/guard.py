"""Every way out of a hardware command is an exception: SIGTERM and SIGHUP become :class:`Terminated`.

Python turns Ctrl-C (SIGINT) into :class:`KeyboardInterrupt`, raised in the main thread, so ``with``
blocks and ``finally`` clauses run; SIGTERM (what ``kill``, systemd and robot supervisors send) and
SIGHUP (the terminal closed) would end the process at once, skipping them -- with the pump still running.
:func:`signals_as_exceptions` makes them raise :class:`Terminated` in the main thread instead, so the
pump's context manager sends ``STOP`` on every way out; :func:`signals_deferred` holds further signals
back while that ``STOP`` is on the wire (a second Ctrl-C must not cut the safe-state request short).

Signals whose handler is ``SIG_IGN`` when we start (``nohup``, a background job of a shell script) stay
ignored: whoever started us asked for that.
"""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Iterator
from types import FrameType

__all__ = ["Terminated", "exit_code_for", "signals_as_exceptions", "signals_deferred"]

#: Signals converted to :class:`Terminated` (SIGINT is Python's KeyboardInterrupt already).
_TERMINATING = ("SIGTERM", "SIGHUP")
_HANDLED = ("SIGINT", *_TERMINATING)


class Terminated(BaseException):
    """The process was asked to end by a signal (SIGTERM, SIGHUP).

    A :class:`BaseException`, like :class:`KeyboardInterrupt`, so ``except Exception`` does not swallow it.

    Attributes
    ----------
    signum : the signal's number.
    """

    def __init__(self, signum: int) -> None:
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


def exit_code_for(exc: BaseException) -> int:
    """The shell's exit code for a process ended by ``exc``'s signal: 128 + the signal's number."""
    if isinstance(exc, Terminated):
        return 128 + exc.signum
    return 128 + signal.SIGINT


def _in_main_thread() -> bool:
    return threading.current_thread() is threading.main_thread()


def _signals(names: tuple[str, ...]) -> list[signal.Signals]:
    return [getattr(signal, name) for name in names if hasattr(signal, name)]


def _raise_terminated(signum: int, _frame: FrameType | None) -> None:
    raise Terminated(signum)


@contextlib.contextmanager
def signals_as_exceptions() -> Iterator[None]:
    """Within the block, SIGTERM and SIGHUP raise :class:`Terminated` and SIGINT ``KeyboardInterrupt``.

    Outside the main thread (where Python cannot install handlers) it does nothing. The previous handlers
    are restored on the way out.
    """
    if not _in_main_thread():
        yield
        return
    previous: dict[signal.Signals, object] = {}
    try:
        for sig in _signals(_HANDLED):
            current = signal.getsignal(sig)
            if current is signal.SIG_IGN:
                continue
            handler = signal.default_int_handler if sig == signal.SIGINT else _raise_terminated
            previous[sig] = signal.signal(sig, handler)
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)  # type: ignore[arg-type]


@contextlib.contextmanager
def signals_deferred() -> Iterator[list[int]]:
    """Within the block, SIGINT, SIGTERM and SIGHUP are only recorded (the list yielded), not raised.

    For the few hundred milliseconds of a safe-state request: the process is already on its way out, so
    a second signal changes nothing but must not interrupt ``STOP``. Does nothing outside the main thread.
    """
    received: list[int] = []
    if not _in_main_thread():
        yield received
        return

    def record(signum: int, _frame: FrameType | None) -> None:
        received.append(signum)

    previous: dict[signal.Signals, object] = {}
    try:
        for sig in _signals(_HANDLED):
            if signal.getsignal(sig) is signal.SIG_IGN:
                continue
            previous[sig] = signal.signal(sig, record)
        yield received
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)  # type: ignore[arg-type]
