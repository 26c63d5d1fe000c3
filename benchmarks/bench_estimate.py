"""Benchmark of the estimate on the default stereo pairs: time per stage, localisation error, and the
one-shot ``estimate_pair`` against an Estimator reused, optionally side by side with other trees.

Run: ``python benchmarks/bench_estimate.py [--repeats 30] [--method paper]``. Single process, one thread
for OpenCV, so the figures are per core. Prints the median and inter-quartile range of each stage and of
the whole estimate (an Estimator reused, as every loop over frames does), the one-shot ``estimate_pair``
(an Estimator built per call) in CPU time, and the markers' localisation RMSE against the renderer's
ground truth.

Side by side: ``python benchmarks/bench_estimate.py --src OLD/src src [--rounds 5] [--calls 20]`` renders
the five pairs once, starts one worker process per source tree (``PYTHONPATH=SRC``) and alternates them,
round after round: each times ``--calls`` one-shot ``estimate_pair`` calls and as many calls of an
Estimator built once (a tree without an Estimator calls ``estimate_pair`` for both), in thread CPU time.
It prints each round's medians, the median over rounds and, for every tree after the first, the median of
the per-round ratios to the first tree (the figure to quote: a round's trees ran under the same load), then
compares the trees' estimates of the five pairs (one-shot and reused), two by two (bit-identical, or how
far apart). ``--stages`` adds each stage's thread CPU time of the reused Estimator, tree beside tree (the
stage clock of every tree reads ``time.perf_counter``, which the worker points at ``time.thread_time``
while it times the stages).
"""

from __future__ import annotations

import os

# One core: idle BLAS threads spinning after the fit's small SVDs slow the next frame's detection.
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import dataclasses  # noqa: E402
import json  # noqa: E402
import platform  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402

STAGES = ("checks", "frame", "detect", "match", "triangulate", "fit")
#: The part's base diameter given with every pair (mm): the pairs' part.
PART_DIAMETER_MM = 50.0
#: How many pairs (part at 10 deg, azimuths 36 deg apart, render seeds 0-4).
N_PAIRS = 5
#: Side by side: each round's median is printed for at most this many rounds (their quartiles beyond).
SHOWN_ROUNDS = 12
#: A worker's reply lines start with this (anything else a tree prints is ignored).
REPLY = "@@bench "


def default_pairs():
    """The five default pairs: a 50 mm part at 10 deg, 3 mm push, azimuths 0-144 deg, as-built seed 0."""
    from softjig.config import CylinderPart, default_jig
    from softjig.sim.asbuilt import draw_as_built
    from softjig.sim.parts import PartPose
    from softjig.sim.render import render_pair

    jig = default_jig()
    as_built = draw_as_built(jig, rng=0)
    part = CylinderPart(PART_DIAMETER_MM)
    return jig, [
        render_pair(as_built, part, PartPose(np.radians(10), np.radians(36 * k), 3.0), rng=k)
        for k in range(N_PAIRS)
    ]


def main() -> None:
    formatter = argparse.RawDescriptionHelpFormatter
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=formatter)
    parser.add_argument("--repeats", type=int, default=30)
    parser.add_argument("--method", choices=("refractive", "paper"), default="refractive")
    parser.add_argument("--src", nargs="+", metavar="SRC", help="source trees to run side by side")
    parser.add_argument("--rounds", type=int, default=5, help="side by side: alternations")
    parser.add_argument("--calls", type=int, default=20, help="side by side: calls of each kind a round")
    parser.add_argument("--stages", action="store_true", help="side by side: per-stage CPU time too")
    parser.add_argument("--worker", metavar="PAIRS_NPZ", help=argparse.SUPPRESS)
    args = parser.parse_args()
    for name in ("repeats", "rounds", "calls"):  # 0: medians and ratios of nothing, printed as NaN
        if getattr(args, name) < 1:
            parser.error(f"--{name} must be at least 1, got {getattr(args, name)}")
    cv2.setNumThreads(1)
    if args.worker:
        _worker(Path(args.worker), args.method)
    elif args.src:
        _side_by_side(args)
    else:
        _stages(args)


def _stages(args: argparse.Namespace) -> None:
    """One tree: the Estimator's stages, the one-shot call, the localisation error."""
    from scipy.spatial import cKDTree

    from softjig.sensing.estimator import Estimator
    from softjig.sensing.pipeline import estimate_pair

    jig, pairs = default_pairs()
    estimate_pair(pairs[0].left, pairs[0].right, jig, part_diameter_mm=PART_DIAMETER_MM)  # warm up (Numba)
    estimator = Estimator(jig, method=args.method)  # built once, as every caller estimating frames does
    records: dict[str, list[float]] = {stage: [] for stage in (*STAGES, "total")}
    errors = []
    for k in range(args.repeats):
        pair = pairs[k % len(pairs)]
        timings: dict[str, float] = {}
        result = estimator.estimate(pair.left, pair.right, part_diameter_mm=PART_DIAMETER_MM, timings=timings)
        for stage in STAGES:
            records[stage].append(timings[stage] * 1e3)
        records["total"].append(sum(timings.values()) * 1e3)
        if k < len(pairs):
            for markers, px, visible in (
                (result.left, pair.markers.left_px, pair.markers.visible_left),
                (result.right, pair.markers.right_px, pair.markers.visible_right),
            ):
                distance, _ = cKDTree(markers.xy_px).query(px[visible])
                errors.append(distance[distance < 2.0])
    print(f"softjig estimate ({args.method}), one default 1280x720 pair, {args.repeats} runs, 1 thread")
    print(
        f"machine: {platform.processor() or platform.machine()}, Python {platform.python_version()}, "
        f"NumPy {np.__version__}, OpenCV {cv2.__version__}"
    )
    print(f"{'stage':<12} {'median ms':>10} {'IQR ms':>16}")
    for stage, values in records.items():
        q1, med, q3 = np.percentile(values, [25, 50, 75])
        print(f"{stage:<12} {med:>10.2f} {q1:>7.2f} - {q3:<7.2f}")
    one_shot = []
    for k in range(args.repeats):  # estimate_pair builds an Estimator per call
        pair = pairs[k % len(pairs)]
        t0 = time.thread_time()
        estimate_pair(pair.left, pair.right, jig, part_diameter_mm=PART_DIAMETER_MM, method=args.method)
        one_shot.append((time.thread_time() - t0) * 1e3)
    print(f"{'one-shot':<12} {np.median(one_shot):>10.2f}   (estimate_pair, CPU: builds an Estimator a call)")
    e = np.concatenate(errors)
    print(
        f"localisation: RMSE {np.sqrt(np.mean(e**2)):.3f} px, median {np.median(e):.3f} px "
        f"over {len(e)} markers (default physics, as-built jig)"
    )


# ------------------------------------------------------------------------------------ side by side


def _side_by_side(args: argparse.Namespace) -> None:
    """Workers per tree, alternated round by round; their medians and their estimates compared."""
    sources = [str(Path(s).resolve()) for s in args.src]
    _, pairs = default_pairs()
    with tempfile.TemporaryDirectory(prefix="bench_estimate-") as folder:
        path = Path(folder) / "pairs.npz"
        arrays = {f"left_{k}": p.left for k, p in enumerate(pairs)}
        arrays.update({f"right_{k}": p.right for k, p in enumerate(pairs)})
        np.savez(path, **arrays)
        workers = [_start_worker(src, path, args.method) for src in sources]
        try:
            kinds = ("one-shot", "reused", "stages") if args.stages else ("one-shot", "reused")
            rows = {(src, kind): [] for src in sources for kind in kinds}
            for r in range(args.rounds):
                order = list(range(len(sources)))
                order = order if r % 2 == 0 else order[::-1]
                for kind in kinds:
                    for i in order:
                        rows[(sources[i], kind)].append(_ask(workers[i], f"{kind} {args.calls}"))
            estimates = [_ask(worker, "estimates 0") for worker in workers]
        finally:
            for worker in workers:
                worker.stdin.close()
                worker.wait()
    print(
        f"estimate_pair ({args.method}) side by side: {len(pairs)} default pairs, {args.calls} calls of each "
        f"kind a round, {args.rounds} rounds alternated, thread CPU ms (median a round)"
    )
    for kind in ("one-shot", "reused"):
        first = [float(np.median(times)) * 1e3 for times in rows[(sources[0], kind)]]
        for src in sources:
            medians = [float(np.median(times)) * 1e3 for times in rows[(src, kind)]]
            shown = (
                " / ".join(f"{m:.2f}" for m in medians)
                if len(medians) <= SHOWN_ROUNDS
                else "rounds' quartiles {:.2f} - {:.2f}".format(*np.percentile(medians, [25, 75]))
            )
            ratio = f"x{np.median(np.divide(medians, first)):.3f}" if src != sources[0] else "      "
            print(f"  {kind:<9} {np.median(medians):6.2f} {ratio}  ({shown})   {src}")
    if args.stages:
        _print_stages(rows, sources)
    for j in range(1, len(sources)):
        for i in range(j):
            difference = _difference(estimates[i], estimates[j])
            print(f"estimates of {sources[j]} against {sources[i]}: {difference}")


def _print_stages(rows: dict, sources: list[str]) -> None:
    """Each stage's median thread CPU time (ms) over every reused call of every round, tree beside tree."""
    print("stages of the reused Estimator, thread CPU ms (median over all calls; trees as numbered above):")
    print(f"  {'stage':<12}" + "".join(f" {f'tree {i}':>9}" for i in range(len(sources))))
    for stage in (*STAGES, "total"):
        cells = []
        for src in sources:
            calls = [call for rounds in rows[(src, "stages")] for call in rounds]
            values = [sum(call.values()) if stage == "total" else call.get(stage, np.nan) for call in calls]
            cells.append(f" {np.median(values) * 1e3:9.3f}")
        print(f"  {stage:<12}" + "".join(cells))
    for i, src in enumerate(sources):
        print(f"  tree {i}: {src}")


def _start_worker(src: str, pairs: Path, method: str) -> subprocess.Popen:
    env = dict(os.environ, PYTHONPATH=src)
    command = [sys.executable, __file__, "--worker", str(pairs), "--method", method]
    return subprocess.Popen(command, env=env, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)


def _ask(worker: subprocess.Popen, command: str):
    worker.stdin.write(command + "\n")
    worker.stdin.flush()
    for line in worker.stdout:
        if line.startswith(REPLY):
            return json.loads(line[len(REPLY) :])
    raise RuntimeError(f"a worker exited without answering {command!r} (exit code {worker.wait()})")


def _difference(reference: list[dict], other: list[dict]) -> str:
    """``"bit-identical"``, or the fields that differ and the largest absolute difference."""
    worst, differing = 0.0, set()
    for a, b in zip(reference, other, strict=True):
        for name in a.keys() | b.keys():
            x, y = a.get(name), b.get(name)
            if x == y:
                continue
            differing.add(name)
            try:
                worst = max(worst, float(np.max(np.abs(np.subtract(x, y, dtype=float)))))
            except (TypeError, ValueError):  # strings, or arrays of another length
                worst = np.inf
    if not differing:
        return "bit-identical"
    normals = [(a["estimate.normal"], b["estimate.normal"]) for a, b in zip(reference, other, strict=True)]
    angle = max(np.degrees(np.arccos(np.clip(np.dot(n, m), -1.0, 1.0))) for n, m in normals)
    return (
        f"normals differ by up to {angle:.3g} deg; fields that differ: {', '.join(sorted(differing))} "
        f"(largest difference {worst:.3g})"
    )


def _summary(result) -> dict:
    """A result's numbers as JSON-ready values (floats are written exactly)."""
    out = {}
    for field in dataclasses.fields(result.estimate):
        value = getattr(result.estimate, field.name)
        if field.name != "warnings":
            out[f"estimate.{field.name}"] = np.asarray(value).tolist() if value is not None else None
    out["left_xy_px"] = np.asarray(result.left.xy_px).tolist()
    out["right_xy_px"] = np.asarray(result.right.xy_px).tolist()
    out["used"] = np.asarray(result.used).tolist()
    out["plane.normal"] = np.asarray(result.plane.normal).tolist()
    return out


def _worker(pairs_path: Path, method: str) -> None:
    """Answer the driver's commands (``KIND CALLS``) with thread CPU times (s), or the estimates."""
    from softjig.config import default_jig
    from softjig.sensing.pipeline import estimate_pair

    try:
        from softjig.sensing.estimator import Estimator
    except ImportError:  # a tree from before the Estimator: estimate_pair caches what it derives
        Estimator = None
    jig = default_jig()
    with np.load(pairs_path) as data:
        pairs = [(data[f"left_{k}"], data[f"right_{k}"]) for k in range(N_PAIRS)]

    def one_shot(left, right):
        return estimate_pair(left, right, jig, part_diameter_mm=PART_DIAMETER_MM, method=method)

    reused = one_shot
    if Estimator is not None:
        estimator = Estimator(jig, method=method)

        def reused(left, right):
            return estimator.estimate(left, right, part_diameter_mm=PART_DIAMETER_MM)

    for left, right in pairs:  # warm up: Numba, tables on disk, and an old tree's caches
        one_shot(left, right)
        reused(left, right)
    for line in sys.stdin:
        kind, calls = line.split()
        if kind == "estimates":
            answer = [_summary(call(left, right)) for call in (one_shot, reused) for left, right in pairs]
        elif kind == "stages":
            reusable = estimator if Estimator is not None else None
            answer = _stage_times(reusable, jig, pairs, int(calls), method)
        else:
            call = one_shot if kind == "one-shot" else reused
            answer = []
            for k in range(int(calls)):
                left, right = pairs[k % len(pairs)]
                t0 = time.thread_time()
                call(left, right)
                answer.append(time.thread_time() - t0)
        print(REPLY + json.dumps(answer), flush=True)


def _stage_times(estimator, jig, pairs: list, calls: int, method: str) -> list[dict[str, float]]:
    """Each call's stage timings (s of thread CPU): the stage clock's ``time.perf_counter`` is pointed at
    ``time.thread_time`` meanwhile (a tree without an Estimator times ``estimate_pair``'s stages)."""
    from softjig.sensing.pipeline import estimate_pair

    answer = []
    wall = time.perf_counter
    time.perf_counter = time.thread_time
    try:
        for k in range(calls):
            left, right = pairs[k % len(pairs)]
            timings: dict[str, float] = {}
            if estimator is not None:
                estimator.estimate(left, right, part_diameter_mm=PART_DIAMETER_MM, timings=timings)
            else:
                estimate_pair(
                    left, right, jig, part_diameter_mm=PART_DIAMETER_MM, method=method, timings=timings
                )
            answer.append(timings)
    finally:
        time.perf_counter = wall
    return answer


if __name__ == "__main__":
    main()
