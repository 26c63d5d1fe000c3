"""The nominal jig's shape: the membrane's rest surface and where the mould puts the markers.

Both the simulator and the estimator need these (the push depth is measured from the rest surface), so
they live outside :mod:`softjig.sim`. The rest shape of the membrane's inner face is the dome
``h(r) = H (1 - (r / R)^k)`` of :class:`~softjig.config.MembraneConfig`; see :mod:`softjig.sim.membrane`
for how it deforms.
"""

from __future__ import annotations

import numpy as np

from softjig.config import JigConfig


def rest_inner_height_mm(jig: JigConfig, x_mm: np.ndarray, y_mm: np.ndarray) -> np.ndarray:
    """Height in J of the undeformed inner face above ``(x, y)``; 0 outside the footprint (mm)."""
    m = jig.membrane
    r = np.hypot(x_mm, y_mm) / m.footprint_radius_mm
    return np.where(r < 1.0, m.dome_height_mm * (1.0 - np.minimum(r, 1.0) ** m.dome_exponent), 0.0)


def rest_slope(jig: JigConfig, x_mm: np.ndarray, y_mm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Gradient ``(dh/dx, dh/dy)`` of the inner rest surface (dimensionless)."""
    m = jig.membrane
    r = np.hypot(x_mm, y_mm)
    rr = np.minimum(r / m.footprint_radius_mm, 1.0)
    dh_dr = -m.dome_height_mm * m.dome_exponent * rr ** (m.dome_exponent - 1) / m.footprint_radius_mm
    with np.errstate(invalid="ignore", divide="ignore"):
        cos, sin = np.where(r > 0, x_mm / r, 0.0), np.where(r > 0, y_mm / r, 0.0)
    inside = r < m.footprint_radius_mm
    return np.where(inside, dh_dr * cos, 0.0), np.where(inside, dh_dr * sin, 0.0)


def rest_outer_height_mm(jig: JigConfig, x_mm: np.ndarray, y_mm: np.ndarray) -> np.ndarray:
    """Height in J of the undeformed outer face (the one a part touches) above ``(x, y)`` (mm)."""
    gx, gy = rest_slope(jig, x_mm, y_mm)
    return rest_inner_height_mm(jig, x_mm, y_mm) + jig.membrane.thickness_mm * np.sqrt(1 + gx**2 + gy**2)


def marker_layout_xy(jig: JigConfig) -> np.ndarray:
    """The markers' nominal ``(x, y)`` in J (mm), ``(N, 2)``: a square or hexagonal grid of the
    configured pitch centred on the jig axis, inside the footprint less the rim margin."""
    mk, m = jig.markers, jig.membrane
    limit = m.footprint_radius_mm - mk.rim_margin_mm
    n = int(np.ceil(limit / mk.pitch_mm)) + 1
    i, j = np.meshgrid(np.arange(-n, n + 1), np.arange(-n, n + 1), indexing="xy")
    if mk.layout == "hex":
        x = (i + 0.5 * (j % 2)) * mk.pitch_mm
        y = j * mk.pitch_mm * np.sqrt(3) / 2
    else:
        x, y = i * mk.pitch_mm, j * mk.pitch_mm
    xy = np.stack([x.ravel(), y.ravel()], axis=1).astype(float)
    return xy[np.hypot(xy[:, 0], xy[:, 1]) <= limit]
