"""Oracles of :func:`softjig.sensing.stereo.match_rectified`: the admissible pairs by a NumPy row sweep,
the components of their graph by SciPy's sparse graph search, and the matching itself as one dense
max-cardinality min-cost assignment over all markers (the definition in the function's Notes)."""

from __future__ import annotations

import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components


def admissible_pairs(
    left: np.ndarray, right: np.ndarray, tol: float, d_min: float, d_max: float
) -> tuple[np.ndarray, np.ndarray]:
    """All admissible ``(left, right)`` index pairs, by left index then by the right markers' stable row
    order (a sweep over rows, no N x K array)."""
    order = np.argsort(right[:, 1], kind="stable")
    right_rows = right[order, 1]
    lo = np.searchsorted(right_rows, left[:, 1] - tol, side="left")
    hi = np.searchsorted(right_rows, left[:, 1] + tol, side="right")
    counts = hi - lo
    li = np.repeat(np.arange(len(left)), counts)
    within = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
    rj = order[np.repeat(lo, counts) + within]
    row_diff = left[li, 1] - right[rj, 1]
    disparity = left[li, 0] - right[rj, 0]
    ok = (np.abs(row_diff) <= tol) & (disparity >= d_min) & (disparity <= d_max)
    return li[ok], rj[ok]


def component_labels(li: np.ndarray, rj: np.ndarray, n_left: int, n_right: int) -> np.ndarray:
    """Connected component of each edge ``(li[k], rj[k])`` of a bipartite graph, numbered in order of the
    component's smallest left index."""
    graph = coo_matrix((np.ones(len(li), np.int8), (li, n_left + rj)), shape=(n_left + n_right,) * 2)
    _, labels = connected_components(graph, directed=False)
    _, first = np.unique(labels[li], return_inverse=True)
    return first.reshape(-1)


def dense_assignment(
    left: np.ndarray, right: np.ndarray, tol: float, d_min: float, d_max: float, weight: float = 0.01
) -> tuple[np.ndarray, np.ndarray, float]:
    """``(left_index, right_index, total cost)`` of one dense max-cardinality min-cost assignment of all
    markers, sorted by left index."""
    dv = left[:, None, 1] - right[None, :, 1]
    d = left[:, None, 0] - right[None, :, 0]
    ok = (np.abs(dv) <= tol) & (d >= d_min) & (d <= d_max)
    half = (d_max - d_min) / 2
    cost = (dv / tol) ** 2 + weight * ((d - d_min - half) / half) ** 2
    infeasible = (min(len(left), len(right)) + 1) * (1 + weight) + 1
    rows, cols = linear_sum_assignment(np.where(ok, cost, infeasible))
    good = ok[rows, cols]
    return rows[good], cols[good], float(cost[rows[good], cols[good]].sum())
