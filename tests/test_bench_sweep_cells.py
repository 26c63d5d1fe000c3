"""bench_sweep_cells.py refuses results that share no frame with the dataset (its figures were NaN)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

SCRIPT = Path(__file__).resolve().parents[1] / "benchmarks" / "bench_sweep_cells.py"


def _run(tmp_path: Path, old_index: int) -> subprocess.CompletedProcess:
    frame = {"index": 1, "alpha_deg": 10.0, "part": {"diameter_mm": 50.0}, "truth": {"normal": [0, 0, 1]}}
    (tmp_path / "frames.jsonl").write_text(json.dumps({"index": 0}) + "\n" + json.dumps(frame) + "\n")
    for name, index in (("old", old_index), ("new", 1)):
        (tmp_path / f"{name}.jsonl").write_text(
            json.dumps({"index": index, "normal": [0.0, 0.6, 0.8]}) + "\n"
        )
    argv = [
        sys.executable,
        str(SCRIPT),
        str(tmp_path),
        str(tmp_path / "old.jsonl"),
        str(tmp_path / "new.jsonl"),
    ]
    return subprocess.run(argv, capture_output=True, text=True, timeout=120)


def test_results_of_another_dataset_are_refused(tmp_path):
    done = _run(tmp_path, old_index=7)
    assert done.returncode == 2
    assert "no loaded frame" in done.stderr and "estimated in both" in done.stderr


def test_a_frame_estimated_by_both_is_compared(tmp_path):
    done = _run(tmp_path, old_index=1)
    assert done.returncode == 0, done.stderr
    assert "| 50 | 10 | 1 | 36.870 | 36.870 | 1.000 |" in done.stdout
