"""Poses, tilt angles and plane fits: the small pieces of 3-D geometry every module shares.

Conventions (``DESIGN.md`` §1, binding): poses are 4x4 homogeneous matrices ``T_a_b`` with
``p_a = T_a_b @ p_b``; lengths in mm, angles in radians. A part tilted by ``alpha`` towards azimuth
``theta`` has the principal normal ``n = (sin a cos t, sin a sin t, cos a)``; its tilt angles, the
projections of ``n`` on the YZ and XZ planes, are ``Ax = atan2(-n_y, n_z)`` and ``Ay = atan2(n_x, n_z)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from softjig.errors import InputError

#: Points whose second singular value is below this ratio of the first lie on a line or a point, to
#: rounding: they define no plane.
DEGENERATE_PLANE_RATIO = 1e-9

#: How far outside a convex hull (mm) a point still counts as inside: a point on the hull's edge is inside.
HULL_TOLERANCE_MM = 1e-9

#: Below this angle (rad) a rotation vector's matrix is taken from the Taylor series of Rodrigues' formula.
ROTVEC_TAYLOR_BELOW_RAD = 1e-4

# ------------------------------------------------------------------------------------------ poses


def pose_from_rotation_translation(rotation: np.ndarray, translation_mm: np.ndarray) -> np.ndarray:
    """A 4x4 pose from a 3x3 rotation matrix and a translation (mm)."""
    T = np.eye(4)
    T[:3, :3] = rotation
    T[:3, 3] = translation_mm
    return T


def pose_from_rotvec_translation(rotvec_rad, translation_mm) -> np.ndarray:
    """A 4x4 pose from a rotation vector (axis times angle, rad) and a translation (mm)."""
    rotation = rotation_from_rotvec(rotvec_rad)
    return pose_from_rotation_translation(rotation, np.asarray(translation_mm, dtype=float))


def rotation_from_rotvec(rotvec_rad) -> np.ndarray:
    """The 3x3 rotation of a rotation vector (axis times angle, rad): Rodrigues' formula
    ``R = I + sin(t) K + (1 - cos(t)) K^2`` (``K`` the cross-product matrix of the unit axis), with its
    Taylor series below :data:`ROTVEC_TAYLOR_BELOW_RAD` (no division by a small angle)."""
    r = np.asarray(rotvec_rad, dtype=float).reshape(3)
    theta = float(np.sqrt(r @ r))
    k = np.array([[0.0, -r[2], r[1]], [r[2], 0.0, -r[0]], [-r[1], r[0], 0.0]])
    if theta < ROTVEC_TAYLOR_BELOW_RAD:
        a, b = 1.0 - theta**2 / 6.0, 0.5 - theta**2 / 24.0
    else:
        a, b = np.sin(theta) / theta, (1.0 - np.cos(theta)) / theta**2
    return np.eye(3) + a * k + b * (k @ k)


def invert_pose(T: np.ndarray) -> np.ndarray:
    """The inverse of a rigid 4x4 pose (``T_b_a`` from ``T_a_b``), exact for rigid motions."""
    R, t = T[:3, :3], T[:3, 3]
    return pose_from_rotation_translation(R.T, -R.T @ t)


def transform_points(T: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Apply a 4x4 pose to ``(N, 3)`` points."""
    points = np.asarray(points, dtype=float)
    return points @ T[:3, :3].T + T[:3, 3]


# ------------------------------------------------------------------------------------ tilt angles


def normal_from_tilt(alpha_rad: float, theta_rad: float) -> np.ndarray:
    """The unit normal of a part tilted by ``alpha`` towards azimuth ``theta`` (in J)."""
    sa = np.sin(alpha_rad)
    return np.array([sa * np.cos(theta_rad), sa * np.sin(theta_rad), np.cos(alpha_rad)])


def rotation_from_tilt(alpha_rad: float, theta_rad: float) -> np.ndarray:
    """The rotation that tilts ``+z`` by ``alpha`` towards azimuth ``theta``, about the horizontal axis
    ``(-sin t, cos t, 0)``: ``rotation_from_tilt(a, t) @ z == normal_from_tilt(a, t)``."""
    axis = np.array([-np.sin(theta_rad), np.cos(theta_rad), 0.0])
    return rotation_from_rotvec(alpha_rad * axis)


def tilt_angles(normal: np.ndarray) -> tuple[float, float]:
    """The paper's tilt angles ``(Ax, Ay)`` (rad) of a normal: ``atan2(-n_y, n_z)``, ``atan2(n_x, n_z)``.

    Works on ``(3,)`` or ``(N, 3)`` arrays (then returns two ``(N,)`` arrays).
    """
    n = np.asarray(normal, dtype=float)
    return np.arctan2(-n[..., 1], n[..., 2]), np.arctan2(n[..., 0], n[..., 2])


def normal_from_tilt_angles(ax_rad: float, ay_rad: float) -> np.ndarray:
    """Invert :func:`tilt_angles`: the unit normal (``n_z > 0``) with tilt angles ``(Ax, Ay)``."""
    n = np.array([np.tan(ay_rad), -np.tan(ax_rad), 1.0])
    return n / np.linalg.norm(n)


def angle_between(a: np.ndarray, b: np.ndarray) -> float | np.ndarray:
    """Angle (rad) between unit vectors, robust near 0 and pi (``atan2(|a x b|, a . b)``)."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    return np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), np.sum(a * b, axis=-1))


# ------------------------------------------------------------------------------------------ planes


@dataclass(frozen=True)
class PlaneFit:
    """A plane ``normal . p + offset = 0`` fitted to points, with ``normal`` a unit vector, ``n_z > 0``.

    Attributes
    ----------
    normal : (3,) unit normal, oriented into the part (``+z`` side).
    offset_mm : ``d`` in ``n . p + d = 0``.
    centroid_mm : (3,) mean of the points, on the plane.
    rms_residual_mm : RMS of the points' signed distances to the plane.
    n_points : how many points were fitted.
    singular_values : the three singular values of the centred points, descending (their ratios tell
        how well the points span a plane).
    """

    normal: np.ndarray
    offset_mm: float
    centroid_mm: np.ndarray
    rms_residual_mm: float
    n_points: int
    singular_values: np.ndarray

    def z_at(self, x_mm: float, y_mm: float) -> float:
        """Height of the plane above ``(x, y)`` (mm)."""
        return float(self.heights_mm(x_mm, y_mm))

    def heights_mm(self, x_mm: np.ndarray, y_mm: np.ndarray) -> np.ndarray:
        """Heights of the plane above many ``(x, y)`` at once (mm), vectorised."""
        return (
            -(self.offset_mm + self.normal[0] * np.asarray(x_mm) + self.normal[1] * np.asarray(y_mm))
            / (self.normal[2])
        )


def fit_plane_svd(points_mm: np.ndarray, *, min_points: int = 3) -> PlaneFit:
    """Least-squares plane through ``(N, 3)`` points (the paper's fit: the SVD of the centred points).

    The normal is the right singular vector of the smallest singular value, oriented so ``n_z > 0``
    (:func:`softjig._geometry_kernels.plane_fit`, one compiled pass over the 3x3 scatter matrix: the
    contact search fits many planes per frame).

    Raises
    ------
    InputError
        Fewer than ``min_points`` (at least 3) points, non-finite points, or points that do not span a
        plane (all on one line or one point: the second singular value is below
        :data:`DEGENERATE_PLANE_RATIO` of the first), or a vertical plane.
    """
    pts = np.asarray(points_mm, dtype=float)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise InputError(f"plane fit needs (N, 3) points, got shape {pts.shape}")
    if not np.isfinite(pts).all():
        raise InputError("plane fit got non-finite points (NaN or inf)")
    need = max(3, min_points)
    if len(pts) < need:
        raise InputError(f"plane fit needs at least {need} points, got {len(pts)}")
    from softjig._geometry_kernels import plane_fit  # Numba is loaded on first use, not with the poses

    centroid, s, normal, rms = plane_fit(np.ascontiguousarray(pts), np.ones(len(pts), dtype=bool))
    if s[0] == 0 or s[1] <= DEGENERATE_PLANE_RATIO * s[0]:
        raise InputError(f"the {len(pts)} points lie on a line or a point and do not define a plane")
    if normal[2] == 0:
        raise InputError("the fitted plane is vertical: its normal cannot point into the part")
    return PlaneFit(
        normal=normal,
        offset_mm=-float(normal @ centroid),
        centroid_mm=centroid,
        rms_residual_mm=float(rms),
        n_points=len(pts),
        singular_values=s,
    )


# ---------------------------------------------------------------------------------------- polygons


def inside_convex_hull_xy(
    hull_of_xy: np.ndarray, xy: np.ndarray, tolerance_mm: float = HULL_TOLERANCE_MM
) -> np.ndarray:
    """Which ``(x, y)`` lie inside the convex hull of ``hull_of_xy`` (or within ``tolerance_mm`` outside
    it), as booleans; none when the hull has no area (fewer than 3 points, or all on a line).

    Andrew's monotone chain and one edge test per point, compiled
    (:func:`softjig._geometry_kernels.inside_hull`): Qhull's ``ConvexHull`` or ``Delaunay.find_simplex``
    cost far more for the few hundred points of a contact.
    """
    members = np.ascontiguousarray(hull_of_xy, dtype=float).reshape(-1, 2)
    query = np.ascontiguousarray(xy, dtype=float).reshape(-1, 2)
    from softjig._geometry_kernels import inside_hull  # Numba is loaded on first use

    return inside_hull(members, query, float(tolerance_mm))
