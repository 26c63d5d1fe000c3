"""Nothing the user recorded is ever lost: an output path that is an input (the same path, a symbolic or a
hard link to it), a dataset's own file, or a folder holding an input is refused with exit 2 before any
work, and the input is left byte for byte as it was. One case per command that writes a path the user
names."""

from __future__ import annotations

import os
import shutil

import pytest
from typer.testing import CliRunner

from softjig.cli import app
from softjig.config import CylinderPart, default_jig
from softjig.io.outputs import check_output, same_path
from softjig.io.simulated import simulate_dataset
from softjig.sim.scenarios import single


@pytest.fixture(scope="module")
def source(tmp_path_factory):
    out = tmp_path_factory.mktemp("outputs") / "ds"
    simulate_dataset(
        out, single(CylinderPart(50.0), 8.0, 30.0, reference=True), default_jig(), seed=5, workers=1,
        progress=False,
    )  # fmt: skip
    return out


@pytest.fixture
def ds(source, tmp_path):
    """A fresh copy of the dataset, and a snapshot of every file's bytes in the test's folder."""
    copy = tmp_path / "ds"
    shutil.copytree(source, copy)
    (tmp_path / "rig.toml").write_text((copy / "rig.toml").read_text())
    (tmp_path / "study.toml").write_text("# a study\n")
    return copy


def _snapshot(root):
    return {p: p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file() and not p.is_symlink()}


def _left(ds):
    return str(ds / "left/000001.png")


def _right(ds):
    return str(ds / "right/000001.png")


def _pair(ds):
    return [_left(ds), _right(ds), "--config", str(ds.parent / "rig.toml")]


def _hard_link(ds):
    link = ds.parent / "hard.png"
    os.link(_left(ds), link)
    return str(link)


def _other(ds):
    other = ds.parent / "empty-jig"
    if not other.exists():
        shutil.copytree(ds, other)
    return str(other)


def _sym_link(ds):
    link = ds.parent / "sym.png"
    link.symlink_to(_right(ds))
    return str(link)


# (command line, the phrase of the refusal); `ds` is the dataset copy, its parent the test's folder
CASES = {
    "estimate --overlay LEFT": lambda ds: ["estimate", *_pair(ds), "--overlay", _left(ds)],
    "estimate --overlay hard link": lambda ds: ["estimate", *_pair(ds), "--overlay", _hard_link(ds)],
    "estimate --displacements symlink": lambda ds: [
        "estimate",
        *_pair(ds),
        "--displacements",
        _sym_link(ds),
    ],
    "estimate --displacements CONFIG": lambda ds: [
        "estimate",
        *_pair(ds),
        "--displacements",
        str(ds.parent / "rig.toml"),
    ],
    "estimate --overlay a dataset's image": lambda ds: [
        "estimate",
        *_pair(ds),
        "--overlay",
        str(ds / "left/000007.png"),
    ],
    "survey --out LEFT --overwrite": lambda ds: ["survey", *_pair(ds), "--out", _left(ds), "--overwrite"],
    "survey DATASET --out its rig --overwrite": lambda ds: [
        "survey",
        str(ds),
        "--out",
        str(ds / "rig.toml"),
        "--overwrite",
    ],
    "convert DATASET into itself": lambda ds: ["convert", str(ds), str(ds / "bag"), "--overwrite"],
    "convert DATASET over its parent": lambda ds: ["convert", str(ds), str(ds.parent), "--overwrite"],
    "live --record over --reference-from": lambda ds: [
        "live",
        "--replay",
        str(ds),
        "--reference-from",
        _other(ds),
        "--record",
        _other(ds),
        "--overwrite",
    ],
    "live --mcap CONFIG": lambda ds: [
        "live",
        "--replay",
        str(ds),
        "--config",
        str(ds.parent / "rig.toml"),
        "--mcap",
        str(ds.parent / "rig.toml"),
        "--overwrite",
    ],
    "calibrate --out frames.jsonl": lambda ds: ["calibrate", str(ds), "--out", str(ds / "frames.jsonl")],
    "calibrate-stereo --out an image": lambda ds: [
        "calibrate-stereo",
        str(ds / "left/*.png"),
        str(ds / "right/*.png"),
        "--board",
        "9x6",
        "--square-mm",
        "10",
        "--out",
        _left(ds),
        "--overwrite",
    ],
    "align-jig --out IMAGE": lambda ds: [
        "align-jig",
        _left(ds),
        "--camera",
        str(ds.parent / "rig.toml"),
        "--flange",
        str(ds.parent / "rig.toml"),
        "--out",
        _left(ds),
    ],
    "fiducials sheet --out a dataset's image": lambda ds: [
        "fiducials",
        "sheet",
        "--out",
        str(ds / "left/000000.png"),
    ],
    "sweep-plan --out CONFIG": lambda ds: [
        "sweep-plan",
        "--config",
        str(ds.parent / "rig.toml"),
        "--out",
        str(ds.parent / "rig.toml"),
    ],
    "study --out the folder holding STUDY.toml": lambda ds: [
        "study",
        str(ds.parent / "study.toml"),
        "--out",
        str(ds.parent),
        "--resume",
    ],
    "simulate --out the folder holding --config": lambda ds: [
        "simulate",
        "--scenario",
        "single",
        "--part-diameter",
        "50",
        "--config",
        str(ds / "rig.toml"),
        "--out",
        str(ds),
        "--overwrite",
    ],
    "config --out a dataset's rig --overwrite": lambda ds: [
        "config",
        "--out",
        str(ds / "rig.toml"),
        "--overwrite",
    ],
}


@pytest.mark.parametrize("case", list(CASES))
def test_an_output_onto_an_input_is_refused_and_the_input_kept(ds, case):
    args = CASES[case](ds)
    before = _snapshot(ds.parent)
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 2, (case, result.output)
    assert "Traceback" not in result.output
    text = " ".join(result.output.split())
    assert ("an input of this command" in text) or ("the dataset's own files" in text), (case, text)
    assert _snapshot(ds.parent) == before, case


def test_same_path_follows_symbolic_and_hard_links(tmp_path):
    a = tmp_path / "a.png"
    a.write_bytes(b"x")
    (tmp_path / "sym").symlink_to(a)
    os.link(a, tmp_path / "hard")
    assert same_path(tmp_path / "sym", a) and same_path(tmp_path / "hard", a)
    assert same_path(tmp_path / "x" / ".." / "a.png", a)
    assert not same_path(tmp_path / "b.png", a)
    check_output(tmp_path / "b.png", "--out", [a])  # a new file beside the input is fine
