"""Compiled kernels of the simulator (:mod:`softjig.sim.render`, :mod:`softjig.sim.membrane`).

Each kernel is the per-pixel (or per-pair) loop of one step of the image model, fused so that it reads
and writes its arrays once instead of once per NumPy operation. The model itself is described where it
is used; these functions only compute it. Every float here is float32 unless said otherwise, as in the
NumPy code they replace.
"""

from __future__ import annotations

import math

import numba
import numpy as np

_ONE = np.float32(1.0)
_ZERO = np.float32(0.0)


@numba.njit(cache=True, nogil=True)
def marker_shapes(
    P: np.ndarray, axis: np.ndarray, origins: np.ndarray, rays: np.ndarray, r: float, step_px: float
) -> np.ndarray:
    """Each marker's local-affine imaging (:mod:`softjig.sim.render`, step 2), float64 ``(n, 9)``.

    Parameters
    ----------
    P, axis : (n, 3)
        Base centres (mm) and unit axes in J.
    origins, rays : (n, 5, 3)
        Oil rays (origin on the top interface, unit direction) of each marker's pixel ``p0`` and of
        ``p0 + step_px (1, 0), (-1, 0), (0, 1), (0, -1)``.
    r : float
        Marker radius (mm).
    step_px : float
        The pixel step of the central differences.

    Returns
    -------
    (n, 9)
        Columns: ``quad`` (3: ``|q|^2 / r^2 = a0 du^2 + a1 du dv + a2 dv^2``), ``lin`` (2: ``(q . axis) / r
        = l0 du + l1 dv``), ``cos_axis`` (``-d . axis``), ``radius_px`` (largest singular value of ``J B``
        times ``r``), ``scale_px_per_mm`` (``sqrt |det J B|``), ``oil_path_mm``. ``B = (e1, e2)`` is an
        orthonormal basis of the plane through ``P`` perpendicular to the ray ``d`` of ``p0``; the
        neighbours' rays meet that plane at ``q``, whose central differences give ``A = (J B)^-1``.
    """
    n = P.shape[0]
    out = np.empty((n, 9))
    inplane = np.empty((5, 2))
    for m in range(n):
        d0, d1, d2 = rays[m, 0, 0], rays[m, 0, 1], rays[m, 0, 2]
        rx, ry = (1.0, 0.0) if abs(d0) < 0.9 else (0.0, 1.0)  # e1 = d x ref, normalised; e2 = d x e1
        e10, e11, e12 = -d2 * ry, d2 * rx, d0 * ry - d1 * rx
        norm = math.sqrt(e10 * e10 + e11 * e11 + e12 * e12)
        e10, e11, e12 = e10 / norm, e11 / norm, e12 / norm
        e20, e21, e22 = d1 * e12 - d2 * e11, d2 * e10 - d0 * e12, d0 * e11 - d1 * e10
        p0, p1, p2 = P[m, 0], P[m, 1], P[m, 2]
        for k in range(1, 5):
            o0, o1, o2 = origins[m, k, 0], origins[m, k, 1], origins[m, k, 2]
            v0, v1, v2 = rays[m, k, 0], rays[m, k, 1], rays[m, k, 2]
            s = ((p0 - o0) * d0 + (p1 - o1) * d1 + (p2 - o2) * d2) / (v0 * d0 + v1 * d1 + v2 * d2)
            h0, h1, h2 = o0 + s * v0 - p0, o1 + s * v1 - p1, o2 + s * v2 - p2
            inplane[k, 0] = h0 * e10 + h1 * e11 + h2 * e12
            inplane[k, 1] = h0 * e20 + h1 * e21 + h2 * e22
        # A = d(in-plane mm) / d(du, dv): columns from the u and the v neighbours
        a00 = (inplane[1, 0] - inplane[2, 0]) / (2.0 * step_px)
        a10 = (inplane[1, 1] - inplane[2, 1]) / (2.0 * step_px)
        a01 = (inplane[3, 0] - inplane[4, 0]) / (2.0 * step_px)
        a11 = (inplane[3, 1] - inplane[4, 1]) / (2.0 * step_px)
        det_a = a00 * a11 - a01 * a10
        j00, j01, j10, j11 = a11 / det_a, -a01 / det_a, -a10 / det_a, a00 / det_a  # J B = A^-1
        r2 = r * r
        out[m, 0] = (a00 * a00 + a10 * a10) / r2  # G = A^T A / r^2
        out[m, 1] = 2.0 * (a00 * a01 + a10 * a11) / r2
        out[m, 2] = (a01 * a01 + a11 * a11) / r2
        ax0, ax1, ax2 = axis[m, 0], axis[m, 1], axis[m, 2]
        ae1 = ax0 * e10 + ax1 * e11 + ax2 * e12
        ae2 = ax0 * e20 + ax1 * e21 + ax2 * e22
        out[m, 3] = (ae1 * a00 + ae2 * a10) / r  # axis . (B A)
        out[m, 4] = (ae1 * a01 + ae2 * a11) / r
        out[m, 5] = -(d0 * ax0 + d1 * ax1 + d2 * ax2)
        s1 = j00 * j00 + j01 * j01 + j10 * j10 + j11 * j11
        s2 = math.hypot(j00 * j00 + j01 * j01 - j10 * j10 - j11 * j11, 2.0 * (j00 * j10 + j01 * j11))
        out[m, 6] = r * math.sqrt(0.5 * (s1 + s2))
        out[m, 7] = math.sqrt(abs(j00 * j11 - j01 * j10))
        out[m, 8] = max(p2, 0.0) / max(d2, 1e-9)
    return out


_NEWTON_MAX_ITER = 100  # as softjig.optics.refracted_ray_directions
_NEWTON_TOLERANCE = 4.0 * np.finfo(np.float64).eps


@numba.njit(cache=True, nogil=True)
def _layered_tangents(
    rho: np.ndarray, pz: np.ndarray, cz: float, z_if: np.ndarray, n_reg: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """``t = tan(theta_m)`` in the lowest-index region each path crosses, and that index ``n_min``, for
    points at horizontal distance ``rho`` and height ``pz`` above the first interface (the Newton
    iteration of :func:`softjig.optics.refracted_ray_directions`, all points until every one converged)."""
    m, regions = rho.shape[0], n_reg.shape[0]
    h = np.zeros((m, regions))
    n_min = np.full(m, np.inf)
    for j in range(m):
        for i in range(regions):
            lo = cz if i == 0 else z_if[i - 1]
            hi = z_if[i] if i < regions - 1 else np.inf
            h[j, i] = max(min(pz[j], hi) - lo, 0.0)
            if h[j, i] > 0.0:
                n_min[j] = min(n_min[j], n_reg[i])
    t = np.zeros(m)
    for _ in range(_NEWTON_MAX_ITER):
        converged = True
        for j in range(m):
            g, dg = 0.0, 0.0
            for i in range(regions):
                a = n_reg[i] * n_reg[i]
                b = a - n_min[j] * n_min[j] if h[j, i] > 0.0 else 0.0
                w = h[j, i] * n_min[j]
                inv_sq = 1.0 / math.sqrt(a + b * (t[j] * t[j]))
                g += w * inv_sq
                dg += w * a * (inv_sq * inv_sq * inv_sq)
            t_new = max(t[j] - (t[j] * g - rho[j]) / dg, 0.0)
            converged &= abs(t_new - t[j]) <= _NEWTON_TOLERANCE * t_new
            t[j] = t_new
        if converged:
            break
    return t, n_min


@numba.njit(cache=True, nogil=True)
def project_refracted(
    P: np.ndarray, T: np.ndarray, K: np.ndarray, dist: np.ndarray, z_if: np.ndarray, n_reg: np.ndarray
) -> np.ndarray:
    """Pixels ``(u, v)`` of the points ``P`` (J, mm, ``(n, 3)``) through the flat layers (interfaces
    ``z_if``, indices ``n_reg`` from the camera's region up), in the camera of pose ``T`` (4x4, J from
    camera), intrinsics ``K`` and OpenCV distortion ``dist`` (5): the model of
    :func:`softjig.optics.project_points`, compiled (0.7 ms of its 0.9 ms per camera and frame were NumPy's
    per-call work on 400 markers). A point behind the camera gets NaN."""
    n = P.shape[0]
    cx, cy, cz = T[0, 3], T[1, 3], T[2, 3]
    rel = np.empty((n, 3))
    for j in range(n):
        rel[j, 0], rel[j, 1], rel[j, 2] = P[j, 0] - cx, P[j, 1] - cy, P[j, 2] - cz
    through = np.flatnonzero(P[:, 2] > z_if[0])
    rho = np.empty(through.shape[0])
    for k in range(through.shape[0]):
        rho[k] = math.hypot(rel[through[k], 0], rel[through[k], 1])
    t, n_min = _layered_tangents(rho, P[through, 2], cz, z_if, n_reg)
    d = rel.copy()  # the straight line for points in the camera's region
    a0 = n_reg[0] * n_reg[0]
    for k in range(through.shape[0]):
        j = through[k]
        tan0 = n_min[k] * t[k] / math.sqrt(a0 + (a0 - n_min[k] * n_min[k]) * t[k] * t[k])
        scale = tan0 / rho[k] if rho[k] > 0.0 else 0.0
        d[j, 0], d[j, 1], d[j, 2] = rel[j, 0] * scale, rel[j, 1] * scale, 1.0
    k1, k2, p1, p2, k3 = dist[0], dist[1], dist[2], dist[3], dist[4]
    out = np.empty((n, 2))
    for j in range(n):
        xc = d[j, 0] * T[0, 0] + d[j, 1] * T[1, 0] + d[j, 2] * T[2, 0]  # R^T d (scale-free)
        yc = d[j, 0] * T[0, 1] + d[j, 1] * T[1, 1] + d[j, 2] * T[2, 1]
        zc = d[j, 0] * T[0, 2] + d[j, 1] * T[1, 2] + d[j, 2] * T[2, 2]
        if not zc > 1e-12 * math.sqrt(d[j, 0] ** 2 + d[j, 1] ** 2 + d[j, 2] ** 2):
            out[j, 0] = out[j, 1] = np.nan
            continue
        x, y = xc / zc, yc / zc
        r2 = x * x + y * y
        radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        xd = x * radial + p1 * 2.0 * x * y + p2 * (r2 + 2.0 * x * x)
        yd = y * radial + p1 * (r2 + 2.0 * y * y) + p2 * 2.0 * x * y
        out[j, 0] = K[0, 0] * xd + K[0, 1] * yd + K[0, 2]
        out[j, 1] = K[1, 1] * yd + K[1, 2]
    return out


@numba.njit(cache=True, nogil=True)
def rays_in_top_region(
    q: np.ndarray,
    R: np.ndarray,
    centre: np.ndarray,
    heights: np.ndarray,
    ratio: np.ndarray,
    ratio_sq: np.ndarray,
    layer_advance: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, int]:
    """Refracted rays in the top region of one camera's ideal normalised points ``q`` (``(m, 2)``): the
    closed form of :func:`softjig.optics.rays_in_top_region_normalized`, compiled (its NumPy operations
    took 0.25 of 0.3 ms a camera and frame on 1900 rays).

    ``R`` (3x3) and ``centre`` (3) are the camera's orientation and centre in J; ``heights`` = ``(h_0,
    z_top)``, the air below the first interface (mm, > 0) and the top interface's height; ``ratio``,
    ``ratio_sq`` and ``layer_advance`` are :func:`softjig.optics.layer_constants`'s. Returns ``origins,
    directions`` (``(m, 3)``, J) and a status: 0, or 1 if a ray does not go up, 2 if a ray is totally
    reflected (the arrays are then incomplete).
    """
    m = q.shape[0]
    origins = np.empty((m, 3))
    directions = np.empty((m, 3))
    regions = ratio_sq.shape[0]
    h0, z_top = heights[0], heights[1]
    for j in range(m):
        x, y = q[j, 0], q[j, 1]
        r0 = x * R[0, 0] + y * R[0, 1] + R[0, 2]
        r1 = x * R[1, 0] + y * R[1, 1] + R[1, 2]
        r2 = x * R[2, 0] + y * R[2, 1] + R[2, 2]
        norm = math.sqrt(r0 * r0 + r1 * r1 + r2 * r2)
        r0, r1, r2 = r0 / norm, r1 / norm, r2 / norm
        if not r2 > 0.0:
            return origins, directions, 1
        sin2 = r0 * r0 + r1 * r1
        advance = h0 / r2
        cos_top = 1.0
        for k in range(regions):
            cos2 = 1.0 - ratio_sq[k] * sin2
            if not cos2 > 0.0:
                return origins, directions, 2
            cos_top = math.sqrt(cos2)
            if k < layer_advance.shape[0]:
                advance += layer_advance[k] / cos_top
        origins[j, 0] = centre[0] + r0 * advance
        origins[j, 1] = centre[1] + r1 * advance
        origins[j, 2] = z_top
        directions[j, 0] = r0 * ratio[-1]
        directions[j, 1] = r1 * ratio[-1]
        directions[j, 2] = cos_top
    return origins, directions, 0


@numba.njit(cache=True, nogil=True)
def cast_marker_patches(
    du: np.ndarray,
    dv: np.ndarray,
    quad: np.ndarray,
    lin: np.ndarray,
    size: int,
    ss: int,
    disc: bool,
    out: np.ndarray,
) -> None:
    """Per-pixel average of the shading factor over the ``ss x ss`` sub-samples of each patch pixel,
    written into ``out`` ``(n, size, size)`` float32 (rows ``dv``, columns ``du``).

    Parameters
    ----------
    du, dv : (n, size * ss) float32
        Offset of each sub-sample column / row from the marker's projected centre (px).
    quad : (n, 3) float32
        ``|q|^2 / r^2 = a0 du^2 + a1 du dv + a2 dv^2``.
    lin : (n, 2) float32
        ``(l0, l1)``: the axis term divided by ``cos_axis``, ``w = -(l0 du + l1 dv)``.
    size, ss : int
        Patch side (px) and sub-samples per pixel side.
    disc : bool
        Flat disc (hit iff ``cos(beta) > |w|``, value 1) instead of the hemisphere (hit iff
        ``cos(beta) > max(w, 0)``, value ``1 + cos(beta)``).

    Only the pixels of a row that hold a sub-sample with ``cos(beta)^2 > 0`` are evaluated (the roots of
    that quadratic in ``du``, found in float64 and widened by a sub-sample, bound them).
    """
    n = du.shape[0]
    q = size * ss
    flat = out.reshape(-1)
    for k in range(flat.shape[0]):
        flat[k] = _ZERO
    row = np.empty(q, dtype=np.float32)
    inv = np.float32(1.0 / (ss * ss))
    for m in range(n):
        a0, a1, a2 = quad[m, 0], quad[m, 1], quad[m, 2]
        l0, l1 = lin[m, 0], lin[m, 1]
        du0 = float(du[m, 0])
        step = float(du[m, 1] - du[m, 0]) if q > 1 else 1.0
        for py in range(size):
            # The pixel columns [p0, p1) holding every sub-sample of this pixel row where cos(beta)^2 =
            # c0 + c1 du + c2 du^2 > 0 (between its roots, widened by a sub-sample): nothing is hit outside.
            lo, hi = np.inf, -np.inf
            for r in range(py * ss, (py + 1) * ss):
                y = float(dv[m, r])
                c0, c1, c2 = 1.0 - float(a2) * y * y, -float(a1) * y, -float(a0)
                if c2 >= 0.0:
                    lo, hi = -np.inf, np.inf
                    break
                disc2 = c1 * c1 - 4.0 * c2 * c0
                if disc2 > 0.0:
                    root = math.sqrt(disc2)
                    lo = min(lo, (-c1 + root) / (2.0 * c2))
                    hi = max(hi, (-c1 - root) / (2.0 * c2))
            if lo > hi:
                continue
            p0, p1 = 0, size
            if math.isfinite(lo):
                p0 = min(max((math.floor((lo - du0) / step) - 1) // ss, 0), size)
                p1 = max(min((math.ceil((hi - du0) / step) + 1) // ss + 1, size), p0)
            if p0 >= p1:
                continue
            xs = du[m, p0 * ss : p1 * ss]  # 1-D views indexed from 0 and a branch-free body: vectorises
            vals = row[: xs.shape[0]]  # the pixel row's sub-sample columns, summed over its sub-rows
            for k in range(xs.shape[0]):
                vals[k] = _ZERO
            for r in range(py * ss, (py + 1) * ss):
                y = dv[m, r]
                c0 = _ONE - a2 * y * y
                c1 = -a1 * y
                c2 = -a0
                w0 = -l1 * y
                if disc:
                    for k in range(xs.shape[0]):
                        x = xs[k]
                        c = math.sqrt(max(c0 + c1 * x + c2 * (x * x), _ZERO))
                        vals[k] += _ONE if c > abs(w0 - l0 * x) else _ZERO
                else:
                    for k in range(xs.shape[0]):
                        x = xs[k]
                        c = math.sqrt(max(c0 + c1 * x + c2 * (x * x), _ZERO))
                        vals[k] += (_ONE + c) if c > max(w0 - l0 * x, _ZERO) else _ZERO
            dst = out[m, py, p0:p1]
            for p in range(p1 - p0):
                acc = _ZERO
                for j in range(ss):
                    acc += vals[p * ss + j]
                dst[p] = acc
    for k in range(flat.shape[0]):
        flat[k] *= inv


@numba.njit(cache=True, nogil=True, inline="always")
def _sensor_row(
    src: np.ndarray,
    hi: np.ndarray,
    lo: np.ndarray,
    z: np.ndarray,
    dst: np.ndarray,
    tables: tuple[np.ndarray, np.ndarray],
    noise: tuple[np.float32, np.float32, np.float32, np.float32],
    half_even: bool,
) -> None:
    """One image row through the sensor into ``dst``: the deviates ``offset[hi] + slope[hi] lo``
    (``tables``), then ``max(max(I, 0) + sqrt(max(I, 0) / full_well + read^2) z, 0)`` times the scale,
    rounded half to even (``half_even``) or half up and saturated at ``top``; ``noise = (1 / full_well,
    read^2, scale, top)``."""
    offset, slope = tables
    inv_full_well, read_var, scale, top = noise
    for x in range(src.shape[0]):  # the gather, apart: the arithmetic below vectorises
        k = hi[x]
        z[x] = offset[k] + slope[k] * np.float32(lo[x])
    if half_even:
        for x in range(src.shape[0]):
            v = max(src[x], _ZERO)
            v = max(v + math.sqrt(v * inv_full_well + read_var) * z[x], _ZERO) * scale
            dst[x] = min(np.rint(v), top)
    else:
        half = np.float32(0.5)
        for x in range(src.shape[0]):
            v = max(src[x], _ZERO)
            v = max(v + math.sqrt(v * inv_full_well + read_var) * z[x], _ZERO)
            dst[x] = min(v * scale + half, top)


@numba.njit(cache=True, nogil=True)
def compose_sensor(
    base: np.ndarray,
    gain: np.ndarray,
    box: tuple[np.ndarray, np.ndarray, int, int],
    patches: np.ndarray,
    origin: np.ndarray,
    order: np.ndarray,
    deviates: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray],
    noise: tuple[np.float32, np.float32, np.float32, np.float32],
    band_rows: int,
    out: np.ndarray,
) -> None:
    """A camera's image from its radiance (:mod:`softjig.sim.render`, steps 3 and 7), ``band_rows`` rows at a
    time, into ``out`` (``uint8``: rounded half to even; ``uint16``: half up).

    The radiance is ``base`` (inside ``box = (radiance, gain, x0, y0)``: its radiance) plus each ``(P, P)``
    patch (top-left pixel ``origin``, ``(x, y)`` px, clipped to the image) times ``gain`` (inside the box:
    its gain); ``order`` lists the patches by top row (a stable sort). Each band of rows is composed in a
    buffer that stays in cache, then goes through the sensor (:func:`_sensor_row`, ``deviates = (hi, lo,
    offset, slope)``, ``noise`` as there): the radiance image is never written whole.
    """
    h, w = base.shape
    n, p = patches.shape[0], patches.shape[1]
    box_radiance, box_gain, box_x0, box_y0 = box
    hi, lo, offset, slope = deviates
    bh, bw = box_radiance.shape
    buf = np.empty((band_rows, w), dtype=np.float32)
    band_gain = np.empty((band_rows, w), dtype=np.float32)  # the gain of a band that meets the box
    z = np.empty(w, dtype=np.float32)
    first = 0
    for y0 in range(0, h, band_rows):
        y1 = min(y0 + band_rows, h)
        boxed = bw > 0 and box_y0 < y1 and y0 < box_y0 + bh
        for y in range(y0, y1):
            buf[y - y0] = base[y]
            if boxed:
                band_gain[y - y0] = gain[y]
            if 0 <= y - box_y0 < bh:
                buf[y - y0, box_x0 : box_x0 + bw] = box_radiance[y - box_y0]
                band_gain[y - y0, box_x0 : box_x0 + bw] = box_gain[y - box_y0]
        while first < n and origin[order[first], 1] + p <= y0:
            first += 1
        for k in range(first, n):
            m = order[k]
            ox, oy = origin[m, 0], origin[m, 1]
            if oy >= y1:
                break
            j0, j1 = max(0, -ox), min(p, w - ox)
            if j0 >= j1:  # wholly left or right of the image (and a negative slice stop would wrap round)
                continue
            for i in range(max(0, y0 - oy), min(p, y1 - oy)):
                y = oy + i
                row_gain = band_gain[y - y0] if boxed else gain[y]
                # 1-D slices indexed from 0 in one loop: it vectorises (a helper splitting the row at the
                # box's columns ran at half the speed: 2.3 against 1.1 ms a camera, 330 patches of 41 x 41 px)
                dst, g = buf[y - y0, ox + j0 : ox + j1], row_gain[ox + j0 : ox + j1]
                src = patches[m, i, j0:j1]
                for j in range(dst.shape[0]):
                    dst[j] += src[j] * g[j]
        for y in range(y0, y1):
            _sensor_row(buf[y - y0], hi[y], lo[y], z, out[y], (offset, slope), noise, out.itemsize == 1)


@numba.njit(cache=True, nogil=True)
def finish_radiance(
    texture: np.ndarray,
    background: np.float32,
    maps: tuple[np.ndarray, np.ndarray, np.ndarray],
    fiducials: bool,
    origin: tuple[int, int],
    radiance: np.ndarray,
    gain: np.ndarray,
) -> None:
    """The bare membrane's radiance and the markers' gain over a region (top-left pixel ``origin = (y0,
    x0)``) from its bead speckle ``texture`` ``s`` (:mod:`softjig.sim.render`, steps 4-6), in one pass: with
    the fiducials' transmission ``c`` and level ``l`` and the illumination ``F`` (``maps``, whole-image),
    ``radiance = ((1 + s) b c + l) F`` and ``gain = (1 + s) c F``, in that order of float32 operations.
    Without ``fiducials`` (none over the region: ``c = 1``, ``l = 0``, which leave every value as it is)
    the first two maps are not read."""
    transmission, level, illumination = maps
    y0, x0 = origin
    for i in range(texture.shape[0]):
        src, rad, gn, f = texture[i], radiance[i], gain[i], illumination[y0 + i, x0:]
        if fiducials:
            c, lv = transmission[y0 + i, x0:], level[y0 + i, x0:]
            for j in range(texture.shape[1]):
                factor = src[j] + _ONE
                rad[j] = (factor * background * c[j] + lv[j]) * f[j]
                gn[j] = factor * c[j] * f[j]
        else:
            for j in range(texture.shape[1]):
                factor = src[j] + _ONE
                rad[j] = factor * background * f[j]
                gn[j] = factor * f[j]


@numba.njit(cache=True, nogil=True)
def blur_matrices(kernel: np.ndarray, size: int, g: np.ndarray, g_t: np.ndarray) -> None:
    """Each marker's blur matrix and its transpose from its 1-D kernel, in place (:mod:`softjig.sim.render`,
    step 3).

    ``kernel`` is ``(n, 2 pad + 1)``; ``g[m]`` (``(size + 2 pad, size)``) has
    ``g[m, i, j] = kernel[m, i - j]`` where ``0 <= i - j <= 2 pad`` and 0 elsewhere, and ``g_t[m]`` is its
    transpose (contiguous, for the second product).
    """
    n, width = kernel.shape
    g[:] = _ZERO
    g_t[:] = _ZERO
    for m in range(n):
        for j in range(size):
            row = g_t[m, j, j : j + width]
            for k in range(width):
                row[k] = kernel[m, k]
                g[m, j + k, j] = kernel[m, k]


_CHUNK = 8  # contacts per chunk of log_envelope's maxima (one AVX2 register; measured best of 4, 8, 16)
_ENVELOPE_CANDIDATE_WINDOW = np.float32(1e-3)  # >> the float32 error of sqrt(dx^2 + dy^2) against hypot


@numba.njit(cache=True, nogil=True)
def log_envelope(
    qx: np.ndarray,
    qy: np.ndarray,
    cx: np.ndarray,
    cy: np.ndarray,
    log_depth: np.ndarray,
    inv_decay: np.ndarray,
) -> np.ndarray:
    """``max_c (log_depth[c] - hypot(q - c) inv_decay[c])`` for each point ``q``, float32 ``(len(qx),)``.

    A first pass finds the maximum with ``sqrt(dx^2 + dy^2)`` (which vectorises), as the maxima of chunks of
    :data:`_CHUNK` contacts (independent of one another, so they proceed side by side; a single running
    maximum is a chain of dependent comparisons); the contacts within a window of it, looked for only in
    the chunks whose maximum reaches the window (a branch per contact over all of them took 40 % of the
    time), are then evaluated with ``hypot``, so the result is the exact maximum of the ``hypot`` values
    (those of the NumPy expression).
    """
    n = qx.shape[0]
    nc = cx.shape[0]
    out = np.empty(n, dtype=np.float32)
    chunks = (nc + _CHUNK - 1) // _CHUNK
    approx = np.full(chunks * _CHUNK, -np.inf, dtype=np.float32)  # the last chunk padded with -inf
    chunk_max = np.empty(chunks, dtype=np.float32)
    for i in range(n):
        x, y = qx[i], qy[i]
        for c in range(nc):  # no reduction in this loop: it vectorises
            dx = x - cx[c]
            dy = y - cy[c]
            approx[c] = log_depth[c] - math.sqrt(dx * dx + dy * dy) * inv_decay[c]
        best = np.float32(-np.inf)
        for j in range(chunks):
            m = approx[j * _CHUNK]
            for k in range(1, _CHUNK):
                m = max(m, approx[j * _CHUNK + k])
            chunk_max[j] = m
            best = max(best, m)
        exact = np.float32(-np.inf)
        floor = best - _ENVELOPE_CANDIDATE_WINDOW
        for j in range(chunks):
            if chunk_max[j] >= floor:
                for c in range(j * _CHUNK, min((j + 1) * _CHUNK, nc)):
                    if approx[c] >= floor:
                        v = log_depth[c] - np.hypot(x - cx[c], y - cy[c]) * inv_decay[c]
                        exact = max(exact, v)
        out[i] = exact
    return out
