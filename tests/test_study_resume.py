"""A study killed half-way (a real `softjig study` process, SIGTERM then SIGKILL) resumes where it stopped,
recomputes nothing it finished, and ends with the rows of an uninterrupted run (issue 17, deliverable 3)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pyarrow.parquet as pq
import pytest

from softjig.errors import InputError
from softjig.study.execute import run_study
from softjig.study.spec import load_study

pytestmark = pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs Linux signals and /proc")

_CLI = "import sys; sys.argv[0] = 'softjig'; from softjig.cli import main; main()"
#: Six designs of two frames and one method: six tasks of about a second each.
STUDY = """
[study]
name = "resume"
seeds = [1]
[vary]
"markers.pitch_mm" = [7.0, 8.0, 9.0]
"cameras.baseline_mm" = [26.0, 34.0]
[frames]
diameters_mm = [50]
alphas_deg = [12]
theta_step_deg = 180
[estimate]
methods = ["refractive"]
"""
N_TASKS = 6
WAIT_S = 240.0  # a cold Numba cache on a loaded 2-core machine


def _start(study: Path, out: Path, *extra: str) -> subprocess.Popen:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    return subprocess.Popen(
        [
            sys.executable,
            "-c",
            _CLI,
            "study",
            str(study),
            "--out",
            str(out),
            "--no-progress",
            "--no-report",
            *extra,
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
    )


def _parts(out: Path) -> dict[str, tuple[int, int]]:
    """Each finished part's (inode, mtime_ns): a part recomputed would be a new file."""
    folder = out / "parts"
    if not folder.is_dir():
        return {}
    return {p.name: (p.stat().st_ino, p.stat().st_mtime_ns) for p in folder.glob("*.parquet")}


def _wait_for_parts(process: subprocess.Popen, out: Path, n: int) -> None:
    deadline = time.monotonic() + WAIT_S
    while len(_parts(out)) < n:
        assert process.poll() is None, process.communicate()
        assert time.monotonic() < deadline, "the study did not finish tasks in time"
        time.sleep(0.05)


def _rows(table) -> list[dict]:
    return [{k: v for k, v in row.items() if k != "estimate_ms"} for row in table.to_pylist()]


def test_a_killed_study_resumes_and_equals_an_uninterrupted_run(tmp_path):
    study = tmp_path / "study.toml"
    study.write_text(STUDY, encoding="utf-8")
    out = tmp_path / "out"
    # 1. SIGTERM after two tasks: exit 143, what finished is consolidated, nothing half-written
    first = _start(study, out, "--workers", "1")
    _wait_for_parts(first, out, 2)
    first.send_signal(signal.SIGTERM)
    _, stderr = first.communicate(timeout=60)
    assert first.returncode == 143, stderr
    assert "Traceback" not in stderr
    kept = _parts(out)
    assert 2 <= len(kept) < N_TASKS
    assert len(pq.read_table(out / "results.parquet")) == 2 * len(kept)
    assert not list(out.rglob("*.tmp"))
    # 2. without --resume the folder is refused, untouched
    with pytest.raises(InputError, match="--resume"):
        run_study(load_study(study), out, workers=1, progress=False, report=False)
    assert _parts(out) == kept
    # 3. resumed on two workers, SIGKILLed after one more task: the finished parts stay as they were
    second = _start(study, out, "--workers", "2", "--resume")
    _wait_for_parts(second, out, len(kept) + 1)
    second.kill()
    second.communicate(timeout=60)
    now = _parts(out)
    assert {name: now[name] for name in kept} == kept
    assert len(now) < N_TASKS
    # 4. resumed to the end: only the missing tasks run
    third = _start(study, out, "--workers", "2", "--resume")
    stdout, stderr = third.communicate(timeout=WAIT_S)
    assert third.returncode == 0, stderr
    assert f"{N_TASKS - len(now)} tasks run ({len(now)} already finished)" in stdout
    assert "designs by RMSE" in stdout  # the summary table, with --no-report too
    final = _parts(out)
    assert {name: final[name] for name in now} == now
    assert len(final) == N_TASKS
    # 5. the same rows as an uninterrupted run, timings aside
    whole = run_study(load_study(study), tmp_path / "whole", workers=1, progress=False, report=False)
    assert _rows(pq.read_table(out / "results.parquet")) == _rows(whole.results)
    assert (
        pq.read_table(out / "designs.parquet")
        .drop(["latency_ms_median"])
        .equals(whole.designs.drop(["latency_ms_median"]))
    )
