"""Stereo correspondence and triangulation of markers for an ideal rectified camera pair.

The rectified pair has identical intrinsics ``(fx, fy, cx, cy)`` and the right camera is
translated by ``+baseline`` along the left camera's x axis, so a point ``(X, Y, Z)`` in the
left camera frame (OpenCV: x right, y down, z forward; mm) projects to the same image row
in both images and to columns that differ by the disparity ``d = u_l - u_r = fx B / Z > 0``.

Conventions: pixel coordinates are ``(u, v) = (column, row)`` in float64 pixels, with the
centre of pixel ``(0, 0)`` at ``(0.0, 0.0)``; lengths are in mm.

Everything here is pure: arrays in, frozen dataclasses / arrays out.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from softjig.checks import finite_float, positive_float
from softjig.errors import InputError
from softjig.sensing._stereo_kernels import pairs_and_components

__all__ = [
    "StereoMatches",
    "disparity_window_px",
    "match_rectified",
    "triangulate_rectified",
]

#: Admissible pairs per assignment problem: the components of the pairs' graph that share markers are
#: solved together, whole, in block-diagonal problems of about this many pairs (few solver calls, bounded
#: memory).
_BATCH_EDGES = 512


@dataclass(frozen=True, eq=False)
class StereoMatches:
    """One-to-one correspondences between left and right marker detections.

    Attributes
    ----------
    left_index : numpy.ndarray, shape (M,), intp
        Index of each matched marker in the left list, increasing.
    right_index : numpy.ndarray, shape (M,), intp
        Index of its partner in the right list.
    row_difference_px : numpy.ndarray, shape (M,), float64
        ``v_left - v_right`` in pixels (ideally 0 for a rectified pair).
    disparity_px : numpy.ndarray, shape (M,), float64
        ``u_left - u_right`` in pixels.

    Notes
    -----
    Instances are immutable: the arrays are read-only. Use the indices to gather the
    points, e.g. ``left_xy[m.left_index]`` and ``right_xy[m.right_index]``.
    """

    left_index: np.ndarray
    right_index: np.ndarray
    row_difference_px: np.ndarray
    disparity_px: np.ndarray

    def __post_init__(self) -> None:
        fields = {
            "left_index": np.array(self.left_index, dtype=np.intp).reshape(-1),
            "right_index": np.array(self.right_index, dtype=np.intp).reshape(-1),
            "row_difference_px": np.array(self.row_difference_px, dtype=np.float64).reshape(-1),
            "disparity_px": np.array(self.disparity_px, dtype=np.float64).reshape(-1),
        }
        lengths = {name: len(value) for name, value in fields.items()}
        if len(set(lengths.values())) > 1:
            raise InputError(f"StereoMatches fields must have equal lengths, got {lengths}.")
        for name, value in fields.items():
            value.setflags(write=False)
            object.__setattr__(self, name, value)

    def __len__(self) -> int:
        return int(self.left_index.shape[0])

    @classmethod
    def _trusted(
        cls,
        left_index: np.ndarray,
        right_index: np.ndarray,
        row_difference: np.ndarray,
        disparity: np.ndarray,
    ) -> StereoMatches:
        """Wrap fresh 1-D arrays of equal length and the right dtypes without copying or checking them."""
        matches = object.__new__(cls)
        for name, value in zip(
            ("left_index", "right_index", "row_difference_px", "disparity_px"),
            (left_index, right_index, row_difference, disparity),
            strict=True,
        ):
            value.setflags(write=False)
            object.__setattr__(matches, name, value)
        return matches


def disparity_window_px(
    fx_px: float,
    baseline_mm: float,
    depth_min_mm: float,
    depth_max_mm: float,
    *,
    margin_px: float = 2.0,
) -> tuple[float, float]:
    """Disparity range of points whose depth lies in ``[depth_min_mm, depth_max_mm]``.

    Parameters
    ----------
    fx_px : float
        Horizontal focal length of the rectified cameras, in pixels (> 0).
    baseline_mm : float
        Distance between the camera centres, in mm (> 0).
    depth_min_mm, depth_max_mm : float
        Nearest and farthest depth ``Z`` of the markers in the left camera frame, in mm
        (``0 < depth_min_mm < depth_max_mm``).
    margin_px : float, optional
        Widening on both sides, in pixels (>= 0), for detection noise and residual
        rectification error. Default 2 px.

    Returns
    -------
    (float, float)
        ``(min_disparity_px, max_disparity_px) =
        (fx B / depth_max - margin, fx B / depth_min + margin)``, ready for
        :func:`match_rectified`.

    Raises
    ------
    InputError
        If a value is not finite, not positive where required, or the depths are not
        increasing.

    Examples
    --------
    >>> lo, hi = disparity_window_px(925.0, 30.0, 175.0, 195.0)
    >>> round(lo, 2), round(hi, 2)
    (140.31, 160.57)
    """
    fx = positive_float(fx_px, "fx_px")
    baseline = positive_float(baseline_mm, "baseline_mm")
    z_min = positive_float(depth_min_mm, "depth_min_mm")
    z_max = positive_float(depth_max_mm, "depth_max_mm")
    margin = finite_float(margin_px, "margin_px")
    if z_min >= z_max:
        raise InputError(
            f"depth_min_mm ({z_min}) must be smaller than depth_max_mm ({z_max}); "
            "pass the nearest depth first."
        )
    if margin < 0.0:
        raise InputError(f"margin_px must be >= 0, got {margin}.")
    return fx * baseline / z_max - margin, fx * baseline / z_min + margin


def match_rectified(
    left_xy: npt.ArrayLike,
    right_xy: npt.ArrayLike,
    *,
    row_tolerance_px: float,
    min_disparity_px: float,
    max_disparity_px: float,
    disparity_weight: float = 0.01,
) -> StereoMatches:
    """Match marker detections of a rectified pair by a one-to-one global assignment.

    Parameters
    ----------
    left_xy, right_xy : array_like, shape (N, 2) and (K, 2)
        Marker centres ``(u, v)`` in pixels in the left and right rectified images. Either
        may be empty.
    row_tolerance_px : float
        Largest accepted ``|v_left - v_right|``, in pixels (> 0).
    min_disparity_px, max_disparity_px : float
        Accepted disparity range ``[min, max]`` of ``d = u_left - u_right``, in pixels
        (``min < max``); see :func:`disparity_window_px`.
    disparity_weight : float, optional
        Weight (>= 0) of the disparity term of the cost, see Notes. The default 0.01 only
        breaks near-ties of the row term.

    Returns
    -------
    StereoMatches
        The matched pairs, sorted by left index. Markers without an admissible partner
        are left out.

    Raises
    ------
    InputError
        If the point arrays are not finite ``(N, 2)`` arrays, the tolerance is not
        positive or the disparity range is empty.

    Notes
    -----
    A pair ``(i, j)`` is admissible if ``|v_i - v_j| <= row_tolerance_px`` and
    ``min_disparity_px <= u_i - u_j <= max_disparity_px``. Its cost is

    ``c_ij = ((v_i - v_j) / tol)^2 + disparity_weight * ((d_ij - d_mid) / h)^2``

    with ``d_mid`` and ``h`` the centre and half-width of the disparity window, so each
    term is at most 1 (resp. ``disparity_weight``). The matching has the largest
    possible number of admissible pairs and, among those, the smallest total cost
    (``scipy.optimize.linear_sum_assignment``, with inadmissible pairs given a cost
    larger than any sum of admissible costs and removed afterwards). Unlike greedy
    nearest-row matching, one marker cannot take the partner another marker needs.

    The disparity term is convex in ``d``, so when several markers lie on the same rows
    (a marker grid aligned with the baseline) and their row costs tie, the assignment
    preserves the left-to-right order of the markers. Order alone cannot resolve rows
    with missing or spurious detections: choose the disparity window narrower than the
    marker pitch in the image (for the nominal jig, 40 px) so that each marker has at
    most one candidate per row.

    Connected components of the admissibility graph are independent: components with a
    single pair are taken directly, the others are solved in batches of whole components.
    The admissible pairs and the components are found in one compiled loop
    (:func:`softjig.sensing._stereo_kernels.pairs_and_components`).
    """
    left = _as_points(left_xy, "left_xy")
    right = _as_points(right_xy, "right_xy")
    tol = positive_float(row_tolerance_px, "row_tolerance_px")
    d_min = finite_float(min_disparity_px, "min_disparity_px")
    d_max = finite_float(max_disparity_px, "max_disparity_px")
    weight = finite_float(disparity_weight, "disparity_weight")
    if d_min >= d_max:
        raise InputError(
            f"min_disparity_px ({d_min}) must be smaller than max_disparity_px ({d_max}); "
            "use disparity_window_px() to derive them from the depth range."
        )
    if weight < 0.0:
        raise InputError(f"disparity_weight must be >= 0, got {weight}.")

    order = np.argsort(right[:, 1], kind="stable")
    li, rj, row_diff, disparity, component, n_conflicts = pairs_and_components(
        left, right, order, tol, d_min, d_max
    )
    if n_conflicts == 0:  # every admissible pair is the only candidate of both its markers
        return StereoMatches._trusted(li, rj, row_diff, disparity)
    conflicts = np.flatnonzero(component >= 0)
    edges_in_component = np.ones(len(li), np.intp)
    edges_in_component[conflicts] = np.bincount(component[conflicts])[component[conflicts]]
    half_window = 0.5 * (d_max - d_min)
    cost = (row_diff / tol) ** 2 + weight * ((disparity - (d_min + half_window)) / half_window) ** 2
    chosen = [np.flatnonzero(edges_in_component == 1)]  # one left, one right marker
    multi = np.flatnonzero(edges_in_component > 1)
    multi = multi[np.argsort(component[multi], kind="stable")]
    starts = np.flatnonzero(np.diff(component[multi], prepend=-1))
    batch_starts = starts[np.flatnonzero(np.diff(starts // _BATCH_EDGES, prepend=-1))]
    if len(multi):
        for edges in np.split(multi, batch_starts[1:]):
            chosen.append(edges[_assign(li[edges], rj[edges], cost[edges], 1.0 + weight)])
    selected = np.concatenate(chosen)
    selected = selected[np.argsort(li[selected], kind="stable")]
    return _matches(left, right, li[selected], rj[selected])


def triangulate_rectified(
    left_xy: npt.ArrayLike,
    right_xy: npt.ArrayLike,
    *,
    fx_px: float,
    fy_px: float,
    cx_px: float,
    cy_px: float,
    baseline_mm: float,
) -> np.ndarray:
    """Triangulate matched points of an ideal rectified pair in the left camera frame.

    Parameters
    ----------
    left_xy, right_xy : array_like, shape (M, 2)
        Matched centres ``(u, v)`` in pixels; row ``k`` of both is the same marker (e.g.
        ``left_xy[m.left_index]`` and ``right_xy[m.right_index]``).
    fx_px, fy_px : float
        Focal lengths of the rectified cameras, in pixels (> 0).
    cx_px, cy_px : float
        Principal point of the rectified cameras, in pixels.
    baseline_mm : float
        Baseline in mm (> 0); the right camera is at ``(+baseline, 0, 0)`` in the left
        camera frame.

    Returns
    -------
    numpy.ndarray, shape (M, 3), float64
        Points ``(X, Y, Z)`` in mm in the left camera frame (x right, y down, z forward):
        ``Z = fx B / d``, ``X = (u_l - cx) Z / fx``, ``Y = (v - cy) Z / fy``, with
        ``d = u_l - u_r`` and ``v`` the mean of the left and right rows.

    Raises
    ------
    InputError
        If the arrays are not finite ``(M, 2)`` arrays of equal length, a camera
        parameter is invalid, or a disparity is not positive (the point would not be in
        front of the cameras).
    """
    left = _as_points(left_xy, "left_xy")
    right = _as_points(right_xy, "right_xy")
    if len(left) != len(right):
        raise InputError(
            f"left_xy has {len(left)} points but right_xy has {len(right)}; pass matched "
            "pairs, e.g. left_xy[m.left_index] and right_xy[m.right_index]."
        )
    fx = positive_float(fx_px, "fx_px")
    fy = positive_float(fy_px, "fy_px")
    cx = finite_float(cx_px, "cx_px")
    cy = finite_float(cy_px, "cy_px")
    baseline = positive_float(baseline_mm, "baseline_mm")
    disparity = left[:, 0] - right[:, 0]
    bad = np.flatnonzero(disparity <= 0.0)
    if len(bad):
        raise InputError(
            f"{len(bad)} of {len(left)} pairs have a disparity u_left - u_right <= 0 "
            f"(first: pair {bad[0]}, d = {disparity[bad[0]]:.3f} px), which puts them "
            "at infinity or behind the cameras; check that the left and right images are not "
            "swapped and match with min_disparity_px > 0."
        )
    z = fx * baseline / disparity
    x = (left[:, 0] - cx) * z / fx
    y = (0.5 * (left[:, 1] + right[:, 1]) - cy) * z / fy
    return np.column_stack([x, y, z])


def _assign(li: np.ndarray, rj: np.ndarray, cost: np.ndarray, max_cost: float) -> np.ndarray:
    """Edges (positions into ``li``/``rj``) chosen by a max-cardinality min-cost assignment."""
    left_nodes, row = np.unique(li, return_inverse=True)
    right_nodes, col = np.unique(rj, return_inverse=True)
    # Any matching with one more admissible pair is cheaper than one with fewer.
    infeasible = (min(len(left_nodes), len(right_nodes)) + 1) * max_cost + 1.0
    matrix = np.full((len(left_nodes), len(right_nodes)), infeasible)
    edge = np.full(matrix.shape, -1, np.intp)
    matrix[row, col] = cost
    edge[row, col] = np.arange(len(li))
    from scipy.optimize import linear_sum_assignment

    rows, cols = linear_sum_assignment(matrix)
    chosen = edge[rows, cols]
    return chosen[chosen >= 0]


def _matches(left: np.ndarray, right: np.ndarray, li: np.ndarray, rj: np.ndarray) -> StereoMatches:
    return StereoMatches(
        left_index=li,
        right_index=rj,
        row_difference_px=left[li, 1] - right[rj, 1],
        disparity_px=left[li, 0] - right[rj, 0],
    )


def _as_points(points: npt.ArrayLike, name: str) -> np.ndarray:
    """``points`` as a finite float64 (N, 2) array, or an InputError naming the argument."""
    try:
        arr = np.asarray(points, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(f"{name} must be an (N, 2) array of pixel coordinates (u, v).") from None
    if arr.ndim == 1 and arr.size == 0:
        arr = arr.reshape(0, 2)
    if arr.ndim != 2 or arr.shape[1] != 2:
        raise InputError(
            f"{name} must be an (N, 2) array of pixel coordinates (u, v), got shape {arr.shape}."
        )
    if not np.isfinite(arr).all():
        raise InputError(f"{name} contains NaN or infinite coordinates; remove them first.")
    return arr
