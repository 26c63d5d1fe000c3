"""Compiled kernel of :mod:`softjig.sensing.uncertainty`: a plane's residual sum and the points' ``(x, y)``
scatter in one pass (Numba is confined to the ``_kernels`` modules, issue 16)."""

from __future__ import annotations

import numba
import numpy as np

from softjig.errors import InputError

#: What :func:`moments` raises for a NaN or inf point.
NON_FINITE = "normal_uncertainty got non-finite points (NaN or inf); drop them first."


@numba.njit(cache=True, error_model="numpy")  # n_z = 0 gives inf, reported below, not an exception
def moments(points: np.ndarray, normal: np.ndarray, offset: float) -> tuple[float, np.ndarray]:
    """The sum of squared vertical residuals to the plane ``normal . p + offset = 0`` and ``X^T X`` of the
    centred ``(x, y)``.

    Raises
    ------
    InputError
        A point is not finite (NaN or inf), with the message the user sees.
    """
    n = points.shape[0]
    mx, my, rss = 0.0, 0.0, 0.0
    for i in range(n):
        if not (np.isfinite(points[i, 0]) and np.isfinite(points[i, 1]) and np.isfinite(points[i, 2])):
            raise InputError(NON_FINITE)
        mx += points[i, 0]
        my += points[i, 1]
        r = (
            -(points[i, 0] * normal[0] + points[i, 1] * normal[1] + points[i, 2] * normal[2] + offset)
            / normal[2]
        )
        rss += r * r
    mx /= max(n, 1)
    my /= max(n, 1)
    xtx = np.zeros((2, 2))
    for i in range(n):
        dx, dy = points[i, 0] - mx, points[i, 1] - my
        xtx[0, 0] += dx * dx
        xtx[0, 1] += dx * dy
        xtx[1, 1] += dy * dy
    xtx[1, 0] = xtx[0, 1]
    return rss, xtx
