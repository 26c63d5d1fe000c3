"""The Rerun sink of the live loop, read back from its .rrd file with rerun-sdk's own reader."""

import numpy as np
import pyarrow as pa
import pytest
from typer.testing import CliRunner

pytest.importorskip("rerun")  # in the [test] extra: CI installs it

from rerun.chunk import RrdReader

from softjig.cli import app
from softjig.config import default_jig
from softjig.errors import InputError
from softjig.io.cameras import ReplaySource
from softjig.io.dataset import Dataset
from softjig.io.simulated import simulate_dataset
from softjig.live.loop import LiveLoop, LiveSettings
from softjig.live.rerun_viewer import NORMAL_ARROW_MM, RERUN_PIXEL_OFFSET, RerunViewer
from softjig.sim.scenarios import paper_sweep


@pytest.fixture(scope="module")
def sweep(tmp_path_factory):
    """A reference frame and 2 loaded frames (D = 50 mm, alpha = 10 deg)."""
    out = tmp_path_factory.mktemp("rerun") / "sweep"
    specs = list(paper_sweep(diameters_mm=(50,), alphas_deg=(10,), theta_step_deg=180))
    simulate_dataset(out, specs, default_jig(), seed=4, workers=1, progress=False)
    return Dataset.open(out)


def _read(path):
    """``{entity: {column: [values per row, in frame order]}}`` of the recording's temporal rows (the
    images' formats, not their pixels)."""
    out: dict[str, dict[str, list]] = {}
    for chunk in RrdReader(path).stream():
        if chunk.is_static:
            continue
        rb = chunk.to_record_batch()
        # not capture_time (a timestamp) nor the images' pixels (megabytes as Python lists)
        keep = [f.name for f in rb.schema if not pa.types.is_timestamp(f.type) and ":buffer" not in f.name]
        batch = rb.select(keep).to_pydict()
        order = np.argsort(batch["frame"]) if "frame" in batch else None
        cols = out.setdefault(chunk.entity_path, {})
        for name, values in batch.items():
            vals = [values[k] for k in order] if order is not None else values
            cols.setdefault(name, []).extend(vals)
    return out


def _last_image(path, entity):
    """The pixels of the entity's image at its last frame (H, W) uint8."""
    best = None
    for chunk in RrdReader(path).stream():
        if chunk.entity_path == entity and not chunk.is_static:
            rb = chunk.to_record_batch()
            k = int(np.argmax(rb.column("frame").to_numpy()))
            frame = rb.column("frame")[k].as_py()
            if best is None or frame > best[0]:
                fmt = rb.column("Image:format")[k].as_py()[0]
                pixels = rb.column("Image:buffer")[k].values[0].values.to_numpy(zero_copy_only=False)
                best = frame, pixels.reshape(fmt["height"], fmt["width"])
    assert best is not None, f"no {entity} in {path}"
    return best[1]


def test_the_rrd_holds_images_markers_contact_normal_over_time(sweep, tmp_path):
    path = tmp_path / "run.rrd"
    viewer = RerunViewer(save_path=path)
    outcomes = []
    loop = LiveLoop(
        ReplaySource(sweep.root, rate="fast"),
        LiveSettings(jig=sweep.jig, method="refractive"),
        sinks=[viewer],
        on_outcome=lambda o, m: outcomes.append(o),
    )
    loop.run()
    ok = [o for o in outcomes if o.result is not None]
    assert len(outcomes) == len(sweep) and ok
    data = _read(path)
    frames = [o.frame.seq for o in outcomes]
    # images: one per side and frame, on the frame timeline
    for side in ("left", "right"):
        assert data[f"/cameras/{side}/image"]["frame"] == frames
    np.testing.assert_array_equal(_last_image(path, "/cameras/right/image"), outcomes[-1].frame.right)
    # markers in Rerun's pixel convention: softjig's (u, v) + 0.5
    last = ok[-1].result
    markers = data["/cameras/left/markers"]["Points2D:positions"][-1]
    np.testing.assert_allclose(markers, last.left.xy_px + RERUN_PIXEL_OFFSET, rtol=0, atol=1e-4)
    fitted = data["/cameras/left/fitted"]["Points2D:positions"][-1]
    assert len(fitted) == int(last.used.sum())
    points = np.asarray(data["/jig/markers"]["Points3D:positions"][-1])
    np.testing.assert_allclose(points, last.points_J, atol=1e-3)
    # the normal: the estimate's, 40 mm long, from the contact centroid on the plane
    vec = np.asarray(data["/jig/normal"]["Arrows3D:vectors"][-1][0])
    np.testing.assert_allclose(vec / NORMAL_ARROW_MM, last.estimate.normal, atol=1e-6)
    origin = np.asarray(data["/jig/normal"]["Arrows3D:origins"][-1][0])
    cx, cy = last.contact.centroid_xy_mm
    np.testing.assert_allclose(origin, [cx, cy, last.plane.z_at(cx, cy)], atol=1e-3)
    # the contact outline: closed, on the fitted plane, its x y the footprint's
    strip = np.asarray(data["/jig/contact"]["LineStrips3D:strips"][-1][0])
    np.testing.assert_allclose(strip[0], strip[-1])
    np.testing.assert_allclose(strip[:-1, :2], last.contact.outline_xy_mm, atol=1e-3)
    np.testing.assert_allclose(strip[:, 2], last.plane.heights_mm(strip[:, 0], strip[:, 1]), atol=1e-3)
    # scalars over time, one per estimated frame
    tilts = [v[0] for v in data["/estimate/tilt_x_deg"]["Scalars:scalars"]]
    np.testing.assert_allclose(tilts, [o.result.estimate.tilt_x_deg for o in ok], atol=1e-4)


def test_cli_live_rerun_save(sweep, tmp_path):
    path = tmp_path / "cli.rrd"
    args = ["live", "--replay", str(sweep.root), "--rate", "fast", "--method", "refractive"]
    res = CliRunner().invoke(app, [*args, "--rerun-save", str(path), "--max-frames", "2"])
    assert res.exit_code == 0, res.output
    assert len(_read(path)["/cameras/left/image"]["frame"]) == 2
    res = CliRunner().invoke(app, [*args, "--rerun-save", str(path), "--max-frames", "1"])
    assert res.exit_code == 2 and "exists" in res.output  # nothing recorded is replaced unasked


def test_bad_targets_are_refused(tmp_path):
    with pytest.raises(InputError, match=r"\.rrd"):
        RerunViewer(save_path=tmp_path / "run.mcap")
    with pytest.raises(InputError, match="needs a viewer"):
        RerunViewer()
    folder = tmp_path / "dir.rrd"
    folder.mkdir()
    with pytest.raises(InputError, match="folder"):
        RerunViewer(save_path=folder, overwrite=True)


def test_without_a_contact_the_outline_is_cleared(sweep, tmp_path):
    """The paper's method finds no contact footprint: the outline is cleared, the normal still drawn."""
    path = tmp_path / "paper.rrd"
    outcomes = []
    LiveLoop(
        ReplaySource(sweep.root, rate="fast"),
        LiveSettings(jig=sweep.jig, method="paper"),
        sinks=[RerunViewer(save_path=path, images=False)],
        on_outcome=lambda o, m: outcomes.append(o),
    ).run()
    ok = [o for o in outcomes if o.result is not None]
    assert ok and all(o.result.contact is None for o in ok)
    data = _read(path)
    assert "/cameras/left/image" not in data
    assert len(data["/jig/contact"]["frame"]) == len(ok)
    assert all(not v for v in data["/jig/contact"].get("LineStrips3D:strips", [None]))
    assert len(data["/jig/normal"]["frame"]) == len(ok)


def test_without_the_sdk_says_how_to_install(monkeypatch, tmp_path):
    import sys

    monkeypatch.setitem(sys.modules, "rerun", None)
    with pytest.raises(InputError, match=r"softjig\[rerun\]"):
        RerunViewer(save_path=tmp_path / "x.rrd")
