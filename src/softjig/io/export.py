"""Export of the marker displacement field (what force and slip estimation build on), atomically."""

from __future__ import annotations

import io
import os
from pathlib import Path

import numpy as np

from softjig.errors import InputError
from softjig.files import write_bytes_atomic, write_text_atomic
from softjig.sensing.pipeline import SensingResult

DISPLACEMENT_COLUMNS = ("id", "x_mm", "y_mm", "z_mm", "dx_mm", "dy_mm", "dz_mm", "in_contact")


def displacement_table(result: SensingResult) -> np.ndarray:
    """``(M, 8)`` rows of :data:`DISPLACEMENT_COLUMNS` for every triangulated marker (id -1: unmatched)."""
    if result.identities is None:
        raise InputError("the displacement field needs the refractive method (marker identities)")
    ids = result.identities.ids.astype(float)[:, None]
    return np.hstack(
        [ids, result.points_J, result.identities.displacement_mm, result.used.astype(float)[:, None]]
    )


def write_displacements(result: SensingResult, path: str | os.PathLike[str]) -> None:
    """Write the displacement field as CSV (``.csv``) or NumPy ``.npz`` (any other suffix)."""
    table = displacement_table(result)
    path = Path(path)
    if path.suffix.lower() == ".csv":
        buffer = io.StringIO()
        np.savetxt(
            buffer,
            table,
            delimiter=",",
            header=",".join(DISPLACEMENT_COLUMNS),
            comments="",
            fmt=["%d", *["%.4f"] * 6, "%d"],
        )
        write_text_atomic(path, buffer.getvalue())
    else:
        buffer = io.BytesIO()
        np.savez(buffer, **{name: table[:, k] for k, name in enumerate(DISPLACEMENT_COLUMNS)})
        write_bytes_atomic(path, buffer.getvalue())
