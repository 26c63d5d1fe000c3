"""The command line: simulate, config, --version and the shared error handling (exit codes 2 and 3)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import typer
from typer.testing import CliRunner

from softjig import __version__
from softjig.cli import app, handle_errors
from softjig.config import default_jig, load_jig
from softjig.errors import ConfigError, EstimationError, InputError
from softjig.io.dataset import Dataset

runner = CliRunner()
SMALL = [
    "simulate",
    "--scenario",
    "paper-sweep",
    "--diameters",
    "50",
    "--alphas",
    "10",
    "--theta-step",
    "90",
    "--no-progress",
    "--workers",
    "1",
]


def _stderr(result) -> str:
    return result.stderr if hasattr(result, "stderr") else result.output


def test_version():
    result = runner.invoke(app, ["--version"])
    assert result.exit_code == 0
    assert result.stdout.strip() == f"softjig {__version__}"


def test_simulate_small_sweep(tmp_path):
    out = tmp_path / "sweep"
    result = runner.invoke(app, [*SMALL, "--out", str(out), "--seed", "1"])
    assert result.exit_code == 0, result.output
    assert "wrote 5 frames" in result.stdout
    ds = Dataset.open(out)
    assert len(ds) == 5 and ds[0].reference
    assert [f.theta_deg for f in ds.frames[1:]] == pytest.approx([0, 90, 180, 270])


def test_simulate_single_and_cube(tmp_path):
    result = runner.invoke(
        app,
        [
            "simulate",
            "--scenario",
            "single",
            "--part-diameter",
            "40",
            "--alpha",
            "15",
            "--theta",
            "30",
            "--out",
            str(tmp_path / "one"),
            "--no-progress",
            "--workers",
            "1",
        ],
    )
    assert result.exit_code == 0, result.output
    (frame,) = Dataset.open(tmp_path / "one")
    assert frame.part.diameter_mm == 40 and frame.alpha_deg == pytest.approx(15)
    result = runner.invoke(
        app,
        [
            "simulate",
            "--scenario",
            "cube",
            "--frames",
            "2",
            "--out",
            str(tmp_path / "cube"),
            "--no-progress",
            "--workers",
            "1",
        ],
    )
    assert result.exit_code == 0, result.output
    ds = Dataset.open(tmp_path / "cube")
    assert len(ds) == 3 and ds[1].part.kind == "box"


def test_simulate_uses_the_given_config(tmp_path):
    jig = default_jig()
    rig = tmp_path / "rig.toml"
    assert runner.invoke(app, ["config", "--out", str(rig)]).exit_code == 0
    rig.write_text(rig.read_text().replace('name = "paper-jig"', 'name = "my-jig"'))
    result = runner.invoke(app, [*SMALL, "--config", str(rig), "--out", str(tmp_path / "ds")])
    assert result.exit_code == 0, result.output
    assert Dataset.open(tmp_path / "ds").jig.name == "my-jig"
    assert load_jig(rig).cameras == jig.cameras


def test_config_writes_the_default_jig(tmp_path):
    out = tmp_path / "rig.toml"
    result = runner.invoke(app, ["config", "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert load_jig(out) == default_jig()
    again = runner.invoke(app, ["config", "--out", str(out)])
    assert again.exit_code == 2 and "--overwrite" in _stderr(again)
    assert runner.invoke(app, ["config", "--out", str(out), "--overwrite"]).exit_code == 0


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--diameters", "a,b"], "--diameters expects comma-separated numbers"),
        (["--alphas", "95"], "alpha must be in [0, 90)"),
        (["--theta-step", "0"], "theta step"),
        (["--part-diameter", "40"], "--part-diameter do(es) not apply"),
        (["--config", "/nonexistent/rig.toml"], "does not exist"),
    ],
)
def test_simulate_bad_input_exits_2(tmp_path, args, message):
    result = runner.invoke(app, [*SMALL, "--out", str(tmp_path / "x"), *args])
    assert result.exit_code == 2, result.output
    err = _stderr(result)
    assert err.startswith("error: ") and message in err
    assert "Traceback" not in result.output


def test_single_needs_a_part_diameter(tmp_path):
    result = runner.invoke(app, ["simulate", "--scenario", "single", "--out", str(tmp_path / "x")])
    assert result.exit_code == 2 and "needs --part-diameter" in _stderr(result)


def test_bad_config_names_the_field(tmp_path):
    rig = tmp_path / "rig.toml"
    runner.invoke(app, ["config", "--out", str(rig)])
    rig.write_text(rig.read_text().replace("diameter_mm = 3.0", "diameter_mm = 9.0"))
    result = runner.invoke(app, [*SMALL, "--config", str(rig), "--out", str(tmp_path / "x")])
    assert result.exit_code == 2
    assert f"{rig}: markers.diameter_mm" in _stderr(result)
    assert not (tmp_path / "x").exists()


def test_existing_dataset_needs_overwrite(tmp_path):
    args = [*SMALL, "--out", str(tmp_path / "ds")]
    assert runner.invoke(app, args).exit_code == 0
    result = runner.invoke(app, args)
    assert result.exit_code == 2 and "already holds a dataset" in _stderr(result)
    assert runner.invoke(app, [*args, "--overwrite"]).exit_code == 0


def test_error_handler_exit_codes():
    demo = typer.Typer()

    @demo.command()
    @handle_errors
    def fail(kind: str) -> None:
        raise {
            "input": InputError("bad image x.png"),
            "config": ConfigError("markers.pitch_mm: bad"),
            "estimate": EstimationError("too few markers"),
        }[kind]

    for kind, code, text in [
        ("input", 2, "bad image x.png"),
        ("config", 2, "markers.pitch_mm: bad"),
        ("estimate", 3, "too few markers"),
    ]:
        result = runner.invoke(demo, [kind])
        assert result.exit_code == code
        assert _stderr(result).strip() == f"error: {text}"
        assert result.exception is None or isinstance(result.exception, SystemExit)


def test_installed_console_script(tmp_path):
    script = Path(sys.executable).parent / "softjig"
    assert script.exists(), "install the package (pip install -e .) to get the softjig script"
    out = tmp_path / "tmp"
    proc = subprocess.run(
        [
            str(script),
            "simulate",
            "--scenario",
            "paper-sweep",
            "--diameters",
            "50",
            "--alphas",
            "10",
            "--theta-step",
            "90",
            "--out",
            str(out),
            "--seed",
            "1",
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 0, proc.stderr
    ds = Dataset.open(out)
    assert len(ds) == 5
    # the same seed through the library with 1 worker gives the same images (the script used all CPUs)
    result = runner.invoke(app, [*SMALL, "--out", str(tmp_path / "again"), "--seed", "1"])
    assert result.exit_code == 0, result.output
    again = Dataset.open(tmp_path / "again")
    for a, b in zip(ds, again, strict=True):
        np.testing.assert_array_equal(a.load_left(), b.load_left())
        np.testing.assert_array_equal(a.load_right(), b.load_right())
    bad = subprocess.run(
        [str(script), "simulate", "--config", str(tmp_path / "none.toml"), "--out", str(tmp_path / "y")],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert bad.returncode == 2 and "error:" in bad.stderr and "Traceback" not in bad.stderr


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--push-depth", "-1"], "positive"),
        (["--push-depth", "40"], "into the plate"),
        (["--scenario", "cube", "--frames", "0"], "at least one frame"),
    ],
)
def test_impossible_simulations_exit_2(tmp_path, args, message):
    base = ["simulate", "--out", str(tmp_path / "x"), "--no-progress", "--workers", "1"]
    if "--scenario" not in args:
        base += ["--scenario", "single", "--part-diameter", "50", "--alpha", "10"]
    result = runner.invoke(app, [*base, *args])
    assert result.exit_code == 2, result.output
    assert message in _stderr(result)
