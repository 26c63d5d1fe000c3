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
penetrates it inside the contact, none lies far below it inside the contact's hull (:func:`holes`), and
none beside the contact lies deep below it where it would still press into the membrane, deeper than the
contact next to it (:func:`holes_beside`: the part's real face beside a strip of wall fitted instead).

The **footprint** of the contact is the convex hull of the contact markers dilated by half a marker pitch
(each marker stands for one cell of the grid; by Steiner's formula the area grows by
``perimeter * p / 2 + pi (p / 2)^2``). Contact is **partial** when, on some side, the fitted plane rises to
the rest membrane within the footprint: there the part lifts off, rather than ending at its edge with the
membrane draped down from it.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numba
import numpy as np

from softjig.config import JigConfig
from softjig.errors import EstimationError
from softjig.geometry import PlaneFit, _inside_hull_kernel, inside_convex_hull_xy
from softjig.jig_shape import rest_inner_height_mm

#: Seeds of :func:`grow_contact`, in the order tried: the candidates indented at least this share of the
#: deepest tenth's depth.
SEED_DEPTH_SHARES = (0.5, 0.75, 0.25)
#: A marker out of the contact lying this many inlier thresholds below the plane, inside the contact's
#: hull, is a hole: no face pressed into the membrane leaves one (:func:`holes`). So is one just outside
#: the contact where the plane would press into the membrane (:func:`holes_beside`).
HOLE_THRESHOLDS = 2.0
_LARGEST = float(np.finfo(float).max)


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
    Noise: the indentation field is smooth (planar under a face, a gently curved drape around it, flat at
    rest), so a marker's indentation minus the mean of its neighbours' (within 1.5 pitches) is noise,
    of variance ``sigma^2 (1 + 1 / k)`` for ``k`` neighbours, except at the few kinks (the contact's
    edge), which a median ignores. Without the pitch, the noise is the spread of the markers indented
    less than the median, which assumes that at least half the markers are at rest: a part that drags
    most of the membrane down (80 mm at 20 deg) inflates it two- to three-fold.
    Zero: the median raw indentation of the markers within 2.5 sigma of it (iterated from the median of
    all), which also absorbs a uniform depth bias of an imperfectly calibrated camera pair.
    """
    if pitch_mm:  # the usual case, in one compiled pass (0.1 ms of NumPy calls, measured)
        depth, zero, noise = _indentation_kernel(
            np.ascontiguousarray(points_J, dtype=float),
            np.ascontiguousarray(reference_z_mm, dtype=float),
            1.5 * pitch_mm,
        )
        if noise > 0:
            return Indentation(depth, float(zero), float(noise))
    raw = np.asarray(reference_z_mm, dtype=float) - points_J[:, 2]
    finite = np.isfinite(raw)
    if not finite.any():
        return Indentation(np.full(len(raw), np.nan), 0.0, float("nan"))
    raw_finite = raw[finite]
    neighbour_noise = _neighbour_noise(points_J[finite, :2], raw_finite, pitch_mm) if pitch_mm else None
    zero = float(np.median(raw_finite))
    noise = float("nan")
    for _ in range(5):
        if neighbour_noise is not None:
            noise = neighbour_noise
        else:
            # A part only pushes markers in, never out, so the markers indented less than the median are
            # at rest however many the part displaced: the noise is the spread of that side.
            low = finite & (raw <= zero)
            noise = max(float(1.4826 * np.median(zero - raw[low])), 1e-6) if low.any() else 1e-6
        at_rest = finite & (np.abs(raw - zero) < 2.5 * noise)
        new_zero = float(np.median(raw[at_rest])) if at_rest.sum() >= 3 else zero
        if abs(new_zero - zero) < 1e-3 * noise:
            break
        zero = new_zero
    return Indentation(raw - zero, zero, noise)


@numba.njit(cache=True)
def _indentation_kernel(
    points: np.ndarray, reference_z: np.ndarray, radius: float
) -> tuple[np.ndarray, float, float]:
    """:func:`indentation` with the neighbour noise: ``(depth, zero, noise)``, or ``noise = -1`` when
    no marker is finite or too few have neighbours (the caller then takes the other way)."""
    n = points.shape[0]
    raw = np.empty(n)
    finite = np.empty(n, dtype=np.bool_)
    m = 0
    for i in range(n):
        raw[i] = reference_z[i] - points[i, 2]
        finite[i] = np.isfinite(raw[i])
        m += finite[i]
    if m < 10:
        return raw, 0.0, -1.0
    xy = np.empty((m, 2))
    raw_finite = np.empty(m)
    k = 0
    for i in range(n):
        if finite[i]:
            xy[k, 0], xy[k, 1], raw_finite[k] = points[i, 0], points[i, 1], raw[i]
            k += 1
    residual, enough = _neighbour_residuals(xy, raw_finite, radius, 8)
    if enough < 10:
        return raw, 0.0, -1.0
    noise = max(1.4826 * np.median(np.abs(residual[:enough])), 1e-6)
    zero = _settle_zero(raw_finite, noise, 5)
    return raw - zero, zero, noise


@numba.njit(cache=True)
def _settle_zero(raw: np.ndarray, noise: float, rounds: int) -> float:
    """The zero of :func:`indentation` for a known noise: from the median of all values, the median of
    the values within 2.5 noise sigmas of it, iterated until it moves by less than 1e-3 sigma."""
    zero = np.median(raw)
    for _ in range(rounds):
        at_rest = raw[np.abs(raw - zero) < 2.5 * noise]
        new_zero = np.median(at_rest) if at_rest.shape[0] >= 3 else zero
        if abs(new_zero - zero) < 1e-3 * noise:
            break
        zero = new_zero
    return zero


def _neighbour_noise(xy: np.ndarray, raw: np.ndarray, pitch_mm: float) -> float | None:
    """Robust sigma of each value minus its neighbours' mean, scaled by ``1 / sqrt(1 + 1/k)``."""
    if len(xy) < 10:
        return None
    # The 8 nearest within 1.5 pitches: a square grid's 4 edge and 4 diagonal neighbours. Compiled
    # (:func:`_neighbour_residuals`, a sweep over the markers sorted by x): the k-d tree's k-nearest query
    # and the NumPy reductions took 0.3-0.4 ms, measured; this, 20 us.
    residual, enough = _neighbour_residuals(
        np.ascontiguousarray(xy, dtype=float), np.ascontiguousarray(raw, dtype=float), 1.5 * pitch_mm, 8
    )
    if enough < 10:
        return None
    return max(float(1.4826 * _median_abs(residual[:enough])), 1e-6)


@numba.njit(cache=True)
def _median_abs(values: np.ndarray) -> float:
    """``np.median(np.abs(values))``, compiled (NumPy's took 20-30 us on 300 values, measured)."""
    return np.median(np.abs(values))


@numba.njit(cache=True)
def _x_window(xs: np.ndarray, x: float, radius: float) -> tuple[int, int]:
    """The slice of the ascending ``xs`` within ``radius`` (and a hair) of ``x``."""
    slack = radius * (1.0 + 1e-9)
    return np.searchsorted(xs, x - slack), np.searchsorted(xs, x + slack, side="right")


@numba.njit(cache=True)
def _grid_cells(xy: np.ndarray, radius: float):
    """Bin (N, 2) points into square cells of side ``radius`` (so each point's neighbours closer than
    ``radius`` lie in its own and the 8 adjacent cells): each point's cell ``(cx, cy)``, the grid's size
    ``(nx, ny)``, and the points of cell ``c = cx * ny + cy`` as ``members[start[c]:start[c + 1]]``."""
    n = xy.shape[0]
    x0, y0 = xy[:, 0].min(), xy[:, 1].min()
    nx = int((xy[:, 0].max() - x0) / radius) + 1
    ny = int((xy[:, 1].max() - y0) / radius) + 1
    cx = np.empty(n, dtype=np.int64)
    cy = np.empty(n, dtype=np.int64)
    start = np.zeros(nx * ny + 1, dtype=np.int64)
    for i in range(n):
        cx[i] = min(int((xy[i, 0] - x0) / radius), nx - 1)
        cy[i] = min(int((xy[i, 1] - y0) / radius), ny - 1)
        start[cx[i] * ny + cy[i] + 1] += 1
    for c in range(nx * ny):
        start[c + 1] += start[c]
    fill = start[:-1].copy()
    members = np.empty(n, dtype=np.int64)
    for i in range(n):
        c = cx[i] * ny + cy[i]
        members[fill[c]] = i
        fill[c] += 1
    return cx, cy, nx, ny, start, members


@numba.njit(cache=True)
def _neighbour_residuals(
    xy: np.ndarray, raw: np.ndarray, radius: float, k_max: int
) -> tuple[np.ndarray, int]:
    """For each point with at least 3 others closer than ``radius`` (at most its ``k_max`` nearest):
    its value minus their mean, over ``sqrt(1 + 1/k)``; the first ``count`` entries, in point order.

    The points are binned into square cells of side ``radius``, so each one's neighbours lie in its own
    and the 8 adjacent cells (half the candidates of a sweep along ``x``, measured 2x faster).
    """
    n = xy.shape[0]
    cx, cy, nx, ny, start, members = _grid_cells(xy, radius)
    r2 = radius * radius
    residual = np.empty(n)
    count = 0
    d2s = np.empty(n)
    idx = np.empty(n, dtype=np.int64)
    for i in range(n):
        m = 0
        for gx in range(max(cx[i] - 1, 0), min(cx[i] + 2, nx)):
            for gy in range(max(cy[i] - 1, 0), min(cy[i] + 2, ny)):
                c = gx * ny + gy
                for s in range(start[c], start[c + 1]):
                    j = members[s]
                    if j == i:
                        continue
                    dx, dy = xy[j, 0] - xy[i, 0], xy[j, 1] - xy[i, 1]
                    d2 = dx * dx + dy * dy
                    if d2 < r2:
                        d2s[m] = d2
                        idx[m] = j
                        m += 1
        if m < 3:
            continue
        total = 0.0
        if m > k_max:
            nearest = np.argsort(d2s[:m], kind="mergesort")[:k_max]
            for q in nearest:
                total += raw[idx[q]]
            m = k_max
        else:
            for q in range(m):
                total += raw[idx[q]]
        residual[count] = (raw[i] - total / m) / np.sqrt(1.0 + 1.0 / m)
        count += 1
    return residual, count


@numba.njit(cache=True)
def _count_within(query: np.ndarray, points: np.ndarray, radius: float, inclusive: bool) -> np.ndarray:
    """How many of ``points`` lie within ``radius`` of each ``query`` point (``<=`` when ``inclusive``,
    else ``<``, as a k-d tree's ``query_ball_point`` and ``distance_upper_bound``)."""
    order = np.argsort(points[:, 0], kind="mergesort")
    xs = points[order, 0]
    r2 = radius * radius
    counts = np.zeros(query.shape[0], dtype=np.int64)
    for i in range(query.shape[0]):
        lo, hi = _x_window(xs, query[i, 0], radius)
        for s in range(lo, hi):
            j = order[s]
            dx, dy = points[j, 0] - query[i, 0], points[j, 1] - query[i, 1]
            d2 = dx * dx + dy * dy
            if d2 <= r2 if inclusive else d2 < r2:
                counts[i] += 1
    return counts


def _near(xy: np.ndarray, members: np.ndarray, radius: float) -> np.ndarray:
    """Which ``xy`` lie closer than ``radius`` to one of ``xy[members]``, as booleans (what a k-d tree's
    query with ``distance_upper_bound`` finds; compiled: 10 us instead of 0.1-0.2 ms, measured)."""
    xy = np.ascontiguousarray(xy, dtype=float)
    return _count_within(xy, xy[members], float(radius), False) > 0


def contact_candidates(dent: Indentation, *, sigmas: float = 4.0, min_depth_mm: float = 0.3) -> np.ndarray:
    """Markers indented beyond ``max(sigmas x noise, min_depth_mm)``, as booleans."""
    threshold = max(sigmas * dent.noise_mm, min_depth_mm) if np.isfinite(dent.noise_mm) else min_depth_mm
    return dent.depth_mm > threshold  # False where NaN, as -inf would be


def penetrating(
    points_J: np.ndarray, contact: np.ndarray, plane: PlaneFit, threshold_mm: float
) -> np.ndarray:
    """Markers that would penetrate the part if ``plane`` were its face: more than ``threshold_mm`` above
    the plane (into the part) with ``(x, y)`` inside the contact's convex hull, as booleans."""
    above = (points_J - plane.centroid_mm) @ plane.normal > threshold_mm
    return above & _inside_hull(points_J[:, :2], contact)


def holes(points_J: np.ndarray, contact: np.ndarray, plane: PlaneFit, depth_mm: float) -> np.ndarray:
    """Markers out of the contact, more than ``depth_mm`` below ``plane``, inside the contact's convex hull.

    A face pressed into the membrane touches it everywhere inside its footprint except near the line where
    it lifts off, where the membrane falls away only gradually: a marker deep below the plane in the
    middle of the footprint means that the plane is not the face (e.g. a ring of membrane wall around
    the real, deeper contact).
    """
    below = (points_J - plane.centroid_mm) @ plane.normal < -depth_mm
    return below & ~contact & _inside_hull(points_J[:, :2], contact)


def _inside_hull(xy: np.ndarray, contact: np.ndarray) -> np.ndarray:
    """Which ``(x, y)`` lie inside the convex hull of the contact's, as booleans (none for < 3 markers, or
    all on a line). A compiled hull test (:func:`~softjig.geometry.inside_convex_hull_xy`): it matches
    ``Delaunay(xy[contact]).find_simplex(xy) >= 0``, which took up to 7 ms per call (measured)."""
    if contact.sum() < 3:
        return np.zeros(len(xy), dtype=bool)
    return inside_convex_hull_xy(xy[contact], xy)


def grow_contact(
    points_J: np.ndarray,
    dent: Indentation,
    candidates: np.ndarray,
    *,
    pitch_mm: float,
    fit_plane,
    threshold_mm: float,
    min_points: int = 6,
    max_tilt_rad: float = np.radians(45.0),
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
    3. **Check.** No marker may lie above the face inside the contact (:func:`penetrating`), nor far
       below it (:func:`holes`), beyond a few that noise explains (2, or 5 % of the contact): the wall
       just outside a deeply pressed edge is as deep as the contact and can win the seed's fit, but its
       plane leaves the real contact markers above it; a ring of wall around a deep contact leaves them
       below it. Such a plane's markers are peeled off the seed and the rest is fitted again (at most
       twice), then the next seed is tried; the first contact without violations is taken, else the one
       with the fewest. A plane tilted beyond ``max_tilt_rad`` (no part pressed into a soft jig stands so
       steep: it is a line of markers on the membrane's wall) counts as the worst.

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
    depth = np.nan_to_num(dent.depth_mm, nan=-np.inf)
    deepest = float(np.percentile(depth[candidates], 90)) if candidates.any() else 0.0
    seeds: list[np.ndarray] = []
    for share in SEED_DEPTH_SHARES:
        seed = candidates & (depth >= share * deepest)
        if seed.sum() >= min_points and not any(np.array_equal(seed, other) for other in seeds):
            seeds.append(seed)
    best: tuple[int, np.ndarray, PlaneFit] | None = None
    failure: EstimationError | None = None
    for seed in seeds or [candidates.copy()]:
        for _ in range(3):
            try:
                contact, plane = _grow(
                    points_J, depth > dent.noise_mm, seed, pitch_mm, fit_plane, threshold_mm, max_rounds
                )
            except EstimationError as exc:  # no plane in what is left of this seed: try the next
                failure = exc
                break
            violations = _violations(points_J, contact, plane, threshold_mm, max_tilt_rad, pitch_mm, dent)
            if best is None or violations < best[0]:
                best = (violations, contact, plane)
            if violations == 0:
                return contact, plane
            remaining = seed & ~contact
            if remaining.sum() < min_points:
                break
            seed = remaining
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
    max_tilt_rad: float = np.radians(45.0),
    dent: Indentation | None = None,
) -> int:
    """How many markers contradict ``plane`` being the face of ``contact`` beyond the few that noise
    explains: penetrating it inside the contact's core, or holes far below it inside its hull
    (:func:`grow_contact`'s check, step 3), and, when the indentations ``dent`` are given, every hole
    beside the contact (:func:`holes_beside`); a plane steeper than ``max_tilt_rad`` counts as the
    worst."""
    if contact.sum() < 3:
        return 0
    return _violations(points_J, contact, plane, threshold_mm, max_tilt_rad, pitch_mm, dent)


def holes_beside(
    points_J: np.ndarray,
    dent: Indentation,
    contact: np.ndarray,
    plane: PlaneFit,
    *,
    threshold_mm: float,
    pitch_mm: float,
) -> np.ndarray:
    """Markers just outside the contact (within 1.5 pitches of it) that lie more than
    :data:`HOLE_THRESHOLDS` inlier thresholds below ``plane`` where the plane would press into the
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
    """
    height = (points_J - plane.centroid_mm) @ plane.normal
    return _holes_beside(points_J, dent, contact, plane, height, threshold_mm, pitch_mm)


def _holes_beside(points_J, dent, contact, plane, height, threshold_mm, pitch_mm) -> np.ndarray:
    """:func:`holes_beside` with the markers' heights above the plane (mm) already computed."""
    out = np.zeros(len(points_J), dtype=bool)
    below = height < -HOLE_THRESHOLDS * threshold_mm
    if not below.any() or not contact.any():
        return out
    depth = np.nan_to_num(dent.depth_mm, nan=-np.inf)
    pressing = depth + height / plane.normal[2] > threshold_mm  # face_depth_mm, from the heights
    candidates = np.flatnonzero(below & pressing & just_outside(points_J[:, :2], contact, pitch_mm))
    if not len(candidates):
        return out
    members = np.flatnonzero(contact)
    gap = points_J[candidates, None, :2] - points_J[None, members, :2]
    near = np.hypot(gap[..., 0], gap[..., 1]) < 1.5 * pitch_mm  # each has one: it is just outside
    deepest_near = np.where(near, depth[members][None, :], -np.inf).max(axis=1)
    out[candidates[depth[candidates] > deepest_near]] = True
    return out


def _violations(
    points_J: np.ndarray,
    contact: np.ndarray,
    plane: PlaneFit,
    threshold_mm: float,
    max_tilt_rad: float,
    pitch_mm: float,
    dent: Indentation | None = None,
) -> int:
    """Markers that contradict ``plane`` being the face of ``contact`` (penetrating it, or holes in it,
    and with ``dent`` the holes beside it), beyond the few that noise explains; a plane steeper than
    ``max_tilt_rad`` counts as the worst."""
    if plane.normal[2] < np.cos(max_tilt_rad):
        return len(points_J) + 1
    # A marker or two of a large contact lie above the plane by noise alone (the threshold is a few
    # sigmas, one-sided): only violations beyond that count, or a smaller, wrong contact peeled off
    # the seed (fewer markers inside its hull, so fewer chances) would beat the right one.
    tolerated = max(2, int(0.05 * contact.sum()))
    # Penetration is judged inside the contact's core (its markers surrounded by contact), not its rim:
    # the growth takes in a ring of wall markers level with a deep edge, whose hull holds more wall above
    # the plane. Holes are judged in the whole hull: the membrane never falls far below a real face.
    # :func:`penetrating` (in the core) and :func:`holes` (in the hull), fused: the markers' heights above
    # the plane computed once, and the core and both hull tests in one compiled pass, made only for the
    # markers above or below (same counts; 45 us in eleven NumPy and compiled calls, measured).
    height = (points_J - plane.centroid_mm) @ plane.normal
    above = height > threshold_mm
    below = (height < -HOLE_THRESHOLDS * threshold_mm) & ~contact
    xy = np.ascontiguousarray(points_J[:, :2], dtype=float)
    count = _violations_kernel(xy, contact, above, below, 1.5 * pitch_mm)
    # A hole beside the contact is 5 depth-noise sigmas below a plane that would press there, where the
    # membrane can only be above it: noise does not explain one, and none is tolerated.
    beside = (
        0
        if dent is None
        else int(_holes_beside(points_J, dent, contact, plane, height, threshold_mm, pitch_mm).sum())
    )
    return max(0, count - tolerated) + beside


@numba.njit(cache=True)
def _violations_kernel(
    xy: np.ndarray, contact: np.ndarray, above: np.ndarray, below: np.ndarray, radius: float
) -> int:
    """How many markers are ``above`` inside the hull of the contact's core (:func:`_core` with
    ``radius`` = 1.5 pitches) plus how many are ``below`` inside the contact's hull (as
    :func:`penetrating` and :func:`holes` with :func:`_inside_hull`; a marker is never both)."""
    index = np.flatnonzero(contact)
    members = xy[index]
    count = 0
    upper = np.flatnonzero(above)
    if len(upper) and len(index) >= 3:
        counts = _count_within(members, members, radius, True) - 1
        core = index[counts >= 4]
        if len(core) < 3:
            core = index
        count += int(_inside_hull_kernel(xy[core], xy[upper], 1e-9).sum())
    lower = np.flatnonzero(below)
    if len(lower) and len(index) >= 3:
        count += int(_inside_hull_kernel(members, xy[lower], 1e-9).sum())
    return count


def _core(xy: np.ndarray, contact: np.ndarray, pitch_mm: float, min_neighbours: int = 4) -> np.ndarray:
    """The contact markers with at least ``min_neighbours`` contact markers within 1.5 pitches (all of
    them if fewer than 3 are)."""
    index = np.flatnonzero(contact)
    members = np.ascontiguousarray(xy[index], dtype=float)
    counts = _count_within(members, members, 1.5 * pitch_mm, True) - 1
    core = np.zeros_like(contact)
    core[index[counts >= min_neighbours]] = True
    return core if core.sum() >= 3 else contact.copy()


def _grow(points_J, eligible, seed, pitch_mm, fit_plane, threshold_mm, max_rounds):
    """Alternate the robust fit of the contact and its growth over the connected markers on the plane.

    Each round's growth is a flood fill (:func:`_flood`): every eligible marker on the plane connected to
    the fit's inliers by steps of at most 1.5 pitches joins at once, so the rounds do not grow with the
    contact's radius (one ring per round made the cost grow as ``N^1.5`` with the contact's markers).
    """
    xy = np.ascontiguousarray(points_J[:, :2], dtype=float)
    contact = seed.copy()
    plane = None
    for _ in range(max_rounds):
        inliers, plane = fit_plane(points_J[contact])
        kept = np.zeros_like(contact)
        kept[np.flatnonzero(contact)[inliers]] = True
        on_plane = np.abs((points_J - plane.centroid_mm) @ plane.normal) < threshold_mm
        grown = _flood(xy, kept, on_plane & eligible, 1.5 * pitch_mm) if kept.any() else kept
        if np.array_equal(grown, contact):
            break
        contact = grown
    return contact, plane


@numba.njit(cache=True)
def _flood(xy: np.ndarray, start: np.ndarray, allowed: np.ndarray, radius: float) -> np.ndarray:
    """``start`` and every ``allowed`` point reached from it by steps shorter than ``radius``, as booleans.

    A breadth-first search over square cells of side ``radius`` (each point's neighbours lie in its own
    and the 8 adjacent cells): linear in the points for a grid of markers.
    """
    n = xy.shape[0]
    cx, cy, nx, ny, start_of, members = _grid_cells(xy, radius)
    reached = start.copy()
    queue = np.empty(n, dtype=np.int64)
    head, tail = 0, 0
    for i in range(n):
        if reached[i]:
            queue[tail] = i
            tail += 1
    r2 = radius * radius
    while head < tail:
        i = queue[head]
        head += 1
        for gx in range(max(cx[i] - 1, 0), min(cx[i] + 2, nx)):
            for gy in range(max(cy[i] - 1, 0), min(cy[i] + 2, ny)):
                c = gx * ny + gy
                for s in range(start_of[c], start_of[c + 1]):
                    j = members[s]
                    if reached[j] or not allowed[j]:
                        continue
                    dx, dy = xy[j, 0] - xy[i, 0], xy[j, 1] - xy[i, 1]
                    if dx * dx + dy * dy < r2:
                        reached[j] = True
                        queue[tail] = j
                        tail += 1
    return reached


def face_depth_mm(points_J: np.ndarray, dent: Indentation, plane: PlaneFit) -> np.ndarray:
    """How deep ``plane`` (the part's face) lies below the unloaded membrane at each marker (mm; NaN-free,
    ``-inf`` where the indentation is unknown): the marker's indentation minus its gap below the plane."""
    # Compiled, the same arithmetic as PlaneFit.heights_mm: 5 NumPy calls took 25 us, measured, and this
    # runs 4-6 times per estimate.
    return _face_depth(
        np.ascontiguousarray(points_J, dtype=float),
        np.ascontiguousarray(dent.depth_mm, dtype=float),
        np.ascontiguousarray(plane.normal, dtype=float),
        float(plane.offset_mm),
    )


@numba.njit(cache=True)
def _face_depth(points: np.ndarray, depth: np.ndarray, normal: np.ndarray, offset: float) -> np.ndarray:
    out = np.empty(points.shape[0])
    for i in range(points.shape[0]):
        height = -(offset + normal[0] * points[i, 0] + normal[1] * points[i, 1]) / normal[2]
        known = depth[i]  # as np.nan_to_num(depth, nan=-inf)
        if np.isnan(known):
            known = -np.inf
        elif np.isinf(known):
            known = _LARGEST if known > 0 else -_LARGEST
        out[i] = known - (height - points[i, 2])
    return out


def under_face(
    points_J: np.ndarray, plane: PlaneFit, radius_mm: float, centre_xy_mm: tuple[float, float] = (0.0, 0.0)
) -> np.ndarray:
    """Which markers' vertical projections onto ``plane`` lie within ``radius_mm`` of the plane's point
    above ``centre_xy_mm`` (under a face of that radius centred there; the jig axis by default), as
    booleans.

    Compiled, the same arithmetic as :meth:`~softjig.geometry.PlaneFit.heights_mm` and a 3-D norm (six
    NumPy calls took 40 us, measured).
    """
    cx, cy = (float(v) for v in centre_xy_mm)
    return _under_face(
        np.ascontiguousarray(points_J, dtype=float),
        np.ascontiguousarray(plane.normal, dtype=float),
        float(plane.offset_mm),
        cx,
        cy,
        plane.z_at(cx, cy),
        float(radius_mm),
    )


@numba.njit(cache=True)
def _under_face(
    points: np.ndarray,
    normal: np.ndarray,
    offset: float,
    cx: float,
    cy: float,
    centre_z: float,
    radius: float,
) -> np.ndarray:
    out = np.empty(points.shape[0], dtype=np.bool_)
    for i in range(points.shape[0]):
        x, y = points[i, 0], points[i, 1]
        dz = -(offset + normal[0] * x + normal[1] * y) / normal[2] - centre_z
        dx, dy = x - cx, y - cy
        out[i] = np.sqrt(dx * dx + dy * dy + dz * dz) < radius
    return out


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
    each refit steepens the plane, which uncovers more of the lift-off side.

    Measured on the default jig (as-built, speckle on, 12 azimuths per cell, part size known): the mean
    fitted tilt of an 80 mm part at 20 deg went from 18.43 to 19.83 deg, of a 60 mm one from 18.02 to
    19.83 deg, with ``clearance_mm`` 1.5 indentation-noise sigmas; at 5-10 deg it changed by < 0.2 deg.

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


@numba.njit(cache=True)
def _footprint(hull: np.ndarray, half_pitch: float) -> tuple[float, np.ndarray, float, np.ndarray]:
    """Area and centroid (shoelace formulas), perimeter, and the vertices moved out by
    ``half_pitch`` away from the centroid, of a polygon of at least 3 vertices."""
    k = hull.shape[0]
    twice_area, cx, cy, perimeter = 0.0, 0.0, 0.0, 0.0
    for i in range(k):
        j = (i + 1) % k
        cross = hull[i, 0] * hull[j, 1] - hull[j, 0] * hull[i, 1]
        twice_area += cross
        cx += (hull[i, 0] + hull[j, 0]) * cross
        cy += (hull[i, 1] + hull[j, 1]) * cross
        dx, dy = hull[j, 0] - hull[i, 0], hull[j, 1] - hull[i, 1]
        perimeter += np.sqrt(dx * dx + dy * dy)
    area = twice_area / 2.0
    centroid = np.empty(2)
    if abs(area) < 1e-12:
        area = 0.0
        centroid[0], centroid[1] = hull[:, 0].mean(), hull[:, 1].mean()
    else:
        centroid[0], centroid[1] = cx / (6.0 * area), cy / (6.0 * area)
    edge = hull.copy()
    for i in range(k):
        ox, oy = hull[i, 0] - centroid[0], hull[i, 1] - centroid[1]
        norm = np.sqrt(ox * ox + oy * oy)
        if norm > 0:
            edge[i, 0] += half_pitch * (ox / norm)
            edge[i, 1] += half_pitch * (oy / norm)
    return abs(area), centroid, perimeter, edge


def _hull_indices(xy: np.ndarray) -> np.ndarray:
    """Indices of the convex hull's vertices of (N >= 3, 2) points, counter-clockwise (``x`` right, ``y``
    up). ``cv2.convexHull`` on float32 copies (mm, so rounding of 1e-5 mm at most): 10 us for 100
    markers, where ``scipy.spatial.ConvexHull`` (Qhull) took about 70 us (measured)."""
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
    if len(hull) >= 3:  # the usual case, compiled: 15 NumPy calls took 0.1-0.2 ms, measured
        hull_area, centroid, perimeter, edge = _footprint(np.ascontiguousarray(hull), half_pitch)
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

    # The clearance is computed only where needed (12 NumPy calls, 30 us, measured).
    clearance = None
    tolerance = max(3.0 * noise_mm, 0.3)
    if edge_face_depth_mm is not None and len(edge_face_depth_mm):
        edge_clearance = float(np.min(edge_face_depth_mm))
    else:
        clearance = clearance_at_edge()
        edge_clearance = float(clearance[int(np.argmin(clearance))])
    lifts = edge_clearance < tolerance
    small = part_diameter_mm is not None and area < 0.7 * np.pi * (part_diameter_mm / 2.0) ** 2
    lift_azimuth = None
    if lifts or small:
        # The side that lifts off: a flat face rises towards the plane's uphill direction, -(n_x, n_y);
        # for a nearly level plane, the middle of the footprint's edge where the plane meets the membrane
        # (a chord across the part), seen from the centroid.
        uphill = -plane.normal[:2]
        if np.hypot(*uphill) > np.sin(np.radians(1.0)):
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
    if not region.partial or slope < 1e-6:
        return (float(centroid[0]), float(centroid[1]))
    downhill = normal[:2] / slope  # the plane is lowest towards +(n_x, n_y)
    along_in_plane = (np.asarray(contact_xy_mm, dtype=float) - centroid) @ downhill / normal[2]
    rim = float(along_in_plane.max()) + pitch_mm / 2.0
    centre = centroid + (rim - radius_mm) * normal[2] * downhill
    return (float(centre[0]), float(centre[1]))


def just_outside(xy_mm: np.ndarray, contact: np.ndarray, pitch_mm: float) -> np.ndarray:
    """The markers not in the contact within 1.5 pitches of one that is, as booleans."""
    if not contact.any():
        return np.zeros(len(xy_mm), dtype=bool)
    return _near(xy_mm, contact, 1.5 * pitch_mm) & ~contact
