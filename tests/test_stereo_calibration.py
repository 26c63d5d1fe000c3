"""Stereo calibration on a real stereo set and on rendered pairs whose true parameters are known."""

import glob
import json
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from typer.testing import CliRunner

from softjig.calibration.stereo import Board, calibrate_stereo, parse_board_size, rig_from_calibration
from softjig.cli import app
from softjig.config import CameraConfig, default_jig, load_jig
from softjig.errors import InputError
from softjig.geometry import invert_pose
from softjig.io.dataset import load_image
from softjig.sim.chessboard import board_corners_px, render_chessboard_view

REAL = str(Path(__file__).resolve().parents[2] / "shared" / "data" / "stereo-chessboard")  # ../shared
LEFTS = sorted(glob.glob(f"{REAL}/left*.jpg"))
RIGHTS = sorted(glob.glob(f"{REAL}/right*.jpg"))
needs_real = pytest.mark.skipif(len(LEFTS) != 12, reason="the real stereo set is not available")

# ----------------------------------------------------------------------------------- real photographs


@pytest.fixture(scope="module")
def real_cal():
    # In this set the camera named "left" is on the right (disparities are negative), so by softjig's
    # convention (+x from the left camera to the right one) its "right" images are the left ones.
    return calibrate_stereo(
        [load_image(p) for p in RIGHTS], [load_image(p) for p in LEFTS], Board(6, 9, 24.0)
    )


@needs_real
def test_real_set_calibrates_with_subpixel_error(real_cal):
    assert len(real_cal.view_names) == 12 and not real_cal.skipped
    assert real_cal.rms_px < 0.3
    assert np.all(real_cal.view_rms_px < 0.35)
    assert real_cal.outliers == ()
    assert 510 < real_cal.K_left[0, 0] < 530 and 510 < real_cal.K_left[1, 1] < 530
    assert abs(real_cal.K_left[0, 0] / real_cal.K_right[0, 0] - 1) < 0.01
    assert 85 < real_cal.baseline_mm < 100
    assert not real_cal.right_is_on_left and real_cal.warnings() == []
    # rectification: both rectified cameras share f and the principal point; P2 holds -f * baseline
    assert real_cal.P1[0, 0] == pytest.approx(real_cal.P2[0, 0])
    assert -real_cal.P2[0, 3] / real_cal.P2[0, 0] == pytest.approx(real_cal.baseline_mm, rel=1e-6)


@needs_real
def test_real_set_rig_config_keeps_the_left_pose(real_cal):
    base = default_jig()
    jig = rig_from_calibration(base, real_cal)
    assert not jig.cameras.rectified
    assert jig.cameras.left.position_mm == base.cameras.left.position_mm
    assert (jig.cameras.left.width_px, jig.cameras.left.height_px) == (640, 512)
    T_lr = invert_pose(jig.cameras.left.T_J_cam) @ jig.cameras.right.T_J_cam
    np.testing.assert_allclose(T_lr, real_cal.T_left_right, atol=1e-9)


@needs_real
def test_cli_on_the_real_set_as_named_warns_that_the_cameras_are_swapped(tmp_path):
    out = tmp_path / "rig.toml"
    res = CliRunner().invoke(
        app,
        [
            "calibrate-stereo",
            f"{REAL}/left0[1-5].jpg",
            f"{REAL}/right0[1-5].jpg",
            "--board",
            "6x9",
            "--square-mm",
            "24",
            "--out",
            str(out),
            "--json",
        ],
    )
    assert res.exit_code == 0, res.output
    data = json.loads(res.stdout.strip().splitlines()[-1])
    for key in ("rms_px", "fx_px", "fy_px", "baseline_mm"):
        assert np.isfinite(data[key])
    assert data["rms_px"] < 0.3 and 85 < data["baseline_mm"] < 100
    assert any("swapped" in w for w in data["warnings"])
    assert load_jig(out).cameras.rectified is False


def test_cli_board_not_found_exits_2(tmp_path, sim_views):
    import cv2

    lefts, rights, _ = sim_views
    for k in range(3):
        # small images: a failed search is slow on big ones
        cv2.imwrite(
            str(tmp_path / f"l{k}.png"), cv2.resize(lefts[k], (160, 120), interpolation=cv2.INTER_AREA)
        )
        cv2.imwrite(
            str(tmp_path / f"r{k}.png"), cv2.resize(rights[k], (160, 120), interpolation=cv2.INTER_AREA)
        )
    res = CliRunner().invoke(
        app,
        [
            "calibrate-stereo",
            str(tmp_path / "l*.png"),
            str(tmp_path / "r*.png"),
            "--board",
            "7x9",
            "--square-mm",
            "24",
            "--out",
            str(tmp_path / "rig.toml"),
        ],
    )
    assert res.exit_code == 2
    assert "--board" in res.output


def test_cli_glob_matching_nothing_exits_2(tmp_path):
    res = CliRunner().invoke(
        app,
        [
            "calibrate-stereo",
            str(tmp_path / "*.png"),
            str(tmp_path / "*.png"),
            "--board",
            "6x9",
            "--square-mm",
            "24",
            "--out",
            str(tmp_path / "rig.toml"),
        ],
    )
    assert res.exit_code == 2 and "matches no file" in res.output


@pytest.mark.parametrize("text", ["6", "6x", "axb", "6x9x2"])
def test_parse_board_size_rejects_bad_forms(text):
    with pytest.raises(InputError, match="COLSxROWS"):
        parse_board_size(text)


def test_parse_board_size():
    assert parse_board_size("6x9") == (6, 9)


# ------------------------------------------------------------------------ rendered pairs, known truth

LEFT_CAM = CameraConfig(
    width_px=640,
    height_px=480,
    fx_px=500.0,
    fy_px=502.0,
    cx_px=322.0,
    cy_px=236.0,
    distortion=(-0.12, 0.05, 0.0008, -0.0005, 0.0),
    position_mm=(-30.0, 0.0, -155.0),
)
RIGHT_CAM = CameraConfig(
    width_px=640,
    height_px=480,
    fx_px=505.0,
    fy_px=503.0,
    cx_px=316.0,
    cy_px=244.0,
    distortion=(-0.10, 0.03, -0.0006, 0.0004, 0.0),
    position_mm=(30.5, 0.8, -154.0),
    rotation_deg=(0.5, -1.5, 0.7),
)
COLS, ROWS, SQUARE = 9, 6, 20.0


def _board_poses(n, rng):
    rng = np.random.default_rng(rng)
    centre = np.array([(COLS - 1) * SQUARE / 2, (ROWS - 1) * SQUARE / 2, 0.0])
    for _ in range(n):
        R = Rotation.from_rotvec(rng.uniform(-0.5, 0.5, 3) * [1, 1, 0.6]).as_matrix()
        c = np.array([rng.uniform(-60, 60), rng.uniform(-40, 40), rng.uniform(350, 550)])
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = R, c - R @ centre
        yield T


@pytest.fixture(scope="module")
def sim_views():
    T_right_left = invert_pose(RIGHT_CAM.T_J_cam) @ LEFT_CAM.T_J_cam
    lefts, rights, truth = [], [], []
    for k, T in enumerate(_board_poses(10, 0)):
        kw = dict(supersampling=3, blur_sigma_px=0.6, noise_std=0.01)
        lefts.append(render_chessboard_view(LEFT_CAM, T, COLS, ROWS, SQUARE, rng=k, **kw))
        rights.append(
            render_chessboard_view(RIGHT_CAM, T_right_left @ T, COLS, ROWS, SQUARE, rng=100 + k, **kw)
        )
        truth.append(board_corners_px(LEFT_CAM, T, COLS, ROWS, SQUARE))
    return lefts, rights, truth


def test_rendered_corners_are_found_where_they_project(sim_views):
    from softjig.calibration.stereo import detect_board

    lefts, _, truth = sim_views
    errors = []
    for image, t in zip(lefts, truth, strict=True):
        c = detect_board(image, Board(COLS, ROWS, SQUARE)).corners_px
        if np.abs(c - t).max() > 3:
            c = c[::-1]
        errors.append(np.sqrt(np.mean(np.sum((c - t) ** 2, axis=1))))
    assert np.median(errors) < 0.1 and max(errors) < 0.25


def test_rendered_pairs_recover_the_true_parameters(sim_views):
    lefts, rights, _ = sim_views
    cal = calibrate_stereo(lefts, rights, Board(COLS, ROWS, SQUARE), fix_k3=True)
    assert cal.rms_px < 0.15
    for K, cam in ((cal.K_left, LEFT_CAM), (cal.K_right, RIGHT_CAM)):
        assert K[0, 0] == pytest.approx(cam.fx_px, rel=3e-3)
        assert K[1, 1] == pytest.approx(cam.fy_px, rel=3e-3)
        assert K[0, 2] == pytest.approx(cam.cx_px, abs=1.5)
        assert K[1, 2] == pytest.approx(cam.cy_px, abs=1.5)
    np.testing.assert_allclose(cal.dist_left[:2], LEFT_CAM.distortion[:2], atol=0.03)
    np.testing.assert_allclose(cal.dist_right[:2], RIGHT_CAM.distortion[:2], atol=0.03)
    T_true = invert_pose(LEFT_CAM.T_J_cam) @ RIGHT_CAM.T_J_cam
    assert cal.baseline_mm == pytest.approx(np.linalg.norm(T_true[:3, 3]), abs=0.3)
    np.testing.assert_allclose(cal.T_left_right[:3, 3], T_true[:3, 3], atol=0.5)
    dR = Rotation.from_matrix(cal.T_left_right[:3, :3].T @ T_true[:3, :3]).magnitude()
    assert np.degrees(dR) < 0.2


def test_too_few_views_is_an_input_error(sim_views):
    lefts, rights, _ = sim_views
    with pytest.raises(InputError, match="at least 3"):
        calibrate_stereo(lefts[:2], rights[:2], Board(COLS, ROWS, SQUARE))
    with pytest.raises(InputError, match="one right image per left"):
        calibrate_stereo(lefts[:3], rights[:2], Board(COLS, ROWS, SQUARE))


# ------------------------------------------------------------- issue 14: --out is never overwritten unasked


def _cli_args(tmp_path, out):
    return [
        "calibrate-stereo",
        str(tmp_path / "l*.png"),
        str(tmp_path / "r*.png"),
        "--board",
        f"{COLS}x{ROWS}",
        "--square-mm",
        str(SQUARE),
        "--out",
        str(out),
    ]


def test_cli_refuses_an_existing_out_without_overwrite(tmp_path):
    out = tmp_path / "rig.toml"
    out.write_text("# the rig calibrated last week\n")
    res = CliRunner().invoke(app, _cli_args(tmp_path, out))
    assert res.exit_code == 2
    assert str(out) in res.output and "--overwrite" in res.output
    assert out.read_text() == "# the rig calibrated last week\n"  # refused before any work


def test_cli_overwrite_replaces_the_out(tmp_path, sim_views):
    import cv2

    lefts, rights, _ = sim_views
    for k in range(6):
        cv2.imwrite(str(tmp_path / f"l{k}.png"), lefts[k])
        cv2.imwrite(str(tmp_path / f"r{k}.png"), rights[k])
    out = tmp_path / "rig.toml"
    out.write_text("# the rig calibrated last week\n")
    res = CliRunner().invoke(app, [*_cli_args(tmp_path, out), "--overwrite", "--json"])
    assert res.exit_code == 0, res.output
    assert load_jig(out).cameras.left.width_px == 640
