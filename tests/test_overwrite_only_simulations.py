"""``--overwrite`` replaces only a dataset softjig simulated, never a recording (issue 14).

A recording (``live --record``, ``convert`` from a bag, a user's own dataset) cannot be made again; a
simulation can, from its seed. A simulation is recognised by the as-built jig softjig writes beside it
(``as_built.toml``, ``as_built_markers.npz``), which every simulated dataset since the first version has.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from softjig.cli import app
from softjig.config import default_jig
from softjig.errors import InputError
from softjig.io.cameras import ReplaySource
from softjig.io.dataset import AS_BUILT_NAME, Dataset, DatasetWriter, is_simulation
from softjig.io.rosbag import is_simulated_bag
from softjig.live.loop import LiveLoop, LiveSettings, Recorder

runner = CliRunner()
SIMULATE = ["simulate", "--scenario", "single", "--part-diameter", "50", "--alpha", "10", "--workers", "1"]


def _digest(root: Path) -> dict[str, bytes]:
    return {p.relative_to(root).as_posix(): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def _recording(tmp_path: Path, source: Path, name: str = "rec") -> Path:
    """A recording of a replayed simulation: it carries the frames' truth, but it is not a simulation."""
    out = tmp_path / name
    sweep = Dataset.open(source)
    LiveLoop(
        ReplaySource(sweep, rate="fast"),
        LiveSettings(jig=sweep.jig, max_frames=2),
        recorder=Recorder(out, sweep.jig),
    ).run()
    return out


def test_a_recording_is_not_a_simulation_even_with_truth(small_dataset, tmp_path):
    rec = _recording(tmp_path, small_dataset)
    assert any(f.truth is not None for f in Dataset.open(rec))  # truth carried over from the replay
    assert is_simulation(small_dataset) and not is_simulation(rec)


def test_simulate_overwrite_refuses_a_recording_and_names_it(small_dataset, tmp_path):
    rec = _recording(tmp_path, small_dataset)
    before = _digest(rec)
    result = runner.invoke(app, [*SIMULATE, "--out", str(rec), "--overwrite"])
    assert result.exit_code == 2, result.output
    assert str(rec) in result.output and "never a recording" in result.output
    assert "choose another output folder" in result.output
    assert _digest(rec) == before and sorted(p.name for p in tmp_path.iterdir()) == ["rec"]


def test_simulate_overwrite_refuses_a_converted_bag(small_dataset, tmp_path):
    bag, out = tmp_path / "bag", tmp_path / "from-bag"
    assert (
        runner.invoke(
            app, ["convert", str(small_dataset), str(bag), "--no-estimate", "--no-progress"]
        ).exit_code
        == 0
    )
    assert runner.invoke(app, ["convert", str(bag), str(out), "--no-progress"]).exit_code == 0
    before = _digest(out)
    result = runner.invoke(app, [*SIMULATE, "--out", str(out), "--overwrite"])
    assert result.exit_code == 2 and "never a recording" in result.output
    assert _digest(out) == before


def test_a_users_own_dataset_is_never_replaced(tmp_path):
    mine = tmp_path / "mine"
    with DatasetWriter(mine, default_jig()) as writer:  # no provenance: as a user's own tool would write it
        writer.add_frame(np.zeros((8, 8), np.uint8), np.zeros((8, 8), np.uint8), {"reference": True})
    before = _digest(mine)
    with (
        pytest.raises(InputError, match="never a recording"),
        DatasetWriter(mine, default_jig(), overwrite=True),
    ):
        pass
    assert _digest(mine) == before


@pytest.mark.parametrize("command", ["simulate", "live --record", "convert"])
def test_overwrite_replaces_a_simulation_atomically(small_dataset, tmp_path, command):
    target = tmp_path / "sim"
    shutil.copytree(small_dataset, target)
    if command == "simulate":
        args = [*SIMULATE, "--out", str(target), "--overwrite"]
    elif command == "live --record":
        args = [
            "live",
            "--replay",
            str(small_dataset),
            "--rate",
            "fast",
            "--record",
            str(target),
            "--overwrite",
        ]
    else:
        bag = tmp_path / "bag"
        assert _to_bag(small_dataset, bag).exit_code == 0
        args = ["convert", str(bag), str(target), "--overwrite", "--no-progress"]
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    assert len(Dataset.open(target)) == (1 if command == "simulate" else 5)
    assert sorted(p.name for p in tmp_path.iterdir() if p.name != "bag") == ["sim"]  # no staging left


def test_a_simulation_whose_as_built_is_a_link_is_not_ours(small_dataset, tmp_path):
    target = tmp_path / "sim"
    shutil.copytree(small_dataset, target)
    elsewhere = tmp_path / "elsewhere.toml"
    (target / AS_BUILT_NAME).rename(elsewhere)
    (target / AS_BUILT_NAME).symlink_to(elsewhere)
    assert not is_simulation(target)
    result = runner.invoke(app, [*SIMULATE, "--out", str(target), "--overwrite"])
    assert result.exit_code == 2 and "never a recording" in result.output


# ------------------------------------------------------------------------------------------ bags


def _to_bag(source: Path, bag: Path, *extra: str):
    return runner.invoke(app, ["convert", str(source), str(bag), "--no-estimate", "--no-progress", *extra])


def test_a_simulations_bag_is_replaced_by_overwrite(small_dataset, tmp_path):
    bag = tmp_path / "bag"
    assert _to_bag(small_dataset, bag).exit_code == 0
    assert is_simulated_bag(bag)
    assert _to_bag(small_dataset, bag, "--overwrite").exit_code == 0


def test_overwrite_never_replaces_a_recorded_bag(small_dataset, tmp_path):
    bag = tmp_path / "live_bag"
    args = [
        "live",
        "--replay",
        str(small_dataset),
        "--rate",
        "fast",
        "--max-frames",
        "2",
        "--record-bag",
        str(bag),
    ]
    assert runner.invoke(app, args).exit_code == 0
    assert not is_simulated_bag(bag)
    before = _digest(bag)
    result = _to_bag(small_dataset, bag, "--overwrite")
    assert result.exit_code == 2 and "never a recording" in result.output and str(bag) in result.output
    again = runner.invoke(app, [*args, "--overwrite"])
    assert again.exit_code == 2 and "never a recording" in again.output
    assert _digest(bag) == before


def test_overwrite_never_replaces_a_bag_of_a_recording_nor_one_softjig_did_not_write(small_dataset, tmp_path):
    from test_rosbag import _images, _write_rosbags_folder

    rec = _recording(tmp_path, small_dataset)
    of_recording = tmp_path / "rec_bag"
    assert _to_bag(rec, of_recording).exit_code == 0
    foreign = tmp_path / "ros2_bag"
    _write_rosbags_folder(foreign, _images(2))
    for bag in (of_recording, foreign):
        before = _digest(bag)
        result = _to_bag(small_dataset, bag, "--overwrite")
        assert result.exit_code == 2 and "never a recording" in result.output, result.output
        assert _digest(bag) == before
