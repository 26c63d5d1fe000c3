"""Tests of softjig.sim.render: the stereo renderer and its ground truth."""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np
import pytest

from softjig.aruco import aruco_dictionary
from softjig.config import CylinderPart, JigConfig, default_jig, exact_jig
from softjig.optics import backproject_pixels, projection_jacobian
from softjig.rig import AIR_REFRACTIVE_INDEX, distortion_of, flat_layers
from softjig.sim.asbuilt import draw_as_built, nominal_as_built
from softjig.sim.membrane import deform
from softjig.sim.parts import PartPose
from softjig.sim.render import MarkerTruth, RenderedPair, idealised, render_pair, render_view

PART = CylinderPart(diameter_mm=50.0)
POSE = PartPose(alpha_rad=np.radians(10.0), theta_rad=np.radians(30.0))


def exact_images_jig(*, blur: bool) -> JigConfig:
    """The nominal jig without noise (and without blur if asked), 16 bits, no illumination fall-off:
    rendered markers can then be compared with their truth to a few thousandths of a pixel."""
    jig = idealised(exact_jig(), blur=blur, noise=False)
    return jig.replace(imaging=replace(jig.imaging, illumination_falloff=0.0, bit_depth=16))


def marker_geometry(jig: JigConfig, camera, xyz: np.ndarray, axis: np.ndarray, px: np.ndarray):
    """Per marker: image radius (px), blur sigma (px) and the angle (deg) between its axis and the ray
    back to the camera, from the public optics (independent of the renderer's internals)."""
    layers = flat_layers(jig)
    K, dist, T = camera.K, distortion_of(camera), camera.T_J_cam
    jac = projection_jacobian(xyz, K, dist, T, layers)
    _, d = backproject_pixels(px, K, dist, T, layers)
    sv = np.linalg.svd(jac, compute_uv=False)  # the Jacobian vanishes along the ray
    radius = jig.markers.diameter_mm / 2.0 * sv[:, 0]
    oil_path = xyz[:, 2] / d[:, 2]
    sigma = jig.medium.blur_coefficient * oil_path**1.5 * np.sqrt(sv[:, 0] * sv[:, 1])
    angle = np.degrees(np.arccos(np.clip(-np.sum(d * axis, axis=1), -1.0, 1.0)))
    return radius, sigma, angle


def centroid_errors(jig: JigConfig, pair: RenderedPair) -> tuple[np.ndarray, np.ndarray]:
    """Distance (px) between the background-subtracted intensity centroid of each isolated visible
    marker and its truth pixel, and the marker's viewing angle (deg), over both images."""
    m = pair.markers
    top = 65535.0 if jig.imaging.bit_depth == 16 else 255.0
    errors, angles = [], []
    for image, px, visible, camera, corners in (
        (pair.left, m.left_px, m.visible_left, jig.cameras.left, pair.fiducial_corners_left_px),
        (pair.right, m.right_px, m.visible_right, jig.cameras.right, pair.fiducial_corners_right_px),
    ):
        radius, sigma, angle = marker_geometry(jig, camera, m.xyz_mm, m.axis, px)
        reach = radius + 3.0 * sigma + 1.5  # all of a marker's light lies within this of its truth
        gap = np.linalg.norm(px[:, None] - px[None], axis=2)
        np.fill_diagonal(gap, np.inf)
        isolated = np.all(gap >= reach[:, None] + reach[None, :], axis=1)
        fid_centre = corners.mean(axis=1)
        fid_reach = np.linalg.norm(corners[:, 0] - corners[:, 2], axis=1) * 8 / 12  # + quiet zone
        far = np.all(
            np.linalg.norm(px[:, None] - fid_centre[None], axis=2) > fid_reach[None] + reach[:, None], axis=1
        )
        h, w = image.shape
        inside = np.all((px - reach[:, None] > 0) & (px + reach[:, None] < [w - 1, h - 1]), axis=1)
        excess = image.astype(float) - jig.imaging.background_level * top
        for i in np.flatnonzero(visible & isolated & far & inside):
            r = int(np.ceil(reach[i]))
            u0, v0 = np.rint(px[i]).astype(int)
            v, u = np.mgrid[v0 - r : v0 + r + 1, u0 - r : u0 + r + 1]
            win = excess[v0 - r : v0 + r + 1, u0 - r : u0 + r + 1] * (
                (u - px[i, 0]) ** 2 + (v - px[i, 1]) ** 2 <= reach[i] ** 2
            )
            c = np.array([(win * u).sum(), (win * v).sum()]) / win.sum()
            errors.append(np.linalg.norm(c - px[i]))
            angles.append(angle[i])
    return np.asarray(errors), np.asarray(angles)


def hemisphere_bias_bound_px(angle_deg: np.ndarray) -> np.ndarray:
    """Measured bound of the hemisphere's centroid bias: about 0.25 px at 20 deg, 1 px at 48 deg
    (quadratic in the angle), plus 0.03 px for the 4x4 supersampling."""
    return 0.03 + 0.5 * (angle_deg / 28.0) ** 2


@pytest.fixture(scope="module")
def default_pair() -> tuple[JigConfig, RenderedPair]:
    as_built = draw_as_built(default_jig(), rng=3)
    return as_built.jig, render_pair(as_built, PART, POSE, rng=11)


@pytest.fixture(scope="module")
def exact_pair() -> tuple[JigConfig, RenderedPair]:
    jig = exact_images_jig(blur=False)
    return jig, render_pair(nominal_as_built(jig), PART, POSE, rng=0)


# ----------------------------------------------------------------------------------- smoke, shapes


def test_pair_shapes_and_truth(default_pair):
    jig, pair = default_pair
    cam = jig.cameras.left
    n = len(pair.markers.xyz_mm)
    assert isinstance(pair.markers, MarkerTruth)
    assert pair.left.shape == pair.right.shape == (cam.height_px, cam.width_px)
    assert pair.left.dtype == np.uint8
    for name in ("left_px", "right_px"):
        assert getattr(pair.markers, name).shape == (n, 2)
    for name in ("visible_left", "visible_right", "in_contact"):
        assert getattr(pair.markers, name).dtype == bool
        assert getattr(pair.markers, name).shape == (n,)
    assert pair.fiducial_corners_left_px.shape == (len(jig.fiducials.ids), 4, 2)
    assert 150 < pair.markers.visible_left.sum() < n
    assert pair.markers.in_contact.any()


@pytest.mark.parametrize(
    ("bit_depth", "color", "dtype"),
    [
        (8, False, np.uint8),
        (16, False, np.uint16),
        (8, True, np.uint8),
        (16, True, np.uint16),
    ],
)
def test_output_dtype_and_shape(bit_depth, color, dtype):
    jig = exact_jig()
    jig = jig.replace(imaging=replace(jig.imaging, bit_depth=bit_depth))
    state = deform(jig, nominal_as_built(jig).marker_xy_mm)
    image, px, visible = render_view(jig, jig.cameras.left, state, 0, color=color)
    shape = (720, 1280, 3) if color else (720, 1280)
    assert image.shape == shape and image.dtype == dtype
    assert px.shape == (len(state.marker_xyz_mm), 2) and visible.dtype == bool
    if color:
        assert np.array_equal(image[..., 0], image[..., 1])
        assert np.array_equal(image[..., 0], image[..., 2])
    gray, _, _ = render_view(jig, jig.cameras.left, state, 0)
    assert np.array_equal(image[..., 0] if color else image, gray)


def test_deterministic_for_a_seed():
    as_built = draw_as_built(default_jig(), rng=1)
    a = render_pair(as_built, PART, POSE, rng=5)
    b = render_pair(as_built, PART, POSE, rng=np.random.default_rng(5))
    c = render_pair(as_built, PART, POSE, rng=6)
    assert np.array_equal(a.left, b.left) and np.array_equal(a.right, b.right)
    assert np.array_equal(a.markers.xyz_mm, b.markers.xyz_mm)
    assert not np.array_equal(a.left, c.left)
    assert not np.array_equal(a.markers.xyz_mm, c.markers.xyz_mm)  # the membrane's ripple


def test_idealised_switches_effects_off():
    jig = default_jig()
    assert idealised(jig) == jig
    flat = idealised(jig, refraction=False)
    assert flat.plate.refractive_index == flat.medium.oil_refractive_index == AIR_REFRACTIVE_INDEX
    assert idealised(jig, blur=False).medium.blur_coefficient == 0.0
    quiet = idealised(jig, noise=False)
    assert quiet.medium.speckle_std == 0.0 and quiet.imaging.read_noise == 0.0
    assert quiet.imaging.full_well_electrons >= 1e12


# ------------------------------------------------------------------------------ noise-free accuracy


def test_centroid_matches_truth_without_blur(exact_pair):
    jig, pair = exact_pair
    errors, angles = centroid_errors(jig, pair)
    assert len(errors) > 300
    head_on = angles < 8.0
    assert head_on.sum() > 50
    assert errors[head_on].max() < 0.05
    assert np.all(errors <= hemisphere_bias_bound_px(angles))
    assert errors.max() < 1.2


def test_centroid_matches_truth_with_blur():
    jig = exact_images_jig(blur=True)
    pair = render_pair(nominal_as_built(jig), PART, POSE, rng=0)
    errors, angles = centroid_errors(jig, pair)
    assert len(errors) > 100  # blurred markers need more room to be isolated
    assert errors[angles < 8.0].max() < 0.05
    assert np.all(errors <= hemisphere_bias_bound_px(angles))


def test_marker_size_and_disparity_range():
    jig = exact_images_jig(blur=False)
    pair = render_pair(nominal_as_built(jig), rng=0)
    m = pair.markers
    both = m.visible_left & m.visible_right
    disparity = m.left_px[both, 0] - m.right_px[both, 0]
    assert disparity.min() > 150.0 and disparity.max() < 185.0
    # The marker's image: the pixels well above the membrane (the lit hemisphere).
    apex = int(np.argmin(np.hypot(m.xyz_mm[:, 0], m.xyz_mm[:, 1])))
    u0, v0 = np.rint(m.left_px[apex]).astype(int)
    level = pair.left[v0 - 15 : v0 + 16, u0 - 15 : u0 + 16] / 65535.0 - jig.imaging.background_level
    lit = level > 0.25 * (jig.imaging.marker_level - jig.imaging.background_level)
    diameter = 2.0 * np.sqrt(lit.sum() / np.pi)
    assert 13.0 < diameter < 18.0


def test_refraction_compresses_apparent_depth():
    jig = exact_images_jig(blur=False)
    disparity = {}
    for on in (True, False):
        j = jig if on else idealised(jig, refraction=False)
        m = render_pair(nominal_as_built(j), rng=0).markers
        apex = int(np.argmin(np.hypot(m.xyz_mm[:, 0], m.xyz_mm[:, 1])))
        disparity[on] = m.left_px[apex, 0] - m.right_px[apex, 0]
        depth_mm = m.xyz_mm[apex, 2] - jig.cameras.left.position_mm[2]
    pinhole = jig.cameras.left.fx_px * jig.cameras.baseline_mm / depth_mm
    assert disparity[False] == pytest.approx(pinhole, abs=1e-6)
    assert disparity[True] - disparity[False] > 5.0  # looks nearer through the denser media


# --------------------------------------------------------------------------------------- fiducials


def test_fiducials_detected_at_their_truth(default_pair):
    jig, pair = default_pair
    params = cv2.aruco.DetectorParameters()
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    detector = cv2.aruco.ArucoDetector(aruco_dictionary(jig.fiducials.dictionary), params)
    for image, truth in (
        (pair.left, pair.fiducial_corners_left_px),
        (pair.right, pair.fiducial_corners_right_px),
    ):
        corners, ids, _ = detector.detectMarkers(image)
        assert ids is not None and sorted(ids.ravel().tolist()) == sorted(jig.fiducials.ids)
        for marker_id, found in zip(ids.ravel(), corners, strict=True):
            expected = truth[list(jig.fiducials.ids).index(marker_id)]
            assert np.abs(found.reshape(4, 2) - expected).max() < 0.5


def test_markers_behind_fiducials_are_not_visible(default_pair):
    _jig, pair = default_pair
    m = pair.markers
    centre = pair.fiducial_corners_left_px.mean(axis=1)
    behind = np.min(np.linalg.norm(m.left_px[:, None] - centre[None], axis=2), axis=1) < 30.0
    assert behind.any() and not m.visible_left[behind].any()


# ------------------------------------------------------------------------------------------ contact


def test_tilted_large_cylinder_lifts_off_on_its_raised_side():
    jig = exact_jig()
    as_built = nominal_as_built(jig)
    pose = PartPose(alpha_rad=np.radians(20.0), theta_rad=0.0)  # the -x side is raised
    pair = render_pair(as_built, CylinderPart(diameter_mm=80.0), pose, rng=2)
    m = pair.markers
    x, y = m.xyz_mm[:, 0], m.xyz_mm[:, 1]
    under = np.hypot(x, y) < 40.0 * np.cos(np.radians(20.0)) - 2.0
    assert m.in_contact.sum() > 10
    assert np.all(x[m.in_contact] > -15.0)
    assert np.any(under & (x < -20.0) & ~m.in_contact)
    assert np.all(m.visible_left[m.in_contact] & m.visible_right[m.in_contact])
    for image, px in ((pair.left, m.left_px), (pair.right, m.right_px)):
        u, v = np.rint(px[m.in_contact]).astype(int).T
        assert np.all(image[v, u] > 2 * 255 * jig.imaging.background_level)


# ------------------------------------------------------------------------------------- edge cases


def test_lens_distortion_enters_through_the_projection():
    jig = exact_images_jig(blur=False)
    distorted = replace(jig.cameras.left, distortion=(-0.08, 0.02, 0.0005, -0.0003, 0.0))
    jig = jig.replace(cameras=replace(jig.cameras, left=distorted, rectified=False))
    pair = render_pair(nominal_as_built(jig), rng=0)
    errors, angles = centroid_errors(jig, pair)
    assert len(errors) > 200
    assert errors[angles < 8.0].max() < 0.05
    assert np.all(errors <= hemisphere_bias_bound_px(angles))
    plain = render_pair(nominal_as_built(exact_images_jig(blur=False)), rng=0)
    moved = np.linalg.norm(pair.markers.left_px - plain.markers.left_px, axis=1)
    assert moved.max() > 5.0  # the distortion is not negligible at the image's edges


def test_membrane_without_markers_renders_fiducials_only():
    jig = exact_jig()
    state = deform(jig, np.zeros((0, 2)))
    image, px, visible = render_view(jig, jig.cameras.right, state, 0)
    assert px.shape == (0, 2) and visible.shape == (0,)
    assert image.shape == (720, 1280)
    assert image.max() > 180  # the fiducials' white quiet zones


def test_pose_without_part_is_the_unloaded_membrane():
    as_built = nominal_as_built(idealised(exact_jig(), noise=False))
    a = render_pair(as_built, None, POSE, rng=0)
    b = render_pair(as_built, rng=0)
    assert np.array_equal(a.left, b.left)
    assert not a.markers.in_contact.any()
