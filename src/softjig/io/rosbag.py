"""ROS 2 bags in and out: stereo pairs from any bag, and softjig's recordings as bags ``ros2 bag play`` plays.

Reading (:class:`BagReader`) goes through `rosbags <https://gitlab.com/ternaris/rosbags>`_ (pure Python:
rosbag2 folders with a ``metadata.yaml``, MCAP or SQLite storage, or a single ``.mcap`` file, with the
message definitions the bag carries), so a bag recorded by ``ros2 bag record`` or by any other tool reads
the same way; the messages of MCAP storage are then streamed by the mcap library (faster zstd, see
:meth:`BagReader._messages`) and deserialised by rosbags. Left and right images (``sensor_msgs/msg/Image``
in ``mono8``, ``mono16``, ``rgb8``, ``bgr8``; ``sensor_msgs/msg/CompressedImage`` in PNG or JPEG) are paired
by their header stamps within a tolerance (:class:`~softjig.io.cameras.FramePairer`).

Writing (:class:`BagWriter`) goes through the `mcap <https://mcap.dev>`_ library, which gives control over
the chunks (:class:`~softjig.io.mcap_chunks.ChunkWriter`, the mcap library's records at zstd level 1):
messages are CDR-serialised with the rosbags type store (ROS 2 Humble definitions, which later
distributions read), collected in chunks of :data:`CHUNK_BYTES`, each compressed with zstd and written
(and flushed) as soon as it is full; the summary and the footer are written at close. A bag
folder holds ``metadata.yaml`` (rosbag2 version 5, the newest Humble reads; written at open and again at
close) and ``NAME_0.mcap``.

**Crash safety.** A recorder killed at any moment leaves every chunk written before the kill intact; the
file lacks only its summary and footer. :class:`BagReader` then reads every complete chunk (with a
:class:`BagTruncationWarning`), and :func:`repair_bag` rewrites such a bag, up to its last complete chunk,
into a new bag folder that every ROS 2 tool reads (as ``ros2 bag reindex`` would), leaving the original
untouched.

**Overwriting.** A bag records where its pairs came from in an MCAP metadata record ``softjig``
(``provenance``: ``"simulation"`` for a bag converted from a simulated dataset, ``"recording"``
otherwise). ``--overwrite`` replaces only a bag of ``"simulation"`` provenance (:func:`is_simulated_bag`),
which can be made again; a recording (``live --record-bag``, a conversion of a recording, an older
softjig bag without the record) or a bag softjig did not write (``ros2 bag record``) is never deleted.

**What a softjig bag holds** (``DESIGN.md``'s command-line contract), all in SI units (REP 103):

- ``/softjig/left/image_raw``, ``/softjig/right/image_raw`` (``sensor_msgs/msg/Image``): the pair,
  losslessly (mono8, mono16 or rgb8);
- ``/softjig/left/camera_info``, ``/softjig/right/camera_info`` (``sensor_msgs/msg/CameraInfo``): the
  rig's K; for a rectified pair no distortion and ``P``'s ``Tx = -fx * baseline`` (m) on the right;
- ``/softjig/part_pose`` (``geometry_msgs/msg/PoseStamped``, frame ``softjig_jig``): the part's face
  point (m: the fitted plane under the part's centre) and the smallest rotation taking ``+z`` to the normal;
- ``/softjig/normal`` (``geometry_msgs/msg/Vector3Stamped``): the principal normal in the jig frame;
- ``/softjig/markers`` (``sensor_msgs/msg/PointCloud2``): the triangulated markers, x y z float32 (m);
- ``/softjig/estimate`` (``std_msgs/msg/String``): the estimate's JSON (the command-line contract's);
- ``/softjig/frame`` (``std_msgs/msg/String``): the frame's JSON (index, part, reference, truth, and
  ``stamp_ns``, the left image's stamp);
- ``/softjig/rig`` (``std_msgs/msg/String``): the nominal jig (``rig.toml``), once;
- ``/tf_static`` (``tf2_msgs/msg/TFMessage``): both cameras' optical frames in ``softjig_jig``, once.

``/tf_static`` and ``/softjig/rig`` are offered with transient-local durability (in ``metadata.yaml`` and
in each MCAP channel's ``offered_qos_profiles``), so a subscriber that joins after ``ros2 bag play``
started still gets them.
"""

from __future__ import annotations

import contextlib
import io
import json
import math
import os
import struct
import warnings
from collections import deque
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import cv2
import numpy as np

from softjig.errors import InputError
from softjig.io.dataset import json_default
from softjig.io.mcap_chunks import ZSTD_LEVEL

if TYPE_CHECKING:
    from softjig.config import JigConfig, Part

__all__ = [
    "CHUNK_BYTES",
    "FRAME_JIG",
    "IMAGE_TYPES",
    "TOPIC_ESTIMATE",
    "TOPIC_FRAME",
    "TOPIC_LEFT",
    "TOPIC_MARKERS",
    "TOPIC_NORMAL",
    "TOPIC_PART_POSE",
    "TOPIC_RIG",
    "TOPIC_RIGHT",
    "BagPair",
    "BagReader",
    "BagTopics",
    "BagTruncationWarning",
    "BagWriter",
    "decode_image_message",
    "is_bag",
    "is_simulated_bag",
    "repair_bag",
]

TOPIC_LEFT = "/softjig/left/image_raw"
TOPIC_RIGHT = "/softjig/right/image_raw"
TOPIC_LEFT_INFO = "/softjig/left/camera_info"
TOPIC_RIGHT_INFO = "/softjig/right/camera_info"
TOPIC_PART_POSE = "/softjig/part_pose"
TOPIC_NORMAL = "/softjig/normal"
TOPIC_MARKERS = "/softjig/markers"
TOPIC_ESTIMATE = "/softjig/estimate"
TOPIC_FRAME = "/softjig/frame"
TOPIC_RIG = "/softjig/rig"
TOPIC_TF_STATIC = "/tf_static"
FRAME_JIG = "softjig_jig"
FRAME_LEFT = "softjig_left_optical"
FRAME_RIGHT = "softjig_right_optical"

IMAGE = "sensor_msgs/msg/Image"
COMPRESSED_IMAGE = "sensor_msgs/msg/CompressedImage"
IMAGE_TYPES = (IMAGE, COMPRESSED_IMAGE)
#: Raw encodings read (``8UC1``/``16UC1``/``8UC3`` are read as mono8/mono16/bgr8, as cv_bridge does).
IMAGE_ENCODINGS = ("mono8", "mono16", "rgb8", "bgr8")
_ENCODING_ALIASES = {"8UC1": "mono8", "16UC1": "mono16", "8UC3": "bgr8"}

#: Uncompressed bytes collected before a chunk is compressed and written: a chunk closes with the message
#: that takes it past this, so a 1280x720 mono8 pair (1.8 MB) is one chunk. A killed recorder loses at most
#: the chunk in progress (one such pair), and a reader decompresses one pair at a time, whose bytes are
#: still in the CPU's caches when they are estimated (less CPU a frame than 4 MiB chunks of ~2.4 pairs).
CHUNK_BYTES = 2**20
#: rosbag2 metadata version written (Humble's; Iron, Jazzy and later read it too).
METADATA_VERSION = 5
MCAP_MAGIC = b"\x89MCAP0\r\n"
#: Default stereo pairing tolerance (s): half a frame period at 30 Hz.
DEFAULT_STAMP_TOLERANCE_S = 0.015

#: The MCAP metadata record of a bag's provenance (``{"provenance": "simulation" | "recording"}``).
PROVENANCE_RECORD = "softjig"
SIMULATION, RECORDING = "simulation", "recording"

_TRUNCATION_SIGNS = ("end magic", "footer", "summary", "truncat", "not enough data", "unexpected end")


class BagTruncationWarning(UserWarning):
    """A bag's MCAP file ends without its summary (a recorder killed mid-write): only its complete chunks
    were read."""


#: How to get what bags need, for the error when it is missing.
INSTALL_HINT = "ROS 2 bag support needs the ros extra: pip install 'softjig[ros]' (rosbags and mcap)"


def require_bag_support() -> None:
    """Raise an :class:`~softjig.errors.InputError` saying how to install rosbags and mcap if missing."""
    try:
        import mcap.records  # noqa: F401
        import rosbags.highlevel  # noqa: F401
        import zstandard  # noqa: F401
    except ImportError as exc:
        raise InputError(f"{INSTALL_HINT}; missing: {exc.name}") from None


def _typestore() -> Any:
    """The ROS 2 Humble message definitions (``rosbags``); one per reader or writer (60 ms to build)."""
    require_bag_support()
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_HUMBLE)


def is_bag(path: str | os.PathLike[str]) -> bool:
    """Whether ``path`` looks like a ROS 2 bag: an ``.mcap``/``.db3`` file, or a folder with a
    ``metadata.yaml`` (or, lacking one, holding ``.mcap`` files and no ``frames.jsonl``)."""
    path = Path(path)
    if path.is_file():
        return path.suffix.lower() in (".mcap", ".db3")
    if not path.is_dir():
        return False
    if (path / "metadata.yaml").is_file():
        return True
    return not (path / "frames.jsonl").exists() and any(path.glob("*.mcap"))


# ------------------------------------------------------------------------------------------- images


def _stamp_ns(header: Any) -> int:
    return int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)


def decode_image_message(msg: Any, msgtype: str, *, where: str = "image") -> np.ndarray:
    """A ``sensor_msgs`` image as softjig's images: ``uint8``/``uint16``, ``(H, W)`` gray or ``(H, W, 3)``
    RGB (``DESIGN.md`` §1).

    Parameters
    ----------
    msg : a deserialised ``sensor_msgs/msg/Image`` or ``sensor_msgs/msg/CompressedImage``.
    msgtype : its type name.
    where : names the message in error messages (topic and stamp).

    Raises
    ------
    InputError
        An encoding softjig does not read (the message names the ones it does), a size that does not fit
        the data, or compressed data OpenCV cannot decode.
    """
    if msgtype == COMPRESSED_IMAGE:
        data = np.asarray(msg.data, dtype=np.uint8)
        image = cv2.imdecode(data, cv2.IMREAD_UNCHANGED) if data.size else None
        if image is None:
            raise InputError(
                f"{where}: cannot decode its compressed data (format {msg.format!r}); softjig reads "
                "PNG and JPEG CompressedImage messages"
            )
        if image.ndim == 3 and image.shape[2] == 4:
            image = cv2.cvtColor(image, cv2.COLOR_BGRA2RGB)
        elif image.ndim == 3:
            image = cv2.cvtColor(image, cv2.COLOR_BGR2RGB)
        if image.dtype not in (np.uint8, np.uint16):
            raise InputError(f"{where}: decoded to pixel type {image.dtype}; softjig reads 8 or 16 bits")
        return image
    if msgtype != IMAGE:
        raise InputError(f"{where}: a {msgtype} is not an image; softjig reads {' or '.join(IMAGE_TYPES)}")
    encoding = _ENCODING_ALIASES.get(msg.encoding, msg.encoding)
    if encoding not in IMAGE_ENCODINGS:
        raise InputError(
            f"{where}: encoding {msg.encoding!r} is not one softjig reads ({', '.join(IMAGE_ENCODINGS)}); "
            "republish the images in one of them"
        )
    height, width, step = int(msg.height), int(msg.width), int(msg.step)
    channels, itemsize = (1, 2) if encoding == "mono16" else ((1, 1) if encoding == "mono8" else (3, 1))
    data = np.asarray(msg.data, dtype=np.uint8)
    if height < 1 or width < 1 or step < width * channels * itemsize or data.size < step * height:
        raise InputError(
            f"{where}: {width}x{height} {encoding} with step {step} does not fit its {data.size} bytes "
            "of data: the message is malformed"
        )
    rows = data[: step * height].reshape(height, step)[:, : width * channels * itemsize]
    if itemsize == 2:
        dtype = np.dtype(">u2") if msg.is_bigendian else np.dtype("<u2")
        image = rows.copy().view(dtype).reshape(height, width).astype(np.uint16, copy=False)
    elif channels == 3:
        image = rows.reshape(height, width, 3)
        image = cv2.cvtColor(image, cv2.COLOR_BGR2RGB) if encoding == "bgr8" else image.copy()
    else:
        image = rows.copy() if step != width else rows.reshape(height, width)
    return image


# ------------------------------------------------------------------------------------------- reading


@dataclass(frozen=True)
class BagTopics:
    """The two image topics of a stereo pair, and how they were chosen (for the user).

    Attributes
    ----------
    left, right : topic names.
    left_type, right_type : their message types.
    reason : ``"given"``, or why these two were picked.
    """

    left: str
    right: str
    left_type: str
    right_type: str
    reason: str = "given"


@dataclass(frozen=True, eq=False)
class BagPair:
    """One stereo pair from a bag, in the shape :func:`softjig.io.batch.estimate_frame` estimates
    (``index``, ``part``, ``reference``, :meth:`load_left`, :meth:`load_right`).

    Attributes
    ----------
    index : the frame's index (a softjig bag's ``/softjig/frame``), else the pair's position from 0.
    stamp_left_ns, stamp_right_ns : the images' header stamps (ns).
    left, right : the images (see :func:`decode_image_message`).
    meta : the frame's JSON object from ``/softjig/frame`` (empty for other bags).
    part : the part named by ``meta``, if any.
    reference : whether ``meta`` marks an unloaded reference frame.
    """

    index: int
    stamp_left_ns: int
    stamp_right_ns: int
    left: np.ndarray
    right: np.ndarray
    meta: dict[str, Any] = field(default_factory=dict)
    part: Part | None = None
    reference: bool = False

    def load_left(self) -> np.ndarray:
        return self.left

    def load_right(self) -> np.ndarray:
        return self.right

    @property
    def stamps(self) -> dict[str, int]:
        """The stamps as a results row carries them."""
        return {"stamp_left_ns": self.stamp_left_ns, "stamp_right_ns": self.stamp_right_ns}


@dataclass(frozen=True)
class _Channel:
    topic: str
    msgtype: str
    count: int | None  # messages (None when unknown: a truncated file)


def _topic_score(name: str, side: str) -> int:
    """How strongly a topic name says ``side`` (``left``/``right``)."""
    lowered = name.lower()
    other = "right" if side == "left" else "left"
    if other in lowered and side not in lowered:
        return -1
    words = {"left": ("left", "infra1", "/l/", "_l/", "cam0", "camera0"),
             "right": ("right", "infra2", "/r/", "_r/", "cam1", "camera1")}[side]  # fmt: skip
    return max((len(w) for w in words if w in lowered), default=0)


class BagReader:
    """Read a ROS 2 bag's stereo pairs (a context manager).

    Parameters
    ----------
    path : a rosbag2 folder (with ``metadata.yaml``) or a single ``.mcap`` (or ``.db3``) file.

    Attributes
    ----------
    path : the bag.
    truncated : whether its MCAP file lacked its summary (only complete chunks are read).
    notes : things the user should know (truncation), in order.

    Raises
    ------
    InputError
        The path does not exist, is not a bag, or cannot be read (the message says why).
    """

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.path = Path(path)
        self.truncated = False
        self.notes: list[str] = []
        self._reader: Any = None
        self._stream_file: Path | None = None
        self._typestore: Any = None
        self._channels: dict[str, _Channel] = {}
        self._mcap_files: list[Path] | None = None

    # -- lifecycle
    def open(self) -> BagReader:
        """Open the bag (idempotent; called by ``with``)."""
        if self._reader is not None or self._stream_file is not None:
            return self
        require_bag_support()
        from rosbags.highlevel import AnyReader, AnyReaderError

        if not self.path.exists():
            raise InputError(f"bag {self.path} does not exist")
        target = self.path
        if target.is_dir() and not (target / "metadata.yaml").is_file():
            files = sorted(target.glob("*.mcap"))
            if len(files) != 1:
                raise InputError(
                    f"{target} has no metadata.yaml and {len(files)} .mcap files: give the bag's "
                    "folder (with metadata.yaml) or one .mcap file"
                )
            target = files[0]
        try:
            reader = AnyReader([target], default_typestore=_typestore())
            reader.open()
        except (AnyReaderError, OSError, ValueError, KeyError) as exc:
            mcap_file = self._mcap_file(target)
            if mcap_file is None or not _looks_truncated(mcap_file, exc):
                raise InputError(f"cannot read bag {self.path}: {exc}") from None
            self._open_truncated(mcap_file, exc)
            return self
        self._reader = reader
        self._typestore = reader.typestore
        self._mcap_files = _plain_mcap_files(reader, target)
        for conn in reader.connections:
            known = self._channels.get(conn.topic)
            count = conn.msgcount + (known.count or 0 if known else 0)
            self._channels[conn.topic] = _Channel(conn.topic, conn.msgtype, count)
        return self

    @staticmethod
    def _mcap_file(target: Path) -> Path | None:
        if target.is_file():
            return target if target.suffix.lower() == ".mcap" else None
        files = sorted(target.glob("*.mcap"))
        return files[0] if len(files) == 1 else None

    def _open_truncated(self, mcap_file: Path, exc: Exception) -> None:
        """Read a summary-less MCAP record by record (every complete chunk)."""
        from rosbags.typesys import get_types_from_msg

        self.truncated = True
        self._stream_file = mcap_file
        store = _typestore()
        types: dict[str, Any] = {}
        counts: dict[str, int] = {}
        channel_types: dict[str, str] = {}
        for kind, record in _stream_records(
            mcap_file, with_messages=True, headers_only=True, validate_crcs=True
        ):
            if kind == "schema" and record.encoding == "ros2msg" and record.name not in store.fielddefs:
                types.update(get_types_from_msg(record.data.decode("utf-8"), record.name))
            elif kind == "channel":
                channel_types[record.topic] = record.msgtype
            elif kind == "message":
                counts[record.topic] = counts.get(record.topic, 0) + 1
        if types:
            store.register(types)
        self._typestore = store
        self._channels = {t: _Channel(t, channel_types[t], counts.get(t, 0)) for t in channel_types}
        note = (
            f"bag {self.path} is truncated ({exc}; its recorder was probably killed): read its "
            f"{sum(counts.values())} messages in complete chunks; `softjig convert {self.path} OUT "
            "--repair` writes a repaired copy that ROS 2 tools read"
        )
        self.notes.append(note)
        warnings.warn(note, BagTruncationWarning, stacklevel=3)

    def close(self) -> None:
        if self._reader is not None:
            with contextlib.suppress(Exception):
                self._reader.close()
            self._reader = None

    def __enter__(self) -> BagReader:
        return self.open()

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- what it holds
    @property
    def topics(self) -> dict[str, tuple[str, int | None]]:
        """Every topic: ``{name: (message type, message count)}``."""
        return {c.topic: (c.msgtype, c.count) for c in self._channels.values()}

    def describe_topics(self) -> str:
        """The topics as one line each (for error messages)."""
        if not self._channels:
            return "  (no topics)"
        return "\n".join(
            f"  {c.topic}  {c.msgtype}  ({'?' if c.count is None else c.count} messages)"
            for c in sorted(self._channels.values(), key=lambda c: c.topic)
        )

    def _messages(self, topics: Sequence[str]) -> Iterator[tuple[str, str, int, Any]]:
        """``(topic, msgtype, log_time_ns, raw CDR)`` of ``topics``: in log-time order through rosbags, or,
        for MCAP storage without rosbag2-level compression, in file order (the order a recorder received
        them) through the mcap library, which decompresses zstd chunks faster than rosbags'
        ``backports.zstd`` and skips its CRC pass."""
        if self._mcap_files is not None:
            for path in self._mcap_files:
                for kind, record in _stream_records(path, with_messages=True, topics=set(topics)):
                    if kind == "message":
                        yield record.topic, record.msgtype, record.log_time, record.data
            return
        if self._reader is not None:
            conns = [c for c in self._reader.connections if c.topic in topics]
            if not conns:
                return
            for conn, timestamp, raw in self._reader.messages(connections=conns):
                yield conn.topic, conn.msgtype, timestamp, raw
            return
        assert self._stream_file is not None
        stream = _stream_records(
            self._stream_file, with_messages=True, topics=set(topics), validate_crcs=True
        )
        for kind, record in stream:
            if kind == "message":
                yield record.topic, record.msgtype, record.log_time, record.data

    def deserialize(self, raw: Any, msgtype: str) -> Any:
        """A message from its CDR bytes (a ``memoryview``: an image's array is a view of them, not a
        copy, see :func:`_chunk_records`)."""
        return self._typestore.deserialize_cdr(memoryview(raw), msgtype)

    def read_text(self, topic: str) -> str | None:
        """The first ``std_msgs/msg/String`` on ``topic``, or ``None`` if the bag has none."""
        channel = self._channels.get(topic)
        if channel is None or channel.msgtype != "std_msgs/msg/String":
            return None
        for _topic, msgtype, _t, raw in self._messages([topic]):
            return str(self.deserialize(raw, msgtype).data)
        return None

    def rig(self) -> JigConfig | None:
        """The nominal jig a softjig bag carries on ``/softjig/rig``, or ``None``."""
        from softjig.config import loads_jig

        text = self.read_text(TOPIC_RIG)
        return None if text is None else loads_jig(text, source=f"{self.path}:{TOPIC_RIG}")

    # -- choosing the pair
    def image_topics(self) -> dict[str, str]:
        """``{topic: msgtype}`` of the image topics."""
        return {c.topic: c.msgtype for c in self._channels.values() if c.msgtype in IMAGE_TYPES}

    def choose_topics(self, left: str | None = None, right: str | None = None) -> BagTopics:
        """The stereo pair's topics: the given ones (checked), else two image topics picked by name.

        Picks ``/softjig/left|right/image_raw`` if present; else the image topics whose names say
        left/right (``left``, ``right``, ``infra1``/``infra2``, ``cam0``/``cam1``); else the only two
        image topics.

        Raises
        ------
        InputError
            A given topic is missing or not an image topic, or no pair can be picked; the message lists
            the bag's topics.
        """
        images = self.image_topics()
        listing = f"the bag's topics:\n{self.describe_topics()}"
        for option, topic in (("--left-topic", left), ("--right-topic", right)):
            if topic is None:
                continue
            if topic not in self._channels:
                raise InputError(f"{option} {topic}: {self.path} has no such topic; {listing}")
            if topic not in images:
                raise InputError(
                    f"{option} {topic} carries {self._channels[topic].msgtype}, not images "
                    f"({' or '.join(IMAGE_TYPES)}); {listing}"
                )
        if left is not None and right is not None:
            if left == right:
                raise InputError("--left-topic and --right-topic name the same topic: give the two views")
            return BagTopics(left, right, images[left], images[right])
        if not images:
            raise InputError(
                f"{self.path} has no image topics ({' or '.join(IMAGE_TYPES)}); {listing}\n"
                "record the cameras' images, or name them with --left-topic and --right-topic"
            )
        reason = ""
        if left is None and right is None and TOPIC_LEFT in images and TOPIC_RIGHT in images:
            left, right, reason = TOPIC_LEFT, TOPIC_RIGHT, "softjig's own topics"
        if left is None or right is None:
            for side in ("left", "right"):
                if (left if side == "left" else right) is not None:
                    continue
                taken = {left, right}
                scored = sorted(((_topic_score(t, side), t) for t in images if t not in taken), reverse=True)
                if scored and scored[0][0] > 0 and (len(scored) == 1 or scored[1][0] < scored[0][0]):
                    if side == "left":
                        left = scored[0][1]
                    else:
                        right = scored[0][1]
            if left is not None and right is not None and left != right:
                reason = "their names say left and right"
            elif len(images) == 2 and (left is None or right is None):
                a, b = sorted(images)
                if left is None and right is None:
                    left, right, reason = a, b, "the bag's only two image topics, in name order"
                elif left is None:
                    left, reason = (a if b == right else b), "the bag's other image topic"
                else:
                    right, reason = (a if b == left else b), "the bag's other image topic"
        if left is None or right is None or left == right:
            raise InputError(
                f"cannot tell which of {self.path}'s {len(images)} image topics are the left and right "
                f"cameras; name them with --left-topic T --right-topic T; {listing}"
            )
        return BagTopics(left, right, images[left], images[right], reason)

    # -- pairs
    def pairs(self, topics: BagTopics, *, tolerance_s: float = DEFAULT_STAMP_TOLERANCE_S) -> PairStream:
        """The stereo pairs of ``topics``, matched by header stamp within ``tolerance_s`` (a
        :class:`PairStream`: iterate it once)."""
        if not (math.isfinite(tolerance_s) and tolerance_s > 0):
            raise InputError(f"--stamp-tolerance must be a positive number of seconds, got {tolerance_s}")
        return PairStream(self, topics, tolerance_s)


class PairStream:
    """The pairs of a bag's two image topics, in stamp order; counts what did not pair.

    Iterating yields :class:`BagPair` objects. Images are paired by header stamp with
    :class:`~softjig.io.cameras.FramePairer` (each image's nearest partner within the tolerance); an
    image that finds none is dropped and counted (:attr:`unpaired`). The first pair fixes the images'
    size and pixel type: the two topics must agree (else :class:`~softjig.errors.InputError`); a later
    pair that differs is still yielded, and its estimate reports the problem.

    Attributes
    ----------
    n_pairs : pairs yielded so far.
    unpaired : images that found no partner.
    nearest_skew_s : the smallest ``|t_right - t_left|`` seen between a left and the next right image
        when nothing paired (for the error message), else ``None``.
    upper_bound : at most this many pairs (the smaller topic's message count; ``None`` unknown).
    """

    def __init__(self, reader: BagReader, topics: BagTopics, tolerance_s: float) -> None:
        self.reader, self.topics, self.tolerance_s = reader, topics, float(tolerance_s)
        self.n_pairs = 0
        self.unpaired = 0
        self.nearest_skew_s: float | None = None
        counts = [reader.topics[t][1] for t in (topics.left, topics.right)]
        self.upper_bound = None if None in counts else min(c for c in counts if c is not None)

    def __len__(self) -> int:
        """An upper bound of the pairs (see :attr:`upper_bound`): what a progress bar needs."""
        return self.upper_bound if self.upper_bound is not None else 0

    def __iter__(self) -> Iterator[BagPair]:
        from softjig.io.cameras import FramePairer

        reader, topics = self.reader, self.topics
        want = [topics.left, topics.right]
        if TOPIC_FRAME in reader.topics:
            want.append(TOPIC_FRAME)
        pairer = FramePairer(self.tolerance_s, max_pending=8)
        frame_meta: dict[int, dict] = {}  # stamp_ns -> /softjig/frame object
        meta_order: deque[int] = deque()
        last = {"left": None, "right": None}
        shape: tuple | None = None
        seen = 0
        parts: dict[str, Part | None] = {}  # a part's canonical JSON -> the part: parsed once a stream
        for topic, msgtype, log_time, raw in reader._messages(want):
            if topic == TOPIC_FRAME:
                obj = _frame_meta(reader.deserialize(raw, msgtype).data)
                if obj is not None:
                    key = int(obj.get("stamp_ns", log_time))
                    frame_meta[key] = obj
                    meta_order.append(key)
                    while len(meta_order) > 64:
                        frame_meta.pop(meta_order.popleft(), None)
                continue
            side = "left" if topic == topics.left else "right"
            msg = reader.deserialize(raw, msgtype)
            stamp = _stamp_ns(msg.header) if hasattr(msg, "header") else int(log_time)
            last[side] = stamp
            if last["left"] is not None and last["right"] is not None:
                skew = abs(last["left"] - last["right"]) / 1e9
                self.nearest_skew_s = skew if self.nearest_skew_s is None else min(self.nearest_skew_s, skew)
            seen += 1
            pairer.push(side, stamp / 1e9, (stamp, msgtype, msg, topic))
            while (popped := pairer.pop()) is not None:
                (_, (sl, tl, ml, topl)), (_, (sr, tr, mr, topr)) = popped
                left = decode_image_message(ml, tl, where=f"{topl} at stamp {sl} ns")
                right = decode_image_message(mr, tr, where=f"{topr} at stamp {sr} ns")
                if shape is None:
                    shape = (left.shape, left.dtype.str)
                    if (right.shape, right.dtype.str) != shape:
                        raise InputError(
                            f"the first pair's images differ: {topl} gives {_describe(left)} but {topr} "
                            f"gives {_describe(right)} (stamps {sl} and {sr} ns): the two topics are not "
                            "one stereo pair; name the right ones with --left-topic and --right-topic"
                        )
                meta = frame_meta.get(sl) or frame_meta.get(sr) or {}
                yield _pair(self.n_pairs, sl, sr, left, right, meta, parts)
                self.n_pairs += 1
        self.unpaired = seen - 2 * self.n_pairs


def _describe(image: np.ndarray) -> str:
    kind = "gray" if image.ndim == 2 else "RGB"
    return f"{image.shape[1]}x{image.shape[0]} {kind} {image.dtype}"


def _frame_meta(text: str) -> dict | None:
    try:
        obj = json.loads(text)
    except (TypeError, ValueError):
        return None
    return obj if isinstance(obj, dict) else None


def _pair(
    position: int, sl: int, sr: int, left: np.ndarray, right: np.ndarray, meta: dict, parts: dict
) -> BagPair:
    """The pair, its index and part from ``meta``; ``parts`` holds the parts already parsed (keyed by
    their canonical JSON: a recording's frames name the same few parts, and parsing one costs ~0.5 ms)."""
    index = meta.get("index")
    index = index if isinstance(index, int) and not isinstance(index, bool) and index >= 0 else position
    part = None
    if isinstance(meta.get("part"), dict):
        key = json.dumps(meta["part"], sort_keys=True, default=str)
        if key not in parts:
            parts[key] = _part(meta["part"])
        part = parts[key]
    return BagPair(index, sl, sr, left, right, meta, part, meta.get("reference") is True)


def _part(obj: dict) -> Part | None:
    """A frame's part, ``None`` if it does not parse (the frame is still estimated, without it)."""
    from softjig.config import part_from_dict
    from softjig.errors import ConfigError

    with contextlib.suppress(ConfigError, InputError, TypeError, ValueError):
        return part_from_dict(obj)
    return None


# --------------------------------------------------------------------------------- MCAP record stream


@dataclass(frozen=True)
class _Record:
    """What :func:`_stream_records` yields (a subset of the MCAP record's fields)."""

    topic: str = ""
    msgtype: str = ""
    log_time: int = 0
    publish_time: int = 0
    data: bytes = b""
    name: str = ""
    encoding: str = ""
    id: int = 0
    schema_id: int = 0
    metadata: dict = field(default_factory=dict)
    message_encoding: str = ""
    sequence: int = 0


def _plain_mcap_files(reader: Any, target: Path) -> list[Path] | None:
    """The MCAP files of a bag opened by rosbags' ``AnyReader`` whose messages can be streamed as they are
    (MCAP storage, no rosbag2 file or message compression), in order; ``None`` for any other bag (rosbags
    reads those)."""
    if target.is_file():
        return [target] if target.suffix.lower() == ".mcap" else None
    try:  # rosbags' own parse of metadata.yaml (a second parse costs ~0.1 s)
        storage = reader.readers[0].storage
        if storage.metadata.compression_mode:
            return None
        if not all(type(x).__name__ == "McapReader" for x in storage.storages):
            return None
        files = [Path(x.path) for x in storage.storages]
    except (AttributeError, IndexError, TypeError):  # another rosbags version: the general path
        return None
    return files if files and all(f.is_file() for f in files) else None


def _looks_truncated(path: Path, exc: Exception) -> bool:
    """Whether a read failure is a summary-less MCAP (magic at the start, none at the end)."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(8)
            fh.seek(0, os.SEEK_END)
            size = fh.tell()
            fh.seek(max(0, size - 8))
            tail = fh.read(8)
    except OSError:
        return False
    if head != MCAP_MAGIC:
        return False
    return tail != MCAP_MAGIC or any(s in str(exc).lower() for s in _TRUNCATION_SIGNS)


def _stream_records(
    path: Path,
    *,
    with_messages: bool,
    headers_only: bool = False,
    topics: set[str] | None = None,
    validate_crcs: bool = False,
) -> Iterator[tuple[str, _Record]]:
    """The schema, channel and (optionally) message records of an MCAP file in file order, up to the
    first record that is cut short (a truncated file ends there).

    ``headers_only`` leaves messages' data out; ``topics`` keeps only those topics' messages. Messages
    are those of complete chunks (with ``validate_crcs``, a chunk whose CRC fails ends the stream), or
    written outside chunks.
    """
    from mcap.exceptions import McapError
    from mcap.records import Channel, Chunk, Message, Schema
    from mcap.stream_reader import StreamReader

    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    decompressors: dict[str, Any] = {}  # one zstd context for the file's chunks

    def records_of(record: Any) -> Iterable[Any]:
        if isinstance(record, Chunk):
            return _chunk_records(record, validate_crc=validate_crcs, decompressors=decompressors)
        return (record,)

    with open(path, "rb") as fh:
        stream = StreamReader(fh, emit_chunks=True, record_size_limit=2**31)
        try:
            for outer in stream.records:
                for record in records_of(outer):
                    if isinstance(record, Schema):
                        schemas[record.id] = record
                        yield "schema", _Record(name=record.name, encoding=record.encoding,
                                                data=record.data, id=record.id)  # fmt: skip
                    elif isinstance(record, Channel):
                        channels[record.id] = record
                        schema = schemas.get(record.schema_id)
                        yield (
                            "channel",
                            _Record(
                                topic=record.topic,
                                msgtype=schema.name if schema else "",
                                id=record.id,
                                schema_id=record.schema_id,
                                metadata=dict(record.metadata),
                                message_encoding=record.message_encoding,
                            ),
                        )
                    elif with_messages and isinstance(record, Message):
                        channel = channels.get(record.channel_id)
                        if channel is None or (topics is not None and channel.topic not in topics):
                            continue
                        schema = schemas.get(channel.schema_id)
                        yield (
                            "message",
                            _Record(
                                topic=channel.topic,
                                msgtype=schema.name if schema else "",
                                log_time=record.log_time,
                                publish_time=record.publish_time,
                                data=b"" if headers_only else record.data,
                                id=record.channel_id,
                                sequence=record.sequence,
                            ),
                        )
        except (McapError, EOFError, ValueError, struct.error, OSError, MemoryError):
            return  # cut short here: everything before was complete


#: An MCAP record's opcode (1 byte) and content length (8 bytes), and a message record's channel id,
#: sequence, log time and publish time before its data (MCAP specification, little-endian, unpadded).
_RECORD_PREFIX = struct.Struct("<BQ")
_MESSAGE_HEADER = struct.Struct("<HIQQ")


def _chunk_records(
    chunk: Any, *, validate_crc: bool, decompressors: dict[str, Any] | None = None
) -> Iterator[Any]:
    """The records of an MCAP chunk, as ``mcap.stream_reader.breakup_chunk`` gives them, except that a
    message's ``data`` is a ``memoryview`` of the decompressed chunk instead of a copy.

    Hand-written for speed: ``breakup_chunk`` copies each message out of the chunk (``BytesIO.read``),
    and ``bytes`` data is copied once more by rosbags' CDR deserialiser (``rawdata[4:]``), which leaves
    a ``memoryview`` uncopied (``numpy.frombuffer`` of it). Without those two copies of each image a
    1280x720 mono8 bag reads in 0.8-1.1 ms a frame less CPU (4.7 instead of 5.6 ms, mean of a frame,
    ``benchmarks/bench_frame.py`` on a loaded machine). Schemas and channels (small) are parsed by the
    mcap library. ``decompressors`` keeps the zstd context of a file's chunks from one chunk to the next.
    """
    import zlib

    from mcap.data_stream import ReadDataStream
    from mcap.opcode import Opcode
    from mcap.records import Channel, Message, Schema
    from mcap.stream_reader import CRCValidationError

    if chunk.compression == "zstd":
        import zstandard

        decompressors = {} if decompressors is None else decompressors
        if "zstd" not in decompressors:
            decompressors["zstd"] = zstandard.ZstdDecompressor()
        data = decompressors["zstd"].decompress(chunk.data, max_output_size=chunk.uncompressed_size)
    elif chunk.compression == "lz4":
        import lz4.frame

        data = lz4.frame.decompress(chunk.data)
    else:  # uncompressed (what mcap does with any other name)
        data = chunk.data
    if validate_crc and chunk.uncompressed_crc != 0 and zlib.crc32(data) != chunk.uncompressed_crc:
        raise CRCValidationError(expected=chunk.uncompressed_crc, actual=zlib.crc32(data), record=chunk)
    view = memoryview(data)
    pos, end = 0, len(view)
    while pos < end:
        opcode, length = _RECORD_PREFIX.unpack_from(view, pos)
        pos += _RECORD_PREFIX.size
        body = view[pos : pos + length]
        if len(body) < length:
            raise EOFError("a record runs past the end of its chunk")
        pos += length
        if opcode == Opcode.MESSAGE:
            channel_id, sequence, log_time, publish_time = _MESSAGE_HEADER.unpack_from(body)
            yield Message(channel_id, log_time, body[_MESSAGE_HEADER.size :], publish_time, sequence)
        elif opcode in (Opcode.CHANNEL, Opcode.SCHEMA):
            kind = Channel if opcode == Opcode.CHANNEL else Schema
            yield kind.read(ReadDataStream(io.BytesIO(body)))


# ------------------------------------------------------------------------------------------- writing


def _qos_yaml(durability_transient_local: bool) -> str:
    """The ``offered_qos_profiles`` string of metadata version 5 (and of an MCAP channel): one profile,
    reliable, keep-last; transient-local durability for latched topics, else volatile."""
    from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime
    from rosbags.rosbag2.metadata import dump_qos_v8

    infinite = QosTime(2147483647, 4294967295)
    qos = Qos(
        history=QosHistory.KEEP_LAST,
        depth=1 if durability_transient_local else 10,
        reliability=QosReliability.RELIABLE,
        durability=QosDurability.TRANSIENT_LOCAL if durability_transient_local else QosDurability.VOLATILE,
        deadline=infinite,
        lifespan=infinite,
        liveliness=QosLiveliness.AUTOMATIC,
        liveliness_lease_duration=infinite,
        avoid_ros_namespace_conventions=False,
    )
    return dump_qos_v8([qos])


def _metadata_yaml(
    file_name: str, topics: dict[str, tuple[str, str, int]], t_min: int | None, t_max: int | None
) -> str:
    """The text of a rosbag2 ``metadata.yaml`` (version :data:`METADATA_VERSION`) for one MCAP file;
    ``topics`` maps each topic to ``(type, offered_qos_profiles, message count)``."""
    from ruamel.yaml import YAML

    start = t_min or 0
    duration = 0 if t_min is None or t_max is None else t_max - t_min
    count = sum(n for _, _, n in topics.values())
    info = {
        "version": METADATA_VERSION,
        "storage_identifier": "mcap",
        "duration": {"nanoseconds": int(duration)},
        "starting_time": {"nanoseconds_since_epoch": int(start)},
        "message_count": int(count),
        "topics_with_message_count": [
            {
                "topic_metadata": {
                    "name": topic,
                    "type": msgtype,
                    "serialization_format": "cdr",
                    "offered_qos_profiles": qos,
                },
                "message_count": int(n),
            }
            for topic, (msgtype, qos, n) in topics.items()
        ],
        "compression_format": "",
        "compression_mode": "",
        "relative_file_paths": [file_name],
        "files": [
            {
                "path": file_name,
                "starting_time": {"nanoseconds_since_epoch": int(start)},
                "duration": {"nanoseconds": int(duration)},
                "message_count": int(count),
            }
        ],
    }
    yaml = YAML(typ="safe")
    yaml.default_flow_style = False
    text = io.StringIO()
    yaml.dump({"rosbag2_bagfile_information": info}, text)
    return text.getvalue()


_LATCHED = (TOPIC_TF_STATIC, TOPIC_RIG)


def rotation_z_to(normal: np.ndarray) -> np.ndarray:
    """The quaternion ``(x, y, z, w)`` of the smallest rotation taking ``+z`` to the unit ``normal``."""
    n = np.asarray(normal, dtype=float)
    n = n / np.linalg.norm(n)
    z = np.array([0.0, 0.0, 1.0])
    axis = np.cross(z, n)
    s, c = float(np.linalg.norm(axis)), float(np.dot(z, n))
    if s < 1e-12:
        return np.array([0.0, 0.0, 0.0, 1.0]) if c > 0 else np.array([1.0, 0.0, 0.0, 0.0])
    half = 0.5 * math.atan2(s, c)
    q = np.empty(4)
    q[:3] = axis / s * math.sin(half)
    q[3] = math.cos(half)
    return q


def _quaternion_from_matrix(R: np.ndarray) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    return Rotation.from_matrix(np.asarray(R, dtype=float)).as_quat()  # x, y, z, w


def is_simulated_bag(path: str | os.PathLike[str]) -> bool:
    """Whether every MCAP file of the bag folder ``path`` says softjig converted it from a simulated
    dataset (its ``softjig`` metadata record's ``provenance``): the only bags ``--overwrite`` replaces. A
    file that cannot be read to its metadata (truncated, foreign) is not."""
    require_bag_support()
    from mcap.reader import make_reader

    files = sorted(Path(path).glob("*.mcap"))
    if not files:
        return False
    for file in files:
        try:
            with open(file, "rb") as fh:
                records = [m.metadata for m in make_reader(fh).iter_metadata() if m.name == PROVENANCE_RECORD]
        except Exception:  # whatever the MCAP library raises (a truncated file): not provably ours
            return False
        if not records or any(r.get("provenance") != SIMULATION for r in records):
            return False
    return True


class BagWriter:
    """Write a ROS 2 bag folder of softjig's topics (a context manager; see the module docstring).

    Parameters
    ----------
    path : the bag folder (created; must not exist, or be empty, unless ``overwrite`` and it is a bag
        this writer could have written: a ``metadata.yaml`` and ``.mcap`` files only).
    jig : the nominal jig: ``/softjig/rig``, the cameras' ``camera_info`` and ``/tf_static``.
    overwrite : replace an existing bag in ``path``, only one converted from a simulation
        (:func:`is_simulated_bag`): never a recording, nor a bag softjig did not write.
    chunk_bytes : uncompressed bytes per MCAP chunk.
    zstd_level : the chunks' zstd level (:data:`~softjig.io.mcap_chunks.ZSTD_LEVEL`, 1, by default; a
        negative level stores the images' bytes nearly as they are: a reader decompresses them several
        times faster, in a bag about 1.6 times larger for camera images).
    durable : fsync the file after each chunk (a recording survives a power cut).
    simulated : the pairs come from a simulated dataset (the bag's provenance record says so, and a
        later ``overwrite`` may replace it); ``False``: a recording.

    Notes
    -----
    Not thread-safe: one thread writes (the live recorder queues to its own thread).
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        jig: JigConfig,
        *,
        overwrite: bool = False,
        chunk_bytes: int = CHUNK_BYTES,
        zstd_level: int = ZSTD_LEVEL,
        durable: bool = True,
        simulated: bool = False,
    ) -> None:
        self.root = Path(path)
        self.simulated = simulated
        self.jig = jig
        self.overwrite = overwrite
        from softjig.io.mcap_chunks import check_options

        check_options(chunk_bytes, zstd_level)  # before any file
        self.chunk_bytes = chunk_bytes
        self.zstd_level = zstd_level
        self.durable = durable
        self.n_pairs = 0
        self._store: Any = None
        self._writer: Any = None
        self._fh: Any = None
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, int] = {}
        self._counts: dict[str, int] = {}
        self._types: dict[str, str] = {}
        self._t_min: int | None = None
        self._t_max: int | None = None
        self._written = 0
        self._static_done = False

    @property
    def mcap_path(self) -> Path:
        return self.root / f"{self.root.name}_0.mcap"

    # -- lifecycle
    def open(self) -> BagWriter:
        require_bag_support()
        from softjig.io.mcap_chunks import ChunkWriter

        if self._writer is not None:
            return self
        root = self.root
        if root.exists() and not root.is_dir():
            raise InputError(f"{root} exists and is not a folder: choose another output folder for the bag")
        if root.is_dir() and any(root.iterdir()):
            members = list(root.iterdir())
            ours = all(m.name == "metadata.yaml" or m.suffix == ".mcap" for m in members) and any(
                m.name == "metadata.yaml" for m in members
            )
            if not ours:
                raise InputError(
                    f"{root} is not empty and is not a bag: choose an empty or new output folder"
                )
            if not self.overwrite:
                raise InputError(
                    f"{root} already holds a bag: choose another output folder or overwrite it (--overwrite)"
                )
            if not is_simulated_bag(root):
                raise InputError(
                    f"{root} holds a recording, not a bag softjig converted from a simulation (its MCAP "
                    f"files lack a {PROVENANCE_RECORD!r} record of simulation provenance): --overwrite "
                    "replaces only a simulation's bag, never a recording (live --record-bag, a converted "
                    f"recording, ros2 bag record); choose another output folder, or move {root} away "
                    "yourself first"
                )
            for member in members:
                member.unlink()
        try:
            root.mkdir(parents=True, exist_ok=True)
            self._fh = open(self.mcap_path, "xb")  # noqa: SIM115 - closed in close()
        except OSError as exc:
            raise InputError(
                f"cannot write the bag {root}: {exc.strerror or exc}; choose another path"
            ) from None
        self._store = _typestore()
        self._writer = ChunkWriter(self._fh, chunk_bytes=self.chunk_bytes, level=self.zstd_level)
        self._writer.start(profile="ros2", library="softjig")
        self._writer.add_metadata(
            PROVENANCE_RECORD, {"provenance": SIMULATION if self.simulated else RECORDING}
        )
        self._write_metadata()  # a bag folder from the start: a killed recorder leaves one to repair
        return self

    def close(self) -> None:
        """Write the summary and footer, then ``metadata.yaml`` with the final counts."""
        if self._writer is None:
            return
        writer, self._writer = self._writer, None
        try:
            writer.finish()
            self._fh.flush()
            if self.durable:
                os.fsync(self._fh.fileno())
        finally:
            self._fh.close()
        self._write_metadata()

    def __enter__(self) -> BagWriter:
        return self.open()

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- low level
    def _channel(self, topic: str, msgtype: str) -> int:
        channel = self._channels.get(topic)
        if channel is not None:
            return channel
        schema = self._schemas.get(msgtype)
        if schema is None:
            msgdef, _ = self._store.generate_msgdef(msgtype, ros_version=2)
            schema = self._writer.register_schema(msgtype, "ros2msg", msgdef.encode("utf-8"))
            self._schemas[msgtype] = schema
        qos = _qos_yaml(topic in _LATCHED)
        channel = self._writer.register_channel(
            topic=topic, message_encoding="cdr", schema_id=schema, metadata={"offered_qos_profiles": qos}
        )
        self._channels[topic] = channel
        self._counts[topic] = 0
        self._types[topic] = msgtype
        return channel

    def write(self, topic: str, msg: Any, stamp_ns: int) -> None:
        """Serialise and append one message logged at ``stamp_ns``."""
        if self._writer is None:
            self.open()
        msgtype = msg.__msgtype__
        channel = self._channel(topic, msgtype)
        data = bytes(self._store.serialize_cdr(msg, msgtype))
        self._writer.add_message(
            channel_id=channel, log_time=int(stamp_ns), data=data, publish_time=int(stamp_ns)
        )
        self._counts[topic] += 1
        self._t_min = stamp_ns if self._t_min is None else min(self._t_min, stamp_ns)
        self._t_max = stamp_ns if self._t_max is None else max(self._t_max, stamp_ns)

    def _sync(self) -> None:
        """Flush a chunk the writer has completed to the disk (crash safety), fsync if durable."""
        position = self._fh.tell()
        if position != self._written:
            self._fh.flush()
            if self.durable:
                os.fsync(self._fh.fileno())
            self._written = position

    def _write_metadata(self) -> None:
        from softjig.files import write_text_atomic

        topics = {t: (self._types[t], _qos_yaml(t in _LATCHED), self._counts[t]) for t in self._channels}
        text = _metadata_yaml(self.mcap_path.name, topics, self._t_min, self._t_max)
        write_text_atomic(self.root / "metadata.yaml", text)

    # -- softjig's messages
    def _header(self, stamp_ns: int, frame_id: str) -> Any:
        T = self._store.types
        sec, nanosec = divmod(int(stamp_ns), 1_000_000_000)
        return T["std_msgs/msg/Header"](
            stamp=T["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec), frame_id=frame_id
        )

    def _string(self, text: str) -> Any:
        return self._store.types["std_msgs/msg/String"](data=text)

    def _static(self, stamp_ns: int) -> None:
        """The rig and the cameras' poses, once, at the first stamp (latched topics)."""
        from softjig.config import dumps_jig

        self._static_done = True
        self.write(TOPIC_RIG, self._string(dumps_jig(self.jig)), stamp_ns)
        T = self._store.types
        transforms = []
        for cam, child in ((self.jig.cameras.left, FRAME_LEFT), (self.jig.cameras.right, FRAME_RIGHT)):
            pose = cam.T_J_cam
            x, y, z = (pose[:3, 3] / 1000.0).tolist()
            qx, qy, qz, qw = _quaternion_from_matrix(pose[:3, :3]).tolist()
            transforms.append(
                T["geometry_msgs/msg/TransformStamped"](
                    header=self._header(stamp_ns, FRAME_JIG),
                    child_frame_id=child,
                    transform=T["geometry_msgs/msg/Transform"](
                        translation=T["geometry_msgs/msg/Vector3"](x=x, y=y, z=z),
                        rotation=T["geometry_msgs/msg/Quaternion"](x=qx, y=qy, z=qz, w=qw),
                    ),
                )
            )
        self.write(TOPIC_TF_STATIC, T["tf2_msgs/msg/TFMessage"](transforms=transforms), stamp_ns)

    def _image(self, image: np.ndarray, stamp_ns: int, frame_id: str) -> Any:
        image = np.ascontiguousarray(image)
        if image.dtype == np.uint8 and image.ndim == 2:
            encoding, step = "mono8", image.shape[1]
        elif image.dtype == np.uint16 and image.ndim == 2:
            encoding, step = "mono16", 2 * image.shape[1]
            image = image.astype("<u2", copy=False)
        elif image.dtype == np.uint8 and image.ndim == 3 and image.shape[2] == 3:
            encoding, step = "rgb8", 3 * image.shape[1]
        else:
            raise InputError(
                f"cannot store an image of shape {image.shape} and type {image.dtype} in a bag: softjig "
                "writes uint8/uint16 gray or uint8 RGB images"
            )
        return self._store.types[IMAGE](
            header=self._header(stamp_ns, frame_id),
            height=image.shape[0],
            width=image.shape[1],
            encoding=encoding,
            is_bigendian=0,
            step=step,
            data=image.reshape(-1).view(np.uint8),
        )

    def _camera_info(self, side: str, stamp_ns: int, frame_id: str) -> Any:
        """The ``CameraInfo`` of a camera of the rig: a rectified pair has no distortion and ``P``'s
        ``Tx = -fx * baseline`` (m) on the right camera; an unrectified one its own K and distortion."""
        stereo = self.jig.cameras
        cam = stereo.left if side == "left" else stereo.right
        K = cam.K
        tx = 0.0
        if stereo.rectified and side == "right":
            tx = -cam.fx_px * stereo.baseline_mm / 1000.0
        P = np.zeros((3, 4))
        P[:, :3] = K
        P[0, 3] = tx
        d = np.zeros(5) if stereo.rectified else np.asarray(cam.distortion, dtype=float)
        T = self._store.types
        return T["sensor_msgs/msg/CameraInfo"](
            header=self._header(stamp_ns, frame_id),
            height=cam.height_px,
            width=cam.width_px,
            distortion_model="plumb_bob",
            d=d,
            k=K.reshape(-1).astype(float),
            r=np.eye(3).reshape(-1),
            p=P.reshape(-1),
            binning_x=0,
            binning_y=0,
            roi=T["sensor_msgs/msg/RegionOfInterest"](
                x_offset=0, y_offset=0, height=0, width=0, do_rectify=False
            ),
        )

    def add_pair(
        self,
        left: np.ndarray,
        right: np.ndarray,
        stamp_left_ns: int,
        stamp_right_ns: int | None = None,
        meta: dict[str, Any] | None = None,
    ) -> None:
        """Append one stereo pair (images, camera_info, and the frame's JSON on ``/softjig/frame``).

        ``meta`` (the dataset frame's object: index, part, reference, truth...) is stored with
        ``stamp_ns`` set to the left stamp, which is how a reader finds it again."""
        if self._writer is None:
            self.open()
        stamp_right_ns = stamp_left_ns if stamp_right_ns is None else stamp_right_ns
        if not self._static_done:
            self._static(min(stamp_left_ns, stamp_right_ns))
        obj = {k: v for k, v in (meta or {}).items() if k not in ("left", "right")}
        obj["stamp_ns"] = int(stamp_left_ns)
        self.write(TOPIC_FRAME, self._string(json.dumps(obj, default=json_default)), stamp_left_ns)
        self.write(TOPIC_LEFT_INFO, self._camera_info("left", stamp_left_ns, FRAME_LEFT), stamp_left_ns)
        self.write(TOPIC_LEFT, self._image(left, stamp_left_ns, FRAME_LEFT), stamp_left_ns)
        self.write(TOPIC_RIGHT_INFO, self._camera_info("right", stamp_right_ns, FRAME_RIGHT), stamp_right_ns)
        self.write(TOPIC_RIGHT, self._image(right, stamp_right_ns, FRAME_RIGHT), stamp_right_ns)
        self.n_pairs += 1
        self._sync()

    def add_estimate(self, stamp_ns: int, result: Any) -> None:
        """Append a pair's estimate (a :class:`~softjig.sensing.pipeline.SensingResult`): the part's pose,
        the normal, the triangulated markers (m, jig frame) and the estimate's JSON."""
        if self._writer is None:
            self.open()
        T = self._store.types
        estimate = result.estimate
        n = np.asarray(estimate.normal, dtype=float)
        centre = estimate.part_centre_xy_mm or estimate.contact_centroid_xy_mm or (0.0, 0.0)
        x_mm, y_mm = float(centre[0]), float(centre[1])
        z_mm = float(result.plane.z_at(x_mm, y_mm))
        qx, qy, qz, qw = rotation_z_to(n).tolist()
        header = self._header(stamp_ns, FRAME_JIG)
        pose = T["geometry_msgs/msg/PoseStamped"](
            header=header,
            pose=T["geometry_msgs/msg/Pose"](
                position=T["geometry_msgs/msg/Point"](x=x_mm / 1000.0, y=y_mm / 1000.0, z=z_mm / 1000.0),
                orientation=T["geometry_msgs/msg/Quaternion"](x=qx, y=qy, z=qz, w=qw),
            ),
        )
        self.write(TOPIC_PART_POSE, pose, stamp_ns)
        vector = T["geometry_msgs/msg/Vector3"](x=float(n[0]), y=float(n[1]), z=float(n[2]))
        self.write(
            TOPIC_NORMAL, T["geometry_msgs/msg/Vector3Stamped"](header=header, vector=vector), stamp_ns
        )
        self.write(TOPIC_MARKERS, self._cloud(np.asarray(result.points_J, dtype=float), stamp_ns), stamp_ns)
        self.write(
            TOPIC_ESTIMATE, self._string(json.dumps(estimate.to_dict(), default=json_default)), stamp_ns
        )
        self._sync()

    def _cloud(self, points_mm: np.ndarray, stamp_ns: int) -> Any:
        T = self._store.types
        points = (points_mm.reshape(-1, 3) / 1000.0).astype("<f4")
        fields = [
            T["sensor_msgs/msg/PointField"](name=name, offset=4 * i, datatype=7, count=1)  # 7: FLOAT32
            for i, name in enumerate("xyz")
        ]
        return T["sensor_msgs/msg/PointCloud2"](
            header=self._header(stamp_ns, FRAME_JIG),
            height=1,
            width=len(points),
            fields=fields,
            is_bigendian=False,
            point_step=12,
            row_step=12 * len(points),
            data=points.reshape(-1).view(np.uint8),
            is_dense=True,
        )


# ------------------------------------------------------------------------------------------- repair


def repair_bag(src: str | os.PathLike[str], dst: str | os.PathLike[str]) -> int:
    """Rewrite a bag whose MCAP lacks its summary (a killed recorder) into a new bag folder ``dst``, up
    to its last complete chunk, as ``ros2 bag reindex`` would; ``src`` is left untouched.

    Messages are copied as they are (no re-serialisation), with their schemas, channels and QoS.

    Returns
    -------
    int : the messages kept.

    Raises
    ------
    InputError
        ``src`` is not an MCAP bag, or ``dst`` exists and is not empty.
    """
    require_bag_support()
    from softjig.files import write_text_atomic
    from softjig.io.mcap_chunks import ChunkWriter

    src, dst = Path(src), Path(dst)
    mcap_file = BagReader._mcap_file(src) if src.exists() else None
    if mcap_file is None:
        raise InputError(f"{src} is not an MCAP bag (a folder with one .mcap, or an .mcap file)")
    if dst.exists() and (not dst.is_dir() or any(dst.iterdir())):
        raise InputError(f"{dst} exists and is not empty: give a new folder for the repaired bag")
    dst.mkdir(parents=True, exist_ok=True)
    out = dst / f"{dst.name}_0.mcap"
    counts: dict[str, int] = {}
    types: dict[str, str] = {}
    qos: dict[str, str] = {}
    t_min = t_max = None
    schema_ids: dict[int, int] = {}
    channel_ids: dict[int, int] = {}
    tmp = out.with_name(out.name + ".part")
    with open(tmp, "wb") as fh:
        writer = ChunkWriter(fh, chunk_bytes=CHUNK_BYTES)
        writer.start(profile="ros2", library="softjig repair")
        for kind, record in _stream_records(mcap_file, with_messages=True, validate_crcs=True):
            if kind == "schema" and record.id not in schema_ids:
                schema_ids[record.id] = writer.register_schema(record.name, record.encoding, record.data)
            elif kind == "channel" and record.id not in channel_ids:
                channel_ids[record.id] = writer.register_channel(
                    topic=record.topic,
                    message_encoding=record.message_encoding,
                    schema_id=schema_ids.get(record.schema_id, 0),
                    metadata=record.metadata,
                )
                counts.setdefault(record.topic, 0)
                types[record.topic] = record.msgtype
                qos[record.topic] = record.metadata.get("offered_qos_profiles", "")
            elif kind == "message" and record.id in channel_ids:
                writer.add_message(
                    channel_id=channel_ids[record.id],
                    log_time=record.log_time,
                    data=record.data,
                    publish_time=record.publish_time,
                    sequence=record.sequence,
                )
                counts[record.topic] += 1
                t_min = record.log_time if t_min is None else min(t_min, record.log_time)
                t_max = record.log_time if t_max is None else max(t_max, record.log_time)
        writer.finish()
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, out)
    topics = {t: (types[t], qos[t], counts[t]) for t in counts}
    write_text_atomic(dst / "metadata.yaml", _metadata_yaml(out.name, topics, t_min, t_max))
    return sum(counts.values())
