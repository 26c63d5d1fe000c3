"""Compiled loops of :func:`softjig.sensing.fiducials.locate_quads_near` (private; Numba).

:func:`locate` runs the three steps (capture the sides on scanlines, refine the corners as OpenCV's
``cornerSubPix`` does, read the cells) in one call: each Python-level call would cost more than the step.
"""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True, nogil=True)
def locate(
    image, index, n_lines, n_samples, midpoints, normals, offsets, min_rise, min_lines, agreement_px,
    max_size_change_px, half, max_iters, eps, weights, white, min_contrast, corners,
):  # fmt: skip
    """The three steps of ``fiducials.locate_quads_near`` in one call, the corners into ``corners``
    (Q, 4, 2); False if any step fails."""
    if not capture(
        image.ravel(), index, n_lines, n_samples, midpoints, normals, offsets, min_rise, min_lines,
        agreement_px, max_size_change_px, corners,
    ):  # fmt: skip
        return False
    if not corner_subpix(image, corners.reshape(-1, 2), half, max_iters, eps):
        return False
    return cells_read(image, corners, weights, white, min_contrast)


@numba.njit(nogil=True)  # no cache of its own: compiled into its callers'
def capture(
    image, index, n_lines, n_samples, midpoints, normals, offsets, min_rise, min_lines, agreement_px,
    max_size_change_px, corners,
):  # fmt: skip
    """The capture step: where each side is, and the quads' corners where those sides meet, into
    ``corners`` (Q, 4, 2); False if a side was not found, or a quad's opposite sides moved unlike (one
    of them took another edge).

    On each scanline (``index`` into the flat image, ``n_samples`` each, ``fiducials.CAPTURE_STEP_PX`` apart,
    ``n_lines`` per side), the side is the outermost rise between two samples of at least half the
    largest (and ``min_rise``); the side moves along its normal by the median of its scanlines, at
    least ``min_lines`` of which must agree to ``agreement_px``; opposite sides must move alike to
    ``max_size_change_px``.
    """
    n_quads = normals.shape[0]
    shift = np.empty((n_quads, 4))
    found = np.empty(n_lines)
    profile = np.empty(n_samples)
    for q in range(n_quads):
        for side in range(4):
            n_found = 0
            for line in range(n_lines):
                base = ((q * 4 + side) * n_lines + line) * n_samples
                for i in range(n_samples):
                    profile[i] = image[index[base + i]]
                top = -1.0e9
                for i in range(n_samples - 1):
                    top = max(top, profile[i + 1] - profile[i])
                if top < min_rise:
                    continue
                threshold = max(float(int(top) // 2), min_rise)
                for i in range(n_samples - 2, -1, -1):
                    if profile[i + 1] - profile[i] >= threshold:
                        found[n_found] = midpoints[i]
                        n_found += 1
                        break
            if n_found < min_lines:
                return False
            for i in range(1, n_found):  # insertion sort of the few votes
                v, j = found[i], i - 1
                while j >= 0 and found[j] > v:
                    found[j + 1] = found[j]
                    j -= 1
                found[j + 1] = v
            median = found[(n_found - 1) // 2]
            agree = 0
            for i in range(n_found):
                if abs(found[i] - median) <= agreement_px:
                    agree += 1
            if agree < min_lines:
                return False
            shift[q, side] = median
        for side in range(2):  # opposite sides move alike (the quad's size changes by ~1 px)
            if abs(shift[q, side] + shift[q, side + 2]) > max_size_change_px:
                return False
        for c in range(4):  # corner c: where side c - 1 meets side c
            a, b = (c + 3) % 4, c
            na0, na1, nb0, nb1 = normals[q, a, 0], normals[q, a, 1], normals[q, b, 0], normals[q, b, 1]
            ra, rb = offsets[q, a] + shift[q, a], offsets[q, b] + shift[q, b]
            det = na0 * nb1 - na1 * nb0
            if abs(det) < 1e-6:
                return False
            corners[q, c, 0] = (ra * nb1 - na1 * rb) / det
            corners[q, c, 1] = (na0 * rb - ra * nb0) / det
    return True


@numba.njit(nogil=True)  # no cache of its own: compiled into its callers'
def corner_subpix(image, corners, half, max_iters, eps):
    """OpenCV's ``cornerSubPix`` (no dead zone) on ``corners`` (N, 2) px, in place; False if a corner
    moved more than ``half`` px (OpenCV then puts it back: here the caller gives up).

    The same iteration as OpenCV's (Gaussian-weighted gradients of a bilinearly resampled window around
    the current estimate, the point where the window's edges meet, until a step is below ``eps`` px or
    ``max_iters`` steps), so it converges to the same corners (to ~``eps``); ported to run inside the
    fused kernel (``cv2.cornerSubPix`` costs more per call than the iteration itself).
    """
    h, w = image.shape
    n = 2 * half + 1
    mask = np.empty((n, n))
    for i in range(n):
        y = (i - half) / half
        for j in range(n):
            x = (j - half) / half
            mask[i, j] = np.exp(-y * y) * np.exp(-x * x)
    patch = np.empty((n + 2, n + 2))
    for k in range(corners.shape[0]):
        x0, y0 = corners[k, 0], corners[k, 1]
        cx, cy = x0, y0
        for _ in range(max_iters):
            # the (n + 2)^2 window centred at (cx, cy), bilinear (as cv2.getRectSubPix)
            left, top = cx - (half + 1), cy - (half + 1)
            ix, iy = int(np.floor(left)), int(np.floor(top))
            a, b = left - ix, top - iy
            if ix < 0 or iy < 0 or ix + n + 2 >= w or iy + n + 2 >= h:
                return False
            for i in range(n + 2):
                for j in range(n + 2):
                    patch[i, j] = (1.0 - b) * (
                        (1.0 - a) * image[iy + i, ix + j] + a * image[iy + i, ix + j + 1]
                    ) + b * ((1.0 - a) * image[iy + i + 1, ix + j] + a * image[iy + i + 1, ix + j + 1])
            sxx, sxy, syy, bx, by = 0.0, 0.0, 0.0, 0.0, 0.0
            for i in range(n):
                py = i - half
                for j in range(n):
                    px = j - half
                    gx = patch[i + 1, j + 2] - patch[i + 1, j]
                    gy = patch[i + 2, j + 1] - patch[i, j + 1]
                    m = mask[i, j]
                    gxx, gxy, gyy = gx * gx * m, gx * gy * m, gy * gy * m
                    sxx += gxx
                    sxy += gxy
                    syy += gyy
                    bx += gxx * px + gxy * py
                    by += gxy * px + gyy * py
            det = sxx * syy - sxy * sxy
            if abs(det) <= 1e-300:
                break
            nx = cx + (syy * bx - sxy * by) / det
            ny = cy + (sxx * by - sxy * bx) / det
            step2 = (nx - cx) ** 2 + (ny - cy) ** 2
            cx, cy = nx, ny
            if cx < 0 or cx >= w or cy < 0 or cy >= h or step2 <= eps * eps:
                break
        if abs(cx - x0) > half or abs(cy - y0) > half:
            return False
        corners[k, 0], corners[k, 1] = cx, cy
    return True


@numba.njit(nogil=True)  # no cache of its own: compiled into its callers'
def cells_read(image, quads, weights, white, min_contrast):
    """Whether every fiducial's 6x6 cells (black border and 4x4 bits) read as ``white`` (M, 36) says, in
    the quads' orientation.

    Each cell is sampled at the points ``weights`` (36 * 3, 4) gives (bilinear in the quad: perspective
    is negligible over one fiducial); a fiducial reads when all cells are on their side of the midpoint
    between its black and white means, with at least ``min_contrast`` between them.
    """
    h, w = image.shape
    n_cells = white.shape[1]
    per_cell = weights.shape[0] // n_cells
    cells = np.empty(n_cells)
    for q in range(quads.shape[0]):
        for cell in range(n_cells):
            total = 0.0
            for k in range(per_cell):
                row = cell * per_cell + k
                x, y = 0.0, 0.0
                for c in range(4):
                    x += weights[row, c] * quads[q, c, 0]
                    y += weights[row, c] * quads[q, c, 1]
                col, line = int(np.rint(x)), int(np.rint(y))
                if col < 0 or line < 0 or col >= w or line >= h:
                    return False
                total += image[line, col]
            cells[cell] = total / per_cell
        white_sum, black_sum, n_white = 0.0, 0.0, 0.0
        for cell in range(n_cells):
            if white[q, cell] > 0.5:
                white_sum += cells[cell]
                n_white += 1.0
            else:
                black_sum += cells[cell]
        if n_white == 0.0 or n_white == n_cells:
            return False
        white_mean, black_mean = white_sum / n_white, black_sum / (n_cells - n_white)
        if not white_mean - black_mean >= min_contrast:
            return False
        middle = (white_mean + black_mean) / 2.0
        for cell in range(n_cells):
            if (cells[cell] > middle) != (white[q, cell] > 0.5):
                return False
    return True
