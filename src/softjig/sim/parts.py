"""Where a part is on the jig: its pose, its bottom face, and which points of the jig lie under it.

A part's frame has its origin at the centre of the part's flat bottom face and its ``z`` axis along the
face's normal, into the part. The paper's experiment places the part on the jig axis, pushes it in until
contact plus a few millimetres, then tilts it about the centre of its bottom face by ``alpha`` towards the
azimuth ``theta`` (:class:`PartPose`); any part may also be placed off the axis and spun about its own
axis (``center_xy_mm``, ``yaw_rad``).

Every part kind of :mod:`softjig.config` works here: a cylinder's face is a disc, every other kind's a
convex polygon (its ``outline_mm()``, counter-clockwise in the part frame).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from softjig.config import BoxPart, CylinderPart, JigConfig, Part, PartPlacement
from softjig.geometry import pose_from_rotation_translation, rotation_from_tilt


@dataclass(frozen=True)
class PartPose:
    """How a part is pressed into the jig.

    Attributes
    ----------
    alpha_rad : tilt of the bottom face from horizontal (rad).
    theta_rad : azimuth towards which the part tilts, from J's ``+x`` towards ``+y`` (rad).
    push_depth_mm : how far the centre of the bottom face lies below the membrane's undeformed outer
        surface at the same ``(x, y)`` (mm); the part's bottom is pushed in by this much.
    center_xy_mm : ``(x, y)`` of the bottom face's centre in J (mm).
    yaw_rad : rotation of the part about its own axis before tilting (matters for boxes).
    """

    alpha_rad: float = 0.0
    theta_rad: float = 0.0
    push_depth_mm: float = 3.0
    center_xy_mm: tuple[float, float] = (0.0, 0.0)
    yaw_rad: float = 0.0

    @classmethod
    def placed(
        cls,
        placement: PartPlacement,
        *,
        alpha_rad: float = 0.0,
        theta_rad: float = 0.0,
        push_depth_mm: float = 3.0,
    ) -> PartPose:
        """A pose with the centre and spin of a :class:`~softjig.config.PartPlacement`."""
        return cls(
            alpha_rad=alpha_rad,
            theta_rad=theta_rad,
            push_depth_mm=push_depth_mm,
            center_xy_mm=tuple(float(v) for v in placement.center_xy_mm),
            yaw_rad=float(np.radians(placement.yaw_deg)),
        )

    def rotation(self) -> np.ndarray:
        """``R_J_part`` (3x3): yaw about the part's axis, then the tilt."""
        yaw = Rotation.from_rotvec([0.0, 0.0, self.yaw_rad]).as_matrix()
        return rotation_from_tilt(self.alpha_rad, self.theta_rad) @ yaw

    def T_J_part(self, jig: JigConfig) -> np.ndarray:
        """The part's pose in J (4x4), its origin at the bottom face's centre."""
        from softjig.jig_shape import rest_outer_height_mm

        cx, cy = self.center_xy_mm
        z = float(rest_outer_height_mm(jig, np.array([cx]), np.array([cy]))[0]) - self.push_depth_mm
        return pose_from_rotation_translation(self.rotation(), np.array([cx, cy, z]))


def bottom_plane_height_mm(T_J_part: np.ndarray, x_mm: np.ndarray, y_mm: np.ndarray) -> np.ndarray:
    """Height in J of the (infinite) plane of the part's bottom face above each ``(x, y)`` (mm)."""
    n = T_J_part[:3, 2]
    c = T_J_part[:3, 3]
    return c[2] - (n[0] * (x_mm - c[0]) + n[1] * (y_mm - c[1])) / n[2]


def _half_planes(outline: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Outward unit normals ``(M, 2)`` and offsets ``(M,)`` of a counter-clockwise convex polygon's edges:
    a point ``p`` is inside where ``normal @ p <= offset`` for every edge."""
    edge = np.roll(outline, -1, axis=0) - outline
    normal = np.column_stack([edge[:, 1], -edge[:, 0]]) / np.hypot(edge[:, 0], edge[:, 1])[:, None]
    return normal, np.sum(normal * outline, axis=1)


def face_coordinates(
    T_J_part: np.ndarray, x_mm: np.ndarray, y_mm: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """``(u, v)`` in the part frame of the points of the face's plane above each ``(x, y)`` (mm)."""
    z = bottom_plane_height_mm(T_J_part, x_mm, y_mm)
    p_J = np.stack([x_mm, y_mm, z], axis=-1) - T_J_part[:3, 3]
    p_part = p_J @ T_J_part[:3, :3]  # R^T p, row-wise
    return p_part[..., 0], p_part[..., 1]


def inside_face_mm(part: Part, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Signed distance (mm) from each point ``(u, v)`` of the face's plane (part frame) to the face's
    edge: positive inside the face."""
    if isinstance(part, CylinderPart):
        return part.diameter_mm / 2.0 - np.hypot(u, v)
    if isinstance(part, BoxPart):
        return np.minimum(part.size_x_mm / 2.0 - np.abs(u), part.size_y_mm / 2.0 - np.abs(v))
    normal, offset = _half_planes(part.outline_mm())
    uv = np.stack([u, v], axis=-1)
    return np.min(offset - uv @ normal.T, axis=-1)


def under_bottom_face(part: Part, T_J_part: np.ndarray, x_mm: np.ndarray, y_mm: np.ndarray) -> np.ndarray:
    """Whether each ``(x, y)`` lies under the part's bottom face (vertical projection), as booleans."""
    u, v = face_coordinates(T_J_part, x_mm, y_mm)
    if isinstance(part, CylinderPart):
        return u**2 + v**2 <= (part.diameter_mm / 2.0) ** 2
    if isinstance(part, BoxPart):
        return (np.abs(u) <= part.size_x_mm / 2.0) & (np.abs(v) <= part.size_y_mm / 2.0)
    return inside_face_mm(part, u, v) >= -1e-9


def bottom_face_samples(part: Part, T_J_part: np.ndarray, spacing_mm: float) -> np.ndarray:
    """Points of the bottom face on a square grid of ``spacing_mm`` in the part frame, in J, ``(M, 3)``;
    the grid is centred on the face's bounding box."""
    if isinstance(part, CylinderPart):
        low_u = low_v = -part.diameter_mm / 2.0
        high_u = high_v = part.diameter_mm / 2.0
    else:
        outline = part.outline_mm()
        (low_u, low_v), (high_u, high_v) = outline.min(axis=0), outline.max(axis=0)
    u = np.arange(low_u, high_u + 1e-9, spacing_mm)
    v = np.arange(low_v, high_v + 1e-9, spacing_mm)
    mid_u, mid_v = (low_u + high_u) / 2.0, (low_v + high_v) / 2.0
    uu, vv = np.meshgrid(u - u.mean() + mid_u, v - v.mean() + mid_v)
    uu, vv = uu.ravel(), vv.ravel()
    if isinstance(part, CylinderPart):
        keep = uu**2 + vv**2 <= high_u**2
        uu, vv = uu[keep], vv[keep]
    elif not isinstance(part, BoxPart):
        keep = inside_face_mm(part, uu, vv) >= -1e-9
        uu, vv = uu[keep], vv[keep]
    local = np.stack([uu, vv, np.zeros_like(uu)], axis=1)
    return local @ T_J_part[:3, :3].T + T_J_part[:3, 3]


def bottom_face_rim(part: Part, T_J_part: np.ndarray, spacing_mm: float) -> np.ndarray:
    """Points along the edge of the bottom face, ``spacing_mm`` apart, in J, ``(M, 3)``."""
    if isinstance(part, CylinderPart):
        radius = part.diameter_mm / 2.0
        n = max(8, int(np.ceil(2 * np.pi * radius / spacing_mm)))
        angle = np.linspace(0.0, 2 * np.pi, n, endpoint=False)
        uu, vv = radius * np.cos(angle), radius * np.sin(angle)
    else:
        corners = part.outline_mm()
        sides = []
        for (u0, v0), (u1, v1) in zip(corners, np.roll(corners, -1, axis=0), strict=True):
            n = max(2, int(np.ceil(np.hypot(u1 - u0, v1 - v0) / spacing_mm)))
            t = np.linspace(0.0, 1.0, n, endpoint=False)
            sides.append(np.column_stack([u0 + t * (u1 - u0), v0 + t * (v1 - v0)]))
        uu, vv = np.concatenate(sides).T
    local = np.stack([uu, vv, np.zeros_like(uu)], axis=1)
    return local @ T_J_part[:3, :3].T + T_J_part[:3, 3]
