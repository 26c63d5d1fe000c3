"""Arrays that take long to derive from a few parameters, kept on disk between runs.

The sub-pixel fit's weight tables (:func:`softjig.sensing.subpixel.fit_tables`) cost 0.3-1 s to build and
depend only on a marker model: every short command (a single ``softjig estimate``) would pay for them at
start-up. They are stored in the user's cache folder, ``$SOFTJIG_CACHE_DIR``, else
``$XDG_CACHE_HOME/softjig``, else ``~/.cache/softjig``, one ``.bin`` file per entry named by a digest of
its key (the kind of array, its format version and every parameter it depends on). A file is one JSON
header line (the key itself, the dtype, the shape and a SHA-256 of the array's bytes) and then the raw
bytes (read at every Estimator's build: a raw file is several times faster to read than an ``.npz``). A
file that does not parse, holds another key or fails its checksum is rebuilt and replaced. Files are
written to a temporary file in the same folder and renamed over the old one, so a reader never sees half
a file. The cache is an optimisation only: if the folder cannot be created or written (a read-only home),
the array is built and returned as if there were no cache; ``SOFTJIG_CACHE_DIR=off`` disables it.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import tempfile
from collections.abc import Callable
from pathlib import Path

import numpy as np

__all__ = ["cache_dir", "cached_array"]

_DISABLED = ("", "0", "off", "none")


def cache_dir() -> Path | None:
    """The folder of softjig's cached arrays (see the module docstring), or ``None`` if disabled."""
    explicit = os.environ.get("SOFTJIG_CACHE_DIR")
    if explicit is not None:
        return None if explicit.strip().lower() in _DISABLED else Path(explicit).expanduser()
    xdg = os.environ.get("XDG_CACHE_HOME", "").strip()
    base = Path(xdg).expanduser() if xdg and Path(xdg).is_absolute() else Path.home() / ".cache"
    return base / "softjig"


def _checksum(array: np.ndarray) -> str:
    header = f"{array.dtype.str}{array.shape}".encode()
    return hashlib.sha256(header + np.ascontiguousarray(array).tobytes()).hexdigest()


def _read(path: Path, key: str) -> np.ndarray | None:
    """The array of a file written by :func:`_write` (one JSON header line, then the raw bytes), or
    ``None`` when it is missing, truncated, of another key or fails its checksum."""
    try:
        data = path.read_bytes()
        header, _, raw = data.partition(b"\n")
        meta = json.loads(header)
        if not isinstance(meta, dict) or meta.get("key") != key:  # another file's JSON (a list, a number)
            return None
        array = np.frombuffer(raw, dtype=np.dtype(meta["dtype"])).reshape(meta["shape"])
        if meta.get("sha256") != _checksum(array):
            return None
    except (OSError, ValueError, KeyError, TypeError, RecursionError):  # missing, truncated, not ours
        return None
    return array


def _write(path: Path, key: str, array: np.ndarray) -> None:
    array = np.ascontiguousarray(array)
    header = json.dumps(
        {"key": key, "dtype": array.dtype.str, "shape": list(array.shape), "sha256": _checksum(array)}
    ).encode()
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as handle:
            handle.write(header + b"\n" + array.tobytes())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def cached_array(kind: str, key: str, build: Callable[[], np.ndarray]) -> np.ndarray:
    """``build()``, or the array a previous call with the same ``kind`` and ``key`` stored on disk.

    Parameters
    ----------
    kind : a file-name-safe name of the kind of array, e.g. ``"subpixel-tables"``.
    key : everything the array depends on, as text: its format version and parameters (floats written
        with ``repr``, so exactly). Two calls with the same key must build identical arrays.
    build : computes the array (any dtype but object) when no valid entry is stored.

    Returns
    -------
    The array, read-only.
    """
    folder = cache_dir()
    path = None
    if folder is not None:
        digest = hashlib.sha256(f"{kind}\n{key}".encode()).hexdigest()[:32]
        path = folder / f"{kind}-{digest}.bin"
        found = _read(path, key)
        if found is not None:
            found.flags.writeable = False
            return found
    array = np.asarray(build())
    if path is not None:
        with contextlib.suppress(OSError):  # a cache we cannot write is no error: the next run builds again
            _write(path, key, array)
    array.flags.writeable = False
    return array
