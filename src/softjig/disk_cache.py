"""Arrays that take long to derive from a few parameters, kept on disk between runs.

The sub-pixel fit's weight tables (:func:`softjig.sensing.subpixel.fit_tables`) cost 0.3-1 s to build and
depend only on a marker model, and what an estimator derives from a jig
(:meth:`softjig.sensing.setup.JigModel.build`) costs about as much as a frame's estimate: every short
command (a single ``softjig estimate``) and every one-shot ``estimate_pair`` would pay for them. They are
stored in the user's cache folder, ``$SOFTJIG_CACHE_DIR``, else ``$XDG_CACHE_HOME/softjig``, else
``~/.cache/softjig``, one ``.bin`` file per entry named by a digest of its key (the kind of arrays, their
format version and every parameter they depend on).

An entry holds one or several named arrays (:func:`cached_arrays`). Its file is one JSON header line (the
digest of the kind and key, each array's name, dtype, shape and offset, the body's size and its
:func:`_checksum`) and then the raw bytes, each array starting at a multiple of :data:`ALIGNMENT` bytes: it is
read at every Estimator's build, and a raw file is several times faster to read than an ``.npz`` (its
arrays are views of the bytes read, not copies). A file that does not parse, holds another key or fails
its checksum is rebuilt and replaced. Files are written to a temporary file in the same folder and renamed
over the old one, so a reader never sees half a file. The cache is an optimisation only: if the folder
cannot be created or written (a read-only home), the arrays are built and returned as if there were no
cache; ``SOFTJIG_CACHE_DIR=off`` disables it. At most :data:`MAX_ENTRIES_PER_KIND` entries of a kind are
kept (the oldest are deleted when one more is written).
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import tempfile
from collections.abc import Callable, Mapping
from pathlib import Path

import numpy as np

__all__ = ["ALIGNMENT", "MAX_ENTRIES_PER_KIND", "cache_dir", "cached_array", "cached_arrays"]

_DISABLED = ("", "0", "off", "none")
#: Every array of an entry starts at a multiple of this many bytes of its file (a cache line).
ALIGNMENT = 64
#: At most this many entries of one kind are kept: the oldest beyond are deleted when one is written.
MAX_ENTRIES_PER_KIND = 256


def cache_dir() -> Path | None:
    """The folder of softjig's cached arrays (see the module docstring), or ``None`` if disabled."""
    folder = _cache_folder()
    return None if folder is None else Path(folder)


def _cache_folder() -> str | None:
    """:func:`cache_dir` as a string (``os.path``: read at every Estimator's build, where ``pathlib``'s
    objects cost more than the file read)."""
    explicit = os.environ.get("SOFTJIG_CACHE_DIR")
    if explicit is not None:
        return None if explicit.strip().lower() in _DISABLED else os.path.expanduser(explicit)
    xdg = os.environ.get("XDG_CACHE_HOME", "").strip()
    if xdg and os.path.isabs(xdg):
        return os.path.join(os.path.expanduser(xdg), "softjig")
    home = os.environ.get("HOME") or os.path.expanduser("~")  # expanduser reads HOME first, too
    return os.path.join(home, ".cache", "softjig")


def _digest(kind: str, key: str) -> str:
    """A 128-bit BLAKE2b digest of an entry's kind and key, in hex: its file's name and its header's
    ``digest`` (CPython's own BLAKE2, not OpenSSL's hashes, whose set-up costs more than hashing a key)."""
    return hashlib.blake2b(f"{kind}\n{key}".encode(), digest_size=16).hexdigest()


def _checksum(body: bytes | bytearray | memoryview) -> int:
    """The body's 64-bit words summed modulo 2**64 (its size is a multiple of :data:`ALIGNMENT`): a word
    changed, a part zeroed, overwritten or cut off changes it; a part moved elsewhere does not (the cache
    guards against accidents, not against tampering). One pass of NumPy's sum: it is checked at every
    Estimator's build, where a CRC or a cryptographic hash of the tables would cost more than the rest
    of the read."""
    return int(np.frombuffer(body, np.uint64).sum(dtype=np.uint64))


def _layout(arrays: Mapping[str, np.ndarray]) -> tuple[list[list], int]:
    """Each array's ``[name, dtype, shape, offset]`` in the body (offsets aligned), and the body's size."""
    entries, offset = [], 0
    for name, array in arrays.items():
        entries.append([name, array.dtype.str, list(array.shape), offset])
        offset += -(-array.nbytes // ALIGNMENT) * ALIGNMENT
    return entries, offset


def _read(path: str, digest: str) -> dict[str, np.ndarray] | None:
    """The arrays of a file written by :func:`_write` (read-only views of its bytes), or ``None`` when it is
    missing, truncated, of another key (``digest``: :func:`_digest` of its kind and key) or fails its
    checksum."""
    try:
        fd = os.open(path, os.O_RDONLY)  # not open(): no buffered reader to make for one read
        try:
            data = os.read(fd, os.fstat(fd).st_size)
        finally:
            os.close(fd)
        start = data.index(b"\n") + 1
        meta = json.loads(data[:start])
        if not isinstance(meta, dict) or meta.get("digest") != digest:  # another file's JSON, or key
            return None
        body = memoryview(data)[start:]
        if len(body) != meta.get("size") or meta.get("sum64") != _checksum(body):
            return None
        arrays = {}
        for name, dtype, shape, offset in meta["arrays"]:
            array = np.ndarray(shape, dtype, data, start + offset)  # a view: read-only, as bytes are
            if not array.flags.aligned:  # bytes not allocated at a multiple of the item size
                array = array.copy()
                array.flags.writeable = False
            arrays[name] = array
    except (OSError, ValueError, KeyError, TypeError, RecursionError):  # missing, truncated, not ours
        return None
    return arrays


def _write(path: str, digest: str, arrays: Mapping[str, np.ndarray]) -> None:
    entries, size = _layout(arrays)
    body = bytearray(size)
    for (_, _, _, offset), array in zip(entries, arrays.values(), strict=True):
        body[offset : offset + array.nbytes] = array.tobytes()
    header = json.dumps(
        {"digest": digest, "arrays": entries, "size": size, "sum64": _checksum(body)}
    ).encode()
    header += b" " * (-(len(header) + 1) % ALIGNMENT)  # the body starts aligned in the file, too
    folder, name = os.path.split(path)
    os.makedirs(folder, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=folder, prefix=f".{name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as handle:
            handle.write(header + b"\n" + bytes(body))
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


def cached_arrays(
    kind: str, key: str, build: Callable[[], Mapping[str, np.ndarray]]
) -> dict[str, np.ndarray]:
    """``build()``, or the named arrays a previous call with the same ``kind`` and ``key`` stored on disk.

    Parameters
    ----------
    kind : a file-name-safe name of the kind of arrays, e.g. ``"jig-model"``.
    key : everything the arrays depend on, as text: their format version and parameters (floats written
        with ``repr``, so exactly). Two calls with the same key must build identical arrays.
    build : computes the arrays (name -> array of any dtype but object) when no valid entry is stored.

    Returns
    -------
    The arrays by name, in ``build``'s order, read-only (views of the file's bytes when read).
    """
    folder = _cache_folder()
    path = None
    if folder is not None:
        digest = _digest(kind, key)
        path = os.path.join(folder, f"{kind}-{digest}.bin")
        found = _read(path, digest)
        if found is not None:
            return found
    arrays = {name: np.asarray(value, order="C") for name, value in build().items()}
    if any(array.dtype.hasobject for array in arrays.values()):
        raise TypeError(f"cached_arrays({kind!r}): arrays of objects cannot be stored as raw bytes")
    if path is not None:
        with contextlib.suppress(OSError):  # a cache we cannot write is no error: the next run builds again
            _write(path, digest, arrays)
            _prune(folder, kind)
    for array in arrays.values():
        array.flags.writeable = False
    return arrays


def _prune(folder: str, kind: str) -> None:
    """Delete the oldest entries of ``kind`` (by modification time) beyond :data:`MAX_ENTRIES_PER_KIND`.

    Called after each write only (an entry is written when none was found): entries keyed by a version of
    the code (:func:`softjig.sensing.setup.model_key`) would otherwise pile up with every edit. A reader
    that had opened a deleted entry reads it whole; one that had not builds the arrays again.
    """
    prefix = f"{kind}-"
    entries = []
    for entry in os.scandir(folder):
        if entry.name.startswith(prefix) and entry.name.endswith(".bin"):
            with contextlib.suppress(OSError):  # deleted meanwhile by another process
                entries.append((entry.stat().st_mtime_ns, entry.path))
    for _, path in sorted(entries, reverse=True)[MAX_ENTRIES_PER_KIND:]:
        with contextlib.suppress(OSError):
            os.unlink(path)


def cached_array(kind: str, key: str, build: Callable[[], np.ndarray]) -> np.ndarray:
    """``build()``, or the array a previous call with the same ``kind`` and ``key`` stored on disk: a
    :func:`cached_arrays` entry of one array (same parameters).

    Returns
    -------
    The array, read-only.
    """
    return cached_arrays(kind, key, lambda: {"array": np.asarray(build())})["array"]
