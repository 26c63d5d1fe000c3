"""The RealSense infrared pair through librealsense itself: a software device with two Y8 infrared
streams (a D4xx's stereo module as pyrealsense2 models it) runs RealSenseIRSource and the rig read-out."""

import time

import numpy as np
import pytest

from softjig.config import default_jig, load_jig, save_jig
from softjig.errors import InputError
from softjig.io.cameras import RealSenseIRSource, open_source, parse_source_spec
from softjig.io.realsense import IRIntrinsics, read_realsense_rig, rig_from_realsense

rs = pytest.importorskip("pyrealsense2")  # in the [test] extra: CI installs it

W, H, FPS = 848, 480, 90
INTR = dict(fx=421.5, fy=421.5, ppx=423.2, ppy=239.7)


def _software_d4xx(serial="0123456789"):
    dev = rs.software_device()
    dev.register_info(rs.camera_info.serial_number, serial)
    dev.register_info(rs.camera_info.name, "Intel RealSense D435 (software)")
    sensor = dev.add_sensor("Stereo Module")
    profiles = {}
    for index in (1, 2):
        v = rs.video_stream()
        v.type, v.index, v.uid = rs.stream.infrared, index, index
        v.width, v.height, v.fps, v.bpp, v.fmt = W, H, FPS, 1, rs.format.y8
        i = rs.intrinsics()
        i.width, i.height, i.fx, i.fy, i.ppx, i.ppy = W, H, INTR["fx"], INTR["fy"], INTR["ppx"], INTR["ppy"]
        i.model, i.coeffs = rs.distortion.brown_conrady, [0.0] * 5
        v.intrinsics = i
        profiles[index] = sensor.add_video_stream(v)
    e = rs.extrinsics()
    e.rotation = [1, 0, 0, 0, 1, 0, 0, 0, 1]
    e.translation = [-0.0501, 0.0, 0.0]  # infrared 2 is 50.1 mm to the right of infrared 1
    profiles[1].register_extrinsics_to(profiles[2], e)
    sensor.add_option(rs.option.emitter_enabled, rs.option_range(0, 1, 1, 1), True)
    sensor.add_option(rs.option.enable_auto_exposure, rs.option_range(0, 1, 1, 1), True)
    sensor.add_option(rs.option.exposure, rs.option_range(1, 165000, 1, 1), True)
    return dev, sensor, profiles


def _inject(sensor, profile, number, pixels, t_ms):
    f = rs.software_video_frame()
    f.pixels, f.bpp, f.stride = pixels, 1, W
    f.timestamp, f.domain, f.frame_number = t_ms, rs.timestamp_domain.hardware_clock, number
    f.profile = profile.as_video_stream_profile()
    sensor.on_video_frame(f)


def test_ir_source_streams_pairs_of_one_exposure():
    dev, sensor, profiles = _software_d4xx()
    src = RealSenseIRSource(width_px=W, height_px=H, fps=FPS, exposure_us=5000, device=dev)
    rng = np.random.default_rng(0)
    sent = []
    with src:
        assert sensor.get_option(rs.option.emitter_enabled) == 0  # off: its dots are not markers
        assert sensor.get_option(rs.option.exposure) == 5000
        got = []
        for n in range(5):
            left = rng.integers(0, 256, (H, W), dtype=np.uint8)
            right = rng.integers(0, 256, (H, W), dtype=np.uint8)
            sent.append((left, right))
            t = 1000.0 + n * 1000.0 / FPS
            if n == 2:  # infrared 2 before infrared 1: paired by frame number, not by order
                _inject(sensor, profiles[2], n, right, t)
                _inject(sensor, profiles[1], n, left, t)
            elif n == 3:  # infrared 2 of this exposure lost: no pair, the next still pairs
                _inject(sensor, profiles[1], n, left, t)
            else:
                _inject(sensor, profiles[1], n, left, t)
                _inject(sensor, profiles[2], n, right, t)
            frame = src.read(1.0)
            if n != 3:
                assert frame is not None
                got.append((n, frame))
            else:
                assert src.read(0.05) is None
        assert (src.incomplete, src.overwritten) == (1, 0)
        for n in range(5, 11):  # six pairs while nobody reads: the four newest are kept
            _inject(sensor, profiles[1], n, sent[0][0], 1000.0 + n * 1000.0 / FPS)
            _inject(sensor, profiles[2], n, sent[0][1], 1000.0 + n * 1000.0 / FPS)
        deadline = time.monotonic() + 2.0
        while src.overwritten < 2 and time.monotonic() < deadline:
            time.sleep(0.01)
        assert src.overwritten == 2
        assert [src.read(1.0).t_left_s for _ in range(4)] == pytest.approx(
            [(1000.0 + n * 1000.0 / FPS) / 1000.0 for n in range(7, 11)]
        )
    for k, (n, frame) in enumerate(got):
        assert frame.seq == k
        assert frame.left.shape == (H, W) and frame.left.dtype == np.uint8
        assert np.array_equal(frame.left, sent[n][0]) and np.array_equal(frame.right, sent[n][1])
        assert frame.skew_s == 0.0
        assert frame.t_left_s == pytest.approx((1000.0 + n * 1000.0 / FPS) / 1000.0)
    with pytest.raises(InputError, match="not open"):
        src.read(0.01)


def test_ir_source_refuses_a_mode_the_device_lacks_naming_what_it_has():
    dev, _, _ = _software_d4xx()
    src = RealSenseIRSource(width_px=1280, height_px=720, fps=30, device=dev)
    with pytest.raises(InputError, match=r"848x480@90"):
        src.open()


@pytest.mark.parametrize(
    ("w", "h", "fps", "match"),
    [(640, 480, 30, "848x480 or 1280x720"), (848, 480, 120, "fps"), (1280, 720, 90, "up to 30")],
)
def test_ir_modes_checked(w, h, fps, match):
    with pytest.raises(InputError, match=match):
        RealSenseIRSource(width_px=w, height_px=h, fps=fps)


def test_source_spec():
    assert parse_source_spec("realsense-ir").kind == "realsense-ir"
    spec = parse_source_spec("realsense-ir:0123456789")
    assert (spec.kind, spec.left) == ("realsense-ir", "0123456789")
    src = open_source(spec, width_px=848, height_px=480, fps=60)
    assert isinstance(src, RealSenseIRSource) and src.serial == "0123456789" and src.fps == 60
    with pytest.raises(InputError):
        parse_source_spec("realsense-ir:1,2")
    assert parse_source_spec("realsense:1,2").kind == "realsense"  # the two-device colour source stays


def test_rig_read_from_the_device_is_rectified_with_its_baseline(tmp_path):
    dev, _, _ = _software_d4xx()
    base = default_jig()
    jig = read_realsense_rig(base, dev, W, H)
    left, right = jig.cameras.left, jig.cameras.right
    assert jig.cameras.rectified
    assert (left.width_px, left.height_px) == (W, H)
    assert (left.fx_px, left.cx_px) == pytest.approx((INTR["fx"], INTR["ppx"]), abs=1e-4)  # float32
    assert jig.cameras.baseline_mm == pytest.approx(50.1)
    offset = np.linalg.inv(left.T_J_cam) @ right.T_J_cam
    np.testing.assert_allclose(offset[:3, 3], [50.1, 0, 0], atol=1e-9)
    assert left.position_mm == base.cameras.left.position_mm
    save_jig(jig, tmp_path / "rig.toml")
    assert load_jig(tmp_path / "rig.toml").cameras == jig.cameras


def test_rig_of_an_unrectified_pair_keeps_its_rotation_and_distortion():
    intr = IRIntrinsics(W, H, 420.0, 420.0, 424.0, 240.0, (0.01, 0, 0, 0, 0))
    c, s = np.cos(0.01), np.sin(0.01)
    R = np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
    jig = rig_from_realsense(default_jig(), intr, intr, R.flatten(order="F"), [-0.05, 0, 0])
    assert not jig.cameras.rectified
    assert jig.cameras.right.distortion[0] == 0.01
    T_1_2 = np.linalg.inv(jig.cameras.left.T_J_cam) @ jig.cameras.right.T_J_cam
    np.testing.assert_allclose(T_1_2[:3, :3], R.T, atol=1e-9)


def test_config_from_realsense_without_a_device_exits_2_naming_what_is_connected(tmp_path):
    from typer.testing import CliRunner

    from softjig.cli import app

    out = tmp_path / "rig.toml"
    res = CliRunner().invoke(app, ["config", "--from-realsense", "any", "--out", str(out)])
    assert res.exit_code == 2, res.output
    assert "no RealSense camera is connected" in res.output and not out.exists()
    res = CliRunner().invoke(app, ["config", "--from-realsense", "0123", "--out", str(out)])
    assert res.exit_code == 2 and "0123 not found" in res.output and not out.exists()


def test_colour_pair_source_kept_and_names_missing_cameras():
    from softjig.io.cameras import CameraError, RealSenseStereoSource

    with pytest.raises(CameraError, match=r"RealSense camera 1, 2 not found; connected: none"):
        RealSenseStereoSource("1", "2").open()
    with pytest.raises(CameraError, match="found 0 RealSense cameras"):
        RealSenseStereoSource().open()


def test_without_pyrealsense2_both_sources_say_how_to_install(monkeypatch):
    import sys

    from softjig.io.cameras import CameraError, RealSenseStereoSource

    monkeypatch.setitem(sys.modules, "pyrealsense2", None)  # as if not installed
    with pytest.raises(CameraError, match=r"softjig\[realsense\]"):
        RealSenseIRSource().open()
    with pytest.raises(CameraError, match=r"softjig\[realsense\]"):
        RealSenseStereoSource("1", "2").open()
    with pytest.raises(InputError, match="both"):  # two colour cameras: both serials or neither
        RealSenseStereoSource("1", None)


def test_live_on_realsense_ir_without_a_device_exits_2():
    from typer.testing import CliRunner

    from softjig.cli import app

    args = ["live", "--source", "realsense-ir:0123", "--method", "refractive", "--max-frames", "1"]
    res = CliRunner().invoke(app, args)
    assert res.exit_code == 2, res.output
    assert "RealSense camera 0123 not found" in res.output


def test_ir_source_options_out_of_range_are_named_and_open_is_idempotent():
    dev, sensor, _ = _software_d4xx()
    # pyrealsense2 2.59 reads option_range's arguments as (min, max, default, step) (observed)
    sensor.add_option(rs.option.gain, rs.option_range(16, 248, 16, 1), True)
    src = RealSenseIRSource(width_px=W, height_px=H, fps=FPS, auto_exposure=False, gain=64, device=dev)
    with src:
        src.open()  # a second open changes nothing
        assert sensor.get_option(rs.option.gain) == 64
        assert sensor.get_option(rs.option.enable_auto_exposure) == 0
    bad = RealSenseIRSource(width_px=W, height_px=H, fps=FPS, exposure_us=1e9, device=_software_d4xx()[0])
    with pytest.raises(InputError, match="cannot set"):
        bad.open()


def test_rig_of_a_mode_the_device_lacks_names_its_modes():
    dev, _, _ = _software_d4xx()
    with pytest.raises(InputError, match=r"848x480@90"):
        read_realsense_rig(default_jig(), dev, 1280, 720)
