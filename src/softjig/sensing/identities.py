"""Marker identities over time: each triangulated marker matched to a reference, with its displacement.

A reference is the unloaded jig: either a reference frame captured once (as DTact and 9DTact users do)
and triangulated like any frame, or the nominal rest shape (the mould's marker grid on the rest dome).
Markers move mostly along the membrane's normal (a few mm) and little sideways (well under half the
marker pitch), so a marker keeps the identity of the nearest reference marker in ``(x, y)``, found with a
k-d tree and resolved one-to-one. The 3-D displacement field this gives is what force and slip
estimation build on.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from softjig.config import JigConfig
from softjig.jig_shape import marker_layout_xy, rest_inner_height_mm


@dataclass(frozen=True)
class ReferenceMarkers:
    """The markers of the unloaded jig, in J.

    Attributes
    ----------
    xyz_mm : (K, 3) each reference marker's position (mm).
    source : ``"reference frame"`` or ``"rest shape"``.
    """

    xyz_mm: np.ndarray
    source: str

    def __len__(self) -> int:
        return len(self.xyz_mm)


def rest_shape_reference(jig: JigConfig) -> ReferenceMarkers:
    """The nominal markers on the nominal rest membrane (no images needed)."""
    xy = marker_layout_xy(jig)
    z = rest_inner_height_mm(jig, xy[:, 0], xy[:, 1])
    return ReferenceMarkers(np.column_stack([xy, z]), "rest shape")


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
    distance, nearest = cKDTree(reference.xyz_mm[:, :2]).query(
        points[:, :2], distance_upper_bound=max_lateral_mm
    )
    found = np.isfinite(distance)
    # One to one: where two markers claim the same reference marker, the nearer keeps it.
    order = np.argsort(np.where(found, distance, np.inf), kind="stable")
    taken = np.zeros(len(reference), dtype=bool)
    for k in order[found[order]]:
        if not taken[nearest[k]]:
            taken[nearest[k]] = True
            ids[k] = nearest[k]
    known = ids >= 0
    displacement[known] = points[known] - reference.xyz_mm[ids[known]]
    return MarkerIdentities(ids, displacement)
