"""Refractive camera model of the sensing soft jig: cameras in air looking up through flat layers.

Two cameras sit in air below a transparent PET base plate and look up, through the plate and a
refractive-index-matched oil, at markers on a membrane.  Every interface is a horizontal plane
``z = const`` of the jig frame, so a light path is fully described by one invariant, the ray
parameter ``kappa = n_i sin(theta_i)`` (Snell's law), which is the same in every region.

Conventions
-----------
* Jig frame **J**: origin at the centre of the plate's top face, ``+z`` up (towards the part),
  ``+x`` along the stereo baseline.  By default the plate occupies ``z in [-5, 0]`` mm, the oil is
  above ``z = 0`` and the cameras are in air around ``z = -155`` mm.
* Camera frames follow OpenCV: ``x`` right, ``y`` down, ``z`` along the optical axis.
* Poses are 4x4 homogeneous matrices ``T_a_b`` mapping points of frame ``b`` to frame ``a``
  (``p_a = T_a_b @ p_b``); ``T_J_cam`` is the camera's pose in J.
* Units: millimetres, radians, pixels (``u`` = column, ``v`` = row).
* Distortion: OpenCV's ``(k1, k2, p1, p2[, k3])`` model.

Every function is vectorised over points: arrays of shape ``(..., 3)`` (or ``(..., 2)`` for
pixels) are accepted and results keep the leading shape.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = [
    "FlatLayers",
    "backproject_pixels",
    "camera_center_J",
    "distort_normalized",
    "jacobian_stencil",
    "layer_constants",
    "pixels_to_normalized",
    "point_on_ray_at_z",
    "project_point_sets",
    "project_points",
    "projection_jacobian",
    "rays_in_top_region",
    "rays_in_top_region_normalized",
    "refract_directions",
    "refracted_ray_directions",
    "stencil_jacobian",
    "trace_rays_through_layers",
    "undistort_normalized",
]

FloatArray = NDArray[np.float64]

_NEWTON_MAX_ITER = 100
_UNDISTORT_MAX_ITER = 20
#: The last row of a pose must be ``(0, 0, 0, 1)`` to this absolute tolerance.
POSE_ROW_TOLERANCE = 1e-12
#: A pose's rotation block must be orthonormal, ``R^T R = I``, to this absolute tolerance.
ROTATION_TOLERANCE = 1e-6
#: OpenCV's iterative undistortion: at most this many iterations, stopping below this change
#: (normalised coordinates).
_CV_UNDISTORT_ITERATIONS, _CV_UNDISTORT_EPS = 50, 1e-12
#: ``np.allclose``'s default tolerances, which the pose and intrinsics checks keep.
_ALLCLOSE_RTOL, _ALLCLOSE_ATOL = 1e-5, 1e-8


# --------------------------------------------------------------------------------------------------
# Data
# --------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class FlatLayers:
    """Horizontal, parallel refracting interfaces (planes ``z = const`` in J), bottom to top.

    Region 0 is below ``interfaces_z_mm[0]`` (the cameras' medium, air); region ``i`` lies between
    ``interfaces_z_mm[i-1]`` and ``interfaces_z_mm[i]``; the last region is above the last interface
    (the oil).  A point exactly on an interface belongs to the region below it.

    Parameters
    ----------
    interfaces_z_mm : tuple of float
        Heights of the interfaces in J, mm, strictly ascending, at least one, e.g. ``(-5.0, 0.0)``.
    refractive_indices : tuple of float
        Refractive index of each region, ``len(interfaces_z_mm) + 1`` values, all finite and
        ``>= 1``, e.g. ``(1.0, 1.575, 1.51)`` for air, PET, oil.

    Raises
    ------
    ValueError
        If the tuples are empty, of mismatched lengths, not finite, not ascending, or an index is
        below 1.
    """

    interfaces_z_mm: tuple[float, ...]
    refractive_indices: tuple[float, ...]
    _constants: tuple = field(init=False, repr=False, compare=False)  # layer_constants, made with it

    def __post_init__(self) -> None:
        try:
            z = tuple(float(v) for v in self.interfaces_z_mm)
            n = tuple(float(v) for v in self.refractive_indices)
        except (TypeError, ValueError) as exc:
            raise ValueError(
                f"FlatLayers: interfaces_z_mm and refractive_indices must be sequences of numbers ({exc})"
            ) from exc
        if len(z) == 0:
            raise ValueError("FlatLayers: interfaces_z_mm must contain at least one interface")
        if len(n) != len(z) + 1:
            raise ValueError(
                f"FlatLayers: need len(interfaces_z_mm) + 1 = {len(z) + 1} refractive indices "
                f"(one per region), got {len(n)}"
            )
        if not all(np.isfinite(z)):
            raise ValueError(f"FlatLayers: interfaces_z_mm must be finite, got {z}")
        if not all(np.isfinite(n)):
            raise ValueError(f"FlatLayers: refractive_indices must be finite, got {n}")
        if any(b <= a for a, b in itertools.pairwise(z)):
            raise ValueError(f"FlatLayers: interfaces_z_mm must be strictly ascending, got {z}")
        if any(v < 1.0 for v in n):
            raise ValueError(f"FlatLayers: refractive indices must all be >= 1, got {n}")
        object.__setattr__(self, "interfaces_z_mm", z)
        object.__setattr__(self, "refractive_indices", n)
        object.__setattr__(self, "_constants", _layer_constants(z, n))

    @classmethod
    def plate_under_oil(
        cls,
        plate_thickness_mm: float = 5.0,
        n_air: float = 1.0,
        n_plate: float = 1.575,
        n_oil: float = 1.51,
    ) -> FlatLayers:
        """The jig's default stack: air below, a plate in ``z in [-thickness, 0]``, oil above.

        Parameters
        ----------
        plate_thickness_mm : float
            Plate thickness, mm (> 0).  The plate's top face is ``z = 0`` of J.
        n_air, n_plate, n_oil : float
            Refractive indices of the camera medium, the plate and the oil.

        Returns
        -------
        FlatLayers
            ``FlatLayers((-plate_thickness_mm, 0.0), (n_air, n_plate, n_oil))``.
        """
        return cls((-float(plate_thickness_mm), 0.0), (n_air, n_plate, n_oil))

    @property
    def n_regions(self) -> int:
        """Number of regions (``len(interfaces_z_mm) + 1``)."""
        return len(self.refractive_indices)

    def region_of_z(self, z_mm: ArrayLike) -> NDArray[np.intp]:
        """Index of the region containing height(s) ``z_mm`` (J, mm); a point on an interface
        belongs to the region below it."""
        return np.searchsorted(np.asarray(self.interfaces_z_mm), np.asarray(z_mm, dtype=float), side="left")


# --------------------------------------------------------------------------------------------------
# Input validation helpers
# --------------------------------------------------------------------------------------------------
def _as_vectors(x: ArrayLike, dim: int, name: str) -> tuple[FloatArray, tuple[int, ...]]:
    a = np.asarray(x, dtype=float)
    if a.ndim == 0 or a.shape[-1] != dim:
        raise ValueError(f"{name} must have shape (..., {dim}), got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name} must be finite (contains NaN or inf)")
    return a.reshape(-1, dim), a.shape[:-1]


def _check_pose(T_J_cam: ArrayLike) -> FloatArray:
    T = np.asarray(T_J_cam, dtype=float)
    if T.shape != (4, 4):
        raise ValueError(f"T_J_cam must be a 4x4 homogeneous matrix, got shape {T.shape}")
    rows = T.tolist()  # 16 numbers: Python floats check them faster than NumPy's small-array calls
    if not all(math.isfinite(v) for row in rows for v in row):
        raise ValueError("T_J_cam must be finite")
    if not all(_near(v, w, POSE_ROW_TOLERANCE) for v, w in zip(rows[3], (0.0, 0.0, 0.0, 1.0), strict=True)):
        raise ValueError(f"T_J_cam's last row must be (0, 0, 0, 1), got {T[3]}")
    R = [row[:3] for row in rows[:3]]
    gram = [[sum(R[k][i] * R[k][j] for k in range(3)) for j in range(3)] for i in range(3)]  # R^T R
    orthonormal = all(
        _near(gram[i][j], float(i == j), ROTATION_TOLERANCE) for i in range(3) for j in range(3)
    )
    if not orthonormal or _det3(R) <= 0:
        raise ValueError("T_J_cam's rotation block must be a proper rotation (orthonormal, det +1)")
    return T


def _check_K(K: ArrayLike) -> FloatArray:
    Km = np.asarray(K, dtype=float)
    if Km.shape != (3, 3):
        raise ValueError(f"K must be a 3x3 intrinsic matrix, got shape {Km.shape}")
    if not np.isfinite(Km).all():
        raise ValueError("K must be finite")
    if not (Km[0, 0] > 0 and Km[1, 1] > 0):
        raise ValueError(f"K's focal lengths must be positive, got fx={Km[0, 0]}, fy={Km[1, 1]}")
    last = Km[2].tolist()
    if Km[1, 0] != 0 or not all(
        _near(v, w, _ALLCLOSE_ATOL) for v, w in zip(last, (0.0, 0.0, 1.0), strict=True)
    ):
        raise ValueError(f"K must be upper triangular with last row (0, 0, 1), got\n{Km}")
    return Km


def _near(a: float, b: float, atol: float) -> bool:
    """``np.allclose``'s test (``|a - b| <= atol + rtol |b|``, its default ``rtol``) of two numbers."""
    return abs(a - b) <= atol + _ALLCLOSE_RTOL * abs(b)


def _det3(R: list[list[float]]) -> float:
    """The determinant of a 3x3 matrix (only its sign is used), by the rule of Sarrus."""
    (a, b, c), (d, e, f), (g, h, i) = R
    return a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g)


def _check_dist(dist: ArrayLike | None) -> FloatArray:
    """Return ``(k1, k2, p1, p2, k3)``; accepts None, 4 or 5 values (or more if the extra are 0)."""
    if dist is None:
        return np.zeros(5)
    d = np.asarray(dist, dtype=float).ravel()
    if not np.all(np.isfinite(d)):
        raise ValueError("dist must be finite")
    if d.size == 0:
        return np.zeros(5)
    if d.size == 4:
        return np.concatenate([d, [0.0]])
    if d.size == 5:
        return d.copy()
    if d.size > 5 and np.all(d[5:] == 0):
        return d[:5].copy()
    raise ValueError(
        "dist must be OpenCV's (k1, k2, p1, p2[, k3]) (4 or 5 values; longer vectors only if the "
        f"extra rational/prism/tilt terms are zero), got {d.size} values"
    )


# --------------------------------------------------------------------------------------------------
# Small helpers
# --------------------------------------------------------------------------------------------------
def camera_center_J(T_J_cam: ArrayLike) -> FloatArray:
    """Optical centre of a camera in J.

    Parameters
    ----------
    T_J_cam : array_like, shape (4, 4)
        Camera pose in J (maps camera-frame points to J), mm.

    Returns
    -------
    ndarray, shape (3,)
        Camera centre in J, mm.
    """
    return _check_pose(T_J_cam)[:3, 3].copy()


def point_on_ray_at_z(origins: ArrayLike, directions: ArrayLike, z_mm: ArrayLike) -> FloatArray:
    """Point where each ray ``o + s d`` reaches the height ``z = z_mm`` (any frame, usually J).

    Parameters
    ----------
    origins, directions : array_like, shape (..., 3)
        Ray origins (mm) and directions (need not be unit).
    z_mm : float or array_like broadcastable to shape (...)
        Target height(s), mm.

    Returns
    -------
    ndarray, shape (..., 3)
        Points on the rays with ``z == z_mm`` (``s`` may be negative).

    Raises
    ------
    ValueError
        If a direction is horizontal (``d_z == 0``).
    """
    o, lead = _as_vectors(origins, 3, "origins")
    d, lead_d = _as_vectors(directions, 3, "directions")
    if lead != lead_d:
        raise ValueError(f"origins {lead} and directions {lead_d} must have the same shape")
    z = np.broadcast_to(np.asarray(z_mm, dtype=float), lead).reshape(-1)
    if np.any(d[:, 2] == 0):
        raise ValueError("point_on_ray_at_z: a ray is horizontal (d_z == 0) and never reaches z")
    s = (z - o[:, 2]) / d[:, 2]
    p = o + s[:, None] * d
    p[:, 2] = z  # exact
    return p.reshape(*lead, 3)


def refract_directions(
    directions: ArrayLike,
    n1: float,
    n2: float,
    normal: ArrayLike = (0.0, 0.0, 1.0),
) -> FloatArray:
    """Refract ray directions at a planar interface (vector form of Snell's law).

    Parameters
    ----------
    directions : array_like, shape (..., 3)
        Incident directions (need not be unit), travelling from the medium of index ``n1`` into
        the medium of index ``n2``.
    n1, n2 : float
        Refractive indices of the incident and transmitting media.
    normal : array_like, shape (3,)
        Interface normal (either orientation; normalised internally).

    Returns
    -------
    ndarray, shape (..., 3)
        Unit transmitted directions, on the same side of the interface as the incident ones.

    Raises
    ------
    ValueError
        On total internal reflection, or a direction parallel to the interface.
    """
    d, lead = _as_vectors(directions, 3, "directions")
    nrm = np.asarray(normal, dtype=float).reshape(3)
    nrm_len = np.linalg.norm(nrm)
    if not np.isfinite(nrm_len) or nrm_len == 0:
        raise ValueError(f"normal must be a finite non-zero vector, got {normal}")
    if not (n1 >= 1.0 and n2 >= 1.0):
        raise ValueError(f"refractive indices must be >= 1, got n1={n1}, n2={n2}")
    nrm = nrm / nrm_len
    d_len = np.linalg.norm(d, axis=1)
    if np.any(d_len == 0):
        raise ValueError("refract_directions: zero-length direction")
    d = d / d_len[:, None]
    cos_i = d @ nrm
    if np.any(cos_i == 0):
        raise ValueError("refract_directions: a direction is parallel to the interface")
    # orient the normal along the propagation, per ray
    sgn = np.sign(cos_i)
    cos_i = np.abs(cos_i)
    eta = n1 / n2
    sin2_t = eta * eta * np.maximum(0.0, 1.0 - cos_i * cos_i)
    if np.any(sin2_t > 1.0):
        bad = int(np.count_nonzero(sin2_t > 1.0))
        raise ValueError(
            f"refract_directions: total internal reflection for {bad} ray(s) going from n1={n1} to n2={n2}"
        )
    cos_t = np.sqrt(1.0 - sin2_t)
    t = eta * d + ((cos_t - eta * cos_i) * sgn)[:, None] * nrm[None, :]
    t /= np.linalg.norm(t, axis=1)[:, None]
    return t.reshape(*lead, 3)


# --------------------------------------------------------------------------------------------------
# Forward: point -> initial ray direction
# --------------------------------------------------------------------------------------------------
def refracted_ray_directions(
    camera_center_J: ArrayLike, points_J: ArrayLike, layers: FlatLayers
) -> FloatArray:
    """Initial direction of the refracted light path from a camera centre to each point.

    Solves, per point, for the ray invariant ``kappa = n_i sin(theta_i)`` such that the path
    leaving the camera centre, refracted at every interface in between (Snell's law), reaches the
    point: ``sum_i h_i kappa / sqrt(n_i^2 - kappa^2) = rho`` with ``h_i`` the vertical distance
    travelled in region ``i`` and ``rho`` the horizontal distance.  The equation is rewritten in
    ``t = tan(theta_m)`` of the lowest-index region crossed, where it is increasing and concave on
    ``[0, inf)``; Newton's method started at ``t = 0`` then increases monotonically to the root
    (the first step is the paraxial solution) and is iterated to machine precision.  ``rho == 0``
    gives exactly the vertical direction.

    Parameters
    ----------
    camera_center_J : array_like, shape (3,)
        Camera centre in J, mm; must lie in region 0 (strictly below every interface).
    points_J : array_like, shape (..., 3)
        Target points in J, mm.  A point in region 0 is reached in a straight line (it may be
        anywhere except at the camera centre); points above the first interface are reached
        through the layers.
    layers : FlatLayers
        The refracting interfaces.

    Returns
    -------
    ndarray, shape (..., 3)
        Unit direction, in J, of the ray leaving the camera centre (in region 0).

    Raises
    ------
    ValueError
        If the camera is not below all interfaces or a point coincides with the camera centre.
    """
    p, lead = _as_vectors(points_J, 3, "points_J")
    return _directions_of_sets([_check_center(camera_center_J, layers)], [p], layers)[0].reshape(*lead, 3)


def _check_center(camera_center_J: ArrayLike, layers: FlatLayers) -> FloatArray:
    """A camera centre as a finite 3-vector in region 0 (ValueError otherwise)."""
    c = np.asarray(camera_center_J, dtype=float).reshape(-1)
    if c.shape != (3,) or not np.isfinite(c).all():
        raise ValueError(f"camera_center_J must be a finite 3-vector, got {camera_center_J!r}")
    z0 = layers.interfaces_z_mm[0]
    if not c[2] < z0:
        raise ValueError(
            f"camera centre z = {c[2]} mm must lie in region 0, strictly below the lowest "
            f"interface z = {z0} mm"
        )
    return c


def _directions_of_sets(
    centers: list[FloatArray], points: list[FloatArray], layers: FlatLayers
) -> list[FloatArray]:
    """:func:`refracted_ray_directions` of each set of ``(M_s, 3)`` points from its camera centre
    (checked), solved together: each set's result is the one a call of its own gives."""
    sizes = [len(p) for p in points]
    p = np.concatenate(points)
    c = np.repeat(np.asarray(centers, dtype=float).reshape(-1, 3), sizes, axis=0)
    rel = p - c
    through = p[:, 2] > layers.interfaces_z_mm[0]  # the others are in region 0: straight lines
    out = np.empty_like(rel)
    if not through.all():
        straight = rel[~through]
        dist = np.linalg.norm(straight, axis=1)
        if np.any(dist == 0):
            raise ValueError("refracted_ray_directions: a point coincides with the camera centre")
        out[~through] = straight / dist[:, None]
    sets = np.repeat(np.arange(len(sizes)), sizes)
    z_if, n_reg = np.asarray(layers.interfaces_z_mm), np.asarray(layers.refractive_indices)
    if through.all() and len(p):
        out = _solve_layered_directions(c[:, 2], rel, p[:, 2], z_if, n_reg, sets)
    elif through.any():
        solved = _solve_layered_directions(
            c[through, 2], rel[through], p[through, 2], z_if, n_reg, sets[through]
        )
        out[through] = solved
    return np.split(out, np.cumsum(sizes)[:-1])


def _solve_layered_directions(
    cz: FloatArray, rel: FloatArray, pz: FloatArray, z_if: FloatArray, n_reg: FloatArray, sets: NDArray
) -> FloatArray:
    """Unit initial directions of points above the first interface (refracted_ray_directions), from
    cameras at heights ``cz`` (per point), ``rel`` the points less their camera's centre.

    Newton in ``t = tan`` of the ray in the lowest-index region crossed, from ``t = 0`` (see
    :func:`refracted_ray_directions`), one NumPy operation over all points at a time. The points of a
    set (``sets``: a set index per point) are iterated until all of them converged, then frozen: a
    set's directions do not depend on the other sets solved with it (an iterate that converged still
    moves by an ulp at the next step).
    """
    # vertical distance travelled in each region, shape (R, M) (regions first: fast reductions)
    lo = np.concatenate([cz[None, :], np.broadcast_to(z_if[:, None], (len(z_if), len(cz)))])
    hi = np.concatenate([z_if, [np.inf]])
    h = np.clip(np.minimum(pz[None, :], hi[:, None]) - lo, 0.0, None)
    crossed = h > 0
    n_min = np.min(np.where(crossed, n_reg[:, None], np.inf), axis=0)  # (M,)
    a = n_reg[:, None] ** 2  # (R, 1)
    b = np.where(crossed, a - n_min[None, :] ** 2, 0.0)  # (R, M), >= 0 where used
    w = h * n_min[None, :]  # (R, M)
    wa = w * a
    rho = np.hypot(rel[:, 0], rel[:, 1])

    # g(t) = sum_i w_i t / sqrt(a_i + b_i t^2) - rho,  g'(t) = sum_i w_i a_i / (a_i + b_i t^2)^1.5
    # Increasing and concave in t >= 0, g(0) = -rho <= 0: Newton from t = 0 climbs monotonically.
    t = np.zeros_like(rho)
    tol = 4.0 * np.finfo(float).eps
    n_sets = int(sets[-1]) + 1
    active = np.ones(n_sets, dtype=bool)
    for _ in range(_NEWTON_MAX_ITER):
        inv_sq = 1.0 / np.sqrt(a + b * (t * t))
        g = t * _sum_over_regions(w * inv_sq) - rho
        dg = _sum_over_regions(wa * (inv_sq * inv_sq * inv_sq))
        step = g / dg
        t_new = np.maximum(t - step, 0.0)
        unsettled = ~(np.abs(t_new - t) <= tol * t_new)
        if n_sets == 1:
            t = t_new
            if not unsettled.any():
                break
            continue
        moving = active[sets]
        t = np.where(moving, t_new, t)
        active &= np.bincount(sets, weights=unsettled & moving, minlength=n_sets) > 0
        if not active.any():
            break
    # tan(theta_0) in region 0 from the invariant
    a0 = n_reg[0] ** 2
    tan0 = n_min * t / np.sqrt(a0 + (a0 - n_min**2) * t * t)
    scale = np.divide(tan0, rho, out=np.zeros_like(rho), where=rho > 0)
    d = np.column_stack([rel[:, 0] * scale, rel[:, 1] * scale, np.ones_like(rho)])
    d /= np.linalg.norm(d, axis=1)[:, None]
    return d


def _sum_over_regions(terms: FloatArray) -> FloatArray:
    """``(R, M) -> (M,)``: each point's terms added region by region, in order, whatever ``M`` (``einsum``
    and ``sum`` add three terms in another order for one point than for many: a point's ray would
    depend on the points solved with it)."""
    total = terms[0].copy()
    for row in terms[1:]:
        total += row
    return total


# --------------------------------------------------------------------------------------------------
# Distortion
# --------------------------------------------------------------------------------------------------
def distort_normalized(xy: ArrayLike, dist: ArrayLike | None) -> FloatArray:
    """Apply OpenCV's radial-tangential distortion to normalised image coordinates.

    Parameters
    ----------
    xy : array_like, shape (..., 2)
        Ideal normalised coordinates ``(X/Z, Y/Z)`` in the camera frame (unitless).
    dist : array_like or None
        ``(k1, k2, p1, p2[, k3])``.

    Returns
    -------
    ndarray, shape (..., 2)
        Distorted normalised coordinates.
    """
    q, lead = _as_vectors(xy, 2, "xy")
    return _distort(q, _check_dist(dist)).reshape(*lead, 2)


def _distort(q: FloatArray, d: FloatArray) -> FloatArray:
    k1, k2, p1, p2, k3 = d
    x, y = q[:, 0], q[:, 1]
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xy2 = 2.0 * x * y
    xd = x * radial + p1 * xy2 + p2 * (r2 + 2.0 * x * x)
    yd = y * radial + p1 * (r2 + 2.0 * y * y) + p2 * xy2
    return np.column_stack([xd, yd])


def undistort_normalized(xy_distorted: ArrayLike, dist: ArrayLike | None) -> FloatArray:
    """Invert :func:`distort_normalized` to machine precision.

    The initial guess comes from ``cv2.undistortPoints`` (fixed-point iteration, robust for
    strong distortion); it is then polished with a vectorised Newton iteration using the
    analytic 2x2 Jacobian of the distortion model.

    Parameters
    ----------
    xy_distorted : array_like, shape (..., 2)
        Distorted normalised coordinates (unitless).
    dist : array_like or None
        ``(k1, k2, p1, p2[, k3])``.

    Returns
    -------
    ndarray, shape (..., 2)
        Ideal normalised coordinates.

    Raises
    ------
    ValueError
        If the inversion does not converge (distortion not invertible there).
    """
    qd, lead = _as_vectors(xy_distorted, 2, "xy_distorted")
    d = _check_dist(dist)
    if not np.any(d) or qd.shape[0] == 0:
        return qd.copy().reshape(*lead, 2)
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, _CV_UNDISTORT_ITERATIONS, _CV_UNDISTORT_EPS)
    # OpenCV < 5 names the overload with termination criteria undistortPointsIter; 5 folds it in.
    undistort = getattr(cv2, "undistortPointsIter", None)
    pts = qd.reshape(-1, 1, 2)
    q = (
        (
            undistort(pts, np.eye(3), d, None, None, crit)
            if undistort
            else cv2.undistortPoints(pts, np.eye(3), d, None, None, None, crit)
        )
        .reshape(-1, 2)
        .astype(float)
    )
    k1, k2, p1, p2, k3 = d
    scale = 1.0 + np.abs(qd).max(axis=1)
    for _ in range(_UNDISTORT_MAX_ITER):
        x, y = q[:, 0], q[:, 1]
        r2 = x * x + y * y
        radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        dradial = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)  # d radial / d r2
        res = _distort(q, d) - qd
        j11 = radial + 2.0 * x * x * dradial + 2.0 * p1 * y + 6.0 * p2 * x
        j22 = radial + 2.0 * y * y * dradial + 6.0 * p1 * y + 2.0 * p2 * x
        j12 = 2.0 * x * y * dradial + 2.0 * p1 * x + 2.0 * p2 * y
        det = j11 * j22 - j12 * j12
        dx = (j22 * res[:, 0] - j12 * res[:, 1]) / det
        dy = (j11 * res[:, 1] - j12 * res[:, 0]) / det
        q = q - np.column_stack([dx, dy])
        if np.all(np.abs(res).max(axis=1) <= 8.0 * np.finfo(float).eps * scale):
            break
    res = np.abs(_distort(q, d) - qd).max(axis=1)
    if not np.all(np.isfinite(q)) or np.any(res > 1e-10 * scale):
        raise ValueError(
            "undistortion did not converge for some pixels (distortion model not invertible "
            "there; pixels far outside the calibrated field?)"
        )
    return q.reshape(*lead, 2)


# --------------------------------------------------------------------------------------------------
# Projection and back-projection
# --------------------------------------------------------------------------------------------------
def project_points(
    points_J: ArrayLike,
    K: ArrayLike,
    dist: ArrayLike | None,
    T_J_cam: ArrayLike,
    layers: FlatLayers | None,
) -> FloatArray:
    """Project points through the flat layers into a pinhole camera with OpenCV distortion.

    Parameters
    ----------
    points_J : array_like, shape (..., 3)
        Points in J, mm (typically markers in the oil).
    K : array_like, shape (3, 3)
        Intrinsics ``[[fx, s, cx], [0, fy, cy], [0, 0, 1]]``, pixels (skew ``s`` is honoured;
        OpenCV ignores it, so keep it 0 when comparing with OpenCV).
    dist : array_like or None
        OpenCV distortion ``(k1, k2, p1, p2[, k3])``; None or zeros for none.
    T_J_cam : array_like, shape (4, 4)
        Camera pose in J; its centre must be below every interface.
    layers : FlatLayers or None
        The refracting interfaces; ``None`` for points seen in a straight line (plain pinhole).

    Returns
    -------
    ndarray, shape (..., 2)
        Pixel coordinates ``(u, v)`` = (column, row).

    Raises
    ------
    ValueError
        If a point is behind the camera (its ray leaves the camera with ``z_cam <= 0``), or on
        invalid inputs (see :func:`refracted_ray_directions`).
    """
    if layers is not None:
        return project_point_sets([(points_J, 0)], [(K, dist, T_J_cam)], layers)[0]
    T = _check_pose(T_J_cam)
    p, lead = _as_vectors(points_J, 3, "points_J")
    return _pixels(p, p - T[:3, 3], _check_K(K), _check_dist(dist), T).reshape(*lead, 2)


def project_point_sets(
    point_sets: Sequence[tuple[ArrayLike, int]],
    cameras: Sequence[tuple[ArrayLike, ArrayLike | None, ArrayLike]],
    layers: FlatLayers,
) -> list[FloatArray]:
    """:func:`project_points` of several sets of points, each into one of the cameras, through the same
    layers: the pixels one call per set gives, in one solve of the refracted rays.

    Parameters
    ----------
    point_sets : ``(points_J, camera)`` per set: ``(..., 3)`` points in J (mm) and the index of their
        camera in ``cameras``.
    cameras : ``(K, dist, T_J_cam)`` per camera, as :func:`project_points` takes them.
    layers : FlatLayers
        The refracting interfaces.

    Returns
    -------
    list of ndarray
        Each set's pixels, shape ``(..., 2)``.

    Raises
    ------
    ValueError
        As :func:`project_points`.
    """
    checked = []
    for K, dist, T_J_cam in cameras:
        T = _check_pose(T_J_cam)
        checked.append((_check_K(K), _check_dist(dist), T, _check_center(T[:3, 3], layers)))
    for _, camera in point_sets:  # a negative index would pick a camera from the end
        if (
            isinstance(camera, bool)
            or not isinstance(camera, int | np.integer)
            or not 0 <= camera < len(checked)
        ):
            raise ValueError(
                f"a point set's camera must be an index in 0..{len(checked) - 1}, got {camera!r}"
            )
    sets = [(*_as_vectors(points_J, 3, "points_J"), checked[camera]) for points_J, camera in point_sets]
    directions = _directions_of_sets([cam[3] for *_, cam in sets], [p for p, _, _ in sets], layers)
    return [
        _pixels(p, dirs_J, Km, d, T).reshape(*lead, 2)
        for (p, lead, (Km, d, T, _)), dirs_J in zip(sets, directions, strict=True)
    ]


def _pixels(p: FloatArray, dirs_J: FloatArray, Km: FloatArray, d: FloatArray, T: FloatArray) -> FloatArray:
    """(M, 2) pixels of the rays leaving a camera at pose ``T`` along ``dirs_J`` towards points ``p``."""
    dirs_cam = dirs_J @ T[:3, :3]  # R^T d for each row
    zc = dirs_cam[:, 2]
    if np.any(zc <= 1e-12):
        bad = np.flatnonzero(zc <= 1e-12)
        raise ValueError(
            f"project_points: {bad.size} point(s) are behind the camera or in its image plane "
            f"(first index {int(bad[0])}, point {p[bad[0]].tolist()} mm in J)"
        )
    q = dirs_cam[:, :2] / zc[:, None]
    qd = _distort(q, d) if np.any(d) else q
    u = Km[0, 0] * qd[:, 0] + Km[0, 1] * qd[:, 1] + Km[0, 2]
    v = Km[1, 1] * qd[:, 1] + Km[1, 2]
    return np.column_stack([u, v])


def trace_rays_through_layers(
    origins_J: ArrayLike, directions_J: ArrayLike, layers: FlatLayers
) -> tuple[FloatArray, FloatArray]:
    """Trace rays starting in region 0 upwards through every interface.

    Parameters
    ----------
    origins_J : array_like, shape (..., 3)
        Ray origins in J, mm, strictly below the lowest interface.
    directions_J : array_like, shape (..., 3)
        Initial directions in J (need not be unit); must point upwards (``d_z > 0``).
    layers : FlatLayers
        The refracting interfaces.

    Returns
    -------
    origins : ndarray, shape (..., 3)
        Intersection of each ray with the last (top) interface, J, mm.
    directions : ndarray, shape (..., 3)
        Unit direction of each ray in the top region, J.

    Raises
    ------
    ValueError
        If an origin is not below the interfaces, a ray does not go up, or total internal
        reflection occurs.
    """
    o, lead = _as_vectors(origins_J, 3, "origins_J")
    d, lead_d = _as_vectors(directions_J, 3, "directions_J")
    if lead != lead_d:
        raise ValueError(f"origins_J {lead} and directions_J {lead_d} must have the same shape")
    z_if = layers.interfaces_z_mm
    n_reg = layers.refractive_indices
    if np.any(o[:, 2] >= z_if[0]):
        raise ValueError(
            f"ray origins must lie in region 0, strictly below the lowest interface z = {z_if[0]} mm"
        )
    if np.any(d[:, 2] <= 0):
        raise ValueError(
            "some rays do not go upwards (d_z <= 0 in J) and never reach the interfaces; "
            "is the camera looking up?"
        )
    d = d / np.linalg.norm(d, axis=1)[:, None]
    for k, zk in enumerate(z_if):
        s = (zk - o[:, 2]) / d[:, 2]
        o = o + s[:, None] * d
        o[:, 2] = zk
        if n_reg[k] != n_reg[k + 1]:
            d = refract_directions(d, n_reg[k], n_reg[k + 1])
    return o.reshape(*lead, 3), d.reshape(*lead, 3)


def backproject_pixels(
    pixels: ArrayLike,
    K: ArrayLike,
    dist: ArrayLike | None,
    T_J_cam: ArrayLike,
    layers: FlatLayers,
) -> tuple[FloatArray, FloatArray]:
    """Back-project pixels to refracted rays in the top region (the oil).

    Parameters
    ----------
    pixels : array_like, shape (..., 2)
        Pixel coordinates ``(u, v)`` = (column, row).
    K : array_like, shape (3, 3)
        Intrinsics, pixels (see :func:`project_points`).
    dist : array_like or None
        OpenCV distortion ``(k1, k2, p1, p2[, k3])``.
    T_J_cam : array_like, shape (4, 4)
        Camera pose in J; its centre must be below every interface.
    layers : FlatLayers
        The refracting interfaces.

    Returns
    -------
    origins : ndarray, shape (..., 3)
        Where each ray crosses the last interface, J, mm.
    directions : ndarray, shape (..., 3)
        Unit direction of each ray in the top region, J.

    Raises
    ------
    ValueError
        If the camera is not below the interfaces, a pixel's ray does not go up, undistortion
        fails, or total internal reflection occurs.
    """
    T = _check_pose(T_J_cam)
    Km = _check_K(K)
    d = _check_dist(dist)
    px, lead = _as_vectors(pixels, 2, "pixels")
    y = (px[:, 1] - Km[1, 2]) / Km[1, 1]
    x = (px[:, 0] - Km[0, 2] - Km[0, 1] * y) / Km[0, 0]
    q = undistort_normalized(np.column_stack([x, y]), d)
    rays_cam = np.column_stack([q, np.ones(q.shape[0])])
    rays_J = rays_cam @ T[:3, :3].T
    c = T[:3, 3]
    if not c[2] < layers.interfaces_z_mm[0]:
        raise ValueError(
            f"camera centre z = {c[2]} mm must lie in region 0, strictly below the lowest "
            f"interface z = {layers.interfaces_z_mm[0]} mm"
        )
    o, dj = trace_rays_through_layers(np.broadcast_to(c, rays_J.shape), rays_J, layers)
    return o.reshape(*lead, 3), dj.reshape(*lead, 3)


def rays_in_top_region(
    pixels: ArrayLike,
    K: ArrayLike,
    dist: ArrayLike | None,
    T_J_cam: ArrayLike,
    layers: FlatLayers,
) -> tuple[FloatArray, FloatArray]:
    """Back-project pixels to refracted rays in the top region, in closed form.

    Same inputs, outputs and errors as :func:`backproject_pixels` (and the same rays, to ~1e-12 mm),
    without its per-interface loop and validation (the pose is not re-checked): see
    :func:`rays_in_top_region_normalized`.

    Parameters
    ----------
    pixels : array_like, shape (..., 2)
        Pixel coordinates ``(u, v)`` = (column, row).
    K : array_like, shape (3, 3)
        Intrinsics, pixels.
    dist : array_like or None
        OpenCV distortion ``(k1, k2, p1, p2[, k3])``.
    T_J_cam : array_like, shape (4, 4)
        Camera pose in J (a rigid transform); its centre must be below every interface.
    layers : FlatLayers
        The refracting interfaces.

    Returns
    -------
    origins : ndarray, shape (..., 3)
        Where each ray crosses the last interface, J, mm.
    directions : ndarray, shape (..., 3)
        Unit direction of each ray in the top region, J.

    Raises
    ------
    ValueError
        If the camera is not below the interfaces, a pixel's ray does not go up, or total internal
        reflection occurs.
    """
    px = np.asarray(pixels, dtype=float)
    lead = px.shape[:-1]
    T = np.asarray(T_J_cam, dtype=float)
    q = pixels_to_normalized(px.reshape(-1, 2), K, dist)
    o, d = rays_in_top_region_normalized(q[None], T[None, :3, :3], T[None, :3, 3], layers)
    return o[0].reshape(*lead, 3), d[0].reshape(*lead, 3)


def pixels_to_normalized(pixels: FloatArray, K: ArrayLike, dist: ArrayLike | None) -> FloatArray:
    """Ideal normalised image coordinates ``(X/Z, Y/Z)`` of ``(M, 2)`` pixels (``K`` inverted, then the
    distortion, if any, with :func:`undistort_normalized`)."""
    Km = np.asarray(K, dtype=float)
    q = (pixels - Km[:2, 2]) / Km[[0, 1], [0, 1]]
    if Km[0, 1] != 0.0:
        q[:, 0] -= Km[0, 1] * q[:, 1] / Km[0, 0]
    if dist is not None and np.any(dist):
        q = undistort_normalized(q, dist)
    return q


def rays_in_top_region_normalized(
    normalized: FloatArray, R_J_cam: FloatArray, centers_J: FloatArray, layers: FlatLayers
) -> tuple[FloatArray, FloatArray]:
    """Refracted rays in the top region of ``C`` cameras' ideal normalised image points, in closed form.

    Through horizontal interfaces a ray keeps its azimuth and its invariant ``kappa = n_0 sin(theta_0)``,
    so in region ``i`` its unit direction has horizontal part ``u_xy n_0 / n_i`` and vertical part
    ``c_i = sqrt(1 - (n_0 / n_i)^2 |u_xy|^2)`` (``u`` its unit direction in region 0), and it reaches the
    top interface displaced horizontally by ``u_xy (h_0 / u_z + sum_i h_i (n_0 / n_i) / c_i)`` with
    ``h_i`` the height of region ``i`` below the top: no refraction and validation per interface, as
    :func:`backproject_pixels` does.

    Parameters
    ----------
    normalized : (C, M, 2) ideal normalised coordinates ``(X/Z, Y/Z)`` in each camera.
    R_J_cam : (C, 3, 3) the cameras' orientations in J.
    centers_J : (C, 3) the cameras' centres in J (mm), below every interface.
    layers : the refracting interfaces.

    Returns
    -------
    origins, directions : (C, M, 3) where each ray crosses the last interface (J, mm) and its unit
        direction above it.

    Raises
    ------
    ValueError
        If a camera is not below the interfaces, a ray does not go up, or total internal reflection
        occurs.
    """
    z_if, ratio, ratio_sq, layer_advance = layer_constants(layers)
    heights_0 = z_if[0] - centers_J[:, 2]  # (C,) air between each camera and the first interface
    if not (heights_0 > 0).all():
        raise ValueError(
            f"camera centre z = {centers_J[:, 2].min()} mm must lie in region 0, strictly below the lowest "
            f"interface z = {z_if[0]} mm"
        )
    # rays = x R[:, 0] + y R[:, 1] + R[:, 2] for each camera, (C, M, 3) in J
    rays = normalized @ np.swapaxes(R_J_cam[:, :, :2], 1, 2) + R_J_cam[:, None, :, 2]
    rays /= np.sqrt(np.einsum("cmi,cmi->cm", rays, rays))[..., None]
    if not (rays[..., 2] > 0).all():
        raise ValueError(
            "some rays do not go upwards (d_z <= 0 in J) and never reach the interfaces; "
            "is the camera looking up?"
        )
    sin2 = np.einsum("cmi,cmi->cm", rays[..., :2], rays[..., :2])  # sin^2(theta_0)
    cos2 = 1.0 - np.multiply.outer(ratio_sq, sin2)  # (R - 1, C, M) in regions 1 .. R - 1
    if not (cos2 > 0).all():  # (n_0 / n_i) sin(theta_0) >= 1
        raise ValueError(f"total internal reflection for some rays going through the layers {layers}")
    cos = np.sqrt(cos2)
    advance = heights_0[:, None] / rays[..., 2]
    for k, layer in enumerate(layer_advance):  # the layers between two interfaces (the plate)
        advance += layer / cos[k]
    origins = np.empty_like(rays)
    origins[..., :2] = centers_J[:, None, :2] + rays[..., :2] * advance[..., None]
    origins[..., 2] = z_if[-1]
    directions = rays  # reused in place: the horizontal part scaled, the vertical one from Snell's law
    directions[..., :2] *= ratio[-1]
    directions[..., 2] = cos[-1]
    return origins, directions


def layer_constants(layers: FlatLayers) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """Read-only constants of the layers (made with them): interface heights, ``n_0 / n_i`` per region,
    its square in regions ``1 ..``, and ``h_i n_0 / n_i`` of the regions between two interfaces."""
    return layers._constants


def _layer_constants(
    interfaces_z_mm: tuple[float, ...], refractive_indices: tuple[float, ...]
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    z_if = np.asarray(interfaces_z_mm, dtype=float)
    ratio = refractive_indices[0] / np.asarray(refractive_indices, dtype=float)
    constants = (z_if, ratio, ratio[1:] ** 2, np.diff(z_if) * ratio[1:-1])
    for array in constants:
        array.flags.writeable = False
    return constants


def projection_jacobian(
    points_J: ArrayLike,
    K: ArrayLike,
    dist: ArrayLike | None,
    T_J_cam: ArrayLike,
    layers: FlatLayers,
    step_mm: float = 1e-3,
) -> FloatArray:
    """Jacobian of :func:`project_points` with respect to the point, by central differences.

    Parameters
    ----------
    points_J : array_like, shape (..., 3)
        Points in J, mm.
    K, dist, T_J_cam, layers
        As in :func:`project_points`.
    step_mm : float
        Finite-difference step, mm (> 0).  Points within ``step_mm`` of an interface are
        differentiated across it (the map has a kink in its derivative there).

    Returns
    -------
    ndarray, shape (..., 2, 3)
        ``J[..., r, c] = d pixel_r / d point_c``, pixels per mm.
    """
    _, lead = _as_vectors(points_J, 3, "points_J")
    stencil = jacobian_stencil(points_J, step_mm)
    return stencil_jacobian(project_points(stencil, K, dist, T_J_cam, layers), step_mm).reshape(*lead, 2, 3)


def jacobian_stencil(points_J: ArrayLike, step_mm: float = 1e-3) -> FloatArray:
    """The ``(6 M, 3)`` points whose projections give :func:`projection_jacobian` at ``M`` points (each
    point moved by ``+step_mm``, then ``-step_mm``, along x, y and z): for a caller that projects them
    with other points (:func:`project_point_sets`) and then calls :func:`stencil_jacobian`."""
    if not (np.isfinite(step_mm) and step_mm > 0):
        raise ValueError(f"step_mm must be a positive number, got {step_mm}")
    p, _ = _as_vectors(points_J, 3, "points_J")
    offsets = np.concatenate([np.eye(3), -np.eye(3)]) * step_mm  # (6, 3)
    return (p[:, None, :] + offsets[None, :, :]).reshape(-1, 3)


def stencil_jacobian(pixels: ArrayLike, step_mm: float = 1e-3) -> FloatArray:
    """``(M, 2, 3)`` central differences of the ``(6 M, 2)`` pixels of a :func:`jacobian_stencil` with
    the same step: ``J[m, r, c] = d pixel_r / d point_c`` (px per mm)."""
    uv = np.asarray(pixels, dtype=float).reshape(-1, 6, 2)
    jac = (uv[:, :3, :] - uv[:, 3:, :]) / (2.0 * step_mm)  # (M, 3 [coord], 2 [pixel])
    return np.swapaxes(jac, 1, 2)
