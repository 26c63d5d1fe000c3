"""Compiled kernel of :mod:`softjig.sensing.refractive`: both cameras' refracted rays and their closest
approach, per marker, in one loop."""

from __future__ import annotations

import numba
import numpy as np

#: Rays whose directions' cross product has a squared norm ``1 - (a . b)^2`` below this are parallel: they
#: have no unique closest approach (their midpoint is NaN).
PARALLEL_SIN2 = 1e-12


@numba.njit(cache=True, nogil=True)
def triangulate(left_px, right_px, intrinsics, poses, z_if, ratio, points, gap):
    """Closed-form refracted rays of both cameras and their closest approach, per marker, into ``points``
    (J, mm) and ``gap`` (mm).

    Parameters
    ----------
    left_px, right_px : (M, 2) finite matched marker centres (px).
    intrinsics : (2, 4) each camera's ``(fx, fy, cx, cy)`` (px).
    poses : (2, 4, 4) each camera's ``T_J_cam``, both below the interfaces.
    z_if : (R - 1,) the interfaces' heights (mm); ``ratio`` (R,) ``n_0 / n_i`` per region.

    Raises
    ------
    ValueError
        If a ray does not go up or is totally reflected.

    Notes
    -----
    The same rays as :func:`softjig.optics.rays_in_top_region_normalized` and the same closest approach
    as :func:`softjig.sensing.refractive.closest_points_of_rays`, without their temporary arrays.
    """
    n_if = z_if.shape[0]
    origin = np.empty((2, 3))
    direction = np.empty((2, 3))
    for m in range(left_px.shape[0]):
        for cam in range(2):
            fx, fy, cx, cy = intrinsics[cam, 0], intrinsics[cam, 1], intrinsics[cam, 2], intrinsics[cam, 3]
            if cam == 0:
                x, y = (left_px[m, 0] - cx) / fx, (left_px[m, 1] - cy) / fy
            else:
                x, y = (right_px[m, 0] - cx) / fx, (right_px[m, 1] - cy) / fy
            T = poses[cam]
            rx = T[0, 0] * x + T[0, 1] * y + T[0, 2]
            ry = T[1, 0] * x + T[1, 1] * y + T[1, 2]
            rz = T[2, 0] * x + T[2, 1] * y + T[2, 2]
            norm = np.sqrt(rx * rx + ry * ry + rz * rz)
            rx, ry, rz = rx / norm, ry / norm, rz / norm
            if not rz > 0.0:
                raise ValueError(
                    "some rays do not go upwards (d_z <= 0 in J) and never reach the interfaces; "
                    "is the camera looking up?"
                )
            sin2 = rx * rx + ry * ry
            advance = (z_if[0] - T[2, 3]) / rz
            cos = rz
            for i in range(1, n_if + 1):  # region i, above interface i - 1
                cos2 = 1.0 - ratio[i] * ratio[i] * sin2
                if not cos2 > 0.0:
                    raise ValueError("total internal reflection for some rays going through the jig's layers")
                cos = np.sqrt(cos2)
                if i < n_if:
                    advance += (z_if[i] - z_if[i - 1]) * ratio[i] / cos
            origin[cam, 0] = T[0, 3] + rx * advance
            origin[cam, 1] = T[1, 3] + ry * advance
            origin[cam, 2] = z_if[n_if - 1]
            direction[cam, 0] = rx * ratio[n_if]
            direction[cam, 1] = ry * ratio[n_if]
            direction[cam, 2] = cos
        b, d, e = 0.0, 0.0, 0.0
        for i in range(3):
            w0 = origin[0, i] - origin[1, i]
            b += direction[0, i] * direction[1, i]
            d += direction[0, i] * w0
            e += direction[1, i] * w0
        denominator = 1.0 - b * b
        if denominator > PARALLEL_SIN2:
            s = (b * e - d) / denominator
            t = (e - b * d) / denominator
        else:  # parallel rays: no unique closest approach
            s, t = np.nan, np.nan
        squared = 0.0
        for i in range(3):
            pa = origin[0, i] + s * direction[0, i]
            pb = origin[1, i] + t * direction[1, i]
            points[m, i] = 0.5 * (pa + pb)
            squared += (pa - pb) * (pa - pb)
        gap[m] = np.sqrt(squared)
