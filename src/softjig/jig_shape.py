"""The nominal jig's shape: the membrane's rest surface and where the mould puts the markers.

Both the simulator and the estimator need these (the push depth is measured from the rest surface), so
they live outside :mod:`softjig.sim`. The rest shape of the membrane's inner face is the dome of
:class:`~softjig.config.MembraneConfig` (a power law, a power of a paraboloid or a measured table: read
it only through these functions, which know every profile); see :mod:`softjig.sim.membrane` for how it
deforms. The markers are a grid or an explicit (possibly surveyed) list, :func:`marker_layout_xy`; where
the layout carries measured heights, :func:`rest_marker_points_mm` is the rest shape at the markers.
"""

from __future__ import annotations

import numpy as np

from softjig.config import JigConfig, MembraneConfig

MAX_OUTER_OFFSET_FACTOR = 10.0
"""Cap of the outer face's vertical offset, in membrane thicknesses. The outer face lies one thickness
along the normal above the inner face, ``t sqrt(1 + |grad h|^2)`` above it vertically; a profile whose
wall meets the plate vertically (``paraboloid_power`` with ``p < 1``) would make that infinite at the rim,
where the vertical offset stops meaning anything (the outer face there lies beside the inner face)."""


def _profile(m: MembraneConfig, r_mm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Height ``h(r)`` (mm) and slope ``dh/dr`` of the inner rest face at radii ``r_mm``; 0 outside."""
    R, H, k = m.footprint_radius_mm, m.dome_height_mm, m.dome_exponent
    inside = r_mm < R
    s = np.minimum(r_mm / R, 1.0)
    if m.dome_profile == "power":  # the arithmetic of the first versions, to the last bit
        h = np.where(r_mm / R < 1.0, H * (1.0 - s**k), 0.0)
        dh = -H * k * s ** (k - 1) / R
    elif m.dome_profile == "paraboloid_power":
        base = 1.0 - s**2
        h = np.where(inside, H * base**k, 0.0)
        with np.errstate(divide="ignore", invalid="ignore"):
            dh = -2.0 * H * k * s * np.where(inside, base, 1.0) ** (k - 1) / R
    else:
        from scipy.interpolate import PchipInterpolator

        r = np.asarray(m.profile_r_mm, dtype=float)
        hh = np.asarray(m.profile_h_mm, dtype=float)
        if r[-1] < R:
            r, hh = np.append(r, R), np.append(hh, 0.0)
        # Mirrored about the axis: the axis is then a maximum, where PCHIP's slope is 0 (a flat top).
        spline = PchipInterpolator(np.concatenate([-r[:0:-1], r]), np.concatenate([hh[:0:-1], hh]))
        rr = np.minimum(r_mm, R)
        h = np.where(inside, spline(rr), 0.0)
        dh = spline(rr, 1)
    return h, np.where(inside, dh, 0.0)


def rest_profile_mm(jig: JigConfig, r_mm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The inner rest face along a radius: height ``h(r)`` in J (mm) and slope ``dh/dr``, at ``r_mm``
    (mm from the jig axis, ``>= 0``); both 0 outside the footprint."""
    return _profile(jig.membrane, np.asarray(r_mm, dtype=float))


def rest_apex_height_mm(jig: JigConfig) -> float:
    """Height of the inner rest face on the jig axis (mm): ``membrane.dome_height_mm`` for every
    profile (a measured table starts at it)."""
    return float(jig.membrane.dome_height_mm)


def rest_inner_height_mm(jig: JigConfig, x_mm: np.ndarray, y_mm: np.ndarray) -> np.ndarray:
    """Height in J of the undeformed inner face above ``(x, y)``; 0 outside the footprint (mm)."""
    return _profile(jig.membrane, np.hypot(x_mm, y_mm))[0]


def rest_slope(jig: JigConfig, x_mm: np.ndarray, y_mm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Gradient ``(dh/dx, dh/dy)`` of the inner rest surface (dimensionless)."""
    r = np.hypot(x_mm, y_mm)
    dh_dr = _profile(jig.membrane, r)[1]
    with np.errstate(invalid="ignore", divide="ignore"):
        cos, sin = np.where(r > 0, x_mm / r, 0.0), np.where(r > 0, y_mm / r, 0.0)
    return dh_dr * cos, dh_dr * sin


def rest_outer_height_mm(jig: JigConfig, x_mm: np.ndarray, y_mm: np.ndarray) -> np.ndarray:
    """Height in J of the undeformed outer face (the one a part touches) above ``(x, y)`` (mm): one
    membrane thickness along the normal above the inner face (vertically at most
    :data:`MAX_OUTER_OFFSET_FACTOR` thicknesses)."""
    gx, gy = rest_slope(jig, x_mm, y_mm)
    stretch = np.minimum(np.sqrt(1 + gx**2 + gy**2), MAX_OUTER_OFFSET_FACTOR)
    return rest_inner_height_mm(jig, x_mm, y_mm) + jig.membrane.thickness_mm * stretch


def marker_layout_xy(jig: JigConfig) -> np.ndarray:
    """The markers' nominal ``(x, y)`` in J (mm), ``(N, 2)``.

    A grid (square or hexagonal, of the configured pitch) has a marker at ``markers.offset_mm`` and is
    turned by ``markers.rotation_deg`` about it; its markers within the footprint less the rim margin of
    the jig axis are kept, row by row (``y`` index outer, ``x`` index inner, before the turn). An explicit
    layout is ``markers.centers_mm`` in its own order.
    """
    mk, m = jig.markers, jig.membrane
    if mk.layout == "explicit":
        return np.asarray(mk.centers_mm, dtype=float).reshape(-1, 2)
    limit = m.footprint_radius_mm - mk.rim_margin_mm
    reach = limit + float(np.hypot(*mk.offset_mm))
    n = int(np.ceil(reach / mk.pitch_mm)) + 1
    row = mk.pitch_mm * np.sqrt(3) / 2 if mk.layout == "hex" else mk.pitch_mm
    n_rows = max(n, int(np.ceil(reach / row)) + 1)
    i, j = np.meshgrid(np.arange(-n, n + 1), np.arange(-n_rows, n_rows + 1), indexing="xy")
    if mk.layout == "hex":
        x = (i + 0.5 * (j % 2)) * mk.pitch_mm
        y = j * row
    else:
        x, y = i * mk.pitch_mm, j * mk.pitch_mm
    xy = np.stack([x.ravel(), y.ravel()], axis=1).astype(float)
    if mk.rotation_deg != 0:
        a = np.radians(mk.rotation_deg)
        xy = xy @ np.array([[np.cos(a), np.sin(a)], [-np.sin(a), np.cos(a)]])
    if tuple(mk.offset_mm) != (0.0, 0.0):
        xy = xy + np.asarray(mk.offset_mm, dtype=float)
    return xy[np.hypot(xy[:, 0], xy[:, 1]) <= limit]


def rest_marker_points_mm(jig: JigConfig) -> np.ndarray:
    """The markers on the rest membrane, ``(N, 3)`` in J (mm), in :func:`marker_layout_xy`'s order.

    ``z`` is the measured inner-face height where the layout has one (an explicit layout with
    ``markers.centers_z_mm``, as ``softjig survey`` writes), otherwise the rest profile's height. This
    is the estimator's rest-shape reference.
    """
    xy = marker_layout_xy(jig)
    if jig.markers.layout == "explicit" and jig.markers.centers_z_mm:
        z = np.asarray(jig.markers.centers_z_mm, dtype=float)
    else:
        z = rest_inner_height_mm(jig, xy[:, 0], xy[:, 1])
    return np.column_stack([xy, z])
