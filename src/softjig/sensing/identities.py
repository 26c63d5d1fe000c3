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

import numpy as np

from softjig.checks import positive_float
from softjig.config import JigConfig
from softjig.errors import InputError
from softjig.jig_shape import rest_marker_points_mm
from softjig.sensing._identities_kernels import one_to_one_nearest
from softjig.sensing.levelling import HeadLevel


@dataclass(frozen=True)
class ReferenceMarkers:
    """The markers of the unloaded jig, in J.

    Attributes
    ----------
    xyz_mm : (K, 3) each reference marker's position (mm); not to be modified once made (its sort by
        ``x``, for :func:`identify_markers`, is made with it).
    source : ``"reference frame"`` or ``"rest shape"``.
    head_level : for a reference frame, the stereo head's pose error measured on it: by its fiducials,
        or levelled on its membrane when they were not seen (:mod:`softjig.sensing.levelling`; its
        markers are then triangulated in the levelled frame); ``None`` for the rest shape, or when the
        head could not be levelled.
    level_note : why a reference frame of the config's poses could not level the head (``None`` when it
        did, or when it did not need to).
    unlevelled_tilt_deg : where the head could not be levelled because the markers fit the rest markers
        as well in several places, the RMS of those alignments' tilts (deg,
        :class:`~softjig.sensing.levelling.AmbiguousLevel`): about how far the config's poses are off;
        else ``None``.
    """

    xyz_mm: np.ndarray
    source: str
    head_level: HeadLevel | None = None
    level_note: str | None = None
    unlevelled_tilt_deg: float | None = None
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

    Raises
    ------
    InputError
        ``points_J`` not of shape (M, 3) or not finite, or ``max_lateral_mm`` not a positive number.
    """
    max_lateral_mm = positive_float(max_lateral_mm, "max_lateral_mm")
    points = np.asarray(points_J, dtype=float)
    if points.ndim != 2 or points.shape[1] != 3:
        raise InputError(
            f"points_J must be an (M, 3) array of marker positions in J (mm), got shape {points.shape}"
        )
    if not np.isfinite(points).all():  # M is at most a few hundred markers: cheap
        raise InputError("points_J contains NaN or infinite positions: drop those markers first")
    ids = np.full(len(points), -1)
    displacement = np.full(points.shape, np.nan)
    if len(points) == 0 or len(reference) == 0:
        return MarkerIdentities(ids, displacement)
    xs, order, reference_xyz = reference.sorted_x()
    ids, displacement = one_to_one_nearest(
        np.ascontiguousarray(points), reference_xyz, xs, order, max_lateral_mm
    )
    return MarkerIdentities(ids, displacement)
