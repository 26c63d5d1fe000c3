"""Speed of the stereo renderer: one default stereo pair, single process, one core.

Run ``python benchmarks/bench_render.py [--repeats 20] [--rounds 5] [--src PATH ...] [--color]``. Renders
the as-built default jig (seed 0) with a 50 mm cylinder tilted by 10 degrees, and prints the median and
inter-quartile range of the time per pair and the median time per stage (summed over both cameras).
BLAS, OpenCV and Numba are limited to one thread, so the figure is per core.

Two ways of rendering are timed: ``Renderer`` (one :class:`softjig.sim.render.Renderer` built for the jig,
then reused for every pair, as a study or a dataset renders many frames of one jig) and ``render_pair``
(the public function, which builds the renderer on every call). A source tree from before the renderer
existed has only the second; its figure stands for both.

``--src`` runs the measurement in a fresh process per source folder and round, with ``PYTHONPATH`` set to
each folder in turn (for example ``--src /work/main/src src`` to set the old tree beside this one); the
rounds alternate between the folders (and reverse their order every other round), so that a busy machine
slows them alike, and the medians are over every pair of every round. Each process renders two untimed
pairs first (Numba's compiled kernels, caches). Without ``--src``, the softjig importable here is measured
in this process. Target: a median of at most 100 ms per pair; issue 17: the ``Renderer`` at most a third
of the old tree's time, measured in one run.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

TARGET_MS = 100.0
SPEED_UP_GOAL = 3.0  # issue 17: a pair in at most a third of the old renderer's time
WARM_UP_PAIRS = 2


def _measure(repeats: int, color: bool) -> dict[str, dict[str, list]]:
    """Time ``repeats`` pairs per way of rendering in this process: CPU and wall seconds, stage CPU times."""
    import cv2

    import softjig.sim.render as render
    from softjig.config import CylinderPart, default_jig
    from softjig.sim.asbuilt import draw_as_built
    from softjig.sim.parts import PartPose

    cv2.setNumThreads(1)
    as_built = draw_as_built(default_jig(), rng=0)
    part = CylinderPart(diameter_mm=50.0)
    pose = PartPose(alpha_rad=np.radians(10.0), theta_rad=np.radians(30.0))

    def per_call(seed: int, timings: dict[str, float]) -> object:
        return render._render_pair(as_built, part, pose, seed, color=color, timings=timings)

    ways = {"render_pair": per_call}
    if hasattr(render, "Renderer"):
        renderer = render.Renderer(as_built)
        ways["Renderer"] = lambda seed, timings: renderer.render_pair(
            part, pose, seed, color=color, timings=timings
        )
    results = {}
    for name, fn in ways.items():
        for seed in range(WARM_UP_PAIRS):
            fn(seed, {})
        wall, cpu, stages = [], [], []
        for seed in range(repeats):
            timings: dict[str, float] = {}
            t0, c0 = time.perf_counter(), time.process_time()
            fn(seed, timings)
            wall.append(time.perf_counter() - t0)
            cpu.append(time.process_time() - c0)
            stages.append(timings)
        results[name] = {"wall": wall, "cpu": cpu, "stages": stages}
    return results


def _child(src: str, repeats: int, color: bool) -> dict[str, dict[str, list]]:
    env = dict(os.environ, PYTHONPATH=str(Path(src).resolve()))
    argv = [sys.executable, __file__, "--child", "--repeats", str(repeats)] + (["--color"] if color else [])
    done = subprocess.run(argv, env=env, capture_output=True, text=True)
    if done.returncode != 0:
        raise SystemExit(f"{src}: exit {done.returncode}\n{done.stderr}")
    return json.loads(done.stdout)


def _summary(label: str, runs: dict[str, list]) -> float:
    """Print one way's figures; return its median CPU ms per pair."""
    print(f"  {label}:")
    for name in ("cpu", "wall"):
        ms = 1e3 * np.asarray(runs[name])
        q1, med, q3 = np.percentile(ms, [25, 50, 75])
        print(f"    {name:4s} time: median {med:6.1f} ms, IQR {q1:.1f}-{q3:.1f} ms, min {ms.min():.1f} ms")
    return float(np.median(1e3 * np.asarray(runs["cpu"])))


def _stage_table(columns: dict[str, list[dict[str, float]]]) -> None:
    """Median CPU ms per stage, one column per (source, way)."""
    names: list[str] = []
    for stages in columns.values():
        for s in stages:
            names += [n for n in s if n not in names]
    labels = list(columns)
    print("per stage (CPU ms, median over pairs, both cameras):")
    print("  " + " " * 16 + "".join(f"{label:>24s}" for label in labels))
    for n in [*names, "total"]:
        cells = []
        for stages in columns.values():
            values = [sum(s.values()) if n == "total" else s.get(n, 0.0) for s in stages]
            cells.append(f"{1e3 * float(np.median(values)):24.2f}")
        print(f"  {n:16s}" + "".join(cells))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--repeats", type=int, default=20, help="timed pairs per process and way (default 20)"
    )
    parser.add_argument("--rounds", type=int, default=5, help="processes per source with --src (default 5)")
    parser.add_argument("--src", nargs="*", default=None, help="source folders to compare (PYTHONPATH)")
    parser.add_argument("--color", action="store_true", help="render RGB images")
    parser.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    for name in ("repeats", "rounds"):
        if getattr(args, name) < 1:
            parser.error(f"--{name} must be at least 1, got {getattr(args, name)}")
    if args.child:
        json.dump(_measure(args.repeats, args.color), sys.stdout)
        return
    if not args.src:
        results = {"here": _measure(args.repeats, args.color)}
    else:
        results = {src: {} for src in args.src}
        for r in range(args.rounds):
            for src in args.src if r % 2 == 0 else reversed(args.src):
                for way, runs in _child(src, args.repeats, args.color).items():
                    merged = results[src].setdefault(way, {"wall": [], "cpu": [], "stages": []})
                    for key in merged:
                        merged[key] += runs[key]
    processes = args.rounds if args.src else 1
    print(f"render one pair (1280x720 x2, {args.repeats} pairs x {processes} processes, one thread):")
    medians = {}
    for src, ways in results.items():
        print(f"softjig from {src}")
        for way, runs in ways.items():
            medians[(src, way)] = _summary(way, runs)
    _stage_table(
        {
            f"{Path(src).resolve().parent.name}:{way}": r["stages"]
            for src, w in results.items()
            for way, r in w.items()
        }
    )
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    best = min(medians.values())
    verdict = "meets" if best <= TARGET_MS else "MISSES"
    print(f"target {TARGET_MS:.0f} ms per pair: {verdict} (1-min load average {load:.2f})")
    if args.src and len(args.src) >= 2:
        old, new = args.src[0], args.src[-1]
        old_ms = medians[(old, "render_pair")]
        for way in ("Renderer", "render_pair"):
            if (new, way) in medians:
                ratio = old_ms / medians[(new, way)]
                goal = f" (goal >= {SPEED_UP_GOAL:.0f}x)" if way == "Renderer" else ""
                print(f"speed-up of {new} {way} over {old}: {ratio:.2f}x{goal}")


if __name__ == "__main__":
    main()
