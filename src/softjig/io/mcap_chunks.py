"""A chunked MCAP writer with the zstd level softjig chooses, for :class:`~softjig.io.rosbag.BagWriter`.

The mcap library's ``Writer`` compresses every chunk at zstd's default level 3 and takes no level. For
1280x720 camera images (noise-like pixels, whose only redundancy is their entropy) level 1 compresses as
well or better (the images' literals carry the ratio, not the matches), compresses several times faster
(a recorder's CPU) and decompresses about twice as fast (what a bag's reader spends a frame; the figures
are in ``benchmarks/RESULTS.md``). :class:`ChunkWriter` writes the same file the mcap ``Writer`` writes
with its defaults (chunked, message indexes, chunk CRCs, the summary with schemas, channels, statistics,
chunk, attachment and metadata indexes and summary offsets, the footer), from the mcap library's own
record classes, so every MCAP reader reads it; only the chunks' zstd level differs (at ``level=3`` the
two files are byte for byte the same, ``tests/test_rosbag.py``).

Crash safety is the caller's: a chunk is written whole to the stream once its uncompressed records
reach ``chunk_bytes`` (or at :meth:`ChunkWriter.flush_chunk` and :meth:`ChunkWriter.finish`); a file
cut after any complete chunk reads up to it.
"""

from __future__ import annotations

import struct
import zlib
from collections import defaultdict
from typing import IO, Any

from softjig.errors import InputError

__all__ = ["ZSTD_LEVEL", "ChunkWriter", "check_options"]

#: The zstd level of softjig's chunks (see the module docstring).
ZSTD_LEVEL = 1
_MAGIC = b"\x89MCAP0\r\n"  # the MCAP specification's, at both ends of the file


def check_options(chunk_bytes: Any, level: Any) -> None:
    """Raise :class:`~softjig.errors.InputError` unless ``chunk_bytes`` is a positive integer and
    ``level`` an integer zstd level from -7 to 22 (zstd's fast levels to its strongest)."""
    if isinstance(level, bool) or not isinstance(level, int) or not -7 <= level <= 22:
        raise InputError(f"the bag's zstd level must be an integer from -7 to 22, got {level!r}")
    if isinstance(chunk_bytes, bool) or not isinstance(chunk_bytes, int) or chunk_bytes < 1:
        raise InputError(f"the bag's chunk size must be a positive number of bytes, got {chunk_bytes!r}")


class ChunkWriter:
    """Write an MCAP file of zstd chunks (the subset of mcap's ``Writer`` API that softjig uses).

    Parameters
    ----------
    stream : a binary file open for writing (not closed here).
    chunk_bytes : uncompressed bytes of records after which a chunk is compressed and written.
    level : the zstd level of the chunks (-7 to 22: zstd's fast levels to its strongest).

    Raises
    ------
    InputError
        A level or chunk size out of range.

    Notes
    -----
    Not thread-safe: one thread writes.
    """

    def __init__(self, stream: IO[bytes], *, chunk_bytes: int, level: int = ZSTD_LEVEL) -> None:
        import zstandard
        from mcap.data_stream import RecordBuilder
        from mcap.records import Statistics

        check_options(chunk_bytes, level)
        self._stream = stream
        self._chunk_bytes = chunk_bytes
        self._compressor = zstandard.ZstdCompressor(level=level)
        self._out = RecordBuilder()  # top-level records on their way to the stream
        self._chunk = RecordBuilder()  # the chunk in progress, uncompressed
        self._chunk_times: tuple[int, int] | None = None  # its messages' (first, last) log times
        self._chunk_index: dict[int, list[tuple[int, int]]] = {}  # channel -> (log time, offset)
        self._schemas: dict[int, Any] = {}
        self._channels: dict[int, Any] = {}
        self._chunk_indexes: list[Any] = []
        self._metadata_indexes: list[Any] = []
        self._stats = Statistics(
            attachment_count=0,
            channel_count=0,
            channel_message_counts=defaultdict(int),
            chunk_count=0,
            message_count=0,
            message_end_time=0,
            message_start_time=0,
            metadata_count=0,
            schema_count=0,
        )

    # -- the data section
    def start(self, profile: str = "", library: str = "softjig") -> None:
        """The magic and the header record."""
        from mcap.records import Header

        self._stream.write(_MAGIC)
        Header(profile, library).write(self._out)
        self._flush()

    def register_schema(self, name: str, encoding: str, data: bytes) -> int:
        """A schema's id (from 1), its record written into the chunk in progress."""
        from mcap.records import Schema

        schema = Schema(id=len(self._schemas) + 1, data=data, encoding=encoding, name=name)
        self._schemas[schema.id] = schema
        self._stats.schema_count += 1
        schema.write(self._chunk)
        self._maybe_finish_chunk()
        return schema.id

    def register_channel(
        self, topic: str, message_encoding: str, schema_id: int, metadata: dict[str, str] | None = None
    ) -> int:
        """A channel's id (from 1), its record written into the chunk in progress."""
        from mcap.records import Channel

        channel = Channel(
            id=len(self._channels) + 1,
            topic=topic,
            message_encoding=message_encoding,
            schema_id=schema_id,
            metadata=dict(metadata or {}),
        )
        self._channels[channel.id] = channel
        self._stats.channel_count += 1
        channel.write(self._chunk)
        self._maybe_finish_chunk()
        return channel.id

    def add_message(
        self, channel_id: int, log_time: int, data: bytes, publish_time: int, sequence: int = 0
    ) -> None:
        """Append a message to the chunk in progress (written out once the chunk is full)."""
        from mcap.records import Message

        stats = self._stats
        first = stats.message_count == 0
        stats.message_start_time = log_time if first else min(log_time, stats.message_start_time)
        stats.message_end_time = max(log_time, stats.message_end_time)
        stats.channel_message_counts[channel_id] += 1
        stats.message_count += 1
        t = self._chunk_times
        self._chunk_times = (log_time, log_time) if t is None else (min(t[0], log_time), max(t[1], log_time))
        self._chunk_index.setdefault(channel_id, []).append((log_time, self._chunk.count))
        Message(channel_id, log_time, data, publish_time, sequence).write(self._chunk)
        self._maybe_finish_chunk()

    def add_metadata(self, name: str, data: dict[str, str]) -> None:
        """A metadata record (outside chunks), indexed in the summary."""
        from mcap.records import Metadata, MetadataIndex

        self._flush()
        offset = self._stream.tell()
        self._stats.metadata_count += 1
        Metadata(name=name, metadata=data).write(self._out)
        self._metadata_indexes.append(MetadataIndex(offset=offset, length=self._out.count, name=name))
        self._flush()

    def flush_chunk(self) -> None:
        """Compress and write the chunk in progress, with its message indexes (nothing if it has no
        message: its schema and channel records wait for the next one)."""
        from mcap.records import Chunk, ChunkIndex, MessageIndex

        if self._chunk_times is None:
            return
        start, end = self._chunk_times
        records = self._chunk.end()
        compressed = self._compressor.compress(records)
        self._stats.chunk_count += 1
        chunk = Chunk(
            compression="zstd",
            data=compressed,
            message_start_time=start,
            message_end_time=end,
            uncompressed_crc=zlib.crc32(records),
            uncompressed_size=len(records),
        )
        self._flush()
        chunk_offset = self._stream.tell()
        chunk.write(self._out)
        index = ChunkIndex(
            message_start_time=start,
            message_end_time=end,
            chunk_start_offset=chunk_offset,
            chunk_length=self._out.count,
            message_index_offsets={},
            message_index_length=0,
            compression="zstd",
            compressed_size=len(compressed),
            uncompressed_size=len(records),
        )
        self._flush()
        index_offset = self._stream.tell()
        for channel_id, entries in self._chunk_index.items():
            index.message_index_offsets[channel_id] = index_offset + self._out.count
            MessageIndex(channel_id=channel_id, records=entries).write(self._out)
        index.message_index_length = self._out.count
        self._flush()
        self._chunk_indexes.append(index)
        self._chunk_times, self._chunk_index = None, {}

    # -- the summary
    def finish(self) -> None:
        """The last chunk, the data end, the summary, the footer and the closing magic (the stream is
        left open)."""
        from mcap.data_stream import RecordBuilder
        from mcap.opcode import Opcode
        from mcap.records import DataEnd, Footer, SummaryOffset

        self.flush_chunk()
        DataEnd(0).write(self._out)
        self._flush()
        summary_start = self._stream.tell()
        summary = RecordBuilder()
        offsets = []
        groups = (
            (Opcode.SCHEMA, list(self._schemas.values())),
            (Opcode.CHANNEL, list(self._channels.values())),
            (Opcode.STATISTICS, [self._stats]),
            (Opcode.CHUNK_INDEX, self._chunk_indexes),
            (Opcode.ATTACHMENT_INDEX, []),  # none: the empty group mcap's Writer writes too
            (Opcode.METADATA_INDEX, self._metadata_indexes),
        )
        for opcode, records in groups:
            group_start = summary.count
            for record in records:
                record.write(summary)
            offsets.append(SummaryOffset(opcode, summary_start + group_start, summary.count - group_start))
        summary_offset_start = summary_start + summary.count
        for offset in offsets:
            offset.write(summary)
        data = summary.end()
        footer_fields = struct.pack("<BQQQ", Opcode.FOOTER, 8 + 8 + 4, summary_start, summary_offset_start)
        crc = zlib.crc32(footer_fields, zlib.crc32(data))
        self._stream.write(data)
        Footer(summary_start=summary_start, summary_offset_start=summary_offset_start, summary_crc=crc).write(
            self._out
        )
        self._flush()
        self._stream.write(_MAGIC)

    # -- helpers
    def _maybe_finish_chunk(self) -> None:
        if self._chunk.count > self._chunk_bytes:
            self.flush_chunk()

    def _flush(self) -> None:
        self._stream.write(self._out.end())
