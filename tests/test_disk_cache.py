"""softjig.disk_cache, and the sub-pixel tables and the jig model kept on disk: the same arrays as built,
atomic, rebuilt if corrupt or derived by other code."""

from __future__ import annotations

import os
from dataclasses import replace

import numpy as np
import pytest
from numpy.testing import assert_array_equal

from softjig import disk_cache
from softjig.config import MarkerConfig, default_jig
from softjig.disk_cache import ALIGNMENT, cache_dir, cached_array, cached_arrays
from softjig.sensing import setup, subpixel
from softjig.sensing.estimator import Estimator
from softjig.sensing.setup import JigModel, model_arrays, model_key
from softjig.sensing.subpixel import MarkerModel, _build_tables, _tables_key

SMALL = MarkerModel(radius_px=3.0, blur_px=1.2, half_width_px=4)


@pytest.fixture
def cache(tmp_path, monkeypatch):
    monkeypatch.setenv("SOFTJIG_CACHE_DIR", str(tmp_path / "cache"))
    return tmp_path / "cache"


def test_cache_dir_follows_the_environment(tmp_path, monkeypatch):
    monkeypatch.delenv("SOFTJIG_CACHE_DIR", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    assert cache_dir() == tmp_path / "softjig"
    monkeypatch.setenv("XDG_CACHE_HOME", "relative/ignored")  # the XDG spec: relative paths are invalid
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    assert cache_dir() == tmp_path / "home" / ".cache" / "softjig"
    monkeypatch.setenv("SOFTJIG_CACHE_DIR", "off")
    assert cache_dir() is None


def test_built_once_then_read(cache):
    calls = []

    def build():
        calls.append(1)
        return np.arange(6, dtype=np.float32).reshape(2, 3)

    first = cached_array("test", "k=1", build)
    second = cached_array("test", "k=1", build)
    assert len(calls) == 1
    assert_array_equal(first, second)
    assert second.dtype == np.float32 and not second.flags.writeable
    assert [p.suffix for p in cache.iterdir()] == [".bin"]  # no temporary file left behind
    cached_array("test", "k=2", build)  # another key: built again
    assert len(calls) == 2


@pytest.mark.parametrize("damage", ["truncate", "garbage", "flip", "json list", "json number", "deep json"])
def test_a_corrupt_entry_is_rebuilt_and_replaced(cache, damage):
    good = np.linspace(0, 1, 50)
    cached_array("test", "k", lambda: good)
    (path,) = cache.iterdir()
    raw = bytearray(path.read_bytes())
    if damage == "truncate":
        raw = raw[: len(raw) // 2]
    elif damage == "garbage":
        raw = bytearray(b"not a cache entry at all")
    elif damage != "flip":  # another file's JSON as the header line
        header = {"json list": b"[1, 2]", "json number": b"3", "deep json": b"[" * 100_000}[damage]
        raw = bytearray(header + b"\n" + good.tobytes())
    else:  # a flipped byte inside the array's data still parses: the checksum catches it
        at = bytes(raw).index(good.tobytes()) + 8
        raw[at] ^= 0xFF
    path.write_bytes(bytes(raw))
    calls = []
    again = cached_array("test", "k", lambda: calls.append(1) or good)
    assert calls == [1]
    assert_array_equal(again, good)
    assert_array_equal(cached_array("test", "k", lambda: 1 / 0), good)  # the replaced entry is valid


def test_an_unwritable_cache_is_no_error(tmp_path, monkeypatch):
    blocker = tmp_path / "file"
    blocker.write_text("a file where the folder should be")
    monkeypatch.setenv("SOFTJIG_CACHE_DIR", str(blocker / "cache"))
    assert_array_equal(cached_array("test", "k", lambda: np.ones(3)), np.ones(3))


def test_subpixel_tables_from_disk_equal_the_built_ones(cache):
    built = _build_tables(SMALL)
    first = subpixel.fit_tables(SMALL)  # built and written (no table is kept in memory)
    read = subpixel.fit_tables(SMALL)
    assert_array_equal(first, built)
    assert_array_equal(read, built)
    assert read.dtype == built.dtype and read.shape == built.shape
    assert len(list(cache.iterdir())) == 1


def test_tables_key_names_every_parameter():
    keys = {_tables_key(SMALL)}
    for name in SMALL.__dataclass_fields__:
        value = getattr(SMALL, name)
        changed = value + 1 if name != "bit_depth" else 16
        keys.add(_tables_key(replace(SMALL, **{name: changed})))
    assert len(keys) == 1 + len(SMALL.__dataclass_fields__)
    assert f"format={subpixel.TABLES_FORMAT_VERSION}" in _tables_key(SMALL)


# --------------------------------------------------------------------------------- named arrays


def test_named_arrays_are_read_back_aligned_and_read_only(cache):
    arrays = {
        "floats": np.linspace(0, 1, 7),
        "ints": np.arange(5, dtype=np.int64).reshape(5, 1),
        "bytes": np.arange(3, dtype=np.uint8),  # 3 bytes: the next array starts aligned all the same
        "empty": np.zeros((0, 3)),
        "scalar": np.array(2.5),
        "singles": np.ones((2, 3), np.float32),
    }
    calls = []
    cached_arrays("test", "k", lambda: calls.append(1) or arrays)
    read = cached_arrays("test", "k", lambda: 1 / 0)
    assert calls == [1] and list(read) == list(arrays)
    for name, array in arrays.items():
        assert_array_equal(read[name], array)
        assert read[name].dtype == array.dtype and read[name].shape == array.shape
        assert not read[name].flags.writeable and read[name].flags.aligned
    (path,) = cache.iterdir()
    data = path.read_bytes()
    assert (data.index(b"\n") + 1) % ALIGNMENT == 0  # the body starts at a multiple of ALIGNMENT


def test_the_oldest_entries_beyond_the_limit_are_deleted(cache, monkeypatch):
    monkeypatch.setattr(disk_cache, "MAX_ENTRIES_PER_KIND", 3)
    for k in range(5):
        cached_arrays("test", f"k={k}", lambda: {"a": np.ones(2)})
        for path in cache.iterdir():  # mtimes in order, however coarse the file system's clock
            if path.name.startswith("test-"):
                os.utime(path, ns=(path.stat().st_atime_ns, path.stat().st_mtime_ns - 10**9))
    cached_array("other", "k", lambda: np.ones(2))  # another kind: not counted with them
    assert len(list(cache.glob("test-*.bin"))) == 3
    assert len(list(cache.glob("other-*.bin"))) == 1
    calls = []
    cached_arrays("test", "k=4", lambda: calls.append(1) or {"a": np.ones(2)})  # the newest: kept
    cached_arrays("test", "k=0", lambda: calls.append(1) or {"a": np.ones(2)})  # the oldest: deleted
    assert calls == [1]


def test_arrays_of_objects_are_refused(cache):
    with pytest.raises(TypeError, match="objects"):
        cached_arrays("test", "k", lambda: {"a": np.array([None, 1])})
    assert not cache.exists()


# ------------------------------------------------------------------------------------- jig model


def _assert_same_model(a: JigModel, b: JigModel) -> None:
    """Bit for bit: every array and number the model's stages read."""
    assert a.setup == b.setup
    for name in ("T_J_left", "T_J_right", "fiducial_quads_left_px", "fiducial_quads_right_px"):
        assert_array_equal(getattr(a.frame.config_frame, name), getattr(b.frame.config_frame, name))
    assert_array_equal(a.frame.T_left_right, b.frame.T_left_right)
    assert a.frame.corners_J_by_id.keys() == b.frame.corners_J_by_id.keys()
    for i in a.frame.corners_J_by_id:
        assert_array_equal(a.frame.corners_J_by_id[i], b.frame.corners_J_by_id[i])
    fa, fb = a.frame.fast, b.frame.fast
    assert fa.expected_quads == fb.expected_quads and fa.sorted_ids == fb.sorted_ids
    assert (fa.n_left, fa.distorted, fa.image_shape) == (fb.n_left, fb.distorted, fb.image_shape)
    assert_array_equal(fa.points_J, fb.points_J)
    assert_array_equal(fa.white, fb.white)
    for name in fa.pinhole.__dataclass_fields__:
        assert_array_equal(getattr(fa.pinhole, name), getattr(fb.pinhole, name))
    for ta, tb in zip(fa.capture_tables, fb.capture_tables, strict=True):
        assert (ta is None) == (tb is None)
        if ta is not None:
            assert (ta.shape, ta.window) == (tb.shape, tb.window)
            for name in ("index", "midpoints", "normals", "offsets"):
                assert_array_equal(getattr(ta, name), getattr(tb, name))
                assert getattr(ta, name).dtype == getattr(tb, name).dtype
    assert_array_equal(a.rest_shape.xyz_mm, b.rest_shape.xyz_mm)
    assert a.rest_reference.height_at_axis_mm == b.rest_reference.height_at_axis_mm
    assert a.rest_reference.scatter_mm is b.rest_reference.scatter_mm is None
    assert (a.marker_tables is None) == (b.marker_tables is None)
    if a.marker_tables is not None:
        assert_array_equal(a.marker_tables, b.marker_tables)
        assert a.marker_tables.dtype == b.marker_tables.dtype


@pytest.mark.parametrize(
    "jig",
    [default_jig(), default_jig().replace(markers=MarkerConfig(layout="hex", pitch_mm=6.0))],
    ids=["default", "hex grid"],
)
def test_the_jig_model_read_from_disk_is_the_one_derived(cache, monkeypatch, jig):
    built = JigModel.build(jig)  # derived and stored
    assert len(list(cache.iterdir())) == 2  # the model, and the sub-pixel tables it read
    with monkeypatch.context() as patch:
        patch.setattr(setup, "model_arrays", lambda *_: pytest.fail("derived again"))
        read = JigModel.build(jig)
    _assert_same_model(read, built)
    monkeypatch.setenv("SOFTJIG_CACHE_DIR", "off")
    _assert_same_model(read, JigModel.build(jig))  # and the one derived without a cache


def test_an_estimate_with_the_model_from_disk_is_bit_identical(cache, monkeypatch, default_scene):
    left, right = default_scene.pair.left, default_scene.pair.right
    Estimator(default_scene.jig)  # stores the model
    from_disk = Estimator(default_scene.jig).estimate(left, right)
    monkeypatch.setenv("SOFTJIG_CACHE_DIR", "off")
    derived = Estimator(default_scene.jig).estimate(left, right)
    assert from_disk.estimate == derived.estimate
    assert_array_equal(from_disk.left.xy_px, derived.left.xy_px)


def test_the_model_key_names_the_jig_and_the_code(monkeypatch):
    jig = default_jig()
    key = model_key(jig)
    assert key is not None and repr(jig) in key and f"format={setup.MODEL_FORMAT_VERSION}" in key
    moved = jig.replace(markers=MarkerConfig(pitch_mm=jig.markers.pitch_mm + 1e-12))
    assert model_key(moved) != key  # floats exactly
    assert setup._CODE is not None and setup._CODE in key
    monkeypatch.setattr(setup, "_CODE", "another version of the code")
    assert model_key(jig) != key  # derived again
    monkeypatch.setattr(setup, "_CODE", None)  # the modules' files unreadable: never read from disk
    assert model_key(jig) is None


def test_an_edit_to_any_module_changes_the_codes_fingerprint(tmp_path):
    """Every module of the package counts, nested ones too (a hand-kept list of the modules deriving the
    model left out the rest shape's indentation, so an edit there would have read stale arrays); the
    byte-code caches and other files do not."""
    package = tmp_path / "softjig"
    (package / "sensing" / "__pycache__").mkdir(parents=True)
    (package / "config.py").write_text("A = 1\n")
    contact = package / "sensing" / "contact.py"
    contact.write_text("B = 2\n")
    before = setup._fingerprint(str(package))
    assert before is not None and before == setup._fingerprint(str(package))
    (package / "sensing" / "__pycache__" / "contact.cpython-311.pyc").write_bytes(b"\0")
    (package / "notes.txt").write_text("not code")
    assert setup._fingerprint(str(package)) == before
    contact.write_text("B = 22\n")
    assert setup._fingerprint(str(package)) != before
    assert setup._fingerprint(str(tmp_path / "no_such_folder")) is None


def test_model_arrays_are_read_only():
    arrays = model_arrays(default_jig())
    assert all(not array.flags.writeable for array in arrays.values()), [
        name for name, array in arrays.items() if array.flags.writeable
    ]
