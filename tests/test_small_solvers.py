"""The plane fit's hand-written solvers (softjig._geometry_kernels: the symmetric 3x3 eigen-decomposition
and the one-sided Jacobi SVD) against numpy.linalg, the fit against NumPy's SVD of the centred points, and
the kernels' median and stable argsort against NumPy's."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from numpy.testing import assert_allclose

from softjig._geometry_kernels import (
    median_in_place,
    plane_fit,
    right_singular_3,
    stable_argsort,
    symmetric_eigen_3x3,
)

EPS = np.finfo(float).eps

finite = st.floats(-1e3, 1e3, allow_nan=False, allow_infinity=False)


def _check_eigen(a: np.ndarray) -> None:
    values, vectors = symmetric_eigen_3x3(a)
    expected, expected_vectors = np.linalg.eigh(a)
    scale = max(np.abs(expected).max(), 1e-300)
    # LAPACK's eigenvalues are off by up to their residual (a symmetric matrix has an eigenvalue within
    # |A v - lambda v| of each computed pair), which on matrices with couplings near underflow exceeds
    # 32 eps: the comparison allows for it. Our own accuracy is checked by our residual below.
    unit = a / scale  # the residual of the scaled matrix: no overflow near 1e308
    lapack_error = (
        scale * np.abs(unit @ expected_vectors - expected_vectors * (expected / scale)).sum(0).max()
    )
    assert_allclose(values, expected, rtol=0, atol=32 * EPS * scale + lapack_error)
    assert np.all(np.diff(values) >= 0)
    assert_allclose(vectors.T @ vectors, np.eye(3), atol=32 * EPS)
    assert_allclose(a @ vectors, vectors * values, atol=64 * EPS * scale)


@settings(max_examples=400, deadline=None)
@given(arrays(float, (3, 3), elements=finite))
@example(np.array([[0.0, 7.99870729e-153, 0.0], [0.0, 0.0, 941.0], [0.0, 0.0, 0.0]]))  # near underflow
def test_symmetric_eigen_is_numpys(m):
    _check_eigen(m + m.T)


@settings(max_examples=200, deadline=None)
@given(
    arrays(float, (3,), elements=st.floats(-1e3, 1e3)),
    arrays(float, (3,), elements=st.floats(-1.0, 1.0)),
    st.sampled_from([0, 1, 2]),
)
def test_symmetric_eigen_with_repeated_and_tiny_eigenvalues(values, axis, repeat):
    """Rotated diagonal matrices, two of whose eigenvalues may be equal, or many orders apart."""
    if repeat:
        values[repeat] = values[repeat - 1]
    norm = np.linalg.norm(axis)
    rotation = np.eye(3)
    if norm > 1e-6:
        k = axis / norm
        cross = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
        rotation = np.eye(3) + np.sin(norm) * cross + (1 - np.cos(norm)) * cross @ cross
    _check_eigen(rotation @ np.diag(values) @ rotation.T)


def test_symmetric_eigen_of_special_matrices():
    for a in (
        np.zeros((3, 3)),
        np.eye(3),
        np.diag([3.0, 1.0, 2.0]),
        np.ones((3, 3)),
        np.diag([1e-300, 1.0, 1e300]),
    ):
        _check_eigen(a)
    values, vectors = symmetric_eigen_3x3(np.diag([3.0, 1.0, 2.0]))
    assert_allclose(values, [1, 2, 3])
    assert_allclose(np.abs(vectors), [[0, 0, 1], [1, 0, 0], [0, 1, 0]])


@settings(max_examples=300, deadline=None)
@given(st.integers(1, 40), st.integers(0, 2**32 - 1), st.sampled_from([1.0, 1e-4, 1e-8, 0.0]))
def test_right_singular_is_numpys_svd(rows, seed, thin):
    """Random ``(m, 3)`` matrices, some with a nearly (or exactly) dependent column: the singular values to
    rounding of themselves, the smallest's right singular vector to the conditioning of its gap."""
    rng = np.random.default_rng(seed)
    a = rng.normal(size=(rows, 3)) * rng.uniform(0.1, 10, 3)
    a[:, 2] = a[:, 0] * 0.3 - a[:, 1] * 0.7 + thin * a[:, 2]
    _, expected, vt = np.linalg.svd(a, full_matrices=False)
    expected = np.concatenate([expected, np.zeros(3 - len(expected))])
    singular, smallest = right_singular_3(a.copy())
    assert_allclose(singular, expected, rtol=0, atol=64 * EPS * expected[0] * max(rows, 1))
    assert np.all(np.diff(singular) <= 0)
    assert np.linalg.norm(smallest) == pytest.approx(1.0, abs=1e-12)
    if rows >= 3 and expected[1] - expected[2] > 1e-6 * expected[0]:
        reference = vt[2]
        gap = (expected[1] - expected[2]) / expected[0]
        assert min(np.abs(smallest - reference).max(), np.abs(smallest + reference).max()) < 1e-13 / gap


@settings(max_examples=200, deadline=None)
@given(
    st.integers(3, 200),
    st.integers(0, 2**32 - 1),
    st.floats(1e-5, 1.0),
    st.floats(0.0, 0.6),
    st.floats(-np.pi, np.pi),
)
def test_plane_fit_is_numpys_svd_of_the_centred_points(count, seed, noise, tilt, azimuth):
    rng = np.random.default_rng(seed)
    normal = np.array([np.sin(tilt) * np.cos(azimuth), np.sin(tilt) * np.sin(azimuth), np.cos(tilt)])
    xy = rng.uniform(-30, 30, (count, 2))
    z = 5.0 - (normal[0] * xy[:, 0] + normal[1] * xy[:, 1]) / normal[2] + rng.normal(0, noise, count)
    points = np.column_stack([xy, z]) + rng.uniform(-100, 100, 3)
    mask = rng.random(count) < 0.8
    if mask.sum() < 3:
        mask[:3] = True
    centroid, singular, fitted, rms = plane_fit(points, mask)
    centred = points[mask] - points[mask].mean(axis=0)
    _, s, vt = np.linalg.svd(centred, full_matrices=False)
    expected = vt[-1] * np.sign(vt[-1][2])
    lam = s**2
    conditioning = lam[0] / (lam[1] - lam[2])  # the normal's error is rounding times this (both ways)
    assert_allclose(centroid, points[mask].mean(axis=0), rtol=1e-14, atol=1e-12)
    assert_allclose(singular[:2], s[:2], rtol=1e-12)
    assert_allclose(fitted, expected, rtol=0, atol=64 * EPS * conditioning)
    assert fitted[2] >= 0
    residual = np.sqrt(np.mean((centred @ fitted) ** 2))
    assert rms == pytest.approx(residual, rel=1e-9, abs=1e-12)


# Few distinct values (ties, which the partition and the merge must keep apart) as well as many.
ties = st.one_of(st.integers(-3, 3).map(float), finite)


@settings(max_examples=400, deadline=None)
@given(st.lists(ties, min_size=1, max_size=80))
def test_median_in_place_is_numpys(values):
    array = np.array(values)
    assert median_in_place(array.copy()) == np.median(array)


@settings(max_examples=400, deadline=None)
@given(st.lists(ties, min_size=0, max_size=120))
def test_stable_argsort_is_numpys(values):
    """Up to 120 values: runs of 16 merged three times, and a ragged last run."""
    array = np.array(values, dtype=float)
    assert np.array_equal(stable_argsort(array), np.argsort(array, kind="stable"))
