"""Two trees' estimates of one zoo, row by row: what a change to the estimator did, way by way.

Run each tree's ``bench_zoo.py`` on the same zoo, then compare::

    PYTHONPATH=OLD/src python benchmarks/bench_zoo.py --seed S --no-sweep --json-out /tmp/old.jsonl
    python benchmarks/bench_zoo.py --seed S --no-sweep --json-out /tmp/new.jsonl
    python benchmarks/bench_zoo_compare.py /tmp/old.jsonl /tmp/new.jsonl [--threshold 0.5]

It prints, for each way, old -> new: the RMSE of the goals' set (parts >= 40 mm) over every estimate and
over the "ok" ones, the suspect estimates of that set, the silent failures and failures over every part,
and the 1-sigma coverage (``bench_zoo``'s definitions, :func:`bench_zoo.summary`); then every row whose
error moved by more than ``--threshold`` deg, or whose quality or failure changed. The RMSE over every
estimate is set by a handful of suspect frames, so the rows say more than the totals: a change can be
judged by the frames it moved.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
from collections.abc import Sequence
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_zoo import WAYS, Row, summary

GOAL_SIZE_MM = 40.0  # the goals' set: parts this wide or wider
_FIELDS = {f.name for f in dataclasses.fields(Row)}


def load_rows(path: Path) -> dict[tuple[int, int, str], Row]:
    """``bench_zoo --json-out``'s rows by ``(design, frame, way)``."""
    if not path.is_file():
        raise SystemExit(f"error: {path} is not a file: give bench_zoo.py --json-out's output")
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError:
        raise SystemExit(f"error: {path} is not text: give bench_zoo.py --json-out's output") from None
    rows = {}
    for number, line in enumerate(text.splitlines(), start=1):
        if not line.strip():
            continue
        try:
            row = Row(**{k: v for k, v in json.loads(line).items() if k in _FIELDS})
        except (json.JSONDecodeError, TypeError, AttributeError) as exc:
            raise SystemExit(
                f"error: {path}:{number} is not a row of bench_zoo.py --json-out ({exc})"
            ) from None
        key = (row.design, row.frame, row.way)
        if key in rows:  # two zoos in one file (the rows name no seed): one would hide the other
            raise SystemExit(
                f"error: {path}:{number} repeats design {row.design}, frame {row.frame}, {row.way}: "
                "give one zoo (one --seed) per file"
            )
        rows[key] = row
    return rows


def way_line(way: str, old: Sequence[Row], new: Sequence[Row]) -> str:
    """One way's totals, old -> new."""

    def figures(rows: Sequence[Row]) -> dict[str, float]:
        goal = [r for r in rows if r.part_size_mm >= GOAL_SIZE_MM]
        ok = [r for r in goal if r.quality == "ok"]
        every, goal_s = summary(rows), summary(goal)
        return {
            "RMSE": goal_s["rmse"],
            "RMSE ok": summary(ok)["rmse"] if ok else math.nan,
            "suspect": goal_s["suspect"],
            "silent": every["silent"],
            "failed": every["failures"],
            "cover %": every["coverage"],
        }

    a, b = figures(old), figures(new)
    cells = [
        f"{k} {a[k]:.2f} -> {b[k]:.2f}" if k.startswith(("RMSE", "cover")) else f"{k} {a[k]} -> {b[k]}"
        for k in a
    ]
    return f"{way:<20} " + " | ".join(cells)


def _error(row: Row) -> str:
    if row.error_deg is None:
        return f"failed ({row.failure})"
    return f"{row.error_deg:.2f}{'' if row.quality == 'ok' else ' suspect'}"


def changed_rows(old: dict, new: dict, threshold_deg: float) -> list[str]:
    """The rows of both whose error moved by more than ``threshold_deg``, or whose quality or failure
    changed, largest move first."""
    moved = []
    for key in sorted(old.keys() & new.keys()):
        a, b = old[key], new[key]
        if (a.error_deg is None) != (b.error_deg is None) or a.quality != b.quality:
            move = math.inf
        elif a.error_deg is None:
            continue
        else:
            move = abs(b.error_deg - a.error_deg)
            if move <= threshold_deg:
                continue
        moved.append(
            (
                move,
                f"  d{key[0]:<3} f{key[1]:<3} {key[2]:<20} {a.part:<8} {a.part_size_mm:3.0f} mm: "
                f"{_error(a)} -> {_error(b)}",
            )
        )
    return [line for _, line in sorted(moved, key=lambda m: -m[0])]


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("old", type=Path, help="bench_zoo.py --json-out of the old tree")
    parser.add_argument("new", type=Path, help="bench_zoo.py --json-out of the new tree, on the same zoo")
    parser.add_argument("--threshold", type=float, default=0.5, help="list rows whose error moved more (deg)")
    args = parser.parse_args(argv)
    if not (math.isfinite(args.threshold) and args.threshold >= 0):
        raise SystemExit(f"error: --threshold must be a finite angle >= 0 deg, got {args.threshold}")
    old, new = load_rows(args.old), load_rows(args.new)
    shared = old.keys() & new.keys()
    if not shared:
        raise SystemExit(
            f"error: {args.old} and {args.new} share no (design, frame, way): run both trees on the same zoo "
            "(the same --seed, --designs and --frames)"
        )
    print(f"{len(shared)} rows in both ({len(old)} old, {len(new)} new)")
    for way, *_ in WAYS:
        keys = sorted(k for k in shared if k[2] == way)
        if keys:
            print(way_line(way, [old[k] for k in keys], [new[k] for k in keys]))
    lines = changed_rows(old, new, args.threshold)
    print(f"{len(lines)} rows moved by more than {args.threshold:g} deg or changed quality or failure")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
