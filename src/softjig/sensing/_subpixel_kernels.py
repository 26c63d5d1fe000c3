"""Compiled loops of :func:`softjig.sensing.subpixel.refine_centres` (private; Numba).

One call, :func:`refine_all`, does every marker's fit: the windows are gathered, multiplied by the
weight tables and fitted by Newton's steps on the weights' cubic, with no per-call NumPy overhead and no
BLAS. See :mod:`softjig.sensing.subpixel` for the model and :func:`refine_all` for which windows are fitted.
"""

from __future__ import annotations

import math

import numba
import numpy as np

MAX_WINDOWS = 3  # windows fitted per marker, at most (the start's, then towards its fit)
CHUNK = 32  # windows gathered at a time: 55 kB of float32 for 21x21 windows
_MAX_STEP_PX = 0.5  # a window's Newton step is clipped to this, per axis
_STEP_TOLERANCE_PX = 1e-6  # a window's Newton steps converged (its fit then within 1e-12 px)
_CLAMP_MARGIN_PX = 0.25  # a window's fit may extrapolate the weights' cubic this far past its range
_HALF_PIXEL = 0.5  # a fit within this of its window's central pixel (per axis) is that window's own


@numba.njit(cache=True, nogil=True)
def refine_all(image, start, tables_t, half, scale, table_range, max_shift, iterations, xy, amp, ok):
    """Fit every marker; writes the centres ``xy`` (N, 2), amplitudes ``amp`` and success ``ok``.

    Round 1 fits each marker in the window centred on the pixel nearest its start. A marker whose fit
    lies nearer another pixel is fitted again in the window centred there, up to :data:`MAX_WINDOWS`
    windows; the result is the successful fit lying nearest its own window's centre (``max |f - c|``),
    within ``max_shift`` px of the start. A fit that found a bright blob beyond its window's reach also
    moves the window there. The windows are gathered :data:`CHUNK` at a time and multiplied by the tables
    in blocks of 4 windows (:func:`block_product`); a window's fit (:func:`steps`) starts at its centre,
    so it is a function of the window's pixels only.
    """
    n_markers = start.shape[0]
    n = 2 * half + 1
    windows = np.zeros((CHUNK, n * n), np.float32)  # zeros: the padding rows of a last block are finite
    coeffs = np.empty((CHUNK, tables_t.shape[0]), np.float32)
    centre = np.empty((n_markers, 2), np.int64)
    tried = np.empty((n_markers, MAX_WINDOWS, 2), np.int64)
    n_tried = np.zeros(n_markers, np.int64)
    best = np.full(n_markers, np.inf)
    todo = np.empty(n_markers, np.int64)
    again = np.empty(n_markers, np.int64)
    count = 0
    for m in range(n_markers):
        su, sv = start[m, 0], start[m, 1]
        xy[m, 0], xy[m, 1], amp[m], ok[m] = su, sv, 0.0, False
        if math.isfinite(su) and math.isfinite(sv):
            centre[m, 0], centre[m, 1] = math.floor(su + 0.5), math.floor(sv + 0.5)
            todo[count] = m
            count += 1
    for _ in range(MAX_WINDOWS):
        n_again = 0
        for c0 in range(0, count, CHUNK):
            rows = min(CHUNK, count - c0)
            for i in range(rows):
                m = todo[c0 + i]
                gather(image, centre[m, 0] - half, centre[m, 1] - half, n, windows[i])
            block_product(windows, tables_t, coeffs, rows)
            for i in range(rows):
                m = todo[c0 + i]
                cu, cv = centre[m, 0], centre[m, 1]
                u, v, a, good = steps(coeffs[i], cu, cv, scale, table_range, iterations)
                k = n_tried[m]
                tried[m, k, 0], tried[m, k, 1] = cu, cv
                n_tried[m] = k + 1
                off = max(abs(u - cu), abs(v - cv))
                near = abs(u - start[m, 0]) <= max_shift and abs(v - start[m, 1]) <= max_shift
                if good and near and off < best[m]:
                    best[m] = off
                    xy[m, 0], xy[m, 1], amp[m], ok[m] = u, v, a, True
                if (good and off <= _HALF_PIXEL) or not a > 0.0 or k + 1 >= MAX_WINDOWS:
                    continue
                nu, nv = math.floor(u + 0.5), math.floor(v + 0.5)
                seen = False
                for j in range(k + 1):
                    seen = seen or (tried[m, j, 0] == nu and tried[m, j, 1] == nv)
                if not seen:
                    centre[m, 0], centre[m, 1] = nu, nv
                    again[n_again] = m
                    n_again += 1
        todo, again = again, todo
        count = n_again
        if count == 0:
            break


@numba.njit(cache=True, nogil=True)
def gather(image, u0, v0, n, window):
    """The ``n x n`` window of top-left pixel ``(u0, v0)``, row-major, into ``window`` (float32); pixels
    past the image edge are read as the nearest edge pixel."""
    h, w = image.shape
    if u0 >= 0 and v0 >= 0 and u0 + n <= w and v0 + n <= h:
        for r in range(n):
            row = image[v0 + r]
            for c in range(n):
                window[r * n + c] = row[u0 + c]
        return
    for r in range(n):
        row = image[min(max(v0 + r, 0), h - 1)]
        for c in range(n):
            window[r * n + c] = row[min(max(u0 + c, 0), w - 1)]


@numba.njit(cache=True, nogil=True, fastmath={"reassoc", "contract"})
def block_product(windows, tables_t, coeffs, rows):
    """``coeffs[:rows] = windows[:rows] @ tables_t.T`` (float32), in blocks of 4 windows x 5 table rows.

    Twenty independent sums, vectorised over the pixels (``reassoc``), reuse each loaded value four or
    five times. Rows past ``rows`` up to a multiple of 4 are computed and ignored (every window is summed
    in the same order, wherever it is in the block).
    """
    n = windows.shape[1]
    for i in range(0, rows, 4):
        x0, x1, x2, x3 = windows[i], windows[i + 1], windows[i + 2], windows[i + 3]
        for j in range(0, tables_t.shape[0], 5):
            t0, t1, t2, t3, t4 = (
                tables_t[j],
                tables_t[j + 1],
                tables_t[j + 2],
                tables_t[j + 3],
                tables_t[j + 4],
            )
            a00 = a01 = a02 = a03 = a04 = a10 = a11 = a12 = a13 = a14 = np.float32(0.0)
            a20 = a21 = a22 = a23 = a24 = a30 = a31 = a32 = a33 = a34 = np.float32(0.0)
            for k in range(n):
                p0, p1, p2, p3, p4 = t0[k], t1[k], t2[k], t3[k], t4[k]
                y = x0[k]
                a00, a01, a02, a03, a04 = a00 + y * p0, a01 + y * p1, a02 + y * p2, a03 + y * p3, a04 + y * p4
                y = x1[k]
                a10, a11, a12, a13, a14 = a10 + y * p0, a11 + y * p1, a12 + y * p2, a13 + y * p3, a14 + y * p4
                y = x2[k]
                a20, a21, a22, a23, a24 = a20 + y * p0, a21 + y * p1, a22 + y * p2, a23 + y * p3, a24 + y * p4
                y = x3[k]
                a30, a31, a32, a33, a34 = a30 + y * p0, a31 + y * p1, a32 + y * p2, a33 + y * p3, a34 + y * p4
            c = coeffs[i]
            c[j], c[j + 1], c[j + 2], c[j + 3], c[j + 4] = a00, a01, a02, a03, a04
            c = coeffs[i + 1]
            c[j], c[j + 1], c[j + 2], c[j + 3], c[j + 4] = a10, a11, a12, a13, a14
            c = coeffs[i + 2]
            c[j], c[j + 1], c[j + 2], c[j + 3], c[j + 4] = a20, a21, a22, a23, a24
            c = coeffs[i + 3]
            c[j], c[j + 1], c[j + 2], c[j + 3], c[j + 4] = a30, a31, a32, a33, a34


@numba.njit(cache=True, nogil=True)
def steps(coeffs, cu, cv, scale, table_range, iterations):
    """Newton steps on ``(A du, A dv)(t) = 0`` from the central pixel ``(cu, cv)`` of the window, the
    weights' cubic (``coeffs``: 10 monomials in graded order, 3 values each) evaluated at the offset
    ``t`` from it.

    The fit is where the linearised estimate of the centre's offset from the reference ``t`` is zero,
    the fixed point of the Gauss-Newton steps ``t <- t + (A du, A dv) / A``; Newton's steps use the
    cubic's exact Jacobian. Where that Jacobian is not a bright blob's centre's (far from it), the step is
    the Gauss-Newton one. The coefficients are read into scalars once (faster than a monomial array).

    Returns the centre ``(u, v)``, the amplitude and whether the fit succeeded (a bright marker, the
    steps converged inside their clamp, ``table_range`` plus a margin).
    """
    a0, u0, v0 = np.float64(coeffs[0]), np.float64(coeffs[1]), np.float64(coeffs[2])
    a1, u1, v1 = np.float64(coeffs[3]), np.float64(coeffs[4]), np.float64(coeffs[5])
    a2, u2, v2 = np.float64(coeffs[6]), np.float64(coeffs[7]), np.float64(coeffs[8])
    a3, u3, v3 = np.float64(coeffs[9]), np.float64(coeffs[10]), np.float64(coeffs[11])
    a4, u4, v4 = np.float64(coeffs[12]), np.float64(coeffs[13]), np.float64(coeffs[14])
    a5, u5, v5 = np.float64(coeffs[15]), np.float64(coeffs[16]), np.float64(coeffs[17])
    a6, u6, v6 = np.float64(coeffs[18]), np.float64(coeffs[19]), np.float64(coeffs[20])
    a7, u7, v7 = np.float64(coeffs[21]), np.float64(coeffs[22]), np.float64(coeffs[23])
    a8, u8, v8 = np.float64(coeffs[24]), np.float64(coeffs[25]), np.float64(coeffs[26])
    a9, u9, v9 = np.float64(coeffs[27]), np.float64(coeffs[28]), np.float64(coeffs[29])
    lim = table_range + _CLAMP_MARGIN_PX
    tu = 0.0
    tv = 0.0
    a = 0.0
    converged = False
    for _ in range(iterations):
        uu, uv, vv = tu * tu, tu * tv, tv * tv
        uuu, uuv, uvv, vvv = uu * tu, uu * tv, tu * vv, vv * tv
        a = a0 + a1 * tu + a2 * tv + a3 * uu + a4 * uv + a5 * vv + a6 * uuu + a7 * uuv + a8 * uvv + a9 * vvv
        if not a > 0.0:
            break
        au = u0 + u1 * tu + u2 * tv + u3 * uu + u4 * uv + u5 * vv + u6 * uuu + u7 * uuv + u8 * uvv + u9 * vvv
        av = v0 + v1 * tu + v2 * tv + v3 * uu + v4 * uv + v5 * vv + v6 * uuu + v7 * uuv + v8 * uvv + v9 * vvv
        # Jacobian of (au, av) with respect to t
        juu = u1 + 2.0 * u3 * tu + u4 * tv + 3.0 * u6 * uu + 2.0 * u7 * uv + u8 * vv
        juv = u2 + u4 * tu + 2.0 * u5 * tv + u7 * uu + 2.0 * u8 * uv + 3.0 * u9 * vv
        jvu = v1 + 2.0 * v3 * tu + v4 * tv + 3.0 * v6 * uu + 2.0 * v7 * uv + v8 * vv
        jvv = v2 + v4 * tu + 2.0 * v5 * tv + v7 * uu + 2.0 * v8 * uv + 3.0 * v9 * vv
        det = juu * jvv - juv * jvu
        if det > 0.0 and juu + jvv < 0.0:
            du = (juv * av - jvv * au) / det
            dv = (jvu * au - juu * av) / det
        else:
            du, dv = au / a, av / a
        du = min(max(du, -_MAX_STEP_PX), _MAX_STEP_PX)
        dv = min(max(dv, -_MAX_STEP_PX), _MAX_STEP_PX)
        if (abs(tu) == lim and du * tu > 0.0) or (abs(tv) == lim and dv * tv > 0.0):
            break  # pushing past the clamp: no centre in this window (a fiducial's square, a cut marker)
        tu = min(max(tu + du, -lim), lim)
        tv = min(max(tv + dv, -lim), lim)
        if abs(du) < _STEP_TOLERANCE_PX and abs(dv) < _STEP_TOLERANCE_PX:
            converged = True
            break
    good = converged and a > 0.0 and abs(tu) < lim and abs(tv) < lim
    return cu + tu, cv + tv, a * scale, good
