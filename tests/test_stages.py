"""The estimator's stages, each with the groups of kornia's tests where its own module's tests have none.

One class a public stage function, on the shared default scene (``conftest.py``): ``smoke`` (it runs on a
typical input and returns its documented result), ``shapes`` (shapes and dtypes, the empty input
included), ``accuracy`` (against the renderer's ground truth). The other groups of each stage are marked
in its module's tests (``pytest -m accuracy tests/test_stereo.py``).
"""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np
import pytest

from softjig.errors import InputError
from softjig.geometry import invert_pose
from softjig.sensing.fiducials import detect_fiducials
from softjig.sensing.identities import identify_markers, rest_shape_reference
from softjig.sensing.jigframe import jig_frame_from_config, jig_frame_from_fiducials
from softjig.sensing.pipeline import sensing_setup
from softjig.sensing.rectify import rectify_pair
from softjig.sensing.refractive import triangulate_refracted
from softjig.sensing.robust import fit_plane_robust
from softjig.sensing.stereo import StereoMatches, match_rectified, triangulate_rectified
from softjig.sensing.subpixel import refine_centres

START_OFFSET_PX = 0.4  # a start within half a pixel of the marker, as the detector's candidates are
DISPARITY_PX = 100.0


def _pose_difference(T_a: np.ndarray, T_b: np.ndarray) -> tuple[float, float]:
    """Translation (mm) and rotation (deg) between two poses."""
    dT = invert_pose(T_a) @ T_b
    return float(np.linalg.norm(dT[:3, 3])), float(np.degrees(np.linalg.norm(cv2.Rodrigues(dT[:3, :3])[0])))


class TestRefineCentres:
    @pytest.mark.smoke
    def test_smoke(self, default_scene):
        truth = default_scene.pair.markers.left_px[default_scene.pair.markers.visible_left]
        model = sensing_setup(default_scene.jig).marker
        fit = refine_centres(default_scene.left, truth + START_OFFSET_PX, model)
        assert fit.ok.mean() > 0.99
        error = np.linalg.norm(fit.xy_px - truth, axis=1)[fit.ok]
        assert np.median(error) < 0.5 * START_OFFSET_PX * np.sqrt(2)  # moved towards the marker

    @pytest.mark.shapes
    @pytest.mark.parametrize("n", [0, 1, 5])
    def test_shapes(self, default_scene, n):
        model = sensing_setup(default_scene.jig).marker
        start = default_scene.pair.markers.left_px[default_scene.pair.markers.visible_left][:n]
        for image in (default_scene.left, default_scene.left.astype(np.float32) / 255.0):
            fit = refine_centres(image, start, model)
            assert fit.xy_px.shape == (n, 2) and fit.xy_px.dtype == np.float64
            assert fit.amplitude.shape == (n,) and fit.ok.shape == (n,) and fit.ok.dtype == bool


class TestDetectFiducials:
    @pytest.mark.smoke
    def test_smoke(self, default_scene):
        found = detect_fiducials(default_scene.left, default_scene.jig.fiducials)
        assert sorted(found) == sorted(default_scene.jig.fiducials.ids)

    @pytest.mark.shapes
    def test_shapes(self, default_scene):
        found = detect_fiducials(default_scene.right, default_scene.jig.fiducials)
        assert all(corners.shape == (4, 2) and corners.dtype.kind == "f" for corners in found.values())
        assert detect_fiducials(np.zeros_like(default_scene.right), default_scene.jig.fiducials) == {}

    @pytest.mark.accuracy
    def test_accuracy(self, default_scene):
        # sub-pixel corners on the rendered (blurred, noisy) images: measured 0.20-0.22 px at worst over
        # as-built seeds 0-2
        found = detect_fiducials(default_scene.left, default_scene.jig.fiducials)
        truth = default_scene.pair.fiducial_corners_left_px
        for k, marker_id in enumerate(default_scene.jig.fiducials.ids):
            assert np.abs(found[marker_id] - truth[k]).max() < 0.35


class TestJigFrameFromFiducials:
    @pytest.mark.smoke
    def test_smoke(self, default_scene):
        frame = jig_frame_from_fiducials(default_scene.left, default_scene.right, default_scene.jig)
        assert frame is not None and frame.source == "fiducials"
        assert frame.reprojection_rms_px < 0.5

    @pytest.mark.shapes
    def test_shapes(self, default_scene):
        frame = jig_frame_from_fiducials(default_scene.left, default_scene.right, default_scene.jig)
        for T in (frame.T_J_left, frame.T_J_right):
            assert T.shape == (4, 4) and np.array_equal(T[3], [0.0, 0.0, 0.0, 1.0])
        blank = np.zeros_like(default_scene.left)
        assert jig_frame_from_fiducials(blank, blank, default_scene.jig) is None  # nothing to find

    @pytest.mark.accuracy
    def test_accuracy(self, default_scene):
        # the as-built head's pose from the nominal intrinsics: measured 0.07-0.20 mm, under 0.01 deg
        # over as-built seeds 0-2
        frame = jig_frame_from_fiducials(default_scene.left, default_scene.right, default_scene.jig)
        truth = jig_frame_from_config(default_scene.as_built.jig)
        for T, T_true in ((frame.T_J_left, truth.T_J_left), (frame.T_J_right, truth.T_J_right)):
            mm, deg = _pose_difference(T, T_true)
            assert mm < 0.5 and deg < 0.05


class TestRectifyPair:
    @pytest.mark.smoke
    @pytest.mark.shapes
    def test_smoke_and_shapes(self, default_scene):
        cameras = default_scene.jig.cameras
        left = replace(cameras.left, distortion=(-0.05, 0.01, 0.0, 0.0, 0.0))
        raw = default_scene.jig.replace(cameras=replace(cameras, left=left, rectified=False))
        left_rect, right_rect, jig = rectify_pair(default_scene.left, default_scene.right, raw)
        for image in (left_rect, right_rect):
            assert image.shape == default_scene.left.shape and image.dtype == default_scene.left.dtype
        assert jig.cameras.rectified


class TestStereo:
    @pytest.mark.smoke
    def test_smoke(self, default_scene):
        """The left image's true marker centres and a copy 100 px to the left: each matched to its copy,
        then triangulated at the depth of that disparity."""
        markers = default_scene.pair.markers
        left = markers.left_px[markers.visible_left]
        right = left - [DISPARITY_PX, 0.0]
        matches = match_rectified(
            left, right, row_tolerance_px=1.0, min_disparity_px=50.0, max_disparity_px=150.0
        )
        assert isinstance(matches, StereoMatches) and len(matches) == len(left)
        assert np.array_equal(matches.left_index, matches.right_index)
        camera, baseline_mm = default_scene.jig.cameras.left, default_scene.jig.cameras.baseline_mm
        intrinsics = {
            "fx_px": camera.fx_px,
            "fy_px": camera.fy_px,
            "cx_px": camera.cx_px,
            "cy_px": camera.cy_px,
        }
        points = triangulate_rectified(left, right, **intrinsics, baseline_mm=baseline_mm)
        assert points.shape == (len(left), 3)
        np.testing.assert_allclose(points[:, 2], camera.fx_px * baseline_mm / DISPARITY_PX)


class TestTriangulateRefracted:
    @pytest.mark.smoke
    @pytest.mark.accuracy
    def test_smoke_and_accuracy(self, default_scene):
        """The renderer's exact refracted projections of the markers, triangulated through the as-built
        layers from the as-built head: the markers' true positions (to 1e-6 mm of the renderer's)."""
        markers = default_scene.pair.markers
        both = markers.visible_left & markers.visible_right
        jig = default_scene.as_built.jig
        points = triangulate_refracted(
            markers.left_px[both], markers.right_px[both], jig, jig_frame_from_config(jig)
        )
        assert points.points_J.shape == (both.sum(), 3)
        assert np.abs(points.points_J - markers.xyz_mm[both]).max() < 1e-3


class TestIdentifyMarkers:
    @pytest.mark.smoke
    def test_smoke(self, default_jig_config):
        reference = rest_shape_reference(default_jig_config)
        shift = np.array([0.4, -0.3, -1.0])
        shifted = reference.xyz_mm + shift  # each marker moved less than half a pitch
        identities = identify_markers(
            shifted, reference, max_lateral_mm=default_jig_config.markers.pitch_mm / 2
        )
        assert np.array_equal(identities.ids, np.arange(len(reference.xyz_mm)))
        np.testing.assert_allclose(identities.displacement_mm, np.broadcast_to(shift, shifted.shape))

    @pytest.mark.shapes
    @pytest.mark.parametrize("n", [0, 1, 7])
    def test_shapes(self, default_jig_config, n):
        reference = rest_shape_reference(default_jig_config)
        identities = identify_markers(reference.xyz_mm[:n], reference, max_lateral_mm=1.0)
        assert identities.ids.shape == (n,) and identities.ids.dtype.kind == "i"
        assert identities.displacement_mm.shape == (n, 3)


class TestFitPlaneRobust:
    @pytest.mark.smoke
    @pytest.mark.shapes
    @pytest.mark.accuracy
    def test_smoke_shapes_and_accuracy(self, default_scene):
        """The markers the part's face presses (their true positions): one plane, parallel to the face
        (measured 0.04 deg on this scene, all 23 markers inliers; the bound leaves room for the ripple)."""
        markers = default_scene.pair.markers
        points = markers.xyz_mm[markers.in_contact]
        fit = fit_plane_robust(points)
        assert fit.inliers.shape == (len(points),) and fit.inliers.dtype == bool
        assert fit.n_inliers == fit.inliers.sum() > 0.9 * len(points)
        assert fit.plane.normal.shape == (3,) and fit.plane.normal[2] > 0
        face_normal = default_scene.pose.rotation()[:, 2]
        assert np.degrees(np.arccos(np.clip(fit.plane.normal @ face_normal, -1.0, 1.0))) < 0.3


class TestStageExceptions:
    """Bad input to each public stage function: an InputError naming the argument, or (a legitimate image
    of another dtype: mono16, float in [0, 1], RGB) the same answer as the 8-bit gray image; never an
    OpenCV traceback or a silently wrong answer."""

    @pytest.mark.exceptions
    @pytest.mark.parametrize(
        "convert",
        [
            lambda g: g.astype(np.uint16) * 257,  # mono16, as the bags carry
            lambda g: g.astype(np.float32) / 255.0,
            lambda g: np.dstack([g, g, g]),
        ],
        ids=["mono16", "float32", "rgb"],
    )
    def test_fiducials_accept_other_image_types(self, default_scene, convert):
        fid = default_scene.jig.fiducials
        expected = detect_fiducials(default_scene.left, fid)
        found = detect_fiducials(convert(default_scene.left), fid)
        assert set(found) == set(expected)
        for marker_id, corners in expected.items():
            np.testing.assert_allclose(found[marker_id], corners, atol=1e-6)
        left, right, jig = default_scene.left, default_scene.right, default_scene.jig
        frame = jig_frame_from_fiducials(convert(left), convert(right), jig)
        reference = jig_frame_from_fiducials(left, right, jig)
        assert frame is not None and reference is not None
        np.testing.assert_allclose(frame.T_J_left, reference.T_J_left, atol=1e-9)

    @pytest.mark.exceptions
    @pytest.mark.parametrize(
        ("image", "message"),
        [
            (np.zeros((0, 0), np.uint8), "empty"),
            (np.full((64, 64), np.nan, np.float32), r"\[0, 1\]"),
            (np.zeros((64, 64), np.int32), "dtype int32"),
            (np.zeros((64, 64, 4), np.uint8), "shape"),
        ],
        ids=["empty", "nan", "int32", "rgba"],
    )
    def test_fiducials_refuse_bad_images(self, default_scene, image, message):
        with pytest.raises(InputError, match=message):
            detect_fiducials(image, default_scene.jig.fiducials)
        with pytest.raises(InputError, match=f"left image: .*{message}"):
            jig_frame_from_fiducials(image, default_scene.right, default_scene.jig)

    @pytest.mark.exceptions
    @pytest.mark.parametrize(
        ("points", "max_lateral_mm", "message"),
        [
            (np.zeros((3, 2)), 1.0, r"points_J .*\(3, 2\)"),
            (np.zeros(6), 1.0, r"points_J .*\(6,\)"),
            (np.full((2, 3), np.nan), 1.0, "points_J .*NaN"),
            (np.zeros((2, 3)), -1.0, "max_lateral_mm"),
            (np.zeros((2, 3)), float("nan"), "max_lateral_mm"),
        ],
        ids=["2-columns", "flat", "nan", "negative-tolerance", "nan-tolerance"],
    )
    def test_identify_markers_refuses(self, default_jig_config, points, max_lateral_mm, message):
        reference = rest_shape_reference(default_jig_config)
        with pytest.raises(InputError, match=message):
            identify_markers(points, reference, max_lateral_mm=max_lateral_mm)

    @pytest.mark.exceptions
    @pytest.mark.parametrize(
        ("image", "start", "kwargs", "message"),
        [
            (np.zeros((64, 64), np.int32), [[30.0, 30.0]], {}, "dtype int32"),
            (np.zeros((0, 0), np.uint8), [[30.0, 30.0]], {}, "non-empty"),
            (np.zeros((64, 64), np.uint8), np.zeros((3, 3)), {}, r"start_xy_px .*\(3, 3\)"),
            (np.zeros((64, 64), np.uint8), [[np.nan, 30.0]], {}, "start_xy_px .*NaN"),
            (np.zeros((64, 64), np.uint8), [[30.0, 30.0]], {"iterations": -1}, "iterations"),
        ],
        ids=["int32", "empty", "3-columns", "nan-start", "negative-iterations"],
    )
    def test_refine_centres_refuses(self, default_scene, image, start, kwargs, message):
        model = sensing_setup(default_scene.jig).marker
        with pytest.raises(InputError, match=message):
            refine_centres(image, np.asarray(start, dtype=float), model, **kwargs)
