"""Start-up of the command line: ``softjig --help`` and a single-pair ``softjig estimate``.

Run: ``python benchmarks/bench_startup.py [--runs 9] [--src PATH ...]``. Each command runs as a fresh
process ``--runs`` times, interleaved (bare, then help and estimate of each source, bare, ...), so that a
busy machine slows every command and source alike; the script prints each one's median wall time and
the ratios to the bare ``python -c "import numpy, cv2, scipy.linalg"``. The goals (issue 14): ``--help``
within 2x and a single-pair estimate within 3x of the bare imports.

``--src`` runs the commands with ``PYTHONPATH`` set to each given source folder in turn (for example
``--src src /work/main/src`` to set this tree beside another); by default, the softjig importable here.
The stereo pair is one simulated default frame (``softjig simulate --scenario single``), rendered once
into a temporary folder. Each source gets one untimed warm-up run of every command first, which fills
the caches a first run builds once per machine (Numba's compiled kernels, the sub-pixel tables).
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

BARE = [sys.executable, "-c", "import numpy, cv2, scipy.linalg"]
SOFTJIG = [sys.executable, "-c", "from softjig.cli import main; main()"]


def _env(src: str | None) -> dict[str, str]:
    env = dict(os.environ)
    if src is not None:
        env["PYTHONPATH"] = str(Path(src).resolve())
    return env


def _run(argv: list[str], env: dict[str, str]) -> float:
    start = time.perf_counter()
    done = subprocess.run(argv, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    seconds = time.perf_counter() - start
    if done.returncode != 0:
        raise SystemExit(f"{' '.join(argv[3:]) or argv}: exit {done.returncode}\n{done.stderr}")
    return seconds


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=9, help="timed runs of each command")
    parser.add_argument("--src", nargs="*", default=[None], help="source folders to compare (PYTHONPATH)")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        data = Path(tmp) / "single"
        first = args.src[0]
        simulate = ["simulate", "--scenario", "single", "--part-diameter", "50", "--alpha", "10"]
        simulate += ["--theta", "60"]
        subprocess.run(
            [*SOFTJIG, *simulate, "--out", str(data), "--no-progress"],
            env=_env(first),
            check=True,
            stdout=subprocess.DEVNULL,
        )
        estimate = [*SOFTJIG, "estimate", str(data / "left/000000.png"), str(data / "right/000000.png")]
        estimate += ["--config", str(data / "rig.toml"), "--part-diameter", "50", "--json"]
        commands = {"softjig --help": [*SOFTJIG, "--help"], "single estimate": estimate}
        envs = {src or "the installed package": _env(src) for src in args.src}
        print(f"python {sys.version.split()[0]}, {os.cpu_count()} CPUs, {args.runs} runs each (medians, s)")
        for env in envs.values():  # warm-up: caches filled once per machine
            for argv in commands.values():
                _run(argv, env)
        bare: list[float] = []
        times = {(src, name): [] for src in envs for name in commands}
        for _ in range(args.runs):  # interleaved: a busy machine slows every command and source alike
            bare.append(_run(BARE, _env(None)))
            for src, env in envs.items():
                for name, argv in commands.items():
                    times[src, name].append(_run(argv, env))
        bare_s = statistics.median(bare)
        print(f"\n  bare imports      {bare_s:6.3f} s  (range {max(bare) - min(bare):5.3f})")
        for src in envs:
            medians = {name: statistics.median(times[src, name]) for name in commands}
            print(f"\nsoftjig from {src}")
            for name, value in medians.items():
                spread = max(times[src, name]) - min(times[src, name])
                print(f"  {name:16s} {value:6.3f} s  (range {spread:5.3f})  {value / bare_s:4.1f}x bare")
            print(
                f"  goals: --help {medians['softjig --help'] / bare_s:.1f}x (<= 2x), "
                f"estimate {medians['single estimate'] / bare_s:.1f}x (<= 3x)"
            )


if __name__ == "__main__":
    main()
