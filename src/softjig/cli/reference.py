"""The reference options of ``softjig live`` and ``softjig serve``, and how they choose the reference.

The refractive method measures indentations against the unloaded jig: its own reference frame when one
is given, else the nominal rest shape (:mod:`softjig.io.reference`). A replay uses its dataset's
reference frame by default, as ``softjig estimate DATASET`` does; cameras use ``--reference-left/-right``
(a pair of the empty jig), ``--reference-from DATASET`` (a recording of this rig), or a ``reference``
request to ``softjig serve`` once running.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from softjig.errors import InputError

if TYPE_CHECKING:
    from softjig.config import JigConfig
    from softjig.io.dataset import Dataset
    from softjig.sensing.identities import ReferenceMarkers

__all__ = [
    "ReferenceFromOption",
    "ReferenceLeftOption",
    "ReferenceRightOption",
    "UseReferenceOption",
    "announced_reference",
    "choose_reference",
]

ReferenceLeftOption = Annotated[
    Path | None,
    typer.Option(
        help="Left image of the unloaded jig (a reference frame; checked unloaded).", show_default=False
    ),
]
ReferenceRightOption = Annotated[
    Path | None,
    typer.Option(
        help="Right image of the unloaded jig (a reference frame; checked unloaded).", show_default=False
    ),
]
ReferenceFromOption = Annotated[
    Path | None,
    typer.Option(
        help="Measure indentations against this dataset's unloaded reference frame (a recording of this "
        "rig; checked unloaded).",
        show_default=False,
    ),
]
UseReferenceOption = Annotated[
    bool,
    typer.Option(
        "--reference/--no-reference",
        help="Replay: measure indentations against the replayed dataset's reference frame (as softjig "
        "estimate DATASET does); --no-reference: the nominal rest shape.",
    ),
]


def choose_reference(
    jig: JigConfig,
    method: str,
    *,
    left: Path | None,
    right: Path | None,
    from_dataset: Path | None,
    replay: Dataset | None,
    use_reference: bool,
) -> ReferenceMarkers | None:
    """The reference the loop starts with (``None``: the rest shape); see the module docstring.

    Raises
    ------
    InputError
        Half a pair, two references, a reference with ``--no-reference`` or the paper's method, a dataset
        without a reference frame, or a reference that is loaded or of another rig.
    """
    from softjig.io.reference import dataset_reference, reference_from_pair

    if (left is None) != (right is None):
        raise InputError("give both --reference-left and --reference-right (one unloaded stereo pair)")
    given = [
        name
        for name, value in (("--reference-left/--reference-right", left), ("--reference-from", from_dataset))
        if value
    ]
    if len(given) > 1:
        raise InputError(f"give one reference: {' or '.join(given)}")
    if given and not use_reference:
        raise InputError(f"{given[0]} and --no-reference contradict each other: give one")
    if method == "paper":
        if given:
            raise InputError(
                f"{given[0]}: the paper's method measures no indentations and uses no reference frame "
                "(use --method refractive)"
            )
        return None
    if left is not None and right is not None:
        from softjig.io.dataset import load_image

        return reference_from_pair(
            load_image(left), load_image(right), jig, where="--reference-left/--reference-right"
        )
    if from_dataset is not None:
        from softjig.io.dataset import Dataset

        reference = dataset_reference(Dataset.open(from_dataset), jig)
        if reference is None:
            raise InputError(
                f"--reference-from {from_dataset}: the dataset has no frame marked reference (an unloaded "
                "frame); record one of the empty jig"
            )
        return reference
    if replay is not None and use_reference:
        return dataset_reference(replay, jig)
    return None


def announced_reference(jig: JigConfig, method: str, **given) -> ReferenceMarkers | None:
    """:func:`choose_reference`, and a line on stderr saying what the estimates measure against."""
    reference = choose_reference(jig, method, **given)
    typer.echo(describe(reference, method), err=True)
    return reference


def describe(reference: ReferenceMarkers | None, method: str) -> str:
    """The stderr line saying what the estimates measure indentations against."""
    if method == "paper":
        return "the paper's method: no indentations, no reference"
    if reference is None:
        return "indentations against the rest shape (no reference frame)"
    return f"indentations against the {reference.source}"
