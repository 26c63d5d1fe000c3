"""Scenarios (pure frame lists) and the simulator that renders them into a dataset."""

from __future__ import annotations

import math

import numpy as np
import pytest

from softjig.config import CylinderPart, default_jig
from softjig.errors import InputError
from softjig.geometry import fit_plane_svd, normal_from_tilt
from softjig.io.dataset import Dataset
from softjig.io.simulated import simulate_dataset
from softjig.jig_shape import rest_inner_height_mm
from softjig.sim.parts import PartPose
from softjig.sim.scenarios import (
    FrameSpec,
    cube_experiment,
    frame_truth,
    paper_sweep,
    single,
    theta_values_deg,
)

# --------------------------------------------------------------------------------------- scenarios


def test_paper_sweep_default_counts_and_order():
    specs = list(paper_sweep())
    assert len(specs) == 1 + 6 * 4 * 36
    ref = specs[0]
    assert ref.part is None and ref.pose is None and ref.meta == {"reference": True}
    first, last = specs[1], specs[-1]
    assert first.part == CylinderPart(diameter_mm=30.0, height_mm=30.0)
    assert (first.meta["alpha_deg"], first.meta["theta_deg"]) == (5.0, 0.0)
    assert last.part.diameter_mm == 80.0
    assert last.meta["alpha_deg"] == pytest.approx(20.0) and last.meta["theta_deg"] == pytest.approx(350.0)
    assert all(s.pose.center_xy_mm == (0.0, 0.0) and s.pose.push_depth_mm == 3.0 for s in specs[1:])
    assert first.meta["part"] == {"diameter_mm": 30.0, "height_mm": 30.0, "kind": "cylinder"}


def test_small_sweep():
    specs = list(paper_sweep(diameters_mm=[50], alphas_deg=[10], theta_step_deg=90))
    assert len(specs) == 1 + 4
    assert [s.meta["theta_deg"] for s in specs[1:]] == pytest.approx([0, 90, 180, 270])
    assert specs[2].pose.alpha_rad == pytest.approx(math.radians(10))
    assert len(list(paper_sweep(diameters_mm=[50], alphas_deg=[10], reference=False))) == 36


def test_theta_values():
    assert len(theta_values_deg(7)) == 52 and max(theta_values_deg(7)) < 360
    assert theta_values_deg(360) == [0.0]
    assert len(theta_values_deg(10)) == 36


@pytest.mark.parametrize(
    "kwargs",
    [
        {"diameters_mm": [0]},
        {"diameters_mm": []},
        {"alphas_deg": [95]},
        {"alphas_deg": [-1]},
        {"theta_step_deg": 0},
        {"theta_step_deg": float("nan")},
        {"push_depth_mm": float("inf")},
    ],
)
def test_paper_sweep_rejects_bad_values(kwargs):
    with pytest.raises(InputError):
        list(paper_sweep(**kwargs))


def test_cube_experiment():
    specs = cube_experiment(n_frames=40, rng=3)
    assert len(specs) == 41 and specs[0].meta["reference"]
    again = cube_experiment(n_frames=40, rng=3)
    assert [s.pose for s in specs] == [s.pose for s in again]
    poses = [s.pose for s in specs[1:]]
    assert all(0 <= p.alpha_rad <= math.radians(15) for p in poses)
    assert all(math.hypot(*p.center_xy_mm) <= 3.0 for p in poses)
    assert len({round(p.yaw_rad, 6) for p in poses}) == 40
    assert specs[1].meta["part"]["kind"] == "box" and specs[1].part.size_x_mm == 50.0
    assert len(cube_experiment(n_frames=5, reference=False, rng=0)) == 5


def test_single():
    (spec,) = single(CylinderPart(60.0), 12.0, 45.0, 2.0)
    assert spec.pose == PartPose(math.radians(12), math.radians(45), 2.0)
    assert spec.meta["alpha_deg"] == pytest.approx(12.0)
    assert len(single(CylinderPart(60.0), 12.0, 45.0, reference=True)) == 2
    with pytest.raises(InputError):
        single(CylinderPart(60.0), 90.0, 0.0)


def test_frame_spec_needs_part_and_pose_together():
    with pytest.raises(ValueError, match="both"):
        FrameSpec(CylinderPart(50.0), None)


def test_frame_truth_definition():
    jig = default_jig()
    t = jig.membrane.thickness_mm
    for alpha_deg, theta_deg in [(0, 0), (10, 30), (20, 200)]:
        pose = PartPose(math.radians(alpha_deg), math.radians(theta_deg), 3.0)
        truth = frame_truth(jig, pose)
        np.testing.assert_allclose(
            truth["normal"], normal_from_tilt(pose.alpha_rad, pose.theta_rad), atol=1e-12
        )
        expected = 3.0 + t * (1 / math.cos(pose.alpha_rad) - 1)
        assert truth["push_depth_mm"] == pytest.approx(expected, abs=1e-9)
        assert np.asarray(truth["T_J_part"]).shape == (4, 4)


# ---------------------------------------------------------------------------------------- simulate


@pytest.fixture(scope="module")
def small_specs():
    return list(paper_sweep(diameters_mm=[50], alphas_deg=[10], theta_step_deg=90))


@pytest.fixture(scope="module")
def sim_w1(tmp_path_factory, small_specs):
    out = tmp_path_factory.mktemp("sim") / "w1"
    return simulate_dataset(out, small_specs, default_jig(), seed=7, workers=1, progress=False)


def _assert_same_dataset(a, b):
    da, db = Dataset.open(a), Dataset.open(b)
    assert len(da) == len(db)
    for fa, fb in zip(da, db, strict=True):
        assert fa.meta == fb.meta
        np.testing.assert_array_equal(fa.load_left(), fb.load_left())
        np.testing.assert_array_equal(fa.load_right(), fb.load_right())
        ta, tb = fa.load_truth_markers(), fb.load_truth_markers()
        assert set(ta) == set(tb)
        for k in ta:
            np.testing.assert_array_equal(ta[k], tb[k])


def test_simulated_dataset_contents(sim_w1, small_specs):
    ds = Dataset.open(sim_w1)
    assert len(ds) == 5
    assert ds.jig == default_jig()  # rig.toml is the NOMINAL jig
    as_built = ds.as_built()
    assert as_built.jig.cameras != ds.jig.cameras  # drawn within the tolerances
    ref = ds[0]
    assert ref.reference and ref.part is None and ref.alpha_deg is None
    truth = ref.load_truth_markers()
    assert not truth["in_contact"].any()
    assert len(truth["xyz_mm"]) == len(as_built.marker_xy_mm)
    for frame in ds.frames[1:]:
        assert frame.part == CylinderPart(50.0) and frame.alpha_deg == pytest.approx(10.0)
        left = frame.load_left()
        assert left.dtype == np.uint8 and left.shape == (720, 1280)
        m = frame.load_truth_markers()
        for name in ("xyz_mm", "axis", "left_px", "right_px"):
            assert len(m[name]) == len(m["in_contact"])
        assert m["fiducial_corners_left_px"].shape[1:] == (4, 2)


def test_truth_matches_the_rendered_markers(sim_w1):
    """The markers in contact lie on the plane the truth describes (to the ripple)."""
    ds = Dataset.open(sim_w1)
    jig = ds.as_built().jig
    h_rest = float(rest_inner_height_mm(jig, np.zeros(1), np.zeros(1))[0])
    for frame in ds.frames[1:]:
        m = frame.load_truth_markers()
        pts = m["xyz_mm"][m["in_contact"]]
        assert len(pts) > 10
        fit = fit_plane_svd(pts)
        angle = np.degrees(np.arccos(np.clip(fit.normal @ frame.truth.normal, -1, 1)))
        assert angle < 0.5
        assert h_rest - fit.z_at(0.0, 0.0) == pytest.approx(frame.truth.push_depth_mm, abs=0.1)
        np.testing.assert_allclose(frame.truth.T_J_part[:3, 2], frame.truth.normal)


def test_workers_do_not_change_the_result(sim_w1, small_specs, tmp_path):
    out = simulate_dataset(tmp_path / "w2", small_specs, default_jig(), seed=7, workers=2, progress=False)
    _assert_same_dataset(sim_w1, out)


def test_seed_changes_the_result(sim_w1, small_specs, tmp_path):
    out = simulate_dataset(tmp_path / "s8", small_specs[:2], default_jig(), seed=8, workers=1, progress=False)
    a, b = Dataset.open(sim_w1), Dataset.open(out)
    assert not np.array_equal(a[1].load_left(), b[1].load_left())


def test_simulate_refuses_existing_dataset_and_bad_arguments(sim_w1, small_specs, tmp_path):
    with pytest.raises(InputError, match="already holds a dataset"):
        simulate_dataset(sim_w1, small_specs, default_jig(), seed=7, workers=1, progress=False)
    with pytest.raises(InputError, match="seed"):
        simulate_dataset(tmp_path / "x", small_specs, default_jig(), seed=-1, progress=False)
    with pytest.raises(InputError, match="workers"):
        simulate_dataset(tmp_path / "x", small_specs, default_jig(), seed=0, workers=0, progress=False)
    too_big = single(CylinderPart(200.0), 0.0, 0.0)
    with pytest.raises(InputError, match="wider than the membrane"):
        simulate_dataset(tmp_path / "x", too_big, default_jig(), seed=0, workers=1, progress=False)
    assert not (tmp_path / "x").exists()
