"""`softjig demo` end to end on a tiny sweep: simulate, estimate, calibrate, evaluate, figures, report."""

from __future__ import annotations

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from softjig.calibration.tilt import load_tilt_calibration
from softjig.cli import app
from softjig.evaluation import experiment
from softjig.evaluation.experiment import ExperimentSettings

runner = CliRunner()


def _tiny(out, **kwargs):
    """One diameter, one tilt, theta every 60 deg (3 frames to calibrate, 3 held out), 3 cube frames."""
    params = {
        "diameters_mm": (50.0,),
        "alphas_deg": (10.0,),
        "theta_step_deg": 60.0,
        "cube_frames": 3,
        "workers": 2,
        "progress": False,
        "quick": True,
    }
    params.update(kwargs)
    return ExperimentSettings(out_dir=out, seed=3, **params)


@pytest.fixture(scope="module")
def demo_run(tmp_path_factory):
    """The CLI with the quick settings swapped for the tiny ones (the real --quick takes ~25 s)."""
    out = tmp_path_factory.mktemp("demo") / "out"
    patch = pytest.MonkeyPatch()
    patch.setattr(experiment, "quick_settings", lambda out_dir, seed=0, **kw: _tiny(out_dir, **kw))
    try:
        result = runner.invoke(app, ["demo", "--quick", "--out", str(out), "--seed", "3", "--no-progress"])
    finally:
        patch.undo()
    return out, result


def test_demo_writes_the_report_and_prints_the_grid(demo_run):
    out, result = demo_run
    assert result.exit_code == 0, result.output
    assert "RMSE (deg), calibrated" in result.stdout and "uncalibrated" in result.stdout
    assert "held out" in result.stdout
    for name in (
        "report.md",
        "summary.json",
        "calibration.json",
        "calibration-per-diameter.json",
        "figures/tilt_before.png",
        "figures/tilt_after.png",
        "figures/rmse_grid.png",
        "figures/cube_normals.png",
        "figures/stereo_pair.png",
        "data/cube/mocap.csv",
        "data/sweep/estimates.jsonl",
    ):
        assert (out / name).is_file(), name
    report = (out / "report.md").read_text()
    assert "held out" in report and "![RMSE grid](figures/rmse_grid.png)" in report


def test_demo_calibration_does_real_work(demo_run):
    out, _ = demo_run
    cal = load_tilt_calibration(out / "calibration.json")  # readable by `softjig estimate --calibration`
    assert cal.scale > 1.2  # refraction compresses depth: the uncalibrated tilts read low
    summary = json.loads((out / "summary.json").read_text())
    ev = summary["evaluation"]
    assert ev["selection"] == "odd" and summary["calibration"]["selection"] == "even"
    assert ev["n_frames"] + ev["n_failed"] == 3
    cal_rmse = np.array(ev["calibrated"]["rmse_deg"], float)
    raw_rmse = np.array(ev["uncalibrated"]["rmse_deg"], float)
    assert cal_rmse.shape == (1, 1) and cal_rmse[0, 0] < raw_rmse[0, 0]
    assert summary["cube"]["calibrated"]["n"] >= 1
    data = json.loads((out / "calibration.json").read_text())
    assert data["source"]["dataset"].endswith("sweep") and data["source"]["method"] == "paper"


def test_no_holdout_uses_every_frame(tmp_path):
    result = experiment.run_experiment(_tiny(tmp_path / "all", split="none", cube_frames=0))
    assert result.calibration.selection == "all" and result.evaluation.selection == "all"
    assert result.cube is None and "same frames" in (tmp_path / "all" / "report.md").read_text()
