"""`softjig convert`: dataset to bag and back, what it refuses, and that it never loses or replaces data."""

from __future__ import annotations

import numpy as np
import pytest
from typer.testing import CliRunner

from softjig.cli import app
from softjig.config import default_jig, save_jig
from softjig.io.dataset import Dataset
from softjig.io.rosbag import TOPIC_LEFT, TOPIC_PART_POSE, BagReader
from softjig.io.simulated import simulate_dataset
from softjig.sim.scenarios import paper_sweep

runner = CliRunner()

IMAGE_DEF = (
    "std_msgs/Header header\nuint32 height\nuint32 width\nstring encoding\nuint8 is_bigendian\n"
    "uint32 step\nuint8[] data\n" + "=" * 80 + "\nMSG: std_msgs/Header\nbuiltin_interfaces/Time stamp\n"
    "string frame_id\n" + "=" * 80 + "\nMSG: builtin_interfaces/Time\nint32 sec\nuint32 nanosec\n"
)


@pytest.fixture(scope="module")
def sweep(tmp_path_factory):
    out = tmp_path_factory.mktemp("convert") / "sweep"
    specs = list(paper_sweep(diameters_mm=(50,), alphas_deg=(10,), theta_step_deg=180))
    simulate_dataset(out, specs, default_jig(), seed=2, workers=1, progress=False)
    return Dataset.open(out)


def _foreign_bag(path, n=3, shape=(720, 1280)):
    """A .mcap written by mcap-ros2-support: mono16 pairs, no softjig topics."""
    from mcap_ros2.writer import Writer

    rng = np.random.default_rng(0)
    pairs = []
    with open(path, "wb") as fh:
        writer = Writer(fh)
        schema = writer.register_msgdef("sensor_msgs/msg/Image", IMAGE_DEF)
        for i in range(n):
            stamp = 1_700_000_000 * 10**9 + i * 50_000_000
            pair = [rng.integers(0, 4096, shape, dtype=np.uint16) for _ in range(2)]
            pairs.append(pair)
            for topic, img in zip(("/left/image", "/right/image"), pair, strict=True):
                header = {"stamp": {"sec": stamp // 10**9, "nanosec": stamp % 10**9}, "frame_id": "c"}
                msg = {
                    "header": header,
                    "height": shape[0],
                    "width": shape[1],
                    "encoding": "mono16",
                    "is_bigendian": 0,
                    "step": 2 * shape[1],
                    "data": img.astype("<u2").tobytes(),
                }
                writer.write_message(topic, schema, msg, log_time=stamp)
        writer.finish()
    return pairs


def test_no_estimate_writes_the_images_only(sweep, tmp_path):
    out = tmp_path / "bag"
    result = runner.invoke(app, ["convert", str(sweep.root), str(out), "--no-estimate", "--no-progress"])
    assert result.exit_code == 0, result.output
    with BagReader(out) as reader:
        assert reader.topics[TOPIC_LEFT][1] == len(sweep)
        assert TOPIC_PART_POSE not in reader.topics


def test_a_foreign_bag_to_a_dataset_needs_a_rig_and_leaves_nothing_behind_without_one(tmp_path):
    bag = tmp_path / "other.mcap"
    pairs = _foreign_bag(bag)
    out = tmp_path / "ds"
    result = runner.invoke(app, ["convert", str(bag), str(out), "--no-progress"])
    assert result.exit_code == 2 and "--config RIG.toml" in result.output
    assert not out.exists()
    rig = tmp_path / "rig.toml"
    save_jig(default_jig(), rig)
    result = runner.invoke(app, ["convert", str(bag), str(out), "--config", str(rig), "--no-progress"])
    assert result.exit_code == 0, result.output
    assert "/left/image and /right/image" in result.output
    ds = Dataset.open(out)
    assert [f.index for f in ds] == [0, 1, 2]
    for (left, right), frame in zip(pairs, ds, strict=True):
        np.testing.assert_array_equal(frame.load_left(), left)  # mono16 kept losslessly
        np.testing.assert_array_equal(frame.load_right(), right)
    assert ds[1].time_s == pytest.approx(0.05)
    assert ds[2].meta["stamp_left_ns"] == 1_700_000_000 * 10**9 + 100_000_000


def test_convert_never_replaces_its_input_nor_a_folder_that_is_not_its_own(sweep, tmp_path):
    result = runner.invoke(app, ["convert", str(sweep.root), str(sweep.root)])
    assert result.exit_code == 2 and "OUT must differ from SRC" in result.output
    other = tmp_path / "papers"
    other.mkdir()
    (other / "notes.txt").write_text("keep me")
    result = runner.invoke(app, ["convert", str(sweep.root), str(other), "--overwrite", "--no-progress"])
    assert result.exit_code == 2 and "not a bag" in result.output
    assert (other / "notes.txt").read_text() == "keep me"


def test_an_existing_bag_is_replaced_only_with_overwrite(sweep, tmp_path):
    out = tmp_path / "bag"
    args = ["convert", str(sweep.root), str(out), "--no-estimate", "--no-progress"]
    assert runner.invoke(app, args).exit_code == 0
    again = runner.invoke(app, args)
    assert again.exit_code == 2 and "--overwrite" in again.output
    assert runner.invoke(app, [*args, "--overwrite"]).exit_code == 0


def test_options_of_the_other_direction_are_refused(sweep, tmp_path):
    result = runner.invoke(app, ["convert", str(sweep.root), str(tmp_path / "b"), "--repair"])
    assert result.exit_code == 2 and "--repair applies to a ROS 2 bag" in result.output
    result = runner.invoke(app, ["convert", str(sweep.root), str(tmp_path / "b"), "--left-topic", "/x"])
    assert result.exit_code == 2 and "apply to a bag" in result.output


def test_bag_to_dataset_to_bag_keeps_every_stamp(tmp_path):
    from softjig.io.bag_convert import bag_to_dataset, dataset_to_bag

    bag = tmp_path / "other.mcap"
    _foreign_bag(bag, n=3, shape=(24, 32))
    with BagReader(bag) as reader:
        first = [(p.stamp_left_ns, p.stamp_right_ns) for p in reader.pairs(reader.choose_topics())]
    bag_to_dataset(bag, tmp_path / "ds", jig=default_jig())
    dataset_to_bag(tmp_path / "ds", tmp_path / "again", estimate=False)
    with BagReader(tmp_path / "again") as reader:
        again = [(p.stamp_left_ns, p.stamp_right_ns) for p in reader.pairs(reader.choose_topics())]
    assert again == first


def test_dataset_to_bag_takes_the_zstd_level(sweep, tmp_path):
    """A negative level stores the images nearly as they are: a larger bag with the same pairs."""
    from softjig.io.bag_convert import dataset_to_bag

    sizes, images = {}, {}
    for level in (1, -1):
        out = tmp_path / f"level{level}"
        dataset_to_bag(sweep, out, estimate=False, start_unix_s=1.7e9, zstd_level=level)
        sizes[level] = sum(p.stat().st_size for p in out.glob("*.mcap"))
        with BagReader(out) as reader:
            images[level] = [(p.left.copy(), p.right.copy()) for p in reader.pairs(reader.choose_topics())]
    assert sizes[-1] > 1.3 * sizes[1]
    assert len(images[1]) == len(sweep)
    for (l1, r1), (l2, r2) in zip(images[1], images[-1], strict=True):
        assert np.array_equal(l1, l2) and np.array_equal(r1, r2)
