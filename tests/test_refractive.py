"""Refractive triangulation, marker identities and the contact footprint, against analytic truth."""

from dataclasses import replace

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from oracles.nearest_identities import kd_tree_identities
from oracles.refracted_rays import traced_triangulation
from softjig.config import default_jig, exact_jig
from softjig.errors import InputError
from softjig.geometry import angle_between, fit_plane_svd, normal_from_tilt
from softjig.jig_shape import marker_layout_xy, rest_inner_height_mm
from softjig.optics import project_points
from softjig.rig import flat_layers
from softjig.sensing.contact import contact_candidates, describe_contact, indentation
from softjig.sensing.identities import ReferenceMarkers, identify_markers, rest_shape_reference
from softjig.sensing.jigframe import jig_frame_from_config
from softjig.sensing.refractive import closest_points_of_rays, triangulate_refracted

JIG = exact_jig()
FRAME = jig_frame_from_config(JIG)


def _project(points):
    layers = flat_layers(JIG)
    cams = JIG.cameras
    return (
        project_points(points, cams.left.K, None, cams.left.T_J_cam, layers),
        project_points(points, cams.right.K, None, cams.right.T_J_cam, layers),
    )


@pytest.mark.accuracy
@settings(max_examples=50, deadline=None)
@given(st.floats(-50, 50), st.floats(-30, 30), st.floats(0.5, 35))
def test_refracted_triangulation_inverts_the_exact_projection(x, y, z):
    point = np.array([[x, y, z]])
    left, right = _project(point)
    result = triangulate_refracted(left, right, JIG, FRAME)
    assert np.allclose(result.points_J, point, atol=1e-8)
    assert result.ray_gap_mm[0] < 1e-8


def test_refraction_matters():
    """The pinhole model (the paper's) puts a point at 30 mm in oil near 18 mm; ours at 30 mm."""
    from softjig.sensing.stereo import triangulate_rectified

    left, right = _project(np.array([[0.0, 0.0, 30.0]]))
    cam = JIG.cameras.left
    pinhole = (
        triangulate_rectified(
            left, right, fx_px=cam.fx_px, fy_px=cam.fy_px, cx_px=cam.cx_px, cy_px=cam.cy_px, baseline_mm=30.0
        )[0, 2]
        + cam.position_mm[2]
    )
    assert pinhole == pytest.approx(-5 + 5 / 1.575 + 30 / 1.51, abs=0.1)
    assert triangulate_refracted(left, right, JIG, FRAME).points_J[0, 2] == pytest.approx(30.0, abs=1e-9)


def _off_by_its_tolerance(field: str, tolerance: float):
    """JIG with its oil's index ``tolerance`` higher (``field`` ``"refractive_index"``), or both cameras'
    focal lengths ``tolerance`` (a fraction) longer (``"focal_fraction"``), than drawn."""
    if field == "refractive_index":
        index = JIG.medium.oil_refractive_index + tolerance
        return JIG.replace(medium=replace(JIG.medium, oil_refractive_index=index))
    cams = JIG.cameras
    longer = {
        side: replace(c, fx_px=c.fx_px * (1 + tolerance), fy_px=c.fy_px * (1 + tolerance))
        for side, c in (("left", cams.left), ("right", cams.right))
    }
    return JIG.replace(cameras=replace(cams, **longer))


@pytest.mark.accuracy
@pytest.mark.parametrize("alpha_deg", [5.0, 20.0])
@pytest.mark.parametrize("field", ["refractive_index", "focal_fraction"])
def test_the_depth_scale_error_tilts_a_face_as_the_refraction_does(field, alpha_deg):
    """An oil's index or a focal length off by its tolerance turns a tilted face's triangulated plane by
    the depth scale error times sin(tilt) cos(tilt), the error ``ToleranceConfig.depth_scale_error`` puts
    in the sigma."""
    tolerance = getattr(default_jig().tolerances, field)
    only = replace(JIG.tolerances, **{field: tolerance})
    scale_error = only.depth_scale_error(JIG.medium.oil_refractive_index)
    alpha = np.radians(alpha_deg)
    normal = normal_from_tilt(alpha, np.radians(30.0))
    xy = np.stack(np.meshgrid(np.linspace(-20, 20, 9), np.linspace(-20, 20, 9)), axis=-1).reshape(-1, 2)
    face = np.column_stack([xy, 25.0 - xy @ normal[:2] / normal[2]])
    built = _off_by_its_tolerance(field, tolerance)
    layers = flat_layers(built)
    left, right = (
        project_points(face, c.K, None, c.T_J_cam, layers) for c in (built.cameras.left, built.cameras.right)
    )
    turned = fit_plane_svd(triangulate_refracted(left, right, JIG, FRAME).points_J).normal
    expected = scale_error * np.sin(alpha) * np.cos(alpha)
    assert angle_between(turned, normal) == pytest.approx(expected, rel=0.1)


@pytest.mark.agreement
def test_closed_form_and_traced_triangulation_agree():
    """The closed-form rays against the oracle tracing every interface (backproject_pixels), for a head
    that is off its nominal pose and a camera with distortion."""
    rng = np.random.default_rng(3)
    jig = default_jig()
    distorted = replace(jig.cameras.left, distortion=(0.02, -0.01, 0.001, -0.0008, 0.0))
    jig = replace(jig, cameras=replace(jig.cameras, left=distorted))
    moved = np.eye(4)  # the head 1 mm and ~0.8 deg off its nominal pose
    moved[:3, :3] = cv2.Rodrigues(np.array([0.008, -0.005, 0.01]))[0]
    moved[:3, 3] = (0.7, -0.4, 0.9)
    nominal = jig_frame_from_config(jig)
    frame = replace(nominal, T_J_left=moved @ nominal.T_J_left, T_J_right=moved @ nominal.T_J_right)
    left = rng.uniform([0, 0], [1280, 720], (400, 2))
    right = left - [rng.uniform(120, 190), 0] + rng.normal(0, 1.0, (400, 2))
    fast = triangulate_refracted(left, right, jig, frame)
    traced = traced_triangulation(left, right, jig, frame)
    np.testing.assert_allclose(fast.points_J, traced.points_J, rtol=0, atol=1e-9)
    np.testing.assert_allclose(fast.ray_gap_mm, traced.ray_gap_mm, rtol=0, atol=1e-9)
    assert np.all(fast.ray_gap_mm > 0)  # noisy matches: skew rays


@pytest.mark.exceptions
@pytest.mark.parametrize(
    ("left", "right", "words"),
    [
        (np.zeros((3, 2)), np.zeros((2, 2)), "left_xy_px has 3 points but right_xy_px has 2"),
        (np.zeros((3, 3)), np.zeros((3, 2)), r"left_xy_px must be an \(M, 2\) array"),
        (np.zeros((1, 2)), [[np.nan, 1.0]], "right_xy_px contains NaN"),
    ],
)
def test_triangulate_refracted_rejects_bad_input(left, right, words):
    with pytest.raises(InputError, match=words):
        triangulate_refracted(left, right, JIG, FRAME)


@pytest.mark.shapes
def test_triangulate_nothing():
    result = triangulate_refracted(np.zeros((0, 2)), [], JIG, FRAME)
    assert result.points_J.shape == (0, 3) and result.ray_gap_mm.shape == (0,)


def test_closest_points_of_skew_rays():
    mid, gap = closest_points_of_rays(
        np.array([[0.0, 0, 0]]), np.array([[1.0, 0, 0]]), np.array([[0.0, 1, 2]]), np.array([[0.0, 1, 0]])
    )
    assert np.allclose(mid, [[0, 0, 1]]) and gap[0] == pytest.approx(2.0)
    mid, _ = closest_points_of_rays(
        np.zeros((1, 3)), np.array([[1.0, 0, 0]]), np.ones((1, 3)), np.array([[1.0, 0, 0]])
    )
    assert np.isnan(mid).all()  # parallel rays: no unique point


@pytest.mark.accuracy
def test_identities_follow_markers_that_moved():
    reference = rest_shape_reference(JIG)
    rng = np.random.default_rng(0)
    order = rng.permutation(len(reference))[:200]
    moved = reference.xyz_mm[order] + np.column_stack([rng.normal(0, 0.3, (200, 2)), -rng.uniform(0, 5, 200)])
    found = identify_markers(moved, reference, max_lateral_mm=4.0)
    assert np.array_equal(found.ids, order)
    assert np.allclose(found.displacement_mm, moved - reference.xyz_mm[order])
    stray = identify_markers(np.array([[500.0, 0, 0]]), reference, max_lateral_mm=4.0)
    assert stray.ids[0] == -1 and np.isnan(stray.displacement_mm).all()
    one = ReferenceMarkers(np.array([[0.0, 0, 30]]), "rest shape")
    twins = identify_markers(np.array([[0.1, 0, 30], [0.5, 0, 30]]), one, max_lateral_mm=4.0)
    assert list(twins.ids) == [0, -1]  # one to one: the nearer keeps it


def _pressed_disc(diameter, alpha_deg, push=3.0):
    """Markers of the rest dome, those under a tilted disc pushed onto its plane (contact by geometry)."""
    xy = marker_layout_xy(JIG)
    rest = rest_inner_height_mm(JIG, xy[:, 0], xy[:, 1])
    n = normal_from_tilt(np.radians(alpha_deg), 0.0)
    plane = 30.0 - push - (n[0] * xy[:, 0] + n[1] * xy[:, 1]) / n[2]
    under = np.hypot(*xy.T) < diameter / 2
    contact = under & (plane < rest)
    z = np.where(contact, plane, rest)
    return np.column_stack([xy, z]), rest, contact


def test_contact_found_from_indentation_and_its_footprint():
    points, rest, contact = _pressed_disc(50, 0.0)
    rng = np.random.default_rng(1)
    points[:, 2] += rng.normal(0, 0.05, len(points)) - 0.8  # noise and a uniform depth bias of the cameras
    dent = indentation(points, rest)
    assert dent.zero_mm == pytest.approx(0.8, abs=0.02) and dent.noise_mm == pytest.approx(0.05, rel=0.3)
    candidates = contact_candidates(dent)
    assert np.array_equal(candidates, contact)
    plane = fit_plane_svd(points[candidates])
    region = describe_contact(points[candidates, :2], plane, JIG, noise_mm=dent.noise_mm, part_diameter_mm=50)
    assert region.area_mm2 == pytest.approx(np.pi * 25**2, rel=0.15)
    assert np.hypot(*region.centroid_xy_mm) < 0.5
    assert not region.partial and region.edge_clearance_mm > 2.0


def test_partial_contact_is_flagged_with_its_side():
    points, _, contact = _pressed_disc(80, 15.0)  # tilted towards +x: it lifts off on the -x side
    plane = fit_plane_svd(points[contact])
    region = describe_contact(points[contact, :2], plane, JIG, noise_mm=0.05, part_diameter_mm=80)
    assert region.partial
    assert abs((region.lift_azimuth_deg - 180.0 + 180.0) % 360.0 - 180.0) < 45.0
    assert region.centroid_xy_mm[0] > 5.0  # the contact lies on the lowered side


@pytest.mark.exceptions
def test_triangulate_refracted_says_why_rays_cannot_be_traced():
    above = np.eye(4)
    above[:3, 3] = (0.0, 0.0, -2.0)  # a camera inside the plate
    frame = replace(FRAME, T_J_left=above)
    with pytest.raises(ValueError, match="region 0"):
        triangulate_refracted(np.array([[600.0, 300.0]]), np.array([[500.0, 300.0]]), JIG, frame)
    down = np.diag([1.0, -1.0, -1.0, 1.0])  # looking down, away from the plate
    down[:3, 3] = FRAME.T_J_left[:3, 3]
    with pytest.raises(ValueError, match="upwards"):
        triangulate_refracted(
            np.array([[600.0, 300.0]]), np.array([[500.0, 300.0]]), JIG, replace(FRAME, T_J_left=down)
        )


@pytest.mark.agreement
def test_identities_match_a_kd_tree_resolved_nearest_first():
    reference = rest_shape_reference(default_jig())
    rng = np.random.default_rng(6)
    for _ in range(10):
        points = reference.xyz_mm[rng.permutation(len(reference))[:250]].copy()
        points[:, :2] += rng.normal(0, 2.5, (len(points), 2))  # some claim the same marker, some none
        expected, moved = kd_tree_identities(points, reference.xyz_mm, 4.0)
        found = identify_markers(points, reference, max_lateral_mm=4.0)
        assert np.array_equal(found.ids, expected)
        assert (found.ids == -1).any() and len(set(found.ids[found.ids >= 0])) == (found.ids >= 0).sum()
        assert np.array_equal(found.displacement_mm, moved, equal_nan=True)
        assert np.isnan(found.displacement_mm[found.ids == -1]).all()
