"""Compiled kernels of :mod:`softjig.geometry`: the one least-squares plane fit (also run inside the robust
fit's refinement, :mod:`softjig.sensing._robust_kernels`) and the convex-hull test of the contact; and the
small solvers the other kernels share (3x3 eigen-decomposition and SVD, the median), written here rather
than compiled in from NumPy (start-up, issue 14)."""

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
    Both are solved here by Jacobi rotations (:func:`symmetric_eigen_3x3`, :func:`right_singular_3`), not
    by LAPACK: NumPy's ``eigh`` and ``svd`` compiled into a kernel carry their argument checks, copies and
    error paths, several hundred symbols that every kernel calling this one loads from Numba's cache in
    each new process (start-up, issue 14).
    """
    n = points.shape[0]
    m = 0
    centroid = np.zeros(3)
    for i in range(n):
        if mask[i]:
            m += 1
            for k in range(3):
                centroid[k] += points[i, k]
    for k in range(3):  # loops, not array expressions: each compiled one brings its checks (issue 14)
        centroid[k] /= m
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
    eigval, eigvec = symmetric_eigen_3x3(scatter)  # ascending
    singular = np.empty(3)
    for k in range(3):
        singular[k] = np.sqrt(max(eigval[2 - k], 0.0))
    normal = np.empty(3)
    for k in range(3):
        normal[k] = eigvec[k, 0]
    if singular[0] > 0.0 and singular[1] <= SCATTER_PRECISE_RATIO * singular[0]:
        centred = np.empty((m, 3))
        row = 0
        for i in range(n):
            if mask[i]:
                for k in range(3):
                    centred[row, k] = points[i, k] - centroid[k]
                row += 1
        singular, normal = right_singular_3(centred)
    if normal[2] < 0:
        for k in range(3):
            normal[k] = -normal[k]
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


#: Jacobi sweeps after which an off-diagonal entry negligible beside both diagonal ones is set to zero
#: (Numerical Recipes' ``jacobi``): the first sweeps rotate every non-zero entry.
SWEEPS_BEFORE_NEGLIGIBLE = 4
#: Jacobi sweeps at most (a 3x3 matrix converges in 4-6; the bound only guards against a NaN).
MAX_SWEEPS = 50


@numba.njit  # no cache of its own: compiled into its callers'
def symmetric_eigen_3x3(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eigenvalues (ascending, ``(3,)``) and unit eigenvectors (the columns of a ``(3, 3)`` rotation) of the
    symmetric 3x3 ``a``, as ``numpy.linalg.eigh``, by cyclic Jacobi rotations.

    Each rotation zeroes one off-diagonal entry; a sweep rotates the three in turn, and the sweeps go on
    until every off-diagonal entry is zero (after :data:`SWEEPS_BEFORE_NEGLIGIBLE` sweeps an entry that
    no longer changes either diagonal entry it couples, to rounding, is set to zero). The eigenvalues are
    accurate to rounding of the largest one, as LAPACK's; the vectors are orthonormal to rounding.
    """
    d = np.empty((3, 3))
    v = np.zeros((3, 3))
    for i in range(3):
        v[i, i] = 1.0
        for j in range(3):
            d[i, j] = a[i, j]
    for sweep in range(MAX_SWEEPS):
        if d[0, 1] == 0.0 and d[0, 2] == 0.0 and d[1, 2] == 0.0:
            break
        for p in range(2):
            for q in range(p + 1, 3):
                apq = d[p, q]
                if apq == 0.0:
                    continue
                g = 100.0 * abs(apq)
                if (
                    sweep >= SWEEPS_BEFORE_NEGLIGIBLE
                    and abs(d[p, p]) + g == abs(d[p, p])
                    and (abs(d[q, q]) + g == abs(d[q, q]))
                ):
                    d[p, q] = d[q, p] = 0.0
                    continue
                h = d[q, q] - d[p, p]
                if abs(h) + g == abs(h):
                    t = apq / h  # t = 1 / (2 theta), theta too large to square
                else:
                    theta = 0.5 * h / apq
                    t = 1.0 / (abs(theta) + np.sqrt(1.0 + theta * theta))
                    if theta < 0.0:
                        t = -t
                c = 1.0 / np.sqrt(1.0 + t * t)
                s = t * c
                # d <- J^T d J: the pair's diagonal moves by t apq, the third row and column rotate.
                d[p, p] -= t * apq
                d[q, q] += t * apq
                d[p, q] = d[q, p] = 0.0
                r = 3 - p - q
                drp, drq = d[r, p], d[r, q]
                d[r, p] = d[p, r] = c * drp - s * drq
                d[r, q] = d[q, r] = s * drp + c * drq
                for k in range(3):
                    vkp, vkq = v[k, p], v[k, q]
                    v[k, p] = c * vkp - s * vkq
                    v[k, q] = s * vkp + c * vkq
    values = np.empty(3)
    vectors = np.empty((3, 3))
    order = _ascending_3(d[0, 0], d[1, 1], d[2, 2])
    for j in range(3):
        values[j] = d[order[j], order[j]]
        for k in range(3):
            vectors[k, j] = v[k, order[j]]
    return values, vectors


@numba.njit  # no cache of its own: compiled into its callers'
def right_singular_3(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The singular values (descending, ``(3,)``) of the ``(m, 3)`` ``a`` and the unit right singular
    vector of the smallest (``(3,)``), as ``numpy.linalg.svd`` (its last row of ``vt``, up to sign), by
    one-sided Jacobi rotations of ``a``'s columns (Hestenes); ``a`` is overwritten with ``U S``.

    Each rotation makes two columns orthogonal; the sweeps go on until every pair is orthogonal to
    rounding. The singular values are the columns' norms, each accurate to rounding of itself, not only
    of the largest one: what the nearly degenerate fits of :func:`plane_fit` need. Fewer than 3 rows give
    zero singular values.
    """
    m = a.shape[0]
    v = np.zeros((3, 3))
    for i in range(3):
        v[i, i] = 1.0
    tolerance = 2.220446049250313e-16 * max(m, 1)
    for _ in range(MAX_SWEEPS):
        rotated = False
        for p in range(2):
            for q in range(p + 1, 3):
                alpha, beta, gamma = 0.0, 0.0, 0.0
                for i in range(m):
                    alpha += a[i, p] * a[i, p]
                    beta += a[i, q] * a[i, q]
                    gamma += a[i, p] * a[i, q]
                if not abs(gamma) > tolerance * np.sqrt(alpha * beta):
                    continue
                rotated = True
                zeta = (beta - alpha) / (2.0 * gamma)
                t = 1.0 / (abs(zeta) + np.sqrt(1.0 + zeta * zeta))
                if zeta < 0.0:
                    t = -t
                c = 1.0 / np.sqrt(1.0 + t * t)
                s = c * t
                for i in range(m):
                    aip, aiq = a[i, p], a[i, q]
                    a[i, p] = c * aip - s * aiq
                    a[i, q] = s * aip + c * aiq
                for k in range(3):
                    vkp, vkq = v[k, p], v[k, q]
                    v[k, p] = c * vkp - s * vkq
                    v[k, q] = s * vkp + c * vkq
        if not rotated:
            break
    norms = np.zeros(3)
    for k in range(3):
        for i in range(m):
            norms[k] += a[i, k] * a[i, k]
        norms[k] = np.sqrt(norms[k])
    order = _ascending_3(norms[0], norms[1], norms[2])
    singular = np.empty(3)
    smallest = np.empty(3)
    for j in range(3):
        singular[j] = norms[order[2 - j]]
        smallest[j] = v[j, order[0]]
    return singular, smallest


@numba.njit  # no cache of its own: compiled into its callers'
def _ascending_3(x0: float, x1: float, x2: float) -> tuple[int, int, int]:
    """The indices of three numbers in ascending order (the first of equals first)."""
    i, j, k = 0, 1, 2
    values = (x0, x1, x2)
    if values[j] < values[i]:
        i, j = j, i
    if values[k] < values[j]:
        j, k = k, j
        if values[j] < values[i]:
            i, j = j, i
    return i, j, k


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
    xs = np.empty(m)
    for i in range(m):
        xs[i] = members[i, 0]
    order = stable_argsort(xs)
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


@numba.njit  # no cache of its own: compiled into its callers'
def median_in_place(values: np.ndarray) -> float:
    """The median of the finite 1-D ``values`` (at least one), as ``numpy.median``: the middle order
    statistic, or the mean ``(a + b) / 2`` of the two middle ones; ``values`` is reordered.

    Quickselect (a three-way partition about the median of three): the kernels that take a median (the
    self-check's split, the contact's noise and zero) call this one instead of compiling NumPy's in,
    whose copies and checks are symbols every new process loads (start-up, issue 14).
    """
    n = values.shape[0]
    half = n // 2
    if n % 2 == 1:
        return _select_in_place(values, half)
    low = _select_in_place(values, half - 1)
    high = values[half]  # every value after the (half - 1)-th is at least it: the next is their least
    for i in range(half + 1, n):
        if values[i] < high:
            high = values[i]
    return (low + high) / 2


@numba.njit  # no cache of its own: compiled into its callers'
def _select_in_place(values: np.ndarray, k: int) -> float:
    """The ``k``-th smallest of ``values`` (0-based); on return it sits at index ``k``, every value before
    it is at most it and every value after it at least it."""
    left, right = 0, values.shape[0] - 1
    while right > left:
        a, b, c = values[left], values[(left + right) // 2], values[right]
        pivot = max(min(a, b), min(max(a, b), c))  # the median of three
        # Three-way partition of [left, right]: [left, lt) below, [lt, i) equal, (gt, right] above.
        lt, i, gt = left, left, right
        while i <= gt:
            value = values[i]
            if value < pivot:
                values[i], values[lt] = values[lt], value
                lt += 1
                i += 1
            elif value > pivot:
                values[i], values[gt] = values[gt], value
                gt -= 1
            else:
                i += 1
        if k < lt:
            right = lt - 1
        elif k > gt:
            left = gt + 1
        else:
            break
    return values[k]


@numba.njit  # no cache of its own: compiled into its callers'
def stable_argsort(values: np.ndarray) -> np.ndarray:
    """The indices that sort the finite 1-D ``values`` ascending, equal values in their order, as
    ``numpy.argsort(values, kind="stable")``: a bottom-up merge sort (insertion sort of runs of 16 first),
    shared by the kernels instead of NumPy's compiled into each (start-up, issue 14)."""
    n = values.shape[0]
    order = np.empty(n, dtype=np.int64)
    for i in range(n):
        order[i] = i
    run = 16
    for start in range(0, n, run):
        for i in range(start + 1, min(start + run, n)):
            item = order[i]
            j = i
            while j > start and values[order[j - 1]] > values[item]:
                order[j] = order[j - 1]
                j -= 1
            order[j] = item
    buffer = np.empty(n, dtype=np.int64)
    width = run
    while width < n:
        for left in range(0, n, 2 * width):
            middle, right = min(left + width, n), min(left + 2 * width, n)
            a, b = left, middle
            for out in range(left, right):  # the left run's item first among equals: stable
                if a < middle and (b >= right or values[order[b]] >= values[order[a]]):
                    buffer[out] = order[a]
                    a += 1
                else:
                    buffer[out] = order[b]
                    b += 1
        order, buffer = buffer, order
        width *= 2
    return order
