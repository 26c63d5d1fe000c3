"""The self-check's split halves: a flat face passes, a curved wall does not (issue 13 item 6)."""

from __future__ import annotations

import numpy as np

from softjig.config import default_jig
from softjig.jig_shape import rest_inner_height_mm
from softjig.sensing.selfcheck import SPLIT_SUSPECT_MIN_DEG, split_halves


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
