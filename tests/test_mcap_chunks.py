"""softjig's chunked MCAP writer: the file mcap's own Writer writes, with zstd level 1 chunks."""

from __future__ import annotations

import io

import numpy as np
import pytest

pytest.importorskip("mcap")
zstandard = pytest.importorskip("zstandard")

from softjig.config import default_jig  # noqa: E402
from softjig.io.mcap_chunks import ZSTD_LEVEL, ChunkWriter  # noqa: E402
from softjig.io.rosbag import BagWriter  # noqa: E402


def _write(writer, rng):
    """The same calls to either writer: schemas, channels, metadata, messages over several chunks."""
    writer.start(profile="ros2", library="test")
    writer.add_metadata("softjig", {"provenance": "simulation"})
    image = writer.register_schema("sensor_msgs/msg/Image", "ros2msg", b"uint8[] data")
    text = writer.register_schema("std_msgs/msg/String", "ros2msg", b"string data")
    left = writer.register_channel(topic="/l", message_encoding="cdr", schema_id=image, metadata={"q": "1"})
    words = writer.register_channel(topic="/s", message_encoding="cdr", schema_id=text, metadata={})
    for i in range(9):
        data = rng.integers(0, 40, 3000, dtype=np.uint8).tobytes()
        writer.add_message(channel_id=left, log_time=1000 + 10 * i, data=data, publish_time=1000 + 10 * i)
        writer.add_message(channel_id=words, log_time=1005 + 10 * i, data=b"hi %d" % i, publish_time=7)
    late = writer.register_channel(topic="/late", message_encoding="cdr", schema_id=text, metadata={})
    writer.add_message(channel_id=late, log_time=5, data=b"early stamp", publish_time=5, sequence=3)
    writer.finish()


def test_at_level_3_it_writes_mcaps_own_writers_file_byte_for_byte():
    """Same records, same chunking, same indexes, summary, CRCs and footer as mcap's Writer (whose zstd
    level is 3): only the level differs in softjig's bags."""
    from mcap.writer import CompressionType, Writer

    ours, theirs = io.BytesIO(), io.BytesIO()
    _write(ChunkWriter(ours, chunk_bytes=7000, level=3), np.random.default_rng(1))
    _write(Writer(theirs, chunk_size=7000, compression=CompressionType.ZSTD), np.random.default_rng(1))
    assert len(ours.getvalue()) > 20_000
    assert ours.getvalue() == theirs.getvalue()


def test_its_files_read_and_validate_with_mcap_and_its_chunks_are_zstd_level_1():
    from mcap.reader import make_reader
    from mcap.records import Chunk
    from mcap.stream_reader import StreamReader

    out = io.BytesIO()
    _write(ChunkWriter(out, chunk_bytes=7000), np.random.default_rng(2))
    data = out.getvalue()
    # every CRC (chunks, summary) checked, every record parsed in file order
    records = list(StreamReader(io.BytesIO(data), validate_crcs=True).records)
    assert sum(type(r).__name__ == "Message" for r in records) == 19
    reader = make_reader(io.BytesIO(data), validate_crcs=True)
    summary = reader.get_summary()
    assert summary is not None and summary.statistics.message_count == 19
    assert summary.statistics.channel_message_counts == {1: 9, 2: 9, 3: 1}
    assert len(summary.chunk_indexes) == summary.statistics.chunk_count >= 3
    assert [m.log_time for _, _, m in reader.iter_messages(log_time_order=True)][:2] == [5, 1000]
    assert [m.name for m in reader.iter_metadata()] == ["softjig"]
    chunks = [r for r in StreamReader(io.BytesIO(data), emit_chunks=True).records if isinstance(r, Chunk)]
    assert ZSTD_LEVEL == 1 and chunks and {c.compression for c in chunks} == {"zstd"}
    for chunk in chunks:  # zstd is deterministic: the stored bytes are level 1's
        raw = zstandard.decompress(chunk.data, chunk.uncompressed_size)
        assert chunk.data == zstandard.ZstdCompressor(level=ZSTD_LEVEL).compress(raw)


def test_a_bag_writers_chunks_are_level_1(tmp_path):
    """BagWriter goes through ChunkWriter (mcap's Writer would leave level 3 chunks)."""
    from mcap.records import Chunk
    from mcap.stream_reader import StreamReader

    rng = np.random.default_rng(3)
    with BagWriter(tmp_path / "bag", default_jig(), chunk_bytes=50_000) as writer:
        for i in range(3):
            pair = [rng.integers(0, 50, (120, 160), dtype=np.uint8) for _ in range(2)]
            writer.add_pair(*pair, 1_700_000_000_000_000_000 + i * 33_000_000)
    with open(writer.mcap_path, "rb") as fh:
        chunks = [r for r in StreamReader(fh, emit_chunks=True).records if isinstance(r, Chunk)]
    assert len(chunks) >= 2
    for chunk in chunks:
        raw = zstandard.decompress(chunk.data, chunk.uncompressed_size)
        assert chunk.data == zstandard.ZstdCompressor(level=1).compress(raw)


def _pairs_bag(path, n=3, shape=(120, 160), **options):
    rng = np.random.default_rng(4)
    part = {"kind": "cylinder", "diameter_mm": 50.0}
    with BagWriter(path, default_jig(), **options) as writer:
        for i in range(n):
            pair = [rng.integers(0, 50, shape, dtype=np.uint8) for _ in range(2)]
            meta = {"index": i, "part": part, "reference": i == 0}
            writer.add_pair(*pair, 1_700_000_000_000_000_000 + i * 33_000_000, meta=meta)
    return writer


def test_the_zstd_level_is_an_option_and_a_bad_one_is_refused_before_any_file(tmp_path):
    from mcap.records import Chunk
    from mcap.stream_reader import StreamReader

    from softjig.errors import InputError

    writer = _pairs_bag(tmp_path / "fast", zstd_level=-1)
    with open(writer.mcap_path, "rb") as fh:
        chunks = [r for r in StreamReader(fh, emit_chunks=True).records if isinstance(r, Chunk)]
    raw = zstandard.decompress(chunks[0].data, chunks[0].uncompressed_size)
    assert chunks[0].data == zstandard.ZstdCompressor(level=-1).compress(raw)
    for bad in (23, -8, 1.5, True, "1"):
        with pytest.raises(InputError, match="zstd level"):
            BagWriter(tmp_path / f"bad{bad}", default_jig(), zstd_level=bad)
        assert not (tmp_path / f"bad{bad}").exists()
    with pytest.raises(InputError, match="chunk size"):
        BagWriter(tmp_path / "bad", default_jig(), chunk_bytes=0)


def test_a_1280x720_pair_is_one_chunk(tmp_path):
    """The default chunk closes with the pair's right image: a killed recorder loses at most one pair, and
    a reader decompresses one pair at a time."""
    from mcap.records import Chunk
    from mcap.stream_reader import StreamReader

    writer = _pairs_bag(tmp_path / "bag", n=3, shape=(720, 1280))
    with open(writer.mcap_path, "rb") as fh:
        chunks = [r for r in StreamReader(fh, emit_chunks=True).records if isinstance(r, Chunk)]
    assert len(chunks) == 3
    assert all(2 * 1280 * 720 < c.uncompressed_size < 2 * 1280 * 720 + 20_000 for c in chunks)


def test_a_stream_parses_each_distinct_part_once(tmp_path, monkeypatch):
    """A recording's frames name the same part: parsing it (a pydantic adapter, ~0.5 ms) once a stream."""
    import softjig.config
    from softjig.io.rosbag import BagReader

    writer = _pairs_bag(tmp_path / "bag", n=4)
    calls = []
    parse = softjig.config.part_from_dict
    monkeypatch.setattr(softjig.config, "part_from_dict", lambda obj: calls.append(obj) or parse(obj))
    with BagReader(writer.root) as reader:
        pairs = list(reader.pairs(reader.choose_topics()))
    assert [p.index for p in pairs] == [0, 1, 2, 3] and [p.reference for p in pairs] == [True] + [False] * 3
    assert len(calls) == 1
    assert all(p.part == parse({"kind": "cylinder", "diameter_mm": 50.0}) for p in pairs)
