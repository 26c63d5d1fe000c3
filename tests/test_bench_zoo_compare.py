"""bench_zoo_compare.py: two trees' bench_zoo rows compared way by way and row by row (no timing)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

SCRIPT = Path(__file__).resolve().parents[1] / "benchmarks" / "bench_zoo_compare.py"


def _row(frame: int, way: str, error: float | None, quality: str | None, size: float = 50.0) -> dict:
    return {
        "design": 3, "family": "hex-hd", "frame": frame, "way": way, "part": "box", "part_size_mm": size,
        "alpha_deg": 10.0, "offset_mm": 5.0, "error_deg": error, "sigma_deg": None if error is None else 0.5,
        "quality": quality, "n_contact": 40, "n_points": None if error is None else 30, "time_ms": 5.0,
        "failure": None if error is not None else "no contact", "silent": False, "covered": False,
    }  # fmt: skip


def _run(tmp_path: Path, old: list[dict], new: list[dict], *options: str) -> subprocess.CompletedProcess:
    for name, rows in (("old", old), ("new", new)):
        (tmp_path / f"{name}.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    argv = [sys.executable, str(SCRIPT), str(tmp_path / "old.jsonl"), str(tmp_path / "new.jsonl"), *options]
    return subprocess.run(argv, capture_output=True, text=True, timeout=300)


def test_the_totals_and_the_rows_a_change_moved(tmp_path):
    old = [
        _row(1, "size+reference", 0.3, "ok"),
        _row(2, "size+reference", 30.0, "suspect"),
        _row(3, "size+reference", 4.0, "ok"),  # silent: 4 deg, 8 sigmas, "ok"
        _row(4, "size+reference", None, None),
    ]
    new = [
        _row(1, "size+reference", 0.31, "ok"),  # moved by less than the threshold: not listed
        _row(2, "size+reference", 0.2, "suspect"),
        _row(3, "size+reference", 4.0, "suspect"),
        _row(4, "size+reference", 0.4, "ok"),
    ]
    done = _run(tmp_path, old, new)
    assert done.returncode == 0, done.stderr
    out = done.stdout
    assert "4 rows in both" in out
    # sqrt((0.3^2 + 30^2 + 4^2) / 3) -> sqrt((0.31^2 + 0.2^2 + 4^2 + 0.4^2) / 4)
    assert "RMSE 17.47 -> 2.02" in out
    assert "silent 1 -> 0" in out and "failed 1 -> 0" in out and "suspect 1 -> 2" in out
    assert "3 rows moved" in out
    assert "30.00 suspect -> 0.20 suspect" in out and "4.00 -> 4.00 suspect" in out
    assert "failed (no contact) -> 0.40" in out and "d3   f1 " not in out


def test_rows_of_another_zoo_are_refused(tmp_path):
    done = _run(tmp_path, [_row(1, "size+reference", 0.3, "ok")], [_row(2, "size+reference", 0.3, "ok")])
    assert done.returncode != 0
    assert "share no (design, frame, way)" in done.stderr


def test_two_zoos_in_one_file_are_refused(tmp_path):
    """The rows name no seed: two seeds' rows in one file would silently hide each other."""
    row = _row(1, "size+reference", 0.3, "ok")
    done = _run(tmp_path, [row], [row, {**row, "error_deg": 9.0}])
    assert done.returncode != 0 and "Traceback" not in done.stderr
    assert "new.jsonl:2 repeats design 3, frame 1, size+reference" in done.stderr


def test_a_file_that_is_not_text_is_refused(tmp_path):
    (tmp_path / "old.jsonl").write_bytes(bytes(range(128, 256)))
    (tmp_path / "new.jsonl").write_text(json.dumps(_row(1, "size+reference", 0.3, "ok")) + "\n")
    argv = [sys.executable, str(SCRIPT), str(tmp_path / "old.jsonl"), str(tmp_path / "new.jsonl")]
    done = subprocess.run(argv, capture_output=True, text=True, timeout=300)
    assert done.returncode != 0 and "Traceback" not in done.stderr
    assert "is not text" in done.stderr


def test_a_threshold_that_is_not_an_angle_is_refused(tmp_path):
    rows = [_row(1, "size+reference", 0.3, "ok")]
    for value in ("nan", "-1"):
        done = _run(tmp_path, rows, rows, "--threshold", value)
        assert done.returncode != 0 and "--threshold must be a finite angle" in done.stderr
