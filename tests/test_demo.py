"""`softjig demo` end to end on a tiny sweep: simulate, estimate, calibrate, evaluate, figures, report."""

from __future__ import annotations

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from softjig.calibration.tilt import load_tilt_calibration
from softjig.cli import app
from softjig.errors import InputError
from softjig.evaluation import experiment as settings_module
from softjig.evaluation.experiment import ExperimentSettings
from softjig.experiments import paper as experiment

runner = CliRunner()


def _tiny(out, **kwargs):
    """One diameter, one tilt, theta every 60 deg (3 frames to calibrate, 3 held out), 3 cube frames."""
    params = {
        "diameters_mm": (50.0,),
        "alphas_deg": (10.0,),
        "theta_step_deg": 60.0,
        "cube_frames": 3,
        "workers": 2,
        "progress": False,
        "quick": True,
        "seed": 3,
    }
    params.update(kwargs)
    return ExperimentSettings(out_dir=out, **params)


@pytest.fixture(scope="module")
def demo_run(tmp_path_factory):
    """The CLI with the quick settings swapped for the tiny ones (the real --quick takes ~25 s)."""
    out = tmp_path_factory.mktemp("demo") / "out"
    patch = pytest.MonkeyPatch()
    patch.setattr(settings_module, "quick_settings", lambda out_dir, seed=0, **kw: _tiny(out_dir, **kw))
    try:
        result = runner.invoke(app, ["demo", "--quick", "--out", str(out), "--seed", "3", "--no-progress"])
    finally:
        patch.undo()
    return out, result


def test_demo_writes_the_report_and_prints_the_grid(demo_run):
    out, result = demo_run
    assert result.exit_code == 0, result.output
    assert "RMSE (deg), calibrated" in result.stdout and "uncalibrated" in result.stdout
    assert "held out" in result.stdout
    for name in (
        "report.md",
        "summary.json",
        "calibration.json",
        "calibration-per-diameter.json",
        "figures/tilt_before.png",
        "figures/tilt_after.png",
        "figures/rmse_grid.png",
        "figures/cube_normals.png",
        "figures/stereo_pair.png",
        "data/cube/mocap.csv",
        "data/sweep/estimates.jsonl",
    ):
        assert (out / name).is_file(), name
    report = (out / "report.md").read_text()
    assert "held out" in report and "![RMSE grid](figures/rmse_grid.png)" in report


def test_demo_calibration_does_real_work(demo_run):
    out, _ = demo_run
    cal = load_tilt_calibration(out / "calibration.json")  # readable by `softjig estimate --calibration`
    assert cal.scale > 1.2  # refraction compresses depth: the uncalibrated tilts read low
    summary = json.loads((out / "summary.json").read_text())
    ev = summary["evaluation"]
    assert ev["selection"] == "odd" and summary["calibration"]["selection"] == "even"
    assert ev["n_frames"] + ev["n_failed"] == 3
    cal_rmse = np.array(ev["calibrated"]["rmse_deg"], float)
    raw_rmse = np.array(ev["uncalibrated"]["rmse_deg"], float)
    assert cal_rmse.shape == (1, 1) and cal_rmse[0, 0] < raw_rmse[0, 0]
    assert summary["cube"]["calibrated"]["n"] >= 1
    data = json.loads((out / "calibration.json").read_text())
    assert data["source"]["dataset"].endswith("sweep") and data["source"]["method"] == "paper"


def test_no_holdout_uses_every_frame(tmp_path):
    result = experiment.run_experiment(_tiny(tmp_path / "all", split="none", cube_frames=0))
    assert result.calibration.selection == "all" and result.evaluation.selection == "all"
    assert result.cube is None and "same frames" in (tmp_path / "all" / "report.md").read_text()


# ------------------------------------------------------------------------ issue 14: the run folder


def _manifest(out):
    return json.loads((out / "manifest.json").read_text())


def _rows(path):
    rows = [json.loads(line) for line in path.read_text().splitlines() if line.strip()]
    return {r["index"]: (r.get("raw_tilt_x_deg"), r.get("raw_tilt_y_deg"), r.get("error")) for r in rows}


def test_an_interrupted_run_resumes_without_rendering_again(demo_run, tmp_path):
    """Ctrl-C after two chunks of two frames, then the same call: the finished chunks are not rendered
    again (the manifest names the run that rendered each, their files keep their mtimes), and the
    results are those of the uninterrupted CLI run (other chunks, other worker count)."""
    reference_out, _ = demo_run
    out = tmp_path / "run"
    settings = _tiny(out, chunk_frames=2, workers=1)

    def stop_at_the_third_chunk(text: str) -> None:
        if text.startswith("sweep: frames 4-"):
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        experiment.run_experiment(settings, on_stage=stop_at_the_third_chunk)
    first = _manifest(out)
    assert first["status"] == "running" and sorted(first["chunks"]) == ["sweep/000", "sweep/001"]
    finished = out / "data" / "sweep" / "chunks" / "001" / "frames.jsonl"
    mtime = finished.stat().st_mtime_ns

    # Other options are refused, naming what differs; the unfinished run is left as it was.
    with pytest.raises(InputError, match="seed"):
        experiment.run_experiment(_tiny(out, chunk_frames=2, workers=1, seed=4))
    assert _manifest(out)["chunks"] == first["chunks"]

    stages: list[str] = []
    result = experiment.run_experiment(settings, on_stage=stages.append)
    assert result.resumed and result.chunks_now == 4 - 2 + 2  # sweep chunks 2, 3 and both cube chunks
    assert any("resuming" in s for s in stages)
    assert not any(s.startswith(("sweep: frames 0-", "sweep: frames 2-")) for s in stages)
    chunks = _manifest(out)["chunks"]
    assert chunks["sweep/000"]["run"] == chunks["sweep/001"]["run"] == 1
    assert chunks["sweep/002"]["run"] == chunks["sweep/003"]["run"] == 2
    assert finished.stat().st_mtime_ns == mtime
    assert _manifest(out)["status"] == "finished"

    for name in ("estimates.jsonl", "estimates-refractive.jsonl"):
        assert _rows(out / "data" / "sweep" / name) == _rows(reference_out / "data" / "sweep" / name)
    ours, theirs = (json.loads((o / "summary.json").read_text()) for o in (out, reference_out))
    for key in ("calibration", "evaluation", "cube", "default_method"):
        assert ours[key] == theirs[key], key


def test_a_finished_run_is_not_overwritten_without_overwrite(demo_run):
    out, _ = demo_run
    before = (out / "report.md").read_text()
    patch = pytest.MonkeyPatch()
    patch.setattr(settings_module, "quick_settings", lambda out_dir, seed=0, **kw: _tiny(out_dir, **kw))
    try:
        result = runner.invoke(app, ["demo", "--quick", "--out", str(out), "--seed", "3", "--no-progress"])
    finally:
        patch.undo()
    assert result.exit_code == 2
    assert str(out) in result.stderr and "--overwrite" in result.stderr and "finished" in result.stderr
    assert (out / "report.md").read_text() == before


def test_overwrite_replaces_only_what_a_run_writes(tmp_path):
    out = tmp_path / "run"
    settings = _tiny(out, cube_frames=0, theta_step_deg=120.0, workers=1, split="none")
    experiment.run_experiment(settings)
    (out / "my-notes.txt").write_text("mine")
    with pytest.raises(InputError, match="finished"):
        experiment.run_experiment(settings)
    from dataclasses import replace

    result = experiment.run_experiment(replace(settings, overwrite=True))
    assert not result.resumed and (out / "my-notes.txt").read_text() == "mine"


def test_a_folder_that_is_not_a_run_is_never_touched(tmp_path):
    out = tmp_path / "photos"
    out.mkdir()
    (out / "calib.png").write_bytes(b"not ours")
    for overwrite in (False, True):
        with pytest.raises(InputError, match="not a softjig demo run"):
            experiment.run_experiment(_tiny(out, overwrite=overwrite))
    assert sorted(p.name for p in out.iterdir()) == ["calib.png"]


def test_the_demo_states_its_disk_use_and_keeps_only_what_the_report_needs(demo_run):
    out, result = demo_run
    printed = " ".join(result.stdout.split())
    assert "disk:" in printed and "MB (measured)" in printed
    from softjig.evaluation.run_folder import disk_use

    use = disk_use(out)
    assert f"holds {use.files} files, {use.mb:.1f} MB" in printed
    images = sorted(p.name for p in (out / "data").rglob("*.png"))
    # The two reference frames (sweep and cube) and the example pairs' frame(s), left and right.
    assert 4 <= len(images) <= 8, images
    summary = json.loads((out / "summary.json").read_text())
    assert summary["rendered"]["files"] > 3 * len(images)


def test_report_html_is_self_contained(demo_run):
    import base64
    import re

    out, _ = demo_run
    page = (out / "report.html").read_text()
    assert page.startswith("<!DOCTYPE html>") and "<table>" in page
    assert "http://" not in page and "https://" not in page and "<link" not in page and "<script" not in page
    sources = re.findall(r'<img [^>]*src="([^"]*)"', page)
    assert len(sources) >= 8  # methods, tilt x3, grid, cube x2, the example pairs
    for src in sources:
        assert src.startswith("data:image/png;base64,")
        assert base64.b64decode(src.split(",", 1)[1])[:8] == b"\x89PNG\r\n\x1a\n"
    assert "refractive (default), uncalibrated" in page and "its own calibration" in page


def test_report_text_is_escaped_in_html():
    from softjig.evaluation.report import _html_text

    assert _html_text("a <b> & **bold `x<y>`** `c&d`") == (
        "a &lt;b&gt; &amp; <strong>bold <code>x&lt;y&gt;</code></strong> <code>c&amp;d</code>"
    )


def test_a_ctrl_c_inside_a_compiled_kernel_stops_the_run_as_a_ctrl_c(tmp_path):
    """SIGINT while a Numba kernel calls back into Python reaches the caller as a SystemError caused by the
    KeyboardInterrupt (seen in CI: the interrupted run exited 1 with a traceback instead of 130); the run
    raises the KeyboardInterrupt, as it documents, and stays resumable."""

    def interrupted_in_a_kernel(text: str) -> None:
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt as exc:
            raise SystemError("CPUDispatcher(...) returned a result with an exception set") from exc

    with pytest.raises(KeyboardInterrupt):
        experiment.run_experiment(_tiny(tmp_path / "run", workers=1), on_stage=interrupted_in_a_kernel)
    assert _manifest(tmp_path / "run")["status"] == "running"


_RUN_SCRIPT = """
import sys
from softjig.evaluation.experiment import ExperimentSettings
from softjig.experiments.paper import run_experiment
settings = ExperimentSettings(
    out_dir=sys.argv[1], seed=3, diameters_mm=(50.0,), alphas_deg=(10.0,), theta_step_deg=120.0,
    cube_frames=0, split="none", workers=2, progress=False, chunk_frames=1,
)
try:
    run_experiment(settings, on_stage=lambda text: print(text, flush=True))
except KeyboardInterrupt:
    sys.exit(130)
"""


def test_ctrl_c_of_a_real_process_then_the_same_run_resumes(tmp_path):
    """SIGINT to a run (workers and all) once its first chunk is done: it stops, and the same settings
    then continue from the chunks it finished."""
    import os
    import signal
    import subprocess
    import sys
    import time

    out = tmp_path / "run"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    proc = subprocess.Popen([sys.executable, "-c", _RUN_SCRIPT, str(out)], env=env, stdout=subprocess.PIPE)
    deadline = time.monotonic() + 120
    try:
        while time.monotonic() < deadline:
            if (out / "manifest.json").is_file() and _manifest(out)["chunks"]:
                break
            time.sleep(0.05)
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=30) == 130
    finally:
        proc.kill()
    done = _manifest(out)["chunks"]
    assert done and _manifest(out)["status"] == "running"
    settings = ExperimentSettings(
        out_dir=out,
        seed=3,
        diameters_mm=(50.0,),
        alphas_deg=(10.0,),
        theta_step_deg=120.0,
        cube_frames=0,
        split="none",
        workers=1,
        progress=False,
        chunk_frames=1,
    )
    result = experiment.run_experiment(settings)
    assert result.resumed and result.chunks_now == 4 - len(done)
    after = _manifest(out)["chunks"]
    assert all(after[key]["run"] == 1 for key in done) and len(after) == 4
