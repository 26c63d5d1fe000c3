"""Raw (unrectified) pairs rectified with the config's calibration, then estimated like rectified ones."""

from dataclasses import replace

import cv2
import numpy as np
import pytest

from softjig.config import CylinderPart, StereoConfig, exact_jig, validate_jig
from softjig.errors import InputError
from softjig.optics import project_points
from softjig.rig import flat_layers
from softjig.sensing.pipeline import estimate_pair
from softjig.sensing.rectify import rectification, rectified_jig, rectify_pair
from softjig.sim.asbuilt import nominal_as_built
from softjig.sim.parts import PartPose
from softjig.sim.render import idealised, render_pair

BASE = idealised(exact_jig(), refraction=False, blur=False, noise=False)
RAW_LEFT = replace(
    BASE.cameras.left, distortion=(-0.08, 0.03, 0.0005, -0.0003, 0.0), fx_px=930.0, cx_px=645.0
)
RAW_RIGHT = replace(
    BASE.cameras.right,
    distortion=(-0.06, 0.02, -0.0004, 0.0002, 0.0),
    fy_px=921.0,
    cy_px=355.0,
    rotation_deg=(0.6, -1.2, 0.8),
    position_mm=(15.2, 0.4, -154.5),
)
RAW = BASE.replace(cameras=StereoConfig(left=RAW_LEFT, right=RAW_RIGHT, rectified=False))
POSE = PartPose(np.radians(10), np.radians(40), 3.0)


@pytest.fixture(scope="module")
def raw_pair():
    return render_pair(nominal_as_built(RAW), CylinderPart(50), POSE, 3)


def test_rectified_jig_satisfies_the_rectified_rules(raw_pair):
    _, _, jig = rectify_pair(raw_pair.left, raw_pair.right, RAW)
    assert jig.cameras.rectified
    validate_jig(jig)
    left, right = jig.cameras.left, jig.cameras.right
    assert left.position_mm == RAW_LEFT.position_mm  # the virtual cameras keep the real optical centres
    np.testing.assert_allclose(right.position_mm, RAW_RIGHT.position_mm, atol=1e-9)
    assert jig.cameras.baseline_mm == pytest.approx(RAW.cameras.baseline_mm)


@pytest.mark.accuracy
def test_rectified_images_put_every_marker_where_the_virtual_cameras_see_it(raw_pair):
    rect = rectification(RAW.cameras)
    layers = flat_layers(RAW)
    truth = raw_pair.markers
    pts = truth.xyz_mm[truth.visible_left & truth.visible_right]
    for side, R, P in (("left", rect.R1, rect.P1), ("right", rect.R2, rect.P2)):
        raw_cam, virt = getattr(RAW.cameras, side), getattr(rect.cameras, side)
        raw_px = project_points(pts, raw_cam.K, raw_cam.distortion, raw_cam.T_J_cam, layers)
        mapped = cv2.undistortPoints(
            raw_px.reshape(-1, 1, 2), raw_cam.K, np.asarray(raw_cam.distortion), R=R, P=P
        )
        expected = project_points(pts, virt.K, None, virt.T_J_cam, layers)
        np.testing.assert_allclose(mapped.reshape(-1, 2), expected, atol=1e-3)
    # and rows agree between the two rectified images (no refraction here)
    l_px = project_points(pts, rect.cameras.left.K, None, rect.cameras.left.T_J_cam, layers)
    r_px = project_points(pts, rect.cameras.right.K, None, rect.cameras.right.T_J_cam, layers)
    np.testing.assert_allclose(l_px[:, 1], r_px[:, 1], atol=1e-6)


def test_estimate_on_a_rectified_raw_pair_matches_a_rectified_rig(raw_pair):
    left, right, jig = rectify_pair(raw_pair.left, raw_pair.right, RAW)
    assert left.shape == raw_pair.left.shape and left.dtype == raw_pair.left.dtype
    got = estimate_pair(left, right, jig, part_diameter_mm=50, method="paper").estimate
    ref_pair = render_pair(nominal_as_built(BASE), CylinderPart(50), POSE, 3)
    ref = estimate_pair(ref_pair.left, ref_pair.right, BASE, part_diameter_mm=50, method="paper").estimate
    assert got.frame_source == "fiducials"
    assert got.tilt_x_deg == pytest.approx(ref.tilt_x_deg, abs=0.1)
    assert got.tilt_y_deg == pytest.approx(ref.tilt_y_deg, abs=0.1)
    assert got.push_depth_mm == pytest.approx(ref.push_depth_mm, abs=0.1)


def test_rectified_config_is_returned_untouched():
    a, b = np.zeros((2, 2), np.uint8), np.ones((2, 2), np.uint8)
    left, right, jig = rectify_pair(a, b, BASE)
    assert left is a and right is b and jig is BASE


def test_an_estimator_rectifies_with_maps_it_computed_once(monkeypatch):
    """No cache on the side: the estimator of a raw rig holds its rectification (maps and rectified jig)."""
    from softjig.sensing import setup
    from softjig.sensing.estimator import Estimator

    estimator = Estimator(RAW)
    assert estimator.model.rectification is not None and estimator.jig == rectified_jig(RAW)
    np.testing.assert_array_equal(
        estimator.model.rectification.maps_left[0], rectification(RAW.cameras).maps_left[0]
    )

    def no_rectification(*args, **kwargs):
        raise AssertionError("rectified again")

    monkeypatch.setattr(setup, "rectification", no_rectification)
    assert Estimator(RAW, model=estimator.model).model.rectification is estimator.model.rectification


@pytest.mark.exceptions
def test_swapped_cameras_are_an_input_error():
    swapped = StereoConfig(
        left=replace(RAW_RIGHT, position_mm=(-15.0, 0.0, -155.0)),
        right=replace(RAW_LEFT, position_mm=(-45.0, 0.0, -155.0)),
        rectified=False,
    )
    with pytest.raises(InputError, match="swapped"):
        rectification(swapped)


@pytest.mark.exceptions
def test_wrong_image_size_is_an_input_error(raw_pair):
    with pytest.raises(InputError, match=r"cameras\.left"):
        rectify_pair(raw_pair.left[:100], raw_pair.right, RAW)


def test_estimate_pair_accepts_the_raw_pair_itself(raw_pair):
    """A raw pair with an unrectified config goes through estimate_pair as is (rectified inside)."""
    left, right, jig = rectify_pair(raw_pair.left, raw_pair.right, RAW)
    via_rectified = estimate_pair(left, right, jig, part_diameter_mm=50, method="paper").estimate
    direct = estimate_pair(raw_pair.left, raw_pair.right, RAW, part_diameter_mm=50, method="paper").estimate
    assert direct == via_rectified


def test_refractive_method_on_a_raw_pair_finds_the_true_normal(raw_pair):
    from softjig.geometry import angle_between, normal_from_tilt

    got = estimate_pair(raw_pair.left, raw_pair.right, RAW, part_diameter_mm=50, method="refractive").estimate
    truth = normal_from_tilt(POSE.alpha_rad, POSE.theta_rad)
    assert np.degrees(angle_between(np.array(got.normal), truth)) < 1.0


@pytest.mark.exceptions
@pytest.mark.parametrize(
    ("dtype", "channels"), [(np.int32, ()), (np.bool_, ()), (np.uint8, (4,))], ids=["int32", "bool", "rgba"]
)
def test_unsupported_images_are_an_input_error(dtype, channels):
    """Not an OpenCV traceback (int32, bool) nor a remapped 4-channel image the estimator then refuses."""
    image = np.zeros((RAW.cameras.left.height_px, RAW.cameras.left.width_px, *channels), dtype)
    with pytest.raises(InputError, match=f"left image .*{np.dtype(dtype)}"):
        rectify_pair(image, image, RAW)
