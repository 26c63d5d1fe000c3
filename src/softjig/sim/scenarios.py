"""What to render: the paper's experiments as lists of frames, and the ground truth of each frame.

A scenario is a sequence of :class:`FrameSpec` (a part, its pose and the frame's metadata), a pure
description with nothing rendered. :func:`softjig.io.simulated.simulate_dataset` draws an as-built jig from
a seed, renders every spec with :func:`softjig.sim.render.render_pair` and writes a dataset
(:mod:`softjig.io.dataset`) with the ground truth of each frame (:func:`frame_truth`).

Ground truth written per frame (``truth`` in ``frames.jsonl``)
---------------------------------------------------------------
- ``normal``: the part's true principal normal in J, ``T_J_part[:3, 2]`` (its bottom face's normal).
- ``push_depth_mm`` (``DESIGN.md`` §1: how far the markers' plane lies below the undeformed membrane on
  the jig axis): ``h_rest_inner(0, 0) - (z_face(0, 0) - t / n_z)``, where ``h_rest_inner`` is the rest
  height of the membrane's inner face (where the markers are), ``z_face(0, 0)`` the height of the plane of
  the part's bottom face above the jig axis, ``t`` the membrane thickness and ``n_z`` the normal's ``z``.
  In contact the inner face lies on the face's plane shifted down by ``t / n_z``
  (:mod:`softjig.sim.membrane`), so ``z_face(0, 0) - t / n_z`` is where the markers' plane crosses the
  axis. For a part centred on the axis this is ``push_depth_mm + t (1 / cos(alpha) - 1)``: the commanded
  push depth (measured on the outer face) plus a small tilt term.
- ``T_J_part``: the part's true 4x4 pose in J; ``markers``: the frame's truth ``.npz``.

Random numbers: the as-built jig is drawn from ``SeedSequence(seed, spawn_key=(0,))`` and frame ``i`` is
rendered with ``SeedSequence(seed, spawn_key=(1, i))``, so a dataset depends on the seed only, never on
the number of worker processes.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from softjig.config import CylinderPart, JigConfig, Part, cube, part_to_dict, validate_part
from softjig.errors import InputError
from softjig.jig_shape import rest_inner_height_mm
from softjig.sim.parts import PartPose, bottom_face_rim, bottom_plane_height_mm

__all__ = [
    "FrameSpec",
    "cube_experiment",
    "frame_truth",
    "paper_sweep",
    "single",
]

PAPER_DIAMETERS_MM = (30.0, 40.0, 50.0, 60.0, 70.0, 80.0)
PAPER_ALPHAS_DEG = (5.0, 10.0, 15.0, 20.0)
CYLINDER_HEIGHT_MM = 30.0


@dataclass(frozen=True)
class FrameSpec:
    """One frame to render: a part and its pose (both ``None`` for the unloaded jig) and the metadata to
    write in ``frames.jsonl`` (degrees at this edge: ``alpha_deg``, ``theta_deg``, ``part``, ...)."""

    part: Part | None
    pose: PartPose | None
    meta: dict[str, Any] = field(default_factory=dict, hash=False)

    def __post_init__(self) -> None:
        if (self.part is None) != (self.pose is None):
            raise ValueError("FrameSpec needs both a part and a pose, or neither (the unloaded jig)")


def _reference() -> FrameSpec:
    return FrameSpec(None, None, {"reference": True})


def _loaded(part: Part, pose: PartPose) -> FrameSpec:
    meta = {
        "alpha_deg": math.degrees(pose.alpha_rad),
        "theta_deg": math.degrees(pose.theta_rad),
        "part": part_to_dict(part),
        "pose": {
            "push_depth_mm": pose.push_depth_mm,
            "center_xy_mm": list(pose.center_xy_mm),
            "yaw_deg": math.degrees(pose.yaw_rad),
        },
    }
    return FrameSpec(part, pose, meta)


def _check_alpha(alpha_deg: float) -> None:
    if not (math.isfinite(alpha_deg) and 0.0 <= alpha_deg < 90.0):
        raise InputError(f"a tilt alpha must be in [0, 90) degrees, got {alpha_deg}")


def _check_push(push_depth_mm: float) -> None:
    if not (math.isfinite(push_depth_mm) and push_depth_mm > 0):
        raise InputError(
            f"the push depth must be a positive number of mm (the part must touch the membrane), "
            f"got {push_depth_mm}"
        )


MIN_FACE_HEIGHT_MM = 2.0  # the membrane and its markers need this much room above the plate


def check_reachable(jig: JigConfig, spec: FrameSpec) -> None:
    """Raise :class:`InputError` if a spec's part would push its bottom face down into the plate.

    The lowest point of the face's edge must stay :data:`MIN_FACE_HEIGHT_MM` above the plate's top face
    (the membrane and its hemispherical markers lie between them).
    """
    if spec.part is None or spec.pose is None:
        return
    T = spec.pose.T_J_part(jig)
    lowest = float(bottom_face_rim(spec.part, T, 2.0)[:, 2].min())
    if lowest < MIN_FACE_HEIGHT_MM:
        raise InputError(
            f"a {spec.part.kind} of {spec.part.diameter_mm:g} mm tilted by "
            f"{math.degrees(spec.pose.alpha_rad):g} deg and pushed {spec.pose.push_depth_mm:g} mm would "
            f"reach z = {lowest:.1f} mm, into the plate (the membrane needs {MIN_FACE_HEIGHT_MM:g} mm): "
            "reduce the push depth or the tilt"
        )


def theta_count(theta_step_deg: float) -> int:
    """How many azimuths :func:`theta_values_deg` gives for ``theta_step_deg`` (deg), without listing them
    (a study refuses a step that gives too many)."""
    if not (math.isfinite(theta_step_deg) and 0.0 < theta_step_deg <= 360.0):
        raise InputError(f"the theta step must be in (0, 360] degrees, got {theta_step_deg}")
    return math.ceil(360.0 / theta_step_deg - 1e-9)


def theta_values_deg(theta_step_deg: float) -> list[float]:
    """The azimuths ``0, step, 2 step, ...`` below 360 degrees."""
    return [i * theta_step_deg for i in range(theta_count(theta_step_deg))]


def paper_sweep(
    diameters_mm: Sequence[float] = PAPER_DIAMETERS_MM,
    alphas_deg: Sequence[float] = PAPER_ALPHAS_DEG,
    theta_step_deg: float = 10.0,
    push_depth_mm: float = 3.0,
    reference: bool = True,
) -> Iterator[FrameSpec]:
    """The paper's tilt sweep: each cylinder (30 mm high), centred on the jig axis, pushed in by
    ``push_depth_mm`` and tilted about the centre of its bottom face by each ``alpha`` while ``theta``
    turns through ``[0, 360)`` in steps of ``theta_step_deg``.

    Yields the unloaded reference frame first (if ``reference``), then the frames in the order diameter,
    alpha, theta: ``1 + len(diameters) * len(alphas) * ceil(360 / step)`` frames (865 by default).

    Raises
    ------
    InputError
        A diameter that is not positive, an alpha outside ``[0, 90)``, a step outside ``(0, 360]``.
    """
    diameters = [float(d) for d in diameters_mm]
    alphas = [float(a) for a in alphas_deg]
    thetas = theta_values_deg(float(theta_step_deg))
    _check_push(push_depth_mm)
    if not diameters:
        raise InputError("the paper sweep needs at least one part diameter")
    if not alphas:
        raise InputError("the paper sweep needs at least one tilt alpha")
    for d in diameters:
        if not (math.isfinite(d) and d > 0):
            raise InputError(f"a part diameter must be a positive number of mm, got {d}")
    for a in alphas:
        _check_alpha(a)
    if reference:
        yield _reference()
    for d in diameters:
        part = CylinderPart(diameter_mm=d, height_mm=CYLINDER_HEIGHT_MM)
        for a in alphas:
            for t in thetas:
                pose = PartPose(
                    alpha_rad=math.radians(a), theta_rad=math.radians(t), push_depth_mm=float(push_depth_mm)
                )
                yield _loaded(part, pose)


def cube_experiment(
    n_frames: int = 60,
    side_mm: float = 50.0,
    max_alpha_deg: float = 15.0,
    rng: np.random.Generator | int | None = None,
    *,
    push_depth_mm: float = 3.0,
    max_offset_mm: float = 3.0,
    reference: bool = True,
) -> list[FrameSpec]:
    """The paper's motion-capture experiment: the cube pressed in at varied random orientations.

    Each of the ``n_frames`` loaded frames draws, independently and uniformly, a tilt ``alpha`` in
    ``[0, max_alpha_deg]``, an azimuth ``theta`` in ``[0, 360)``, a yaw about the cube's own axis in
    ``[0, 90)`` degrees (the cube's symmetry) and an offset of the bottom face's centre from the jig axis
    uniform in the disc of radius ``max_offset_mm``; the push depth is ``push_depth_mm``. The unloaded
    reference frame comes first if ``reference`` (so ``n_frames + 1`` frames).
    """
    if n_frames < 1:
        raise InputError(f"the cube experiment needs at least one frame, got {n_frames}")
    _check_alpha(max_alpha_deg)
    _check_push(push_depth_mm)
    if not (math.isfinite(max_offset_mm) and max_offset_mm >= 0):
        raise InputError(f"the cube's offset must be zero or positive, got {max_offset_mm}")
    part = cube(float(side_mm))
    validate_part(part)
    rng = np.random.default_rng(rng)
    specs = [_reference()] if reference else []
    for _ in range(int(n_frames)):
        alpha = rng.uniform(0.0, math.radians(max_alpha_deg))
        theta = rng.uniform(0.0, 2 * math.pi)
        yaw = rng.uniform(0.0, math.pi / 2)
        radius = max_offset_mm * math.sqrt(rng.uniform())
        phi = rng.uniform(0.0, 2 * math.pi)
        pose = PartPose(
            alpha_rad=float(alpha),
            theta_rad=float(theta),
            push_depth_mm=float(push_depth_mm),
            center_xy_mm=(radius * math.cos(phi), radius * math.sin(phi)),
            yaw_rad=float(yaw),
        )
        specs.append(_loaded(part, pose))
    return specs


def single(
    part: Part, alpha_deg: float, theta_deg: float, push_depth_mm: float = 3.0, *, reference: bool = False
) -> list[FrameSpec]:
    """One part, centred on the jig axis, tilted by ``alpha_deg`` towards ``theta_deg`` (one frame; the
    unloaded reference frame first if ``reference``)."""
    _check_alpha(float(alpha_deg))
    _check_push(push_depth_mm)
    validate_part(part)
    pose = PartPose(
        alpha_rad=math.radians(alpha_deg),
        theta_rad=math.radians(theta_deg),
        push_depth_mm=float(push_depth_mm),
    )
    return [*([_reference()] if reference else []), _loaded(part, pose)]


# ---------------------------------------------------------------------------------------- truth


def frame_truth(jig: JigConfig, pose: PartPose) -> dict[str, Any]:
    """The ``truth`` entry of a loaded frame (JSON-ready): ``normal``, ``push_depth_mm``, ``T_J_part``.

    See the module docstring for the push depth's exact definition.
    """
    T = pose.T_J_part(jig)
    n = T[:3, 2]
    zero = np.zeros(1)
    h_rest = float(rest_inner_height_mm(jig, zero, zero)[0])
    z_markers_plane = float(bottom_plane_height_mm(T, zero, zero)[0]) - jig.membrane.thickness_mm / n[2]
    return {
        "normal": [float(v) for v in n],
        "push_depth_mm": h_rest - z_markers_plane,
        "T_J_part": T.tolist(),
    }
