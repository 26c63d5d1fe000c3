"""Atomic file writes: nothing a user recorded is ever left half-written.

Every file is first written to a temporary file beside its target, then renamed onto it. The temporary
file is created with mode ``0o666`` and the kernel applies the process's umask, so outputs get the modes
any other program's would (``0644`` under the usual umask ``022``, ``0600`` under ``077``); a
:func:`tempfile.mkstemp` file would be ``0600`` whatever the umask, unreadable by a robot process of
another user. The temporary file is removed on every exception (a full disk, Ctrl-C, a SIGTERM turned into
an exception by :func:`softjig.io.workers.terminate_raises`). A process killed outright (SIGKILL, a power
cut) cannot remove its temporary file: its name holds the writer's pid, and the next writer of the same
results file or text file (:func:`remove_stale_temporaries`) deletes those whose process is gone.
"""

from __future__ import annotations

import os
import re
import secrets
from pathlib import Path

from softjig.errors import InputError


def write_bytes_atomic(path: str | os.PathLike[str], data: bytes, *, durable: bool = True) -> None:
    """Write ``data`` to ``path`` atomically: a temporary file in the same folder, fsync, then rename.

    A crash or a kill at any moment leaves either the old file or the new one, never a partial file.
    ``durable`` (the default) also survives a power cut: the file and its folder entry are fsynced
    (a few ms each); data that can be regenerated (a simulation) may skip that.

    Raises
    ------
    InputError
        The path is a folder or cannot be written (permissions, missing drive, disk full).
    """
    path = Path(path)
    fd, tmp = temp_file_beside(path)
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
            if durable:
                fh.flush()
                os.fsync(fh.fileno())
        os.replace(tmp, path)
    except OSError as exc:
        Path(tmp).unlink(missing_ok=True)
        raise InputError(f"cannot write {path}: {exc.strerror or exc}; choose another path") from None
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    if durable:
        fsync_folder(path.parent)


def temp_file_beside(path: Path) -> tuple[int, Path]:
    """A new temporary file in ``path``'s folder (made if missing), to be renamed onto ``path`` when
    complete: its open descriptor and its path.

    Raises
    ------
    InputError
        The path is a folder or its folder cannot be written (permissions, missing drive, disk full).
    """
    if path.is_dir():
        raise InputError(f"cannot write {path}: it is a folder; give a file name inside it")
    flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_CLOEXEC", 0) | getattr(os, "O_BINARY", 0)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        for _ in range(100):
            tmp = path.parent / f".{path.name}.{os.getpid()}-{secrets.token_hex(4)}.tmp"
            try:
                # 0o666 & ~umask, applied by the kernel: no umask read, no race with other threads.
                return os.open(tmp, flags, 0o666), tmp
            except FileExistsError:
                continue
        raise FileExistsError(f"no free temporary name beside {path}")
    except OSError as exc:
        raise InputError(f"cannot write {path}: {exc.strerror or exc}; choose another path") from None


def _running(pid: int) -> bool:
    """Whether a process ``pid`` runs on this machine (of any user)."""
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OSError):
        return True  # another user's process, or a platform that cannot tell: keep its file
    return True


def remove_stale_temporaries(path: str | os.PathLike[str]) -> list[Path]:
    """Delete the temporary files :func:`temp_file_beside` made for ``path`` in processes that are gone
    (killed before they could clean up); returns what was deleted. One listing of ``path``'s folder: for
    files written once per command (results, configs, calibrations), not per frame.

    Only names of our pattern (``.NAME.PID-HEX.tmp``) whose pid no longer runs are touched."""
    path = Path(path)
    pattern = re.compile(rf"\.{re.escape(path.name)}\.(\d+)-[0-9a-f]+\.tmp")
    removed = []
    try:
        entries = list(os.scandir(path.parent))
    except OSError:
        return removed
    for entry in entries:
        match = pattern.fullmatch(entry.name)
        if match and not _running(int(match.group(1))) and entry.is_file(follow_symlinks=False):
            try:
                os.unlink(entry.path)
            except OSError:
                continue
            removed.append(Path(entry.path))
    return removed


def fsync_folder(folder: Path) -> None:
    """Make a rename durable across a power cut (POSIX: fsync the folder's entry table)."""
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass  # some filesystems cannot fsync a folder; the rename is still atomic
    finally:
        os.close(fd)


def write_text_atomic(path: str | os.PathLike[str], text: str) -> None:
    """Write a UTF-8 text file atomically (see :func:`write_bytes_atomic`), removing the temporary files
    of killed writers of the same file (:func:`remove_stale_temporaries`)."""
    remove_stale_temporaries(path)
    write_bytes_atomic(path, text.encode("utf-8"))


def read_text_file(path: str | os.PathLike[str], what: str, *, encoding: str = "utf-8") -> str:
    """The text of a file the user named (``what`` says which, e.g. ``"study"``), or an InputError that
    names it: missing, unreadable, or not text in ``encoding``."""
    try:
        return Path(path).read_text(encoding=encoding)
    except FileNotFoundError:
        raise InputError(f"{what} file {path} does not exist") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"cannot read {what} file {path}: {exc}") from None
