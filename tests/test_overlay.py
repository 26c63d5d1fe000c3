"""The overlay of `softjig estimate --overlay` and the report's stereo pair: a visible normal and a legend."""

from __future__ import annotations

import numpy as np
import pytest
from typer.testing import CliRunner

from softjig.cli import app
from softjig.config import default_jig
from softjig.evaluation import overlay
from softjig.io.batch import dataset_reference
from softjig.io.dataset import Dataset
from softjig.io.simulated import simulate_dataset
from softjig.sensing.pipeline import estimate_pair
from softjig.sim.scenarios import paper_sweep

runner = CliRunner()
MAGENTA = np.array(overlay.MAGENTA)


@pytest.fixture(scope="module")
def pair(tmp_path_factory):
    """A reference frame and two loaded frames: D = 50 mm tilted 10 deg at theta 0 and 180 deg."""
    out = tmp_path_factory.mktemp("overlay") / "sweep"
    specs = list(paper_sweep(diameters_mm=(50,), alphas_deg=(10,), theta_step_deg=180))
    simulate_dataset(out, specs, default_jig(), seed=5, workers=1, progress=False)
    return Dataset.open(out)


def _magenta_extent_px(image: np.ndarray, width: int) -> float:
    """The diagonal of the bounding box of the magenta (normal) pixels in the left image (px)."""
    left = image[:, :width].astype(int)
    near = np.abs(left - MAGENTA).sum(axis=2) < 60
    ys, xs = np.nonzero(near)
    assert len(xs), "no normal drawn"
    return float(np.hypot(xs.max() - xs.min(), ys.max() - ys.min()))


@pytest.mark.parametrize("method", ["paper", "refractive"])
def test_the_normal_is_an_arrow_long_enough_to_see(pair, method):
    frame = pair[1]
    left, right = frame.load_left(), frame.load_right()
    extra = {"reference": dataset_reference(pair, pair.jig)} if method == "refractive" else {}
    result = estimate_pair(left, right, pair.jig, part_diameter_mm=50.0, method=method, **extra)
    image = overlay.draw_overlay(left, right, result, pair.jig)
    assert image.shape == (left.shape[0], 2 * left.shape[1], 3)
    # The old 20 mm along the normal, seen by cameras looking along it, was 3-6 px; the magenta of the
    # legend's own arrow lies in the right image, not counted here.
    assert _magenta_extent_px(image, left.shape[1]) >= overlay.MIN_ARROW_PX
    base, tip = overlay.normal_arrow_px(result, pair.jig)
    # A 10 deg tilt (the paper's method reads about 6) exaggerated 5 times, 30 mm long: 15-25 mm sideways.
    assert np.hypot(*(tip - base)) > 1.3 * overlay.MIN_ARROW_PX


def test_the_arrow_points_where_the_part_tilts(pair):
    """theta 0 and 180 deg tilt the part opposite ways: the drawn arrows point opposite ways."""
    reference = dataset_reference(pair, pair.jig)
    directions = []
    for k in (1, 2):
        frame = pair[k]
        result = estimate_pair(
            frame.load_left(), frame.load_right(), pair.jig, part_diameter_mm=50.0, reference=reference
        )
        base, tip = overlay.normal_arrow_px(result, pair.jig)
        directions.append((tip - base) / np.hypot(*(tip - base)))
    assert float(np.dot(*directions)) < -0.9


def test_the_legend_is_drawn_on_the_image(pair, tmp_path):
    """`estimate --overlay`: the right image's top right corner holds the legend (dark box, every colour)."""
    import cv2

    frame = pair[1]
    out = tmp_path / "o.png"
    args = [str(frame.left_path), str(frame.right_path), "--config", str(pair.root / "rig.toml")]
    result = runner.invoke(app, ["estimate", *args, "--part-diameter", "50", "--overlay", str(out)])
    assert result.exit_code == 0, result.output
    image = cv2.imread(str(out))[:, :, ::-1].astype(int)
    corner = image[:320, -460:]
    for colour in (overlay.RED, overlay.GREEN, overlay.YELLOW, overlay.CYAN, overlay.MAGENTA):
        assert (np.abs(corner - np.array(colour)).sum(axis=2) < 60).any(), colour
    assert (np.abs(corner - np.array(overlay.WHITE)).sum(axis=2) < 30).sum() > 200  # the labels' text


def test_a_marker_left_out_for_a_glint_over_it_is_crossed_out(pair):
    """A glint painted over the rim of a matched marker in the left image: the refractive estimate leaves
    that marker out (it does not look like one) and the overlay crosses it out, in both images."""
    frame = pair[1]
    left, right = frame.load_left(), frame.load_right()
    reference = dataset_reference(pair, pair.jig)
    clean = estimate_pair(left, right, pair.jig, part_diameter_mm=50.0, reference=reference)
    k = len(clean.matches.left_index) // 2
    u, v = clean.left.xy_px[clean.matches.left_index[k]]
    rows, cols = np.mgrid[0 : left.shape[0], 0 : left.shape[1]]
    glint = 255.0 * np.exp(-((cols - u - 6.0) ** 2 + (rows - v) ** 2) / (2 * 1.5**2))
    glinted = np.clip(left + glint, 0, 255).astype(np.uint8)
    result = estimate_pair(glinted, right, pair.jig, part_diameter_mm=50.0, reference=reference)
    assert any("they do not look like a marker" in w for w in result.estimate.warnings)
    left_out = np.flatnonzero(np.isnan(result.indentation.depth_mm))
    assert len(left_out) >= 1
    image = overlay.draw_overlay(glinted, right, result, pair.jig)
    width = left.shape[1]
    for j in left_out:
        for xy, x0 in (
            (result.left.xy_px[result.matches.left_index[j]], 0),
            (result.right.xy_px[result.matches.right_index[j]], width),
        ):
            x, y = round(float(xy[0])) + x0, round(float(xy[1]))
            assert np.abs(image[y, x].astype(int) - np.array(overlay.RED)).sum() < 60
