"""Motion-capture ground truth: T_d = inv(T_j) T_o, n_d = R_d z on hand-made poses; Motive's CSV export."""

# ruff: noqa: E501 - the Motive export below keeps its real, long lines

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from softjig.errors import InputError
from softjig.evaluation.mocap import (
    mocap_normals,
    motive_csv_text,
    normals_at,
    parse_motive_csv,
    read_motive_csv,
    relative_poses,
)
from softjig.geometry import pose_from_rotation_translation


def _pose(rotvec_deg, t_mm):
    return pose_from_rotation_translation(
        Rotation.from_rotvec(np.radians(rotvec_deg)).as_matrix(), np.asarray(t_mm, float)
    )


def test_identity_jig_object_tilted_about_x():
    # object rotated +10 deg about x: its z axis goes to (0, -sin 10, cos 10), i.e. Ax = +10 deg
    n = mocap_normals(np.eye(4), _pose([10, 0, 0], [0, 0, 30]))
    assert np.allclose(n, [0, -np.sin(np.radians(10)), np.cos(np.radians(10))], atol=1e-12)


def test_jig_pose_cancels_out():
    T_j = _pose([-90, 0, 0], [150.0, 740.0, -1200.0])  # a y-up mocap frame, far from the origin
    T_rel = _pose([0, 12, 0], [3, -2, 28])  # tilt 12 deg about y: n = (sin 12, 0, cos 12)
    T_o = T_j @ T_rel
    assert np.allclose(relative_poses(T_j, T_o), T_rel, atol=1e-9)
    n = mocap_normals(T_j, T_o)
    assert np.allclose(n, [np.sin(np.radians(12)), 0, np.cos(np.radians(12))], atol=1e-12)
    # batched, with a yaw of the jig per frame
    T_js = np.array([_pose([0, 0, yaw], [0, 0, 0]) @ T_j for yaw in (0, 30, 60)])
    T_os = np.array([T @ T_rel for T in T_js])
    assert np.allclose(mocap_normals(T_js, T_os), n, atol=1e-12)


def test_jig_body_offset_and_object_axis():
    # J is the jig body's frame turned 90 deg about z: a normal along body +x is J's -y
    T_jigbody_J = _pose([0, 0, 90], [0, 0, 0])
    n = mocap_normals(np.eye(4), np.eye(4), T_jigbody_J=T_jigbody_J, object_axis=(1, 0, 0))
    assert np.allclose(n, [0, -1, 0], atol=1e-12)
    with pytest.raises(InputError, match="object_axis"):
        mocap_normals(np.eye(4), np.eye(4), object_axis=(0, 0, 0))
    with pytest.raises(InputError, match="4x4"):
        relative_poses(np.eye(3), np.eye(4))


# A small export in Motive's documented layout, written by hand: metadata line, blank line, Type / Name /
# ID rows, the component row, the axis row; the jig also exports a marker (to be ignored) and the cube is
# occluded in frame 2 (empty cells). Units: meters. Frame 0: cube 10 deg about x, 30 mm above the jig.
_S, _C = np.sin(np.radians(5)), np.cos(np.radians(5))  # quaternion of 10 deg about x: (sin 5, 0, 0, cos 5)
MOTIVE = f"""Format Version,1.23,Take Name,cube_take,Take Notes,,Capture Frame Rate,120.000000,Export Frame Rate,120.000000,Capture Start Time,2023-06-02 12.09.45.344 PM,Capture Start Frame,100,Total Frames in Take,3,Total Exported Frames,3,Rotation Type,Quaternion,Length Units,Meters,Coordinate Space,Global

,Type,Rigid Body,Rigid Body,Rigid Body,Rigid Body,Rigid Body,Rigid Body,Rigid Body,Rigid Body,Rigid Body Marker,Rigid Body Marker,Rigid Body Marker,Marker Quality,Rigid Body,Rigid Body,Rigid Body,Rigid Body,Rigid Body,Rigid Body,Rigid Body,Rigid Body
,Name,jig,jig,jig,jig,jig,jig,jig,jig,jig:Marker1,jig:Marker1,jig:Marker1,jig:Marker1,cube,cube,cube,cube,cube,cube,cube,cube
,ID,1,1,1,1,1,1,1,1,1,1,1,1,2,2,2,2,2,2,2,2
,,Rotation,Rotation,Rotation,Rotation,Position,Position,Position,Mean Marker Error,Position,Position,Position,,Rotation,Rotation,Rotation,Rotation,Position,Position,Position,Mean Marker Error
Frame,Time (Seconds),X,Y,Z,W,X,Y,Z,,X,Y,Z,,X,Y,Z,W,X,Y,Z,
0,0.000000,0,0,0,1,0.1,0.2,0.3,0.0002,0.11,0.2,0.3,1,{_S:.9f},0,0,{_C:.9f},0.1,0.2,0.33,0.0001
1,0.008333,0,0,0,1,0.1,0.2,0.3,0.0002,0.11,0.2,0.3,1,0,0,0,1,0.1,0.2,0.33,0.0001
2,0.016667,0,0,0,1,0.1,0.2,0.3,0.0002,0.11,0.2,0.3,1,,,,,,,,
"""


def test_parse_a_hand_written_motive_export(tmp_path):
    path = tmp_path / "take.csv"
    path.write_text(MOTIVE)
    take = read_motive_csv(path)
    assert take.metadata["Take Name"] == "cube_take" and take.metadata["Length Units"] == "Meters"
    assert list(take.bodies) == ["jig", "cube"]  # the marker columns are not rigid bodies
    assert take.frame.tolist() == [0, 1, 2] and take.time_s[1] == pytest.approx(1 / 120, abs=1e-6)
    jig, cube = take.body("jig"), take.body("cube")
    assert jig.id == "1" and cube.id == "2"
    assert np.allclose(jig.position_mm[0], [100, 200, 300])  # meters -> mm
    assert cube.mean_marker_error_mm[0] == pytest.approx(0.1)
    assert cube.tracked.tolist() == [True, True, False]
    n = normals_at(take, jig_body="jig", object_body="cube", frames=[0, 1, 2, 7])
    assert np.allclose(n[0], [0, -np.sin(np.radians(10)), np.cos(np.radians(10))], atol=1e-8)
    assert np.allclose(n[1], [0, 0, 1], atol=1e-12)
    assert np.isnan(n[2]).all() and np.isnan(n[3]).all()  # occluded; not in the take
    by_time = normals_at(take, jig_body="jig", object_body="cube", times_s=[0.001, 0.0085, 5.0])
    assert np.allclose(by_time[:2], n[:2]) and np.isnan(by_time[2]).all()
    T = relative_poses(jig.poses()[0], cube.poses()[0])
    assert np.allclose(T[:3, 3], [0, 0, 30], atol=1e-9)
    with pytest.raises(InputError, match="no rigid body 'robot'"):
        take.body("robot")


def test_writer_round_trip_in_every_unit():
    rng = np.random.default_rng(0)
    poses = np.array([_pose(rng.normal(size=3) * 20, rng.normal(size=3) * 500) for _ in range(4)])
    poses[2] = np.nan
    for units in ("Meters", "Centimeters", "Millimeters"):
        take = parse_motive_csv(motive_csv_text({"a": poses, "b": poses[::-1]}, units=units))
        back = take.body("a").poses()
        assert np.isnan(back[2]).all()
        keep = [0, 1, 3]
        assert np.allclose(back[keep], poses[keep], atol=1e-5)


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("Frame,Time\n0,0\n", "Format Version"),
        (MOTIVE.replace("Rotation Type,Quaternion", "Rotation Type,XYZ"), "Quaternion"),
        (MOTIVE.replace("Length Units,Meters", "Length Units,Furlongs"), "Length Units"),
        (MOTIVE.replace("Frame,Time", "Frm,Time"), "Frame"),
        (MOTIVE.replace("0,0.000000,0,0,0,1", "0,0.000000,x,0,0,1"), "not a number"),
    ],
)
def test_bad_exports_say_what_to_do(text, message):
    with pytest.raises(InputError, match=message):
        parse_motive_csv(text)


def test_missing_file():
    with pytest.raises(InputError, match="does not exist"):
        read_motive_csv("/nonexistent/take.csv")
