"""The paper's Ox, Oy, S on synthetic sine sweeps with known offset and scale."""

import numpy as np
import pytest

from softjig.calibration.tilt import TiltCalibration, fit_tilt_calibration
from softjig.errors import InputError
from softjig.geometry import normal_from_tilt, tilt_angles


def _sweep(alpha_deg, offset_deg=(0.0, 0.0), gain=1.0, step_deg=10):
    thetas = np.radians(np.arange(0, 360, step_deg))
    ax, ay = tilt_angles(np.array([normal_from_tilt(np.radians(alpha_deg), t) for t in thetas]))
    return ax / gain + np.radians(offset_deg[0]), ay / gain + np.radians(offset_deg[1])


def test_pure_sine_recovers_offset_and_scale():
    # Exact sines A = (alpha / g) sin(theta) + O: the paper's formulas recover O and S = g exactly.
    theta = np.radians(np.arange(0, 360, 10))
    alpha, g, ox, oy = np.radians(15), 1.47, np.radians(0.8), np.radians(-0.3)
    ax, ay = alpha / g * np.sin(theta) + ox, alpha / g * np.cos(theta) + oy
    cal = fit_tilt_calibration(ax, ay, alpha)
    assert cal.offset_x_rad == pytest.approx(ox, abs=1e-12)
    assert cal.offset_y_rad == pytest.approx(oy, abs=1e-12)
    assert cal.scale == pytest.approx(g, abs=1e-9)
    cx, cy = cal.apply(ax, ay)
    assert np.allclose(cx, alpha * np.sin(theta), atol=1e-9)
    assert np.allclose(cy, alpha * np.cos(theta), atol=1e-9)


def test_hand_computed_case():
    # Four samples: Ax = (1, 3, 1, -1) deg -> Ox = 1, sigma_x = sqrt(2); Ay = (2, 2, 4, 0) deg -> Oy = 2,
    # sigma_y = sqrt(2); S = 2 * 2 / (sqrt 2 * 2 sqrt 2) = 1 for alpha = 2 deg.
    ax, ay = np.radians([1, 3, 1, -1]), np.radians([2, 2, 4, 0])
    cal = fit_tilt_calibration(ax, ay, np.radians(2))
    assert np.degrees(cal.offset_x_rad) == pytest.approx(1.0)
    assert np.degrees(cal.offset_y_rad) == pytest.approx(2.0)
    assert cal.scale == pytest.approx(1.0)


def test_pooled_sweeps_use_rms_alpha():
    # Sines of several amplitudes pooled (the paper: "the same offsets and scales" for all data).
    theta = np.radians(np.arange(0, 360, 10))
    g, ox, oy = 1.3, np.radians(0.5), np.radians(-0.2)
    alphas = np.radians(np.repeat([5, 10, 15, 20], len(theta)))
    phase = np.tile(theta, 4)
    cal = fit_tilt_calibration(alphas / g * np.sin(phase) + ox, alphas / g * np.cos(phase) + oy, alphas)
    assert cal.scale == pytest.approx(g, rel=1e-9)
    assert cal.offset_x_rad == pytest.approx(ox, abs=1e-12)


def test_real_tilt_angles_are_near_sines():
    # The true Ax = atan(tan(alpha) sin(theta)) is not an exact sine, so the paper's formula gives a perfect
    # sensor S = 0.9994, 0.9975, 0.9943, 0.9898 at 5, 10, 15, 20 deg (the formula's own approximation).
    for alpha_deg, expected in ((5, 0.99937), (10, 0.99746), (15, 0.99427), (20, 0.98977)):
        ax, ay = _sweep(alpha_deg)
        assert fit_tilt_calibration(ax, ay, np.radians(alpha_deg)).scale == pytest.approx(expected, abs=2e-5)


def test_identity_and_errors():
    assert TiltCalibration().is_identity()
    with pytest.raises(InputError, match="at least 3"):
        fit_tilt_calibration(np.zeros(2), np.zeros(2), 0.1)
    with pytest.raises(InputError, match="do not vary"):
        fit_tilt_calibration(np.zeros(5), np.zeros(5), 0.1)
    with pytest.raises(InputError, match="one length"):
        fit_tilt_calibration(np.zeros(5), np.zeros(4), 0.1)
    with pytest.raises(InputError, match="NaN"):
        fit_tilt_calibration(np.array([0, 1, np.nan]), np.zeros(3), 0.1)


def test_calibration_file_round_trip_and_errors(tmp_path):
    from softjig.calibration.tilt import load_tilt_calibration, save_tilt_calibration

    cal = TiltCalibration(np.radians(0.7), np.radians(-0.4), 1.52, method="paper")
    path = tmp_path / "cal.json"
    save_tilt_calibration(cal, path, source={"dataset": "x"})
    back = load_tilt_calibration(path)
    assert back.method == "paper"
    assert back.scale == cal.scale
    assert back.offset_x_rad == pytest.approx(cal.offset_x_rad, abs=1e-15)
    with pytest.raises(InputError, match="does not exist"):
        load_tilt_calibration(tmp_path / "missing.json")
    path.write_text('{"offset_x_deg": 1, "offset_y_deg": "x", "scale": 1}')
    with pytest.raises(InputError, match="offset_y_deg"):
        load_tilt_calibration(path)
    path.write_text("{not json")
    with pytest.raises(InputError, match="cannot read"):
        load_tilt_calibration(path)


def test_every_calibration_written_names_its_method(tmp_path):
    from softjig.calibration.tilt import save_tilt_calibration, tilt_calibration_to_dict

    unnamed = TiltCalibration(0.0, 0.0, 1.5)
    assert tilt_calibration_to_dict(unnamed, source={"method": "paper"})["method"] == "paper"
    with pytest.raises(InputError, match="must record the estimation method"):
        save_tilt_calibration(unnamed, tmp_path / "cal.json")
    assert not (tmp_path / "cal.json").exists()


def test_a_file_without_its_method_is_refused_with_how_to_redo_it(tmp_path):
    from softjig.calibration.tilt import load_tilt_calibration

    path = tmp_path / "old.json"
    path.write_text('{"offset_x_deg": 0.1, "offset_y_deg": 0.2, "scale": 1.8, "source": {"method": "paper"}}')
    with pytest.raises(InputError, match=r"softjig calibrate DATASET --method METHOD --out CAL\.json") as err:
        load_tilt_calibration(path)
    assert '"method": "paper"' in str(err.value)  # what the old file's source says, and how to use it


def test_a_method_mismatch_is_refused(tmp_path):
    from softjig.calibration.tilt import check_calibration_for, load_tilt_calibration, save_tilt_calibration

    path = tmp_path / "cal.json"
    save_tilt_calibration(TiltCalibration(0.0, 0.0, 1.8, method="paper"), path)
    assert load_tilt_calibration(path, method="paper").method == "paper"
    with pytest.raises(InputError, match="--method paper"):
        load_tilt_calibration(path, method="refractive")
    check_calibration_for(None, "refractive")
    with pytest.raises(InputError, match="does not record"):
        check_calibration_for(TiltCalibration(), "refractive")


@pytest.mark.parametrize(
    ("ax", "ay", "alpha", "match"),
    [
        (np.sin(np.arange(6.0)), np.cos(np.arange(6.0)), 0.0, "alpha = 0"),
        (np.full(6, 0.1), np.full(6, 0.1) + 1e-12, 0.1, "do not vary"),
        (0.01 * np.sin(np.arange(6.0)), 0.01 * np.cos(np.arange(6.0)), np.radians(10) * 57.3, "outside"),
        (np.sin(np.arange(6.0)), np.cos(np.arange(6.0)), 0.001, "outside"),
    ],
)
def test_a_sweep_that_cannot_determine_the_scale_is_refused(ax, ay, alpha, match):
    with pytest.raises(InputError, match=match):
        fit_tilt_calibration(ax, ay, alpha)


@pytest.mark.parametrize("scale", [0.0, -1.0, np.nan, np.inf])
def test_a_calibration_with_a_scale_not_finite_and_positive_cannot_exist(scale):
    with pytest.raises(InputError, match="scale"):
        TiltCalibration(0.0, 0.0, scale)
    with pytest.raises(InputError, match="offset_x_rad"):
        TiltCalibration(np.nan, 0.0, 1.0)
