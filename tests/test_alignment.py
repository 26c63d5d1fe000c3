"""Jig-to-robot alignment on rendered hand-eye images of the four circles, with a known pose."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from softjig.calibration.alignment import align_jig_to_robot, detect_circles
from softjig.config import AlignmentConfig, CameraConfig, default_jig
from softjig.errors import EstimationError
from softjig.geometry import invert_pose, pose_from_rotvec_translation
from softjig.sim.handeye import render_handeye_view

JIG = default_jig()
CAM = CameraConfig(
    width_px=640,
    height_px=480,
    fx_px=560.0,
    fy_px=561.0,
    cx_px=322.0,
    cy_px=238.0,
    distortion=(-0.08, 0.02, 0.0003, -0.0002, 0.0),
)
T_FLANGE_CAM = pose_from_rotvec_translation(np.radians([1.0, -2.0, 3.0]), [60.0, -20.0, 40.0])


def _scene(yaw_deg, tilt=(8.0, 5.0), jig=JIG, seed=1):
    T_robot_jig = pose_from_rotvec_translation(np.radians([0.5, -0.8, yaw_deg]), [650.0, 120.0, 40.0])
    R_J_cam = Rotation.from_rotvec(np.radians([*tilt, 20.0])).as_matrix() @ np.diag([1.0, -1.0, -1.0])
    T_J_cam = np.eye(4)
    T_J_cam[:3, :3], T_J_cam[:3, 3] = R_J_cam, [20.0, -30.0, 420.0]
    T_robot_flange = T_robot_jig @ T_J_cam @ invert_pose(T_FLANGE_CAM)
    image = render_handeye_view(jig, CAM, T_J_cam, supersampling=3, noise_std=0.01, rng=seed)
    return image, T_robot_jig, T_robot_flange


def _errors(T_est, T_true):
    E = invert_pose(T_true) @ T_est
    return np.linalg.norm(E[:3, 3]), np.degrees(Rotation.from_matrix(E[:3, :3]).magnitude())


@pytest.fixture(scope="module")
def scene():
    return _scene(12.0)


def test_recovers_the_known_pose(scene):
    image, T_true, T_flange = scene
    a = align_jig_to_robot(image, JIG, CAM, T_flange, T_FLANGE_CAM)
    dt, dr = _errors(a.T_robot_jig, T_true)
    assert dt < 0.3 and dr < 0.15
    assert a.reprojection_rms_px < 0.2 and a.warnings == ()
    assert a.ambiguous_orders == 4  # the default layout is a square: the prior decided


def test_circles_come_back_in_the_configs_order(scene):
    image, T_true, T_flange = scene
    a = align_jig_to_robot(image, JIG, CAM, T_flange, T_FLANGE_CAM)
    al = JIG.alignment
    pts = np.column_stack([np.asarray(al.circle_centers_mm), np.zeros(4)])
    T_cam_jig = invert_pose(T_flange @ T_FLANGE_CAM) @ T_true
    import cv2

    rvec, _ = cv2.Rodrigues(T_cam_jig[:3, :3])
    px, _ = cv2.projectPoints(pts, rvec, T_cam_jig[:3, 3], CAM.K, np.asarray(CAM.distortion))
    np.testing.assert_allclose(a.circles_px, px.reshape(-1, 2), atol=0.3)


def test_a_prior_within_45_degrees_resolves_a_turned_jig():
    image, T_true, T_flange = _scene(80.0)
    prior = Rotation.from_euler("z", 90, degrees=True).as_matrix()
    a = align_jig_to_robot(image, JIG, CAM, T_flange, T_FLANGE_CAM, R_robot_jig_prior=prior)
    assert _errors(a.T_robot_jig, T_true)[1] < 0.15
    wrong = align_jig_to_robot(image, JIG, CAM, T_flange, T_FLANGE_CAM)  # prior 0: 80 deg off -> 90 deg wrong
    assert _errors(wrong.T_robot_jig, T_true)[1] > 80


def test_an_asymmetric_layout_needs_no_prior():
    jig = JIG.replace(
        alignment=AlignmentConfig(
            circle_centers_mm=((-100.0, -100.0), (100.0, -100.0), (100.0, 60.0), (-100.0, 100.0))
        )
    )
    image, T_true, T_flange = _scene(100.0, jig=jig)
    a = align_jig_to_robot(image, jig, CAM, T_flange, T_FLANGE_CAM)
    assert a.ambiguous_orders == 1
    assert _errors(a.T_robot_jig, T_true)[1] < 0.15


def test_missing_circles_are_an_estimation_error():
    with pytest.raises(EstimationError, match="alignment circles"):
        detect_circles(np.full((100, 100), 30, np.uint8), 4)


def test_cli_align_jig(tmp_path, scene):
    import json

    import cv2
    from typer.testing import CliRunner

    from softjig.cli import app

    image, T_true, T_flange = scene
    cv2.imwrite(str(tmp_path / "he.png"), image)
    cam = {k: getattr(CAM, k) for k in ("width_px", "height_px", "fx_px", "fy_px", "cx_px", "cy_px")}
    cam["distortion"] = list(CAM.distortion)
    cam["T_flange_cam"] = T_FLANGE_CAM.tolist()
    (tmp_path / "cam.json").write_text(json.dumps(cam))
    (tmp_path / "flange.json").write_text(json.dumps({"T_robot_flange": T_flange.tolist()}))
    out = tmp_path / "robot-jig.json"
    res = CliRunner().invoke(
        app,
        [
            "align-jig",
            str(tmp_path / "he.png"),
            "--camera",
            str(tmp_path / "cam.json"),
            "--flange",
            str(tmp_path / "flange.json"),
            "--out",
            str(out),
        ],
    )
    assert res.exit_code == 0, res.output
    T = np.array(json.loads(out.read_text())["T_robot_jig"])
    assert _errors(T, T_true)[0] < 0.3


# ---------------------------------------------------------------- issue 14: no pose that is not credible


def _write_inputs(tmp_path, image, T_flange, cam_changes=None, flange_json=None):
    import json

    import cv2

    cv2.imwrite(str(tmp_path / "he.png"), image)
    cam = {k: getattr(CAM, k) for k in ("width_px", "height_px", "fx_px", "fy_px", "cx_px", "cy_px")}
    cam["distortion"] = list(CAM.distortion)
    cam["T_flange_cam"] = T_FLANGE_CAM.tolist()
    cam.update(cam_changes or {})
    (tmp_path / "cam.json").write_text(json.dumps(cam))
    flange = flange_json if flange_json is not None else json.dumps({"T_robot_flange": T_flange.tolist()})
    (tmp_path / "flange.json").write_text(flange)


def _align_cli(tmp_path):
    from typer.testing import CliRunner

    from softjig.cli import app

    out = tmp_path / "robot-jig.json"
    args = ["align-jig", str(tmp_path / "he.png"), "--camera", str(tmp_path / "cam.json")]
    args += ["--flange", str(tmp_path / "flange.json"), "--out", str(out)]
    return CliRunner().invoke(app, args), out


@pytest.mark.parametrize("kind", ["noise", "stereo"])
def test_an_image_without_the_circles_gives_no_pose(tmp_path, scene, default_scene, kind):
    """Issue 14: a noise image and a stereo image gave exit 0 and a robot pose (RMS 64-128 px)."""
    _, _, T_flange = scene
    if kind == "noise":
        image = (np.random.default_rng(0).random((480, 640)) * 255).astype(np.uint8)
    else:  # a crop of the stereo camera's view of the markers (many bright blobs, no circles)
        image = np.ascontiguousarray(default_scene.left[100:580, 300:940])
    _write_inputs(tmp_path, image, T_flange)
    result, out = _align_cli(tmp_path)
    assert result.exit_code == 3, result.output
    assert "no credible pose" in result.output or "alignment circles" in result.output
    assert not out.exists()


@pytest.mark.parametrize(
    ("cam_changes", "flange_change", "match"),
    [
        ({"fx_px": -560.0}, None, "fx_px must be positive"),
        ({"cx_px": 5000.0}, None, "principal point"),
        ({"width_px": 1280, "height_px": 720, "cx_px": 640.0, "cy_px": 360.0}, None, "640 x 480 px"),
        (None, "scaled", "not orthonormal"),
        (None, "reflected", "determinant -1"),
        (None, "nan", "NaN"),
        (None, "km", "no robot reaches"),
        (None, "quaternion", "unit norm"),
    ],
)
def test_inputs_that_are_not_credible_are_refused(tmp_path, scene, cam_changes, flange_change, match):
    """Issue 14: a flange matrix that is not a rotation, fx < 0 gave a pose; NaN gave NaN, then a
    traceback."""
    import json

    image, _, T_flange = scene
    T = T_flange.copy()
    flange_json = None
    if flange_change == "scaled":
        T[:3, :3] *= 1.1
    elif flange_change == "reflected":
        T[:3, 0] *= -1
    elif flange_change == "nan":
        T[0, 3] = np.nan
        flange_json = json.dumps({"T_robot_flange": T.tolist()})  # Python's json writes NaN
    elif flange_change == "km":
        T[:3, 3] = [1e9, 0, 0]
    elif flange_change == "quaternion":
        flange_json = json.dumps({"position_mm": [600.0, 0, 400.0], "quaternion_xyzw": [0, 0, 0, 2.0]})
    _write_inputs(tmp_path, image, T, cam_changes, flange_json)
    result, out = _align_cli(tmp_path)
    assert result.exit_code == 2, result.output
    assert match in result.output
    assert not out.exists()
    assert "Traceback" not in result.output


def test_a_wrong_circle_diameter_is_refused(scene):
    image, _, T_flange = scene
    jig = JIG.replace(alignment=AlignmentConfig(circle_diameter_mm=JIG.alignment.circle_diameter_mm / 2))
    with pytest.raises(EstimationError, match="times the area"):
        align_jig_to_robot(image, jig, CAM, T_flange, T_FLANGE_CAM)


def test_check_pose_orthonormalises_within_tolerance(scene):
    from softjig.calibration.alignment import check_pose

    _, _, T_flange = scene
    typed = np.round(T_flange, 4)  # as printed with 4 decimals
    T = check_pose(typed, "T")
    np.testing.assert_allclose(T[:3, :3].T @ T[:3, :3], np.eye(3), atol=1e-12)
    np.testing.assert_allclose(T, typed, atol=1e-3)
