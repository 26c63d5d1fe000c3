"""A calibration applies to the estimation method it was fitted to (issue 14): old files without a
top-level ``method`` and mismatched methods are refused by `softjig estimate` (exit 2)."""

from __future__ import annotations

import json

import pytest
from typer.testing import CliRunner

from softjig.cli import app

runner = CliRunner()


@pytest.fixture(scope="module")
def pair(tmp_path_factory):
    root = tmp_path_factory.mktemp("one") / "one"
    result = runner.invoke(
        app,
        [
            *("simulate", "--scenario", "single", "--part-diameter", "50", "--alpha", "10", "--theta", "60"),
            *("--out", str(root), "--no-progress"),
        ],
    )
    assert result.exit_code == 0, result.output
    return root


def _estimate(pair, calibration, *extra):
    args = ["estimate", str(pair / "left/000000.png"), str(pair / "right/000000.png")]
    args += ["--config", str(pair / "rig.toml"), "--calibration", str(calibration), "--json", *extra]
    return runner.invoke(app, args)


def _calibration(path, **fields):
    data = {"format": "softjig-tilt-calibration", "version": 1, "offset_x_deg": -0.2, "offset_y_deg": 0.1}
    data.update(scale=1.8, source={"method": "paper"}, **fields)
    path.write_text(json.dumps(data))
    return path


def test_the_demos_old_calibration_is_refused_with_how_to_redo_it(pair, tmp_path):
    """The demo wrote the paper method's calibration without a top-level method: `softjig estimate` with
    the default method applied it (tilts nearly doubled, exit 0)."""
    result = _estimate(pair, _calibration(tmp_path / "old.json"))
    assert result.exit_code == 2, result.output
    assert "softjig calibrate DATASET --method" in result.output
    assert "tilt_x_deg" not in result.stdout


def test_a_method_mismatch_is_refused(pair, tmp_path):
    cal = _calibration(tmp_path / "paper.json", method="paper")
    result = _estimate(pair, cal)  # the default method: refractive
    assert result.exit_code == 2, result.output
    assert "--method paper" in result.output
    matched = _estimate(pair, cal, "--method", "paper", "--part-diameter", "50")
    assert matched.exit_code == 0, matched.output
    assert json.loads(matched.stdout)["calibrated"] is True
