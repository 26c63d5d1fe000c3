"""The front designs' rigs (softjig.study.best): DIR/best/NNN.toml holds the design's full jig config, loads
with softjig.config, runs `softjig simulate --config`, and a rewrite removes only our own stale rigs."""

from __future__ import annotations

import dataclasses
import os

import pytest
from typer.testing import CliRunner

from softjig.cli import app
from softjig.config import JigConfig, default_jig, load_jig
from softjig.errors import ConfigError
from softjig.io.dataset import Dataset
from softjig.study.best import HEADER_MARK, best_rig_name, write_best_rigs

PITCHES_MM = {0: 6.0, 3: 8.0, 12: 10.0}


def _config_for(design_id: int) -> JigConfig:
    jig = default_jig()
    return jig.replace(markers=dataclasses.replace(jig.markers, pitch_mm=PITCHES_MM[design_id]))


def test_names_are_zero_padded():
    assert [best_rig_name(i) for i in (0, 7, 123, 1234)] == ["000.toml", "007.toml", "123.toml", "1234.toml"]


def test_a_written_rig_loads_and_simulate_accepts_it(tmp_path):
    paths = write_best_rigs(tmp_path / "best", [12, 3], _config_for, notes={12: "markers.pitch_mm = 10"})
    assert [p.name for p in paths] == ["012.toml", "003.toml"]
    text = paths[0].read_text()
    assert text.startswith(HEADER_MARK + "\n# markers.pitch_mm = 10\n")
    assert load_jig(paths[0]) == _config_for(12)
    assert load_jig(paths[1]).markers.pitch_mm == 8.0
    result = CliRunner().invoke(
        app,
        [
            "simulate",
            "--scenario",
            "single",
            "--part-diameter",
            "40",
            "--config",
            str(paths[0]),
            "--out",
            str(tmp_path / "ds"),
            "--no-progress",
            "--workers",
            "1",
        ],
    )
    assert result.exit_code == 0, result.output
    assert Dataset.open(tmp_path / "ds").jig.markers.pitch_mm == 10.0


def test_rewrite_removes_only_our_stale_rigs(tmp_path):
    best = tmp_path / "best"
    write_best_rigs(best, [0, 3], _config_for)
    (best / "100.toml").write_text("# the user's own rig\n")  # not ours: kept
    (best / "notes.txt").write_text("mine")
    write_best_rigs(best, [3, 12], _config_for)
    assert sorted(p.name for p in best.iterdir()) == ["003.toml", "012.toml", "100.toml", "notes.txt"]


def test_an_impossible_design_writes_nothing(tmp_path):
    def config_for(design_id: int) -> JigConfig:
        if design_id == 3:
            jig = default_jig()
            # markers closer than their diameter: validate_jig refuses it, naming the field
            return dataclasses.replace(jig, markers=dataclasses.replace(jig.markers, pitch_mm=1.0))
        return _config_for(design_id)

    with pytest.raises(ConfigError, match="pitch"):
        write_best_rigs(tmp_path / "best", [0, 3], config_for)
    assert not (tmp_path / "best").exists()


def test_rigs_honour_the_umask(tmp_path):
    old = os.umask(0o077)
    try:
        (path,) = write_best_rigs(tmp_path / "best", [0], _config_for)
    finally:
        os.umask(old)
    assert path.stat().st_mode & 0o777 == 0o600
