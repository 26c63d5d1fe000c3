"""Processes that clean up: real `softjig` processes with workers, killed and interrupted from outside.

The workers are found through ``/proc`` (psutil is not a dependency): a parent killed by any signal,
SIGKILL included, leaves no worker behind; SIGTERM and SIGINT end the command within seconds with exit
143 / 130, no traceback and no temporary file.
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from softjig.config import default_jig
from softjig.io.simulated import simulate_dataset
from softjig.io.workers import Terminated, signals_unwrapped, terminate_raises
from softjig.sim.scenarios import paper_sweep

pytestmark = pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs Linux /proc")

_CLI = "import sys; sys.argv[0] = 'softjig'; from softjig.cli import main; main()"
#: How long, at most, a command may take to end after a signal (s); generous on a loaded 2-core machine.
END_WITHIN_S = 6.0


def _children(pid: int) -> set[int]:
    """The pids whose parent is ``pid`` (every thread's children, as the kernel lists them)."""
    found: set[int] = set()
    for task in Path(f"/proc/{pid}/task").glob("*/children"):
        with contextlib.suppress(OSError):
            found.update(int(p) for p in task.read_text().split())
    return found


def _alive(pid: int) -> bool:
    """Whether ``pid`` runs (a zombie waiting for its reaper does not)."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return stat.rsplit(")", 1)[1].split()[0] != "Z"


def _wait_for(predicate, timeout_s: float) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(0.05)
    return predicate()


@pytest.fixture(scope="module")
def long_dataset(tmp_path_factory):
    """A reference frame and three loaded frames, listed 60 times (240 frames): a run of many seconds."""
    root = tmp_path_factory.mktemp("proc") / "ds"
    specs = list(paper_sweep(diameters_mm=(50,), alphas_deg=(10,), theta_step_deg=120))
    simulate_dataset(root, specs, default_jig(), seed=2, workers=1, progress=False)
    frames = [json.loads(line) for line in (root / "frames.jsonl").read_text().splitlines()]
    with open(root / "frames.jsonl", "w") as fh:
        for k in range(60 * len(frames)):
            fh.write(json.dumps({**frames[k % len(frames)], "index": k}) + "\n")
    return root


def _start(args: list[str], cwd: Path) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-c", _CLI, *args],
        cwd=cwd,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )


def _start_with_workers(args: list[str], cwd: Path, n: int = 2) -> tuple[subprocess.Popen, set[int]]:
    proc = _start(args, cwd)
    assert _wait_for(lambda: len(_children(proc.pid)) >= n or proc.poll() is not None, 120), "no workers"
    workers = _children(proc.pid)
    assert proc.poll() is None and len(workers) >= n, proc.stderr.read() if proc.poll() is not None else ""
    time.sleep(0.3)  # the workers are at work
    return proc, workers


def _gone(workers: set[int], timeout_s: float) -> bool:
    """Whether every worker ended within ``timeout_s``; survivors are killed (no orphan outlives a failing
    test, and none keeps the test's stderr pipe open)."""
    if _wait_for(lambda: not any(_alive(pid) for pid in workers), timeout_s):
        return True
    for pid in workers:
        with contextlib.suppress(OSError):
            os.kill(pid, signal.SIGKILL)
    return False


def _estimate_args(root: Path, out: Path) -> list[str]:
    return ["estimate", str(root), "--workers", "2", "--no-progress", "--out", str(out)]


def _temporary_files(root: Path) -> list[Path]:
    return sorted(root.rglob("*.tmp"))


def test_sigkill_of_estimate_kills_its_workers_and_the_next_run_removes_its_temporary_file(
    long_dataset, tmp_path
):
    proc, workers = _start_with_workers(_estimate_args(long_dataset, tmp_path / "est.jsonl"), tmp_path)
    proc.kill()
    proc.wait(10)
    assert _gone(workers, 2.0), "workers outlived their parent"
    left = _temporary_files(tmp_path)  # nothing runs in a killed process: its results file's temporary
    assert [p.name.split(".")[3].split("-")[0] for p in left] == [str(proc.pid)]
    from softjig.files import remove_stale_temporaries

    assert remove_stale_temporaries(tmp_path / "est.jsonl") == left  # what the next run does first


@pytest.mark.parametrize(("signum", "code"), [(signal.SIGTERM, 143), (signal.SIGINT, 130)])
def test_sigterm_and_sigint_end_estimate_at_once_and_cleanly(long_dataset, tmp_path, signum, code):
    out = tmp_path / "est.jsonl"
    out.write_text("the old results\n")
    proc, workers = _start_with_workers(_estimate_args(long_dataset, out), tmp_path)
    t0 = time.monotonic()
    proc.send_signal(signum)  # the parent alone, as `kill` does
    try:
        returncode = proc.wait(END_WITHIN_S)
    except subprocess.TimeoutExpired:
        proc.kill()
        pytest.fail(f"still running {END_WITHIN_S} s after {signal.Signals(signum).name}")
    elapsed = time.monotonic() - t0
    assert _gone(workers, 1.0), "workers outlived their parent"
    stderr = proc.stderr.read()
    assert returncode == code, stderr
    assert "Traceback" not in stderr and "error:" in stderr
    assert _temporary_files(tmp_path) == []
    assert out.read_text() == "the old results\n"  # the results file is replaced only when complete
    print(f"{signal.Signals(signum).name}: ended in {elapsed:.2f} s")


def test_sigkill_of_simulate_kills_its_workers(tmp_path):
    args = ["simulate", "--scenario", "paper-sweep", "--diameters", "50,60", "--alphas", "10", "--theta-step",
            "30", "--workers", "2", "--no-progress", "--out", str(tmp_path / "sim")]  # fmt: skip
    proc, workers = _start_with_workers(args, tmp_path)
    proc.kill()
    proc.wait(10)
    assert _gone(workers, 2.0), "workers outlived their parent"


@pytest.mark.parametrize(("signum", "code"), [(signal.SIGTERM, 143), (signal.SIGINT, 130)])
def test_sigterm_and_sigint_end_simulate_at_once_without_temporary_files(tmp_path, signum, code):
    args = ["simulate", "--scenario", "paper-sweep", "--diameters", "50,60", "--alphas", "10", "--theta-step",
            "30", "--workers", "2", "--no-progress", "--out", str(tmp_path / "sim")]  # fmt: skip
    proc, workers = _start_with_workers(args, tmp_path)
    proc.send_signal(signum)
    try:
        returncode = proc.wait(END_WITHIN_S)
    except subprocess.TimeoutExpired:
        proc.kill()
        pytest.fail(f"still running {END_WITHIN_S} s after {signal.Signals(signum).name}")
    assert _gone(workers, 1.0), "workers outlived their parent"
    stderr = proc.stderr.read()
    assert returncode == code and "Traceback" not in stderr, stderr
    assert _temporary_files(tmp_path) == []


def test_terminate_raises_turns_sigterm_into_an_exception_and_restores_the_handler():
    before = signal.getsignal(signal.SIGTERM)
    cleaned = False
    with pytest.raises(Terminated) as info, terminate_raises():
        try:
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(5)
        finally:
            cleaned = True
    assert cleaned and info.value.exit_code == 143
    assert signal.getsignal(signal.SIGTERM) is before


def test_a_sigterm_that_a_library_turns_into_a_keyboard_interrupt_is_still_terminated():
    """Ray's ``ray.wait`` replaces the exception a signal handler raises while it waits by a plain
    ``KeyboardInterrupt`` (its ``check_status``): a SIGTERM must still end the command as one (143)."""
    with pytest.raises(Terminated) as info, terminate_raises():
        try:
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(5)
        except Terminated:
            raise KeyboardInterrupt from None  # what the library raises instead
    assert info.value.exit_code == 143
    with pytest.raises(KeyboardInterrupt) as ctrl_c, terminate_raises():
        raise KeyboardInterrupt  # a Ctrl-C, no SIGTERM: stays one
    assert not isinstance(ctrl_c.value, Terminated)


@pytest.mark.parametrize("signal_exc", [KeyboardInterrupt(), Terminated(signal.SIGTERM)])
def test_signals_unwrapped_raises_the_signal_behind_a_kernels_system_error(signal_exc):
    with pytest.raises(type(signal_exc)) as raised, signals_unwrapped():
        try:
            raise signal_exc
        except KeyboardInterrupt as exc:
            raise SystemError("returned a result with an exception set") from exc
    assert raised.value is signal_exc


def test_signals_unwrapped_passes_other_system_errors_and_follows_a_looping_chain_once():
    first, second = SystemError("a bug"), ValueError("its cause")
    first.__cause__, second.__cause__ = second, first
    with pytest.raises(SystemError, match="a bug"), signals_unwrapped():
        raise first


@pytest.mark.parametrize("signum", [signal.SIGKILL, signal.SIGTERM])
def test_demo_leaves_no_worker_behind(tmp_path, signum):
    args = [
        "demo",
        "--quick",
        "--cube-frames",
        "0",
        "--workers",
        "2",
        "--no-progress",
        "--out",
        str(tmp_path / "d"),
    ]
    proc, workers = _start_with_workers(args, tmp_path)
    proc.send_signal(signum)
    try:
        returncode = proc.wait(END_WITHIN_S)
    except subprocess.TimeoutExpired:
        proc.kill()
        pytest.fail(f"still running {END_WITHIN_S} s after {signal.Signals(signum).name}")
    assert _gone(workers, 2.0), "workers outlived their parent"
    if signum == signal.SIGTERM:
        stderr = proc.stderr.read()
        assert returncode == 143 and "Traceback" not in stderr, stderr
        assert _temporary_files(tmp_path) == []


def test_a_worker_killed_from_outside_ends_estimate_with_a_message_not_a_traceback(long_dataset, tmp_path):
    proc, workers = _start_with_workers(_estimate_args(long_dataset, tmp_path / "est.jsonl"), tmp_path)
    os.kill(min(workers), signal.SIGKILL)  # as the kernel's out-of-memory killer would
    try:
        returncode = proc.wait(END_WITHIN_S)
    except subprocess.TimeoutExpired:
        proc.kill()
        pytest.fail(f"still running {END_WITHIN_S} s after a worker was killed")
    assert _gone(workers, 1.0)
    stderr = proc.stderr.read()
    assert returncode == 2 and "a worker process died" in stderr and "Traceback" not in stderr, stderr
    assert _temporary_files(tmp_path) == [] and not (tmp_path / "est.jsonl").exists()
