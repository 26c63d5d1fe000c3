"""The render and study benchmarks refuse counts they would answer with NaN figures or a traceback."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parents[1] / "benchmarks" / "bench_render_equivalence.py"


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--frames", "0"], "--frames must be between 1 and 36"),
        (["--frames", "37"], "--frames must be between 1 and 36"),  # was cut to the grid's 36 silently
        (["--seeds", "0"], "--seeds must be at least 1"),
        (["--frames", "1", "--seeds", "1"], "at least 2"),  # one frame: no standard error (NaN)
    ],
)
def test_frame_counts_without_figures_are_refused(args, message):
    done = subprocess.run([sys.executable, str(SCRIPT), *args], capture_output=True, text=True, timeout=120)
    assert done.returncode == 2
    assert message in done.stderr


@pytest.mark.parametrize("name", ["--repeats", "--rounds"])
def test_bench_render_refuses_no_pairs(name):
    # --repeats 0 (or --rounds 0 with --src) ended in a traceback on the empty medians
    bench_render = SCRIPT.with_name("bench_render.py")
    done = subprocess.run(
        [sys.executable, str(bench_render), name, "0"], capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 2
    assert f"{name} must be at least 1" in done.stderr


@pytest.mark.parametrize("name", ["--tasks", "--frames-per-task", "--repeats", "--empty"])
def test_bench_study_refuses_no_work(name):
    # each ended in a traceback (an empty median, a division by --empty) after Ray had started
    bench_study = SCRIPT.with_name("bench_study.py")
    done = subprocess.run(
        [sys.executable, str(bench_study), name, "0"], capture_output=True, text=True, timeout=300
    )
    assert done.returncode == 2
    assert f"{name} must be at least 1" in done.stderr
