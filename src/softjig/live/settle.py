"""When has the estimate settled? After jamming, the membrane and the bead pack still creep for a while.

Pure: :func:`settled_since` looks at a run of timestamped estimates and says whether the latest
``settle_s`` seconds of them stayed within their own uncertainty.

Criterion: the estimates of the window from the newest one at least ``settle_s`` older than the last, to the
last (so the window spans ``settle_s`` however sparse the samples: a busy estimator drops frames), all gave
an estimate, and each one's normal lies within ``k * sigma_i`` of the window's mean normal, with ``sigma_i``
the estimate's own 1-sigma angular uncertainty (``tilt_sigma_deg``, an RMS angle). For an estimate that only
jitters with its own noise the angle to the mean exceeds ``k`` sigma with probability ``exp(-k^2)``
(Rayleigh): ``k = 3`` lets through a window of 30 still frames with probability 0.997, while a creep of more
than ``3 sigma`` over the window fails it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

__all__ = ["DEFAULT_SETTLE_SIGMAS", "Sample", "settled_since"]

#: The band, in each estimate's own sigmas, within which a settled estimate stays.
DEFAULT_SETTLE_SIGMAS = 3.0


@dataclass(frozen=True)
class Sample:
    """One estimate of the run.

    Attributes
    ----------
    t_s : when its pair was captured (s, any clock, increasing).
    normal : (3,) unit normal in J, or ``None`` when the pair gave no estimate.
    sigma_deg : its 1-sigma angular uncertainty (deg), or ``None`` when unknown.
    """

    t_s: float
    normal: tuple[float, float, float] | None
    sigma_deg: float | None


def settled_since(samples: Sequence[Sample], settle_s: float, *, k: float = DEFAULT_SETTLE_SIGMAS) -> bool:
    """Whether the last ``settle_s`` seconds of ``samples`` stayed within ``k`` of their own sigmas (see the
    module docstring). ``False`` while the samples cover less than ``settle_s``, or if any sample of the
    window lacks an estimate or a sigma."""
    if not samples or settle_s < 0:
        return False
    t_last = samples[-1].t_s
    old_enough = [i for i, s in enumerate(samples) if t_last - s.t_s >= settle_s]
    if not old_enough:
        return False
    window = samples[old_enough[-1] :]  # from the newest sample at least settle_s old: both ends seen
    if any(s.normal is None or s.sigma_deg is None or not math.isfinite(s.sigma_deg) for s in window):
        return False
    normals = np.array([s.normal for s in window], dtype=float)
    mean = normals.mean(axis=0)
    mean /= np.linalg.norm(mean)
    angles_deg = np.degrees(np.arccos(np.clip(normals @ mean, -1.0, 1.0)))
    sigmas = np.array([s.sigma_deg for s in window], dtype=float)
    return bool(np.all(angles_deg <= k * sigmas))
