"""Compiled kernels of :mod:`softjig.sensing.robust`: the scoring of a batch of 3-point hypotheses, the
least-squares refinement of an inlier set, and the choice of the best refined candidate.

Numba's cache checks only the file of the kernel it caches (its modification time and size), not what
it uses from elsewhere: the kernels of :mod:`softjig._geometry_kernels` are compiled into it and the
constants of :mod:`softjig.geometry` frozen into it, so a change to either file needs this file touched
too, or the cache keeps the old code (the hand-written 3x3 solvers of ``plane_fit``, issue 14, came with
this paragraph).
"""

from __future__ import annotations

import numba
import numpy as np

from softjig._geometry_kernels import inside_hull, plane_fit, stable_argsort
from softjig.geometry import DEGENERATE_PLANE_RATIO, HULL_TOLERANCE_MM

#: A triple whose triangle's angle at its first point has a sine below this is collinear: no plane.
COLLINEAR_SINE = 1e-6

#: A plane whose unit normal has ``|n_z|`` below this is vertical: it has no side "into the part".
VERTICAL_NZ = 1e-6


@numba.njit(cache=True)
def score_batch(
    points: np.ndarray,
    triples: np.ndarray,
    threshold_mm: float,
    lqs_factor: float,
    h: int,
    threshold_sigmas: float,
    min_scale_mm: float,
) -> tuple[np.ndarray, np.ndarray, float, float]:
    """The planes through ``triples`` (as :func:`softjig.sensing.robust._planes_from_triples`, skipping
    triples with a repeated point) and the best one's score: one compiled pass per batch of hypotheses.

    Returns ``(normals, offsets, key, ratio)``: the least key of the batch (the MSAC cost
    ``sum min(r^2, t^2)`` when ``threshold_mm > 0``, else the LQS key, the ``h``-th smallest ``|r|``)
    and the share of points within the threshold of that plane (``threshold_sigmas max(lqs_factor
    key, min_scale_mm)`` for LQS); ``key = inf`` when no triple gives a plane.
    """
    m, n = triples.shape[0], points.shape[0]
    normals = np.empty((m, 3))
    offsets = np.empty(m)
    k = 0
    for j in range(m):
        a, b, c = triples[j, 0], triples[j, 1], triples[j, 2]
        if (a - b) * (a - c) * (b - c) == 0:  # a repeated point
            continue
        e10, e11, e12 = points[b, 0] - points[a, 0], points[b, 1] - points[a, 1], points[b, 2] - points[a, 2]
        e20, e21, e22 = points[c, 0] - points[a, 0], points[c, 1] - points[a, 1], points[c, 2] - points[a, 2]
        c0 = e11 * e22 - e12 * e21
        c1 = e12 * e20 - e10 * e22
        c2 = e10 * e21 - e11 * e20
        norm = np.sqrt(c0 * c0 + c1 * c1 + c2 * c2)
        scale = np.sqrt(e10 * e10 + e11 * e11 + e12 * e12) * np.sqrt(e20 * e20 + e21 * e21 + e22 * e22)
        if not norm > COLLINEAR_SINE * scale:
            continue
        n0, n1, n2 = c0 / norm, c1 / norm, c2 / norm
        if not abs(n2) > VERTICAL_NZ:
            continue
        if n2 < 0:
            n0, n1, n2 = -n0, -n1, -n2
        normals[k, 0], normals[k, 1], normals[k, 2] = n0, n1, n2
        offsets[k] = -(n0 * points[a, 0] + n1 * points[a, 1] + n2 * points[a, 2])
        k += 1
    best_key, best_ratio = np.inf, 0.0
    abs_r = np.empty(n)
    for j in range(k):
        for i in range(n):
            abs_r[i] = abs(
                normals[j, 0] * points[i, 0]
                + normals[j, 1] * points[i, 1]
                + normals[j, 2] * points[i, 2]
                + offsets[j]
            )
        if threshold_mm > 0:
            t2 = threshold_mm * threshold_mm
            key = 0.0
            for i in range(n):
                key += min(abs_r[i] * abs_r[i], t2)
            limit = threshold_mm
        else:
            key = np.sort(abs_r)[h - 1]
            limit = threshold_sigmas * max(lqs_factor * key, min_scale_mm)
        if key < best_key:
            best_key = key
            inside = 0
            for i in range(n):
                inside += abs_r[i] <= limit
            best_ratio = inside / n
    return normals[:k], offsets[:k], best_key, best_ratio


@numba.njit(cache=True)
def refine(
    points: np.ndarray, mask: np.ndarray, t: float, max_rounds: int
) -> tuple[bool, np.ndarray, np.ndarray]:
    """Alternate the least-squares plane of the inliers (:func:`softjig._geometry_kernels.plane_fit`) and
    the re-selection ``|r| <= t``, until the set no longer changes (at most ``max_rounds``).

    Returns ``(refined, mask, residuals)``: ``refined`` is false when the set falls below 3 points, onto a
    line, or onto a vertical plane (then the mask and residuals are meaningless).
    """
    n = points.shape[0]
    residuals = np.zeros(n)
    given = mask
    mask = np.empty(n, dtype=np.bool_)
    count = 0
    for i in range(n):
        mask[i] = given[i]
        count += given[i]
    for _ in range(max_rounds):
        if count < 3:
            return False, mask, residuals
        centroid, singular, normal, _ = plane_fit(points, mask)
        if singular[0] <= 0 or singular[1] <= DEGENERATE_PLANE_RATIO * singular[0] or normal[2] == 0:
            return False, mask, residuals
        offset = -(normal[0] * centroid[0] + normal[1] * centroid[1] + normal[2] * centroid[2])
        same = True
        count = 0
        for i in range(n):
            residuals[i] = (
                points[i, 0] * normal[0] + points[i, 1] * normal[1] + points[i, 2] * normal[2] + offset
            )
            inside = abs(residuals[i]) <= t
            count += inside
            if inside != mask[i]:
                same = False
                mask[i] = inside
        if same:
            break
    return count >= 3, mask, residuals


@numba.njit(cache=True)
def best_candidate(
    points: np.ndarray,
    normals: np.ndarray,
    offsets: np.ndarray,
    t: float,
    pool_size: int,
    n_candidates: int,
    same_set_jaccard: float,
    one_sided: bool,
    max_rounds: int,
    above_penalty: float,
) -> tuple[bool, np.ndarray, np.ndarray]:
    """The refined candidate of lowest selection cost among the hypothesis planes ``normals . p + offsets``.

    The candidates are the inlier sets (``|r| <= t``) of the ``pool_size`` hypotheses of lowest MSAC cost
    ``sum min(r^2, t^2)`` that have at least 3 inliers, skipping any set whose Jaccard index with one
    already taken is at least ``same_set_jaccard``, at most ``n_candidates``. Each is refined
    (:func:`refine`); repeated results are dropped. The selection cost is the MSAC cost plus, with
    ``one_sided``, ``above_penalty t^2`` per point more than ``t`` above the plane inside the ``(x, y)``
    hull of its inliers (it would penetrate the part). Returns ``(found, mask, residuals)`` of the
    winner (the first of equals); ``found`` is false when no candidate refines.
    """
    h, n = normals.shape[0], points.shape[0]
    masks = np.empty((h, n), dtype=np.bool_)
    cost = np.empty(h)
    t2 = t * t
    for j in range(h):
        total = 0.0
        for i in range(n):
            r = (
                normals[j, 0] * points[i, 0]
                + normals[j, 1] * points[i, 1]
                + normals[j, 2] * points[i, 2]
                + offsets[j]
            )
            masks[j, i] = abs(r) <= t
            total += min(r * r, t2)
        cost[j] = total
    order = stable_argsort(cost)  # the pool: the first pool_size of these
    pool = min(pool_size, h)
    alive = np.zeros(pool, dtype=np.bool_)
    for q in range(pool):
        count = 0
        for i in range(n):
            count += masks[order[q], i]
        alive[q] = count >= 3
    kept = np.zeros((n_candidates, n), dtype=np.bool_)
    n_taken, n_kept = 0, 0
    best_cost = np.inf
    best_mask = np.zeros(n, dtype=np.bool_)
    best_residuals = np.zeros(n)
    for q in range(pool):
        if n_taken >= n_candidates:
            break
        if not alive[q]:
            continue
        taken = masks[order[q]]
        n_taken += 1
        for other in range(q, pool):  # rule out the sets too like it (itself included)
            if alive[other]:
                row = masks[order[other]]
                both, either = 0, 0
                for i in range(n):
                    both += row[i] and taken[i]
                    either += row[i] or taken[i]
                if not both < same_set_jaccard * either:
                    alive[other] = False
        refined, mask, residuals = refine(points, taken, t, max_rounds)
        if not refined:
            continue
        repeated = False
        for other in range(n_kept):
            same = True
            for i in range(n):
                if kept[other, i] != mask[i]:
                    same = False
                    break
            if same:
                repeated = True
                break
        if repeated:
            continue
        n_inliers = 0
        for i in range(n):
            kept[n_kept, i] = mask[i]
            n_inliers += mask[i]
        n_kept += 1
        selection = 0.0
        n_above = 0
        for i in range(n):
            selection += min(residuals[i] * residuals[i], t2)
            n_above += residuals[i] > t
        if one_sided and n_above > 0:
            selection += above_penalty * t2 * _above_inside(points, mask, residuals, t, n_above, n_inliers)
        if selection < best_cost:
            best_cost, best_mask, best_residuals = selection, mask, residuals
    return n_kept > 0, best_mask, best_residuals


@numba.njit  # no cache of its own: compiled into its callers'
def _above_inside(
    points: np.ndarray, mask: np.ndarray, residuals: np.ndarray, t: float, n_above: int, n_inliers: int
) -> int:
    """How many of the ``n_above`` points more than ``t`` above the plane lie inside the ``(x, y)`` hull
    of the ``n_inliers`` points of ``mask`` (:func:`best_candidate`'s one-sided penalty)."""
    above = np.empty((n_above, 2))
    inliers = np.empty((n_inliers, 2))
    a, b = 0, 0
    for i in range(points.shape[0]):
        if residuals[i] > t:
            above[a, 0], above[a, 1] = points[i, 0], points[i, 1]
            a += 1
        if mask[i]:
            inliers[b, 0], inliers[b, 1] = points[i, 0], points[i, 1]
            b += 1
    inside = inside_hull(inliers, above, HULL_TOLERANCE_MM)
    n_inside = 0
    for i in range(n_above):
        n_inside += inside[i]
    return n_inside
