"""Batch estimation: rows streamed in frame order, atomically, the same on any number of workers."""

from __future__ import annotations

import json
import multiprocessing
import os

import pytest

import softjig.io.batch as batch
import softjig.io.dataset as dataset_module
from softjig.config import default_jig
from softjig.errors import InputError
from softjig.io.batch import (
    BatchSettings,
    RowsWriter,
    dataset_reference,
    estimate_dataset,
    estimate_dataset_to_file,
    rows_to_text,
    write_rows,
)
from softjig.io.dataset import Dataset, Frame
from softjig.io.simulated import simulate_dataset
from softjig.sim.scenarios import paper_sweep


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    """A reference frame, 3 loaded frames (D = 50 mm) and a frame whose left image is corrupt."""
    root = tmp_path_factory.mktemp("batch") / "sweep"
    specs = list(paper_sweep(diameters_mm=(50,), alphas_deg=(10,), theta_step_deg=120))
    simulate_dataset(root, specs, default_jig(), seed=3, workers=1, progress=False)
    (root / "left" / "bad.png").write_bytes(b"\x89PNG cut short")
    line = {"index": 4, "left": "left/bad.png", "right": "right/000001.png", "alpha_deg": 10.0,
            "theta_deg": 0.0, "part": {"kind": "cylinder", "diameter_mm": 50.0}}  # fmt: skip
    with open(root / "frames.jsonl", "a") as fh:
        fh.write(json.dumps(line) + "\n")
    return Dataset.open(root)


@pytest.fixture(scope="module")
def settings(dataset):
    return BatchSettings(jig=dataset.jig, reference=dataset_reference(dataset, dataset.jig))


@pytest.fixture(scope="module")
def rows(dataset, settings):
    """The rows computed one by one in this process: what every other way must reproduce."""
    return list(estimate_dataset(dataset, settings, workers=1))


def test_rows_cover_every_frame_in_order(dataset, rows):
    assert [row["index"] for row in rows] == [frame.index for frame in dataset] == [0, 1, 2, 3, 4]
    assert rows[0] == {"index": 0, "reference": True}
    assert all("normal" in row for row in rows[1:4])
    assert rows[4]["exit_code"] == 2 and "cannot decode" in rows[4]["error"]


@pytest.mark.parametrize("name", ["estimates.jsonl", "estimates.csv"])
@pytest.mark.parametrize("workers", [1, 2])
def test_streamed_file_equals_the_whole_text(dataset, settings, rows, tmp_path, name, workers):
    out = tmp_path / name
    summary = estimate_dataset_to_file(dataset, settings, out, workers=workers)
    assert out.read_bytes() == rows_to_text(rows, out).encode("utf-8")
    assert (summary.n_rows, summary.n_loaded, summary.n_failed) == (5, 4, 1)
    assert summary.first_failure == rows[4]
    assert [p.name for p in tmp_path.iterdir()] == [name]  # no temporary file left behind


def test_csv_has_the_columns_of_every_row(rows, tmp_path):
    out = tmp_path / "r.csv"
    assert write_rows(iter(rows), out) == len(rows)
    lines = out.read_text().splitlines()
    assert lines[0] == ",".join(batch.CSV_COLUMNS)
    assert len(lines) == 1 + len(rows) and lines[1].startswith("0,") and lines[1].endswith(",True,,")


def test_workers_and_chunks_give_identical_rows(dataset, settings, rows):
    assert list(estimate_dataset(dataset, settings, workers=2)) == rows
    assert list(estimate_dataset(dataset, settings, workers=2, chunk_frames=1)) == rows
    assert list(estimate_dataset(dataset, settings, workers=2, chunk_frames=3)) == rows


@pytest.mark.skipif("fork" not in multiprocessing.get_all_start_methods(), reason="needs fork")
def test_the_parent_warms_up_on_the_first_loaded_frame_and_the_workers_read_the_rest(
    dataset, settings, rows, monkeypatch
):
    real_estimate, real_parse = batch.estimate_frame, dataset_module._frame_from_json
    parsed_here = []

    def tagged(frame, settings):  # the forked workers inherit the patch
        return {**real_estimate(frame, settings), "pid": os.getpid()}

    monkeypatch.setattr(batch, "estimate_frame", tagged)
    monkeypatch.setattr(
        dataset_module, "_frame_from_json", lambda *a: parsed_here.append(1) or real_parse(*a)
    )
    got = list(estimate_dataset(dataset, settings, workers=2))
    assert [{k: v for k, v in row.items() if k != "pid"} for row in got] == rows
    # frame 0 is the unloaded reference, frame 1 the first loaded one: both estimated here, then forked
    assert [row["pid"] == os.getpid() for row in got] == [True, True, False, False, False]
    assert len(parsed_here) == 2  # the workers parsed their frames' lines themselves


def test_chunks_shrink_towards_the_end():
    assert [batch._chunk_size(remaining, 2) for remaining in (10_000, 64, 20, 8, 7, 1)] == [8, 8, 2, 1, 1, 1]
    assert batch._chunk_size(10_000, 2) == batch.MAX_CHUNK_FRAMES


def test_spawned_workers_give_identical_rows(dataset, settings, rows, monkeypatch):
    """Where workers cannot be forked (macOS, Windows) they are spawned: no warm-up in the parent, and the
    dataset (its line offsets) is pickled to each worker once."""
    monkeypatch.setattr(batch, "_pool_context", lambda: multiprocessing.get_context("spawn"))
    assert list(estimate_dataset(dataset, settings, workers=2, chunk_frames=2)) == rows


class _Stop(Exception):
    pass


@pytest.mark.parametrize("workers", [1, 2])
def test_a_failed_run_leaves_the_old_file(dataset, settings, tmp_path, workers):
    out = tmp_path / "estimates.jsonl"
    out.write_text("the good results of an earlier run\n")
    seen = []

    def fail_at_third_row(row):
        seen.append(row["index"])
        assert out.read_text() == "the good results of an earlier run\n"  # not replaced while running
        if len(seen) == 3:
            raise _Stop

    with pytest.raises(_Stop):
        estimate_dataset_to_file(dataset, settings, out, workers=workers, on_row=fail_at_third_row)
    assert seen == [0, 1, 2]
    assert out.read_text() == "the good results of an earlier run\n"
    assert [p.name for p in tmp_path.iterdir()] == ["estimates.jsonl"]


def test_a_failed_run_leaves_no_file(rows, tmp_path):
    out = tmp_path / "new.csv"

    def failing():
        yield from rows[:2]
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        write_rows(failing(), out)
    assert list(tmp_path.iterdir()) == []


def test_unwritable_targets_fail_before_any_frame(dataset, settings, tmp_path):
    called = []
    with pytest.raises(InputError, match="is a folder"):
        estimate_dataset_to_file(dataset, settings, tmp_path, workers=1, on_row=called.append)
    assert called == []
    with pytest.raises(RuntimeError, match="outside"):
        RowsWriter(tmp_path / "x.jsonl").write({"index": 0})


class _CountingDataset:
    """A long dataset of reference frames (cheap rows, no image read) that counts the frames drawn."""

    def __init__(self, root, n):
        self.frames = [Frame(root, i, "left/x.png", "right/x.png", reference=True) for i in range(n)]
        self.drawn = 0

    def __len__(self):
        return len(self.frames)

    def __iter__(self):
        for frame in self.frames:
            self.drawn += 1
            yield frame


def test_frames_in_flight_are_bounded(settings, tmp_path):
    data = _CountingDataset(tmp_path, 2000)
    rows = estimate_dataset(data, settings, workers=2)
    assert next(rows) == {"index": 0, "reference": True}
    chunk = batch._chunk_size(2000, 2)
    assert data.drawn <= (batch.CHUNKS_IN_FLIGHT_PER_WORKER * 2 + 1) * chunk < 100
    assert [row["index"] for row in rows] == list(range(1, 2000))  # and the rest, in order
    assert data.drawn == 2000
