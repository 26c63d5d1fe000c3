"""softjig.disk_cache and the sub-pixel tables kept on disk: same tables, atomic, rebuilt if corrupt."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from numpy.testing import assert_array_equal

from softjig.disk_cache import cache_dir, cached_array
from softjig.sensing import subpixel
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
