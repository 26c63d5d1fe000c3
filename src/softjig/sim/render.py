r"""Stereo renderer of the simulated soft jig: what the two cameras under the plate see.

The renderer is the tests' oracle: it returns, with each stereo pair, the exact ground truth (where
every marker's base centre projects, through the refraction, in each image; which markers touch the
part; where the fiducials' corners are).

Scene
-----
Two cameras in air look up (``DESIGN.md`` §1: camera ``z`` ≈ J's ``+z``, camera ``x`` = J's ``x``, so
each image is a mirror of the view from above) through the PET plate and the index-matched oil + glass
bead filling at white hemispherical markers (``markers.diameter_mm``) on the inner face of a black
silicone membrane. ArUco fiducials are printed on the plate's bottom face (``fiducials.z_mm``), facing
the cameras, and are seen through air only. Frames and units: J (mm) for geometry, pixels
``(u, v) = (column, row)`` with the centre of pixel ``(0, 0)`` at ``(0.0, 0.0)``.

Image model
-----------
Radiance is computed in float32 on ``[0, 1]`` (fraction of full scale), in this order:

1. **Membrane**: the black membrane at ``imaging.background_level`` (``b``).
2. **Markers**, rendered from their real shape with ``imaging.supersampling`` (``S``) sub-samples per
   pixel side. Each marker is a hemisphere of radius ``r`` on the membrane, base centre ``P`` and axis
   ``a`` (unit, pointing into the oil, towards the cameras). A marker spans ~15 px at ~170 mm, so the
   perspective change across it is ~1 % and a *local-affine* ray model is used: with ``p0`` the exact
   projection of ``P`` (:func:`softjig.optics.project_points`), ``J`` the 2x3 projection Jacobian at
   ``P`` (:func:`softjig.optics.projection_jacobian`) and ``d`` the unit oil ray of ``p0``
   (:func:`softjig.optics.backproject_pixels`), the ray through the sub-pixel ``p0 + du`` is the line
   ``P + q + s d`` with ``q = B (J B)^{-1} du`` (``B`` a 3x2 orthonormal basis of the plane
   perpendicular to ``d``). Since ``q ⊥ d``, it meets the sphere ``|X - P| = r`` first at
   ``X - P = q - sqrt(r^2 - |q|^2) d``, which counts only if it lies on the half protruding into the
   oil, ``(X - P)·a >= 0`` (otherwise the ray meets the black membrane). The shading of a hit is

   .. math:: I = b + (m - b)\,\bigl(\tfrac12 + \tfrac12 \cos\beta\bigr),
             \qquad \cos\beta = n\cdot(-d) = \sqrt{1 - |q|^2 / r^2},

   with ``m`` = ``imaging.marker_level`` and ``n`` the sphere's normal: diffuse light from the LEDs
   beside the cameras plus the bead pack's scattered light. Rays are cast only in a square patch of
   half-side ``ceil(radius_px)`` around each marker's rounded centre (``radius_px``: the largest
   singular value of ``J B`` times ``r``, the largest over the markers; no pixel farther out is
   touched), for all markers at once in cache-sized chunks; the ``S x S`` sub-samples of each pixel
   (at the centres of its ``S x S`` cells) are averaged. With ``imaging.marker_appearance = "disc"``
   the marker is instead a flat painted disc of radius ``r`` in the membrane's plane at ``P`` (normal
   ``a``): the ray meets that plane at ``X - P = q + s d`` with ``s = (q.a) / cos_axis``, inside the
   disc iff ``|q|^2 + s^2 <= r^2``, lit uniformly at ``I = b + (m - b) cos_axis`` (Lambertian, light and
   view both along ``d``; ``cos_axis = -d.a``). A disc has no hemisphere bias (below). Each marker's
   excess over the membrane is scaled by its fixed brightness factor (:func:`marker_brightness`,
   ``imaging.marker_brightness_spread``: cast or painted markers differ in reflectance).
3. **Blur** growing with the path through the bead pack: ``L`` = length of the refracted ray in the oil
   from ``z = 0`` to ``P``; ``sigma_mm = medium.blur_coefficient * L ** 1.5`` perpendicular to the ray,
   converted to pixels by the local scale ``sqrt(|det(J B)|)`` (px/mm). Each marker's patch, padded by
   ``ceil(3 sigma_max)`` px, is convolved with its own isotropic Gaussian (truncated at the pad and
   normalised per input pixel, so a marker's light and its centroid are preserved) as a batched
   separable product ``G P G^T``; the excess over the membrane is then added into the image.
4. **Bead speckle**: the light from the membrane crosses the bead pack, whose imperfect beads transmit
   it unevenly, so the speckle *multiplies* the image: ``I <- I (1 + s)`` with ``s`` a zero-mean,
   spatially correlated Gaussian texture of relative standard deviation ``medium.speckle_std``: white
   noise on a grid coarser by ``f = round(c / 2)`` (``c`` = one bead diameter projected, ~5.5 px),
   smoothed there by a Gaussian of ``c / (2 f)`` coarse pixels, renormalised to the standard
   deviation, and resized up bilinearly (the smoothing keeps the interpolation from modulating the
   variance on the coarse grid). The beads of a real jig stay where they are between frames, so with
   ``medium.speckle_static`` (the default) the texture is the bead pack's: drawn from
   ``medium.speckle_seed`` and the camera, with ``c`` taken on the rest membrane above the camera
   (:func:`speckle_correlation_px`), the same in every frame and process. Only where the part has
   pushed the membrane by more than ``medium.speckle_redraw_displacement_mm`` (about half a bead: the
   beads next to it are pushed out of their pockets and re-pack) is a fraction
   ``medium.speckle_redraw_fraction`` of its variance new (only the layer of beads next to the
   membrane moves, not the whole column; :func:`_bead_speckle`). With ``speckle_static = False`` the
   texture is drawn anew from ``rng`` every frame, with ``c`` from the frame's markers (the idealised
   model the simulator used before). It is applied *before* the fiducials, which lie below the plate
   and are opaque: there is no speckle on the fiducials.
5. **Fiducials**: each ArUco marker (``cv2.aruco.generateImageMarker`` of ``fiducials.dictionary`` and
   ``fiducials.ids``, its own 1-cell black border included in ``fiducials.size_mm``) with a white quiet
   zone one cell wide, white 0.85 and black 0.05, is warped (``cv2.warpPerspective``, bilinear, with an
   antialiased coverage mask) by the homography mapping its black square's corners to their exact
   projections (:func:`softjig.sensing.fiducials.fiducial_corners_J`), opaque over the membrane. With
   lens distortion the homography is an approximation away from the four corners (exact at them).
   A membrane marker whose image disc (radius ``radius_px``) meets a fiducial's quiet zone is not
   visible (the quad is grown by the radius along its edges' normals: conservative at its corners).
   A marker is also not visible unless its whole disc lies inside the image.
6. **Illumination fall-off and exposure**: times ``e * max(1 - imaging.illumination_falloff * (rho /
   rho_corner)^2, 0.02)``, ``rho`` the distance from the illumination's centre, offset from the image
   centre ``((W-1)/2, (H-1)/2)`` by ``imaging.illumination_center`` (fractions of the half-width and
   half-height; mirrored in ``u`` for the right camera), ``rho_corner`` the image centre's distance to a
   corner, ``e`` the camera's ``imaging.exposure`` (left, right).
7. **Sensor noise and gain**: Gaussian of variance ``I / full_well + read_noise^2`` (shot plus read
   noise, independent, so one draw), on the radiance clipped at 0; then times the camera's
   ``imaging.gain`` (left, right); the result is clipped to ``[0, 1]`` and rounded to the nearest
   ``uint8`` or ``uint16`` level (``imaging.bit_depth``). The standard-normal
   deviates come from two random bytes each (:func:`_standard_normal`: the inverse CDF piecewise
   linear between the 1/256 quantiles, unit variance, bounded by 3.3; ~5x faster than
   ``rng.standard_normal``).
8. **Lens distortion** (``camera.distortion``) enters through the projection and its Jacobian.
9. ``color=True`` returns ``(H, W, 3)`` RGB with three equal channels (the membrane and markers are
   grey; the pipeline converts to grey at its edge).

Every per-frame random draw comes from ``rng = np.random.default_rng(rng)`` (the membrane's ripple, then
the left camera's redrawn or per-frame speckle and noise, then the right camera's): a seed reproduces a
pair bit for bit. The jig's fixed textures (static speckle, marker brightness) come from their own seeds
in the config. Full-image
float32 temporaries are kept per thread between frames (page faults on fresh buffers would cost more
than the arithmetic); rendering from several threads at once is safe.

Ground truth and the hemisphere's bias
--------------------------------------
A marker's truth pixel is the exact projection of its **base centre** through the refraction. A
hemisphere seen obliquely does not image symmetrically about that point (the half of the sphere behind
the base plane is missing), so its intensity-weighted centroid moves from the truth along the image of
its axis, towards the image of its apex, by an amount that grows as the square of the angle ``theta``
between its axis and the view ray: measured on the default geometry (4x4 supersampling, no noise),
about ``4.1e-4 px * theta_deg^2``: < 0.03 px below 8 deg, ~0.05 at 10 deg, ~0.15 at 20 deg,
~0.3 at 27 deg, up to ~1 px at 48 deg (the steepest markers on the dome's rim). The blur is symmetric
and does not move it further.
"""

from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass, replace
from functools import lru_cache

import cv2
import numpy as np
from scipy.special import ndtri

from softjig.aruco import aruco_dictionary
from softjig.config import CameraConfig, ImagingConfig, JigConfig, MediumConfig, Part, PlateConfig
from softjig.jig_shape import rest_inner_height_mm
from softjig.optics import backproject_pixels, project_points, projection_jacobian
from softjig.rig import AIR_REFRACTIVE_INDEX, distortion_of, flat_layers
from softjig.sensing.fiducials import fiducial_corners_J
from softjig.sim.asbuilt import AsBuiltJig
from softjig.sim.membrane import MembraneState, deform
from softjig.sim.parts import PartPose

__all__ = ["MarkerTruth", "RenderedPair", "idealised", "marker_brightness", "render_pair", "render_view"]

_FIDUCIAL_WHITE = 0.85
_FIDUCIAL_BLACK = 0.05
_BLUR_TRUNCATE_SIGMAS = 3.0
_CHUNK_SAMPLES = 100_000  # sub-samples per ray-casting chunk: its float32 temporaries stay in cache
_MIN_MARKER_BRIGHTNESS = 0.05  # a marker's brightness factor is clipped here (a normal draw has tails)
_MIN_ILLUMINATION = 0.02  # the fall-off map is clipped here (an off-centre spot, a steep fall-off)
_CAMERA_INDEX = {"left": 0, "right": 1}


# ------------------------------------------------------------------------------------------- results


@dataclass(frozen=True)
class MarkerTruth:
    """Ground truth of every membrane marker in one stereo pair.

    Attributes
    ----------
    xyz_mm : (N, 3) float
        Marker base centres in J (mm), from :class:`~softjig.sim.membrane.MembraneState`.
    axis : (N, 3) float
        Unit axis of each hemisphere in J, pointing into the oil (down, towards the cameras).
    in_contact : (N,) bool
        Whether the membrane at the marker touches the part's bottom face.
    left_px, right_px : (N, 2) float
        Exact projection ``(u, v)`` of ``xyz_mm`` into the left / right image through the refraction
        (px); markers outside the image are included (and not visible).
    visible_left, visible_right : (N,) bool
        Whether the marker's whole image disc lies inside the image and clear of every fiducial
        (quiet zone included).
    """

    xyz_mm: np.ndarray
    axis: np.ndarray
    in_contact: np.ndarray
    left_px: np.ndarray
    right_px: np.ndarray
    visible_left: np.ndarray
    visible_right: np.ndarray


@dataclass(frozen=True)
class RenderedPair:
    """A rendered stereo pair and its ground truth.

    Attributes
    ----------
    left, right : ndarray
        ``(H, W)`` ``uint8`` or ``uint16`` (``imaging.bit_depth``), or ``(H, W, 3)`` RGB with equal
        channels when rendered with ``color=True``.
    markers : MarkerTruth
        Where every membrane marker is, in J and in both images.
    fiducial_corners_left_px, fiducial_corners_right_px : (M, 4, 2) float
        Exact projections of :func:`~softjig.sensing.fiducials.fiducial_corners_J` (ArUco corner
        order), px.
    """

    left: np.ndarray
    right: np.ndarray
    markers: MarkerTruth
    fiducial_corners_left_px: np.ndarray
    fiducial_corners_right_px: np.ndarray


# ---------------------------------------------------------------------------------------- public API


def idealised(jig: JigConfig, *, refraction: bool = True, blur: bool = True, noise: bool = True) -> JigConfig:
    """The same jig with some image effects switched off, for exact tests.

    Each flag says whether that effect is **kept**; pass ``False`` to remove it.

    Parameters
    ----------
    jig : JigConfig
        The jig to simplify.
    refraction : bool
        ``False``: the plate's and the oil's refractive index become the air's
        (:data:`softjig.rig.AIR_REFRACTIVE_INDEX`), so rays go straight.
    blur : bool
        ``False``: ``medium.blur_coefficient = 0``.
    noise : bool
        ``False``: no bead speckle (``medium.speckle_std = 0``), no read noise and a full well of
        1e12 electrons (negligible shot noise). Quantisation to ``imaging.bit_depth`` stays.

    Returns
    -------
    JigConfig
        A validated copy.
    """
    plate: PlateConfig = jig.plate
    medium: MediumConfig = jig.medium
    imaging: ImagingConfig = jig.imaging
    if not refraction:
        plate = replace(plate, refractive_index=AIR_REFRACTIVE_INDEX)
        medium = replace(medium, oil_refractive_index=AIR_REFRACTIVE_INDEX)
    if not blur:
        medium = replace(medium, blur_coefficient=0.0)
    if not noise:
        medium = replace(medium, speckle_std=0.0)
        imaging = replace(imaging, read_noise=0.0, full_well_electrons=1e12)
    return jig.replace(plate=plate, medium=medium, imaging=imaging)


def render_view(
    jig: JigConfig,
    camera: CameraConfig,
    state: MembraneState,
    rng: np.random.Generator | int | None,
    *,
    color: bool = False,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Render what one camera sees of the membrane in ``state`` (see the module docstring).

    Parameters
    ----------
    jig : JigConfig
        The jig as built (plate, medium, markers, fiducials, imaging).
    camera : CameraConfig
        The camera: intrinsics, distortion and pose in J. If it equals ``jig.cameras.right`` (and not
        the left one) it is rendered as the right camera (its exposure, gain, mirrored illumination
        centre and bead-pack texture), otherwise as the left.
    state : MembraneState
        Marker base centres and axes in J (mm).
    rng : numpy.random.Generator, int or None
        Source of every per-frame random draw (redrawn or per-frame speckle, sensor noise).
    color : bool
        Return ``(H, W, 3)`` RGB (equal channels) instead of ``(H, W)``.

    Returns
    -------
    image : ndarray
        ``(H, W)`` (or ``(H, W, 3)``) ``uint8`` or ``uint16`` per ``imaging.bit_depth``.
    marker_px : (N, 2) float
        Exact projection of each marker's base centre (px).
    visible : (N,) bool
        Whether each marker's whole image disc is inside the image and clear of the fiducials.
    """
    rng = np.random.default_rng(rng)
    side = "right" if camera == jig.cameras.right and camera != jig.cameras.left else "left"
    image, px, visible, _ = _render_view(jig, camera, side, state, rng, color, _Timer(None))
    return image, px, visible


def render_pair(
    as_built: AsBuiltJig,
    part: Part | None = None,
    pose: PartPose | None = None,
    rng: np.random.Generator | int | None = None,
    *,
    color: bool = False,
) -> RenderedPair:
    """Render a stereo pair of the as-built jig with a part pressed into it, with its ground truth.

    The membrane is deformed by :func:`softjig.sim.membrane.deform` at the as-built markers
    (``as_built.marker_xy_mm``), with the per-frame ripple and edge conformity of
    ``jig.tolerances`` (``membrane_ripple_mm``, ``edge_conformity_mm``); then each camera of
    ``as_built.jig`` renders it with its own intrinsics and pose (:func:`render_view`).

    Parameters
    ----------
    as_built : AsBuiltJig
        The jig as built and its markers' rest positions.
    part : Part or None
        The part pressed into the jig; ``None`` renders the unloaded membrane.
    pose : PartPose or None
        How the part is pressed in; ``None`` with a part means ``PartPose()`` (centred, upright,
        3 mm in). Ignored without a part.
    rng : numpy.random.Generator, int or None
        Seed or generator of every random draw (ripple, speckle, noise): a seed gives identical
        images.
    color : bool
        Render RGB images ``(H, W, 3)`` with equal channels.

    Returns
    -------
    RenderedPair
    """
    return _render_pair(as_built, part, pose, rng, color=color, timings=None)


# ---------------------------------------------------------------------------------------- internals


class _Timer:
    """Accumulates the process's CPU time per stage into a dict (a no-op without one)."""

    def __init__(self, timings: dict[str, float] | None) -> None:
        self.timings = timings
        self.t = time.process_time()

    def lap(self, stage: str) -> None:
        if self.timings is None:
            return
        now = time.process_time()
        self.timings[stage] = self.timings.get(stage, 0.0) + (now - self.t)
        self.t = now


def _render_pair(
    as_built: AsBuiltJig,
    part: Part | None,
    pose: PartPose | None,
    rng: np.random.Generator | int | None,
    *,
    color: bool,
    timings: dict[str, float] | None,
) -> RenderedPair:
    """:func:`render_pair`, accumulating the seconds spent per stage into ``timings``."""
    rng = np.random.default_rng(rng)
    timer = _Timer(timings)
    jig = as_built.jig
    T_J_part = None
    if part is not None:
        T_J_part = (pose or PartPose()).T_J_part(jig)
    state = deform(
        jig,
        as_built.marker_xy_mm,
        part,
        T_J_part,
        ripple_mm=jig.tolerances.membrane_ripple_mm,
        edge_conformity_mm=jig.tolerances.edge_conformity_mm,
        rng=rng,
    )
    timer.lap("deform")
    left, left_px, vis_left, fid_left = _render_view(jig, jig.cameras.left, "left", state, rng, color, timer)
    right, right_px, vis_right, fid_right = _render_view(
        jig, jig.cameras.right, "right", state, rng, color, timer
    )
    truth = MarkerTruth(
        xyz_mm=state.marker_xyz_mm,
        axis=state.marker_axis,
        in_contact=state.in_contact,
        left_px=left_px,
        right_px=right_px,
        visible_left=vis_left,
        visible_right=vis_right,
    )
    return RenderedPair(left, right, truth, fid_left, fid_right)


@dataclass(frozen=True)
class _MarkerOptics:
    """Local-affine imaging of each marker in one camera (see the module docstring)."""

    px: np.ndarray  # (N, 2) projection of the base centre
    near: np.ndarray  # (N,) within margin_px of the image: the other fields are NaN elsewhere
    margin_px: float
    quad: np.ndarray  # (N, 3) |q|^2 / r^2 = a0 du^2 + a1 du dv + a2 dv^2
    lin: np.ndarray  # (N, 2) (q . axis) / r = l0 du + l1 dv
    cos_axis: np.ndarray  # (N,) -d . axis: cosine of the angle between the axis and the view ray
    radius_px: np.ndarray  # (N,) largest image radius of the sphere
    scale_px_per_mm: np.ndarray  # (N,) sqrt |det J B|
    oil_path_mm: np.ndarray  # (N,) length of the ray in the oil, z = 0 to the marker


def _marker_optics(
    jig: JigConfig, camera: CameraConfig, state: MembraneState, margin_px: float | None = None
) -> _MarkerOptics:
    """Local-affine imaging of the markers whose projection lies within ``margin_px`` of the image
    (default: a tenth of its larger side); the others get NaN (they are neither drawn nor visible)."""
    layers = flat_layers(jig)
    K, dist, T = camera.K, distortion_of(camera), camera.T_J_cam
    P = np.asarray(state.marker_xyz_mm, dtype=float)
    axis = np.asarray(state.marker_axis, dtype=float)
    px = project_points(P, K, dist, T, layers)
    if margin_px is None:
        margin_px = 0.1 * max(camera.width_px, camera.height_px)
    near = np.all(
        (px > -margin_px) & (px < [camera.width_px + margin_px, camera.height_px + margin_px]), axis=1
    )
    quad, lin = np.full((len(P), 3), np.nan), np.full((len(P), 2), np.nan)
    cos_axis, radius, scale, oil_path = (np.full(len(P), np.nan) for _ in range(4))
    if near.any():
        jac = projection_jacobian(P[near], K, dist, T, layers)  # (n, 2, 3) px/mm
        _, d = backproject_pixels(px[near], K, dist, T, layers)  # (n, 3) unit oil rays, going up
        # Orthonormal basis (e1, e2) of the plane perpendicular to d.
        ref = np.where(np.abs(d[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
        e1 = np.cross(d, ref)
        e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
        e2 = np.cross(d, e1)
        B = np.stack([e1, e2], axis=2)  # (n, 3, 2)
        JB = jac @ B  # (n, 2, 2)
        A = np.linalg.inv(JB)  # du -> in-plane mm coordinates
        r = jig.markers.diameter_mm / 2.0
        G = np.swapaxes(A, 1, 2) @ A / r**2  # |q|^2 / r^2 = du^T G du
        quad[near] = np.stack([G[:, 0, 0], G[:, 0, 1] + G[:, 1, 0], G[:, 1, 1]], axis=1)
        lin[near] = np.einsum("nk,nkj->nj", axis[near], B @ A) / r
        cos_axis[near] = -np.sum(d * axis[near], axis=1)
        radius[near] = r * np.linalg.svd(JB, compute_uv=False)[:, 0]
        scale[near] = np.sqrt(np.abs(np.linalg.det(JB)))
        oil_path[near] = np.maximum(P[near, 2], 0.0) / np.maximum(d[:, 2], 1e-9)
    return _MarkerOptics(
        px=px,
        near=near,
        margin_px=float(margin_px),
        quad=quad,
        lin=lin,
        cos_axis=cos_axis,
        radius_px=radius,
        scale_px_per_mm=scale,
        oil_path_mm=oil_path,
    )


def _cast_marker_patches(
    optics: _MarkerOptics, idx: np.ndarray, origin: np.ndarray, size: int, ss: int, disc: bool = False
) -> np.ndarray:
    """Average shading factor ``1 + cos(beta)`` (0 off the marker) of each pixel of a ``size x size``
    patch whose top-left pixel is at ``origin`` (integer px), for the markers ``idx``; with ``disc``,
    of a flat disc of the marker's radius in the membrane's plane, ``2 cos_axis`` where it is hit.

    Returns ``(len(idx), size, size)`` float32. The ``ss x ss`` sub-samples of a pixel sit at the
    centres of its ``ss x ss`` cells. The per-sample quadratic and linear forms are rank-3 and rank-2
    outer products (one small batched matmul each); the block average is ``cv2.resize(INTER_AREA)``
    at an integer factor, which is exact. Markers are processed in chunks whose float32 temporaries
    stay in the CPU's cache.
    """
    q = size * ss
    sub = np.arange(q) // ss + (np.arange(q) % ss + 0.5) / ss - 0.5
    du = ((origin[:, 0] - optics.px[idx, 0])[:, None] + sub).astype(np.float32)  # (n, q) columns
    dv = ((origin[:, 1] - optics.px[idx, 1])[:, None] + sub).astype(np.float32)  # (n, q) rows
    a0, a1, a2 = optics.quad[idx].astype(np.float32).T[:, :, None]
    cos_axis = np.maximum(optics.cos_axis[idx], 1e-6)
    l0, l1 = (optics.lin[idx] / cos_axis[:, None]).astype(np.float32).T[:, :, None]
    ones = np.ones_like(du)
    # cos(beta)^2 = 1 - |q|^2/r^2 = [1 - a2 dv^2, -a1 dv, -a0] . [1, du, du^2]
    quad_rows = np.stack([1.0 - a2 * dv * dv, -a1 * dv, -a0 * ones], axis=2)
    quad_cols = np.stack([ones, du, du * du], axis=1)
    # On the protruding half iff (X - P).axis / r = lin.du + cos(beta) cos_axis >= 0, i.e.
    # cos(beta) >= w = -(lin.du) / cos_axis = [-l1 dv, -l0] . [1, du]
    side_rows = np.stack([-l1 * dv, -l0 * ones], axis=2)
    side_cols = np.stack([ones, du], axis=1)
    out = np.empty((len(idx), size, size), dtype=np.float32)
    chunk = max(1, _CHUNK_SAMPLES // (q * q))
    for start in range(0, len(idx), chunk):
        sl = slice(start, start + chunk)
        n = len(du[sl])
        s = np.matmul(quad_rows[sl], quad_cols[sl], out=_WORKSPACE.get("rays_s", (n, q, q)))
        np.maximum(s, 0.0, out=s)
        np.sqrt(s, out=s)  # cos(beta), rows dv, columns du
        w = np.matmul(side_rows[sl], side_cols[sl], out=_WORKSPACE.get("rays_w", (n, q, q)))
        if disc:
            # The ray meets the base plane at (X - P) = q + s d, s / r = -w: inside the disc iff
            # |q|^2 / r^2 + w^2 <= 1, i.e. cos(beta) >= |w|.
            np.abs(w, out=w)
        else:
            np.maximum(w, 0.0, out=w)  # so that the strict test also drops s == 0 (off the sphere)
        hit = np.greater(s, w, out=_WORKSPACE.get("rays_hit", (n, q, q), np.bool_))
        if disc:
            np.copyto(s, hit)
        else:
            s += 1.0
            s *= hit
        flat = cv2.resize(s.reshape(n * q, q), (size, n * size), interpolation=cv2.INTER_AREA)
        out[sl] = flat.reshape(n, size, size)
    if disc:  # Lambertian: the light from beside the camera and the view both at angle acos(cos_axis)
        out *= (2.0 * cos_axis).astype(np.float32)[:, None, None]
    return out


def _gaussian_matrices(sigma_px: np.ndarray, size: int, pad: int) -> np.ndarray:
    """``(N, size + 2 pad, size)`` float32: column ``j`` spreads input pixel ``j`` over output pixels
    ``j .. j + 2 pad`` with a Gaussian of ``sigma_px`` truncated at ``pad`` and normalised to sum 1
    (light is conserved; the kernel is symmetric, so centroids are too)."""
    offsets = np.arange(-pad, pad + 1, dtype=np.float64)
    s = np.maximum(np.asarray(sigma_px, dtype=np.float64), 1e-3)[:, None]
    kernel = np.exp(-0.5 * np.minimum((offsets / s) ** 2, 200.0))
    kernel /= kernel.sum(axis=1, keepdims=True)
    kernel[kernel < 1e-20] = 0.0  # float32 denormals would slow the products down tenfold
    i = np.arange(size + 2 * pad)[:, None]
    j = np.arange(size)[None, :]
    k = i - j  # index into the kernel: output i, input j
    valid = (k >= 0) & (k <= 2 * pad)
    g = kernel.astype(np.float32)[:, np.clip(k, 0, 2 * pad)]
    g *= valid
    return g


def _paste(image: np.ndarray, patches: np.ndarray, origin: np.ndarray) -> None:
    """Add ``(N, P, P)`` patches into ``image`` with their top-left pixels at ``origin`` (clipped)."""
    h, w = image.shape
    size = patches.shape[1]
    lo = np.maximum(origin, 0)
    hi = np.minimum(origin + size, [w, h])
    a = lo - origin
    b = hi - origin
    rows = np.column_stack([lo[:, 1], hi[:, 1], lo[:, 0], hi[:, 0], a[:, 1], b[:, 1], a[:, 0], b[:, 0]])
    keep = (rows[:, 0] < rows[:, 1]) & (rows[:, 2] < rows[:, 3])
    for k, (y0, y1, x0, x1, py0, py1, px0, px1) in zip(
        np.flatnonzero(keep).tolist(), rows[keep].tolist(), strict=True
    ):
        image[y0:y1, x0:x1] += patches[k, py0:py1, px0:px1]


@lru_cache(maxsize=32)
def _fiducial_texture(dictionary: str, marker_id: int, cell_px: int) -> np.ndarray:
    """``(side, side, 2)`` float32: premultiplied grey level and coverage (1) of a fiducial with its
    one-cell white quiet zone; the black square spans pixels ``cell_px .. side - cell_px - 1``."""
    d = aruco_dictionary(dictionary)
    cells = d.markerSize + 2
    img = cv2.aruco.generateImageMarker(d, int(marker_id), cells * cell_px, borderBits=1)
    img = cv2.copyMakeBorder(img, cell_px, cell_px, cell_px, cell_px, cv2.BORDER_CONSTANT, value=255)
    level = _FIDUCIAL_BLACK + (_FIDUCIAL_WHITE - _FIDUCIAL_BLACK) * img.astype(np.float32) / 255.0
    tex = np.stack([level, np.ones_like(level)], axis=2)
    tex.flags.writeable = False
    return tex


def _draw_fiducials(image: np.ndarray, jig: JigConfig, corners_px: np.ndarray) -> list[np.ndarray]:
    """Composite every fiducial over ``image`` (in place); return each one's quiet-zone quad (px)."""
    fid = jig.fiducials
    cells = aruco_dictionary(fid.dictionary).markerSize + 2
    h, w = image.shape
    quads = []
    for marker_id, corners in zip(fid.ids, corners_px, strict=True):
        side_px = float(np.max(np.linalg.norm(corners - np.roll(corners, 1, axis=0), axis=1)))
        cell = max(2, math.ceil(side_px / cells))
        tex = _fiducial_texture(fid.dictionary, int(marker_id), cell)
        lo, hi = cell - 0.5, (cells + 1) * cell - 0.5  # the black square's edges in the texture
        src = np.array([[lo, lo], [hi, lo], [hi, hi], [lo, hi]], dtype=np.float32)
        H = cv2.getPerspectiveTransform(src, corners.astype(np.float32))
        e = tex.shape[0] - 0.5
        outer = np.array([[-0.5, -0.5], [e, -0.5], [e, e], [-0.5, e]], dtype=np.float32)
        quad = cv2.perspectiveTransform(outer[None], H)[0].astype(float)
        quads.append(quad)
        x0 = max(int(np.floor(quad[:, 0].min())) - 1, 0)
        y0 = max(int(np.floor(quad[:, 1].min())) - 1, 0)
        x1 = min(int(np.ceil(quad[:, 0].max())) + 2, w)
        y1 = min(int(np.ceil(quad[:, 1].max())) + 2, h)
        if x0 >= x1 or y0 >= y1:
            continue
        shift = np.array([[1.0, 0.0, -x0], [0.0, 1.0, -y0], [0.0, 0.0, 1.0]])
        warped = cv2.warpPerspective(
            tex,
            shift @ H,
            (x1 - x0, y1 - y0),
            flags=cv2.INTER_LINEAR,
            borderMode=cv2.BORDER_CONSTANT,
            borderValue=0,
        )
        roi = image[y0:y1, x0:x1]
        roi *= 1.0 - warped[..., 1]
        roi += warped[..., 0]
    return quads


def _hidden_by_quads(px: np.ndarray, radius_px: np.ndarray, quads: list[np.ndarray]) -> np.ndarray:
    """Whether the disc of ``radius_px`` around each ``px`` meets any convex quad (conservative: the
    quad is grown by the radius along each edge's normal, which also takes its corners' squares)."""
    hidden = np.zeros(len(px), dtype=bool)
    for quad in quads:
        edges = np.roll(quad, -1, axis=0) - quad
        normals = np.stack([edges[:, 1], -edges[:, 0]], axis=1)
        normals /= np.linalg.norm(normals, axis=1, keepdims=True)
        centre = quad.mean(axis=0)
        # orient the normals outwards
        sign = np.sign(np.sum((quad - centre) * normals, axis=1))
        normals *= sign[:, None]
        dist = np.einsum("nk,ek->ne", px, normals) - np.sum(quad * normals, axis=1)[None, :]
        hidden |= np.all(dist < radius_px[:, None], axis=1)
    return hidden


@lru_cache(maxsize=8)
def _falloff_map(
    width: int, height: int, falloff: float, center: tuple[float, float] = (0.0, 0.0), exposure: float = 1.0
) -> np.ndarray:
    """``exposure * max(1 - falloff (rho / rho_corner)^2, 0.02)``, float32 ``(H, W)``: ``rho`` from the
    illumination's centre, ``center`` (fractions of the half-width and half-height off the image
    centre), ``rho_corner`` the image centre's distance to a corner."""
    half_w, half_h = (width - 1) / 2.0, (height - 1) / 2.0
    x = np.arange(width, dtype=np.float32) - np.float32(half_w * (1.0 + center[0]))
    y = np.arange(height, dtype=np.float32) - np.float32(half_h * (1.0 + center[1]))
    r2_corner = half_w**2 + half_h**2
    m = 1.0 - np.float32(falloff / r2_corner) * (y[:, None] ** 2 + x[None, :] ** 2)
    m = (np.maximum(m, _MIN_ILLUMINATION) * exposure).astype(np.float32)
    m.flags.writeable = False
    return m


class _Workspace(threading.local):
    """Per-thread float32 image buffers reused from frame to frame.

    Allocating a fresh multi-megabyte array costs about a millisecond per megabyte in page faults on
    first touch; the renderer's full-image temporaries are therefore kept, per thread and shape.
    """

    def __init__(self) -> None:
        self.buffers: dict[tuple[str, tuple[int, ...]], np.ndarray] = {}

    def get(self, name: str, shape: tuple[int, ...], dtype: type = np.float32) -> np.ndarray:
        key = (name, shape)
        buf = self.buffers.get(key)
        if buf is None or buf.dtype != dtype:
            if len(self.buffers) > 32:  # many image sizes in one thread: start over
                self.buffers.clear()
            buf = self.buffers[key] = np.empty(shape, dtype=dtype)
        return buf


_WORKSPACE = _Workspace()


@lru_cache(maxsize=1)
def _normal_tables() -> tuple[np.ndarray, np.ndarray]:
    """Look-up tables of the standard-normal generator (see :func:`_standard_normal`).

    The inverse CDF of the normal distribution is taken piecewise linear between the 257 quantiles
    at ``k / 256``; the two unbounded tail bins end where a uniform spread keeps their conditional
    mean (``+-3.28``); the whole is rescaled to unit variance. Deviate ``(i, j)`` (bin ``i``, sub-step
    ``j``, both bytes) is ``offset[i] + slope[i] * j``; returns ``offset, slope`` as ``(1, 256)``
    float32 tables.
    """
    knots = ndtri(np.arange(257) / 256.0)
    tail_mean = 256.0 * np.exp(-0.5 * knots[255] ** 2) / np.sqrt(2.0 * np.pi)  # E[z | z > q_255]
    knots[256] = 2.0 * tail_mean - knots[255]
    knots[0] = -knots[256]
    width = np.diff(knots)
    values = knots[:-1, None] + width[:, None] * ((np.arange(256) + 0.5) / 256.0)[None, :]
    scale = 1.0 / np.sqrt(np.mean(values**2))  # all 65536 outcomes: unit variance
    offset = (knots[:-1] + width * 0.5 / 256.0) * scale
    slope = width / 256.0 * scale
    out = (offset.astype(np.float32).reshape(1, 256), slope.astype(np.float32).reshape(1, 256))
    for t in out:
        t.flags.writeable = False
    return out


def _standard_normal(
    rng: np.random.Generator, shape: tuple[int, int], out: np.ndarray | None = None
) -> np.ndarray:
    """Standard-normal float32 deviates, ``(h, w)``, written into ``out`` if given.

    Two uniform bytes per deviate come from ``rng``'s bit generator (eight per 64-bit draw); the first
    picks one of 256 equal-probability bins of the normal distribution, the second a position in it
    (:func:`_normal_tables`): mean 0, variance 1, every 1/256 quantile exact, deviates bounded by
    3.3 (the 0.1 % of a true normal beyond are drawn inside the tail bins). About 5x faster than
    ``rng.standard_normal`` for an image, which matters at 30 frames per second.
    """
    h, w = shape
    count = h * w
    raw = rng.bit_generator.random_raw((2 * count + 7) // 8).view(np.uint8)
    hi = raw[:count].reshape(h, w)
    lo = raw[count : 2 * count].reshape(h, w)
    offset, slope = _normal_tables()
    if out is None:
        out = np.empty((h, w), dtype=np.float32)
    tmp = _WORKSPACE.get("normal_slope", (h, w))
    sub = _WORKSPACE.get("normal_sub", (h, w))
    cv2.LUT(hi, offset, dst=out)
    cv2.LUT(hi, slope, dst=tmp)
    np.copyto(sub, lo)
    cv2.accumulateProduct(tmp, sub, out)  # out += tmp * sub
    return out


def _speckle(rng: np.random.Generator, shape: tuple[int, int], corr_px: float, std: float) -> np.ndarray:
    """A zero-mean Gaussian texture of standard deviation ``std`` and correlation length about
    ``corr_px`` px, float32 ``(h, w)`` (a view of a reused buffer)."""
    h, w = shape
    f = max(1, round(corr_px / 2.0))
    hs, ws = h // f + 2, w // f + 2
    coarse = _standard_normal(rng, (hs, ws))
    sigma = max(corr_px / (2.0 * f), 0.3)
    coarse = cv2.GaussianBlur(coarse, (0, 0), sigmaX=sigma, borderType=cv2.BORDER_REFLECT)
    coarse *= np.float32(std / max(float(coarse.std()), 1e-12))
    fine = _WORKSPACE.get("speckle", (hs * f, ws * f))
    cv2.resize(coarse, (ws * f, hs * f), dst=fine, interpolation=cv2.INTER_LINEAR)
    return fine[:h, :w]


def _coarse_grid(shape: tuple[int, int], corr_px: float) -> tuple[int, tuple[int, int], float]:
    """:func:`_speckle`'s coarse grid for an image of ``shape``: its factor ``f``, its shape and the
    smoothing sigma on it (coarse px)."""
    h, w = shape
    f = max(1, round(corr_px / 2.0))
    return f, (h // f + 2, w // f + 2), max(corr_px / (2.0 * f), 0.3)


def _coarse_texture(rng: np.random.Generator, coarse_shape: tuple[int, int], sigma: float) -> np.ndarray:
    """White noise on the coarse grid smoothed by ``sigma`` coarse px, of unit standard deviation."""
    coarse = _standard_normal(rng, coarse_shape)
    coarse = cv2.GaussianBlur(coarse, (0, 0), sigmaX=sigma, borderType=cv2.BORDER_REFLECT)
    coarse *= np.float32(1.0 / max(float(coarse.std()), 1e-12))
    return coarse


def _upsample(coarse: np.ndarray, f: int, shape: tuple[int, int], std: float) -> np.ndarray:
    """``std`` times the coarse texture resized up bilinearly by ``f``, cropped to ``shape`` (a view of a
    reused buffer)."""
    hs, ws = coarse.shape
    if std != 1.0:
        coarse = coarse * np.float32(std)
    fine = _WORKSPACE.get("speckle", (hs * f, ws * f))
    cv2.resize(coarse, (ws * f, hs * f), dst=fine, interpolation=cv2.INTER_LINEAR)
    return fine[: shape[0], : shape[1]]


def speckle_correlation_px(jig: JigConfig, camera: CameraConfig) -> float:
    """One bead diameter projected into ``camera`` (px) on the membrane's rest surface above it: the
    static texture's correlation length, a property of the jig and the camera only (not of the frame, so
    every frame's texture is the same).

    Paraxially, a ray leaving the camera at a small angle ``t`` in air runs at ``t / n`` in a flat layer
    of index ``n``, so a lateral offset ``dx`` at height ``z`` images at ``fx dx / D`` px with the
    equivalent distance ``D = d_air + t_plate / n_plate + z / n_oil`` (``d_air`` from the camera up to
    the plate's bottom face).
    """
    x, y, z_cam = (float(v) for v in camera.position_mm)
    z = max(float(rest_inner_height_mm(jig, np.array([x]), np.array([y]))[0]), 0.0)
    t = jig.plate.thickness_mm
    distance = (-t - z_cam) + t / jig.plate.refractive_index + z / jig.medium.oil_refractive_index
    corr = 0.5 * (camera.fx_px + camera.fy_px) * jig.medium.bead_diameter_mm / max(distance, 1e-6)
    return float(corr) if math.isfinite(corr) and corr > 0 else 5.0


def _bead_speckle(
    jig: JigConfig,
    camera: CameraConfig,
    side: str,
    optics: _MarkerOptics,
    moved: np.ndarray,
    rng: np.random.Generator,
) -> np.ndarray:
    """The bead pack's speckle ``s`` in this frame, float32 ``(H, W)`` (a view of a reused buffer).

    The static texture is drawn from ``SeedSequence(medium.speckle_seed, spawn_key=(0, camera))``, so it
    is the same in every frame of the jig and in every process. Around each marker in ``moved`` (the
    membrane there has moved beads), within ``pitch / sqrt(2)`` of it (the membrane between markers moved
    too), the beads next to the membrane re-pack: the texture is a sum over the bead column's layers, of
    which those carrying a fraction ``f = medium.speckle_redraw_fraction`` of its variance are drawn
    anew from ``rng``, so the texture's correlation with the static one there is ``1 - f``. On the
    coarse grid, ``s = (1 - f m) s_static + sqrt(1 - (1 - f m)^2) s_new``, ``m`` the mask (softened
    over one coarse pixel): the variance stays ``speckle_std^2`` everywhere.
    """
    md = jig.medium
    shape = (camera.height_px, camera.width_px)
    corr_px = speckle_correlation_px(jig, camera)
    f, coarse_shape, sigma = _coarse_grid(shape, corr_px)
    seed = np.random.SeedSequence(md.speckle_seed, spawn_key=(0, _CAMERA_INDEX[side]))
    coarse = _coarse_texture(np.random.default_rng(seed), coarse_shape, sigma)
    if md.speckle_redraw_fraction > 0 and moved.any():
        centre = (optics.px[moved] + 0.5) / f - 0.5  # coarse-grid coordinates of the fine pixel
        radius = jig.markers.pitch_mm / math.sqrt(2.0) * optics.scale_px_per_mm[moved] / f
        # Only the box around the moved region is redrawn (its mask is zero elsewhere).
        reach = radius + 5.0  # the mask's softening kernel reaches 4 coarse px
        hs, ws = coarse_shape
        x0, y0 = (max(int(np.floor(np.min(centre[:, k] - reach))), 0) for k in (0, 1))
        x1 = min(int(np.ceil(np.max(centre[:, 0] + reach))) + 1, ws)
        y1 = min(int(np.ceil(np.max(centre[:, 1] + reach))) + 1, hs)
        if x0 < x1 and y0 < y1:
            mask = np.zeros((y1 - y0, x1 - x0), dtype=np.float32)
            local = np.rint((centre - [x0, y0]) * 16).astype(int).tolist()
            for (u, v), r in zip(local, radius.tolist(), strict=True):  # 4 fractional bits (shift=4)
                cv2.circle(mask, (u, v), max(1, round(16 * r)), 1.0, -1, cv2.LINE_AA, 4)
            mask = cv2.GaussianBlur(mask, (0, 0), sigmaX=1.0)
            keep = 1.0 - np.float32(md.speckle_redraw_fraction) * mask  # correlation with the static one
            fresh = _coarse_texture(rng, mask.shape, sigma)
            fresh *= np.sqrt(np.maximum(1.0 - keep * keep, 0.0))
            box = coarse[y0:y1, x0:x1]
            box *= keep
            box += fresh
    return _upsample(coarse, f, shape, md.speckle_std)


def marker_brightness(im: ImagingConfig, n_markers: int) -> np.ndarray:
    """Each marker's brightness factor, ``(n_markers,)``: ``1 + imaging.marker_brightness_spread * z``
    (clipped at 0.05), ``z`` standard normal drawn from
    ``SeedSequence(imaging.marker_brightness_seed, spawn_key=(1,))`` in marker order, so fixed per marker
    for a jig (the same in both cameras, every frame and every process)."""
    if im.marker_brightness_spread == 0:
        return np.ones(n_markers)
    rng = np.random.default_rng(np.random.SeedSequence(im.marker_brightness_seed, spawn_key=(1,)))
    z = rng.standard_normal(n_markers)
    return np.maximum(1.0 + im.marker_brightness_spread * z, _MIN_MARKER_BRIGHTNESS)


def _patch_extent(optics: _MarkerOptics, md: MediumConfig) -> tuple[int, np.ndarray, int]:
    """Half-side of the ray-cast patches (px), each marker's blur sigma (px) and the blur pad (px)."""
    # A pixel k px from the (rounded) centre is at least |k| - 1 px from the true centre: the
    # sphere's image (semi-major axis radius_px) covers no pixel with |k| >= radius_px + 1.
    half = math.ceil(float(np.nanmax(optics.radius_px)))
    sigma_px = md.blur_coefficient * optics.oil_path_mm**1.5 * optics.scale_px_per_mm
    pad = math.ceil(_BLUR_TRUNCATE_SIGMAS * float(np.nanmax(sigma_px)))
    return half, sigma_px, pad


def _render_view(
    jig: JigConfig,
    camera: CameraConfig,
    side: str,
    state: MembraneState,
    rng: np.random.Generator,
    color: bool,
    timer: _Timer,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Render one camera; returns the image, the markers' px and visibility, the fiducials' px."""
    im, md = jig.imaging, jig.medium
    h, w = camera.height_px, camera.width_px
    bg, level = np.float32(im.background_level), np.float32(im.marker_level)
    optics = _marker_optics(jig, camera, state)
    layers = flat_layers(jig)
    corners_J = fiducial_corners_J(jig.fiducials)
    corners_px = project_points(corners_J, camera.K, distortion_of(camera), camera.T_J_cam, layers).reshape(
        (*corners_J.shape[:2], 2)
    )
    timer.lap("geometry")

    image = _WORKSPACE.get("image", (h, w))
    image.fill(bg)
    if optics.near.any():
        half, sigma_px, pad = _patch_extent(optics, md)
        if half + pad + 1 >= optics.margin_px:  # a marker left out could reach into the image
            optics = _marker_optics(jig, camera, state, margin_px=np.inf)
            half, sigma_px, pad = _patch_extent(optics, md)
        size = 2 * half + 1
        centre = np.rint(optics.px).astype(np.int64)
        # Only markers whose blurred patch touches the image are cast.
        reach = half + pad
        on = optics.near & (
            (centre[:, 0] + reach >= 0)
            & (centre[:, 0] - reach < w)
            & (centre[:, 1] + reach >= 0)
            & (centre[:, 1] - reach < h)
        )
        idx = np.flatnonzero(on)
        origin = centre[idx] - half
        patches = _cast_marker_patches(
            optics, idx, origin, size, im.supersampling, disc=im.marker_appearance == "disc"
        )
        amplitude = 0.5 * (level - bg) * marker_brightness(im, len(optics.px))[idx]
        patches *= amplitude.astype(np.float32)[:, None, None]
        timer.lap("markers")
        if pad > 0:
            g = _gaussian_matrices(sigma_px[idx], size, pad)
            patches = (g @ patches) @ np.ascontiguousarray(np.swapaxes(g, 1, 2))
            origin = origin - pad
        timer.lap("blur")
        _paste(image, patches, origin)
        timer.lap("paste")

    if md.speckle_std > 0:
        if md.speckle_static:
            displaced = np.abs(np.asarray(state.indentation_mm)) > md.speckle_redraw_displacement_mm
            moved = optics.near & displaced
            speckle = _bead_speckle(jig, camera, side, optics, moved, rng)
        else:
            scale = optics.scale_px_per_mm[optics.near]
            corr_px = md.bead_diameter_mm * float(np.median(scale)) if len(scale) else 5.0
            speckle = _speckle(rng, (h, w), corr_px, md.speckle_std)
        speckle += np.float32(1.0)
        image *= speckle
    timer.lap("speckle")

    quads = _draw_fiducials(image, jig, corners_px)
    r = optics.radius_px
    inside = (
        (optics.px[:, 0] - r >= -0.5)
        & (optics.px[:, 0] + r <= w - 0.5)
        & (optics.px[:, 1] - r >= -0.5)
        & (optics.px[:, 1] + r <= h - 0.5)
    )
    visible = inside & ~_hidden_by_quads(optics.px, r, quads)
    timer.lap("fiducials")

    k = _CAMERA_INDEX[side]
    exposure = float(im.exposure[k])
    if im.illumination_falloff > 0:
        cu, cv = (float(c) for c in im.illumination_center)
        center = (cu if k == 0 else -cu, cv)
        image *= _falloff_map(w, h, im.illumination_falloff, center, exposure)
    elif exposure != 1.0:
        image *= np.float32(exposure)
    timer.lap("falloff")

    image = _sensor(image, im, rng, float(im.gain[k]))
    if color:
        image = np.repeat(image[:, :, None], 3, axis=2)
    timer.lap("noise+quantise")
    return image, optics.px, visible, corners_px


def _sensor(image: np.ndarray, im: ImagingConfig, rng: np.random.Generator, gain: float = 1.0) -> np.ndarray:
    """Shot and read noise, the camera's ``gain``, clipping to [0, 1] and rounding to the bit depth
    (float32, in place)."""
    cv2.max(image, 0.0, dst=image)
    # sigma^2 = I / full_well + read^2 (shot and read noise are independent Gaussians: one draw)
    sigma = _WORKSPACE.get("sigma", image.shape)
    cv2.addWeighted(image, 1.0 / im.full_well_electrons, image, 0.0, im.read_noise**2, dst=sigma)
    cv2.sqrt(sigma, dst=sigma)
    z = _standard_normal(rng, image.shape, out=_WORKSPACE.get("normal", image.shape))
    cv2.accumulateProduct(sigma, z, image)  # image += sigma * z
    cv2.max(image, 0.0, dst=image)
    if im.bit_depth == 8:
        # saturates at 255 and rounds to nearest
        return cv2.convertScaleAbs(image, alpha=255.0 * gain)
    image *= np.float32(65535.0 * gain)
    image += np.float32(0.5)
    np.minimum(image, np.float32(65535.0), out=image)
    return image.astype(np.uint16)
