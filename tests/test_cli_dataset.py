"""`softjig estimate DATASET`: nothing wrong with exit 0, nothing of the dataset or the inputs destroyed."""

from __future__ import annotations

import json
import shutil

import pytest
from typer.testing import CliRunner

from softjig.cli import app
from softjig.config import default_jig
from softjig.io.dataset import Dataset
from softjig.io.simulated import simulate_dataset
from softjig.sim.scenarios import paper_sweep

runner = CliRunner()


@pytest.fixture(scope="module")
def source(tmp_path_factory):
    """A reference frame and 3 loaded frames (D = 50 mm)."""
    out = tmp_path_factory.mktemp("cli-ds") / "sweep"
    specs = list(paper_sweep(diameters_mm=(50,), alphas_deg=(10,), theta_step_deg=120))
    simulate_dataset(out, specs, default_jig(), seed=4, workers=1, progress=False)
    return out


@pytest.fixture
def ds(source, tmp_path):
    """A copy of the dataset this test may spoil."""
    return shutil.copytree(source, tmp_path / "ds")


def _estimate(*args: str):
    return runner.invoke(app, ["estimate", *map(str, args), "--no-progress", "--workers", "1"])


def test_every_image_missing_exits_3_and_still_writes_every_error(ds):
    for side in ("left", "right"):
        for k in (1, 2, 3):  # the loaded frames' (the reference frame's missing: exit 2, see below)
            (ds / side / f"{k:06d}.png").unlink()
    result = _estimate(ds)
    assert result.exit_code == 3, result.output
    assert "no frame of" in result.output and "gave an estimate" in result.output
    assert "does not exist" in result.output
    rows = [json.loads(line) for line in (ds / "estimates.jsonl").read_text().splitlines()]
    assert [row.get("exit_code") for row in rows[1:]] == [2, 2, 2]


def test_a_missing_reference_image_exits_2(ds):
    (ds / "left" / "000000.png").unlink()
    result = _estimate(ds)
    assert result.exit_code == 2 and "000000.png does not exist" in result.output


def test_only_reference_frames_exits_3(ds):
    path = ds / "frames.jsonl"
    path.write_text(path.read_text().splitlines()[0] + "\n")
    result = _estimate(ds)
    assert result.exit_code == 3 and "only unloaded reference frames" in result.output


def test_an_empty_frames_file_exits_2_before_any_work(ds):
    (ds / "frames.jsonl").write_text("")
    result = _estimate(ds)
    assert result.exit_code == 2 and "has no frames" in result.output
    assert not (ds / "estimates.jsonl").exists()


def test_some_frames_estimated_is_exit_0_with_a_warning(ds):
    (ds / "left" / "000002.png").write_bytes(b"not a png")
    result = _estimate(ds)
    assert result.exit_code == 0, result.output
    assert "estimated 2 of 3 loaded frames" in result.output and "1 frames gave no estimate" in result.output


def test_a_duplicate_index_exits_2_naming_the_line(ds):
    path = ds / "frames.jsonl"
    lines = path.read_text().splitlines()
    path.write_text("\n".join([*lines, lines[2]]) + "\n")
    result = _estimate(ds)
    assert result.exit_code == 2 and "line 5: frame index 2 was already used on line 3" in result.output


def test_a_garbage_line_is_skipped_with_a_warning(ds):
    path = ds / "frames.jsonl"
    lines = path.read_text().splitlines()
    lines.insert(2, "}}garbage{{")
    path.write_text("\n".join(lines) + "\n")
    result = _estimate(ds)
    assert result.exit_code == 0, result.output
    assert "warning:" in result.output and "line 3: not valid JSON" in result.output
    assert "estimated 3 of 3 loaded frames" in result.output


def test_a_path_outside_the_dataset_exits_2_naming_the_line(ds, tmp_path):
    path = ds / "frames.jsonl"
    lines = path.read_text().splitlines()
    frame = json.loads(lines[1])
    frame["left"] = "../../etc/passwd"
    lines[1] = json.dumps(frame)
    path.write_text("\n".join(lines) + "\n")
    result = _estimate(ds)
    assert result.exit_code == 2 and "line 2: left '../../etc/passwd' is outside the dataset" in result.output


@pytest.mark.parametrize(
    "name", ["frames.jsonl", "rig.toml", "as_built.toml", "left/000001.png", "truth/000001.npz", "left/x.csv"]
)
def test_out_into_the_datasets_own_files_is_refused(ds, name):
    before = {p: p.read_bytes() for p in ds.rglob("*") if p.is_file()}
    result = _estimate(ds, "--out", ds / name)
    assert result.exit_code == 2 and "one of the dataset's own files" in result.output
    assert {p: p.read_bytes() for p in ds.rglob("*") if p.is_file()} == before
    assert len(Dataset.open(ds)) == 4


def test_out_onto_a_link_to_the_index_or_an_input_is_refused(ds, tmp_path):
    (tmp_path / "link.jsonl").symlink_to(ds / "frames.jsonl")
    result = _estimate(ds, "--out", tmp_path / "link.jsonl")
    assert result.exit_code == 2 and "one of the dataset's own files" in result.output
    rig = tmp_path / "rig.toml"
    shutil.copy(ds / "rig.toml", rig)
    result = _estimate(ds, "--config", rig, "--out", rig)
    assert result.exit_code == 2 and "is an input of this command" in result.output
    assert rig.read_bytes() == (ds / "rig.toml").read_bytes()


def test_out_elsewhere_in_the_dataset_folder_is_fine(ds):
    result = _estimate(ds, "--out", ds / "results.csv")
    assert result.exit_code == 0, result.output
    first = (ds / "results.csv").read_text()
    assert len(first.splitlines()) == 1 + len(Dataset.open(ds))  # the header and a row a frame
    again = _estimate(ds, "--out", ds / "results.csv")  # our own results file: replaced, not appended to
    assert again.exit_code == 0, again.output
    assert (ds / "results.csv").read_text() == first


def test_out_into_another_datasets_files_or_not_a_results_file_is_refused(ds, source, tmp_path):
    other = shutil.copytree(source, tmp_path / "other")
    for target in (other / "frames.jsonl", other / "left" / "000009.jsonl"):
        result = _estimate(ds, "--out", target)
        assert result.exit_code == 2 and "one of the dataset's own files" in result.output
    photo = tmp_path / "photo.png"
    photo.write_bytes(b"precious")
    result = _estimate(ds, "--out", photo)
    assert result.exit_code == 2 and "must end in .jsonl or .csv" in result.output
    assert photo.read_bytes() == b"precious" and len(Dataset.open(other)) == 4
