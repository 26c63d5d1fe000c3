"""The live sensing loop: capture -> estimate -> publish, record, view; at camera rate, never dying.

Two threads share one slot:

* the **capture** thread reads the source (:mod:`softjig.io.cameras`) and puts each pair in the slot. A
  real-time source (cameras, a replay at its recorded rate) never waits for the estimator: a pair that
  arrives while the previous one is still waiting replaces it, and the replaced pair is counted as
  *dropped*. A replay "as fast as possible" instead reads its next pair only once the estimator is idle,
  so every frame is estimated and its latency is its processing time. Each pair is also
  handed to the recorder (if any). A camera that fails or falls silent is reported unhealthy at once,
  closed, and re-opened after a back-off (0.5 s doubling to 5 s) until it delivers again: the loop never
  dies of it. A replay's frame that cannot be read (:class:`~softjig.io.cameras.BadFrame`: a missing or
  corrupt image) is not a camera failure: it is skipped at once and counted (``bad_frames``).
* the **estimator** (the caller's thread) takes the newest pair, runs the loop's one
  :class:`~softjig.sensing.estimator.Estimator`, builds the estimate message (:func:`estimate_message`)
  and hands it to the sinks (the ZeroMQ publisher, the viewer). The *latency* of a frame is the time from
  the pair's arrival to its message being ready. Health messages (:func:`health_message`) go out every
  ``health_period_s`` and whenever the camera's health changes.

Ctrl-C (``KeyboardInterrupt`` in the estimator's thread) or :meth:`LiveLoop.stop` end the loop cleanly:
the capture thread is joined, the frames queued for the recorder are written, a last health message with
status ``"stopped"`` is sent, and the summary (:class:`LiveSummary`) is returned.

Recording (:class:`Recorder`) writes the dataset format (``DESIGN.md`` §3) as it goes, in its own thread
with a bounded queue, through :class:`~softjig.io.dataset.DatasetWriter` (each ``frames.jsonl`` line is
written and fsynced after the frame's images, so a killed recorder leaves every completed frame
readable). Frames the disk cannot keep up with are counted (``not_recorded``) rather than queued without
bound; a lossless replay waits for the recorder instead.
"""

from __future__ import annotations

import contextlib
import queue
import statistics
import threading
import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

from softjig.calibration.tilt import TiltCalibration
from softjig.config import JigConfig
from softjig.errors import EstimationError, InputError
from softjig.io.cameras import BadFrame, SourceExhausted, StereoFrame, StereoSource
from softjig.io.workers import signals_unwrapped
from softjig.sensing.identities import ReferenceMarkers

__all__ = [
    "HealthSnapshot",
    "LiveLoop",
    "LiveSettings",
    "LiveSink",
    "LiveSummary",
    "PublisherSink",
    "Recorder",
    "estimate_message",
    "frame_record_meta",
    "health_message",
    "health_status",
]

#: Latencies kept for the median and 95th percentile (the most recent frames).
LATENCY_WINDOW = 10_000


@dataclass(frozen=True)
class LiveSettings:
    """How the loop estimates and how it treats its camera.

    Attributes
    ----------
    jig : the nominal jig of the cameras.
    part_diameter_mm : the crop diameter (mm); ``None`` takes each replayed frame's ``part``.
    calibration : the tilt calibration to apply, if any.
    method : the estimation method (:data:`softjig.sensing.pipeline.METHODS`); ``None``: the pipeline's
        default.
    reference : the unloaded jig's markers the refractive method measures indentations against
        (:mod:`softjig.io.reference`: a reference frame); ``None``: the nominal rest shape. Each
        estimate's ``indentation_reference`` says which.
    max_frames : stop after this many captured pairs (``None``: until the source ends or Ctrl-C).
    read_timeout_s : a camera that delivers nothing for this long is unhealthy (s).
    reopen_after_timeouts : consecutive silent time-outs after which the source is re-opened.
    retry_delay_s, retry_delay_max_s : back-off before re-opening a failed source, doubling (s).
    health_period_s : period of the health messages (s).
    """

    jig: JigConfig
    part_diameter_mm: float | None = None
    calibration: TiltCalibration | None = None
    method: str | None = None
    reference: ReferenceMarkers | None = None
    max_frames: int | None = None
    read_timeout_s: float = 1.0
    reopen_after_timeouts: int = 3
    retry_delay_s: float = 0.5
    retry_delay_max_s: float = 5.0
    health_period_s: float = 1.0

    def __post_init__(self) -> None:
        if self.max_frames is not None and self.max_frames < 1:
            raise InputError(f"--max-frames must be at least 1, got {self.max_frames}")
        if self.part_diameter_mm is not None:  # refused here, not pair after pair
            from softjig.sensing.estimator import check_part_diameter

            check_part_diameter(self.part_diameter_mm, self.jig)
        for name in ("read_timeout_s", "retry_delay_s", "retry_delay_max_s", "health_period_s"):
            if not getattr(self, name) > 0:
                raise InputError(f"{name} must be positive, got {getattr(self, name)}")


@dataclass(frozen=True)
class FrameOutcome:
    """What the estimator made of one pair.

    Attributes
    ----------
    frame : the pair.
    result : the pipeline's result (:class:`~softjig.sensing.pipeline.SensingResult`), or ``None``.
    error : why there is no result, or ``None``.
    exit_code : 0 estimate, 2 bad input, 3 no estimate possible (the command-line contract's codes).
    latency_s : from the pair's arrival to its message being ready (s).
    """

    frame: StereoFrame
    result: Any
    error: str | None
    exit_code: int
    latency_s: float


@dataclass(frozen=True)
class HealthSnapshot:
    """The loop's counters at one moment (the content of a health message).

    Attributes
    ----------
    source : the source's name.
    camera_healthy : whether the camera delivers.
    camera_message : why it is unhealthy, or ``None``.
    last_frame_age_s : time since the last pair arrived (s), ``None`` before the first.
    camera_errors, reopens : camera failures met, and re-openings of the source.
    bad_frames : replayed frames skipped because they cannot be read (a replay's missing images).
    captured, processed, dropped, estimated, failed, recorded, not_recorded : frame counts.
    last_ok : whether the last processed frame gave an estimate (``None`` before the first).
    latency_last_s, latency_median_s, latency_p95_s : latencies (s), ``None`` before the first frame.
    rate_hz : processed frames per second since the previous snapshot.
    stopped : whether the loop has ended.
    """

    source: str
    camera_healthy: bool
    camera_message: str | None
    last_frame_age_s: float | None
    camera_errors: int
    reopens: int
    captured: int
    processed: int
    dropped: int
    estimated: int
    failed: int
    recorded: int
    not_recorded: int
    last_ok: bool | None
    latency_last_s: float | None
    latency_median_s: float | None
    latency_p95_s: float | None
    rate_hz: float
    stopped: bool = False
    bad_frames: int = 0


def health_status(snapshot: HealthSnapshot) -> str:
    """The one-word state a robot acts on.

    ``"stopped"`` the loop ended; ``"unhealthy"`` the camera does not deliver (no estimate can come);
    ``"starting"`` no frame processed yet; ``"no_estimate"`` frames arrive but the last gave no estimate
    (no part on the jig, a part off-centre); ``"ok"`` estimates flow.
    """
    if snapshot.stopped:
        return "stopped"
    if not snapshot.camera_healthy:
        return "unhealthy"
    if snapshot.last_ok is None:
        return "starting"
    return "ok" if snapshot.last_ok else "no_estimate"


def _ms(value: float | None) -> float | None:
    return None if value is None else round(1000.0 * value, 3)


def health_message(snapshot: HealthSnapshot, *, seq: int, time_unix_s: float) -> dict[str, Any]:
    """The payload of a ``softjig.health`` message (schema in ``docs/live.md``)."""
    return {
        "seq": seq,
        "time_unix_s": time_unix_s,
        "status": health_status(snapshot),
        "camera": {
            "source": snapshot.source,
            "healthy": snapshot.camera_healthy,
            "message": snapshot.camera_message,
            "last_frame_age_s": snapshot.last_frame_age_s,
            "errors": snapshot.camera_errors,
            "reopens": snapshot.reopens,
        },
        "frames": {
            "captured": snapshot.captured,
            "processed": snapshot.processed,
            "dropped": snapshot.dropped,
            "estimated": snapshot.estimated,
            "failed": snapshot.failed,
            "recorded": snapshot.recorded,
            "not_recorded": snapshot.not_recorded,
            "unreadable": snapshot.bad_frames,
        },
        "latency_ms": {
            "last": _ms(snapshot.latency_last_s),
            "median": _ms(snapshot.latency_median_s),
            "p95": _ms(snapshot.latency_p95_s),
        },
        "rate_hz": round(snapshot.rate_hz, 3),
    }


def estimate_message(outcome: FrameOutcome, *, seq: int, dropped: int, time_unix_s: float) -> dict[str, Any]:
    """The payload of a ``softjig.estimate`` message (schema in ``docs/live.md``)."""
    frame = outcome.frame
    estimate = outcome.result.estimate.to_dict() if outcome.result is not None else None
    return {
        "seq": seq,
        "time_unix_s": time_unix_s,
        "frame": {
            "seq": frame.seq,
            "index": frame.source_index,
            "capture_time_unix_s": frame.wall_time_s,
            "skew_ms": round(1000.0 * frame.skew_s, 3),
        },
        "latency_ms": _ms(outcome.latency_s),
        "dropped_frames": dropped,
        "ok": outcome.result is not None,
        "estimate": estimate,
        "error": outcome.error,
        "exit_code": outcome.exit_code,
    }


class LiveSink(Protocol):
    """Where the estimator's output goes (a publisher, a viewer)."""

    def on_frame(self, outcome: FrameOutcome, message: dict[str, Any]) -> None: ...

    def on_health(self, message: dict[str, Any]) -> None: ...

    def close(self) -> None: ...


class PublisherSink:
    """Publishes estimate and health messages on a :class:`~softjig.io.stream.Publisher`."""

    def __init__(self, publisher: Any) -> None:
        self.publisher = publisher

    def on_frame(self, outcome: FrameOutcome, message: dict[str, Any]) -> None:
        from softjig.io.stream import TOPIC_ESTIMATE

        self.publisher.publish(TOPIC_ESTIMATE, message)

    def on_health(self, message: dict[str, Any]) -> None:
        from softjig.io.stream import TOPIC_HEALTH

        self.publisher.publish(TOPIC_HEALTH, message)

    def close(self) -> None:
        self.publisher.close()


# -------------------------------------------------------------------------------------------- recorder


def frame_record_meta(frame: StereoFrame, t0_s: float, default_part: dict | None) -> dict[str, Any]:
    """The ``frames.jsonl`` metadata of a recorded pair: times relative to the first pair, the skew, the
    replayed frame's pose, part and truth (without its marker file, which is not copied)."""
    meta: dict[str, Any] = {
        "time_s": round(frame.time_s - t0_s, 6),
        "t_left_s": round(frame.t_left_s - t0_s, 6),
        "t_right_s": round(frame.t_right_s - t0_s, 6),
        "skew_ms": round(1000.0 * frame.skew_s, 3),
        "capture_time_unix_s": frame.wall_time_s,
        "source_seq": frame.seq,
    }
    src = frame.meta
    if "index" in src:
        meta["source_index"] = src["index"]
    for key in ("alpha_deg", "theta_deg", "part", "pose", "reference"):
        if key in src:
            meta[key] = src[key]
    if isinstance(src.get("truth"), dict):
        truth = {k: v for k, v in src["truth"].items() if k != "markers"}
        if truth:
            meta["truth"] = truth
    if "part" not in meta and not meta.get("reference") and default_part is not None:
        meta["part"] = default_part
    return meta


class Recorder:
    """Record pairs to a dataset folder in a background thread, with a bounded queue.

    Parameters
    ----------
    path : the dataset folder (created; refused if it holds anything unless ``overwrite``).
    jig : the nominal jig, written as ``rig.toml``.
    queue_frames : pairs waiting to be written at most.
    default_part : the ``part`` entry of frames that do not name one (cameras, given a part diameter).
    overwrite : replace a dataset softjig simulated in ``path`` (never a recording:
        :class:`~softjig.io.dataset.DatasetWriter`).
    """

    def __init__(
        self,
        path: str | Path,
        jig: JigConfig,
        *,
        queue_frames: int = 8,
        default_part: dict | None = None,
        overwrite: bool = False,
    ) -> None:
        from softjig.io.dataset import DatasetWriter

        self.writer = DatasetWriter(path, jig, overwrite=overwrite).open()  # errors surface here, early
        self.default_part = default_part
        self._queue: queue.Queue[StereoFrame | None] = queue.Queue(maxsize=max(1, queue_frames))
        self._t0: float | None = None
        self.recorded = 0
        self.not_recorded = 0
        self.error: str | None = None
        self._thread = threading.Thread(target=self._run, name="softjig-recorder", daemon=True)
        self._thread.start()

    def submit(self, frame: StereoFrame, *, wait: bool) -> bool:
        """Queue a pair; without ``wait``, a full queue refuses it (counted in ``not_recorded``)."""
        if self.error is not None:
            self.not_recorded += 1
            return False
        try:
            self._queue.put(frame, block=wait)
        except queue.Full:
            self.not_recorded += 1
            return False
        return True

    def _run(self) -> None:
        while True:
            frame = self._queue.get()
            if frame is None:
                return
            if self.error is not None:
                self.not_recorded += 1
                continue
            if self._t0 is None:
                self._t0 = min(frame.t_left_s, frame.t_right_s)
            try:
                self.writer.add_frame(
                    frame.left, frame.right, frame_record_meta(frame, self._t0, self.default_part)
                )
                self.recorded += 1
            except (OSError, InputError) as exc:  # a full disk: stop recording, keep sensing
                self.error = f"recording to {self.writer.root} failed: {exc}"
                self.not_recorded += 1

    def close(self) -> None:
        """Write what is queued, then close the dataset."""
        if self._thread.is_alive():
            self._queue.put(None)
            self._thread.join()
        self.writer.close()


# ---------------------------------------------------------------------------------------------- loop


@dataclass(frozen=True)
class LiveSummary:
    """How a run went.

    Attributes
    ----------
    final : the loop's counters at the end (frames captured, processed, dropped, estimated, failed,
        recorded; camera errors; latencies): the last health message's content.
    duration_s : wall time of the run (s).
    interrupted : whether Ctrl-C (or :meth:`LiveLoop.stop`) ended it.
    exhausted : whether the source ended (a replay's last frame).
    last_error, last_exit_code : the last estimation error, if any, and its exit code (2 or 3).
    sink_errors : errors raised by sinks (each is reported once, then the loop goes on).
    first_bad_frame : why the first skipped replay frame could not be read, if any (see
        :attr:`HealthSnapshot.bad_frames`).
    """

    final: HealthSnapshot
    duration_s: float
    interrupted: bool
    exhausted: bool
    last_error: str | None = None
    last_exit_code: int = 0
    sink_errors: tuple[str, ...] = field(default_factory=tuple)
    first_bad_frame: str | None = None

    @property
    def throughput_hz(self) -> float:
        """Processed frames per second of the run."""
        return self.final.processed / self.duration_s if self.duration_s > 0 else 0.0


def _percentile(values: Sequence[float], q: float) -> float:
    ordered = sorted(values)
    k = min(len(ordered) - 1, max(0, round(q * (len(ordered) - 1))))
    return ordered[k]


class LiveLoop:
    """Capture, estimate and publish until the source ends, ``max_frames`` pairs, Ctrl-C or :meth:`stop`.

    Parameters
    ----------
    source : the cameras or a replay (opened by :meth:`run` and closed when it ends).
    settings : how to estimate and how to treat the camera.
    sinks : where estimates and health go (:class:`PublisherSink`, a viewer).
    recorder : records every captured pair, if given (closed when the loop ends).
    on_outcome : called with each :class:`FrameOutcome` and its message (progress, tests).
    """

    def __init__(
        self,
        source: StereoSource,
        settings: LiveSettings,
        *,
        sinks: Sequence[LiveSink] = (),
        recorder: Recorder | None = None,
        on_outcome: Any = None,
    ) -> None:
        self.source = source
        self.settings = settings
        self.sinks = list(sinks)
        self.recorder = recorder
        self.on_outcome = on_outcome
        self._stop = threading.Event()
        self._cond = threading.Condition()
        self._pending: StereoFrame | None = None
        self._busy = False  # the estimator is working on a pair
        self._exhausted = False
        self._capture_done = False
        self._health_dirty = False
        # counters (written by one thread each; read under the condition's lock for snapshots)
        self._captured = self._dropped = self._processed = self._estimated = self._failed = 0
        self._camera_errors = self._reopens = self._bad_frames = 0
        self._first_bad_frame: str | None = None
        self._camera_healthy = True
        self._camera_message: str | None = None
        self._last_frame_s: float | None = None
        self._last_ok: bool | None = None
        self._last_error: str | None = None
        self._last_exit_code = 0
        self._latencies: deque[float] = deque(maxlen=LATENCY_WINDOW)
        self._health_seq = 0
        self._estimate_seq = 0
        self._rate_mark = (time.monotonic(), 0)
        self._sink_errors: list[str] = []
        self._estimator: Any = None  # built on the first pair (estimator())
        self._reference = settings.reference  # replaced by use_reference
        self._estimator_lock = threading.Lock()  # the estimator's thread builds, a request replaces

    # -- control
    def stop(self) -> None:
        """Ask the loop to end (thread-safe; the loop returns its summary shortly after)."""
        self._stop.set()
        with self._cond:
            self._cond.notify_all()

    # -- capture thread
    def _set_camera(self, healthy: bool, message: str | None) -> None:
        with self._cond:
            if healthy != self._camera_healthy or (not healthy and message != self._camera_message):
                self._health_dirty = True
            self._camera_healthy, self._camera_message = healthy, message
            self._cond.notify_all()

    def _capture(self) -> None:
        settings = self.settings
        delay = settings.retry_delay_s
        opened = True
        silent = 0
        try:
            while not self._stop.is_set():
                if settings.max_frames is not None and self._captured >= settings.max_frames:
                    return
                if not self.source.realtime:  # lossless: read the next pair only once the estimator is
                    with self._cond:  # idle, so that latency measures processing, not a backlog
                        while (self._pending is not None or self._busy) and not self._stop.is_set():
                            self._cond.wait(0.1)
                try:
                    if not opened:
                        self.source.open()
                        opened = True
                        self._reopens += 1
                    frame = self.source.read(settings.read_timeout_s)
                except SourceExhausted:
                    self._exhausted = True
                    return
                except BadFrame as exc:  # the source is fine: on to the next frame, no back-off
                    with self._cond:
                        self._bad_frames += 1
                        self._first_bad_frame = self._first_bad_frame or str(exc)
                    continue
                except Exception as exc:
                    self._camera_errors += 1
                    self._set_camera(False, f"{self.source.name}: {exc}")
                    with contextlib.suppress(Exception):
                        self.source.close()
                    opened = False
                    self._stop.wait(delay)
                    delay = min(2.0 * delay, settings.retry_delay_max_s)
                    continue
                if frame is None:
                    silent += 1
                    self._set_camera(
                        False, f"{self.source.name}: no image for {silent * settings.read_timeout_s:.1f} s"
                    )
                    if silent >= settings.reopen_after_timeouts:
                        self._camera_errors += 1
                        with contextlib.suppress(Exception):
                            self.source.close()
                        opened, silent = False, 0
                    continue
                silent, delay = 0, settings.retry_delay_s
                self._set_camera(True, None)
                self._captured += 1
                self._last_frame_s = frame.received_s
                if self.recorder is not None:
                    self.recorder.submit(frame, wait=not self.source.realtime)
                with self._cond:
                    if self.source.realtime:
                        if self._pending is not None:
                            self._dropped += 1
                    else:
                        while self._pending is not None and not self._stop.is_set():
                            self._cond.wait(0.1)
                    self._pending = frame
                    self._cond.notify_all()
        finally:
            with self._cond:
                self._capture_done = True
                self._cond.notify_all()

    # -- estimator
    def _part_diameter_mm(self, frame: StereoFrame) -> float | None:
        """The given diameter, else the replayed frame's part's, else ``None`` (the pipeline decides
        whether it needs one: the paper's method does, and says so)."""
        if self.settings.part_diameter_mm is not None:
            return self.settings.part_diameter_mm
        from softjig.config import part_from_dict

        part = frame.meta.get("part")
        if not isinstance(part, dict):
            return None
        return float(part_from_dict(part).diameter_mm)  # a box's is its inscribed circle's

    def _estimate(self, frame: StereoFrame) -> FrameOutcome:
        result, error, code = None, None, 0
        try:
            estimator = self.estimator()
            result = estimator.estimate(
                frame.left, frame.right, part_diameter_mm=self._part_diameter_mm(frame)
            )
        except EstimationError as exc:
            error, code = str(exc), 3
        except InputError as exc:
            error, code = str(exc), 2
        return FrameOutcome(frame, result, error, code, time.monotonic() - frame.received_s)

    def estimator(self) -> Any:
        """The settings' :class:`~softjig.sensing.estimator.Estimator`, built on the first pair (by the one
        thread that estimates) and kept for the loop's life; a settings error is each pair's error."""
        estimator = self._estimator
        if estimator is not None:
            return estimator
        with self._estimator_lock:
            if self._estimator is None:
                from softjig.sensing.estimator import DEFAULT_METHOD, Estimator

                self._estimator = Estimator(
                    self.settings.jig,
                    method=self.settings.method or DEFAULT_METHOD,
                    reference=self._reference,
                    calibration=self.settings.calibration,
                )
            return self._estimator

    def use_reference(
        self, reference: ReferenceMarkers, *, warm: Callable[[Any], object] | None = None
    ) -> None:
        """Estimate against ``reference`` from the next pair on (thread-safe: the estimator is replaced
        whole, its jig's model shared; a pair being estimated keeps the one it started with).

        ``warm`` is called with the new estimator before it replaces the one in use (a warm-up,
        :func:`softjig.live.serve.warm_estimator`), so the first pair against it costs what later ones do.
        """
        replacement = self.estimator().with_reference(reference)
        if warm is not None:
            warm(replacement)
        with self._estimator_lock:
            self._reference = reference
            self._estimator = replacement

    @property
    def reference_source(self) -> str:
        """What the loop's refractive estimates measure indentations against: ``"reference frame"`` or
        ``"rest shape"``."""
        return "rest shape" if self._reference is None else self._reference.source

    def snapshot(self, *, stopped: bool = False) -> HealthSnapshot:
        """The loop's counters now (thread-safe)."""
        now = time.monotonic()
        with self._cond:
            lat = list(self._latencies)
            t_mark, n_mark = self._rate_mark
            rate = (self._processed - n_mark) / (now - t_mark) if now > t_mark else 0.0
            self._rate_mark = (now, self._processed)
            return HealthSnapshot(
                source=self.source.name,
                camera_healthy=self._camera_healthy,
                camera_message=self._camera_message,
                last_frame_age_s=None if self._last_frame_s is None else now - self._last_frame_s,
                camera_errors=self._camera_errors,
                bad_frames=self._bad_frames,
                reopens=self._reopens,
                captured=self._captured,
                processed=self._processed,
                dropped=self._dropped,
                estimated=self._estimated,
                failed=self._failed,
                recorded=self.recorder.recorded if self.recorder else 0,
                not_recorded=self.recorder.not_recorded if self.recorder else 0,
                last_ok=self._last_ok,
                latency_last_s=lat[-1] if lat else None,
                latency_median_s=statistics.median(lat) if lat else None,
                latency_p95_s=_percentile(lat, 0.95) if lat else None,
                rate_hz=rate,
                stopped=stopped,
            )

    def _call_sinks(self, method: str, *args: Any) -> None:
        for sink in self.sinks:
            try:
                getattr(sink, method)(*args)
            except Exception as exc:
                note = f"{type(sink).__name__}.{method} failed: {exc}"
                if note not in self._sink_errors:
                    self._sink_errors.append(note)

    def _publish_health(self, *, stopped: bool = False) -> None:
        message = health_message(
            self.snapshot(stopped=stopped), seq=self._health_seq, time_unix_s=time.time()
        )
        self._health_seq += 1
        self._call_sinks("on_health", message)

    def _handle(self, frame: StereoFrame) -> None:
        outcome = self._estimate(frame)
        with self._cond:
            self._processed += 1
            self._latencies.append(outcome.latency_s)
            self._last_ok = outcome.result is not None
            if outcome.result is not None:
                self._estimated += 1
            else:
                self._failed += 1
                self._last_error, self._last_exit_code = outcome.error, outcome.exit_code
            dropped = self._dropped
        message = estimate_message(outcome, seq=self._estimate_seq, dropped=dropped, time_unix_s=time.time())
        self._estimate_seq += 1
        self._call_sinks("on_frame", outcome, message)
        if self.on_outcome is not None:
            self.on_outcome(outcome, message)

    def run(self) -> LiveSummary:
        """Run until the end; returns the summary. The source is opened here (a camera that cannot be
        opened at all raises :class:`~softjig.io.cameras.CameraError`, exit code 2) and closed on exit."""
        t_start = time.monotonic()
        try:
            self.source.open()
        except BaseException:  # nothing ran: the recorder and the sinks are closed all the same
            if self.recorder is not None:
                self.recorder.close()  # an overwrite with no frame leaves the old recording in place
            for sink in self.sinks:
                with contextlib.suppress(Exception):
                    sink.close()
            raise
        capture = threading.Thread(target=self._capture, name="softjig-capture", daemon=True)
        interrupted = False
        next_health = time.monotonic()
        try:
            capture.start()
            while True:
                frame = None
                with self._cond:
                    if self._pending is None and not self._capture_done and not self._stop.is_set():
                        wait = max(0.0, min(next_health - time.monotonic(), 0.25))
                        self._cond.wait(wait)
                    frame, self._pending = self._pending, None
                    if frame is not None:
                        self._busy = True
                        self._cond.notify_all()
                    finished = frame is None and (self._capture_done or self._stop.is_set())
                    dirty, self._health_dirty = self._health_dirty, False
                if dirty or time.monotonic() >= next_health:
                    self._publish_health()
                    next_health = time.monotonic() + self.settings.health_period_s
                if frame is not None:
                    with signals_unwrapped():  # a Ctrl-C inside a compiled kernel: a KeyboardInterrupt
                        self._handle(frame)
                    with self._cond:
                        self._busy = False
                        self._cond.notify_all()
                elif finished:
                    break
            interrupted = self._stop.is_set()
        except KeyboardInterrupt:
            interrupted = True
        finally:
            self._stop.set()
            with self._cond:
                self._cond.notify_all()
            capture.join(timeout=max(5.0, 2 * self.settings.read_timeout_s))
            with contextlib.suppress(Exception):
                self.source.close()
            if self.recorder is not None:
                self.recorder.close()
            self._publish_health(stopped=True)
            for sink in self.sinks:
                with contextlib.suppress(Exception):
                    sink.close()
        return LiveSummary(
            final=self.snapshot(stopped=True),
            duration_s=time.monotonic() - t_start,
            interrupted=interrupted,
            exhausted=self._exhausted,
            last_error=self._last_error,
            last_exit_code=self._last_exit_code,
            sink_errors=tuple(self._sink_errors),
            first_bad_frame=self._first_bad_frame,
        )
