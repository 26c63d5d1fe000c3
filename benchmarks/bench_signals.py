"""How fast ``softjig estimate DATASET`` and ``softjig simulate`` (2 workers each) clean up after a signal.

Run (about a minute on a quiet 2-core machine)::

    python benchmarks/bench_signals.py [--repeats 5] [--scratch /tmp/softjig-signals]

For each command and each of SIGINT, SIGTERM and SIGKILL sent to the parent alone (as ``kill PID`` does)
once its two workers run, ``--repeats`` times, it prints the median and the largest of: the time from the
signal to the parent's exit, the time from the signal until no worker is left (read from ``/proc``), the
exit codes seen, and how many temporary files (``*.tmp``) were left. The goal (issue 14): exit within a
second or two with 130 / 143, no worker left, no temporary file (SIGKILL may leave the results file's one
temporary file: nothing can run in a killed process). Linux only (``/proc``).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import shutil
import signal
import statistics
import subprocess
import sys
import time
from pathlib import Path

CLI = "import sys; sys.argv[0] = 'softjig'; from softjig.cli import main; main()"


def children(pid: int) -> set[int]:
    found: set[int] = set()
    for task in Path(f"/proc/{pid}/task").glob("*/children"):
        with contextlib.suppress(OSError):
            found.update(int(p) for p in task.read_text().split())
    return found


def alive(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


def make_dataset(root: Path) -> Path:
    from softjig.config import default_jig
    from softjig.io.simulated import simulate_dataset
    from softjig.sim.scenarios import paper_sweep

    specs = list(paper_sweep(diameters_mm=(50,), alphas_deg=(10,), theta_step_deg=120))
    simulate_dataset(root, specs, default_jig(), seed=2, workers=1, progress=False)
    frames = [json.loads(line) for line in (root / "frames.jsonl").read_text().splitlines()]
    with open(root / "frames.jsonl", "w") as fh:
        for k in range(60 * len(frames)):
            fh.write(json.dumps({**frames[k % len(frames)], "index": k}) + "\n")
    return root


def one_run(args: list[str], cwd: Path, signum: int) -> tuple[float, float, int, int]:
    """(seconds to the parent's exit, seconds until no worker is left, exit code, temporary files left)."""
    proc = subprocess.Popen(
        [sys.executable, "-c", CLI, *args], cwd=cwd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
    )
    deadline = time.monotonic() + 120
    while len(children(proc.pid)) < 2 and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.02)
    workers = children(proc.pid)
    if proc.poll() is not None or len(workers) < 2:
        raise RuntimeError(f"{args[0]}: no workers seen")
    time.sleep(0.3)
    t0 = time.monotonic()
    os.kill(proc.pid, signum)
    code = proc.wait(120)
    t_exit = time.monotonic() - t0
    while any(alive(pid) for pid in workers) and time.monotonic() - t0 < 60:
        time.sleep(0.01)
    t_workers = time.monotonic() - t0
    for pid in workers:  # never leave one behind, even if the code under test does
        if alive(pid):
            os.kill(pid, signal.SIGKILL)
    return t_exit, t_workers, code, len(list(cwd.rglob("*.tmp")))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--scratch", type=Path, default=Path("/tmp/softjig-signals"))
    opts = parser.parse_args()
    shutil.rmtree(opts.scratch, ignore_errors=True)
    dataset = make_dataset(opts.scratch / "ds")
    commands = {
        "estimate": lambda out: ["estimate", str(dataset), "--workers", "2", "--no-progress", "--out",
                                 str(out / "est.jsonl")],
        "simulate": lambda out: ["simulate", "--diameters", "50,60", "--alphas", "10", "--theta-step", "30",
                                 "--workers", "2", "--no-progress", "--out", str(out / "sim")],
    }  # fmt: skip
    print(f"load average {os.getloadavg()[0]:.2f}; {opts.repeats} repeats; medians (max)")
    header = f"{'command':9} {'signal':8} {'exit s':>14} {'workers gone s':>16}"
    print(f"{header} {'exit codes':>12} {'.tmp left':>9}")
    for name, make_args in commands.items():
        for signum in (signal.SIGINT, signal.SIGTERM, signal.SIGKILL):
            runs = []
            for k in range(opts.repeats):
                cwd = opts.scratch / f"{name}-{signum}-{k}"
                cwd.mkdir(parents=True)
                runs.append(one_run(make_args(cwd), cwd, signum))
            t_exit, t_gone, codes, tmps = zip(*runs, strict=True)
            print(
                f"{name:9} {signal.Signals(signum).name:8} "
                f"{statistics.median(t_exit):7.2f} ({max(t_exit):4.2f}) "
                f"{statistics.median(t_gone):9.2f} ({max(t_gone):4.2f}) "
                f"{','.join(sorted({str(c) for c in codes})):>12} {sum(tmps):>9}"
            )
    shutil.rmtree(opts.scratch, ignore_errors=True)


if __name__ == "__main__":
    main()
