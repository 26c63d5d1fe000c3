"""`softjig sweep-plan`: the robot's tilt-sweep poses; `softjig align-jig`: the jig's pose in the robot
frame from a hand-eye image of its four alignment circles (issue 7)."""

from __future__ import annotations

import csv
import io
import json
from pathlib import Path
from typing import Annotated

import numpy as np
import typer

from softjig.cli.app import app, handle_errors, load_config, parse_numbers, warn
from softjig.errors import InputError


def _read_json(path: Path, what: str) -> dict:
    try:
        data = json.loads(Path(path).read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise InputError(f"{what} file {path} does not exist") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(f"cannot read {what} file {path}: {exc}") from None
    if not isinstance(data, dict):
        raise InputError(f"{what} file {path} must hold a JSON object")
    return data


def _pose_from(data: dict, key: str, path: Path) -> np.ndarray:
    """A 4x4 pose from ``{key: 4x4}`` or ``{"position_mm": [..], "quaternion_xyzw": [..]}``."""
    from scipy.spatial.transform import Rotation

    if key in data:
        T = np.asarray(data[key], dtype=float)
        if T.shape != (4, 4) or not np.allclose(T[3], [0, 0, 0, 1]):
            raise InputError(f"{path}: {key} must be a 4x4 homogeneous matrix (mm)")
        return T
    if "position_mm" in data and "quaternion_xyzw" in data:
        T = np.eye(4)
        T[:3, :3] = Rotation.from_quat(np.asarray(data["quaternion_xyzw"], float)).as_matrix()
        T[:3, 3] = np.asarray(data["position_mm"], float)
        return T
    raise InputError(f"{path}: give {key} (a 4x4 matrix) or position_mm and quaternion_xyzw (x, y, z, w)")


@app.command("sweep-plan")
@handle_errors
def sweep_plan(
    diameters: Annotated[str, typer.Option(help="Part diameters (mm), e.g. 30,50,80.")] = "30,50,80",
    alphas: Annotated[str, typer.Option(help="Tilt angles (deg), e.g. 5,10,15,20.")] = "5,10,15,20",
    step: Annotated[float, typer.Option(help="Step of the tilt direction theta (deg).")] = 10.0,
    out: Annotated[Path, typer.Option(help="The plan, JSON.")] = Path("sweep-plan.json"),
    csv_out: Annotated[
        Path | None, typer.Option("--csv", help="The plan, CSV.", show_default="OUT with .csv")
    ] = None,
    config: Annotated[Path | None, typer.Option(help="The nominal jig (rig.toml).")] = None,
    robot_jig: Annotated[
        Path | None,
        typer.Option(help="JSON with T_robot_jig (written by `softjig align-jig`): adds robot-frame poses."),
    ] = None,
    push_depth: Annotated[float, typer.Option(help="Push after contact (mm).")] = 3.0,
    clearance: Annotated[float, typer.Option(help="Approach height above the membrane (mm).")] = 20.0,
) -> None:
    """Write the tilt sweep's poses (position, quaternion x,y,z,w) in J and the robot frame, in order."""
    from softjig.io.files import write_text_atomic
    from softjig.planning import sweep_plan as make_plan
    from softjig.planning import sweep_plan_rows
    from softjig.planning.contact import CONTACT_THRESHOLD_N

    jig = load_config(config)
    T = _pose_from(_read_json(robot_jig, "--robot-jig"), "T_robot_jig", robot_jig) if robot_jig else None
    plan = make_plan(
        jig,
        parse_numbers(diameters, "--diameters"),
        parse_numbers(alphas, "--alphas"),
        step,
        push_depth_mm=push_depth,
        clearance_mm=clearance,
        T_robot_jig=T,
    )
    doc = {
        "frame": "part frame (origin at the centre of the part's bottom face, z into the part) in J"
        + (" and in the robot base frame" if T is not None else ""),
        "units": {"position": "mm", "angles": "deg", "quaternion": "x, y, z, w"},
        "contact_rule": {
            "force_change_N": CONTACT_THRESHOLD_N,
            "note": "descend to each 'press' pose; stop when the wrist force changes by this "
            "much, then push push_depth_mm further",
        },
        "push_depth_mm": push_depth,
        "T_robot_jig": None if T is None else T.tolist(),
        "poses": [p.to_dict() for p in plan],
    }
    write_text_atomic(out, json.dumps(doc, indent=1) + "\n")
    rows = sweep_plan_rows(plan)
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=list(rows[0]), lineterminator="\n")
    writer.writeheader()
    writer.writerows(rows)
    csv_path = csv_out or out.with_suffix(".csv")
    write_text_atomic(csv_path, buf.getvalue())
    n_tilt = sum(p.phase == "tilt" for p in plan)
    typer.echo(f"wrote {len(plan)} poses ({n_tilt} tilted) to {out} and {csv_path}")
    if T is None:
        warn("no --robot-jig given: the poses are in the jig frame J only")


@app.command("align-jig")
@handle_errors
def align_jig(
    image: Annotated[Path, typer.Argument(help="The hand-eye camera's image of the jig's four circles.")],
    camera: Annotated[
        Path,
        typer.Option(
            help="JSON: the hand-eye camera (width_px, height_px, fx_px, fy_px, cx_px, cy_px, "
            "distortion) and T_flange_cam (4x4, mm).",
            show_default=False,
        ),
    ],
    flange: Annotated[
        Path,
        typer.Option(
            help="JSON: the flange pose when the image was taken: T_robot_flange (4x4) or "
            "position_mm + quaternion_xyzw.",
            show_default=False,
        ),
    ],
    out: Annotated[Path, typer.Option(help="Where to write T_robot_jig (JSON).")] = Path("robot-jig.json"),
    config: Annotated[Path | None, typer.Option(help="The jig (alignment circles).")] = None,
    prior_yaw_deg: Annotated[
        float, typer.Option(help="Roughly how the jig is turned about the robot's z (deg); within 45 deg.")
    ] = 0.0,
    json_output: Annotated[bool, typer.Option("--json", help="Print one JSON object.")] = False,
) -> None:
    """Find the jig's pose in the robot base frame (T_robot_jig) by PnP on its four white circles."""
    from scipy.spatial.transform import Rotation

    from softjig.calibration.alignment import align_jig_to_robot
    from softjig.config import CameraConfig
    from softjig.io.dataset import load_image
    from softjig.io.files import write_text_atomic

    jig = load_config(config)
    cam_data = _read_json(camera, "--camera")
    T_flange_cam = _pose_from(cam_data, "T_flange_cam", camera)
    fields = ("width_px", "height_px", "fx_px", "fy_px", "cx_px", "cy_px", "distortion")
    try:
        intrinsics = CameraConfig(
            **{k: (tuple(cam_data[k]) if k == "distortion" else cam_data[k]) for k in fields if k in cam_data}
        )
    except TypeError as exc:
        raise InputError(f"{camera}: {exc}") from None
    T_robot_flange = _pose_from(_read_json(flange, "--flange"), "T_robot_flange", flange)
    prior = Rotation.from_euler("z", prior_yaw_deg, degrees=True).as_matrix()
    result = align_jig_to_robot(
        load_image(image), jig, intrinsics, T_robot_flange, T_flange_cam, R_robot_jig_prior=prior
    )
    data = result.to_dict()
    write_text_atomic(out, json.dumps(data, indent=1) + "\n")
    for message in result.warnings:
        warn(message)
    if json_output:
        typer.echo(json.dumps(data))
        return
    T = result.T_robot_jig
    rot = Rotation.from_matrix(T[:3, :3]).as_rotvec(degrees=True)
    typer.echo(
        f"T_robot_jig: position ({T[0, 3]:.2f}, {T[1, 3]:.2f}, {T[2, 3]:.2f}) mm, rotation vector "
        f"({rot[0]:.3f}, {rot[1]:.3f}, {rot[2]:.3f}) deg; circles' reprojection RMS "
        f"{result.reprojection_rms_px:.3f} px; wrote {out}"
    )
