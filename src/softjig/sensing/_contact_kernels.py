"""Compiled kernels of :mod:`softjig.sensing.contact`: neighbour sweeps over square cells, the contact's
flood fill and violation counts, and the per-marker plane arithmetic (each one pass over the markers).

Numba is confined to this module (issue 16); ``benchmarks/bench_kernels.py`` measures what each kernel
gains a pair over its NumPy counterpart.

Numba's cache checks only the file of the kernel it caches (its modification time and size), not what
it uses from elsewhere: the kernels of :mod:`softjig._geometry_kernels` are compiled into it and the
constants of :mod:`softjig.geometry` frozen into it, so a change to either file needs this file touched
too, or the cache keeps the old code (the hand-written 3x3 solvers of ``plane_fit``, issue 14, came with
this paragraph).
"""

from __future__ import annotations

import numba
import numpy as np

from softjig._geometry_kernels import inside_hull, median_in_place, stable_argsort
from softjig.geometry import HULL_TOLERANCE_MM

#: The largest finite float: ``np.nan_to_num``'s stand-in for ``+inf``.
LARGEST = float(np.finfo(float).max)
#: The fewest finite markers, and the fewest with neighbours, for the neighbour noise of ``indentation``.
MIN_NOISE_MARKERS = 10
#: The terms of the quadratic surface fitted to a marker's neighbours for the neighbour noise.
QUADRATIC_TERMS = 6
#: The fewest neighbours a marker needs for its residual to count: the quadratic's terms and as many
#: again, so that one outlying neighbour cannot be fitted exactly.
MIN_QUADRATIC_NEIGHBOURS = 2 * QUADRATIC_TERMS
#: The largest variance of the quadratic's prediction, in units of one marker's, for the residual to
#: count: a marker at the grid's edge, whose neighbours lie to one side, is extrapolated to, not fitted.
MAX_PREDICTION_VARIANCE = 1.0
#: The median absolute deviation of a Gaussian times this is its standard deviation.
MAD_TO_SIGMA = 1.4826
#: The smallest noise reported (mm): a perfect simulation's zero noise would make every threshold zero.
NOISE_FLOOR_MM = 1e-6
#: The zero of the indentations: the median of the markers within this many noise sigmas of it ...
AT_REST_SIGMAS = 2.5
#: (when at least this many markers lie there) ...
MIN_AT_REST = 3
#: ... iterated at most this many times, until it moves by less than ...
ZERO_ROUNDS = 5
#: ... this many sigmas.
ZERO_TOLERANCE_SIGMAS = 1e-3
#: A contact marker with this many contact markers within 1.5 pitches is in the contact's core.
CORE_NEIGHBOURS = 4
#: A polygon of less area (mm^2) has no centroid by the shoelace formula: its vertices' mean is taken.
DEGENERATE_AREA_MM2 = 1e-12
#: ``noise`` returned by :func:`indentation` when the neighbour noise cannot be measured.
NO_NOISE = -1.0


@numba.njit  # no cache of its own: compiled into its callers'
def x_window(xs: np.ndarray, x: float, radius: float) -> tuple[int, int]:
    """The slice of the ascending ``xs`` within ``radius`` (and a hair) of ``x``."""
    slack = radius * (1.0 + 1e-9)
    return np.searchsorted(xs, x - slack), np.searchsorted(xs, x + slack, side="right")


@numba.njit  # no cache of its own: compiled into its callers'
def grid_cells(xy: np.ndarray, radius: float):
    """Bin (N, 2) points into square cells of side ``radius`` (so each point's neighbours closer than
    ``radius`` lie in its own and the 8 adjacent cells): each point's cell ``(cx, cy)``, the grid's size
    ``(nx, ny)``, and the points of cell ``c = cx * ny + cy`` as ``members[start[c]:start[c + 1]]``."""
    n = xy.shape[0]
    x0, y0 = xy[:, 0].min(), xy[:, 1].min()
    nx = int((xy[:, 0].max() - x0) / radius) + 1
    ny = int((xy[:, 1].max() - y0) / radius) + 1
    cx = np.empty(n, dtype=np.int64)
    cy = np.empty(n, dtype=np.int64)
    start = np.zeros(nx * ny + 1, dtype=np.int64)
    for i in range(n):
        cx[i] = min(int((xy[i, 0] - x0) / radius), nx - 1)
        cy[i] = min(int((xy[i, 1] - y0) / radius), ny - 1)
        start[cx[i] * ny + cy[i] + 1] += 1
    for c in range(nx * ny):
        start[c + 1] += start[c]
    fill = start[:-1].copy()
    members = np.empty(n, dtype=np.int64)
    for i in range(n):
        c = cx[i] * ny + cy[i]
        members[fill[c]] = i
        fill[c] += 1
    return cx, cy, nx, ny, start, members


@numba.njit  # no cache of its own: compiled into its callers'
def quadratic_residuals(xy: np.ndarray, raw: np.ndarray, radius: float) -> tuple[np.ndarray, int]:
    """For each point with enough others closer than ``radius`` (:data:`MIN_QUADRATIC_NEIGHBOURS`, around
    it well enough that the fit's prediction is no noisier than the point, :data:`MAX_PREDICTION_VARIANCE`):
    its value minus a quadratic surface least-squares fitted to theirs, evaluated at the point, over
    ``sqrt(1 + v)`` (``v``: the prediction's variance in units of one point's); the first ``count`` rows,
    in point order. ``raw`` is ``(m, k)``: ``k`` fields on the same points share the fits' geometry.

    A quadratic follows the drape's curvature, which the mean of the nearest neighbours does not (its
    residual carries ``pitch^2 / 4`` times the field's Laplacian, as large as the noise on a coarse grid).
    The points are binned into square cells of side ``radius``, so each one's neighbours lie in its own
    and the 8 adjacent cells.
    """
    n, k = raw.shape
    cx, cy, nx, ny, start, members = grid_cells(xy, radius)
    r2 = radius * radius
    residual = np.empty((n, k))
    count = 0
    normal = np.empty((QUADRATIC_TERMS, QUADRATIC_TERMS))
    rhs = np.empty((k, QUADRATIC_TERMS))
    unit = np.empty(QUADRATIC_TERMS)
    inverse = 1.0 / radius
    for i in range(n):
        # The normal equations A^T A, A^T z of the terms (1, u, w, u^2, uw, w^2) summed as their 15 distinct
        # moments in scalars, then solved by a 6x6 Cholesky: 3-4x faster than NumPy's matmul and solve on
        # each marker's small arrays (BLAS/LAPACK calls, copies).
        s0 = su = sw = suu = suw = sww = 0.0
        suuu = suuw = suww = swww = su4 = su3w = su2w2 = suw3 = sw4 = 0.0
        rhs[:] = 0.0
        m = 0
        for gx in range(max(cx[i] - 1, 0), min(cx[i] + 2, nx)):
            for gy in range(max(cy[i] - 1, 0), min(cy[i] + 2, ny)):
                c = gx * ny + gy
                for s in range(start[c], start[c + 1]):
                    j = members[s]
                    if j == i:
                        continue
                    dx, dy = xy[j, 0] - xy[i, 0], xy[j, 1] - xy[i, 1]
                    if dx * dx + dy * dy < r2:
                        u, w = dx * inverse, dy * inverse  # scaled to the radius: a well-conditioned fit
                        uu, uw, ww = u * u, u * w, w * w
                        s0 += 1.0
                        su += u
                        sw += w
                        suu += uu
                        suw += uw
                        sww += ww
                        suuu += uu * u
                        suuw += uu * w
                        suww += u * ww
                        swww += ww * w
                        su4 += uu * uu
                        su3w += uu * uw
                        su2w2 += uu * ww
                        suw3 += uw * ww
                        sw4 += ww * ww
                        for f in range(k):
                            z = raw[j, f]
                            rhs[f, 0] += z
                            rhs[f, 1] += u * z
                            rhs[f, 2] += w * z
                            rhs[f, 3] += uu * z
                            rhs[f, 4] += uw * z
                            rhs[f, 5] += ww * z
                        m += 1
        if m < MIN_QUADRATIC_NEIGHBOURS:
            continue
        # lower triangle, row by row: N[p, q] = sum of term_p term_q
        normal[0, 0] = s0
        normal[1, 0], normal[1, 1] = su, suu
        normal[2, 0], normal[2, 1], normal[2, 2] = sw, suw, sww
        normal[3, 0], normal[3, 1], normal[3, 2], normal[3, 3] = suu, suuu, suuw, su4
        normal[4, 0], normal[4, 1], normal[4, 2], normal[4, 3], normal[4, 4] = suw, suuw, suww, su3w, su2w2
        normal[5, 0], normal[5, 1], normal[5, 2] = sww, suww, swww
        normal[5, 3], normal[5, 4], normal[5, 5] = su2w2, suw3, sw4
        if not _cholesky_in_place(normal):
            continue
        # (A^T A)^-1 e0 and (A^T A)^-1 A^T z: the prediction's variance (its first entry, in units of one
        # point's) and the fitted coefficients (the first is the quadratic's value at the point).
        unit[:] = 0.0
        unit[0] = 1.0
        _cholesky_solve_in_place(normal, unit)
        variance = unit[0]
        if not (0.0 < variance <= MAX_PREDICTION_VARIANCE):
            continue
        scale = 1.0 / np.sqrt(1.0 + variance)
        for f in range(k):
            _cholesky_solve_in_place(normal, rhs[f])
            residual[count, f] = (raw[i, f] - rhs[f, 0]) * scale
        count += 1
    return residual, count


@numba.njit  # no cache of its own: compiled into its callers'
def _cholesky_in_place(a: np.ndarray) -> bool:
    """Overwrite the lower triangle of the symmetric ``a`` (only its lower triangle is read) with its
    Cholesky factor ``L`` (``a = L L^T``); ``False`` if ``a`` is not positive definite (the neighbours do
    not determine a quadratic: too few, or on a line)."""
    k = a.shape[0]
    for j in range(k):
        d = a[j, j]
        for t in range(j):
            d -= a[j, t] * a[j, t]
        if not d > 0.0:
            return False
        a[j, j] = np.sqrt(d)
        for r in range(j + 1, k):
            v = a[r, j]
            for t in range(j):
                v -= a[r, t] * a[j, t]
            a[r, j] = v / a[j, j]
    return True


@numba.njit  # no cache of its own: compiled into its callers'
def _cholesky_solve_in_place(factor: np.ndarray, x: np.ndarray) -> None:
    """Overwrite ``x`` (``b`` on entry) with the solution of ``L L^T x = b``, ``L`` the lower triangle of
    ``factor`` (:func:`_cholesky_in_place`)."""
    k = factor.shape[0]
    for r in range(k):  # L y = b
        for t in range(r):
            x[r] -= factor[r, t] * x[t]
        x[r] /= factor[r, r]
    for r in range(k - 1, -1, -1):  # L^T x = y
        for t in range(r + 1, k):
            x[r] -= factor[t, r] * x[t]
        x[r] /= factor[r, r]


@numba.njit  # no cache of its own: compiled into its callers'
def settle_zero(raw: np.ndarray, noise: float, rounds: int) -> float:
    """The zero of :func:`~softjig.sensing.contact.indentation` for a known noise: from the median of all
    values, the median of the values within :data:`AT_REST_SIGMAS` noise sigmas of it, iterated until it
    moves by less than :data:`ZERO_TOLERANCE_SIGMAS` sigmas (medians by
    :func:`~softjig._geometry_kernels.median_in_place`, on a copy)."""
    n = raw.shape[0]
    scratch = np.empty(n)
    for i in range(n):
        scratch[i] = raw[i]
    zero = median_in_place(scratch)
    for _ in range(rounds):
        count = 0
        for i in range(n):
            if abs(raw[i] - zero) < AT_REST_SIGMAS * noise:
                scratch[count] = raw[i]
                count += 1
        new_zero = median_in_place(scratch[:count]) if count >= MIN_AT_REST else zero
        if abs(new_zero - zero) < ZERO_TOLERANCE_SIGMAS * noise:
            break
        zero = new_zero
    return zero


@numba.njit(cache=True)
def indentation(
    points: np.ndarray, reference_z: np.ndarray, radius: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`~softjig.sensing.contact.indentation` with the neighbour noise against each of the ``k``
    columns of ``reference_z`` (``(n, k)``): ``(depth (n, k), zero (k,), noise (k,))``, or every
    ``noise =`` :data:`NO_NOISE` when fewer than :data:`MIN_NOISE_MARKERS` markers are finite (in every
    column) or have neighbours (an expected outcome: the caller then measures the noise from the markers
    at rest). The columns share the markers' neighbours and their fits' geometry."""
    n, k = reference_z.shape
    raw = np.empty((n, k))
    finite = np.empty(n, dtype=np.bool_)
    m = 0
    for i in range(n):
        finite[i] = True
        for f in range(k):
            raw[i, f] = reference_z[i, f] - points[i, 2]
            finite[i] &= np.isfinite(raw[i, f])
        m += finite[i]
    zero, noise = np.zeros(k), np.empty(k)
    for f in range(k):
        noise[f] = NO_NOISE
    if m < MIN_NOISE_MARKERS:
        return raw, zero, noise
    xy = np.empty((m, 2))
    raw_finite = np.empty((m, k))
    q = 0
    for i in range(n):
        if finite[i]:
            xy[q, 0], xy[q, 1] = points[i, 0], points[i, 1]
            for f in range(k):
                raw_finite[q, f] = raw[i, f]
            q += 1
    residual, enough = quadratic_residuals(xy, raw_finite, radius)
    if enough < MIN_NOISE_MARKERS:
        return raw, zero, noise
    column = np.empty(m)
    for f in range(k):
        noise[f] = max(_mad_sigma(residual, f, enough, column), NOISE_FLOOR_MM)
        for i in range(m):
            column[i] = raw_finite[i, f]
        zero[f] = settle_zero(column, noise[f], ZERO_ROUNDS)
        for i in range(n):
            raw[i, f] -= zero[f]
    return raw, zero, noise


@numba.njit(cache=True)
def neighbour_scatter(xy: np.ndarray, values: np.ndarray, radius: float) -> float:
    """The MAD-scaled sigma of ``values`` (``(m,)``) about a quadratic fitted to each point's neighbours
    within ``radius`` (:func:`quadratic_residuals`), or :data:`NO_NOISE` where fewer than
    :data:`MIN_NOISE_MARKERS` points have enough neighbours."""
    residual, enough = quadratic_residuals(xy, values.reshape(-1, 1), radius)
    if enough < MIN_NOISE_MARKERS:
        return NO_NOISE
    return _mad_sigma(residual, 0, enough, np.empty(enough))


@numba.njit  # no cache of its own: compiled into its callers'
def _mad_sigma(residual: np.ndarray, column: int, count: int, scratch: np.ndarray) -> float:
    """The MAD-scaled sigma of the first ``count`` residuals of ``column`` (``scratch``: at least ``count``
    long, overwritten)."""
    for i in range(count):
        scratch[i] = abs(residual[i, column])
    return MAD_TO_SIGMA * median_in_place(scratch[:count])


@numba.njit(cache=True)
def count_within(query: np.ndarray, points: np.ndarray, radius: float, inclusive: bool) -> np.ndarray:
    """How many of ``points`` lie within ``radius`` of each ``query`` point (``<=`` when ``inclusive``,
    else ``<``, as a k-d tree's ``query_ball_point`` and ``distance_upper_bound``)."""
    n = points.shape[0]
    xs = np.empty(n)
    for i in range(n):
        xs[i] = points[i, 0]
    order = stable_argsort(xs)
    for s in range(n):
        xs[s] = points[order[s], 0]
    r2 = radius * radius
    counts = np.zeros(query.shape[0], dtype=np.int64)
    for i in range(query.shape[0]):
        lo, hi = x_window(xs, query[i, 0], radius)
        for s in range(lo, hi):
            j = order[s]
            dx, dy = points[j, 0] - query[i, 0], points[j, 1] - query[i, 1]
            d2 = dx * dx + dy * dy
            if d2 <= r2 if inclusive else d2 < r2:
                counts[i] += 1
    return counts


@numba.njit(cache=True)
def violations(
    xy: np.ndarray,
    contact: np.ndarray,
    above: np.ndarray,
    far_above: np.ndarray,
    below: np.ndarray,
    radius: float,
    tolerated: int,
    far_tolerated: int,
) -> int:
    """How many markers contradict a contact beyond the ``tolerated`` few: those ``above`` inside the hull
    of the contact's core (its markers with at least :data:`CORE_NEIGHBOURS` other contact markers within
    ``radius``, 1.5 pitches; all of them if fewer than 3 are) plus those ``below`` inside the contact's
    hull, less ``tolerated``; but at least those of the first that are also ``far_above``, less
    ``far_tolerated`` (a marker is never both above and below; none for a contact of fewer than 3
    markers)."""
    n = xy.shape[0]
    index = np.empty(n, dtype=np.int64)  # the contact's markers, in order
    m, n_upper, n_lower = 0, 0, 0
    for i in range(n):
        if contact[i]:
            index[m] = i
            m += 1
        n_upper += above[i]
        n_lower += below[i]
    members = _rows(xy, index, m)
    count, far = 0, 0
    if n_upper and m >= 3:
        counts = count_within(members, members, radius, True)
        core = np.empty(m, dtype=np.int64)
        c = 0
        for j in range(m):
            if counts[j] - 1 >= CORE_NEIGHBOURS:
                core[c] = index[j]
                c += 1
        hull = _rows(xy, core, c) if c >= 3 else members
        inside = inside_hull(hull, _flagged_rows(xy, above, n_upper), HULL_TOLERANCE_MM)
        j = 0
        for i in range(n):
            if above[i]:
                if inside[j]:
                    if far_above[i]:
                        far += 1
                    else:
                        count += 1
                j += 1
    if n_lower and m >= 3:
        count += _count_inside(members, _flagged_rows(xy, below, n_lower))
    return max(0, count + far - tolerated, far - far_tolerated)


@numba.njit  # no cache of its own: compiled into its callers'
def _rows(xy: np.ndarray, index: np.ndarray, count: int) -> np.ndarray:
    """``xy[index[:count]]`` as a new ``(count, 2)`` array."""
    out = np.empty((count, 2))
    for j in range(count):
        out[j, 0], out[j, 1] = xy[index[j], 0], xy[index[j], 1]
    return out


@numba.njit  # no cache of its own: compiled into its callers'
def _flagged_rows(xy: np.ndarray, flags: np.ndarray, count: int) -> np.ndarray:
    """``xy[flags]`` (``count`` of them) as a new ``(count, 2)`` array."""
    out = np.empty((count, 2))
    j = 0
    for i in range(xy.shape[0]):
        if flags[i]:
            out[j, 0], out[j, 1] = xy[i, 0], xy[i, 1]
            j += 1
    return out


@numba.njit  # no cache of its own: compiled into its callers'
def _count_inside(hull_of: np.ndarray, query: np.ndarray) -> int:
    """How many of ``query`` lie inside the convex hull of ``hull_of`` (:func:`inside_hull`)."""
    inside = inside_hull(hull_of, query, HULL_TOLERANCE_MM)
    total = 0
    for i in range(inside.shape[0]):
        total += inside[i]
    return total


@numba.njit(cache=True)
def membrane_groups(
    xy: np.ndarray, depth: np.ndarray, radius: float, slope: float, margin: float
) -> tuple[np.ndarray, np.ndarray]:
    """The groups of points joined by steps between neighbours closer than ``radius`` whose depths differ
    by at most ``slope`` times their distance plus ``margin`` (each point's group label, ``(N,)``), and
    which points have a neighbour they do not step to (``(N,)`` booleans): the connected components of
    :func:`~softjig.sensing.contact.off_the_membrane`'s graph, by breadth-first search over square cells
    of side ``radius`` (linear in the points for a grid of markers; scipy's k-d tree pairs and sparse
    components took 0.6 ms a default pair, measured)."""
    n = xy.shape[0]
    cx, cy, nx, ny, start_of, members = grid_cells(xy, radius)
    group = np.full(n, -1, dtype=np.int64)
    cut = np.zeros(n, dtype=np.bool_)
    queue = np.empty(n, dtype=np.int64)
    r2 = radius * radius
    label = 0
    for seed in range(n):
        if group[seed] >= 0:
            continue
        group[seed] = label
        queue[0] = seed
        head, tail = 0, 1
        while head < tail:
            i = queue[head]
            head += 1
            for gx in range(max(cx[i] - 1, 0), min(cx[i] + 2, nx)):
                for gy in range(max(cy[i] - 1, 0), min(cy[i] + 2, ny)):
                    c = gx * ny + gy
                    for s in range(start_of[c], start_of[c + 1]):
                        j = members[s]
                        dx, dy = xy[j, 0] - xy[i, 0], xy[j, 1] - xy[i, 1]
                        d2 = dx * dx + dy * dy
                        if j == i or d2 > r2:
                            continue
                        change = abs(depth[i] - depth[j])
                        if change <= margin or change <= np.sqrt(d2) * slope + margin:
                            if group[j] < 0:
                                group[j] = label
                                queue[tail] = j
                                tail += 1
                        else:
                            cut[i] = True
        label += 1
    return group, cut


@numba.njit(cache=True)
def flood(xy: np.ndarray, start: np.ndarray, allowed: np.ndarray, radius: float) -> np.ndarray:
    """``start`` and every ``allowed`` point reached from it by steps shorter than ``radius``, as booleans.

    A breadth-first search over square cells of side ``radius`` (each point's neighbours lie in its own
    and the 8 adjacent cells): linear in the points for a grid of markers.
    """
    n = xy.shape[0]
    cx, cy, nx, ny, start_of, members = grid_cells(xy, radius)
    reached = start.copy()
    queue = np.empty(n, dtype=np.int64)
    head, tail = 0, 0
    for i in range(n):
        if reached[i]:
            queue[tail] = i
            tail += 1
    r2 = radius * radius
    while head < tail:
        i = queue[head]
        head += 1
        for gx in range(max(cx[i] - 1, 0), min(cx[i] + 2, nx)):
            for gy in range(max(cy[i] - 1, 0), min(cy[i] + 2, ny)):
                c = gx * ny + gy
                for s in range(start_of[c], start_of[c + 1]):
                    j = members[s]
                    if reached[j] or not allowed[j]:
                        continue
                    dx, dy = xy[j, 0] - xy[i, 0], xy[j, 1] - xy[i, 1]
                    if dx * dx + dy * dy < r2:
                        reached[j] = True
                        queue[tail] = j
                        tail += 1
    return reached


@numba.njit(cache=True)
def face_depth(points: np.ndarray, depth: np.ndarray, normal: np.ndarray, offset: float) -> np.ndarray:
    out = np.empty(points.shape[0])
    for i in range(points.shape[0]):
        height = -(offset + normal[0] * points[i, 0] + normal[1] * points[i, 1]) / normal[2]
        known = depth[i]  # as np.nan_to_num(depth, nan=-inf)
        if np.isnan(known):
            known = -np.inf
        elif np.isinf(known):
            known = LARGEST if known > 0 else -LARGEST
        out[i] = known - (height - points[i, 2])
    return out


@numba.njit(cache=True)
def footprint(hull: np.ndarray, half_pitch: float) -> tuple[float, np.ndarray, float, np.ndarray]:
    """Area and centroid (shoelace formulas), perimeter, and the vertices moved out by
    ``half_pitch`` away from the centroid, of a polygon of at least 3 vertices."""
    k = hull.shape[0]
    twice_area, cx, cy, perimeter = 0.0, 0.0, 0.0, 0.0
    for i in range(k):
        j = (i + 1) % k
        cross = hull[i, 0] * hull[j, 1] - hull[j, 0] * hull[i, 1]
        twice_area += cross
        cx += (hull[i, 0] + hull[j, 0]) * cross
        cy += (hull[i, 1] + hull[j, 1]) * cross
        dx, dy = hull[j, 0] - hull[i, 0], hull[j, 1] - hull[i, 1]
        perimeter += np.sqrt(dx * dx + dy * dy)
    area = twice_area / 2.0
    centroid = np.empty(2)
    if abs(area) < DEGENERATE_AREA_MM2:
        area = 0.0
        centroid[0], centroid[1] = hull[:, 0].mean(), hull[:, 1].mean()
    else:
        centroid[0], centroid[1] = cx / (6.0 * area), cy / (6.0 * area)
    edge = hull.copy()
    for i in range(k):
        ox, oy = hull[i, 0] - centroid[0], hull[i, 1] - centroid[1]
        norm = np.sqrt(ox * ox + oy * oy)
        if norm > 0:
            edge[i, 0] += half_pitch * (ox / norm)
            edge[i, 1] += half_pitch * (oy / norm)
    return abs(area), centroid, perimeter, edge
