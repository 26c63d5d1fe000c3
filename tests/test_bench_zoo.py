"""bench_zoo's core on one tiny zoo design, so that the benchmark cannot silently rot (no timing)."""

from __future__ import annotations

import importlib.util
import json
import sys
from dataclasses import replace
from pathlib import Path

import pytest

from softjig.sim.zoo import ZooRanges, draw_designs

BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"


@pytest.fixture(scope="module")
def bench():
    spec = importlib.util.spec_from_file_location("softjig_bench_zoo", BENCHMARKS / "bench_zoo.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules["softjig_bench_zoo"] = module
    try:
        spec.loader.exec_module(module)
        yield module
    finally:
        sys.modules.pop("softjig_bench_zoo", None)


def test_silent_and_coverage_definitions(bench):
    base = dict(
        design=0,
        family="f",
        frame=1,
        way="w",
        part="cylinder",
        part_size_mm=50.0,
        alpha_deg=10.0,
        offset_mm=0.0,
        n_contact=40,
        n_points=30,
        time_ms=5.0,
        failure=None,
    )
    silent = bench.Row(**base, error_deg=3.5, sigma_deg=0.5, quality="ok")
    flagged = bench.Row(**base, error_deg=3.5, sigma_deg=0.5, quality="suspect")
    honest = bench.Row(**base, error_deg=3.5, sigma_deg=1.0, quality="ok")
    small = bench.Row(**base, error_deg=0.4, sigma_deg=0.5, quality="ok")
    assert silent.silent and not flagged.silent and not honest.silent and not small.silent
    assert small.covered and not silent.covered
    s = bench.summary([silent, flagged, honest, small])
    assert s["silent"] == 1 and s["suspect"] == 1 and s["coverage"] == 25.0 and s["failures"] == 0


def test_one_tiny_design_four_ways(bench, tmp_path):
    ranges = replace(ZooRanges(), resolutions=((640, 480),))
    design = next(draw_designs(1, seed=2, frames=1, ranges=ranges))
    rows = bench.evaluate_design(design.jig, design.specs, design.seed, design=0, family=design.family)
    assert [r.way for r in rows] == [w for w, *_ in bench.WAYS]
    for r in rows:
        assert (r.error_deg is None) == (r.failure is not None) == (r.normal is None)
        if r.normal is not None:  # the estimate's unit normal, pointing up into the membrane
            assert abs(sum(v * v for v in r.normal) - 1.0) < 1e-9 and r.normal[2] > 0
    lines = bench.table_by(rows, lambda r: r.family, "t") + bench.timing_table(rows)
    out = tmp_path / "RESULTS.md"
    out.write_text("# softjig benchmark results\n\n## Other\n\nkept\n")
    bench.write_section(out, lines)
    bench.write_section(out, lines)  # replaces its own section, keeps the others
    text = out.read_text()
    assert text.count(bench.SECTION) == 1 and "## Other\n\nkept" in text
    json.dumps([r.__dict__ for r in rows])


def test_suspect_reasons_are_counted_by_kind_with_their_false_alarms(bench):
    assert (
        bench.reason_kind("suspect: only 16 markers were fitted, too few to check (at least 15 are needed)")
        == "only N markers were fitted"
    )
    assert bench.reason_kind("suspect: the plane is tilted 41 deg: steep") == "the plane is tilted N deg"
    assert bench.reason_kind(
        "suspect: 1 marker in or beside the contact lies above it, so"
    ) == bench.reason_kind("suspect: 3 markers in or beside the contact lie above it, so")
    base = dict(
        design=0, family="f", frame=1, way="no size+reference", part="box", part_size_mm=40.0,
        alpha_deg=10.0, offset_mm=0.0, sigma_deg=0.5, n_contact=20, n_points=16, time_ms=5.0, failure=None,
    )  # fmt: skip
    partial = "only N markers are in partial contact"
    rows = [
        bench.Row(**base, error_deg=0.4, quality="suspect", reasons=(partial,)),
        bench.Row(**base, error_deg=12.0, quality="suspect", reasons=(partial, "another contact fits")),
        bench.Row(**base, error_deg=2.0, quality="suspect", reasons=("another contact fits",)),
        bench.Row(**base, error_deg=0.2, quality="ok"),
    ]
    lines = bench.reasons_table(rows)
    assert f"| no size+reference | {partial} | 2 | 1 | 1 | 1 |" in lines
    assert "| no size+reference | another contact fits | 2 | 0 | 1 | 1 |" in lines
