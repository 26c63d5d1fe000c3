"""First-order normal and tilt uncertainty: Jacobians by finite differences, coverage by Monte Carlo."""

import numpy as np
import pytest

from softjig.errors import InputError
from softjig.geometry import fit_plane_svd, normal_from_tilt, normal_from_tilt_angles, tilt_angles
from softjig.sensing.uncertainty import (
    NormalUncertainty,
    normal_from_slopes,
    normal_uncertainty,
    tilt_angles_from_slopes,
    with_depth_scale_error,
    with_spread_between,
)


def random_plane_points(rng, *, n_points, radius_mm, sigma_mm, alpha_rad, theta_rad):
    """``n_points`` uniform on a disc (off-centre by up to 5 mm) on the plane of normal ``n`` through
    ``z = -2`` on the axis, with Gaussian depth (z) noise. Returns the points and ``n``."""
    n = normal_from_tilt(alpha_rad, theta_rad)
    r = radius_mm * np.sqrt(rng.uniform(0, 1, n_points))
    phi = rng.uniform(0, 2 * np.pi, n_points)
    xy = np.column_stack([r * np.cos(phi), r * np.sin(phi)]) + rng.uniform(-5, 5, 2)
    z = -2.0 - (xy @ n[:2]) / n[2] + rng.normal(0.0, sigma_mm, n_points)
    return np.column_stack([xy, z]), n


# ----------------------------------------------------------------------------------- Jacobians


@pytest.mark.parametrize(("a", "b"), [(0.0, 0.0), (0.3, -0.2), (-0.36, 0.05), (1.2, 0.7)])
def test_jacobians_match_finite_differences(a, b):
    eps = 1e-6
    n, jn = normal_from_slopes(a, b)
    angles, jt = tilt_angles_from_slopes(a, b)
    assert np.linalg.norm(n) == pytest.approx(1.0) and n[2] > 0
    np.testing.assert_allclose(angles, tilt_angles(n), atol=1e-15)
    for k, (da, db) in enumerate([(eps, 0.0), (0.0, eps)]):
        fd_n = (normal_from_slopes(a + da, b + db)[0] - normal_from_slopes(a - da, b - db)[0]) / (2 * eps)
        fd_t = (tilt_angles_from_slopes(a + da, b + db)[0] - tilt_angles_from_slopes(a - da, b - db)[0]) / (
            2 * eps
        )
        np.testing.assert_allclose(jn[:, k], fd_n, atol=1e-9)
        np.testing.assert_allclose(jt[:, k], fd_t, atol=1e-9)
    # The normal stays unit: its Jacobian is orthogonal to it.
    np.testing.assert_allclose(n @ jn, 0.0, atol=1e-15)


def test_covariance_is_rank_two_and_orthogonal_to_the_normal():
    rng = np.random.default_rng(1)
    pts, _ = random_plane_points(rng, n_points=40, radius_mm=30, sigma_mm=0.2, alpha_rad=0.3, theta_rad=1.0)
    fit = fit_plane_svd(pts)
    u = normal_uncertainty(pts, fit)
    assert isinstance(u, NormalUncertainty)
    np.testing.assert_allclose(u.covariance, u.covariance.T)
    np.testing.assert_allclose(u.covariance @ fit.normal, 0.0, atol=1e-15)
    eig = np.linalg.eigvalsh(u.covariance)
    assert eig[0] < 1e-12 * eig[2] and eig[1] > 0
    assert u.tilt_sigma_rad == pytest.approx(np.sqrt(np.trace(u.covariance)))
    assert u.residual_sigma_mm == pytest.approx(0.2, rel=0.3)


def test_hand_computed_case():
    # Four points at (+-10, 0), (0, +-10) on z = 0: X^T X = 200 I, so sigma(Ax) = sigma(Ay) = s / sqrt(200).
    xy = np.array([[-10.0, 0], [10, 0], [0, -10], [0, 10]])
    pts = np.column_stack([xy, np.zeros(4)])
    u = normal_uncertainty(pts, fit_plane_svd(pts), point_sigma_mm=0.1)
    assert u.tilt_sigma_x_rad == pytest.approx(0.1 / np.sqrt(200))
    assert u.tilt_sigma_y_rad == pytest.approx(0.1 / np.sqrt(200))
    assert u.tilt_sigma_rad == pytest.approx(0.1 / 10)
    assert u.residual_sigma_mm == 0.1


def test_floor_raises_the_noise_scale():
    rng = np.random.default_rng(2)
    pts, _ = random_plane_points(rng, n_points=30, radius_mm=20, sigma_mm=0.01, alpha_rad=0.1, theta_rad=0.0)
    fit = fit_plane_svd(pts)
    low = normal_uncertainty(pts, fit)
    floored = normal_uncertainty(pts, fit, floor_mm=0.1)
    assert low.residual_sigma_mm < 0.02 and floored.residual_sigma_mm == 0.1
    assert floored.tilt_sigma_x_rad == pytest.approx(low.tilt_sigma_x_rad * 0.1 / low.residual_sigma_mm)
    assert normal_uncertainty(pts, fit, point_sigma_mm=0.05, floor_mm=0.1).residual_sigma_mm == 0.1


# ---------------------------------------------------------------------------------- Monte Carlo


def test_monte_carlo_coverage_and_scale():
    # Random planes (tilt <= 20 deg), 6-150 points on discs of radius 15-40 mm, z-noise 0.05-0.5 mm.
    rng = np.random.default_rng(0)
    trials = 2500
    z_est = np.empty((trials, 2))  # errors / predicted sigma, noise estimated from the residuals
    z_true = np.empty((trials, 2))  # errors / predicted sigma, noise known
    for k in range(trials):
        pts, n = random_plane_points(
            rng,
            n_points=int(rng.integers(6, 151)),
            radius_mm=rng.uniform(15, 40),
            sigma_mm=(sigma := rng.uniform(0.05, 0.5)),
            alpha_rad=np.radians(rng.uniform(0, 20)),
            theta_rad=rng.uniform(0, 2 * np.pi),
        )
        fit = fit_plane_svd(pts)
        err = np.subtract(tilt_angles(fit.normal), tilt_angles(n))
        est = normal_uncertainty(pts, fit)
        known = normal_uncertainty(pts, fit, point_sigma_mm=sigma)
        z_est[k] = err / [est.tilt_sigma_x_rad, est.tilt_sigma_y_rad]
        z_true[k] = err / [known.tilt_sigma_x_rad, known.tilt_sigma_y_rad]
    coverage = np.mean(np.abs(z_est) <= 1.0, axis=0)
    assert np.all(np.abs(coverage - 0.683) <= 0.03), coverage
    assert np.all(np.abs(np.mean(np.abs(z_true) <= 1.0, axis=0) - 0.683) <= 0.03)
    # The errors' spread matches the predicted sigma (known noise: exactly a unit normal).
    assert np.all(np.abs(np.std(z_true, axis=0) - 1.0) <= 0.1)
    # Estimated noise: Student-t with N - 3 dof, heavier tails; its robust spread still matches.
    assert np.all(np.abs(1.4826 * np.median(np.abs(z_est), axis=0) - 1.0) <= 0.1)


@pytest.mark.parametrize(
    ("n_points", "radius_mm", "sigma_mm", "alpha_deg"),
    [(8, 15, 0.3, 20), (40, 25, 0.1, 10), (150, 40, 0.5, 5)],
)
def test_error_std_matches_prediction_for_a_fixed_layout(n_points, radius_mm, sigma_mm, alpha_deg):
    # One marker layout, 800 noise draws: the std of the tilt errors matches the predicted sigma.
    rng = np.random.default_rng(n_points)
    clean, n = random_plane_points(
        rng,
        n_points=n_points,
        radius_mm=radius_mm,
        sigma_mm=0.0,
        alpha_rad=np.radians(alpha_deg),
        theta_rad=2.0,
    )
    pred = normal_uncertainty(clean, fit_plane_svd(clean), point_sigma_mm=sigma_mm)
    errs, tilt_err = np.empty((800, 2)), np.empty(800)
    for k in range(800):
        pts = clean + np.column_stack([np.zeros((n_points, 2)), rng.normal(0, sigma_mm, n_points)])
        fit = fit_plane_svd(pts)
        errs[k] = np.subtract(tilt_angles(fit.normal), tilt_angles(n))
        tilt_err[k] = np.linalg.norm(np.cross(fit.normal, n))
    np.testing.assert_allclose(errs.std(axis=0), [pred.tilt_sigma_x_rad, pred.tilt_sigma_y_rad], rtol=0.1)
    assert np.sqrt(np.mean(tilt_err**2)) == pytest.approx(pred.tilt_sigma_rad, rel=0.1)


# -------------------------------------------------------------------------------------- errors


def test_three_points_need_a_known_sigma():
    pts = np.array([[0.0, 0, 0], [10, 0, 0], [0, 10, 1]])
    fit = fit_plane_svd(pts)
    with pytest.raises(InputError, match="at least 4 points"):
        normal_uncertainty(pts, fit)
    u = normal_uncertainty(pts, fit, point_sigma_mm=0.1)
    assert np.isfinite(u.tilt_sigma_rad) and u.tilt_sigma_rad > 0


@pytest.mark.parametrize(
    ("points", "kwargs", "match"),
    [
        (np.zeros((5, 2)), {}, "shape"),
        (np.array([[0, 0, 0], [1, 0, 0], [0, 1, np.nan], [1, 1, 0.0]]), {}, "non-finite"),
        (np.random.default_rng(0).normal(size=(6, 3)), {"point_sigma_mm": 0.0}, "point_sigma_mm"),
        (np.random.default_rng(0).normal(size=(6, 3)), {"floor_mm": -0.1}, "floor_mm"),
        (np.column_stack([np.arange(5.0), np.arange(5.0), np.zeros(5)]), {"point_sigma_mm": 0.1}, "line"),
    ],
)
def test_bad_input_raises(points, kwargs, match):
    plane = fit_plane_svd(np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]]))
    with pytest.raises(InputError, match=match):
        normal_uncertainty(points, plane, **kwargs)


def test_downward_normal_raises():
    pts = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]])
    plane = fit_plane_svd(pts)
    flipped = type(plane)(**{**plane.__dict__, "normal": -plane.normal})
    with pytest.raises(InputError, match="n_z > 0"):
        normal_uncertainty(pts, flipped)


def test_a_depth_scale_error_tilts_a_tilted_normal_along_its_tilt_and_a_level_one_not_at_all():
    xy = np.array([[-10.0, 0], [10, 0], [0, -10], [0, 10]])
    pts = np.column_stack([xy, np.zeros(4)])
    base = normal_uncertainty(pts, fit_plane_svd(pts), point_sigma_mm=0.1)
    level = with_depth_scale_error(base, np.array([0.0, 0.0, 1.0]), 0.01)
    assert np.allclose(level.covariance, base.covariance, atol=1e-18)
    # Tilted 15 deg about x: a depth scale error of 1 % moves it by 0.01 sin(15) cos(15) rad about x only.
    tilted = normal_from_tilt_angles(np.radians(15.0), 0.0)
    scaled = with_depth_scale_error(base, tilted, 0.01)
    added = 0.01 * np.sin(np.radians(15.0)) * np.cos(np.radians(15.0))
    assert scaled.tilt_sigma_x_rad == pytest.approx(np.hypot(base.tilt_sigma_x_rad, added), rel=1e-3)
    assert scaled.tilt_sigma_y_rad == pytest.approx(base.tilt_sigma_y_rad)
    assert scaled.tilt_sigma_rad == pytest.approx(np.hypot(base.tilt_sigma_rad, added), rel=1e-3)
    for bad in (-0.01, 1.0, float("nan")):
        with pytest.raises(InputError, match="scale_error"):
            with_depth_scale_error(base, tilted, bad)


def test_spread_between_two_normals_adds_half_their_difference_in_quadrature():
    xy = np.array([[-10.0, 0], [10, 0], [0, -10], [0, 10]])
    pts = np.column_stack([xy, np.zeros(4)])
    base = normal_uncertainty(pts, fit_plane_svd(pts), point_sigma_mm=0.1)
    a = normal_from_tilt_angles(np.radians(0.4), 0.0)
    b = normal_from_tilt_angles(np.radians(-0.4), 0.0)
    spread = with_spread_between(base, a, b)
    assert spread.tilt_sigma_x_rad == pytest.approx(np.hypot(base.tilt_sigma_x_rad, np.radians(0.4)))
    assert spread.tilt_sigma_y_rad == pytest.approx(base.tilt_sigma_y_rad)
    assert spread.tilt_sigma_rad > base.tilt_sigma_rad
    same = with_spread_between(base, a, a)
    assert same.tilt_sigma_x_rad == pytest.approx(base.tilt_sigma_x_rad)
