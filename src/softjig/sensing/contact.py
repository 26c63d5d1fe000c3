"""The contact region, found without being told the part's size, and its footprint.

The paper must be told the part's base size to crop the markers it fits. Instead, each marker's
**indentation** (how far it lies below the unloaded membrane: a reference frame, or the nominal rest shape)
says which markers the part displaced. Indentations are measured against a robust zero and noise scale of
the markers at rest (a part only pushes markers in, so the less indented side of the distribution is
uncontaminated), which also absorbs a uniform depth bias of an imperfectly calibrated camera pair.
Markers indented beyond the noise are *candidates*; the contact is grown from the deepest of them over
the neighbours on their plane (:func:`grow_contact`, robust fits from :mod:`softjig.sensing.robust`),
rejecting the membrane that the indentation drags down around it.

The **footprint** of the contact is the convex hull of the contact markers dilated by half a marker pitch
(each marker stands for one cell of the grid; by Steiner's formula the area grows by
``perimeter * p / 2 + pi (p / 2)^2``). Contact is **partial** when, on some side, the fitted plane rises to
the rest membrane within the footprint: there the part lifts off, rather than ending at its edge with the
membrane draped down from it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import ConvexHull, Delaunay, QhullError, cKDTree

from softjig.config import JigConfig
from softjig.geometry import PlaneFit
from softjig.jig_shape import rest_inner_height_mm


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


def indentation(points_J: np.ndarray, reference_z_mm: np.ndarray) -> Indentation:
    """Indentations from each marker's reference height (the reference frame's, or the rest shape's)."""
    raw = np.asarray(reference_z_mm, dtype=float) - points_J[:, 2]
    finite = np.isfinite(raw)
    if not finite.any():
        return Indentation(np.full(len(raw), np.nan), 0.0, float("nan"))
    # Zero and noise of the markers at rest. A part only pushes markers in, never out, so the markers
    # indented less than the median are at rest however many the part displaced: the noise is the spread
    # of that side (1.4826 x their median distance from the zero), and the zero is re-estimated from the
    # markers within 2.5 sigma of it (their median), which also removes the bias of the first median.
    zero = float(np.median(raw[finite]))
    noise = float("nan")
    for _ in range(5):
        low = finite & (raw <= zero)
        noise = max(float(1.4826 * np.median(zero - raw[low])), 1e-6) if low.any() else 1e-6
        at_rest = finite & (np.abs(raw - zero) < 2.5 * noise)
        new_zero = float(np.median(raw[at_rest])) if at_rest.sum() >= 3 else zero
        if abs(new_zero - zero) < 1e-3 * noise:
            break
        zero = new_zero
    return Indentation(raw - zero, zero, noise)


def contact_candidates(dent: Indentation, *, sigmas: float = 4.0, min_depth_mm: float = 0.3) -> np.ndarray:
    """Markers indented beyond ``max(sigmas x noise, min_depth_mm)``, as booleans."""
    threshold = max(sigmas * dent.noise_mm, min_depth_mm) if np.isfinite(dent.noise_mm) else min_depth_mm
    return np.nan_to_num(dent.depth_mm, nan=-np.inf) > threshold


def penetrating(
    points_J: np.ndarray, contact: np.ndarray, plane: PlaneFit, threshold_mm: float
) -> np.ndarray:
    """Markers that would penetrate the part if ``plane`` were its face: more than ``threshold_mm`` above
    the plane (into the part) with ``(x, y)`` inside the contact's convex hull, as booleans."""
    above = (points_J - plane.centroid_mm) @ plane.normal > threshold_mm
    if contact.sum() < 3 or not above.any():
        return np.zeros(len(points_J), dtype=bool)
    try:
        hull = Delaunay(points_J[contact, :2])
    except (QhullError, ValueError):
        return np.zeros(len(points_J), dtype=bool)
    return above & (hull.find_simplex(points_J[:, :2]) >= 0)


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
       more markers, but shallower) must not outvote it.
    2. **Grow.** The robust plane of the seed; then every neighbouring marker (within 1.5 pitches of a
       contact marker) within ``threshold_mm`` of the plane and pushed in beyond the noise joins, and the
       plane is fitted again, until nothing changes. The wall of membrane beside a deep indentation rises
       steeply off the plane, and where the part lifts off the membrane falls away below it, so the growth
       stops at both.
    3. **Check.** No marker may lie above the face inside the contact (:func:`penetrating`): the wall
       just outside a deeply pressed edge is as deep as the contact and can win the seed's fit, but its
       plane leaves the real contact markers above it. Such a plane's markers are peeled off the seed and
       the rest is fitted again (at most twice); the contact with the fewest penetrating markers wins. A
       plane tilted beyond ``max_tilt_rad`` (no part pressed into a soft jig stands so steep: it is a
       line of markers on the membrane's wall) counts as the worst.

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
    deep_depth = 0.5 * float(np.percentile(depth[candidates], 90)) if candidates.any() else 0.0
    seed = candidates & (depth >= deep_depth)
    if seed.sum() < min_points:
        seed = candidates.copy()
    best: tuple[int, np.ndarray, PlaneFit] | None = None
    for _ in range(3):
        contact, plane = _grow(
            points_J, depth > dent.noise_mm, seed, pitch_mm, fit_plane, threshold_mm, max_rounds
        )
        violations = int(penetrating(points_J, contact, plane, threshold_mm).sum())
        if plane.normal[2] < np.cos(max_tilt_rad):
            violations = len(points_J) + 1
        if best is None or violations < best[0]:
            best = (violations, contact, plane)
        remaining = seed & ~contact
        if violations == 0 or remaining.sum() < min_points:
            break
        seed = remaining
    assert best is not None
    return best[1], best[2]


def _grow(points_J, eligible, seed, pitch_mm, fit_plane, threshold_mm, max_rounds):
    xy = points_J[:, :2]
    contact = seed.copy()
    plane = None
    for _ in range(max_rounds):
        inliers, plane = fit_plane(points_J[contact])
        kept = np.zeros_like(contact)
        kept[np.flatnonzero(contact)[inliers]] = True
        near = np.zeros_like(contact)
        if kept.any():
            distance_xy, _ = cKDTree(xy[kept]).query(xy, distance_upper_bound=1.5 * pitch_mm)
            near = np.isfinite(distance_xy)
        on_plane = np.abs((points_J - plane.centroid_mm) @ plane.normal) < threshold_mm
        grown = kept | (near & on_plane & eligible)
        if np.array_equal(grown, contact):
            break
        contact = grown
    return contact, plane


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


def _polygon_area_centroid(polygon: np.ndarray) -> tuple[float, np.ndarray]:
    x, y = polygon[:, 0], polygon[:, 1]
    cross = x * np.roll(y, -1) - np.roll(x, -1) * y
    area = cross.sum() / 2.0
    if abs(area) < 1e-12:
        return 0.0, polygon.mean(axis=0)
    cx = ((x + np.roll(x, -1)) * cross).sum() / (6.0 * area)
    cy = ((y + np.roll(y, -1)) * cross).sum() / (6.0 * area)
    return abs(area), np.array([cx, cy])


def describe_contact(
    contact_xy_mm: np.ndarray,
    plane: PlaneFit,
    jig: JigConfig,
    *,
    noise_mm: float,
    part_diameter_mm: float | None = None,
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
    """
    half_pitch = jig.markers.pitch_mm / 2.0
    xy = np.asarray(contact_xy_mm, dtype=float)
    try:
        hull = xy[ConvexHull(xy).vertices]  # counter-clockwise in 2-D
    except (QhullError, ValueError):
        hull = xy  # fewer than 3 points, or all on a line: the points themselves
    hull_area, centroid = _polygon_area_centroid(hull) if len(hull) >= 3 else (0.0, xy.mean(axis=0))
    perimeter = (
        float(np.linalg.norm(np.roll(hull, -1, axis=0) - hull, axis=1).sum()) if len(hull) > 1 else 0.0
    )
    area = hull_area + perimeter * half_pitch + np.pi * half_pitch**2
    # The footprint's edge: each hull vertex moved out by half a pitch, away from the centroid.
    outward = hull - centroid
    norms = np.linalg.norm(outward, axis=1, keepdims=True)
    edge = hull + half_pitch * np.divide(outward, norms, out=np.zeros_like(outward), where=norms > 0)
    plane_z = plane.heights_mm(edge[:, 0], edge[:, 1])
    clearance = rest_inner_height_mm(jig, edge[:, 0], edge[:, 1]) - plane_z
    lowest = int(np.argmin(clearance))
    tolerance = max(3.0 * noise_mm, 0.3)
    lifts = bool(clearance[lowest] < tolerance)
    small = part_diameter_mm is not None and area < 0.7 * np.pi * (part_diameter_mm / 2.0) ** 2
    lift_azimuth = None
    if lifts or small:
        # The side that lifts off: the middle of the footprint's edge where the plane meets the membrane
        # (a chord across the part), seen from the centroid.
        low = clearance < tolerance if lifts else clearance <= clearance[lowest]
        direction = edge[low].mean(axis=0) - centroid
        lift_azimuth = float(np.degrees(np.arctan2(direction[1], direction[0])) % 360.0)
    return ContactRegion(
        area_mm2=float(area),
        centroid_xy_mm=(float(centroid[0]), float(centroid[1])),
        outline_xy_mm=edge,
        partial=bool(lifts or small),
        lift_azimuth_deg=lift_azimuth,
        edge_clearance_mm=float(clearance[lowest]),
    )
