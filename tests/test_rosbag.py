"""ROS 2 bags: pairs read from bags written by other libraries, softjig's bags read by other libraries,
image encodings, pairing by stamp, bad bags, a recorder killed mid-write, and `softjig estimate BAG`."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
import time
import warnings

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from softjig.cli import app
from softjig.config import default_jig
from softjig.errors import InputError
from softjig.io.bag_convert import dataset_to_bag
from softjig.io.dataset import Dataset
from softjig.io.rosbag import (
    TOPIC_LEFT,
    TOPIC_MARKERS,
    TOPIC_NORMAL,
    TOPIC_PART_POSE,
    TOPIC_RIGHT,
    BagReader,
    BagTruncationWarning,
    BagWriter,
    decode_image_message,
    rotation_z_to,
)
from softjig.io.simulated import simulate_dataset
from softjig.sim.scenarios import paper_sweep

runner = CliRunner()

# The definitions as `ros2 bag record` stores them (written here by hand, not by rosbags).
HEADER_DEF = "builtin_interfaces/Time stamp\nstring frame_id\n"
TIME_DEF = "int32 sec\nuint32 nanosec\n"
SEP = "=" * 80 + "\n"
IMAGE_DEF = (
    "std_msgs/Header header\nuint32 height\nuint32 width\nstring encoding\nuint8 is_bigendian\n"
    "uint32 step\nuint8[] data\n"
    f"{SEP}MSG: std_msgs/Header\n{HEADER_DEF}{SEP}MSG: builtin_interfaces/Time\n{TIME_DEF}"
)
COMPRESSED_DEF = (
    "std_msgs/Header header\nstring format\nuint8[] data\n"
    f"{SEP}MSG: std_msgs/Header\n{HEADER_DEF}{SEP}MSG: builtin_interfaces/Time\n{TIME_DEF}"
)
STRING_DEF = "string data\n"

T0_NS = 1_700_000_000_000_000_000


def _header(stamp_ns):
    return {"stamp": {"sec": stamp_ns // 10**9, "nanosec": stamp_ns % 10**9}, "frame_id": "cam"}


def _images(n, shape=(24, 32), seed=0):
    rng = np.random.default_rng(seed)
    return [
        (rng.integers(0, 256, shape, dtype=np.uint8), rng.integers(0, 256, shape, dtype=np.uint8))
        for _ in range(n)
    ]


def _write_mcap_ros2(
    path,
    pairs,
    *,
    left="/stereo/left/image_raw",
    right="/stereo/right/image_raw",
    skew_ns=2_000_000,
    period_ns=33_333_333,
    extra_topic=True,
    **writer_options,
):
    """A single .mcap written by mcap-ros2-support (no rosbags involved); log times differ from the
    header stamps, so pairing must use the stamps. ``writer_options``: its writer's chunk size and
    compression."""
    from mcap_ros2.writer import Writer

    with open(path, "wb") as fh:
        writer = Writer(fh, **writer_options)
        image = writer.register_msgdef("sensor_msgs/msg/Image", IMAGE_DEF)
        string = writer.register_msgdef("std_msgs/msg/String", STRING_DEF)
        for i, (a, b) in enumerate(pairs):
            stamp = T0_NS + i * period_ns
            for topic, img, s in ((left, a, stamp), (right, b, stamp + skew_ns)):
                msg = {
                    "header": _header(s),
                    "height": img.shape[0],
                    "width": img.shape[1],
                    "encoding": "mono8",
                    "is_bigendian": 0,
                    "step": img.shape[1],
                    "data": img.tobytes(),
                }
                writer.write_message(
                    topic, image, msg, log_time=s + 50_000_000 + (7 if topic == right else 0)
                )
            if extra_topic:
                writer.write_message("/chatter", string, {"data": f"hello {i}"}, log_time=stamp)
        writer.finish()


def _colour(gray):
    return np.dstack([gray, gray // 2, 255 - gray])


def _write_rosbags_folder(path, pairs, *, fmt="png", storage="mcap"):
    """A rosbag2 folder (metadata.yaml + MCAP) written by rosbags' own Writer, CompressedImage on the left
    and raw bgr8 Image on the right."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    T = ts.types
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    with Writer(path, version=9, storage_plugin=plugin) as writer:
        cl = writer.add_connection("/cam_left/compressed", "sensor_msgs/msg/CompressedImage", typestore=ts)
        cr = writer.add_connection("/cam_right/image", "sensor_msgs/msg/Image", typestore=ts)
        for i, (a, b) in enumerate(pairs):
            stamp = T0_NS + i * 33_333_333
            sec, ns = divmod(stamp, 10**9)
            hdr = T["std_msgs/msg/Header"](
                stamp=T["builtin_interfaces/msg/Time"](sec=sec, nanosec=ns), frame_id="c"
            )
            ok, enc = cv2.imencode("." + fmt, np.ascontiguousarray(_colour(a)[:, :, ::-1]))  # OpenCV: BGR
            assert ok
            msg = T["sensor_msgs/msg/CompressedImage"](
                header=hdr, format=f"rgb8; {fmt} compressed bgr8", data=enc.reshape(-1)
            )
            writer.write(cl, stamp, ts.serialize_cdr(msg, msg.__msgtype__))
            rgb = _colour(b)
            bgr = np.ascontiguousarray(rgb[:, :, ::-1])
            msg = T["sensor_msgs/msg/Image"](
                header=hdr,
                height=b.shape[0],
                width=b.shape[1],
                encoding="bgr8",
                is_bigendian=0,
                step=3 * b.shape[1],
                data=bgr.reshape(-1),
            )
            writer.write(cr, stamp, ts.serialize_cdr(msg, msg.__msgtype__))


# ------------------------------------------------------------------------------- reading others' bags


def test_pairs_from_an_mcap_written_by_mcap_ros2_support(tmp_path):
    pairs = _images(5)
    bag = tmp_path / "other.mcap"
    _write_mcap_ros2(bag, pairs)
    with BagReader(bag) as reader:
        topics = reader.choose_topics()
        assert (topics.left, topics.right) == ("/stereo/left/image_raw", "/stereo/right/image_raw")
        assert "left and right" in topics.reason
        got = list(reader.pairs(topics, tolerance_s=0.005))
    assert len(got) == 5
    for i, ((a, b), pair) in enumerate(zip(pairs, got, strict=True)):
        np.testing.assert_array_equal(pair.left, a)
        np.testing.assert_array_equal(pair.right, b)
        assert pair.stamp_left_ns == T0_NS + i * 33_333_333  # the header stamp, not the log time
        assert pair.stamp_right_ns - pair.stamp_left_ns == 2_000_000
        assert pair.index == i and pair.meta == {} and not pair.reference


@pytest.mark.parametrize("compression", ["ZSTD", "LZ4", "NONE"])
def test_pairs_from_small_chunks_of_every_compression(tmp_path, compression):
    """The reader's own chunk parser (messages as views of the decompressed chunk): zstd, lz4 and
    uncompressed chunks of a few messages each, pairs split across chunks, the same images back."""
    from mcap.writer import CompressionType

    pairs = _images(7, shape=(40, 56), seed=3)
    bag = tmp_path / f"{compression.lower()}.mcap"
    _write_mcap_ros2(bag, pairs, chunk_size=5000, compression=CompressionType[compression])
    with BagReader(bag) as reader:
        got = list(reader.pairs(reader.choose_topics(), tolerance_s=0.005))
    assert len(got) == len(pairs)
    for (a, b), pair in zip(pairs, got, strict=True):
        np.testing.assert_array_equal(pair.left, a)
        np.testing.assert_array_equal(pair.right, b)


@pytest.mark.parametrize(("fmt", "storage"), [("png", "mcap"), ("jpg", "mcap"), ("png", "sqlite3")])
def test_pairs_from_a_rosbag2_folder_written_by_rosbags_compressed_and_bgr8(tmp_path, fmt, storage):
    yy, xx = np.mgrid[0:24, 0:32]
    pairs = [
        ((xx * 6 + yy * 3 + 20 * i).astype(np.uint8), (xx * 3 + yy * 5 + 9 * i).astype(np.uint8))
        for i in range(3)
    ]
    bag = tmp_path / "folder"
    _write_rosbags_folder(bag, pairs, fmt=fmt, storage=storage)
    assert (bag / "metadata.yaml").is_file()
    with BagReader(bag) as reader:
        topics = reader.choose_topics()
        assert (topics.left, topics.right) == ("/cam_left/compressed", "/cam_right/image")
        got = list(reader.pairs(topics))
    assert len(got) == 3
    for (a, b), pair in zip(pairs, got, strict=True):
        if fmt == "png":
            np.testing.assert_array_equal(pair.left, _colour(a))  # RGB, whatever OpenCV's order
        else:  # lossy, but the same picture, in RGB order
            assert pair.left.shape == (*a.shape, 3)
            assert np.abs(pair.left.astype(int) - _colour(a)).mean() < 8  # a channel swap is ~100 off
        np.testing.assert_array_equal(pair.right, _colour(b))  # bgr8 -> RGB


def test_decode_mono16_both_byte_orders_rgb8_and_padded_rows():
    from types import SimpleNamespace as NS

    img16 = np.arange(12, dtype=np.uint16).reshape(3, 4) * 1000
    for big in (0, 1):
        data = img16.astype(">u2" if big else "<u2").tobytes()
        msg = NS(
            encoding="mono16", height=3, width=4, step=8, is_bigendian=big, data=np.frombuffer(data, np.uint8)
        )
        out = decode_image_message(msg, "sensor_msgs/msg/Image")
        assert out.dtype == np.uint16
        np.testing.assert_array_equal(out, img16)
    rgb = np.arange(2 * 3 * 3, dtype=np.uint8).reshape(2, 3, 3)
    padded = np.zeros((2, 12), np.uint8)  # step 12 > 9 bytes of pixels
    padded[:, :9] = rgb.reshape(2, 9)
    msg = NS(encoding="rgb8", height=2, width=3, step=12, is_bigendian=0, data=padded.reshape(-1))
    np.testing.assert_array_equal(decode_image_message(msg, "sensor_msgs/msg/Image"), rgb)
    with pytest.raises(InputError, match="encoding 'yuv422'"):
        decode_image_message(
            NS(encoding="yuv422", height=2, width=3, step=6, is_bigendian=0, data=np.zeros(12, np.uint8)),
            "sensor_msgs/msg/Image",
        )
    with pytest.raises(InputError, match="does not fit"):
        decode_image_message(
            NS(encoding="mono8", height=20, width=3, step=3, is_bigendian=0, data=np.zeros(12, np.uint8)),
            "sensor_msgs/msg/Image",
        )


def test_stamps_that_never_pair_say_by_how_much(tmp_path):
    bag = tmp_path / "skewed.mcap"
    _write_mcap_ros2(bag, _images(3), skew_ns=20_000_000)
    result = runner.invoke(
        app,
        [
            "estimate",
            str(bag),
            "--config",
            str(_rig(tmp_path)),
            "--no-progress",
            "--stamp-tolerance",
            "0.005",
            "--out",
            str(tmp_path / "r.jsonl"),
        ],
    )
    assert result.exit_code == 2, result.output
    # the nearest: a right image (+20 ms) and the next left one (+33.3 ms)
    assert (
        "within 5 ms" in result.output
        and "13.333 ms" in result.output
        and "--stamp-tolerance" in result.output
    )
    assert not (tmp_path / "r.jsonl").exists()


def _rig(tmp_path):
    from softjig.config import save_jig

    path = tmp_path / "rig.toml"
    save_jig(default_jig(), path)
    return path


def test_a_bag_without_image_topics_lists_its_topics(tmp_path):
    from mcap_ros2.writer import Writer

    bag = tmp_path / "chatter.mcap"
    with open(bag, "wb") as fh:
        writer = Writer(fh)
        schema = writer.register_msgdef("std_msgs/msg/String", STRING_DEF)
        writer.write_message("/chatter", schema, {"data": "hi"}, log_time=T0_NS)
        writer.finish()
    result = runner.invoke(app, ["estimate", str(bag), "--config", str(_rig(tmp_path)), "--no-progress"])
    assert result.exit_code == 2
    assert (
        "no image topics" in result.output and "/chatter  std_msgs/msg/String  (1 messages)" in result.output
    )


def test_a_missing_topic_and_a_non_image_topic_are_refused_with_the_listing(tmp_path):
    bag = tmp_path / "other.mcap"
    _write_mcap_ros2(bag, _images(2))
    rig = str(_rig(tmp_path))
    result = runner.invoke(
        app, ["estimate", str(bag), "--config", rig, "--left-topic", "/nope", "--no-progress"]
    )
    assert (
        result.exit_code == 2
        and "no such topic" in result.output
        and "/stereo/left/image_raw" in result.output
    )
    result = runner.invoke(
        app,
        [
            "estimate",
            str(bag),
            "--config",
            rig,
            "--left-topic",
            "/chatter",
            "--right-topic",
            "/stereo/right/image_raw",
            "--no-progress",
        ],
    )
    assert result.exit_code == 2 and "not images" in result.output


def test_three_image_topics_without_names_ask_for_the_topic_options(tmp_path):
    from mcap_ros2.writer import Writer

    bag = tmp_path / "three.mcap"
    img = np.zeros((4, 4), np.uint8)
    with open(bag, "wb") as fh:
        writer = Writer(fh)
        schema = writer.register_msgdef("sensor_msgs/msg/Image", IMAGE_DEF)
        for topic in ("/a", "/b", "/c"):
            writer.write_message(
                topic,
                schema,
                {
                    "header": _header(T0_NS),
                    "height": 4,
                    "width": 4,
                    "encoding": "mono8",
                    "is_bigendian": 0,
                    "step": 4,
                    "data": img.tobytes(),
                },
                log_time=T0_NS,
            )
        writer.finish()
    with BagReader(bag) as reader, pytest.raises(InputError, match="--left-topic T --right-topic T"):
        reader.choose_topics()
    with BagReader(bag) as reader:
        assert reader.choose_topics("/a", "/c").right == "/c"


def test_mismatched_sizes_or_encodings_of_the_two_topics_are_refused(tmp_path):
    from mcap_ros2.writer import Writer

    bag = tmp_path / "mismatch.mcap"
    with open(bag, "wb") as fh:
        writer = Writer(fh)
        schema = writer.register_msgdef("sensor_msgs/msg/Image", IMAGE_DEF)
        for i in range(2):
            for topic, (h, w), enc, step in (("/left", (4, 6), "mono8", 6), ("/right", (4, 6), "rgb8", 18)):
                writer.write_message(
                    topic,
                    schema,
                    {
                        "header": _header(T0_NS + i),
                        "height": h,
                        "width": w,
                        "encoding": enc,
                        "is_bigendian": 0,
                        "step": step,
                        "data": bytes(step * h),
                    },
                    log_time=T0_NS + i,
                )
        writer.finish()
    result = runner.invoke(app, ["estimate", str(bag), "--config", str(_rig(tmp_path)), "--no-progress"])
    assert result.exit_code == 2
    assert "6x4 gray uint8" in result.output and "6x4 RGB uint8" in result.output


def test_a_foreign_bag_needs_a_config(tmp_path):
    bag = tmp_path / "other.mcap"
    _write_mcap_ros2(bag, _images(2))
    result = runner.invoke(app, ["estimate", str(bag), "--no-progress"])
    assert result.exit_code == 2 and "--config RIG.toml" in result.output


# ------------------------------------------------------------------------------ softjig's own bags


@pytest.fixture(scope="module")
def sweep(tmp_path_factory):
    out = tmp_path_factory.mktemp("rosbag") / "sweep"
    specs = list(paper_sweep(diameters_mm=(50,), alphas_deg=(10,), theta_step_deg=90))
    simulate_dataset(out, specs, default_jig(), seed=4, workers=1, progress=False)
    return Dataset.open(out)


@pytest.fixture(scope="module")
def sweep_bag(sweep, tmp_path_factory):
    out = tmp_path_factory.mktemp("rosbag") / "sweep_bag"
    summary = dataset_to_bag(sweep, out, start_unix_s=1_700_000_000.0)
    assert (summary.n_frames, summary.n_estimated, summary.n_failed) == (5, 4, 0)
    return out


def test_our_bag_reads_with_mcap_ros2_support(sweep, sweep_bag):
    """The other library (mcap + mcap-ros2-support's decoder) reads every message of our bag."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    mcap_file = next(sweep_bag.glob("*.mcap"))
    with open(mcap_file, "rb") as fh:
        reader = make_reader(fh, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
        assert summary is not None and summary.chunk_indexes  # chunked, summary written
        assert {c.compression for c in summary.chunk_indexes} == {"zstd"}
        by_topic = {}
        for schema, channel, message, decoded in reader.iter_decoded_messages():
            by_topic.setdefault(channel.topic, []).append((schema.name, channel, message, decoded))
    types = {t: v[0][0] for t, v in by_topic.items()}
    assert types[TOPIC_LEFT] == types[TOPIC_RIGHT] == "sensor_msgs/msg/Image"
    assert types["/softjig/left/camera_info"] == "sensor_msgs/msg/CameraInfo"
    assert types[TOPIC_PART_POSE] == "geometry_msgs/msg/PoseStamped"
    assert types[TOPIC_NORMAL] == "geometry_msgs/msg/Vector3Stamped"
    assert types[TOPIC_MARKERS] == "sensor_msgs/msg/PointCloud2"
    assert types["/tf_static"] == "tf2_msgs/msg/TFMessage"
    assert len(by_topic[TOPIC_LEFT]) == 5 and len(by_topic[TOPIC_PART_POSE]) == 4
    # images byte for byte
    frame0 = sweep[1]
    img = by_topic[TOPIC_LEFT][1][3]
    assert img.encoding == "mono8" and (img.height, img.width) == frame0.load_left().shape
    np.testing.assert_array_equal(
        np.frombuffer(bytes(img.data), np.uint8).reshape(img.height, img.width), frame0.load_left()
    )
    # camera_info: K, and the baseline in the right camera's P (Tx = -fx B, metres)
    jig = sweep.jig
    info_r = by_topic["/softjig/right/camera_info"][0][3]
    assert np.allclose(list(info_r.k), jig.cameras.right.K.ravel())
    assert info_r.p[3] == pytest.approx(-jig.cameras.right.fx_px * jig.cameras.baseline_mm / 1000.0)
    assert by_topic["/softjig/left/camera_info"][0][3].p[3] == 0.0
    # /tf_static: the cameras in the jig frame (metres), transient local in the channel's QoS
    _, tf_channel, _, tf = by_topic["/tf_static"][0]
    assert {t.child_frame_id for t in tf.transforms} == {"softjig_left_optical", "softjig_right_optical"}
    left_tf = next(t for t in tf.transforms if t.child_frame_id == "softjig_left_optical")
    assert left_tf.header.frame_id == "softjig_jig"
    assert left_tf.transform.translation.x == pytest.approx(jig.cameras.left.position_mm[0] / 1000.0)
    assert left_tf.transform.translation.z == pytest.approx(jig.cameras.left.position_mm[2] / 1000.0)
    assert "durability: 1" in tf_channel.metadata["offered_qos_profiles"]  # 1: transient local
    assert "durability: 2" in by_topic[TOPIC_LEFT][0][1].metadata["offered_qos_profiles"]  # 2: volatile
    # the estimate as ROS messages: metres, jig frame, orientation taking +z to the normal
    estimates = [json.loads(d.data) for *_, d in by_topic["/softjig/estimate"]]
    for (_, _, _, pose), (_, _, _, normal), est in zip(
        by_topic[TOPIC_PART_POSE], by_topic[TOPIC_NORMAL], estimates, strict=True
    ):
        assert pose.header.frame_id == normal.header.frame_id == "softjig_jig"
        n = np.array([normal.vector.x, normal.vector.y, normal.vector.z])
        np.testing.assert_allclose(n, est["normal"])
        q = pose.pose.orientation
        from scipy.spatial.transform import Rotation

        np.testing.assert_allclose(Rotation.from_quat([q.x, q.y, q.z, q.w]).apply([0, 0, 1]), n, atol=1e-12)
        cx, cy = est["part_centre_xy_mm"] or est["contact_centroid_xy_mm"]
        assert (pose.pose.position.x, pose.pose.position.y) == pytest.approx((cx / 1000.0, cy / 1000.0))
        assert 0.0 < pose.pose.position.z < 0.04  # the face is on the membrane, tens of mm above the plate
    cloud = by_topic[TOPIC_MARKERS][0][3]
    assert [f.name for f in cloud.fields] == ["x", "y", "z"] and cloud.point_step == 12
    xyz = np.frombuffer(bytes(cloud.data), "<f4").reshape(-1, 3)
    assert len(xyz) == cloud.width > 10 and np.all(np.abs(xyz) < 0.2)  # metres


def test_metadata_yaml_is_a_rosbag2_one_with_transient_local_tf_static(sweep_bag):
    from ruamel.yaml import YAML

    info = YAML(typ="safe").load((sweep_bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert info["storage_identifier"] == "mcap" and info["relative_file_paths"] == ["sweep_bag_0.mcap"]
    topics = {t["topic_metadata"]["name"]: t for t in info["topics_with_message_count"]}
    assert topics[TOPIC_LEFT]["message_count"] == 5
    assert sum(t["message_count"] for t in topics.values()) == info["message_count"]
    qos = YAML(typ="safe").load(topics["/tf_static"]["topic_metadata"]["offered_qos_profiles"])
    assert qos[0]["durability"] == 1 and qos[0]["reliability"] == 1


def test_estimating_our_bag_equals_estimating_the_dataset(sweep, sweep_bag, tmp_path):
    ds_out, bag_out = tmp_path / "ds.jsonl", tmp_path / "bag.jsonl"
    r1 = runner.invoke(
        app, ["estimate", str(sweep.root), "--out", str(ds_out), "--workers", "1", "--no-progress"]
    )
    r2 = runner.invoke(  # two workers: the pairs travel to forked workers
        app, ["estimate", str(sweep_bag), "--out", str(bag_out), "--workers", "2", "--no-progress"]
    )
    assert r1.exit_code == 0, r1.output
    assert r2.exit_code == 0, r2.output
    assert "softjig's own topics" in r2.output  # says which topics it read
    rows_ds = [json.loads(line) for line in ds_out.read_text().splitlines()]
    rows_bag = [json.loads(line) for line in bag_out.read_text().splitlines()]
    assert len(rows_bag) == len(rows_ds) == 5
    for a, b in zip(rows_ds, rows_bag, strict=True):
        assert b["stamp_left_ns"] >= 1_700_000_000 * 10**9
        assert {k: v for k, v in b.items() if not k.startswith("stamp_")} == a
    assert rows_bag[0] == {
        "index": 0,
        "reference": True,
        **{k: rows_bag[0][k] for k in ("stamp_left_ns", "stamp_right_ns")},
    }
    assert rows_ds[1]["indentation_reference"] == "reference frame"


def test_estimating_the_bags_mcap_file_alone_equals_the_folder(sweep_bag, tmp_path):
    out = tmp_path / "file.jsonl"
    mcap_file = next(sweep_bag.glob("*.mcap"))
    folder = tmp_path / "folder.jsonl"
    for source, target in ((mcap_file, out), (sweep_bag, folder)):
        result = runner.invoke(
            app, ["estimate", str(source), "--out", str(target), "--workers", "1", "--no-progress"]
        )
        assert result.exit_code == 0, result.output
    rows = [json.loads(line) for line in out.read_text().splitlines()]
    assert len(rows) == 5 and rows == [json.loads(line) for line in folder.read_text().splitlines()]


def test_convert_round_trip_bag_to_dataset_keeps_images_parts_and_reference(sweep, sweep_bag, tmp_path):
    back = tmp_path / "back"
    result = runner.invoke(app, ["convert", str(sweep_bag), str(back), "--no-progress"])
    assert result.exit_code == 0, result.output
    again = Dataset.open(back)
    assert len(again) == len(sweep)
    for a, b in zip(sweep, again, strict=True):
        np.testing.assert_array_equal(a.load_left(), b.load_left())
        np.testing.assert_array_equal(a.load_right(), b.load_right())
        assert (a.reference, a.part, a.alpha_deg, a.theta_deg) == (
            b.reference,
            b.part,
            b.alpha_deg,
            b.theta_deg,
        )
        assert b.meta["source_index"] == a.index
    assert again[2].time_s == pytest.approx(2 / 30.0, abs=1e-6)
    assert again.jig == sweep.jig


def test_the_writer_refuses_to_replace_what_is_not_a_bag(tmp_path):
    keep = tmp_path / "notes"
    keep.mkdir()
    (keep / "thesis.tex").write_text("precious")
    with pytest.raises(InputError, match="not a bag"):
        BagWriter(keep, default_jig(), overwrite=True).open()
    assert (keep / "thesis.tex").read_text() == "precious"
    result = runner.invoke(app, ["convert", str(tmp_path / "missing"), str(tmp_path / "o")])
    assert result.exit_code == 2


def test_rotation_z_to_takes_z_to_the_normal():
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(3)
    for n in [*rng.normal(size=(20, 3)), np.array([0, 0, 1.0]), np.array([0, 0, -1.0])]:
        n = n / np.linalg.norm(n)
        np.testing.assert_allclose(Rotation.from_quat(rotation_z_to(n)).apply([0, 0, 1]), n, atol=1e-12)


# --------------------------------------------------------------------------------- crash safety

RECORDER = textwrap.dedent(
    """
    import sys, numpy as np
    from softjig.config import default_jig
    from softjig.io.rosbag import BagWriter
    rng = np.random.default_rng(0)
    writer = BagWriter(sys.argv[1], default_jig(), chunk_bytes=20_000).open()
    i = 0
    while True:
        a = rng.integers(0, 256, (48, 64), dtype=np.uint8)
        writer.add_pair(a, 255 - a, 1_700_000_000 * 10**9 + i * 33_333_333, meta={"index": i})
        i += 1
        if i == 40:
            print("written", flush=True)
    """
)


def test_a_recorder_killed_mid_write_leaves_a_bag_that_reads_and_repairs(tmp_path):
    bag = tmp_path / "killed"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    proc = subprocess.Popen([sys.executable, "-c", RECORDER, str(bag)], stdout=subprocess.PIPE, env=env)
    try:
        line = proc.stdout.readline()
        assert line.strip() == b"written"
        time.sleep(0.05)
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=30)
    assert (bag / "metadata.yaml").is_file()
    # rosbags alone cannot read it (no summary, no footer) ...
    from rosbags.highlevel import AnyReader

    with pytest.raises(Exception), AnyReader([bag]) as r:  # noqa: B017
        list(r.messages())
    # ... ours reads every complete chunk, and says so
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        with BagReader(bag) as reader:
            assert reader.truncated
            pairs = list(reader.pairs(reader.choose_topics()))
    assert any(issubclass(w.category, BagTruncationWarning) for w in caught)
    assert len(pairs) >= 40
    assert [p.index for p in pairs] == list(range(len(pairs)))  # complete, in order, none lost before the cut
    for p in pairs:
        np.testing.assert_array_equal(p.right, 255 - p.left)
    # estimating it reads every complete pair too, says the bag is truncated and how to repair it
    rows = tmp_path / "killed.jsonl"
    result = runner.invoke(app, ["estimate", str(bag), "--out", str(rows), "--workers", "1", "--no-progress"])
    assert "truncated" in result.output and "--repair" in result.output, result.output
    assert result.exit_code == 3  # noise of the wrong size gives no estimate; every pair has its row
    assert len(rows.read_text().splitlines()) == len(pairs)
    # the repaired copy reads with rosbags (what ROS 2 tools read), with the same pairs; the original stays
    size = next(bag.glob("*.mcap")).stat().st_size
    fixed = tmp_path / "fixed"
    result = runner.invoke(app, ["convert", str(bag), str(fixed), "--repair"])
    assert result.exit_code == 0, result.output
    assert next(bag.glob("*.mcap")).stat().st_size == size
    with AnyReader([fixed]) as r:
        n_left = sum(1 for c, _, _ in r.messages() if c.topic == TOPIC_LEFT)
    assert n_left == len(pairs)
    with BagReader(fixed) as reader:
        assert not reader.truncated
        assert len(list(reader.pairs(reader.choose_topics()))) == len(pairs)


def test_a_truncated_file_that_is_not_mcap_is_a_clear_error(tmp_path):
    bag = tmp_path / "junk.mcap"
    bag.write_bytes(b"not a bag at all")
    result = runner.invoke(app, ["estimate", str(bag), "--config", str(_rig(tmp_path)), "--no-progress"])
    assert result.exit_code == 2 and "cannot read bag" in result.output


def test_live_record_bag_records_every_pair_and_estimate_and_estimates_like_the_dataset(sweep, tmp_path):
    bag, rows_bag, rows_ds = tmp_path / "live_bag", tmp_path / "bag.jsonl", tmp_path / "ds.jsonl"
    result = runner.invoke(
        app,
        [
            "live",
            "--replay",
            str(sweep.root),
            "--rate",
            "fast",
            "--record-bag",
            str(bag),
            "--method",
            "refractive",
        ],
    )
    assert result.exit_code == 0, result.output
    assert "5 recorded to" in result.output
    with BagReader(bag) as reader:
        assert not reader.truncated
        assert reader.topics[TOPIC_LEFT][1] == 5
        assert reader.topics[TOPIC_PART_POSE][1] == 4  # the reference frame has no part: no estimate
        stamps = [p.stamp_left_ns for p in reader.pairs(reader.choose_topics())]
    assert stamps == sorted(stamps) and stamps[0] > 1_600_000_000 * 10**9  # wall-clock stamps
    r1 = runner.invoke(app, ["estimate", str(bag), "--out", str(rows_bag), "--workers", "1", "--no-progress"])
    r2 = runner.invoke(
        app, ["estimate", str(sweep.root), "--out", str(rows_ds), "--workers", "1", "--no-progress"]
    )
    assert r1.exit_code == 0 and r2.exit_code == 0, r1.output + r2.output
    a = [json.loads(line) for line in rows_ds.read_text().splitlines()]
    b = [
        {k: v for k, v in json.loads(line).items() if not k.startswith("stamp_")}
        for line in rows_bag.read_text().splitlines()
    ]
    assert a == b
    both = runner.invoke(
        app,
        [
            "live",
            "--replay",
            str(sweep.root),
            "--record",
            str(tmp_path / "d"),
            "--record-bag",
            str(tmp_path / "b"),
        ],
    )
    assert both.exit_code == 2 and "not both" in both.output


def test_without_the_ros_extra_the_commands_say_how_to_install_it(tmp_path, monkeypatch):
    bag = tmp_path / "other.mcap"
    _write_mcap_ros2(bag, _images(2))
    monkeypatch.setitem(sys.modules, "rosbags.highlevel", None)  # as if rosbags were not installed
    result = runner.invoke(app, ["estimate", str(bag), "--config", str(_rig(tmp_path)), "--no-progress"])
    assert result.exit_code == 2
    assert "pip install 'softjig[ros]'" in result.output and "Traceback" not in result.output


def test_estimate_bag_refuses_to_write_over_the_bag_and_exits_3_when_nothing_estimates(sweep_bag, tmp_path):
    meta = sweep_bag / "metadata.yaml"
    before = meta.read_bytes()
    result = runner.invoke(app, ["estimate", str(sweep_bag), "--out", str(meta), "--no-progress"])
    assert result.exit_code == 2 and meta.read_bytes() == before
    # a foreign bag of noise: every pair is read, none gives an estimate -> exit 3, every error written
    bag, out = tmp_path / "noise.mcap", tmp_path / "noise.jsonl"
    _write_mcap_ros2(bag, _images(3, shape=(720, 1280)))
    result = runner.invoke(
        app,
        [
            "estimate",
            str(bag),
            "--config",
            str(_rig(tmp_path)),
            "--out",
            str(out),
            "--workers",
            "1",
            "--no-progress",
        ],
    )
    assert result.exit_code == 3, result.output
    rows = [json.loads(line) for line in out.read_text().splitlines()]
    assert len(rows) == 3 and all("error" in r and "stamp_left_ns" in r for r in rows)


def test_the_commands_stamp_tolerance_default_is_the_readers():
    """cli.options keeps its own copy of the default (it must not import the bag reader): the same value."""
    from softjig.cli.options import DEFAULT_STAMP_TOLERANCE_S as cli_default
    from softjig.io.rosbag import DEFAULT_STAMP_TOLERANCE_S as reader_default

    assert cli_default == reader_default
