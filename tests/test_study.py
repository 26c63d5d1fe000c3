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
    assert len(spec.frame_specs()) == 1 + 2 * 3 * 12 == 1 + spec.n_frames
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
    (
        {"markers.pitch_mm": {"start": 6, "stop": 8, "num": 100_000_000}},
        "vary.markers.pitch_mm: num = 100,000,000 values is over the 20,000 designs",
    ),
    (
        {"markers.pitch_mm": {"start": 6, "stop": 8, "num": 200}, "cameras.baseline_mm": [*range(20, 121)]},
        "vary.cameras.baseline_mm: the study would hold 20,200 designs or more",
    ),
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
        (
            {"study": {"name": "t"}, "frames": {"theta_step_deg": 1e-9}},
            "frames.theta_step_deg: 1e-09 gives 2,160,000,000,000 sweep frames per design",
        ),
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


def _one_design(study: Study) -> Study:
    return Study(replace(study.spec, vary=(("markers.pitch_mm", (7.0,)),)), study.designs[:1])


def test_a_tasks_rows_are_the_one_shot_estimates_of_its_frames(tmp_path):
    """One Estimator per method and task gives every frame the estimate `estimate_pair` gives it alone (the
    old per-frame path): the same normals, sigmas, qualities and markers; only the timings differ."""
    from softjig.sensing.pipeline import estimate_pair, reference_from_pair
    from softjig.sim.asbuilt import draw_as_built
    from softjig.sim.render import render_pair

    study = _one_design(_study(SMALL, tmp_path))
    inp = next(task_inputs(study, make_tasks(study)))
    columns = run_task(inp).columns
    seed, jig = inp.task.seed, inp.jig
    as_built = draw_as_built(jig, np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(0,))))

    def pair(index):
        rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(1, index)))
        return render_pair(as_built, inp.frames[index].part, inp.frames[index].pose, rng)

    unloaded = pair(0)
    reference = reference_from_pair(unloaded.left, unloaded.right, jig)
    i = 0
    for k in range(1, len(inp.frames)):
        p = pair(k)
        for method in inp.methods:
            old = estimate_pair(
                p.left,
                p.right,
                jig,
                part_diameter_mm=50.0,
                method=method,
                reference=reference if method == "refractive" else None,
            ).estimate
            assert (columns["method"][i], columns["frame"][i]) == (method, k - 1)
            new = (columns["est_nx"][i], columns["est_ny"][i], columns["est_nz"][i])
            assert new == pytest.approx(tuple(old.normal), abs=1e-12)
            assert columns["sigma_deg"][i] == pytest.approx(old.tilt_sigma_deg, abs=1e-12)
            assert columns["quality"][i] == old.quality
            assert columns["markers_under_part"][i] == old.n_points
            i += 1
    assert i == len(columns["method"])


def test_a_designs_latency_is_the_warm_estimate_alone(tmp_path):
    """`latency_ms_median` is one more frame's cost to a running estimator (bench_estimate's per-pair time),
    not the estimator's build (~0.5 s) nor its first call's warm-up: within a few times the warm
    estimate of one of the study's frames timed here, in the same process under the same load."""
    import time

    from softjig.sensing.estimator import Estimator
    from softjig.sim.asbuilt import draw_as_built
    from softjig.sim.render import render_pair

    study = _one_design(_study(SMALL.replace('"refractive", "paper"', '"refractive"'), tmp_path))
    run = run_study(study, tmp_path / "out", workers=1, progress=False, report=False)
    latency = run.designs.column("latency_ms_median").to_pylist()[0]
    inp = next(task_inputs(study, make_tasks(study)))
    as_built = draw_as_built(inp.jig, np.random.default_rng(1))
    unloaded = render_pair(as_built, inp.frames[0].part, inp.frames[0].pose, np.random.default_rng(2))
    loaded = render_pair(as_built, inp.frames[1].part, inp.frames[1].pose, np.random.default_rng(3))
    estimator = Estimator(inp.jig)
    estimator = estimator.with_reference(estimator.reference_from_pair(unloaded.left, unloaded.right))
    warm_ms = []
    for _ in range(4):
        t0 = time.perf_counter()
        estimator.estimate(loaded.left, loaded.right, part_diameter_mm=50.0)
        warm_ms.append(1e3 * (time.perf_counter() - t0))
    per_pair = float(np.median(warm_ms[1:]))
    assert 0 < latency < 3 * per_pair + 5.0, (latency, per_pair)


def test_a_task_builds_its_jigs_model_once_for_every_frame_and_method(tmp_path, monkeypatch):
    """The per-jig set-up (:class:`JigModel`) is built once per task and shared by the methods' estimators,
    not once per frame and method (the real build, counted)."""
    from softjig.sensing.setup import JigModel

    built = []
    real = JigModel.build.__func__

    def counted(cls, jig):
        built.append(jig)
        return real(cls, jig)

    monkeypatch.setattr(JigModel, "build", classmethod(counted))
    study = _one_design(_study(SMALL, tmp_path))
    columns = run_task(next(task_inputs(study, make_tasks(study)))).columns
    assert len(columns["method"]) == 4  # 2 frames x 2 methods, every one estimated
    assert all(q != "failed" for q in columns["quality"])
    assert len(built) == 1


# ------------------------------------------------------------------------------------------ explicit poses

POSES = """
[study]
name = "poses"
seeds = [2]
[vary]
"markers.pitch_mm" = [8.0]
[[frames.poses]]
diameter_mm = 50
alpha_deg = 12
theta_deg = 45
push_depth_mm = 2.5
[[frames.poses]]
diameter_mm = 40
alpha_deg = 0
[estimate]
methods = ["refractive"]
"""


def test_explicit_poses_are_the_frames_in_their_order(tmp_path):
    study = _study(POSES, tmp_path)
    specs = study.spec.frame_specs()
    assert len(specs) == 3 and specs[0].part is None  # the reference first
    assert [(s.part.diameter_mm, round(math.degrees(s.pose.alpha_rad), 9)) for s in specs[1:]] == [
        (50.0, 12.0),
        (40.0, 0.0),
    ]
    assert (math.degrees(specs[1].pose.theta_rad), specs[1].pose.push_depth_mm) == pytest.approx((45.0, 2.5))
    assert specs[2].pose.push_depth_mm == 3.0  # the default, as the sweep's
    columns = run_task(next(task_inputs(study, make_tasks(study)))).columns
    poses = zip(columns["diameter_mm"], columns["alpha_deg"], columns["theta_deg"], strict=True)
    got = [v for pose in poses for v in pose]
    assert got == pytest.approx([50.0, 12.0, 45.0, 40.0, 0.0, 0.0])
    assert columns["depth_mm"][0] == pytest.approx(2.5, abs=0.3)  # the true depth, on the as-built jig
    assert all(q != "failed" for q in columns["quality"])
    assert columns["error_deg"][0] < 2.0
    # a sweep's identity is what it was before poses existed (its folders still resume)
    sweep = _study(SMALL, tmp_path, "sweep.toml").spec.canonical()["frames"]
    assert set(sweep) == {"diameters_mm", "alphas_deg", "theta_step_deg", "push_depth_mm"}
    assert study.spec.canonical()["frames"] == {
        "poses": [
            {"diameter_mm": 50.0, "alpha_deg": 12.0, "theta_deg": 45.0, "push_depth_mm": 2.5},
            {"diameter_mm": 40.0, "alpha_deg": 0.0, "theta_deg": 0.0, "push_depth_mm": 3.0},
        ]
    }


_ONE_POSE = {"diameter_mm": 50, "alpha_deg": 10}


@pytest.mark.parametrize(
    ("frames", "message"),
    [
        ({"poses": [_ONE_POSE], "alphas_deg": [5]}, "frames: give either poses or the paper sweep's"),
        ({"poses": []}, "frames.poses: an empty list gives no frame"),
        (
            {"poses": [{**_ONE_POSE, "alpha_deg": 95}]},
            "frames.poses.0.alpha_deg: Input should be less than 90",
        ),
        (
            {"poses": [{**_ONE_POSE, "theta_deg": 360}]},
            "frames.poses.0.theta_deg: Input should be less than 360",
        ),
        (
            {"poses": [{**_ONE_POSE, "diameter_mm": -5}]},
            "frames.poses.0.diameter_mm: Input should be greater",
        ),
        (
            {"poses": [{**_ONE_POSE, "push_depth_mm": 0}]},
            "frames.poses.0.push_depth_mm: Input should be greater",
        ),
        ({"poses": [_ONE_POSE, {**_ONE_POSE, "depth_mm": 2}]}, "frames.poses.1.depth_mm: Unexpected keyword"),
        ({"poses": [{"alpha_deg": 10}]}, "frames.poses.0.diameter_mm"),
        ({"poses": [{**_ONE_POSE, "diameter_mm": 500}]}, "frames: the 500 mm part does not fit the design"),
        ({"poses": [{**_ONE_POSE, "push_depth_mm": 30}]}, "into the plate"),
    ],
)
def test_bad_poses_are_errors_naming_the_pose_and_key(frames, message):
    with pytest.raises(ConfigError) as info:
        build_designs(parse_study({"study": {"name": "t"}, "frames": frames}))
    assert message in str(info.value)


def test_the_best_rigs_command_for_explicit_poses_renders_the_first_pose(tmp_path):
    from softjig.io.dataset import Dataset
    from softjig.study.report import _frames_text, _simulate_command

    spec = _study(POSES, tmp_path).spec
    command = _simulate_command(spec, 0)
    assert command.startswith("softjig simulate --scenario single --config best/")
    assert "--part-diameter 50 --alpha 12 --theta 45 --push-depth 2.5 --seed 2" in command
    assert _frames_text(spec.frames) == "2 explicit poses of parts of diameter 40, 50 mm tilted by 0, 12 deg"
    args = command.split()[1:]
    args[args.index("--config") + 1] = str(tmp_path / "rig.toml")
    assert runner.invoke(app, ["config", "--out", str(tmp_path / "rig.toml")]).exit_code == 0
    result = runner.invoke(app, [*args, "--out", str(tmp_path / "ds"), "--no-progress", "--workers", "1"])
    assert result.exit_code == 0, result.output
    frame = Dataset.open(tmp_path / "ds")[0]
    assert (frame.part.diameter_mm, frame.alpha_deg) == (50.0, pytest.approx(12.0))
