"""ZeroMQ streaming on real loopback sockets: schema, late joiners, a slow subscriber, binding rules."""

from __future__ import annotations

import json
import os
import threading
import time

import pytest

from softjig.errors import InputError
from softjig.io.stream import (
    SCHEMA_VERSION,
    TOPIC_ESTIMATE,
    TOPIC_HEALTH,
    Publisher,
    Subscriber,
    check_endpoint,
    decode_message,
    encode_message,
)

LOCAL = "tcp://127.0.0.1:*"


@pytest.mark.parametrize(
    "endpoint",
    [
        "tcp://127.0.0.1:5555",
        "tcp://localhost:1",
        "tcp://[::1]:5555",
        "tcp://127.0.0.1:*",
        "ipc:///tmp/softjig.sock",
    ],
)
def test_loopback_endpoints_are_accepted(endpoint):
    assert check_endpoint(endpoint) == endpoint


@pytest.mark.parametrize("endpoint", ["tcp://0.0.0.0:5555", "tcp://*:5555", "tcp://192.168.1.10:5555"])
def test_other_interfaces_need_allow_remote(endpoint):
    with pytest.raises(InputError, match="--allow-remote"):
        check_endpoint(endpoint)
    assert check_endpoint(endpoint, allow_remote=True) == endpoint


@pytest.mark.parametrize(
    "endpoint",
    ["127.0.0.1:5555", "tcp://127.0.0.1", "tcp://127.0.0.1:0", "tcp://127.0.0.1:99999", "udp://127.0.0.1:5"],
)
def test_malformed_endpoints_are_refused(endpoint):
    with pytest.raises(InputError):
        check_endpoint(endpoint)


def test_messages_round_trip_with_schema_and_version():
    frames = encode_message(TOPIC_ESTIMATE, {"seq": 3, "latency_ms": float("nan"), "normal": (0.0, 0.0, 1.0)})
    assert frames[0] == b"softjig.estimate"
    topic, payload = decode_message(frames)
    assert topic == TOPIC_ESTIMATE
    assert payload == {
        "schema": TOPIC_ESTIMATE,
        "version": SCHEMA_VERSION,
        "seq": 3,
        "latency_ms": None,
        "normal": [0.0, 0.0, 1.0],
    }


def test_decode_refuses_other_versions_and_garbage():
    body = json.dumps({"schema": TOPIC_HEALTH, "version": SCHEMA_VERSION + 1}).encode()
    with pytest.raises(InputError, match="version"):
        decode_message([b"softjig.health", body])
    with pytest.raises(InputError, match="not JSON"):
        decode_message([b"softjig.health", b"{"])
    with pytest.raises(InputError, match="2 frames"):
        decode_message([b"x"])
    with pytest.raises(InputError, match="unknown topic"):
        encode_message("softjig.other", {})


def _publish_until_received(pub, sub, timeout_s=10.0):
    """Publish heartbeat messages until the subscriber's connection is up (ZeroMQ's slow joiner)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        pub.publish(TOPIC_HEALTH, {"seq": -1})
        if sub.receive(0.05) is not None:
            return
    raise AssertionError("the subscriber never connected")


def test_a_subscriber_receives_what_is_published_in_order():
    with Publisher(LOCAL) as pub, Subscriber(pub.endpoint) as sub:
        assert pub.endpoint.startswith("tcp://127.0.0.1:")
        _publish_until_received(pub, sub)
        for seq in range(20):
            pub.publish(TOPIC_ESTIMATE, {"seq": seq})
        got = sub.receive_until(lambda t, p: t == TOPIC_ESTIMATE and p["seq"] == 19, timeout_s=10.0)
        seqs = [p["seq"] for t, p in got if t == TOPIC_ESTIMATE]
        assert seqs == list(range(20))


def test_topic_filter():
    with Publisher(LOCAL) as pub, Subscriber(pub.endpoint, topics=(TOPIC_HEALTH,)) as sub:
        _publish_until_received(pub, sub)
        pub.publish(TOPIC_ESTIMATE, {"seq": 0})
        pub.publish(TOPIC_HEALTH, {"seq": 1})
        got = sub.receive_until(lambda t, p: p["seq"] == 1, timeout_s=10.0)
        assert {t for t, _ in got} == {TOPIC_HEALTH}


def test_a_late_subscriber_gets_the_stream_from_when_it_joins():
    with Publisher(LOCAL) as pub:
        stop = threading.Event()
        counter = {"seq": 0}

        def publish_forever():
            while not stop.is_set():
                pub.publish(TOPIC_ESTIMATE, {"seq": counter["seq"]})
                counter["seq"] += 1
                time.sleep(0.002)

        thread = threading.Thread(target=publish_forever, daemon=True)
        thread.start()
        try:
            while counter["seq"] < 100:
                time.sleep(0.01)
            with Subscriber(pub.endpoint) as late:
                got = []
                deadline = time.monotonic() + 10.0
                while len(got) < 50 and time.monotonic() < deadline:
                    message = late.receive(0.2)
                    if message is not None:
                        got.append(message[1]["seq"])
        finally:
            stop.set()
            thread.join(timeout=5)
    assert len(got) == 50
    assert got[0] >= 100  # it missed what came before it joined...
    assert got == list(range(got[0], got[0] + 50))  # ...and then got everything, in order


def _rss_bytes():
    with open(f"/proc/{os.getpid()}/statm") as fh:
        return int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")


@pytest.mark.skipif(not os.path.exists("/proc/self/statm"), reason="needs Linux /proc")
def test_a_slow_subscriber_neither_blocks_the_publisher_nor_grows_its_memory():
    payload = {"blob": "x" * 65536}  # 64 kB per message
    n = 3000  # 192 MB in all: an unbounded queue would show in the resident size
    with Publisher(LOCAL, hwm=8) as pub, Subscriber(pub.endpoint, hwm=1) as slow:
        _publish_until_received(pub, slow)
        before = pub.stats
        rss0 = _rss_bytes()
        t0 = time.monotonic()
        for seq in range(n):
            pub.publish(TOPIC_ESTIMATE, {"seq": seq, **payload})
        elapsed = time.monotonic() - t0
        growth = _rss_bytes() - rss0
        received = 0
        while slow.receive(0.5) is not None:
            received += 1
    assert (pub.stats.sent - before.sent) + (pub.stats.refused - before.refused) == n
    assert elapsed < 60.0  # never blocked (typically well under a second)
    assert growth < 100 * 2**20, f"resident memory grew by {growth / 2**20:.0f} MB"
    assert received < n // 4, f"the slow subscriber still got {received} of {n} messages"
    print(
        f"\n{n} x 64 kB published in {elapsed:.2f} s, RSS +{growth / 2**20:.1f} MB, slow subscriber "
        f"got {received}"
    )


def test_binding_a_used_port_is_an_input_error():
    with Publisher(LOCAL) as pub, pytest.raises(InputError, match="cannot bind"):
        Publisher(pub.endpoint)


def _slow_subscriber_lags(receive, pub, loops: int = 5, nap_s: float = 0.2) -> list[int]:
    """How many messages behind the publisher each of a slow subscriber's receipts is.

    A thread publishes estimates with their ``seq`` at about 200 Hz; the subscriber takes one message per
    loop, then naps ``nap_s`` (a slow robot program). The lag is the number published before the receive
    began minus the ``seq`` received: a backlog read one at a time grows it by ~40 per loop.
    """
    stop = threading.Event()
    published = {"n": 0}

    def publish():
        while not stop.is_set():
            pub.publish(TOPIC_ESTIMATE, {"seq": published["n"]})
            published["n"] += 1
            time.sleep(0.005)

    thread = threading.Thread(target=publish, daemon=True)
    thread.start()
    lags = []
    try:
        for _ in range(loops):
            time.sleep(nap_s)
            before = published["n"]
            seq = receive()
            lags.append(before - 1 - seq)
    finally:
        stop.set()
        thread.join(timeout=5)
    return lags


def test_a_latest_only_subscriber_gets_the_newest_message_not_a_backlog():
    with Publisher(LOCAL) as pub, Subscriber(pub.endpoint, latest_only=True) as sub:
        _publish_until_received(pub, sub)

        def receive():
            while True:
                message = sub.receive(5.0)
                assert message is not None, "nothing received"
                if message[0] == TOPIC_ESTIMATE:
                    return message[1]["seq"]

        lags = _slow_subscriber_lags(receive, pub)
        assert max(lags) <= 20, f"lags behind the publisher: {lags}"  # 20 messages = 0.1 s
        assert sub.skipped > 100  # it did pass over the backlog


def test_a_latest_only_subscriber_keeps_the_newest_of_each_topic():
    with Publisher(LOCAL) as pub, Subscriber(pub.endpoint, latest_only=True) as sub:
        _publish_until_received(pub, sub)
        while sub.receive(0.2) is not None:  # forget the connection heartbeats
            pass
        for seq in range(10):
            pub.publish(TOPIC_ESTIMATE, {"seq": seq})
            pub.publish(TOPIC_HEALTH, {"seq": 100 + seq})
        time.sleep(0.5)  # all queued at the subscriber
        got = [sub.receive(1.0), sub.receive(1.0), sub.receive(0.1)]
        assert [(t, p["seq"]) for t, p in got[:2]] == [(TOPIC_ESTIMATE, 9), (TOPIC_HEALTH, 109)]
        assert got[2] is None
