"""Calibration from a sweep's estimates (calibration/sweep.py) and `softjig calibrate`: synthetic sweeps."""

from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np
import pytest
from typer.testing import CliRunner

from softjig.calibration.sweep import (
    alternate_theta_mask,
    fit_sweep_calibration,
    load_result_rows,
    load_sweep_calibration,
    save_sweep_calibration,
    sweep_samples,
)
from softjig.calibration.tilt import load_tilt_calibration
from softjig.cli import app
from softjig.config import CylinderPart, default_jig, part_to_dict
from softjig.errors import InputError
from softjig.io.batch import write_rows
from softjig.io.dataset import DatasetWriter

runner = CliRunner()
GAIN = {30.0: 1.3, 50.0: 1.6, 80.0: 2.1}  # the sensor reads alpha / gain
OX, OY = 0.8, -0.35  # deg


def _sweep(diameters=(30.0, 50.0, 80.0), alphas=(5.0, 10.0, 15.0, 20.0), step=10.0, gain=None):
    """Frames and rows of a synthetic sweep: pure sines A = (alpha / g) sin(theta) + O, exactly the model
    of the paper's formulas (so they must recover O and g to rounding)."""
    reference = SimpleNamespace(index=0, alpha_deg=None, theta_deg=None, part=None, reference=True)
    frames, rows, index = [reference], [{"index": 0, "reference": True}], 1
    for d in diameters:
        g = (gain or GAIN)[d]
        for a in alphas:
            for t in np.arange(0.0, 360.0, step):
                frames.append(
                    SimpleNamespace(
                        index=index,
                        alpha_deg=a,
                        theta_deg=float(t),
                        part=CylinderPart(diameter_mm=d),
                        reference=False,
                    )
                )
                rows.append(
                    {
                        "index": index,
                        "raw_tilt_x_deg": a / g * np.sin(np.radians(t)) + OX,
                        "raw_tilt_y_deg": a / g * np.cos(np.radians(t)) + OY,
                    }
                )
                index += 1
    return frames, rows


def test_pooled_recovers_offset_and_scale_exactly():
    frames, rows = _sweep(gain={30.0: 1.47, 50.0: 1.47, 80.0: 1.47})
    samples = sweep_samples(frames, rows)
    assert len(samples) == 3 * 4 * 36 and samples.n_skipped == 1 and samples.n_failed == 0
    cal = fit_sweep_calibration(samples)
    assert np.degrees(cal.pooled.offset_x_rad) == pytest.approx(OX, abs=1e-9)
    assert np.degrees(cal.pooled.offset_y_rad) == pytest.approx(OY, abs=1e-9)
    assert cal.pooled.scale == pytest.approx(1.47, abs=1e-9)
    assert cal.mode == "pooled" and cal.per_diameter == () and cal.warnings == ()


def test_per_diameter_recovers_each_scale():
    samples = sweep_samples(*_sweep())
    cal = fit_sweep_calibration(samples, mode="per-diameter")
    assert [d for d, _, _ in cal.per_diameter] == [30.0, 50.0, 80.0]
    for d, c, n in cal.per_diameter:
        assert n == 4 * 36
        assert c.scale == pytest.approx(GAIN[d], abs=1e-9)
        assert np.degrees(c.offset_x_rad) == pytest.approx(OX, abs=1e-9)
        assert cal.for_diameter(d) is c
    assert cal.for_diameter(99.0) is cal.pooled
    # pooled over sines of different gains: between the extremes
    assert 1.3 < cal.pooled.scale < 2.1


def test_even_and_odd_halves_are_disjoint_full_sweeps():
    samples = sweep_samples(*_sweep(diameters=(50.0,), alphas=(10.0,)))
    even, odd = samples.select("even"), samples.select("odd")
    assert len(even) == len(odd) == 18
    assert set(even.index).isdisjoint(odd.index)
    assert np.allclose(np.mod(even.theta_deg, 20.0), 0.0) and np.allclose(np.mod(odd.theta_deg, 20.0), 10.0)
    for half in ("even", "odd"):  # each half is a full sweep, so the formulas still recover the truth
        cal = fit_sweep_calibration(samples, selection=half)
        assert cal.pooled.scale == pytest.approx(1.6, abs=1e-9) and cal.selection == half
    # failed frames keep their place in the numbering of theta steps
    mask = alternate_theta_mask([50, 50, 50, 50], [10, 10, 10, 10], [270, 0, 180, 90])
    assert mask.tolist() == [False, True, True, False]


def test_failed_frames_are_left_out_counted_and_warned():
    frames, rows = _sweep(diameters=(50.0,), alphas=(10.0,))
    for k in (1, 2, 3, 4, 5, 6, 7, 8, 9):  # a gap of 90 deg in the sweep
        rows[k] = {"index": rows[k]["index"], "error": "only 3 markers", "exit_code": 3}
    samples = sweep_samples(frames, rows)
    assert samples.n_failed == 9 and len(samples) == 27 and samples.failed_errors[0] == "only 3 markers"
    cal = fit_sweep_calibration(samples)
    assert len(cal.failed_frames) == 9 and len(cal.frames) == 27
    assert cal.warnings and "full turn" in cal.warnings[0]


def test_errors_name_the_problem():
    frames, rows = _sweep(diameters=(50.0,), alphas=(10.0,))
    with pytest.raises(InputError, match="no estimate row"):
        sweep_samples(frames, rows[:-1])
    with pytest.raises(InputError, match="no sweep frame"):
        sweep_samples(frames[:1], rows[:1])
    samples = sweep_samples(frames, rows)
    with pytest.raises(InputError, match="mode"):
        fit_sweep_calibration(samples, mode="robust")
    with pytest.raises(InputError, match="selection"):
        samples.select("middle")
    few = sweep_samples(frames[:3], rows[:3])
    with pytest.raises(InputError, match="at least 3"):
        fit_sweep_calibration(few)


def test_json_is_versioned_records_its_source_and_estimate_reads_it(tmp_path):
    cal = fit_sweep_calibration(sweep_samples(*_sweep()), mode="per-diameter", selection="even")
    path = tmp_path / "cal.json"
    save_sweep_calibration(cal, path, source={"dataset": "/data/sweep", "method": "paper"})
    data = json.loads(path.read_text())
    assert data["format"] == "softjig-tilt-calibration" and data["version"] == 1
    for key in ("offset_x_deg", "offset_y_deg", "scale"):
        assert isinstance(data[key], float)
    src = data["source"]
    assert src["dataset"] == "/data/sweep" and src["method"] == "paper" and src["selection"] == "even"
    assert src["n_frames"] == len(src["frames"]) == 3 * 4 * 18 and "created" in src and "formula" in src
    assert [e["diameter_mm"] for e in data["per_diameter"]] == [30.0, 50.0, 80.0]
    plain = load_tilt_calibration(path)  # what `softjig estimate --calibration` applies: the pooled one
    assert plain.scale == pytest.approx(cal.pooled.scale)
    back = load_sweep_calibration(path)
    assert back.mode == "per-diameter" and back.for_diameter(80.0).scale == pytest.approx(2.1, abs=1e-9)
    assert back.frames == cal.frames


def test_samples_join_one_pass_streams_of_frames_and_rows():
    """The frames and the rows are each read once, in one pass (a dataset streams its frames, estimate
    rows may stream from the workers); only the raw tilts and errors of the rows are kept."""
    frames, rows = _sweep(diameters=(50.0,), alphas=(10.0,), step=30.0)
    whole = sweep_samples(frames, rows)
    streamed = sweep_samples(iter(frames), ({**row, "normal": [0.0, 0.0, 1.0]} for row in rows))
    assert streamed.index.tolist() == whole.index.tolist()
    np.testing.assert_array_equal(streamed.raw_x_deg, whole.raw_x_deg)
    np.testing.assert_array_equal(streamed.raw_y_deg, whole.raw_y_deg)


@pytest.mark.parametrize("suffix", [".jsonl", ".csv"])
def test_result_rows_round_trip(tmp_path, suffix):
    frames, rows = _sweep(diameters=(50.0,), alphas=(10.0,), step=30.0)
    path = tmp_path / f"r{suffix}"
    write_rows(rows, path)
    back = load_result_rows(path)
    cal = fit_sweep_calibration(sweep_samples(frames, back))
    assert cal.pooled.scale == pytest.approx(1.6, abs=1e-6)
    with pytest.raises(InputError, match="does not exist"):
        load_result_rows(tmp_path / "missing.jsonl")


def test_cli_calibrate_from_a_results_file(tmp_path):
    frames, rows = _sweep(diameters=(40.0, 60.0), alphas=(10.0, 20.0), step=30.0, gain={40.0: 1.5, 60.0: 1.5})
    root = tmp_path / "sweep"
    tiny = np.zeros((4, 4), np.uint8)
    with DatasetWriter(root, default_jig()) as writer:  # the images are never read with --results
        for f in frames:
            meta = (
                {"reference": True}
                if f.reference
                else {"alpha_deg": f.alpha_deg, "theta_deg": f.theta_deg, "part": part_to_dict(f.part)}
            )
            writer.add_frame(tiny, tiny, meta)
    write_rows(rows, root / "estimates.jsonl")
    out = tmp_path / "cal.json"
    result = runner.invoke(
        app,
        [
            "calibrate",
            str(root),
            "--out",
            str(out),
            "--results",
            str(root / "estimates.jsonl"),
            "--per-diameter",
        ],
    )
    assert result.exit_code == 0, result.output
    data = json.loads(out.read_text())
    assert data["scale"] == pytest.approx(1.5, abs=1e-9)
    assert data["offset_x_deg"] == pytest.approx(OX, abs=1e-9)
    assert data["source"]["dataset"] == str(root.resolve()) and len(data["per_diameter"]) == 2
    assert "S = 1.50000" in result.stdout
    bad = runner.invoke(app, ["calibrate", str(root), "--out", str(out), "--frames", "middle"])
    assert bad.exit_code == 2
    missing = runner.invoke(app, ["calibrate", str(tmp_path / "nope"), "--out", str(out)])
    assert missing.exit_code == 2


def _write_sweep(root, frames):
    tiny = np.zeros((4, 4), np.uint8)
    with DatasetWriter(root, default_jig()) as writer:  # images never read: refused before estimating
        for f in frames:
            meta = (
                {"reference": True}
                if f.reference
                else {"alpha_deg": f.alpha_deg, "theta_deg": f.theta_deg, "part": part_to_dict(f.part)}
            )
            writer.add_frame(tiny, tiny, meta)


def test_cli_calibrate_refuses_a_sweep_at_alpha_zero(tmp_path):
    """Issue 14: `softjig calibrate` of a sweep at alpha = 0 wrote S = 0 with exit 0."""
    frames, rows = _sweep(diameters=(50.0,), alphas=(0.0,), step=30.0)
    root = tmp_path / "sweep"
    _write_sweep(root, frames)
    write_rows(rows, root / "estimates.jsonl")
    out = tmp_path / "cal.json"
    for extra in ([], ["--results", str(root / "estimates.jsonl")]):
        result = runner.invoke(app, ["calibrate", str(root), "--out", str(out), "--no-progress", *extra])
        assert result.exit_code == 2, result.output
        assert "alpha_deg = 0" in result.output and "--alphas" in result.output
        assert not out.exists()


@pytest.mark.parametrize(("step", "frames_option", "needed"), [(180.0, "all", 3), (120.0, "even", 6)])
def test_cli_calibrate_refuses_too_few_tilt_directions(tmp_path, step, frames_option, needed):
    frames, _ = _sweep(diameters=(50.0,), alphas=(10.0,), step=step)
    root = tmp_path / "sweep"
    _write_sweep(root, frames)
    out = tmp_path / "cal.json"
    result = runner.invoke(
        app, ["calibrate", str(root), "--out", str(out), "--frames", frames_option, "--no-progress"]
    )
    assert result.exit_code == 2, result.output
    assert f"at least {needed} per turn" in result.output
    assert f"--theta-step {360 / needed:g}" in result.output
    assert not out.exists()


def test_rows_method_is_recorded_at_the_top_level(tmp_path):
    """The demo's writer (fit_sweep_calibration + save_sweep_calibration) gets the method from its rows."""
    frames, rows = _sweep(diameters=(50.0,), alphas=(10.0,), step=30.0)
    rows = [{**row, "method": "paper"} for row in rows]
    cal = fit_sweep_calibration(sweep_samples(frames, rows), mode="per-diameter")
    path = tmp_path / "cal.json"
    save_sweep_calibration(cal, path)
    data = json.loads(path.read_text())
    assert data["method"] == "paper"
    assert load_sweep_calibration(path).for_diameter(50.0).method == "paper"
    mixed = rows[:5] + [{**row, "method": "refractive"} for row in rows[5:]]
    with pytest.raises(InputError, match="mix the methods"):
        sweep_samples(frames, mixed)


def test_compare_refuses_a_theta_step_too_coarse_before_estimating(tmp_path):
    """Issue 14: `softjig compare out/small` (theta step 90) blamed 'failed frames'."""
    frames, _ = _sweep(diameters=(50.0,), alphas=(10.0,), step=90.0)
    root = tmp_path / "small"
    _write_sweep(root, frames)
    result = runner.invoke(app, ["compare", str(root), "--no-progress"])
    assert result.exit_code == 2, result.output
    assert "failed" not in result.output
    assert "at least 6 per turn" in result.output and "--theta-step 60" in result.output
