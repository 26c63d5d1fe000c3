"""The benchmark suite's core functions on one tiny frame, so that it cannot silently rot (no timing)."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("skimage", reason="the benchmark suite's peers need scikit-image (the bench extra)")

BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"


@pytest.fixture(scope="module")
def suite():
    sys.path.insert(0, str(BENCHMARKS))
    try:
        spec = importlib.util.spec_from_file_location("softjig_bench_suite", BENCHMARKS / "suite.py")
        module = importlib.util.module_from_spec(spec)
        sys.modules[spec.name] = module  # its dataclasses look their module up
        spec.loader.exec_module(module)
        yield module
    finally:
        sys.modules.pop("softjig_bench_suite", None)
        sys.path.remove(str(BENCHMARKS))


@pytest.fixture(scope="module")
def rendered(suite):
    from softjig.config import default_jig

    jig = default_jig()
    pairs, seconds = suite.render_pairs(jig, 1)
    return jig, pairs, seconds


def _crop(image, u0, v0, size):
    """A size x size window of the image, its truth shifted into it (a tiny frame)."""
    inside = np.all(
        (image.truth_px >= [u0 + 8, v0 + 8]) & (image.truth_px < [u0 + size - 8, v0 + size - 8]), axis=1
    )
    return type(image)(
        image.name, image.pixels[v0 : v0 + size, u0 : u0 + size].copy(), image.truth_px[inside] - [u0, v0],
        np.empty((0, 4)),
    )  # fmt: skip


def test_score_matches_one_to_one(suite):
    image = suite.Image("t", np.zeros((10, 10), np.uint8), np.array([[1.0, 1.0], [5.0, 5.0]]),
                        np.array([[7.0, 7.0, 9.0, 9.0]]))  # fmt: skip
    s = suite.score(np.array([[1.5, 1.0], [1.2, 1.0], [8.0, 8.0], [5.0, 9.0]]), image)
    np.testing.assert_allclose(s.errors_px, [0.2])  # the nearer of two detections of one marker
    assert (s.n_truth, s.n_false, s.recall) == (2, 2, 0.5)  # [8, 8] is in the ignored box


def test_detectors_find_the_markers_of_a_tiny_frame(suite, rendered):
    jig, pairs, seconds = rendered
    assert len(seconds) == 1 and seconds[0] > 0
    image = _crop(suite.images_of(pairs)[0], 440, 200, 160)
    assert len(image.truth_px) >= 4
    settings = suite.PeerSettings(suite.sensing_setup(jig).sigma_px, 0.05, 0.03)
    detectors = {**suite.our_detectors(jig), **suite.peer_detectors(settings)}
    assert {"ours", "plain LoG + 3x3 quadratic", "skimage blob_log", "cv2 SimpleBlobDetector"} <= set(
        detectors
    )
    results = suite.run_detectors(detectors, [image], repeats=1)
    for result in results:
        assert result.score.recall > 0.8, result.name
        assert result.score.rmse_px < 1.0, result.name
        assert len(result.seconds) == 1
    table = suite.detector_table(results, 1, 0.1)
    assert table.rows[0][0] == "ours" and table.rows[0][7] == "1.00" and "RMSE/CRB" in table.headers
    text, markdown = suite.format_text(table), suite.format_markdown(table)
    assert "skimage blob_log" in text and markdown.startswith("### ") and "|---|" in markdown


def test_estimate_timings_and_tables(suite, rendered, tmp_path):
    jig, pairs, _ = rendered
    records = suite.time_estimates(pairs, jig, "paper", repeats=1)
    assert {"detect", "fit", "total"} <= set(records) and all(len(v) == 1 for v in records.values())
    tables = [suite.estimate_table("paper", records), suite.machine_table()]
    assert tables[0].rows[-1][0] == "total"
    assert dict(tables[1].rows)["cores"].isdigit()
    out = tmp_path / "RESULTS.md"
    suite.write_results(tables, out, "python benchmarks/suite.py")
    assert out.read_text().startswith("# softjig benchmark results") and "| stage |" in out.read_text()
