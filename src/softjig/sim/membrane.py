r"""The membrane: its rest shape, its markers, and how it deforms under a part's flat bottom face.

Model
-----
**Rest shape.** The membrane's inner face (the one carrying the markers, seen by the cameras) is a dome
clamped to the plate at the footprint radius ``R``, by default

.. math:: h(r) = H \left(1 - (r / R)^k\right), \qquad r < R,

with ``H`` = ``membrane.dome_height_mm`` (height over the plate on the axis) and ``k`` =
``membrane.dome_exponent`` (2 is a paraboloid; the default 4 gives the flatter top of a bag of jammed
beads); ``membrane.dome_profile`` also offers ``H (1 - (r/R)^2)^p`` and a measured table, all read
through :mod:`softjig.jig_shape`. The outer face lies one membrane thickness ``t`` above it along the
normal, i.e. ``t * sqrt(1 + |grad h|^2)`` above it vertically.

**Contact.** The part's bottom face is a plane (finite: a disc or a convex polygon, anywhere on the
jig and spun about the part's axis). Where that plane lies
below the outer rest surface (penetration ``g = h_outer - z_face > 0``) the membrane is pushed down and
conforms to the face: the inner face then lies on the face's plane shifted down by ``t / n_z``. Where the
face lies above the rest surface there is no contact and nothing pushes: a large part tilted far lifts
off on its raised side by geometry alone.

**Around the contact.** The bead pack and the membrane's tension spread each indentation: the surface
returns to rest with an exponential decay (the deflection of an elastic membrane on an elastic
foundation decays as ``exp(-d / lambda)``) of length ``lambda`` = ``membrane.decay_length_mm``, but never
with a wall steeper than the beads' angle of repose ``beta`` = ``membrane.max_wall_slope_deg``: a deep
indentation ``g`` spreads over ``lambda_g = max(lambda, g / tan(beta))``, so the wall's slope at the
edge, ``g / lambda_g``, is at most ``tan(beta)``. The deflection at any point ``q`` outside the contact
is the envelope of the decayed indentations,

.. math:: w(q) = \max_{c \in \text{contact}} g(c)\, e^{-|q - c| / \lambda_{g(c)}},

so it is continuous, equal to the indentation at the contact's edge and monotone away from it. The same
envelope also acts inside the face's footprint: where the face barely penetrates (near the edge that lifts
off) a deeper neighbouring indentation pulls the membrane below the face (``w > g``), and the membrane
leaves the face there. The displaced volume is assumed to spread over the rest of the bag (no bulge is
modelled).

**Markers** are material points of the inner face; the model moves them vertically (membrane stretch is
small at these indentations) and each hemisphere keeps its axis along the inner face's normal, pointing
into the oil. Two as-built effects act on markers in contact: a ripple where 1 mm beads press through
the 0.7 mm membrane (``tolerances.membrane_ripple_mm``, random per frame) and, optionally, incomplete
conformity near the face's edge (``tolerances.edge_conformity_mm``, decaying over ``lambda`` from the edge).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from softjig.config import JigConfig, Part
from softjig.jig_shape import rest_inner_height_mm, rest_outer_height_mm
from softjig.sim import _kernels
from softjig.sim.parts import (
    bottom_face_rim,
    bottom_face_samples,
    bottom_plane_height_mm,
    inside_face_mm,
    under_bottom_face,
)

_CONTACT_SAMPLE_SPACING_MM = 3.0  # inside the face: the envelope is smooth at this scale (lambda >= 5 mm)
_RIM_SAMPLE_SPACING_MM = 0.5  # along the face's edge, where the membrane drapes off it: dense, so the
# surface just outside the edge starts from the indentation at the edge (no step)
_CONTACT_TOLERANCE_MM = 1e-4  # the envelope is computed in float32: ignore its round-off


@dataclass(frozen=True)
class MembraneState:
    """Where the markers are for one part pose.

    Attributes
    ----------
    marker_xyz_mm : (N, 3) centre of each marker's base on the inner face, in J.
    marker_axis : (N, 3) unit normal of the inner face at each marker, pointing into the oil (down):
        the axis of the marker's hemisphere.
    in_contact : (N,) whether the membrane at the marker touches the part's bottom face.
    indentation_mm : (N,) how far the inner face at the marker lies below its rest height.
    """

    marker_xyz_mm: np.ndarray
    marker_axis: np.ndarray
    in_contact: np.ndarray
    indentation_mm: np.ndarray


@dataclass(frozen=True)
class RestHeights:
    """The rest surface at each marker and at its four neighbours half a marker radius away (the stencil of
    :func:`deform`): the same in every frame of a jig, so computed once per jig
    (:class:`softjig.sim.render.Renderer`).

    Attributes
    ----------
    inner, outer : (5, N) float, read-only
        Inner and outer rest heights in J (mm) at the markers, then at ``x + s``, ``x - s``, ``y + s``,
        ``y - s`` (``s`` a quarter of ``markers.diameter_mm``).
    """

    inner: np.ndarray
    outer: np.ndarray


def _stencil(jig: JigConfig, marker_xy_mm: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """The markers' ``x, y`` and their four neighbours (``(5, N)`` each), and the step ``s`` (mm)."""
    x, y = marker_xy_mm[:, 0].astype(float), marker_xy_mm[:, 1].astype(float)
    s = jig.markers.diameter_mm / 4.0
    return np.stack([x, x + s, x - s, x, x]), np.stack([y, y, y, y + s, y - s]), s


def rest_heights(jig: JigConfig, marker_xy_mm: np.ndarray) -> RestHeights:
    """:class:`RestHeights` of the markers at ``marker_xy_mm`` ((N, 2), J, mm)."""
    xs, ys, _ = _stencil(jig, marker_xy_mm)
    inner, outer = rest_inner_height_mm(jig, xs, ys), rest_outer_height_mm(jig, xs, ys)
    inner.flags.writeable = outer.flags.writeable = False
    return RestHeights(inner, outer)


class _Surface:
    """The deformed inner face for one part pose, evaluated anywhere (see the module docstring)."""

    def __init__(self, jig: JigConfig, part: Part | None, T_J_part: np.ndarray | None) -> None:
        self.jig, self.part, self.T = jig, part, T_J_part
        self.contact_xy = np.zeros((0, 2))
        self.contact_depth = np.zeros(0)
        if part is None or T_J_part is None:
            return
        samples = np.concatenate(
            [
                bottom_face_samples(part, T_J_part, _CONTACT_SAMPLE_SPACING_MM),
                bottom_face_rim(part, T_J_part, _RIM_SAMPLE_SPACING_MM),
            ]
        )
        depth = rest_outer_height_mm(jig, samples[:, 0], samples[:, 1]) - samples[:, 2]
        keep = depth > 0
        self.contact_xy, self.contact_depth = samples[keep, :2], depth[keep]

    def envelope_mm(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Deflection spread from the contact: ``max_c g_c exp(-|q - c| / lambda)``."""
        if len(self.contact_depth) == 0:
            return np.zeros_like(x)
        m = self.jig.membrane
        decay = np.maximum(m.decay_length_mm, self.contact_depth / np.tan(np.radians(m.max_wall_slope_deg)))
        qx, qy = x.ravel().astype(np.float32), y.ravel().astype(np.float32)
        cx, cy = np.ascontiguousarray(self.contact_xy.T, dtype=np.float32)
        log_depth = np.log(self.contact_depth).astype(np.float32)
        inverse_decay = (1.0 / decay).astype(np.float32)
        out = _kernels.log_envelope(qx, qy, cx, cy, log_depth, inverse_decay)
        return np.exp(out.astype(float)).reshape(x.shape)

    def height_mm(self, x: np.ndarray, y: np.ndarray, rest: RestHeights) -> tuple[np.ndarray, np.ndarray]:
        """Inner-face height and contact flag at each ``(x, y)``, whose rest heights are ``rest``'s."""
        if len(self.contact_depth) == 0:
            return rest.inner, np.zeros(x.shape, dtype=bool)
        assert self.part is not None and self.T is not None
        face_z = bottom_plane_height_mm(self.T, x, y)
        penetration = rest.outer - face_z
        envelope = self.envelope_mm(x, y)
        contact = (
            under_bottom_face(self.part, self.T, x, y)
            & (penetration > 0)
            & (penetration >= envelope - _CONTACT_TOLERANCE_MM)
        )
        inner_on_face = face_z - self.jig.membrane.thickness_mm / self.T[2, 2]
        return np.where(contact, inner_on_face, rest.inner - envelope), contact


def _distance_inside_face_mm(part: Part, T_J_part: np.ndarray, xyz: np.ndarray) -> np.ndarray:
    """Distance (mm) from each point, projected into the face's plane, to the face's edge."""
    local = (xyz - T_J_part[:3, 3]) @ T_J_part[:3, :3]
    return inside_face_mm(part, local[:, 0], local[:, 1])


def deform(
    jig: JigConfig,
    marker_xy_mm: np.ndarray,
    part: Part | None = None,
    T_J_part: np.ndarray | None = None,
    *,
    ripple_mm: float = 0.0,
    edge_conformity_mm: float = 0.0,
    rng: np.random.Generator | int | None = None,
    rest: RestHeights | None = None,
) -> MembraneState:
    """Marker positions, axes and contact for a part pressed into the jig (or none: the rest state).

    Parameters
    ----------
    jig : the jig (as built, when simulating).
    marker_xy_mm : (N, 2) the markers' ``(x, y)`` on the membrane, in J (mm).
    part, T_J_part : the part and its pose in J (4x4, origin at its bottom face's centre); ``None`` for
        the unloaded jig.
    ripple_mm : standard deviation of the vertical ripple of markers in contact (mm).
    edge_conformity_mm : how far markers in contact at the face's very edge stay short of it (mm),
        decaying with the distance from the edge over ``membrane.decay_length_mm``.
    rng : seed or generator for the ripple.
    rest : the rest surface at ``marker_xy_mm``'s stencil (:func:`rest_heights`), if computed already
        (it is the same for every frame of a jig); computed here otherwise.

    Returns
    -------
    MembraneState
    """
    rng = np.random.default_rng(rng)
    xs, ys, s = _stencil(jig, marker_xy_mm)
    x, y = xs[0], ys[0]
    if rest is None:
        rest = rest_heights(jig, marker_xy_mm)
    elif rest.inner.shape != xs.shape:
        raise ValueError(f"rest heights of {rest.inner.shape[1]} markers given for {len(x)} markers")
    surface = _Surface(jig, part, T_J_part)
    # The hemisphere sits on a patch of the membrane as wide as itself: its axis is the patch's mean
    # normal, from central differences half a marker radius either side. The marker and its four
    # neighbours are evaluated in one call (each point on its own: the same numbers as five calls).
    heights, contacts = surface.height_mm(xs, ys, rest)
    z, contact = heights[0], contacts[0]
    zx = (heights[1] - heights[2]) / (2 * s)
    zy = (heights[3] - heights[4]) / (2 * s)
    axis = np.stack([zx, zy, -np.ones_like(zx)], axis=1)
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    z = z.copy()
    if part is not None and T_J_part is not None and contact.any():
        if edge_conformity_mm > 0:
            xyz = np.stack([x, y, z], axis=1)[contact]
            edge = np.maximum(_distance_inside_face_mm(part, T_J_part, xyz), 0.0)
            z[contact] -= edge_conformity_mm * np.exp(-edge / jig.membrane.decay_length_mm)
        if ripple_mm > 0:
            z[contact] += rng.normal(0.0, ripple_mm, int(contact.sum()))
    indentation = rest.inner[0] - z
    return MembraneState(
        marker_xyz_mm=np.stack([x, y, z], axis=1),
        marker_axis=axis,
        in_contact=contact,
        indentation_mm=indentation,
    )
