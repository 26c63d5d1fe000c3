"""The dataset reader and writer: round trips, crash safety, laziness and every bad input."""

from __future__ import annotations

import gc
import json
import pickle
import tracemalloc
from pathlib import Path

import cv2
import numpy as np
import pytest

from softjig.config import CylinderPart, default_jig, exact_jig, part_to_dict
from softjig.errors import ConfigError, InputError
from softjig.io import dataset as ds_mod
from softjig.io.dataset import (
    Dataset,
    DatasetLineWarning,
    DatasetTruncationWarning,
    DatasetWriter,
    Frame,
    encode_png,
    load_image,
)
from softjig.sim.asbuilt import draw_as_built

H, W = 48, 64


def _images(rng: np.random.Generator, dtype=np.uint8, color: bool = False) -> tuple[np.ndarray, np.ndarray]:
    shape = (H, W, 3) if color else (H, W)
    hi = np.iinfo(dtype).max
    return (
        rng.integers(0, hi, shape, endpoint=True).astype(dtype),
        rng.integers(0, hi, shape, endpoint=True).astype(dtype),
    )


def _truth(rng: np.random.Generator, n: int = 7) -> dict[str, np.ndarray]:
    return {
        "xyz_mm": rng.normal(size=(n, 3)),
        "axis": rng.normal(size=(n, 3)),
        "in_contact": rng.random(n) > 0.5,
        "left_px": rng.normal(size=(n, 2)),
        "right_px": rng.normal(size=(n, 2)),
        "visible_left": rng.random(n) > 0.2,
        "visible_right": rng.random(n) > 0.2,
    }


def _meta(i: int) -> dict:
    part = CylinderPart(diameter_mm=40.0 + i)
    return {
        "time_s": 0.1 * i,
        "alpha_deg": 10.0,
        "theta_deg": 30.0 * i,
        "part": part_to_dict(part),
        "truth": {
            "normal": [0.1, 0.0, float(np.sqrt(0.99))],
            "push_depth_mm": 3.0,
            "T_J_part": np.eye(4).tolist(),
        },
        "custom": {"note": f"frame {i}"},
    }


@pytest.fixture
def jig():
    return default_jig()


def _write(path: Path, jig, n: int = 3, *, dtype=np.uint8, color=False, truth=True, seed=0):
    rng = np.random.default_rng(seed)
    written = []
    with DatasetWriter(path, jig, as_built=draw_as_built(jig, 1)) as writer:
        ref_l, ref_r = _images(rng, dtype, color)
        writer.add_frame(ref_l, ref_r, {"reference": True}, truth_markers=_truth(rng) if truth else None)
        written.append((ref_l, ref_r, {"reference": True}))
        for i in range(1, n):
            left, right = _images(rng, dtype, color)
            meta = _meta(i)
            idx = writer.add_frame(left, right, meta, truth_markers=_truth(rng) if truth else None)
            assert idx == i
            written.append((left, right, meta))
    return written


# ------------------------------------------------------------------------------------- round trip


@pytest.mark.parametrize(
    ("dtype", "color"), [(np.uint8, False), (np.uint16, False), (np.uint8, True), (np.uint16, True)]
)
def test_round_trip_is_bit_exact(tmp_path, jig, dtype, color):
    written = _write(tmp_path / "ds", jig, 3, dtype=dtype, color=color)
    ds = Dataset.open(tmp_path / "ds")
    assert len(ds) == 3
    assert ds.jig == jig
    for frame, (left, right, meta) in zip(ds, written, strict=True):
        got_l, got_r = frame.load_left(), frame.load_right()
        assert got_l.dtype == dtype and got_l.shape == left.shape
        np.testing.assert_array_equal(got_l, left)
        np.testing.assert_array_equal(got_r, right)
        expected = {
            "index": frame.index,
            "left": f"left/{frame.index:06d}.png",
            "right": f"right/{frame.index:06d}.png",
            **json.loads(json.dumps(meta)),
        }
        expected.setdefault("truth", {})["markers"] = f"truth/{frame.index:06d}.npz"
        assert frame.meta == expected


def test_frame_fields_and_truth(tmp_path, jig):
    rng_ref = np.random.default_rng(0)
    _write(tmp_path / "ds", jig, 3)
    ds = Dataset.open(tmp_path / "ds")
    ref, f1 = ds[0], ds[1]
    assert ref.reference and ref.alpha_deg is None and ref.part is None
    assert not f1.reference
    assert f1.alpha_deg == 10.0 and f1.theta_deg == 30.0 and f1.time_s == pytest.approx(0.1)
    assert f1.part == CylinderPart(diameter_mm=41.0)
    assert f1.truth is not None and f1.truth.push_depth_mm == 3.0
    np.testing.assert_allclose(f1.truth.T_J_part, np.eye(4))
    assert f1.truth.normal.shape == (3,)
    # the truth npz holds exactly what was written (same rng sequence as _write)
    _images(rng_ref)
    truth0 = _truth(rng_ref)
    got = ref.load_truth_markers()
    assert set(got) == set(truth0)
    for k, v in truth0.items():
        np.testing.assert_array_equal(got[k], v)
    assert [f.index for f in ds] == [0, 1, 2]
    assert ds[-1].index == 2


def test_as_built_stored_for_analysis(tmp_path, jig):
    _write(tmp_path / "ds", jig, 1)
    ds = Dataset.open(tmp_path / "ds")
    assert ds.has_as_built
    as_built = ds.as_built()
    expected = draw_as_built(jig, 1)
    assert as_built.jig == expected.jig
    np.testing.assert_array_equal(as_built.marker_xy_mm, expected.marker_xy_mm)
    assert ds.jig == jig  # the nominal jig is what the dataset's jig is


def test_recording_without_truth_or_as_built(tmp_path, jig):
    rng = np.random.default_rng(0)
    with DatasetWriter(tmp_path / "rec", jig) as writer:
        writer.add_frame(*_images(rng), {"time_s": 0.0})
    ds = Dataset.open(tmp_path / "rec")
    assert not ds.has_as_built
    assert ds[0].truth is None
    with pytest.raises(InputError, match=r"as_built\.toml"):
        ds.as_built()
    with pytest.raises(InputError, match="no truth markers"):
        ds[0].load_truth_markers()


def test_writer_accepts_png_bytes(tmp_path, jig):
    rng = np.random.default_rng(3)
    left, right = _images(rng, np.uint16)
    with DatasetWriter(tmp_path / "ds", jig) as writer:
        writer.add_frame(encode_png(left), encode_png(right), {})
    frame = Dataset.open(tmp_path / "ds")[0]
    np.testing.assert_array_equal(frame.load_left(), left)
    np.testing.assert_array_equal(frame.load_right(), right)


def test_empty_dataset_is_valid(tmp_path, jig):
    with DatasetWriter(tmp_path / "ds", jig):
        pass
    assert len(Dataset.open(tmp_path / "ds")) == 0


# ---------------------------------------------------------------------------------------- laziness


def test_open_reads_no_image(tmp_path, jig, monkeypatch):
    _write(tmp_path / "ds", jig, 5)
    calls = []
    monkeypatch.setattr(ds_mod.cv2, "imdecode", lambda *a, **k: calls.append(a) or None)
    monkeypatch.setattr(ds_mod.np, "fromfile", lambda *a, **k: calls.append(a) or None)
    ds = Dataset.open(tmp_path / "ds")
    frames = list(ds)
    assert len(frames) == 5 and ds[3].index == 3
    assert calls == []


def _long_frames_file(root: Path, jig, n: int) -> None:
    """A dataset of ``n`` frames (two parts, truth poses, blank lines here and there) whose images do not
    exist: opening and reading frames never touches them."""
    _write(root, jig, 1)
    parts = [part_to_dict(CylinderPart(50.0)), part_to_dict(CylinderPart(30.0))]
    with open(root / "frames.jsonl", "a") as fh:
        for i in range(1, n):
            record = {"index": i, "left": f"left/{i:06d}.png", "right": f"right/{i:06d}.png",
                      "alpha_deg": 10.0, "theta_deg": float(i % 360), "part": parts[i % 2],
                      "truth": {"normal": [0.0, 0.0, 1.0], "T_J_part": np.eye(4).tolist()}}  # fmt: skip
            fh.write(json.dumps(record) + ("\n\n" if i % 1000 == 0 else "\n"))


def test_open_holds_line_offsets_not_frames(tmp_path, jig):
    n = 5000
    _long_frames_file(tmp_path / "ds", jig, n)
    Dataset.open(tmp_path / "ds")  # the first open imports what parsing needs: not held per frame
    gc.collect()
    tracemalloc.start()
    try:
        ds = Dataset.open(tmp_path / "ds")
        # What the open allocated and still holds, wherever it was called from (not what other threads
        # of earlier tests allocate meanwhile, nor imports).
        held = sum(
            stat.size
            for stat in tracemalloc.take_snapshot().statistics("filename")
            if "softjig" in stat.traceback[0].filename
        )
    finally:
        tracemalloc.stop()
    assert len(ds) == n
    # 16 bytes a frame (its line's offset and number); a parsed frame with its meta is over 2 KB.
    assert held < 32 * n + 64 * 1024, f"{held / n:.0f} bytes held per frame"
    alive = [o for o in gc.get_objects() if isinstance(o, Frame) and o.root == ds.root]
    assert alive == []  # no frame of it exists after open


def test_frames_are_parsed_when_asked(tmp_path, jig, monkeypatch):
    _long_frames_file(tmp_path / "ds", jig, 3000)
    ds = Dataset.open(tmp_path / "ds")
    parsed = []
    real = ds_mod._frame_from_json
    monkeypatch.setattr(ds_mod, "_frame_from_json", lambda *a: parsed.append(a[1]["index"]) or real(*a))
    assert len(ds) == 3000 and parsed == []
    assert ds[2500].index == 2500 and ds[-1].index == 2999 and parsed == [2500, 2999]
    assert ds[-1] is ds[2999] and parsed == [2500, 2999]  # the last frame asked for is kept
    assert [f.index for f in ds.iter_frames(998, 1003)] == [998, 999, 1000, 1001, 1002]  # a blank line
    assert [f.index for f in ds[1999:2002]] == [1999, 2000, 2001]
    assert [f.index for f in ds[10:16:5]] == [10, 15]
    assert len(parsed) == 2 + 5 + 3 + 2
    assert [f.index for f in ds] == list(range(3000))
    with pytest.raises(IndexError, match="out of range"):
        ds[3000]
    assert ds[1].part is ds[3].part and ds[1].part != ds[2].part  # one Part per distinct part
    np.testing.assert_array_equal(ds[7].truth.T_J_part, np.eye(4))


def test_a_dataset_pickles_small_for_spawned_workers(tmp_path, jig):
    _long_frames_file(tmp_path / "ds", jig, 2000)
    ds = Dataset.open(tmp_path / "ds")
    data = pickle.dumps(ds)
    assert len(data) < 16 * 2000 + 32 * 1024
    back = pickle.loads(data)
    assert len(back) == 2000 and back[1234] == ds[1234] and back.jig == ds.jig


def test_frames_appended_after_open_are_not_seen_and_a_rewrite_is_caught(tmp_path, jig):
    _write(tmp_path / "ds", jig, 3)
    ds = Dataset.open(tmp_path / "ds")
    path = tmp_path / "ds" / "frames.jsonl"
    with open(path, "a") as fh:  # a recorder still running
        fh.write(json.dumps({"index": 3, "left": "left/000003.png", "right": "right/000003.png"}) + "\n")
    assert len(ds) == 3 and [f.index for f in ds] == [0, 1, 2]
    path.write_text(path.read_text().splitlines()[2] + "\n")  # rewritten: frame 2's line only
    with pytest.raises(InputError, match="changed since the dataset was opened"):
        list(ds)
    with pytest.raises(InputError, match="changed since the dataset was opened"):
        ds[1]


# ----------------------------------------------------------------------------------- crash safety


@pytest.mark.parametrize("newline", [False, True])
def test_killed_writer_leaves_complete_frames(tmp_path, jig, newline):
    written = _write(tmp_path / "ds", jig, 4)
    line = json.dumps({"index": 4, "left": "left/000004.png", "right": "right/000004.png", "alpha_deg": 10.0})
    with open(tmp_path / "ds" / "frames.jsonl", "a") as fh:
        fh.write(line[: len(line) // 2] + ("\n" if newline else ""))
    with pytest.warns(DatasetTruncationWarning, match="line 5"):
        ds = Dataset.open(tmp_path / "ds")
    assert len(ds) == 4
    assert ds.warnings and "line 5" in ds.warnings[0]
    for frame, (left, _, _) in zip(ds, written, strict=True):
        np.testing.assert_array_equal(frame.load_left(), left)


def test_writer_leaves_no_temporary_files(tmp_path, jig):
    _write(tmp_path / "ds", jig, 2)
    assert not [p for p in (tmp_path / "ds").rglob("*") if p.name.startswith(".")]


# ------------------------------------------------------------------------------------- bad inputs


def test_missing_folder(tmp_path):
    with pytest.raises(InputError, match="does not exist"):
        Dataset.open(tmp_path / "nope")


def test_not_a_folder(tmp_path):
    (tmp_path / "file").write_text("x")
    with pytest.raises(InputError, match="not a folder"):
        Dataset.open(tmp_path / "file")


def test_missing_rig(tmp_path, jig):
    _write(tmp_path / "ds", jig, 1)
    (tmp_path / "ds" / "rig.toml").unlink()
    with pytest.raises(InputError, match=r"rig\.toml does not exist"):
        Dataset.open(tmp_path / "ds")


def test_invalid_rig_names_file_and_field(tmp_path, jig):
    _write(tmp_path / "ds", jig, 1)
    rig = tmp_path / "ds" / "rig.toml"
    rig.write_text(rig.read_text().replace("pitch_mm = 8.0", "pitch_mm = -8.0"))
    with pytest.raises(ConfigError, match=r"rig\.toml.*markers\.pitch_mm"):
        Dataset.open(tmp_path / "ds")


def test_missing_frames_file(tmp_path, jig):
    _write(tmp_path / "ds", jig, 1)
    (tmp_path / "ds" / "frames.jsonl").unlink()
    with pytest.raises(InputError, match=r"frames\.jsonl does not exist"):
        Dataset.open(tmp_path / "ds")


@pytest.mark.parametrize("garbage", ["cut", "ascii", "binary"])
def test_a_garbage_line_in_the_middle_is_skipped_with_a_warning(tmp_path, jig, garbage):
    written = _write(tmp_path / "ds", jig, 4)
    path = tmp_path / "ds" / "frames.jsonl"
    lines = path.read_bytes().splitlines()
    lines[1] = {"cut": lines[1][:20], "ascii": b"hello world", "binary": b"\xff\xfe\x00garbage"}[garbage]
    path.write_bytes(b"\n".join(lines) + b"\n")
    with pytest.warns(DatasetLineWarning, match=r"frames\.jsonl, line 2: not valid JSON") as caught:
        ds = Dataset.open(tmp_path / "ds")
    assert not any(isinstance(w.message, DatasetTruncationWarning) for w in caught)
    assert [frame.index for frame in ds] == [0, 2, 3]
    assert len(ds.warnings) == 1 and "line 2" in ds.warnings[0]
    np.testing.assert_array_equal(ds[1].load_left(), written[2][0])


def test_several_garbage_lines_are_counted_in_one_warning(tmp_path, jig):
    _write(tmp_path / "ds", jig, 2)
    path = tmp_path / "ds" / "frames.jsonl"
    path.write_text("junk\n" + path.read_text() + "more junk\n{\n" + path.read_text().splitlines()[0][:5])
    with pytest.warns(DatasetLineWarning) as caught:
        ds = Dataset.open(tmp_path / "ds")
    assert len(ds) == 2
    notes = [str(w.message) for w in caught]
    assert any("line 1 and 2 more lines" in note for note in notes)
    assert any("last line is cut short" in note and "line 6" in note for note in notes)


def test_a_duplicate_frame_index_is_refused_naming_both_lines(tmp_path, jig):
    _write(tmp_path / "ds", jig, 3)
    path = tmp_path / "ds" / "frames.jsonl"
    lines = path.read_text().splitlines()
    lines[2] = lines[2].replace('"index":2', '"index":1')
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(InputError, match=r"line 3: frame index 1 was already used on line 2"):
        Dataset.open(tmp_path / "ds")


@pytest.mark.parametrize(
    ("key", "value"),
    [
        ("left", "../../etc/passwd"),
        ("right", "/etc/passwd"),
        ("left", "left/../../outside.png"),
        ("right", "C:\\Windows\\x.png"),
        ("left", "..\\..\\x.png"),
    ],
)
def test_paths_leaving_the_dataset_are_refused_naming_the_line(tmp_path, jig, key, value):
    _write(tmp_path / "ds", jig, 1)
    line = {"index": 1, "left": "left/000000.png", "right": "right/000000.png", key: value}
    with open(tmp_path / "ds" / "frames.jsonl", "a") as fh:
        fh.write(json.dumps(line) + "\n")
    with pytest.raises(InputError, match=f"line 2: {key} .* is outside the dataset folder"):
        Dataset.open(tmp_path / "ds")


def test_truth_markers_leaving_the_dataset_are_refused(tmp_path, jig):
    _write(tmp_path / "ds", jig, 1)
    line = {"index": 1, "left": "left/000000.png", "right": "right/000000.png",
            "truth": {"markers": "../secret.npz"}}  # fmt: skip
    with open(tmp_path / "ds" / "frames.jsonl", "a") as fh:
        fh.write(json.dumps(line) + "\n")
    with pytest.raises(InputError, match=r"line 2: truth\.markers .* is outside the dataset folder"):
        Dataset.open(tmp_path / "ds")


def test_a_symbolic_link_leading_out_of_the_dataset_is_not_followed(tmp_path, jig):
    written = _write(tmp_path / "ds", jig, 2)
    secret = tmp_path / "secret.png"
    secret.write_bytes(encode_png(written[0][0]))
    (tmp_path / "ds" / "left" / "000001.png").unlink()
    (tmp_path / "ds" / "left" / "000001.png").symlink_to(secret)
    ds = Dataset.open(tmp_path / "ds")
    with pytest.raises(InputError, match=r"frame 1: left image 'left/000001\.png' is outside the dataset"):
        ds[1].load_left()
    np.testing.assert_array_equal(ds[1].load_right(), written[1][1])


@pytest.mark.parametrize(
    ("line", "match"),
    [
        ("[1, 2]", "expected a JSON object"),
        ('{"index": 0, "left": "left/000000.png"}', "lacks right"),
        ('{"index": -1, "left": "a.png", "right": "b.png"}', "index must be"),
        ('{"index": 0, "left": 3, "right": "b.png"}', "left must be"),
        ('{"index": 0, "left": "a", "right": "b", "alpha_deg": "ten"}', "alpha_deg must be"),
        ('{"index": 0, "left": "a", "right": "b", "part": {"kind": "sphere"}}', "part.kind"),
        ('{"index": 0, "left": "a", "right": "b", "truth": {"normal": [0, 1]}}', "truth.normal"),
    ],
)
def test_invalid_frame_objects(tmp_path, jig, line, match):
    _write(tmp_path / "ds", jig, 1)
    with open(tmp_path / "ds" / "frames.jsonl", "a") as fh:
        fh.write(line + "\n")
    with pytest.raises(InputError, match=match) as info:
        Dataset.open(tmp_path / "ds")
    assert "line 2" in str(info.value)


def test_missing_and_unreadable_images(tmp_path, jig):
    _write(tmp_path / "ds", jig, 2)
    ds = Dataset.open(tmp_path / "ds")
    (tmp_path / "ds" / "left" / "000000.png").unlink()
    with pytest.raises(InputError, match=r"000000\.png does not exist"):
        ds[0].load_left()
    (tmp_path / "ds" / "right" / "000001.png").write_bytes(b"\x89PNG\r\n\x1a\n garbage")
    with pytest.raises(InputError, match=r"cannot decode image .*000001\.png"):
        ds[1].load_right()
    (tmp_path / "ds" / "truth" / "000001.npz").unlink()
    with pytest.raises(InputError, match="re-simulate"):
        ds[1].load_truth_markers()


def test_load_image_errors(tmp_path):
    with pytest.raises(InputError, match="does not exist"):
        load_image(tmp_path / "none.png")
    with pytest.raises(InputError, match="not a file"):
        load_image(tmp_path)
    (tmp_path / "empty.png").write_bytes(b"")
    with pytest.raises(InputError, match="cannot decode"):
        load_image(tmp_path / "empty.png")


def test_load_image_color_is_rgb(tmp_path):
    bgr = np.zeros((4, 5, 3), np.uint8)
    bgr[..., 0] = 200  # blue in OpenCV's order
    cv2.imwrite(str(tmp_path / "blue.png"), bgr)
    rgb = load_image(tmp_path / "blue.png")
    assert rgb.shape == (4, 5, 3) and rgb[0, 0, 2] == 200 and rgb[0, 0, 0] == 0


# ----------------------------------------------------------------------------------- overwriting


def test_refuses_to_overwrite_a_dataset(tmp_path, jig):
    _write(tmp_path / "ds", jig, 2)
    with pytest.raises(InputError, match="already holds a dataset"), DatasetWriter(tmp_path / "ds", jig):
        pass
    assert len(Dataset.open(tmp_path / "ds")) == 2
    _write(tmp_path / "other", jig, 1)
    with DatasetWriter(tmp_path / "ds", exact_jig(jig), overwrite=True) as writer:
        writer.add_frame(*_images(np.random.default_rng(0)), {})
    ds = Dataset.open(tmp_path / "ds")
    assert len(ds) == 1 and not ds.has_as_built and ds.jig == exact_jig(jig)
    assert not (tmp_path / "ds" / "left" / "000001.png").exists()


def test_refuses_a_non_dataset_folder_even_with_overwrite(tmp_path, jig):
    (tmp_path / "stuff").mkdir()
    (tmp_path / "stuff" / "thesis.tex").write_text("precious")
    with (
        pytest.raises(InputError, match="not a softjig dataset"),
        DatasetWriter(tmp_path / "stuff", jig, overwrite=True),
    ):
        pass
    assert (tmp_path / "stuff" / "thesis.tex").read_text() == "precious"
    (tmp_path / "afile").write_text("x")
    with pytest.raises(InputError, match="not a folder"), DatasetWriter(tmp_path / "afile", jig):
        pass


def test_overwrite_refuses_a_folder_of_calibration_photos(tmp_path, jig):
    photos = tmp_path / "calib"
    for side in ("left", "right"):
        (photos / side).mkdir(parents=True)
        (photos / side / "board-01.png").write_bytes(encode_png(np.zeros((4, 4), np.uint8)))
    (photos / "rig.toml").write_text("# calibrated by hand\n")
    before = {p: p.read_bytes() for p in photos.rglob("*") if p.is_file()}
    with (
        pytest.raises(InputError, match="not a softjig dataset"),
        DatasetWriter(photos, jig, overwrite=True),
    ):
        pass
    assert {p: p.read_bytes() for p in photos.rglob("*") if p.is_file()} == before


@pytest.mark.parametrize("foreign", ["notes.txt", "left/board-01.png", "truth/x.npz", "photos/a.png"])
def test_overwrite_refuses_a_dataset_holding_files_softjig_did_not_write(tmp_path, jig, foreign):
    _write(tmp_path / "ds", jig, 2)
    (tmp_path / "ds" / foreign).parent.mkdir(exist_ok=True)
    (tmp_path / "ds" / foreign).write_text("precious")
    with (
        pytest.raises(InputError, match=f"holds files softjig did not write \\({foreign.split('/')[0]}"),
        DatasetWriter(tmp_path / "ds", jig, overwrite=True),
    ):
        pass
    assert (tmp_path / "ds" / foreign).read_text() == "precious" and len(Dataset.open(tmp_path / "ds")) == 2


def test_overwrite_is_atomic_the_old_dataset_stays_until_the_new_one_is_complete(tmp_path, jig):
    old = _write(tmp_path / "ds", jig, 3)
    (tmp_path / "ds" / "estimates.jsonl").write_text("{}\n")  # softjig's own results: replaced too
    rng = np.random.default_rng(9)
    writer = DatasetWriter(tmp_path / "ds", exact_jig(jig), overwrite=True).open()
    new = _images(rng)
    writer.add_frame(*new, {})
    during = Dataset.open(tmp_path / "ds")  # a reader, or a kill now, sees the old dataset whole
    assert len(during) == 3 and during.jig == jig
    np.testing.assert_array_equal(during[2].load_left(), old[2][0])
    staged = Dataset.open(tmp_path / "ds.softjig-new")  # and the new frames so far
    assert len(staged) == 1
    writer.close()
    ds = Dataset.open(tmp_path / "ds")
    assert len(ds) == 1 and ds.jig == exact_jig(jig) and not ds.has_as_built
    np.testing.assert_array_equal(ds[0].load_left(), new[0])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ds"]
    assert not (tmp_path / "ds" / "estimates.jsonl").exists()


def test_a_killed_overwrite_leaves_both_and_the_next_one_is_refused_until_looked_at(tmp_path, jig):
    _write(tmp_path / "ds", jig, 3)
    writer = DatasetWriter(tmp_path / "ds", jig, overwrite=True).open()
    writer.add_frame(*_images(np.random.default_rng(1)), {})
    writer._frames_fh.close()  # killed: never closed
    assert len(Dataset.open(tmp_path / "ds")) == 3 and len(Dataset.open(tmp_path / "ds.softjig-new")) == 1
    with (
        pytest.raises(InputError, match=r"ds\.softjig-new exists: an earlier overwrite .* did not finish"),
        DatasetWriter(tmp_path / "ds", jig, overwrite=True),
    ):
        pass
    assert len(Dataset.open(tmp_path / "ds.softjig-new")) == 1


@pytest.mark.parametrize(("durable", "kept"), [(False, False), (True, True)])
def test_an_overwrite_left_by_an_exception_keeps_the_old_dataset(tmp_path, jig, durable, kept):
    _write(tmp_path / "ds", jig, 3)
    with (
        pytest.raises(KeyboardInterrupt),
        DatasetWriter(tmp_path / "ds", jig, overwrite=True, durable=durable) as w,
    ):
        w.add_frame(*_images(np.random.default_rng(1)), {})
        raise KeyboardInterrupt
    assert len(Dataset.open(tmp_path / "ds")) == 3
    assert (tmp_path / "ds.softjig-new").exists() == kept  # a recording's new frames are never deleted


def test_writer_rejects_bad_frames(tmp_path, jig):
    rng = np.random.default_rng(0)
    with DatasetWriter(tmp_path / "ds", jig) as writer:
        left, right = _images(rng)
        with pytest.raises(InputError, match="uint8 or uint16"):
            writer.add_frame(left.astype(float), right, {})
        with pytest.raises(InputError, match="must not set index"):
            writer.add_frame(left, right, {"index": 5})
        with pytest.raises(InputError, match="JSON"):
            writer.add_frame(left, right, {"alpha_deg": float("nan")})
        with pytest.raises(InputError, match="truth markers lack"):
            writer.add_frame(left, right, {}, truth_markers={"xyz_mm": np.zeros((1, 3))})
        assert writer.add_frame(left, right, {"alpha_deg": np.float64(5.0)}) == 0
    ds = Dataset.open(tmp_path / "ds")
    assert len(ds) == 1 and ds[0].alpha_deg == 5.0


def test_an_overwrite_without_any_frame_keeps_the_old_dataset(tmp_path, jig):
    _write(tmp_path / "ds", jig, 3)
    with DatasetWriter(tmp_path / "ds", exact_jig(jig), overwrite=True):
        pass  # a camera that delivered nothing
    ds = Dataset.open(tmp_path / "ds")
    assert len(ds) == 3 and ds.jig == jig
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ds"]


def test_overwriting_the_current_folder_by_its_name_dot(tmp_path, jig, monkeypatch):
    _write(tmp_path / "ds", jig, 3)
    monkeypatch.chdir(tmp_path / "ds")
    with DatasetWriter(Path("."), jig, overwrite=True) as writer:
        writer.add_frame(*_images(np.random.default_rng(2)), {})
    assert len(Dataset.open(tmp_path / "ds")) == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ds"]
