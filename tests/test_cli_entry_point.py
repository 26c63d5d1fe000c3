"""The ``softjig`` console script ends its process without the interpreter's teardown (issue 14, item 4).

Run for real, in subprocesses: what it prints is complete, its output files are complete, its exit codes
are the contract's, its atexit handlers run; and the interpreter's teardown (0.35 s of a 1.8 s single
estimate) is skipped.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

from softjig.cli import app
from softjig.io.dataset import Dataset

SOFTJIG = Path(sys.executable).with_name("softjig")  # the console script pip installs beside python


def _softjig(*args: str | Path, cwd: Path | None = None) -> subprocess.CompletedProcess:
    assert SOFTJIG.exists(), f"the console script {SOFTJIG} is missing: pip install -e . first"
    return subprocess.run(
        [str(SOFTJIG), *map(str, args)], capture_output=True, text=True, timeout=300, cwd=cwd
    )


def _pair(dataset: Path, k: int = 1) -> list[str]:
    frame = Dataset.open(dataset)[k]
    return [str(frame.left_path), str(frame.right_path), "--config", str(dataset / "rig.toml")]


def test_a_pair_prints_the_whole_estimate_and_exits_0(small_dataset):
    args = ["estimate", *_pair(small_dataset), "--part-diameter", "50", "--json"]
    done = _softjig(*args)
    assert done.returncode == 0, done.stderr
    in_process = CliRunner().invoke(app, args)
    assert in_process.exit_code == 0, in_process.output
    assert json.loads(done.stdout) == json.loads(in_process.stdout)  # every byte printed, same numbers
    assert done.stdout.endswith("\n") and done.stderr == ""


def test_bad_input_exits_2_with_its_message(small_dataset):
    left, right, *rest = _pair(small_dataset)
    done = _softjig("estimate", right, left, *rest, "--part-diameter", "50")
    assert done.returncode == 2
    assert "swapped" in done.stderr and "Traceback" not in done.stderr
    assert _softjig("no-such-command").returncode == 2


def test_a_dataset_with_workers_writes_every_row(small_dataset, tmp_path):
    out = tmp_path / "estimates.jsonl"
    done = _softjig("estimate", small_dataset, "--out", out, "--workers", "2", "--no-progress")
    assert done.returncode == 0, done.stderr
    rows = [json.loads(line) for line in out.read_text().splitlines()]  # one per frame, reference included
    assert [row["index"] for row in rows] == [frame.index for frame in Dataset.open(small_dataset)]
    estimates = [row for row in rows if not row.get("reference")]
    n_loaded = len(estimates)
    assert n_loaded >= 4 and all("normal" in row for row in estimates)
    assert f"estimated {n_loaded} of {n_loaded} loaded frames" in done.stdout
    assert not [p for p in tmp_path.iterdir() if p != out]  # no temporary file left


_END_PROCESS = """
import atexit, ctypes, sys
from softjig.cli import end_process
atexit.register(lambda: print("atexit ran", file=sys.stderr))
class Teardown:
    def __del__(self):
        print("teardown ran", file=sys.stderr)
teardown = Teardown()  # collected by the interpreter's teardown only
sys.stdout.write("x" * 1_000_000 + "\\n")  # far more than a pipe holds: still in Python's buffer
ctypes.CDLL(None).printf(b"from C\\n")  # C's stdio buffer (stdout is a pipe: fully buffered)
end_process(sys.argv[1] if sys.argv[1].isalpha() else int(sys.argv[1]))
"""


@pytest.mark.parametrize(("code", "status"), [("0", 0), ("3", 3), ("143", 143), ("message", 1)])
def test_end_process_keeps_output_and_atexit_and_skips_the_teardown(code, status):
    argv = [sys.executable, "-c", _END_PROCESS, code]
    done = subprocess.run(argv, capture_output=True, text=True, timeout=60)
    assert done.returncode == status
    assert done.stdout.startswith("x" * 1_000_000 + "\n") and done.stdout.endswith("from C\n")
    assert "atexit ran" in done.stderr and "teardown ran" not in done.stderr
    assert ("message" in done.stderr) == (code == "message")


_RACING_EXIT_HOOK = """
import sys, threading, time
from softjig.cli import end_process
raised = []
def wake_up():  # as concurrent.futures' hook when a dead worker's pool closed its pipe meanwhile
    if not raised:
        raised.append(True)
        raise OSError(9, "Bad file descriptor")
threading._register_atexit(wake_up)
def write():
    time.sleep(0.3)
    print("written", flush=True)
threading.Thread(target=write).start()  # not a daemon: joined at exit
end_process(2)
"""


def test_an_exit_hook_that_races_a_closed_pipe_still_joins_the_threads_and_keeps_the_code():
    """CPython 3.11's ``concurrent.futures`` exit hook can raise ``OSError`` when a pool whose worker died
    closed its wake-up pipe meanwhile (gh-125451): the exit code stays, no traceback is printed, and a
    thread still writing is joined."""
    done = subprocess.run(
        [sys.executable, "-c", _RACING_EXIT_HOOK], capture_output=True, text=True, timeout=60
    )
    assert done.returncode == 2, done.stderr
    assert "Traceback" not in done.stderr
    assert done.stdout == "written\n"


def test_the_console_script_skips_the_teardown():
    """The real entry point: an object only the interpreter's teardown collects is never collected
    (on the old entry point its ``__del__`` ran after the command)."""
    code = (
        "import sys\n"
        "class Teardown:\n"
        "    def __del__(self):\n"
        "        print('teardown ran', file=sys.stderr)\n"
        "teardown = Teardown()\n"
        "from softjig.cli import main\n"
        "sys.argv = ['softjig', '--version']\n"
        "main()\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0 and done.stdout.startswith("softjig ")
    assert "teardown ran" not in done.stderr


def test_a_pair_estimate_imports_only_what_it_uses(small_dataset):
    """Start-up (issue 14): ``--json`` prints no table (no rich), writes no TOML (no tomli_w) and applies
    no calibration file (no softjig.calibration); each was imported by every estimate before."""
    code = (
        "import atexit, sys\n"
        "atexit.register(lambda: print('MODULES', ' '.join(sorted(sys.modules)), file=sys.stderr))\n"
        "from softjig.cli import main\n"
        f"sys.argv = ['softjig', 'estimate', *{_pair(small_dataset)!r}, '--part-diameter', '50', '--json']\n"
        "main()\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert "normal" in json.loads(done.stdout)
    modules = done.stderr.split("MODULES ", 1)[1].split()
    unused = [
        m for m in modules if m.split(".")[0] in ("rich", "tomli_w") or m.startswith("softjig.calibration")
    ]
    assert unused == []
