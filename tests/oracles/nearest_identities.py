"""Oracle of :func:`softjig.sensing.identities.identify_markers`: SciPy's k-d tree queried with a distance
bound, then the claims resolved in the stable order of distance (the nearer point keeps a marker)."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree


def kd_tree_identities(
    points_J: np.ndarray, reference_xyz_mm: np.ndarray, max_lateral_mm: float
) -> tuple[np.ndarray, np.ndarray]:
    """Each point's reference marker (``-1`` for none) and its displacement from it (NaN for none)."""
    points = np.asarray(points_J, dtype=float).reshape(-1, 3)
    distance, nearest = cKDTree(reference_xyz_mm[:, :2]).query(
        points[:, :2], distance_upper_bound=max_lateral_mm
    )
    order = np.argsort(distance, kind="stable")
    order = order[np.isfinite(distance[order])]
    _, first = np.unique(nearest[order], return_index=True)  # the nearest claim of each marker
    winners = order[first]
    ids = np.full(len(points), -1)
    ids[winners] = nearest[winners]
    displacement = np.full(points.shape, np.nan)
    displacement[winners] = points[winners] - reference_xyz_mm[nearest[winners]]
    return ids, displacement
