"""`softjig estimate` end to end: a pair (table, --json, --overlay), a dataset (JSONL, CSV), exit codes."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from softjig.cli import app
from softjig.config import default_jig, dumps_jig
from softjig.errors import InputError
from softjig.io.batch import BatchSettings
from softjig.io.dataset import Dataset

runner = CliRunner()


@pytest.fixture(scope="module")
def sweep(small_dataset):
    """The small sweep of DESIGN.md's contract: a reference frame and 4 loaded frames (D = 50 mm)."""
    return Dataset.open(small_dataset)


def _pair_args(sweep, k=1):
    frame = sweep[k]
    return [str(frame.left_path), str(frame.right_path), "--config", str(sweep.root / "rig.toml")]


def test_pair_json_has_the_contract_keys(sweep):
    result = runner.invoke(app, ["estimate", *_pair_args(sweep), "--part-diameter", "50", "--json"])
    assert result.exit_code == 0, result.output
    data = json.loads(result.stdout)
    for key in (
        "normal",
        "tilt_x_deg",
        "tilt_y_deg",
        "push_depth_mm",
        "n_points",
        "rms_residual_mm",
        "frame_source",
        "warnings",
    ):
        assert key in data
    assert data["frame_source"] == "fiducials" and data["n_points"] > 20
    assert data["normal"][2] > 0.9


def test_pair_table_and_overlay(sweep, tmp_path):
    overlay = tmp_path / "overlay.png"
    result = runner.invoke(
        app, ["estimate", *_pair_args(sweep), "--part-diameter", "50", "--overlay", str(overlay)]
    )
    assert result.exit_code == 0, result.output
    assert "tilt Ax / Ay" in result.stdout and "fiducials" in result.stdout
    picture = cv2.imread(str(overlay))
    assert picture.shape == (720, 2560, 3)
    assert (picture[..., 0] != picture[..., 1]).any()  # something was drawn in colour


def test_pair_calibration_is_applied(sweep, tmp_path):
    cal = tmp_path / "cal.json"
    cal.write_text(json.dumps({"method": "refractive", "offset_x_deg": 0, "offset_y_deg": 0, "scale": 2.0}))
    plain = json.loads(
        runner.invoke(app, ["estimate", *_pair_args(sweep), "--part-diameter", "50", "--json"]).stdout
    )
    scaled = json.loads(
        runner.invoke(
            app,
            ["estimate", *_pair_args(sweep), "--part-diameter", "50", "--json", "--calibration", str(cal)],
        ).stdout
    )
    assert scaled["calibrated"] and scaled["tilt_x_deg"] == pytest.approx(2 * plain["tilt_x_deg"])


def test_dataset_jsonl_and_csv(sweep, tmp_path):
    out = tmp_path / "results.jsonl"
    result = runner.invoke(
        app, ["estimate", str(sweep.root), "--out", str(out), "--workers", "2", "--no-progress"]
    )
    assert result.exit_code == 0, result.output
    rows = [json.loads(line) for line in out.read_text().splitlines()]
    assert [row["index"] for row in rows] == [frame.index for frame in sweep]
    assert rows[0] == {"index": 0, "reference": True}  # the unloaded reference frame
    assert all("normal" in row for row in rows[1:])
    assert "estimated 4 of 4 loaded frames" in result.output
    csv_out = tmp_path / "results.csv"
    result = runner.invoke(
        app,
        [
            "estimate",
            str(sweep.root),
            "--out",
            str(csv_out),
            "--workers",
            "1",
            "--part-diameter",
            "50",
            "--no-progress",
        ],
    )
    assert result.exit_code == 0, result.output
    lines = csv_out.read_text().splitlines()
    assert lines[0].startswith("index,normal_x") and len(lines) == 1 + len(sweep)


def test_workers_give_identical_results(sweep, tmp_path):
    outs = []
    for workers in ("1", "2"):
        out = tmp_path / f"r{workers}.jsonl"
        result = runner.invoke(
            app, ["estimate", str(sweep.root), "--out", str(out), "--workers", workers, "--no-progress"]
        )
        assert result.exit_code == 0, result.output
        outs.append(out.read_text())
    assert len(outs[0].splitlines()) == len(sweep)
    assert outs[0] == outs[1]


@pytest.mark.parametrize(
    ("extra", "code", "message"),
    [
        (["--part-diameter", "8"], 3, "sensing.min_points"),
        (["--method", "paper"], 2, "--part-diameter"),
        (["--part-diameter", "50", "--method", "magic"], 2, "magic"),
        (["--part-diameter", "50", "--calibration", "/nonexistent.json"], 2, "does not exist"),
        (["--part-diameter", "50", "--workers", "2"], 2, "DATASET"),
    ],
)
def test_pair_errors_and_exit_codes(sweep, extra, code, message):
    result = runner.invoke(app, ["estimate", *_pair_args(sweep), *extra])
    assert result.exit_code == code
    assert message in result.output
    assert "Traceback" not in result.output


def test_bad_files(sweep, tmp_path):
    left = sweep[1].left_path
    result = runner.invoke(
        app,
        [
            "estimate",
            str(left),
            str(tmp_path / "none.png"),
            "--config",
            str(sweep.root / "rig.toml"),
            "--part-diameter",
            "50",
        ],
    )
    assert result.exit_code == 2 and "does not exist" in result.output
    corrupt = tmp_path / "corrupt.png"
    corrupt.write_bytes(b"\x89PNG not really")
    result = runner.invoke(
        app,
        [
            "estimate",
            str(left),
            str(corrupt),
            "--config",
            str(sweep.root / "rig.toml"),
            "--part-diameter",
            "50",
        ],
    )
    assert result.exit_code == 2
    small = tmp_path / "small.png"
    cv2.imwrite(str(small), np.zeros((100, 100), np.uint8))
    result = runner.invoke(
        app,
        [
            "estimate",
            str(left),
            str(small),
            "--config",
            str(sweep.root / "rig.toml"),
            "--part-diameter",
            "50",
        ],
    )
    assert result.exit_code == 2 and "right one is 100x100" in result.output
    result = runner.invoke(app, ["estimate", str(left), str(left), "--part-diameter", "50"])
    assert result.exit_code == 2 and "--config" in result.output


def test_fiducials_required_but_hidden_exit_3(sweep, tmp_path):
    strict = tmp_path / "strict.toml"
    strict.write_text(dumps_jig(sweep.jig).replace('extrinsics = "auto"', 'extrinsics = "fiducials"'))
    left = cv2.imread(str(sweep[1].left_path), cv2.IMREAD_UNCHANGED)
    left[:, :] = np.where(np.arange(1280) < 420, 25, left).astype(left.dtype)  # hide two fiducials
    left[:, 1000:] = 25
    hidden = tmp_path / "hidden.png"
    cv2.imwrite(str(hidden), left)
    result = runner.invoke(
        app,
        ["estimate", str(hidden), str(sweep[1].right_path), "--config", str(strict), "--part-diameter", "50"],
    )
    assert result.exit_code == 3 and "fiducials" in result.output


def test_pair_tilt_agrees_with_the_truth(sweep):
    """Uncalibrated, refraction compresses the tilt, but its signs and rough size follow the truth."""
    from softjig.geometry import normal_from_tilt, tilt_angles

    for k in (1, 2, 3, 4):
        frame = sweep[k]
        data = json.loads(
            runner.invoke(app, ["estimate", *_pair_args(sweep, k), "--part-diameter", "50", "--json"]).stdout
        )
        ax, ay = np.degrees(
            tilt_angles(normal_from_tilt(np.radians(frame.alpha_deg), np.radians(frame.theta_deg)))
        )
        for measured, true in ((data["tilt_x_deg"], ax), (data["tilt_y_deg"], ay)):
            if abs(true) > 5:
                assert np.sign(measured) == np.sign(true)
                assert 0.3 * abs(true) < abs(measured) < 1.2 * abs(true)
            else:
                assert abs(measured) < 2.5


def test_outputs_that_are_folders_exit_2(sweep, tmp_path):
    result = runner.invoke(
        app, ["estimate", *_pair_args(sweep), "--part-diameter", "50", "--overlay", str(tmp_path)]
    )
    assert result.exit_code == 2 and "is a folder" in result.output
    result = runner.invoke(
        app, ["estimate", str(sweep.root), "--out", str(tmp_path), "--no-progress", "--workers", "1"]
    )
    assert result.exit_code == 2 and "is a folder" in result.output


def test_dataset_rejects_pair_only_options(sweep):
    result = runner.invoke(app, ["estimate", str(sweep.root), "--json"])
    assert result.exit_code == 2 and "stereo pair" in result.output


def test_a_calibration_applies_to_its_own_method_only(sweep, tmp_path):
    """`softjig calibrate` records the method it calibrated; another method refuses it (exit 2)."""
    out = tmp_path / "cal.json"
    result = runner.invoke(
        app,
        [
            "calibrate",
            str(sweep.root),
            "--out",
            str(out),
            "--method",
            "paper",
            "--workers",
            "1",
            "--no-progress",
        ],
    )
    assert result.exit_code == 0, result.output
    assert json.loads(out.read_text())["method"] == "paper"
    refused = runner.invoke(app, ["estimate", *_pair_args(sweep), "--calibration", str(out)])
    assert refused.exit_code == 2 and "does not apply" in refused.output
    accepted = runner.invoke(
        app,
        [
            "estimate",
            *_pair_args(sweep),
            "--calibration",
            str(out),
            "--method",
            "paper",
            "--part-diameter",
            "50",
            "--json",
        ],
    )
    assert accepted.exit_code == 0 and json.loads(accepted.stdout)["calibrated"]


@pytest.mark.parametrize("method", [[], ["--method", "paper"]])
def test_swapped_images_are_named(sweep, method):
    """Issue 14: RIGHT LEFT gave exit 3 "no contact" (default method) or exit 0 with a 22 mm push (paper)."""
    left, right, *rest = _pair_args(sweep)
    result = runner.invoke(app, ["estimate", right, left, *rest, "--part-diameter", "50", *method])
    assert result.exit_code == 2, result.output
    assert "swapped" in result.output and "Traceback" not in result.output


@pytest.mark.parametrize("diameter", ["1e9", "190", "inf"])
def test_part_wider_than_the_membrane_is_refused(sweep, diameter):
    """Issue 14: --part-diameter 1e9 gave exit 0 and a wrong tilt."""
    result = runner.invoke(app, ["estimate", *_pair_args(sweep), "--part-diameter", diameter])
    assert result.exit_code == 2, result.output
    assert "part diameter" in result.output or "--part-diameter" in result.output  # inf: while parsing


@pytest.mark.parametrize(
    ("diameter", "message"), [("0", "positive"), ("-5", "positive"), ("1e6", "membrane")]
)
def test_a_dataset_refuses_a_bad_part_diameter_before_any_frame(sweep, tmp_path, diameter, message):
    """A dataset given --part-diameter 0, -5 or 1e6 exited 3 after writing every frame's error over the
    results file; it is one bad option, refused once (exit 2) and nothing written."""
    out = tmp_path / "results.jsonl"
    out.write_text("kept\n")
    args = ["estimate", str(sweep.root), "--out", str(out), "--workers", "1", "--part-diameter", diameter]
    result = runner.invoke(app, [*args, "--no-progress"])
    assert result.exit_code == 2, result.output
    assert "part diameter" in result.output and message in result.output
    assert "Traceback" not in result.output
    assert out.read_text() == "kept\n"


@pytest.mark.parametrize("diameter", [True, "50", float("nan")])
def test_batch_settings_refuse_a_part_diameter_that_is_not_a_number(diameter):
    """Given in Python (no option parser in between), ``True`` was taken for 1 mm and ``"50"`` raised a
    TypeError from NumPy: both are refused with a message naming the part diameter."""
    with pytest.raises(InputError, match="part diameter must be a positive number"):
        BatchSettings(default_jig(), part_diameter_mm=diameter)


def test_12_bit_counts_in_a_16_bit_png(sweep, tmp_path):
    """Issue 14: a 12-bit camera's counts in a 16-bit PNG gave 0 markers and "noise (nan mm)", exit 3."""
    paths = []
    for name, source in (("left", sweep[1].left_path), ("right", sweep[1].right_path)):
        image = cv2.imread(str(source), cv2.IMREAD_UNCHANGED).astype(np.uint16) * 16  # 12-bit counts
        paths.append(str(tmp_path / f"{name}.png"))
        cv2.imwrite(paths[-1], image)
    plain = runner.invoke(app, ["estimate", *_pair_args(sweep), "--json"])
    result = runner.invoke(app, ["estimate", *paths, "--config", str(sweep.root / "rig.toml"), "--json"])
    assert result.exit_code == 0, result.output
    assert "nan" not in result.output.lower()
    packed, unpacked = json.loads(result.stdout), json.loads(plain.stdout)
    assert any("low 12 bits" in w for w in packed["warnings"])
    assert abs(packed["tilt_x_deg"] - unpacked["tilt_x_deg"]) < 0.3
    assert abs(packed["tilt_y_deg"] - unpacked["tilt_y_deg"]) < 0.3


def test_every_estimate_carries_quality_and_sigma(sweep, tmp_path):
    """Issue 13 item 6: the JSON object and every dataset row carry ``quality`` and ``tilt_sigma_deg``."""
    for method in ([], ["--method", "paper"]):
        result = runner.invoke(
            app, ["estimate", *_pair_args(sweep), "--part-diameter", "50", "--json", *method]
        )
        assert result.exit_code == 0, result.output
        data = json.loads(result.stdout)
        assert data["quality"] == "ok", data["warnings"]
        assert 0 < data["tilt_sigma_deg"] < 2
    for out in (tmp_path / "rows.jsonl", tmp_path / "rows.csv"):
        result = runner.invoke(app, ["estimate", str(sweep.root), "--out", str(out), "--workers", "1"])
        assert result.exit_code == 0, result.output
        text = out.read_text()
        assert "quality" in text and "tilt_sigma_deg" in text
    rows = [json.loads(line) for line in (tmp_path / "rows.jsonl").read_text().splitlines()][1:]
    assert all(row["quality"] in ("ok", "suspect") and row["tilt_sigma_deg"] > 0 for row in rows)


def test_no_part_size_ignores_the_frames_parts(sweep, tmp_path):
    """Issue 13 item 5: ``--no-part-size`` runs the size-free case on a dataset whose frames name a part."""
    sized, free = tmp_path / "sized.jsonl", tmp_path / "free.jsonl"
    for out, extra in ((sized, []), (free, ["--no-part-size"])):
        result = runner.invoke(
            app, ["estimate", str(sweep.root), "--out", str(out), "--workers", "1", *extra]
        )
        assert result.exit_code == 0, result.output
    sized_rows = [json.loads(line) for line in sized.read_text().splitlines()][1:]
    free_rows = [json.loads(line) for line in free.read_text().splitlines()][1:]
    assert all(row["part_diameter_mm"] == 50 for row in sized_rows)
    assert all(row["part_diameter_mm"] is None for row in free_rows)
    for extra in (["--part-diameter", "50"], ["--method", "paper"]):
        result = runner.invoke(app, ["estimate", str(sweep.root), "--no-part-size", *extra])
        assert result.exit_code == 2 and "--no-part-size" in result.output
    result = runner.invoke(app, ["estimate", *_pair_args(sweep), "--no-part-size"])
    assert result.exit_code == 2 and "--no-part-size" in result.output


def test_the_table_says_suspect_plainly(capsys):
    from softjig.cli.estimate import _print_estimate_table

    reason = "the two halves of the contact are tilted 6.0 deg apart"
    estimate = {
        "normal": [0.0, 0.0, 1.0], "tilt_x_deg": 0.0, "tilt_y_deg": 0.0, "calibrated": False,
        "push_depth_mm": 3.0, "n_points": 40, "rms_residual_mm": 0.1, "n_markers_left": 300,
        "n_markers_right": 300, "n_matches": 290, "frame_source": "fiducials", "method": "paper",
        "tilt_sigma_deg": 0.4, "quality": "suspect", "warnings": [f"suspect: {reason}"],
    }  # fmt: skip
    _print_estimate_table(estimate)
    out = capsys.readouterr().out
    assert f"SUSPECT: {reason}" in out and "quality" in out


@pytest.mark.parametrize("extra", [["--part-diameter", "50"], ["--part-diameter", "1e9"]])
def test_pair_leaves_the_garbage_collector_as_it_found_it(sweep, extra):
    """A pair's estimate runs with the cyclic collector paused (start-up cost), and an in-process caller
    gets it back on afterwards, whether the estimate succeeded or was refused."""
    import gc
    import sys

    def estimating() -> bool:  # the estimator's code is on the stack
        frame = sys._getframe()
        while frame is not None and "softjig/sensing/" not in frame.f_code.co_filename.replace("\\", "/"):
            frame = frame.f_back
        return frame is not None

    paused_during = []  # collection passes while the pair itself was estimated
    gc.callbacks.append(lambda phase, info: estimating() and paused_during.append(phase))
    try:
        assert gc.isenabled()
        result = runner.invoke(app, ["estimate", *_pair_args(sweep), *extra])
        assert gc.isenabled()
    finally:
        gc.callbacks.pop()
    assert "Traceback" not in result.output
    assert result.exit_code == (0 if extra[1] == "50" else 2), result.output
    assert paused_during == []


def test_the_lazy_copies_of_the_suspect_prefix_are_the_estimators():
    """The command line and the study runner keep their own copy (they import the estimator lazily)."""
    from softjig.cli.estimate import SUSPECT_PREFIX
    from softjig.sensing.results import SUSPECT_PREFIX as ESTIMATORS
    from softjig.study.run import _SUSPECT_PREFIX

    assert SUSPECT_PREFIX == _SUSPECT_PREFIX == ESTIMATORS
