"""Write one benchmark's own section of benchmarks/RESULTS.md, leaving the others as they are."""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

from softjig.files import write_text_atomic


def replace_section(path: Path, heading: str, lines: Iterable[str]) -> None:
    """Replace the section of ``path`` that starts with ``heading`` (up to the next ``## `` heading), or
    append it; the file is written atomically."""
    text = path.read_text() if path.exists() else "# softjig benchmark results\n"
    body = "\n".join([heading, "", *lines]).rstrip() + "\n"
    start = text.find(heading)
    if start < 0:
        text = text.rstrip() + "\n\n" + body
    else:
        end = text.find("\n## ", start + len(heading))
        text = text[:start] + body + ("" if end < 0 else text[end + 1 :])
    write_text_atomic(path, text)
