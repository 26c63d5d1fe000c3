"""Every ``softjig ...`` command of README.md's and docs/build-your-own-jig.md's ```bash blocks runs as
written (issue 14).

The commands run in order, as a new user types them, in one empty folder, each as its own process with
a timeout; the README's own commands make the datasets the later ones read. Placeholders the documents
leave to the reader (``LEFT.png``, ``RIGHT.png``, ``DATASET``, the ``[--optional]`` arguments) are
replaced by small datasets made first, and ``softjig demo`` runs ``--quick``. Commands that need hardware
(cameras, the pump) are run by :func:`test_hardware_commands_without_their_hardware_exit_2_with_a_message`
on this machine without them: each must end with a clear error.
"""

from __future__ import annotations

import json
import os
import re
import shlex
import socket
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SOFTJIG = [sys.executable, "-c", "from softjig.cli import main; main()"]
#: What the README leaves to the reader, and what the test gives for it (made by earlier commands).
PLACEHOLDERS = {
    "LEFT.png": "out/one/left/000000.png",
    "RIGHT.png": "out/one/right/000000.png",
    "DATASET": "out/small",
}
#: Commands that would run for long as written, and the small version the test runs instead.
SMALLER = {("softjig", "demo"): ["--quick", "--out", "out/demo"]}
TIMEOUT_S = 600


def bash_commands(markdown: Path) -> list[str]:
    """The shell commands of a Markdown file's ```bash blocks: continuation lines joined, comments
    dropped, ``a && b`` split in two."""
    commands: list[str] = []
    for block in re.findall(r"```bash\n(.*?)```", markdown.read_text(encoding="utf-8"), flags=re.S):
        joined = re.sub(r"\\\n", " ", block)
        for line in joined.splitlines():
            words = shlex.split(line, comments=True)
            command: list[str] = []
            for word in [*words, "&&"]:
                if word == "&&":
                    if command:
                        commands.append(shlex.join(command))
                    command = []
                else:
                    command.append(word)
    return commands


#: Commands that need hardware: the test cannot run them (skipped, with this reason).
HARDWARE = {
    "--source": "reads cameras (opencv:/realsense:)",
    "jig": "talks to the pump controller over a serial port",
}


def hardware_reason(words: list[str]) -> str | None:
    """Why a command cannot run here, or ``None``."""
    if words[1] == "jig":
        return HARDWARE["jig"]
    if "--source" in words:
        return HARDWARE["--source"]
    return None


def softjig_commands(markdown: Path) -> list[list[str]]:
    """The ``softjig`` commands of :func:`bash_commands` as argument lists, placeholders substituted and
    ``[--optional ARG]`` dropped."""
    out = []
    for command in bash_commands(markdown):
        words = shlex.split(command)
        if words[0] != "softjig":
            continue
        words = [PLACEHOLDERS.get(w, w) for w in words]
        kept, optional = [], False
        for word in words:
            optional = optional or word.startswith("[")
            if not optional:
                kept.append(word)
            optional = optional and not word.endswith("]")
        out.append(kept + SMALLER.get(tuple(kept[:2]), []))
    return out


def _run(words: list[str], cwd: Path) -> None:
    env = {**os.environ, "PYTHONPATH": str(ROOT / "src")}
    done = subprocess.run(
        [*SOFTJIG, *words[1:]], cwd=cwd, env=env, capture_output=True, text=True, timeout=TIMEOUT_S
    )
    assert done.returncode == 0, f"{shlex.join(words)}\nexit {done.returncode}\n{done.stderr[-2000:]}"


def test_the_parser_finds_the_readmes_commands():
    guide = [c[1] for c in softjig_commands(ROOT / "docs/build-your-own-jig.md")]
    assert {"calibrate-stereo", "fiducials", "align-jig", "sweep-plan", "calibrate", "estimate"} <= set(guide)
    commands = softjig_commands(ROOT / "README.md")
    names = [c[1] for c in commands]
    for name in ("config", "simulate", "estimate", "calibrate", "compare", "demo"):
        assert name in names
    assert all("#" not in word for c in commands for word in c)  # comments dropped


@pytest.mark.slow
def test_every_readme_command_runs_as_written(tmp_path):
    for words in softjig_commands(ROOT / "README.md"):
        assert hardware_reason(words) is None
        _run(words, tmp_path)


REAL_CHESSBOARD = ROOT.parent / "shared" / "data" / "stereo-chessboard"  # ../shared beside the repo


def _doc_json_files(markdown: Path) -> dict[str, dict]:
    """The JSON files a document shows in its ```json blocks, each after a ``// NAME`` line."""
    files = {}
    for block in re.findall(r"```json\n(.*?)```", markdown.read_text(encoding="utf-8"), flags=re.S):
        for part in re.split(r"^// ", block, flags=re.M)[1:]:
            name, _, body = part.partition("\n")
            files[name.split(":")[0].strip()] = json.loads(body)
    return files


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def _render_handeye(folder: Path, files: dict[str, dict]) -> None:
    """handeye.png: the doc's hand-eye camera (handeye.json) at the doc's flange pose (flange.json), the
    jig (rig.toml as the doc's commands left it) 390 mm below it, at (600, 100, 0) in the robot frame."""
    import cv2
    import numpy as np
    from scipy.spatial.transform import Rotation

    from softjig.config import CameraConfig, load_jig
    from softjig.geometry import invert_pose
    from softjig.sim.handeye import render_handeye_view

    cam = files["handeye.json"]
    fields = ("width_px", "height_px", "fx_px", "fy_px", "cx_px", "cy_px")
    camera = CameraConfig(**{k: cam[k] for k in fields}, distortion=tuple(cam["distortion"]))
    flange = files["flange.json"]
    T_robot_flange = np.eye(4)
    T_robot_flange[:3, :3] = Rotation.from_quat(flange["quaternion_xyzw"]).as_matrix()
    T_robot_flange[:3, 3] = flange["position_mm"]
    T_robot_jig = np.eye(4)
    T_robot_jig[:3, 3] = [600.0, 100.0, 0.0]
    T_J_cam = invert_pose(T_robot_jig) @ T_robot_flange @ np.asarray(cam["T_flange_cam"], float)
    image = render_handeye_view(load_jig(folder / "rig.toml"), camera, T_J_cam, noise_std=0.01, rng=0)
    cv2.imwrite(str(folder / "handeye.png"), image)
    for name, data in files.items():
        (folder / name).write_text(json.dumps(data))


@pytest.mark.slow
@pytest.mark.skipif(not REAL_CHESSBOARD.is_dir(), reason="the real stereo chessboard set is not available")
def test_every_build_your_own_jig_command_runs_as_written(tmp_path):
    """The guide's commands in order, on: the real chessboard set for the stereo calibration (as the guide
    says, its right*.jpg are softjig's left images), a simulated unloaded pair for the fiducials and the
    estimate (with that pair's own rig.toml: the guide's is of cameras whose jig we do not have), a
    rendered hand-eye view for the alignment, a small simulated sweep for DATASET."""
    import shutil

    doc = ROOT / "docs" / "build-your-own-jig.md"
    (tmp_path / "calib").mkdir()
    for k, path in enumerate(sorted(REAL_CHESSBOARD.glob("right*.jpg"))):
        shutil.copy(path, tmp_path / "calib" / f"left{k:02d}.png")  # OpenCV reads the content, not the name
    for k, path in enumerate(sorted(REAL_CHESSBOARD.glob("left*.jpg"))):
        shutil.copy(path, tmp_path / "calib" / f"right{k:02d}.png")
    setup = [
        "softjig config --out base.toml",
        "softjig simulate --scenario single --part-diameter 50 --alpha 0 --out out/one",
        "softjig simulate --scenario paper-sweep --diameters 50 --alphas 10 --theta-step 60 --out out/small",
    ]
    for command in setup:
        _run(shlex.split(command), tmp_path)
    files = _doc_json_files(doc)
    assert {"handeye.json", "flange.json"} <= set(files)
    port = str(_free_port())
    ran = 0
    for words in softjig_commands(doc):
        if hardware_reason(words):
            continue
        if "left.png" in words:  # a pair of the guide's cameras: the simulated pair, with its own rig
            words = [
                {"left.png": PLACEHOLDERS["LEFT.png"], "right.png": PLACEHOLDERS["RIGHT.png"]}.get(w, w)
                for w in words
            ]
            words[words.index("--config") + 1] = "out/one/rig.toml"
        words = [w.replace("5555", port) for w in words]
        if words[1] == "align-jig":
            _render_handeye(tmp_path, files)
        _run(words, tmp_path)
        ran += 1
    assert ran >= 9


@pytest.mark.parametrize(
    "words",
    [
        w
        for doc in ("README.md", "docs/build-your-own-jig.md", "docs/live.md")
        for w in softjig_commands(ROOT / doc)
        if hardware_reason(w)
    ],
    ids=shlex.join,
)
def test_hardware_commands_without_their_hardware_exit_2_with_a_message(words, tmp_path):
    """The documents' camera and pump commands as written, on a machine without the hardware: a clear
    error and exit 2, no traceback (the pump commands themselves run in tests/test_docs_live.py, against
    a simulated controller on a pty)."""
    words = [w.replace("5555", str(_free_port())) for w in words]
    if "--config" in words:
        _run(["softjig", "config", "--out", words[words.index("--config") + 1]], tmp_path)
    env = {**os.environ, "PYTHONPATH": str(ROOT / "src")}
    done = subprocess.run(
        [*SOFTJIG, *words[1:]], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=TIMEOUT_S
    )
    assert done.returncode == 2, f"{shlex.join(words)}: {hardware_reason(words)}\n{done.stderr[-2000:]}"
    assert "error:" in done.stderr and "Traceback" not in done.stderr, done.stderr[-2000:]
