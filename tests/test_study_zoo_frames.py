"""A study's ``[frames] zoo = { count = N }``: random parts and poses drawn as ``softjig simulate --scenario
zoo`` draws a design's, reproducible by the study seed, the same for every design of a seed (issue 17)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from softjig.errors import ConfigError
from softjig.sim.zoo import ZooRanges, draw_frames
from softjig.study.run import make_tasks, run_task, task_inputs
from softjig.study.spec import ZOO_FRAMES_SPAWN_KEY, Study, build_designs, load_study, parse_study

ZOO = """
[study]
name = "zoo"
seeds = [4, 5]
[vary]
"markers.pitch_mm" = [7.0, 9.0]
[frames]
zoo = { count = 3 }
[estimate]
methods = ["refractive"]
"""


def _study(text: str, tmp_path) -> Study:
    path = tmp_path / "study.toml"
    path.write_text(text, encoding="utf-8")
    return load_study(path)


def _described(specs) -> list[tuple]:
    return [
        (
            s.part.kind,
            s.part.diameter_mm,
            s.pose.alpha_rad,
            s.pose.theta_rad,
            s.pose.center_xy_mm,
            s.pose.push_depth_mm,
        )
        for s in specs[1:]
    ]


def test_zoo_frames_are_drawn_as_the_zoo_draws_them_from_the_seed(tmp_path):
    spec = _study(ZOO, tmp_path).spec
    specs = spec.frame_specs(4)
    assert specs[0].part is None and specs[0].meta == {"reference": True}  # the reference first
    assert len(specs) == 4
    rng = np.random.default_rng(np.random.SeedSequence(4, spawn_key=(ZOO_FRAMES_SPAWN_KEY,)))
    assert _described(specs) == _described(draw_frames(spec.base, 3, rng, ZooRanges()))
    assert _described(spec.frame_specs(4)) == _described(specs)  # reproducible
    assert _described(spec.frame_specs(5)) != _described(specs)  # another seed, other frames
    r = ZooRanges()
    for s in specs[1:]:
        assert s.part.kind in r.part_kinds and r.part_size_mm[0] <= s.part.diameter_mm <= r.part_size_mm[1]
        assert r.tilt_deg[0] <= math.degrees(s.pose.alpha_rad) <= r.tilt_deg[1]
        assert math.hypot(*s.pose.center_xy_mm) <= r.max_offset_mm
        assert r.push_mm[0] <= s.pose.push_depth_mm <= r.push_mm[1]


def test_every_design_of_a_seed_is_tested_on_the_same_frames(tmp_path):
    study = _study(ZOO, tmp_path)
    tasks = make_tasks(study)
    assert len(tasks) == 2 * 2  # designs x seeds, one chunk each
    rows = {}
    for inp in task_inputs(study, tasks):
        assert _described(inp.frames) == _described(study.spec.frame_specs(inp.task.seed))
        rows[(inp.task.design_id, inp.task.seed)] = inp
    for seed in (4, 5):
        assert _described(rows[(0, seed)].frames) == _described(rows[(1, seed)].frames)
    columns = run_task(rows[(1, 5)]).columns
    expected = study.spec.frame_specs(5)[1:]
    assert columns["diameter_mm"] == pytest.approx([s.part.diameter_mm for s in expected])
    assert columns["alpha_deg"] == pytest.approx([math.degrees(s.pose.alpha_rad) for s in expected])
    assert any(q != "failed" for q in columns["quality"])


def test_the_zoo_frames_identify_the_study(tmp_path):
    spec = _study(ZOO, tmp_path).spec
    frames = spec.canonical()["frames"]
    assert frames == {
        "zoo": {
            "count": 3,
            "part_kinds": ["cylinder", "box", "polygon"],
            "part_size_mm": [30.0, 90.0],
            "tilt_deg": [0.0, 20.0],
            "max_offset_mm": 20.0,
            "push_mm": [2.0, 8.0],
        }
    }
    narrowed = _study(ZOO.replace("zoo = { count = 3 }", "zoo = { count = 3, tilt_deg = [0, 10] }"), tmp_path)
    assert narrowed.spec.study_hash != spec.study_hash
    assert all(math.degrees(s.pose.alpha_rad) <= 10.0 for s in narrowed.spec.frame_specs(4)[1:])


@pytest.mark.parametrize(
    ("frames", "message"),
    [
        ({"zoo": {"count": 0}}, "frames.zoo.count: Input should be greater than or equal to 1"),
        ({"zoo": {"count": 10**6}}, "frames.zoo.count: Input should be less than or equal to 10000"),
        ({"zoo": {}}, "frames.zoo.count"),
        ({"zoo": {"count": 3, "tilt": [0, 5]}}, "frames.zoo.tilt: Unexpected keyword"),
        ({"zoo": {"count": 3, "tilt_deg": [10, 5]}}, "frames.zoo.tilt_deg: [10, 5] needs low <= high"),
        ({"zoo": {"count": 3, "tilt_deg": [0, 95]}}, "frames.zoo.tilt_deg.1: Input should be less than 90"),
        (
            {"zoo": {"count": 3, "part_size_mm": [-5, 30]}},
            "frames.zoo.part_size_mm.0: Input should be greater",
        ),
        (
            {"zoo": {"count": 3, "part_kinds": ["sphere"]}},
            "frames.zoo.part_kinds.0: Input should be 'cylinder'",
        ),
        ({"zoo": {"count": 3, "part_kinds": []}}, "frames.zoo.part_kinds: an empty list draws no part"),
        ({"zoo": {"count": 3}, "alphas_deg": [5]}, "frames: give either zoo, poses or the paper sweep's"),
        (
            {"zoo": {"count": 3, "part_size_mm": [250, 300]}},
            "frames.zoo: no part of these ranges fits the jig",
        ),
    ],
)
def test_bad_zoo_frames_are_errors_naming_the_key(frames, message):
    with pytest.raises(ConfigError) as info:
        build_designs(parse_study({"study": {"name": "t"}, "frames": frames}))
    assert message in str(info.value)


def test_a_zoo_frame_that_does_not_fit_a_design_is_an_error_before_any_work():
    data = {
        "study": {"name": "t", "seeds": [0]},
        "vary": {"membrane.footprint_radius_mm": [95.0, 60.0]},
        "frames": {"zoo": {"count": 20}},
    }
    with pytest.raises(ConfigError) as info:
        build_designs(parse_study(data))
    message = str(info.value)
    assert message.startswith("frames.zoo: frame ") and "of seed 0" in message
    assert "does not fit the design membrane.footprint_radius_mm = 60.0" in message
    assert "narrow frames.zoo.part_size_mm or max_offset_mm" in message


def test_the_report_says_what_the_zoo_frames_are(tmp_path):
    from softjig.study.report import _frames_text, _simulate_command

    spec = _study(ZOO, tmp_path).spec
    assert _frames_text(spec.frames).startswith(
        "3 random parts and poses per seed, the same for every design"
    )
    assert _simulate_command(spec, 0).startswith("softjig simulate --scenario paper-sweep --config best/")


def test_the_docs_zoo_example_is_a_valid_study():
    import re
    import tomllib
    from pathlib import Path

    text = (Path(__file__).parents[1] / "docs" / "studies.md").read_text(encoding="utf-8")
    (block,) = [b for b in re.findall(r"```toml\n(.*?)```", text, re.S) if "zoo = { count = 20 }" in b]
    commented = "\n".join(
        line.strip().removeprefix("# ") for line in block.splitlines() if line.strip().startswith("#")
    )
    narrowed = "[frames]\n" + " ".join(commented.splitlines()[1:])  # the optional form, uncommented
    for frames in (tomllib.loads(block)["frames"], tomllib.loads(narrowed)["frames"]):
        spec = parse_study({"study": {"name": "docs", "seeds": [0]}, "frames": frames})
        assert len(spec.frame_specs(0)) == 21 and spec.n_frames == 20
    assert (
        spec.frames.zoo.canonical()
        == parse_study({"study": {"name": "d"}, "frames": {"zoo": {"count": 20}}}).frames.zoo.canonical()
    )  # the defaults the docs show are the zoo's


def test_zoo_frames_are_grouped_in_bands_for_the_per_cell_rmse(tmp_path):
    """Every zoo frame has its own diameter and tilt: a cell per frame would say nothing, so the cells of
    designs.parquet are 20 mm x 5 deg bands named by their centre; a sweep's cells stay its poses."""
    from softjig.study.results import _cells, frame_cells

    zoo = _study(ZOO, tmp_path).spec
    d = np.array([32.8213, 47.1, 41.0, 88.0])
    a = np.array([8.84052, 6.2, 14.9, 0.3])
    err = np.array([0.3, 0.4, 1.0, 0.2])
    cd, ca = frame_cells(zoo, d, a)
    assert cd.tolist() == [30.0, 50.0, 50.0, 90.0] and ca.tolist() == [7.5, 7.5, 12.5, 2.5]
    cells, worst, worst_rmse = _cells(cd, ca, err)
    assert [(c["diameter_mm"], c["alpha_deg"], c["n"]) for c in cells] == [
        (30.0, 7.5, 1),
        (50.0, 7.5, 1),
        (50.0, 12.5, 1),
        (90.0, 2.5, 1),
    ]
    assert worst == "D50 a12.5" and worst_rmse == pytest.approx(1.0)
    sweep = _study(ZOO.replace("zoo = { count = 3 }", "diameters_mm = [40]\nalphas_deg = [5]"), tmp_path).spec
    assert [x.tolist() for x in frame_cells(sweep, d, a)] == [d.tolist(), a.tolist()]
