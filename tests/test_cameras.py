"""Camera sources: pairing by timestamp, replay (fast and at the recorded rate), OpenCV on video files."""

from __future__ import annotations

import time

import cv2
import numpy as np
import pytest

from softjig.config import default_jig
from softjig.errors import InputError
from softjig.io.cameras import (
    CameraError,
    FramePairer,
    OpenCVStereoSource,
    ReplaySource,
    SourceExhausted,
    open_source,
    parse_source_spec,
)
from softjig.io.dataset import DatasetWriter


@pytest.fixture(scope="module")
def sweep(small_dataset):
    return small_dataset


@pytest.fixture()
def timed(tmp_path):
    """A tiny recording with times 0, 0.15, 0.3 s and one 10 s later."""
    rng = np.random.default_rng(0)
    with DatasetWriter(tmp_path / "timed", default_jig()) as writer:
        for t in (0.0, 0.15, 0.3, 10.0):
            image = rng.integers(0, 255, (8, 10), dtype=np.uint8)
            writer.add_frame(image, image, {"time_s": t})
    return tmp_path / "timed"


# ------------------------------------------------------------------------------------------ pairing


def test_pairer_pairs_equal_timestamps_in_order():
    pairer = FramePairer(0.01)
    for k in range(3):
        pairer.push("left", k * 0.033, f"L{k}")
        pairer.push("right", k * 0.033 + 0.002, f"R{k}")
    pairs = [pairer.pop() for _ in range(3)]
    assert [(p[0][1], p[1][1]) for p in pairs] == [("L0", "R0"), ("L1", "R1"), ("L2", "R2")]
    assert pairer.pop() is None
    assert pairer.dropped == 0


def test_pairer_drops_an_image_that_can_have_no_partner():
    pairer = FramePairer(0.01)
    pairer.push("left", 0.000, "L0")  # the right camera missed this one
    pairer.push("left", 0.033, "L1")
    pairer.push("right", 0.034, "R1")
    (tl, left), (tr, right) = pairer.pop()
    assert (left, right) == ("L1", "R1")
    assert tr - tl == pytest.approx(0.001)
    assert pairer.dropped == 1


def test_pairer_prefers_the_closer_partner():
    pairer = FramePairer(0.02)
    pairer.push("right", 0.030, "R")
    pairer.push("left", 0.012, "L0")  # within the bound, but L1 is closer
    pairer.push("left", 0.029, "L1")
    assert pairer.pop()[0][1] == "L1"
    assert pairer.dropped == 1


def test_pairer_bounds_what_it_keeps():
    pairer = FramePairer(0.01, max_pending=2)
    for k in range(5):
        pairer.push("left", float(k), k)
    assert pairer.dropped == 3
    with pytest.raises(InputError, match="side"):
        pairer.push("middle", 0.0, None)
    with pytest.raises(InputError):
        FramePairer(0.0)


# ------------------------------------------------------------------------------------------ specs


@pytest.mark.parametrize(
    ("text", "kind", "left", "right"),
    [
        ("opencv:0,1", "opencv", 0, 1),
        ("opencv:/dev/video0,/dev/video2", "opencv", "/dev/video0", "/dev/video2"),
        ("realsense", "realsense", None, None),
        ("realsense:123,456", "realsense", "123", "456"),
    ],
)
def test_parse_source_spec(text, kind, left, right):
    spec = parse_source_spec(text)
    assert (spec.kind, spec.left, spec.right) == (kind, left, right)


@pytest.mark.parametrize("text", ["opencv", "opencv:0", "opencv:0,1,2", "usb:0,1", "realsense:1"])
def test_parse_source_spec_refuses_other_forms(text):
    with pytest.raises(InputError, match="--source must be"):
        parse_source_spec(text)


def test_open_source_refuses_a_missing_video_file(tmp_path):
    with pytest.raises(InputError, match="neither a device"):
        open_source(f"opencv:{tmp_path}/a.avi,{tmp_path}/b.avi")


# ------------------------------------------------------------------------------------------- replay


def test_fast_replay_delivers_every_frame_then_ends(sweep):
    with ReplaySource(sweep, rate="fast") as source:
        assert not source.realtime
        frames = [source.read(1.0) for _ in range(5)]
        with pytest.raises(SourceExhausted):
            source.read(1.0)
    assert [f.source_index for f in frames] == [0, 1, 2, 3, 4]
    assert all(f.skew_s == 0.0 for f in frames)
    assert frames[0].left.shape == (720, 1280)
    assert frames[1].meta["part"]["diameter_mm"] == 50.0
    assert frames[1].time_s == pytest.approx(1 / 30)  # no time_s in a simulation: 30 Hz


def test_recorded_rate_replay_keeps_the_recorded_spacing(timed):
    source = ReplaySource(timed, rate="recorded")
    source.open()
    assert source.realtime
    t0 = time.monotonic()
    got = [source.read(1.0) for _ in range(3)]
    elapsed = time.monotonic() - t0
    assert [f.time_s for f in got] == [0.0, 0.15, 0.3]
    assert elapsed >= 0.25  # at least the recorded 0.3 s, less scheduling slack
    assert source.read(0.05) is None  # the next frame is 9.7 s away: a time-out, not a frame
    source.close()


def test_replay_refuses_bad_options(sweep):
    with pytest.raises(InputError, match="rate"):
        ReplaySource(sweep, rate="slow")
    with pytest.raises(InputError, match="fps"):
        ReplaySource(sweep, fps=0.0)


# ------------------------------------------------------------------------------------------- OpenCV


def _write_video(path, n_frames, shade):
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 30.0, (64, 48))
    assert writer.isOpened()
    for k in range(n_frames):
        image = np.full((48, 64, 3), shade, dtype=np.uint8)
        image[:, :, 2] = 10 * k  # red grows (BGR): the source must hand out RGB
        writer.write(image)
    writer.release()


def test_opencv_source_reads_two_video_files_as_a_pair(tmp_path):
    _write_video(tmp_path / "l.avi", 4, 60)
    _write_video(tmp_path / "r.avi", 4, 180)
    source = open_source(f"opencv:{tmp_path / 'l.avi'},{tmp_path / 'r.avi'}")
    assert isinstance(source, OpenCVStereoSource)
    with source:
        frames = [source.read(1.0) for _ in range(4)]
        with pytest.raises(CameraError, match="delivered no image"):
            source.read(1.0)
    assert [f.seq for f in frames] == [0, 1, 2, 3]
    for f in frames:
        assert f.left.shape == (48, 64, 3) and f.left.dtype == np.uint8
        assert abs(int(f.left[..., 1].mean()) - 60) < 8 and abs(int(f.right[..., 1].mean()) - 180) < 8
        assert 0.0 <= f.skew_s < 1.0
    assert frames[3].left[..., 0].mean() > frames[0].left[..., 0].mean() + 15  # RGB order


def test_opencv_source_names_a_camera_it_cannot_open(tmp_path):
    source = OpenCVStereoSource(str(tmp_path / "nope.avi"), str(tmp_path / "nope2.avi"))
    with pytest.raises(CameraError, match="cannot open"):
        source.open()
