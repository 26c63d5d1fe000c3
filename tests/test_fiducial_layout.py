"""The printable fiducial sheet (exact scale, the cameras' view) and the stereo check of the fiducials."""

import re

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from softjig.calibration.fiducial_layout import check_fiducials, fiducial_sheet, with_fiducials
from softjig.cli import app
from softjig.config import default_jig, load_jig
from softjig.errors import ConfigError
from softjig.sensing.fiducials import detect_fiducials

JIG = default_jig()


@pytest.fixture(scope="module")
def pair(unloaded_scene):
    return unloaded_scene.pair


def test_png_sheet_puts_each_marker_at_its_place_and_size():
    dpi = 150
    png = fiducial_sheet(JIG, fmt="png", dpi=dpi)
    img = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_GRAYSCALE)
    px_per_mm = dpi / 25.4
    margin = 12.0
    assert img.shape[1] == pytest.approx((JIG.plate.size_x_mm + 2 * margin) * px_per_mm, abs=1)
    found = detect_fiducials(img, JIG.fiducials)
    assert sorted(found) == list(JIG.fiducials.ids)
    origin = np.array([img.shape[1], img.shape[0]]) / 2.0
    for marker_id, (cx, cy) in zip(JIG.fiducials.ids, JIG.fiducials.centers_mm, strict=True):
        corners_mm = (found[marker_id] + 0.5 - origin) / px_per_mm  # pixel centres -> edges
        np.testing.assert_allclose(corners_mm.mean(axis=0), [cx, cy], atol=0.2)
        side = np.linalg.norm(np.diff(corners_mm, axis=0, append=corners_mm[:1]), axis=1)
        np.testing.assert_allclose(side, JIG.fiducials.size_mm, atol=0.3)
        # ArUco's first corner is the marker's top-left as the cameras see it: smallest x and y in J
        assert np.all(corners_mm[0] <= corners_mm.mean(axis=0))


def test_pdf_sheet_has_the_exact_page_size():
    pdf = fiducial_sheet(JIG, fmt="pdf")
    assert pdf.startswith(b"%PDF")
    box = [float(v) for v in re.search(rb"/MediaBox\s*\[([^\]]+)\]", pdf).group(1).split()]
    points_per_mm = 72 / 25.4
    assert box[2] - box[0] == pytest.approx((JIG.plate.size_x_mm + 24) * points_per_mm, abs=0.01)
    assert box[3] - box[1] == pytest.approx((JIG.plate.size_y_mm + 24) * points_per_mm, abs=0.01)


def test_check_passes_on_a_rendered_pair(pair):
    result = check_fiducials(pair.left, pair.right, JIG)
    assert result.ok, result.problems
    assert result.found_left == result.found_right == (0, 1, 2, 3)
    assert result.reprojection_rms_px < 1.0


def test_check_flags_a_misplaced_fiducial(pair):
    moved = with_fiducials(JIG, centers_mm=((-72.0, -38.0), (72.0, -38.0), (72.0, 38.0), (-69.0, 38.0)))
    result = check_fiducials(pair.left, pair.right, moved)
    assert not result.ok
    assert max(result.per_fiducial_rms_px.values()) > 1.0


def test_check_reports_missing_ids(pair):
    other = with_fiducials(JIG, ids=(0, 1, 2, 7))
    result = check_fiducials(pair.left, pair.right, other)
    assert result.missing == (7,) and not result.ok


def test_invalid_layout_is_a_config_error():
    with pytest.raises(ConfigError, match=r"fiducials\.ids"):
        with_fiducials(JIG, ids=(0, 1, 2))


def test_cli_sheet_and_check(tmp_path, pair):
    runner = CliRunner()
    res = runner.invoke(
        app,
        [
            "fiducials",
            "sheet",
            "--out",
            str(tmp_path / "f.png"),
            "--dpi",
            "100",
            "--size-mm",
            "16",
            "--config-out",
            str(tmp_path / "rig.toml"),
        ],
    )
    assert res.exit_code == 0, res.output
    assert (tmp_path / "f.png").exists() and load_jig(tmp_path / "rig.toml").fiducials.size_mm == 16
    cv2.imwrite(str(tmp_path / "l.png"), pair.left)
    cv2.imwrite(str(tmp_path / "r.png"), pair.right)
    res = runner.invoke(app, ["fiducials", "check", str(tmp_path / "l.png"), str(tmp_path / "r.png")])
    assert res.exit_code == 0, res.output
    res = runner.invoke(
        app,
        [
            "fiducials",
            "check",
            str(tmp_path / "l.png"),
            str(tmp_path / "r.png"),
            "--config",
            str(tmp_path / "rig.toml"),
        ],
    )
    assert res.exit_code == 3  # the 16 mm config does not match the 14 mm fiducials in the images
