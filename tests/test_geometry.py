"""Poses, tilt angles and the SVD plane fit against hand-computed cases."""

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from numpy.testing import assert_allclose

from softjig.errors import InputError
from softjig.geometry import (
    angle_between,
    fit_plane_svd,
    invert_pose,
    normal_from_tilt,
    normal_from_tilt_angles,
    pose_from_rotvec_translation,
    rotation_from_tilt,
    tilt_angles,
    transform_points,
)


def test_pose_inverse_round_trip():
    rng = np.random.default_rng(0)
    T = pose_from_rotvec_translation(rng.normal(size=3), rng.normal(size=3) * 10)
    assert np.allclose(invert_pose(T) @ T, np.eye(4), atol=1e-12)
    p = rng.normal(size=(5, 3))
    assert np.allclose(transform_points(invert_pose(T), transform_points(T, p)), p)


def test_tilt_angles_hand_computed():
    # Tilt of 10 deg towards +x: rotation about +y by 10 deg: Ay = 10 deg, Ax = 0.
    ax, ay = tilt_angles(normal_from_tilt(np.radians(10), 0.0))
    assert ax == pytest.approx(0.0, abs=1e-15) and np.degrees(ay) == pytest.approx(10.0)
    # Towards +y: the normal leans to +y, a rotation about x by -10 deg: Ax = atan2(-n_y, n_z) = -10 deg.
    ax, ay = tilt_angles(normal_from_tilt(np.radians(10), np.pi / 2))
    assert np.degrees(ax) == pytest.approx(-10.0) and ay == pytest.approx(0.0, abs=1e-15)


def test_tilt_sweep_is_a_sine_of_amplitude_alpha():
    thetas = np.radians(np.arange(0, 360, 10))
    n = np.array([normal_from_tilt(np.radians(15), t) for t in thetas])
    ax, ay = tilt_angles(n)
    assert np.degrees(np.max(np.abs(ay))) == pytest.approx(15.0)
    assert np.degrees(np.max(np.abs(ax))) == pytest.approx(15.0)
    assert np.mean(ax) == pytest.approx(0, abs=1e-12) and np.mean(ay) == pytest.approx(0, abs=1e-12)


@given(st.floats(0, 1.2), st.floats(-np.pi, np.pi))
def test_rotation_from_tilt_maps_z_to_normal(alpha, theta):
    n = normal_from_tilt(alpha, theta)
    assert np.allclose(rotation_from_tilt(alpha, theta) @ [0, 0, 1], n, atol=1e-12)
    assert np.allclose(normal_from_tilt_angles(*tilt_angles(n)), n, atol=1e-12)
    assert angle_between(n, [0, 0, 1]) == pytest.approx(alpha, abs=1e-9)


def test_plane_fit_exact_and_noisy():
    rng = np.random.default_rng(1)
    n_true = normal_from_tilt(np.radians(12), np.radians(40))
    xy = rng.uniform(-20, 20, (200, 2))
    z = 25.0 - (n_true[0] * xy[:, 0] + n_true[1] * xy[:, 1]) / n_true[2]
    pts = np.column_stack([xy, z])
    fit = fit_plane_svd(pts)
    assert np.allclose(fit.normal, n_true, atol=1e-12)
    assert fit.z_at(0, 0) == pytest.approx(25.0)
    assert fit.rms_residual_mm < 1e-12 and fit.n_points == 200
    noisy = fit_plane_svd(pts + rng.normal(0, 0.05, pts.shape))
    assert np.degrees(angle_between(noisy.normal, n_true)) < 0.1
    assert 0.03 < noisy.rms_residual_mm < 0.06


def test_plane_fit_normal_points_up_whatever_the_order():
    pts = np.array([[0, 0, 0], [0, 1, 0], [1, 0, 0.0], [1, 1, 0.0]])
    assert fit_plane_svd(pts).normal[2] == pytest.approx(1.0)
    assert fit_plane_svd(pts[::-1]).normal[2] == pytest.approx(1.0)


@pytest.mark.parametrize(
    ("points", "message"),
    [
        (np.zeros((2, 3)), "at least 3"),
        (np.zeros((5, 2)), r"\(N, 3\)"),
        (np.array([[0, 0, 0], [1, 1, 1], [2, 2, 2], [3, 3, 3.0]]), "line or a point"),
        (np.array([[0, 0, 0], [1, 0, 0], [0, 1, np.nan]]), "non-finite"),
        (np.array([[0, 0, 0], [0, 0, 1], [1, 0, 0], [1, 0, 1.0]]), "vertical"),
    ],
)
def test_plane_fit_errors(points, message):
    with pytest.raises(InputError, match=message):
        fit_plane_svd(points)


def test_rotation_from_rotvec_is_scipys():
    """The closed-form Rodrigues rotation (no scipy.spatial import: 0.3 s of start-up) equals SciPy's."""
    from scipy.spatial.transform import Rotation

    from softjig.geometry import rotation_from_rotvec

    rng = np.random.default_rng(0)
    for scale in (0.0, 1e-9, 1e-5, 1e-4, 1e-3, 0.5, 3.0, np.pi):
        for _ in range(20):
            v = rng.normal(size=3)
            v *= scale / max(np.linalg.norm(v), 1e-300)
            expected = Rotation.from_rotvec(v).as_matrix()
            np.testing.assert_allclose(rotation_from_rotvec(v), expected, atol=2e-15)


@pytest.mark.parametrize("width_mm", [1e-3, 1e-5, 1e-7])
def test_plane_fit_of_a_thin_strip_is_the_svd(width_mm):
    """Points along a 40 mm strip 2 um to 0.2 nm wide, on a tilted plane: the same normal, largest
    singular values and RMS as NumPy's SVD of the centred points (below 1e-6 of the largest singular
    value the fit takes the SVD itself: the scatter matrix has lost the small ones' precision)."""
    rng = np.random.default_rng(4)
    n_true = normal_from_tilt(np.radians(20), np.radians(-30))
    xy = np.column_stack([rng.uniform(-20, 20, 50), rng.uniform(-width_mm, width_mm, 50)])
    z = 3.0 - (n_true[0] * xy[:, 0] + n_true[1] * xy[:, 1]) / n_true[2] + rng.normal(0, 1e-3 * width_mm, 50)
    pts = np.column_stack([xy, z])
    fit = fit_plane_svd(pts)
    _, s, vt = np.linalg.svd(pts - pts.mean(axis=0), full_matrices=False)
    expected = vt[2] * np.sign(vt[2, 2])
    assert_allclose(fit.singular_values[:2], s[:2], rtol=1e-6)
    assert_allclose(fit.normal, expected, atol=1e-6)
    assert fit.rms_residual_mm == pytest.approx(s[2] / np.sqrt(len(pts)), rel=1e-6)


def test_importing_geometry_does_not_load_numba():
    """Poses and tilt angles are used everywhere (the config, the CLI): the compiled plane fit and hull
    test are loaded when first called, not when geometry is imported."""
    import subprocess
    import sys

    code = (
        "import sys, softjig.geometry as g, numpy as np\n"
        "assert 'numba' not in sys.modules, 'numba loaded on import'\n"
        "g.fit_plane_svd(np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0.1]]))\n"
        "assert 'numba' in sys.modules\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True)
