"""The Foxglove view: an MCAP log read back, the live WebSocket server on loopback, the plane's pose."""

from __future__ import annotations

import json
import socket
from collections import Counter

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

pytest.importorskip("foxglove")
mcap_reader = pytest.importorskip("mcap.reader")

from softjig.errors import InputError  # noqa: E402
from softjig.io.cameras import ReplaySource  # noqa: E402
from softjig.io.dataset import Dataset  # noqa: E402
from softjig.live.loop import LiveLoop, LiveSettings  # noqa: E402
from softjig.live.viewer import FoxgloveViewer, plane_square_pose  # noqa: E402


@pytest.fixture(scope="module")
def sweep(small_dataset):
    return Dataset.open(small_dataset)


@pytest.mark.parametrize("normal", [(0.0, 0.0, 1.0), (0.17, -0.1, 0.98), (0.0, 0.0, -1.0), (1.0, 0.0, 0.0)])
def test_plane_and_arrow_orientations_point_along_the_normal(normal):
    n = np.asarray(normal) / np.linalg.norm(normal)
    position, q_plane, q_arrow = plane_square_pose(n, np.array([1.0, 2.0, 30.0]))
    np.testing.assert_allclose(position, [0.001, 0.002, 0.030])
    np.testing.assert_allclose(Rotation.from_quat(q_plane).apply([0, 0, 1]), n, atol=1e-9)
    np.testing.assert_allclose(Rotation.from_quat(q_arrow).apply([1, 0, 0]), n, atol=1e-9)


def test_the_mcap_log_holds_images_markers_points_plane_and_estimates(sweep, tmp_path):
    path = tmp_path / "run.mcap"
    viewer = FoxgloveViewer(mcap_path=path)
    messages = []
    summary = LiveLoop(
        ReplaySource(sweep, rate="fast"),
        LiveSettings(jig=sweep.jig, method="paper"),  # no estimate for the reference frame
        sinks=[viewer],
        on_outcome=lambda o, m: messages.append(m),
    ).run()
    assert summary.final.processed == 5 and summary.final.estimated == 4 and not summary.sink_errors
    with open(path, "rb") as fh:
        records = list(mcap_reader.make_reader(fh).iter_messages())
    counts = Counter(channel.topic for _, channel, _ in records)
    for topic in ("/left/image", "/right/image", "/softjig/estimate"):
        assert counts[topic] == 5
    for topic in ("/left/markers", "/right/markers", "/points", "/plane", "/tf"):
        assert counts[topic] == 4  # frames with an estimate
    assert counts["/softjig/health"] >= 2
    schemas = {channel.topic: schema.name for schema, channel, _ in records}
    assert schemas["/left/image"] == "foxglove.RawImage"
    assert schemas["/points"] == "foxglove.PointCloud"
    assert schemas["/plane"] == "foxglove.SceneUpdate"
    assert schemas["/softjig/estimate"] == "softjig.estimate"
    logged = [json.loads(m.data) for _, c, m in records if c.topic == "/softjig/estimate"]
    assert [m["seq"] for m in logged] == [m["seq"] for m in messages]
    assert logged[1]["estimate"]["normal"] == messages[1]["estimate"]["normal"]
    image = next(m for _, c, m in records if c.topic == "/left/image")
    assert len(image.data) > 1280 * 720  # the whole gray image (plus the message's header)


def test_the_live_server_listens_on_loopback_only(tmp_path):
    viewer = FoxgloveViewer(serve=True, port=0)
    try:
        assert viewer.port and viewer.port > 0
        with socket.create_connection(("127.0.0.1", viewer.port), timeout=5):
            pass
    finally:
        viewer.close()
    with pytest.raises(InputError, match="allow-remote"):
        FoxgloveViewer(serve=True, host="0.0.0.0", port=0)
    with pytest.raises(InputError, match="needs an MCAP file"):
        FoxgloveViewer()


def test_an_existing_mcap_file_is_not_overwritten(tmp_path):
    (tmp_path / "x.mcap").write_bytes(b"precious")
    with pytest.raises(InputError, match="exists"):
        FoxgloveViewer(mcap_path=tmp_path / "x.mcap")
    assert (tmp_path / "x.mcap").read_bytes() == b"precious"
