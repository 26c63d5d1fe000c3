"""Compiled kernels of :mod:`softjig.sensing.selfcheck`: the split halves' two plane fits and their noise,
per principal axis, in one pass (Numba is confined to the ``_kernels`` modules, issue 16).

Numba's cache keys a kernel on its own module's text: the code of the kernels it calls
(:mod:`softjig._geometry_kernels`) is compiled into it, so a change there needs a change here too (the
hand-written 3x3 solvers of ``plane_fit``, issue 14, came with this paragraph).
"""

from __future__ import annotations

import numba
import numpy as np

from softjig._geometry_kernels import plane_fit

#: A half's plane with ``n_z`` at most this is vertical: no tilt to compare.
VERTICAL_NZ = 1e-9
#: A half's ``(x, y)`` scatter whose determinant is below this share of its squared trace lies on a line.
COLLINEAR_DET_RATIO = 1e-12


@numba.njit(cache=True)
def split_fits(
    points: np.ndarray, sigma: float, min_points: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``selfcheck.split_halves``' splits in one compiled pass:
    ``(ok (2,), normals (2, 2, 3), sigmas (2, 2))`` for the splits at the median along each principal
    axis of the points' centred ``(x, y)`` (:func:`half_fits`)."""
    n = points.shape[0]
    mx, my = points[:, 0].mean(), points[:, 1].mean()
    sxx, sxy, syy = 0.0, 0.0, 0.0
    for i in range(n):
        dx, dy = points[i, 0] - mx, points[i, 1] - my
        sxx += dx * dx
        sxy += dx * dy
        syy += dy * dy
    # The 2x2 scatter's eigenvectors in closed form: the major axis at angle phi, the minor across it.
    phi = 0.5 * np.arctan2(2.0 * sxy, sxx - syy)
    ok = np.zeros(2, dtype=np.bool_)
    normals = np.zeros((2, 2, 3))
    sigmas = np.zeros((2, 2))
    along = np.empty(n)
    for k in range(2):
        ux, uy = np.cos(phi + 0.5 * np.pi * k), np.sin(phi + 0.5 * np.pi * k)
        for i in range(n):
            along[i] = (points[i, 0] - mx) * ux + (points[i, 1] - my) * uy
        side = along > np.median(along)
        ok[k], normals[k], sigmas[k] = half_fits(points, side, sigma, min_points)
    return ok, normals, sigmas


@numba.njit(cache=True)
def half_fits(
    points: np.ndarray, side: np.ndarray, sigma: float, min_points: int
) -> tuple[bool, np.ndarray, np.ndarray]:
    """The least-squares planes of ``points[side]`` and ``points[~side]``: ``(ok, normals (2, 3),
    sigmas (2,))``, each normal with ``n_z > 0`` and the RMS angle of its error for a depth noise
    ``sigma`` (mm), as :func:`~softjig.sensing.uncertainty.normal_uncertainty` with ``point_sigma_mm``
    (``ok`` false when a half has fewer than ``min_points`` or its ``(x, y)`` lie on a line: an expected
    outcome, not an error).
    """
    normals = np.zeros((2, 3))
    sigmas = np.zeros(2)
    for h in range(2):
        mask = side == (h == 0)
        if mask.sum() < min_points:
            return False, normals, sigmas
        c, _, n, _ = plane_fit(points, mask)  # the one plane fit (n_z >= 0)
        if n[2] <= VERTICAL_NZ:
            return False, normals, sigmas
        sxx, sxy, syy = 0.0, 0.0, 0.0  # the (x, y) scatter, summed as plane_fit's
        for i in range(points.shape[0]):
            if mask[i]:
                d0, d1 = points[i, 0] - c[0], points[i, 1] - c[1]
                sxx += d0 * d0
                sxy += d0 * d1
                syy += d1 * d1
        det = sxx * syy - sxy * sxy
        if det <= COLLINEAR_DET_RATIO * (sxx + syy) ** 2:
            return False, normals, sigmas
        # cov(a, b) = sigma^2 (X^T X)^-1 of the slopes, propagated to the unit normal (normal_from_slopes)
        scale = sigma * sigma / det
        caa, cab, cbb = scale * syy, -scale * sxy, scale * sxx
        a, b = -n[0] / n[2], -n[1] / n[2]
        w3 = (1.0 + a * a + b * b) ** 1.5
        j = np.array([[-(1.0 + b * b), a * b], [a * b, -(1.0 + a * a)], [-a, -b]]) / w3
        trace = 0.0
        for r in range(3):
            trace += j[r, 0] * j[r, 0] * caa + 2.0 * j[r, 0] * j[r, 1] * cab + j[r, 1] * j[r, 1] * cbb
        normals[h] = n
        sigmas[h] = np.sqrt(trace)
    return True, normals, sigmas
