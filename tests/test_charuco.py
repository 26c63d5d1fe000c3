"""ChArUco boards rendered with known truth: the pattern agrees with OpenCV's own, the corners are found
where they project (whole, partial, distorted views), and `softjig calibrate-stereo --charuco` recovers
the rig, for boards of both the current (OpenCV >= 4.6) and the legacy pattern."""

import json

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from typer.testing import CliRunner

from softjig.aruco import aruco_dictionary
from softjig.calibration.stereo import Board, detect_board
from softjig.cli import app
from softjig.config import CameraConfig, load_jig
from softjig.geometry import invert_pose
from softjig.sim.chessboard import charuco_corners_px, charuco_pattern, render_charuco_view

LEFT_CAM = CameraConfig(
    width_px=480,
    height_px=360,
    fx_px=420.0,
    fy_px=421.5,
    cx_px=242.0,
    cy_px=177.0,
    distortion=(-0.12, 0.05, 0.0008, -0.0005, 0.0),
    position_mm=(-30.0, 0.0, -155.0),
)
RIGHT_CAM = CameraConfig(
    width_px=480,
    height_px=360,
    fx_px=424.0,
    fy_px=422.5,
    cx_px=237.0,
    cy_px=183.0,
    distortion=(-0.10, 0.03, -0.0006, 0.0004, 0.0),
    position_mm=(30.5, 0.8, -154.0),
    rotation_deg=(0.5, -1.5, 0.7),
)
T_RIGHT_LEFT = invert_pose(RIGHT_CAM.T_J_cam) @ LEFT_CAM.T_J_cam
TRUE_BASELINE_MM = float(np.linalg.norm(T_RIGHT_LEFT[:3, 3]))
# 7 x 6 squares: an even number of rows, the size for which the legacy and current patterns differ.
COLS, ROWS, SQUARE, MARKER = 7, 6, 20.0, 15.0
RENDER = dict(supersampling=3, blur_sigma_px=0.6, noise_std=0.01)


def _pose(rotvec, centre_mm):
    """The board's pose in the left camera: its centre at ``centre_mm``, turned by ``rotvec`` (rad)."""
    R = Rotation.from_rotvec(rotvec).as_matrix()
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = np.asarray(centre_mm, float) - R @ [COLS * SQUARE / 2, ROWS * SQUARE / 2, 0.0]
    return T


def _poses(n, seed):
    rng = np.random.default_rng(seed)
    out = []
    for k in range(n):
        rot = rng.uniform(-0.45, 0.45, 3) * [1, 1, 0.5]
        # most views whole; every third pushed to an edge of the image so the board is cut by it
        shift = [rng.uniform(-40, 40), rng.uniform(-25, 25)] if k % 3 else [rng.choice([-1, 1]) * 150, 0]
        out.append(_pose(rot, [*shift, rng.uniform(280, 360)]))
    return out


def _render_pair(T, legacy, k):
    left = render_charuco_view(LEFT_CAM, T, COLS, ROWS, SQUARE, MARKER, legacy=legacy, rng=k, **RENDER)
    right = render_charuco_view(
        RIGHT_CAM, T_RIGHT_LEFT @ T, COLS, ROWS, SQUARE, MARKER, legacy=legacy, rng=100 + k, **RENDER
    )
    return left, right


@pytest.mark.parametrize("legacy", [False, True])
@pytest.mark.parametrize("size", [(7, 6), (5, 5)])
def test_pattern_is_opencvs(size, legacy):
    """Rendered face-on, one texel per pixel, the board is OpenCV's ``generateImage`` pixel for pixel."""
    cols, rows = size
    cb = cv2.aruco.CharucoBoard((cols, rows), SQUARE, MARKER, aruco_dictionary("DICT_4X4_50"))
    cb.setLegacyPattern(legacy)
    px = 40  # pixels per square: the 6 marker cells are 5 px each
    ref = cb.generateImage((cols * px, rows * px), marginSize=0, borderBits=1)
    flat = CameraConfig(
        width_px=cols * px,
        height_px=rows * px,
        fx_px=1000.0,
        fy_px=1000.0,
        cx_px=cols * px / 2 - 0.5,
        cy_px=rows * px / 2 - 0.5,
    )
    T = np.eye(4)
    T[:3, 3] = [-cols * SQUARE / 2, -rows * SQUARE / 2, 1000.0 * SQUARE / px]
    ours = render_charuco_view(flat, T, cols, rows, SQUARE, MARKER, legacy=legacy, supersampling=1)
    assert np.array_equal(ours > 127, ref > 127)


def test_legacy_differs_only_for_an_even_number_of_rows():
    assert not np.array_equal(charuco_pattern(7, 6), charuco_pattern(7, 6, legacy=True))
    assert np.array_equal(charuco_pattern(7, 5), charuco_pattern(7, 5, legacy=True))
    assert charuco_pattern(7, 6)[0, 0] == -1 and charuco_pattern(7, 6, legacy=True)[0, 0] == 0


@pytest.mark.parametrize("legacy", [False, True])
def test_corners_found_where_they_project_whole_and_partial(legacy):
    board = Board(COLS, ROWS, SQUARE, kind="charuco", marker_mm=MARKER, legacy=legacy)
    whole = _pose([0.3, -0.2, 0.1], [0.0, 0.0, 320.0])
    cut = _pose([-0.2, 0.3, 0.0], [165.0, 20.0, 320.0])  # the right third of the board outside the image
    for T, partial in ((whole, False), (cut, True)):
        img = render_charuco_view(LEFT_CAM, T, COLS, ROWS, SQUARE, MARKER, legacy=legacy, rng=1, **RENDER)
        truth = charuco_corners_px(LEFT_CAM, T, COLS, ROWS, SQUARE)
        view = detect_board(img, board)
        assert view is not None
        err = np.linalg.norm(view.corners_px - truth[view.ids], axis=1)
        # sub-pixel, with the lens's distortion: the corners are the projected truth (measured: RMS
        # 0.14 px, worst 0.3 px at the distorted edge); a corner given a wrong id, the failure this
        # guards against, is a square (>= 25 px) away
        assert np.median(err) < 0.3 and err.max() < 1.0, err
        # and unbiased (OpenCV 4.8-4.10's detector alone is 0.5 px off in u and v)
        assert np.all(np.abs(np.mean(view.corners_px - truth[view.ids], axis=0)) < 0.1)
        inside = (truth[:, 0] > 3) & (truth[:, 0] < LEFT_CAM.width_px - 4)
        if partial:
            assert not inside.all() and len(view.ids) < board.n_corners
        else:
            assert len(view.ids) == board.n_corners
        assert set(view.ids) <= set(np.flatnonzero(inside))


@pytest.mark.parametrize("printed_legacy", [False, True])
def test_a_whole_view_of_the_other_pattern_is_not_detected(printed_legacy):
    """Whole views tell the patterns apart (partial ones may not: the markers of one pattern's rows are
    the other's shifted by a square), so a board given the wrong pattern is not found, never misread."""
    T = _pose([0.3, -0.2, 0.1], [0.0, 0.0, 320.0])
    img = render_charuco_view(LEFT_CAM, T, COLS, ROWS, SQUARE, MARKER, legacy=printed_legacy, **RENDER)
    wrong = Board(COLS, ROWS, SQUARE, kind="charuco", marker_mm=MARKER, legacy=not printed_legacy)
    assert detect_board(img, wrong) is None


@pytest.fixture(scope="module", params=[False, True], ids=["current", "legacy"])
def calibrated(request, tmp_path_factory):
    legacy = request.param
    tmp = tmp_path_factory.mktemp("legacy" if legacy else "current")
    for k, T in enumerate(_poses(9, 3)):
        left, right = _render_pair(T, legacy, k)
        cv2.imwrite(str(tmp / f"left{k:02d}.png"), left)
        cv2.imwrite(str(tmp / f"right{k:02d}.png"), right)
    out = tmp / "rig.toml"
    args = [
        "calibrate-stereo",
        str(tmp / "left*.png"),
        str(tmp / "right*.png"),
        "--charuco",
        "--board",
        f"{COLS}x{ROWS}",
        "--square-mm",
        str(SQUARE),
        "--marker-mm",
        str(MARKER),
        "--fix-k3",
        "--json",
    ]
    res = CliRunner().invoke(app, [*args, "--out", str(out), *(["--legacy-pattern"] if legacy else [])])
    assert res.exit_code == 0, res.output
    return json.loads(res.stdout.strip().splitlines()[-1]), load_jig(out), legacy, tmp, args


def test_calibrate_stereo_charuco_recovers_the_rig(calibrated):
    data, jig, *_ = calibrated
    assert data["skipped"] == [] and len(data["views"]) == 9
    assert data["rms_px"] < 0.3
    # Nine views of 30 corners on 480 x 360 images: measured errors are 0.2-0.6 % in f, 0.1-0.6 % in the
    # baseline over seeds and tilts (OpenCV 5.0); the tolerances are twice the worst of those.
    assert data["fx_px"] == pytest.approx(LEFT_CAM.fx_px, rel=0.012)
    assert data["fy_px"] == pytest.approx(LEFT_CAM.fy_px, rel=0.012)
    assert data["right"]["fx_px"] == pytest.approx(RIGHT_CAM.fx_px, rel=0.012)
    assert data["cx_px"] == pytest.approx(LEFT_CAM.cx_px, abs=3.0)
    assert data["baseline_mm"] == pytest.approx(TRUE_BASELINE_MM, rel=0.012)
    T_left_right = invert_pose(jig.cameras.left.T_J_cam) @ jig.cameras.right.T_J_cam
    # the right camera's position in the left's frame: measured 0.8 mm off, nearly all along z (depth,
    # the worst-determined direction of a relative pose); the tolerance is 2 % of the baseline
    miss = np.linalg.norm(T_left_right[:3, 3] - invert_pose(T_RIGHT_LEFT)[:3, 3])
    assert miss < 0.02 * TRUE_BASELINE_MM
    assert jig.cameras.rectified is False


def test_the_wrong_pattern_exits_2_naming_the_option(calibrated):
    _, _, legacy, tmp, args = calibrated
    whole = [a.replace("*", "0[1245]") if a.endswith("*.png") else a for a in args]  # whole views only
    out = tmp / "wrong.toml"
    flag = [] if legacy else ["--legacy-pattern"]
    res = CliRunner().invoke(app, [*whole, "--out", str(out), *flag])
    assert res.exit_code == 2, res.output
    assert ("without --legacy-pattern" if not legacy else "with --legacy-pattern") in res.output
    assert not out.exists()
