"""The sub-pixel model fit as `refine_centres` documents it, in float64 NumPy, one marker at a time."""

from __future__ import annotations

import numpy as np

from softjig.sensing.subpixel import MarkerModel, fit_tables

MAX_WINDOWS = 3
MAX_SHIFT_PX = 2.5
CLAMP_PX = 1.25  # the weights' range (1 px) and the margin a window's fit may extrapolate


def window_fit(image: np.ndarray, centre: tuple[int, int], model: MarkerModel, iterations: int = 20):
    """One window's fit: Newton's steps on the weights' cubic from the window's centre (Gauss-Newton's
    where the Jacobian is not a bright blob's), clipped to 0.5 px a step and :data:`CLAMP_PX` in all.
    Returns ``(u, v, amplitude, good)``."""
    tables = fit_tables(model).astype(np.float64)
    half = model.half_width_px
    scale = {np.dtype(np.uint8): 1 / 255, np.dtype(np.uint16): 1 / 65535}.get(image.dtype, 1.0)
    h, w = image.shape
    rows = np.clip(np.arange(centre[1] - half, centre[1] + half + 1), 0, h - 1)
    cols = np.clip(np.arange(centre[0] - half, centre[0] + half + 1), 0, w - 1)
    coef = (image[np.ix_(rows, cols)].astype(np.float64).ravel() @ tables).reshape(10, 3)
    t, a, converged = np.zeros(2), 0.0, False
    for _ in range(iterations):
        u, v = t
        phi = np.array([1, u, v, u * u, u * v, v * v, u**3, u * u * v, u * v * v, v**3])
        d_u = np.array([0, 1, 0, 2 * u, v, 0, 3 * u * u, 2 * u * v, v * v, 0])
        d_v = np.array([0, 0, 1, 0, u, 2 * v, 0, u * u, 2 * u * v, 3 * v * v])
        a, au, av = phi @ coef
        if not a > 0.0:
            break
        jac = np.array([[d_u @ coef[:, 1], d_v @ coef[:, 1]], [d_u @ coef[:, 2], d_v @ coef[:, 2]]])
        if np.linalg.det(jac) > 0 and np.trace(jac) < 0:
            step = -np.linalg.solve(jac, [au, av])
        else:
            step = np.array([au, av]) / a
        step = np.clip(step, -0.5, 0.5)
        if np.any((np.abs(t) == CLAMP_PX) & (step * t > 0)):
            break
        t = np.clip(t + step, -CLAMP_PX, CLAMP_PX)
        if np.all(np.abs(step) < 1e-6):
            converged = True
            break
    good = converged and a > 0 and bool(np.all(np.abs(t) < CLAMP_PX))
    return centre[0] + t[0], centre[1] + t[1], a * scale, good


def refine(image: np.ndarray, start: np.ndarray, model: MarkerModel, iterations: int = 20):
    """Every marker, one at a time: the window at the pixel nearest the start, then (up to
    :data:`MAX_WINDOWS`) the window at the pixel nearest the last fit while that fit lies nearer another
    pixel; the result is the successful fit nearest its own window's centre within :data:`MAX_SHIFT_PX`
    of the start. Returns ``(N, 2)`` centres (the start where the fit failed) and ``(N,)`` success."""
    xy, ok = np.array(start, dtype=float), np.zeros(len(start), bool)
    for m, s in enumerate(xy.copy()):
        if not np.all(np.isfinite(s)):
            continue
        centre, tried, best = tuple(np.floor(s + 0.5).astype(int)), [], np.inf
        while True:
            u, v, a, good = window_fit(image, centre, model, iterations)
            tried.append(centre)
            off = max(abs(u - centre[0]), abs(v - centre[1]))
            if good and np.abs(np.array([u, v]) - s).max() <= MAX_SHIFT_PX and off < best:
                best, xy[m], ok[m] = off, (u, v), True
            following = tuple(np.floor(np.array([u, v]) + 0.5).astype(int))
            if (good and off <= 0.5) or not a > 0 or len(tried) >= MAX_WINDOWS or following in tried:
                break
            centre = following
    return xy, ok
