"""`softjig study --ray local`: the same study on a local Ray cluster of two workers gives the same rows as the
local pool (issue 17, deliverable 2: no change to the study)."""

from __future__ import annotations

from softjig.study.execute import run_study
from softjig.study.spec import load_study

STUDY = """
[study]
name = "ray"
seeds = [2]
[vary]
"cameras.baseline_mm" = [28.0, 36.0]
[frames]
diameters_mm = [60]
alphas_deg = [8]
theta_step_deg = 360
[estimate]
methods = ["refractive", "paper"]
"""


def test_a_local_ray_cluster_of_two_workers_gives_the_local_pools_rows(tmp_path):
    path = tmp_path / "study.toml"
    path.write_text(STUDY, encoding="utf-8")
    study = load_study(path)
    on_ray = run_study(study, tmp_path / "ray", ray="local", workers=2, progress=False, report=False)
    local = run_study(study, tmp_path / "local", workers=1, progress=False, report=False)
    assert (on_ray.ran, len(on_ray.results)) == (2, 4)
    assert on_ray.results.drop(["estimate_ms"]).equals(local.results.drop(["estimate_ms"]))
    assert set(on_ray.results.column("quality").to_pylist()) <= {"ok", "suspect"}
