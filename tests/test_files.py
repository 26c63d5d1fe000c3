"""Atomic writers: outputs get the umask's modes, and no temporary file outlives a failure."""

from __future__ import annotations

import os
import stat
import subprocess
import sys

import numpy as np
import pytest

from softjig.config import default_jig
from softjig.errors import InputError
from softjig.files import write_bytes_atomic, write_text_atomic
from softjig.io.batch import RowsWriter
from softjig.io.dataset import DatasetWriter


def _mode(path) -> int:
    return stat.S_IMODE(os.stat(path).st_mode)


@pytest.fixture(params=[0o022, 0o077, 0o002])
def umask(request):
    old = os.umask(request.param)
    try:
        yield request.param
    finally:
        os.umask(old)


def test_atomic_files_get_the_umasks_mode(tmp_path, umask):
    expected = 0o666 & ~umask
    write_bytes_atomic(tmp_path / "a.bin", b"x")
    write_text_atomic(tmp_path / "b.toml", "x = 1\n")
    with RowsWriter(tmp_path / "rows.jsonl") as out:
        out.write({"index": 0})
    with DatasetWriter(tmp_path / "ds", default_jig()) as writer:
        writer.add_frame(np.zeros((4, 4), np.uint8), np.zeros((4, 4), np.uint8), {})
    for path in (
        tmp_path / "a.bin",
        tmp_path / "b.toml",
        tmp_path / "rows.jsonl",
        tmp_path / "ds" / "rig.toml",
        tmp_path / "ds" / "frames.jsonl",
        tmp_path / "ds" / "left" / "000000.png",
    ):
        assert _mode(path) == expected, path


@pytest.mark.parametrize("umask_value", [0o022, 0o077])
def test_the_cli_writes_with_the_umasks_mode(tmp_path, umask_value):
    script = (
        f"import os, sys; os.umask({umask_value}); sys.argv = ['softjig', 'config', '--out', sys.argv[1]]; "
        "from softjig.cli import main; main()"
    )
    out = tmp_path / "x.toml"
    subprocess.run([sys.executable, "-c", script, str(out)], check=True, capture_output=True)
    assert _mode(out) == 0o666 & ~umask_value


class _Boom(BaseException):
    pass


def test_no_temporary_file_survives_any_exception(tmp_path, monkeypatch):
    target = tmp_path / "x.bin"
    target.write_bytes(b"old")

    def fail(*_args):
        raise _Boom

    monkeypatch.setattr(os, "replace", fail)
    with pytest.raises(_Boom):
        write_bytes_atomic(target, b"new")
    monkeypatch.undo()
    with pytest.raises(KeyboardInterrupt), RowsWriter(tmp_path / "rows.jsonl") as out:
        out.write({"index": 0})
        raise KeyboardInterrupt
    assert sorted(p.name for p in tmp_path.iterdir()) == ["x.bin"]
    assert target.read_bytes() == b"old"


def test_a_folder_target_is_refused(tmp_path):
    with pytest.raises(InputError, match="it is a folder"):
        write_bytes_atomic(tmp_path, b"x")


def _dead_pid() -> int:
    proc = subprocess.Popen([sys.executable, "-c", "pass"])
    proc.wait()
    return proc.pid


def test_the_next_writer_removes_the_temporary_files_of_killed_writers_only(tmp_path):
    dead = _dead_pid()
    stale = [tmp_path / f".rows.jsonl.{dead}-0badf00d.tmp", tmp_path / f".x.toml.{dead}-12345678.tmp"]
    kept = [
        tmp_path / f".rows.jsonl.{os.getpid()}-0badf00d.tmp",  # a running writer's
        tmp_path / ".rows.jsonl.k3j4h5g6.tmp",  # not our pattern
        tmp_path / f".other.jsonl.{dead}-0badf00d.tmp",  # another target's
    ]
    for path in stale + kept:
        path.write_text("partial")
    with RowsWriter(tmp_path / "rows.jsonl") as out:
        out.write({"index": 0})
    write_text_atomic(tmp_path / "x.toml", "x = 1\n")
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
        ["rows.jsonl", "x.toml", *(p.name for p in kept)]
    )
