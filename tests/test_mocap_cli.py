"""`simulate --scenario cube` writes its motion capture; `softjig mocap` compares a dataset with it alone."""

from __future__ import annotations

import json

import pytest
from typer.testing import CliRunner

from softjig.cli import app
from softjig.evaluation.mocap import read_motive_csv

runner = CliRunner()


@pytest.fixture(scope="module")
def cube(tmp_path_factory):
    out = tmp_path_factory.mktemp("mocap") / "cube"
    res = runner.invoke(
        app,
        [
            "simulate",
            "--scenario",
            "cube",
            "--frames",
            "3",
            "--out",
            str(out),
            "--seed",
            "1",
            "--workers",
            "1",
            "--no-progress",
        ],
    )
    assert res.exit_code == 0, res.output
    return out


def test_simulate_cube_writes_a_motive_csv(cube):
    take = read_motive_csv(cube / "mocap.csv")
    assert {"SoftJig", "Cube"} <= set(take.bodies)
    assert len(take.frame) == 4  # the reference frame (no cube pose: untracked) and 3 loaded frames


def test_mocap_cli_compares_the_default_method(cube):
    res = runner.invoke(app, ["mocap", str(cube), "--json", "--no-progress", "--workers", "1"])
    assert res.exit_code == 0, res.output
    data = json.loads(res.stdout)
    assert data["method"] == "refractive" and data["n_frames"] == 3 and data["calibrated"] is None
    assert 0 < data["uncalibrated"]["rmse_deg"] < 1.5  # refraction modelled: no calibration needed


def test_mocap_cli_with_the_paper_method_and_its_calibration(cube, tmp_path):
    cal = tmp_path / "cal.json"
    cal.write_text(json.dumps({"offset_x_deg": 0.0, "offset_y_deg": 0.0, "scale": 1.6, "method": "paper"}))
    args = ["mocap", str(cube), "--csv", str(cube / "mocap.csv"), "--no-progress", "--workers", "1"]
    res = runner.invoke(app, [*args, "--method", "paper", "--calibration", str(cal), "--json"])
    assert res.exit_code == 0, res.output
    data = json.loads(res.stdout)
    # The paper's pinhole model reads the tilts low; S = 1.6 brings them closer.
    assert data["calibrated"]["rmse_deg"] < data["uncalibrated"]["rmse_deg"]
    table = runner.invoke(app, [*args, "--method", "paper", "--calibration", str(cal)])
    assert table.exit_code == 0 and "calibrated" in table.stdout and "RMSE" in table.stdout
    # A calibration of another method is refused before any estimation.
    res = runner.invoke(app, [*args, "--calibration", str(cal)])
    assert res.exit_code == 2 and "paper" in res.output


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--jig-body", "Robot"], "Robot"),
        (["--csv", "missing.csv"], "missing.csv"),
        (["--method", "svd"], "--method"),
    ],
)
def test_mocap_cli_bad_input_exits_2(cube, extra, message):
    res = runner.invoke(app, ["mocap", str(cube), "--no-progress", "--workers", "1", *extra])
    assert res.exit_code == 2, res.output
    assert message in res.output
