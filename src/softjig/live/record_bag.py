"""Record the live loop to a ROS 2 bag (``softjig live ... --record-bag OUT``): every captured pair, and
each estimate the loop makes, as softjig's topics (:mod:`softjig.io.rosbag`).

:class:`BagRecorder` is both the loop's recorder (it takes every captured pair, like
:class:`~softjig.live.loop.Recorder`) and one of its sinks (it takes each estimate): both go through one
bounded queue to one writer thread, so the camera and the estimator never wait for the disk unless the
source is a lossless replay. Pairs the disk cannot keep up with are counted (``not_recorded``). The bag is
crash-safe (its chunks are flushed as they fill, see :class:`~softjig.io.rosbag.BagWriter`).

Stamps: ROS stamps are wall-clock times. A pair's stamps are the host's wall-clock time at which it was
complete (:attr:`~softjig.io.cameras.StereoFrame.wall_time_s`), less how much earlier each image was
captured than the later of the two (on the source's own clock), so the recorded skew is the source's.
An estimate is stamped with its pair's left stamp.
"""

from __future__ import annotations

import contextlib
import queue
import threading
from pathlib import Path
from typing import Any

from softjig.config import JigConfig
from softjig.errors import InputError
from softjig.io.cameras import StereoFrame
from softjig.io.rosbag import BagWriter
from softjig.live.loop import frame_record_meta

__all__ = ["BagRecorder", "frame_stamps_ns"]


def frame_stamps_ns(frame: StereoFrame) -> tuple[int, int]:
    """A live pair's left and right ROS stamps (ns since the epoch; see the module docstring)."""
    latest = max(frame.t_left_s, frame.t_right_s)
    return (
        round((frame.wall_time_s - (latest - frame.t_left_s)) * 1e9),
        round((frame.wall_time_s - (latest - frame.t_right_s)) * 1e9),
    )


class BagRecorder:
    """Record pairs and estimates to a ROS 2 bag folder in a background thread, with a bounded queue.

    Parameters
    ----------
    path : the bag folder (created; refused if it holds anything unless ``overwrite`` and it is a bag).
    jig : the nominal jig (``/softjig/rig``, ``camera_info``, ``/tf_static``).
    queue_items : pairs and estimates waiting to be written at most.
    default_part : the ``part`` of frames that do not name one (cameras, given a part diameter).
    overwrite : replace an existing bag in ``path``.

    Attributes
    ----------
    recorded, not_recorded : pairs written, and pairs refused (full queue, failed disk).
    error : why recording stopped, or ``None``.
    """

    def __init__(
        self,
        path: str | Path,
        jig: JigConfig,
        *,
        queue_items: int = 16,
        default_part: dict | None = None,
        overwrite: bool = False,
    ) -> None:
        self.writer = BagWriter(path, jig, overwrite=overwrite).open()  # errors surface here, early
        self.default_part = default_part
        self._queue: queue.Queue[tuple[str, Any] | None] = queue.Queue(maxsize=max(2, queue_items))
        self._t0: float | None = None
        self.recorded = 0
        self.not_recorded = 0
        self.estimates_recorded = 0
        self.error: str | None = None
        self._closed = False
        self._thread = threading.Thread(target=self._run, name="softjig-bag-recorder", daemon=True)
        self._thread.start()

    # -- recorder (capture thread)
    def submit(self, frame: StereoFrame, *, wait: bool) -> bool:
        """Queue a pair; without ``wait``, a full queue refuses it (counted in ``not_recorded``)."""
        if self.error is not None or self._closed:
            self.not_recorded += 1
            return False
        try:
            self._queue.put(("pair", frame), block=wait)
        except queue.Full:
            self.not_recorded += 1
            return False
        return True

    # -- sink (estimator thread)
    def on_frame(self, outcome: Any, message: dict[str, Any]) -> None:
        """Queue the pair's estimate, if it has one (never blocks: a full queue drops it)."""
        if outcome.result is None or self.error is not None or self._closed:
            return
        with contextlib.suppress(queue.Full):
            self._queue.put(("estimate", (outcome.frame, outcome.result)), block=False)

    def on_health(self, message: dict[str, Any]) -> None:
        pass

    # -- writer thread
    def _run(self) -> None:
        while True:
            item = self._queue.get()
            if item is None:
                return
            kind, payload = item
            if self.error is not None:
                self.not_recorded += kind == "pair"
                continue
            try:
                if kind == "pair":
                    frame: StereoFrame = payload
                    if self._t0 is None:
                        self._t0 = min(frame.t_left_s, frame.t_right_s)
                    sl, sr = frame_stamps_ns(frame)
                    meta = frame_record_meta(frame, self._t0, self.default_part)
                    if "source_index" in meta:
                        meta["index"] = meta["source_index"]
                    self.writer.add_pair(frame.left, frame.right, sl, sr, meta)
                    self.recorded += 1
                else:
                    frame, result = payload
                    self.writer.add_estimate(frame_stamps_ns(frame)[0], result)
                    self.estimates_recorded += 1
            except (OSError, InputError) as exc:  # a full disk: stop recording, keep sensing
                self.error = f"recording to {self.writer.root} failed: {exc}"
                self.not_recorded += kind == "pair"

    def close(self) -> None:
        """Write what is queued, then close the bag (summary, footer, metadata.yaml). Idempotent."""
        if self._closed:
            return
        self._closed = True
        if self._thread.is_alive():
            self._queue.put(None)
            self._thread.join()
        try:
            self.writer.close()
        except OSError as exc:
            self.error = self.error or f"closing the bag {self.writer.root} failed: {exc}"
