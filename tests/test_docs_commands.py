"""Every ``softjig ...`` command of README.md's ```bash blocks runs as written (issue 14).

The commands run in order, as a new user types them, in one empty folder, each as its own process with
a timeout; the README's own commands make the datasets the later ones read. Placeholders the README
leaves to the reader (``LEFT.png``, ``RIGHT.png``, ``DATASET``) are replaced by the small datasets made
before them, and ``softjig demo`` runs ``--quick``; a command that needs hardware would be skipped with
its reason (README has none).
"""

from __future__ import annotations

import os
import re
import shlex
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


def softjig_commands(markdown: Path) -> list[list[str]]:
    """The ``softjig`` commands of :func:`bash_commands` as argument lists, placeholders substituted."""
    out = []
    for command in bash_commands(markdown):
        words = shlex.split(command)
        if words[0] != "softjig":
            continue
        words = [PLACEHOLDERS.get(w, w) for w in words]
        words += SMALLER.get(tuple(words[:2]), [])
        out.append(words)
    return out


def test_the_parser_finds_the_readmes_commands():
    commands = softjig_commands(ROOT / "README.md")
    names = [c[1] for c in commands]
    for name in ("config", "simulate", "estimate", "calibrate", "compare", "demo"):
        assert name in names
    assert all("#" not in word for c in commands for word in c)  # comments dropped


@pytest.mark.slow
def test_every_readme_command_runs_as_written(tmp_path):
    env = {**os.environ, "PYTHONPATH": str(ROOT / "src")}
    for words in softjig_commands(ROOT / "README.md"):
        done = subprocess.run(
            [*SOFTJIG, *words[1:]],
            cwd=tmp_path,
            env=env,
            capture_output=True,
            text=True,
            timeout=TIMEOUT_S,
        )
        assert done.returncode == 0, f"{shlex.join(words)}\nexit {done.returncode}\n{done.stderr[-2000:]}"
