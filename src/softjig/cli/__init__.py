"""The ``softjig`` command line: one module per command, all registered on :data:`app`.

Command modules are imported on first use (see :mod:`softjig.cli.app`, :data:`~softjig.cli.app.COMMANDS`).
"""

from __future__ import annotations

import atexit
import os
import sys
import threading
from typing import NoReturn

from softjig.cli.app import EXIT_BAD_INPUT, EXIT_NO_ESTIMATE, EXIT_OK, app, error, handle_errors, warn

__all__ = ["EXIT_BAD_INPUT", "EXIT_NO_ESTIMATE", "EXIT_OK", "app", "error", "handle_errors", "main", "warn"]

#: The exit status of a process whose stdout could not be flushed at exit (CPython's own, ``Py_Exit``).
EXIT_FLUSH_FAILED = 120


def main() -> NoReturn:
    """Console-script entry point (``softjig``): run the command, then end the process without the
    interpreter's teardown.

    The command has done its work, and every ``with`` and ``finally`` of it has run (outputs written,
    fsynced and renamed by :mod:`softjig.files` and the writers, worker pools stopped, temporary files
    removed), when :data:`app` raises ``SystemExit``. The interpreter would then tear down every module
    and object: about 0.35 s after a single-pair estimate on a quiet machine (a quarter of the command's
    time; 1.2-1.5 s at load 8), four fifths of it Python's garbage collector walking the ~135,000
    objects of NumPy, SciPy, Numba/LLVM and pydantic (measured with ``perf``; ``benchmarks/
    bench_startup.py`` prints it as "finalisation"), all for memory the kernel frees at exit anyway.
    :func:`end_process` keeps every exit step with an effect outside the process and skips that one.

    Exit codes are the app's (0, 2, 3, 130, 143, ...). Only an exception the app does not handle (a bug)
    takes the interpreter's normal path: its traceback, exit 1. In-process callers (tests, ``CliRunner``)
    call :data:`app` and keep an ordinary ``SystemExit``.
    """
    try:
        app(prog_name="softjig")
    except SystemExit as exc:
        code = exc.code
    else:  # standalone mode always raises SystemExit; kept for a future Typer that returns
        code = EXIT_OK
    end_process(code)


def end_process(code: int | str | None) -> NoReturn:
    """End the process with ``code`` as ``sys.exit(code)`` would, minus the interpreter's teardown.

    In the interpreter's order (``Py_FinalizeEx``): non-daemon threads joined, after ``threading``'s exit
    hooks (``concurrent.futures`` stops its pools' threads there); the :mod:`atexit` handlers
    (multiprocessing's children, ``weakref.finalize`` callbacks, logging, Ray); stdout and stderr flushed,
    and C's stdio buffers (a native library's ``printf``); then :func:`os._exit`. A ``code`` that is not
    an int is printed on stderr and exits 1, as in ``sys.exit("message")``; a stdout that cannot be
    flushed (a closed pipe) exits 120, as CPython does; a closed one is skipped, as CPython does.
    """
    if code is None:
        code = EXIT_OK
    elif not isinstance(code, int):
        print(code, file=sys.stderr)
        code = 1
    _join_threads()
    atexit._run_exitfuncs()
    for stream in (sys.stdout, sys.stderr):
        if stream is None or stream.closed:
            continue
        try:
            stream.flush()
        except OSError:  # a closed pipe (`softjig ... | head -1`)
            code = EXIT_FLUSH_FAILED
    _flush_c_stdio()
    os._exit(code)


def _join_threads() -> None:
    """``threading._shutdown()``, what the interpreter calls first at exit: ``threading``'s exit hooks, then
    the non-daemon threads joined.

    In CPython 3.11 a hook can raise ``OSError`` (``Bad file descriptor``; a race fixed later by
    gh-125451's lock): a process pool whose worker died closes its wake-up pipe in its manager thread
    while ``concurrent.futures``' exit hook writes to it (seen once in 1,986 tests: `softjig estimate
    --workers` with a worker killed). The interpreter prints such an exception and goes on without
    joining the threads. Here the hooks run once more, when the pipe is marked closed and
    ``concurrent.futures``' hooks (idempotent) skip it, so the threads are still joined; a second failure
    is let go, as the interpreter lets it go (the exit code stands).
    """
    import contextlib

    try:
        threading._shutdown()  # type: ignore[attr-defined]
    except OSError:
        with contextlib.suppress(OSError):
            threading._shutdown()  # type: ignore[attr-defined]


def _flush_c_stdio() -> None:
    """``fflush(NULL)``: what C's ``exit`` would flush and :func:`os._exit` does not."""
    import contextlib
    import ctypes

    with contextlib.suppress(OSError, AttributeError, TypeError):  # no C library by that name (not POSIX)
        ctypes.CDLL(None).fflush(None)
