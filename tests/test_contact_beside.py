"""Holes beside the contact (:func:`softjig.sensing.contact.holes_beside`) and in its dent
(:func:`~softjig.sensing.contact.holes_in_the_dent`) on synthetic markers: a strip of wall fitted beside a
deeper face has them, a real face with its lift-off side and its wall does not."""

from __future__ import annotations

import numpy as np

from softjig.geometry import fit_plane_svd, normal_from_tilt_angles
from softjig.sensing.contact import (
    BESIDE_HOLE_THRESHOLDS,
    DENT_HOLE_THRESHOLDS,
    Indentation,
    contact_violations,
    face_depth_mm,
    holes_beside,
    holes_in_the_dent,
    just_outside,
)

PITCH = 8.0
REST_Z = 30.0  # a flat unloaded membrane
THRESHOLD = 0.5  # the contact plane's inlier band (mm), 2.5 sigmas of 0.2 mm


def _grid(radius_mm: float) -> np.ndarray:
    r = np.arange(-radius_mm, radius_mm + 1e-9, PITCH)
    x, y = np.meshgrid(r, r)
    xy = np.column_stack([x.ravel(), y.ravel()])
    return xy[np.hypot(*xy.T) <= radius_mm]


def _membrane(alpha_deg: float, push_mm: float, radius_mm: float, wall_mm: float):
    """A face of ``radius_mm`` tilted towards +x, centred on the axis ``push_mm`` below the rest membrane;
    beside it, the membrane rises linearly from the face's edge to the rest level over ``wall_mm``, and
    where the face rises out of the membrane (face above rest) the membrane is at rest."""
    xy = _grid(60.0)
    normal = normal_from_tilt_angles(0.0, np.radians(alpha_deg))
    face_z = REST_Z - push_mm - (normal[0] * xy[:, 0] + normal[1] * xy[:, 1]) / normal[2]
    r = np.hypot(*xy.T)
    on_face = (r <= radius_mm) & (face_z < REST_Z)
    # Beside the face: the depth of the face's edge along the same ray, decaying to 0 over wall_mm.
    edge_xy = xy * (radius_mm / np.maximum(r, 1e-9))[:, None]
    edge_z = REST_Z - push_mm - (normal[0] * edge_xy[:, 0] + normal[1] * edge_xy[:, 1]) / normal[2]
    edge_depth = np.clip(REST_Z - edge_z, 0.0, None)
    wall_depth = edge_depth * np.clip(1.0 - (r - radius_mm) / wall_mm, 0.0, 1.0)
    z = np.where(on_face, face_z, REST_Z - np.where(r > radius_mm, wall_depth, 0.0))
    points = np.column_stack([xy, z])
    return points, Indentation(REST_Z - z, 0.0, 0.05), on_face


def test_a_face_with_its_wall_and_lift_off_has_no_hole_beside():
    points, dent, on_face = _membrane(alpha_deg=15.0, push_mm=4.0, radius_mm=25.0, wall_mm=12.0)
    plane = fit_plane_svd(points[on_face])
    beside = holes_beside(points, dent, on_face, plane, threshold_mm=THRESHOLD, pitch_mm=PITCH)
    assert not beside.any()
    assert contact_violations(points, on_face, plane, threshold_mm=THRESHOLD, pitch_mm=PITCH, dent=dent) == 0


def test_a_shallow_strip_beside_a_deeper_face_has_holes_beside():
    """The wall of the raised side (at rest, shallow) fitted instead of the face: the face's markers next
    to it lie deep below that plane, where the plane still presses into the membrane."""
    points, dent, on_face = _membrane(alpha_deg=15.0, push_mm=10.0, radius_mm=20.0, wall_mm=20.0)
    x, r = points[:, 0], np.hypot(*points[:, :2].T)
    strip = ~on_face & (x <= -20.0) & (r <= 45.0) & (dent.depth_mm > 0.3)  # the raised side's wall
    assert strip.sum() >= 6
    plane = fit_plane_svd(points[strip])
    beside = holes_beside(points, dent, strip, plane, threshold_mm=THRESHOLD, pitch_mm=PITCH)
    # The holes are the face's markers and the membrane dragged down right beside the face: all pushed
    # in deeper than any marker of the strip.
    assert (beside & on_face).any()
    assert dent.depth_mm[beside].min() > dent.depth_mm[strip].max()
    without = contact_violations(points, strip, plane, threshold_mm=THRESHOLD, pitch_mm=PITCH)
    with_dent = contact_violations(
        points,
        strip,
        plane,
        threshold_mm=THRESHOLD,
        pitch_mm=PITCH,
        dent=dent,
        beside_thresholds=BESIDE_HOLE_THRESHOLDS,
    )
    assert with_dent == without + int(beside.sum())


def test_markers_below_a_plane_but_shallower_than_the_contact_are_no_holes():
    """Just outside the contact and below its plane, but not deeper than the contact beside them (the
    membrane falling away where the face rises out of it): not a hole."""
    xy = _grid(40.0)
    contact = xy[:, 0] <= 0.0
    z = np.where(contact, REST_Z - 3.0, REST_Z - 2.0)  # a level face 3 mm deep; beside it 2 mm deep
    points = np.column_stack([xy, z])
    # The plane of the contact, tilted so that it rises over the markers beside: they lie below it.
    plane = fit_plane_svd(np.column_stack([xy[contact], z[contact] + 0.3 * xy[contact, 0]]))
    dent = Indentation(REST_Z - z, 0.0, 0.05)
    assert not holes_beside(points, dent, contact, plane, threshold_mm=THRESHOLD, pitch_mm=PITCH).any()
    deeper = np.where(contact, z, REST_Z - 5.0)  # now deeper than the contact next to them: holes
    points = np.column_stack([xy, deeper])
    dent = Indentation(REST_Z - deeper, 0.0, 0.05)
    assert holes_beside(points, dent, contact, plane, threshold_mm=THRESHOLD, pitch_mm=PITCH).any()


def _strip_beside_a_face():
    """The wall strip of :func:`test_a_shallow_strip_beside_a_deeper_face_has_holes_beside`, its plane."""
    points, dent, on_face = _membrane(alpha_deg=15.0, push_mm=10.0, radius_mm=20.0, wall_mm=20.0)
    x, r = points[:, 0], np.hypot(*points[:, :2].T)
    strip = ~on_face & (x <= -20.0) & (r <= 45.0) & (dent.depth_mm > 0.3)
    return points, dent, strip, fit_plane_svd(points[strip])


def test_violations_with_the_markers_just_outside_given_are_the_same():
    """The caller's just-outside markers (the fit stage has them already) give the same count."""
    points, dent, strip, plane = _strip_beside_a_face()
    outside = just_outside(points[:, :2], strip, PITCH)
    kwargs = {"threshold_mm": THRESHOLD, "pitch_mm": PITCH, "dent": dent, "beside_thresholds": 1.5}
    given = contact_violations(points, strip, plane, outside=outside, **kwargs)
    assert given == contact_violations(points, strip, plane, **kwargs) > 0


def test_a_marker_of_unknown_indentation_is_no_hole_beside():
    """NaN depths (no reference marker, no rest height) are deeper than nothing: such a marker is never a
    hole, and the others are judged as before."""
    points, dent, strip, plane = _strip_beside_a_face()
    holes = holes_beside(points, dent, strip, plane, threshold_mm=THRESHOLD, pitch_mm=PITCH)
    unknown = np.flatnonzero(holes)[0]
    depth = dent.depth_mm.copy()
    depth[unknown] = np.nan
    with_nan = holes_beside(
        points, Indentation(depth, 0.0, 0.05), strip, plane, threshold_mm=THRESHOLD, pitch_mm=PITCH
    )
    expected = holes.copy()
    expected[unknown] = False
    assert np.array_equal(with_nan, expected)


def _flat_contact_with_markers_above(heights_mm: list[float]):
    """A flat contact of a 20 mm face on the axis (21 markers), 4 mm deep, with its central markers
    raised by ``heights_mm`` (taken out of the contact, as a fit would leave them)."""
    xy = _grid(20.0)
    z = np.full(len(xy), REST_Z - 4.0)
    central = np.argsort(np.hypot(*xy.T))[: len(heights_mm)]
    z[central] += heights_mm
    points = np.column_stack([xy, z])
    contact = np.ones(len(xy), dtype=bool)
    contact[central] = False
    return points, contact, fit_plane_svd(points[contact])


def test_markers_far_above_the_plane_are_tolerated_once():
    """Inside the core of a contact of under 40 markers, two markers just above the plane (within two
    inlier thresholds) are noise, and so is one far above it (a mismatched marker); two far above are
    one violation: no face leaves a rise of membrane that pierces it."""
    near, far = 1.5 * THRESHOLD, 2.5 * THRESHOLD
    for heights, expected in [([near, near], 0), ([far], 0), ([far, far], 1)]:
        points, contact, plane = _flat_contact_with_markers_above(heights)
        count = contact_violations(points, contact, plane, threshold_mm=THRESHOLD, pitch_mm=PITCH)
        assert count == expected, (heights, count)


def _holes_in_the_dent(points, dent, contact, plane):
    return holes_in_the_dent(
        points,
        dent,
        contact,
        plane,
        threshold_mm=THRESHOLD,
        pitch_mm=PITCH,
        plane_depth_mm=face_depth_mm(points, dent, plane),
        outside=just_outside(points[:, :2], contact, PITCH),
    )


def test_a_face_with_its_wall_and_lift_off_has_no_hole_in_its_dent():
    points, dent, on_face = _membrane(alpha_deg=15.0, push_mm=4.0, radius_mm=25.0, wall_mm=12.0)
    assert not _holes_in_the_dent(points, dent, on_face, fit_plane_svd(points[on_face])).any()


def test_a_face_fitted_without_its_lowered_rim_has_no_hole_in_its_dent():
    """The rim's markers lie deeper than any marker fitted, but on the plane: no evidence against it."""
    points, dent, on_face = _membrane(alpha_deg=15.0, push_mm=4.0, radius_mm=25.0, wall_mm=12.0)
    fitted = on_face & (points[:, 0] < 10.0)
    assert dent.depth_mm[on_face & ~fitted].max() > dent.depth_mm[fitted].max() + 1.0
    assert not _holes_in_the_dent(points, dent, fitted, fit_plane_svd(points[fitted])).any()


def test_a_stretch_of_drape_far_from_a_deeper_face_has_holes_in_its_dent_beyond_those_beside_it():
    """The wall of the raised side, over 1.5 pitches from the face, fitted instead of it: only the dent's
    extent reaches the face's markers, deep below that plane where it still presses into the membrane."""
    points, dent, on_face = _membrane(alpha_deg=15.0, push_mm=10.0, radius_mm=20.0, wall_mm=30.0)
    x, r = points[:, 0], np.hypot(*points[:, :2].T)
    strip = ~on_face & (x <= -20.0) & (r >= 20.0 + 1.5 * PITCH) & (dent.depth_mm > 0.3)
    assert strip.sum() >= 6
    plane = fit_plane_svd(points[strip])
    holes = _holes_in_the_dent(points, dent, strip, plane)
    beyond_beside = on_face & ~just_outside(points[:, :2], strip, PITCH)  # where holes_beside never looks
    assert (holes & beyond_beside).sum() >= 2
    gaps = (plane.centroid_mm - points[holes]) @ plane.normal
    assert gaps.min() > DENT_HOLE_THRESHOLDS * THRESHOLD


def test_deep_markers_cut_off_from_the_dent_are_not_holes_in_it():
    """A cluster of mismatched markers deep under the plane, beyond markers at rest: not of the dent."""
    points, dent, on_face = _membrane(alpha_deg=15.0, push_mm=10.0, radius_mm=20.0, wall_mm=30.0)
    x, r = points[:, 0], np.hypot(*points[:, :2].T)
    strip = ~on_face & (x <= -20.0) & (r >= 20.0 + 1.5 * PITCH) & (dent.depth_mm > 0.3)
    plane = fit_plane_svd(points[strip])
    # Only the strip is pushed in; a cluster far off in the membrane at rest is deep (mismatched).
    depth = np.where(strip, dent.depth_mm, 0.0)
    far = (x > 40.0) & (np.abs(points[:, 1]) < 10.0)
    assert far.sum() >= 2
    depth[far] = 20.0
    moved = points.copy()
    moved[:, 2] = np.where(strip, points[:, 2], REST_Z - depth)
    lone = Indentation(depth, 0.0, 0.05)
    assert not _holes_in_the_dent(moved, lone, strip, plane).any()
    # The same cluster joined to the strip by pushed-in markers is of the dent.
    between = (np.abs(points[:, 1]) < 10.0) & ~far & ~strip
    depth[between] = 5.0
    moved[:, 2] = np.where(strip, points[:, 2], REST_Z - depth)
    assert _holes_in_the_dent(moved, Indentation(depth, 0.0, 0.05), strip, plane)[far].any()
