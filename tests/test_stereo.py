"""Tests of softjig.sensing.stereo: matching and triangulation for a rectified pair."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from oracles.stereo_assignment import admissible_pairs, component_labels, dense_assignment
from softjig.errors import InputError
from softjig.sensing import stereo
from softjig.sensing._stereo_kernels import pairs_and_components
from softjig.sensing.stereo import (
    StereoMatches,
    disparity_window_px,
    match_rectified,
    triangulate_rectified,
)

# The jig's rectified pair.
FX, FY, CX, CY, BASELINE = 925.0, 925.0, 639.5, 359.5, 30.0
CAMERA = {"fx_px": FX, "fy_px": FY, "cx_px": CX, "cy_px": CY, "baseline_mm": BASELINE}


def project(points_mm: np.ndarray, *, fx=FX, fy=FY, cx=CX, cy=CY, baseline=BASELINE):
    """Ideal projections ``(left_xy, right_xy)`` of points in the left camera frame."""
    x, y, z = points_mm.T
    v = fy * y / z + cy
    left = np.column_stack([fx * x / z + cx, v])
    right = np.column_stack([fx * (x - baseline) / z + cx, v])
    return left, right


def marker_surface(seed: int, *, half_size_mm: tuple[float, float] = (56.0, 32.0)) -> np.ndarray:
    """Markers of a deformed membrane: a tilted, dented 8 mm grid about 185 mm away."""
    rng = np.random.default_rng(seed)
    x, y = np.meshgrid(
        np.arange(-half_size_mm[0], half_size_mm[0] + 1, 8.0),
        np.arange(-half_size_mm[1], half_size_mm[1] + 1, 8.0),
    )
    x, y = x.ravel(), y.ravel()
    dent = 6.0 * np.exp(-((x - rng.uniform(-30, 30)) ** 2 + (y - rng.uniform(-15, 15)) ** 2) / 400)
    z = 185.0 + 0.02 * x - 0.03 * y - dent + rng.normal(0.0, 0.3, x.shape)
    return np.column_stack([x, y, z])


def check_matches(matches: StereoMatches, true_right_of_left: dict[int, int]) -> None:
    """Every true pair found and nothing else matched."""
    found = dict(zip(matches.left_index.tolist(), matches.right_index.tolist(), strict=True))
    assert found == true_right_of_left


@pytest.mark.accuracy
def test_marker_scene_with_row_jitter_spurious_and_missing_detections():
    rng = np.random.default_rng(0)
    points = marker_surface(seed=0)
    left, right = project(points)
    n = len(points)
    left += rng.normal(0.0, 0.1, left.shape)  # detection noise
    right += rng.normal(0.0, 0.1, right.shape)
    right[:, 1] += rng.choice([-1, 1], n) * rng.uniform(1.0, 2.0, n)  # row jitter 1-2 px
    tol = 2.5
    d_min, d_max = disparity_window_px(FX, BASELINE, 175.0, 195.0)

    # Spurious detections anywhere that no real marker could be matched with (a
    # detection on a marker's row inside its disparity window is indistinguishable
    # from the marker).
    def admissible_with(points_a, points_b, sign):
        dv = points_a[:, None, 1] - points_b[None, :, 1]
        d = sign * (points_a[:, None, 0] - points_b[None, :, 0])
        return ((np.abs(dv) <= tol) & (d >= d_min) & (d <= d_max)).any(axis=1)

    spurious_right = rng.uniform([0, 0], [1280, 720], (40, 2))
    spurious_right = spurious_right[~admissible_with(spurious_right, left, -1)][:15]
    spurious_left = rng.uniform([0, 0], [1280, 720], (40, 2))
    all_right = np.vstack([right, spurious_right])
    spurious_left = spurious_left[~admissible_with(spurious_left, all_right, 1)][:15]
    assert len(spurious_left) == len(spurious_right) == 15
    all_left = np.vstack([left, spurious_left])

    missing = rng.choice(n, 5, replace=False)  # markers not detected in the right image
    keep = np.setdiff1d(np.arange(len(all_right)), missing)
    order = rng.permutation(len(keep))
    shuffled_right = all_right[keep[order]]
    right_position = {int(k): i for i, k in enumerate(keep[order])}
    truth = {i: right_position[i] for i in range(n) if i not in set(missing.tolist())}

    matches = match_rectified(
        all_left,
        shuffled_right,
        row_tolerance_px=tol,
        min_disparity_px=d_min,
        max_disparity_px=d_max,
    )
    check_matches(matches, truth)
    assert np.all(np.diff(matches.left_index) > 0)
    assert_allclose(
        matches.row_difference_px,
        all_left[matches.left_index, 1] - shuffled_right[matches.right_index, 1],
    )
    assert_allclose(
        matches.disparity_px,
        all_left[matches.left_index, 0] - shuffled_right[matches.right_index, 0],
    )
    assert np.abs(matches.row_difference_px).max() <= tol


def test_dense_random_cloud_with_wide_window():
    # 400 random points, 100 mm of depth: the disparity window (about 120 px) holds many
    # candidates per row, so the assignment decides. Rows are accurate to 0.05 px.
    rng = np.random.default_rng(1)
    n = 400
    points = rng.uniform([-70, -40, 150], [70, 40, 250], (n, 3))
    left, right = project(points)
    right[:, 1] += rng.normal(0.0, 0.05, n)
    d_min, d_max = disparity_window_px(FX, BASELINE, 150.0, 250.0)
    order = rng.permutation(n)
    matches = match_rectified(
        left, right[order], row_tolerance_px=1.0, min_disparity_px=d_min, max_disparity_px=d_max
    )
    correct = order[matches.right_index] == matches.left_index
    print(f"dense random cloud: {np.count_nonzero(~correct)} wrong pairs of {n}")
    assert len(matches) == n
    assert correct.mean() >= 0.99, f"{np.count_nonzero(~correct)} wrong pairs"


def greedy_nearest_row(left, right, tol, d_min, d_max):
    """The baseline that the global assignment replaces: each left marker in turn takes
    the free right marker with the closest row."""
    taken, pairs = set(), {}
    for i, (u, v) in enumerate(left):
        best = None
        for j, (ur, vr) in enumerate(right):
            ok = j not in taken and abs(v - vr) <= tol and d_min <= u - ur <= d_max
            if ok and (best is None or abs(v - vr) < abs(v - right[best, 1])):
                best = j
        if best is not None:
            taken.add(best)
            pairs[i] = best
    return pairs


@pytest.mark.parametrize(
    ("left_rows", "right_rows"),
    [
        # Greedy gives L0 the nearer R0 and leaves L1 without an admissible partner.
        ((100.0, 101.0), (100.6, 99.0)),
        # Greedy gives L0 the nearer R0 and L1 the poor R1: a total squared row error of
        # 1.69 px^2 instead of 0.37 px^2.
        ((100.0, 100.6), (100.5, 99.4)),
    ],
)
def test_global_assignment_beats_greedy_nearest_row(left_rows, right_rows):
    left = np.column_stack([[500.0, 520.0], left_rows])
    right = np.column_stack([[360.0, 352.0], right_rows])
    truth = {0: 1, 1: 0}
    window = {"row_tolerance_px": 1.5, "min_disparity_px": 135.0, "max_disparity_px": 175.0}
    greedy = greedy_nearest_row(left, right, 1.5, 135.0, 175.0)
    assert greedy != truth
    assert len(greedy) == (1 if left_rows[1] == 101.0 else 2)
    check_matches(match_rectified(left, right, **window), truth)


@pytest.mark.parametrize("batch_edges", [4, 512])
@pytest.mark.parametrize("seed", range(5))
def test_matching_is_the_optimal_assignment(seed, batch_edges, monkeypatch):
    # Crowded rows, many candidates each: compare with one dense assignment over all
    # markers (also with tiny batches, to exercise the batching of components).
    monkeypatch.setattr(stereo, "_BATCH_EDGES", batch_edges)
    rng = np.random.default_rng(seed)
    left = rng.uniform([0, 0], [400, 60], (80, 2))
    right = rng.uniform([0, 0], [400, 60], (70, 2))
    window = {"row_tolerance_px": 1.0, "min_disparity_px": 10.0, "max_disparity_px": 60.0}
    matches = match_rectified(left, right, **window)
    assert len(np.unique(matches.right_index)) == len(matches)
    half = 25.0
    cost = (matches.row_difference_px / 1.0) ** 2 + 0.01 * ((matches.disparity_px - 35.0) / half) ** 2
    li_ref, _, cost_ref = dense_assignment(left, right, 1.0, 10.0, 60.0)
    assert len(matches) == len(li_ref)
    assert_allclose(cost.sum(), cost_ref, rtol=1e-9)


def test_same_row_markers_keep_their_order():
    # Five markers on one image row, every left-right pairing admissible: the row cost
    # ties and the convex disparity term picks the order-preserving assignment.
    left = np.column_stack([np.arange(5) * 40.0 + 400.0, np.full(5, 200.0)])
    right = left - [150.0, 0.0]
    order = np.random.default_rng(2).permutation(5)
    matches = match_rectified(
        left, right[order], row_tolerance_px=2.0, min_disparity_px=0.0, max_disparity_px=320.0
    )
    assert_array_equal(order[matches.right_index], matches.left_index)


@pytest.mark.shapes
def test_empty_inputs_and_no_candidates():
    window = {"row_tolerance_px": 2.0, "min_disparity_px": 100.0, "max_disparity_px": 200.0}
    points = np.array([[500.0, 100.0], [600.0, 300.0]])
    for left, right in [([], points), (points, np.empty((0, 2))), ([], [])]:
        matches = match_rectified(left, right, **window)
        assert len(matches) == 0
        assert matches.left_index.dtype == np.intp
        assert matches.disparity_px.shape == (0,)
    assert len(match_rectified(points, points + np.array([0.0, 10.0]), **window)) == 0  # rows
    assert len(match_rectified(points, points, **window)) == 0  # disparity 0


@pytest.mark.agreement
def test_matching_400_markers_is_the_dense_assignment():
    """A 416-marker grid (20 px window) and a 400-point random cloud (120 px window): the same pairs as one
    dense assignment over all markers."""
    rng = np.random.default_rng(3)
    points = marker_surface(seed=3, half_size_mm=(100.0, 60.0))  # 416 markers
    left, right = project(points)
    right[:, 1] += rng.uniform(-1.5, 1.5, len(points))
    right = right[rng.permutation(len(right))]
    d_min, d_max = disparity_window_px(FX, BASELINE, 175.0, 195.0)
    cloud = rng.uniform([-70, -40, 150], [70, 40, 250], (400, 3))
    cloud_left, cloud_right = project(cloud)
    cloud_min, cloud_max = disparity_window_px(FX, BASELINE, 150.0, 250.0)
    for a, b, tol, lo, hi in (
        (left, right, 2.5, d_min, d_max),
        (cloud_left, cloud_right, 2.5, cloud_min, cloud_max),
    ):
        matches = match_rectified(a, b, row_tolerance_px=tol, min_disparity_px=lo, max_disparity_px=hi)
        assert len(matches) == len(a)
        li_ref, rj_ref, _ = dense_assignment(a, b, tol, lo, hi)
        assert_array_equal(matches.left_index, li_ref)
        assert_array_equal(matches.right_index, rj_ref)


# ---------------------------------------------------------------------------------------
# Triangulation


@pytest.mark.accuracy
def test_triangulation_round_trip_is_exact():
    rng = np.random.default_rng(4)
    points = rng.uniform([-70, -40, 120], [70, 40, 300], (200, 3))
    camera = {"fx_px": 930.0, "fy_px": 921.0, "cx_px": 650.2, "cy_px": 350.7, "baseline_mm": 30}
    left, right = project(points, fx=930.0, fy=921.0, cx=650.2, cy=350.7, baseline=camera["baseline_mm"])
    assert_allclose(triangulate_rectified(left, right, **camera), points, rtol=0, atol=1e-9)


def test_triangulation_through_matching():
    points = marker_surface(seed=5)
    left, right = project(points)
    order = np.random.default_rng(5).permutation(len(points))
    right = right[order]
    d_min, d_max = disparity_window_px(FX, BASELINE, 175.0, 195.0)
    m = match_rectified(left, right, row_tolerance_px=1.0, min_disparity_px=d_min, max_disparity_px=d_max)
    xyz = triangulate_rectified(left[m.left_index], right[m.right_index], **CAMERA)
    assert_allclose(xyz, points[m.left_index], atol=1e-9)
    assert xyz.shape == (len(points), 3)


def test_triangulation_uses_the_mean_row():
    left, right = project(np.array([[10.0, 5.0, 200.0]]))
    left[:, 1] += 0.5
    right[:, 1] -= 0.5
    assert_allclose(triangulate_rectified(left, right, **CAMERA)[0], [10.0, 5.0, 200.0])


@pytest.mark.shapes
def test_triangulation_of_nothing():
    assert triangulate_rectified(np.empty((0, 2)), [], **CAMERA).shape == (0, 3)


# ---------------------------------------------------------------------------------------
# Errors and helpers


def test_disparity_window():
    lo, hi = disparity_window_px(925.0, 30.0, 175.0, 195.0, margin_px=0.0)
    assert_allclose([lo, hi], [925 * 30 / 195, 925 * 30 / 175])
    assert disparity_window_px(925.0, 30.0, 175.0, 195.0) == (lo - 2.0, hi + 2.0)
    with pytest.raises(InputError, match=r"depth_min_mm .* must be smaller"):
        disparity_window_px(925.0, 30.0, 195.0, 175.0)
    with pytest.raises(InputError, match="margin_px must be >= 0"):
        disparity_window_px(925.0, 30.0, 175.0, 195.0, margin_px=-1.0)
    with pytest.raises(InputError, match="baseline_mm must be > 0"):
        disparity_window_px(925.0, 0.0, 175.0, 195.0)


GOOD = np.array([[500.0, 100.0]])


@pytest.mark.exceptions
@pytest.mark.parametrize(
    ("left", "right", "kwargs", "words"),
    [
        (np.zeros((3, 3)), GOOD, {}, r"left_xy must be an \(N, 2\) array"),
        (GOOD, np.zeros(4), {}, r"right_xy must be an \(N, 2\) array"),
        (GOOD, [["a", "b"]], {}, "right_xy must be"),
        ([[np.nan, 1.0]], GOOD, {}, "left_xy contains NaN or infinite"),
        (GOOD, [[500.0, 100.0], [350.0, np.inf]], {}, "right_xy contains NaN or infinite"),
        (GOOD, GOOD, {"row_tolerance_px": 0.0}, "row_tolerance_px must be > 0"),
        (GOOD, GOOD, {"min_disparity_px": 200.0}, "must be smaller than max_disparity_px"),
        (GOOD, GOOD, {"max_disparity_px": float("inf")}, "max_disparity_px must be finite"),
        (GOOD, GOOD, {"disparity_weight": -1.0}, "disparity_weight must be >= 0"),
    ],
)
def test_match_rectified_rejects_bad_input(left, right, kwargs, words):
    window = {"row_tolerance_px": 2.0, "min_disparity_px": 100.0, "max_disparity_px": 200.0}
    with pytest.raises(InputError, match=words):
        match_rectified(left, right, **(window | kwargs))


@pytest.mark.exceptions
def test_triangulate_rectified_rejects_bad_input():
    left = np.array([[500.0, 100.0], [400.0, 120.0]])
    right = left - [150.0, 0.0]
    with pytest.raises(InputError, match="left_xy has 2 points but right_xy has 1"):
        triangulate_rectified(left, right[:1], **CAMERA)
    swapped = right.copy()
    swapped[1, 0] = 420.0
    with pytest.raises(InputError, match=r"1 of 2 pairs .* \(first: pair 1, d = -20.000 px\)"):
        triangulate_rectified(left, swapped, **CAMERA)
    with pytest.raises(InputError, match="fx_px must be > 0"):
        triangulate_rectified(left, right, **(CAMERA | {"fx_px": -925.0}))
    with pytest.raises(InputError, match="cy_px must be finite"):
        triangulate_rectified(left, right, **(CAMERA | {"cy_px": float("nan")}))


def test_stereo_matches_is_immutable():
    m = StereoMatches(
        left_index=[0, 2],
        right_index=[1, 0],
        row_difference_px=[0.1, -0.2],
        disparity_px=[150.0, 151.0],
    )
    assert len(m) == 2
    assert m.left_index.dtype == np.intp
    with pytest.raises(ValueError, match="read-only"):
        m.disparity_px[0] = 1.0
    with pytest.raises(InputError, match="equal lengths"):
        StereoMatches(left_index=[0], right_index=[1, 2], row_difference_px=[0.0], disparity_px=[1.0])


# ---------------------------------------------------------------------------------------
# The compiled row sweep and union-find against the oracles (NumPy sweep, SciPy graph search, dense
# assignment)


@pytest.mark.agreement
@pytest.mark.parametrize("seed", range(6))
def test_matching_equals_the_dense_assignment(seed):
    """Grids with row jitter, spurious detections and wide windows: few to hundreds of conflicts."""
    rng = np.random.default_rng(seed)
    left, right = project(marker_surface(seed))
    right[:, 1] += rng.uniform(-1.5, 1.5, len(right))
    doubles = right[rng.choice(len(right), 6, replace=False)] + [4.0, 0.3]  # split detections
    right = np.vstack([right, doubles, rng.uniform([0, 0], [1280, 720], (30, 2))])
    right = right[rng.permutation(len(right))]
    conflicts = []
    for tol, lo, hi in ((2.5, 140.0, 161.0), (3.0, 120.0, 200.0), (6.0, 60.0, 260.0)):
        matches = match_rectified(left, right, row_tolerance_px=tol, min_disparity_px=lo, max_disparity_px=hi)
        li_ref, rj_ref, _ = dense_assignment(left, right, tol, lo, hi)
        assert_array_equal(matches.left_index, li_ref)
        assert_array_equal(matches.right_index, rj_ref)
        assert_array_equal(matches.disparity_px, left[li_ref, 0] - right[rj_ref, 0])
        li, rj = admissible_pairs(left, right, tol, lo, hi)
        alone = (np.bincount(li, minlength=len(left))[li] == 1) & (np.bincount(rj)[rj] == 1)
        conflicts.append(int((~alone).sum()))
    assert 0 < conflicts[0] < 50 < 200 < conflicts[-1]  # a few conflicts to hundreds


def test_pairs_and_components_of_the_compiled_loop_match_numpy_and_scipy():
    rng = np.random.default_rng(7)
    for _ in range(50):
        n_left, n_right = rng.integers(1, 40, 2)
        left = rng.uniform([0, 0], [300, 60], (n_left, 2))
        right = rng.uniform([0, 0], [300, 60], (n_right, 2))
        right[rng.integers(0, n_right, 3), 1] = right[0, 1]  # equal rows: the sort must be stable
        window = (rng.uniform(0.5, 8.0), -20.0, rng.uniform(0.0, 150.0))
        order = np.argsort(right[:, 1], kind="stable")
        li, rj, row_diff, disparity, component, n_conflicts = pairs_and_components(
            left, right, order, *window
        )
        assert_array_equal(row_diff, left[li, 1] - right[rj, 1])
        assert_array_equal(disparity, left[li, 0] - right[rj, 0])
        li_ref, rj_ref = admissible_pairs(left, right, *window)
        assert_array_equal(li, li_ref)
        assert_array_equal(rj, rj_ref)
        conflicts = component >= 0
        assert n_conflicts == conflicts.sum()
        if n_conflicts:
            graph = component_labels(li[conflicts], rj[conflicts], n_left, n_right)
            assert_array_equal(component[conflicts], graph)
