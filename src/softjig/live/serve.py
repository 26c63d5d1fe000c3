"""A warm estimation service a robot asks (``softjig serve``): ZeroMQ REP, one JSON reply per JSON request.

The robot does not start a process (1-3 s) for a 2-5 ms estimate, nor subscribe to a stream and keep its
own books: it asks, and gets the answer to its question. Requests (one JSON object each):

- ``{"op": "estimate", "timeout_s": T}`` -> ``"estimate"``: the estimate (the estimate contract's
  fields) of the first pair captured after the request; ``"frame"`` (its capture time and skew),
  ``"latency_ms"`` (pair to estimate), ``"waited_ms"`` (request to reply);
- ``{"op": "settled", "timeout_s": T}`` -> the same, once the estimate has stayed within its own sigma for
  ``settle_s`` (:mod:`softjig.live.settle`), counted from the request; else
  ``{"ok": false, "error": "timeout ..."}``;
- ``{"op": "fix"}``, ``{"op": "release"}`` -> ``"pump"``: the pump controller's state once the jig holds
  (or its error: the jig is then in its safe state);
- ``{"op": "reference", "timeout_s": T}`` -> ``"reference"``: the first pair captured after the request
  becomes the unloaded reference the estimates measure their indentations against from then on (ask it
  while the jig is empty and released); a pair with a part pressed in, or not of this rig, is refused
  (:func:`softjig.io.reference.reference_from_pair`) and the reference in use is kept;
- ``{"op": "health"}`` -> ``"health"``: the live loop's health message (``docs/live.md``), ``"pump"``,
  ``"settle_s"``, ``"reference"`` (``"reference frame"`` or ``"rest shape"``).

Every reply carries ``"ok"``, ``"schema": "softjig.reply"`` and ``"version": 1``. A failure is
``{"ok": false, "schema": ..., "version": ..., "error": "..."}`` (and ``"exit_code"`` 2 or 3
when the pair gave no estimate). A request that is not JSON, not an object, names an unknown op, or is
longer than ``max_request_bytes`` gets such a reply and the service goes on; a message longer than
:data:`HARD_MAX_MESSAGE_BYTES` is refused by ZeroMQ itself (``ZMQ_MAXMSGSIZE``: the sender is
disconnected and gets no reply), so no request can exhaust the memory.

**Warm before the cameras open.** The loop's own estimator (its method, calibration and reference) is
built and run once on a pair (a replay's first loaded frame, or a pair rendered from the jig) before the
source is opened (:meth:`EstimationService.warm_up`): the Numba kernels are loaded and the per-jig and
per-reference tables built, so the first pair after start is estimated as fast as the hundredth. A
``reference`` request warms the new estimator on that pair again before it replaces the one in use.
``health`` says what the last warm-up ran (``"warmed_up"``).

Threads: the live loop (:class:`~softjig.live.loop.LiveLoop`, which owns capture and estimation) runs in
a background thread and posts every outcome to an :class:`OutcomeBoard`; the caller's thread answers
requests. :meth:`EstimationService.stop` (SIGINT, SIGTERM) ends both, and sends the pump to its safe state.
"""

from __future__ import annotations

import contextlib
import dataclasses
import itertools
import json
import math
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from softjig.errors import InputError, SoftjigError
from softjig.io.cameras import SourceExhausted, StereoFrame, StereoSource
from softjig.live.loop import FrameOutcome, LiveLoop, LiveSettings, health_message
from softjig.live.settle import DEFAULT_SETTLE_SIGMAS, Sample, settled_since

__all__ = [
    "HARD_MAX_MESSAGE_BYTES",
    "OPS",
    "REPLY_SCHEMA",
    "REPLY_VERSION",
    "EstimationService",
    "LoopingReplay",
    "OutcomeBoard",
    "PumpAdapter",
    "ServeSettings",
    "WarmUp",
    "rendered_warm_up_pair",
    "warm_estimator",
    "warm_up",
]

REPLY_SCHEMA = "softjig.reply"
REPLY_VERSION = 1
OPS = ("estimate", "settled", "fix", "release", "health", "reference")
#: Largest request answered (bytes); longer ones get an error reply.
DEFAULT_MAX_REQUEST_BYTES = 64 * 1024
#: Largest message ZeroMQ accepts at all (bytes; ``ZMQ_MAXMSGSIZE``): the sender of a longer one is
#: disconnected.
HARD_MAX_MESSAGE_BYTES = 1024 * 1024
#: Outcomes kept for ``settled`` (at 90 Hz, 11 s).
HISTORY = 1024
#: Pairs (their images) kept for a ``reference`` request: the newest few, so a request finds the first
#: pair after it however soon after the estimator's thread its own thread wakes.
PAIRS_KEPT = 4


@dataclass(frozen=True)
class ServeSettings:
    """How the service answers.

    Attributes
    ----------
    endpoint : where the REP socket binds (``tcp://127.0.0.1:PORT``; loopback unless ``allow_remote``).
    allow_remote : allow a non-loopback address (trusted cell networks only).
    settle_s : how long an estimate must stay within its sigma to be settled (s).
    settle_sigmas : the band, in the estimates' own sigmas (:mod:`softjig.live.settle`).
    max_request_bytes : longer requests get an error reply.
    default_timeout_s : an ``estimate``/``settled`` request's wait without its own ``timeout_s`` (s).
    max_timeout_s : the longest wait a request may ask for (s).
    pump_timeout_s : how long ``fix``/``release`` wait for the jig to hold (s).
    """

    endpoint: str = "tcp://127.0.0.1:5556"
    allow_remote: bool = False
    settle_s: float = 0.5
    settle_sigmas: float = DEFAULT_SETTLE_SIGMAS
    max_request_bytes: int = DEFAULT_MAX_REQUEST_BYTES
    default_timeout_s: float = 5.0
    max_timeout_s: float = 300.0
    pump_timeout_s: float = 10.0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.settle_s) and self.settle_s >= 0):
            raise InputError(f"settle_s must be a non-negative number of seconds, got {self.settle_s}")
        for name in ("settle_sigmas", "default_timeout_s", "max_timeout_s", "pump_timeout_s"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise InputError(f"{name} must be a positive number, got {value}")
        if not 0 < self.max_request_bytes <= HARD_MAX_MESSAGE_BYTES:
            raise InputError(
                f"max_request_bytes must be 1-{HARD_MAX_MESSAGE_BYTES}, got {self.max_request_bytes}"
            )


# ----------------------------------------------------------------------------------------------- pump


class PumpAdapter:
    """The service's only contact with :mod:`softjig.hardware.pump` (one place to adjust if its API
    changes): fix, release, status, the safe state, and the heartbeat while the jig holds.

    After ``fix`` a background thread polls ``STATUS`` every
    :data:`~softjig.hardware.protocol.HEARTBEAT_PERIOD_S` (as ``softjig jig hold`` does), so the
    controller's watchdog stays fed while the jig holds the part between requests; a fault it meets sends
    the controller to its safe state (the driver does) and is reported by ``health``. One lock serialises
    the serial line between the requests and the heartbeat.

    Parameters
    ----------
    port : the pump controller's serial port (or a serial-like object, tests).
    timeout_s : how long fix and release wait for the jig to hold (s).
    """

    def __init__(self, port: Any, *, timeout_s: float = 10.0) -> None:
        from softjig.hardware.pump import PumpController

        self.timeout_s = float(timeout_s)
        self._pump = PumpController(port)
        self._lock = threading.Lock()
        self._holding = threading.Event()
        self._closed = threading.Event()
        self.heartbeat_error: str | None = None
        self._heart = threading.Thread(target=self._heartbeat, name="softjig-pump-heartbeat", daemon=True)
        self._heart.start()

    def _heartbeat(self) -> None:
        from softjig.hardware.protocol import HEARTBEAT_PERIOD_S

        while not self._closed.wait(HEARTBEAT_PERIOD_S):
            if not self._holding.is_set():
                continue
            with self._lock:
                if not self._holding.is_set():
                    continue
                try:
                    status = self._pump.status()
                except SoftjigError as exc:
                    self.heartbeat_error = str(exc)
                    self._holding.clear()
                    continue
                if status.state != "fixed":
                    self.heartbeat_error = f"the jig left 'fixed' while holding (state {status.state})"
                    self._holding.clear()

    def fix(self) -> dict[str, Any]:
        with self._lock:
            status = self._pump.fix(wait=True, timeout_s=self.timeout_s).to_dict()
            self.heartbeat_error = None
            self._holding.set()
            return status

    def release(self) -> dict[str, Any]:
        with self._lock:
            self._holding.clear()
            return self._pump.release(wait=True, timeout_s=self.timeout_s).to_dict()

    @property
    def holding(self) -> bool:
        """Whether the jig was fixed and not released since (the heartbeat keeps it so)."""
        return self._holding.is_set()

    def status(self) -> dict[str, Any]:
        with self._lock:
            status = self._pump.status().to_dict()
        return {**status, "holding": self._holding.is_set(), "heartbeat_error": self.heartbeat_error}

    def safe(self) -> None:
        """The safe state (``STOP``), best effort: the way out of every exit."""
        self._holding.clear()
        with self._lock, contextlib.suppress(Exception):
            self._pump.safe()

    def close(self) -> None:
        self._closed.set()
        self.safe()
        self._heart.join(timeout=5.0)
        self._pump.close()


# ------------------------------------------------------------------------------------------- sources


class LoopingReplay(StereoSource):
    """A replay that starts again at its first frame when it ends (a service outlives its recording).

    Parameters
    ----------
    make : builds a fresh, unopened :class:`~softjig.io.cameras.ReplaySource` (called at each lap).
    """

    def __init__(self, make: Callable[[], StereoSource]) -> None:
        self._make = make
        self._source = make()
        self.name = self._source.name
        self.realtime = self._source.realtime
        self._offset = 0
        self._last_seq = -1
        self.laps = 0

    def open(self) -> None:
        self._source.open()

    def read(self, timeout_s: float) -> StereoFrame | None:
        try:
            frame = self._source.read(timeout_s)
        except SourceExhausted:
            self._source.close()
            self._offset, self.laps = self._offset + self._last_seq + 1, self.laps + 1
            self._source = self._make()
            self._source.open()
            frame = self._source.read(timeout_s)
        if frame is None:
            return None
        self._last_seq = frame.seq
        return dataclasses.replace(frame, seq=frame.seq + self._offset)

    def close(self) -> None:
        self._source.close()


# ------------------------------------------------------------------------------------------- outcomes


@dataclass(frozen=True)
class _Posted:
    received_s: float
    sample: Sample
    message: dict[str, Any]


class OutcomeBoard:
    """The live loop's outcomes, for requests to wait on (thread-safe).

    :meth:`post` is the loop's ``on_outcome``; :meth:`first_after` and :meth:`settled_after` wait for
    outcomes of pairs captured (complete, :attr:`~softjig.io.cameras.StereoFrame.received_s`) after a
    moment of the host's monotonic clock.
    """

    def __init__(self, history: int = HISTORY) -> None:
        self._cond = threading.Condition()
        self._posted: deque[_Posted] = deque(maxlen=history)
        self._pairs: deque[StereoFrame] = deque(maxlen=PAIRS_KEPT)
        self.ended: str | None = None

    def post(self, outcome: FrameOutcome, message: dict[str, Any]) -> None:
        est = message.get("estimate")
        sample = Sample(
            t_s=outcome.frame.received_s,
            normal=tuple(est["normal"]) if est else None,
            sigma_deg=est.get("tilt_sigma_deg") if est else None,
        )
        with self._cond:
            self._posted.append(_Posted(outcome.frame.received_s, sample, message))
            self._pairs.append(outcome.frame)
            self._cond.notify_all()

    def end(self, why: str) -> None:
        """The loop stopped: waiting requests are answered with ``why``."""
        with self._cond:
            self.ended = why
            self._cond.notify_all()

    def _wait(self, pick: Callable[[list[Any]], Any], deadline: float, *, pairs: bool = False) -> Any:
        with self._cond:
            while True:
                found = pick(list(self._pairs if pairs else self._posted))
                if found is not None or self.ended is not None:
                    return found
                left = deadline - time.monotonic()
                if left <= 0:
                    return None
                self._cond.wait(min(left, 0.5))

    def first_after(self, t_s: float, deadline: float) -> dict[str, Any] | None:
        """The message of the first pair captured after ``t_s``, or ``None`` at ``deadline``."""

        def pick(posted: list[_Posted]) -> _Posted | None:
            return next((p for p in posted if p.received_s > t_s), None)

        found = self._wait(pick, deadline)
        return None if found is None else found.message

    def pair_after(self, t_s: float, deadline: float) -> StereoFrame | None:
        """The first pair captured after ``t_s`` (its images), or ``None`` at ``deadline``."""

        def pick(pairs: list[StereoFrame]) -> StereoFrame | None:
            return next((p for p in pairs if p.received_s > t_s), None)

        return self._wait(pick, deadline, pairs=True)

    def settled_after(self, t_s: float, settle_s: float, k: float, deadline: float) -> dict[str, Any] | None:
        """The message of the first pair at which the estimates since ``t_s`` have stayed within ``k`` of
        their sigmas for ``settle_s``, or ``None`` at ``deadline``."""

        def pick(posted: list[_Posted]) -> _Posted | None:
            run = [p for p in posted if p.received_s > t_s]
            for j in range(len(run)):
                if settled_since([p.sample for p in run[: j + 1]], settle_s, k=k):
                    return run[j]
            return None

        found = self._wait(pick, deadline)
        return None if found is None else found.message


# ------------------------------------------------------------------------------------------- warm-up


#: Loaded frames of a replay tried for the warm-up before a rendered pair is used instead.
WARM_UP_CANDIDATES = 5


def first_loaded_pair(dataset: Any) -> tuple[Any, Any, float | None] | None:
    """``(left, right, part_diameter_mm)`` of a dataset's first readable loaded frame among its first
    :data:`WARM_UP_CANDIDATES` (what :func:`warm_up` takes), or ``None`` (warm up on a rendered pair)."""
    loaded = (frame for frame in dataset if not frame.reference)
    for frame in itertools.islice(loaded, WARM_UP_CANDIDATES):
        diameter = None if frame.part is None else float(frame.part.diameter_mm)
        try:
            return frame.load_left(), frame.load_right(), diameter
        except SoftjigError:  # an unreadable frame: the replay skips it too
            continue
    return None


@dataclass(frozen=True)
class WarmUp:
    """What a warm-up did: which estimator it ran, against what, and how long it took.

    Attributes
    ----------
    seconds : wall time of the warm-up (s): the estimator's build, if it was not built yet, and one estimate.
    method : the estimator's method.
    against : what the warm-up estimate measured its indentations against (``"reference frame"``,
        ``"rest shape"``): the estimate's own ``indentation_reference``, so it is the estimator the loop
        uses; ``None`` for the paper's method, or when the pair gave no estimate.
    estimated : whether the pair gave an estimate (one that did not still warmed most of the pipeline).
    """

    seconds: float
    method: str
    against: str | None
    estimated: bool

    def to_dict(self) -> dict[str, Any]:
        """The ``warmed_up`` field of serve's ``health`` reply (milliseconds)."""
        return {
            "ms": round(1000.0 * self.seconds, 3),
            "method": self.method,
            "against": self.against,
            "estimated": self.estimated,
        }

    def __str__(self) -> str:
        against = f", against the {self.against}" if self.against else ""
        failed = "" if self.estimated else " (its pair gave no estimate)"
        return f"warmed up in {self.seconds:.2f} s: the {self.method} estimator{against}{failed}"


def rendered_warm_up_pair(settings: LiveSettings) -> tuple[Any, Any, float | None]:
    """A pair of the nominal jig to warm up on when no recorded one is at hand (cameras): a centred 50 mm
    cylinder tilted by 5 degrees, ``(left, right, part_diameter_mm)``."""
    from softjig.config import CylinderPart
    from softjig.sim.asbuilt import nominal_as_built
    from softjig.sim.parts import PartPose
    from softjig.sim.render import render_pair

    part = CylinderPart(50.0)
    rendered = render_pair(nominal_as_built(settings.jig), part, PartPose(alpha_rad=math.radians(5.0)), 0)
    return rendered.left, rendered.right, settings.part_diameter_mm or part.diameter_mm


def warm_estimator(estimator: Any, settings: LiveSettings, pair: tuple[Any, Any, float | None]) -> WarmUp:
    """Estimate ``pair`` (``(left, right, part_diameter_mm)``) once with ``estimator``; a pair that gives
    no estimate still warms most of the pipeline, and is not an error."""
    left, right, diameter = pair
    t0 = time.perf_counter()
    against = None
    estimated = False
    with contextlib.suppress(SoftjigError):
        result = estimator.estimate(left, right, part_diameter_mm=settings.part_diameter_mm or diameter)
        against, estimated = result.estimate.indentation_reference, True
    return WarmUp(time.perf_counter() - t0, estimator.method, against, estimated)


def warm_up(loop: LiveLoop, pair: tuple[Any, Any, float | None] | None = None) -> WarmUp:
    """Build the loop's own estimator (with its method, calibration and reference) and estimate one pair
    with it, before the cameras open, so the first pair after start costs what the hundredth does.

    The estimator warmed is the one the loop then uses (:meth:`~softjig.live.loop.LiveLoop.estimator`),
    not a throw-away one: a one-shot estimate would load the kernels but leave the loop's estimator, and
    the tables of its jig and reference, to be built on the robot's first pair.

    ``pair`` is ``(left, right, part_diameter_mm)`` (a replay's first loaded frame); without it a pair of
    the nominal jig is rendered (:func:`rendered_warm_up_pair`). A settings error (the estimator cannot be
    built) is left to each pair, as the loop reports it."""
    t0 = time.perf_counter()
    pair = rendered_warm_up_pair(loop.settings) if pair is None else pair
    try:
        estimator = loop.estimator()
    except SoftjigError:
        return WarmUp(time.perf_counter() - t0, loop.settings.method or "refractive", None, False)
    done = warm_estimator(estimator, loop.settings, pair)
    return dataclasses.replace(done, seconds=time.perf_counter() - t0)


# ------------------------------------------------------------------------------------------- service


def _reply(ok: bool, **fields: Any) -> dict[str, Any]:
    return {"ok": ok, "schema": REPLY_SCHEMA, "version": REPLY_VERSION, **fields}


def _error(message: str, **fields: Any) -> dict[str, Any]:
    return _reply(False, error=message, **fields)


class EstimationService:
    """The REP socket, the live loop and the pump, together (see the module docstring).

    Parameters
    ----------
    source : the cameras or a replay (opened when :meth:`start` starts the loop).
    live : how the loop estimates.
    settings : how the service answers.
    pump : the pump, if the service drives one.

    Raises
    ------
    InputError
        The endpoint is malformed, not loopback without ``allow_remote``, or cannot be bound (a busy port).
    """

    def __init__(
        self,
        source: StereoSource,
        live: LiveSettings,
        settings: ServeSettings,
        *,
        pump: PumpAdapter | None = None,
    ) -> None:
        import zmq

        from softjig.io.stream import check_endpoint

        check_endpoint(settings.endpoint, allow_remote=settings.allow_remote)
        self.source, self.live, self.settings, self.pump = source, live, settings, pump
        self.board = OutcomeBoard()
        self.loop = LiveLoop(source, live, on_outcome=self.board.post)
        self.warmed_up: WarmUp | None = None  # the last warm-up (health's "warmed_up")
        self._warm_pair: tuple[Any, Any, float | None] | None = None  # what a new reference is warmed on
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.answered = 0
        self._ctx = zmq.Context()
        self._socket = self._ctx.socket(zmq.REP)
        self._socket.setsockopt(zmq.LINGER, 0)
        self._socket.setsockopt(zmq.MAXMSGSIZE, HARD_MAX_MESSAGE_BYTES)
        try:
            self._socket.bind(settings.endpoint)
        except zmq.ZMQError as exc:
            self._socket.close(0)
            self._ctx.term()
            raise InputError(
                f"cannot bind {settings.endpoint}: {exc} (is another softjig serve or program using that "
                "port? choose another with --bind)"
            ) from None
        self.endpoint = self._socket.getsockopt_string(zmq.LAST_ENDPOINT)

    # -- lifecycle
    def warm_up(self, pair: tuple[Any, Any, float | None] | None = None) -> WarmUp:
        """Warm the loop's estimator on ``pair`` (none: a rendered one) before :meth:`start` opens the
        cameras (:func:`warm_up`); the pair is kept to warm the estimator of a new reference."""
        self._warm_pair = rendered_warm_up_pair(self.live) if pair is None else pair
        self.warmed_up = warm_up(self.loop, self._warm_pair)
        return self.warmed_up

    def _warm_new_estimator(self, estimator: Any) -> None:
        """Warm the estimator of a new reference, before it replaces the one in use (``use_reference``)."""
        if self._warm_pair is not None:
            self.warmed_up = warm_estimator(estimator, self.live, self._warm_pair)

    def start(self) -> None:
        """Start the live loop in its thread (it opens the source)."""

        def run() -> None:
            try:
                summary = self.loop.run()
                why = "the source ended" if summary.exhausted else "the live loop stopped"
            except Exception as exc:  # a source that cannot be opened at all
                why = f"the source failed: {exc}"
            self.board.end(why)

        self._thread = threading.Thread(target=run, name="softjig-serve-loop", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        """Ask :meth:`serve_forever` to return (thread-safe, signal-safe)."""
        self._stop.set()

    def close(self) -> None:
        """Stop the loop, send the pump to its safe state, close the socket."""
        self.loop.stop()
        if self._thread is not None:
            self._thread.join(timeout=10.0)
        if self.pump is not None:
            self.pump.close()
        if not self._socket.closed:
            self._socket.close(0)
            self._ctx.term()

    # -- serving
    def serve_forever(self, *, poll_s: float = 0.1) -> None:
        """Answer requests until :meth:`stop`; one reply per request, whatever it holds."""
        import zmq

        while not self._stop.is_set():
            if not self._socket.poll(int(poll_s * 1000)):
                continue
            try:
                frames = self._socket.recv_multipart(flags=zmq.NOBLOCK)
            except zmq.Again:
                continue
            reply = self.handle(frames)
            self._socket.send(json.dumps(reply, allow_nan=False, default=str).encode("utf-8"))
            self.answered += 1

    def handle(self, frames: list[bytes]) -> dict[str, Any]:
        """The reply to one request's message frames (never raises)."""
        try:
            request = self._parse(frames)
            return self._dispatch(request)
        except InputError as exc:
            return _error(str(exc))
        except SoftjigError as exc:
            return _error(str(exc))
        except Exception as exc:  # the service stays up whatever a request does
            return _error(f"internal error answering the request: {type(exc).__name__}: {exc}")

    def _parse(self, frames: list[bytes]) -> dict[str, Any]:
        size = sum(len(f) for f in frames)
        if size > self.settings.max_request_bytes:
            raise InputError(
                f"request of {size} bytes exceeds the limit of {self.settings.max_request_bytes} bytes"
            )
        if len(frames) != 1:
            raise InputError(f"a request is one message frame holding a JSON object, got {len(frames)}")
        try:
            request = json.loads(frames[0].decode("utf-8"))
        except (UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise InputError(f'request is not JSON ({exc}); send e.g. {{"op": "estimate"}}') from None
        if not isinstance(request, dict):
            raise InputError('a request is a JSON object, e.g. {"op": "estimate"}')
        op = request.get("op")
        if op not in OPS:
            raise InputError(f"unknown op {op!r}; valid: {', '.join(OPS)}")
        return request

    def _timeout(self, request: dict[str, Any]) -> float:
        value = request.get("timeout_s", self.settings.default_timeout_s)
        if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
            raise InputError(f"timeout_s must be a number of seconds, got {value!r}")
        if not 0 < value <= self.settings.max_timeout_s:
            raise InputError(f"timeout_s must be in (0, {self.settings.max_timeout_s:g}] s, got {value}")
        return float(value)

    def _dispatch(self, request: dict[str, Any]) -> dict[str, Any]:
        op = request["op"]
        if op == "health":
            snapshot = self.loop.snapshot()
            pump = None
            if self.pump is not None:
                try:
                    pump = self.pump.status()
                except SoftjigError as exc:
                    pump = {"error": str(exc)}
            health = health_message(snapshot, seq=self.answered, time_unix_s=time.time())
            return _reply(
                True,
                health=health,
                pump=pump,
                settle_s=self.settings.settle_s,
                ended=self.board.ended,
                reference=self.loop.reference_source,
                warmed_up=None if self.warmed_up is None else self.warmed_up.to_dict(),
            )
        if op in ("fix", "release"):
            if self.pump is None:
                return _error(f"{op}: this service drives no pump; start it with --pump PORT")
            return _reply(True, pump=self.pump.fix() if op == "fix" else self.pump.release())
        if op == "reference":
            return self._take_reference(request)
        timeout = self._timeout(request)
        t_request = time.monotonic()
        deadline = t_request + timeout
        if op == "estimate":
            message = self.board.first_after(t_request, deadline)
            what = "a pair captured after the request"
        else:
            message = self.board.settled_after(
                t_request, self.settings.settle_s, self.settings.settle_sigmas, deadline
            )
            what = (
                f"an estimate that stayed within {self.settings.settle_sigmas:g} sigma for "
                f"{self.settings.settle_s:g} s"
            )
        waited_ms = round(1000.0 * (time.monotonic() - t_request), 3)
        if message is None:
            if self.board.ended is not None:
                return _error(f"{op}: {self.board.ended}; no more pairs come", waited_ms=waited_ms)
            hint = ""
            if op == "settled" and (self.live.method or "") == "paper":
                hint = " (the paper's method gives no sigma: serve with --method refractive)"
            return _error(f"timeout after {timeout:g} s waiting for {what}{hint}", waited_ms=waited_ms)
        fields = {"frame": message["frame"], "latency_ms": message["latency_ms"], "waited_ms": waited_ms}
        if not message["ok"]:
            return _error(
                f"{op}: the pair gave no estimate: {message['error']}",
                exit_code=message["exit_code"],
                **fields,
            )
        return _reply(True, estimate=message["estimate"], **fields)

    def _take_reference(self, request: dict[str, Any]) -> dict[str, Any]:
        """The ``reference`` op: the first pair captured after the request, checked unloaded and of this
        rig, becomes the loop's reference; a refused pair leaves the reference in use as it was."""
        from softjig.io.reference import reference_from_pair

        method = self.live.method or "refractive"
        if method == "paper":
            return _error(
                "reference: the paper's method measures no indentations, so it uses no reference frame "
                "(serve with --method refractive)"
            )
        if self.pump is not None and self.pump.holding:
            return _error(
                'reference: the jig holds a part; release it ({"op": "release"}) and remove the part'
            )
        timeout = self._timeout(request)
        t_request = time.monotonic()
        pair = self.board.pair_after(t_request, t_request + timeout)
        if pair is None:
            if self.board.ended is not None:
                return _error(f"reference: {self.board.ended}; no more pairs come")
            return _error(f"timeout after {timeout:g} s waiting for a pair captured after the request")
        frame = {"seq": pair.seq, "index": pair.source_index, "capture_time_unix_s": pair.wall_time_s}
        try:
            reference = reference_from_pair(
                pair.left,
                pair.right,
                self.live.jig,
                estimator=self.loop.estimator(),
                where="the pair captured for the reference",
            )
        except InputError as exc:
            kept = self.loop.reference_source
            return _error(f"reference refused, still estimating against the {kept}: {exc}", frame=frame)
        self.loop.use_reference(reference, warm=self._warm_new_estimator)
        return _reply(True, reference={"source": reference.source, "markers": len(reference)}, frame=frame)
