"""`softjig align-jig`: the jig's pose in the robot base frame from a hand-eye image."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

import typer

from softjig.cli.app import app, handle_errors, load_config, pose_from_json, read_json_file, warn
from softjig.errors import InputError


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
        float,
        typer.Option(
            min=-180.0,
            max=180.0,
            help="Roughly how the jig is turned about the robot's z (deg); within 45 deg.",
        ),
    ] = 0.0,
    max_reprojection_px: Annotated[
        float,
        typer.Option(
            min=0.1,
            max=20.0,
            help="Refuse a pose whose circles reproject with a larger RMS (px): a right one is within ~1 px.",
        ),
    ] = 2.0,
    json_output: Annotated[bool, typer.Option("--json", help="Print one JSON object.")] = False,
) -> None:
    """Find the jig's pose in the robot base frame (T_robot_jig) by PnP on its four white circles."""
    from scipy.spatial.transform import Rotation

    from softjig.calibration.alignment import align_jig_to_robot, check_intrinsics
    from softjig.config import CameraConfig
    from softjig.files import write_text_atomic
    from softjig.io.dataset import load_image
    from softjig.io.outputs import check_output

    check_output(out, "--out", [image, camera, flange, config])
    jig = load_config(config)
    cam_data = read_json_file(camera, "--camera")
    T_flange_cam = pose_from_json(cam_data, "T_flange_cam", camera)
    fields = ("width_px", "height_px", "fx_px", "fy_px", "cx_px", "cy_px", "distortion")
    missing = [k for k in fields if k not in cam_data and k != "distortion"]  # distortion: 0 if not given
    if missing:
        raise InputError(f"{camera}: give the hand-eye camera's {', '.join(missing)}")
    try:
        intrinsics = CameraConfig(
            **{k: (tuple(cam_data[k]) if k == "distortion" else cam_data[k]) for k in fields if k in cam_data}
        )
    except TypeError as exc:
        raise InputError(f"{camera}: {exc}") from None
    try:
        check_intrinsics(intrinsics)
    except InputError as exc:
        raise InputError(f"{camera}: {exc}") from None
    T_robot_flange = pose_from_json(read_json_file(flange, "--flange"), "T_robot_flange", flange)
    prior = Rotation.from_euler("z", prior_yaw_deg, degrees=True).as_matrix()
    result = align_jig_to_robot(
        load_image(image),
        jig,
        intrinsics,
        T_robot_flange,
        T_flange_cam,
        R_robot_jig_prior=prior,
        max_reprojection_px=max_reprojection_px,
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
