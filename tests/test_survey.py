"""Self-survey: the unloaded jig's markers become the rig's measured layout and rest shape."""

import json
import math
from dataclasses import replace

import numpy as np
import pytest
from typer.testing import CliRunner

from softjig.cli import app
from softjig.config import (
    CylinderPart,
    RegularPolygonPart,
    default_jig,
    dumps_jig,
    exact_jig,
    load_jig,
    loads_jig,
)
from softjig.errors import InputError
from softjig.io.dataset import Dataset
from softjig.io.simulated import simulate_dataset
from softjig.jig_shape import rest_marker_points_mm, rest_profile_mm
from softjig.sensing.identities import rest_shape_reference
from softjig.sensing.pipeline import estimate_pair
from softjig.sensing.survey import smoothed_heights, survey_markers
from softjig.sim.parts import PartPose
from softjig.sim.scenarios import FrameSpec

runner = CliRunner()


def _loaded(part, pose):
    return FrameSpec(part, pose, {"alpha_deg": math.degrees(pose.alpha_rad), "theta_deg": 0.0})


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    """The default jig as built (markers 0.2 mm off their grid, head and indices off): its reference
    frame, then an off-centre hexagon pressed in 3 mm."""
    out = tmp_path_factory.mktemp("survey") / "ds"
    specs = [
        FrameSpec(None, None, {"reference": True}),
        _loaded(
            RegularPolygonPart(6, 45.0),
            PartPose(math.radians(8), math.radians(30), 3.0, center_xy_mm=(6.0, -4.0), yaw_rad=0.2),
        ),
    ]
    simulate_dataset(out, specs, default_jig(), seed=11, workers=1, progress=False)
    return Dataset.open(out)


def test_survey_is_closer_to_the_as_built_markers_than_the_drawing(dataset, tmp_path):
    out = tmp_path / "surveyed.toml"
    result = runner.invoke(app, ["survey", str(dataset.root), "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert "lateral median" in result.output
    jig = load_jig(out)
    assert jig.markers.layout == "explicit" and len(jig.markers.centers_z_mm) == len(jig.markers.centers_mm)
    assert jig.membrane.dome_profile == "table"
    truth = dataset[0].load_truth_markers()["xyz_mm"]  # every marker of the as-built jig at rest
    surveyed = rest_marker_points_mm(jig)
    # each surveyed marker is the as-built marker nearest to it
    nearest = np.argmin(np.linalg.norm(surveyed[:, None, :2] - truth[None, :, :2], axis=2), axis=1)
    survey_error = np.hypot(*(surveyed[:, :2] - truth[nearest, :2]).T)
    nominal = rest_marker_points_mm(dataset.jig)
    from_nominal = np.argmin(np.linalg.norm(truth[nearest, None, :2] - nominal[None, :, :2], axis=2), axis=1)
    nominal_error = np.hypot(*(nominal[from_nominal, :2] - truth[nearest, :2]).T)
    assert len(surveyed) > 200
    assert np.median(survey_error) < 0.5 * np.median(nominal_error)
    assert np.percentile(survey_error, 95) < np.percentile(nominal_error, 95)
    # the estimator's rest-shape reference is the surveyed one
    assert np.array_equal(rest_shape_reference(jig).xyz_mm, surveyed)
    # heights: the measured table follows the as-built dome (here the drawn one) within the noise
    r = np.linspace(0.0, 80.0, 9)
    assert np.allclose(rest_profile_mm(jig, r)[0], rest_profile_mm(dataset.jig, r)[0], atol=0.5)


def test_surveyed_rig_estimates_as_well(dataset, tmp_path):
    out = tmp_path / "surveyed.toml"
    assert runner.invoke(app, ["survey", str(dataset.root), "--out", str(out)]).exit_code == 0
    frame = dataset[1]
    truth = frame.truth.normal
    errors = []
    for jig in (dataset.jig, load_jig(out)):
        n = estimate_pair(frame.load_left(), frame.load_right(), jig).estimate.normal
        errors.append(math.degrees(math.acos(min(1.0, abs(float(np.dot(n, truth)))))))
    assert errors[1] < 1.0 and errors[1] < errors[0] + 0.3, errors


def test_survey_report_as_json(dataset, tmp_path):
    out = tmp_path / "s.toml"
    result = runner.invoke(app, ["survey", str(dataset.root), "--out", str(out), "--json"])
    assert result.exit_code == 0, result.output
    report = json.loads(result.stdout)
    s = report["summary"]
    assert s["markers_surveyed"] == len(report["markers"]) == len(load_jig(out).markers.centers_mm)
    assert s["markers_nominal"] == len(rest_marker_points_mm(dataset.jig))
    for row in report["markers"][:20]:
        assert np.allclose(np.subtract(row["measured_mm"], row["nominal_mm"]), row["offset_mm"])
    # as built, each marker is 0.2 mm (one sigma per axis) off the grid: median lateral offset ~0.24 mm
    assert 0.1 < s["lateral_median_mm"] < 0.5
    assert s["lateral_max_mm"] >= s["lateral_median_mm"]


def test_survey_of_a_loaded_pair_is_refused(dataset, tmp_path):
    frame = dataset[1]
    out = tmp_path / "s.toml"
    result = runner.invoke(
        app,
        [
            "survey",
            str(frame.left_path),
            str(frame.right_path),
            "--config",
            str(dataset.root / "rig.toml"),
            "--out",
            str(out),
        ],
    )
    assert result.exit_code == 2, result.output
    assert "loaded" in result.output and "part is pressed" in result.output
    assert not out.exists()


def test_survey_of_a_pair_of_noise_is_refused(dataset, tmp_path):
    """Noise triangulates a dozen stray points, most within half a pitch of some marker and too scattered
    for the dent check: a survey of them would write a rig of a dozen markers."""
    from softjig.io.dataset import encode_png

    rng = np.random.default_rng(0)
    shape = (dataset.jig.cameras.left.height_px, dataset.jig.cameras.left.width_px)
    paths = []
    for side in ("left", "right"):
        paths.append(tmp_path / f"{side}.png")
        paths[-1].write_bytes(encode_png(rng.integers(0, 255, shape, dtype=np.uint8)))
    out = tmp_path / "s.toml"
    args = ["survey", *map(str, paths), "--config", str(dataset.root / "rig.toml"), "--out", str(out)]
    result = runner.invoke(app, args)
    assert result.exit_code == 2, result.output
    assert "half a pitch" in result.output
    assert not out.exists()


def test_survey_of_one_unloaded_pair(dataset, tmp_path):
    frame = dataset[0]
    out = tmp_path / "s.toml"
    csv = tmp_path / "markers.csv"
    args = ["survey", str(frame.left_path), str(frame.right_path), "--out", str(out)]
    result = runner.invoke(app, args)
    assert result.exit_code == 2 and "--config" in result.output  # a pair needs its nominal rig
    rig = str(dataset.root / "rig.toml")
    result = runner.invoke(app, [*args, "--config", rig, "--markers-csv", str(csv)])
    assert result.exit_code == 0, result.output
    assert csv.read_text().startswith("x_mm,y_mm,z_mm\n")
    # the CSV makes the same layout through `softjig config --markers-csv`
    again = tmp_path / "again.toml"
    result = runner.invoke(app, ["config", "--config", rig, "--markers-csv", str(csv), "--out", str(again)])
    assert result.exit_code == 0, result.output
    assert load_jig(again).markers.centers_mm == load_jig(out).markers.centers_mm


def test_survey_never_silently_replaces_the_input_rig(dataset, tmp_path):
    rig = dataset.root / "rig.toml"
    before = rig.read_bytes()
    result = runner.invoke(app, ["survey", str(dataset.root), "--out", str(rig)])
    assert result.exit_code == 2 and "the rig the survey reads" in result.output
    assert rig.read_bytes() == before
    out = tmp_path / "s.toml"
    out.write_text("mine")
    result = runner.invoke(app, ["survey", str(dataset.root), "--out", str(out)])
    assert result.exit_code == 2 and out.read_text() == "mine"
    result = runner.invoke(app, ["survey", str(dataset.root), "--out", str(out), "--overwrite"])
    assert result.exit_code == 0 and load_jig(out).markers.layout == "explicit"


def test_dataset_without_a_reference_frame(tmp_path):
    out = tmp_path / "ds"
    spec = _loaded(CylinderPart(40.0), PartPose(0.0, 0.0, 3.0))
    simulate_dataset(out, [spec], default_jig(), seed=1, workers=1, progress=False)
    result = runner.invoke(app, ["survey", str(out), "--out", str(tmp_path / "s.toml")])
    assert result.exit_code == 2 and "reference" in result.output


# ---------------------------------------------------------------------------------- pure, no images

JIG = exact_jig()


def _rest_points(noise_mm=0.15, seed=0):
    rng = np.random.default_rng(seed)
    xyz = rest_marker_points_mm(JIG).copy()
    xyz[:, :2] += rng.normal(0.0, 0.2, (len(xyz), 2))
    from softjig.jig_shape import rest_inner_height_mm

    xyz[:, 2] = rest_inner_height_mm(JIG, *xyz[:, :2].T) + rng.normal(0.0, noise_mm, len(xyz))
    return xyz


def test_survey_of_synthetic_rest_points():
    points = _rest_points()
    survey = survey_markers(points, JIG)
    assert len(survey.measured_xyz_mm) == len(points)
    assert np.array_equal(survey.measured_xyz_mm[:, :2], points[survey.nominal_index, :2])  # own x, y
    assert loads_jig(dumps_jig(survey.jig)) == survey.jig
    h = np.asarray(survey.jig.membrane.profile_h_mm)
    assert np.all(np.diff(h) <= 0) and survey.jig.membrane.dome_height_mm == h[0]
    assert survey.dent.sigma_mm == pytest.approx(0.15, rel=0.3)


@pytest.mark.parametrize(
    ("push_mm", "radius_mm", "centre"),
    [(2.0, 25.0, (0.0, 0.0)), (1.5, 40.0, (0.0, 0.0)), (3.0, 15.0, (30.0, -20.0))],
)
def test_dented_points_are_refused(push_mm, radius_mm, centre):
    points = _rest_points()
    d = np.hypot(points[:, 0] - centre[0], points[:, 1] - centre[1])
    points[:, 2] -= push_mm * np.where(d < radius_mm, 1.0, np.exp(-(d - radius_mm) / 5.0))
    with pytest.raises(InputError, match="loaded"):
        survey_markers(points, JIG)


def test_a_smooth_build_error_is_not_a_part():
    """A tilted, offset stereo head (what the fiducials leave) is no part; a dome built 2 mm lower on
    top is refused unless the user accepts that departure."""
    points = _rest_points()
    points[:, 2] += 0.4 + 0.004 * points[:, 0] - 0.003 * points[:, 1]
    survey_markers(points, JIG)
    low = _rest_points()
    low[:, 2] -= 2.0 * np.exp(-((np.hypot(*low[:, :2].T) / 45.0) ** 2))
    with pytest.raises(InputError, match="max-deviation"):
        survey_markers(low, JIG)
    surveyed = survey_markers(low, JIG, max_deviation_mm=2.5)
    assert surveyed.jig.membrane.dome_height_mm == pytest.approx(28.0, abs=0.5)  # pooled monotone


def test_smoothing_halves_the_noise():
    points = _rest_points(noise_mm=0.2, seed=3)
    from softjig.jig_shape import rest_inner_height_mm

    truth = rest_inner_height_mm(JIG, *points[:, :2].T)
    inner = np.hypot(*points[:, :2].T) < 70
    raw = np.std((points[:, 2] - truth)[inner])
    smooth = np.std((smoothed_heights(points, JIG.markers.pitch_mm) - truth)[inner])
    assert smooth < 0.65 * raw


def test_too_few_markers():
    with pytest.raises(InputError, match="unloaded jig"):
        survey_markers(np.array([[0.0, 0.0, 30.0], [8.0, 0.0, 30.0]]), JIG)


def test_surveyed_layout_with_an_other_grid():
    """A rotated, offset hex grid: the survey matches each point to its own nominal marker."""
    jig = JIG.replace(markers=replace(JIG.markers, layout="hex", rotation_deg=15.0, offset_mm=(2.0, -3.0)))
    points = np.add(rest_marker_points_mm(jig), [0.1, -0.1, 0.0])
    survey = survey_markers(points, jig, smooth=False)
    assert np.allclose(survey.offset_mm, [0.1, -0.1, 0.0], atol=1e-6)
    assert survey.summary()["lateral_max_mm"] == pytest.approx(math.hypot(0.1, 0.1))


def test_survey_measures_a_dome_built_off_its_drawing(tmp_path):
    """The jig was built with a rounder dome (power 3) than its rig says (power 4), on a rotated hex
    grid: the survey refuses to take 3 mm of departure for granted, then, told so, measures the dome."""
    drawn = default_jig().replace(
        markers=replace(default_jig().markers, layout="hex", rotation_deg=15.0, offset_mm=(2.0, -3.0))
    )
    built = drawn.replace(membrane=replace(drawn.membrane, dome_exponent=3.0))
    out = tmp_path / "ds"
    simulate_dataset(
        out, [FrameSpec(None, None, {"reference": True})], built, seed=4, workers=1, progress=False
    )
    (out / "rig.toml").write_text(dumps_jig(drawn))  # the user's rig: the drawing
    surveyed = tmp_path / "s.toml"
    result = runner.invoke(app, ["survey", str(out), "--out", str(surveyed)])
    assert result.exit_code == 2 and "--max-deviation" in result.output
    result = runner.invoke(app, ["survey", str(out), "--out", str(surveyed), "--max-deviation", "4"])
    assert result.exit_code == 0, result.output
    jig = load_jig(surveyed)
    r = np.linspace(0.0, 80.0, 17)
    truth = rest_profile_mm(built, r)[0]
    measured_error = np.abs(rest_profile_mm(jig, r)[0] - truth)
    drawn_error = np.abs(rest_profile_mm(drawn, r)[0] - truth)
    assert drawn_error.max() > 3.0 and measured_error.max() < 0.6
    # and at the markers, the surveyed rest shape is the built one within the noise
    markers = rest_marker_points_mm(jig)
    from softjig.jig_shape import rest_inner_height_mm

    dz = markers[:, 2] - rest_inner_height_mm(built, *markers[:, :2].T)
    assert np.percentile(np.abs(dz - np.median(dz)), 95) < 0.4


def test_several_unloaded_frames_are_combined():
    frames = [_rest_points(noise_mm=0.2, seed=s) for s in range(4)]
    truth_xy = rest_marker_points_mm(JIG)[:, :2]
    single = survey_markers(frames[0], JIG, smooth=False)
    several = survey_markers(frames, JIG, smooth=False)
    assert several.n_frames == 4 and several.summary()["frames"] == 4
    from softjig.jig_shape import rest_inner_height_mm

    err_one = np.std(
        single.measured_xyz_mm[:, 2] - rest_inner_height_mm(JIG, *single.measured_xyz_mm[:, :2].T)
    )
    err_four = np.std(
        several.measured_xyz_mm[:, 2] - rest_inner_height_mm(JIG, *several.measured_xyz_mm[:, :2].T)
    )
    assert err_four < 0.7 * err_one
    assert np.array_equal(several.nominal_index, np.arange(len(truth_xy)))
    dented = [frames[0], frames[1].copy()]
    dented[1][np.hypot(*dented[1][:, :2].T) < 25, 2] -= 3.0
    with pytest.raises(InputError, match="frame 2 of 2: this frame is loaded"):
        survey_markers(dented, JIG)


def test_a_survey_without_fiducials_says_its_offsets_include_the_cameras_error(dataset, tmp_path):
    """Without the fiducials the markers are measured in the cameras' nominal pose: a zoo design whose
    head was tilted by 0.9 deg read every marker 4 mm off (exit 0, no word of why)."""
    frame = dataset[0]
    rig = tmp_path / "config-extrinsics.toml"
    rig.write_text(dumps_jig(replace(dataset.jig, sensing=replace(dataset.jig.sensing, extrinsics="config"))))
    args = ["survey", str(frame.left_path), str(frame.right_path), "--config", str(rig)]
    result = runner.invoke(app, [*args, "--out", str(tmp_path / "s.toml"), "--json"])
    assert result.exit_code == 0, result.output
    assert json.loads(result.stdout)["frame_source"] == "config"
    assert "fiducials were not seen" in result.stderr and "placement error" in result.stderr
    result = runner.invoke(app, ["survey", str(dataset.root), "--out", str(tmp_path / "f.toml")])
    assert result.exit_code == 0 and "fiducials were not seen" not in result.stderr
