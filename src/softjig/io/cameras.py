"""Stereo camera sources behind one interface: replay of a dataset, two OpenCV/V4L2 cameras, two RealSense.

Every source is a :class:`StereoSource`: :meth:`~StereoSource.open`, then :meth:`~StereoSource.read` until
:class:`SourceExhausted` (a replay's end), then :meth:`~StereoSource.close` (or use ``with``). ``read``
returns a :class:`StereoFrame` (two images, each with its capture time, so the pair's *skew* is known), or
``None`` when no pair came within the time-out; it raises :class:`CameraError` when a camera failed (the
live loop closes the source, waits and re-opens it).

Sources
-------
:class:`ReplaySource`
    A dataset (``DESIGN.md`` §3) replayed at its recorded rate (``time_s`` of each frame; a fixed frame
    rate where frames have no time) or as fast as possible (every frame, none dropped).
:class:`OpenCVStereoSource`
    Any two cameras OpenCV opens (V4L2 device numbers or paths, or video files): both are *grabbed* one
    after the other and only then decoded, the way OpenCV syncs cameras without a hardware trigger; the
    time of each grab is the image's capture time (host monotonic clock, s).
:class:`RealSenseStereoSource`
    Two Intel RealSense cameras chosen by serial number, colour streams (``pyrealsense2``, the optional
    ``realsense`` extra, imported only here). Each camera streams on its own; frames are paired by their
    device timestamps with :class:`FramePairer`. This path cannot be tested without the cameras.

Pairing (:class:`FramePairer`) is pure: feed it timestamped images of each side, pop pairs whose skew is
within a bound; images that can no longer find a partner are dropped and counted.

Times are seconds; a source's timestamps are on its own clock (a dataset's ``time_s``, the host's
monotonic clock, the cameras' clock) and only differences are meaningful. Every frame also carries the
host's monotonic time at which the pair was complete (:attr:`StereoFrame.received_s`, the reference of
the live loop's latency) and the wall-clock time (:attr:`StereoFrame.wall_time_s`, for messages).
"""

from __future__ import annotations

import abc
import contextlib
import threading
import time
from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from softjig.errors import CameraError, InputError

__all__ = [
    "CameraError",
    "FramePairer",
    "OpenCVStereoSource",
    "RealSenseIRSource",
    "RealSenseStereoSource",
    "ReplaySource",
    "SourceExhausted",
    "SourceSpec",
    "StereoFrame",
    "StereoSource",
    "open_source",
    "parse_source_spec",
]

#: Frame rate assumed for replayed frames without ``time_s`` (a RealSense D435 colour stream), Hz.
DEFAULT_FPS = 30.0


class SourceExhausted(Exception):
    """A finite source (a replay) has delivered its last frame."""


class BadFrame(InputError):
    """One frame of a replay cannot be read (a missing or corrupt image): the source is fine and goes on
    with the next frame, so the loop skips it at once and counts it instead of backing off as it does
    for a failed camera (a back-off per missing image would stall a replay for minutes)."""


@dataclass(frozen=True, eq=False)
class StereoFrame:
    """One stereo pair from a source.

    Attributes
    ----------
    left, right : the images, ``uint8``/``uint16``, ``(H, W)`` gray or ``(H, W, 3)`` RGB.
    t_left_s, t_right_s : each image's capture time on the source's clock (s).
    seq : the source's pair counter, from 0.
    received_s : host monotonic time (:func:`time.monotonic`) when the pair was complete (s).
    wall_time_s : host wall-clock time (Unix, s) when the pair was complete.
    meta : what the source knows about the frame (a replay: the dataset frame's JSON object, whose
        ``index`` is the frame's index in the dataset); empty for cameras.
    """

    left: np.ndarray
    right: np.ndarray
    t_left_s: float
    t_right_s: float
    seq: int
    received_s: float
    wall_time_s: float
    meta: Mapping[str, Any] = field(default_factory=dict)

    @classmethod
    def completed_now(
        cls,
        left: np.ndarray,
        right: np.ndarray,
        t_left_s: float,
        t_right_s: float,
        seq: int,
        meta: Mapping[str, Any] | None = None,
    ) -> StereoFrame:
        """A pair completed now: ``received_s`` and ``wall_time_s`` are the host's clocks at this call."""
        return cls(left, right, t_left_s, t_right_s, seq, time.monotonic(), time.time(), dict(meta or {}))

    @property
    def skew_s(self) -> float:
        """Right capture time minus left capture time (s)."""
        return self.t_right_s - self.t_left_s

    @property
    def time_s(self) -> float:
        """The pair's capture time: the mean of both images' (s, source clock)."""
        return 0.5 * (self.t_left_s + self.t_right_s)

    @property
    def source_index(self) -> int:
        """The frame's index in its dataset (replay), else :attr:`seq`."""
        index = self.meta.get("index")
        return index if isinstance(index, int) else self.seq


class StereoSource(abc.ABC):
    """A pair of cameras, or a recording of one.

    Attributes
    ----------
    name : a short description for messages (``"replay:/data/run1"``, ``"opencv:0,1"``).
    realtime : whether frames come at their own pace (cameras, replay at the recorded rate): a consumer
        that is busy must drop them. ``False`` for a replay as fast as possible, which waits for its
        consumer and never drops.
    """

    name: str = "source"
    realtime: bool = True

    @abc.abstractmethod
    def open(self) -> None:
        """Start delivering (idempotent). Raises :class:`CameraError` if a camera cannot be opened."""

    @abc.abstractmethod
    def read(self, timeout_s: float) -> StereoFrame | None:
        """The next pair, or ``None`` if none came within ``timeout_s`` seconds.

        Raises
        ------
        CameraError
            A camera failed (unplugged, stopped streaming); close and re-open the source to retry.
        SourceExhausted
            A replay delivered its last frame.
        """

    @abc.abstractmethod
    def close(self) -> None:
        """Stop and release the cameras (idempotent)."""

    def __enter__(self) -> StereoSource:
        self.open()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


# ------------------------------------------------------------------------------------------ pairing


class FramePairer:
    """Pair the images of two free-running cameras by timestamp (pure, no I/O, not thread-safe).

    Parameters
    ----------
    max_skew_s : the largest ``|t_right - t_left|`` of a pair (s); half a frame period is a good bound.
    max_pending : images kept per side while waiting for a partner; older ones are dropped.

    Notes
    -----
    Images of each side must be pushed in time order. A left image older than the oldest right one by
    more than ``max_skew_s`` can match no later right image (they are newer still), so it is dropped,
    and symmetrically; when the next image of a side is closer to the other side's head, the head is
    dropped in its favour. :attr:`dropped` counts every image dropped.
    """

    def __init__(self, max_skew_s: float, *, max_pending: int = 4) -> None:
        if not max_skew_s > 0:
            raise InputError(f"max_skew_s must be positive, got {max_skew_s}")
        self.max_skew_s = float(max_skew_s)
        self._sides: dict[str, deque[tuple[float, Any]]] = {
            "left": deque(maxlen=max_pending),
            "right": deque(maxlen=max_pending),
        }
        self.dropped = 0

    def push(self, side: str, t_s: float, image: Any) -> None:
        """Add one image of ``side`` (``"left"`` or ``"right"``) captured at ``t_s``."""
        if side not in self._sides:
            raise InputError(f"side must be 'left' or 'right', got {side!r}")
        queue = self._sides[side]
        if len(queue) == queue.maxlen:
            self.dropped += 1
        queue.append((float(t_s), image))

    def pop(self) -> tuple[tuple[float, Any], tuple[float, Any]] | None:
        """The oldest pair ``((t_left, left), (t_right, right))`` within the skew bound, or ``None``."""
        left, right = self._sides["left"], self._sides["right"]
        while left and right:
            (tl, _), (tr, _) = left[0], right[0]
            if abs(tr - tl) <= self.max_skew_s:
                if len(left) > 1 and abs(left[1][0] - tr) < abs(tr - tl):
                    left.popleft()
                    self.dropped += 1
                    continue
                if len(right) > 1 and abs(right[1][0] - tl) < abs(tr - tl):
                    right.popleft()
                    self.dropped += 1
                    continue
                return left.popleft(), right.popleft()
            (left if tl < tr else right).popleft()
            self.dropped += 1
        return None


# ------------------------------------------------------------------------------------------- replay


class ReplaySource(StereoSource):
    """A dataset replayed as a camera pair.

    Parameters
    ----------
    dataset : a :class:`~softjig.io.dataset.Dataset` or its folder.
    rate : ``"recorded"``: at the recorded rate (each frame's ``time_s``, else ``fps``), frames a busy
        consumer misses are dropped like a camera's; ``"fast"``: every frame, as fast as the consumer
        takes them.
    fps : frame rate of frames without ``time_s`` (Hz).

    The frames' capture times are their recorded ``t_left_s``/``t_right_s`` (recordings), else
    ``time_s``, else ``index / fps``; ``meta`` is the frame's JSON object from ``frames.jsonl``.
    """

    def __init__(self, dataset: Any, *, rate: str = "recorded", fps: float = DEFAULT_FPS) -> None:
        from softjig.io.dataset import Dataset

        if rate not in ("recorded", "fast"):
            raise InputError(f"replay rate must be 'recorded' or 'fast', got {rate!r}")
        if not (np.isfinite(fps) and fps > 0):
            raise InputError(f"fps must be a positive number, got {fps}")
        self.dataset = dataset if isinstance(dataset, Dataset) else Dataset.open(dataset)
        self.rate = rate
        self.fps = float(fps)
        self.realtime = rate == "recorded"
        self.name = f"replay:{self.dataset.root}"
        self._next = 0
        self._t0_source: float | None = None
        self._t0_host: float | None = None

    def _times(self, i: int) -> tuple[float, float]:
        frame = self.dataset[i]
        meta = frame.meta
        tl, tr = meta.get("t_left_s"), meta.get("t_right_s")
        if isinstance(tl, int | float) and isinstance(tr, int | float):
            return float(tl), float(tr)
        t = frame.time_s if frame.time_s is not None else i / self.fps
        return t, t

    def open(self) -> None:
        self._t0_source = self._t0_host = None  # re-opening restarts the clock, not the frames

    def read(self, timeout_s: float) -> StereoFrame | None:
        if self._next >= len(self.dataset):
            raise SourceExhausted(f"{self.name}: all {len(self.dataset)} frames replayed")
        i = self._next
        t_left, t_right = self._times(i)
        if self.realtime:
            t_src = max(t_left, t_right)
            now = time.monotonic()
            if self._t0_host is None or self._t0_source is None:
                self._t0_host, self._t0_source = now, t_src
            due = self._t0_host + (t_src - self._t0_source)
            if due - now > timeout_s:
                time.sleep(max(timeout_s, 0.0))
                return None
            if due > now:
                time.sleep(due - now)
        frame = self.dataset[i]
        self._next += 1  # a frame that cannot be read is skipped, not retried forever
        try:
            left, right = frame.load_left(), frame.load_right()
        except InputError as exc:
            raise BadFrame(f"{self.name}, frame {frame.index}: {exc}") from None
        return StereoFrame.completed_now(left, right, t_left, t_right, i, frame.meta)

    def close(self) -> None:
        pass


# ------------------------------------------------------------------------------------------- OpenCV


def _to_rgb(image: np.ndarray) -> np.ndarray:
    """OpenCV's BGR (or BGRA, or gray) to RGB or gray, ``DESIGN.md`` §1."""
    import cv2

    if image.ndim == 3 and image.shape[2] == 3:
        return cv2.cvtColor(image, cv2.COLOR_BGR2RGB)
    if image.ndim == 3 and image.shape[2] == 4:
        return cv2.cvtColor(image, cv2.COLOR_BGRA2RGB)
    if image.ndim == 3 and image.shape[2] == 1:
        return image[:, :, 0]
    return image


class OpenCVStereoSource(StereoSource):
    """Two cameras opened by OpenCV (V4L2 on Linux), or two video files.

    Parameters
    ----------
    left, right : a device number (``0``), a device path (``/dev/video2``) or a video file.
    width_px, height_px, fps : the mode to ask the cameras for (ignored by video files); ``None`` keeps
        the camera's default.

    Notes
    -----
    :meth:`read` grabs the left camera, then the right, then decodes both: the grabs are as close in
    time as the driver allows, and their host times are the images' capture times, so
    :attr:`StereoFrame.skew_s` is the measured gap between the grabs. Each camera keeps a single buffer
    (``CAP_PROP_BUFFERSIZE = 1``) so that a grab returns a fresh image. A failed grab raises
    :class:`CameraError` (the camera stopped delivering, or a video file ended).
    """

    def __init__(
        self,
        left: int | str,
        right: int | str,
        *,
        width_px: int | None = None,
        height_px: int | None = None,
        fps: float | None = None,
    ) -> None:
        self.devices = (left, right)
        self.width_px, self.height_px, self.fps = width_px, height_px, fps
        self.name = f"opencv:{left},{right}"
        self.realtime = True
        self._caps: list[Any] = []
        self._seq = 0

    def _open_one(self, device: int | str) -> Any:
        import cv2

        cap = cv2.VideoCapture(device)
        if not cap.isOpened():
            cap.release()
            what = f"camera {device}" if isinstance(device, int) else f"{device}"
            raise CameraError(
                f"cannot open {what}: check that it is plugged in, not used by another "
                "program (v4l2-ctl --list-devices lists cameras) and that you may read it"
            )
        cap.set(cv2.CAP_PROP_BUFFERSIZE, 1)
        for prop, value in (
            (cv2.CAP_PROP_FRAME_WIDTH, self.width_px),
            (cv2.CAP_PROP_FRAME_HEIGHT, self.height_px),
            (cv2.CAP_PROP_FPS, self.fps),
        ):
            if value is not None:
                cap.set(prop, float(value))
        return cap

    def open(self) -> None:
        if self._caps:
            return
        caps = []
        try:
            for device in self.devices:
                caps.append(self._open_one(device))
        except BaseException:
            for cap in caps:
                cap.release()
            raise
        self._caps = caps

    def read(self, timeout_s: float) -> StereoFrame | None:
        if not self._caps:
            raise CameraError(f"{self.name} is not open")
        times = []
        for device, cap in zip(self.devices, self._caps, strict=True):
            if not cap.grab():
                raise CameraError(
                    f"camera {device} of {self.name} delivered no image (unplugged, stopped "
                    "streaming, or the end of a video file)"
                )
            times.append(time.monotonic())
        images = []
        for device, cap in zip(self.devices, self._caps, strict=True):
            ok, image = cap.retrieve()
            if not ok or image is None:
                raise CameraError(
                    f"camera {device} of {self.name}: an image was grabbed but could not be decoded"
                )
            images.append(_to_rgb(image))
        seq, self._seq = self._seq, self._seq + 1
        return StereoFrame.completed_now(images[0], images[1], times[0], times[1], seq)

    def close(self) -> None:
        for cap in self._caps:
            cap.release()
        self._caps = []


# ---------------------------------------------------------------------------------------- RealSense


class RealSenseStereoSource(StereoSource):
    """Two Intel RealSense cameras (e.g. the paper's D435s), colour streams, chosen by serial number.

    Parameters
    ----------
    serial_left, serial_right : the cameras' serial numbers (``rs-enumerate-devices -s`` lists them);
        ``None`` for both takes the only two cameras connected, ordered by serial number.
    width_px, height_px, fps : the colour stream's mode (the D435 does 1280 x 720 at 30 Hz).
    max_skew_s : the largest gap between a pair's device timestamps (s); half a frame period by default.

    Notes
    -----
    Mirrors :class:`OpenCVStereoSource`; the images are RGB (``rgb8``). Each camera streams on its own
    and the pairs are formed by device timestamp (:class:`FramePairer`); for the timestamps of two
    cameras to be comparable, enable the global time domain (the default of recent librealsense) or
    sync the cameras by cable. Needs ``pip install 'softjig[realsense]'``. Not covered by the test
    suite (no camera on the test machines).
    """

    def __init__(
        self,
        serial_left: str | None = None,
        serial_right: str | None = None,
        *,
        width_px: int = 1280,
        height_px: int = 720,
        fps: int = 30,
        max_skew_s: float | None = None,
    ) -> None:
        if (serial_left is None) != (serial_right is None):
            raise InputError("give both RealSense serial numbers (left and right) or neither")
        self.serials = (serial_left, serial_right)
        self.width_px, self.height_px, self.fps = int(width_px), int(height_px), int(fps)
        self.max_skew_s = max_skew_s if max_skew_s is not None else 0.5 / self.fps
        self.name = f"realsense:{serial_left},{serial_right}" if serial_left else "realsense"
        self.realtime = True
        self._pipes: list[Any] = []
        self._pairer = FramePairer(self.max_skew_s)
        self._seq = 0

    @staticmethod
    def _rs() -> Any:
        try:
            import pyrealsense2 as rs
        except ImportError:
            raise CameraError(
                "RealSense cameras need pyrealsense2: pip install 'softjig[realsense]'"
            ) from None
        return rs

    def open(self) -> None:
        if self._pipes:
            return
        rs = self._rs()
        connected = sorted(dev.get_info(rs.camera_info.serial_number) for dev in rs.context().query_devices())
        serials = self.serials
        if serials[0] is None:
            if len(connected) != 2:
                raise CameraError(
                    f"found {len(connected)} RealSense cameras ({', '.join(connected) or 'none'}); "
                    "name the two to use: --source realsense:LEFT_SERIAL,RIGHT_SERIAL"
                )
            serials = (connected[0], connected[1])
        missing = [s for s in serials if s not in connected]
        if missing:
            raise CameraError(
                f"RealSense camera {', '.join(missing)} not found; connected: "
                f"{', '.join(connected) or 'none'} (check the cable and the serial numbers)"
            )
        pipes = []
        try:
            for serial in serials:
                config = rs.config()
                config.enable_device(serial)
                config.enable_stream(rs.stream.color, self.width_px, self.height_px, rs.format.rgb8, self.fps)
                pipe = rs.pipeline()
                pipe.start(config)
                pipes.append(pipe)
        except RuntimeError as exc:
            for pipe in pipes:
                pipe.stop()
            raise CameraError(f"cannot start RealSense {serials}: {exc}") from None
        self._pipes = pipes
        self._pairer = FramePairer(self.max_skew_s)

    def read(self, timeout_s: float) -> StereoFrame | None:
        if not self._pipes:
            raise CameraError(f"{self.name} is not open")
        deadline = time.monotonic() + timeout_s
        while True:
            for side, pipe in zip(("left", "right"), self._pipes, strict=True):
                try:
                    frames = pipe.poll_for_frames()
                except RuntimeError as exc:
                    raise CameraError(f"RealSense {side} camera of {self.name} failed: {exc}") from None
                if frames:
                    color = frames.get_color_frame()
                    if color:
                        self._pairer.push(side, color.get_timestamp() / 1000.0, np.array(color.get_data()))
            pair = self._pairer.pop()
            if pair is not None:
                (tl, left), (tr, right) = pair
                seq, self._seq = self._seq, self._seq + 1
                return StereoFrame.completed_now(left, right, tl, tr, seq)
            if time.monotonic() >= deadline:
                return None
            time.sleep(0.002)

    def close(self) -> None:
        for pipe in self._pipes:
            with contextlib.suppress(RuntimeError):  # already stopped or unplugged
                pipe.stop()
        self._pipes = []


class RealSenseIRSource(StereoSource):
    """One RealSense D4xx's infrared 1 and 2 (Y8) as the stereo pair: hardware-synchronised (one sensor,
    one exposure: the two images of a pair share the device's frame number) and rectified on the chip.

    Parameters
    ----------
    serial : the device's serial number; ``None`` takes the only one connected.
    width_px, height_px, fps : 848 x 480 (up to 90 Hz) or 1280 x 720 (up to 30 Hz).
    emitter : leave the dot projector on (off by default: its dots would be taken for markers).
    auto_exposure : the sensor's auto exposure; ``False`` with ``exposure_us`` / ``gain`` to fix them.
    exposure_us, gain : manual exposure (µs) and gain, applied when given.
    device : a ``pyrealsense2`` device to use instead of looking one up (a ``software_device`` in tests).

    Attributes
    ----------
    incomplete : exposures of which one image never came (dropped by the device or the USB link).
    overwritten : complete pairs dropped because the reader fell 4 pairs behind.

    Notes
    -----
    Streams through the sensor directly (``sensor.open`` / ``start`` with a callback), not a pipeline,
    so that a software device runs the same code. Needs ``pip install 'softjig[realsense]'``.
    """

    def __init__(
        self,
        serial: str | None = None,
        *,
        width_px: int = 848,
        height_px: int = 480,
        fps: int = 30,
        emitter: bool = False,
        auto_exposure: bool = True,
        exposure_us: float | None = None,
        gain: float | None = None,
        device: Any = None,
    ) -> None:
        from softjig.io.realsense import check_ir_mode

        check_ir_mode(int(width_px), int(height_px), int(fps))
        self.serial, self.device = serial, device
        self.width_px, self.height_px, self.fps = int(width_px), int(height_px), int(fps)
        self.emitter, self.auto_exposure = bool(emitter), bool(auto_exposure)
        self.exposure_us, self.gain = exposure_us, gain
        self.name = f"realsense-ir:{serial}" if serial else "realsense-ir"
        self.realtime = True
        self._sensor: Any = None
        self._lock = threading.Lock()
        self._pending: dict[int, dict[int, tuple[float, np.ndarray]]] = {}
        self._ready: deque = deque(maxlen=4)  # newest pairs; a slow reader drops
        self._seq = 0
        self.incomplete = 0
        self.overwritten = 0

    def _on_frame(self, frame: Any) -> None:
        """librealsense's callback (its thread): file each infrared image under its frame number."""
        frames = list(frame.as_frameset()) if frame.is_frameset() else [frame]
        with self._lock:
            for f in frames:
                index = f.get_profile().stream_index()
                number = int(f.get_frame_number())
                entry = self._pending.setdefault(number, {})
                entry[index] = (f.get_timestamp() / 1000.0, np.array(f.get_data(), dtype=np.uint8, copy=True))
                if 1 in entry and 2 in entry:
                    if len(self._ready) == self._ready.maxlen:
                        self.overwritten += 1
                    self._ready.append(self._pending.pop(number))
                    for old in [n for n in self._pending if n < number]:
                        del self._pending[old]  # its partner will never come
                        self.incomplete += 1

    def _set(self, rs: Any, option: Any, value: float) -> None:
        if self._sensor.supports(option):
            try:
                self._sensor.set_option(option, float(value))
            except RuntimeError as exc:
                raise CameraError(f"{self.name}: cannot set {option} to {value}: {exc}") from None

    def open(self) -> None:
        if self._sensor is not None:
            return
        from softjig.io.realsense import find_device, infrared_profiles, rs_module

        rs = rs_module()
        device = self.device if self.device is not None else find_device(self.serial)
        sensor, ir1, ir2 = infrared_profiles(device, self.width_px, self.height_px, self.fps)
        self._sensor = sensor
        self._set(rs, rs.option.emitter_enabled, 1.0 if self.emitter else 0.0)
        self._set(rs, rs.option.enable_auto_exposure, 1.0 if self.auto_exposure else 0.0)
        if self.exposure_us is not None:
            self._set(rs, rs.option.exposure, self.exposure_us)
        if self.gain is not None:
            self._set(rs, rs.option.gain, self.gain)
        try:
            sensor.open([ir1, ir2])
            sensor.start(self._on_frame)
        except RuntimeError as exc:  # pragma: no cover - needs a real D4xx (busy or unplugged)
            self._sensor = None
            raise CameraError(f"cannot start {self.name}: {exc}") from None

    def read(self, timeout_s: float) -> StereoFrame | None:
        if self._sensor is None:
            raise CameraError(f"{self.name} is not open")
        deadline = time.monotonic() + timeout_s
        while True:
            with self._lock:
                pair = self._ready.popleft() if self._ready else None
            if pair is not None:
                (tl, left), (tr, right) = pair[1], pair[2]
                seq, self._seq = self._seq, self._seq + 1
                shape = (self.height_px, self.width_px)
                return StereoFrame.completed_now(left.reshape(shape), right.reshape(shape), tl, tr, seq)
            if time.monotonic() >= deadline:
                return None
            time.sleep(0.001)

    def close(self) -> None:
        sensor, self._sensor = self._sensor, None
        if sensor is not None:
            for step in (sensor.stop, sensor.close):
                with contextlib.suppress(RuntimeError):  # already stopped or unplugged
                    step()
        with self._lock:
            self._pending.clear()
            self._ready.clear()


# ---------------------------------------------------------------------------------------- choosing


@dataclass(frozen=True)
class SourceSpec:
    """A parsed ``--source`` value: ``kind`` (``"opencv"``, ``"realsense"`` or ``"realsense-ir"``) and the
    two devices (``realsense-ir``: ``left`` the one device's serial, or ``None``)."""

    kind: str
    left: int | str | None = None
    right: int | str | None = None


def parse_source_spec(text: str) -> SourceSpec:
    """Parse ``--source``: ``opencv:LEFT,RIGHT`` (device numbers, device paths or video files),
    ``realsense`` or ``realsense:LEFT_SERIAL,RIGHT_SERIAL``.

    Raises
    ------
    InputError
        Any other form, with the valid ones.
    """
    usage = (
        "--source must be opencv:LEFT,RIGHT (e.g. opencv:0,1 or opencv:/dev/video0,/dev/video2), "
        f"realsense, realsense:LEFT_SERIAL,RIGHT_SERIAL or realsense-ir[:SERIAL]; got {text!r}"
    )
    kind, _, rest = text.strip().partition(":")
    kind = kind.lower()
    if kind == "realsense-ir":
        if "," in rest:
            raise InputError(f"--source realsense-ir[:SERIAL] names one device; got {text!r}")
        return SourceSpec("realsense-ir", rest.strip() or None)
    if kind == "realsense" and not rest:
        return SourceSpec("realsense")
    if kind not in ("opencv", "realsense"):
        raise InputError(usage)
    parts = [p.strip() for p in rest.split(",")]
    if len(parts) != 2 or not all(parts):
        raise InputError(usage)
    if kind == "realsense":
        return SourceSpec("realsense", parts[0], parts[1])
    devices = [int(p) if p.isdigit() else p for p in parts]
    return SourceSpec("opencv", devices[0], devices[1])


def open_source(
    spec: str | SourceSpec,
    *,
    width_px: int | None = None,
    height_px: int | None = None,
    fps: float | None = None,
) -> StereoSource:
    """A (not yet opened) source for a ``--source`` value (:func:`parse_source_spec`)."""
    spec = parse_source_spec(spec) if isinstance(spec, str) else spec
    if spec.kind == "realsense-ir":
        kw = {k: v for k, v in (("width_px", width_px), ("height_px", height_px)) if v is not None}
        return RealSenseIRSource(
            None if spec.left is None else str(spec.left), **kw, fps=round(fps) if fps else 30
        )
    if spec.kind == "realsense":
        kwargs = {k: v for k, v in (("width_px", width_px), ("height_px", height_px)) if v is not None}
        if fps is not None:
            kwargs["fps"] = round(fps)
        left = None if spec.left is None else str(spec.left)
        right = None if spec.right is None else str(spec.right)
        return RealSenseStereoSource(left, right, **kwargs)
    for device in (spec.left, spec.right):
        if isinstance(device, str) and not device.startswith("/dev/") and not Path(device).exists():
            raise InputError(
                f"--source opencv: {device} is neither a device number, a /dev path nor an "
                "existing video file"
            )
    assert spec.left is not None and spec.right is not None
    return OpenCVStereoSource(spec.left, spec.right, width_px=width_px, height_px=height_px, fps=fps)
