"""The study's report (softjig.study.report): the ranking in the terminal, report.html self-contained, the
figures, the Pareto fronts and their designs' rigs, on synthetic tables of exactly the study contract's
schema (tests/study_tables.py) and a real study spec."""

from __future__ import annotations

import base64
import os
import re

import numpy as np
import pytest
from rich.console import Console

from softjig.config import load_jig
from softjig.errors import InputError
from softjig.study.best import HEADER_MARK
from softjig.study.report import (
    cell_grid,
    cost_columns,
    ranked_designs,
    summary_table,
    write_study_outputs,
)
from softjig.study.spec import build_designs
from study_tables import (
    FAILED_DESIGN,
    SILENT_DESIGN,
    designs_table,
    expected_front,
    results_table,
    study_spec,
)

PNG = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def study(tmp_path_factory):
    spec = study_spec()
    results, designs = results_table(spec), designs_table(spec)
    out = tmp_path_factory.mktemp("study")
    return spec, results, designs, out, write_study_outputs(out, spec, results, designs)


def _text(table) -> str:
    console = Console(width=250, record=True, color_system=None)
    console.print(table)
    return console.export_text().replace("\u2502", " ")


def test_summary_ranks_by_rmse_with_failed_designs_last():
    spec = study_spec()
    designs = designs_table(spec)
    ranked = ranked_designs(designs)
    rmse = [r["rmse_deg"] for r in ranked]
    finite = [v for v in rmse if np.isfinite(v)]
    assert finite == sorted(finite) and not np.isfinite(rmse[-1])
    assert (ranked[-1]["design_id"], ranked[-1]["method"]) == (FAILED_DESIGN, "paper")
    lines = _text(summary_table(designs, rows=None)).splitlines()
    body = [line for line in lines if re.match(r"^\W*\d+\W+\d{3}\W", line)]
    assert len(body) == designs.num_rows
    assert body[0].split()[:3] == ["1", "001", "refractive"]  # pitch 6, distance 120, hex: the best
    assert "hex" in body[0] and "D40 a20 0.85" in body[0]
    assert "n/a" in body[-1] and f"{FAILED_DESIGN:03d}" in body[-1]
    table = summary_table(designs)
    heads = [str(c.header).replace(".\n", ".").replace("\n", " ") for c in table.columns]
    assert heads == [
        "rank",
        "design",
        "method",
        *spec.paths,
        "RMSE (deg)",
        "worst cell (deg)",
        "recall",
        "suspect",
        "silent",
        "latency (ms)",
        "markers",
    ]


def test_summary_shows_the_best_rows_and_says_how_many_more():
    designs = designs_table(study_spec())
    text = _text(summary_table(designs, rows=5))
    assert f"{designs.num_rows - 5} more rows in designs.parquet" in text
    table = summary_table(designs)
    silent = [i for i, r in enumerate(ranked_designs(designs)[:20]) if r["silent"]]
    assert [table.rows[i].style for i in silent] == ["red"] * len(silent) and silent
    assert all(table.rows[i].style is None for i in range(len(table.rows)) if i not in silent)


def test_missing_contract_column_is_an_input_error():
    designs = designs_table(study_spec()).drop_columns(["recall"])
    with pytest.raises(InputError, match="recall"):
        summary_table(designs)


def test_cost_columns_default_to_marker_count_and_varied_camera_distance():
    spec = study_spec()
    assert cost_columns(designs_table(spec), spec.paths) == ("marker_count", "cameras.distance_mm")
    assert cost_columns(designs_table(spec), ["markers.pitch_mm"]) == ("marker_count",)


def test_front_designs_and_their_rigs(study):
    spec, _, designs, out, outputs = study
    front = expected_front(spec, designs, "marker_count") | expected_front(
        spec, designs, "cameras.distance_mm"
    )
    assert set(outputs.front_design_ids) == front
    assert [p.name for p in outputs.best_rigs] == [f"{i:03d}.toml" for i in sorted(front)]
    by_id = {d.design_id: d for d in build_designs(spec)}
    for path in outputs.best_rigs:
        design_id = int(path.stem)
        assert load_jig(path) == by_id[design_id].jig  # the design's full config, from the study's product
        text = path.read_text()
        assert text.startswith(HEADER_MARK) and f"design {design_id:03d}" in text
    assert sorted(p.name for p in (out / "best").iterdir()) == [p.name for p in outputs.best_rigs]


def test_report_html_is_self_contained(study):
    _, _, designs, out, outputs = study
    page = outputs.report_html.read_text()
    assert outputs.report_html == out / "report.html"
    assert "<script" not in page.lower() and "http://" not in page and "https://" not in page
    assert "<link" not in page.lower() and 'src="data:image/png;base64,' in page
    images = re.findall(r'src="data:image/png;base64,([A-Za-z0-9+/=]+)"', page)
    assert len(images) == len(outputs.figures) == 4
    for data, path in zip(images, outputs.figures, strict=True):
        assert base64.b64decode(data) == path.read_bytes() and path.read_bytes().startswith(PNG)
    assert {p.name for p in outputs.figures} == {
        "accuracy.png",
        "best-cells.png",
        "pareto-marker_count.png",
        "pareto-cameras.distance_mm.png",
    }
    assert all(p.parent == out / "figures" for p in outputs.figures)
    assert page.count("<tr") >= designs.num_rows  # every row ranked (24 rows < the 50 shown)
    assert "pitch-distance-layout" in page and '<a href="best/001.toml">best/001.toml</a>' in page
    # the silent design is on the marker-count front: marked in the ranking and in that front's table
    assert (
        len(
            re.findall(
                rf'<tr class="silent">(<td class="num">\d+</td>)?<td class="num">{SILENT_DESIGN:03d}', page
            )
        )
        == 2
    )
    assert f"{designs.num_rows // 2 * 8 * 2 - 8} ok" in page and "8 failed" in page


def test_failed_cells_come_from_the_results():
    spec = study_spec()
    row = next(r for r in designs_table(spec).to_pylist() if r["design_id"] == SILENT_DESIGN)
    grid = cell_grid(row["cells"], [(40.0, 20.0), (40.0, 20.0), (60.0, 5.0)])
    assert grid.diameters_mm.tolist() == [40, 60] and grid.alphas_deg.tolist() == [5, 20]
    assert grid.failed.tolist() == [[0, 2], [1, 0]] and grid.count.tolist() == [[2, 2], [2, 2]]
    assert grid.rmse_deg[0, 1] == pytest.approx(row["rmse_deg"] + 0.1)
    with pytest.raises(InputError, match="cells"):
        cell_grid('[{"diameter_mm": 40}]')


def test_a_design_table_with_no_estimates_still_reports(tmp_path):
    spec = study_spec()
    designs = designs_table(spec).slice(0, 0)
    outputs = write_study_outputs(tmp_path, spec, results_table(spec).slice(0, 0), designs)
    assert outputs.front_design_ids == () and outputs.best_rigs == ()
    assert outputs.report_html.is_file()


def test_other_costs_and_bad_costs(tmp_path):
    spec = study_spec()
    results, designs = results_table(spec), designs_table(spec)
    outputs = write_study_outputs(tmp_path, spec, results, designs, costs=["markers.pitch_mm"])
    assert set(outputs.front_design_ids) == expected_front(spec, designs, "markers.pitch_mm")
    assert [p.name for p in outputs.figures if p.name.startswith("pareto")] == ["pareto-markers.pitch_mm.png"]
    for bad, message in (("markers.layout", "not numbers"), ("plate.thickness_mm", "no cost column")):
        with pytest.raises(InputError, match=message):
            write_study_outputs(tmp_path / "x", spec, results, designs, costs=[bad])
    assert not (tmp_path / "x").exists(), "a bad cost is found before anything is written"


def test_on_the_study_commands_own_tables(tmp_path):
    """The synthetic tables have the study's own schemas, and the report reads designs.parquet as the
    study aggregates it (softjig.study.results.design_table) from synthetic estimates."""
    from softjig.study.results import design_table, designs_schema, results_schema
    from softjig.study.spec import Study
    from study_tables import designs_schema as our_designs_schema
    from study_tables import results_schema as our_results_schema

    spec = study_spec()
    assert our_results_schema(spec) == results_schema(spec)
    assert our_designs_schema(spec) == designs_schema(spec)
    results = results_table(spec)
    study = Study(spec, build_designs(spec))
    designs = design_table(study, results, set(range(spec.n_designs)))
    outputs = write_study_outputs(tmp_path, spec, results, designs)
    front = expected_front(spec, designs, "marker_count") | expected_front(
        spec, designs, "cameras.distance_mm"
    )
    assert set(outputs.front_design_ids) == front and front
    for path in outputs.best_rigs:
        assert load_jig(path) == study.designs[int(path.stem)].jig
    page = outputs.report_html.read_text()
    assert "8 failed" in page and len(outputs.figures) == 4


def test_outputs_honour_the_umask(tmp_path):
    spec = study_spec()
    old = os.umask(0o027)
    try:
        outputs = write_study_outputs(tmp_path, spec, results_table(spec), designs_table(spec))
    finally:
        os.umask(old)
    for path in (outputs.report_html, *outputs.figures, *outputs.best_rigs):
        assert path.stat().st_mode & 0o777 == 0o640, path
