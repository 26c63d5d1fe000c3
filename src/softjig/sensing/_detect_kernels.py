"""Compiled loops of :mod:`softjig.sensing.detect` (private; Numba): the pyramid's candidate search and
the markers' point asymmetry.

:func:`coarse_peaks` finds and refines the peaks of the coarse LoG response in one call, where NumPy
and a k-d tree take several calls per image (see benchmarks/RESULTS.md for the gain);
:func:`point_asymmetry` compares each marker with its half-turn image.
"""

from __future__ import annotations

import math

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


@numba.njit(cache=True, nogil=True)
def point_asymmetry(image, xy, amplitude, radius, scale):
    """:func:`softjig.sensing.detect.point_asymmetry`'s loop: for each centre ``xy[k]`` (px) the RMS
    difference between the pixels within ``radius`` of it and their half-turn images about it, over
    ``amplitude[k]`` (full-scale fractions; ``scale``: full scale per image unit); NaN where the
    amplitude is not positive or fewer than half of the pixel pairs lie inside the image.

    The half-turn of pixel ``c + d`` about ``(u, v)`` lies at ``2 (u, v) - c - d``, whose fractional part
    is the same for every ``d``: one set of bilinear weights per centre. A pair and its half-turn give
    the same difference, so one half of the disc is summed (``d_y > 0``, and ``d_x > 0`` on ``d_y = 0``).
    """
    h, w = image.shape
    reach = math.ceil(radius)
    side = 2 * reach + 1
    offsets = np.empty((side * side, 2), np.int64)  # the half disc's offsets d
    pairs = 0
    for dy in range(0, reach + 1):
        for dx in range(-reach, reach + 1):
            if not (dy == 0 and dx <= 0) and dx * dx + dy * dy <= radius * radius:
                offsets[pairs, 0], offsets[pairs, 1] = dx, dy
                pairs += 1
    out = np.full(xy.shape[0], np.nan)
    for k in range(xy.shape[0]):
        u, v, a = xy[k, 0], xy[k, 1], amplitude[k]
        if pairs == 0 or not (a > 0.0 and math.isfinite(u) and math.isfinite(v)):
            continue
        cu, cv = math.floor(u + 0.5), math.floor(v + 0.5)
        mu, mv = 2.0 * u - cu, 2.0 * v - cv  # the half-turn of c + d is (mu - dx, mv - dy)
        fu, fv = math.floor(mu), math.floor(mv)
        tu, tv = mu - fu, mv - fv
        w00, w10, w01, w11 = (1 - tu) * (1 - tv), tu * (1 - tv), (1 - tu) * tv, tu * tv
        inside = min(cu, fu) - reach >= 0 and min(cv, fv) - reach >= 0
        inside = inside and max(cu, fu + 1) + reach < w and max(cv, fv + 1) + reach < h
        total, used = 0.0, 0
        for j in range(pairs):
            dx, dy = offsets[j, 0], offsets[j, 1]
            pu, pv, qu, qv = cu + dx, cv + dy, fu - dx, fv - dy
            if not inside and (
                pu < 0 or pv < 0 or pu >= w or pv >= h or qu < 0 or qv < 0 or qu + 1 >= w or qv + 1 >= h
            ):
                continue
            turned = (
                w00 * image[qv, qu]
                + w10 * image[qv, qu + 1]
                + w01 * image[qv + 1, qu]
                + w11 * image[qv + 1, qu + 1]
            )
            d = image[pv, pu] - turned
            total += d * d
            used += 1
        if 2 * used >= pairs:
            out[k] = math.sqrt(total / used) * scale / a
    return out
