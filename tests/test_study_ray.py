"""`softjig study --ray local`: a local Ray cluster of two workers runs the same study as the local pool, with
the same rows (issue 17, deliverable 2: no change to the study); SIGTERM stops it cleanly (exit 143, not
Ray's abort) and ``--resume`` finishes it."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

from softjig.study.execute import run_study
from softjig.study.spec import load_study

_CLI = "import sys; sys.argv[0] = 'softjig'; from softjig.cli import main; main()"
STUDY = """
[study]
name = "ray"
seeds = [2]
[vary]
"cameras.baseline_mm" = [26.0, 30.0, 34.0, 38.0]
[frames]
diameters_mm = [60]
alphas_deg = [8]
theta_step_deg = 180
[estimate]
methods = ["refractive", "paper"]
"""
WAIT_S = 240.0


def _parts(out) -> list:
    return sorted((out / "parts").glob("*.parquet")) if (out / "parts").is_dir() else []


def test_a_local_ray_cluster_of_two_workers_stops_on_sigterm_and_its_rows_are_the_local_pools(tmp_path):
    path = tmp_path / "study.toml"
    path.write_text(STUDY, encoding="utf-8")
    out = tmp_path / "ray"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    command = [sys.executable, "-c", _CLI, "study", str(path), "--out", str(out), "--ray", "local"]
    process = subprocess.Popen(
        [*command, "--workers", "2", "--no-progress", "--no-report"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
    )
    deadline = time.monotonic() + WAIT_S
    while not _parts(out):
        assert process.poll() is None, process.communicate()
        assert time.monotonic() < deadline
        time.sleep(0.1)
    process.send_signal(signal.SIGTERM)
    _, stderr = process.communicate(timeout=60)
    assert process.returncode == 143, stderr  # Ray's own handler would abort (134) with a stack dump
    assert "terminated by SIGTERM" in stderr and "Traceback" not in stderr
    finished = len(_parts(out))
    assert 1 <= finished < 4
    # the rows Ray finished, completed on the local pool, are the rows of a local run
    study = load_study(path)
    resumed = run_study(study, out, workers=2, progress=False, report=False, resume=True)
    assert (resumed.skipped, resumed.ran, len(resumed.results)) == (finished, 4 - finished, 4 * 2 * 2)
    local = run_study(study, tmp_path / "local", workers=1, progress=False, report=False)
    assert resumed.results.drop(["estimate_ms"]).equals(local.results.drop(["estimate_ms"]))
    assert set(resumed.results.column("quality").to_pylist()) <= {"ok", "suspect"}
