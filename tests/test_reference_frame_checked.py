"""A frame a recorder marked ``reference`` is checked before estimates are measured against it (issue 14).

``softjig estimate DATASET``, ``softjig live --replay`` and ``softjig serve --replay`` take a dataset's
reference frame from one place (:func:`softjig.io.reference.dataset_reference`); it is checked as
``softjig survey`` and serve's ``reference`` request check theirs: a loaded or unusable frame is refused
(exit 2) naming the frame and offering ``--no-reference``, instead of shifting every indentation.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys

import numpy as np
import pytest
from typer.testing import CliRunner

from softjig.cli import app
from softjig.config import CylinderPart, default_jig
from softjig.io.dataset import Dataset, encode_png
from softjig.io.reference import dataset_reference
from softjig.io.simulated import simulate_dataset
from softjig.sim.scenarios import single

runner = CliRunner()


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    """An unloaded reference frame (index 0), then a part pressed in (index 1)."""
    out = tmp_path_factory.mktemp("checked") / "ds"
    specs = single(CylinderPart(50.0), 8.0, 30.0, reference=True)
    simulate_dataset(out, specs, default_jig(), seed=5, workers=1, progress=False)
    return out


def _marked(dataset, tmp_path, edit) -> object:
    """A copy of ``dataset`` whose reference frame's JSON line is changed by ``edit(record, root)``."""
    root = tmp_path / "marked"
    shutil.copytree(dataset, root)
    lines = [json.loads(x) for x in (root / "frames.jsonl").read_text().splitlines()]
    assert lines[0]["reference"] is True and not lines[1].get("reference")
    edit(lines[0], root, lines[1])
    (root / "frames.jsonl").write_text("".join(json.dumps(x) + "\n" for x in lines))
    return root


def _loaded(record, _root, loaded):
    record["left"], record["right"] = loaded["left"], loaded["right"]  # the recorder marked a loaded pair


def _blank(record, root, _loaded):
    blank = encode_png(
        np.zeros((default_jig().cameras.left.height_px, default_jig().cameras.left.width_px), np.uint8)
    )
    (root / record["left"]).write_bytes(blank)  # the lens cap on
    (root / record["right"]).write_bytes(blank)


def _noise(record, root, _loaded):
    rng = np.random.default_rng(0)  # a garbage frame: noise triangulates a dozen stray points
    shape = (default_jig().cameras.left.height_px, default_jig().cameras.left.width_px)
    (root / record["left"]).write_bytes(encode_png(rng.integers(0, 255, shape, dtype=np.uint8)))
    (root / record["right"]).write_bytes(encode_png(rng.integers(0, 255, shape, dtype=np.uint8)))


def _missing(record, root, _loaded):
    (root / record["left"]).unlink()


def test_the_recorded_reference_frame_is_taken_when_it_is_unloaded(dataset):
    ds = Dataset.open(dataset)
    reference = dataset_reference(ds, ds.jig)
    assert reference is not None and reference.source == "reference frame"


@pytest.mark.parametrize(
    ("edit", "says"),
    [
        (_loaded, "is loaded"),
        (_blank, "blank"),
        (_noise, "within half a pitch"),
        (_missing, "does not exist"),
    ],
)
def test_estimate_dataset_refuses_an_unusable_reference_frame(dataset, tmp_path, edit, says):
    root = _marked(dataset, tmp_path, edit)
    out = tmp_path / "rows.jsonl"
    result = runner.invoke(app, ["estimate", str(root), "--out", str(out), "--workers", "1"])
    assert result.exit_code == 2, result.output
    message = " ".join(result.output.split())
    assert f"frame 0 of {root} (marked reference)" in message and says in message
    assert "--no-reference" in message
    assert not out.exists()
    if edit is not _missing:  # offered, and it works: the rest shape
        again = runner.invoke(
            app, ["estimate", str(root), "--no-reference", "--out", str(out), "--workers", "1"]
        )
        assert again.exit_code == 0, again.output
        rows = {r["index"]: r for r in map(json.loads, out.read_text().splitlines())}
        assert rows[1]["indentation_reference"] == "rest shape"


def test_a_replay_refuses_it_alike(dataset, tmp_path):
    root = _marked(dataset, tmp_path, _loaded)
    result = runner.invoke(app, ["live", "--replay", str(root), "--rate", "fast", "--max-frames", "2"])
    assert result.exit_code == 2, result.output
    message = " ".join(result.output.split())
    assert "frame 0" in message and "is loaded" in message and "--no-reference" in message
    assert (
        runner.invoke(app, ["live", "--replay", str(root), "--rate", "fast", "--no-reference"]).exit_code == 0
    )


@pytest.mark.skipif(sys.platform == "win32", reason="POSIX processes")
def test_serve_refuses_it_before_serving(dataset, tmp_path):
    root = _marked(dataset, tmp_path, _loaded)
    proc = subprocess.run(
        [sys.executable, "-c", "from softjig.cli import main; main()", "serve", "--replay", str(root)],
        capture_output=True,
        text=True,
        timeout=120,
        env={**os.environ, "COLUMNS": "200"},
    )
    message = " ".join(proc.stderr.split())
    assert proc.returncode == 2, proc.stderr
    assert "frame 0" in message and "is loaded" in message and "--no-reference" in message
    assert "serving on" not in message


def test_estimate_bag_refuses_it_alike(dataset, tmp_path):
    root = _marked(dataset, tmp_path, _loaded)
    bag = tmp_path / "bag"
    convert = ["convert", str(root), str(bag), "--no-estimate", "--no-progress"]
    assert runner.invoke(app, convert).exit_code == 0
    out = tmp_path / "rows.jsonl"
    result = runner.invoke(app, ["estimate", str(bag), "--out", str(out), "--workers", "1", "--no-progress"])
    assert result.exit_code == 2, result.output
    message = " ".join(result.output.split())
    assert "the bag's pair 0 (marked reference)" in message and "is loaded" in message
    assert "--no-reference" in message and not out.exists()
    again = runner.invoke(
        app, ["estimate", str(bag), "--no-reference", "--out", str(out), "--workers", "1", "--no-progress"]
    )
    assert again.exit_code == 0, again.output
