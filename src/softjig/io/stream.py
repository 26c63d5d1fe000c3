"""Streaming estimates to a robot: ZeroMQ PUB/SUB, JSON messages with a versioned schema.

Every message is a two-part ZeroMQ message: the topic (:data:`TOPIC_ESTIMATE` or :data:`TOPIC_HEALTH`,
ASCII) and one UTF-8 JSON object carrying ``"schema"`` (the topic again) and ``"version"``
(:data:`SCHEMA_VERSION`). Fields may be *added* within a version; a field removed, renamed or changed in
meaning bumps the version, so a subscriber checks ``version`` and ignores fields it does not know. The
schema is documented in ``docs/live.md``; :func:`estimate_message` and :func:`health_message` (in
:mod:`softjig.live.loop`) build the payloads.

The :class:`Publisher` never blocks and never grows without bound: sends are non-blocking and each
subscriber has a send queue of at most ``hwm`` messages (ZeroMQ's high-water mark); when a slow
subscriber's queue is full, new messages *for that subscriber* are dropped (PUB semantics) while fast
subscribers still get everything. A subscriber that joins late gets the messages from then on; health
messages are periodic, so it learns the loop's state within one health period.

A subscriber that acts on estimates must not read a backlog one message at a time: ZeroMQ queues what it
has not read and, once the queue is full, drops the *newest* messages, so a slow reader acts on ever older
estimates. :class:`Subscriber` with ``latest_only=True`` drains the queue on every receive and returns the
newest message of each topic. (``ZMQ_CONFLATE`` is no way out: it keeps a single *frame*, and a softjig
message has two.)

The publisher binds to the loopback interface unless told otherwise (``allow_remote=True``): a jig's
estimates are for the robot controller on the same machine or, deliberately, on a trusted cell network.
"""

from __future__ import annotations

import ipaddress
import json
import math
import time
from dataclasses import dataclass
from typing import Any

from softjig.errors import InputError

__all__ = [
    "SCHEMA_VERSION",
    "TOPIC_ESTIMATE",
    "TOPIC_HEALTH",
    "Publisher",
    "Subscriber",
    "check_endpoint",
    "decode_message",
    "encode_message",
]

SCHEMA_VERSION = 1
TOPIC_ESTIMATE = "softjig.estimate"
TOPIC_HEALTH = "softjig.health"
TOPICS = (TOPIC_ESTIMATE, TOPIC_HEALTH)

#: Messages queued per subscriber before the publisher drops that subscriber's messages.
DEFAULT_HWM = 32


def _json_default(value: Any) -> Any:
    import numpy as np

    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    raise TypeError(f"cannot send {type(value).__name__} as JSON")


def _finite(value: Any) -> Any:
    """NaN and infinities (not JSON) become ``null``."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_finite(v) for v in value]
    return value


def encode_message(topic: str, payload: dict[str, Any]) -> list[bytes]:
    """The two frames ``[topic, json]`` of a message; ``schema`` and ``version`` are set here."""
    if topic not in TOPICS:
        raise InputError(f"unknown topic {topic!r}; valid: {', '.join(TOPICS)}")
    body = {"schema": topic, "version": SCHEMA_VERSION, **payload}
    text = json.dumps(_finite(body), default=_json_default, allow_nan=False, separators=(",", ":"))
    return [topic.encode("ascii"), text.encode("utf-8")]


def decode_message(frames: list[bytes]) -> tuple[str, dict[str, Any]]:
    """``(topic, payload)`` of a received message.

    Raises
    ------
    InputError
        Not two frames, not a JSON object, a topic that disagrees with ``schema``, or a ``version``
        other than :data:`SCHEMA_VERSION` (the message says which).
    """
    if len(frames) != 2:
        raise InputError(f"a softjig message has 2 frames (topic, JSON), got {len(frames)}")
    topic = frames[0].decode("ascii", errors="replace")
    try:
        payload = json.loads(frames[1].decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(f"{topic}: the payload is not JSON ({exc})") from None
    if not isinstance(payload, dict) or payload.get("schema") != topic:
        raise InputError(
            f"{topic}: not a softjig message (schema {payload.get('schema')!r})"
            if isinstance(payload, dict)
            else f"{topic}: the payload is not a JSON object"
        )
    if payload.get("version") != SCHEMA_VERSION:
        raise InputError(
            f"{topic}: schema version {payload.get('version')!r}, this softjig reads version "
            f"{SCHEMA_VERSION}; update the subscriber or the publisher"
        )
    return topic, payload


_LOOPBACK_NAMES = ("localhost",)


def check_endpoint(endpoint: str, *, allow_remote: bool = False) -> str:
    """Validate a ZeroMQ endpoint to bind; returns it.

    ``tcp://HOST:PORT`` (``PORT`` 1-65535, or ``*`` for any free port) with ``HOST`` a loopback address
    (``127.0.0.1``, ``::1``, ``localhost``) unless ``allow_remote``; ``ipc://PATH`` and ``inproc://NAME``
    are local by nature.

    Raises
    ------
    InputError
        A malformed endpoint, or a non-loopback host without ``allow_remote``.
    """
    scheme, sep, rest = endpoint.partition("://")
    if not sep or scheme not in ("tcp", "ipc", "inproc") or not rest:
        raise InputError(f"--publish must look like tcp://127.0.0.1:5555 (or ipc://PATH), got {endpoint!r}")
    if scheme != "tcp":
        return endpoint
    host, colon, port = rest.rpartition(":")
    if not colon or not host:
        raise InputError(f"--publish {endpoint!r} lacks a port: use tcp://127.0.0.1:5555")
    if port != "*" and not (port.isdigit() and 0 < int(port) < 65536):
        raise InputError(f"--publish {endpoint!r}: the port must be 1-65535 (or * for any), got {port!r}")
    bare = host[1:-1] if host.startswith("[") and host.endswith("]") else host
    try:
        loopback = ipaddress.ip_address(bare).is_loopback
    except ValueError:
        loopback = bare.lower() in _LOOPBACK_NAMES
    if not loopback and not allow_remote:
        raise InputError(
            f"--publish {endpoint!r} would accept connections from other machines; bind to "
            "127.0.0.1, or pass --allow-remote if the robot is on a trusted network"
        )
    return endpoint


@dataclass(frozen=True)
class PublisherStats:
    """What a :class:`Publisher` did: messages handed to ZeroMQ and refused (would have blocked)."""

    sent: int
    refused: int


class Publisher:
    """A ZeroMQ PUB socket bound to ``endpoint`` sending softjig messages without ever blocking.

    Parameters
    ----------
    endpoint : where to bind (:func:`check_endpoint`).
    hwm : messages queued per subscriber (ZeroMQ ``SNDHWM``); beyond it a slow subscriber misses
        messages, and memory stays bounded.
    allow_remote : allow binding to a non-loopback address.

    Attributes
    ----------
    endpoint : the bound endpoint (with the actual port when ``*`` was asked).
    """

    def __init__(self, endpoint: str, *, hwm: int = DEFAULT_HWM, allow_remote: bool = False) -> None:
        import zmq

        check_endpoint(endpoint, allow_remote=allow_remote)
        self._ctx = zmq.Context()
        self._socket = self._ctx.socket(zmq.PUB)
        self._socket.setsockopt(zmq.SNDHWM, int(hwm))
        self._socket.setsockopt(zmq.LINGER, 0)
        try:
            self._socket.bind(endpoint)
        except zmq.ZMQError as exc:
            self._socket.close(0)
            self._ctx.term()
            raise InputError(
                f"cannot bind {endpoint}: {exc} (is another softjig or program using that "
                "port? choose another)"
            ) from None
        self.endpoint = self._socket.getsockopt_string(zmq.LAST_ENDPOINT)
        self._sent = 0
        self._refused = 0

    def publish(self, topic: str, payload: dict[str, Any]) -> bool:
        """Send one message without blocking; ``False`` if ZeroMQ refused it (counted)."""
        import zmq

        frames = encode_message(topic, payload)
        try:
            self._socket.send_multipart(frames, flags=zmq.NOBLOCK, copy=True)
        except zmq.Again:
            self._refused += 1
            return False
        self._sent += 1
        return True

    @property
    def stats(self) -> PublisherStats:
        return PublisherStats(sent=self._sent, refused=self._refused)

    def close(self) -> None:
        """Close the socket at once (pending messages are discarded)."""
        if not self._socket.closed:
            self._socket.close(0)
            self._ctx.term()

    def __enter__(self) -> Publisher:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class Subscriber:
    """A ZeroMQ SUB socket connected to a softjig publisher (for robots, tools and tests).

    Parameters
    ----------
    endpoint : the publisher's endpoint (``tcp://127.0.0.1:5555``).
    topics : the topics to receive (default: all).
    hwm : messages queued before ZeroMQ drops new ones (``RCVHWM``).
    latest_only : each :meth:`receive` drains what is queued and returns only the newest message of each
        topic (the older ones are counted in :attr:`skipped`): what a robot acting on estimates wants.
        Keep ``hwm`` large then: a queue that overflows between two receives loses the newest messages.

    Attributes
    ----------
    skipped : messages passed over because a newer one of their topic was queued (``latest_only``).

    Examples
    --------
    >>> with Subscriber("tcp://127.0.0.1:5555", latest_only=True) as sub:   # doctest: +SKIP
    ...     topic, msg = sub.receive(timeout_s=1.0)
    """

    #: The most messages one drain reads (a bound on a receive's work whatever the publisher's rate).
    MAX_DRAIN = 100_000

    def __init__(
        self,
        endpoint: str,
        *,
        topics: tuple[str, ...] = TOPICS,
        hwm: int = 1000,
        latest_only: bool = False,
    ) -> None:
        import zmq

        self.latest_only = bool(latest_only)
        self.skipped = 0
        self._pending: dict[str, tuple[int, dict[str, Any]]] = {}  # topic -> (arrival order, payload)
        self._arrivals = 0
        self._ctx = zmq.Context()
        self._socket = self._ctx.socket(zmq.SUB)
        self._socket.setsockopt(zmq.RCVHWM, int(hwm))
        self._socket.setsockopt(zmq.LINGER, 0)
        for topic in topics:
            self._socket.setsockopt(zmq.SUBSCRIBE, topic.encode("ascii"))
        self._socket.connect(endpoint)

    def receive(self, timeout_s: float) -> tuple[str, dict[str, Any]] | None:
        """The next ``(topic, payload)`` (:func:`decode_message`), or ``None`` after ``timeout_s``.

        With ``latest_only``: of the newest message of each topic queued now, the one that arrived first
        (so the newest estimate and the newest health message both come out, and nothing older).
        """
        if not self.latest_only:
            if not self._socket.poll(int(max(timeout_s, 0.0) * 1000)):
                return None
            return decode_message(self._socket.recv_multipart())
        self._drain()
        if not self._pending:
            if not self._socket.poll(int(max(timeout_s, 0.0) * 1000)):
                return None
            self._drain()
        topic = min(self._pending, key=lambda t: self._pending[t][0])
        return topic, self._pending.pop(topic)[1]

    def _drain(self) -> None:
        """Read every message queued now without waiting; keep the newest of each topic."""
        import zmq

        for _ in range(self.MAX_DRAIN):
            try:
                frames = self._socket.recv_multipart(flags=zmq.NOBLOCK)
            except zmq.Again:
                return
            topic, payload = decode_message(frames)
            if topic in self._pending:
                self.skipped += 1
            self._arrivals += 1
            self._pending[topic] = (self._arrivals, payload)

    def receive_until(self, predicate: Any, timeout_s: float) -> list[tuple[str, dict[str, Any]]]:
        """Every message received until ``predicate(topic, payload)`` is true or ``timeout_s`` passes."""
        deadline = time.monotonic() + timeout_s
        got = []
        while (left := deadline - time.monotonic()) > 0:
            message = self.receive(min(left, 0.2))
            if message is None:
                continue
            got.append(message)
            if predicate(*message):
                break
        return got

    def close(self) -> None:
        if not self._socket.closed:
            self._socket.close(0)
            self._ctx.term()

    def __enter__(self) -> Subscriber:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
