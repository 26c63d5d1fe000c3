"""The live loop on replays: every frame when fast, drops when busy, a failing camera, stop, Ctrl-C, CLI."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import threading
import time

import pytest
from typer.testing import CliRunner

from softjig.cli import app
from softjig.config import default_jig
from softjig.io.cameras import CameraError, ReplaySource, StereoSource
from softjig.io.dataset import Dataset
from softjig.io.simulated import simulate_dataset
from softjig.io.stream import TOPIC_ESTIMATE, TOPIC_HEALTH, Publisher, Subscriber
from softjig.live.loop import HealthSnapshot, LiveLoop, LiveSettings, PublisherSink, health_status
from softjig.sim.scenarios import paper_sweep

runner = CliRunner()


@pytest.fixture(scope="module")
def sweep(tmp_path_factory):
    """A reference frame and 4 loaded frames (D = 50 mm, alpha = 10 deg)."""
    out = tmp_path_factory.mktemp("live") / "sweep"
    specs = list(paper_sweep(diameters_mm=(50,), alphas_deg=(10,), theta_step_deg=90))
    simulate_dataset(out, specs, default_jig(), seed=4, workers=1, progress=False)
    return Dataset.open(out)


def _free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _collect(sub, timeout_s=20.0):
    """Messages until the final health message (status "stopped")."""
    return sub.receive_until(lambda t, p: t == TOPIC_HEALTH and p["status"] == "stopped", timeout_s)


def _connected_pair():
    pub = Publisher("tcp://127.0.0.1:*")
    sub = Subscriber(pub.endpoint)
    deadline = time.monotonic() + 10
    while time.monotonic() < deadline:  # ZeroMQ's slow joiner: wait until the subscription is live
        pub.publish(TOPIC_HEALTH, {"seq": -1, "status": "probe"})
        if sub.receive(0.05) is not None:
            break
    while sub.receive(0.05) is not None:
        pass
    return pub, sub


def test_fast_replay_estimates_every_frame_and_publishes_it(sweep):
    pub, sub = _connected_pair()
    with sub:
        summary = LiveLoop(
            ReplaySource(sweep, rate="fast"),
            LiveSettings(jig=sweep.jig, method="paper"),  # the paper's method needs the frame's part
            sinks=[PublisherSink(pub)],
        ).run()
        messages = _collect(sub)
    assert (summary.final.captured, summary.final.processed, summary.final.dropped) == (5, 5, 0)
    assert summary.exhausted and not summary.interrupted
    assert (summary.final.estimated, summary.final.failed) == (4, 1)  # the reference frame names no part
    estimates = [p for t, p in messages if t == TOPIC_ESTIMATE]
    assert [p["seq"] for p in estimates] == [0, 1, 2, 3, 4]
    assert [p["frame"]["index"] for p in estimates] == [0, 1, 2, 3, 4]
    first, loaded = estimates[0], estimates[1]
    assert (first["ok"], first["exit_code"], first["estimate"]) == (False, 2, None)
    assert "part" in first["error"]
    assert loaded["ok"] and loaded["exit_code"] == 0 and loaded["error"] is None
    for key in ("normal", "tilt_x_deg", "tilt_y_deg", "push_depth_mm", "n_points"):
        assert key in loaded["estimate"]
    assert loaded["latency_ms"] > 0 and loaded["frame"]["skew_ms"] == 0.0
    healths = [p for t, p in messages if t == TOPIC_HEALTH]
    assert healths[-1]["status"] == "stopped"
    assert healths[-1]["frames"] == {
        "captured": 5,
        "processed": 5,
        "dropped": 0,
        "estimated": 4,
        "failed": 1,
        "recorded": 0,
        "not_recorded": 0,
        "unreadable": 0,
    }
    assert healths[-1]["latency_ms"]["median"] > 0


def test_a_busy_estimator_drops_camera_rate_frames_and_counts_them(sweep):
    # 1000 Hz replay, and a consumer that takes 0.2 s per outcome: frames arrive (as fast as the replay
    # decodes them, ~30 ms) while the estimator is busy, however fast the estimate itself is
    outcomes = []

    def slow_consumer(outcome, message):
        time.sleep(0.2)
        outcomes.append(message)

    summary = LiveLoop(
        ReplaySource(sweep, rate="recorded", fps=1000.0),
        LiveSettings(jig=sweep.jig, part_diameter_mm=50.0),
        on_outcome=slow_consumer,
    ).run()
    assert summary.final.captured == 5
    assert summary.final.dropped >= 1
    assert summary.final.processed + summary.final.dropped == summary.final.captured
    assert [m["dropped_frames"] for m in outcomes] == sorted(m["dropped_frames"] for m in outcomes)
    assert outcomes[-1]["frame"]["index"] == 4  # the newest frame is never the one dropped


class _FlakySource(StereoSource):
    """A replay whose camera fails: an error on the 2nd read, then silence, then frames again."""

    def __init__(self, dataset, script):
        self.inner = ReplaySource(dataset, rate="fast")
        self.name, self.realtime = "flaky", True
        self.script = list(script)  # per read: "ok", "error" or "silent"
        self.opens = 0

    def open(self):
        self.opens += 1

    def read(self, timeout_s):
        action = self.script.pop(0) if self.script else "ok"
        if action == "error":
            raise CameraError("camera 1 stopped streaming")
        if action == "silent":
            time.sleep(timeout_s)
            return None
        return self.inner.read(timeout_s)

    def close(self):
        pass


def test_a_failing_camera_is_retried_and_reported_unhealthy(sweep):
    source = _FlakySource(sweep, ["ok", "error", "silent", "silent", "ok", "error"])
    settings = LiveSettings(
        jig=sweep.jig,
        part_diameter_mm=50.0,
        read_timeout_s=0.05,
        reopen_after_timeouts=2,
        retry_delay_s=0.01,
        retry_delay_max_s=0.05,
        health_period_s=5.0,
    )
    pub, sub = _connected_pair()
    with sub:
        summary = LiveLoop(source, settings, sinks=[PublisherSink(pub)]).run()
        messages = _collect(sub)
    assert summary.final.captured == 5 and summary.exhausted  # every frame got through in the end
    assert summary.final.camera_errors == 3  # two errors and one re-open after silence
    assert summary.final.reopens == 3 and source.opens == 4
    statuses = [p["status"] for t, p in messages if t == TOPIC_HEALTH]
    assert "unhealthy" in statuses
    unhealthy = next(p for t, p in messages if t == TOPIC_HEALTH and p["status"] == "unhealthy")
    assert not unhealthy["camera"]["healthy"] and unhealthy["camera"]["message"]
    assert statuses[-1] == "stopped"


class _Endless(StereoSource):
    name, realtime = "endless", True

    def __init__(self, dataset):
        self.dataset = dataset

    def open(self):
        pass

    def read(self, timeout_s):
        source = ReplaySource(self.dataset, rate="fast")
        frame = source.read(timeout_s)
        time.sleep(0.01)
        return frame

    def close(self):
        pass


def test_stop_ends_an_endless_loop_cleanly(sweep):
    loop = LiveLoop(_Endless(sweep), LiveSettings(jig=sweep.jig, part_diameter_mm=50.0))
    timer = threading.Timer(1.0, loop.stop)
    timer.start()
    summary = loop.run()
    timer.cancel()
    assert summary.interrupted and not summary.exhausted
    assert summary.final.captured >= 1


def test_a_ctrl_c_inside_a_compiled_kernel_ends_the_loop_as_a_ctrl_c(sweep):
    """SIGINT while a Numba kernel calls back into Python arrives as a SystemError caused by the
    KeyboardInterrupt; the loop ends interrupted, with its summary, as on any other Ctrl-C."""

    def interrupted_in_a_kernel(outcome, message):
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt as exc:
            raise SystemError("CPUDispatcher(...) returned a result with an exception set") from exc

    summary = LiveLoop(
        _Endless(sweep),
        LiveSettings(jig=sweep.jig, part_diameter_mm=50.0),
        on_outcome=interrupted_in_a_kernel,
    ).run()
    assert summary.interrupted and summary.final.processed == 1


def test_max_frames_limits_the_captured_pairs(sweep):
    summary = LiveLoop(
        ReplaySource(sweep, rate="fast"), LiveSettings(jig=sweep.jig, part_diameter_mm=50.0, max_frames=2)
    ).run()
    assert (summary.final.captured, summary.final.processed) == (2, 2)


def test_health_status_words():
    base = dict(
        source="s",
        camera_healthy=True,
        camera_message=None,
        last_frame_age_s=0.0,
        camera_errors=0,
        reopens=0,
        captured=1,
        processed=1,
        dropped=0,
        estimated=1,
        failed=0,
        recorded=0,
        not_recorded=0,
        last_ok=True,
        latency_last_s=0.1,
        latency_median_s=0.1,
        latency_p95_s=0.1,
        rate_hz=10.0,
    )
    assert health_status(HealthSnapshot(**base)) == "ok"
    assert health_status(HealthSnapshot(**{**base, "last_ok": False})) == "no_estimate"
    assert health_status(HealthSnapshot(**{**base, "last_ok": None})) == "starting"
    assert health_status(HealthSnapshot(**{**base, "camera_healthy": False})) == "unhealthy"
    assert health_status(HealthSnapshot(**base, stopped=True)) == "stopped"


# --------------------------------------------------------------------------------------------- CLI


def test_cli_live_replay_publishes(sweep):
    port = _free_port()
    endpoint = f"tcp://127.0.0.1:{port}"
    result = runner.invoke(
        app,
        [
            "live",
            "--replay",
            str(sweep.root),
            "--publish",
            endpoint,
            "--rate",
            "fast",
            "--max-frames",
            "3",
            "--part-diameter",
            "50",
            "--jsonl",
            "--method",
            "paper",
        ],
    )
    assert result.exit_code == 0, result.output
    assert "3 pairs captured" in result.output
    assert result.stdout.count('"schema":"softjig.estimate"') == 3


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--source", "opencv:0,1"], "either --replay"),
        (["--publish", "tcp://0.0.0.0:5555"], "--allow-remote"),
        (["--max-frames", "0"], "max-frames"),
    ],
)
def test_cli_live_bad_usage_exits_2(sweep, args, message):
    result = runner.invoke(app, ["live", "--replay", str(sweep.root), *args])
    assert result.exit_code == 2
    assert message in result.output


@pytest.mark.parametrize(
    ("args", "code"),
    [
        (["--method", "paper"], 2),  # the reference frame names no part: the paper's crop is unknown
        (["--method", "paper", "--part-diameter", "1"], 3),  # valid, but too few markers in a 1 mm crop
    ],
)
def test_cli_live_without_any_estimate_exits_with_the_frames_code(sweep, args, code):
    result = runner.invoke(
        app, ["live", "--replay", str(sweep.root), "--rate", "fast", "--max-frames", "1", *args]
    )
    assert result.exit_code == code, result.output
    assert "no frame gave an estimate" in result.output


@pytest.mark.skipif(sys.platform == "win32", reason="POSIX signals")
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_ctrl_c_stops_the_live_command_cleanly(sweep, sig):
    port = _free_port()
    proc = subprocess.Popen(
        [
            sys.executable,
            "-c",
            "from softjig.cli import main; main()",
            "live",
            "--replay",
            str(sweep.root),
            "--fps",
            "0.5",
            "--part-diameter",
            "50",
            "--publish",
            f"tcp://127.0.0.1:{port}",
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, "COLUMNS": "200"},
    )
    try:
        with Subscriber(f"tcp://127.0.0.1:{port}") as sub:
            first = sub.receive(timeout_s=30.0)  # the loop is running: a health or estimate message
            assert first is not None
        proc.send_signal(sig)
        _out, err = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 0, err
    assert "stopped:" in err and "Traceback" not in err


def _with_bad_frames(sweep, tmp_path, n_bad: int, keep_good: bool = True):
    """A copy of the sweep with ``n_bad`` frames whose images are missing (after its good ones)."""
    import json
    import shutil

    root = shutil.copytree(sweep.root, tmp_path / "bad")
    lines = (root / "frames.jsonl").read_text().splitlines() if keep_good else []
    for k in range(n_bad):
        lines.append(
            json.dumps({"index": 100 + k, "left": f"left/gone{k}.png", "right": f"right/gone{k}.png"})
        )
    (root / "frames.jsonl").write_text("\n".join(lines) + "\n")
    return root


def test_a_replays_unreadable_frames_are_skipped_at_once_not_retried_like_a_camera(sweep, tmp_path):
    root = _with_bad_frames(sweep, tmp_path, 6)
    settings = LiveSettings(jig=sweep.jig)  # the real back-off: 0.5 s doubling to 5 s per camera error
    assert settings.retry_delay_s >= 0.5
    t0 = time.monotonic()
    summary = LiveLoop(ReplaySource(root, rate="fast"), settings).run()
    elapsed = time.monotonic() - t0
    final = summary.final
    assert (final.bad_frames, final.camera_errors, final.reopens) == (6, 0, 0)
    assert final.captured == final.processed == 5 and summary.exhausted
    assert "frame 100" in summary.first_bad_frame and "does not exist" in summary.first_bad_frame
    assert elapsed < 6 * settings.retry_delay_s  # one back-off per frame would take 17.5 s


def test_cli_live_reports_skipped_frames_and_exits_2_when_none_could_be_read(sweep, tmp_path):
    some = _with_bad_frames(sweep, tmp_path / "some", 2)
    result = runner.invoke(app, ["live", "--replay", str(some), "--rate", "fast"])
    assert result.exit_code == 0, result.output
    assert "2 unreadable frames skipped" in result.output and "warning:" in result.output
    none = _with_bad_frames(sweep, tmp_path / "none", 3, keep_good=False)
    result = runner.invoke(app, ["live", "--replay", str(none), "--rate", "fast"])
    assert result.exit_code == 2 and "no frame of the replay could be read" in result.output


def test_cli_live_refuses_an_empty_replay(sweep, tmp_path):
    import shutil

    root = shutil.copytree(sweep.root, tmp_path / "empty")
    (root / "frames.jsonl").write_text("")
    result = runner.invoke(app, ["live", "--replay", str(root)])
    assert result.exit_code == 2 and "has no frames" in result.output


@pytest.mark.parametrize("diameter", ["0", "1e6"])
def test_cli_live_refuses_a_part_diameter_no_jig_holds(sweep, diameter):
    """Refused once (exit 2) before the first pair, not pair after pair: the live loop checked only its
    sign, so a part wider than the membrane ran the camera (every pair refused, exit 2 only once a
    replay ended; a camera would go on)."""
    result = runner.invoke(
        app, ["live", "--replay", str(sweep.root), "--rate", "fast", "--part-diameter", diameter]
    )
    assert result.exit_code == 2, result.output
    assert "part diameter" in result.output and "Traceback" not in result.output
    assert "pairs captured" not in result.output  # the loop never started


@pytest.mark.parametrize(("option", "value"), [("--method", "svd"), ("--rate", "slow")])
def test_cli_live_choices_are_checked_before_any_work_and_listed(tmp_path, option, value):
    result = runner.invoke(app, ["live", "--replay", str(tmp_path / "not-yet-read"), option, value])
    assert result.exit_code == 2
    assert value in result.output and "does not exist" not in result.output  # refused before the replay
    choices = ("refractive", "paper") if option == "--method" else ("recorded", "fast")
    assert all(choice in result.output for choice in choices)
    help_text = runner.invoke(app, ["live", "--help"], env={"COLUMNS": "200"}).output
    assert "|".join(choices) in help_text or all(choice in help_text for choice in choices)


def test_mcap_overwrite_replaces_only_an_mcap_file(tmp_path):
    from softjig.live.viewer import _is_mcap

    (tmp_path / "log.mcap").write_bytes(b"\x89MCAP0\r\n...")
    (tmp_path / "photo.png").write_bytes(b"\x89PNG\r\n\x1a\n")
    assert _is_mcap(tmp_path / "log.mcap") and not _is_mcap(tmp_path / "photo.png")
    assert not _is_mcap(tmp_path)
