"""Is any cell of the paper's sweep worse than before? Per-frame errors of two estimators, paired.

Issue 13's goal "on the paper's sweep, no cell worse than today" compares RMSEs of a few frames a cell:
with ``--theta-step 30`` a cell of ``softjig compare``'s held-out half holds 6 frames, whose RMSE moves
by about 30 % from noise alone. This benchmark compares the two estimators frame by frame on the same
images instead: for each (diameter, tilt) cell, the RMSE of every frame's error against the truth, old and
new, and a paired one-sided Wilcoxon signed-rank test of the squared errors (is the new one larger?).
Over 24 cells and two ways, about one p below 0.05 is expected by chance.

Run (the old tree simulates, so both trees can read the dataset's rig)::

    PYTHONPATH=OLD/src python -c "from softjig.cli import main; main()" simulate --scenario paper-sweep \\
        --theta-step 30 --seed 0 --out /tmp/sweep
    PYTHONPATH=OLD/src python -c "from softjig.cli import main; main()" estimate /tmp/sweep \\
        --out /tmp/old.jsonl [--no-part-size]
    softjig estimate /tmp/sweep --out /tmp/new.jsonl [--no-part-size]
    python benchmarks/bench_sweep_cells.py /tmp/sweep /tmp/old.jsonl /tmp/new.jsonl
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import numpy as np
from scipy import stats

WORSE_P = 0.05


def truths(root: Path) -> dict[int, tuple[float, float, np.ndarray]]:
    """``index -> (diameter mm, tilt deg, true normal)`` of the dataset's loaded frames."""
    out = {}
    for line in (root / "frames.jsonl").read_text().splitlines():
        frame = json.loads(line)
        if frame.get("truth") and frame.get("part"):
            normal = np.asarray(frame["truth"]["normal"], dtype=float)
            out[frame["index"]] = (float(frame["part"]["diameter_mm"]), float(frame["alpha_deg"]), normal)
    return out


def errors_deg(results: Path, truth: dict) -> dict[int, float]:
    """``index -> angle between the estimated and the true normal (deg)`` of the frames estimated."""
    out = {}
    for line in results.read_text().splitlines():
        row = json.loads(line)
        if row.get("index") in truth and "normal" in row:
            cos = float(np.dot(row["normal"], truth[row["index"]][2]))
            out[row["index"]] = math.degrees(math.acos(min(1.0, max(-1.0, cos))))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("dataset", type=Path)
    parser.add_argument("old", type=Path, help="results of the old estimator (softjig estimate --out)")
    parser.add_argument("new", type=Path, help="results of the new estimator")
    args = parser.parse_args()
    truth = truths(args.dataset)
    old, new = errors_deg(args.old, truth), errors_deg(args.new, truth)
    both = sorted(set(old) & set(new))
    if not both:  # else every figure below is the NaN of an empty mean
        parser.error(
            f"no loaded frame of {args.dataset} is estimated in both {args.old} and {args.new} "
            f"(loaded {len(truth)}, estimated by old {len(old)}, new {len(new)}): results of another dataset?"
        )
    print(f"frames: {len(truth)} loaded, estimated by old {len(old)}, new {len(new)}, both {len(both)}")
    print("| D mm | tilt deg | frames | RMSE old deg | RMSE new deg | p (new worse) |")
    print("|---|---|---|---|---|---|")
    worse = better = significant = 0
    for cell in sorted({truth[i][:2] for i in both}):
        idx = [i for i in both if truth[i][:2] == cell]
        a, b = np.array([old[i] for i in idx]), np.array([new[i] for i in idx])
        rms_a, rms_b = math.sqrt(np.mean(a**2)), math.sqrt(np.mean(b**2))
        p = stats.wilcoxon(b**2, a**2, alternative="greater").pvalue if np.any(a != b) else 1.0
        worse += rms_b > rms_a + 0.005
        better += rms_b < rms_a - 0.005
        significant += p < WORSE_P
        mark = " **worse**" if p < WORSE_P else ""
        print(f"| {cell[0]:.0f} | {cell[1]:.0f} | {len(idx)} | {rms_a:.3f} | {rms_b:.3f} | {p:.3f}{mark} |")
    a, b = np.array([old[i] for i in both]), np.array([new[i] for i in both])
    p_all = stats.wilcoxon(b**2, a**2, alternative="greater").pvalue if np.any(a != b) else 1.0
    print(
        f"\ncells worse by > 0.005 deg: {worse}, better: {better}, worse with p < {WORSE_P}: {significant}; "
        f"all frames: RMSE {math.sqrt(np.mean(a**2)):.3f} -> {math.sqrt(np.mean(b**2)):.3f} (p {p_all:.3f})"
    )


if __name__ == "__main__":
    main()
