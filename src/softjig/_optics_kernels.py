"""Compiled kernel of :mod:`softjig.optics`: the Newton solve of the refracted rays from camera centres to
points through flat layers (:func:`softjig.optics.refracted_ray_directions`), for many sets of points at
once (an estimator's set-up projects about 1500 points in five sets: the NumPy loop's per-operation cost
was most of the set-up)."""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True, nogil=True)
def layered_directions(cz, rel, pz, z_if, n_reg, sets, n_sets, max_iter, tol, out):
    """Unit initial directions of points above the first interface into ``out`` (M, 3).

    Parameters
    ----------
    cz : (M,) the height of each point's camera (mm, below the first interface).
    rel : (M, 3) each point less its camera's centre (mm).
    pz : (M,) the points' heights (mm).
    z_if, n_reg : (R - 1,) interface heights (mm) and (R,) each region's refractive index.
    sets : (M,) each point's set, ``0 .. n_sets - 1``.
    max_iter, tol : at most this many Newton steps; a point moving by at most ``tol`` relative settled.

    Notes
    -----
    The operations of the NumPy solve, in its order, so the directions are the same to the bit: Newton
    in ``t = tan`` of the ray in the lowest-index region crossed, from ``t = 0``, every point of a set
    stepped until all of them settled, then frozen.
    """
    n_points = pz.shape[0]
    n_regions = n_reg.shape[0]
    w = np.empty((n_regions, n_points))
    b = np.empty((n_regions, n_points))
    a = np.empty(n_regions)
    n_min = np.empty(n_points)
    rho = np.empty(n_points)
    for i in range(n_regions):
        a[i] = n_reg[i] * n_reg[i]
    for j in range(n_points):
        smallest = np.inf
        for i in range(n_regions):
            lo = cz[j] if i == 0 else z_if[i - 1]
            top = min(pz[j], z_if[i]) if i < n_regions - 1 else pz[j]
            height = max(top - lo, 0.0)
            w[i, j] = height
            if height > 0.0 and n_reg[i] < smallest:
                smallest = n_reg[i]
        n_min[j] = smallest
        for i in range(n_regions):
            b[i, j] = a[i] - smallest * smallest if w[i, j] > 0.0 else 0.0
            w[i, j] = w[i, j] * smallest
        rho[j] = np.hypot(rel[j, 0], rel[j, 1])
    t = np.zeros(n_points)
    active = np.ones(n_sets, dtype=np.bool_)
    unsettled = np.zeros(n_sets, dtype=np.bool_)
    for _ in range(max_iter):
        unsettled[:] = False
        for j in range(n_points):
            if not active[sets[j]]:
                continue
            g, dg = 0.0, 0.0
            tj = t[j]
            for i in range(n_regions):
                inv_sq = 1.0 / np.sqrt(a[i] + b[i, j] * (tj * tj))
                g += w[i, j] * inv_sq
                dg += (w[i, j] * a[i]) * (inv_sq * inv_sq * inv_sq)
            g = tj * g - rho[j]
            stepped = tj - g / dg
            t_new = stepped if not stepped < 0.0 else 0.0
            if not abs(t_new - tj) <= tol * t_new:
                unsettled[sets[j]] = True
            t[j] = t_new
        done = True
        for s in range(n_sets):
            active[s] = active[s] and unsettled[s]
            done = done and not active[s]
        if done:
            break
    a0 = n_reg[0] * n_reg[0]
    for j in range(n_points):
        tan0 = n_min[j] * t[j] / np.sqrt(a0 + (a0 - n_min[j] * n_min[j]) * t[j] * t[j])
        scale = tan0 / rho[j] if rho[j] > 0.0 else 0.0
        x, y = rel[j, 0] * scale, rel[j, 1] * scale
        norm = np.sqrt(x * x + y * y + 1.0)
        out[j, 0] = x / norm
        out[j, 1] = y / norm
        out[j, 2] = 1.0 / norm
