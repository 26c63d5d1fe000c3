"""The RMSE grid and its definitions, evaluation of a calibration on a sweep, findings, figures (pure)."""

from __future__ import annotations

import numpy as np
import pytest

from softjig.calibration.sweep import SweepSamples, fit_sweep_calibration
from softjig.calibration.tilt import TiltCalibration
from softjig.errors import InputError
from softjig.evaluation.metrics import commanded_tilt_angles_deg, rmse_deg, rmse_grid, tilt_error_summary
from softjig.evaluation.report import grid_markdown, paper_findings
from softjig.evaluation.tilt_sweep import corrected_tilts_deg, evaluate_sweep
from softjig.geometry import normal_from_tilt, normal_from_tilt_angles, tilt_angles


def test_commanded_angles_are_the_binding_convention():
    ax, ay = commanded_tilt_angles_deg([10.0, 10.0, 20.0], [0.0, 90.0, 45.0])
    assert ax[0] == pytest.approx(0.0, abs=1e-12) and ay[0] == pytest.approx(10.0)  # tilt towards +x
    assert ax[1] == pytest.approx(-10.0) and ay[1] == pytest.approx(0.0, abs=1e-12)  # towards +y: Ax < 0
    n = normal_from_tilt(np.radians(20), np.radians(45))
    assert (ax[2], ay[2]) == pytest.approx(tuple(np.degrees(tilt_angles(n))))


def test_rmse_pools_both_axes():
    # ex = (1, -1), ey = (3, 3): sqrt((1 + 1 + 9 + 9) / 4) = sqrt(5)
    assert rmse_deg([1, -1], [3, 3]) == pytest.approx(np.sqrt(5))
    assert np.isnan(rmse_deg([], []))
    with pytest.raises(InputError):
        rmse_deg([1, 2], [1])


def test_grid_groups_cells_and_counts_failures():
    d = [30, 30, 30, 50, 50]
    a = [5, 5, 10, 5, 5]
    grid = rmse_grid(
        d, a, [1, -1, 2, 0, 0], [3, 3, 0, 0, 2], failed_diameters_mm=[50, 80], failed_alphas_deg=[10, 5]
    )
    assert grid.diameters_mm.tolist() == [30, 50, 80] and grid.alphas_deg.tolist() == [5, 10]
    assert grid.cell(30, 5) == pytest.approx(np.sqrt(5))
    assert grid.cell(30, 10) == pytest.approx(np.sqrt(2))
    assert grid.cell(50, 5) == pytest.approx(1.0)
    assert np.isnan(grid.cell(50, 10)) and grid.failed[1, 1] == 1 and grid.failed[2, 0] == 1
    assert grid.count.tolist() == [[2, 1], [2, 0], [0, 0]]
    assert grid.rmse_x_deg[0, 0] == pytest.approx(1.0) and grid.rmse_y_deg[0, 0] == pytest.approx(3.0)
    data = grid.to_dict()
    assert data["rmse_deg"][1][1] is None and data["failed"][2][0] == 1
    table = grid_markdown(grid)
    assert "| 30 | 2.24 | 1.41 |" in table and "n/a (1 failed)" in table
    with pytest.raises(InputError, match="NaN"):
        rmse_grid([30], [5], [np.nan], [0])
    with pytest.raises(InputError, match="no frame"):
        rmse_grid([], [], [], [])


def _samples(gain=1.6, ox=0.5, oy=-0.3, diameters=(30.0, 50.0, 80.0), alphas=(5.0, 20.0), step=30.0):
    """A sweep read by a sensor with the true (not sine) tilt angles divided by ``gain`` plus offsets."""
    rows = [(d, a, t) for d in diameters for a in alphas for t in np.arange(0.0, 360.0, step)]
    d, a, t = (np.array(v, float) for v in zip(*rows, strict=True))
    cx, cy = commanded_tilt_angles_deg(a, t)
    return SweepSamples(np.arange(len(d)), d, a, t, cx / gain + ox, cy / gain + oy)


def test_evaluation_of_a_calibration_on_held_out_frames():
    samples = _samples()
    cal = fit_sweep_calibration(samples, selection="even")
    ev = evaluate_sweep(samples, cal.pooled, selection="odd")
    assert ev.selection == "odd" and ev.n_frames == len(samples) // 2 and ev.n_failed == 0
    # the formulas' only error is that real tilt angles are not exact sines: < 0.2 deg at 20 deg
    assert np.nanmax(ev.calibrated.rmse_deg) < 0.2
    # uncalibrated, the error grows with alpha (a scale error) on top of the offsets
    assert ev.uncalibrated.cell(50, 20) > 5 * ev.calibrated.cell(50, 20)
    assert ev.uncalibrated.cell(50, 20) > ev.uncalibrated.cell(50, 5)
    # the identity calibration leaves the raw angles as they are
    raw = corrected_tilts_deg(samples, TiltCalibration())
    assert np.allclose(raw[0], samples.raw_x_deg)


def test_error_summary_of_normals():
    truth = np.array([normal_from_tilt(np.radians(10), np.radians(t)) for t in (0, 90, 180)])
    shifted = [np.radians(np.add(np.degrees(tilt_angles(n)), (1.0, 0.0))) for n in truth]
    est = np.array([normal_from_tilt_angles(*angles) for angles in shifted])
    s = tilt_error_summary(est, truth)
    assert s.n == 3 and s.rmse_x_deg == pytest.approx(1.0) and s.rmse_y_deg == pytest.approx(0.0, abs=1e-9)
    assert s.rmse_deg == pytest.approx(np.sqrt(0.5)) and s.bias_x_deg == pytest.approx(1.0)
    assert 0.9 < s.mean_angle_deg < 1.01
    assert tilt_error_summary(truth, truth).max_angle_deg == pytest.approx(0.0, abs=1e-6)


def test_paper_findings_on_a_paper_like_grid():
    d = np.repeat([30.0, 40.0, 50.0, 60.0, 70.0, 80.0], 4)
    a = np.tile([5.0, 10.0, 15.0, 20.0], 6)
    err = np.where(d < 50, 4.0, 1.0) + np.where((d == 80) & (a == 20), 1.5, 0.0)
    findings = paper_findings(rmse_grid(d, a, err, err))
    assert [f.holds for f in findings] == [True, True, True]
    err_big = err + np.where(d >= 50, 3.0, 0.0)
    assert paper_findings(rmse_grid(d, a, err_big, err_big))[1].holds is False


def test_figures_are_pngs(tmp_path):
    from softjig.evaluation import figures

    samples = _samples(diameters=(50.0,), alphas=(10.0,), step=90.0)
    cal = TiltCalibration(0.0, 0.0, 1.6)
    figures.tilt_sweep_figure(samples, None, tmp_path / "before.png")
    figures.tilt_sweep_figure(samples, cal, tmp_path / "after.png")
    ev = evaluate_sweep(samples, cal)
    figures.rmse_grid_figure([("cal", ev.calibrated), ("raw", ev.uncalibrated)], tmp_path / "grid.png")
    truth = np.array([normal_from_tilt(np.radians(10), np.radians(t)) for t in (0, 90, 180)])
    figures.normal_projection_figure([("raw", truth * [0.5, 0.5, 1])], truth, tmp_path / "cube.png")
    for name in ("before", "after", "grid", "cube"):
        assert (tmp_path / f"{name}.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_rmse_panels_share_one_colour_scale():
    """Issue 14: the calibrated and uncalibrated grids were each on their own scale, so the same colour
    meant 1 deg in one panel and 8 deg in the other."""
    from softjig.evaluation import figures

    d = np.repeat([30.0, 50.0], 2)
    a = np.tile([10.0, 20.0], 2)
    small, large = rmse_grid(d, a, np.full(4, 0.5), np.full(4, 0.5)), rmse_grid(d, a, d / 10, d / 10)
    for fig in (
        figures.rmse_grid_plot([("small", small), ("large", large)]),
        figures.methods_plot([("a", small), ("b", large), ("c", small)], [("x", 1.0), ("y", float("nan"))]),
    ):
        limits = [im.get_clim() for ax in fig.axes for im in ax.images]
        assert len(limits) >= 2 and all(lim == pytest.approx((0.0, 5.0)) for lim in limits)
        assert len([ax for ax in fig.axes if ax.get_label() == "<colorbar>"]) == 1
