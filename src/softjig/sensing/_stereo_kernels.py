"""Compiled kernel of :mod:`softjig.sensing.stereo`: the admissible pairs of a rectified pair and the
connected components of their graph, in one loop."""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True, nogil=True)
def pairs_and_components(left, right, order, tol, d_min, d_max):
    """Admissible pairs of finite marker centres and the components of the pairs that share a marker.

    Parameters
    ----------
    left, right : (N, 2), (K, 2) float64 finite marker centres ``(u, v)`` (px).
    order : (K,) int64 the right markers sorted by row ``v``, stably (NumPy's stable argsort, which
        would cost seconds of compilation here).
    tol, d_min, d_max : the row tolerance and the disparity window (px), as
        :func:`softjig.sensing.stereo.match_rectified` takes them.

    Returns
    -------
    li, rj : (E,) int64 the admissible pairs ``(left, right)``, by left index, then by the right
        markers' row order.
    row_diff, disparity : (E,) float64 ``v_l - v_r`` and ``u_l - u_r`` of each pair (px).
    component : (E,) int64 the connected component of each pair that shares a marker with another
        pair, numbered in order of the component's smallest left index; -1 for the pairs whose both
        markers have no other candidate.
    n_conflicts : int the number of pairs with ``component >= 0``.

    Notes
    -----
    A row sweep (a binary search of each left row's band ``[v - tol, v + tol]`` in the sorted right rows),
    the node degrees, then a union-find with path halving over the pairs that share a marker.
    """
    n_left, n_right = left.shape[0], right.shape[0]
    right_rows = np.empty(n_right)
    for k in range(n_right):
        right_rows[k] = right[order[k], 1]
    lo = np.empty(n_left, np.int64)
    hi = np.empty(n_left, np.int64)
    total = 0
    for i in range(n_left):
        below, above = left[i, 1] - tol, left[i, 1] + tol
        a, b = 0, n_right
        while a < b:
            m = (a + b) // 2
            if right_rows[m] < below:
                a = m + 1
            else:
                b = m
        lo[i] = a
        b = n_right
        while a < b:
            m = (a + b) // 2
            if right_rows[m] <= above:
                a = m + 1
            else:
                b = m
        hi[i] = a
        total += hi[i] - lo[i]
    li = np.empty(total, np.int64)
    rj = np.empty(total, np.int64)
    row_diff = np.empty(total)
    disparity = np.empty(total)
    n = 0
    for i in range(n_left):
        for k in range(lo[i], hi[i]):
            j = order[k]
            d = left[i, 0] - right[j, 0]
            r = left[i, 1] - right[j, 1]
            if abs(r) <= tol and d >= d_min and d <= d_max:
                li[n], rj[n], row_diff[n], disparity[n] = i, j, r, d
                n += 1
    li, rj, row_diff, disparity = li[:n].copy(), rj[:n].copy(), row_diff[:n].copy(), disparity[:n].copy()
    degree = np.zeros(n_left + n_right, np.int64)
    for e in range(n):
        degree[li[e]] += 1
        degree[n_left + rj[e]] += 1
    parent = np.arange(n_left + n_right)
    root = np.empty(2, np.int64)
    n_conflicts = 0
    for e in range(n):
        if degree[li[e]] > 1 or degree[n_left + rj[e]] > 1:
            n_conflicts += 1
            for side, node in enumerate((li[e], n_left + rj[e])):
                while parent[node] != node:  # path halving
                    parent[node] = parent[parent[node]]
                    node = parent[node]
                root[side] = node
            if root[0] != root[1]:
                parent[max(root[0], root[1])] = min(root[0], root[1])
    component = np.full(n, -1, np.int64)
    number = np.full(n_left + n_right, -1, np.int64)
    count = 0
    for e in range(n):
        if degree[li[e]] > 1 or degree[n_left + rj[e]] > 1:
            node = li[e]
            while parent[node] != node:
                parent[node] = parent[parent[node]]
                node = parent[node]
            if number[node] < 0:
                number[node] = count
                count += 1
            component[e] = number[node]
    return li, rj, row_diff, disparity, component, n_conflicts
