"""Processes that clean up: worker pools whose workers die with their parent, and SIGTERM as an exception.

Two rules, for every command that runs worker processes (``estimate DATASET``, ``simulate``, ``demo``):

* **A worker never outlives its parent.** Each worker asks the kernel for ``SIGKILL`` when its parent dies
  (Linux ``prctl(PR_SET_PDEATHSIG)``, through :mod:`ctypes`), then checks that its parent is still the
  process that started it (the parent may have died between the fork and the ``prctl``: the signal is then
  never sent). Where ``prctl`` is missing (macOS, Windows) a daemon thread of the worker polls its parent's
  pid instead. So a parent killed by any signal, ``SIGKILL`` included, leaves no orphan (before: each
  orphan kept ~130 MB and a core until its queue ran dry). A worker ignores ``SIGINT``: a Ctrl-C in a
  terminal reaches the whole process group, and the parent alone decides (it stops the workers); the
  workers print no tracebacks.
* **A command ends within a second or two of SIGINT or SIGTERM, with its exit code and no traceback.**
  :func:`terminate_raises` turns ``SIGTERM`` (and ``SIGHUP``) into a :class:`Terminated` exception in the
  main thread, so every ``finally`` runs (atomic writers remove their temporary files, a pump is sent to
  its safe state); the CLI maps it to ``128 + signal`` (143 for SIGTERM) as a shell would. A pool left by an
  exception (:func:`worker_pool`) cancels its queue and terminates its workers at once instead of waiting
  for the tasks in progress (a frame being rendered could hold Ctrl-C for minutes).

``PR_SET_PDEATHSIG`` fires when the *thread* that forked the worker ends; :class:`ProcessPoolExecutor`
(Python 3.11) starts its workers in the thread that submits, so submit from the main thread.
"""

from __future__ import annotations

import contextlib
import os
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterator
from typing import TYPE_CHECKING, Any

from softjig.errors import SoftjigError

if TYPE_CHECKING:  # imported when a pool is made: every command imports this module (the CLI's signals)
    from concurrent.futures import ProcessPoolExecutor

__all__ = [
    "Terminated",
    "die_with_parent",
    "init_worker",
    "signals_unwrapped",
    "stderr_progress",
    "stop_pool",
    "terminate_raises",
    "worker_pool",
]

_PR_SET_PDEATHSIG = 1  # <linux/prctl.h>
#: Seconds the workers of an aborted pool get to end after SIGTERM before they are killed.
TERMINATE_GRACE_S = 1.0
#: Seconds between two checks of the parent's pid where ``prctl`` is missing.
PARENT_POLL_S = 0.25


class Terminated(KeyboardInterrupt):
    """The process received ``SIGTERM`` or ``SIGHUP`` (:func:`terminate_raises`).

    A :class:`KeyboardInterrupt`, so that code stopping cleanly on Ctrl-C stops the same way on a
    SIGTERM; :attr:`exit_code` is the shell's ``128 + signal``.
    """

    def __init__(self, signum: int) -> None:
        super().__init__(f"terminated by {signal.Signals(signum).name}")
        self.signum = int(signum)

    @property
    def exit_code(self) -> int:
        """``128 + signal``: 143 for SIGTERM, 129 for SIGHUP."""
        return 128 + self.signum


@contextlib.contextmanager
def terminate_raises(signums: tuple[int, ...] = (signal.SIGTERM, signal.SIGHUP)) -> Iterator[None]:
    """Inside: ``SIGTERM`` (and ``SIGHUP``) raise :class:`Terminated` in the main thread; restored after.

    Each such signal raises, as each Ctrl-C raises :class:`KeyboardInterrupt` (ignoring a second one would
    leave a process that swallowed the first deaf to SIGTERM for ever). A plain ``KeyboardInterrupt`` that
    leaves the block after such a signal is raised as its :class:`Terminated`: a library waiting in
    compiled code may replace the handler's exception by its own ``KeyboardInterrupt`` (Ray's ``ray.wait``
    does, through its ``check_status``: a study on a Ray cluster then exited 130, not 143). Outside the
    main thread (signals cannot be handled there) this does nothing.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    received: list[int] = []

    def handler(signum: int, _frame: object) -> None:
        received.append(signum)
        raise Terminated(signum)

    previous = {}
    for signum in signums:
        with contextlib.suppress(OSError, ValueError):  # a signal this platform lacks
            previous[signum] = signal.signal(signum, handler)
    try:
        yield
    except KeyboardInterrupt as exc:
        if received and not isinstance(exc, Terminated):
            raise Terminated(received[-1]) from None
        raise
    finally:
        for signum, old in previous.items():
            signal.signal(signum, old)


@contextlib.contextmanager
def signals_unwrapped() -> Iterator[None]:
    """Inside: a ``SystemError`` caused by Ctrl-C or :class:`Terminated` is raised as that exception.

    A signal handler's exception raised while a compiled kernel calls back into Python (Numba's
    ``_numba_unpickle``) reaches the caller as ``SystemError: ... returned a result with an exception
    set`` whose cause is the ``KeyboardInterrupt``; code that stops cleanly on Ctrl-C (and says how to
    resume) would take it for a bug. Any other ``SystemError`` passes unchanged.
    """
    try:
        yield
    except SystemError as exc:
        signal_exc = _signal_behind(exc)
        if signal_exc is None:
            raise
        raise signal_exc from None


def _signal_behind(exc: BaseException) -> KeyboardInterrupt | None:
    """The ``KeyboardInterrupt`` (or :class:`Terminated`) among ``exc``'s causes and contexts, if any."""
    seen: BaseException | None = exc
    visited: set[int] = set()  # a chain may loop (``raise a from b`` with ``b`` caused by ``a``)
    while seen is not None and id(seen) not in visited:
        visited.add(id(seen))
        if isinstance(seen, KeyboardInterrupt):
            return seen
        seen = seen.__cause__ or seen.__context__
    return None


def die_with_parent(parent_pid: int) -> None:
    """Make this process (a worker) end when the process ``parent_pid`` that started it ends.

    Linux: the kernel sends ``SIGKILL`` on the parent's death (``PR_SET_PDEATHSIG``); elsewhere, a daemon
    thread polls :func:`os.getppid` every :data:`PARENT_POLL_S`. If the parent is already gone (this
    process was re-parented before the request took effect), the process exits at once.
    """
    armed = False
    if sys.platform.startswith("linux"):
        try:
            import ctypes

            libc = ctypes.CDLL(None, use_errno=True)
            armed = libc.prctl(_PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0) == 0
        except (OSError, AttributeError):
            armed = False
    if os.getppid() != parent_pid:  # the parent died before the request: nobody will signal us
        os._exit(1)
    if armed:
        return

    def watch() -> None:
        while os.getppid() == parent_pid:
            time.sleep(PARENT_POLL_S)
        os._exit(1)

    threading.Thread(target=watch, name="softjig-parent-watch", daemon=True).start()


def init_worker(parent_pid: int, initializer: Callable[..., None] | None, *initargs: Any) -> None:
    """A pool worker's first act: die with the parent, leave Ctrl-C to the parent, default SIGTERM (a
    forked worker inherits the parent's handlers), then the pool's own ``initializer(*initargs)``."""
    die_with_parent(parent_pid)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    with contextlib.suppress(OSError, ValueError, AttributeError):
        signal.signal(signal.SIGHUP, signal.SIG_DFL)
    if initializer is not None:
        initializer(*initargs)


def stop_pool(pool: ProcessPoolExecutor, *, abort: bool) -> None:
    """Shut a pool down: wait for its tasks, or, with ``abort``, cancel the queue and end the workers now
    (SIGTERM, then SIGKILL after :data:`TERMINATE_GRACE_S`)."""
    if not abort:
        pool.shutdown(wait=True, cancel_futures=True)
        return
    # ProcessPoolExecutor has no public way to end its workers before Python 3.14 (terminate_workers).
    processes = list((getattr(pool, "_processes", None) or {}).values())
    pool.shutdown(wait=False, cancel_futures=True)
    for process in processes:
        with contextlib.suppress(Exception):
            process.terminate()
    deadline = time.monotonic() + TERMINATE_GRACE_S
    for process in processes:
        with contextlib.suppress(Exception):
            process.join(max(0.0, deadline - time.monotonic()))
            if process.is_alive():
                process.kill()
                process.join(1.0)


@contextlib.contextmanager
def worker_pool(
    workers: int,
    *,
    mp_context: Any = None,
    initializer: Callable[..., None] | None = None,
    initargs: tuple = (),
) -> Iterator[ProcessPoolExecutor]:
    """A :class:`ProcessPoolExecutor` whose workers die with this process (:func:`init_worker`); left
    normally it waits for its tasks, left by an exception (Ctrl-C, SIGTERM, an error, a generator closed
    early) it ends its workers at once (:func:`stop_pool`).

    Raises
    ------
    SoftjigError
        A worker died (``BrokenProcessPool``: the kernel's out-of-memory killer, a signal): a message
        saying so instead of a traceback (exit 2)."""
    from concurrent.futures import ProcessPoolExecutor

    pool = ProcessPoolExecutor(
        workers,
        mp_context=mp_context,
        initializer=init_worker,
        initargs=(os.getpid(), initializer, *initargs),
    )
    try:
        yield pool
    except BaseException as exc:
        stop_pool(pool, abort=True)
        from concurrent.futures.process import BrokenProcessPool

        if isinstance(exc, BrokenProcessPool):  # a worker was killed (out of memory, by hand)
            raise SoftjigError(
                "a worker process died (killed by the system, for instance out of memory, or by a "
                "signal): nothing was lost; run again, with fewer --workers if memory is short"
            ) from None
        raise
    stop_pool(pool, abort=False)


#: The environment variables that set the thread count of BLAS, OpenMP and Numba in a new process.
THREAD_VARIABLES = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS")


@contextlib.contextmanager
def one_thread_per_worker() -> Iterator[None]:
    """Workers started inside run one OpenCV thread each (and, when spawned, one BLAS/OpenMP/Numba thread):
    the workers are the parallelism, and more threads than cores slow every worker down. A forked worker
    inherits this process's OpenCV setting, so it is set to one thread while the workers start and
    restored after, with the environment variables."""
    import cv2

    saved = {name: os.environ.get(name) for name in THREAD_VARIABLES}
    threads = cv2.getNumThreads()
    os.environ.update(dict.fromkeys(THREAD_VARIABLES, "1"))
    cv2.setNumThreads(1)
    try:
        yield
    finally:
        cv2.setNumThreads(threads)
        for name, value in saved.items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value


def stderr_progress(label: str, *fields: str, eta: str | None = None) -> Any:
    """A (not yet started) Rich progress bar on stderr: ``label``, the bar, done/total, a text column per
    format string of ``fields``, elapsed time, then ``eta`` (a text, if given) and the time remaining."""
    from rich.console import Console
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )

    columns = [TextColumn(label), BarColumn(), MofNCompleteColumn(), *map(TextColumn, fields)]
    columns += [TimeElapsedColumn(), *([TextColumn(eta)] if eta is not None else []), TimeRemainingColumn()]
    return Progress(*columns, console=Console(stderr=True))
