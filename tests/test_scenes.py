"""The shared scenes of conftest.py: what they promise (read-only, the stated scene, one seed one pair)."""

from __future__ import annotations

import numpy as np
import pytest

from estimator_cases import coarse_jig, fine_grid_jig, oil_above_plate_jig
from scenes import DEFAULT_POSE, render_scene
from softjig.config import CylinderPart
from softjig.sim.asbuilt import draw_as_built
from softjig.sim.render import render_pair


@pytest.mark.parametrize("name", ["default_scene", "unloaded_scene"])
def test_a_session_scene_cannot_be_written_into(request, name):
    scene = request.getfixturevalue(name)
    arrays = [
        scene.left,
        scene.right,
        scene.pair.markers.xyz_mm,
        scene.pair.markers.left_px,
        scene.pair.fiducial_corners_left_px,
        scene.as_built.marker_xy_mm,
    ]
    for array in arrays:
        with pytest.raises(ValueError, match="read-only"):
            array[...] = 0


def test_the_default_scene_is_the_benchmarks_first_pair(default_scene):
    """benchmarks/bench_estimate.py's first pair: a 50 mm part at 10 deg, as-built and render seed 0."""
    pair = render_pair(draw_as_built(default_scene.jig, rng=0), CylinderPart(50.0), DEFAULT_POSE, rng=0)
    assert np.array_equal(pair.left, default_scene.left) and np.array_equal(pair.right, default_scene.right)
    assert default_scene.part == CylinderPart(50.0) and default_scene.pose == DEFAULT_POSE


def test_the_unloaded_scene_has_no_part_and_the_default_as_built_jig(default_scene, unloaded_scene):
    assert unloaded_scene.part is None and unloaded_scene.pose is None
    assert not unloaded_scene.pair.markers.in_contact.any()
    assert unloaded_scene.as_built.jig == default_scene.as_built.jig
    assert np.array_equal(unloaded_scene.as_built.marker_xy_mm, default_scene.as_built.marker_xy_mm)


def test_one_seed_gives_one_pair_and_another_seed_another(default_scene):
    again = render_scene(seed=default_scene.seed)
    other = render_scene(seed=default_scene.seed + 1)
    assert np.array_equal(again.left, default_scene.left)
    assert not np.array_equal(other.left, default_scene.left)
    assert render_scene(as_built_seed=None).as_built.jig == default_scene.jig  # None: exactly as designed


def test_the_trust_cases_have_the_static_bead_speckle():
    """estimator_cases' designs are about a bead pack that stays put: the simulator's default."""
    assert all(jig.medium.speckle_static for jig in (fine_grid_jig(), coarse_jig(), oil_above_plate_jig()))
