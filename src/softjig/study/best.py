"""The winning designs' rigs: ``DIR/best/NNN.toml``, each the full jig config of one design on the Pareto
front, ready for ``softjig simulate --config`` (and any other command's ``--config``).

``NNN`` is the design's id, zero-padded to three digits (more when the study has more designs). Each file
starts with comment lines naming the study, the design's varied values and why it is there; the rest is
:func:`softjig.config.dumps_jig` of the design, written atomically (:mod:`softjig.files`, the umask's
modes). A later report of the same folder (a resumed study) replaces the files it wrote before: a rig of
ours that is no longer on the front is removed, recognised by its first line; any other file is left.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Iterable, Mapping
from pathlib import Path

from softjig.config import JigConfig, dumps_jig, loads_jig, validate_jig
from softjig.files import write_text_atomic

__all__ = ["HEADER_MARK", "best_rig_name", "write_best_rigs"]

#: The first line of every rig this module writes: how it recognises its own files (and only those).
HEADER_MARK = "# softjig study: a design on the Pareto front"
_OUR_NAME = re.compile(r"\d{3,}\.toml")


def best_rig_name(design_id: int) -> str:
    """The file name of a design's rig, ``NNN.toml`` (``7`` -> ``007.toml``, ``1234`` -> ``1234.toml``)."""
    return f"{int(design_id):03d}.toml"


def _rig_text(jig: JigConfig, note: str) -> str:
    lines = [HEADER_MARK, *(f"# {line}".rstrip() for line in note.splitlines())]
    return "\n".join(lines) + "\n\n" + dumps_jig(jig)


def _ours(path: Path) -> bool:
    try:
        with path.open(encoding="utf-8") as fh:
            return fh.readline().rstrip("\n") == HEADER_MARK
    except (OSError, UnicodeDecodeError):
        return False


def write_best_rigs(
    best_dir: Path,
    design_ids: Iterable[int],
    config_for: Callable[[int], JigConfig],
    *,
    notes: Mapping[int, str] | None = None,
) -> tuple[Path, ...]:
    """Write each design's rig to ``best_dir/NNN.toml``; remove the rigs this module wrote there before
    for designs no longer listed.

    Parameters
    ----------
    best_dir : the folder (``DIR/best``), made if missing.
    design_ids : the designs to write (each once, in this order).
    config_for : the full jig config of a design id (the study's base config with the design's varied
        values); it raises :class:`~softjig.errors.ConfigError` for an impossible design.
    notes : per design, text for the comment lines at the top of its file (its values, its accuracy).

    Returns
    -------
    The paths written, in the order of ``design_ids``.

    Raises
    ------
    ConfigError
        A design's config is invalid (checked before anything is written).
    InputError
        A file cannot be written.
    """
    notes = notes or {}
    ids = list(dict.fromkeys(int(i) for i in design_ids))
    texts = {}
    for design_id in ids:
        jig = config_for(design_id)
        validate_jig(jig)
        text = _rig_text(jig, notes.get(design_id, f"design {design_id}"))
        loads_jig(text, source=f"the rig of design {design_id}")  # what we write reads back
        texts[design_id] = text
    best_dir = Path(best_dir)
    paths = []
    for design_id, text in texts.items():
        path = best_dir / best_rig_name(design_id)
        write_text_atomic(path, text)
        paths.append(path)
    keep = {p.name for p in paths}
    if best_dir.is_dir():
        for old in best_dir.iterdir():
            if _OUR_NAME.fullmatch(old.name) and old.name not in keep and old.is_file() and _ours(old):
                old.unlink(missing_ok=True)
    return tuple(paths)
