"""Robust plane fit: a tilted disc of markers whose raised side has lifted off, plus wall markers."""

import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from oracles.robust_candidates import best_candidate as oracle_best_candidate
from softjig.errors import InputError
from softjig.geometry import angle_between, fit_plane_svd, normal_from_tilt
from softjig.sensing import robust
from softjig.sensing._robust_kernels import best_candidate
from softjig.sensing.robust import RobustPlaneFit, fit_plane_robust


def grid_disc(radius_mm: float, pitch_mm: float = 8.0) -> np.ndarray:
    """``(M, 2)`` marker positions (mm) on a square grid, inside a disc about the origin."""
    k = np.arange(-np.ceil(radius_mm / pitch_mm), np.ceil(radius_mm / pitch_mm) + 1) * pitch_mm
    xy = np.stack(np.meshgrid(k, k), axis=-1).reshape(-1, 2)
    return xy[np.hypot(xy[:, 0], xy[:, 1]) <= radius_mm + 1e-9]


def contact_scene(
    rng,
    *,
    alpha_deg=15.0,
    theta_deg=30.0,
    radius_mm=40.0,
    lift_fraction=0.33,
    wall_fraction=0.0,
    noise_mm=0.0,
):
    """Markers under a part tilted by ``alpha`` towards ``theta`` (its face ``n . p + d = 0``).

    The face descends towards ``theta``; the raised side (the ``lift_fraction`` of the disc farthest
    against ``theta``) has lifted off: those markers lie *below* the plane, on a flatter surface that
    meets it at the contact boundary, their gap growing with the distance from it. Wall markers
    (``wall_fraction`` of the disc's count) sit on a ring just outside the disc on the deep side, 0.5 mm
    and more *above* the extended plane. Returns the points (mm), the true normal and the contact mask.
    """
    n = normal_from_tilt(np.radians(alpha_deg), np.radians(theta_deg))
    z0 = -3.0

    def z_plane(xy):
        return z0 - (xy @ n[:2]) / n[2]

    xy = grid_disc(radius_mm) + rng.uniform(-1.0, 1.0, size=(1, 2))
    along = xy @ np.array([np.cos(np.radians(theta_deg)), np.sin(np.radians(theta_deg))])
    z = z_plane(xy) + rng.normal(0.0, noise_mm, len(xy))
    contact = np.ones(len(xy), dtype=bool)
    if lift_fraction > 0:
        boundary = np.quantile(along, lift_fraction)
        lift = along < boundary
        beyond = boundary - along[lift]
        z[lift] -= 0.7 * np.tan(np.radians(alpha_deg)) * beyond + 0.01 * beyond**2
        contact[lift] = False
    pts = np.column_stack([xy, z])
    n_wall = round(wall_fraction * len(xy))
    if n_wall:
        azimuth = np.radians(theta_deg) + rng.uniform(-1.0, 1.0, n_wall)
        r = radius_mm + rng.uniform(2.0, 10.0, n_wall)
        wxy = np.column_stack([r * np.cos(azimuth), r * np.sin(azimuth)])
        wz = z_plane(wxy) + 0.5 + 0.4 * (r - radius_mm) + rng.normal(0.0, noise_mm, n_wall)
        pts = np.vstack([pts, np.column_stack([wxy, wz])])
        contact = np.concatenate([contact, np.zeros(n_wall, dtype=bool)])
    return pts, n, contact


def err_deg(a, b):
    return float(np.degrees(angle_between(a, b)))


# ------------------------------------------------------------------------------------ accuracy

OUTLIER_CASES = [  # (lift fraction of the disc, wall markers as a fraction of the disc's count)
    (0.0, 0.0),
    (0.2, 0.0),
    (0.33, 0.0),  # the raised third
    (0.3, 0.1),
    (0.4, 0.2),  # 50 % outliers
]


@pytest.mark.accuracy
@pytest.mark.parametrize("one_sided", [True, False])
@pytest.mark.parametrize(("lift", "wall"), OUTLIER_CASES)
@pytest.mark.parametrize("alpha_deg", [8.0, 20.0])
def test_exact_plane_recovered_where_svd_fails(lift, wall, alpha_deg, one_sided):
    worst = 0.0
    for seed in range(4):
        rng = np.random.default_rng(seed)
        theta = rng.uniform(0, 360)
        pts, n, contact = contact_scene(
            rng, alpha_deg=alpha_deg, theta_deg=theta, lift_fraction=lift, wall_fraction=wall
        )
        fit = fit_plane_robust(pts, rng=seed, one_sided=one_sided)
        worst = max(worst, err_deg(fit.plane.normal, n))
        wall_markers = (pts - [0.0, 0.0, -3.0]) @ n > 0.4  # above the true plane
        assert not np.any(fit.inliers & wall_markers)
        # Every contact marker is kept; only lifted-off markers within the threshold may join them.
        assert np.all(fit.inliers[contact])
        assert np.sum(fit.inliers & ~contact) <= 2
        if lift > 0:
            assert err_deg(fit_plane_svd(pts).normal, n) > 1.0
    assert worst < 0.1


@pytest.mark.accuracy
@pytest.mark.parametrize(("lift", "wall"), OUTLIER_CASES[1:])
def test_noisy_plane_as_good_as_the_contact_markers_alone(lift, wall):
    # 0.05 mm depth noise: the robust fit is as good as a least-squares fit to the true contact set.
    for seed in range(4):
        rng = np.random.default_rng(100 + seed)
        pts, n, contact = contact_scene(
            rng,
            alpha_deg=rng.uniform(5, 20),
            theta_deg=rng.uniform(0, 360),
            lift_fraction=lift,
            wall_fraction=wall,
            noise_mm=0.05,
        )
        fit = fit_plane_robust(pts, rng=seed)
        oracle = err_deg(fit_plane_svd(pts[contact]).normal, n)
        assert err_deg(fit.plane.normal, n) < oracle + 0.05
        assert err_deg(fit.plane.normal, n) < 0.1
        assert 0.1 < fit.threshold_mm < 0.2  # 2.5 sigma = 0.125 mm
        assert err_deg(fit_plane_svd(pts).normal, n) > 1.0


def test_small_set_with_exhaustive_hypotheses():
    # 12 markers (220 triples: all enumerated), the raised 4 lifted off.
    rng = np.random.default_rng(3)
    pts, n, contact = contact_scene(rng, alpha_deg=15, theta_deg=200, radius_mm=14, lift_fraction=0.34)
    assert len(pts) <= 13
    fit = fit_plane_robust(pts)
    assert fit.iterations == len(pts) * (len(pts) - 1) * (len(pts) - 2) // 6
    assert np.array_equal(fit.inliers, contact)
    assert err_deg(fit.plane.normal, n) < 1e-6


@pytest.mark.parametrize("n_side", [3, 5, 11])
def test_noise_only_keeps_every_point_and_matches_svd(n_side):
    # Bounded noise (uniform +-0.05 mm plus a 0.1 mm ripple): no point is an outlier.
    rng = np.random.default_rng(n_side)
    k = np.linspace(-30, 30, n_side)
    xy = np.stack(np.meshgrid(k, k), -1).reshape(-1, 2) + rng.uniform(-2, 2, (n_side**2, 2))
    n = normal_from_tilt(np.radians(12), np.radians(70))
    z = 2.0 - (xy @ n[:2]) / n[2] + rng.uniform(-0.05, 0.05, len(xy)) + 0.1 * np.sin(xy[:, 0] / 6.0)
    pts = np.column_stack([xy, z])
    fit = fit_plane_robust(pts)
    assert fit.n_inliers == len(pts) and fit.inliers.all()
    np.testing.assert_allclose(fit.plane.normal, fit_plane_svd(pts).normal, atol=1e-6)
    assert fit.threshold_mm >= 0.05


def test_given_threshold_is_used():
    rng = np.random.default_rng(5)
    pts, n, _ = contact_scene(rng, lift_fraction=0.3, wall_fraction=0.1, noise_mm=0.05)
    fit = fit_plane_robust(pts, threshold_mm=0.2)
    assert fit.threshold_mm == 0.2
    assert err_deg(fit.plane.normal, n) < 0.1
    assert isinstance(fit, RobustPlaneFit) and fit.n_inliers == int(fit.inliers.sum())


def test_one_sided_penalty_rejects_a_plane_below_contact_markers_in_its_footprint():
    # A flat face touching the top of the dome: a central patch of contact markers (40 %) on z = 0,
    # surrounded by a ring of displaced markers 0.8 mm lower (60 %, exaggeratedly coplanar). The ring's
    # plane has more support, but the patch lies above it inside its footprint: the part would have
    # to penetrate the membrane. Only the one-sided fit chooses the patch.
    xy = grid_disc(40.0)
    rng = np.random.default_rng(2)
    patch = np.hypot(xy[:, 0], xy[:, 1]) < 25.0
    z = np.where(patch, 0.0, -0.8) + rng.normal(0, 0.02, len(xy))
    pts = np.column_stack([xy, z])
    assert 0.35 < patch.mean() < 0.45
    two_sided = fit_plane_robust(pts, threshold_mm=0.1, one_sided=False)
    assert np.array_equal(two_sided.inliers, ~patch)
    one_sided = fit_plane_robust(pts, threshold_mm=0.1, one_sided=True)
    assert np.array_equal(one_sided.inliers, patch)


def test_deterministic_and_accepts_a_generator():
    rng = np.random.default_rng(7)
    pts, _, _ = contact_scene(rng, lift_fraction=0.4, wall_fraction=0.2, noise_mm=0.1)
    a, b = fit_plane_robust(pts, rng=11), fit_plane_robust(pts, rng=11)
    assert np.array_equal(a.inliers, b.inliers) and np.array_equal(a.plane.normal, b.plane.normal)
    assert a.threshold_mm == b.threshold_mm and a.iterations == b.iterations
    # an integer seed's triples are drawn once and sliced: the same as a generator drawing batches in turn
    c = fit_plane_robust(pts, rng=np.random.default_rng(11))
    assert np.array_equal(a.plane.normal, c.plane.normal) and np.array_equal(a.inliers, c.inliers)
    assert a.iterations == c.iterations


def test_adaptive_iterations_stay_small():
    rng = np.random.default_rng(8)
    pts, _, _ = contact_scene(rng, lift_fraction=0.3, noise_mm=0.05)
    assert fit_plane_robust(pts).iterations <= 128  # 70 % inliers: ~17 needed, at least 100 drawn
    assert fit_plane_robust(pts, max_iterations=10).iterations == 10


# -------------------------------------------------------------------------------------- errors


@pytest.mark.exceptions
@pytest.mark.parametrize(
    "points",
    [np.zeros((2, 3)), np.zeros((5, 2)), np.array([[0, 0, 0], [1, 0, np.nan], [0, 1, 0.0]])],
)
def test_bad_points_raise(points):
    with pytest.raises(InputError):
        fit_plane_robust(points)


@pytest.mark.exceptions
def test_collinear_points_raise():
    pts = np.column_stack([np.arange(6.0), 2 * np.arange(6.0), np.zeros(6)])
    with pytest.raises(InputError, match="line"):
        fit_plane_robust(pts)


@pytest.mark.exceptions
def test_too_few_inliers_names_the_counts():
    rng = np.random.default_rng(9)
    pts, _, _ = contact_scene(rng, lift_fraction=0.33, noise_mm=0.02)
    with pytest.raises(InputError, match=r"at least 70 inliers.*of 81"):
        fit_plane_robust(pts, min_inliers=70)
    with pytest.raises(InputError, match="at least 200"):
        fit_plane_robust(pts, min_inliers=200)


@pytest.mark.exceptions
@pytest.mark.parametrize("threshold", [0.0, -1.0, float("nan")])
def test_bad_threshold_raises(threshold):
    with pytest.raises(InputError, match="threshold_mm"):
        fit_plane_robust(np.random.default_rng(0).normal(size=(10, 3)), threshold_mm=threshold)


@pytest.mark.parametrize("noise_mm", [0.0, 0.05, 0.2])
@pytest.mark.parametrize("one_sided", [True, False])
def test_candidate_choice_is_the_numpy_oracle(noise_mm, one_sided):
    """The compiled choice of the best refined candidate against the same steps with NumPy's SVD and Qhull:
    the same inliers, residuals to 1e-9 mm, on scenes with lift-off and wall markers."""
    rng = np.random.default_rng(11)
    for case in range(8):
        pts, _, _ = contact_scene(
            rng, radius_mm=rng.uniform(20, 40), lift_fraction=0.3, wall_fraction=0.2, noise_mm=noise_mm
        )
        centred = pts - pts.mean(axis=0)
        t = 0.3
        draw = robust._triple_source(case, len(centred), 1000)
        normals, offsets, _ = robust._hypotheses(centred, draw, t, 1000)
        args = (t, robust._CANDIDATE_POOL, robust._N_CANDIDATES, robust._SAME_SET_JACCARD, one_sided)
        tail = (robust._MAX_REFINE_ROUNDS, robust._ABOVE_PENALTY)
        found, mask, residuals = best_candidate(centred, normals, offsets, *args, *tail)
        expected = oracle_best_candidate(centred, normals, offsets, *args, *tail)
        assert found and expected is not None
        assert_array_equal(mask, expected[0])
        assert_allclose(residuals, expected[1], rtol=0, atol=1e-9)
