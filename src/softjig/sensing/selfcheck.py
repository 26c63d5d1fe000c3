"""Self-checks of a contact plane: evidence, from the frame alone, that an estimate may be wrong.

A robot acts on a wrong normal as readily as on a right one, so every estimate of the refractive method
says whether it passed these checks (``quality``: ``"ok"`` or ``"suspect"``, with the reasons among its
warnings), and its ``tilt_sigma_deg`` grows with what the checks see beyond the noise.

**Split halves.** The contact markers are split in two along each principal axis of their footprint
(``(x, y)`` about the centroid), and a plane is fitted to each half. A flat face leaves two halves whose
normals differ only by their noise, ``sigma_d^2 = sigma_a^2 + sigma_b^2`` (:func:`~softjig.sensing.
uncertainty.normal_uncertainty` of each half); a plane fitted to a curved surface (the membrane's wall
beside the part, or the drape around it) leaves halves tilted apart by the curvature across the
footprint. The halves' noise comes from the markers' noise measured elsewhere (their own residuals
would count that curvature as noise). The excess of the difference over its noise is an error the
residuals do not show: it is added to the normal's uncertainty (half of it, as for two equally
plausible normals), and a difference beyond :data:`SPLIT_SUSPECT_SIGMAS` of its noise *and*
:data:`SPLIT_SUSPECT_MIN_DEG` makes the estimate suspect. Splitting along both axes sees a curvature
in any direction.

**Rival contacts.** Where two ways of finding the contact (e.g. the face searched from the jig axis
and from the dent's centroid, or the size-free contact cut to the face) both give a plane that no
marker contradicts, their normals are compared the same way (:func:`agreement`): normals farther
apart than their noise allows mean that the frame holds two plausible faces (the part's and a strip of
the membrane's wall beside a small contact), and whichever is reported, the estimate is suspect.
Without the part's size, the rival is the other arm of a V (a tilted face and the wall beside its
lowered edge meet at the deepest markers), unless it is the rougher surface of the two (:func:`rougher`:
a wall curves up to the rest shape, a face is flat).

The other checks (the contact's consistency with its plane, its area against the part's, a plane too
steep for a part on a soft jig) are made where their quantities are (:mod:`softjig.sensing.contact`,
:mod:`softjig.sensing.pipeline`); this module is pure math on points.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import stats

from softjig.errors import InputError
from softjig.geometry import PlaneFit
from softjig.sensing._selfcheck_kernels import split_fits
from softjig.sensing.uncertainty import normal_uncertainty

__all__ = ["SplitCheck", "agreement", "split_halves"]

#: The halves' normals differing by more than this many sigmas of their difference's noise (a 2-D
#: Gaussian difference of RMS ``noise`` exceeds ``k noise`` with probability ``exp(-k^2)``: 1e-4 for 3) ...
SPLIT_SUSPECT_SIGMAS = 3.0
#: ... and by more than this (deg), makes an estimate suspect: below it, a difference is too small to
#: matter to a robot even when the noise model is too optimistic.
SPLIT_SUSPECT_MIN_DEG = 1.5
#: The fewest markers a half may have to be fitted (a plane and a residual scale need 4; a few more keep
#: one stray marker from tilting it).
MIN_HALF_POINTS = 6


@dataclass(frozen=True)
class SplitCheck:
    """The agreement of the planes of the contact's two halves (:func:`split_halves`).

    Attributes
    ----------
    angle_rad : the angle between the two halves' normals (rad), along the axis where it is largest
        relative to its noise.
    noise_rad : the RMS angle the noise alone would give them, ``sqrt(sigma_a^2 + sigma_b^2)`` (rad).
    normal_a, normal_b : (3,) the two halves' unit normals (``n_z > 0``).
    """

    angle_rad: float
    noise_rad: float
    normal_a: np.ndarray
    normal_b: np.ndarray

    @property
    def sigmas(self) -> float:
        """The angle in units of its noise."""
        return self.angle_rad / self.noise_rad if self.noise_rad > 0 else math.inf

    @property
    def excess_rad(self) -> float:
        """The part of the angle the noise does not explain, ``sqrt(max(0, angle^2 - noise^2))`` (rad)."""
        return math.sqrt(max(0.0, self.angle_rad**2 - self.noise_rad**2))

    @property
    def suspect(self) -> bool:
        """Whether the halves disagree beyond both :data:`SPLIT_SUSPECT_SIGMAS` and
        :data:`SPLIT_SUSPECT_MIN_DEG`."""
        return self.sigmas > SPLIT_SUSPECT_SIGMAS and self.angle_rad > math.radians(SPLIT_SUSPECT_MIN_DEG)


def split_halves(
    points_mm: np.ndarray, *, point_sigma_mm: float, noise_factor: float = 1.0
) -> SplitCheck | None:
    """Fit the two halves of the contact markers along each principal axis of their ``(x, y)``.

    Parameters
    ----------
    points_mm : (N, 3) the contact markers in J (mm).
    point_sigma_mm : the markers' noise (mm), measured elsewhere (e.g. the frame's markers at rest): the
        halves' own residuals would count the curvature being tested as noise.
    noise_factor : the factor on the first-order sigmas for the errors the model leaves out (the one the
        estimate's own uncertainty is inflated by), so that ``noise_rad`` is calibrated.

    Returns
    -------
    SplitCheck or None
        The split along the axis whose halves disagree most relative to their noise; ``None`` when no
        split leaves :data:`MIN_HALF_POINTS` markers (not on a line) on each side.
    """
    pts = np.ascontiguousarray(points_mm, dtype=float)
    if len(pts) < 2 * MIN_HALF_POINTS:
        return None
    ok, normals, sigmas = split_fits(pts, float(point_sigma_mm), MIN_HALF_POINTS)
    worst: SplitCheck | None = None
    for k in range(2):  # the split across the minor and across the major axis
        if not ok[k]:
            continue
        check = SplitCheck(
            angle_rad=_angle_between(normals[k, 0].tolist(), normals[k, 1].tolist()),
            noise_rad=noise_factor * math.hypot(sigmas[k, 0], sigmas[k, 1]),
            normal_a=normals[k, 0].copy(),
            normal_b=normals[k, 1].copy(),
        )
        if worst is None or check.sigmas > worst.sigmas:
            worst = check
    return worst


def agreement(
    points_a: np.ndarray,
    normal_a: np.ndarray,
    points_b: np.ndarray,
    normal_b: np.ndarray,
    *,
    point_sigma_mm: float,
    noise_factor: float = 1.0,
) -> SplitCheck | None:
    """The agreement of two planes fitted to two sets of markers (two candidate contacts), as a
    :class:`SplitCheck` (``suspect`` when they disagree beyond their noise and
    :data:`SPLIT_SUSPECT_MIN_DEG`).

    Parameters
    ----------
    points_a, points_b : (N, 3) the markers of each contact in J (mm).
    normal_a, normal_b : (3,) their planes' unit normals (``n_z > 0``).
    point_sigma_mm : the markers' noise (mm), measured elsewhere (as for :func:`split_halves`).
    noise_factor : the factor on the first-order sigmas for the errors the model leaves out.

    Returns
    -------
    SplitCheck or None
        ``None`` when a set has fewer than 4 markers or its ``(x, y)`` lie on a line. The noise is that
        of two independent fits, ``sqrt(sigma_a^2 + sigma_b^2)``: contacts that share markers have
        correlated errors, so their true noise is smaller and the test errs towards agreeing.
    """
    sigmas = []
    for points, normal in ((points_a, normal_a), (points_b, normal_b)):
        pts = np.asarray(points, dtype=float)
        if len(pts) < 4:
            return None
        n = np.asarray(normal, dtype=float)
        centroid = pts.mean(axis=0)
        plane = PlaneFit(
            normal=n,
            offset_mm=-float(n @ centroid),
            centroid_mm=centroid,
            rms_residual_mm=0.0,
            n_points=len(pts),
            singular_values=np.zeros(3),
        )
        try:
            sigmas.append(normal_uncertainty(pts, plane, point_sigma_mm=point_sigma_mm).tilt_sigma_rad)
        except InputError:  # on a line: no tilt across it
            return None
    a, b = np.asarray(normal_a, dtype=float), np.asarray(normal_b, dtype=float)
    return SplitCheck(
        angle_rad=_angle_between(a.tolist(), b.tolist()),
        noise_rad=noise_factor * math.hypot(*sigmas),
        normal_a=a.copy(),
        normal_b=b.copy(),
    )


def rougher(points_a: np.ndarray, plane_a: PlaneFit, points_b: np.ndarray, plane_b: PlaneFit) -> float:
    """How well the noise explains that the markers ``points_a`` scatter about their ``plane_a`` more than
    ``points_b`` about ``plane_b``: the one-sided p-value of the F test of their residual variances
    (each the sum of squared distances over ``N - 3``, for a plane's three parameters).

    Small when ``a`` is the rougher surface (a curved strip of the membrane's wall beside a flat face);
    about one half for two flat faces of the same noise. Both sets need four markers or more
    (``InputError`` otherwise).
    """
    variances, dofs = [], []
    for points, plane in ((points_a, plane_a), (points_b, plane_b)):
        pts = np.asarray(points, dtype=float)
        if len(pts) < 4:
            raise InputError(
                f"the F test of two planes' roughness needs 4 markers or more in each, got {len(pts)}"
            )
        residuals = pts @ np.asarray(plane.normal, dtype=float) + plane.offset_mm
        dofs.append(len(pts) - 3)
        variances.append(float(residuals @ residuals) / dofs[-1])
    if variances[1] == 0.0:
        return 0.0 if variances[0] > 0.0 else 0.5
    return float(stats.f.sf(variances[0] / variances[1], dofs[0], dofs[1]))


def _angle_between(a: list[float], b: list[float]) -> float:
    """:func:`~softjig.geometry.angle_between` of two unit 3-vectors given as lists (rad): the same
    ``atan2(|a x b|, a . b)`` in the same order of operations, in scalars (``np.cross`` and
    ``np.linalg.norm`` on (3,) arrays cost more than the arithmetic)."""
    cx = a[1] * b[2] - a[2] * b[1]
    cy = a[2] * b[0] - a[0] * b[2]
    cz = a[0] * b[1] - a[1] * b[0]
    return math.atan2(math.sqrt(cx * cx + cy * cy + cz * cz), a[0] * b[0] + a[1] * b[1] + a[2] * b[2])
