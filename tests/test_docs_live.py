"""docs/live.md as written: its `softjig jig` commands run against a simulated controller, its subscriber
example keeps up with a publisher, and what it says of the pump is what the code does."""

from __future__ import annotations

import json
import re
import shlex
import threading
import time
from pathlib import Path

import pytest
from typer.testing import CliRunner

from softjig.cli import app
from softjig.hardware import protocol
from softjig.hardware.simulator import SimulatedPumpController
from softjig.io.stream import TOPIC_ESTIMATE, TOPIC_HEALTH, Publisher

DOC = Path(__file__).resolve().parents[1] / "docs" / "live.md"
DOC_PORT = "/dev/ttyACM0"


def blocks(language: str) -> list[str]:
    return re.findall(rf"```{language}\n(.*?)```", DOC.read_text(encoding="utf-8"), flags=re.S)


def jig_commands() -> list[list[str]]:
    commands = []
    for block in blocks("bash"):
        for line in block.splitlines():
            if line.startswith("softjig jig "):
                commands.append(shlex.split(line, comments=True))
    return commands


def test_the_docs_show_every_jig_command():
    shown = {argv[2] for argv in jig_commands()}
    assert shown == {"status", "fix", "hold", "stop", "release"}


def test_every_jig_command_in_the_docs_runs_as_written():
    """In the docs' order, against one controller; only `hold`'s duration is shortened (to 0.3 s), and
    `hold` without one gets it (it would otherwise hold until Ctrl-C)."""
    simulator, port = SimulatedPumpController.on_pty(fix_time_s=0.1, release_time_s=0.1)
    runner = CliRunner()
    with simulator:
        for argv in jig_commands():
            args = [port if a == DOC_PORT else a for a in argv[1:]]
            if args[1] == "hold":
                if "--duration" in args:
                    args[args.index("--duration") + 1] = "0.3"
                else:
                    args += ["--duration", "0.3"]
            result = runner.invoke(app, args)
            assert result.exit_code == 0, f"{shlex.join(argv)}: {result.output}"
            if "--json" in args:
                json.loads(result.stdout)
    assert simulator.state == "released"  # the docs end with a release


def test_the_docs_state_the_protocol_constants_the_code_uses():
    text = DOC.read_text(encoding="utf-8")
    assert f"at most {protocol.MAX_REPLY_BYTES} bytes" in text
    assert f"at least {protocol.WATCHDOG_MIN_S:g} s" in text
    assert f"default {protocol.HEARTBEAT_PERIOD_S:g} s" in text
    assert "pump off, valve closed" in text and "pump off, valve closed" in protocol.__doc__


def _example_subscriber(endpoint: str) -> dict:
    """The docs' Python example up to its endless loop, connected to ``endpoint``: its namespace."""
    (code,) = [b for b in blocks("python") if "def receive_latest" in b]
    assert "CONFLATE" not in code and "RCVHWM" not in code  # neither would keep the newest
    head = code.split("\nwhile True:")[0].replace("tcp://127.0.0.1:5555", endpoint)
    namespace: dict = {}
    exec(compile(head, str(DOC), "exec"), namespace)
    return namespace


def test_the_docs_subscriber_acts_on_the_newest_estimate_not_a_backlog():
    with Publisher("tcp://127.0.0.1:*") as pub:
        ns = _example_subscriber(pub.endpoint)
        sub, receive_latest = ns["sub"], ns["receive_latest"]
        try:
            deadline = time.monotonic() + 10.0
            while not receive_latest(sub, 50):  # ZeroMQ's slow joiner
                pub.publish(TOPIC_HEALTH, {"seq": -1})
                assert time.monotonic() < deadline, "the example never connected"
            stop = threading.Event()
            published = {"n": 0}

            def publish():
                while not stop.is_set():
                    pub.publish(TOPIC_ESTIMATE, {"seq": published["n"], "time_unix_s": time.time()})
                    published["n"] += 1
                    time.sleep(0.005)

            thread = threading.Thread(target=publish, daemon=True)
            thread.start()
            lags = []
            try:
                for _ in range(5):
                    time.sleep(0.2)  # a slow robot program
                    before = published["n"]
                    latest = receive_latest(sub)
                    lags.append(before - 1 - latest[TOPIC_ESTIMATE.encode()]["seq"])
            finally:
                stop.set()
                thread.join(timeout=5)
        finally:
            sub.close(0)
            ns["ctx"].term()
    # one message at a time, these lags grow by ~40 a loop (37, 73, 110, 148, 185 measured)
    assert max(lags) <= 20, f"the example lags behind the publisher: {lags}"


@pytest.mark.parametrize("word", ["RCVHWM", "CONFLATE"])
def test_the_docs_explain_why_not(word):
    assert word in DOC.read_text(encoding="utf-8")
