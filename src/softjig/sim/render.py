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
   ``P`` and ``d`` the unit oil ray of ``p0`` (:func:`softjig.optics.rays_in_top_region`, compiled), the ray
   through the sub-pixel ``p0 + du`` is the line ``P + q + s d`` with ``q = B (J B)^{-1} du`` (``B`` a
   3x2 orthonormal basis of the plane perpendicular to ``d``). ``(J B)^{-1}`` is found by central
   differences of the back-projection: the oil rays of ``p0 +- 0.01 px`` in ``u`` and in ``v`` meet that
   plane through ``P`` at ``q(du)``. Since ``q ⊥ d``, it meets the sphere ``|X - P| = r`` first at
   ``X - P = q - sqrt(r^2 - |q|^2) d``, which counts only if it lies on the half protruding into the
   oil, ``(X - P)·a >= 0`` (otherwise the ray meets the black membrane). The shading of a hit is

   .. math:: I = b + (m - b)\,\bigl(\tfrac12 + \tfrac12 \cos\beta\bigr),
             \qquad \cos\beta = n\cdot(-d) = \sqrt{1 - |q|^2 / r^2},

   with ``m`` = ``imaging.marker_level`` and ``n`` the sphere's normal: diffuse light from the LEDs
   beside the cameras plus the bead pack's scattered light. Rays are cast only in a square patch of
   half-side ``ceil(radius_px)`` around each marker's rounded centre (``radius_px``: the largest
   singular value of ``J B`` times ``r``, the largest over the markers; no pixel farther out is
   touched; within it, only the pixels of a row that can hold a hit); the ``S x S`` sub-samples of each
   pixel (at the centres of its ``S x S`` cells) are averaged. With ``imaging.marker_appearance = "disc"``
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
   membrane moves, not the whole column; :func:`_redrawn_speckle`). With ``speckle_static = False`` the
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
   **Bubbles and glints** (5b; none by default): ``medium.bubbles`` air bubbles lodged in the bead pack
   (:func:`bubbles_J`), fixed in 3-D, are projected into each image with their radius; each is a dark
   ring at its rim (the light meeting the air at a grazing angle is reflected away) over the membrane
   and the markers behind it, and a small bright spot (the lights' reflection). ``imaging.glints``
   saturated spots a few pixels wide (the lights reflected by the plate's faces and the beads) lie at
   fixed places in each image (drawn from ``medium.speckle_seed`` and the camera), in front of
   everything. Both are drawn into the maps of what lies in front of the membrane, with the fiducials.
   A marker whose paint has flaked off (``imaging.missing_marker_fraction``) has no light of its own.
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
in the config.

Per-jig work is done once
-------------------------
Everything that depends on the jig and not on the frame (the membrane's rest heights at the markers, each
camera's static speckle texture, the fiducials' composite and which pixels they cover, the fall-off map,
and so the radiance of the bare membrane, ``((b (1 + s)) c + f) e F``, with ``c`` and ``f`` the fiducials'
transmission and premultiplied level) is computed once by :class:`Renderer`, built from the as-built jig; a
frame then only projects and casts its markers, redraws the speckle where the part moved beads (the box
around them gets its own radiance and gain), and composes each image band by band in one pass: the bare
radiance, plus the markers' blurred excess times ``(1 + s) c e F``, then the sensor noise and rounding
(the float radiance image is never written whole). This is the same image model as the steps above, in
another order of the same float32 products: the images differ from the step-by-step order only by float
rounding (a grey level here and there). A :class:`Renderer`'s per-jig arrays are read-only and each pair
being rendered at once gets its own scratch buffers, so threads may share it. :func:`render_pair` and
:func:`render_view` build one per call; reuse a :class:`Renderer` to render many frames of one jig.

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

import cv2
import numpy as np
from scipy.special import ndtri

from softjig.aruco import aruco_dictionary
from softjig.config import CameraConfig, ImagingConfig, JigConfig, MediumConfig, Part, PlateConfig
from softjig.jig_shape import rest_inner_height_mm
from softjig.optics import FlatLayers, layer_constants, pixels_to_normalized, project_points
from softjig.rig import AIR_REFRACTIVE_INDEX, distortion_of, flat_layers
from softjig.sensing.fiducials import fiducial_corners_J
from softjig.sim import _kernels
from softjig.sim.asbuilt import AsBuiltJig
from softjig.sim.membrane import MembraneState, deform, rest_heights
from softjig.sim.parts import PartPose

__all__ = [
    "MarkerTruth",
    "RenderedPair",
    "Renderer",
    "bubbles_J",
    "idealised",
    "marker_brightness",
    "render_pair",
    "render_view",
]

_FIDUCIAL_WHITE = 0.85
_FIDUCIAL_BLACK = 0.05
_BLUR_TRUNCATE_SIGMAS = 3.0
_MIN_MARKER_BRIGHTNESS = 0.05  # a marker's brightness factor is clipped here (a normal draw has tails)
_MIN_ILLUMINATION = 0.02  # the fall-off map is clipped here (an off-centre spot, a steep fall-off)
_MASK_REACH_COARSE_PX = 5.0  # the redraw mask's softening kernel (sigma 1) reaches 4 coarse px
_MASK_SUBPIXEL_BITS = 4  # cv2.circle's fractional bits for the redraw mask's centres and radii
_CAMERA_INDEX = {"left": 0, "right": 1}
# A bubble (step 5b): a dark ring at its rim, where the light meeting the air at a grazing angle is
# reflected away (total internal reflection), centred at this share of its radius, this wide (a share of
# the radius) and this dark; a small bright spot, the lights' reflection, this far up-left of its centre
# (a share of the radius), this wide and bright; drawn out to this many radii.
_BUBBLE_RIM_RHO = 0.85
_BUBBLE_RIM_WIDTH = 0.15
_BUBBLE_RIM_DARKNESS = 0.85
_BUBBLE_SPOT_OFFSET = 0.3
_BUBBLE_SPOT_SIGMA = 0.12
_BUBBLE_SPOT_LEVEL = 0.6
_BUBBLE_REACH = 1.4
# A glint: a Gaussian spot of this peak radiance (saturated: beyond full scale) and a standard deviation
# drawn in this range (px).
_GLINT_LEVEL = 1.5
_GLINT_SIGMA_PX = (0.8, 2.5)
_PIXEL_STEP = 0.01  # px: central differences of the back-projection (a 1e-3 mm step on the membrane)
_PIXEL_OFFSETS = np.array([[0.0, 0.0], [1.0, 0.0], [-1.0, 0.0], [0.0, 1.0], [0.0, -1.0]]) * _PIXEL_STEP
_PIXEL_OFFSETS.flags.writeable = False
_BAND_ROWS = 64  # rows composed at a time: the band's radiance (320 kB at 1280 px) stays in the L2 cache
_NO_PATCHES = np.zeros((0, 1, 1), dtype=np.float32)
_NO_ORIGINS = np.zeros((0, 2), dtype=np.int64)
_NO_BOX = np.zeros((0, 0), dtype=np.float32)
for _empty in (_NO_PATCHES, _NO_ORIGINS, _NO_BOX):
    _empty.flags.writeable = False


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
        (quiet zone included), and its paint is there (not one of ``imaging.missing_marker_fraction``).
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


class Renderer:
    """The simulator of one as-built jig: built once, then renders any number of its stereo pairs.

    Building it computes what every frame of the jig shares (module docstring, "Per-jig work is done
    once"): the markers' brightness factors and the membrane's rest heights at them, and, per camera, the
    fiducials' corners and composite, the static bead speckle, the illumination fall-off and the bare
    membrane's radiance. It holds only
    read-only arrays: one renderer may serve several threads.

    Parameters
    ----------
    as_built : AsBuiltJig
        The jig as built and its markers' rest positions.

    Examples
    --------
    >>> renderer = Renderer(draw_as_built(default_jig(), rng=0))  # doctest: +SKIP
    >>> pairs = [renderer.render_pair(part, pose, seed) for seed in range(100)]  # doctest: +SKIP
    """

    def __init__(self, as_built: AsBuiltJig) -> None:
        jig = as_built.jig
        self.as_built = as_built
        self._brightness = marker_brightness(jig.imaging, len(as_built.marker_xy_mm))
        self._rest = rest_heights(jig, as_built.marker_xy_mm)
        self._views = {
            side: _CameraView.build(jig, camera, side)
            for side, camera in (("left", jig.cameras.left), ("right", jig.cameras.right))
        }
        # Scratch buffers of finished pairs, for the next pair (one per thread rendering at once).
        self._idle_scratch: list[_Scratch] = []
        self._scratch_lock = threading.Lock()

    @property
    def jig(self) -> JigConfig:
        """The as-built jig's configuration."""
        return self.as_built.jig

    def render_pair(
        self,
        part: Part | None = None,
        pose: PartPose | None = None,
        rng: np.random.Generator | int | None = None,
        *,
        color: bool = False,
        timings: dict[str, float] | None = None,
    ) -> RenderedPair:
        """Render a stereo pair with a part pressed into the jig, with its ground truth.

        The membrane is deformed by :func:`softjig.sim.membrane.deform` at the as-built markers
        (``as_built.marker_xy_mm``), with the per-frame ripple and edge conformity of
        ``jig.tolerances`` (``membrane_ripple_mm``, ``edge_conformity_mm``); then each camera renders it
        with its own intrinsics and pose.

        Parameters
        ----------
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
        timings : dict or None
            If given, the process's CPU seconds spent per stage are added into it (for benchmarks).

        Returns
        -------
        RenderedPair
        """
        rng = np.random.default_rng(rng)
        timer = _Timer(timings)
        jig = self.jig
        T_J_part = None if part is None else (pose or PartPose()).T_J_part(jig)
        state = deform(
            jig,
            self.as_built.marker_xy_mm,
            part,
            T_J_part,
            ripple_mm=jig.tolerances.membrane_ripple_mm,
            edge_conformity_mm=jig.tolerances.edge_conformity_mm,
            rng=rng,
            rest=self._rest,
        )
        timer.lap("deform")
        with self._scratch_lock:
            scratch = self._idle_scratch.pop() if self._idle_scratch else _Scratch()
        try:
            left = self._views["left"].render(jig, state, self._brightness, rng, color, timer, scratch)
            right = self._views["right"].render(jig, state, self._brightness, rng, color, timer, scratch)
        finally:
            with self._scratch_lock:
                self._idle_scratch.append(scratch)
        truth = MarkerTruth(
            xyz_mm=state.marker_xyz_mm,
            axis=state.marker_axis,
            in_contact=state.in_contact,
            left_px=left.px,
            right_px=right.px,
            visible_left=left.visible,
            visible_right=right.visible,
        )
        return RenderedPair(left.image, right.image, truth, left.corners_px, right.corners_px)


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
    brightness = marker_brightness(jig.imaging, len(state.marker_xyz_mm))
    view = _CameraView.build(jig, camera, side)
    result = view.render(jig, state, brightness, rng, color, _Timer(None), _Scratch())
    return result.image, result.px, result.visible


def render_pair(
    as_built: AsBuiltJig,
    part: Part | None = None,
    pose: PartPose | None = None,
    rng: np.random.Generator | int | None = None,
    *,
    color: bool = False,
) -> RenderedPair:
    """Render a stereo pair of the as-built jig with a part pressed into it, with its ground truth.

    ``Renderer(as_built).render_pair(part, pose, rng, color=color)``: see :meth:`Renderer.render_pair`.
    It builds the jig's renderer on every call; to render many frames of one jig, build a
    :class:`Renderer` once and call its method.

    Parameters
    ----------
    as_built : AsBuiltJig
        The jig as built and its markers' rest positions.
    part : Part or None
        The part pressed into the jig; ``None`` renders the unloaded membrane.
    pose : PartPose or None
        How the part is pressed in; ``None`` with a part means ``PartPose()``. Ignored without a part.
    rng : numpy.random.Generator, int or None
        Seed or generator of every random draw (ripple, speckle, noise): a seed gives identical
        images.
    color : bool
        Render RGB images ``(H, W, 3)`` with equal channels.

    Returns
    -------
    RenderedPair
    """
    return Renderer(as_built).render_pair(part, pose, rng, color=color)


def marker_brightness(im: ImagingConfig, n_markers: int) -> np.ndarray:
    """Each marker's brightness factor, ``(n_markers,)``: ``1 + imaging.marker_brightness_spread * z``
    (clipped at 0.05), ``z`` standard normal drawn from
    ``SeedSequence(imaging.marker_brightness_seed, spawn_key=(1,))`` in marker order, so fixed per marker
    for a jig (the same in both cameras, every frame and every process); 0 for the markers missing from a
    damaged membrane (``imaging.missing_marker_fraction``, drawn from ``spawn_key=(2,)``)."""
    if im.marker_brightness_spread == 0:
        factor = np.ones(n_markers)
    else:
        rng = np.random.default_rng(np.random.SeedSequence(im.marker_brightness_seed, spawn_key=(1,)))
        z = rng.standard_normal(n_markers)
        factor = np.maximum(1.0 + im.marker_brightness_spread * z, _MIN_MARKER_BRIGHTNESS)
    if im.missing_marker_fraction > 0:  # paint flaked off: no light of its own
        rng = np.random.default_rng(np.random.SeedSequence(im.marker_brightness_seed, spawn_key=(2,)))
        factor[rng.random(n_markers) < im.missing_marker_fraction] = 0.0
    return factor


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
    """:func:`render_pair`, accumulating the seconds spent per stage into ``timings`` (the renderer's
    construction under ``"renderer"``)."""
    timer = _Timer(timings)
    renderer = Renderer(as_built)
    timer.lap("renderer")
    return renderer.render_pair(part, pose, rng, color=color, timings=timings)


class _Scratch:
    """Float32 temporaries of one pair's rendering, kept for the next pair (:class:`Renderer`): a buffer
    per name, replaced when a frame needs another shape. Used by one thread at a time."""

    def __init__(self) -> None:
        self._buffers: dict[str, np.ndarray] = {}

    def get(self, name: str, shape: tuple[int, ...]) -> np.ndarray:
        """The buffer ``name`` of ``shape`` (its content is left from its last use)."""
        buf = self._buffers.get(name)
        if buf is None or buf.shape != tuple(shape):
            buf = self._buffers[name] = np.empty(shape, dtype=np.float32)
        return buf


@dataclass(frozen=True)
class _Fiducial:
    """One fiducial's composite in a camera: over pixels ``[y0:y1, x0:x1]`` the image becomes
    ``image * cover + level`` (``cover`` the transmission ``1 - coverage``, ``level`` the premultiplied
    grey level); ``quad`` is its quiet zone's outline (px)."""

    y0: int
    y1: int
    x0: int
    x1: int
    cover: np.ndarray
    level: np.ndarray
    quad: np.ndarray


@dataclass(frozen=True)
class _SpeckleGrid:
    """The static speckle's coarse grid in a camera (:func:`_coarse_grid`) and its texture there, of unit
    standard deviation."""

    factor: int
    sigma: float
    texture: np.ndarray


@dataclass(frozen=True)
class _ViewResult:
    image: np.ndarray
    px: np.ndarray
    visible: np.ndarray
    corners_px: np.ndarray


def _read_only(*arrays: np.ndarray) -> None:
    for a in arrays:
        a.flags.writeable = False


@dataclass(frozen=True, eq=False)
class _CameraView:
    """What one camera's images owe to the jig alone (built once by :class:`Renderer`).

    ``base`` is the bare membrane's radiance after every per-pixel factor (static speckle, fiducials,
    fall-off and exposure); ``gain`` is what a marker's excess radiance over the membrane is multiplied by
    on its way to the same point (``(1 + s) c e F``). Without a static speckle (``speckle_static = False``
    or ``speckle_std = 0``) ``base`` and ``gain`` leave the speckle out and each frame applies its own.
    """

    camera: CameraConfig
    side: str
    layers: FlatLayers
    corners_px: np.ndarray
    fiducials: tuple[_Fiducial, ...]
    quad_half_planes: tuple[np.ndarray, np.ndarray]  # of the fiducials' quiet zones (_quad_half_planes)
    speckle: _SpeckleGrid | None
    # (H, W): the transmission and level of what lies in front of the membrane (fiducials, bubbles,
    # glints), illumination
    maps: tuple[np.ndarray, np.ndarray, np.ndarray]
    overlays: tuple[tuple[int, int, int, int], ...]  # (y0, y1, x0, x1): where the first two maps are not 1, 0
    base: np.ndarray
    gain: np.ndarray

    @classmethod
    def build(cls, jig: JigConfig, camera: CameraConfig, side: str) -> _CameraView:
        im, md = jig.imaging, jig.medium
        h, w = camera.height_px, camera.width_px
        layers = flat_layers(jig)
        corners_J = fiducial_corners_J(jig.fiducials)
        corners_px = project_points(corners_J, camera.K, distortion_of(camera), camera.T_J_cam, layers)
        corners_px = corners_px.reshape((*corners_J.shape[:2], 2))
        fiducials = _fiducial_composites(jig, corners_px, (h, w))
        k = _CAMERA_INDEX[side]
        exposure = np.float32(im.exposure[k])
        if im.illumination_falloff > 0:
            cu, cv = (float(c) for c in im.illumination_center)
            centre = (cu if k == 0 else -cu, cv)
            illumination = _falloff_map(w, h, im.illumination_falloff, centre, float(exposure))
        else:
            illumination = np.full((h, w), exposure, dtype=np.float32)
        speckle = None
        texture = np.zeros((h, w), dtype=np.float32)
        if md.speckle_std > 0 and md.speckle_static:
            f, coarse_shape, sigma = _coarse_grid((h, w), speckle_correlation_px(jig, camera))
            seed = np.random.SeedSequence(md.speckle_seed, spawn_key=(0, k))
            speckle = _SpeckleGrid(
                f, sigma, _coarse_texture(np.random.default_rng(seed), coarse_shape, sigma)
            )
            texture = _upsample(speckle.texture, f, (h, w), md.speckle_std)
        transmission, level = _fiducial_maps(fiducials, (h, w))
        overlays = (
            *((f.y0, f.y1, f.x0, f.x1) for f in fiducials),
            *_defects(jig, camera, k, layers, transmission, level),
        )
        maps = (transmission, level, illumination)
        half_planes = _quad_half_planes([f.quad for f in fiducials])
        _read_only(*half_planes, *maps)
        base, gain = _finish(texture, im, overlays, maps, 0, 0)
        view = cls(
            camera, side, layers, corners_px, fiducials, half_planes, speckle, maps, overlays, base, gain
        )
        _read_only(corners_px, base, gain)
        if speckle is not None:
            _read_only(speckle.texture)
        return view

    def render(
        self,
        jig: JigConfig,
        state: MembraneState,
        brightness: np.ndarray,
        rng: np.random.Generator,
        color: bool,
        timer: _Timer,
        scratch: _Scratch,
    ) -> _ViewResult:
        """Render this camera's image of the membrane in ``state`` (module docstring, steps 1-9), its
        temporaries in ``scratch``."""
        im = jig.imaging
        camera = self.camera
        h, w = camera.height_px, camera.width_px
        optics = _marker_optics(jig, camera, state, self.layers)
        timer.lap("geometry")
        excess = _marker_excess(jig, camera, state, optics, brightness, self.layers, timer, scratch)
        if excess is not None:
            optics = excess[2]
        base, gain, box = self._frame_radiance(jig, state, optics, rng)
        timer.lap("speckle")
        patches, origin = (excess[0], excess[1]) if excess is not None else (_NO_PATCHES, _NO_ORIGINS)
        out = _compose(base, gain, box, patches, origin, im, rng, float(im.gain[_CAMERA_INDEX[self.side]]))
        if color:
            out = np.repeat(out[:, :, None], 3, axis=2)
        timer.lap("compose+noise")
        r = optics.radius_px
        inside = (
            (optics.px[:, 0] - r >= -0.5)
            & (optics.px[:, 0] + r <= w - 0.5)
            & (optics.px[:, 1] - r >= -0.5)
            & (optics.px[:, 1] + r <= h - 0.5)
        )
        # A marker whose paint flaked off (brightness 0) is drawn as bare membrane: nothing to see.
        visible = inside & ~_hidden_by_quads(optics.px, r, self.quad_half_planes) & (brightness > 0)
        timer.lap("fiducials")
        return _ViewResult(out, optics.px, visible, self.corners_px)

    def _frame_radiance(
        self, jig: JigConfig, state: MembraneState, optics: _MarkerOptics, rng: np.random.Generator
    ) -> tuple[np.ndarray, np.ndarray, _Box | None]:
        """This frame's bare-membrane radiance and the markers' gain (module docstring, steps 4-6), and
        the box where the beads re-packed, whose radiance and gain replace them there (or None)."""
        md = jig.medium
        if md.speckle_std > 0 and not md.speckle_static:
            scale = optics.scale_px_per_mm[optics.near]
            corr_px = md.bead_diameter_mm * float(np.median(scale)) if len(scale) else 5.0
            shape = (self.camera.height_px, self.camera.width_px)
            texture = _speckle(rng, shape, corr_px, md.speckle_std)
            return (*_finish(texture, jig.imaging, self.overlays, self.maps, 0, 0), None)
        if self.speckle is None or md.speckle_redraw_fraction <= 0:
            return self.base, self.gain, None
        displaced = np.abs(np.asarray(state.indentation_mm)) > md.speckle_redraw_displacement_mm
        moved = optics.near & displaced
        if not moved.any():
            return self.base, self.gain, None
        redrawn = _redrawn_speckle(jig, self.speckle, optics, moved, rng, self.base.shape)
        if redrawn is None:
            return self.base, self.gain, None
        texture, x0, y0 = redrawn
        box_radiance, box_gain = _finish(texture, jig.imaging, self.overlays, self.maps, y0, x0)
        return self.base, self.gain, _Box(box_radiance, box_gain, x0, y0)


def _finish(
    texture: np.ndarray,
    im: ImagingConfig,
    overlays: tuple[tuple[int, int, int, int], ...],
    maps: tuple[np.ndarray, np.ndarray, np.ndarray],
    y0: int,
    x0: int,
) -> tuple[np.ndarray, np.ndarray]:
    """The bare membrane's radiance and the markers' gain over the region of a bead speckle ``texture``
    (top-left pixel ``y0, x0``; module docstring, steps 4-6): its speckle, the fiducials, bubbles and
    glints over it, the fall-off and exposure (:func:`softjig.sim._kernels.finish_radiance`; a camera
    view's ``overlays`` and ``maps``, the first two maps read only if an overlay's box meets the
    region)."""
    h, w = texture.shape
    under = any(oy0 < y0 + h and y0 < oy1 and ox0 < x0 + w and x0 < ox1 for oy0, oy1, ox0, ox1 in overlays)
    radiance = np.empty(texture.shape, dtype=np.float32)
    gain = np.empty(texture.shape, dtype=np.float32)
    texture = np.ascontiguousarray(texture)  # a crop's rows: contiguous, the kernel's loop vectorises
    background = np.float32(im.background_level)
    _kernels.finish_radiance(texture, background, maps, under, (y0, x0), radiance, gain)
    return radiance, gain


def _fiducial_maps(fiducials: tuple[_Fiducial, ...], shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """The fiducials' transmission ``c`` (1 off them) and premultiplied level ``l`` (0 off them) over the
    whole image: a radiance ``I`` under them is ``I c + l``. (The fiducials do not overlap, so one map
    holds each pixel's only fiducial.)"""
    transmission = np.ones(shape, dtype=np.float32)
    level = np.zeros(shape, dtype=np.float32)
    for fid in fiducials:
        roi = (slice(fid.y0, fid.y1), slice(fid.x0, fid.x1))
        transmission[roi] *= fid.cover
        level[roi] = level[roi] * fid.cover + fid.level
    return transmission, level


def _defects(
    jig: JigConfig,
    camera: CameraConfig,
    k: int,
    layers: FlatLayers,
    transmission: np.ndarray,
    level: np.ndarray,
) -> list[tuple[int, int, int, int]]:
    """Draw the bead pack's bubbles and the camera's glints into the maps of what lies in front of the
    membrane (module docstring, step 5b), in place; the boxes ``(y0, y1, x0, x1)`` they touch.

    A bubble lies behind the fiducials (in the oil, above the plate): through one, the membrane's
    radiance ``I`` becomes ``I T + H`` (``T`` its transmission, ``H`` its highlight), then the fiducial's
    ``c``, ``l`` apply, so ``c <- T c`` and ``l <- H c + l``. A glint (a reflection at the plate) lies
    in front of both: ``l <- l + G``."""
    boxes = []
    if jig.medium.bubbles:
        centres, radii = bubbles_J(jig)
        px = _project(centres, camera, layers)
        rim = _project(centres + radii[:, None] * np.array([1.0, 0.0, 0.0]), camera, layers)
        for (u, v), radius_px in zip(px, np.hypot(*(rim - px).T), strict=True):
            boxes.append(_draw_bubble(transmission, level, u, v, radius_px))
    if jig.imaging.glints:
        h, w = level.shape
        rng = np.random.default_rng(np.random.SeedSequence(jig.medium.speckle_seed, spawn_key=(3, k)))
        us, vs = rng.uniform(0, w - 1, jig.imaging.glints), rng.uniform(0, h - 1, jig.imaging.glints)
        sigmas = rng.uniform(*_GLINT_SIGMA_PX, jig.imaging.glints)
        for u, v, sigma in zip(us, vs, sigmas, strict=True):
            boxes.append(_draw_glint(level, u, v, sigma))
    return [box for box in boxes if box is not None]


def _draw_bubble(
    transmission: np.ndarray, level: np.ndarray, u: float, v: float, radius_px: float
) -> tuple[int, int, int, int] | None:
    """One bubble of image radius ``radius_px`` centred at ``(u, v)`` (px) into the maps (:func:`_defects`);
    the box it touches, or ``None`` when it lies outside the image."""
    box = _pixel_box(u, v, _BUBBLE_REACH * radius_px, transmission.shape)
    if box is None:
        return None
    y0, y1, x0, x1 = box
    yy, xx = np.mgrid[y0:y1, x0:x1]
    rho = np.hypot(xx - u, yy - v) / radius_px
    ring = _BUBBLE_RIM_DARKNESS * np.exp(-(((rho - _BUBBLE_RIM_RHO) / _BUBBLE_RIM_WIDTH) ** 2))
    offset = _BUBBLE_SPOT_OFFSET * radius_px
    spot = np.hypot(xx - (u - offset), yy - (v - offset)) / (_BUBBLE_SPOT_SIGMA * radius_px)
    c = transmission[y0:y1, x0:x1]
    level[y0:y1, x0:x1] += (_BUBBLE_SPOT_LEVEL * np.exp(-0.5 * spot**2) * c).astype(np.float32)
    c *= (1.0 - ring).astype(np.float32)
    return box


def _draw_glint(level: np.ndarray, u: float, v: float, sigma_px: float) -> tuple[int, int, int, int] | None:
    """One glint, a Gaussian spot of standard deviation ``sigma_px`` centred at ``(u, v)`` (px), into the
    level map (:func:`_defects`); the box it touches."""
    box = _pixel_box(u, v, 3.0 * sigma_px, level.shape)
    if box is None:
        return None
    y0, y1, x0, x1 = box
    yy, xx = np.mgrid[y0:y1, x0:x1]
    spot = _GLINT_LEVEL * np.exp(-0.5 * ((xx - u) ** 2 + (yy - v) ** 2) / sigma_px**2)
    level[y0:y1, x0:x1] += spot.astype(np.float32)
    return box


def bubbles_J(jig: JigConfig) -> tuple[np.ndarray, np.ndarray]:
    """The centres (``(n, 3)``, mm, J) and radii (``(n,)``, mm) of the ``medium.bubbles`` air bubbles
    lodged in the bead pack: uniform over the membrane's footprint, each at a uniform height between the
    plate's top face and the membrane at rest (clear of both, or on the plate where the fill is shallower
    than the bubble), radii uniform in ``[0.5, 1.5] medium.bubble_radius_mm``; drawn from
    ``SeedSequence(medium.speckle_seed, spawn_key=(2,))`` (the pack's own), so the same in both cameras
    and every frame."""
    md = jig.medium
    rng = np.random.default_rng(np.random.SeedSequence(md.speckle_seed, spawn_key=(2,)))
    r = jig.membrane.footprint_radius_mm * np.sqrt(rng.uniform(0.0, 1.0, md.bubbles))
    phi = rng.uniform(0.0, 2.0 * np.pi, md.bubbles)
    x, y = r * np.cos(phi), r * np.sin(phi)
    radii = md.bubble_radius_mm * rng.uniform(0.5, 1.5, md.bubbles)
    bottom = float(flat_layers(jig).interfaces_z_mm[-1])
    room = np.maximum(rest_inner_height_mm(jig, x, y) - bottom - 2.0 * radii, 0.0)
    z = bottom + radii + rng.uniform(0.0, 1.0, md.bubbles) * room
    return np.column_stack([x, y, z]), radii


def _pixel_box(
    u: float, v: float, reach_px: float, shape: tuple[int, int]
) -> tuple[int, int, int, int] | None:
    """The pixels within ``reach_px`` of ``(u, v)`` (a square), clipped to the image: ``(y0, y1, x0, x1)``,
    or ``None`` when it misses the image."""
    h, w = shape
    y0, y1 = max(int(np.floor(v - reach_px)), 0), min(int(np.ceil(v + reach_px)) + 1, h)
    x0, x1 = max(int(np.floor(u - reach_px)), 0), min(int(np.ceil(u + reach_px)) + 1, w)
    return (y0, y1, x0, x1) if y0 < y1 and x0 < x1 else None


@dataclass(frozen=True)
class _Box:
    """A frame's radiance and gain over the fine pixels from ``(y0, x0)`` where they differ from the jig's."""

    radiance: np.ndarray
    gain: np.ndarray
    x0: int
    y0: int


def _compose(
    base: np.ndarray,
    gain: np.ndarray,
    box: _Box | None,
    patches: np.ndarray,
    origin: np.ndarray,
    im: ImagingConfig,
    rng: np.random.Generator,
    camera_gain: float,
) -> np.ndarray:
    """The camera's image (module docstring, steps 3 and 7): the bare membrane's radiance ``base``
    (``box``'s inside it) plus each marker's excess ``patches`` (top-left pixels ``origin``) times ``gain``
    (``box``'s inside it); then shot and read noise of variance ``I / full_well + read^2`` (independent
    Gaussians: one draw, :func:`_standard_normal`'s two bytes per pixel), the camera's gain, clipping to
    [0, 1] and rounding to the bit depth. One pass, band by band
    (:func:`softjig.sim._kernels.compose_sensor`)."""
    hi, lo = _random_bytes(rng, base.shape)
    full = 255.0 if im.bit_depth == 8 else 65535.0
    noise = (
        np.float32(1.0 / im.full_well_electrons),
        np.float32(im.read_noise**2),
        np.float32(full * camera_gain),
        np.float32(full),
    )
    out = np.empty(base.shape, dtype=np.uint8 if im.bit_depth == 8 else np.uint16)
    boxed = (_NO_BOX, _NO_BOX, 0, 0) if box is None else (box.radiance, box.gain, box.x0, box.y0)
    origin = np.ascontiguousarray(origin, dtype=np.int64)
    order = np.argsort(origin[:, 1], kind="stable")
    deviates = (hi, lo, _NORMAL_OFFSET, _NORMAL_SLOPE)
    _kernels.compose_sensor(base, gain, boxed, patches, origin, order, deviates, noise, _BAND_ROWS, out)
    return out


def _redrawn_speckle(
    jig: JigConfig,
    grid: _SpeckleGrid,
    optics: _MarkerOptics,
    moved: np.ndarray,
    rng: np.random.Generator,
    shape: tuple[int, int],
) -> tuple[np.ndarray, int, int] | None:
    """The bead pack's speckle ``s`` where the part re-packed beads in this frame: ``(texture, x0, y0)``,
    ``texture`` float32 over the fine pixels from ``(y0, x0)`` that differ from the static
    texture, or None if none do.

    The static texture is drawn from ``SeedSequence(medium.speckle_seed, spawn_key=(0, camera))``, so it
    is the same in every frame of the jig and in every process. Around each marker in ``moved`` (the
    membrane there has moved beads), within ``pitch / sqrt(2)`` of it (the membrane between markers moved
    too), the beads next to the membrane re-pack: the texture is a sum over the bead column's layers, of
    which those carrying a fraction ``f = medium.speckle_redraw_fraction`` of its variance are drawn
    anew from ``rng``, so the texture's correlation with the static one there is ``1 - f``. On the
    coarse grid, ``s = (1 - f m) s_static + sqrt(1 - (1 - f m)^2) s_new``, ``m`` the mask (softened
    over one coarse pixel): the variance stays ``speckle_std^2`` everywhere. The fine texture is the
    coarse one resized up bilinearly; only the fine pixels whose interpolation reads a changed coarse
    pixel are recomputed (from a crop two coarse pixels wider, so that they equal the whole resize).
    """
    md = jig.medium
    f = grid.factor
    centre = (optics.px[moved] + 0.5) / f - 0.5  # coarse-grid coordinates of the fine pixel
    radius = jig.markers.pitch_mm / math.sqrt(2.0) * optics.scale_px_per_mm[moved] / f
    # Only the box around the moved region is redrawn (its mask is zero elsewhere).
    reach = radius + _MASK_REACH_COARSE_PX
    hs, ws = grid.texture.shape
    x0, y0 = (max(int(np.floor(np.min(centre[:, k] - reach))), 0) for k in (0, 1))
    x1 = min(int(np.ceil(np.max(centre[:, 0] + reach))) + 1, ws)
    y1 = min(int(np.ceil(np.max(centre[:, 1] + reach))) + 1, hs)
    if x0 >= x1 or y0 >= y1:
        return None
    mask = np.zeros((y1 - y0, x1 - x0), dtype=np.float32)
    sub = 1 << _MASK_SUBPIXEL_BITS
    local = np.rint((centre - [x0, y0]) * sub).astype(int).tolist()
    for (u, v), r in zip(local, radius.tolist(), strict=True):
        cv2.circle(mask, (u, v), max(1, round(sub * r)), 1.0, -1, cv2.LINE_AA, _MASK_SUBPIXEL_BITS)
    mask = cv2.GaussianBlur(mask, (0, 0), sigmaX=1.0)
    keep = 1.0 - np.float32(md.speckle_redraw_fraction) * mask  # correlation with the static one
    fresh = _coarse_texture(rng, mask.shape, grid.sigma)
    fresh *= np.sqrt(np.maximum(1.0 - keep * keep, 0.0))
    # The coarse rows/columns [a, b) around the box, resized up: fine pixels [(a + 1) f, (b - 1) f) of the
    # crop equal the whole texture's (their bilinear neighbours lie inside the crop).
    ya, yb, xa, xb = max(y0 - 2, 0), min(y1 + 2, hs), max(x0 - 2, 0), min(x1 + 2, ws)
    crop = grid.texture[ya:yb, xa:xb].copy()
    box = crop[y0 - ya : y1 - ya, x0 - xa : x1 - xa]
    box *= keep
    box += fresh
    fine = _upsample(crop, f, ((yb - ya) * f, (xb - xa) * f), md.speckle_std)
    fy0 = ya * f + (0 if ya == 0 else f)
    fx0 = xa * f + (0 if xa == 0 else f)
    fy1 = min(yb * f - (0 if yb == hs else f), shape[0])
    fx1 = min(xb * f - (0 if xb == ws else f), shape[1])
    if fy0 >= fy1 or fx0 >= fx1:
        return None
    return fine[fy0 - ya * f : fy1 - ya * f, fx0 - xa * f : fx1 - xa * f], fx0, fy0


def _marker_excess(
    jig: JigConfig,
    camera: CameraConfig,
    state: MembraneState,
    optics: _MarkerOptics,
    brightness: np.ndarray,
    layers: FlatLayers,
    timer: _Timer,
    scratch: _Scratch,
) -> tuple[np.ndarray, np.ndarray, _MarkerOptics] | None:
    """Each marker's blurred excess radiance over the membrane, ``(patches, origin, optics)`` (module
    docstring, steps 2-3: ``(n, P, P)`` float32 patches, their top-left pixels), or None if no marker's
    patch reaches into the image. ``optics`` is re-evaluated for every marker when one left out by
    :func:`_marker_optics`'s margin could reach into the image."""
    im, md = jig.imaging, jig.medium
    h, w = camera.height_px, camera.width_px
    if not optics.near.any():
        return None
    half, sigma_px, pad = _patch_extent(optics, md)
    if half + pad + 1 >= optics.margin_px:  # a marker left out could reach into the image
        optics = _marker_optics(jig, camera, state, layers, margin_px=np.inf)
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
    out = scratch.get("cast", (len(optics.px), size, size))[: len(idx)]
    patches = _cast_marker_patches(
        optics, idx, origin, size, im.supersampling, disc=im.marker_appearance == "disc", out=out
    )
    amplitude = 0.5 * (np.float32(im.marker_level) - np.float32(im.background_level)) * brightness[idx]
    patches *= amplitude.astype(np.float32)[:, None, None]
    timer.lap("markers")
    if pad > 0:  # G P G^T, G (n, size + 2 pad, size)
        n, t = len(idx), size + 2 * pad
        g = scratch.get("blur_g", (len(optics.px), t, size))[:n]
        g_t = scratch.get("blur_g_t", (len(optics.px), size, t))[:n]
        _kernels.blur_matrices(_gaussian_kernels(sigma_px[idx], pad), size, g, g_t)
        rows = np.matmul(g, patches, out=scratch.get("blur_rows", (len(optics.px), t, size))[:n])
        patches = np.matmul(rows, g_t, out=scratch.get("blurred", (len(optics.px), t, t))[:n])
        origin = origin - pad
    timer.lap("blur")
    return patches, origin, optics


_NORMAL_KNOTS = 256  # equal-probability bins of the two-byte standard-normal generator


def _normal_tables() -> tuple[np.ndarray, np.ndarray]:
    """Look-up tables of the standard-normal generator (see :func:`_standard_normal`).

    The inverse CDF of the normal distribution is taken piecewise linear between the 257 quantiles
    at ``k / 256``; the two unbounded tail bins end where a uniform spread keeps their conditional
    mean (``+-3.28``); the whole is rescaled to unit variance. Deviate ``(i, j)`` (bin ``i``, sub-step
    ``j``, both bytes) is ``offset[i] + slope[i] * j``; returns ``offset, slope`` as ``(256,)``
    float32 tables.
    """
    n = _NORMAL_KNOTS
    knots = ndtri(np.arange(n + 1) / n)
    tail_mean = n * np.exp(-0.5 * knots[n - 1] ** 2) / np.sqrt(2.0 * np.pi)  # E[z | z > q_255]
    knots[n] = 2.0 * tail_mean - knots[n - 1]
    knots[0] = -knots[n]
    width = np.diff(knots)
    values = knots[:-1, None] + width[:, None] * ((np.arange(n) + 0.5) / n)[None, :]
    scale = 1.0 / np.sqrt(np.mean(values**2))  # all 65536 outcomes: unit variance
    offset = ((knots[:-1] + width * 0.5 / n) * scale).astype(np.float32)
    slope = (width / n * scale).astype(np.float32)
    _read_only(offset, slope)
    return offset, slope


_NORMAL_OFFSET, _NORMAL_SLOPE = _normal_tables()  # constants of the generator, not state


def _random_bytes(rng: np.random.Generator, shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Two uniform random bytes per pixel, ``(hi, lo)`` each ``uint8 (h, w)``, from ``rng``'s bit
    generator (eight per 64-bit draw: ``hi`` the first ``h w``, ``lo`` the next)."""
    h, w = shape
    count = h * w
    raw = rng.bit_generator.random_raw((2 * count + 7) // 8).view(np.uint8)
    return raw[:count].reshape(h, w), raw[count : 2 * count].reshape(h, w)


def _standard_normal(rng: np.random.Generator, shape: tuple[int, int]) -> np.ndarray:
    """Standard-normal float32 deviates, ``(h, w)``.

    Two uniform bytes per deviate come from ``rng``'s bit generator (:func:`_random_bytes`); the first
    picks one of 256 equal-probability bins of the normal distribution, the second a position in it
    (:func:`_normal_tables`): mean 0, variance 1, every 1/256 quantile exact, deviates bounded by
    3.3 (the 0.1 % of a true normal beyond are drawn inside the tail bins). About 5x faster than
    ``rng.standard_normal`` for an image, which matters at 30 frames per second.
    """
    hi, lo = _random_bytes(rng, shape)
    out = cv2.LUT(hi, _NORMAL_OFFSET.reshape(1, -1))
    slope = cv2.LUT(hi, _NORMAL_SLOPE.reshape(1, -1))
    cv2.accumulateProduct(slope, lo.astype(np.float32), out)  # out += slope * lo
    return out


def _speckle(rng: np.random.Generator, shape: tuple[int, int], corr_px: float, std: float) -> np.ndarray:
    """A zero-mean Gaussian texture of standard deviation ``std`` and correlation length about
    ``corr_px`` px, float32 ``(h, w)`` (the per-frame texture of ``speckle_static = False``)."""
    f, coarse_shape, sigma = _coarse_grid(shape, corr_px)
    coarse = _standard_normal(rng, coarse_shape)
    coarse = cv2.GaussianBlur(coarse, (0, 0), sigmaX=sigma, borderType=cv2.BORDER_REFLECT)
    coarse *= np.float32(std / max(float(coarse.std()), 1e-12))
    return _upsample(coarse, f, shape, 1.0)


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
    """``std`` times the coarse texture resized up bilinearly by ``f``, cropped to ``shape`` (a new
    contiguous array)."""
    hs, ws = coarse.shape
    if std != 1.0:
        coarse = coarse * np.float32(std)
    fine = cv2.resize(coarse, (ws * f, hs * f), interpolation=cv2.INTER_LINEAR)
    if fine.shape == tuple(shape):
        return fine
    return np.ascontiguousarray(fine[: shape[0], : shape[1]])


def _patch_extent(optics: _MarkerOptics, md: MediumConfig) -> tuple[int, np.ndarray, int]:
    """Half-side of the ray-cast patches (px), each marker's blur sigma (px) and the blur pad (px)."""
    # A pixel k px from the (rounded) centre is at least |k| - 1 px from the true centre: the
    # sphere's image (semi-major axis radius_px) covers no pixel with |k| >= radius_px + 1.
    half = math.ceil(float(np.nanmax(optics.radius_px)))
    sigma_px = md.blur_coefficient * optics.oil_path_mm**1.5 * optics.scale_px_per_mm
    pad = math.ceil(_BLUR_TRUNCATE_SIGMAS * float(np.nanmax(sigma_px)))
    return half, sigma_px, pad


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
    jig: JigConfig,
    camera: CameraConfig,
    state: MembraneState,
    layers: FlatLayers,
    margin_px: float | None = None,
) -> _MarkerOptics:
    """Local-affine imaging of the markers whose projection lies within ``margin_px`` of the image
    (default: a tenth of its larger side); the others get NaN (they are neither drawn nor visible)."""
    P = np.asarray(state.marker_xyz_mm, dtype=float)
    axis = np.asarray(state.marker_axis, dtype=float)
    px = _project(P, camera, layers)
    if margin_px is None:
        margin_px = 0.1 * max(camera.width_px, camera.height_px)
    near = np.all(
        (px > -margin_px) & (px < [camera.width_px + margin_px, camera.height_px + margin_px]), axis=1
    )
    quad, lin = np.full((len(P), 3), np.nan), np.full((len(P), 2), np.nan)
    cos_axis, radius, scale, oil_path = (np.full(len(P), np.nan) for _ in range(4))
    if near.any():
        # The oil rays of each marker's pixel and of its four neighbours at +-_PIXEL_STEP in u and v.
        pixels = (px[near][:, None, :] + _PIXEL_OFFSETS).reshape(-1, 2)
        origins, rays = (a.reshape(-1, len(_PIXEL_OFFSETS), 3) for a in _rays(pixels, camera, layers))
        r = jig.markers.diameter_mm / 2.0
        shape = _kernels.marker_shapes(
            np.ascontiguousarray(P[near]), np.ascontiguousarray(axis[near]), origins, rays, r, _PIXEL_STEP
        )
        quad[near], lin[near] = shape[:, 0:3], shape[:, 3:5]
        cos_axis[near], radius[near], scale[near], oil_path[near] = shape[:, 5:9].T
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


def _project(points: np.ndarray, camera: CameraConfig, layers: FlatLayers) -> np.ndarray:
    """``(N, 2)`` pixels of ``(N, 3)`` points in J through the layers: :func:`softjig.optics.project_points`'s
    model (to ~1e-12 px), compiled (:func:`softjig.sim._kernels.project_refracted`)."""
    z_if = np.asarray(layers.interfaces_z_mm, dtype=float)
    T = np.ascontiguousarray(camera.T_J_cam, dtype=float)
    if not T[2, 3] < z_if[0]:
        raise ValueError(f"camera centre z = {T[2, 3]} mm must lie below the lowest interface {z_if[0]} mm")
    dist = np.zeros(5)
    given = distortion_of(camera)
    dist[: len(given)] = given
    n_reg = np.asarray(layers.refractive_indices, dtype=float)
    px = _kernels.project_refracted(np.ascontiguousarray(points, dtype=float), T, camera.K, dist, z_if, n_reg)
    if np.isnan(px).any():
        raise ValueError("a marker is behind the camera or in its image plane")
    return px


def _rays(pixels: np.ndarray, camera: CameraConfig, layers: FlatLayers) -> tuple[np.ndarray, np.ndarray]:
    """Oil rays ``(origins, directions)`` of ``(M, 2)`` pixels: :func:`softjig.optics.rays_in_top_region`'s
    model (the same rays to float rounding, its errors), the closed form compiled
    (:func:`softjig.sim._kernels.rays_in_top_region`)."""
    T = np.asarray(camera.T_J_cam, dtype=float)
    q = np.ascontiguousarray(pixels_to_normalized(pixels, camera.K, distortion_of(camera)))
    z_if, ratio, ratio_sq, layer_advance = layer_constants(layers)
    heights = np.array([z_if[0] - T[2, 3], z_if[-1]])
    if not heights[0] > 0:
        raise ValueError(f"camera centre z = {T[2, 3]} mm must lie below the lowest interface {z_if[0]} mm")
    R, centre = np.ascontiguousarray(T[:3, :3]), np.ascontiguousarray(T[:3, 3])
    origins, directions, status = _kernels.rays_in_top_region(
        q, R, centre, heights, ratio, ratio_sq, layer_advance
    )
    if status == 1:
        raise ValueError("some rays do not go upwards (d_z <= 0 in J); is the camera looking up?")
    if status == 2:
        raise ValueError(f"total internal reflection for some rays going through the layers {layers}")
    return origins, directions


def _cast_marker_patches(
    optics: _MarkerOptics,
    idx: np.ndarray,
    origin: np.ndarray,
    size: int,
    ss: int,
    disc: bool = False,
    out: np.ndarray | None = None,
) -> np.ndarray:
    """Average shading factor ``1 + cos(beta)`` (0 off the marker) of each pixel of a ``size x size``
    patch whose top-left pixel is at ``origin`` (integer px), for the markers ``idx``; with ``disc``,
    of a flat disc of the marker's radius in the membrane's plane, ``2 cos_axis`` where it is hit.

    Returns ``(len(idx), size, size)`` float32 (``out`` if given). The ``ss x ss`` sub-samples of a pixel
    sit at the centres of its ``ss x ss`` cells (:func:`softjig.sim._kernels.cast_marker_patches`).
    """
    q = size * ss
    sub = (np.arange(q) + 0.5) / ss - 0.5
    du = ((origin[:, 0] - optics.px[idx, 0])[:, None] + sub).astype(np.float32)  # (n, q) columns
    dv = ((origin[:, 1] - optics.px[idx, 1])[:, None] + sub).astype(np.float32)  # (n, q) rows
    cos_axis = np.maximum(optics.cos_axis[idx], 1e-6)
    quad = np.ascontiguousarray(optics.quad[idx], dtype=np.float32)
    lin = np.ascontiguousarray(optics.lin[idx] / cos_axis[:, None], dtype=np.float32)
    if out is None:
        out = np.empty((len(idx), size, size), dtype=np.float32)
    _kernels.cast_marker_patches(du, dv, quad, lin, size, ss, disc, out)
    if disc:  # Lambertian: the light from beside the camera and the view both at angle acos(cos_axis)
        out *= (2.0 * cos_axis).astype(np.float32)[:, None, None]
    return out


def _gaussian_kernels(sigma_px: np.ndarray, pad: int) -> np.ndarray:
    """``(N, 2 pad + 1)`` float32: each marker's Gaussian of ``sigma_px`` over the offsets ``-pad .. pad``,
    truncated there and normalised to sum 1 (light is conserved; the kernel is symmetric, so centroids
    are too). :func:`softjig.sim._kernels.blur_matrices` spreads it into the patch's blur matrix ``G``,
    whose column ``j`` spreads input pixel ``j`` over output pixels ``j .. j + 2 pad``."""
    offsets = np.arange(-pad, pad + 1, dtype=np.float64)
    s = np.maximum(np.asarray(sigma_px, dtype=np.float64), 1e-3)[:, None]
    kernel = np.exp(-0.5 * np.minimum((offsets / s) ** 2, 200.0))
    kernel /= kernel.sum(axis=1, keepdims=True)
    kernel[kernel < 1e-20] = 0.0  # float32 denormals would slow the products down tenfold
    return kernel.astype(np.float32)


def _fiducial_texture(dictionary: str, marker_id: int, cell_px: int) -> np.ndarray:
    """``(side, side, 2)`` float32: premultiplied grey level and coverage (1) of a fiducial with its
    one-cell white quiet zone; the black square spans pixels ``cell_px .. side - cell_px - 1``."""
    d = aruco_dictionary(dictionary)
    cells = d.markerSize + 2
    img = cv2.aruco.generateImageMarker(d, int(marker_id), cells * cell_px, borderBits=1)
    img = cv2.copyMakeBorder(img, cell_px, cell_px, cell_px, cell_px, cv2.BORDER_CONSTANT, value=255)
    level = _FIDUCIAL_BLACK + (_FIDUCIAL_WHITE - _FIDUCIAL_BLACK) * img.astype(np.float32) / 255.0
    return np.stack([level, np.ones_like(level)], axis=2)


def _fiducial_composites(
    jig: JigConfig, corners_px: np.ndarray, shape: tuple[int, int]
) -> tuple[_Fiducial, ...]:
    """Each fiducial warped into the image (module docstring, step 5): its composite and quiet-zone quad."""
    fid = jig.fiducials
    cells = aruco_dictionary(fid.dictionary).markerSize + 2
    h, w = shape
    out = []
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
        x0 = max(int(np.floor(quad[:, 0].min())) - 1, 0)
        y0 = max(int(np.floor(quad[:, 1].min())) - 1, 0)
        x1 = min(int(np.ceil(quad[:, 0].max())) + 2, w)
        y1 = min(int(np.ceil(quad[:, 1].max())) + 2, h)
        if x0 >= x1 or y0 >= y1:
            empty = np.zeros((0, 0), dtype=np.float32)
            out.append(_Fiducial(0, 0, 0, 0, empty, empty, quad))
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
        cover = 1.0 - warped[..., 1]
        level = np.ascontiguousarray(warped[..., 0])
        _read_only(cover, level, quad)
        out.append(_Fiducial(y0, y1, x0, x1, cover, level, quad))
    return tuple(out)


def _quad_half_planes(quads: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Outward unit normals ``(M, 4, 2)`` and offsets ``(M, 4)`` of each convex quad's edges: a point ``p``
    lies ``p . normal - offset`` outside an edge."""
    normals, offsets = np.zeros((len(quads), 4, 2)), np.zeros((len(quads), 4))
    for k, quad in enumerate(quads):
        edges = np.roll(quad, -1, axis=0) - quad
        n = np.stack([edges[:, 1], -edges[:, 0]], axis=1)
        n /= np.linalg.norm(n, axis=1, keepdims=True)
        n *= np.sign(np.sum((quad - quad.mean(axis=0)) * n, axis=1))[:, None]  # outwards
        normals[k], offsets[k] = n, np.sum(quad * n, axis=1)
    return normals, offsets


def _hidden_by_quads(
    px: np.ndarray, radius_px: np.ndarray, half_planes: tuple[np.ndarray, np.ndarray]
) -> np.ndarray:
    """Whether the disc of ``radius_px`` around each ``px`` meets any convex quad (conservative: the
    quad is grown by the radius along each edge's normal, which also takes its corners' squares);
    ``half_planes`` from :func:`_quad_half_planes`."""
    normals, offsets = half_planes
    if len(normals) == 0:
        return np.zeros(len(px), dtype=bool)
    dist = np.einsum("nk,mek->nme", px, normals) - offsets[None]
    return np.any(np.all(dist < radius_px[:, None, None], axis=2), axis=1)


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
    m = np.add.outer(y * y, x * x)  # float32 (H, W)
    m *= np.float32(-falloff / r2_corner)
    m += np.float32(1.0)
    np.maximum(m, np.float32(_MIN_ILLUMINATION), out=m)
    return m if exposure == 1.0 else (m * exposure).astype(np.float32)
