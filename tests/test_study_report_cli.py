"""A real small study end to end: `softjig study` prints the ranking, writes report.html, the figures and
the front design's rig, and `softjig simulate --config DIR/best/NNN.toml` renders that design."""

from __future__ import annotations

import shlex

import pytest
from typer.testing import CliRunner

from softjig.cli import app
from softjig.config import load_jig
from softjig.io.dataset import Dataset
from softjig.study.best import HEADER_MARK

TINY = """
[study]
name = "tiny"
[vary]
"markers.pitch_mm" = [7.0, 9.0]
[frames]
diameters_mm = [50]
alphas_deg = [10]
theta_step_deg = 360
[estimate]
methods = ["refractive"]
"""


def test_a_small_study_reports_and_its_best_rig_simulates(tmp_path):
    study, out = tmp_path / "tiny.toml", tmp_path / "out"
    study.write_text(TINY)
    runner = CliRunner()
    result = runner.invoke(app, ["study", str(study), "--out", str(out), "--workers", "1", "--no-progress"])
    assert result.exit_code == 0, result.output
    assert "designs by RMSE" in result.stdout and "pitch_mm" in result.stdout
    # it says where everything is
    assert f"report: {out / 'report.html'} (3 figures)" in result.stdout
    assert f"results: {out / 'results.parquet'}, designs: {out / 'designs.parquet'}" in result.stdout
    assert f"in {out / 'best'} (the Pareto front's designs" in result.stdout
    assert f"softjig simulate --config {out / 'best'}" in result.stdout
    page = (out / "report.html").read_text()
    assert "softjig study: tiny" in page
    assert page.count("data:image/png;base64,") == 3  # accuracy, cells, the front
    assert sorted(p.name for p in (out / "figures").iterdir()) == [
        "accuracy.png",
        "best-cells.png",
        "pareto-marker_count.png",
    ]
    rigs = sorted((out / "best").iterdir())
    assert rigs and all(p.read_text().startswith(HEADER_MARK) for p in rigs)
    pitches = {load_jig(p).markers.pitch_mm for p in rigs}
    assert pitches <= {7.0, 9.0}
    # the rig says how to render its study frames again: run that command (from the study's folder)
    (command,) = [line[4:] for line in rigs[0].read_text().splitlines() if line.startswith("#   softjig ")]
    args = [*shlex.split(command)[1:], "--out", str(tmp_path / "ds"), "--no-progress", "--workers", "1"]
    args[args.index("--config") + 1] = str(out / args[args.index("--config") + 1])
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    ds = Dataset.open(tmp_path / "ds")
    assert ds.jig == load_jig(rigs[0]) and len(ds) == 2 and ds[0].reference
    assert (ds[1].part.diameter_mm, ds[1].alpha_deg) == (50.0, pytest.approx(10.0))
