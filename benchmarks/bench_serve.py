"""Request-to-reply latency of ``softjig serve``, and what warming up before the cameras open saves.

Simulates a still part (1280x720, the default jig, a 50 mm cylinder tilted by 10 degrees; one pair
repeated with fresh noise), starts ``softjig serve --replay DATASET`` (the replay at its 30 Hz, looping,
as cameras would deliver) as a subprocess, and asks it ``{"op": "estimate"}`` over a loopback REQ socket:
the first request as soon as the service says it is serving, then ``--requests`` more, one after the
other. Each reply waits for the first pair captured after its request, so the expected round trip is
up to one frame period (33 ms; half of it on average) plus the estimate.

Reported (medians of one run): round trip (request to reply), the estimate's own latency (pair complete
to estimate ready, the reply's ``latency_ms``), for the first request and the rest; and the same first
request with ``--no-warm-up`` (the estimator then warms up on the robot's first pair).

Run: ``python benchmarks/bench_serve.py [--requests 100]``. The development machine is shared by several
sessions: quote medians, and the load average printed with them.
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _run(dataset: Path, n_requests: int, *, warm: bool) -> tuple[list[float], list[float]]:
    """Round trips and estimate latencies (ms) of ``1 + n_requests`` estimate requests."""
    import zmq

    port = _free_port()
    args = [
        sys.executable,
        "-c",
        "from softjig.cli import main; main()",
        "serve",
        "--replay",
        str(dataset),
        "--bind",
        f"tcp://127.0.0.1:{port}",
        "--warm-up" if warm else "--no-warm-up",
    ]
    proc = subprocess.Popen(args, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 300
        assert proc.stderr is not None
        for line in proc.stderr:
            if "serving on" in line:
                break
            if time.monotonic() > deadline:
                raise RuntimeError("softjig serve did not start")
        ctx = zmq.Context()
        sock = ctx.socket(zmq.REQ)
        sock.setsockopt(zmq.LINGER, 0)
        sock.connect(f"tcp://127.0.0.1:{port}")
        trips, latencies = [], []
        for _ in range(1 + n_requests):
            t0 = time.perf_counter()
            sock.send(json.dumps({"op": "estimate"}).encode())
            if not sock.poll(60_000):
                raise RuntimeError("no reply within 60 s")
            reply = json.loads(sock.recv())
            trips.append(1000.0 * (time.perf_counter() - t0))
            if not reply["ok"]:
                raise RuntimeError(reply["error"])
            latencies.append(reply["latency_ms"])
        sock.close(0)
        ctx.term()
        return trips, latencies
    finally:
        proc.terminate()
        proc.wait(timeout=60)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--requests", type=int, default=100)
    parser.add_argument("--frames", type=int, default=30, help="frames of the replayed still part")
    args = parser.parse_args()

    from softjig.config import CylinderPart, default_jig
    from softjig.io.simulated import simulate_dataset
    from softjig.sim.scenarios import single

    root = Path(tempfile.mkdtemp(prefix="bench_serve_"))
    specs = [s for _ in range(args.frames) for s in single(CylinderPart(50.0), 10.0, 0.0)]
    simulate_dataset(root / "still", specs, default_jig(), seed=5, workers=os.cpu_count(), progress=False)

    trips, lat = _run(root / "still", args.requests, warm=True)
    cold_trips, cold_lat = _run(root / "still", 0, warm=False)
    med = statistics.median
    print(
        f"softjig serve --replay (30 Hz, 1280x720), {args.requests} requests after the first, one at a time"
    )
    print(f"{'':<34} {'round trip ms':>14} {'estimate latency ms':>20}")
    print(f"{'first request (warmed up)':<34} {trips[0]:>14.1f} {lat[0]:>20.1f}")
    print(f"{'later requests, median':<34} {med(trips[1:]):>14.1f} {med(lat[1:]):>20.1f}")
    q95 = sorted(trips[1:])[int(0.95 * (len(trips) - 2))]
    print(f"{'later requests, 95th percentile':<34} {q95:>14.1f} {'':>20}")
    print(f"{'first request, --no-warm-up':<34} {cold_trips[0]:>14.1f} {cold_lat[0]:>20.1f}")
    print(
        f"target: one frame period (33.3 ms) + the estimate ({med(lat[1:]):.1f} ms) = "
        f"{33.3 + med(lat[1:]):.1f} ms; load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs "
        "(the machine is shared: timings are noisy)"
    )


if __name__ == "__main__":
    main()
