"""Compiled loops of :mod:`softjig.sensing.jigframe` (private; Numba).

:func:`gauss_newton` fits the stereo head's pose to the fiducial corners (on NumPy arrays each step would
be about a hundred small array operations); :func:`inside_quads` tests the detector's candidates against
the fiducials' quads (vectorised, NumPy's inner loops are too short to pay).
"""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True, nogil=True)
def gauss_newton(points, observed, n_left, focal, centre, R_start, t_start, R_rl, t_rl, max_steps, tol):
    """Gauss-Newton steps of the head's pose ``(R, t)`` (``T_left_J``) for corners ``points`` (N, 3) in J
    seen at ``observed`` (N, 2) px, the first ``n_left`` in the left camera and the rest in the right one.

    Returns ``R``, ``t``, the residuals (2 N,) px before the last step, and whether a step fell below
    ``tol`` (rad, and ``100 tol`` mm) within ``max_steps``.
    """
    n = points.shape[0]
    R = R_start.copy()
    t = t_start.copy()
    residuals = np.empty(2 * n)
    H = np.empty((6, 6))
    b = np.empty(6)
    row = np.empty(6)
    g = np.empty(3)
    gr = np.empty(3)
    X_left = np.empty(3)
    X = np.empty(3)
    rotation = np.empty((3, 3))
    for _ in range(max_steps):
        H[:] = 0.0
        b[:] = 0.0
        for k in range(n):
            for i in range(3):
                X_left[i] = R[i, 0] * points[k, 0] + R[i, 1] * points[k, 1] + R[i, 2] * points[k, 2] + t[i]
            if k >= n_left:
                for i in range(3):
                    X[i] = R_rl[i, 0] * X_left[0] + R_rl[i, 1] * X_left[1] + R_rl[i, 2] * X_left[2] + t_rl[i]
            else:
                X[:] = X_left
            inv_z = 1.0 / X[2]
            for c in range(2):  # u, then v
                f = focal[k, c]
                r = f * X[c] * inv_z + centre[k, c] - observed[k, c]
                residuals[2 * k + c] = r
                g[:] = 0.0  # d pixel / d X in this camera
                g[c] = f * inv_z
                g[2] = -f * X[c] * inv_z * inv_z
                if k >= n_left:  # to d pixel / d X_left
                    for i in range(3):
                        gr[i] = g[0] * R_rl[0, i] + g[1] * R_rl[1, i] + g[2] * R_rl[2, i]
                    g[:] = gr
                row[0] = X_left[1] * g[2] - X_left[2] * g[1]  # X_left x g: d pixel / d omega
                row[1] = X_left[2] * g[0] - X_left[0] * g[2]
                row[2] = X_left[0] * g[1] - X_left[1] * g[0]
                row[3], row[4], row[5] = g[0], g[1], g[2]
                for i in range(6):
                    b[i] -= row[i] * r
                    for j in range(i + 1):
                        H[i, j] += row[i] * row[j]
        # Cholesky H = L L^T (lower triangle of H), then two triangular solves for the step
        for j in range(6):
            d = H[j, j]
            for m in range(j):
                d -= H[j, m] * H[j, m]
            if not d > 0.0:
                return R, t, residuals, False
            H[j, j] = np.sqrt(d)
            for i in range(j + 1, 6):
                s = H[i, j]
                for m in range(j):
                    s -= H[i, m] * H[j, m]
                H[i, j] = s / H[j, j]
        for i in range(6):
            s = b[i]
            for m in range(i):
                s -= H[i, m] * b[m]
            b[i] = s / H[i, i]
        for i in range(5, -1, -1):
            s = b[i]
            for m in range(i + 1, 6):
                s -= H[m, i] * b[m]
            b[i] = s / H[i, i]
        # R <- exp(omega) R, t <- exp(omega) t + v (Rodrigues' formula)
        wx, wy, wz = b[0], b[1], b[2]
        theta = np.sqrt(wx * wx + wy * wy + wz * wz)
        if theta < 1e-12:
            sa, sb = 1.0, 0.5
        else:
            sa, sb = np.sin(theta) / theta, (1.0 - np.cos(theta)) / (theta * theta)
        # exp(omega) = I + sa [omega]_x + sb [omega]_x^2, with [omega]_x^2 = omega omega^T - theta^2 I
        for i in range(3):  # b[:3] is omega
            for j in range(3):
                rotation[i, j] = sb * b[i] * b[j]
            rotation[i, i] += 1.0 - sb * theta * theta
        rotation[0, 1] -= sa * wz
        rotation[1, 0] += sa * wz
        rotation[0, 2] += sa * wy
        rotation[2, 0] -= sa * wy
        rotation[1, 2] -= sa * wx
        rotation[2, 1] += sa * wx
        for j in range(3):  # R <- rotation R, column by column
            c0, c1, c2 = R[0, j], R[1, j], R[2, j]
            for i in range(3):
                R[i, j] = rotation[i, 0] * c0 + rotation[i, 1] * c1 + rotation[i, 2] * c2
        c0, c1, c2 = t[0], t[1], t[2]
        for i in range(3):
            t[i] = rotation[i, 0] * c0 + rotation[i, 1] * c1 + rotation[i, 2] * c2 + b[3 + i]
        if max(abs(wx), abs(wy), abs(wz)) < tol and max(abs(b[3]), abs(b[4]), abs(b[5])) < 100.0 * tol:
            return R, t, residuals, True
    return R, t, residuals, False


@numba.njit(cache=True, nogil=True)
def inside_quads(xy, quads):
    """Whether each point ``xy`` (N, 2) lies inside (or on the edge of) any convex quad (Q, 4, 2)."""
    out = np.zeros(xy.shape[0], np.bool_)
    for q in range(quads.shape[0]):
        lo_u, hi_u = quads[q, :, 0].min(), quads[q, :, 0].max()
        lo_v, hi_v = quads[q, :, 1].min(), quads[q, :, 1].max()
        for i in range(xy.shape[0]):
            u, v = xy[i, 0], xy[i, 1]
            if out[i] or not (lo_u <= u <= hi_u and lo_v <= v <= hi_v):
                continue
            positive = negative = True
            for k in range(4):
                a, b = quads[q, k], quads[q, (k + 1) % 4]
                cross = (b[0] - a[0]) * (v - a[1]) - (b[1] - a[1]) * (u - a[0])
                positive &= cross >= 0.0
                negative &= cross <= 0.0
            out[i] = positive or negative
    return out
