"""Compiled loops of the pyramid's candidate search in :mod:`softjig.sensing.detect` (private; Numba).

:func:`coarse_peaks` finds and refines the peaks of the coarse LoG response in one call, where NumPy
and a k-d tree take several calls per image (see benchmarks/RESULTS.md for the gain).
"""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True, nogil=True)
def coarse_peaks(response, threshold, half_width, fit_pinv, max_offset):
    """Peaks of the coarse response, quadratic-refined: ``(u, v)`` (M, 2) coarse px and values (M,).

    In one call, what ``detect._local_maxima`` and ``detect._refine_quadratic`` do (border 1): a pixel
    above ``threshold`` is a peak if no pixel within ``half_width`` (Chebyshev) is larger, nor equal
    and earlier in row-major order (on an exact plateau the first pixel is kept). A fit that is not a
    maximum within ``max_offset`` keeps the pixel and its value. The scan (:func:`flank_free`) and the
    peaks' tests are separate loops: fused, the scan's loop vectorises less well.
    """
    rows, cols = flank_free(response, threshold)
    xy = np.empty((len(rows), 2))
    vals = np.empty(len(rows))
    window = np.empty(9)
    fit = np.empty(6)
    n = 0
    for i in range(len(rows)):
        r, c = rows[i], cols[i]
        if not is_peak(response, r, c, half_width):
            continue
        k = 0
        for dr in range(-1, 2):
            for dc in range(-1, 2):
                window[k] = response[r + dr, c + dc]
                k += 1
        fit[:] = 0.0  # fit_pinv @ window, written out (a BLAS call per peak cost 1 us)
        for a in range(6):
            for j in range(9):
                fit[a] += fit_pinv[a, j] * window[j]
        x, y, peak = quadratic_maximum(fit, float(response[r, c]), max_offset)
        xy[n, 0], xy[n, 1], vals[n] = c + x, r + y, peak
        n += 1
    return xy[:n].copy(), vals[:n].copy()


@numba.njit(cache=True, nogil=True)
def flank_free(response, threshold):
    """Row-major rows and columns of the pixels above ``threshold`` with no larger 4-neighbour (border 1).

    Written without short-circuits: many pixels above the threshold sit on a peak's flank, and the
    mispredicted branches of ``and``/``or`` would cost more than the comparisons they skip.
    """
    h, w = response.shape
    rows, cols = [], []
    for r in range(1, h - 1):
        up, row, down = response[r - 1], response[r], response[r + 1]
        for c in range(1, w - 1):
            value = row[c]
            flank = (row[c + 1] > value) | (down[c] > value) | (row[c - 1] > value) | (up[c] > value)
            if (value > threshold) & (not flank):
                rows.append(r)
                cols.append(c)
    return rows, cols


@numba.njit(cache=True, nogil=True)
def is_peak(response, r, c, half_width):
    """Whether no pixel within ``half_width`` (Chebyshev) of ``(r, c)`` is larger, nor equal and earlier
    in row-major order."""
    h, w = response.shape
    value = response[r, c]
    for rr in range(max(r - half_width, 0), min(r + half_width + 1, h)):
        for cc in range(max(c - half_width, 0), min(c + half_width + 1, w)):
            other = response[rr, cc]
            if other > value or (other == value and (rr < r or (rr == r and cc < c))):
                return False
    return True


@numba.njit(cache=True, nogil=True)
def quadratic_maximum(fit, value, max_offset):
    """Offset ``(x, y)`` and value of the maximum of ``a + b x + c y + d x^2 + e x y + f y^2``
    (``fit``); ``(0, 0, value)`` if it is not a maximum within ``max_offset`` per axis."""
    a, b, cq, d, e, f = fit[0], fit[1], fit[2], fit[3], fit[4], fit[5]
    det = 4.0 * d * f - e * e
    if d < 0.0 and det > 0.0:
        xf = (e * cq - 2.0 * f * b) / det
        yf = (e * b - 2.0 * d * cq) / det
        if abs(xf) <= max_offset and abs(yf) <= max_offset:
            return xf, yf, a + b * xf + cq * yf + d * xf * xf + e * xf * yf + f * yf * yf
    return 0.0, 0.0, value
