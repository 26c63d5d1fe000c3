"""Marker identities over time: each triangulated marker matched to a reference, with its displacement.

A reference is the unloaded jig: either a reference frame captured once (as DTact and 9DTact users do)
and triangulated like any frame, or the nominal rest shape (the mould's marker grid on the rest dome).
Markers move mostly along the membrane's normal (a few mm) and little sideways (well under half the
marker pitch), so a marker keeps the identity of the nearest reference marker in ``(x, y)``, found with a
k-d tree and resolved one-to-one. The 3-D displacement field this gives is what force and slip
estimation build on.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numba
import numpy as np

from softjig.config import JigConfig
from softjig.jig_shape import rest_marker_points_mm


@dataclass(frozen=True)
class ReferenceMarkers:
    """The markers of the unloaded jig, in J.

    Attributes
    ----------
    xyz_mm : (K, 3) each reference marker's position (mm); not to be modified once made (its sort by
        ``x``, for :func:`identify_markers`, is made with it).
    source : ``"reference frame"`` or ``"rest shape"``.
    """

    xyz_mm: np.ndarray
    source: str
    _sorted_x: tuple[np.ndarray, np.ndarray, np.ndarray] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        xyz = np.ascontiguousarray(self.xyz_mm, dtype=float).reshape(-1, 3)
        order = np.argsort(xyz[:, 0], kind="stable")
        object.__setattr__(self, "_sorted_x", (np.ascontiguousarray(xyz[order, 0]), order, xyz))

    def __len__(self) -> int:
        return len(self.xyz_mm)

    def sorted_x(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The markers' ``x`` ascending, their order and their positions, contiguous (for
        :func:`identify_markers`), made with the reference."""
        return self._sorted_x


def rest_shape_reference(jig: JigConfig) -> ReferenceMarkers:
    """The nominal markers on the nominal rest membrane (no images needed).

    An estimator builds it once (each estimate without a reference frame needs it); its array is
    read-only.
    """
    xyz = rest_marker_points_mm(jig)  # a surveyed layout's measured heights, else the rest profile's
    xyz.setflags(write=False)
    return ReferenceMarkers(xyz, "rest shape")


@dataclass(frozen=True)
class MarkerIdentities:
    """Which reference marker each triangulated marker is, and how far it moved.

    Attributes
    ----------
    ids : (M,) index into the reference's markers, ``-1`` where none lies within reach.
    displacement_mm : (M, 3) position minus the reference's, in J (NaN where ``ids == -1``).
    """

    ids: np.ndarray
    displacement_mm: np.ndarray


def identify_markers(
    points_J: np.ndarray, reference: ReferenceMarkers, *, max_lateral_mm: float
) -> MarkerIdentities:
    """Match triangulated markers to a reference by their ``(x, y)``, one to one.

    Parameters
    ----------
    points_J : (M, 3) the markers of this frame, in J (mm).
    reference : the unloaded jig's markers.
    max_lateral_mm : farthest sideways a marker may be from its reference (half the marker pitch is
        the natural choice: beyond it the identity is ambiguous).

    Returns
    -------
    MarkerIdentities
    """
    points = np.asarray(points_J, dtype=float).reshape(-1, 3)
    ids = np.full(len(points), -1)
    displacement = np.full(points.shape, np.nan)
    if len(points) == 0 or len(reference) == 0:
        return MarkerIdentities(ids, displacement)
    xs, order, reference_xyz = reference.sorted_x()
    ids, displacement = _one_to_one_nearest(
        np.ascontiguousarray(points), reference_xyz, xs, order, float(max_lateral_mm)
    )
    return MarkerIdentities(ids, displacement)


@numba.njit(cache=True)
def _one_to_one_nearest(
    points: np.ndarray, reference: np.ndarray, xs: np.ndarray, order: np.ndarray, reach: float
) -> tuple[np.ndarray, np.ndarray]:
    """Each point's nearest reference marker in ``(x, y)`` closer than ``reach`` (``-1`` if none); where
    two claim the same one, the nearer keeps it (ties: the earlier point). Returns the ids and the
    points' displacements from their reference markers (NaN without one).

    The same as a k-d tree's query with ``distance_upper_bound`` and a claim loop in the stable order of
    distance, compiled, with a sweep over the reference sorted by ``x`` (``xs``, ``order``): 20 us
    instead of 0.3 ms for 300 markers (measured).
    """
    n = points.shape[0]
    nearest = np.full(n, -1, dtype=np.int64)
    distance = np.full(n, np.inf)
    r2 = reach * reach
    slack = reach * (1.0 + 1e-9)
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
