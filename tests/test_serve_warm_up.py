"""`softjig serve` and `live` warm the estimator they will use, with its reference, before the cameras
open, and a `reference` request warms the new one before it replaces the one in use (issue 15 item 6:
no warm-up at the robot's expense).

Observable: the warm-up's own estimate says what it measured its indentations against (the stderr line,
and the `warmed_up` field of `health`), so a warm-up of a throw-away estimator of the rest shape cannot
pass for one of the loop's estimator of the reference frame. Real loopback sessions, as tests/test_serve.py.
"""

from __future__ import annotations

import sys
import time

import pytest
from typer.testing import CliRunner

from softjig.cli import app
from test_serve import reference_then_loaded_dataset, serve_replay, stop_served

pytestmark = pytest.mark.skipif(sys.platform == "win32", reason="POSIX signals")

FRAME_PERIOD_S = 0.1


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    """An unloaded reference frame (index 0), then a loaded one (index 1), 0.1 s apart."""
    return reference_then_loaded_dataset(tmp_path_factory.mktemp("warm") / "ds", FRAME_PERIOD_S)


def test_serve_warms_the_estimator_of_its_reference_frame_before_serving(dataset):
    proc, seen, client = serve_replay(dataset)
    try:
        (line,) = [x for x in seen if "warmed up in" in x]
        assert "the refractive estimator, against the reference frame" in line, seen
        assert seen.index(line) < next(i for i, x in enumerate(seen) if "serving on" in x)
        health = client.ask({"op": "health"})
    finally:
        stop_served(proc, client)
    assert health["ok"] and health["reference"] == "reference frame"
    warmed = health["warmed_up"]
    assert warmed["against"] == "reference frame" and warmed["estimated"] and warmed["ms"] > 0


def test_a_reference_request_warms_the_new_estimator(dataset):
    """Served against the rest shape (and warmed so); once a reference is taken, the estimator that
    replaced the old one was warmed against it, before it answered any pair."""
    proc, seen, client = serve_replay(dataset, "--no-reference")
    try:
        assert any("the refractive estimator, against the rest shape" in x for x in seen), seen
        assert client.ask({"op": "health"})["warmed_up"]["against"] == "rest shape"
        taken = None
        deadline = time.monotonic() + 60.0
        while taken is None and time.monotonic() < deadline:
            reply = client.ask({"op": "reference"})
            if reply["ok"]:
                taken = reply
        assert taken is not None, "no reference was taken in 60 s"
        health = client.ask({"op": "health"})
    finally:
        stop_served(proc, client)
    assert health["reference"] == "reference frame"
    assert health["warmed_up"]["against"] == "reference frame" and health["warmed_up"]["estimated"]


def test_live_warms_the_estimator_of_its_reference_frame(dataset):
    result = CliRunner().invoke(
        app, ["live", "--replay", str(dataset), "--rate", "fast", "--max-frames", "2"]
    )
    assert result.exit_code == 0, result.output
    assert "the refractive estimator, against the reference frame" in result.output


def test_the_paper_method_is_warmed_without_a_reference(dataset):
    args = ["live", "--replay", str(dataset), "--rate", "fast", "--max-frames", "2", "--method", "paper"]
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 0, result.output
    (line,) = [x for x in result.output.splitlines() if "warmed up in" in x]
    assert "the paper estimator" in line and "against" not in line
