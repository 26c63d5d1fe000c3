"""The robot's tilt-sweep plan and the contact rule."""

import csv
import json

import numpy as np
import pytest
from typer.testing import CliRunner

from softjig.cli import app
from softjig.config import default_jig
from softjig.errors import ConfigError, InputError
from softjig.geometry import normal_from_tilt, pose_from_rotvec_translation
from softjig.planning import detect_contact, sweep_plan, sweep_plan_rows

JIG = default_jig()


def test_plan_order_and_count():
    plan = sweep_plan(JIG, [30, 50, 80], [20, 5, 10, 15], 10)
    per_part = 2 + 4 * 36 + 2
    assert len(plan) == 3 * per_part
    assert [p.index for p in plan] == list(range(len(plan)))
    first = plan[:per_part]
    assert [p.phase for p in first[:2]] == ["approach", "press"]
    assert [p.phase for p in first[-2:]] == ["press", "retract"]
    tilts = [(p.alpha_deg, p.theta_deg) for p in first if p.phase == "tilt"]
    assert tilts[0] == (5.0, 0.0) and tilts[1] == (5.0, 10.0) and tilts[36] == (10.0, 0.0)  # alphas ascending
    assert {p.diameter_mm for p in plan[per_part : 2 * per_part]} == {50.0}


def test_tilt_poses_have_the_commanded_normal_and_pivot_on_the_bottom_centre():
    plan = sweep_plan(JIG, [50], [10], 45, push_depth_mm=3.0)
    press = plan[1].T_J_part
    for p in plan:
        if p.phase != "tilt":
            continue
        n = p.T_J_part[:3, 2]
        np.testing.assert_allclose(
            n, normal_from_tilt(np.radians(p.alpha_deg), np.radians(p.theta_deg)), atol=1e-12
        )
        np.testing.assert_allclose(p.T_J_part[:3, 3], press[:3, 3], atol=1e-9)  # tilted about that point
        q = np.array(p.to_dict()["quaternion_xyzw"])
        assert np.linalg.norm(q) == pytest.approx(1.0) and q[3] >= 0


def test_robot_frame_poses_are_the_jig_poses_moved_by_T_robot_jig():
    T = pose_from_rotvec_translation(np.radians([0, 0, 30]), [500.0, -100.0, 20.0])
    plan = sweep_plan(JIG, [50], [10], 90, T_robot_jig=T)
    for p in plan:
        np.testing.assert_allclose(p.T_robot_part, T @ p.T_J_part)
    row = sweep_plan_rows(plan)[3]
    assert {"robot_x_mm", "robot_qw", "x_mm", "qw"} <= set(row)


@pytest.mark.parametrize(
    ("args", "match"),
    [
        (([50], [70], 10), "alphas"),
        (([50], [10], 0), "theta step"),
        (([], [10], 10), "diameters"),
    ],
)
def test_bad_values_are_input_errors(args, match):
    with pytest.raises(InputError, match=match):
        sweep_plan(JIG, *args)


def test_a_part_wider_than_the_membrane_is_rejected():
    with pytest.raises(ConfigError, match="wider than the membrane"):
        sweep_plan(JIG, [300], [10], 10)


# ----------------------------------------------------------------------------------- contact rule


def test_contact_at_the_first_change_of_one_newton():
    forces = [5.0, 5.1, 4.9, 5.0, 5.0, 5.2, 5.6, 6.01, 7.0]  # the part's weight tared by the first five
    result = detect_contact(forces)
    assert result and result.index == 7 and result.change_N == pytest.approx(1.01)


def test_contact_on_force_vectors_uses_the_magnitude_of_the_change():
    f = np.zeros((10, 3))
    f[6:] = [0.6, 0.0, 0.85]  # |change| = 1.04 N
    assert detect_contact(f).index == 6
    f[6:] = [0.5, 0.0, 0.5]  # 0.71 N: not yet
    result = detect_contact(f)
    assert not result and result.index is None and result.change_N == pytest.approx(np.hypot(0.5, 0.5))


def test_contact_with_a_known_baseline_and_threshold():
    assert detect_contact([0.0, 0.5, 2.1], baseline_N=0.0, threshold_N=2.0).index == 2


@pytest.mark.parametrize("forces", [[1.0, 2.0], [[1, 2]] * 6, [np.nan] * 6])
def test_contact_bad_input(forces):
    with pytest.raises(InputError):
        detect_contact(forces)


# -------------------------------------------------------------------------------------------- CLI


def test_cli_writes_json_and_csv(tmp_path):
    T = pose_from_rotvec_translation([0, 0, 0.2], [400.0, 0.0, 10.0])
    (tmp_path / "robot-jig.json").write_text(json.dumps({"T_robot_jig": T.tolist()}))
    out = tmp_path / "plan.json"
    res = CliRunner().invoke(
        app,
        [
            "sweep-plan",
            "--diameters",
            "30,50,80",
            "--alphas",
            "5,10,15,20",
            "--step",
            "10",
            "--out",
            str(out),
            "--robot-jig",
            str(tmp_path / "robot-jig.json"),
        ],
    )
    assert res.exit_code == 0, res.output
    doc = json.loads(out.read_text())
    assert len(doc["poses"]) == 3 * (4 + 4 * 36)
    assert doc["contact_rule"]["force_change_N"] == 1.0
    assert "robot_position_mm" in doc["poses"][0]
    with open(tmp_path / "plan.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == len(doc["poses"]) and rows[2]["phase"] == "tilt"
    assert float(rows[2]["robot_x_mm"]) == pytest.approx(doc["poses"][2]["robot_position_mm"][0])


def test_cli_bad_alphas_exit_2(tmp_path):
    res = CliRunner().invoke(app, ["sweep-plan", "--alphas", "5,x", "--out", str(tmp_path / "p.json")])
    assert res.exit_code == 2


# ------------------------------------------------------------- issue 14: every number bounded by physics


def _plan_cli(tmp_path, *args):
    out = tmp_path / "plan.json"
    res = CliRunner().invoke(app, ["sweep-plan", "--out", str(out), *args])
    return res, out


@pytest.mark.parametrize(
    ("args", "match"),
    [
        (["--push-depth", "1e9"], "dome height"),  # was: a pose 1000 km into the plate
        (["--push-depth", "-1"], "push depth"),
        (["--push-depth", "nan"], "finite"),
        (["--step", "1e-9"], "more than 100,000"),  # was: the machine out of memory
        (["--step", "0"], "theta step"),
        (["--step", "inf"], "finite"),
        (["--clearance", "1e7"], "clearance"),
        (["--diameters", "80", "--alphas", "50", "--push-depth", "20"], "base plate"),
    ],
)
def test_cli_out_of_physics_values_exit_2_and_write_nothing(tmp_path, args, match):
    res, out = _plan_cli(tmp_path, *args)
    assert res.exit_code == 2, res.output
    assert match in res.output
    assert not out.exists() and not out.with_suffix(".csv").exists()


def test_the_pose_count_is_checked_before_allocating():
    """A step of 1e-9 deg is refused at once (10^12 poses were allocated until the kernel killed us)."""
    with pytest.raises(InputError, match="poses"):
        sweep_plan(JIG, [50], [10], 1e-12)


def test_poses_beyond_the_robots_reach_are_refused(tmp_path):
    T = pose_from_rotvec_translation([0, 0, 0.2], [900.0, 0.0, 10.0])
    plan = sweep_plan(JIG, [50], [10], 90, T_robot_jig=T, reach_mm=1000.0)
    assert max(np.linalg.norm(p.T_robot_part[:3, 3]) for p in plan) <= 1000.0
    with pytest.raises(InputError, match="beyond its reach"):
        sweep_plan(JIG, [50], [10], 90, T_robot_jig=T, reach_mm=850.0)
    (tmp_path / "robot-jig.json").write_text(json.dumps({"T_robot_jig": T.tolist()}))
    res, out = _plan_cli(tmp_path, "--robot-jig", str(tmp_path / "robot-jig.json"), "--reach-mm", "850")
    assert res.exit_code == 2 and "beyond its reach" in res.output and not out.exists()
    res, _ = _plan_cli(tmp_path, "--reach-mm", "850")
    assert res.exit_code == 2 and "T_robot_jig" in res.output


def test_a_robot_jig_pose_that_is_not_rigid_is_refused(tmp_path):
    T = np.eye(4)
    T[:3, :3] *= 2.0
    with pytest.raises(InputError, match="not orthonormal"):
        sweep_plan(JIG, [50], [10], 90, T_robot_jig=T)
