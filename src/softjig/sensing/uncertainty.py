"""First-order uncertainty of a fitted plane's normal and tilt angles.

The markers' triangulation noise is mostly along ``z``, the cameras' depth direction (stereo depth error
grows as ``z^2 / (f b)`` while the lateral error stays a fraction of it), so the plane is modelled as a
regression of depth on position, about the points' centroid ``(x0, y0)``::

    z = a (x - x0) + b (y - y0) + c + e,    e ~ N(0, s^2) independent,

whose slopes have the least-squares covariance ``cov(a, b) = s^2 (X^T X)^-1`` with ``X`` the ``(N, 2)``
centred ``(x, y)`` (centring makes ``(a, b)`` uncorrelated with ``c``). The unit normal (``n_z > 0``,
into the part) and the paper's tilt angles are functions of the slopes,

    n = (-a, -b, 1) / w,   w = sqrt(1 + a^2 + b^2),
    Ax = atan2(-n_y, n_z) = atan(b),   Ay = atan2(n_x, n_z) = -atan(a),

and their covariances follow by first-order propagation, ``J cov(a, b) J^T``, with the analytic
Jacobians of :func:`normal_from_slopes` and :func:`tilt_angles_from_slopes`. To first order the SVD
(orthogonal) fit of :func:`softjig.geometry.fit_plane_svd` has the same error as this regression when the
noise is along ``z``, so the model applies to it; the Monte Carlo tests check the 1-sigma coverage.

Noise scale ``s``: ``point_sigma_mm`` when the caller knows it, else the residuals' ``s^2 = RSS / (N - 3)``
(vertical residuals to the given plane, 3 fitted parameters). Either is raised to ``floor_mm`` if smaller:
the residuals only reveal the random part of the error, while unmodelled systematic errors (membrane
ripple, refraction, calibration) do not average out over the markers, and a floor stops a lucky, very
flat sample from claiming an implausibly small uncertainty.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from softjig.checks import finite_float, positive_float
from softjig.errors import InputError
from softjig.geometry import PlaneFit

__all__ = [
    "NormalUncertainty",
    "inflated",
    "normal_from_slopes",
    "normal_uncertainty",
    "tilt_angles_from_slopes",
    "with_angle_floor",
    "with_depth_scale_error",
    "with_spread_between",
]


@dataclass(frozen=True)
class NormalUncertainty:
    """First-order uncertainty of a plane's normal, from :func:`normal_uncertainty`.

    Attributes
    ----------
    covariance : (3, 3) ndarray
        Covariance of the unit normal in J (dimensionless); rank 2, with ``n`` in its null space.
    tilt_sigma_x_rad : float
        1-sigma of the tilt angle ``Ax = atan2(-n_y, n_z)`` (rad).
    tilt_sigma_y_rad : float
        1-sigma of the tilt angle ``Ay = atan2(n_x, n_z)`` (rad).
    tilt_sigma_rad : float
        RMS angle between the estimated and the true normal, ``sqrt(trace(covariance))`` (rad).
    residual_sigma_mm : float
        The depth-noise scale ``s`` used (mm), after the floor.
    """

    covariance: np.ndarray
    tilt_sigma_x_rad: float
    tilt_sigma_y_rad: float
    tilt_sigma_rad: float
    residual_sigma_mm: float


def normal_from_slopes(slope_x: float, slope_y: float) -> tuple[np.ndarray, np.ndarray]:
    """The unit normal of the plane ``z = a x + b y + c`` and its Jacobian with respect to ``(a, b)``.

    Parameters
    ----------
    slope_x, slope_y : float
        The slopes ``a = dz/dx`` and ``b = dz/dy`` (dimensionless).

    Returns
    -------
    normal : (3,) ndarray
        ``(-a, -b, 1) / w`` with ``w = sqrt(1 + a^2 + b^2)`` (``n_z > 0``).
    jacobian : (3, 2) ndarray
        ``d n / d (a, b)``: columns ``(-(1 + b^2), a b, -a) / w^3`` and ``(a b, -(1 + a^2), -b) / w^3``.
    """
    a, b = float(slope_x), float(slope_y)
    w = np.sqrt(1.0 + a * a + b * b)
    w3 = w**3
    normal = np.array([-a, -b, 1.0]) / w
    jacobian = np.array([[-(1.0 + b * b), a * b], [a * b, -(1.0 + a * a)], [-a, -b]]) / w3
    return normal, jacobian


def tilt_angles_from_slopes(slope_x: float, slope_y: float) -> tuple[np.ndarray, np.ndarray]:
    """The tilt angles ``(Ax, Ay)`` (rad) of the plane ``z = a x + b y + c`` and their Jacobian.

    Returns
    -------
    angles : (2,) ndarray
        ``(Ax, Ay) = (atan(b), -atan(a))``, equal to :func:`softjig.geometry.tilt_angles` of the normal.
    jacobian : (2, 2) ndarray
        ``d (Ax, Ay) / d (a, b) = [[0, 1 / (1 + b^2)], [-1 / (1 + a^2), 0]]``.
    """
    a, b = float(slope_x), float(slope_y)
    angles = np.array([np.arctan(b), -np.arctan(a)])
    jacobian = np.array([[0.0, 1.0 / (1.0 + b * b)], [-1.0 / (1.0 + a * a), 0.0]])
    return angles, jacobian


def normal_uncertainty(
    points_mm: np.ndarray,
    plane: PlaneFit,
    *,
    point_sigma_mm: float | None = None,
    floor_mm: float = 0.0,
) -> NormalUncertainty:
    """First-order covariance of a fitted plane's normal and 1-sigma of its tilt angles.

    Parameters
    ----------
    points_mm : (N, 3) array_like
        The points the plane was fitted to (for a robust fit, its inliers), in J (mm).
    plane : PlaneFit
        The fitted plane (``normal`` with ``n_z > 0``); the propagation is linearised at its slopes.
    point_sigma_mm : float, optional
        Known depth-noise standard deviation of one point (mm). ``None`` estimates it from the vertical
        residuals to ``plane`` as ``sqrt(RSS / (N - 3))``, which needs ``N >= 4``.
    floor_mm : float, optional
        Lower bound on the noise scale (mm), for unmodelled systematic errors (see the module docstring).

    Returns
    -------
    NormalUncertainty
        Covariance of the unit normal (3x3, rank 2) and the 1-sigma of ``Ax``, ``Ay`` and of the angle
        between estimated and true normal (rad).

    Raises
    ------
    InputError
        Points not ``(N, 3)`` or non-finite; fewer than 4 points without ``point_sigma_mm`` (or fewer than
        3 with it); points whose ``(x, y)`` lie on a line; a plane with ``n_z <= 0``; a non-positive
        ``point_sigma_mm`` or a negative ``floor_mm``.

    Notes
    -----
    With ``cov(a, b) = s^2 (X^T X)^-1``, ``var(Ax) = var(b) / (1 + b^2)^2`` and
    ``var(Ay) = var(a) / (1 + a^2)^2``; for ``N`` points spread with RMS radius ``rho`` about their centroid
    (isotropically), ``sigma(Ax) ~ s / (rho sqrt(N / 2))`` at small tilt.

    Examples
    --------
    >>> import numpy as np
    >>> from softjig.geometry import fit_plane_svd
    >>> xy = np.array([[-10.0, 0], [10, 0], [0, -10], [0, 10]])
    >>> pts = np.column_stack([xy, np.zeros(4)])
    >>> u = normal_uncertainty(pts, fit_plane_svd(pts), point_sigma_mm=0.1)
    >>> round(u.tilt_sigma_x_rad, 6)  # 0.1 mm / sqrt(200 mm^2)
    0.007071
    """
    pts = np.asarray(points_mm, dtype=float)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise InputError(f"normal_uncertainty needs (N, 3) points, got shape {pts.shape}.")
    if not np.isfinite(pts).all():
        raise InputError("normal_uncertainty got non-finite points (NaN or inf); drop them first.")
    normal = np.asarray(plane.normal, dtype=float)
    floor = finite_float(floor_mm, "floor_mm")
    if floor < 0:
        raise InputError(f"floor_mm must be >= 0, got {floor}.")
    n_pts = len(pts)
    if point_sigma_mm is None and n_pts < 4:
        raise InputError(
            f"estimating the noise from the residuals needs at least 4 points (N - 3 > 0), got {n_pts}; "
            "pass point_sigma_mm to use a known noise."
        )
    if n_pts < 3:
        raise InputError(f"normal_uncertainty needs at least 3 points, got {n_pts}.")
    if normal.shape != (3,) or not all(math.isfinite(v) for v in normal.tolist()) or normal[2] <= 0:
        raise InputError(f"the plane's normal must be a finite 3-vector with n_z > 0, got {normal}.")

    # Scalar arithmetic on Python floats from here: the same formulas as with 2x2 NumPy arrays, without
    # their calls.
    n0, n1, n2 = normal.tolist()
    a, b = -n0 / n2, -n1 / n2
    x, y = pts[:, 0], pts[:, 1]
    if point_sigma_mm is None:
        residual = -(x * n0 + y * n1 + pts[:, 2] * n2 + float(plane.offset_mm)) / n2  # vertical (mm)
        s = math.sqrt(float(residual @ residual) / (n_pts - 3))  # 3 fitted parameters
    else:
        s = positive_float(point_sigma_mm, "point_sigma_mm")
    s = max(s, floor)

    # The 2x2 eigenvalues and inverse in closed form (no eigvalsh and inv calls).
    dx, dy = x - x.sum() / n_pts, y - y.sum() / n_pts  # X^T X of the centred (x, y) (the means)
    sxx, sxy, syy = float(dx @ dx), float(dx @ dy), float(dy @ dy)
    half_trace, det = 0.5 * (sxx + syy), sxx * syy - sxy * sxy
    root = math.hypot(0.5 * (sxx - syy), sxy)
    if half_trace - root <= 1e-12 * max(half_trace + root, 1e-300):
        raise InputError(f"the {n_pts} points' (x, y) lie on a line: the plane's tilt across it is unknown.")
    scale = s * s / det
    cov_aa, cov_ab, cov_bb = scale * syy, -scale * sxy, scale * sxx  # s^2 (X^T X)^-1

    _, jac_n = normal_from_slopes(a, b)
    cov_n = jac_n @ np.array([[cov_aa, cov_ab], [cov_ab, cov_bb]]) @ jac_n.T
    cov_n = 0.5 * (cov_n + cov_n.T)
    # Tilt angles: d(Ax, Ay)/d(a, b) = [[0, 1 / (1 + b^2)], [-1 / (1 + a^2), 0]] (tilt_angles_from_slopes).
    var_x = cov_bb / (1.0 + b * b) ** 2
    var_y = cov_aa / (1.0 + a * a) ** 2
    return NormalUncertainty(
        covariance=cov_n,
        tilt_sigma_x_rad=math.sqrt(var_x),
        tilt_sigma_y_rad=math.sqrt(var_y),
        tilt_sigma_rad=math.sqrt(cov_n[0, 0] + cov_n[1, 1] + cov_n[2, 2]),
        residual_sigma_mm=s,
    )


def with_spread_between(
    uncertainty: NormalUncertainty, normal_a: np.ndarray, normal_b: np.ndarray, *, share: float = 1.0
) -> NormalUncertainty:
    """Add the spread between two equally plausible normals (e.g. of the narrowest and widest contact the
    noise allows) to an uncertainty, as an independent error of covariance ``share^2 d d^T / 4``,
    ``d = a - b``: the two lie about one sigma either side of the truth.

    Parameters
    ----------
    uncertainty : the statistical uncertainty of the normal.
    normal_a, normal_b : (3,) unit normals with ``n_z > 0``.
    share : the part of their difference to add, in [0, 1] (e.g. the share that their own noise, already
        in ``uncertainty``, does not explain).
    """
    a, b = np.asarray(normal_a, dtype=float), np.asarray(normal_b, dtype=float)
    share = float(share)
    if not 0.0 <= share <= 1.0:
        raise InputError(f"share must be in [0, 1], got {share}.")
    half_n = share * (a - b) / 2.0
    (ax_a, ay_a), (ax_b, ay_b) = _tilts(a.tolist()), _tilts(b.tolist())  # on floats
    covariance = uncertainty.covariance + np.outer(half_n, half_n)
    return NormalUncertainty(
        covariance=covariance,
        tilt_sigma_x_rad=math.hypot(uncertainty.tilt_sigma_x_rad, share * (ax_a - ax_b) / 2.0),
        tilt_sigma_y_rad=math.hypot(uncertainty.tilt_sigma_y_rad, share * (ay_a - ay_b) / 2.0),
        tilt_sigma_rad=math.sqrt(covariance[0, 0] + covariance[1, 1] + covariance[2, 2]),
        residual_sigma_mm=uncertainty.residual_sigma_mm,
    )


def _tilts(normal) -> tuple[float, float]:
    """``(Ax, Ay)`` of a normal (rad), as :func:`softjig.geometry.tilt_angles`."""
    return math.atan2(-normal[1], normal[2]), math.atan2(normal[0], normal[2])


def inflated(uncertainty: NormalUncertainty, factor: float) -> NormalUncertainty:
    """The same uncertainty with every sigma multiplied by ``factor`` (the covariance by its square), for
    errors the model leaves out."""
    f = positive_float(factor, "factor")
    return NormalUncertainty(
        covariance=uncertainty.covariance * f * f,
        tilt_sigma_x_rad=uncertainty.tilt_sigma_x_rad * f,
        tilt_sigma_y_rad=uncertainty.tilt_sigma_y_rad * f,
        tilt_sigma_rad=uncertainty.tilt_sigma_rad * f,
        residual_sigma_mm=uncertainty.residual_sigma_mm,
    )


def with_angle_floor(
    uncertainty: NormalUncertainty, normal: np.ndarray, floor_rad: float
) -> NormalUncertainty:
    """Add an isotropic error of RMS angle ``floor_rad`` to the normal's uncertainty (``floor_rad^2 / 2``
    on each tilt angle, and in the plane perpendicular to ``normal``): a systematic error of the normal
    that does not shrink with the number of markers (the as-built jig against the nominal one)."""
    f = finite_float(floor_rad, "floor_rad")
    if f < 0:
        raise InputError(f"floor_rad must be >= 0, got {f}.")
    n = np.asarray(normal, dtype=float)
    half = 0.5 * f * f
    covariance = uncertainty.covariance + half * (np.eye(3) - np.outer(n, n))
    return NormalUncertainty(
        covariance=covariance,
        tilt_sigma_x_rad=math.sqrt(uncertainty.tilt_sigma_x_rad**2 + half),
        tilt_sigma_y_rad=math.sqrt(uncertainty.tilt_sigma_y_rad**2 + half),
        tilt_sigma_rad=math.sqrt(covariance[0, 0] + covariance[1, 1] + covariance[2, 2]),
        residual_sigma_mm=uncertainty.residual_sigma_mm,
    )


def with_depth_scale_error(
    uncertainty: NormalUncertainty, normal: np.ndarray, scale_error: float
) -> NormalUncertainty:
    """Add the error of a plane's normal whose depths are known only up to a relative ``scale_error``
    (1 sigma), the same for every marker: the normals of the plane with its depths scaled by
    ``1 + scale_error`` and ``1 - scale_error`` are one sigma either side of the truth
    (:func:`with_spread_between`).

    Why: a refractive index or a focal length a little off scales every triangulated depth by the same
    factor, which tilts a tilted face further or less far (``tan`` of its tilt scales by that factor) in
    the direction of its tilt: an error of about ``scale_error sin(tilt) cos(tilt)`` rad that does not
    shrink with the number of markers, and none for a level face.

    Parameters
    ----------
    uncertainty : the normal's uncertainty so far.
    normal : (3,) the plane's unit normal, ``n_z > 0``.
    scale_error : the relative error of the depths (1 sigma), in [0, 1).
    """
    s = finite_float(scale_error, "scale_error")
    if not 0.0 <= s < 1.0:
        raise InputError(f"scale_error must be in [0, 1), got {s}.")
    n = np.asarray(normal, dtype=float)
    # A depth scaled by k turns the normal (n_x, n_y, n_z) into one along (n_x, n_y, n_z / k).
    deeper, shallower = n / [1.0, 1.0, 1.0 + s], n / [1.0, 1.0, 1.0 - s]
    return with_spread_between(
        uncertainty, deeper / np.linalg.norm(deeper), shallower / np.linalg.norm(shallower)
    )
