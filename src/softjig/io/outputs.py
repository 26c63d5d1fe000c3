"""Outputs never overwrite what the user recorded: a command's inputs, or a dataset's own files.

Every command that writes a file or folder the user names checks it here before any work: an output that
is one of the command's inputs (the same path once resolved, or the same file through a symbolic or hard
link, :func:`os.path.samefile`), lies inside an input folder or holds an input (an output folder that
would be replaced), or that is, or lies inside, a file or folder of a softjig dataset
(:func:`softjig.io.dataset.is_dataset_member`, :meth:`softjig.io.dataset.Dataset.owns`), is refused
with exit 2 and nothing is written.
"""

from __future__ import annotations

import os
from collections.abc import Iterable
from pathlib import Path

from softjig.errors import InputError

__all__ = ["check_output", "same_path"]


def same_path(a: str | os.PathLike[str], b: str | os.PathLike[str]) -> bool:
    """Whether ``a`` and ``b`` name the same file or folder: equal once resolved (links followed), or the
    same inode when both exist (a hard link)."""
    if Path(a).resolve() == Path(b).resolve():
        return True
    try:
        return os.path.samefile(a, b)
    except OSError:
        return False


def _inside(path: Path, folder: Path) -> bool:
    return path.resolve().is_relative_to(folder.resolve())


def check_output(
    out: str | os.PathLike[str],
    option: str,
    inputs: Iterable[str | os.PathLike[str] | None] = (),
    *,
    datasets: Iterable[object] = (),
) -> None:
    """Refuse an output path that would overwrite an input or a dataset's file.

    Parameters
    ----------
    out : the output the user named.
    option : how the message names it (``"--overlay"``).
    inputs : the command's input files and folders (``None`` entries are skipped); an output inside an
        input folder, and an output folder that holds an input, are refused too.
    datasets : opened :class:`~softjig.io.dataset.Dataset` inputs: any file they own is refused.

    Raises
    ------
    InputError
        Naming the output, what it would destroy, and what to do.
    """
    from softjig.io.dataset import is_dataset_member

    path = Path(out)
    for given in inputs:
        if given is None:
            continue
        given = Path(given)
        inside = given.is_dir() and _inside(path, given)
        if same_path(path, given) or inside or _inside(given, path):
            raise InputError(
                f"{option} {path} is an input of this command ({given}), or inside it: writing there would "
                "overwrite what you recorded; give a new path"
            )
    for dataset in datasets:
        if dataset.owns(path):  # type: ignore[attr-defined]
            raise InputError(
                f"{option} {path} is one of the dataset's own files: writing there would destroy it; give "
                "a new file name (e.g. DATASET/estimates.jsonl, the default of estimate --out)"
            )
    if is_dataset_member(path):
        raise InputError(
            f"{option} {path} is one of the dataset's own files (rig.toml, frames.jsonl, left/, right/, "
            "truth/): writing there would destroy it; give a path outside them"
        )
