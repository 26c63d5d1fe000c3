"""Tests of softjig.sim.zoo and ``softjig simulate --scenario zoo``: random makeable jig designs."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest
from typer.testing import CliRunner

from softjig.cli.app import app
from softjig.config import default_jig, load_jig, validate_jig, validate_part
from softjig.errors import InputError
from softjig.io.dataset import Dataset
from softjig.sim.scenarios import check_reachable
from softjig.sim.zoo import PLATE_MATERIALS, ZooRanges, draw_designs, draw_frames

# Small images and few frames: the zoo's drawing is what is tested here, not the renderer.
SMALL = ZooRanges(resolutions=((640, 480), (800, 600)))


def test_same_seed_same_designs_and_independent_of_their_number():
    a = list(draw_designs(3, seed=11, frames=2))
    b = list(draw_designs(3, seed=11, frames=2))
    assert [d.jig for d in a] == [d.jig for d in b]
    assert [[s.meta for s in d.specs] for d in a] == [[s.meta for s in d.specs] for d in b]
    assert [d.seed for d in a] == [d.seed for d in b]
    first_two = list(draw_designs(2, seed=11, frames=2))
    assert [d.jig for d in first_two] == [d.jig for d in a[:2]]
    other = list(draw_designs(3, seed=12, frames=2))
    assert [d.jig for d in other] != [d.jig for d in a]


def test_every_design_validates_and_starts_with_its_reference_frame():
    designs = list(draw_designs(12, seed=0, frames=3))
    for d in designs:
        validate_jig(d.jig)
        assert d.specs[0].part is None and d.specs[0].meta == {"reference": True}
        assert len(d.specs) == 4
        for spec in d.specs[1:]:
            validate_part(spec.part, d.jig)
            check_reachable(d.jig, spec)
            assert spec.part.kind in ("cylinder", "box", "polygon")
            assert 30.0 <= spec.part.diameter_mm <= 90.0
            assert np.hypot(*spec.pose.center_xy_mm) <= 20.0
            assert 0.0 <= np.degrees(spec.pose.alpha_rad) <= 20.0
            assert 2.0 <= spec.pose.push_depth_mm <= 8.0
        cams = d.jig.cameras
        assert 20.0 <= cams.baseline_mm <= 60.0
        assert (640, 480) <= (cams.left.width_px, cams.left.height_px) <= (1920, 1200)
        assert d.jig.plate.refractive_index in PLATE_MATERIALS.values()
        assert 3.0 <= d.jig.plate.thickness_mm <= 10.0
        assert 1.45 <= d.jig.medium.oil_refractive_index <= 1.56
        assert 1.5 <= d.jig.markers.diameter_mm <= 4.0 and 4.0 <= d.jig.markers.pitch_mm <= 12.0
        assert d.family == f"{d.jig.markers.layout}-{d.labels['resolution_class']}"
    # the ranges are covered, not one corner of them
    assert len({d.jig.plate.refractive_index for d in designs}) >= 3
    assert {d.jig.markers.layout for d in designs} == {"square", "hex"}
    assert {d.jig.membrane.dome_profile for d in designs} == {"power", "paraboloid_power"}
    assert any(d.labels["oil_above_plate"] for d in designs)
    assert len({d.family for d in designs}) >= 3
    assert len({d.jig.medium.speckle_seed for d in designs}) == len(designs)


def test_ranges_that_cannot_be_met_are_a_clear_error():
    impossible = replace(SMALL, marker_pitch_mm=(4.0, 4.5), marker_diameter_mm=(3.0, 4.0), max_attempts=5)
    with pytest.raises(InputError, match="no makeable design in 5 draws"):
        list(draw_designs(2, seed=0, frames=1, ranges=impossible))
    with pytest.raises(InputError, match="at least one design"):
        list(draw_designs(0, seed=0))
    with pytest.raises(InputError, match="at least one loaded frame"):
        list(draw_designs(1, seed=0, frames=0))
    with pytest.raises(InputError, match="lo <= hi"):
        ZooRanges(baseline_mm=(60.0, 20.0))
    with pytest.raises(InputError, match="part_kinds is empty"):
        ZooRanges(part_kinds=())


@pytest.mark.parametrize("frames", [0, -3, 2.9, True])
def test_draw_frames_refuses_a_count_that_is_not_a_positive_integer(frames):
    # It returned the reference frame alone for 0 or -3 and truncated 2.9 to 2 loaded frames.
    with pytest.raises(InputError, match="at least one loaded frame"):
        draw_frames(default_jig(), frames, np.random.default_rng(0))


def test_cli_writes_each_design_as_a_dataset(tmp_path):
    out = tmp_path / "zoo"
    runner = CliRunner()
    args = ["simulate", "--scenario", "zoo", "--designs", "2", "--frames", "2", "--seed", "5"]
    result = runner.invoke(app, [*args, "--out", str(out), "--workers", "1", "--no-progress"])
    assert result.exit_code == 0, result.output
    manifest = json.loads((out / "zoo.json").read_text())
    assert [d["dir"] for d in manifest["designs"]] == ["000", "001"]
    expected = list(draw_designs(2, seed=5, frames=2))
    for design, entry in zip(expected, manifest["designs"], strict=True):
        ds = Dataset.open(out / entry["dir"])
        assert load_jig(out / entry["dir"] / "rig.toml") == design.jig
        assert len(ds) == 3
        assert entry["family"] == design.family
    lines = (out / "000" / "frames.jsonl").read_text().splitlines()
    first, second = json.loads(lines[0]), json.loads(lines[1])
    assert first.get("reference") is True and "normal" not in first.get("truth", {})
    assert len(second["truth"]["normal"]) == 3 and second["part"]["kind"] in ("cylinder", "box", "polygon")


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--designs", "0"], "at least one design"),
        (["--frames", "0"], "at least one loaded frame"),
        (["--alphas", "5"], "--alphas"),
        (["--push-depth", "5"], "--push-depth"),
        (["--config", "rig.toml"], "--config does not apply"),
    ],
)
def test_cli_zoo_bad_input_exits_2(tmp_path, extra, message):
    runner = CliRunner()
    out = tmp_path / "z"
    result = runner.invoke(app, ["simulate", "--scenario", "zoo", "--out", str(out), "--no-progress", *extra])
    assert result.exit_code == 2, result.output
    assert message in result.output
    assert not out.exists()


def test_a_zoo_frame_count_beyond_the_limit_is_refused_before_anything_is_drawn():
    """A mistyped --frames (10^9) hung while drawing the first design's frames, before any was written."""
    from softjig.sim.zoo import MAX_ZOO_FRAMES, draw_designs
    from softjig.study.spec import MAX_ZOO_FRAMES as STUDY_MAX_ZOO_FRAMES

    assert STUDY_MAX_ZOO_FRAMES == MAX_ZOO_FRAMES
    with pytest.raises(InputError, match="at most 10,000 loaded frames"):
        next(draw_designs(1, seed=0, frames=10**9))
