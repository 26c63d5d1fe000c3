"""Oracle of the robust plane fit's candidate choice (:func:`softjig.sensing._robust_kernels.best_candidate`):
the same steps in NumPy and SciPy, each in its plainest form (NumPy's SVD for the planes, Qhull for the
hull)."""

from __future__ import annotations

import numpy as np
from scipy.spatial import ConvexHull, QhullError


def svd_plane(points: np.ndarray) -> tuple[np.ndarray, float] | None:
    """Least-squares plane (unit normal with ``n_z > 0``, offset) of ``(M, 3)`` points by NumPy's SVD, or
    ``None`` for a line, a point or a vertical plane."""
    centroid = points.mean(axis=0)
    _, s, vt = np.linalg.svd(points - centroid, full_matrices=False)
    if len(s) < 3 or s[0] <= 0 or s[1] <= 1e-9 * s[0] or vt[2, 2] == 0:
        return None
    normal = vt[2] * np.sign(vt[2, 2])
    return normal, -float(normal @ centroid)


def refined(points: np.ndarray, mask: np.ndarray, t: float, max_rounds: int):
    """``(mask, residuals)`` after alternating the SVD plane of the inliers and ``|r| <= t``, or ``None``."""
    residuals = np.zeros(len(points))
    for _ in range(max_rounds):
        plane = svd_plane(points[mask]) if mask.sum() >= 3 else None
        if plane is None:
            return None
        residuals = points @ plane[0] + plane[1]
        again = np.abs(residuals) <= t
        if np.array_equal(again, mask):
            break
        mask = again
    return (mask, residuals) if mask.sum() >= 3 else None


def inside_hull(members_xy: np.ndarray, query_xy: np.ndarray, tolerance: float = 1e-9) -> np.ndarray:
    """Which query points lie in the convex hull of ``members_xy`` (Qhull), none for a flat hull."""
    try:
        equations = ConvexHull(members_xy).equations
    except (QhullError, ValueError):
        return np.zeros(len(query_xy), dtype=bool)
    return np.all(query_xy @ equations[:, :2].T + equations[:, 2] <= tolerance, axis=1)


def best_candidate(points, normals, offsets, t, pool_size, n_candidates, same_set_jaccard, one_sided,
                   max_rounds, above_penalty):  # fmt: skip
    """``(mask, residuals)`` of the lowest selection cost among the refined diverse inlier sets, or None."""
    residuals = normals @ points.T + offsets[:, None]
    masks = np.abs(residuals) <= t
    order = np.argsort(np.minimum(residuals**2, t * t).sum(axis=1), kind="stable")[:pool_size]
    pool = masks[order]
    alive = pool.sum(axis=1) >= 3
    best, best_cost, kept = None, np.inf, []
    for _ in range(n_candidates):
        if not alive.any():
            break
        taken = pool[np.argmax(alive)]
        alive &= (pool & taken).sum(axis=1) < same_set_jaccard * (pool | taken).sum(axis=1)
        result = refined(points, taken, t, max_rounds)
        if result is None or any(np.array_equal(result[0], other) for other in kept):
            continue
        kept.append(result[0])
        mask, r = result
        cost = np.minimum(r**2, t * t).sum()
        if one_sided:
            cost += above_penalty * t * t * inside_hull(points[mask, :2], points[r > t, :2]).sum()
        if cost < best_cost:
            best, best_cost = result, cost
    return best
