"""A resumable run's folder: its manifest, what is finished, what it may delete, and its disk use.

``softjig demo`` renders and estimates its frames in chunks; after each chunk, ``manifest.json`` in the
run folder records it as done (atomically). The manifest holds the run's *fingerprint* (every option that
changes what is rendered or computed), so a run interrupted by Ctrl-C or a kill continues where it
stopped when started again with the same options, and is refused with another's. A finished run is never
replaced without ``overwrite``; a folder without a manifest (not a run of ours) is never touched.

Only what the run wrote is ever deleted: a chunk's images and truth files named in its own
``frames.jsonl`` (after they were estimated), or, with ``overwrite``, the members a run writes
(:data:`RUN_MEMBERS`).

Manifest (JSON)::

    {"kind": "softjig-demo-run", "version": 1, "status": "running" | "finished",
     "fingerprint": {...}, "runs": 2,
     "chunks": {"sweep/000": {"first": 0, "n": 64, "run": 1, "rendered_files": 192,
                               "rendered_bytes": 61234567, "deleted_files": 189}, ...}}
"""

from __future__ import annotations

import json
import os
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from softjig.errors import InputError
from softjig.files import write_text_atomic

__all__ = ["MANIFEST_NAME", "RUN_MEMBERS", "DiskUse", "RunFolder", "delete_frame_files", "disk_use"]

MANIFEST_NAME = "manifest.json"
KIND = "softjig-demo-run"
VERSION = 1
#: What a run writes at the top of its folder (removed by ``overwrite``, and only these).
RUN_MEMBERS = (
    "report.md",
    "report.html",
    "summary.json",
    "calibration.json",
    "calibration-per-diameter.json",
    "calibration-refractive.json",
    "figures",
    "data",
    MANIFEST_NAME,
)


@dataclass(frozen=True)
class DiskUse:
    """Files and bytes under a folder."""

    files: int
    bytes: int

    @property
    def mb(self) -> float:
        """Megabytes (10^6 bytes)."""
        return self.bytes / 1e6


def disk_use(root: str | os.PathLike[str]) -> DiskUse:
    """Count the regular files under ``root`` and their sizes (bytes), measured on disk now."""
    files = size = 0
    for folder, _dirs, names in os.walk(root):
        for name in names:
            try:
                st = os.stat(os.path.join(folder, name), follow_symlinks=False)
            except FileNotFoundError:
                continue
            files += 1
            size += st.st_size
    return DiskUse(files, size)


def delete_frame_files(dataset_root: Path, keep_local: set[int]) -> int:
    """Delete the images and truth files of a dataset's frames, except the frames ``keep_local`` (local
    indices), reading the names from the dataset's own ``frames.jsonl``; returns how many were deleted.
    Names that would leave the dataset's folder are never followed."""
    root = dataset_root.resolve()
    deleted = 0
    with open(dataset_root / "frames.jsonl", encoding="utf-8") as fh:
        for line in fh:
            try:
                record = json.loads(line)
            except json.JSONDecodeError:
                continue
            if record.get("index") in keep_local:
                continue
            names = [record.get("left"), record.get("right"), (record.get("truth") or {}).get("markers")]
            for name in names:
                if not isinstance(name, str):
                    continue
                path = (dataset_root / name).resolve()
                if root not in path.parents:
                    continue
                try:
                    path.unlink()
                    deleted += 1
                except FileNotFoundError:
                    pass
    return deleted


class RunFolder:
    """The folder of one resumable run and its manifest.

    Parameters
    ----------
    root : the run folder.
    fingerprint : every option that changes the run's results (JSON-able); compared on resume.
    overwrite : replace a finished run, or an unfinished one with other options.

    Raises
    ------
    InputError
        ``root`` is a file, or a non-empty folder without a manifest (not a run of ours), or holds a
        finished run (or an unfinished one with another fingerprint) and ``overwrite`` is not set.
    """

    def __init__(self, root: str | os.PathLike[str], fingerprint: dict[str, Any], *, overwrite: bool) -> None:
        self.root = Path(root)
        self.fingerprint = json.loads(json.dumps(fingerprint))  # as it reads back from the file
        self.resumed = False
        manifest = self._existing()
        if manifest is not None:
            same = manifest.get("fingerprint") == self.fingerprint
            if manifest.get("status") == "running" and same:
                self.resumed = True
            elif not overwrite:
                raise InputError(self._refusal(manifest))
            else:
                self._clear()
                manifest = None
        if manifest is None:
            manifest = {
                "kind": KIND,
                "version": VERSION,
                "status": "running",
                "fingerprint": self.fingerprint,
                "runs": 0,
                "chunks": {},
            }
        manifest["runs"] = int(manifest.get("runs", 0)) + 1
        manifest["status"] = "running"
        self.manifest = manifest
        self.save()

    @property
    def path(self) -> Path:
        return self.root / MANIFEST_NAME

    @property
    def run_number(self) -> int:
        """1 for a fresh run, 2 for its first resumption..."""
        return int(self.manifest["runs"])

    def _existing(self) -> dict | None:
        root = self.root
        if root.exists() and not root.is_dir():
            raise InputError(f"{root} exists and is not a folder: choose another --out")
        if not root.is_dir() or not any(root.iterdir()):
            return None
        try:
            manifest = json.loads((root / MANIFEST_NAME).read_text(encoding="utf-8"))
        except FileNotFoundError:
            raise InputError(
                f"{root} is not empty and holds no {MANIFEST_NAME}, so it is not a softjig demo run (or one "
                "of an older softjig): choose another --out, or delete it yourself"
            ) from None
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise InputError(
                f"cannot read {root / MANIFEST_NAME}: {exc}; choose another --out, or delete the folder"
            ) from None
        if not isinstance(manifest, dict) or manifest.get("kind") != KIND:
            raise InputError(f"{root / MANIFEST_NAME} is not a softjig demo manifest: choose another --out")
        return manifest

    def _refusal(self, manifest: dict) -> str:
        if manifest.get("status") == "finished":
            return (
                f"{self.root} holds a finished demo run: choose another --out, or pass --overwrite to "
                "replace it"
            )
        old = manifest.get("fingerprint") or {}
        differ = [
            k for k in sorted(set(old) | set(self.fingerprint)) if old.get(k) != self.fingerprint.get(k)
        ]
        shown = ", ".join(f"{k} {old.get(k)!r} (now {self.fingerprint.get(k)!r})" for k in differ[:4])
        return (
            f"{self.root} holds an unfinished demo run with other options ({shown}): run again with the "
            "same options to resume it, or pass --overwrite to start over"
        )

    def _clear(self) -> None:
        """Remove what a run writes (:data:`RUN_MEMBERS`), nothing else."""
        for name in RUN_MEMBERS:
            member = self.root / name
            if member.is_dir() and not member.is_symlink():
                shutil.rmtree(member)
            elif member.exists() or member.is_symlink():
                member.unlink()

    def save(self) -> None:
        """Write the manifest atomically."""
        self.root.mkdir(parents=True, exist_ok=True)
        write_text_atomic(self.path, json.dumps(self.manifest, indent=1) + "\n")

    def done(self, key: str) -> bool:
        """Whether the chunk ``key`` was finished (by this run or an earlier one)."""
        return bool(self.manifest["chunks"].get(key, {}).get("done"))

    def finish_chunk(self, key: str, **record: Any) -> None:
        """Record the chunk ``key`` as done (with ``record``) and save the manifest."""
        self.manifest["chunks"][key] = {**record, "run": self.run_number, "done": True}
        self.save()

    def chunks(self) -> dict[str, dict]:
        return dict(self.manifest["chunks"])

    def finish(self) -> None:
        """Mark the run finished: from now on it is only replaced with ``overwrite``."""
        self.manifest["status"] = "finished"
        self.save()
