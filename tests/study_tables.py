"""Synthetic study tables of exactly the study contract's schema (results.parquet, designs.parquet), for the
report's tests: a known ranking and known Pareto fronts without rendering anything."""

from __future__ import annotations

import itertools
import json
import math

import numpy as np
import pyarrow as pa

from softjig.study.spec import StudySpec, parse_study

STUDY = {
    "study": {"name": "pitch-distance-layout", "seeds": [0]},
    "vary": {
        "markers.pitch_mm": [6.0, 8.0, 10.0],
        "cameras.distance_mm": [120.0, 150.0],
        "markers.layout": ["square", "hex"],
    },
    "frames": {"diameters_mm": [40, 60], "alphas_deg": [5, 20], "theta_step_deg": 180},
    "estimate": {"methods": ["refractive", "paper"]},
}
FAILED_DESIGN = 11  # every "paper" estimate of this design failed
SILENT_DESIGN = 4  # "refractive" of this design has a silent failure


def study_spec() -> StudySpec:
    return parse_study(STUDY)


def design_rmse(pitch: float, distance: float, layout: str, method: str) -> float:
    """A made-up accuracy: finer pitch and nearer cameras are better, hex a bit better, paper worse."""
    return (
        0.1 * pitch
        + 0.01 * (distance - 100)
        - (0.05 if layout == "hex" else 0.0)
        + (0.5 if method == "paper" else 0)
    )


def marker_count(pitch: float, layout: str) -> int:
    return round(4000 / pitch**2 * (1.15 if layout == "hex" else 1.0))


def _design_values(spec: StudySpec):
    return list(itertools.product(*(values for _, values in spec.vary)))


def results_table(spec: StudySpec) -> pa.Table:
    rows = []
    frames = [
        (d, a, t) for d in spec.frames.diameters_mm for a in spec.frames.alphas_deg for t in (0.0, 180.0)
    ]
    for design_id, values in enumerate(_design_values(spec)):
        for method in spec.methods:
            rmse = design_rmse(*values, method)
            failed = design_id == FAILED_DESIGN and method == "paper"
            for frame, (d, a, t) in enumerate(frames):
                nan = math.nan
                row = dict(zip(spec.paths, values, strict=True))
                row.update(
                    design_id=design_id,
                    method=method,
                    seed=0,
                    frame=frame,
                    diameter_mm=float(d),
                    alpha_deg=float(a),
                    theta_deg=t,
                    depth_mm=3.0,
                    true_nx=0.0,
                    true_ny=0.0,
                    true_nz=1.0,
                    est_nx=nan if failed else 0.0,
                    est_ny=nan if failed else 0.0,
                    est_nz=nan if failed else 1.0,
                    error_deg=nan if failed else rmse,
                    sigma_deg=nan if failed else 0.3,
                    quality="failed" if failed else "ok",
                    reason="too few markers" if failed else "",
                    markers_under_part=0 if failed else 12,
                    estimate_ms=3.0,
                )
                rows.append(row)
    return pa.Table.from_pylist(rows, schema=results_schema(spec))


def results_schema(spec: StudySpec) -> pa.Schema:
    varied = [(p, pa.float64() if p in spec.numeric_paths else pa.string()) for p in spec.paths]
    f64, i64, s = pa.float64(), pa.int64(), pa.string()
    return pa.schema(
        [("design_id", i64), ("method", s), ("seed", i64), ("frame", i64), *varied]
        + [(c, f64) for c in ("diameter_mm", "alpha_deg", "theta_deg", "depth_mm")]
        + [(c, f64) for c in ("true_nx", "true_ny", "true_nz", "est_nx", "est_ny", "est_nz")]
        + [("error_deg", f64), ("sigma_deg", f64), ("quality", s), ("reason", s)]
        + [("markers_under_part", i64), ("estimate_ms", f64)]
    )


def designs_schema(spec: StudySpec) -> pa.Schema:
    varied = [(p, pa.float64() if p in spec.numeric_paths else pa.string()) for p in spec.paths]
    f64, i64, s = pa.float64(), pa.int64(), pa.string()
    return pa.schema(
        [
            ("design_id", i64),
            ("method", s),
            *varied,
            ("n_estimates", i64),
            ("rmse_deg", f64),
            ("cells", s),
            ("worst_cell", s),
            ("worst_cell_rmse_deg", f64),
            ("recall", f64),
            ("suspect_fraction", f64),
            ("silent", i64),
            ("median_markers_under_part", f64),
            ("latency_ms_median", f64),
            ("marker_count", i64),
        ]
    )


def designs_table(spec: StudySpec) -> pa.Table:
    rows = []
    for design_id, values in enumerate(_design_values(spec)):
        for method in spec.methods:
            failed = design_id == FAILED_DESIGN and method == "paper"
            rmse = math.nan if failed else design_rmse(*values, method)
            cells = [
                {
                    "diameter_mm": float(d),
                    "alpha_deg": float(a),
                    "rmse_deg": None if failed else rmse + 0.1 * (a > 10),
                    "n": 0 if failed else 2,
                }
                for d in spec.frames.diameters_mm
                for a in spec.frames.alphas_deg
            ]
            row = dict(zip(spec.paths, values, strict=True))
            row.update(
                design_id=design_id,
                method=method,
                n_estimates=8,
                rmse_deg=rmse,
                cells=json.dumps(cells),
                worst_cell="" if failed else "D40 a20",
                worst_cell_rmse_deg=math.nan if failed else rmse + 0.1,
                recall=0.0 if failed else 1.0,
                suspect_fraction=0.0,
                silent=1 if (design_id == SILENT_DESIGN and method == "refractive") else 0,
                median_markers_under_part=math.nan if failed else 12.0,
                latency_ms_median=3.0,
                marker_count=marker_count(values[0], values[2]),
            )
            rows.append(row)
    return pa.Table.from_pylist(rows, schema=designs_schema(spec))


def expected_front(spec: StudySpec, designs: pa.Table, cost_column: str) -> set[int]:
    """Brute force: the designs no design of the same method beats in both (cost, RMSE)."""
    rows = designs.to_pylist()
    out = set()
    for r in rows:
        if not np.isfinite(r["rmse_deg"]):
            continue
        beaten = any(
            o["method"] == r["method"]
            and np.isfinite(o["rmse_deg"])
            and o[cost_column] <= r[cost_column]
            and o["rmse_deg"] <= r["rmse_deg"]
            and (o[cost_column] < r[cost_column] or o["rmse_deg"] < r["rmse_deg"])
            for o in rows
        )
        if not beaten:
            out.add(r["design_id"])
    return out
