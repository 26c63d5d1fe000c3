"""The jig frame from the fiducials: the fast path (read near the expected quads, Gauss-Newton) and the
general one (ArUco detector, SciPy's Levenberg-Marquardt) against the straightforward oracle, and the
fallbacks."""

import cv2
import numpy as np
import pytest

from oracles.jigframe import inside_fiducials as oracle_inside_fiducials
from oracles.jigframe import jig_frame as oracle_jig_frame
from softjig.config import default_jig
from softjig.geometry import invert_pose
from softjig.sensing import jigframe
from softjig.sensing.fiducials import (
    CAPTURE_PX,
    CAPTURE_SCANLINES,
    CAPTURE_STEP_PX,
    capture_table,
    detect_fiducials,
    locate_fiducials_near,
)
from softjig.sensing.jigframe import jig_frame_from_config, jig_frame_from_fiducials, resolve_jig_frame
from softjig.sim.asbuilt import draw_as_built
from softjig.sim.render import render_pair

JIG = default_jig()
EXPECTED = jig_frame_from_config(JIG)


@pytest.fixture(scope="module", params=[0, 2, 5])
def pair(request):
    """An as-built jig's pair; seed 2 puts the head's fiducials ~26 px from where the config expects."""
    return render_pair(draw_as_built(JIG, rng=request.param), rng=request.param)


def _pose_difference(T_a: np.ndarray, T_b: np.ndarray) -> tuple[float, float]:
    """Translation (mm) and rotation (deg) between two poses."""
    dT = invert_pose(T_a) @ T_b
    angle = np.linalg.norm(cv2.Rodrigues(dT[:3, :3])[0])  # exact for small angles (arccos is not)
    return float(np.linalg.norm(dT[:3, 3])), float(np.degrees(angle))


@pytest.mark.agreement
def test_fast_path_finds_the_same_corners_as_the_aruco_detector(pair):
    for image, quads in (
        (pair.left, EXPECTED.fiducial_quads_left_px),
        (pair.right, EXPECTED.fiducial_quads_right_px),
    ):
        fast = locate_fiducials_near(image, JIG.fiducials, quads)
        aruco = detect_fiducials(image, JIG.fiducials, expected_quads_px=quads)
        assert fast is not None and list(fast) == list(JIG.fiducials.ids)
        for marker_id, corners in fast.items():
            assert np.abs(corners - aruco[marker_id]).max() < 0.01


@pytest.mark.agreement
def test_fast_path_gives_the_oracles_pose(pair):
    fast = jig_frame_from_fiducials(pair.left, pair.right, JIG)
    oracle = oracle_jig_frame(pair.left, pair.right, JIG)
    assert fast is not None and fast.source == "fiducials"
    for a, b in ((fast.T_J_left, oracle.T_J_left), (fast.T_J_right, oracle.T_J_right)):
        mm, deg = _pose_difference(a, b)
        assert mm < 1e-3 and deg < 1e-4
    assert fast.fiducial_ids == oracle.fiducial_ids == tuple(JIG.fiducials.ids)
    assert fast.reprojection_rms_px == pytest.approx(oracle.reprojection_rms_px, abs=1e-3)
    assert np.abs(fast.fiducial_quads_left_px - oracle.fiducial_quads_left_px).max() < 0.01


def test_general_path_gives_the_oracles_pose(pair, monkeypatch):
    monkeypatch.setattr(jigframe, "_jig_frame_fast", lambda *args: None)  # as if the fast path failed
    general = jig_frame_from_fiducials(pair.left, pair.right, JIG)
    oracle = oracle_jig_frame(pair.left, pair.right, JIG)
    mm, deg = _pose_difference(general.T_J_left, oracle.T_J_left)
    assert mm < 1e-3 and deg < 1e-4
    assert general.fiducial_ids == oracle.fiducial_ids


def test_gauss_newton_reaches_the_levenberg_marquardt_optimum(pair):
    found = [
        locate_fiducials_near(pair.left, JIG.fiducials, EXPECTED.fiducial_quads_left_px),
        locate_fiducials_near(pair.right, JIG.fiducials, EXPECTED.fiducial_quads_right_px),
    ]
    corners = jigframe.frame_constants(JIG).corners_J_by_id
    obj = [np.concatenate([corners[i] for i in f]) for f in found]
    img = [np.concatenate([f[i] for i in f]) for f in found]
    T_gn, res_gn = jigframe._fit_pose_gauss_newton(obj, img, JIG)
    T_lm, res_lm = jigframe._fit_pose_lm(obj, img, JIG)
    mm, deg = _pose_difference(T_gn, T_lm)
    assert mm < 1e-5 and deg < 1e-6
    assert np.abs(res_gn - res_lm).max() < 1e-6


def test_occluded_fiducial_falls_back_to_the_detector(pair):
    left = pair.left.copy()
    quad = EXPECTED.fiducial_quads_left_px[0]
    lo, hi = np.floor(quad.min(axis=0)).astype(int) - 20, np.ceil(quad.max(axis=0)).astype(int) + 20
    left[max(lo[1], 0) : hi[1], max(lo[0], 0) : hi[0]] = 10  # fiducial 0 hidden in the left image
    assert locate_fiducials_near(left, JIG.fiducials, EXPECTED.fiducial_quads_left_px) is None
    frame, warnings = resolve_jig_frame(left, pair.right, JIG)
    oracle = oracle_jig_frame(left, pair.right, JIG)
    assert frame.source == "fiducials" and warnings == []
    assert frame.fiducial_ids == oracle.fiducial_ids == tuple(JIG.fiducials.ids[1:])
    mm, deg = _pose_difference(frame.T_J_left, oracle.T_J_left)
    assert mm < 1e-3 and deg < 1e-4


def test_wrong_ids_are_not_read_as_the_expected_fiducials(pair):
    """The cells must read as the configured ids, in their orientation."""
    swapped = JIG.fiducials.__class__(**{**JIG.fiducials.__dict__, "ids": (1, 0, 2, 3)})
    assert locate_fiducials_near(pair.left, swapped, EXPECTED.fiducial_quads_left_px) is None
    rotated = np.roll(EXPECTED.fiducial_quads_left_px, 1, axis=1)  # the same places, corners turned
    assert locate_fiducials_near(pair.left, JIG.fiducials, rotated) is None


@pytest.mark.shapes
def test_nothing_to_find():
    blank = np.full((JIG.cameras.left.height_px, JIG.cameras.left.width_px), 30, np.uint8)
    assert locate_fiducials_near(blank, JIG.fiducials, EXPECTED.fiducial_quads_left_px) is None
    assert locate_fiducials_near(blank[:100, :100], JIG.fiducials, EXPECTED.fiducial_quads_left_px) is None
    assert jig_frame_from_fiducials(blank, blank, JIG) is None
    frame, warnings = resolve_jig_frame(blank, blank, JIG)
    assert frame.source == "config" and "were not found" in warnings[0]


def test_a_head_far_off_takes_the_general_path_once(monkeypatch):
    """As-built draw 235 puts the fiducials ~43 px from where the config expects them: beyond the fast
    path's capture. The first frame takes the general path; the next ones start where it found them (kept
    in the caller's FiducialMemory, nowhere else)."""
    pair = render_pair(draw_as_built(JIG, rng=235), rng=1)
    constants = jigframe.frame_constants(JIG)
    fast_first = jigframe._jig_frame_fast(
        pair.left, pair.right, JIG, constants, constants.fast.expected_quads, constants.fast.capture_tables
    )
    assert fast_first is None
    memory = jigframe.FiducialMemory()
    first = jig_frame_from_fiducials(pair.left, pair.right, JIG, constants=constants, memory=memory)
    assert first is not None and first.fiducial_ids == tuple(JIG.fiducials.ids)
    assert memory.quads is not None

    def no_detector(*args, **kwargs):
        raise AssertionError("the general path ran again")

    monkeypatch.setattr(jigframe, "detect_fiducials", no_detector)
    again = jig_frame_from_fiducials(pair.left, pair.right, JIG, constants=constants, memory=memory)
    with pytest.raises(AssertionError, match="general path ran again"):  # without the memory, it would
        jig_frame_from_fiducials(pair.left, pair.right, JIG, constants=constants)
    mm, deg = _pose_difference(first.T_J_left, again.T_J_left)
    assert mm < 1e-3 and deg < 1e-4


def test_inside_fiducials_matches_the_straightforward_test():
    rng = np.random.default_rng(3)
    angle = rng.uniform(0, 2 * np.pi, (5, 1))
    square = np.array([[-1.0, -1.0], [1.0, -1.0], [1.0, 1.0], [-1.0, 1.0]])
    quads = np.empty((5, 4, 2))
    for q in range(5):  # rotated, sheared squares in both windings
        c, s = np.cos(angle[q, 0]), np.sin(angle[q, 0])
        shape = square @ np.array([[c, -s], [s, c]]).T @ np.array([[1.0, 0.3], [0.0, 1.0]])
        quads[q] = rng.uniform(50, 500, 2) + 30 * (shape if q % 2 else shape[::-1])
    xy = np.concatenate([rng.uniform(0, 560, (4000, 2)), quads.reshape(-1, 2)])  # and the corners
    inside = jigframe.inside_fiducials(xy, quads)
    assert np.array_equal(inside, oracle_inside_fiducials(xy, quads))
    assert 0 < inside.sum() < len(xy)
    assert not jigframe.inside_fiducials(xy, np.empty((0, 4, 2))).any()


@pytest.mark.agreement
def test_capture_table_samples_the_straightforward_scanlines():
    """Each sample's pixel: corner + t along the side + a step along the side's outward normal, rounded
    (the sample grid as one (Q, 4, S, L, 2) array), for the expected quads moved about the image; none
    when a scanline leaves it."""
    quads = np.ascontiguousarray(EXPECTED.fiducial_quads_left_px, dtype=float)
    shape = (JIG.cameras.left.height_px, JIG.cameras.left.width_px)
    steps = np.arange(-CAPTURE_PX, CAPTURE_PX + 1, CAPTURE_STEP_PX, dtype=float)
    scanlines = np.asarray(CAPTURE_SCANLINES)[None, None, :, None]
    for shift in ([0.0, 0.0], [7.5, -3.25], [-12.0, 9.0]):
        moved = quads + np.asarray(shift)
        table = capture_table(moved.tobytes(), len(moved), shape)
        assert table is not None
        on_side = moved[:, :, None, :] + scanlines * (moved[:, [1, 2, 3, 0]] - moved)[:, :, None]
        samples = on_side[..., None, :] + steps[:, None] * table.normals[:, :, None, None, :]
        pix = np.rint(samples).astype(np.intp)
        assert table.shape == pix.shape[:4]
        assert np.array_equal(table.index, (pix[..., 1] * shape[1] + pix[..., 0]).ravel())
    assert capture_table((quads - [5000.0, 0.0]).tobytes(), len(quads), shape) is None
