"""`softjig sweep-plan`: the robot's tilt-sweep poses; `softjig align-jig`: the jig's pose in the robot
frame from a hand-eye image of its four alignment circles."""

from __future__ import annotations

import csv
import io
import json
from pathlib import Path
from typing import Annotated

import typer

from softjig.cli.app import (
    app,
    handle_errors,
    load_config,
    parse_numbers,
    pose_from_json,
    read_json_file,
    warn,
)


@app.command("sweep-plan")
@handle_errors
def sweep_plan(
    diameters: Annotated[str, typer.Option(help="Part diameters (mm), e.g. 30,50,80.")] = "30,50,80",
    alphas: Annotated[str, typer.Option(help="Tilt angles (deg), e.g. 5,10,15,20.")] = "5,10,15,20",
    step: Annotated[float, typer.Option(help="Step of the tilt direction theta (deg), in (0, 360].")] = 10.0,
    out: Annotated[Path, typer.Option(help="The plan, JSON.")] = Path("sweep-plan.json"),
    csv_out: Annotated[
        Path | None, typer.Option("--csv", help="The plan, CSV.", show_default="OUT with .csv")
    ] = None,
    config: Annotated[Path | None, typer.Option(help="The nominal jig (rig.toml).")] = None,
    robot_jig: Annotated[
        Path | None,
        typer.Option(help="JSON with T_robot_jig (written by `softjig align-jig`): adds robot-frame poses."),
    ] = None,
    push_depth: Annotated[
        float, typer.Option(help="Push after contact (mm), at most the membrane's dome height.")
    ] = 3.0,
    clearance: Annotated[
        float, typer.Option(help="Approach height above the membrane (mm), at most 1000.")
    ] = 20.0,
    reach: Annotated[
        float | None,
        typer.Option(
            "--reach-mm",
            help="The robot's reach (mm from its base frame's origin): refuse a plan with a pose beyond it "
            "(needs --robot-jig).",
            show_default=False,
        ),
    ] = None,
) -> None:
    """Write the tilt sweep's poses (position, quaternion x,y,z,w) in J and the robot frame, in order."""
    from softjig.files import write_text_atomic
    from softjig.io.outputs import check_output
    from softjig.planning import sweep_plan as make_plan
    from softjig.planning import sweep_plan_rows
    from softjig.planning.contact import CONTACT_THRESHOLD_N

    check_output(out, "--out", [config, robot_jig, csv_out])
    if csv_out is not None:
        check_output(csv_out, "--csv-out", [config, robot_jig])
    jig = load_config(config)
    T = None
    if robot_jig:
        T = pose_from_json(read_json_file(robot_jig, "--robot-jig"), "T_robot_jig", robot_jig)
    plan = make_plan(
        jig,
        parse_numbers(diameters, "--diameters"),
        parse_numbers(alphas, "--alphas"),
        step,
        push_depth_mm=push_depth,
        clearance_mm=clearance,
        T_robot_jig=T,
        reach_mm=reach,
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
