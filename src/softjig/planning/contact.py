"""The paper's contact rule: contact when the force on the robot's wrist changes by 1 N or more.

"The contact with the jig was judged when the force applied to the wrist of the manipulator changed by
1 N or more" (Sakuma et al., "Jig Coordinate Calibration"). The change is measured from the free-air
reading (the part's weight and the sensor's offset, tared by the mean of the first readings of the
descent), as the magnitude of the change of the force vector (or of the scalar reading).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from softjig.errors import InputError

__all__ = ["CONTACT_THRESHOLD_N", "ContactResult", "detect_contact"]

CONTACT_THRESHOLD_N = 1.0


@dataclass(frozen=True)
class ContactResult:
    """Where contact was judged in a series of force readings.

    Attributes
    ----------
    index : the first reading whose change from the baseline reaches the threshold, or ``None``.
    change_N : that reading's change (N), or the largest change seen when there was no contact.
    baseline_N : the free-air reading subtracted, ``(3,)`` or ``(1,)`` (N).
    """

    index: int | None
    change_N: float
    baseline_N: np.ndarray

    def __bool__(self) -> bool:
        return self.index is not None


def detect_contact(
    forces_N: np.ndarray,
    *,
    threshold_N: float = CONTACT_THRESHOLD_N,
    baseline_samples: int = 5,
    baseline_N: np.ndarray | None = None,
) -> ContactResult:
    """Apply the contact rule to wrist force readings taken during a descent.

    Parameters
    ----------
    forces_N : ``(T,)`` scalar readings or ``(T, 3)`` force vectors (N), oldest first.
    threshold_N : the change that means contact (the paper: 1 N).
    baseline_samples : how many first readings are averaged as the free-air baseline.
    baseline_N : the free-air reading, if known (then ``baseline_samples`` is not used).

    Returns
    -------
    ContactResult
        Falsy when no reading reaches the threshold.

    Raises
    ------
    InputError
        Bad shapes, non-finite readings, a non-positive threshold, or too few readings for the baseline.

    Examples
    --------
    >>> detect_contact([0.1, 0.0, 0.1, 0.05, 0.1, 0.3, 0.8, 1.2]).index
    7
    """
    f = np.asarray(forces_N, dtype=float)
    if f.ndim == 1:
        f = f[:, None]
    if f.ndim != 2 or f.shape[1] not in (1, 3):
        raise InputError(f"forces must be (T,) or (T, 3) readings in N, got shape {np.shape(forces_N)}")
    if not np.all(np.isfinite(f)):
        raise InputError("force readings must be finite numbers (N)")
    if not (np.isfinite(threshold_N) and threshold_N > 0):
        raise InputError(f"the contact threshold must be a positive number of N, got {threshold_N}")
    if baseline_N is None:
        if len(f) < baseline_samples or baseline_samples < 1:
            raise InputError(
                f"need at least {max(baseline_samples, 1)} readings in free air "
                f"for the baseline, got {len(f)}"
            )
        base = f[:baseline_samples].mean(axis=0)
    else:
        base = np.broadcast_to(np.asarray(baseline_N, float), (f.shape[1],)).copy()
    change = np.linalg.norm(f - base, axis=1)
    hits = np.flatnonzero(change >= threshold_N)
    if hits.size == 0:
        return ContactResult(None, float(change.max(initial=0.0)), base)
    k = int(hits[0])
    return ContactResult(k, float(change[k]), base)
