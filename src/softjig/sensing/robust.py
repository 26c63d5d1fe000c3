"""Robust plane fit to the contact markers under a part's flat face.

The candidate contact markers (``(N, 3)`` points in mm, jig frame J) mix markers that touch the face,
which lie on its plane up to the triangulation noise, with two kinds of outliers: markers where a
tilted part has lifted off, which can only lie *below* the face's plane (on the cameras' side, the
membrane cannot penetrate the part), and markers on the membrane's wall beside a deep indentation,
outside the face, which lie *above* the extended plane. A least-squares (SVD) fit averages them in and
tilts the plane by degrees; :func:`fit_plane_robust` finds the plane of the contact markers alone.

Method
------
1. **Hypotheses.** Planes through 3 markers (every triple when there are at most 256 of them, else
   triples drawn with the seeded ``rng``), in batches of 64, each batch scored in one array operation
   (residuals of every hypothesis at every point, ``(H, N)``). Degenerate triples (nearly collinear,
   or a vertical plane) are skipped.
2. **Preliminary scale.** With ``threshold_mm=None`` the hypotheses are first ranked scale-free by the
   least quantile of squares (LQS: the ``h``-th smallest ``|r|``, ``h = max(4, ceil(0.4 N))``, which
   tolerates up to 60 % outliers). The best LQS plane is refitted (least squares) to its ``h`` closest
   points, since a 3-point plane through noisy markers a few mm apart is tilted by the noise, and
   ``s0 = |r|_(h) / Phi^-1((1 + (h - 1/2) / N) / 2) * sqrt(N / (N - 3))`` (consistent for Gaussian noise
   without outliers, larger with them) gives ``t0 = 2.5 max(s0, 0.05 mm)``. The floor on the scale keeps
   noise-free data (``s = 0``) from rejecting points for rounding errors, keeps a handful of markers that
   happen to be coplanar from rejecting the rest, and stands for the unmodelled systematic errors
   (membrane ripple, refraction) that no sample of residuals reveals; 0.05 mm is the low end of the
   triangulation noise.
3. **MSAC.** Every hypothesis is scored with the truncated quadratic loss ``sum_i min(r_i^2, t^2)``
   (MSAC [2]_): unlike RANSAC's inlier count, it prefers the plane that fits its inliers best among
   those with the same support. The number of hypotheses adapts to the inlier ratio ``w`` of the best
   one so far, ``k = log(1 - 0.999) / log(1 - w^3)`` (99.9 % confidence of drawing one all-inlier
   triple), at least 100 and at most ``max_iterations``.
4. **Local refinement** [4]_. The 3 best hypotheses with clearly different inlier sets (Jaccard index
   below 0.8) are refined: least-squares refit on the inliers, re-select ``|r| <= t``, until the set no
   longer changes (at most 10 rounds). The candidate of lowest MSAC cost (plus the one-sided penalty)
   wins.
5. **Final scale.** With an automatic threshold, ``s = 1.4826 median |r| sqrt(m / (m - 3))`` over the
   winner's ``m`` residuals within ``2 t``, or within the median ``|r|`` if wider (only those above the
   plane with ``one_sided``, when there are at least 8), and ``t = k max(s, 0.05 mm)`` with ``k`` the
   Student-t quantile (``m - 3`` degrees of freedom) of the coverage of 2.5 sigma, 98.8 %: 2.55 for 100
   points, 3.5 for 9, 8.9 for 5, so a scale estimated from a few markers does not reject the others.
   Then refine again, until ``t`` changes by less than 1 % (at most 8 rounds). The ``2 t`` window drops
   the gross outliers but still recovers a ``t0`` that was too tight; a wider one lets the lifted-off
   markers just below the plane inflate the scale, which then admits more of them.
6. **One-sided penalty** (``one_sided=True``). A point more than ``t`` *above* a candidate plane (along
   its normal, into the part) whose ``(x, y)`` lies inside the convex hull of the plane's inliers would
   penetrate the part's face, which is impossible: each costs an extra ``t^2`` (twice an ordinary
   outlier). Points above the plane *outside* the inliers' footprint are not penalised: they are the
   membrane's wall beside the face. A plain penalty on every point above the plane would charge the true
   plane for those wall markers, while the plane through the lifted-off markers, which lies *above* the
   contact markers on their side of the contact boundary, is never charged: with 30 % lift-off and 20 %
   wall markers it would tie with the true plane. The penalty acts only in the choice between refined
   candidates (a convex hull per hypothesis would be too slow), and the scale of step 5 uses the residuals
   above the plane, which the lifted-off markers cannot reach.

No M-estimator refinement follows (none is implemented). The error that remains comes from lifted-off
markers just below the plane, within ``t``, which are indistinguishable from noise by their residual
alone.

Limits: the fit degrades when the triangulation noise approaches the lifted-off markers' gaps below the
plane (small contact discs with many outliers fail first); with Gaussian noise about 1 % of the contact
markers fall beyond 2.5 sigma and are dropped by design, and a few markers that happen to be coplanar can
hold the automatic threshold down on small sets. The figures are in ``benchmarks/RESULTS.md`` (robust
plane fit).

References
----------
.. [1] M. A. Fischler and R. C. Bolles, "Random sample consensus", Commun. ACM 24(6), 1981.
.. [2] P. H. S. Torr and A. Zisserman, "MLESAC: A new robust estimator with application to estimating
       image geometry", CVIU 78(1), 2000 (the MSAC cost).
.. [3] P. J. Rousseeuw and A. M. Leroy, *Robust Regression and Outlier Detection*, Wiley, 1987 (LQS and
       its scale).
.. [4] O. Chum, J. Matas and J. Kittler, "Locally optimized RANSAC", DAGM 2003.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable
from dataclasses import dataclass
from functools import lru_cache
from statistics import NormalDist

import numpy as np

from softjig._geometry_kernels import plane_fit
from softjig.checks import positive_float
from softjig.errors import InputError
from softjig.geometry import DEGENERATE_PLANE_RATIO, PlaneFit, fit_plane_svd
from softjig.sensing._robust_kernels import COLLINEAR_SINE, VERTICAL_NZ, best_candidate, refine, score_batch

__all__ = ["RobustPlaneFit", "fit_plane_robust"]

_CONFIDENCE = 0.999  # probability of drawing at least one all-inlier triple
_BATCH = 64  # hypotheses scored per array operation
_EXHAUSTIVE_MAX = 256  # enumerate every triple when there are at most this many
_MIN_ITERATIONS = 100  # never stop before this many hypotheses (cheap; guards against a lucky early w)
_LQS_QUANTILE = 0.4  # LQS ranks planes by this quantile of |r|: tolerates up to 60 % outliers
_THRESHOLD_SIGMAS = 2.5  # inlier threshold in units of the noise scale
_COVERAGE_QUANTILE = NormalDist().cdf(_THRESHOLD_SIGMAS)  # one-sided quantile of +-2.5 sigma
_MIN_SCALE_MM = 0.05  # floor of the automatic noise scale (the threshold is at least 2.5 x this)
_MAD_TO_SIGMA = 1.4826  # sigma / median(|r|) for Gaussian noise
_MAX_REFINE_ROUNDS = 10  # least-squares refits of one candidate's inliers, at most
_MIN_ABOVE_FOR_SCALE = 8  # the one-sided scale needs at least this many residuals above the plane
_MIN_INLIER_RATIO = 1e-6  # the adaptive hypothesis count's inlier ratio is at least this (no log(0))
_MAX_SCALE_ROUNDS = 8  # re-estimations of the automatic threshold after refinement
_SETTLED_THRESHOLD_CHANGE = 0.01  # the automatic threshold has settled when it changes by less than this
_N_CANDIDATES = 3  # refined candidates compared at the end
_CANDIDATE_POOL = 50 * _N_CANDIDATES  # the candidates are drawn from this many lowest-cost hypotheses
_SAME_SET_JACCARD = 0.8  # inlier sets this similar count as one candidate
_SCALE_WINDOW = 2.0  # the scale is re-estimated from the residuals within this many thresholds
_ABOVE_PENALTY = 1.0  # extra cost, in t^2, of a point above the plane inside its inliers' footprint


@dataclass(frozen=True)
class RobustPlaneFit:
    """The result of :func:`fit_plane_robust`.

    Attributes
    ----------
    plane : PlaneFit
        Least-squares (SVD) plane of the inliers (:func:`softjig.geometry.fit_plane_svd`), in J.
    inliers : (N,) bool ndarray
        Which input points lie within ``threshold_mm`` of ``plane``.
    n_inliers : int
        ``inliers.sum()``.
    threshold_mm : float
        The inlier distance used (mm): given, or estimated from the data.
    iterations : int
        How many 3-point hypotheses were drawn.
    """

    plane: PlaneFit
    inliers: np.ndarray
    n_inliers: int
    threshold_mm: float
    iterations: int


def fit_plane_robust(
    points_mm: np.ndarray,
    *,
    threshold_mm: float | None = None,
    rng: int | np.random.Generator | None = 0,
    max_iterations: int = 1000,
    min_inliers: int = 3,
    one_sided: bool = True,
) -> RobustPlaneFit:
    """Fit a plane to the contact markers, ignoring lifted-off and wall markers (RANSAC/MSAC + LS).

    Parameters
    ----------
    points_mm : (N, 3) array_like
        Candidate contact markers in the jig frame J (mm), ``N >= 3``.
    threshold_mm : float, optional
        Inlier distance (mm, perpendicular to the plane). ``None`` estimates it from the data as about
        ``2.5 max(s, 0.05 mm)``, with ``s`` a robust noise scale (see the module's Method, steps 2 and 5).
    rng : int or numpy.random.Generator or None, optional
        Seed or generator for the 3-point samples; the default makes the fit deterministic.
    max_iterations : int, optional
        Cap on the number of 3-point hypotheses (the adaptive count is usually far lower).
    min_inliers : int, optional
        Fewest inliers (at least 3) a plane must have to be returned.
    one_sided : bool, optional
        Penalise planes with points more than the threshold above them inside their inliers' footprint
        (they would penetrate the part), and take the noise scale from the residuals above the plane; see
        the module's Method, steps 5 and 6.

    Returns
    -------
    RobustPlaneFit
        The least-squares plane of the inliers, the inlier mask, the threshold and the hypothesis count.

    Raises
    ------
    InputError
        Points not ``(N, 3)``, non-finite, fewer than 3, all collinear; a non-positive ``threshold_mm``;
        or no plane with at least ``min_inliers`` inliers (the message gives the counts).

    Notes
    -----
    Distances are signed along the plane's normal ``n`` (``n_z > 0``, into the part): lifted-off markers
    have negative residuals, wall markers positive ones. The inlier threshold is symmetric; only the
    choice between refined candidates and the final scale are one-sided.

    Examples
    --------
    >>> import numpy as np
    >>> xy = np.stack(np.meshgrid(np.arange(-24.0, 25, 8), np.arange(-24.0, 25, 8)), -1).reshape(-1, 2)
    >>> z = -5.0 + 0.2 * xy[:, 0]
    >>> z[xy[:, 0] > 10] -= 3.0  # lifted off: below the plane
    >>> fit = fit_plane_robust(np.column_stack([xy, z]))
    >>> fit.n_inliers, (np.round(fit.plane.normal / fit.plane.normal[2], 6) + 0.0).tolist()
    (35, [-0.2, 0.0, 1.0])
    """
    pts = _check_points(points_mm)
    n = len(pts)
    if threshold_mm is not None:
        threshold_mm = positive_float(threshold_mm, "threshold_mm")
    if int(max_iterations) < 1:
        raise InputError(f"max_iterations must be >= 1, got {max_iterations}.")
    need = max(3, int(min_inliers))
    if n < need:
        raise InputError(f"robust plane fit needs at least {need} points (min_inliers), got {n}.")
    centred = pts - pts.sum(axis=0) / n  # work centred (pts.mean(axis=0)): offsets small, residuals precise

    draw = _triple_source(rng, n, int(max_iterations))
    normals, offsets, iterations = _hypotheses(centred, draw, threshold_mm, int(max_iterations))
    if len(normals) == 0:
        raise InputError(f"the {n} points lie on a line or a point and do not define a plane.")
    auto = threshold_mm is None
    if auto:
        threshold_mm = _threshold_from_lqs(centred, normals @ centred.T + offsets[:, None])
    t = float(threshold_mm)

    best = _best_candidate(centred, normals, offsets, t, one_sided)
    if best is None:
        raise InputError(f"no hypothesis plane's inliers among the {n} points define a plane.")
    if auto:  # re-estimate the scale about the chosen plane and refine again, until t settles
        settled = _settle_scale(centred, best, t, one_sided)
        if settled is not None:
            best, t = settled

    mask = best[0]
    n_in = int(mask.sum())
    if n_in < need:
        raise InputError(
            f"no plane has at least {need} inliers (min_inliers): the best has {n_in} of {n} points "
            f"within {t:.3g} mm."
        )
    return RobustPlaneFit(
        plane=fit_plane_svd(pts[mask]),
        inliers=mask,
        n_inliers=n_in,
        threshold_mm=t,
        iterations=iterations,
    )


# ------------------------------------------------------------------------------------------ steps


def _triple_source(
    rng: int | np.random.Generator | None, n: int, max_iterations: int
) -> Callable[[int, int], np.ndarray]:
    """``draw(start, count)``: the random triples ``start .. start + count`` of ``N = n`` points, as
    ``np.random.default_rng(rng).integers(0, n, size=(count, 3))`` drawn in turn would give them.

    For an integer seed (the default) the whole sequence is drawn once per ``(seed, n, max_iterations)``
    and sliced (batches drawn in turn are the rows of one draw of all of them), so a fit does not pay for
    making a seeded generator.
    """
    if isinstance(rng, (int, np.integer)) and not isinstance(rng, bool):
        table = _seeded_triples(int(rng), n, max_iterations)
        return lambda start, count: table[start : start + count]
    generator = np.random.default_rng(rng)
    return lambda start, count: generator.integers(0, n, size=(count, 3))


@lru_cache(maxsize=512)
def _seeded_triples(seed: int, n: int, count: int) -> np.ndarray:
    triples = np.random.default_rng(seed).integers(0, n, size=(count, 3))
    triples.flags.writeable = False
    return triples


def _check_points(points_mm) -> np.ndarray:
    pts = np.asarray(points_mm, dtype=float)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise InputError(f"robust plane fit needs (N, 3) points, got shape {pts.shape}.")
    if not np.isfinite(pts).all():
        raise InputError("robust plane fit got non-finite points (NaN or inf); drop them first.")
    if len(pts) < 3:
        raise InputError(f"robust plane fit needs at least 3 points, got {len(pts)}.")
    return pts


def _lqs_order(n: int) -> int:
    """Rank ``h`` (1-based) of the residual the LQS criterion minimises: ``ceil(0.4 N)``, at least 4."""
    return min(n, max(4, math.ceil(_LQS_QUANTILE * n)))


def _lqs_scale(abs_residual_h: float | np.ndarray, n: int) -> float | np.ndarray:
    """Preliminary scale from the ``h``-th smallest absolute residual, consistent for Gaussian noise
    without outliers, with the factor ``sqrt(N / (N - 3))`` for the 3 fitted parameters."""
    h = _lqs_order(n)
    consistency = 1.0 / NormalDist().inv_cdf(0.5 * (1.0 + (h - 0.5) / n))  # |r| quantile (h - 1/2) / N
    return consistency * math.sqrt(n / max(n - 3, 1)) * abs_residual_h


def _planes_from_triples(points: np.ndarray, triples: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit normals (``n_z > 0``) and offsets of the planes through each triple, degenerate ones dropped."""
    p0, p1, p2 = (points[triples[:, k]] for k in range(3))
    e1, e2 = p1 - p0, p2 - p0
    cross = np.cross(e1, e2)
    norm = np.linalg.norm(cross, axis=1)
    scale = np.linalg.norm(e1, axis=1) * np.linalg.norm(e2, axis=1)
    ok = norm > COLLINEAR_SINE * scale  # sine of the triangle's angle at p0
    normals = cross[ok] / norm[ok, None]
    ok_z = np.abs(normals[:, 2]) > VERTICAL_NZ
    normals = normals[ok_z] * np.sign(normals[ok_z, 2])[:, None]
    offsets = -np.einsum("ij,ij->i", normals, p0[ok][ok_z])
    return normals, offsets


def _required_iterations(inlier_ratio: float) -> float:
    w3 = min(max(inlier_ratio, _MIN_INLIER_RATIO), 1.0) ** 3
    if w3 >= 1.0:
        return 0.0
    return math.log(1.0 - _CONFIDENCE) / math.log1p(-w3)


def _hypotheses(
    points: np.ndarray,
    draw: Callable[[int, int], np.ndarray],
    threshold_mm: float | None,
    max_iterations: int,
) -> tuple[np.ndarray, np.ndarray, int]:
    """Draw and keep hypothesis planes until the adaptive count is reached (vectorised per batch)."""
    n = len(points)
    if math.comb(n, 3) <= _EXHAUSTIVE_MAX:
        triples = np.array(list(itertools.combinations(range(n), 3)), dtype=np.intp)
        normals, offsets = _planes_from_triples(points, triples)
        return normals, offsets, len(triples)

    h = _lqs_order(n)
    t_batch = -1.0 if threshold_mm is None else float(threshold_mm)
    lqs_factor = float(_lqs_scale(1.0, n)) if threshold_mm is None else 0.0  # 10 us of NormalDist
    all_normals, all_offsets = [], []
    drawn = 0
    best_key = math.inf
    best_ratio = 0.0
    while drawn < max_iterations:
        count = min(_BATCH, max_iterations - drawn)
        triples = draw(drawn, count)  # those with a repeated point are skipped
        drawn += count
        # One compiled pass per batch: planes, their scores, the best one's inlier ratio.
        normals, offsets, key, ratio = score_batch(
            points, triples, t_batch, lqs_factor, h, _THRESHOLD_SIGMAS, _MIN_SCALE_MM
        )
        if len(normals):
            all_normals.append(normals)
            all_offsets.append(offsets)
            if key < best_key:  # LQS (scale-free) without a threshold, else the MSAC cost
                best_key = key
                best_ratio = ratio
        if drawn >= max(_MIN_ITERATIONS, _required_iterations(best_ratio)):
            break
    if not all_normals:
        return np.empty((0, 3)), np.empty(0), drawn
    return np.concatenate(all_normals), np.concatenate(all_offsets), drawn


def _threshold_from_lqs(points: np.ndarray, residuals: np.ndarray) -> float:
    """Preliminary inlier threshold (mm): 2.5 x the LQS scale of the best LQS hypothesis, refitted.

    A 3-point plane through noisy markers a few mm apart is tilted by the noise, so its order statistics
    overstate the scale several-fold on small patches; the best LQS hypothesis is therefore first refitted
    (least squares) to its ``h`` closest points, and the scale taken from the refitted plane's residuals.
    """
    n = residuals.shape[1]
    h = _lqs_order(n)
    abs_r = np.abs(residuals)
    key = np.partition(abs_r, h - 1, axis=1)[:, h - 1]
    best = abs_r[int(np.argmin(key))]
    closest = np.zeros(n, dtype=bool)
    closest[np.argsort(best, kind="stable")[:h]] = True
    plane = _lsq_plane(np.ascontiguousarray(points), closest)
    if plane is not None:
        best = np.abs(points @ plane[0] + plane[1])
    s0 = float(_lqs_scale(float(np.partition(best, h - 1)[h - 1]), n))
    return _THRESHOLD_SIGMAS * max(s0, _MIN_SCALE_MM)


def _threshold_from_refined(residuals: np.ndarray, t: float, one_sided: bool) -> float:
    """Inlier threshold (mm) from a refined plane's residuals: a Student-t factor (about 2.5) times the
    MAD scale of the residuals within ``2 t``, or within the median ``|r|`` if that is wider.

    The window drops the gross outliers, yet holds most inliers even when ``t`` is too tight, so ``t``
    recovers from a bad start in a few rounds (widening it to half the points stops a tight subset, made
    self-consistent by the refit, from holding ``t`` down); a wider window lets the lifted-off markers
    just below the plane inflate the scale, which then admits more of them. With ``one_sided``, only the
    residuals above the plane count (when there are at least 8): lifted-off markers lie below it, while
    the noise is symmetric.
    """
    abs_r = np.abs(residuals)
    half = np.partition(abs_r, (len(abs_r) - 1) // 2)[(len(abs_r) - 1) // 2]  # the inliers are >= half
    window = abs_r <= max(_SCALE_WINDOW * t, half)
    if one_sided and np.count_nonzero(window & (residuals > 0)) >= _MIN_ABOVE_FOR_SCALE:
        window &= residuals > 0
    r = np.abs(residuals[window])
    m = len(r)
    if m <= 3:
        return t
    s = _MAD_TO_SIGMA * float(np.median(r)) * math.sqrt(m / (m - 3))  # 3 fitted parameters
    return _student_factor(m - 3) * max(s, _MIN_SCALE_MM)


def _student_factor(dof: int) -> float:
    """The threshold in units of an estimated scale with ``dof`` degrees of freedom: the Student-t quantile
    of the two-sided coverage that 2.5 sigma has for a known scale (98.8 %): 2.5 for many points, 3.9
    for 6 degrees of freedom, 9.3 for 2 (a scale from a handful of points must not reject points)."""
    return _student_quantile(max(dof, 1))


@lru_cache(maxsize=256)
def _student_quantile(dof: int) -> float:
    # scipy.stats is imported here, on the first fit, not at module level: it is slow to import and
    # every command's start-up would pay for it.
    from scipy.stats import t as student_t

    return float(student_t.ppf(_COVERAGE_QUANTILE, dof))


def _lsq_plane(points: np.ndarray, mask: np.ndarray) -> tuple[np.ndarray, float] | None:
    """Least-squares plane (unit normal, offset) of the ``mask``-ed ``(M, 3)`` points, ``None`` for a
    line, a point or a vertical plane (:func:`softjig._geometry_kernels.plane_fit`)."""
    centroid, singular, normal, _ = plane_fit(points, mask)
    if singular[0] <= 0 or singular[1] <= DEGENERATE_PLANE_RATIO * singular[0] or normal[2] == 0:
        return None
    return normal, -float(normal @ centroid)


def _refine(points: np.ndarray, mask: np.ndarray, t: float) -> tuple[np.ndarray, np.ndarray] | None:
    """Alternate least-squares refit and inlier re-selection until stable; ``(mask, residuals)``, or
    ``None`` if the set falls onto a line or below 3 points."""
    refined, mask, residuals = refine(points, mask, float(t), _MAX_REFINE_ROUNDS)
    return (mask, residuals) if refined else None


def _settle_scale(
    points: np.ndarray, refined: tuple[np.ndarray, np.ndarray], t: float, one_sided: bool
) -> tuple[tuple[np.ndarray, np.ndarray], float] | None:
    """Alternate the scale re-estimation and the refinement of one candidate until its threshold settles
    (changes by less than :data:`_SETTLED_THRESHOLD_CHANGE`)."""
    for _ in range(_MAX_SCALE_ROUNDS):
        t_new = _threshold_from_refined(refined[1], t, one_sided)
        again = _refine(points, refined[0], t_new)
        if again is None:
            return None
        refined, t_old, t = again, t, t_new
        if abs(t - t_old) <= _SETTLED_THRESHOLD_CHANGE * t_old:
            break
    return refined, t


def _best_candidate(
    points: np.ndarray, normals: np.ndarray, offsets: np.ndarray, t: float, one_sided: bool
) -> tuple[np.ndarray, np.ndarray] | None:
    """The ``(mask, residuals)`` of the best refined candidate (the module's Method, steps 4 and 6), or
    ``None`` if none refines.

    The candidates are the inlier sets (``|r| <= t``) of the lowest-MSAC-cost hypotheses, among the
    :data:`_CANDIDATE_POOL` cheapest those of at least 3 points, skipping sets too like one already taken
    (Jaccard index at least :data:`_SAME_SET_JACCARD`), at most :data:`_N_CANDIDATES`. Each is refined
    (:func:`_refine`), repeated results dropped; the winner has the lowest MSAC cost plus, with
    ``one_sided``, :data:`_ABOVE_PENALTY` ``t^2`` per point more than ``t`` above the plane inside the
    ``(x, y)`` hull of its inliers (it would penetrate the part). One compiled pass
    (:func:`softjig.sensing._robust_kernels.best_candidate`).
    """
    found, mask, residuals = best_candidate(
        np.ascontiguousarray(points),
        normals,
        offsets,
        float(t),
        _CANDIDATE_POOL,
        _N_CANDIDATES,
        _SAME_SET_JACCARD,
        one_sided,
        _MAX_REFINE_ROUNDS,
        _ABOVE_PENALTY,
    )
    return (mask, residuals) if found else None
