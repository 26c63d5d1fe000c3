"""Recording while sensing: the dataset format as it goes, lossless, and readable after a SIGKILL."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import time
import warnings

import numpy as np
import pytest

from softjig.errors import InputError
from softjig.io.cameras import ReplaySource
from softjig.io.dataset import Dataset, DatasetTruncationWarning
from softjig.live.loop import LiveLoop, LiveSettings, Recorder


@pytest.fixture(scope="module")
def sweep(small_dataset):
    return Dataset.open(small_dataset)


def test_recording_a_replay_is_a_lossless_dataset(sweep, tmp_path):
    recorder = Recorder(tmp_path / "rec", sweep.jig)
    summary = LiveLoop(ReplaySource(sweep, rate="fast"), LiveSettings(jig=sweep.jig), recorder=recorder).run()
    assert (summary.final.recorded, summary.final.not_recorded) == (5, 0)
    rec = Dataset.open(tmp_path / "rec")
    assert len(rec) == 5 and rec.jig == sweep.jig
    for original, copy in zip(sweep, rec, strict=True):
        np.testing.assert_array_equal(copy.load_left(), original.load_left())
        np.testing.assert_array_equal(copy.load_right(), original.load_right())
        assert copy.meta["source_index"] == original.index
        assert copy.part == original.part and copy.alpha_deg == original.alpha_deg
        assert copy.reference == original.reference
    assert [f.time_s for f in rec] == pytest.approx([k / 30 for k in range(5)], abs=1e-5)
    assert rec[1].truth is not None and rec[1].truth.markers is None  # the truth's .npz is not copied
    np.testing.assert_allclose(rec[1].truth.normal, sweep[1].truth.normal)
    assert rec[0].meta["skew_ms"] == 0.0


def test_a_recording_is_replayed_at_its_recorded_times(sweep, tmp_path):
    LiveLoop(
        ReplaySource(sweep, rate="fast"),
        LiveSettings(jig=sweep.jig),
        recorder=Recorder(tmp_path / "rec", sweep.jig),
    ).run()
    with ReplaySource(tmp_path / "rec", rate="fast") as replay:
        times = [replay.read(1.0).time_s for _ in range(5)]
    assert times == pytest.approx([k / 30 for k in range(5)], abs=1e-5)


def test_recorder_refuses_a_folder_in_use(sweep, tmp_path):
    (tmp_path / "busy").mkdir()
    (tmp_path / "busy" / "notes.txt").write_text("mine")
    with pytest.raises(InputError, match="not empty"):
        Recorder(tmp_path / "busy", sweep.jig)


@pytest.mark.skipif(sys.platform == "win32", reason="POSIX signals")
def test_a_recorder_killed_mid_recording_leaves_every_completed_frame_readable(sweep, tmp_path):
    out = tmp_path / "killed"
    proc = subprocess.Popen(
        [
            sys.executable,
            "-c",
            "from softjig.cli import main; main()",
            "live",
            "--replay",
            str(sweep.root),
            "--fps",
            "3",
            "--part-diameter",
            "50",
            "--record",
            str(out),
        ],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
    )
    frames = out / "frames.jsonl"
    try:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and proc.poll() is None:
            if frames.exists() and frames.read_bytes().count(b"\n") >= 2:
                break
            time.sleep(0.01)
        assert proc.poll() is None, "the recorder ended before it could be killed"
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == -signal.SIGKILL
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DatasetTruncationWarning)
        rec = Dataset.open(out)
    assert 2 <= len(rec) <= 5
    for frame in rec:  # every frame frames.jsonl names is complete
        original = sweep[frame.meta["source_index"]]
        np.testing.assert_array_equal(frame.load_left(), original.load_left())
        np.testing.assert_array_equal(frame.load_right(), original.load_right())


def test_record_overwrite_never_deletes_a_folder_of_calibration_photos(sweep, tmp_path):
    from typer.testing import CliRunner

    from softjig.cli import app

    photos = tmp_path / "calib"
    for side in ("left", "right"):
        (photos / side).mkdir(parents=True)
        (photos / side / "board-01.png").write_bytes(b"a photo")
    (photos / "rig.toml").write_text("# calibrated\n")
    before = {p: p.read_bytes() for p in photos.rglob("*") if p.is_file()}
    args = ["live", "--replay", str(sweep.root), "--rate", "fast", "--record", str(photos), "--overwrite"]
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 2 and "not a softjig dataset" in result.output
    assert {p: p.read_bytes() for p in photos.rglob("*") if p.is_file()} == before


def test_record_overwrite_replaces_an_old_simulation_only_when_the_new_recording_is_complete(sweep, tmp_path):
    shutil.copytree(sweep.root, tmp_path / "rec")  # a simulation: it may be replaced
    recorder = Recorder(tmp_path / "rec", sweep.jig, overwrite=True)
    assert Dataset.open(tmp_path / "rec").has_as_built  # while recording, the old simulation is whole
    LiveLoop(
        ReplaySource(sweep, rate="fast"), LiveSettings(jig=sweep.jig, max_frames=2), recorder=recorder
    ).run()
    rec = Dataset.open(tmp_path / "rec")
    assert len(rec) == 2 and not rec.has_as_built
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rec"]


def test_record_overwrite_never_replaces_a_recording(sweep, tmp_path):
    old = Recorder(tmp_path / "rec", sweep.jig)
    LiveLoop(ReplaySource(sweep, rate="fast"), LiveSettings(jig=sweep.jig, max_frames=2), recorder=old).run()
    with pytest.raises(InputError, match=r"holds a recording.*never a recording"):
        Recorder(tmp_path / "rec", sweep.jig, overwrite=True)
    assert len(Dataset.open(tmp_path / "rec")) == 2
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rec"]


def test_record_into_the_replayed_dataset_is_refused(sweep):
    from typer.testing import CliRunner

    from softjig.cli import app

    for target in (sweep.root, sweep.root / "again"):
        args = ["live", "--replay", str(sweep.root), "--rate", "fast", "--record", str(target), "--overwrite"]
        result = CliRunner().invoke(app, args)
        assert result.exit_code == 2 and "inside the replayed dataset" in result.output
    assert len(Dataset.open(sweep.root)) == 5 and (sweep.root / "truth").is_dir()


def test_a_camera_that_cannot_be_opened_leaves_an_old_recording_in_place(sweep, tmp_path):
    from softjig.io.cameras import CameraError, StereoSource

    class _Unplugged(StereoSource):
        name, realtime = "unplugged", True

        def open(self):
            raise CameraError("unplugged: no such device")

        def read(self, timeout_s):
            raise AssertionError("never read")

        def close(self):
            pass

    shutil.copytree(sweep.root, tmp_path / "rec")  # an old simulation, which an overwrite may replace
    loop = LiveLoop(
        _Unplugged(),
        LiveSettings(jig=sweep.jig),
        recorder=Recorder(tmp_path / "rec", sweep.jig, overwrite=True),
    )
    with pytest.raises(CameraError, match="unplugged"):
        loop.run()
    assert len(Dataset.open(tmp_path / "rec")) == 5 and Dataset.open(tmp_path / "rec").has_as_built
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rec"]  # and the next --overwrite may go ahead
