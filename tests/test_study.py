"""`softjig study` (issue 17): the study file, its designs, the output folder, the tasks and their rows."""

from __future__ import annotations

import json
import math
from dataclasses import replace

import numpy as np
import pyarrow.parquet as pq
import pytest
from typer.testing import CliRunner

from softjig.cli import app
from softjig.errors import ConfigError, InputError
from softjig.study.execute import run_study
from softjig.study.results import RESULT_FIELDS, designs_schema, results_schema
from softjig.study.run import make_tasks, run_task, task_inputs
from softjig.study.spec import FramesSpec, Study, build_designs, load_study, parse_study

runner = CliRunner()

ISSUE_EXAMPLE = """
[study]
name = "pitch-vs-baseline"
seeds = [0, 1]
[vary]
"markers.pitch_mm" = [6.0, 8.0, 10.0]
"cameras.baseline_mm" = { start = 20.0, stop = 60.0, num = 5 }
[frames]
diameters_mm = [40, 60]
alphas_deg = [5, 10, 20]
theta_step_deg = 30
[estimate]
methods = ["refractive"]
"""

#: Two designs, one seed, two frames, both methods: 4 renders and 8 estimates.
SMALL = """
[study]
name = "small"
seeds = [3]
[vary]
"markers.pitch_mm" = [7.0, 10.0]
[frames]
diameters_mm = [50]
alphas_deg = [10]
theta_step_deg = 180
[estimate]
methods = ["refractive", "paper"]
"""


def _study(text: str, tmp_path, name: str = "study.toml") -> Study:
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return load_study(path)


def _spec(**vary) -> Study:
    spec = parse_study({"study": {"name": "t"}, "vary": vary})
    return Study(spec, build_designs(spec))


# ------------------------------------------------------------------------------------------ the file


def test_the_issues_example_is_the_product_of_its_lists_row_major(tmp_path):
    study = _study(ISSUE_EXAMPLE, tmp_path)
    spec = study.spec
    assert spec.n_designs == len(study.designs) == 15
    assert spec.paths == ("markers.pitch_mm", "cameras.baseline_mm")
    assert spec.vary[1][1] == pytest.approx((20.0, 30.0, 40.0, 50.0, 60.0))
    # row-major in file order: the last path varies fastest
    assert study.designs[7].values == (8.0, 40.0)
    jig = study.designs[7].jig
    assert jig.markers.pitch_mm == 8.0
    assert jig.cameras.baseline_mm == pytest.approx(40.0)
    assert jig.cameras.left.position_mm == pytest.approx((-20.0, 0.0, -155.0))
    assert len(spec.frame_specs()) == 1 + 2 * 3 * 12
    assert len(make_tasks(study)) == 15 * 2  # 72 frames fit one task


def test_toml_dotted_keys_and_quoted_paths_are_the_same_study(tmp_path):
    quoted = _study(SMALL, tmp_path, "a.toml")
    dotted = _study(SMALL.replace('"markers.pitch_mm"', "markers.pitch_mm"), tmp_path, "b.toml")
    assert dotted.spec.paths == ("markers.pitch_mm",)
    assert dotted.spec.study_hash == quoted.spec.study_hash
    other = _study(SMALL.replace("seeds = [3]", "seeds = [4]"), tmp_path, "c.toml")
    assert other.spec.study_hash != quoted.spec.study_hash


def test_aliases_set_the_fields_they_are_made_of():
    study = _spec(
        **{"plate.thickness_mm": [8.0], "cameras.distance_mm": [120.0], "cameras.baseline_mm": [50.0]}
    )
    cams = study.designs[0].jig.cameras
    # the distance is measured from the design's own plate (real fields first, then aliases)
    assert cams.left.position_mm == pytest.approx((-25.0, 0.0, -128.0))
    assert cams.right.position_mm == pytest.approx((25.0, 0.0, -128.0))
    study = _spec(**{"cameras.resolution_px": [[640, 480]], "cameras.focal_px": [500]})
    left = study.designs[0].jig.cameras.left
    assert (left.width_px, left.height_px, left.cx_px, left.cy_px, left.fx_px) == (
        640,
        480,
        319.5,
        239.5,
        500.0,
    )
    assert study.designs[0].jig.cameras.right.fy_px == 500.0


def test_any_config_field_by_its_path_with_values_as_the_model_holds_them():
    study = _spec(
        **{
            "medium.speckle_static": [True, False],
            "markers.layout": ["square", "hex"],
            "imaging.supersampling": [2],
        }
    )
    assert [d.jig.markers.layout for d in study.designs] == ["square", "hex", "square", "hex"]
    assert study.designs[2].jig.medium.speckle_static is False
    assert study.spec.numeric_paths == ("imaging.supersampling",)
    assert isinstance(study.designs[0].jig.imaging.supersampling, int)


BAD = [
    (
        {"markers.pich_mm": [6.0]},
        "vary.markers.pich_mm: unknown config field 'pich_mm' in markers; did you mean markers.pitch_mm",
    ),
    ({"marker.pitch_mm": [6.0]}, "did you mean markers?"),
    ({"markers": [6.0]}, "vary.markers: is a section"),
    (
        {"markers.pitch_mm": {"start": 4, "stop": 8, "num": 0}},
        "vary.markers.pitch_mm: a range needs num >= 1",
    ),
    ({"markers.pitch_mm": []}, "vary.markers.pitch_mm: an empty list"),
    ({"markers.pitch_mm": ["wide"]}, "vary.markers.pitch_mm = 'wide': Input should be a valid number"),
    ({"markers.layout": ["triangle"]}, "vary.markers.layout = 'triangle': Input should be 'square', 'hex'"),
    (
        {"markers.pitch_mm": [8.0, -1.0]},
        "markers.pitch_mm = -1.0 is impossible: markers.pitch_mm: must be a positive",
    ),
    (
        {"markers.diameter_mm": [3.0, 9.0]},
        "markers.diameter_mm = 9.0 is impossible: markers.diameter_mm: markers (9.0 mm)",
    ),
    ({"cameras.baseline_mm": [0.0]}, "cameras.baseline_mm = 0.0 is impossible"),
    (
        {"cameras.resolution_px": [[640.5, 480]]},
        "vary.cameras.resolution_px = [640.5, 480]: must be a pair of integers",
    ),
    (
        {"membrane.footprint_radius_mm": [95.0, 28.0]},
        "frames: the 60 mm part does not fit the design membrane.footprint_radius_mm = 28.0",
    ),
]


@pytest.mark.parametrize(("vary", "message"), BAD, ids=[m.split(":")[0][:40] for _, m in BAD])
def test_bad_paths_values_and_designs_are_errors_naming_the_field(vary, message):
    with pytest.raises(ConfigError) as info:
        _spec(**vary)
    assert message in str(info.value)


@pytest.mark.parametrize(
    ("data", "message"),
    [
        ({"study": {"name": "t", "seed": [1]}}, "study.seed"),
        ({"study": {"name": "t", "seeds": []}}, "study.seeds: give at least one seed"),
        ({"study": {"name": "t", "seeds": [-1]}}, "study.seeds: a seed is a non-negative integer"),
        (
            {"study": {"name": "t"}, "estimate": {"methods": ["best"]}},
            "estimate.methods: unknown method 'best'",
        ),
        (
            {"study": {"name": "t"}, "frames": {"alphas_deg": [95.0]}},
            "frames: a tilt alpha must be in [0, 90)",
        ),
        ({"study": {"name": "t"}, "frame": {}}, "frame: unknown section"),
        ({"vary": {}}, "study: missing"),
    ],
)
def test_bad_sections_are_errors_naming_the_key(data, message):
    with pytest.raises(ConfigError) as info:
        spec = parse_study(data)
        build_designs(spec)
    assert message in str(info.value)


def test_the_command_refuses_a_bad_study_with_exit_2_before_any_work(tmp_path):
    path = tmp_path / "bad.toml"
    path.write_text(SMALL.replace('"markers.pitch_mm" = [7.0, 10.0]', '"markers.pitch_mm" = [7.0, 2.0]'))
    result = runner.invoke(app, ["study", str(path), "--out", str(tmp_path / "out")])
    assert result.exit_code == 2
    assert "markers.pitch_mm = 2.0 is impossible" in result.output
    assert not (tmp_path / "out").exists()


# ------------------------------------------------------------------------------------------ the folder


def test_an_output_folder_is_refused_for_another_study_and_kept_intact(tmp_path):
    study = _study(SMALL, tmp_path)
    out = tmp_path / "out"
    run = run_study(study, out, workers=1, progress=False, report=False)
    assert run.ran == 2
    before = {p: p.read_bytes() for p in sorted(out.rglob("*")) if p.is_file()}
    other = _study(SMALL.replace("seeds = [3]", "seeds = [4]"), tmp_path, "other.toml")
    for resume in (False, True):
        with pytest.raises(InputError, match="holds the results of another study"):
            run_study(other, out, workers=1, progress=False, report=False, resume=resume)
    with pytest.raises(InputError, match="pass --resume"):
        run_study(study, out, workers=1, progress=False, report=False)
    assert {p: p.read_bytes() for p in sorted(out.rglob("*")) if p.is_file()} == before
    again = run_study(study, out, workers=1, progress=False, report=False, resume=True)
    assert (again.ran, again.skipped) == (0, 2)
    assert again.results.equals(run.results)
    foreign = tmp_path / "foreign"
    foreign.mkdir()
    (foreign / "notes.txt").write_text("mine")
    with pytest.raises(InputError, match="holds no study"):
        run_study(study, foreign, workers=1, progress=False, report=False)
    assert [p.name for p in foreign.iterdir()] == ["notes.txt"]


def test_the_tables_follow_the_contract_and_the_estimates_are_right(tmp_path):
    study = _study(SMALL, tmp_path)
    run = run_study(study, tmp_path / "out", workers=2, progress=False, report=False)
    results = pq.read_table(tmp_path / "out" / "results.parquet")
    designs = pq.read_table(tmp_path / "out" / "designs.parquet")
    assert results.schema.equals(results_schema(study.spec))
    assert designs.schema.equals(designs_schema(study.spec))
    assert results.column_names[:5] == ["design_id", "method", "seed", "frame", "markers.pitch_mm"]
    assert set(results.column_names) == {n for n, _ in RESULT_FIELDS} | {"markers.pitch_mm"}
    assert len(results) == 2 * 1 * 2 * 2  # designs x seeds x frames x methods
    rows = results.to_pylist()
    assert [(r["design_id"], r["method"], r["frame"]) for r in rows[:4]] == [
        (0, "paper", 0),
        (0, "paper", 1),
        (0, "refractive", 0),
        (0, "refractive", 1),
    ]
    refractive = [r for r in rows if r["method"] == "refractive"]
    assert all(r["quality"] != "failed" and r["error_deg"] < 2.0 for r in refractive)
    for r in rows:
        n = np.array([r["true_nx"], r["true_ny"], r["true_nz"]])
        assert math.degrees(math.acos(n[2])) == pytest.approx(r["alpha_deg"])
        assert r["markers_under_part"] > 0 and r["estimate_ms"] > 0
    assert {r["theta_deg"] for r in rows} == {0.0, 180.0}
    d = designs.to_pylist()
    assert [(x["design_id"], x["method"]) for x in d] == [
        (0, "paper"),
        (0, "refractive"),
        (1, "paper"),
        (1, "refractive"),
    ]
    for x in d:
        mine = [
            r["error_deg"] for r in rows if (r["design_id"], r["method"]) == (x["design_id"], x["method"])
        ]
        assert x["rmse_deg"] == pytest.approx(math.sqrt(np.mean(np.square(mine))))
        assert x["n_estimates"] == 2 and x["recall"] == 1.0 and x["worst_cell"] == "D50 a10"
        assert json.loads(x["cells"])[0]["n"] == 2
    assert d[0]["marker_count"] > d[2]["marker_count"]  # a finer pitch has more markers
    assert run.results.equals(results)


def test_a_frame_is_the_same_whatever_the_chunking():
    study = _spec(**{"markers.pitch_mm": [8.0]})
    frames = FramesSpec(diameters_mm=(50.0,), alphas_deg=(10.0,), theta_step_deg=120.0)
    whole = Study(replace(study.spec, frames=frames, methods=("refractive",)), study.designs)
    chunked = Study(replace(whole.spec, frames_per_task=1), study.designs)
    tasks = make_tasks(chunked)
    assert [(t.first, t.stop) for t in tasks] == [(0, 1), (1, 2), (2, 3)]
    one = run_task(next(task_inputs(whole, make_tasks(whole)))).columns
    parts = [run_task(inp).columns for inp in task_inputs(chunked, tasks)]
    for name in one:
        if name != "estimate_ms":
            assert one[name] == [v for p in parts for v in p[name]], name


@pytest.mark.parametrize(
    ("address", "message"),
    [("127.0.0.1:1", "nothing answers there"), ("nonsense", "give a cluster's address as host:port")],
)
def test_an_unreachable_ray_cluster_is_exit_2_before_the_folder_is_started(tmp_path, address, message):
    path = tmp_path / "study.toml"
    path.write_text(SMALL, encoding="utf-8")
    result = runner.invoke(app, ["study", str(path), "--out", str(tmp_path / "out"), "--ray", address])
    assert result.exit_code == 2
    assert message in result.output
    assert not (tmp_path / "out").exists()


def test_a_studys_frame_is_the_frame_softjig_simulate_renders_of_the_design(tmp_path):
    """Frame k of design d, seed S is frame k + 1 of `simulate_dataset` of the design's jig with seed S (the
    reference first): the same as-built jig, the same images, so the same estimate."""
    from softjig.io.batch import dataset_reference
    from softjig.io.dataset import Dataset
    from softjig.io.simulated import simulate_dataset
    from softjig.sensing.pipeline import estimate_pair

    study = _study(SMALL.replace("theta_step_deg = 180", "theta_step_deg = 360"), tmp_path)
    spec, design = study.spec, study.designs[1]
    row = run_task(next(task_inputs(study, [t for t in make_tasks(study) if t.design_id == 1]))).columns
    simulate_dataset(
        tmp_path / "ds", spec.frame_specs(), design.jig, seed=spec.seeds[0], workers=1, progress=False
    )
    ds = Dataset.open(tmp_path / "ds")
    frame = ds[1]
    assert row["true_nx"][0] == pytest.approx(frame.truth.normal[0], abs=1e-12)
    assert row["depth_mm"][0] == pytest.approx(frame.truth.push_depth_mm, abs=1e-12)
    estimate = estimate_pair(
        frame.load_left(),
        frame.load_right(),
        ds.jig,
        part_diameter_mm=50.0,
        reference=dataset_reference(ds, ds.jig),
    ).estimate
    k = row["method"].index("refractive")
    assert (row["est_nx"][k], row["est_ny"][k], row["est_nz"][k]) == pytest.approx(estimate.normal, abs=1e-12)
