"""Benchmarks (render, study, bag, estimate) refuse counts they would answer with NaN or a traceback."""

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


@pytest.mark.parametrize(
    ("script", "name"),
    [
        # --repeats 0 (or --rounds 0 with --src) ended in a traceback on the empty medians
        ("bench_render.py", "--repeats"),
        ("bench_render.py", "--rounds"),
        # the side-by-side medians and ratios of no round or call were NaN, exit 0
        ("bench_estimate.py", "--rounds"),
        ("bench_estimate.py", "--calls"),
        ("bench_estimate.py", "--repeats"),
        # --frames-per-alpha 0 divided by zero; --rounds 0 was taken for 1
        ("bench_bag.py", "--frames-per-alpha"),
        ("bench_bag.py", "--rounds"),
        # each ended in a traceback (an empty median, a division by --empty) after Ray had started
        ("bench_study.py", "--tasks"),
        ("bench_study.py", "--frames-per-task"),
        ("bench_study.py", "--repeats"),
        ("bench_study.py", "--empty"),
    ],
)
def test_benchmarks_refuse_no_work(script, name):
    done = subprocess.run(
        [sys.executable, str(SCRIPT.with_name(script)), name, "0"],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 2
    assert f"{name} must be at least 1" in done.stderr
