"""The contact's pure functions on synthetic markers: lift-off pruning and the face's centre."""

from dataclasses import replace

import numpy as np
import pytest

from softjig.config import default_jig
from softjig.geometry import fit_plane_svd, normal_from_tilt_angles
from softjig.jig_shape import marker_layout_xy, rest_inner_height_mm
from softjig.sensing.contact import (
    FootprintMisfit,
    Indentation,
    describe_contact,
    drop_lifted_off,
    face_centre_xy,
    footprint_misfit,
    markers_at_rest,
    off_the_membrane,
    off_the_rest_membrane,
)

PITCH = 8.0
REST_Z = 30.0  # a flat unloaded membrane, for the synthetic cases


def _grid(radius_mm: float) -> np.ndarray:
    r = np.arange(-radius_mm, radius_mm + 1e-9, PITCH)
    x, y = np.meshgrid(r, r)
    xy = np.column_stack([x.ravel(), y.ravel()])
    return xy[np.hypot(*xy.T) <= radius_mm]


def _tilted_face(alpha_deg: float, push_mm: float):
    """A face tilted towards +x, its centre ``push_mm`` below the flat rest membrane."""
    normal = normal_from_tilt_angles(0.0, np.radians(alpha_deg))
    return normal, lambda x, y: REST_Z - push_mm - (normal[0] * x + normal[1] * y) / normal[2]


def test_drop_lifted_off_restores_the_tilt_flattened_by_the_drape():
    """80 mm face at 20 deg, 3 mm push: the raised side lifts off, and the membrane it drags down stays
    0.2-0.8 mm below the face for one pitch beyond the lift-off line (within any inlier band), which
    flattens the least-squares plane."""
    rng = np.random.default_rng(1)
    normal, face_z = _tilted_face(20.0, 3.0)
    xy = _grid(40.0)
    z_face = face_z(xy[:, 0], xy[:, 1])
    touching = z_face < REST_Z
    lifted = ~touching & (z_face - REST_Z < PITCH * np.tan(np.radians(20.0)))
    z = np.where(touching, z_face, REST_Z)
    z[lifted] = z_face[lifted] - 0.2 - 0.6 * rng.random(lifted.sum())
    points = np.column_stack([xy, z + rng.normal(0.0, 0.02, len(xy))])
    dent = Indentation(REST_Z - points[:, 2], 0.0, 0.02)
    used = touching | lifted
    plane = fit_plane_svd(points[used])
    kept, pruned = drop_lifted_off(points, dent, used, plane, clearance_mm=0.2, fit_plane=fit_plane_svd)
    assert np.degrees(np.arccos(plane.normal @ normal)) > 0.3  # the drape does flatten it
    assert np.degrees(np.arccos(pruned.normal @ normal)) < 0.1
    assert not (kept & lifted).any()
    assert (kept & touching).sum() >= (REST_Z - z_face > 0.25).sum() - 2  # only the touching markers within
    # the clearance of the lift-off line go with them


def test_drop_lifted_off_keeps_a_full_contact():
    normal, face_z = _tilted_face(5.0, 3.0)
    xy = _grid(16.0)
    points = np.column_stack([xy, face_z(xy[:, 0], xy[:, 1])])
    dent = Indentation(REST_Z - points[:, 2], 0.0, 0.02)
    used = np.ones(len(xy), bool)
    kept, plane = drop_lifted_off(
        points, dent, used, fit_plane_svd(points), clearance_mm=0.2, fit_plane=fit_plane_svd
    )
    assert kept.all()
    assert np.allclose(plane.normal, normal, atol=1e-9)


@pytest.mark.parametrize("centre", [(0.0, 0.0), (6.0, -4.0)])
def test_face_centre_in_partial_contact_is_not_the_contact_centroid(centre):
    """A 70 mm face at 20 deg lifts off on its raised side: the footprint's centroid lies ~15 mm downhill,
    the face's centre (one radius uphill of the rim) is found within a few mm."""
    jig = default_jig()
    normal = normal_from_tilt_angles(0.0, np.radians(20.0))
    radius = 35.0
    xy = _grid(60.0)
    inside = np.hypot(*(xy - centre).T) < radius
    # contact: the face lies below the (flat) rest membrane, 3 mm at its centre
    face_depth = 3.0 + (xy - centre) @ normal[:2] / normal[2]
    contact = inside & (face_depth > 0)
    z = REST_Z - face_depth
    points = np.column_stack([xy, z])
    plane = fit_plane_svd(points[contact])
    region = describe_contact(points[contact, :2], plane, jig, noise_mm=0.05, part_diameter_mm=2 * radius)
    region = replace(region, partial=True)  # the jig's dome is not our flat membrane
    estimate = face_centre_xy(points[contact, :2], region, plane, radius, pitch_mm=PITCH)
    centroid_error = np.hypot(*(np.asarray(region.centroid_xy_mm) - centre))
    assert centroid_error > 10.0
    assert np.hypot(*(np.asarray(estimate) - centre)) < PITCH / 2


def test_face_centre_in_full_contact_is_the_centroid():
    jig = default_jig()
    xy = _grid(16.0)
    points = np.column_stack([xy, np.full(len(xy), 27.0)])
    plane = fit_plane_svd(points)
    region = describe_contact(xy, plane, jig, noise_mm=0.05)
    assert not region.partial
    assert face_centre_xy(xy, region, plane, 20.0, pitch_mm=PITCH) == pytest.approx(region.centroid_xy_mm)


def test_a_lift_off_seen_only_beside_the_outline_still_has_a_direction():
    """A level plane well below the rest membrane at its outline, while a marker just outside the contact
    says the face does not reach it: the lift-off direction was the mean of no edge points (NaN, and a
    RuntimeWarning), now the outline's lowest point."""
    import warnings

    jig = default_jig()
    xy = _grid(16.0)
    plane = fit_plane_svd(np.column_stack([xy, np.full(len(xy), 27.0)]))
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        region = describe_contact(xy, plane, jig, noise_mm=0.05, edge_face_depth_mm=np.array([-1.0, 2.0]))
    assert region.partial
    assert region.lift_azimuth_deg is not None and np.isfinite(region.lift_azimuth_deg)


@pytest.mark.parametrize("tilt_deg", [8.0, 12.0, 18.0])
@pytest.mark.parametrize("azimuth_deg", [30.0, 200.0])
def test_the_membrane_under_a_face_of_the_parts_size_fits_the_face_not_the_wall_beside_it(
    tilt_deg, azimuth_deg
):
    """A 44 mm face 9 mm off the axis, its lowered rim 5 mm deep, on the default jig's dome and markers:
    pressed where the face lies below the unloaded membrane, at rest where it lies above, and a wall
    falling from the rim at 0.5 mm per mm beside it. Its partial contact and the strip of wall beside
    the lowered rim are both planar enough to be faces; placed where each puts a face of the part's size,
    the face's plane predicts the membrane under it within its noise, the wall's does not."""
    jig = default_jig()
    rng = np.random.default_rng(3)
    xy = marker_layout_xy(jig)
    rest = rest_inner_height_mm(jig, xy[:, 0], xy[:, 1])
    radius, centre, rim_depth, wall_slope, noise = 22.0, np.array([8.0, -5.0]), 5.0, 0.5, 0.05
    down = np.array([np.cos(np.radians(azimuth_deg)), np.sin(np.radians(azimuth_deg))])  # the lowered rim
    offset = xy - centre
    distance = np.hypot(*offset.T)
    slope = np.tan(np.radians(tilt_deg))
    inside = distance < radius
    face_depth = rim_depth - (radius - offset @ down) * slope
    rim_depth_beside = rim_depth - radius * (1.0 - (offset / distance[:, None]) @ down) * slope
    depth = np.where(
        inside,
        np.maximum(face_depth, 0.0),
        np.maximum(rim_depth_beside - wall_slope * (distance - radius), 0.0),
    )
    depth += rng.normal(0.0, noise, len(xy))
    points = np.column_stack([xy, rest - depth])
    dent = Indentation(depth, 0.0, noise)
    face, wall = inside & (depth > 4 * noise), ~inside & (depth > 4 * noise)
    assert face.sum() >= 4 and wall.sum() >= 4  # each a plane the rival check would weigh

    def misfit(contact):
        plane = fit_plane_svd(points[contact])
        return footprint_misfit(points, dent, contact, plane, radius, jig, noise_mm=noise).rms_sigmas

    assert misfit(face) < 2.5
    assert misfit(wall) > 2.0 * misfit(face)


def test_a_misfit_within_the_noise_is_no_evidence():
    """Of two faces, the one whose RMS misfit is smaller fits better, but both within 1 sigma are a tie,
    and a face with no marker under it is never better nor worse."""
    within, also_within, beyond = FootprintMisfit(4.0, 16), FootprintMisfit(0.5, 8), FootprintMisfit(90.0, 10)
    assert within.fits_better_than(beyond) and not beyond.fits_better_than(within)
    assert not within.fits_better_than(also_within) and not also_within.fits_better_than(within)
    nothing = FootprintMisfit(0.0, 0)
    assert not nothing.fits_better_than(beyond) and not beyond.fits_better_than(nothing)


def test_a_face_with_no_marker_under_it_fits_nothing():
    """A level face of 1 mm radius centred between four markers has none under it: no evidence, the
    worst misfit (never the better face)."""
    jig = default_jig()
    xy = _grid(16.0)
    points = np.column_stack([xy, np.full(len(xy), 27.0)])
    contact = (np.abs(xy[:, 0] - PITCH / 2) <= PITCH / 2) & (np.abs(xy[:, 1] - PITCH / 2) <= PITCH / 2)
    assert contact.sum() == 4
    dent = Indentation(np.zeros(len(xy)), 0.0, 0.05)
    plane = fit_plane_svd(points[contact])
    misfit = footprint_misfit(points, dent, contact, plane, 1.0, jig, noise_mm=0.05)
    assert misfit.n_markers == 0 and misfit.rms_sigmas == np.inf


# ------------------------------------------------------------------ compiled helpers against references


def _marker_cloud(rng: np.random.Generator, count: int) -> np.ndarray:
    """A jittered 8 mm grid (as the markers) or, every other call, uniform points, in a disc."""
    grid = np.stack(np.meshgrid(np.arange(-64.0, 65, 8), np.arange(-64.0, 65, 8)), -1).reshape(-1, 2)
    grid = grid[np.hypot(*grid.T) < 65]
    grid = grid + rng.normal(0, 0.4, grid.shape)
    return grid if count % 2 else rng.uniform(-60, 60, (count, 2))


def test_inside_hull_matches_delaunay():
    from scipy.spatial import Delaunay

    from softjig.geometry import inside_convex_hull_xy

    rng = np.random.default_rng(3)
    for trial in range(60):
        xy = _marker_cloud(rng, 150 + trial)
        contact = rng.random(len(xy)) < rng.uniform(0.05, 0.6)
        expected = Delaunay(xy[contact]).find_simplex(xy) >= 0
        assert np.array_equal(inside_convex_hull_xy(xy[contact], xy), expected)
    line = np.column_stack([np.arange(5.0), np.zeros(5)])  # no area: nothing is inside
    assert not inside_convex_hull_xy(line, line).any()


def test_neighbour_helpers_match_a_kd_tree():
    from scipy.spatial import cKDTree

    from softjig.sensing.contact import indentation, just_outside

    rng = np.random.default_rng(4)
    for trial in range(20):
        xy = _marker_cloud(rng, 200 + trial)
        raw = rng.normal(0, 0.05, len(xy)) + 0.01 * xy[:, 0]
        residual = []
        for i, near in enumerate(cKDTree(xy).query_ball_point(xy, 20.0)):  # 2.5 pitches of 8 mm
            near = [j for j in near if j != i]
            if len(near) < 12:
                continue
            u, w = ((xy[near] - xy[i]) / 20.0).T
            design = np.column_stack([np.ones_like(u), u, w, u * u, u * w, w * w])
            variance = np.linalg.inv(design.T @ design)[0, 0]
            if 0 < variance <= 1:
                prediction = np.linalg.lstsq(design, raw[near], rcond=None)[0][0]
                residual.append((raw[i] - prediction) / np.sqrt(1 + variance))
        expected = max(1.4826 * np.median(np.abs(residual)), 1e-6)
        points = np.column_stack([xy, -raw])  # indented by raw below a flat reference at 0
        assert indentation(points, np.zeros(len(xy)), pitch_mm=8.0).noise_mm == pytest.approx(
            expected, rel=1e-9
        )
        contact = rng.random(len(xy)) < 0.3
        distance, _ = cKDTree(xy[contact]).query(xy, distance_upper_bound=12.0)
        assert np.array_equal(just_outside(xy, contact, 8.0), np.isfinite(distance) & ~contact)


def test_fit_plane_matches_the_svd_of_the_points():
    rng = np.random.default_rng(5)
    for _ in range(20):
        xy = rng.uniform(-30, 30, (int(rng.integers(4, 200)), 2))
        z = rng.normal(0, 0.2, len(xy)) + xy @ rng.normal(0, 0.3, 2) - 5.0
        points = np.column_stack([xy, z])
        fit = fit_plane_svd(points)
        _, s, vt = np.linalg.svd(points - points.mean(axis=0), full_matrices=False)
        normal = vt[2] * np.sign(vt[2, 2])
        assert np.allclose(fit.normal, normal, rtol=0, atol=1e-12)
        assert np.allclose(fit.singular_values, s, rtol=1e-9)
        assert fit.rms_residual_mm == pytest.approx(
            np.sqrt(np.mean(((points - fit.centroid_mm) @ normal) ** 2))
        )
    with pytest.raises(Exception, match="line"):
        fit_plane_svd(np.column_stack([np.arange(6.0), 2 * np.arange(6.0), np.zeros(6)]))


@pytest.mark.parametrize("grid", ["square", "hex"])
def test_indentation_noise_on_a_coarse_grid_is_the_markers_noise_not_the_drapes_curvature(grid):
    """On a coarse grid (9.4 mm pitch, as zoo seed 0 design 42), a smoothly curved drape must not pass
    for noise: the estimate stays within 25 % of the per-marker noise the heights were drawn with (the
    mean of the nearest neighbours put ``3 pitch^2 / 8`` times the bowl's Laplacian into it: 2x)."""
    from softjig.sensing.contact import indentation

    pitch, sigma = 9.4, 0.2
    rows = np.arange(-6, 7)
    x, y = np.meshgrid(rows * pitch, rows * pitch * (np.sqrt(3) / 2 if grid == "hex" else 1.0))
    if grid == "hex":
        x = x + (rows[:, None] % 2) * pitch / 2
    xy = np.c_[x.ravel(), y.ravel()]
    drape = 8.0 * (1.0 - np.sum(xy**2, axis=1) / 80.0**2)  # mm: a bowl, its Laplacian -4 x 8 / 80^2
    estimates = []
    for seed in range(5):
        z = -drape + np.random.default_rng(seed).normal(0.0, sigma, len(xy))
        estimates.append(indentation(np.c_[xy, z], np.zeros(len(xy)), pitch_mm=pitch).noise_mm)
    assert 0.75 * sigma < np.median(estimates) < 1.25 * sigma


def _jittered_grid(rng, pitch_mm=6.0):
    """Marker centres (x, y) of a square grid over +-40 mm, each moved by 0.2 mm of noise."""
    g = np.arange(-40.0, 40.1, pitch_mm)
    gx, gy = np.meshgrid(g, g)
    return np.column_stack([gx.ravel(), gy.ravel()]) + rng.normal(0, 0.2, (gx.size, 2))


def _shared_and_each(points, references, pitch_mm=6.0):
    """The indentations against ``references`` in one shared pass, and each from its own call."""
    from softjig.sensing.contact import indentation, indentations

    shared = indentations(points, references, pitch_mm=pitch_mm)
    return shared, tuple(indentation(points, z, pitch_mm=pitch_mm) for z in references)


def test_indentations_against_two_references_equal_one_call_each():
    """The reference frame's and the rest shape's indentation share their neighbour fits in one pass: each
    must be what its own call gives."""
    rng = np.random.default_rng(3)
    xy = _jittered_grid(rng)
    z = -0.004 * (xy**2).sum(axis=1) - 3.0 * (np.hypot(*xy.T) < 15) + rng.normal(0, 0.1, len(xy))
    points = np.column_stack([xy, z])
    reference = -0.004 * (xy**2).sum(axis=1) + rng.normal(0, 0.05, len(xy))
    rest = -0.0041 * (xy**2).sum(axis=1)
    both, each = _shared_and_each(points, (reference, rest))
    for shared, own in zip(both, each, strict=True):
        np.testing.assert_allclose(shared.depth_mm, own.depth_mm, rtol=0, atol=1e-12)
        assert shared.zero_mm == pytest.approx(own.zero_mm, abs=1e-12)
        assert shared.noise_mm == pytest.approx(own.noise_mm, rel=1e-12)
    assert both[0].noise_mm != pytest.approx(both[1].noise_mm)  # two different fields


def test_indentations_against_references_unknown_at_different_markers_equal_one_call_each():
    """A marker without a reference height in one reference must not leave the other's fits: the shared
    pass fits only markers finite in every column, so such references are measured one call each."""
    rng = np.random.default_rng(4)
    xy = _jittered_grid(rng)
    points = np.column_stack([xy, -0.004 * (xy**2).sum(axis=1) + rng.normal(0, 0.1, len(xy))])
    reference = -0.004 * (xy**2).sum(axis=1)
    reference[::3] = np.nan  # markers with no reference marker near
    rest = -0.0041 * (xy**2).sum(axis=1)
    for shared, own in zip(*_shared_and_each(points, (reference, rest)), strict=True):
        np.testing.assert_array_equal(shared.depth_mm, own.depth_mm)
        assert (shared.zero_mm, shared.noise_mm) == (own.zero_mm, own.noise_mm)


def test_indentation_refuses_references_and_markers_of_another_shape():
    """A reference shorter than the markers, one of two columns, or markers without their z were read past
    their ends (a noise of 1e-6 mm, or a depth per reference entry) instead of refused."""
    from softjig.errors import InputError
    from softjig.sensing.contact import indentation, indentations

    g = np.arange(-40.0, 40.1, 6.0)
    gx, gy = np.meshgrid(g, g)
    points = np.column_stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)])
    n = len(points)
    for reference in (np.zeros(n - 50), np.zeros(n + 50), np.zeros((n, 2))):
        with pytest.raises(InputError, match="reference height per marker"):
            indentation(points, reference, pitch_mm=6.0)
    with pytest.raises(InputError, match="reference height per marker"):
        indentations(points, (), pitch_mm=6.0)
    with pytest.raises(InputError, match=r"\(M, 3\) markers"):
        indentation(points[:, :2], np.zeros(n), pitch_mm=6.0)


def _steep_dent(xy: np.ndarray) -> np.ndarray:
    """Depths (mm) of a 40-deg face pressed 6 mm in over a 25 mm disc (tilted towards +x), with a wall
    that falls at 70 deg from its edge: markers on a steep wall and a steep face, both on the membrane."""
    face = 6.0 + np.tan(np.radians(40.0)) * xy[:, 0]
    outside = np.maximum(np.hypot(*xy.T) - 25.0, 0.0)
    return np.maximum(np.where(outside > 0, face - np.tan(np.radians(70.0)) * outside, face), 0.0)


def test_points_off_the_membrane_are_the_mismatched_ones():
    """Two neighbouring markers of a row matched to their row's next markers lie 20 mm too deep (they
    support each other), one lies 15 mm too high; a marker of unknown depth and a lone marker with no
    neighbour are not judged. The steep face and wall stay: each marker is within a 45-deg step of a
    neighbour."""
    xy = _grid(60.0)
    depth = _steep_dent(xy)
    rng = np.random.default_rng(3)
    depth += rng.normal(0.0, 0.05, len(depth))
    row = np.flatnonzero((xy[:, 1] == 4.0) & np.isin(xy[:, 0], [-12.0, -4.0]))  # under the face
    high = int(np.flatnonzero((xy[:, 0] == 36.0) & (xy[:, 1] == 20.0))[0])  # on the wall
    unknown = int(np.flatnonzero((xy[:, 0] == 4.0) & (xy[:, 1] == 36.0))[0])
    depth[row] += 20.0
    depth[high] -= 15.0
    depth[unknown] = np.nan
    # a lone marker and a lone pair, at the edge of the view: no neighbour outside them to judge them by
    xy = np.vstack([xy, [[200.0, 0.0], [300.0, 0.0], [300.0 + PITCH, 0.0]]])
    depth = np.append(depth, [25.0, 20.0, 19.0])
    points = np.column_stack([xy, REST_Z - depth])
    off = off_the_membrane(points, depth, pitch_mm=PITCH, noise_mm=0.05, min_points=6)
    assert len(row) == 2
    assert sorted(np.flatnonzero(off)) == sorted([*row, high])


def test_a_block_of_mismatched_points_larger_than_a_contact_is_off_the_membrane_inside_the_plate():
    """Two rows of three mismatched points, each within a 45-deg step of the next: a group as large as
    a contact may be, but four of them triangulate inside the base plate (z < 0), which leaves two."""
    xy = _grid(60.0)
    depth = _steep_dent(xy)
    block = np.flatnonzero(np.isin(xy[:, 1], [-4.0, 4.0]) & np.isin(xy[:, 0], [-20.0, -12.0, -4.0]))
    points = np.column_stack([xy, REST_Z - depth])
    points[block, 2] = [-2.0, 1.0, -3.0, -1.5, 0.5, -2.5]
    depth = REST_Z - points[:, 2]
    assert len(block) == 6
    off = off_the_membrane(points, depth, pitch_mm=PITCH, noise_mm=0.05, min_points=6)
    assert sorted(np.flatnonzero(off)) == sorted(block)


def test_steps_are_judged_at_the_depths_noise_and_the_plate_at_the_heights_noise():
    """With a reference frame a marker's depth scatters less than its height (the reference cancels what
    biases the marker's height in both frames). A point 19.5 mm too deep under a 40-deg face is off the
    membrane at the depths' noise (0.05 mm), though a step at the heights' noise (0.5 mm) would join it
    to the face beside it; a membrane whose heights read 1 mm low (inside the plate by 2 of the heights'
    sigmas) is not off it, though it would be at the depths' noise."""
    xy = _grid(60.0)
    depth = _steep_dent(xy)
    spike = int(np.flatnonzero((xy[:, 0] == -4.0) & (xy[:, 1] == 4.0))[0])
    depth[spike] += 19.5
    points = np.column_stack([xy, REST_Z - depth])
    off = off_the_membrane(points, depth, pitch_mm=PITCH, noise_mm=0.05, height_noise_mm=0.5, min_points=6)
    assert np.flatnonzero(off).tolist() == [spike]
    assert not off_the_membrane(points, depth, pitch_mm=PITCH, noise_mm=0.5, min_points=6).any()
    low = np.column_stack([xy, np.full(len(xy), -1.0)])
    at_rest = np.zeros(len(xy))
    kept = off_the_membrane(low, at_rest, pitch_mm=PITCH, noise_mm=0.05, height_noise_mm=0.5, min_points=6)
    assert not kept.any()
    assert off_the_membrane(low, at_rest, pitch_mm=PITCH, noise_mm=0.05, min_points=6).all()


def test_the_markers_at_rest_are_those_over_two_pitches_from_every_pushed_in_or_unknown_one():
    """The markers a loaded frame levels the head on: far from the dent (pushed in 1.5 noise sigmas or
    more) and from a marker of unknown depth (a point left out), all of them when nothing is pushed."""
    xy = _grid(60.0)
    points = np.column_stack([xy, np.full(len(xy), REST_Z)])
    noise = 0.1
    assert markers_at_rest(points, Indentation(np.zeros(len(xy)), 0.0, noise), pitch_mm=PITCH).all()
    depth = np.where(np.hypot(xy[:, 0] - 12.0, xy[:, 1] + 4.0) <= 8.0, 2.0, 0.0)  # a dent of 5 markers
    depth[np.flatnonzero((xy[:, 0] == -44.0) & (xy[:, 1] == -4.0))] = np.nan  # a point left out
    depth[np.flatnonzero((xy[:, 0] == -4.0) & (xy[:, 1] == 36.0))] = 1.4 * noise  # noise, at rest
    at_rest = markers_at_rest(points, Indentation(depth, 0.0, noise), pitch_mm=PITCH)
    not_at_rest = xy[~(np.nan_to_num(depth, nan=np.inf) < 1.5 * noise)]  # the dent and the unknown one
    assert len(not_at_rest) == 6
    distance = np.hypot(*(xy[:, None, :] - not_at_rest[None, :, :]).transpose(2, 0, 1)).min(axis=1)
    expected = distance >= 2 * PITCH
    assert at_rest.tolist() == expected.tolist()
    assert 0 < at_rest.sum() < len(xy)


def test_no_point_is_off_the_membrane_at_rest_or_under_a_steep_face():
    xy = _grid(60.0)
    for depth in (np.zeros(len(xy)), _steep_dent(xy)):
        points = np.column_stack([xy, REST_Z - depth])
        assert not off_the_membrane(points, depth, pitch_mm=PITCH, noise_mm=0.05, min_points=6).any()


def test_a_block_of_mismatched_points_just_above_the_plate_is_off_the_unloaded_membrane():
    """An unloaded membrane is one smooth sheet: a block of six points (two rows of three) that
    triangulate 1-3 mm above the plate, under the dome's top, is off it although it is as large as a
    contact may be; every other marker, on the rest shape with 0.05 mm noise, stays."""
    jig = default_jig()
    xy = marker_layout_xy(jig)
    rng = np.random.default_rng(5)
    points = np.column_stack(
        [xy, rest_inner_height_mm(jig, xy[:, 0], xy[:, 1]) + rng.normal(0, 0.05, len(xy))]
    )
    pitch = jig.markers.pitch_mm
    block = np.argsort(np.hypot(xy[:, 0] - pitch, xy[:, 1] - pitch / 2))[:6]
    points[block, 2] = rng.uniform(1.0, 3.0, 6)
    assert not off_the_rest_membrane(np.delete(points, block, axis=0), jig).any()
    assert sorted(np.flatnonzero(off_the_rest_membrane(points, jig))) == sorted(block)


def test_membrane_groups_are_the_components_of_the_step_graph():
    """The compiled groups of :func:`off_the_membrane` against scipy's k-d tree pairs and sparse
    connected components: the same partition, and the same markers with a neighbour they do not step to."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    from softjig.sensing._contact_kernels import membrane_groups

    rng = np.random.default_rng(8)
    for trial in range(20):
        xy = _marker_cloud(rng, 150 + trial)
        depth = np.where(rng.random(len(xy)) < 0.1, rng.uniform(5, 30, len(xy)), rng.normal(0, 0.1, len(xy)))
        group, cut = membrane_groups(xy, depth, 12.0, 1.0, 0.5)
        pairs = cKDTree(xy).query_pairs(12.0, output_type="ndarray")
        i, j = pairs.T
        step = np.abs(depth[i] - depth[j]) <= np.hypot(*(xy[i] - xy[j]).T) + 0.5
        n = len(xy)
        _, expected = connected_components(
            coo_matrix((np.ones(step.sum()), (i[step], j[step])), shape=(n, n))
        )
        same = expected[:, None] == expected[None, :]
        assert np.array_equal(group[:, None] == group[None, :], same)
        expected_cut = np.zeros(n, dtype=bool)
        expected_cut[i[~step]] = expected_cut[j[~step]] = True
        assert np.array_equal(cut, expected_cut)


def test_the_scatter_of_the_pushed_in_markers_is_theirs_not_the_membranes_at_rest():
    """Beads pressing through the membrane where a face holds it ripple its markers (0.15 mm here) more
    than the membrane at rest scatters (0.03 mm): the pushed-in markers' scatter is theirs, within 25 %,
    whatever the tilted face's plane; where too few are pushed in, it is not measured (NaN)."""
    from softjig.sensing.contact import Indentation, indentation, pushed_in_scatter_mm

    pitch, rest_sigma, ripple = 5.0, 0.03, 0.15
    g = np.arange(-60.0, 60.1, pitch)
    gx, gy = np.meshgrid(g, g)
    xy = np.column_stack([gx.ravel(), gy.ravel()])
    estimates, at_rest = [], []
    for seed in range(5):
        rng = np.random.default_rng(seed)
        face = np.hypot(xy[:, 0] - 10.0, xy[:, 1]) < 30.0
        depth = np.where(face, 3.0 + 0.1 * xy[:, 0] + rng.normal(0.0, ripple, len(xy)), 0.0)
        depth += rng.normal(0.0, rest_sigma, len(xy))
        points = np.column_stack([xy, -depth])
        dent = indentation(points, np.zeros(len(xy)), pitch_mm=pitch)
        at_rest.append(dent.noise_mm)
        estimates.append(pushed_in_scatter_mm(points, dent, face, pitch_mm=pitch))
    assert 0.75 * ripple < np.median(estimates) < 1.25 * ripple
    assert np.median(at_rest) < 2 * rest_sigma  # the whole membrane's noise does not see the ripple
    few = np.zeros(len(xy), dtype=bool)
    few[:9] = True
    assert np.isnan(pushed_in_scatter_mm(points, Indentation(depth, 0.0, 0.03), few, pitch_mm=pitch))
