"""`softjig serve`: a real REQ socket on loopback against a `softjig serve --replay` subprocess (every wait
bounded): estimates of pairs captured after the request, settle detection after a creep, the pump, bad
requests answered without the service going down, a busy port, a remote bind refused, SIGTERM."""

from __future__ import annotations

import json
import os
import queue
import signal
import socket
import statistics
import subprocess
import sys
import threading
import time

import numpy as np
import pytest
import zmq

from softjig.config import CylinderPart, default_jig
from softjig.hardware.pump import SimulatedPumpController
from softjig.io.simulated import simulate_dataset
from softjig.live.settle import Sample, settled_since
from softjig.sim.scenarios import single

pytestmark = pytest.mark.skipif(sys.platform == "win32", reason="POSIX signals and pseudo-terminals")

#: Frames of the creep dataset: the part's tilt creeps 4 -> 8 deg over 3 frames, then holds 10 deg.
CREEP_ALPHAS = (4.0, 6.0, 8.0, *([10.0] * 9))
FRAME_PERIOD_S = 0.1


# ------------------------------------------------------------------------------------- settle (pure)


def _still(n, sigma=0.3, step_s=0.1, rng=0, drift_deg=0.0, tilt_deg=10.0):
    rng = np.random.default_rng(rng)
    out = []
    for i in range(n):
        a = np.radians(tilt_deg + drift_deg * i + rng.normal(0, sigma / np.sqrt(2)))
        b = rng.normal(0, np.radians(sigma / np.sqrt(2)))
        n_ = np.array([np.sin(a), np.sin(b), np.cos(a)])
        out.append(Sample(i * step_s, tuple(n_ / np.linalg.norm(n_)), sigma))
    return out


def test_still_estimates_settle_once_the_window_is_covered():
    samples = _still(12)
    assert not settled_since(samples[:5], 0.5)  # 0.4 s of samples: not yet
    assert settled_since(samples[:6], 0.5)
    assert settled_since(samples, 0.5)


def test_a_creep_of_a_few_sigma_over_the_window_is_not_settled():
    assert not settled_since(_still(12, drift_deg=0.3), 0.5)  # 1.5 deg over 0.5 s, sigma 0.3 deg
    creep = _still(12, drift_deg=1.0)  # 10 -> 21 deg, then still at 21 deg
    still = [Sample(1.2 + s.t_s, s.normal, s.sigma_deg) for s in _still(8, rng=1, tilt_deg=21.0)]
    assert not settled_since(creep + still[:3], 0.5)  # the window still reaches into the creep
    assert settled_since(creep + still, 0.5)  # 0.7 s of still estimates after it


def test_a_failed_or_sigma_less_estimate_in_the_window_is_not_settled():
    samples = _still(8)
    assert not settled_since([*samples[:-1], Sample(0.7, None, None)], 0.5)
    assert not settled_since([*samples[:-1], Sample(0.7, samples[-1].normal, None)], 0.5)


# ------------------------------------------------------------------------------- the service process


def _timed(out, frame_period_s: float):
    """The dataset at ``out``, its frames stamped ``frame_period_s`` apart (``time_s``)."""
    lines = (out / "frames.jsonl").read_text().splitlines()
    with open(out / "frames.jsonl", "w") as fh:
        for i, line in enumerate(lines):
            fh.write(json.dumps({**json.loads(line), "time_s": round(i * frame_period_s, 6)}) + "\n")
    return out


@pytest.fixture(scope="module")
def creep(tmp_path_factory):
    out = tmp_path_factory.mktemp("serve") / "creep"
    specs = [spec for alpha in CREEP_ALPHAS for spec in single(CylinderPart(50.0), alpha, 0.0)]
    simulate_dataset(out, specs, default_jig(), seed=11, workers=1, progress=False)
    return _timed(out, FRAME_PERIOD_S)


def reference_then_loaded_dataset(out, frame_period_s: float):
    """A replay dataset at ``out``: an unloaded reference frame (index 0), then a loaded one (index 1),
    ``frame_period_s`` apart (for the serve tests that swap references)."""
    specs = single(CylinderPart(50.0), 8.0, 30.0, reference=True)
    simulate_dataset(out, specs, default_jig(), seed=3, workers=1, progress=False)
    return _timed(out, frame_period_s)


def _free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _start(args, wait_for="serving on", timeout_s=180.0):
    """A `softjig ...` subprocess, and its stderr lines so far (a reader thread keeps reading them)."""
    proc = subprocess.Popen(
        [sys.executable, "-c", "from softjig.cli import main; main()", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, "COLUMNS": "200"},
    )
    lines: queue.Queue[str] = queue.Queue()
    seen: list[str] = []
    reader = threading.Thread(target=lambda: [lines.put(x) for x in proc.stderr], daemon=True)
    reader.start()
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        try:
            line = lines.get(timeout=0.5)
        except queue.Empty:
            if proc.poll() is not None:
                break
            continue
        seen.append(line)
        if wait_for in line:
            return proc, seen, lines, reader
    proc.kill()
    proc.wait()
    raise AssertionError(f"softjig {' '.join(args)} did not say {wait_for!r}: {''.join(seen)}")


def serve_replay(dataset, *extra):
    """`softjig serve --replay dataset` on a free loopback port, once serving: (process, its stderr lines
    so far, a :class:`Client` of it). Stop it with :func:`stop_served`."""
    port = _free_port()
    proc, seen, _lines, _reader = _start(
        ["serve", "--replay", str(dataset), "--bind", f"tcp://127.0.0.1:{port}", *extra]
    )
    return proc, seen, Client(f"tcp://127.0.0.1:{port}")


def stop_served(proc, client):
    client.close()
    proc.terminate()
    proc.wait(timeout=60)


class Client:
    """A REQ socket with bounded waits (a fresh socket after a lost reply: REQ must alternate)."""

    def __init__(self, endpoint):
        self.endpoint = endpoint
        self.ctx = zmq.Context()
        self._new()

    def _new(self):
        self.sock = self.ctx.socket(zmq.REQ)
        self.sock.setsockopt(zmq.LINGER, 0)
        self.sock.connect(self.endpoint)

    def ask_raw(self, data: bytes, timeout_s=30.0):
        self.sock.send(data)
        if not self.sock.poll(int(timeout_s * 1000)):
            self.sock.close(0)
            self._new()
            return None
        return json.loads(self.sock.recv())

    def ask(self, request, timeout_s=30.0):
        return self.ask_raw(json.dumps(request).encode(), timeout_s)

    def close(self):
        self.sock.close(0)
        self.ctx.term()


@pytest.fixture(scope="module")
def service(creep):
    sim, pty_path = SimulatedPumpController.on_pty(fix_time_s=0.2, release_time_s=0.2)
    sim.start()
    port = _free_port()
    args = [
        "serve",
        "--replay",
        str(creep),
        "--bind",
        f"tcp://127.0.0.1:{port}",
        "--pump",
        pty_path,
        "--settle-s",
        "0.3",
        "--method",
        "refractive",
    ]
    proc, seen, lines, reader = _start(args)
    client = Client(f"tcp://127.0.0.1:{port}")
    yield {
        "proc": proc,
        "client": client,
        "sim": sim,
        "port": port,
        "stderr": seen,
        "lines": lines,
        "reader": reader,
    }
    client.close()
    if proc.poll() is None:
        proc.kill()
        proc.wait()
    sim.stop()


def test_it_warms_up_before_serving(service):
    assert any("warmed up in" in line for line in service["stderr"])


def test_estimate_is_of_a_pair_captured_after_the_request_and_keeps_the_contract(service):
    client = service["client"]
    t_sent = time.time()
    reply = client.ask({"op": "estimate"})
    assert reply["ok"] and reply["schema"] == "softjig.reply" and reply["version"] == 1, reply
    assert reply["frame"]["capture_time_unix_s"] > t_sent
    est = reply["estimate"]
    for key in (
        "normal",
        "tilt_x_deg",
        "tilt_y_deg",
        "push_depth_mm",
        "n_points",
        "rms_residual_mm",
        "frame_source",
        "warnings",
        "tilt_sigma_deg",
    ):
        assert key in est
    assert abs(np.linalg.norm(est["normal"]) - 1.0) < 1e-9


def test_first_request_is_as_fast_as_later_ones(service):
    """Generous bounds (a shared, loaded machine): the figure itself is in benchmarks/bench_serve.py."""
    client = Client(f"tcp://127.0.0.1:{service['port']}")
    try:
        latencies = []
        for _ in range(8):
            reply = client.ask({"op": "estimate"})
            assert reply["ok"], reply
            latencies.append(reply["latency_ms"])
    finally:
        client.close()
    later = statistics.median(latencies[1:])
    assert latencies[0] < 3 * later + 250.0, latencies


def test_settled_waits_out_the_creep(service):
    reply = service["client"].ask({"op": "settled", "timeout_s": 20}, timeout_s=40)
    assert reply["ok"], reply
    index = reply["frame"]["index"]
    first_still = CREEP_ALPHAS.index(10.0)
    # in the still part, and at least settle_s (0.3 s = 3 frames) into it: never during the creep
    assert index >= first_still + 3, index
    assert reply["estimate"]["normal"][0] == pytest.approx(np.sin(np.radians(10.0)), abs=0.02)


def test_settled_times_out_with_a_clear_error(service):
    reply = service["client"].ask({"op": "settled", "timeout_s": 0.05})
    assert not reply["ok"] and reply["error"].startswith("timeout")


def test_fix_and_release_drive_the_pump(service):
    client, sim = service["client"], service["sim"]
    reply = client.ask({"op": "fix"})
    assert reply["ok"] and reply["pump"]["state"] == "fixed", reply
    reply = client.ask({"op": "release"})
    assert reply["ok"] and reply["pump"]["state"] == "released", reply
    assert {"FIX", "RELEASE"} <= set(sim.requests)
    health = client.ask({"op": "health"})
    assert health["ok"] and health["pump"]["state"] == "released"
    assert health["health"]["status"] in ("ok", "no_estimate") and health["health"]["frames"]["processed"] > 0


def test_a_fixed_jig_is_kept_fixed_by_the_heartbeat_between_requests(service):
    """The controller's watchdog (2 s in the simulator) stops a pump nobody talks to; the service's
    heartbeat keeps it regulating while the jig holds, until release."""
    client, sim = service["client"], service["sim"]
    assert client.ask({"op": "fix"})["pump"]["state"] == "fixed"
    time.sleep(3.0)  # longer than the watchdog, no request meanwhile
    health = client.ask({"op": "health"})
    assert health["pump"]["state"] == "fixed" and health["pump"]["holding"], health["pump"]
    assert sim.watchdog_trips == 0
    assert client.ask({"op": "release"})["pump"]["state"] == "released"


@pytest.mark.parametrize(
    ("payload", "message"),
    [
        (b"not json", "not JSON"),
        (b"[1, 2]", "JSON object"),
        (b'{"op": "teleport"}', "unknown op 'teleport'; valid: estimate, settled, fix, release, health"),
        (b'{"op": "estimate", "timeout_s": -1}', "timeout_s"),
        (b'{"op": "estimate", "timeout_s": NaN}', "timeout_s must be a number"),  # Python's JSON reads NaN
        (b'{"op": "settled", "timeout_s": 1e999}', "timeout_s must be a number"),  # inf
        (b'{"op": "estimate", "timeout_s": 1e9}', "timeout_s must be in (0, 300] s"),
        (b'{"op": "estimate", "timeout_s": true}', "timeout_s must be a number"),
        (b'{"op": "health", "pad": "' + b"x" * 100_000 + b'"}', "exceeds the limit of 65536 bytes"),
    ],
)
def test_bad_requests_get_an_error_reply_and_the_service_stays_up(service, payload, message):
    client = service["client"]
    reply = client.ask_raw(payload)
    assert reply is not None and reply["ok"] is False and message in reply["error"], reply
    assert client.ask({"op": "health"})["ok"]


def test_a_message_beyond_zmq_maxmsgsize_is_dropped_and_the_service_stays_up(service):
    client = service["client"]
    assert client.ask_raw(b"x" * (2 * 1024 * 1024), timeout_s=2.0) is None  # disconnected by ZeroMQ
    assert client.ask({"op": "health"})["ok"]  # a fresh socket is answered


def test_a_busy_port_is_a_clear_error(service, creep):
    proc = subprocess.run(
        [
            sys.executable,
            "-c",
            "from softjig.cli import main; main()",
            "serve",
            "--replay",
            str(creep),
            "--bind",
            f"tcp://127.0.0.1:{service['port']}",
        ],
        capture_output=True,
        text=True,
        timeout=120,
        env={**os.environ, "COLUMNS": "200"},
    )
    assert proc.returncode == 2, proc.stderr
    assert "cannot bind" in proc.stderr and "--bind" in proc.stderr and "Traceback" not in proc.stderr
    assert service["client"].ask({"op": "health"})["ok"]


def test_a_remote_bind_needs_allow_remote(creep):
    proc = subprocess.run(
        [
            sys.executable,
            "-c",
            "from softjig.cli import main; main()",
            "serve",
            "--replay",
            str(creep),
            "--bind",
            "tcp://0.0.0.0:5999",
        ],
        capture_output=True,
        text=True,
        timeout=120,
        env={**os.environ, "COLUMNS": "200"},
    )
    assert proc.returncode == 2 and "--allow-remote" in proc.stderr


def test_sigterm_stops_it_cleanly_and_sends_the_pump_to_its_safe_state(service):
    client, sim, proc = service["client"], service["sim"], service["proc"]
    assert client.ask({"op": "fix"})["pump"]["state"] == "fixed"
    proc.send_signal(signal.SIGTERM)
    assert proc.wait(timeout=60) == 0
    service["reader"].join(timeout=10)
    rest = []
    while not service["lines"].empty():
        rest.append(service["lines"].get())
    assert any("stopped: answered" in line for line in rest), rest
    assert sim.requests[-1] == "STOP" and sim.state == "safe"


# ------------------------------------------------------------------------------------- in process


def test_warm_up_without_a_pair_renders_one_of_the_jig(creep):
    """The cameras' path (--source): a pair of the nominal jig is rendered and estimated."""
    from softjig.io.cameras import ReplaySource
    from softjig.live.loop import LiveLoop, LiveSettings
    from softjig.live.serve import warm_up

    loop = LiveLoop(ReplaySource(creep), LiveSettings(jig=default_jig(), method="refractive"))
    done = warm_up(loop)
    assert done.seconds > 0 and done.estimated and done.against == "rest shape"


def test_handle_answers_anything_without_raising(creep):
    from softjig.io.cameras import ReplaySource
    from softjig.live.loop import LiveSettings
    from softjig.live.serve import EstimationService, ServeSettings

    service = EstimationService(
        ReplaySource(creep), LiveSettings(jig=default_jig()), ServeSettings(endpoint="tcp://127.0.0.1:*")
    )
    try:
        assert "one message frame" in service.handle([b'{"op": "health"}', b"x"])["error"]
        assert "not JSON" in service.handle([b"\xff\xfe"])["error"]
        assert "drives no pump" in service.handle([b'{"op": "release"}'])["error"]
        assert "timeout_s" in service.handle([b'{"op": "estimate", "timeout_s": true}'])["error"]
        # the loop was never started: an estimate times out, with a clear error
        reply = service.handle([b'{"op": "estimate", "timeout_s": 0.05}'])
        assert reply["ok"] is False and reply["error"].startswith("timeout after 0.05 s")
        assert service.handle([b'{"op": "health"}'])["health"]["status"] == "starting"
    finally:
        service.close()


def test_a_pump_that_cannot_be_opened_is_a_clear_error(creep, tmp_path):
    from typer.testing import CliRunner

    from softjig.cli import app

    result = CliRunner().invoke(
        app,
        [
            "serve",
            "--replay",
            str(creep),
            "--bind",
            f"tcp://127.0.0.1:{_free_port()}",
            "--pump",
            str(tmp_path / "no-such-tty"),
        ],
    )
    assert result.exit_code == 2 and "serial port" in result.output, result.output


@pytest.mark.parametrize(("option", "value"), [("--method", "svd"), ("--rate", "slow")])
def test_choices_are_listed_and_checked_before_any_work(tmp_path, option, value):
    """Like live: a misspelt choice is refused while parsing (exit 2), naming the valid ones, before the
    replay is opened or the estimator warmed up."""
    from typer.testing import CliRunner

    from softjig.cli import app

    missing = tmp_path / "no-such-dataset"  # never opened: the options fail first
    result = CliRunner().invoke(app, ["serve", "--replay", str(missing), option, value])
    assert result.exit_code == 2
    assert ("refractive" in result.output) if option == "--method" else ("recorded" in result.output)
    assert "no-such-dataset" not in result.output


@pytest.mark.parametrize(
    ("options", "message"),
    [
        (["--rate", "fast"], "--rate applies to --replay, not to cameras"),
        (["--method", "paper"], "the paper's method on live cameras needs --part-diameter MM"),
    ],
)
def test_cameras_are_checked_as_live_checks_them_before_any_are_opened(options, message):
    """``--source`` goes through live's checks (:func:`softjig.cli.live.open_cameras`): refused, exit 2,
    before the (here missing) cameras are opened."""
    from typer.testing import CliRunner

    from softjig.cli import app

    result = CliRunner().invoke(app, ["serve", "--source", "opencv:/no/l.avi,/no/r.avi", *options])
    assert result.exit_code == 2 and message in " ".join(result.output.split()), result.output
