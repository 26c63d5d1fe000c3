"""Tests of softjig.optics: refraction through the flat layers, projection and back-projection."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from softjig.optics import (
    FlatLayers,
    backproject_pixels,
    camera_center_J,
    distort_normalized,
    jacobian_stencil,
    point_on_ray_at_z,
    project_point_sets,
    project_points,
    projection_jacobian,
    rays_in_top_region,
    refract_directions,
    refracted_ray_directions,
    stencil_jacobian,
    trace_rays_through_layers,
    undistort_normalized,
)

K = np.array([[925.0, 0.0, 639.5], [0.0, 925.0, 359.5], [0.0, 0.0, 1.0]])
LAYERS = FlatLayers((-5.0, 0.0), (1.0, 1.575, 1.51))
DIST = np.array([0.02, -0.01, 0.001, -0.0008, 0.0])


def pose(center, rvec=(0.0, 0.0, 0.0)) -> np.ndarray:
    """T_J_cam with the given centre (J, mm) and rotation vector (camera axes -> J)."""
    T = np.eye(4)
    T[:3, :3] = cv2.Rodrigues(np.asarray(rvec, dtype=float))[0]
    T[:3, 3] = center
    return T


T_LEFT = pose((-15.0, 0.0, -155.0))
T_RIGHT = pose((15.0, 0.0, -155.0))


def cv2_project(points_J, T_J_cam, dist) -> np.ndarray:
    T_cam_J = np.linalg.inv(T_J_cam)
    rvec = cv2.Rodrigues(T_cam_J[:3, :3])[0]
    uv, _ = cv2.projectPoints(
        np.asarray(points_J, dtype=float).reshape(-1, 1, 3),
        rvec,
        T_cam_J[:3, 3],
        K,
        np.asarray(dist, dtype=float),
    )
    return uv.reshape(-1, 2)


def trace_to_points(c, d0, points, layers):
    """Trace from c with initial directions d0 up to each point's region.

    Returns the distance of each point from the last ray segment and the ray invariant
    n_i sin(theta_i) of every region crossed (NaN where not crossed), shape (N, R).
    """
    z_if = np.asarray(layers.interfaces_z_mm)
    n = np.asarray(layers.refractive_indices)
    N = points.shape[0]
    o = np.broadcast_to(c, (N, 3)).astype(float).copy()
    d = d0 / np.linalg.norm(d0, axis=1)[:, None]
    kappa = np.full((N, n.size), np.nan)
    kappa[:, 0] = n[0] * np.hypot(d[:, 0], d[:, 1])
    for k, zk in enumerate(z_if):
        m = points[:, 2] > zk
        if not np.any(m):
            break
        s = (zk - o[m, 2]) / d[m, 2]
        o[m] = o[m] + s[:, None] * d[m]
        d[m] = refract_directions(d[m], n[k], n[k + 1])
        kappa[m, k + 1] = n[k + 1] * np.hypot(d[m, 0], d[m, 1])
    v = points - o
    perp = v - np.sum(v * d, axis=1)[:, None] * d
    return np.linalg.norm(perp, axis=1), kappa


def dist_point_to_rays(points, origins, directions) -> np.ndarray:
    v = points - origins
    perp = v - np.sum(v * directions, axis=1)[:, None] * directions
    return np.linalg.norm(perp, axis=1)


# ---------------------------------------------------------------------------------------------
# FlatLayers
# ---------------------------------------------------------------------------------------------
def test_flat_layers_normalises_and_defaults():
    layers = FlatLayers([-5, 0], [1, 1.575, 1.51])
    assert layers.interfaces_z_mm == (-5.0, 0.0)
    assert layers.refractive_indices == (1.0, 1.575, 1.51)
    assert FlatLayers.plate_under_oil() == LAYERS
    assert layers.n_regions == 3
    np.testing.assert_array_equal(layers.region_of_z([-10, -5, -1, 0, 3]), [0, 0, 1, 1, 2])


@pytest.mark.parametrize(
    ("z", "n", "match"),
    [
        ((), (1.0,), "at least one"),
        ((-5.0, 0.0), (1.0, 1.5), "refractive indices"),
        ((0.0, -5.0), (1.0, 1.5, 1.5), "ascending"),
        ((0.0, 0.0), (1.0, 1.5, 1.5), "ascending"),
        ((-5.0, 0.0), (1.0, 0.9, 1.5), ">= 1"),
        ((-5.0, np.nan), (1.0, 1.5, 1.5), "finite"),
        ((-5.0, 0.0), (1.0, np.inf, 1.5), "finite"),
        (("a", 0.0), (1.0, 1.5, 1.5), "numbers"),
    ],
)
def test_flat_layers_validation(z, n, match):
    with pytest.raises(ValueError, match=match):
        FlatLayers(z, n)


# ---------------------------------------------------------------------------------------------
# Vector Snell and helpers
# ---------------------------------------------------------------------------------------------
def test_refract_directions_snell_and_normal_orientation():
    rng = np.random.default_rng(0)
    d = rng.normal(size=(200, 3))
    d[:, 2] = np.abs(d[:, 2]) + 0.1
    for normal in [(0, 0, 1), (0, 0, -1), (0, 0, 7)]:
        t = refract_directions(d, 1.0, 1.5, normal)
        np.testing.assert_allclose(np.linalg.norm(t, axis=1), 1.0, atol=1e-15)
        du = d / np.linalg.norm(d, axis=1)[:, None]
        np.testing.assert_allclose(
            1.0 * np.hypot(du[:, 0], du[:, 1]), 1.5 * np.hypot(t[:, 0], t[:, 1]), atol=1e-14
        )
        assert np.all(t[:, 2] > 0)  # stays on the far side
        # plane of incidence kept: the horizontal components are parallel
        np.testing.assert_allclose(du[:, 0] * t[:, 1] - du[:, 1] * t[:, 0], 0.0, atol=1e-15)
    np.testing.assert_allclose(refract_directions(d, 1.3, 1.3), du, atol=1e-15)
    np.testing.assert_array_equal(refract_directions([0.0, 0.0, 2.0], 1.0, 1.5), [0, 0, 1])


def test_refract_directions_general_normal_matches_rotated_case():
    rng = np.random.default_rng(0)
    R = cv2.Rodrigues(np.array([0.3, -0.2, 0.5]))[0]
    d = rng.normal(size=(50, 3))
    d[:, 2] = np.abs(d[:, 2]) + 0.2
    t_ref = refract_directions(d, 1.0, 1.4)
    t_rot = refract_directions(d @ R.T, 1.0, 1.4, R @ np.array([0.0, 0.0, 1.0]))
    np.testing.assert_allclose(t_rot, t_ref @ R.T, atol=1e-14)


def test_refract_directions_total_internal_reflection_and_grazing():
    steep = np.array([[np.sin(0.9), 0.0, np.cos(0.9)]])  # 51.6 deg > asin(1/1.5) = 41.8 deg
    with pytest.raises(ValueError, match="total internal reflection"):
        refract_directions(steep, 1.5, 1.0)
    refract_directions(steep, 1.0, 1.5)  # fine the other way
    with pytest.raises(ValueError, match="parallel"):
        refract_directions([[1.0, 0.0, 0.0]], 1.0, 1.5)
    with pytest.raises(ValueError, match="normal"):
        refract_directions(steep, 1.0, 1.5, (0, 0, 0))


def test_point_on_ray_at_z_and_camera_center():
    o = np.array([[1.0, 2.0, -10.0], [0.0, 0.0, 0.0]])
    d = np.array([[1.0, 0.0, 2.0], [0.0, -1.0, -1.0]])
    np.testing.assert_allclose(point_on_ray_at_z(o, d, 0.0), [[6.0, 2.0, 0.0], [0.0, 0.0, 0.0]])
    np.testing.assert_allclose(point_on_ray_at_z(o, d, [2.0, -3.0]), [[7, 2, 2], [0, -3, -3]])
    with pytest.raises(ValueError, match="horizontal"):
        point_on_ray_at_z(o, [[1.0, 0.0, 0.0], [0.0, 1.0, 1.0]], 0.0)
    np.testing.assert_array_equal(camera_center_J(T_LEFT), [-15.0, 0.0, -155.0])


# ---------------------------------------------------------------------------------------------
# Solving the refracted path
# ---------------------------------------------------------------------------------------------
def random_points(rng, n=500):
    return np.column_stack([rng.uniform(-90, 90, n), rng.uniform(-90, 90, n), rng.uniform(-4.99, 40, n)])


@pytest.mark.parametrize(
    "layers",
    [
        LAYERS,
        FlatLayers((-5.0, 0.0), (1.0, 1.0, 1.0)),
        FlatLayers((-5.0, 0.0), (1.0, 1.575, 1.575)),
        # an index lower than the camera medium's, and a lower-index layer in the middle
        FlatLayers((-20.0, -5.0, 0.0, 10.0), (1.33, 1.0, 1.6, 1.2, 1.51)),
    ],
)
def test_snell_holds_and_path_reaches_point(layers):
    rng = np.random.default_rng(0)
    c = np.array([-15.0, 0.0, -155.0])
    pts = random_points(rng)
    pts[:5] = [
        [-15.0, 0.0, 20.0],
        [60.0, 0.0, 0.0],
        [0.0, 0.0, -5.0],
        [800.0, 300.0, 40.0],
        [-15.0, 1e-9, 0.5],
    ]
    d0 = refracted_ray_directions(c, pts, layers)
    np.testing.assert_allclose(np.linalg.norm(d0, axis=1), 1.0, atol=1e-15)
    miss, kappa = trace_to_points(c, d0, pts, layers)
    assert np.max(miss) < 1e-9
    crossed = np.isfinite(kappa)
    assert np.all(crossed[:, 0])
    reference = np.broadcast_to(kappa[:, :1], kappa.shape)
    np.testing.assert_allclose(kappa[crossed], reference[crossed], rtol=1e-12, atol=1e-14)


def test_forward_trace_through_oil_ray():
    """The oil ray from trace_rays_through_layers passes through the point (< 1e-9 mm)."""
    rng = np.random.default_rng(0)
    c = np.array([-15.0, 0.0, -155.0])
    pts = random_points(rng)
    pts[:, 2] = np.abs(pts[:, 2])
    d0 = refracted_ray_directions(c, pts, LAYERS)
    o, d = trace_rays_through_layers(np.broadcast_to(c, pts.shape), d0, LAYERS)
    np.testing.assert_allclose(o[:, 2], 0.0, atol=0)
    assert np.max(dist_point_to_rays(pts, o, d)) < 1e-9


def test_vertical_path_is_exact():
    d = refracted_ray_directions([3.0, -2.0, -155.0], [[3.0, -2.0, 0.0], [3.0, -2.0, 37.5]], LAYERS)
    np.testing.assert_array_equal(d, [[0.0, 0.0, 1.0], [0.0, 0.0, 1.0]])


def test_points_in_camera_medium_are_straight_lines():
    c = np.array([-15.0, 0.0, -155.0])
    pts = np.array([[0.0, 0.0, -5.0], [10.0, 3.0, -100.0], [0.0, 0.0, -300.0]])
    rel = pts - c
    np.testing.assert_allclose(
        refracted_ray_directions(c, pts, LAYERS), rel / np.linalg.norm(rel, axis=1)[:, None]
    )


def test_refracted_ray_directions_validation():
    with pytest.raises(ValueError, match="region 0"):
        refracted_ray_directions([0.0, 0.0, -5.0], [[0.0, 0.0, 10.0]], LAYERS)
    with pytest.raises(ValueError, match="region 0"):
        refracted_ray_directions([0.0, 0.0, 1.0], [[0.0, 0.0, 10.0]], LAYERS)
    with pytest.raises(ValueError, match="coincides"):
        refracted_ray_directions([0.0, 0.0, -50.0], [[0.0, 0.0, -50.0]], LAYERS)
    with pytest.raises(ValueError, match="shape"):
        refracted_ray_directions([0.0, 0.0, -50.0], [[0.0, 0.0]], LAYERS)
    with pytest.raises(ValueError, match="finite"):
        refracted_ray_directions([0.0, 0.0, -50.0], [[0.0, np.nan, 1.0]], LAYERS)


# ---------------------------------------------------------------------------------------------
# Projection
# ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize("dist", [np.zeros(5), DIST, np.array([-0.05, 0.01, 0.002, 0.001, -0.003])])
def test_equal_indices_match_plain_pinhole(dist):
    rng = np.random.default_rng(0)
    layers = FlatLayers((-5.0, 0.0), (1.0, 1.0, 1.0))
    T = pose((-15.0, 2.0, -155.0), (0.02, -0.015, 0.03))
    pts = random_points(rng, 1000)
    uv = project_points(pts, K, dist, T, layers)
    np.testing.assert_allclose(uv, cv2_project(pts, T, dist), atol=1e-9, rtol=0)


def test_distortion_formula_matches_cv2():
    rng = np.random.default_rng(0)
    xy = rng.uniform(-0.6, 0.6, size=(300, 2))
    for dist in [DIST, np.array([0.1, -0.05, 0.003, -0.002, 0.01]), DIST[:4]]:
        uv_cv, _ = cv2.projectPoints(
            np.column_stack([xy, np.ones(len(xy))]).reshape(-1, 1, 3),
            np.zeros(3),
            np.zeros(3),
            np.eye(3),
            dist,
        )
        np.testing.assert_allclose(distort_normalized(xy, dist), uv_cv.reshape(-1, 2), atol=1e-14)


def test_undistort_inverts_distortion_and_agrees_with_cv2():
    rng = np.random.default_rng(0)
    xy = rng.uniform(-0.7, 0.7, size=(300, 2))
    dist = np.array([0.1, -0.05, 0.003, -0.002, 0.01])
    xyd = distort_normalized(xy, dist)
    np.testing.assert_allclose(undistort_normalized(xyd, dist), xy, atol=1e-14)
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-15)
    ref = cv2.undistortPoints(xyd.reshape(-1, 1, 2), np.eye(3), dist, None, None, None, crit)
    np.testing.assert_allclose(undistort_normalized(xyd, dist), ref.reshape(-1, 2), atol=1e-7)
    np.testing.assert_array_equal(undistort_normalized(xyd, None), xyd)


def test_shapes_are_preserved():
    p = np.array([1.0, 2.0, 10.0])
    assert project_points(p, K, None, T_LEFT, LAYERS).shape == (2,)
    grid = np.zeros((4, 5, 3))
    grid[..., 2] = 10.0
    uv = project_points(grid, K, DIST, T_LEFT, LAYERS)
    assert uv.shape == (4, 5, 2)
    o, d = backproject_pixels(uv, K, DIST, T_LEFT, LAYERS)
    assert o.shape == d.shape == (4, 5, 3)
    assert projection_jacobian(grid, K, DIST, T_LEFT, LAYERS).shape == (4, 5, 2, 3)
    assert project_points(np.zeros((0, 3)), K, DIST, T_LEFT, LAYERS).shape == (0, 2)


def test_project_backproject_round_trip_seeded():
    rng = np.random.default_rng(0)
    pts = random_points(rng, 1000)
    pts[:, 2] = np.abs(pts[:, 2])
    T = pose((-15.0, 0.0, -155.0), (0.01, -0.012, 0.005))
    uv = project_points(pts, K, DIST, T, LAYERS)
    o, d = backproject_pixels(uv, K, DIST, T, LAYERS)
    assert np.max(dist_point_to_rays(pts, o, d)) < 1e-9
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-15)
    np.testing.assert_allclose(o[:, 2], 0.0, atol=0)


rot_strategy = st.tuples(
    st.floats(-1, 1), st.floats(-1, 1), st.floats(-1, 1), st.floats(0.0, np.deg2rad(1.0))
)
dist_strategy = st.one_of(
    st.just((0.0, 0.0, 0.0, 0.0, 0.0)),
    st.tuples(
        st.floats(-0.05, 0.05),
        st.floats(-0.02, 0.02),
        st.floats(-0.002, 0.002),
        st.floats(-0.002, 0.002),
        st.just(0.0),
    ),
)


@settings(max_examples=300, deadline=None, derandomize=True)
@given(
    x=st.floats(-89.9, 89.9),
    y=st.floats(-89.9, 89.9),
    z=st.floats(0.0, 40.0),
    rot=rot_strategy,
    dist=dist_strategy,
    right=st.booleans(),
)
def test_round_trip_property(x, y, z, rot, dist, right):
    axis = np.array(rot[:3])
    norm = np.linalg.norm(axis)
    rvec = axis / norm * rot[3] if norm > 1e-6 else np.zeros(3)
    T = pose((15.0 if right else -15.0, 0.0, -155.0), rvec)
    p = np.array([[x, y, z]])
    uv = project_points(p, K, dist, T, LAYERS)
    o, d = backproject_pixels(uv, K, dist, T, LAYERS)
    assert dist_point_to_rays(p, o, d)[0] < 1e-6
    q = point_on_ray_at_z(o, d, z + 15.0)
    uv2 = project_points(q, K, dist, T, LAYERS)
    assert np.max(np.abs(uv2 - uv)) < 1e-6


def test_camera_looking_down_or_point_behind_raises():
    with pytest.raises(ValueError, match="behind the camera"):
        project_points([[-15.0, 0.0, -200.0]], K, None, T_LEFT, LAYERS)
    T_down = pose((-15.0, 0.0, -155.0), (np.pi, 0.0, 0.0))  # optical axis along -z of J
    with pytest.raises(ValueError, match="behind the camera"):
        project_points([[0.0, 0.0, 10.0]], K, None, T_down, LAYERS)
    with pytest.raises(ValueError, match="upwards"):
        backproject_pixels([[639.5, 359.5]], K, None, T_down, LAYERS)


def test_camera_above_interface_raises():
    T_up = pose((0.0, 0.0, -2.0))
    with pytest.raises(ValueError, match="region 0"):
        project_points([[0.0, 0.0, 10.0]], K, None, T_up, LAYERS)
    with pytest.raises(ValueError, match="region 0"):
        backproject_pixels([[639.5, 359.5]], K, None, T_up, LAYERS)


def test_bad_camera_parameters_raise():
    p = [[0.0, 0.0, 10.0]]
    with pytest.raises(ValueError, match="4x4"):
        project_points(p, K, None, np.eye(3), LAYERS)
    bad_T = T_LEFT.copy()
    bad_T[:3, :3] *= 2.0
    with pytest.raises(ValueError, match="rotation"):
        project_points(p, K, None, bad_T, LAYERS)
    with pytest.raises(ValueError, match="3x3"):
        project_points(p, K[:2], None, T_LEFT, LAYERS)
    with pytest.raises(ValueError, match="focal"):
        project_points(p, np.diag([-1.0, 1.0, 1.0]), None, T_LEFT, LAYERS)
    with pytest.raises(ValueError, match="dist"):
        project_points(p, K, [0.1, 0.2, 0.3], T_LEFT, LAYERS)
    with pytest.raises(ValueError, match="dist"):
        project_points(p, K, [0.1, 0.0, 0.0, 0.0, 0.0, 0.5, 0.0, 0.0], T_LEFT, LAYERS)
    # trailing zero rational terms are fine
    project_points(p, K, [0.1, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0], T_LEFT, LAYERS)


def test_backproject_total_internal_reflection_raises():
    # cameras in water (1.33) under an air gap: steep rays are totally reflected
    layers = FlatLayers((-20.0, 0.0), (1.33, 1.0, 1.51))
    with pytest.raises(ValueError, match="total internal reflection"):
        backproject_pixels([[639.5 + 925.0 * 1.5, 359.5]], K, None, T_LEFT, layers)
    backproject_pixels([[639.5 + 925.0 * 0.5, 359.5]], K, None, T_LEFT, layers)


# ---------------------------------------------------------------------------------------------
# Apparent depth
# ---------------------------------------------------------------------------------------------
def effective_depth(z):
    return 150.0 + 5.0 / 1.575 + z / 1.51


@pytest.mark.parametrize("z", [0.0, 10.0, 20.0, 30.0, 40.0])
def test_stereo_disparity_matches_paraxial_apparent_depth(z):
    p = np.array([[0.0, 0.0, z]])
    disparity = (project_points(p, K, None, T_LEFT, LAYERS) - project_points(p, K, None, T_RIGHT, LAYERS))[0]
    assert disparity[1] == pytest.approx(0.0, abs=1e-12)
    expected = 925.0 * 30.0 / effective_depth(z)
    assert disparity[0] == pytest.approx(expected, rel=5e-3)
    no_refraction = 925.0 * 30.0 / (155.0 + z)
    assert disparity[0] > no_refraction  # refraction makes the point look closer
    if z >= 30.0:
        assert abs(disparity[0] / no_refraction - 1.0) > 0.05


@pytest.mark.parametrize("z", [0.0, 20.0, 40.0])
def test_near_axis_offset_is_paraxial(z):
    delta = 1e-3
    uv = project_points([[-15.0 + delta, 2 * delta, z]], K, None, T_LEFT, LAYERS)[0]
    np.testing.assert_allclose(
        uv - K[:2, 2], 925.0 * np.array([delta, 2 * delta]) / effective_depth(z), rtol=1e-6
    )


# ---------------------------------------------------------------------------------------------
# Jacobian
# ---------------------------------------------------------------------------------------------
def test_projection_jacobian_equal_indices_is_pinhole_jacobian():
    rng = np.random.default_rng(0)
    layers = FlatLayers((-5.0, 0.0), (1.0, 1.0, 1.0))
    pts = random_points(rng, 50)
    jac = projection_jacobian(pts, K, None, T_LEFT, layers)
    pc = pts - T_LEFT[:3, 3]
    x, y, zc = pc.T
    expected = np.zeros((50, 2, 3))
    expected[:, 0, 0] = 925.0 / zc
    expected[:, 0, 2] = -925.0 * x / zc**2
    expected[:, 1, 1] = 925.0 / zc
    expected[:, 1, 2] = -925.0 * y / zc**2
    np.testing.assert_allclose(jac, expected, atol=1e-7)


def test_projection_jacobian_linearises_projection():
    rng = np.random.default_rng(0)
    pts = random_points(rng, 100)
    pts[:, 2] = np.abs(pts[:, 2]) + 0.5
    jac = projection_jacobian(pts, K, DIST, T_LEFT, LAYERS)
    step = rng.normal(scale=0.01, size=pts.shape)
    duv = project_points(pts + step, K, DIST, T_LEFT, LAYERS) - project_points(pts, K, DIST, T_LEFT, LAYERS)
    np.testing.assert_allclose(np.einsum("nij,nj->ni", jac, step), duv, atol=1e-5)
    with pytest.raises(ValueError, match="step_mm"):
        projection_jacobian(pts, K, DIST, T_LEFT, LAYERS, step_mm=0.0)


def test_point_sets_project_exactly_as_one_call_per_set():
    """Sets solved together give each set's pixels bit for bit as a call of its own (an iterate that
    converged still moves by an ulp: each set stops when its own points converged), whatever else is in
    the solve: points in the air, on an interface, on the axis, and an empty set."""
    rng = np.random.default_rng(3)
    cameras = [
        (K, DIST, T_LEFT),
        (K, None, T_RIGHT),
        (K, None, pose((20.0, 5.0, -140.0), (0.02, -0.03, 0.01))),
    ]
    sets = [
        (random_points(rng, 400), 0),
        (np.array([[0.0, 0.0, 18.0]]), 1),
        (np.array([[-15.0, 0.0, 10.0], [3.0, 1.0, 0.0], [2.0, -4.0, -50.0]]), 0),
        (np.zeros((0, 3)), 1),
        (random_points(rng, 7).reshape(7, 1, 3), 2),
    ]
    together = project_point_sets(sets, cameras, LAYERS)
    for (points, camera), pixels in zip(sets, together, strict=True):
        alone = project_points(points, *cameras[camera], LAYERS)
        assert pixels.shape == alone.shape == (*np.shape(points)[:-1], 2)
        assert np.array_equal(pixels, alone)
    # two points converging before the 400 of the other set (solved to the end, they would move by an ulp)
    rng = np.random.default_rng(3)
    few, many = (random_points(rng, 2), 0), (random_points(rng, 400), 1)
    left_right = [(K, None, T_LEFT), (K, None, T_RIGHT)]
    assert np.array_equal(
        project_point_sets([few, many], left_right, LAYERS)[0], project_points(few[0], *left_right[0], LAYERS)
    )
    with pytest.raises(ValueError, match="behind the camera"):
        project_point_sets([sets[0], ([[-15.0, 0.0, -200.0]], 0)], cameras, LAYERS)
    with pytest.raises(ValueError, match="region 0"):
        project_point_sets([sets[1]], [*cameras, (K, None, pose((0.0, 0.0, -2.0)))], LAYERS)
    for camera in (-1, 3, 1.0, True):  # -1 took the last camera
        with pytest.raises(ValueError, match=r"camera must be an index in 0\.\.2"):
            project_point_sets([(sets[1][0], camera)], cameras, LAYERS)


def test_jacobian_stencil_gives_the_projection_jacobian():
    rng = np.random.default_rng(4)
    pts = random_points(rng, 20)
    stencil = jacobian_stencil(pts, 2e-3)
    assert stencil.shape == (120, 3)
    jac = stencil_jacobian(project_points(stencil, K, DIST, T_LEFT, LAYERS), 2e-3)
    assert np.array_equal(jac, projection_jacobian(pts, K, DIST, T_LEFT, LAYERS, step_mm=2e-3))
    with pytest.raises(ValueError, match="step_mm"):
        jacobian_stencil(pts, -1.0)


# ---------------------------------------------------------------------------------------------
# Closed-form back-projection (the fast path) against the traced one


@pytest.mark.parametrize(
    "layers",
    [
        LAYERS,
        FlatLayers((0.0,), (1.0, 1.51)),
        FlatLayers((-8.0, -5.0, 0.0), (1.0003, 1.49, 1.575, 1.33)),
        FlatLayers((-5.0, 0.0), (1.0, 1.0, 1.0)),
    ],
)
def test_closed_form_backprojection_matches_the_traced_one(layers):
    rng = np.random.default_rng(1)
    uv = rng.uniform([-200, -100], [1480, 820], (500, 2))
    K_skewed = K.copy()
    K_skewed[0, 1] = 0.7
    for k, dist in ((K, None), (K, DIST), (K_skewed, DIST)):
        T = pose((-15.0, 2.0, -155.0), (0.02, -0.03, 0.4))
        o_ref, d_ref = backproject_pixels(uv, k, dist, T, layers)
        o, d = rays_in_top_region(uv, k, dist, T, layers)
        np.testing.assert_allclose(o, o_ref, rtol=0, atol=1e-10)
        np.testing.assert_allclose(d, d_ref, rtol=0, atol=1e-13)
    o, d = rays_in_top_region(uv.reshape(20, 25, 2), K, None, T_LEFT, layers)
    assert o.shape == d.shape == (20, 25, 3)


def test_closed_form_backprojection_raises_like_the_traced_one():
    T_down = pose((-15.0, 0.0, -155.0), (np.pi, 0.0, 0.0))
    with pytest.raises(ValueError, match="upwards"):
        rays_in_top_region([[639.5, 359.5]], K, None, T_down, LAYERS)
    with pytest.raises(ValueError, match="region 0"):
        rays_in_top_region([[639.5, 359.5]], K, None, pose((0.0, 0.0, -2.0)), LAYERS)
    layers = FlatLayers((-20.0, 0.0), (1.33, 1.0, 1.51))
    with pytest.raises(ValueError, match="total internal reflection"):
        rays_in_top_region([[639.5 + 925.0 * 1.5, 359.5]], K, None, T_LEFT, layers)
    rays_in_top_region([[639.5 + 925.0 * 0.5, 359.5]], K, None, T_LEFT, layers)
