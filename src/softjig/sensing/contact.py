"""The contact region, found without being told the part's size, and its footprint.

The paper must be told the part's base size to crop the markers it fits. Instead, each marker's
**indentation** (how far it lies below the unloaded membrane: a reference frame, or the nominal rest shape)
says which markers the part displaced. Indentations are measured against a robust zero and noise scale of
the markers at rest (a part only pushes markers in, so the less indented side of the distribution is
uncontaminated), which also absorbs a uniform depth bias of an imperfectly calibrated camera pair.
Markers indented beyond the noise are *candidates*; the contact is grown from the deepest of them over
the neighbours on their plane (:func:`grow_contact`, robust fits from :mod:`softjig.sensing.robust`),
rejecting the membrane that the indentation drags down around it.

A plane is the face of its contact only if no marker contradicts it (:func:`contact_violations`): none
penetrates it inside the contact, none lies far below it inside the contact's hull (a hole), and
none beside the contact lies deep below it where it would still press into the membrane, deeper than the
contact next to it (:func:`holes_beside`: the part's real face beside a strip of wall fitted instead).
The contact chosen is also checked across its whole dent (:func:`holes_in_the_dent`): no marker joined to
it through pushed-in markers lies deep below its plane, where the plane would press, deeper than the face
reaches at the contact (a stretch of drape fitted far from the part's deeper face).

The **footprint** of the contact is the convex hull of the contact markers dilated by half a marker pitch
(each marker stands for one cell of the grid; by Steiner's formula the area grows by
``perimeter * p / 2 + pi (p / 2)^2``). Contact is **partial** when, on some side, the fitted plane rises to
the rest membrane within the footprint: there the part lifts off, rather than ending at its edge with the
membrane draped down from it.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import cv2
import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from softjig.config import JigConfig
from softjig.errors import EstimationError, InputError
from softjig.geometry import PlaneFit
from softjig.jig_shape import rest_inner_height_mm
from softjig.sensing import _contact_kernels as kernels
from softjig.sensing._contact_kernels import (
    AT_REST_SIGMAS,
    MAD_TO_SIGMA,
    MIN_AT_REST,
    NOISE_FLOOR_MM,
    ZERO_ROUNDS,
    ZERO_TOLERANCE_SIGMAS,
)

#: Seeds of :func:`grow_contact`, in the order tried: the candidates indented at least this share of the
#: deepest tenth's depth.
SEED_DEPTH_SHARES = (0.5, 0.75, 0.25)
#: A marker out of the contact lying this many inlier thresholds below the plane, inside the contact's
#: hull, is a hole: no face pressed into the membrane leaves one (:func:`contact_violations`).
HOLE_THRESHOLDS = 2.0
#: A marker just outside the contact, pushed in deeper than the contact beside it, is a hole beside it
#: when it lies this many inlier thresholds below the plane (:func:`holes_beside`), as a check of the
#: contact chosen (:func:`contact_violations` with ``beside_thresholds``): 1.5 thresholds are 3.75
#: sigmas of a marker's height (one-sided, 1e-4 by noise alone), and noise must also make it deeper than
#: every contact marker beside it. The choice between contacts (:func:`grow_contact`) keeps
#: :data:`HOLE_THRESHOLDS`: there, the looser test traded a right contact (3.5 deg off, which it makes
#: suspect) for a smaller, wrong one that no marker contradicted (35 deg off; zoo seed 0, design 7,
#: frame 2, stirred image model, size-free against the rest shape).
BESIDE_HOLE_THRESHOLDS = 1.5
#: A marker of the contact's dent pushed in deeper than the face reaches in or just outside the contact
#: is a hole in the dent (:func:`holes_in_the_dent`) when it also lies this many inlier thresholds below
#: the plane where the plane presses into the membrane (2 thresholds: 5 sigmas of a marker's height) ...
DENT_HOLE_THRESHOLDS = 2.0
#: ... and the check of the contact chosen counts holes in the dent only when there are this many (one
#: may be a stereo mismatch that passed :func:`off_the_membrane`).
DENT_HOLE_MIN_MARKERS = 2
#: The fewest pushed-in markers whose scatter :func:`pushed_in_scatter_mm` measures.
MIN_SCATTER_MARKERS = 10
#: A marker's neighbours lie within this many marker pitches (a square grid's 8 nearest).
NEIGHBOUR_RADIUS_PITCHES = 1.5
#: A marker indented by this many noise sigmas or more (or of unknown depth) is not at rest
#: (:func:`markers_at_rest`) ...
PUSHED_SIGMAS = 1.5
#: ... nor is one within this many pitches of it: the membrane drags down around a part's face about a
#: pitch beyond its last clearly pushed-in marker.
AT_REST_REACH_PITCHES = 2.0
#: The indentation noise is measured against a quadratic fitted to the markers within this many pitches
#: (a square grid's 20 nearest, a hexagonal grid's 18: two rings, which a quadratic needs, since the
#: first ring alone cannot tell the field's curvature from the marker's own noise).
NOISE_RADIUS_PITCHES = 2.5
#: The steepest plausible contact plane (deg): no part pressed into a soft jig stands steeper.
MAX_TILT_DEG = 45.0
#: Two neighbouring markers are a step apart on the membrane (:func:`off_the_membrane`) when their depths
#: differ by less than :data:`MAX_TILT_DEG`'s slope over their distance plus this many sigmas of the
#: difference (beyond it one-sided, 3e-5 by noise alone).
OFF_MEMBRANE_SIGMAS = 4.0
#: Violations of a contact's plane that noise explains: at least this many ...
TOLERATED_VIOLATIONS = 2
#: ... or this share of the contact's markers.
TOLERATED_VIOLATION_SHARE = 0.05
#: The plane within ``max(LIFT_NOISE_SIGMAS noise, MIN_LIFT_CLEARANCE_MM)`` of the rest membrane at the
#: footprint's edge lifts off there (:func:`describe_contact`).
LIFT_NOISE_SIGMAS = 3.0
MIN_LIFT_CLEARANCE_MM = 0.3
#: With the part's size known, a footprint under this share of its base is partial contact.
PARTIAL_AREA_SHARE = 0.7
#: A plane tilted less than this (deg) is level: its lift-off side is found from the clearance instead.
LEVEL_PLANE_DEG = 1.0
#: A plane whose horizontal normal component is below this is level for :func:`face_centre_xy`.
LEVEL_SLOPE = 1e-6
#: :func:`footprint_misfit` counts a marker's misfit up to this many noise sigmas: beyond it, the marker
#: is a mismatch, not evidence about the face, and one must not outweigh the rest.
FOOTPRINT_MISFIT_CAP_SIGMAS = 10.0


@dataclass(frozen=True)
class Indentation:
    """How far each marker lies below the unloaded membrane.

    Attributes
    ----------
    depth_mm : (M,) indentation of each marker (mm, positive = pushed in), about the robust zero.
    zero_mm : the median raw indentation that was subtracted (a depth bias of the cameras, mm).
    noise_mm : robust standard deviation of the indentation of markers at rest (mm).
    """

    depth_mm: np.ndarray
    zero_mm: float
    noise_mm: float


def indentation(
    points_J: np.ndarray, reference_z_mm: np.ndarray, *, pitch_mm: float | None = None
) -> Indentation:
    """Indentations from each marker's reference height (the reference frame's, or the rest shape's).

    Parameters
    ----------
    points_J : (M, 3) the markers (mm, J).
    reference_z_mm : (M,) each marker's height in the unloaded jig (mm).
    pitch_mm : the markers' pitch (mm). When given, the noise is measured from the differences between
        neighbouring markers (see Notes), which a large part's drape does not inflate.

    Notes
    -----
    Noise: the indentation field is smooth (planar under a face, a curved drape around it, flat at
    rest), so a marker's indentation minus a quadratic least-squares fitted to its neighbours' (within
    2.5 pitches, :data:`NOISE_RADIUS_PITCHES`) is noise, of variance ``sigma^2 (1 + v)`` for the fit's
    prediction variance ``v sigma^2``, except near the few kinks (the contact's edge), which a median
    ignores. The mean of the 8 nearest neighbours instead carries ``3 pitch^2 / 8`` times the drape's
    Laplacian, as large as the noise on a coarse (9.4 mm) grid. Without the pitch, the noise is the
    spread of the markers indented less than the median, which assumes that at least half the markers
    are at rest: a part that drags most of the membrane down (80 mm at 20 deg) inflates it two- to
    three-fold.
    Zero: the median raw indentation of the markers within 2.5 sigma of it (iterated from the median of
    all), which also absorbs a uniform depth bias of an imperfectly calibrated camera pair.
    """
    return indentations(points_J, (reference_z_mm,), pitch_mm=pitch_mm)[0]


def indentations(
    points_J: np.ndarray, reference_zs_mm: Sequence[np.ndarray], *, pitch_mm: float | None = None
) -> tuple[Indentation, ...]:
    """:func:`indentation` against each of several reference heights (for example the reference frame's
    and the rest shape's), in one pass: the neighbour noise's fits depend on the markers' positions only,
    so they are shared. The pass fits the markers finite against every reference, so references unknown
    (NaN) at different markers are taken one call each: each result is its own call's."""
    points_J = np.asarray(points_J, dtype=float)
    if points_J.ndim != 2 or points_J.shape[1] != 3:
        raise InputError(f"indentation needs (M, 3) markers, got shape {points_J.shape}")
    shapes = [np.shape(z) for z in reference_zs_mm]
    if not shapes or any(shape != (len(points_J),) for shape in shapes):
        raise InputError(
            f"indentation needs one ({len(points_J)},) reference height per marker, got {shapes}"
        )
    columns = np.column_stack(reference_zs_mm)
    finite = np.isfinite(columns)
    if len(reference_zs_mm) > 1 and not (finite == finite[:, :1]).all():
        return tuple(indentation(points_J, z, pitch_mm=pitch_mm) for z in reference_zs_mm)
    if pitch_mm:  # the usual case, in one compiled pass
        depth, zero, noise = kernels.indentation(
            np.ascontiguousarray(points_J, dtype=float),
            np.ascontiguousarray(columns, dtype=float),
            NOISE_RADIUS_PITCHES * pitch_mm,
        )
        if (noise > 0).all():
            return tuple(
                Indentation(np.ascontiguousarray(depth[:, f]), float(zero[f]), float(noise[f]))
                for f in range(len(noise))
            )
    return tuple(_indentation_from_markers_at_rest(points_J, z) for z in reference_zs_mm)


def _indentation_from_markers_at_rest(points_J: np.ndarray, reference_z_mm: np.ndarray) -> Indentation:
    """Too few markers with neighbours (or no pitch): the noise of the markers at rest."""
    raw = np.asarray(reference_z_mm, dtype=float) - points_J[:, 2]
    finite = np.isfinite(raw)
    if not finite.any():
        return Indentation(np.full(len(raw), np.nan), 0.0, float("nan"))
    zero = float(np.median(raw[finite]))
    noise = float("nan")
    for _ in range(ZERO_ROUNDS):
        # A part only pushes markers in, never out, so the markers indented less than the median are
        # at rest however many the part displaced: the noise is the spread of that side.
        low = finite & (raw <= zero)
        noise = (
            max(float(MAD_TO_SIGMA * np.median(zero - raw[low])), NOISE_FLOOR_MM)
            if low.any()
            else NOISE_FLOOR_MM
        )
        at_rest = finite & (np.abs(raw - zero) < AT_REST_SIGMAS * noise)
        new_zero = float(np.median(raw[at_rest])) if at_rest.sum() >= MIN_AT_REST else zero
        if abs(new_zero - zero) < ZERO_TOLERANCE_SIGMAS * noise:
            break
        zero = new_zero
    return Indentation(raw - zero, zero, noise)


def markers_at_rest(points_J: np.ndarray, dent: Indentation, *, pitch_mm: float) -> np.ndarray:
    """The markers far from every pushed-in one (indented :data:`PUSHED_SIGMAS` noise sigmas or more, or
    of unknown depth): more than :data:`AT_REST_REACH_PITCHES` pitches away, as booleans. Where they lie
    on the rest membrane, a loaded frame levels the stereo head as the unloaded one does
    (:meth:`softjig.sensing.estimator.Estimator.estimate`)."""
    pushed = ~(dent.depth_mm < PUSHED_SIGMAS * dent.noise_mm)  # NaN (unknown) compares False: pushed
    if not pushed.any():
        return np.ones(len(points_J), dtype=bool)
    return ~_near(points_J[:, :2], pushed, AT_REST_REACH_PITCHES * pitch_mm)


def _near(xy: np.ndarray, members: np.ndarray, radius: float) -> np.ndarray:
    """Which ``xy`` lie closer than ``radius`` to one of ``xy[members]``, as booleans (what a k-d tree's
    query with ``distance_upper_bound`` finds)."""
    xy = np.ascontiguousarray(xy, dtype=float)
    return kernels.count_within(xy, xy[members], float(radius), False) > 0


def off_the_membrane(
    points_J: np.ndarray,
    depth_mm: np.ndarray,
    *,
    pitch_mm: float,
    noise_mm: float,
    min_points: int | None,
    height_noise_mm: float | None = None,
) -> np.ndarray:
    """Markers off the membrane, as booleans: those inside the base plate (below ``z = 0`` by more than
    :data:`OFF_MEMBRANE_SIGMAS` times ``height_noise_mm``), and of the others those in a group of fewer
    than ``min_points`` that has neighbours outside it but no step to one, a step being a depth
    difference a face tilted :data:`MAX_TILT_DEG` explains over the two markers' distance, plus
    :data:`OFF_MEMBRANE_SIGMAS` times the difference's noise (from ``noise_mm``). Such a group is no
    contact (too few to fit) and no part of one, since a face leaves each marker it presses within that
    slope of its neighbours in contact: the points are not where their markers are.

    Why: on a rectified pair, a marker whose partner was not detected in the other image can be matched to
    the next marker along its row (the disparity window spans the membrane's whole depth, more than a
    pitch in the image), and its neighbours along the row after it: the points then lie ``pitch * Z / B``
    off the membrane (the cameras' distance over their baseline: 2-12 pitches), 20-30 mm deep for a jig
    145 mm from cameras 43 mm apart. Six such points outvoted the contact's markers in zoo seed 4,
    design 32, frames 6 and 9 ("ok" and 15-17 deg off); two of them were neighbours, so a test of each
    marker against its neighbours alone keeps them. A block of such points can be larger than a contact
    (six, two rows of three, in seed 4, design 17, frame 4), but most of it then lies inside the plate.

    Parameters
    ----------
    points_J : (M, 3) the markers (mm, J).
    depth_mm : (M,) their indentations (mm); NaN where unknown (never flagged, nor a neighbour).
    pitch_mm : the markers' pitch (mm): neighbours lie within :data:`NEIGHBOUR_RADIUS_PITCHES` of it.
    noise_mm : the noise of one marker's ``depth_mm`` (mm).
    min_points : the fewest markers a contact may have (``sensing.min_points``); ``None`` for an unloaded
        membrane, one smooth sheet: every group but the largest is off it.
    height_noise_mm : the noise of one marker's height ``z`` (mm); ``noise_mm`` when not given. The two
        differ with a reference frame: its depths are differenced against the same marker's reference
        height, which cancels what biases a marker's height in both frames (the bead pack's speckle over
        a marker that stays put), so they scatter less than the heights. A step judged at the heights'
        noise joins a point that a mismatch put millimetres deep to the face beside it (zoo seed 3, design
        32, frame 1 with the damaged image model: a point 11 mm off, 8 mm deeper than its deepest
        neighbour 5.9 mm away, with heights scattering 0.44 mm and depths 0.25 mm).
    """
    depth = np.asarray(depth_mm, dtype=float)
    height_noise_mm = noise_mm if height_noise_mm is None else height_noise_mm
    off = points_J[:, 2] < -OFF_MEMBRANE_SIGMAS * height_noise_mm  # inside the base plate (top face: z = 0)
    known = np.flatnonzero(np.isfinite(depth) & ~off)
    if len(known) < 2:
        return off
    group, cut = kernels.membrane_groups(
        np.ascontiguousarray(points_J[known, :2], dtype=float),
        np.ascontiguousarray(depth[known]),
        NEIGHBOUR_RADIUS_PITCHES * pitch_mm,
        float(np.tan(np.radians(MAX_TILT_DEG))),
        OFF_MEMBRANE_SIGMAS * np.sqrt(2.0) * noise_mm,
    )
    size = np.bincount(group)
    cut_off = np.zeros(len(size), dtype=bool)  # a group with a neighbour it steps to nowhere
    cut_off[group[cut]] = True
    off[known] = cut_off[group] & (size[group] < (size.max() if min_points is None else min_points))
    return off


def off_the_rest_membrane(points_J: np.ndarray, jig: JigConfig) -> np.ndarray:
    """:func:`off_the_membrane` for a frame of the unloaded jig, one smooth sheet (every group but the
    largest is off it), from the markers' depths below the config's rest shape and their noise
    (:func:`indentation`), as booleans. A reference frame's mismatched points would otherwise be the
    reference of the markers beside them (zoo seed 4: 9 and 11 points in two designs' reference frames,
    six of them a block two rows by three just above the plate)."""
    rest_z = rest_inner_height_mm(jig, points_J[:, 0], points_J[:, 1])
    at_rest = indentation(points_J, rest_z, pitch_mm=jig.markers.pitch_mm)
    if not np.isfinite(at_rest.noise_mm):  # too few markers to measure the noise: none judged
        return np.zeros(len(points_J), dtype=bool)
    return off_the_membrane(
        points_J,
        at_rest.depth_mm,
        pitch_mm=jig.markers.pitch_mm,
        noise_mm=at_rest.noise_mm,
        min_points=None,
    )


def contact_candidates(dent: Indentation, *, sigmas: float = 4.0, min_depth_mm: float = 0.3) -> np.ndarray:
    """Markers indented beyond ``max(sigmas x noise, min_depth_mm)``, as booleans."""
    threshold = max(sigmas * dent.noise_mm, min_depth_mm) if np.isfinite(dent.noise_mm) else min_depth_mm
    return dent.depth_mm > threshold  # False where NaN, as -inf would be


def pushed_in_scatter_mm(
    points_J: np.ndarray, heights: Indentation, pushed_in: np.ndarray, *, pitch_mm: float
) -> float:
    """The scatter (mm, 1 sigma) of the ``pushed_in`` markers' heights about a smooth surface: each one's
    height (``heights``, an indentation) minus a quadratic fitted to its pushed-in neighbours within
    :data:`NOISE_RADIUS_PITCHES` pitches, MAD-scaled; NaN where fewer than :data:`MIN_SCATTER_MARKERS` of
    them are known or have enough neighbours.

    Why: :func:`indentation`'s noise is the median over every marker, most of them at rest. Where the
    membrane is pressed onto a rigid face, the beads behind it press through it (a ripple of 0.1-0.2 mm,
    random from marker to marker), so the markers on the face scatter about its plane more than the
    membrane at rest does; the contact plane's inlier band must be set from theirs. A band set from the
    membrane at rest keeps a strip of a large face and the plane of a strip is any plane through it (zoo
    seed 4, design 30, frame 5: 14 of 163 markers in contact, 35 deg off)."""
    depth = heights.depth_mm[pushed_in]
    known = np.isfinite(depth)
    if known.sum() < MIN_SCATTER_MARKERS:
        return float("nan")
    scatter = kernels.neighbour_scatter(
        np.ascontiguousarray(points_J[pushed_in][known, :2], dtype=float),
        np.ascontiguousarray(depth[known], dtype=float),
        NOISE_RADIUS_PITCHES * pitch_mm,
    )
    return float(scatter) if scatter > 0 else float("nan")


def grow_contact(
    points_J: np.ndarray,
    dent: Indentation,
    candidates: np.ndarray,
    *,
    pitch_mm: float,
    fit_plane,
    threshold_mm: float,
    min_points: int = 6,
    max_tilt_rad: float = np.radians(MAX_TILT_DEG),
    max_rounds: int = 30,
) -> tuple[np.ndarray, PlaneFit]:
    """The markers in contact: the robust plane of the deeply pushed-in markers, grown over neighbours.

    1. **Seed.** The deep candidates (indented at least half as deep as the deepest tenth): a rigid face
       leaves the deepest impression where it touches, and the membrane dragged down around it (often
       more markers, but shallower) must not outvote it. Where the check (3) rejects the result, seeds
       of the candidates at least 3/4 and 1/4 as deep are tried next (:data:`SEED_DEPTH_SHARES`): at
       20 deg the wall beside a 50-80 mm part's lowered edge is as deep as half its contact.
    2. **Grow.** The robust plane of the seed; then every neighbouring marker (within 1.5 pitches of a
       contact marker) within ``threshold_mm`` of the plane and pushed in beyond the noise joins, and the
       plane is fitted again, until nothing changes. The wall of membrane beside a deep indentation rises
       steeply off the plane, and where the part lifts off the membrane falls away below it, so the growth
       stops at both.
    3. **Check.** No marker may lie above the face inside the contact, nor far below it inside the contact's
       hull, beyond a few that noise explains (2, or 5 % of the contact): the wall just outside a deeply
       pressed edge is as deep as the contact and can win the seed's fit, but its plane leaves the real
       contact markers above it; a ring of wall around a deep contact leaves them below it. Such a plane's
       markers are peeled off the seed and the rest is fitted again (at most twice), then the next seed is
       tried; the first contact without violations is taken, else the one with the fewest. Before a
       contradicted contact is peeled, the growth is tried again kept to the markers as deep as its seed
       (:func:`_deep_regrowth`). A plane tilted beyond ``max_tilt_rad`` (no part pressed into a soft jig
       stands so steep: it is a line of markers on the membrane's wall) counts as the worst.

    Parameters
    ----------
    points_J : (M, 3) the markers (mm, J).
    dent : their indentations.
    candidates : (M,) the clearly pushed-in markers.
    pitch_mm : the markers' pitch (mm).
    fit_plane : ``fit_plane(points) -> (inliers (K,) bool, PlaneFit)``, a robust plane fit.
    threshold_mm : the farthest a marker on the plane may lie from it (mm).
    min_points : the fewest markers a contact may have.
    max_tilt_rad : the steepest plausible contact plane (rad).

    Returns
    -------
    (used, plane) : (M,) the contact markers, and their plane.
    """
    depth = _nan_as_minus_inf(dent.depth_mm)
    deepest = float(np.percentile(depth[candidates], 90)) if candidates.any() else 0.0

    def grow(eligible: np.ndarray, seed: np.ndarray) -> tuple[np.ndarray, PlaneFit]:
        return _grow(points_J, eligible, seed, pitch_mm, fit_plane, threshold_mm, max_rounds)

    seeds: list[tuple[np.ndarray, np.ndarray]] = []  # each seed, and the markers as deep as it
    for share in SEED_DEPTH_SHARES:
        as_deep = depth >= share * deepest
        seed = candidates & as_deep
        if seed.sum() >= min_points and not any(np.array_equal(seed, other) for other, _ in seeds):
            seeds.append((seed, as_deep))
    best: tuple[int, np.ndarray, PlaneFit] | None = None
    failure: EstimationError | None = None
    for seed, as_deep in seeds or [(candidates.copy(), candidates)]:
        for _ in range(3):
            try:
                contact, plane = grow(depth > dent.noise_mm, seed)
            except EstimationError as exc:  # no plane in what is left of this seed: try the next
                failure = exc
                break
            violations = _violations(points_J, contact, plane, threshold_mm, max_tilt_rad, pitch_mm, dent)
            if best is None or violations < best[0]:
                best = (violations, contact, plane)
            if violations == 0:
                return contact, plane
            deep = _deep_regrowth(seed, as_deep, contact, grow)
            if deep is not None and not _violations(
                points_J, *deep, threshold_mm, max_tilt_rad, pitch_mm, dent
            ):
                return deep
            remaining = seed & ~contact
            if remaining.sum() < min_points:
                break
            seed = as_deep = remaining
    if best is None:
        raise failure or EstimationError("no plane could be fitted to the pushed-in markers")
    return best[1], best[2]


def contact_violations(
    points_J: np.ndarray,
    contact: np.ndarray,
    plane: PlaneFit,
    *,
    threshold_mm: float,
    pitch_mm: float,
    max_tilt_rad: float = np.radians(MAX_TILT_DEG),
    dent: Indentation | None = None,
    beside_thresholds: float = HOLE_THRESHOLDS,
    outside: np.ndarray | None = None,
) -> int:
    """How many markers contradict ``plane`` being the face of ``contact`` beyond the few that noise
    explains: penetrating it inside the contact's core, or holes far below it inside its hull
    (:func:`grow_contact`'s check, step 3), and, when the indentations ``dent`` are given, every hole
    beside the contact (:func:`holes_beside`, ``beside_thresholds`` inlier thresholds deep: the
    :data:`HOLE_THRESHOLDS` of the choice between contacts, or :data:`BESIDE_HOLE_THRESHOLDS` to check
    the contact chosen); a plane steeper than ``max_tilt_rad`` counts as the worst. ``outside``: the
    markers just outside ``contact`` (:func:`just_outside`), when the caller has them."""
    if contact.sum() < 3:
        return 0
    return _violations(
        points_J, contact, plane, threshold_mm, max_tilt_rad, pitch_mm, dent, beside_thresholds, outside
    )


def holes_beside(
    points_J: np.ndarray,
    dent: Indentation,
    contact: np.ndarray,
    plane: PlaneFit,
    *,
    threshold_mm: float,
    pitch_mm: float,
    depth_thresholds: float = BESIDE_HOLE_THRESHOLDS,
) -> np.ndarray:
    """Markers just outside the contact (within 1.5 pitches of it) that lie more than
    ``depth_thresholds`` inlier thresholds below ``plane`` where the plane would press into the
    membrane (its :func:`face_depth_mm` beyond ``threshold_mm``), and are pushed in deeper than every
    contact marker within 1.5 pitches of them, as booleans.

    No face leaves one. The part is convex, so all of it lies above the plane of its face, and the
    membrane beside a face is only dragged down by it: it rises from the face's edge (above the plane,
    beside the lowered edge and across the tilt), or falls away below the face where it rises out of the
    membrane, but no deeper than the face's edge next to it (the lift-off side; the membrane at rest
    lies below a plane above it). A marker below a plane that would still press into the membrane, and
    deeper than the contact beside it, was pushed by something deeper than the plane: the plane is a
    strip of the membrane's wall, and the part's real, deeper face lies beside it. On the design zoo
    (seed 0: frames 1-5 of its 50 designs and its 14 silent failures, the four ways), such a wall fitted
    beside a small or off-centre contact, 10-30 deg off, passed every check of the contact's own markers
    in 14 estimates; 7 had a hole beside, none of the other 887 estimates reported "ok" did.

    The depth below the plane is :data:`BESIDE_HOLE_THRESHOLDS` inlier thresholds (3.75 sigmas of a
    marker's height), not the :data:`HOLE_THRESHOLDS` of a hole inside the hull: beside the contact,
    the marker must also be deeper than the contact next to it, which the membrane dragged down beside a
    face never is. At 2 thresholds, a wall strip meeting a small face in a V at the dent's deepest markers
    (zoo seed 0, design 42, frame 4, size-free) left the face's five deepest markers 2.6-4.8 sigmas
    below the wall's plane and was reported "ok", 16.6 deg off. The cost, checking the contact chosen at
    1.5 (zoo seed 0, 25 designs x 4 frames, the four ways: 400 estimates per image model): one more
    suspect estimate with the bead pack's image model (1.3 deg off), three with the stirred one (3.5-14.9
    deg off, one of them its only silent failure); none within 1 deg, no error changed.
    """
    height = (points_J - plane.centroid_mm) @ plane.normal
    return _holes_beside(points_J, dent, contact, plane, height, threshold_mm, pitch_mm, depth_thresholds)


def _holes_beside(
    points_J, dent, contact, plane, height, threshold_mm, pitch_mm, depth_thresholds, outside=None
) -> np.ndarray:
    """:func:`holes_beside` with the markers' heights above the plane (mm) already computed, and the
    markers just outside the contact (:func:`just_outside`) when they are. Only the markers deep below
    the plane are looked at further (usually none or a few)."""
    out = np.zeros(len(points_J), dtype=bool)
    below = np.flatnonzero(height < -depth_thresholds * threshold_mm)
    if not len(below) or not contact.any():
        return out
    depth = _nan_as_minus_inf(dent.depth_mm)
    pressing = depth[below] + height[below] / plane.normal[2] > threshold_mm  # face_depth_mm, from heights
    below = below[pressing]
    if not len(below):
        return out
    outside = just_outside(points_J[:, :2], contact, pitch_mm) if outside is None else outside
    candidates = below[outside[below]]
    if not len(candidates):
        return out
    members = np.flatnonzero(contact)
    gap = points_J[candidates, None, :2] - points_J[None, members, :2]
    near = (
        np.hypot(gap[..., 0], gap[..., 1]) < NEIGHBOUR_RADIUS_PITCHES * pitch_mm
    )  # each has one: it is just outside
    deepest_near = np.where(near, depth[members][None, :], -np.inf).max(axis=1)
    out[candidates[depth[candidates] > deepest_near]] = True
    return out


def holes_in_the_dent(
    points_J: np.ndarray,
    dent: Indentation,
    contact: np.ndarray,
    plane: PlaneFit,
    *,
    threshold_mm: float,
    pitch_mm: float,
    plane_depth_mm: np.ndarray,
    outside: np.ndarray,
) -> np.ndarray:
    """Markers of the contact's dent, however far from the contact, that only a deeper face explains, as
    booleans: pushed in deeper than ``plane`` reaches below the unloaded membrane at any marker in or just
    outside ``contact`` (``plane_depth_mm``, :func:`face_depth_mm`; ``outside``, :func:`just_outside`),
    and lying :data:`DENT_HOLE_THRESHOLDS` inlier thresholds below the plane where it presses into the
    membrane. "Of the dent": joined to the contact through markers clearly pushed in
    (:func:`contact_candidates`) that lie within :data:`NEIGHBOUR_RADIUS_PITCHES` of each other, so a
    cluster of mismatched markers far from the part is no evidence.

    :func:`holes_beside` looks just outside the contact; this looks across the whole dent. A rigid face
    presses its dent deepest where it reaches deepest, and the membrane elsewhere is only dragged down
    by it, no deeper than the face reaches. A marker deeper than that, and under a plane that would
    still press into it, was pushed by a face that is deeper than the plane fitted: the plane is a stretch
    of the membrane's drape beside the part's edge. Beside a part tilted 17 deg on a bead pack whose walls
    slope at 20 deg (``softjig.sim.zoo.gentle_wall_model``; zoo seed 4, design 12, frame 14), a plane
    of 53 drape markers, 11 deg off, none of them in contact, passed every other check; 44 markers of its
    dent lay 1.7-9.6 pitches from them, 1.9-5.5 mm below it, up to 6.7 mm deeper than any of them.
    """
    out = np.zeros(len(points_J), dtype=bool)
    if not contact.any():
        return out
    depth = _nan_as_minus_inf(dent.depth_mm)
    reach = max(depth[contact].max(), plane_depth_mm[contact | outside].max())
    height = (points_J - plane.centroid_mm) @ plane.normal
    candidates = (
        ~contact
        & (depth > reach)
        & (height < -DENT_HOLE_THRESHOLDS * threshold_mm)
        & (plane_depth_mm > threshold_mm)
    )
    if not candidates.any():  # the usual case: the costlier test of the dent's extent is skipped
        return out
    pushed = np.flatnonzero(contact | candidates | contact_candidates(dent))
    pairs = cKDTree(points_J[pushed, :2]).query_pairs(
        NEIGHBOUR_RADIUS_PITCHES * pitch_mm, output_type="ndarray"
    )
    links = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(pushed), len(pushed)))
    _, label = connected_components(links, directed=False)
    in_the_dent = np.zeros(len(points_J), dtype=bool)
    in_the_dent[pushed] = np.isin(label, label[contact[pushed]])
    return candidates & in_the_dent


def _nan_as_minus_inf(values: np.ndarray) -> np.ndarray:
    """``np.nan_to_num(values, nan=-np.inf)`` (NaN to ``-inf``, infinities to the largest finite floats),
    returning ``values`` itself when all are finite (the usual case: the conversion costs more than the
    test)."""
    return values if np.isfinite(values).all() else np.nan_to_num(values, nan=-np.inf)


def _violations(
    points_J: np.ndarray,
    contact: np.ndarray,
    plane: PlaneFit,
    threshold_mm: float,
    max_tilt_rad: float,
    pitch_mm: float,
    dent: Indentation | None = None,
    beside_thresholds: float = HOLE_THRESHOLDS,
    outside: np.ndarray | None = None,
) -> int:
    """Markers that contradict ``plane`` being the face of ``contact`` (penetrating it, or holes in it,
    and with ``dent`` the holes beside it, ``beside_thresholds`` inlier thresholds deep), beyond the few
    that noise explains; a plane steeper than ``max_tilt_rad`` counts as the worst. With ``dent``, the
    markers of unknown depth (NaN, :func:`off_the_membrane`) are not judged."""
    if plane.normal[2] < np.cos(max_tilt_rad):
        return len(points_J) + 1
    # A marker or two of a large contact lie above the plane by noise alone (the threshold is a few
    # sigmas, one-sided): only violations beyond that count, or a smaller, wrong contact peeled off
    # the seed (fewer markers inside its hull, so fewer chances) would beat the right one.
    tolerated = max(TOLERATED_VIOLATIONS, int(TOLERATED_VIOLATION_SHARE * contact.sum()))
    # Penetration is judged inside the contact's core (its markers surrounded by contact), not its rim:
    # the growth takes in a ring of wall markers level with a deep edge, whose hull holds more wall above
    # the plane. Holes are judged in the whole hull: the membrane never falls far below a real face.
    # The markers' heights above the plane are computed once, and the core and both hull tests made in
    # one compiled pass (``_contact_kernels.violations``), only for the markers above or below.
    # Markers as far above the plane as a hole lies below it (:data:`HOLE_THRESHOLDS` thresholds, 5
    # sigmas) are not noise but mismatched markers, one or 5 % of the contact; beyond those, each counts
    # whatever else is tolerated. A ring of wall markers around a rise of membrane fits a plane that the
    # rise pierces.
    height = (points_J - plane.centroid_mm) @ plane.normal
    if dent is not None:  # a marker of unknown depth (off the membrane: a mismatch) is no evidence
        height = np.where(np.isnan(dent.depth_mm), np.nan, height)
    above = height > threshold_mm
    far_above = height > HOLE_THRESHOLDS * threshold_mm
    below = (height < -HOLE_THRESHOLDS * threshold_mm) & ~contact
    xy = np.ascontiguousarray(points_J[:, :2], dtype=float)
    count = kernels.violations(
        xy,
        contact,
        above,
        far_above,
        below,
        NEIGHBOUR_RADIUS_PITCHES * pitch_mm,
        tolerated,
        max(1, int(TOLERATED_VIOLATION_SHARE * contact.sum())),
    )
    # A hole beside the contact is 3.75-5 sigmas below a plane that would press there, and deeper than
    # the contact beside it, where the membrane can only be above it: noise does not explain one, and
    # none is tolerated.
    beside = (
        0
        if dent is None
        else int(
            _holes_beside(
                points_J, dent, contact, plane, height, threshold_mm, pitch_mm, beside_thresholds, outside
            ).sum()
        )
    )
    return count + beside


def _deep_regrowth(
    seed: np.ndarray,
    as_deep: np.ndarray,
    contact: np.ndarray,
    grow: Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, PlaneFit]],
) -> tuple[np.ndarray, PlaneFit] | None:
    """The contact grown again from ``seed`` over the markers ``as_deep`` as the seed only (``grow(eligible,
    seed)``, :func:`_grow`), where it is part of ``contact`` (grown over every marker pushed in beyond the
    noise, which markers contradict) but not all of it; else ``None`` (also where no plane grows).
    :func:`grow_contact` takes it only where no marker contradicts it.

    Why: where the membrane's drape is broad and shallow (a bead pack whose walls slope gently), the
    dome's rest shape falls through the plane of a level face along a ring far from it, and the growth
    over every pushed-in marker follows the drape out to that ring: the contact's hull then spans the
    membrane, the markers inside it that the drape holds above the plane contradict the face, and peeling
    the face off the seed leaves a strip of drape to be fitted (zoo seed 5, design 17, frame 10 with
    ``gentle_wall_model``, size-free against the reference: a 51 mm face tilted 1.6 deg, 159 markers in
    contact on a 4.6 mm grid, grew to 261 markers with 36 violations; the 101 markers fitted instead, 22
    of them in contact, were "ok" and 8.5 deg off). Kept to the seed's depth, the growth stays on the face.
    Only the same contact without its run-out is taken: a regrowth that takes in markers ``contact`` did
    not, or that markers contradict, can be a plane the deep markers alone make, and made a small
    contact's wall the best contact in zoo seed 5, design 45, frame 7 (27 deg off, "ok";
    benchmarks/RESULTS.md)."""
    try:
        deep = grow(as_deep, seed)
    except EstimationError:
        return None
    return deep if not (deep[0] & ~contact).any() and deep[0].sum() < contact.sum() else None


def _grow(points_J, eligible, seed, pitch_mm, fit_plane, threshold_mm, max_rounds):
    """Alternate the robust fit of the contact and its growth over the connected markers on the plane.

    Each round's growth is a flood fill (``_contact_kernels.flood``): every eligible marker on the plane
    connected to the fit's inliers by steps of at most 1.5 pitches joins at once, so the rounds do not grow
    with the contact's radius (one ring per round made the cost grow as ``N^1.5`` with the contact's
    markers).
    """
    xy = np.ascontiguousarray(points_J[:, :2], dtype=float)
    contact = seed.copy()
    plane = None
    for _ in range(max_rounds):
        inliers, plane = fit_plane(points_J[contact])
        kept = np.zeros_like(contact)
        kept[np.flatnonzero(contact)[inliers]] = True
        on_plane = np.abs((points_J - plane.centroid_mm) @ plane.normal) < threshold_mm
        grown = (
            kernels.flood(xy, kept, on_plane & eligible, NEIGHBOUR_RADIUS_PITCHES * pitch_mm)
            if kept.any()
            else kept
        )
        if np.array_equal(grown, contact):
            break
        contact = grown
    return contact, plane


def face_depth_mm(points_J: np.ndarray, dent: Indentation, plane: PlaneFit) -> np.ndarray:
    """How deep ``plane`` (the part's face) lies below the unloaded membrane at each marker (mm; NaN-free,
    ``-inf`` where the indentation is unknown): the marker's indentation minus its gap below the plane."""
    # Compiled, the same arithmetic as PlaneFit.heights_mm (this runs 4-6 times per estimate).
    return kernels.face_depth(
        np.ascontiguousarray(points_J, dtype=float),
        np.ascontiguousarray(dent.depth_mm, dtype=float),
        np.ascontiguousarray(plane.normal, dtype=float),
        float(plane.offset_mm),
    )


def under_face(
    points_J: np.ndarray, plane: PlaneFit, radius_mm: float, centre_xy_mm: tuple[float, float] = (0.0, 0.0)
) -> np.ndarray:
    """Which markers' vertical projections onto ``plane`` lie within ``radius_mm`` of the plane's point
    above ``centre_xy_mm`` (under a face of that radius centred there; the jig axis by default), as
    booleans.

    The same arithmetic as :meth:`~softjig.geometry.PlaneFit.heights_mm` and a 3-D norm.
    """
    cx, cy = (float(v) for v in centre_xy_mm)
    n0, n1, n2 = (float(v) for v in plane.normal)
    x, y = points_J[:, 0], points_J[:, 1]
    dz = -(float(plane.offset_mm) + n0 * x + n1 * y) / n2 - plane.z_at(cx, cy)
    dx, dy = x - cx, y - cy
    return np.sqrt(dx * dx + dy * dy + dz * dz) < float(radius_mm)


def ambiguous_selection(
    points_J: np.ndarray,
    dent: Indentation,
    used: np.ndarray,
    dropped: np.ndarray,
    plane: PlaneFit,
    *,
    clearance_mm: float,
    margin_mm: float,
    face_depth: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """The narrowest and widest contacts that the noise allows near the lift-off line.

    :func:`drop_lifted_off` decides each marker by its face depth against ``clearance_mm``; those within
    ``margin_mm`` of it (one noise sigma) could have gone either way. Returns ``(narrow, wide)``: ``used``
    without its doubtful markers, and ``used`` with the doubtful ones of ``dropped``. The spread of their
    planes is the part of the error that the residuals do not show. ``face_depth``: the markers'
    :func:`face_depth_mm` for ``plane``, when already computed.
    """
    depth = face_depth_mm(points_J, dent, plane) if face_depth is None else face_depth
    narrow = used & (depth > clearance_mm + margin_mm)
    wide = used | (dropped & (depth > clearance_mm - margin_mm))
    return narrow, wide


def drop_lifted_off(
    points_J: np.ndarray,
    dent: Indentation,
    used: np.ndarray,
    plane: PlaneFit,
    *,
    clearance_mm: float,
    fit_plane,
    min_points: int = 6,
    max_rounds: int = 15,
) -> tuple[np.ndarray, PlaneFit]:
    """Drop the markers where the face would not reach down into the membrane, and fit again.

    The part touches the membrane only where its face lies below the unloaded membrane. At each marker
    the face's depth below it is the marker's indentation minus its gap below the fitted plane
    (``depth - (plane_z - z)``). Where a tilted part lifts off, the membrane it drags down stays just
    below the face, within the inlier band of any fit, and flattens the plane: those markers have a face
    depth near zero (or negative), the markers in contact one near their own indentation. Markers whose
    face depth is below ``clearance_mm`` are dropped and the plane fitted again, until nothing changes;
    each refit steepens the plane, which uncovers more of the lift-off side (the gain on tilted large
    parts is in ``benchmarks/RESULTS.md``).

    Parameters
    ----------
    points_J : (M, 3) the markers (mm, J).
    dent : their indentations.
    used : (M,) the contact found so far.
    plane : its plane.
    clearance_mm : the least depth of the face below the unloaded membrane at a marker in contact (mm).
    fit_plane : ``fit_plane(points) -> PlaneFit``.
    min_points : never keep fewer markers than this.

    Returns
    -------
    (used, plane) : the contact markers that remain, and their plane.
    """
    for _ in range(max_rounds):
        keep = used & (face_depth_mm(points_J, dent, plane) > clearance_mm)
        if keep.sum() < min_points or np.array_equal(keep, used):
            break
        used = keep
        plane = fit_plane(points_J[used])
    return used, plane


@dataclass(frozen=True)
class ContactRegion:
    """Where the part touches the membrane.

    Attributes
    ----------
    area_mm2 : footprint area (mm^2).
    centroid_xy_mm : footprint centroid ``(x, y)`` in J (mm): the part's position on the jig.
    outline_xy_mm : (K, 2) footprint outline in J, counter-clockwise (mm).
    partial : whether the part lifts off on some side.
    lift_azimuth_deg : azimuth (from J's ``+x`` towards ``+y``) of the side that lifts off, or ``None``.
    edge_clearance_mm : the least indentation of the fitted plane at the footprint's edge (mm): about
        zero where the part lifts off, the push depth where the part's edge bounds the contact.
    """

    area_mm2: float
    centroid_xy_mm: tuple[float, float]
    outline_xy_mm: np.ndarray
    partial: bool
    lift_azimuth_deg: float | None
    edge_clearance_mm: float


def _hull_indices(xy: np.ndarray) -> np.ndarray:
    """Indices of the convex hull's vertices of (N >= 3, 2) points, counter-clockwise (``x`` right, ``y``
    up). ``cv2.convexHull`` on float32 copies (mm, so rounding of 1e-5 mm at most), cheaper than
    ``scipy.spatial.ConvexHull`` (Qhull)."""
    return cv2.convexHull(xy.astype(np.float32), clockwise=False, returnPoints=False).ravel()


def describe_contact(
    contact_xy_mm: np.ndarray,
    plane: PlaneFit,
    jig: JigConfig,
    *,
    noise_mm: float,
    part_diameter_mm: float | None = None,
    edge_face_depth_mm: np.ndarray | None = None,
) -> ContactRegion:
    """The footprint of the contact markers and whether the contact is partial.

    Parameters
    ----------
    contact_xy_mm : (N, 2) ``(x, y)`` of the markers in contact (mm, J).
    plane : the plane fitted to them (its height is compared with the rest membrane).
    jig : the nominal jig (marker pitch, rest shape).
    noise_mm : the indentation noise: a plane within ``max(3 noise, 0.3 mm)`` of the rest membrane at
        the footprint's edge counts as lifting off.
    part_diameter_mm : when known, a footprint under 70 % of the part's base also counts as partial.
    edge_face_depth_mm : the face depths (:func:`face_depth_mm`) of the markers just outside the contact
        (within 1.5 pitches of it), when known: the plane's clearance at the footprint's edge is then
        their least, measured against the unloaded membrane's own markers (the reference frame), rather
        than the nominal rest shape half a pitch beyond the hull, which a depth bias of the cameras or
        an as-built membrane shifts.
    """
    half_pitch = jig.markers.pitch_mm / 2.0
    xy = np.asarray(contact_xy_mm, dtype=float)
    hull = xy[_hull_indices(xy)] if len(xy) >= 3 else xy  # all on a line: its two ends
    if len(hull) >= 3:  # the usual case, compiled
        hull_area, centroid, perimeter, edge = kernels.footprint(np.ascontiguousarray(hull), half_pitch)
    else:
        hull_area, centroid = 0.0, xy.mean(axis=0)
        perimeter = (
            float(np.linalg.norm(np.roll(hull, -1, axis=0) - hull, axis=1).sum()) if len(hull) > 1 else 0.0
        )
        # The footprint's edge: each hull vertex moved out by half a pitch, away from the centroid.
        outward = hull - centroid
        norms = np.linalg.norm(outward, axis=1, keepdims=True)
        edge = hull + half_pitch * np.divide(outward, norms, out=np.zeros_like(outward), where=norms > 0)
    area = hull_area + perimeter * half_pitch + np.pi * half_pitch**2

    def clearance_at_edge() -> np.ndarray:  # the rest membrane above the plane at the edge (mm)
        plane_z = plane.heights_mm(edge[:, 0], edge[:, 1])
        return rest_inner_height_mm(jig, edge[:, 0], edge[:, 1]) - plane_z

    # The clearance is computed only where needed.
    clearance = None
    tolerance = max(LIFT_NOISE_SIGMAS * noise_mm, MIN_LIFT_CLEARANCE_MM)
    if edge_face_depth_mm is not None and len(edge_face_depth_mm):
        edge_clearance = float(np.min(edge_face_depth_mm))
    else:
        clearance = clearance_at_edge()
        edge_clearance = float(clearance[int(np.argmin(clearance))])
    lifts = edge_clearance < tolerance
    small = part_diameter_mm is not None and area < PARTIAL_AREA_SHARE * np.pi * (part_diameter_mm / 2.0) ** 2
    lift_azimuth = None
    if lifts or small:
        # The side that lifts off: a flat face rises towards the plane's uphill direction, -(n_x, n_y);
        # for a nearly level plane, the middle of the footprint's edge where the plane meets the membrane
        # (a chord across the part), seen from the centroid.
        uphill = -plane.normal[:2]
        if np.hypot(*uphill) > np.sin(np.radians(LEVEL_PLANE_DEG)):
            direction = uphill
        else:
            clearance = clearance_at_edge() if clearance is None else clearance
            lowest = int(np.argmin(clearance))
            low = clearance < tolerance if lifts else clearance <= clearance[lowest]
            if not low.any():  # the lift-off was seen just outside the outline, not on it: its lowest point
                low = clearance <= clearance[lowest]
            direction = edge[low].mean(axis=0) - centroid
        lift_azimuth = float(np.degrees(np.arctan2(direction[1], direction[0])) % 360.0)
    return ContactRegion(
        area_mm2=float(area),
        centroid_xy_mm=(float(centroid[0]), float(centroid[1])),
        outline_xy_mm=edge,
        partial=bool(lifts or small),
        lift_azimuth_deg=lift_azimuth,
        edge_clearance_mm=edge_clearance,
    )


def face_centre_xy(
    contact_xy_mm: np.ndarray, region: ContactRegion, plane: PlaneFit, radius_mm: float, *, pitch_mm: float
) -> tuple[float, float]:
    """Where the centre of the part's face (a disc of known radius) lies on the jig, ``(x, y)`` in J (mm).

    In full contact the footprint is the whole face, and its centroid is the face's centre. In partial
    contact the footprint's centroid lies on the lowered side: the face's rim still bounds the contact
    downhill, so the centre is one radius uphill of that rim. The rim lies beyond the outermost contact
    markers by half a pitch on average (the next marker out is not in contact); distances along the
    tilt are shortened by ``n_z`` in the horizontal ``(x, y)``. Across the tilt, the footprint is
    symmetric about the centre, and its centroid's coordinate is kept.

    Parameters
    ----------
    contact_xy_mm : (N, 2) ``(x, y)`` of the markers in contact (mm, J).
    region : their footprint (:func:`describe_contact`).
    plane : their plane.
    radius_mm : the radius of the part's face (mm).
    pitch_mm : the markers' pitch (mm).
    """
    centroid = np.asarray(region.centroid_xy_mm, dtype=float)
    normal = plane.normal
    slope = float(np.hypot(normal[0], normal[1]))
    if not region.partial or slope < LEVEL_SLOPE:
        return (float(centroid[0]), float(centroid[1]))
    downhill = normal[:2] / slope  # the plane is lowest towards +(n_x, n_y)
    along_in_plane = (np.asarray(contact_xy_mm, dtype=float) - centroid) @ downhill / normal[2]
    rim = float(along_in_plane.max()) + pitch_mm / 2.0
    centre = centroid + (rim - radius_mm) * normal[2] * downhill
    return (float(centre[0]), float(centre[1]))


@dataclass(frozen=True)
class FootprintMisfit:
    """How far the markers under a face are from what the face makes of the membrane
    (:func:`footprint_misfit`).

    Attributes
    ----------
    sum_squares : the sum of the markers' squared misfits, in units of the indentation noise (each
        capped at :data:`FOOTPRINT_MISFIT_CAP_SIGMAS`).
    n_markers : how many markers lie under the face.
    """

    sum_squares: float
    n_markers: int

    @property
    def rms_sigmas(self) -> float:
        """The RMS misfit (noise sigmas); ``inf`` when no marker lies under the face."""
        return math.sqrt(self.sum_squares / self.n_markers) if self.n_markers else math.inf

    def fits_better_than(self, other: FootprintMisfit) -> bool:
        """Whether this face fits the membrane under it better than ``other`` does: the smaller RMS misfit,
        each taken as at least the noise's own (1 sigma: a misfit within the noise is no evidence, and two
        faces that both fit within it are a tie). A face with no marker under it is no evidence either
        way."""
        if not (self.n_markers and other.n_markers):
            return False
        return max(self.rms_sigmas, 1.0) < max(other.rms_sigmas, 1.0)


def footprint_misfit(
    points_J: np.ndarray,
    dent: Indentation,
    contact: np.ndarray,
    plane: PlaneFit,
    radius_mm: float,
    jig: JigConfig,
    *,
    noise_mm: float,
) -> FootprintMisfit:
    """How far the markers under a face of ``radius_mm`` on ``plane``, placed where ``contact`` puts it
    (:func:`face_centre_xy`), are from what such a face makes of the membrane.

    A rigid face presses the membrane to its plane wherever the plane lies below the unloaded membrane,
    and leaves it at rest wherever it lies above (nothing else presses it there, and the jammed beads
    hold it): each marker under the face is predicted at ``max(face depth, 0)``
    (:func:`face_depth_mm`), and its misfit is its indentation's distance from that, in units of
    ``noise_mm``. Where two contacts of a frame are both plausible (the part's face and a strip of the
    membrane's wall beside its lowered edge, which meet in a V), the wall's plane, given the part's
    radius and placed uphill of its lowered edge, predicts the membrane pressed where it lies at rest, or
    at rest where the face presses it. The model leaves out the membrane's sag below a face near its
    lift-off line and the rim's placement (uncertain by half a pitch), so the face's own misfit is often
    a few sigmas too: alone, it tells the two apart no better than a coin (benchmarks/RESULTS.md).

    Parameters
    ----------
    points_J : (M, 3) the markers (mm, J).
    dent : their indentation.
    contact : (M,) the contact's markers (booleans), which place the face.
    plane : the contact's plane.
    radius_mm : the radius of the part's face (mm).
    jig : the nominal jig (marker pitch, rest shape).
    noise_mm : the indentation noise (mm, > 0).
    """
    xy = points_J[contact, :2]
    region = describe_contact(xy, plane, jig, noise_mm=noise_mm, part_diameter_mm=2.0 * radius_mm)
    centre = face_centre_xy(xy, region, plane, radius_mm, pitch_mm=jig.markers.pitch_mm)
    under = under_face(points_J, plane, radius_mm, centre) & np.isfinite(dent.depth_mm)
    predicted = np.maximum(face_depth_mm(points_J, dent, plane)[under], 0.0)
    misfit = np.minimum(np.abs(dent.depth_mm[under] - predicted) / noise_mm, FOOTPRINT_MISFIT_CAP_SIGMAS)
    return FootprintMisfit(float(misfit @ misfit), int(under.sum()))


def just_outside(xy_mm: np.ndarray, contact: np.ndarray, pitch_mm: float) -> np.ndarray:
    """The markers not in the contact within 1.5 pitches of one that is, as booleans."""
    if not contact.any():
        return np.zeros(len(xy_mm), dtype=bool)
    return _near(xy_mm, contact, NEIGHBOUR_RADIUS_PITCHES * pitch_mm) & ~contact
