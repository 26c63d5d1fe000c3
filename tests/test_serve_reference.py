"""The reference a live estimate measures its indentations against: a replay's own reference frame by
default (equal to `softjig estimate DATASET`), serve's `reference` request (checked unloaded), and
references of another rig or with a part pressed in refused with a clear message.

Real loopback sessions: `softjig serve --replay` subprocesses and a REQ socket (as tests/test_serve.py)."""

from __future__ import annotations

import json
import shutil
import sys
import time

import numpy as np
import pytest
from typer.testing import CliRunner

from softjig.cli import app
from softjig.config import default_jig
from test_serve import reference_then_loaded_dataset, serve_replay, stop_served

pytestmark = pytest.mark.skipif(sys.platform == "win32", reason="POSIX signals")

FRAME_PERIOD_S = 0.1


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    """An unloaded reference frame (index 0), then a loaded one (index 1), 0.1 s apart."""
    return reference_then_loaded_dataset(tmp_path_factory.mktemp("reference") / "ds", FRAME_PERIOD_S)


@pytest.fixture(scope="module")
def estimated(dataset, tmp_path_factory):
    """`softjig estimate DATASET`'s row of the loaded frame (against the dataset's reference frame)."""
    out = tmp_path_factory.mktemp("estimated") / "rows.jsonl"
    result = CliRunner().invoke(app, ["estimate", str(dataset), "--out", str(out), "--workers", "1"])
    assert result.exit_code == 0, result.output
    rows = [json.loads(line) for line in out.read_text().splitlines()]
    (row,) = [r for r in rows if r["index"] == 1]
    assert row["indentation_reference"] == "reference frame"
    return row


@pytest.fixture(scope="module")
def rest_shape_row(dataset, tmp_path_factory):
    out = tmp_path_factory.mktemp("rest") / "rows.jsonl"
    result = CliRunner().invoke(
        app, ["estimate", str(dataset), "--no-reference", "--out", str(out), "--workers", "1"]
    )
    assert result.exit_code == 0, result.output
    (row,) = [json.loads(x) for x in out.read_text().splitlines() if json.loads(x)["index"] == 1]
    assert row["indentation_reference"] == "rest shape"
    return row


def _estimate_of_loaded_frame(client, tries=20):
    """The estimate of the loaded frame (the replay loops over the reference frame and it)."""
    for _ in range(tries):
        reply = client.ask({"op": "estimate"})
        if reply["ok"] and reply["frame"]["index"] == 1:
            return reply["estimate"]
    raise AssertionError(f"no estimate of frame 1 in {tries} requests; the last reply: {reply}")


def test_a_replay_estimates_against_its_datasets_reference_frame(dataset, estimated):
    proc, seen, client = serve_replay(dataset)
    try:
        assert any("indentations against the reference frame" in line for line in seen), seen
        assert client.ask({"op": "health"})["reference"] == "reference frame"
        est = _estimate_of_loaded_frame(client)
    finally:
        stop_served(proc, client)
    assert est["indentation_reference"] == "reference frame"
    np.testing.assert_allclose(est["normal"], estimated["normal"], atol=1e-9)
    assert est["push_depth_mm"] == pytest.approx(estimated["push_depth_mm"], abs=1e-9)


def test_the_reference_request_refuses_a_loaded_pair_and_takes_an_unloaded_one(
    dataset, estimated, rest_shape_row
):
    """Served against the rest shape, the answer is the rest shape's; a `reference` request on the loaded
    frame is refused (the reference is kept), one on the empty jig's frame is taken, and from then on the
    answer is the reference frame's: the one `softjig estimate DATASET` gives."""
    assert not np.allclose(rest_shape_row["normal"], estimated["normal"], atol=1e-6)  # the test can fail
    proc, seen, client = serve_replay(dataset, "--no-reference")
    try:
        assert any("against the rest shape" in line for line in seen), seen
        before = _estimate_of_loaded_frame(client)
        assert before["indentation_reference"] == "rest shape"
        np.testing.assert_allclose(before["normal"], rest_shape_row["normal"], atol=1e-9)
        refused = taken = None
        deadline = time.monotonic() + 60.0
        while (refused is None or taken is None) and time.monotonic() < deadline:
            reply = client.ask({"op": "reference"})
            if reply["frame"]["index"] == 1:  # the part is pressed in
                assert not reply["ok"] and "is loaded" in reply["error"], reply
                assert "a part is pressed" in reply["error"]
                if taken is None:  # refused before any was taken: the rest shape is kept
                    assert "still estimating against the rest shape" in reply["error"]
                    assert client.ask({"op": "health"})["reference"] == "rest shape"
                refused = reply
            else:
                assert reply["ok"], reply
                assert reply["reference"]["source"] == "reference frame" and reply["reference"]["markers"] > 0
                taken = reply
        assert refused is not None and taken is not None
        assert client.ask({"op": "health"})["reference"] == "reference frame"
        after = _estimate_of_loaded_frame(client)
    finally:
        stop_served(proc, client)
    assert after["indentation_reference"] == "reference frame"
    np.testing.assert_allclose(after["normal"], estimated["normal"], atol=1e-9)


def test_the_paper_method_refuses_a_reference_request(dataset):
    from softjig.io.cameras import ReplaySource
    from softjig.live.loop import LiveSettings
    from softjig.live.serve import EstimationService, ServeSettings

    service = EstimationService(
        ReplaySource(dataset),
        LiveSettings(jig=default_jig(), method="paper"),
        ServeSettings(endpoint="tcp://127.0.0.1:*"),
    )
    try:
        reply = service.handle([b'{"op": "reference"}'])
        assert not reply["ok"] and "no reference frame" in reply["error"]
    finally:
        service.close()


# -------------------------------------------------------------------------------------- live (CLI)


def _live(*args):
    return CliRunner().invoke(app, ["live", "--rate", "fast", "--jsonl", *args])


def _estimates(output):
    return [json.loads(x) for x in output.splitlines() if x.startswith("{")]


def test_live_replay_uses_its_reference_frame_and_no_reference_the_rest_shape(
    dataset, estimated, rest_shape_row
):
    for extra, row in (((), estimated), (("--no-reference",), rest_shape_row)):
        result = _live("--replay", str(dataset), "--max-frames", "2", *extra)
        assert result.exit_code == 0, result.output
        (message,) = [m for m in _estimates(result.output) if m["frame"]["index"] == 1]
        assert message["estimate"]["indentation_reference"] == row["indentation_reference"]
        np.testing.assert_allclose(message["estimate"]["normal"], row["normal"], atol=1e-9)


def test_live_takes_a_reference_pair_and_refuses_a_loaded_one(dataset, estimated):
    def pair(index):
        return ["--reference-left", str(dataset / f"left/{index:06d}.png"),
                "--reference-right", str(dataset / f"right/{index:06d}.png")]  # fmt: skip

    result = _live("--replay", str(dataset), "--no-reference", "--max-frames", "2", *pair(0))
    assert result.exit_code == 2 and "contradict" in result.output
    result = _live("--replay", str(dataset), "--max-frames", "2", *pair(0))
    assert result.exit_code == 0, result.output
    (message,) = [m for m in _estimates(result.output) if m["frame"]["index"] == 1]
    assert message["estimate"]["indentation_reference"] == "reference frame"
    np.testing.assert_allclose(message["estimate"]["normal"], estimated["normal"], atol=1e-9)
    result = _live("--replay", str(dataset), "--max-frames", "2", *pair(1))
    assert result.exit_code == 2, result.output
    assert "is loaded" in result.output and "a part is pressed" in result.output
    assert "Traceback" not in result.output


def test_a_reference_from_another_dataset_of_the_rig_is_used(dataset, estimated, tmp_path):
    other = tmp_path / "empty-jig"
    shutil.copytree(dataset, other)
    result = _live("--replay", str(dataset), "--no-reference", "--reference-from", str(other))
    assert result.exit_code == 2 and "contradict" in result.output
    result = _live("--replay", str(dataset), "--reference-from", str(other), "--max-frames", "2")
    assert result.exit_code == 0, result.output
    (message,) = [m for m in _estimates(result.output) if m["frame"]["index"] == 1]
    np.testing.assert_allclose(message["estimate"]["normal"], estimated["normal"], atol=1e-9)


@pytest.mark.parametrize(
    ("old", "new", "message"),
    [
        ("width_px = 1280", "width_px = 1264", "1264x"),
        ("pitch_mm = 8.0", "pitch_mm = 7.0", "markers but the config's has"),
    ],
)
def test_a_reference_of_another_rig_is_refused(dataset, tmp_path, old, new, message):
    other = tmp_path / "other-rig"
    shutil.copytree(dataset, other)
    rig = (other / "rig.toml").read_text()
    assert old in rig
    (other / "rig.toml").write_text(rig.replace(old, new))
    result = _live("--replay", str(dataset), "--reference-from", str(other), "--max-frames", "1")
    assert result.exit_code == 2, result.output
    assert message in result.output and "reference frame of this rig" in result.output
    assert "Traceback" not in result.output


def test_estimate_refuses_a_dataset_of_another_rig_than_its_config(dataset, tmp_path):
    other = tmp_path / "rig.toml"
    other.write_text((dataset / "rig.toml").read_text().replace("pitch_mm = 8.0", "pitch_mm = 7.0"))
    result = CliRunner().invoke(
        app, ["estimate", str(dataset), "--config", str(other), "--out", str(tmp_path / "r.jsonl")]
    )
    assert result.exit_code == 2 and "markers but the config's has" in result.output, result.output


def test_estimate_refuses_a_loaded_reference_pair(dataset):
    result = CliRunner().invoke(
        app,
        [
            "estimate", str(dataset / "left/000001.png"), str(dataset / "right/000001.png"),
            "--config", str(dataset / "rig.toml"),
            "--reference-left", str(dataset / "left/000001.png"),
            "--reference-right", str(dataset / "right/000001.png"),
        ],
    )  # fmt: skip
    assert result.exit_code == 2 and "is loaded" in result.output, result.output
