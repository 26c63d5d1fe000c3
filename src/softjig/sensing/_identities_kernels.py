"""Compiled kernel of :mod:`softjig.sensing.identities`: each marker's nearest reference marker, one to
one."""

from __future__ import annotations

import numba
import numpy as np

#: Relative widening of the ``x`` band swept for each point, so rounding never drops a reference marker
#: at exactly ``reach``.
SWEEP_SLACK = 1e-9


@numba.njit(cache=True)
def one_to_one_nearest(
    points: np.ndarray, reference: np.ndarray, xs: np.ndarray, order: np.ndarray, reach: float
) -> tuple[np.ndarray, np.ndarray]:
    """Each point's nearest reference marker in ``(x, y)`` closer than ``reach`` (``-1`` if none); where
    two claim the same one, the nearer keeps it (ties: the earlier point). Returns the ids and the
    points' displacements from their reference markers (NaN without one).

    The same as a k-d tree's query with ``distance_upper_bound`` and a claim loop in the stable order of
    distance, with a sweep over the reference sorted by ``x`` (``xs``, ``order``) instead of the tree.
    """
    n = points.shape[0]
    nearest = np.full(n, -1, dtype=np.int64)
    distance = np.full(n, np.inf)
    r2 = reach * reach
    slack = reach * (1.0 + SWEEP_SLACK)
    for i in range(n):
        lo = np.searchsorted(xs, points[i, 0] - slack)
        hi = np.searchsorted(xs, points[i, 0] + slack, side="right")
        best = np.inf
        for s in range(lo, hi):
            j = order[s]
            dx, dy = reference[j, 0] - points[i, 0], reference[j, 1] - points[i, 1]
            d2 = dx * dx + dy * dy
            if d2 < r2 and d2 < best:
                best = d2
                nearest[i] = j
        if nearest[i] >= 0:
            distance[i] = np.sqrt(best)
    ids = np.full(n, -1, dtype=np.int64)
    displacement = np.full((n, 3), np.nan)
    taken = np.zeros(reference.shape[0], dtype=np.bool_)
    for i in np.argsort(distance, kind="mergesort"):
        j = nearest[i]
        if j >= 0 and not taken[j]:
            taken[j] = True
            ids[i] = j
            for c in range(3):
                displacement[i, c] = points[i, c] - reference[j, c]
    return ids, displacement
