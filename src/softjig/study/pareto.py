"""The Pareto front of two objectives, both minimised (pure math: no files, no tables).

A design *dominates* another when it is no worse in both objectives and strictly better in at least one.
The front is the set of designs no other design dominates. Two designs with equal objectives do not
dominate each other, so ties are all on the front (or all off it): the front never depends on the order
of its input. A design with a NaN objective (a design whose every estimate failed has no RMSE) has no
place on either axis: it is never on the front and dominates nothing; the front is that of the others.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from softjig.errors import InputError

__all__ = ["dominates", "pareto_front"]


def dominates(a: ArrayLike, b: ArrayLike) -> bool:
    """Whether objective vector ``a`` dominates ``b`` (both minimised): ``a <= b`` everywhere and
    ``a < b`` somewhere. Any NaN makes it false."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    return bool(np.all(a <= b) and np.any(a < b))


def _checked(x: ArrayLike, y: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
    if x.ndim != 1 or x.shape != y.shape:
        raise InputError(
            f"a Pareto front needs two objectives of equal length, got shapes {x.shape} and {y.shape}"
        )
    return x, y


def pareto_front(x: ArrayLike, y: ArrayLike) -> np.ndarray:
    """Which points are on the Pareto front of ``(x, y)``, both minimised.

    Parameters
    ----------
    x, y : (N,) the two objectives of each point (e.g. a cost and an RMSE in deg); NaN or infinite
        where a point has no value (it is then off the front and ignored by the others).

    Returns
    -------
    (N,) bool: ``True`` for the points no finite point dominates.

    Notes
    -----
    A sweep in :math:`O(N \\log N)`: sorted by ``x`` then ``y``, a group of points of equal ``x`` keeps
    only its smallest ``y`` (and its ties), and those only if every point of smaller ``x`` has a larger
    ``y``.

    Examples
    --------
    >>> pareto_front([1, 2, 3, 2], [3, 1, 0, 2]).tolist()
    [True, True, True, False]
    """
    x, y = _checked(x, y)
    front = np.zeros(x.shape, dtype=bool)
    valid = np.flatnonzero(np.isfinite(x) & np.isfinite(y))
    order = valid[np.lexsort((y[valid], x[valid]))]
    best_y = np.inf  # smallest y among points of strictly smaller x
    start = 0
    while start < len(order):
        stop = start
        while stop < len(order) and x[order[stop]] == x[order[start]]:
            stop += 1
        group = order[start:stop]
        group_min = y[group[0]]  # sorted by y within a group
        if group_min < best_y:
            front[group[y[group] == group_min]] = True
            best_y = group_min
        start = stop
    return front
