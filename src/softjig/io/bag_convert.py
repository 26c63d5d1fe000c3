"""Datasets to ROS 2 bags and back (``softjig convert``), without losing what either holds.

A dataset (``DESIGN.md`` §3) becomes a bag of softjig's topics (:mod:`softjig.io.rosbag`): every frame's
images, its ``frames.jsonl`` object on ``/softjig/frame`` (index, part, reference, pose, truth: all but the
image paths; the truth's marker ``.npz`` files are not copied) and, unless told not to, softjig's
**estimate** of the frame (``/softjig/part_pose``, ``/softjig/normal``, ``/softjig/markers``,
``/softjig/estimate``): the bag then holds what softjig measures, as a live recording does, and the
truth stays where it is labelled as truth. A bag becomes a dataset with the pairs of its two image
topics, their ``/softjig/frame`` objects (if it is softjig's), the stamps (``t_left_s``, ``t_right_s``,
``time_s`` from the first pair, ``capture_time_unix_s``) and the rig it carries (or the one given).

Stamps of a converted dataset: a frame's ``capture_time_unix_s`` (when the pair was complete: its later
image) less each image's lead on the later one (``t_left_s``, ``t_right_s``) where it has them (live
recordings, as :mod:`softjig.live.record_bag` stamps them); else ``start_unix_s`` plus its ``time_s`` (or
its position over the frame rate). A bag's pair becomes a frame with its stamps (``stamp_left_ns``,
``stamp_right_ns``, used as they are on the way back: a round trip keeps them to the nanosecond) and
``capture_time_unix_s`` its later stamp.
"""

from __future__ import annotations

import itertools
import math
import os
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from softjig.config import JigConfig
from softjig.errors import EstimationError, InputError
from softjig.io.dataset import Dataset, DatasetWriter, Frame, is_simulation
from softjig.io.mcap_chunks import ZSTD_LEVEL
from softjig.io.rosbag import DEFAULT_STAMP_TOLERANCE_S, BagReader, BagWriter

__all__ = ["ConvertSummary", "bag_to_dataset", "dataset_to_bag", "frame_stamps_ns"]

#: Frame rate assumed for frames without times (Hz).
DEFAULT_FPS = 30.0


@dataclass(frozen=True)
class ConvertSummary:
    """What a conversion wrote.

    Attributes
    ----------
    n_frames : stereo pairs written.
    n_estimated : pairs with an estimate written (dataset to bag).
    n_failed : loaded pairs the estimator gave no estimate for (dataset to bag; their images are kept).
    unpaired : images of the bag that found no partner (bag to dataset).
    topics : the two image topics read, and why (bag to dataset).
    notes : things the user should know.
    """

    n_frames: int
    n_estimated: int = 0
    n_failed: int = 0
    unpaired: int = 0
    topics: str = ""
    notes: tuple[str, ...] = ()


def frame_stamps_ns(
    frame: Frame, position: int, start_unix_s: float, fps: float = DEFAULT_FPS
) -> tuple[int, int]:
    """The left and right stamps (ns since the Unix epoch) of a dataset frame (see the module docstring)."""
    meta = frame.meta

    def num(key: str) -> float | None:
        value = meta.get(key)
        ok = isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)
        return float(value) if ok else None

    exact = meta.get("stamp_left_ns"), meta.get("stamp_right_ns")  # a frame that came from a bag
    if all(isinstance(v, int) and not isinstance(v, bool) and v >= 0 for v in exact):
        return int(exact[0]), int(exact[1])
    tl, tr, wall = num("t_left_s"), num("t_right_s"), num("capture_time_unix_s")

    def ns(seconds: float) -> int:
        return round(seconds * 1e9)

    if wall is not None:  # when the pair was complete (its later image), less each image's lead on it
        if tl is not None and tr is not None:
            latest = max(tl, tr)
            return ns(wall) - ns(latest - tl), ns(wall) - ns(latest - tr)
        return ns(wall), ns(wall)
    start = ns(start_unix_s)  # separately: a float of ~1.7e9 s holds only ~0.2 us
    if tl is not None and tr is not None:
        return start + ns(tl), start + ns(tr)
    t = frame.time_s if frame.time_s is not None else position / fps
    return start + ns(t), start + ns(t)


def dataset_to_bag(
    dataset: Dataset | str | os.PathLike[str],
    out: str | os.PathLike[str],
    *,
    jig: JigConfig | None = None,
    estimate: bool = True,
    method: str | None = None,
    use_reference: bool = True,
    overwrite: bool = False,
    start_unix_s: float | None = None,
    on_frame: Callable[[int], None] | None = None,
    zstd_level: int = ZSTD_LEVEL,
) -> ConvertSummary:
    """Write a dataset as a ROS 2 bag folder ``out``.

    Parameters
    ----------
    dataset : the dataset or its folder.
    out : the bag folder (:class:`~softjig.io.rosbag.BagWriter`).
    jig : the nominal jig (default: the dataset's ``rig.toml``).
    estimate : estimate every loaded frame and write its pose, normal, markers and estimate.
    method : estimation method (default: the pipeline's).
    use_reference : the refractive method measures indentations against the dataset's reference frame.
    overwrite : replace an existing bag in ``out``.
    start_unix_s : the stamp of a frame at ``time_s = 0`` for frames without a wall-clock time (s since
        the epoch; default now).
    on_frame : called with each frame's index once it is written (progress).
    zstd_level : the bag's zstd level (:class:`~softjig.io.rosbag.BagWriter`'s ``zstd_level``: 1 by
        default; a negative level stores camera images nearly as they are, in a bag ~1.6 times larger
        whose reader decompresses a 1280x720 mono8 pair in ~0.1 ms instead of ~1 ms).

    A bag folder that exists but is incomplete is never left behind on an error before the first frame;
    on an error later, the frames written so far stay a readable bag.
    """
    from softjig.io.batch import BatchSettings, dataset_reference, frame_part_diameter_mm
    from softjig.sensing.estimator import DEFAULT_METHOD, Estimator

    dataset = dataset if isinstance(dataset, Dataset) else Dataset.open(dataset)
    jig = jig or dataset.jig
    method = method or DEFAULT_METHOD
    start = time.time() if start_unix_s is None else float(start_unix_s)
    reference = None
    if estimate and use_reference and method == "refractive":
        reference = dataset_reference(dataset, jig)
    settings = BatchSettings(jig=jig, method=method, reference=reference)
    estimator = Estimator(jig, method=method, reference=reference) if estimate else None
    n_estimated = n_failed = n_frames = 0
    notes: list[str] = []
    simulated = is_simulation(dataset.root)
    with BagWriter(out, jig, overwrite=overwrite, simulated=simulated, zstd_level=zstd_level) as writer:
        for position, frame in enumerate(dataset.iter_frames()):
            left, right = frame.load_left(), frame.load_right()
            sl, sr = frame_stamps_ns(frame, position, start)
            writer.add_pair(left, right, sl, sr, dict(frame.meta))
            n_frames += 1
            if estimate and not frame.reference:
                try:
                    result = estimator.estimate(
                        left, right, part_diameter_mm=frame_part_diameter_mm(frame, settings)
                    )
                except (EstimationError, InputError) as exc:
                    n_failed += 1
                    if len(notes) < 3:
                        notes.append(f"frame {frame.index}: no estimate ({exc})")
                else:
                    writer.add_estimate(sl, result)
                    n_estimated += 1
            if on_frame is not None:
                on_frame(frame.index)
    return ConvertSummary(n_frames, n_estimated, n_failed, notes=tuple(notes))


def bag_to_dataset(
    bag: str | os.PathLike[str],
    out: str | os.PathLike[str],
    *,
    jig: JigConfig | None = None,
    left_topic: str | None = None,
    right_topic: str | None = None,
    tolerance_s: float = DEFAULT_STAMP_TOLERANCE_S,
    overwrite: bool = False,
    on_frame: Callable[[int], None] | None = None,
) -> ConvertSummary:
    """Write a bag's stereo pairs as a dataset folder ``out`` (:class:`~softjig.io.dataset.DatasetWriter`).

    Parameters
    ----------
    bag : a rosbag2 folder or ``.mcap`` file.
    out : the dataset folder.
    jig : the nominal jig (default: the bag's ``/softjig/rig``; required for other bags).
    left_topic, right_topic : the image topics (default: picked, see
        :meth:`~softjig.io.rosbag.BagReader.choose_topics`).
    tolerance_s : largest stamp difference of a pair (s).
    overwrite : replace an existing dataset in ``out``.
    on_frame : called with each written frame's index (progress).

    Raises
    ------
    InputError
        The bag has no usable image topics, carries no rig and none was given, or no images paired.
    """
    with BagReader(bag) as reader:
        topics = reader.choose_topics(left_topic, right_topic)
        jig = jig or reader.rig()
        if jig is None:
            raise InputError(f"{bag} carries no softjig rig (/softjig/rig): pass --config RIG.toml")
        pairs = reader.pairs(topics, tolerance_s=tolerance_s)
        stream = iter(pairs)
        first = next(stream, None)
        if first is None:  # nothing to write: no empty dataset is left behind
            raise no_pairs_error(bag, topics, pairs)
        t0 = min(first.stamp_left_ns, first.stamp_right_ns)
        with DatasetWriter(out, jig, overwrite=overwrite) as writer:
            for pair in itertools.chain([first], stream):
                meta: dict[str, Any] = {
                    k: v for k, v in pair.meta.items() if k not in ("index", "left", "right", "stamp_ns")
                }
                mid_ns = (pair.stamp_left_ns + pair.stamp_right_ns) // 2  # integers: exact to the ns
                meta.update(
                    time_s=round((mid_ns - t0) / 1e9, 9),
                    t_left_s=round((pair.stamp_left_ns - t0) / 1e9, 9),
                    t_right_s=round((pair.stamp_right_ns - t0) / 1e9, 9),
                    capture_time_unix_s=max(pair.stamp_left_ns, pair.stamp_right_ns) / 1e9,
                    stamp_left_ns=pair.stamp_left_ns,
                    stamp_right_ns=pair.stamp_right_ns,
                )
                if "index" in pair.meta:
                    meta["source_index"] = pair.meta["index"]
                if isinstance(meta.get("truth"), dict):
                    meta["truth"] = {k: v for k, v in meta["truth"].items() if k != "markers"}
                index = writer.add_frame(pair.left, pair.right, meta)
                if on_frame is not None:
                    on_frame(index)
        return ConvertSummary(
            pairs.n_pairs,
            unpaired=pairs.unpaired,
            topics=f"{topics.left} and {topics.right} ({topics.reason})",
            notes=tuple(reader.notes),
        )


def no_pairs_error(bag: Any, topics: Any, pairs: Any) -> InputError:
    """The error for a bag whose two image topics gave no pair."""
    counts = pairs.reader.topics
    if pairs.nearest_skew_s is None:
        return InputError(
            f"{bag}: {topics.left} has {counts[topics.left][1]} and {topics.right} has "
            f"{counts[topics.right][1]} messages: nothing to pair"
        )
    return InputError(
        f"{bag}: no image of {topics.left} has one of {topics.right} within {pairs.tolerance_s * 1000:g} ms "
        f"(the nearest stamps differ by {pairs.nearest_skew_s * 1000:.3f} ms): raise --stamp-tolerance if "
        "they are one stereo pair, or name the right topics"
    )
