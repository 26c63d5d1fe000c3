"""The robot's tilt-sweep plan: the poses of the paper's calibration experiment, in visiting order.

The paper's robot "grasps these objects and moves to the origin ... then moved ... in the Z direction
until it contacted the jig, and then it was tilted ... to the specified angles alpha ... from the center
of the contacting bottom", the tilt direction turning through 360° (Sakuma et al., "Jig Coordinate
Calibration"). For each part diameter the plan is:

1. ``approach``: the part upright above the jig axis, ``clearance_mm`` above the membrane's apex;
2. ``press``: upright, ``push_depth_mm`` below the *nominal* contact height (the membrane's rest outer
   apex). This is a guarded move's target: descend until the contact rule fires
   (:func:`softjig.planning.contact.detect_contact`), then go ``push_depth_mm`` further, and shift every
   later pose of this part by the measured contact height minus the nominal one;
3. ``tilt``: for each ``alpha`` (ascending), the part tilted by ``alpha`` towards ``theta`` = 0, step,
   ..., about the centre of its bottom face (``PartPose`` of the simulator: the same poses it renders);
4. ``press`` again (back upright), then ``retract`` (the approach pose); the robot then changes parts.

Poses are those of the **part frame** (origin at the centre of the part's bottom face, ``z`` along its
axis into the part, i.e. up) in J and, given ``T_robot_jig``, in the robot's base frame:
``T_robot_part = T_robot_jig @ T_J_part``. The robot's tool centre point must be defined at the centre of
the held part's bottom face with that orientation (a TCP whose ``z`` points out of the flange, down,
differs by a turn of 180° about ``x``). Quaternions are ``(x, y, z, w)``, scalar last (ROS's order).
Units: mm and degrees (this is an edge of the code: files a robot reads).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from softjig.config import JigConfig
from softjig.errors import InputError
from softjig.geometry import pose_from_rotation_translation

__all__ = ["MAX_CLEARANCE_MM", "MAX_POSES", "PHASES", "SweepPose", "sweep_plan", "sweep_plan_rows"]

PHASES = ("approach", "press", "tilt", "retract")
#: Most poses a plan may have (checked before any is made): the paper's sweep has 894; at a few seconds
#: a pose, 100,000 is days of robot time, and a theta step of 1e-9 deg would be 10^12 poses.
MAX_POSES = 100_000
#: Highest approach above the membrane (mm): a metre above the jig is outside any robot cell around it.
MAX_CLEARANCE_MM = 1000.0


@dataclass(frozen=True)
class SweepPose:
    """One pose of the plan.

    Attributes
    ----------
    index : position in the visiting order (from 0).
    phase : ``"approach"``, ``"press"``, ``"tilt"`` or ``"retract"``.
    diameter_mm, alpha_deg, theta_deg : the part and its tilt (``alpha = theta = 0`` upright).
    T_J_part : (4, 4) the part frame in J (mm).
    T_robot_part : (4, 4) the part frame in the robot base frame, or ``None`` without ``T_robot_jig``.
    """

    index: int
    phase: str
    diameter_mm: float
    alpha_deg: float
    theta_deg: float
    T_J_part: np.ndarray
    T_robot_part: np.ndarray | None

    def to_dict(self) -> dict:
        """Flat JSON/CSV row: ``position_mm`` ``[x, y, z]`` and ``quaternion_xyzw`` in J, and
        ``robot_position_mm``, ``robot_quaternion_xyzw`` when the robot frame is known."""
        row = {
            "index": self.index,
            "phase": self.phase,
            "diameter_mm": self.diameter_mm,
            "alpha_deg": self.alpha_deg,
            "theta_deg": self.theta_deg,
            "position_mm": [float(v) for v in self.T_J_part[:3, 3]],
            "quaternion_xyzw": _quat(self.T_J_part),
        }
        if self.T_robot_part is not None:
            row["robot_position_mm"] = [float(v) for v in self.T_robot_part[:3, 3]]
            row["robot_quaternion_xyzw"] = _quat(self.T_robot_part)
        return row


def _quat(T: np.ndarray) -> list[float]:
    q = Rotation.from_matrix(T[:3, :3]).as_quat()  # (x, y, z, w)
    if q[3] < 0:
        q = -q  # one of the two signs, always the same: w >= 0
    return [float(v) for v in q]


def _check(values: Sequence[float], name: str, lo: float, hi: float) -> list[float]:
    vals = [float(v) for v in values]
    if not vals:
        raise InputError(f"{name}: give at least one value")
    for v in vals:
        if not (math.isfinite(v) and lo < v < hi):
            raise InputError(f"{name}: {v} is out of range ({lo}, {hi})")
    return vals


def sweep_plan(
    jig: JigConfig,
    diameters_mm: Sequence[float],
    alphas_deg: Sequence[float],
    theta_step_deg: float,
    *,
    push_depth_mm: float = 3.0,
    clearance_mm: float = 20.0,
    T_robot_jig: np.ndarray | None = None,
    reach_mm: float | None = None,
) -> list[SweepPose]:
    """The poses of the paper's tilt sweep, in the order a robot should visit them (module docstring).

    Parameters
    ----------
    jig : the nominal jig (its membrane gives the nominal contact height).
    diameters_mm : the parts, in the order they are used.
    alphas_deg : tilt angles, each in (0, 60) degrees; visited in ascending order.
    theta_step_deg : step of the tilt direction in (0, 360] degrees; ``theta`` = 0, step, ... < 360.
    push_depth_mm : how far the part is pushed in after contact (mm), at most the membrane's dome height
        (deeper, the part would reach the base plate).
    clearance_mm : height of the approach pose above the membrane's apex (mm), at most
        :data:`MAX_CLEARANCE_MM`.
    T_robot_jig : (4, 4) the jig's pose in the robot base frame (:mod:`softjig.calibration.alignment`):
        a rigid pose (:func:`~softjig.calibration.alignment.check_pose`).
    reach_mm : the robot's reach (mm from the origin of its base frame); with ``T_robot_jig``, every pose
        must lie within it.

    Raises
    ------
    InputError
        An out-of-range or non-finite value; more than :data:`MAX_POSES` poses (before any is made); a
        part wider than the membrane; a tilted part whose rim would reach the base plate; a pose out of
        the robot's reach.
    """
    from softjig.calibration.alignment import check_pose
    from softjig.config import CylinderPart, validate_part
    from softjig.jig_shape import rest_outer_height_mm
    from softjig.sim.parts import PartPose
    from softjig.sim.scenarios import theta_values_deg

    diameters = _check(diameters_mm, "diameters", 0.0, math.inf)
    alphas = sorted(_check(alphas_deg, "alphas", 0.0, 60.0))
    step = float(theta_step_deg)
    if not (math.isfinite(step) and 0.0 < step <= 360.0):
        raise InputError(f"the theta step must be in (0, 360] degrees, got {theta_step_deg}")
    n_theta = math.ceil(360.0 / step - 1e-9)
    n_poses = len(diameters) * (4 + len(alphas) * n_theta)
    if n_poses > MAX_POSES:
        raise InputError(
            f"the plan would have {n_poses:.4g} poses ({n_theta:.4g} tilt directions per tilt at a theta "
            f"step of {step:g} deg), more than {MAX_POSES:,}: use a coarser step (the paper's is 10 deg)"
        )
    thetas = theta_values_deg(step)
    dome = jig.membrane.dome_height_mm
    for name, v, hi, why in (
        ("push depth", push_depth_mm, dome, "the membrane's dome height: deeper, the part reaches the plate"),
        ("clearance", clearance_mm, MAX_CLEARANCE_MM, "a metre above the jig"),
    ):
        if not (math.isfinite(v) and 0 <= v <= hi):
            raise InputError(f"the {name} must be between 0 and {hi:g} mm ({why}), got {v}")
    for d in diameters:
        validate_part(CylinderPart(d), jig)
    T_rj = None if T_robot_jig is None else check_pose(T_robot_jig, "T_robot_jig")
    if reach_mm is not None:
        if not (math.isfinite(reach_mm) and reach_mm > 0):
            raise InputError(f"the robot's reach must be a positive number of mm, got {reach_mm}")
        if T_rj is None:
            raise InputError("a robot reach needs the jig's pose in the robot frame (T_robot_jig)")
    apex = float(rest_outer_height_mm(jig, np.array([0.0]), np.array([0.0]))[0])
    floor = jig.membrane.thickness_mm  # the membrane stays between the part and the plate's top (z = 0)
    for d in diameters:
        lowest = apex - push_depth_mm - d / 2 * math.sin(math.radians(alphas[-1]))
        if lowest <= floor:
            raise InputError(
                f"tilted by {alphas[-1]:g} deg after a push of {push_depth_mm:g} mm, the rim of the "
                f"{d:g} mm part would be {lowest:.1f} mm above the base plate, less than the membrane's "
                f"{floor:g} mm: push less or tilt less"
            )
    upright = np.eye(3)
    plan: list[SweepPose] = []

    def add(phase: str, d: float, a: float, t: float, T_J_part: np.ndarray) -> None:
        T_r = None if T_rj is None else T_rj @ T_J_part
        plan.append(SweepPose(len(plan), phase, d, a, t, T_J_part, T_r))

    for d in diameters:
        above = pose_from_rotation_translation(upright, np.array([0.0, 0.0, apex + clearance_mm]))
        pressed = pose_from_rotation_translation(upright, np.array([0.0, 0.0, apex - push_depth_mm]))
        add("approach", d, 0.0, 0.0, above)
        add("press", d, 0.0, 0.0, pressed)
        for a in alphas:
            for t in thetas:
                pose = PartPose(math.radians(a), math.radians(t), push_depth_mm)
                add("tilt", d, a, t, pose.T_J_part(jig))
        add("press", d, 0.0, 0.0, pressed)
        add("retract", d, 0.0, 0.0, above)
    if reach_mm is not None:
        far = max(plan, key=lambda p: float(np.linalg.norm(p.T_robot_part[:3, 3])))
        distance = float(np.linalg.norm(far.T_robot_part[:3, 3]))
        if distance > reach_mm:
            raise InputError(
                f"pose {far.index} ({far.phase}, D = {far.diameter_mm:g} mm) is {distance:.1f} mm from the "
                f"robot's base, beyond its reach of {reach_mm:g} mm: move the jig closer or check T_robot_jig"
            )
    return plan


def sweep_plan_rows(plan: Sequence[SweepPose]) -> list[dict]:
    """The plan as flat rows for CSV (vectors split into ``x_mm``, ``qx`` ... columns)."""
    rows = []
    for p in plan:
        d = p.to_dict()
        row = {k: d[k] for k in ("index", "phase", "diameter_mm", "alpha_deg", "theta_deg")}
        row.update(zip(("x_mm", "y_mm", "z_mm"), d["position_mm"], strict=True))
        row.update(zip(("qx", "qy", "qz", "qw"), d["quaternion_xyzw"], strict=True))
        if "robot_position_mm" in d:
            row.update(zip(("robot_x_mm", "robot_y_mm", "robot_z_mm"), d["robot_position_mm"], strict=True))
            row.update(
                zip(("robot_qx", "robot_qy", "robot_qz", "robot_qw"), d["robot_quaternion_xyzw"], strict=True)
            )
        rows.append(row)
    return rows
