"""Start-up of the command line: ``softjig --help`` and a single-pair ``softjig estimate``.

Run: ``python benchmarks/bench_startup.py [--runs 9] [--src PATH ...]``. Each command runs as a fresh
process ``--runs`` times, interleaved (bare, then help and estimate of each source, bare, ...), so that a
busy machine slows every command and source alike; the script prints each one's median wall time (and
CPU time: user + system, steadier on a shared machine) and the ratios to the bare
``python -c "import numpy, cv2, scipy.linalg"``. The goals (issue 14): ``--help`` within 2x and a
single-pair estimate within 3x of the bare imports (wall time).

``--src`` runs the commands with ``PYTHONPATH`` set to each given source folder in turn (for example
``--src src /work/main/src`` to set this tree beside another); by default, the softjig importable here.
The stereo pair is one simulated default frame (``softjig simulate --scenario single``), rendered once
into a temporary folder. Each source gets one untimed warm-up run of every command first, which fills
the caches a first run builds once per machine (Numba's compiled kernels, the sub-pixel tables). Then, per
source, the estimate's Numba share in one process (medians of a few runs): ``import numba``, the first
kernel's load from the cache (which initialises Numba's CPU target), the other kernels' loads, the whole
command in the process, and its ``finalisation``: the time from the end of its work and exit handlers until
the process has ended (the interpreter's teardown, which ``softjig.cli.main`` skips).

Byte-code: each source's modules are compiled once (``__pycache__``, written by the warm-up runs) and
read in the timed ones, as an installed package's are (``pip`` compiles them at install). An environment
with ``PYTHONDONTWRITEBYTECODE`` set would otherwise leave a source tree without them, and every run of it
would compile softjig's ~50 modules from source (0.1 s of CPU, a quarter of the bare imports), a cost no
installed copy pays; ``--keep-env`` keeps the environment's setting (the figures before 2 Dec 2026).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

BARE = [sys.executable, "-c", "import numpy, cv2, scipy.linalg"]
SOFTJIG = [sys.executable, "-c", "from softjig.cli import main; main()"]
# The estimate in one process with Numba's share timed: its import, then every compiled kernel loaded from
# the cache (the first load also initialises Numba's CPU target). The figures are written by the first
# atexit handler registered, so the last one run: when the command's work and every exit handler are done;
# what the process spends after it (until its parent sees it end) is the interpreter's finalisation.
# Prints one JSON line on stderr.
BREAKDOWN = """
import atexit, json, sys, time
t0 = time.monotonic()
import numba
import numba.core.caching as caching
t1 = time.monotonic()
loads = []
original = caching.Cache.load_overload
def load_overload(self, sig, target_context):
    start = time.monotonic()
    try:
        return original(self, sig, target_context)
    finally:
        loads.append(time.monotonic() - start)
caching.Cache.load_overload = load_overload
def report():
    figures = {"numba import": t1 - t0, "first kernel (target init)": loads[0] if loads else 0.0}
    figures.update({"other kernel loads": sum(loads[1:]), "kernels": len(loads)})
    figures["in-process total"] = time.monotonic() - t0
    figures["work_end"] = time.monotonic()
    sys.stderr.write(json.dumps(figures) + "\\n")
    sys.stderr.flush()
atexit.register(report)
from softjig.cli import main
sys.argv = ["softjig", *sys.argv[1:]]
main()
"""


def _env(src: str | None, keep_env: bool = False) -> dict[str, str]:
    env = dict(os.environ)
    if not keep_env:  # byte-code written once and read after, as an installed package's (module docstring)
        env.pop("PYTHONDONTWRITEBYTECODE", None)
    if src is not None:
        env["PYTHONPATH"] = str(Path(src).resolve())
    return env


def _run(argv: list[str], env: dict[str, str]) -> tuple[float, float]:
    """The wall time and the CPU time (user + system, s) of one run of ``argv``."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    done = subprocess.run(argv, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    seconds = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if done.returncode != 0:
        raise SystemExit(f"{' '.join(argv[3:]) or argv}: exit {done.returncode}\n{done.stderr}")
    return seconds, after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime


def _line(name: str, runs: list[tuple[float, float]], bare: tuple[float, float] | None = None) -> str:
    """``name``: median wall time, its range, median CPU time, and both as multiples of ``bare``'s."""
    wall, cpu = (statistics.median(column) for column in zip(*runs, strict=True))
    walls = [run[0] for run in runs]
    text = f"  {name:16s} {wall:6.3f} s  (range {max(walls) - min(walls):5.3f})  cpu {cpu:6.3f} s"
    return text if bare is None else text + f"  {wall / bare[0]:4.1f}x bare ({cpu / bare[1]:.1f}x cpu)"


def _breakdown(argv: list[str], env: dict[str, str], runs: int) -> dict[str, float]:
    """Medians over ``runs`` of the :data:`BREAKDOWN` figures for ``softjig`` arguments ``argv``, with
    ``finalisation``: from the end of the last exit handler until the process ended (its pipes closed and
    it was reaped; the interpreter's teardown of modules and objects, and the kernel's of the process)."""
    rows = []
    for _ in range(runs):
        argv_breakdown = [sys.executable, "-c", BREAKDOWN, *argv]
        child = subprocess.Popen(
            argv_breakdown, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True
        )
        stderr = child.communicate()[1]
        ended = time.monotonic()
        if child.returncode != 0:
            raise SystemExit(f"breakdown: exit {child.returncode}\n{stderr}")
        row = json.loads(stderr.strip().splitlines()[-1])
        row["finalisation"] = ended - row.pop("work_end")
        rows.append(row)
    return {key: statistics.median(row[key] for row in rows) for key in rows[0]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=9, help="timed runs of each command")
    parser.add_argument("--src", nargs="*", default=[None], help="source folders to compare (PYTHONPATH)")
    parser.add_argument(
        "--keep-env", action="store_true", help="keep PYTHONDONTWRITEBYTECODE (modules compiled each run)"
    )
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        data = Path(tmp) / "single"
        first = args.src[0]
        simulate = ["simulate", "--scenario", "single", "--part-diameter", "50", "--alpha", "10"]
        simulate += ["--theta", "60"]
        subprocess.run(
            [*SOFTJIG, *simulate, "--out", str(data), "--no-progress"],
            env=_env(first, args.keep_env),
            check=True,
            stdout=subprocess.DEVNULL,
        )
        estimate = [*SOFTJIG, "estimate", str(data / "left/000000.png"), str(data / "right/000000.png")]
        estimate += ["--config", str(data / "rig.toml"), "--part-diameter", "50", "--json"]
        commands = {"softjig --help": [*SOFTJIG, "--help"], "single estimate": estimate}
        envs = {src or "the installed package": _env(src, args.keep_env) for src in args.src}
        print(f"python {sys.version.split()[0]}, {os.cpu_count()} CPUs, {args.runs} runs each (medians, s)")
        no_bytecode = "PYTHONDONTWRITEBYTECODE" in next(iter(envs.values()))
        print("  byte-code: " + ("not written, compiled each run" if no_bytecode else "written once, read"))
        for env in envs.values():  # warm-up: caches filled once per machine
            for argv in commands.values():
                _run(argv, env)
        bare: list[tuple[float, float]] = []
        times = {(src, name): [] for src in envs for name in commands}
        for _ in range(args.runs):  # interleaved: a busy machine slows every command and source alike
            bare.append(_run(BARE, _env(None, args.keep_env)))
            for src, env in envs.items():
                for name, argv in commands.items():
                    times[src, name].append(_run(argv, env))
        bare_s = tuple(statistics.median(column) for column in zip(*bare, strict=True))
        print(f"  load average {' '.join(f'{x:.1f}' for x in os.getloadavg())}")
        print("\n" + _line("bare imports", bare))
        for src in envs:
            medians = {name: statistics.median(run[0] for run in times[src, name]) for name in commands}
            print(f"\nsoftjig from {src}")
            for name in commands:
                print(_line(name, times[src, name], bare_s))
            print(
                f"  goals: --help {medians['softjig --help'] / bare_s[0]:.1f}x (<= 2x), "
                f"estimate {medians['single estimate'] / bare_s[0]:.1f}x (<= 3x)"
            )
            parts = _breakdown(estimate[3:], envs[src], max(3, args.runs // 3))
            kernels = int(parts.pop("kernels"))
            print(f"  the estimate in one process ({kernels} compiled kernels loaded):")
            for name, value in parts.items():
                print(f"    {name:28s} {value:6.3f} s")


if __name__ == "__main__":
    main()
