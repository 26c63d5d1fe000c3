"""The choices of the command line's options, as enums: ``--help`` lists them and Typer refuses any other
value while parsing, before a command does any work (exit 2).

Light on purpose (no NumPy, no softjig internals): a command's signature is read when it runs, and
these mirror the library's own lists (``tests/test_cli_app.py`` checks they agree):
:data:`softjig.sensing.pipeline.METHODS` and :data:`softjig.calibration.sweep.SELECTIONS`. Use them as
an option's type::

    method: Annotated[Method, typer.Option(help="...")] = DEFAULT_METHOD
"""

from __future__ import annotations

from enum import StrEnum

__all__ = ["DEFAULT_METHOD", "FrameSelection", "Method", "ReplayRate"]


class Method(StrEnum):
    """Estimation methods (:data:`softjig.sensing.pipeline.METHODS`)."""

    refractive = "refractive"
    paper = "paper"


#: :data:`softjig.sensing.pipeline.DEFAULT_METHOD`.
DEFAULT_METHOD = Method.refractive


class FrameSelection(StrEnum):
    """Frames of a sweep a calibration is fitted to (:data:`softjig.calibration.sweep.SELECTIONS`)."""

    all = "all"
    even = "even"
    odd = "odd"


class ReplayRate(StrEnum):
    """How fast a replayed dataset is delivered: at its ``recorded`` rate (like cameras), or ``fast``."""

    recorded = "recorded"
    fast = "fast"
