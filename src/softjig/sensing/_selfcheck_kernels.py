"""Compiled kernels of :mod:`softjig.sensing.selfcheck`: the split halves' two plane fits and their noise,
per principal axis, in one pass (Numba is confined to the ``_kernels`` modules, issue 16).

Numba's cache checks only the file of the kernel it caches (its modification time and size), not the
kernels it calls: those of :mod:`softjig._geometry_kernels` are compiled into it, so a change there needs
this file touched too, or the cache keeps the old code (the hand-written 3x3 solvers of ``plane_fit``,
issue 14, came with this paragraph).
"""

from __future__ import annotations

import numba
import numpy as np

from softjig._geometry_kernels import median_in_place, plane_fit

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
    axis of the points' centred ``(x, y)`` (:func:`half_fits_into`).

    Written in loops over preallocated arrays, with the median by :func:`~softjig._geometry_kernels.
    median_in_place`: NumPy's ``mean``, ``median``, array expressions and slice assignments compiled in
    bring their checks and error messages, symbols every new process loads (start-up, issue 14).
    """
    n = points.shape[0]
    mx, my = 0.0, 0.0
    for i in range(n):  # as ``points[:, 0].mean()``: summed in order, then divided
        mx += points[i, 0]
        my += points[i, 1]
    mx /= n
    my /= n
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
    scratch = np.empty(n)
    side = np.empty(n, dtype=np.bool_)
    mask = np.empty(n, dtype=np.bool_)
    for k in range(2):
        ux, uy = np.cos(phi + 0.5 * np.pi * k), np.sin(phi + 0.5 * np.pi * k)
        for i in range(n):
            along[i] = (points[i, 0] - mx) * ux + (points[i, 1] - my) * uy
            scratch[i] = along[i]
        middle = median_in_place(scratch)
        for i in range(n):
            side[i] = along[i] > middle
        ok[k] = half_fits_into(points, side, sigma, min_points, mask, normals[k], sigmas[k])
    return ok, normals, sigmas


@numba.njit  # no cache of its own: compiled into its callers'
def half_fits_into(
    points: np.ndarray,
    side: np.ndarray,
    sigma: float,
    min_points: int,
    mask: np.ndarray,
    normals: np.ndarray,
    sigmas: np.ndarray,
) -> bool:
    """The least-squares planes of ``points[side]`` and ``points[~side]`` into ``normals`` (2, 3) and
    ``sigmas`` (2,), ``mask`` (N,) as scratch: each normal with ``n_z > 0`` and the RMS angle of its error
    for a depth noise ``sigma`` (mm), as :func:`~softjig.sensing.uncertainty.normal_uncertainty` with
    ``point_sigma_mm``; false when a half has fewer than ``min_points`` or its ``(x, y)`` lie on a line
    (an expected outcome, not an error: the first half that fails leaves its row and the later ones as
    they were)."""
    for h in range(2):
        count = 0
        for i in range(points.shape[0]):
            mask[i] = side[i] == (h == 0)
            count += mask[i]
        if count < min_points:
            return False
        c, _, n, _ = plane_fit(points, mask)  # the one plane fit (n_z >= 0)
        if n[2] <= VERTICAL_NZ:
            return False
        sxx, sxy, syy = 0.0, 0.0, 0.0  # the (x, y) scatter, summed as plane_fit's
        for i in range(points.shape[0]):
            if mask[i]:
                d0, d1 = points[i, 0] - c[0], points[i, 1] - c[1]
                sxx += d0 * d0
                sxy += d0 * d1
                syy += d1 * d1
        det = sxx * syy - sxy * sxy
        if det <= COLLINEAR_DET_RATIO * (sxx + syy) ** 2:
            return False
        # cov(a, b) = sigma^2 (X^T X)^-1 of the slopes, propagated to the unit normal (normal_from_slopes):
        # J (3x2) = [[-(1 + b^2), a b], [a b, -(1 + a^2)], [-a, -b]] / w3, trace(J cov J^T)
        scale = sigma * sigma / det
        caa, cab, cbb = scale * syy, -scale * sxy, scale * sxx
        a, b = -n[0] / n[2], -n[1] / n[2]
        w3 = (1.0 + a * a + b * b) ** 1.5
        trace = 0.0
        for r in range(3):
            if r == 0:
                j0, j1 = -(1.0 + b * b) / w3, a * b / w3
            elif r == 1:
                j0, j1 = a * b / w3, -(1.0 + a * a) / w3
            else:
                j0, j1 = -a / w3, -b / w3
            trace += j0 * j0 * caa + 2.0 * j0 * j1 * cab + j1 * j1 * cbb
        for k in range(3):
            normals[h, k] = n[k]
        sigmas[h] = np.sqrt(trace)
    return True
