"""The self-check's split halves and rival contacts: a flat face passes, a curved wall or a wall beside
the face does not (issue 13 item 6)."""

from __future__ import annotations

import numpy as np
import pytest

from softjig.config import default_jig
from softjig.errors import InputError
from softjig.geometry import fit_plane_svd
from softjig.jig_shape import rest_inner_height_mm
from softjig.sensing.selfcheck import SPLIT_SUSPECT_MIN_DEG, agreement, rougher, split_halves


def _grid(centre, radius, pitch=5.0):
    g = np.arange(-radius, radius + 1e-9, pitch)
    xy = np.stack(np.meshgrid(g, g), -1).reshape(-1, 2)
    return xy[np.hypot(*xy.T) <= radius] + np.asarray(centre)


def test_a_noisy_tilted_plane_passes():
    rng = np.random.default_rng(0)
    for trial in range(20):
        xy = _grid((0.0, 0.0), 25.0)
        sigma_mm = 0.2
        z = -5.0 + 0.2 * xy[:, 0] - 0.1 * xy[:, 1] + rng.normal(0, sigma_mm, len(xy))
        check = split_halves(np.column_stack([xy, z]), point_sigma_mm=sigma_mm, noise_factor=1.35)
        assert check is not None and not check.suspect, trial
        assert check.excess_rad < np.radians(1.0)


def test_the_membranes_wall_is_suspect():
    """A strip of the rest membrane's steep rim, fitted as if it were a face: its halves disagree."""
    jig = default_jig()
    rng = np.random.default_rng(1)
    xy = _grid((62.0, 0.0), 14.0)
    sigma_mm = 0.1
    z = rest_inner_height_mm(jig, xy[:, 0], xy[:, 1]) + rng.normal(0, sigma_mm, len(xy))
    check = split_halves(np.column_stack([xy, z]), point_sigma_mm=sigma_mm, noise_factor=1.35)
    assert check.suspect
    assert np.degrees(check.angle_rad) > SPLIT_SUSPECT_MIN_DEG


def test_too_few_points_give_no_check():
    xy = _grid((0.0, 0.0), 6.0)
    assert split_halves(np.column_stack([xy, np.zeros(len(xy))]), point_sigma_mm=0.1) is None


def _fit(points):
    return fit_plane_svd(points).normal


def test_two_samples_of_one_face_agree():
    """Two contacts of the same noisy face (different markers): their normals agree within the noise."""
    rng = np.random.default_rng(2)
    for trial in range(20):
        a, b = _grid((-8.0, 0.0), 12.0), _grid((8.0, 0.0), 12.0)
        sigma_mm = 0.3
        pa = np.column_stack([a, -4.0 + 0.3 * a[:, 0] + rng.normal(0, sigma_mm, len(a))])
        pb = np.column_stack([b, -4.0 + 0.3 * b[:, 0] + rng.normal(0, sigma_mm, len(b))])
        check = agreement(pa, _fit(pa), pb, _fit(pb), point_sigma_mm=sigma_mm, noise_factor=1.5)
        assert check is not None and not check.suspect, trial


def test_a_face_and_the_wall_beside_it_disagree():
    """A level face and a strip of wall rising at 15 deg beside it, each fitted alone: a rival."""
    rng = np.random.default_rng(3)
    sigma_mm = 0.3
    face, wall = _grid((0.0, 0.0), 12.0), _grid((25.0, 0.0), 8.0)
    pf = np.column_stack([face, -6.0 + rng.normal(0, sigma_mm, len(face))])
    pw = np.column_stack([wall, -6.0 + np.tan(np.radians(15.0)) * (wall[:, 0] - 17.0)])
    pw[:, 2] += rng.normal(0, sigma_mm, len(wall))
    check = agreement(pf, _fit(pf), pw, _fit(pw), point_sigma_mm=sigma_mm, noise_factor=1.5)
    assert check.suspect and abs(np.degrees(check.angle_rad) - 15.0) < 2.0
    assert agreement(pf[:3], _fit(pf), pw, _fit(pw), point_sigma_mm=sigma_mm) is None  # too few


def test_a_curved_wall_is_rougher_than_a_flat_face():
    """:func:`rougher`: the p-value is small where the first set scatters about its plane more than the
    second (a wall curving up to the rest shape beside a flat face), about one half for two flat faces of
    the same noise, and large the other way round."""
    rng = np.random.default_rng(3)
    xy = rng.uniform(-15.0, 15.0, size=(20, 2))
    face = np.c_[xy, 0.2 * xy[:, 0] + rng.normal(0.0, 0.2, 20)]
    wall = np.c_[xy, 0.2 * xy[:, 0] + 0.02 * xy[:, 0] ** 2 + rng.normal(0.0, 0.2, 20)]
    twin = np.c_[xy, 0.2 * xy[:, 0] + rng.normal(0.0, 0.2, 20)]
    plane = {name: fit_plane_svd(points) for name, points in (("face", face), ("wall", wall), ("twin", twin))}
    assert rougher(wall, plane["wall"], face, plane["face"]) < 0.01
    assert rougher(face, plane["face"], wall, plane["wall"]) > 0.99
    assert 0.05 < rougher(twin, plane["twin"], face, plane["face"]) < 0.95


def test_roughness_needs_four_markers():
    points = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    plane = fit_plane_svd(np.r_[points, [[1.0, 1.0, 0.0]]])
    with pytest.raises(InputError, match="4 markers or more"):
        rougher(points, plane, points, plane)
