"""Per-frame cost of estimating a ROS 2 bag of mono8 pairs, stage by stage, old code against new.

The frames are those of ``bench_bag.py`` (a paper sweep, 1280x720 mono8, the default jig; made there, or
here when ``--data`` has none). Each source tree (``--src``, default: the tree this file is in) runs in
its own warm worker process (``PYTHONPATH`` = that tree's ``src``), writes its own bag of the dataset
(its own writer, zstd chunks) and reads it. The workers take turns, round by round (the order alternating),
and each round reports, in CPU ms a frame (``time.process_time``, one thread):

* ``estimate``: one :class:`~softjig.sensing.estimator.Estimator` (refractive, against the reference
  frame) on pairs already in memory, and its stages (``checks`` = rectification and image checks,
  ``frame``, ``detect``, ``match``, ``triangulate``, ``fit``);
* ``bag read`` and ``bag read+estimate``: the whole bag, as ``softjig estimate BAG --workers 1`` reads it,
  as the mean over the frames (total CPU / frames, what a recording costs: where a zstd chunk holds
  several pairs, only some frames pay for decompressing it) and the median (which then leaves the
  chunks out).

The printed figures are medians over the rounds. Then the trees' results are compared, field by field:
the estimates of every bench frame (from the PNG dataset) and of the default pair of
``tests/test_pipeline.py`` with both methods, and the detected markers.

Run: ``python benchmarks/bench_frame.py --src /tmp/old/src src [--rounds 5] [--data /tmp/bag_frame]``.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

STAGES = ("checks", "frame", "detect", "match", "triangulate", "fit")
ROWS = ("estimate", *STAGES, "bag read (mean)", "bag read+estimate (mean)", "bag read+estimate (median)")


# ------------------------------------------------------------------------------------------ worker


class _Timed:
    """A stage object whose calls of ``method`` add their CPU time to ``spent[name]``."""

    def __init__(self, inner, method: str, name: str, spent: dict[str, float]) -> None:
        self._inner, self._name, self._spent = inner, name, spent
        setattr(self, method, self._timed(getattr(inner, method)))

    def _timed(self, call):
        def timed(*args, **kwargs):
            t0 = time.process_time()
            try:
                return call(*args, **kwargs)
            finally:
                self._spent[self._name] = self._spent.get(self._name, 0.0) + time.process_time() - t0

        return timed

    def __getattr__(self, attr):
        return getattr(self._inner, attr)


def _estimate_pass(estimator, pairs, spent: dict[str, float]) -> dict[str, float]:
    """CPU ms a frame of estimating ``pairs`` (median) and of each stage (median)."""
    from softjig.errors import SoftjigError

    per_stage: dict[str, list[float]] = {s: [] for s in ("estimate", *STAGES)}
    for left, right in pairs:
        spent.clear()
        t0 = time.process_time()
        with contextlib.suppress(SoftjigError):
            estimator.estimate(left, right)
        total = time.process_time() - t0
        per_stage["estimate"].append(total)
        for stage in STAGES[1:]:
            per_stage[stage].append(spent.get(stage, 0.0))
        per_stage["checks"].append(total - sum(spent.values()))
    return {k: 1000 * statistics.median(v) for k, v in per_stage.items()}


def _bag_pass(bag: Path, estimator, *, estimate: bool) -> tuple[float, float]:
    """Mean and median CPU ms a loaded frame of reading the bag (and estimating), first frame (the bag's
    opening, its reference frame) left out (:func:`bench_bag.frame_figures`)."""
    from bench_bag import frame_figures
    from softjig.io.rosbag import BagReader

    with BagReader(bag) as reader:
        _, cpu, mean = frame_figures(reader.pairs(reader.choose_topics()), estimator, estimate=estimate)
    return 1000 * mean, 1000 * statistics.median(cpu)


def _results(estimator_cls, jig, reference, dataset) -> list:
    """Every bench frame's estimate and markers (from the PNG dataset), and the default pair's."""
    import numpy as np

    from softjig.config import CylinderPart, default_jig
    from softjig.errors import SoftjigError
    from softjig.sim.asbuilt import draw_as_built
    from softjig.sim.parts import PartPose
    from softjig.sim.render import render_pair

    def row(estimator, left, right, **kw):
        try:
            result = estimator.estimate(left, right, **kw)
        except SoftjigError as exc:
            return {"error": str(exc)}
        return {
            **result.estimate.to_dict(),
            "left_xy": result.left.xy_px.tolist(),
            "right_xy": result.right.xy_px.tolist(),
        }

    estimator = estimator_cls(jig, reference=reference, method="refractive")
    rows = [row(estimator, f.load_left(), f.load_right()) for f in dataset if not f.reference]
    jig0 = default_jig()
    pose = PartPose(np.radians(10), np.radians(40), 3.0)
    pair = render_pair(draw_as_built(jig0, 7), CylinderPart(50), pose, 3)
    rows.append(row(estimator_cls(jig0, method="refractive"), pair.left, pair.right))
    rows.append(row(estimator_cls(jig0, method="paper"), pair.left, pair.right, part_diameter_mm=50.0))
    return rows


def worker(data: Path, bag: Path) -> None:
    """Serve ``time`` and ``results`` requests on stdin, one JSON line each on stdout."""
    import cv2

    cv2.setNumThreads(1)
    from softjig.io.bag_convert import dataset_to_bag
    from softjig.io.batch import dataset_reference
    from softjig.io.dataset import Dataset
    from softjig.io.rosbag import BagReader
    from softjig.sensing.estimator import Estimator

    dataset = Dataset.open(data / "dataset")
    jig = dataset.jig
    dataset_to_bag(dataset, bag, estimate=False, start_unix_s=1.7e9)
    reference = dataset_reference(dataset, jig)
    with BagReader(bag) as reader:
        frames = reader.pairs(reader.choose_topics())
        pairs = [(f.load_left(), f.load_right()) for f in frames if not f.reference]
    spent: dict[str, float] = {}
    estimator = Estimator(jig, reference=reference, method="refractive")
    timed = Estimator(jig, reference=reference, method="refractive", model=estimator.model)
    for attr, method, name in (
        ("frame_finder", "find", "frame"),
        ("detector", "detect", "detect"),
        ("matcher", "match", "match"),
        ("triangulator", "triangulate", "triangulate"),
        ("fitter", "fit", "fit"),
    ):
        setattr(timed, attr, _Timed(getattr(timed, attr), method, name, spent))
    for _ in range(2):  # warm-up: Numba, tables, page cache
        _estimate_pass(timed, pairs, spent)
        _bag_pass(bag, estimator, estimate=True)
    print(json.dumps({"ready": len(pairs)}), flush=True)
    for line in sys.stdin:
        if line.strip() == "time":
            out = _estimate_pass(timed, pairs, spent)
            out["bag read (mean)"], _ = _bag_pass(bag, estimator, estimate=False)
            mean, median = _bag_pass(bag, estimator, estimate=True)
            out["bag read+estimate (mean)"], out["bag read+estimate (median)"] = mean, median
            print(json.dumps(out), flush=True)
        elif line.strip() == "results":
            print(json.dumps(_results(Estimator, jig, reference, dataset)), flush=True)


# ------------------------------------------------------------------------------------------ parent


def _ensure_data(data: Path, src: str) -> None:
    """The bench_bag dataset in ``data/dataset``, simulated by ``src``'s code when missing."""
    if (data / "dataset" / "frames.jsonl").exists():
        return
    code = (
        "import os, sys; from pathlib import Path;"
        "from softjig.config import default_jig; from softjig.io.simulated import simulate_dataset;"
        "from softjig.sim.scenarios import paper_sweep;"
        "specs = list(paper_sweep(diameters_mm=(50,), alphas_deg=(5, 10, 15, 20), theta_step_deg=30.0));"
        "simulate_dataset(Path(sys.argv[1]), specs, default_jig(), seed=7, workers=os.cpu_count(),"
        " progress=False)"
    )
    env = {**os.environ, "PYTHONPATH": src}
    subprocess.run([sys.executable, "-c", code, str(data / "dataset")], check=True, env=env)


def _start(src: str, data: Path, bag: Path) -> subprocess.Popen:
    env = {**os.environ, "PYTHONPATH": src}
    cmd = [sys.executable, __file__, "--worker", "--data", str(data), "--bag", str(bag)]
    proc = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, env=env)
    return proc


def _ask(proc: subprocess.Popen, what: str):
    assert proc.stdin is not None and proc.stdout is not None
    proc.stdin.write(what + "\n")
    proc.stdin.flush()
    line = proc.stdout.readline()
    if not line:
        raise RuntimeError(f"a worker ended without answering {what!r}")
    return json.loads(line)


def _differences(a, b, path="") -> list[tuple[str, float | str]]:
    """Where two JSON values differ: ``(path, max |difference|)`` for numbers, ``(path, "a != b")``."""
    if isinstance(a, dict) and isinstance(b, dict):
        out = []
        for key in sorted(set(a) | set(b)):
            out += _differences(a.get(key), b.get(key), f"{path}.{key}")
        return out
    if isinstance(a, list) and isinstance(b, list) and len(a) == len(b):
        out = []
        for x, y in zip(a, b, strict=True):
            out += _differences(x, y, f"{path}[]")
        return out
    if a == b:
        return []
    numbers = (int, float)
    if isinstance(a, numbers) and isinstance(b, numbers) and not isinstance(a, bool):
        return [(path, abs(float(a) - float(b)))]
    return [(path, f"{str(a)[:60]} != {str(b)[:60]}")]


def _compare(results: list[list]) -> None:
    base = results[0]
    names = [f"bench frame {i}" for i in range(len(base) - 2)]
    names += ["default pair refractive", "default pair paper"]
    for other_index, other in enumerate(results[1:], start=1):
        worst: dict[str, float | str] = {}
        differing = 0
        for name, a, b in zip(names, base, other, strict=True):
            diffs = _differences(a, b)
            differing += bool(diffs)
            for key, d in diffs:
                if isinstance(d, str):
                    worst[key] = f"{name}: {d}"
                elif not isinstance(worst.get(key), str) and d > worst.get(key, -1.0):
                    worst[key] = d
        print(f"results, tree 0 vs tree {other_index}: {len(base) - differing} of {len(base)} identical")
        for key, d in sorted(worst.items()):
            print(f"  {key}: {d if isinstance(d, str) else f'max |difference| {d:.3g}'}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--src", nargs="+", default=[str(Path(__file__).resolve().parents[1] / "src")])
    parser.add_argument("--data", type=Path, default=Path(tempfile.gettempdir()) / "bench_frame_data")
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--bag", type=Path, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker:
        worker(args.data, args.bag)
        return
    srcs = [str(Path(s).resolve()) for s in args.src]
    _ensure_data(args.data, srcs[-1])
    with tempfile.TemporaryDirectory(prefix="bench_frame_") as tmp:
        procs = [_start(src, args.data, Path(tmp) / f"bag{i}") for i, src in enumerate(srcs)]
        frames = [json.loads(p.stdout.readline())["ready"] for p in procs]  # type: ignore[union-attr]
        rounds: list[list[dict]] = [[] for _ in procs]
        for r in range(args.rounds):
            order = range(len(procs)) if r % 2 == 0 else reversed(range(len(procs)))
            for i in order:
                rounds[i].append(_ask(procs[i], "time"))
        results = [_ask(p, "results") for p in procs]
        for p in procs:
            p.stdin.close()  # type: ignore[union-attr]
            p.wait()
    print(f"{frames[0]} frames 1280x720 mono8, one worker; CPU ms a frame, medians of {args.rounds} rounds")
    print(f"{'':<28}" + "".join(f"{f'tree {i}':>10}" for i in range(len(srcs))))
    for row in ROWS:
        values = [statistics.median(r[row] for r in tree) for tree in rounds]
        print(f"{row:<28}" + "".join(f"{v:>10.2f}" for v in values))
    for i, src in enumerate(srcs):
        print(f"tree {i}: {src}")
    print(f"load average now {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs")
    _compare(results)


if __name__ == "__main__":
    main()
