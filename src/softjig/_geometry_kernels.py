"""Compiled kernels of :mod:`softjig.geometry`: the one least-squares plane fit (also run inside the robust
fit's refinement, :mod:`softjig.sensing._robust_kernels`) and the convex-hull test of the contact."""

from __future__ import annotations

import numba
import numpy as np

#: Below this ratio of the second to the first singular value the 3x3 scatter matrix has lost the
#: precision of the small singular values (their squares sit near the rounding of the large one's): the
#: plane is then taken from the SVD of the centred points themselves.
SCATTER_PRECISE_RATIO = 1e-6


@numba.njit(cache=True)
def plane_fit(points: np.ndarray, mask: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """Least-squares plane of the finite ``(N, 3)`` points selected by ``mask`` (at least one).

    Returns
    -------
    centroid : (3,) the selected points' mean.
    singular_values : (3,) of the centred points, descending.
    normal : (3,) unit normal, the right singular vector of the smallest singular value, ``n_z >= 0``.
    rms : float the RMS distance of the selected points to the plane.

    Notes
    -----
    The normal is the eigenvector of the smallest eigenvalue of the 3x3 scatter matrix (the singular
    values are the square roots of its eigenvalues): one pass over the points, no ``(N, 3)`` SVD. Nearly
    degenerate points (second singular value below :data:`SCATTER_PRECISE_RATIO` of the first) are
    fitted by the SVD of the centred points instead, which keeps the small singular values' precision.
    """
    n = points.shape[0]
    m = 0
    centroid = np.zeros(3)
    for i in range(n):
        if mask[i]:
            m += 1
            for k in range(3):
                centroid[k] += points[i, k]
    centroid /= m
    scatter = np.zeros((3, 3))
    for i in range(n):
        if mask[i]:
            d0, d1, d2 = points[i, 0] - centroid[0], points[i, 1] - centroid[1], points[i, 2] - centroid[2]
            scatter[0, 0] += d0 * d0
            scatter[0, 1] += d0 * d1
            scatter[0, 2] += d0 * d2
            scatter[1, 1] += d1 * d1
            scatter[1, 2] += d1 * d2
            scatter[2, 2] += d2 * d2
    scatter[1, 0], scatter[2, 0], scatter[2, 1] = scatter[0, 1], scatter[0, 2], scatter[1, 2]
    eigval, eigvec = np.linalg.eigh(scatter)  # ascending
    singular = np.sqrt(np.maximum(eigval[::-1], 0.0))
    normal = eigvec[:, 0].copy()
    if singular[0] > 0.0 and singular[1] <= SCATTER_PRECISE_RATIO * singular[0]:
        centred = np.empty((m, 3))
        row = 0
        for i in range(n):
            if mask[i]:
                for k in range(3):
                    centred[row, k] = points[i, k] - centroid[k]
                row += 1
        _, singular, vt = np.linalg.svd(centred, full_matrices=False)
        if singular.shape[0] < 3:  # fewer than 3 points: the plane's normal is not determined
            singular = np.concatenate((singular, np.zeros(3 - singular.shape[0])))
        normal = vt[vt.shape[0] - 1].copy()
    if normal[2] < 0:
        normal = -normal
    total = 0.0
    for i in range(n):
        if mask[i]:
            r = (
                (points[i, 0] - centroid[0]) * normal[0]
                + (points[i, 1] - centroid[1]) * normal[1]
                + (points[i, 2] - centroid[2]) * normal[2]
            )
            total += r * r
    return centroid, singular, normal, np.sqrt(total / m)


@numba.njit(cache=True)
def inside_hull(members: np.ndarray, query: np.ndarray, tolerance: float) -> np.ndarray:
    """Which ``(x, y)`` of ``query`` lie inside the convex hull of ``members`` (or within ``tolerance``
    outside it); none when the hull has no area.

    Andrew's monotone chain for the strictly convex hull (counter-clockwise), then one edge test per
    query point.
    """
    inside = np.zeros(query.shape[0], dtype=np.bool_)
    m = members.shape[0]
    if m < 3:
        return inside
    order = np.argsort(members[:, 0], kind="mergesort")
    for i in range(1, m):  # ties in x by y (insertion: the order is nearly sorted)
        j = i
        while j > 0:
            a, b = order[j - 1], order[j]
            if members[a, 0] == members[b, 0] and members[a, 1] > members[b, 1]:
                order[j - 1], order[j] = b, a
                j -= 1
            else:
                break
    hull = np.empty(2 * m + 1, dtype=np.int64)
    k = 0
    for step in range(2):
        start = k
        for s in range(m):
            i = order[s] if step == 0 else order[m - 1 - s]
            while k >= start + 2:
                o, a = hull[k - 2], hull[k - 1]
                turn = (members[a, 0] - members[o, 0]) * (members[i, 1] - members[o, 1]) - (
                    members[a, 1] - members[o, 1]
                ) * (members[i, 0] - members[o, 0])
                if turn > 0.0:
                    break
                k -= 1
            hull[k] = i
            k += 1
        k -= 1  # the last point of each chain starts the other
    h = k
    if h < 3:
        return inside
    for q in range(query.shape[0]):
        ok = True
        for e in range(h):
            a, b = hull[e], hull[(e + 1) % h]
            ex, ey = members[b, 0] - members[a, 0], members[b, 1] - members[a, 1]
            cross = ex * (query[q, 1] - members[a, 1]) - ey * (query[q, 0] - members[a, 0])
            if -cross > tolerance * np.sqrt(ex * ex + ey * ey):
                ok = False
                break
        inside[q] = ok
    return inside
