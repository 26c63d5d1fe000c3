"""The Pareto front (softjig.study.pareto): no front point dominated, every other point dominated by one on
the front, ties and NaN (failed designs) handled; property-tested against the definition."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from softjig.errors import InputError
from softjig.study.pareto import dominates, pareto_front

# Small integers force ties in either objective; NaN stands for a failed design (no RMSE).
VALUE = st.one_of(st.integers(0, 6).map(float), st.floats(0, 10, allow_nan=False), st.just(math.nan))
POINTS = st.lists(st.tuples(VALUE, VALUE), max_size=40)


@settings(deadline=None)  # the brute-force check is quadratic: slow on a loaded machine, not wrong
@given(POINTS)
def test_front_matches_the_definition(points):
    x = np.array([p[0] for p in points], dtype=float)
    y = np.array([p[1] for p in points], dtype=float)
    front = pareto_front(x, y)
    finite = np.isfinite(x) & np.isfinite(y)
    assert front.dtype == bool and front.shape == x.shape
    assert not front[~finite].any(), "a design with no value is never on the front"
    pts = np.column_stack([x, y])
    for i in np.flatnonzero(finite):
        dominated = any(dominates(pts[j], pts[i]) for j in np.flatnonzero(finite))
        assert front[i] == (not dominated)
        if not front[i]:
            assert any(dominates(pts[j], pts[i]) for j in np.flatnonzero(front)), (
                "every point off the front is dominated by a point on it"
            )
    if finite.any():
        assert front.any()


@settings(deadline=None)
@given(POINTS, st.randoms(use_true_random=False))
def test_front_does_not_depend_on_order(points, rnd):
    x = np.array([p[0] for p in points], dtype=float)
    y = np.array([p[1] for p in points], dtype=float)
    perm = list(range(len(points)))
    rnd.shuffle(perm)
    assert (pareto_front(x, y)[perm] == pareto_front(x[perm], y[perm])).all()


def test_ties_are_all_on_the_front_or_all_off():
    # two identical best designs, two identical dominated ones, a same-cost worse one
    front = pareto_front([1, 1, 2, 2, 1], [1, 1, 3, 3, 2])
    assert front.tolist() == [True, True, False, False, False]
    # equal cost, one strictly better: only it; equal RMSE, one cheaper: only it
    assert pareto_front([3, 3], [1, 2]).tolist() == [True, False]
    assert pareto_front([3, 2], [1, 1]).tolist() == [False, True]


def test_failed_designs_are_ignored():
    assert pareto_front([1, 2, math.nan, 0], [math.nan, 1, 0, math.inf]).tolist() == [
        False,
        True,
        False,
        False,
    ]
    assert pareto_front([], []).tolist() == []
    assert not pareto_front([math.nan], [1.0]).any()


def test_bad_shapes_are_an_input_error():
    with pytest.raises(InputError, match="equal length"):
        pareto_front([1, 2], [1])


def test_the_docstring_example_holds():
    import doctest

    from softjig.study import pareto

    assert doctest.testmod(pareto).failed == 0
