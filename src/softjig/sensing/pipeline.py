"""From a rectified stereo pair to the part's principal normal: the paper's method and ours.

Both methods share the front end, each stage in its own module:

1. markers in each image: LoG at the scale implied by the markers' size in the image, local maxima
   (on a downsampled pyramid level), and a maximum-likelihood fit of the marker model for the sub-pixel
   centre (:mod:`softjig.sensing.detect`, :mod:`softjig.sensing.subpixel`; the paper's quadratic fit
   with ``refine="quadratic"``);
2. the cameras' pose in J from the fiducials, or the config's (:mod:`softjig.sensing.jigframe`), and the
   markers on the fiducials dropped;
3. stereo matching on rows within a tolerance and a disparity window implied by the jig's geometry, as
   a one-to-one global assignment (:mod:`softjig.sensing.stereo`).

``method="paper"`` then does exactly what Sakuma et al. publish ("Optical Sensing"): pinhole
triangulation as if the cameras looked through air, the points within the part's base radius of the jig
axis, an SVD plane. Its depths come out compressed (by about the oil's index), which the paper's tilt
calibration ``S`` absorbs; its push depth is measured from the rest membrane as the same triangulation
sees it, so zero push reads zero, and stays compressed by the same factor.

``method="refractive"`` (the default) fixes the paper's known weaknesses:

- each marker is triangulated through the plate and the oil by Snell's law
  (:mod:`softjig.sensing.refractive`): metric depths, no robot calibration needed for the tilt;
- the contact region is found from each marker's indentation against the unloaded jig (a reference
  frame, or the nominal rest shape), not from a part size (:mod:`softjig.sensing.contact`); when the
  part's size is given, only under the tilted face's elliptical footprint;
- the plane is fitted robustly, and the markers where the face would not reach below the unloaded
  membrane are dropped, so markers where the part lifts off do not pull it
  (:mod:`softjig.sensing.robust`, :func:`~softjig.sensing.contact.drop_lifted_off`), and partial contact
  is flagged;
- the normal comes with its covariance and 1-sigma tilt errors (:mod:`softjig.sensing.uncertainty`);
- the contact footprint gives the contact's position (x, y) on the jig, and, when the part's size is
  given, the centre of its face; every marker gets an identity and a 3-D displacement
  (:mod:`softjig.sensing.identities`).

``fast=False`` runs the straightforward implementation of every stage, to check the fast one against.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field

import numpy as np

from softjig.caching import cached_by_identity
from softjig.config import JigConfig
from softjig.errors import EstimationError, InputError
from softjig.geometry import (
    PlaneFit,
    fit_plane_svd,
    normal_from_tilt_angles,
    tilt_angles,
    transform_points,
)
from softjig.jig_shape import marker_layout_xy, rest_inner_height_mm
from softjig.optics import project_points, projection_jacobian
from softjig.rig import flat_layers
from softjig.sensing.contact import (
    ContactRegion,
    Indentation,
    ambiguous_selection,
    contact_candidates,
    contact_violations,
    describe_contact,
    drop_lifted_off,
    face_centre_xy,
    face_depth_mm,
    grow_contact,
    indentation,
    just_outside,
    under_face,
)
from softjig.sensing.detect import (
    DEFAULT_CANDIDATES,
    DEFAULT_REFINE,
    Markers,
    check_image_content,
    detect_markers,
    gray_image,
    log_sigma_px,
    packed_bit_depth,
    unpack_bit_depth,
)
from softjig.sensing.identities import (
    MarkerIdentities,
    ReferenceMarkers,
    identify_markers,
    rest_shape_reference,
)
from softjig.sensing.jigframe import JigFrame, inside_fiducials, resolve_jig_frame
from softjig.sensing.rectify import rectify_pair
from softjig.sensing.refractive import triangulate_refracted
from softjig.sensing.robust import fit_plane_robust
from softjig.sensing.selfcheck import MIN_HALF_POINTS, SplitCheck, agreement, split_halves
from softjig.sensing.stereo import StereoMatches, match_rectified, triangulate_rectified
from softjig.sensing.subpixel import MIN_MODEL_BLUR_PX, MarkerModel
from softjig.sensing.uncertainty import (
    NormalUncertainty,
    inflated,
    normal_uncertainty,
    with_angle_floor,
    with_spread_between,
)
from softjig.tilt_calibration import TiltCalibration

METHODS = ("refractive", "paper")
# The best we have (DESIGN.md): on the paper's simulated sweep, uncalibrated, it beats the paper's method
# calibrated in 18 of 24 cells (`softjig compare`; issue 6's notes). `--method paper` keeps the published
# method exactly.
DEFAULT_METHOD = "refractive"
# Unmodelled, systematic errors of a triangulated marker (hemisphere seen obliquely, membrane ripple, the
# as-built cameras): the residual scale used for the normal's uncertainty is at least this.
UNCERTAINTY_FLOOR_MM = 0.05
CONTACT_INLIER_SIGMAS = 2.5  # a marker within this many depth-noise sigmas of the contact plane is on it
# The errors the first-order model leaves out (the obliquely seen hemispheres, the lift-off line's
# markers, the frame). Calibrated on varied designs (issue 13): five jigs other than the default (1024x768
# on a 5 mm grid, 1920x1200 with an 8 mm PMMA plate, an oil above the plate's index, 640x480 on a 10 mm
# grid, a flatter hex-gridded dome), a static speckle, two seeds, 10 parts each (30-80 mm, 0-20 deg, a
# third off the axis), with and without the size and the reference frame: the 1-sigma coverage of
# tilt_sigma_deg was 53-58 % with 1.35 (the default sweep's factor) and no floor, 63-70 % with these two.
# benchmarks/bench_zoo.py checks it on more designs.
MODEL_ERROR_FACTOR = 1.5
# An error of the normal that does not shrink with more markers (the as-built jig against the nominal
# one): added in quadrature, as an isotropic RMS angle (deg); the same calibration as above.
NORMAL_ANGLE_FLOOR_DEG = 0.1
# The face must lie this many depth-noise sigmas below the unloaded membrane at a marker to touch it.
LIFT_OFF_SIGMAS = 1.5
# Fewer fitted markers than this cannot be checked well enough (the split halves need 6 each, and the
# check's power grows with them), and such an estimate is suspect: on the design zoo, 13 markers of the
# wall beside a 30 mm part on a 10 mm grid passed the split check 24 deg off.
SELF_CHECK_MIN_POINTS = 15
# A contact of fewer than this share of the clearly pushed-in markers is suspect: a face presses most of
# its dent (the drape around it is shallower), a strip of wall fitted instead of a large face is a few
# of them (bench_zoo: 17-21 of 170-220). Size-free only: with the size, the contact is cut to the face
# and a steep part's drape is most of the dent (on bench_zoo the check flagged 20 good sized estimates).
MIN_CANDIDATE_SHARE = 0.2
# No part pressed into a soft jig stands steeper than this (deg): such a plane is a strip of the wall.
MAX_PLAUSIBLE_TILT_DEG = 45.0
# With the part's size known, a contact footprint larger than the part's face grown by this many marker
# pitches all round (the footprint is the markers' hull dilated by half a pitch, and the drape's first
# ring may join it) is not that part's.
CONTACT_AREA_SLACK_PITCHES = 1.0
# Swapped images: refused when the markers matched with the images exchanged are at least this share
# of the markers of the image with fewer ...
SWAPPED_MATCH_SHARE = 0.5
# ... and this many times the markers matched as given (a rectified pair's disparities are all positive).
SWAPPED_MATCH_FACTOR = 2.0
# With the part's size known, the face's centre is searched where the contact is: at most this many
# rounds of (fit under the face, move its centre to where that contact puts it), ...
FACE_CENTRE_ROUNDS = 4
# ... ending when the centre moves by less than this many marker pitches (a quarter of a grid cell).
FACE_CENTRE_TOLERANCE_PITCHES = 0.25
# With the part's size, a dent whose centroid lies this many part radii or more from the jig axis is
# searched from there too (a centred face covers its own dent's centroid: a small part steeply tilted
# drags the membrane down mostly beside its lowered edge, 0.5-1 radius off).
OFF_AXIS_DENT_RADII = 1.0
# A dent whose centroid lies this many pitches or more off the axis (but under a radius) is also searched
# from there, as a rival only: a face searched from the axis that it contradicts makes the estimate suspect.
RIVAL_SEARCH_PITCHES = 1.0
# ... when the face found from the axis has fewer markers than SELF_CHECK_MIN_POINTS and one more half of
# the split check (MIN_HALF_POINTS): the self-check has little power there (the zoo's two such silent
# failures had 15), while a larger face is placed by its own markers. The search costs 0.2-0.5 ms.
# The search starts on the jig axis and stays there when the contact found puts the face's centre within
# this share of the part's radius of it.
CENTRED_SHARE = 0.5


@dataclass(frozen=True)
class Estimate:
    """One stereo pair's estimate of the part's orientation, as reported to users and robots.

    Attributes
    ----------
    normal : unit principal normal in J, pointing into the part (calibrated when ``calibrated``).
    tilt_x_deg, tilt_y_deg : tilt angles ``Ax = atan2(-n_y, n_z)``, ``Ay = atan2(n_x, n_z)`` (deg).
    push_depth_mm : how far the fitted plane lies below the rest membrane on the jig axis (mm).
    n_points : markers used in the plane fit.
    rms_residual_mm : RMS distance of those markers to the plane (mm).
    frame_source : ``"fiducials"`` or ``"config"``: where the cameras' pose in J came from.
    warnings : things a user should know about this estimate.
    method : ``"refractive"`` or ``"paper"``.
    calibrated : whether a tilt calibration was applied.
    raw_tilt_x_deg, raw_tilt_y_deg : tilt angles before calibration (deg).
    part_diameter_mm : the part's base diameter given by the user (mm), or ``None``.
    n_markers_left, n_markers_right, n_matches : detections and stereo matches.
    tilt_sigma_x_deg, tilt_sigma_y_deg : 1-sigma errors of the tilt angles (``refractive`` only).
    tilt_sigma_deg : 1-sigma angle between the estimated and the true normal (deg), with what the
        self-check's split halves show beyond the noise; for ``paper``, of its (compressed) raw normal.
    normal_covariance : (3, 3) covariance of the normal, as nested lists (``refractive`` only).
    contact_area_mm2, contact_centroid_xy_mm, contact_outline_xy_mm : the contact footprint: area,
        centroid ``(x, y)`` in J (the part's position on the jig) and outline (``refractive`` only).
    contact_partial : whether the part lifts off on some side (``refractive`` only).
    part_centre_xy_mm : where the centre of the part's face lies, ``(x, y)`` in J (mm), when the part's
        diameter is known (``refractive`` only): the contact's centroid in full contact, one radius uphill
        of the face's rim in partial contact (:func:`~softjig.sensing.contact.face_centre_xy`).
    lift_azimuth_deg : towards which azimuth it lifts off, if it does.
    indentation_reference : what indentations were measured against (``"reference frame"`` or
        ``"rest shape"``).
    quality : ``"ok"``, or ``"suspect"`` when a self-check of the frame's own evidence says the estimate
        may be wrong; the reasons are among ``warnings`` (they start with ``"suspect: "``). The exit code
        is 0 either way: a robot should not act on a suspect estimate without a second look.
    """

    normal: tuple[float, float, float]
    tilt_x_deg: float
    tilt_y_deg: float
    push_depth_mm: float
    n_points: int
    rms_residual_mm: float
    frame_source: str
    warnings: tuple[str, ...]
    method: str
    calibrated: bool
    raw_tilt_x_deg: float
    raw_tilt_y_deg: float
    part_diameter_mm: float | None
    n_markers_left: int
    n_markers_right: int
    n_matches: int
    tilt_sigma_x_deg: float | None = None
    tilt_sigma_y_deg: float | None = None
    tilt_sigma_deg: float | None = None
    normal_covariance: tuple[tuple[float, ...], ...] | None = None
    contact_area_mm2: float | None = None
    contact_centroid_xy_mm: tuple[float, float] | None = None
    contact_outline_xy_mm: tuple[tuple[float, float], ...] | None = None
    contact_partial: bool | None = None
    part_centre_xy_mm: tuple[float, float] | None = None
    lift_azimuth_deg: float | None = None
    indentation_reference: str | None = None
    quality: str = "ok"

    def to_dict(self) -> dict:
        """The JSON form (``DESIGN.md``'s command-line contract): plain floats, lists and strings."""

        def plain(value):
            if isinstance(value, tuple | list):
                return [plain(v) for v in value]
            return value

        return {key: plain(value) for key, value in asdict(self).items()}


@dataclass(frozen=True)
class SensingResult:
    """Everything one run of the pipeline found, for overlays and analysis.

    Attributes
    ----------
    estimate : the reported estimate.
    left, right : the markers detected in each image (fiducials excluded).
    matches : the stereo matches (indices into ``left`` and ``right``).
    points_J : (M, 3) the triangulated matches in J (mm), one per match.
    used : (M,) which of them were fitted (the paper's crop, or the contact found).
    plane : the fitted plane (uncalibrated).
    frame : the cameras' pose in J and its source.
    identities : each point's reference marker and displacement (``refractive``).
    indentation : each point's indentation (``refractive``).
    contact : the contact footprint (``refractive``).
    uncertainty : the normal's uncertainty (``refractive``).
    """

    estimate: Estimate
    left: Markers
    right: Markers
    matches: StereoMatches
    points_J: np.ndarray
    used: np.ndarray
    plane: PlaneFit
    frame: JigFrame
    identities: MarkerIdentities | None = None
    indentation: Indentation | None = None
    contact: ContactRegion | None = None
    uncertainty: NormalUncertainty | None = None


@dataclass(frozen=True)
class SensingSetup:
    """What the estimator derives once from the nominal jig's geometry.

    Attributes
    ----------
    sigma_px : LoG scale matched to a marker at the membrane's apex, blur included (px).
    threshold : detection threshold on the scale-normalised LoG response.
    min_disparity_px, max_disparity_px : the disparity window of markers anywhere on the membrane.
    rest_apex_z_mm : height in J of the rest membrane's apex as the pinhole triangulation sees it: the
        push depth's zero. Refraction through flat layers puts a point of the oil at an apparent height in
        J (paraxially ``-t + t / n_plate + z / n_oil``) that does not depend on where the cameras are,
        so it is computed once, from the nominal geometry.
    marker : the marker and noise model of the sub-pixel fit (:mod:`softjig.sensing.subpixel`): a
        marker at the apex (radius and blur in px) and the config's imaging and medium (levels, speckle,
        shot and read noise, bit depth).
    candidates, refine : how :func:`~softjig.sensing.detect.detect_markers` finds and refines the markers
        (defaults: the pyramid and the model fit; ``"full"`` and ``"quadratic"`` are the straightforward
        path, Sakuma et al.'s). Markers blurred by less than ``MIN_MODEL_BLUR_PX`` (idealised
        simulations) are refined by the quadratic fit.
    """

    sigma_px: float
    threshold: float | None
    min_disparity_px: float
    max_disparity_px: float
    rest_apex_z_mm: float
    marker: MarkerModel | None = None
    candidates: str = DEFAULT_CANDIDATES
    refine: str | None = DEFAULT_REFINE


def sensing_setup(jig: JigConfig) -> SensingSetup:
    """Derive the detection scale, disparity window and push-depth reference from the nominal jig."""
    return _sensing_setup_cached(jig)


@cached_by_identity()
def _sensing_setup_cached(jig: JigConfig) -> SensingSetup:
    left, right = jig.cameras.left, jig.cameras.right
    layers = flat_layers(jig)
    apex = np.array([[0.0, 0.0, jig.membrane.dome_height_mm]])
    # px per mm at the apex (mean singular value of the projection's Jacobian in the marker's plane)
    jac = projection_jacobian(apex, left.K, left.distortion, left.T_J_cam, layers)[0][:, :2]
    px_per_mm = float(np.mean(np.linalg.svd(jac, compute_uv=False)))
    blur_mm = jig.medium.blur_coefficient * jig.membrane.dome_height_mm**1.5
    if jig.sensing.log_sigma_px is not None:
        sigma = jig.sensing.log_sigma_px
    else:
        sigma = log_sigma_px(jig.markers.diameter_mm * px_per_mm, blur_sigma_px=blur_mm * px_per_mm)
    radius_px = 0.5 * jig.markers.diameter_mm * px_per_mm
    marker = MarkerModel(
        radius_px=radius_px,
        blur_px=blur_mm * px_per_mm,
        background=jig.imaging.background_level,
        amplitude=jig.imaging.marker_level - jig.imaging.background_level,
        speckle_std=jig.medium.speckle_std,
        speckle_corr_px=jig.medium.bead_diameter_mm * px_per_mm,
        read_noise=jig.imaging.read_noise,
        full_well=jig.imaging.full_well_electrons,
        bit_depth=jig.imaging.bit_depth,
        half_width_px=max(2, round(1.25 * radius_px)),  # 1.3 % above the bound of a 25x25 window
    )
    # Disparities of markers anywhere between the rest membrane and the plate.
    xy = marker_layout_xy(jig)
    z_rest = rest_inner_height_mm(jig, xy[:, 0], xy[:, 1])
    points = np.concatenate([np.column_stack([xy, z_rest]), np.column_stack([xy, np.zeros(len(xy))])])
    u_left = project_points(points, left.K, left.distortion, left.T_J_cam, layers)
    u_right = project_points(points, right.K, right.distortion, right.T_J_cam, layers)
    disparity = u_left[:, 0] - u_right[:, 0]
    margin = jig.sensing.disparity_margin_px
    # The rest apex as the pinhole triangulation sees it: the reference of the push depth.
    pl = project_points(apex, left.K, left.distortion, left.T_J_cam, layers)
    pr = project_points(apex, right.K, right.distortion, right.T_J_cam, layers)
    apex_J = transform_points(left.T_J_cam, _triangulate(pl, pr, jig))
    return SensingSetup(
        sigma_px=float(sigma),
        threshold=jig.sensing.detection_threshold,
        min_disparity_px=float(max(disparity.min() - margin, 1.0)),
        max_disparity_px=float(disparity.max() + margin),
        rest_apex_z_mm=float(apex_J[0, 2]),
        marker=marker,
        # the model fit's weight tables need a profile smooth at the pixel scale (subpixel.MarkerModel)
        refine=DEFAULT_REFINE if marker.blur_px >= MIN_MODEL_BLUR_PX else "quadratic",
    )


def _triangulate(left_xy: np.ndarray, right_xy: np.ndarray, jig: JigConfig) -> np.ndarray:
    cam = jig.cameras.left
    return triangulate_rectified(
        left_xy,
        right_xy,
        fx_px=cam.fx_px,
        fy_px=cam.fy_px,
        cx_px=cam.cx_px,
        cy_px=cam.cy_px,
        baseline_mm=jig.cameras.baseline_mm,
    )


def _checked_pair(
    left: np.ndarray, right: np.ndarray, jig: JigConfig
) -> tuple[np.ndarray, np.ndarray, tuple[str, ...]]:
    """The pair's gray images in their own dtype (``uint8``/``uint16``, or float32 in [0, 1]), checked,
    and warnings.

    Nothing is converted to float: the content checks read a 1-in-64 subsample, and the same-image test
    compares a 1-in-64 subsample first (different images almost always differ there). ``uint16`` images
    of a 10-, 12- or 14-bit camera (only the low bits used, :func:`~softjig.sensing.detect.packed_bit_depth`)
    are scaled to the 16-bit range, with a warning that names it.
    """
    grays = []
    for name, image in (("left", left), ("right", right)):
        try:
            gray, _ = gray_image(image)
        except InputError as exc:
            raise InputError(f"{name} image: {exc}") from None
        grays.append(gray)
    warnings: tuple[str, ...] = ()
    bits = packed_bit_depth(*grays) if grays[0].shape == grays[1].shape else None
    if bits is not None:
        grays = [unpack_bit_depth(g, bits) for g in grays]
        warnings = (
            f"the 16-bit images use only their low {bits} bits (brightest value below {2**bits}): read as "
            f"{bits}-bit counts and scaled by {2 ** (16 - bits)} to the 16-bit range; save the camera's "
            "frames scaled to full range to silence this",
        )
    if grays[0].shape != grays[1].shape:
        raise InputError(
            f"the left image is {grays[0].shape[1]}x{grays[0].shape[0]} px but the right one is "
            f"{grays[1].shape[1]}x{grays[1].shape[0]}: pass the two images of one stereo pair"
        )
    cam = jig.cameras.left
    if grays[0].shape != (cam.height_px, cam.width_px):
        raise InputError(
            f"the images are {grays[0].shape[1]}x{grays[0].shape[0]} px but the config's cameras are "
            f"{cam.width_px}x{cam.height_px}: pass the rig.toml of the cameras that took them"
        )
    for name, gray in zip(("left", "right"), grays, strict=True):
        check_image_content(gray, name=f"the {name} image")
    same_sample = grays[0].dtype == grays[1].dtype and np.array_equal(grays[0][::8, ::8], grays[1][::8, ::8])
    if same_sample and np.array_equal(grays[0], grays[1]):
        raise InputError("the left and right images are the same image: pass the two views of a stereo pair")
    return grays[0], grays[1], warnings


@dataclass(frozen=True)
class Observation:
    """What both methods share: the detected markers, their matches and the cameras' pose.

    Attributes
    ----------
    left, right : markers detected in each image, fiducials excluded.
    matches : the stereo matches.
    frame : the cameras' poses in J.
    warnings : from the front end (e.g. fiducials not found).
    """

    left: Markers
    right: Markers
    matches: StereoMatches
    frame: JigFrame
    warnings: tuple[str, ...] = field(default=())

    @property
    def left_xy_px(self) -> np.ndarray:
        """(M, 2) matched centres in the left image."""
        return self.left.xy_px[self.matches.left_index]

    @property
    def right_xy_px(self) -> np.ndarray:
        """(M, 2) matched centres in the right image."""
        return self.right.xy_px[self.matches.right_index]


def observe_pair(
    left: np.ndarray,
    right: np.ndarray,
    jig: JigConfig,
    clock: _StageClock | None = None,
    *,
    fast: bool = True,
) -> Observation:
    """Check a stereo pair, find the jig frame, detect and match the markers (both methods' front end).

    ``fast=False`` runs the straightforward implementation of every stage (full ArUco detection,
    full-resolution LoG candidates, the reference matching), for checking the fast one against.

    Raises
    ------
    InputError
        Bad images (size, dtype, blank or saturated, the same image twice) or an unrectified config.
    EstimationError
        Fiducials required (``sensing.extrinsics = "fiducials"``) but not found.
    """
    clock = clock or _StageClock(None)
    if not jig.cameras.rectified:
        raise InputError(
            "the config's cameras are not a rectified pair (cameras.rectified = false): rectify the images "
            "first, with the stereo calibration of the cameras"
        )
    gray_left, gray_right, image_warnings = _checked_pair(left, right, jig)
    u8_left, u8_right = _as_u8(left, gray_left), _as_u8(right, gray_right)
    setup = sensing_setup(jig)
    clock.lap("checks")
    frame, warnings = resolve_jig_frame(u8_left, u8_right, jig, fast=fast)
    warnings = [*image_warnings, *warnings]
    clock.lap("frame")
    candidates = setup.candidates if fast else "full"
    kwargs = {"sigma_px": setup.sigma_px, "candidates": candidates, "refine": setup.refine}
    if setup.threshold is not None:
        kwargs["threshold"] = setup.threshold
    if setup.marker is not None:
        kwargs["model"] = setup.marker
    markers_left = detect_markers(gray_left, exclude=_on_fiducials(frame.fiducial_quads_left_px), **kwargs)
    markers_right = detect_markers(gray_right, exclude=_on_fiducials(frame.fiducial_quads_right_px), **kwargs)
    clock.lap("detect")
    matches = match_rectified(
        markers_left.xy_px,
        markers_right.xy_px,
        row_tolerance_px=jig.sensing.row_tolerance_px,
        min_disparity_px=setup.min_disparity_px,
        max_disparity_px=setup.max_disparity_px,
    )
    if len(matches) < 0.5 * min(len(markers_left), len(markers_right)):
        _refuse_swapped(markers_left, markers_right, matches, setup, jig)
        warnings = [
            *warnings,
            f"only {len(matches)} of {min(len(markers_left), len(markers_right))} markers were matched "
            "between the images: check the rectification and sensing.row_tolerance_px",
        ]
    clock.lap("match")
    return Observation(markers_left, markers_right, matches, frame, tuple(warnings))


def _refuse_swapped(
    left: Markers, right: Markers, matches: StereoMatches, setup: SensingSetup, jig: JigConfig
) -> None:
    """Raise :class:`InputError` when the pair's markers match far better with the images swapped.

    In a rectified pair a point's disparity ``u_left - u_right`` is positive (the right camera sits at
    ``+x``): swapped images give every marker a negative one, outside the jig's disparity window, so
    few markers match, and the fiducials' poses disagree. Called only when few markers matched.
    """
    swapped = match_rectified(
        right.xy_px,
        left.xy_px,
        row_tolerance_px=jig.sensing.row_tolerance_px,
        min_disparity_px=setup.min_disparity_px,
        max_disparity_px=setup.max_disparity_px,
    )
    fewest = min(len(left), len(right))
    if len(swapped) >= SWAPPED_MATCH_SHARE * fewest and len(swapped) > SWAPPED_MATCH_FACTOR * len(matches):
        raise InputError(
            f"the left and right images look swapped: {len(swapped)} of {fewest} markers match with a "
            f"positive disparity when the first image is taken as the right camera's, {len(matches)} as "
            "given; pass LEFT RIGHT in that order (the left camera's image first)"
        )


def reference_from_pair(left: np.ndarray, right: np.ndarray, jig: JigConfig) -> ReferenceMarkers:
    """Triangulate a stereo pair of the unloaded jig into the reference for indentations and identities.

    Raises
    ------
    EstimationError
        Fewer markers than ``sensing.min_points`` were matched.
    """
    observation = observe_pair(left, right, jig)
    points = triangulate_refracted(observation.left_xy_px, observation.right_xy_px, jig, observation.frame)
    if len(points.points_J) < jig.sensing.min_points:
        raise EstimationError(
            f"the reference pair gave only {len(points.points_J)} markers: is it a pair of the unloaded jig?"
        )
    return ReferenceMarkers(points.points_J, "reference frame")


def estimate_pair(
    left: np.ndarray,
    right: np.ndarray,
    jig: JigConfig,
    *,
    part_diameter_mm: float | None = None,
    calibration: TiltCalibration | None = None,
    method: str = DEFAULT_METHOD,
    reference: ReferenceMarkers | None = None,
    timings: dict[str, float] | None = None,
    fast: bool = True,
) -> SensingResult:
    """Estimate the principal normal of the part on the jig from one rectified stereo pair.

    Parameters
    ----------
    left, right : (H, W) or (H, W, 3) uint8 or uint16 images of the nominal jig's cameras (RGB); a raw
        (unrectified) pair when ``jig.cameras.rectified`` is false, rectified first
        (:func:`softjig.sensing.rectify.rectify_pair`).
    jig : the nominal jig (the estimator never knows the as-built one).
    part_diameter_mm : diameter of the part's base (mm). The paper's method needs it (markers within half
        of it from the jig axis are fitted); ours does not, and uses it only to judge partial contact.
    calibration : the paper's tilt calibration to apply, if any.
    method : ``"refractive"`` (the default: ours) or ``"paper"`` (exactly as published).
    reference : the unloaded jig's markers (:func:`reference_from_pair`), for ``"refractive"``; the
        nominal rest shape when ``None``.
    timings : if given, filled with each stage's wall time in seconds (``checks``, ``frame``,
        ``detect``, ``match``, ``triangulate``, ``fit``).
    fast : ``False`` runs the straightforward implementation of each stage (same method, same results
        within rounding; see :func:`observe_pair`), ten times slower: for checking the fast one.

    Returns
    -------
    SensingResult
        The estimate and what led to it; pixel coordinates are in the rectified images.

    Raises
    ------
    InputError
        Bad images (size, dtype, blank or saturated), a bad diameter or method.
    EstimationError
        No contact or too few markers in it (fewer than ``sensing.min_points``), points that do not
        define a plane, or fiducials required but not found.
    """
    if method not in METHODS:
        raise InputError(f"unknown method {method!r}; valid: {', '.join(METHODS)}")
    _check_part_diameter(part_diameter_mm, jig)
    if calibration is not None and calibration.method not in (None, method):
        raise InputError(
            f"the tilt calibration was fitted to the {calibration.method} method's estimates and does not "
            f"apply to the {method} method's: estimate with --method {calibration.method}, or calibrate "
            f"again with --method {method}"
        )
    if method == "paper" and part_diameter_mm is None:
        raise InputError("the paper's method needs the part's base diameter (--part-diameter MM)")
    clock = _StageClock(timings)
    if not jig.cameras.rectified:  # a raw pair: rectify it with the stereo calibration in the config
        left, right, jig = rectify_pair(left, right, jig)
    observation = observe_pair(left, right, jig, clock, fast=fast)
    if method == "paper":
        result = _paper_estimate(observation, jig, part_diameter_mm, calibration, clock)
    else:
        result = _refractive_estimate(
            observation, jig, part_diameter_mm, calibration, reference, clock, fast=fast
        )
    clock.lap("fit")
    return result


def _check_part_diameter(part_diameter_mm: float | None, jig: JigConfig) -> None:
    """A part's base diameter must be a positive, finite number of mm smaller than the membrane."""
    if part_diameter_mm is None:
        return
    if not (np.isfinite(part_diameter_mm) and part_diameter_mm > 0):
        raise InputError(f"the part diameter must be a positive number of mm, got {part_diameter_mm}")
    membrane = 2.0 * jig.membrane.footprint_radius_mm
    if part_diameter_mm >= membrane:
        raise InputError(
            f"the part diameter ({part_diameter_mm:g} mm) must be smaller than the membrane "
            f"(2 x membrane.footprint_radius_mm = {membrane:g} mm): give the diameter of the part's base "
            "in mm"
        )


def _mm(value: float) -> str:
    """A length for a message: ``"0.07 mm"``, or ``"unknown"`` (never ``nan mm``)."""
    return f"{value:.2f} mm" if np.isfinite(value) else "unknown"


def _calibrated(
    plane: PlaneFit, calibration: TiltCalibration | None
) -> tuple[float, float, float, float, np.ndarray]:
    """Raw and calibrated tilt angles (rad) and the calibrated normal."""
    raw_ax, raw_ay = (float(v) for v in tilt_angles(plane.normal))
    if calibration is None or calibration.is_identity():
        return raw_ax, raw_ay, raw_ax, raw_ay, plane.normal
    ax, ay = (float(v) for v in calibration.apply(raw_ax, raw_ay))
    return raw_ax, raw_ay, ax, ay, normal_from_tilt_angles(ax, ay)


def _common_fields(
    observation: Observation,
    plane: PlaneFit,
    calibration,
    method,
    part_diameter_mm,
    n_used: int,
    warnings: list[str],
) -> dict:
    raw_ax, raw_ay, ax, ay, normal = _calibrated(plane, calibration)
    return {
        "normal": tuple(float(v) for v in normal),
        "tilt_x_deg": float(np.degrees(ax)),
        "tilt_y_deg": float(np.degrees(ay)),
        "n_points": n_used,
        "rms_residual_mm": plane.rms_residual_mm,
        "frame_source": observation.frame.source,
        "warnings": tuple(warnings),
        "method": method,
        "calibrated": calibration is not None and not calibration.is_identity(),
        "raw_tilt_x_deg": float(np.degrees(raw_ax)),
        "raw_tilt_y_deg": float(np.degrees(raw_ay)),
        "part_diameter_mm": None if part_diameter_mm is None else float(part_diameter_mm),
        "n_markers_left": len(observation.left),
        "n_markers_right": len(observation.right),
        "n_matches": len(observation.matches),
    }


def _paper_estimate(
    observation: Observation,
    jig: JigConfig,
    part_diameter_mm: float,
    calibration: TiltCalibration | None,
    clock: _StageClock,
) -> SensingResult:
    setup = sensing_setup(jig)
    matches = observation.matches
    points_cam = (
        _triangulate(observation.left_xy_px, observation.right_xy_px, jig)
        if len(matches)
        else np.zeros((0, 3))
    )
    points_J = transform_points(observation.frame.T_J_left, points_cam)
    clock.lap("triangulate")
    radius = part_diameter_mm / 2.0
    used = np.hypot(points_J[:, 0], points_J[:, 1]) < radius
    n_used = int(used.sum())
    minimum = jig.sensing.min_points
    if n_used < minimum:
        raise EstimationError(
            f"only {n_used} markers lie within {radius:g} mm of the jig axis (the part's base radius); at "
            f"least {minimum} are needed (sensing.min_points). Detected {len(observation.left)} left / "
            f"{len(observation.right)} right, matched {len(matches)}: is a part on the jig, centred, and is "
            "the part diameter right?"
        )
    plane = _fit_or_fail(points_J[used], minimum)
    warnings = list(observation.warnings)
    # The statistical uncertainty and the self-check of the crop's points (the crop is not robust: a
    # plane through the drape beside the face shows in its halves); the method's uncalibrated tilts are
    # compressed by about the oil's index, which its tilt calibration absorbs and no sigma covers.
    points = points_J[used]
    sigma = inflated(normal_uncertainty(points, plane, floor_mm=UNCERTAINTY_FLOOR_MM), MODEL_ERROR_FACTOR)
    split = split_halves(points, point_sigma_mm=sigma.residual_sigma_mm, noise_factor=MODEL_ERROR_FACTOR)
    sigma_rad = sigma.tilt_sigma_rad
    if split is not None:
        sigma_rad = float(np.hypot(sigma_rad, 0.5 * split.excess_rad))
    sigma_rad = float(np.hypot(sigma_rad, np.radians(NORMAL_ANGLE_FLOOR_DEG)))
    suspect = _suspicions(split, 0, plane, None, None, jig, n_used, minimum)
    warnings.extend(suspect)
    estimate = Estimate(
        tilt_sigma_deg=float(np.degrees(sigma_rad)),
        quality="suspect" if suspect else "ok",
        push_depth_mm=setup.rest_apex_z_mm - plane.z_at(0.0, 0.0),
        **_common_fields(observation, plane, calibration, "paper", part_diameter_mm, n_used, warnings),
    )
    return SensingResult(
        estimate, observation.left, observation.right, matches, points_J, used, plane, observation.frame
    )


def _fit_or_fail(points: np.ndarray, minimum: int) -> PlaneFit:
    try:
        return fit_plane_svd(points, min_points=minimum)
    except InputError as exc:
        raise EstimationError(f"no plane could be fitted: {exc}") from None


def _reference_height_at_axis(reference: ReferenceMarkers, pitch_mm: float) -> float:
    """Height of the reference membrane on the jig axis: a quadratic surface through its nearest markers.

    Computed once per reference and pitch (it cost 0.1 ms per estimate, measured) and kept with it.
    """
    key = ("height_at_axis", pitch_mm)
    if key in reference._cache:
        return reference._cache[key]
    xyz = reference.xyz_mm
    near = np.hypot(xyz[:, 0], xyz[:, 1]) < 2.5 * pitch_mm
    if near.sum() < 6:
        height = float(xyz[np.argmin(np.hypot(xyz[:, 0], xyz[:, 1])), 2])
    else:
        x, y, z = xyz[near].T
        design = np.column_stack([np.ones_like(x), x, y, x * x, x * y, y * y])
        height = float(np.linalg.lstsq(design, z, rcond=None)[0][0])
    reference._cache[key] = height
    return height


def _contact_under_known_face(
    points_J: np.ndarray,
    dent: Indentation,
    candidates: np.ndarray,
    radius_mm: float,
    fit,
    minimum: int,
    jig: JigConfig,
    noise_mm: float,
    threshold_mm: float,
    size_free: Callable[[], tuple[np.ndarray, PlaneFit]] | None = None,
) -> tuple[np.ndarray, PlaneFit, SplitCheck | None]:
    """The contact when the part's base radius is known, wherever the part stands on the jig, and the
    agreement with a rival contact that no marker contradicts either but whose normal is far from it
    (``None`` when there is none: the estimate is suspect when there is).

    - **The face searched from the indentation** (:func:`_search_face`): from the jig axis (the paper's
      setting) and, when the dent's centroid lies :data:`OFF_AXIS_DENT_RADII` radii or more off the
      axis, from there too, keeping the one whose plane fewer markers contradict
      (:func:`~softjig.sensing.contact.contact_violations`), then the larger contact. On the paper's
      sweep it is right where the size-free growth takes the wall beside a small, steeply tilted part
      (30 mm at 15-20 deg).
    - When no search finds a face, or only one of fewer than :data:`SELF_CHECK_MIN_POINTS` markers (too
      few to check), **the size-free contact cut to the face** (``size_free()``:
      :func:`~softjig.sensing.contact.grow_contact`'s markers and plane, made only then): the face placed
      where that contact puts it (:func:`~softjig.sensing.contact.face_centre_xy`), and that contact's
      markers under it; taken over a small search's contact only when it has enough markers to check and
      passes the checks (no violations, halves that agree).
    - **Rivals** (:func:`_rival`): two searched faces, or a search's face and the cut, that no marker
      contradicts but whose normals disagree beyond their noise (:func:`~softjig.sensing.selfcheck.
      agreement`): the frame holds two plausible faces (the part's and a strip of the membrane's wall
      beside a small contact), and the estimate is suspect whichever is reported.
    """
    pitch = jig.markers.pitch_mm
    ways = []
    searches = []
    rival = None
    dent_centre = points_J[candidates, :2].mean(axis=0) if candidates.any() else np.zeros(2)
    starts = [None] if np.hypot(*dent_centre) < OFF_AXIS_DENT_RADII * radius_mm else [None, dent_centre]
    for start in starts:  # from the jig axis and, for a dent off the axis, from the dent's centroid
        try:
            searches.append(
                _search_face(points_J, dent, candidates, radius_mm, fit, minimum, jig, noise_mm, start)
            )
        except EstimationError:
            continue
    if len(searches) > 1:  # the one whose plane fewer markers contradict, then the larger contact
        scores = [
            (
                contact_violations(
                    points_J, used, plane, threshold_mm=threshold_mm, pitch_mm=pitch, dent=dent
                ),
                -used.sum(),
            )
            for used, plane in searches
        ]
        best = min(range(len(scores)), key=scores.__getitem__)
        rival = (
            _rival(points_J, searches[best], searches[1 - best], threshold_mm)
            if scores[1 - best][0] == 0
            else None
        )
        searches = [searches[best]]
    elif (
        len(searches) == 1
        and searches[0][0].sum() < SELF_CHECK_MIN_POINTS + MIN_HALF_POINTS
        and np.hypot(*dent_centre) >= RIVAL_SEARCH_PITCHES * pitch
    ):
        rival = _rival_search(
            points_J,
            dent,
            candidates,
            radius_mm,
            fit,
            minimum,
            jig,
            noise_mm,
            threshold_mm,
            searches[0],
            dent_centre,
        )
    ways.extend(searches)
    grown = None
    few = not ways or ways[0][0].sum() < SELF_CHECK_MIN_POINTS
    if few and size_free is not None:  # computed only then: it costs 0.7 ms (measured)
        try:
            grown, grown_plane = size_free()
        except EstimationError:
            grown = None
    if grown is not None and grown.sum() >= minimum:
        region = describe_contact(
            points_J[grown, :2], grown_plane, jig, noise_mm=noise_mm, part_diameter_mm=2 * radius_mm
        )
        centre = face_centre_xy(points_J[grown, :2], region, grown_plane, radius_mm, pitch_mm=pitch)
        # Half a pitch of slack (the footprint's markers stand for grid cells); the markers are already
        # the inliers of a robust fit: a least-squares refit suffices.
        selection = grown & under_face(points_J, grown_plane, radius_mm + pitch / 2.0, centre)
        if not ways and selection.sum() >= minimum:
            ways.append((selection, _fit_or_fail(points_J[selection], minimum)))
        elif selection.sum() >= SELF_CHECK_MIN_POINTS:  # the search's contact is too small to check
            cut = (selection, _fit_or_fail(points_J[selection], minimum))
            check = split_halves(
                points_J[selection],
                point_sigma_mm=threshold_mm / CONTACT_INLIER_SIGMAS,
                noise_factor=MODEL_ERROR_FACTOR,
            )
            violations = contact_violations(
                points_J, *cut, threshold_mm=threshold_mm, pitch_mm=pitch, dent=dent
            )
            if check is not None and not check.suspect and violations == 0:
                # A larger contact that passes the self-check, taken; suspect if it contradicts a search's
                # face that no marker contradicts either (on the zoo the cut was right in 2 of 3 such
                # frames, the search's small face in the third).
                ways.insert(0, cut)
                rival = _plausible_rival(points_J, ways[1], cut, threshold_mm, pitch, dent)
    if not ways:
        raise EstimationError(
            f"no {2 * radius_mm:g} mm face was found in the contact: fewer than {minimum} pushed-in markers "
            "lie under it (sensing.min_points); is the part's size right?"
        )
    return (*ways[0], rival)


def _rival_search(
    points_J, dent, candidates, radius_mm, fit, minimum, jig, noise_mm, threshold_mm, search, start
):
    """The robust plane of the pushed-in markers within ``radius_mm`` of ``start`` (one fit, not a
    :func:`_search_face`: that cost 1.1 ms on the default pair, measured), as a rival of ``search``
    when the two disagree and no marker contradicts either; else ``None``."""
    selection = (dent.depth_mm > dent.noise_mm) & _within(points_J, start, radius_mm)
    if selection.sum() < minimum:
        return None
    inliers, plane = fit(points_J[selection])
    used = np.zeros(len(points_J), dtype=bool)
    used[np.flatnonzero(selection)[inliers]] = True
    if used.sum() < minimum or _rival(points_J, search, (used, plane), threshold_mm) is None:
        return None  # they agree: the violations (0.2 ms) are not counted
    pitch = jig.markers.pitch_mm
    if contact_violations(points_J, used, plane, threshold_mm=threshold_mm, pitch_mm=pitch, dent=dent):
        return None
    return _plausible_rival(points_J, search, (used, plane), threshold_mm, pitch, dent)


def _plausible_rival(points_J, search, cut, threshold_mm: float, pitch_mm: float, dent) -> SplitCheck | None:
    """The ``search``'s face's disagreement with the ``cut`` (:func:`_rival`), when no marker contradicts
    the search's face either; else ``None``."""
    used, plane = search
    if contact_violations(points_J, used, plane, threshold_mm=threshold_mm, pitch_mm=pitch_mm, dent=dent):
        return None
    return _rival(points_J, cut, search, threshold_mm)


def _rival(points_J: np.ndarray, chosen, other, threshold_mm: float) -> SplitCheck | None:
    """``other``'s agreement with the ``chosen`` contact (each ``(used, plane)``) when it contradicts it
    (:func:`~softjig.sensing.selfcheck.agreement`), else ``None``."""
    check = agreement(
        points_J[chosen[0]],
        chosen[1].normal,
        points_J[other[0]],
        other[1].normal,
        point_sigma_mm=threshold_mm / CONTACT_INLIER_SIGMAS,
        noise_factor=MODEL_ERROR_FACTOR,
    )
    return check if check is not None and check.suspect else None


def _search_face(
    points_J: np.ndarray,
    dent: Indentation,
    candidates: np.ndarray,
    radius_mm: float,
    fit,
    minimum: int,
    jig: JigConfig,
    noise_mm: float,
    start_xy: np.ndarray | None = None,
) -> tuple[np.ndarray, PlaneFit]:
    """The contact under a face of ``radius_mm``, searched from the indentation (from ``start_xy``, when
    given, instead of the jig axis).

    The face is a tilted disc (a polygon's inscribed disc), so its footprint on the membrane is an
    ellipse, not the paper's circle, and it is centred where the part stands, not on the jig axis. The
    face's centre is first taken on the jig axis (the paper's setting; the centroid of the clearly
    pushed-in markers, ``candidates``, when none lies under a face there); the pushed-in markers within
    ``radius_mm`` of it are fitted robustly once (their plane gives the tilt),
    then only those under the face (within ``radius_mm`` of its centre *measured in the face's plane*,
    :func:`~softjig.sensing.contact.under_face`) are fitted again. The centre is then moved to where the
    contact found puts the face (:func:`~softjig.sensing.contact.face_centre_xy`: the footprint's
    centroid in full contact, one radius uphill of the lowered rim in partial contact), and the whole
    repeated until it moves by less than :data:`FACE_CENTRE_TOLERANCE_PITCHES` pitches (at most
    :data:`FACE_CENTRE_ROUNDS` times); a face found on the axis stays there when the contact puts its
    centre within :data:`CENTRED_SHARE` radii of it (a small contact's centre is uncertain: from the
    indentation's centroid, the search of a 30 mm part at 20 deg drifted onto the wall). The membrane's
    wall beside the lowered edge lies outside the ellipse; where the part lifts off, the one-sided robust
    fit rejects the markers below the face.
    """
    pushed = dent.depth_mm > dent.noise_mm  # False where NaN (unknown)
    pitch = jig.markers.pitch_mm
    tolerance = FACE_CENTRE_TOLERANCE_PITCHES * pitch
    centre = np.zeros(2) if start_xy is None else np.asarray(start_xy, dtype=float)
    used, plane = None, None
    for round_ in range(FACE_CENTRE_ROUNDS):
        found = _fit_under_face(points_J, pushed, centre, radius_mm, fit, minimum)
        if found is None:
            if round_ == 0 and candidates.any():  # nothing under a centred face: start where the dent is
                centre = points_J[candidates, :2].mean(axis=0)
                continue
            break
        used, plane = found
        region = describe_contact(
            points_J[used, :2], plane, jig, noise_mm=noise_mm, part_diameter_mm=2 * radius_mm
        )
        moved_to = np.array(face_centre_xy(points_J[used, :2], region, plane, radius_mm, pitch_mm=pitch))
        if np.hypot(*(moved_to - centre)) < tolerance:
            break
        if not centre.any() and np.hypot(*moved_to) < CENTRED_SHARE * radius_mm:
            break  # about centred: kept on the axis (a small contact's centre is uncertain by a pitch)
        centre = moved_to
    if used is None:
        raise EstimationError(
            f"only {int((pushed & _within(points_J, centre, radius_mm)).sum())} pushed-in markers lie "
            f"within {radius_mm:g} mm of the contact's centre ({centre[0]:+.1f}, {centre[1]:+.1f}) mm; at "
            f"least {minimum} are needed (sensing.min_points): is the part's size right?"
        )
    return used, plane


def _within(points_J: np.ndarray, centre_xy: np.ndarray, radius_mm: float) -> np.ndarray:
    return np.hypot(points_J[:, 0] - centre_xy[0], points_J[:, 1] - centre_xy[1]) < radius_mm


def _fit_under_face(
    points_J: np.ndarray, pushed: np.ndarray, centre_xy: np.ndarray, radius_mm: float, fit, minimum: int
) -> tuple[np.ndarray, PlaneFit] | None:
    """The robust contact under a face of ``radius_mm`` centred above ``centre_xy`` (``None``: too few)."""
    selection = pushed & _within(points_J, centre_xy, radius_mm)
    if selection.sum() < minimum:
        return None
    plane = None
    for _ in range(3):
        inliers, plane = fit(points_J[selection])
        used = np.zeros(len(points_J), dtype=bool)
        used[np.flatnonzero(selection)[inliers]] = True
        new_selection = pushed & under_face(points_J, plane, radius_mm, tuple(centre_xy))
        if np.array_equal(new_selection, selection) or new_selection.sum() < minimum:
            break
        selection = new_selection
    return used, plane


def _refractive_estimate(
    observation: Observation,
    jig: JigConfig,
    part_diameter_mm: float | None,
    calibration: TiltCalibration | None,
    reference: ReferenceMarkers | None,
    clock: _StageClock,
    *,
    fast: bool = True,
) -> SensingResult:
    matches = observation.matches
    triangulated = triangulate_refracted(
        observation.left_xy_px, observation.right_xy_px, jig, observation.frame
    )
    points_J = triangulated.points_J
    clock.lap("triangulate")
    reference = reference or rest_shape_reference(jig)
    identities = identify_markers(points_J, reference, max_lateral_mm=jig.markers.pitch_mm / 2.0)
    known = identities.ids >= 0
    reference_z = reference.xyz_mm[np.maximum(identities.ids, 0), 2]
    if not known.all():  # the rest shape where no reference marker is near
        unknown = points_J[~known]
        reference_z[~known] = rest_inner_height_mm(jig, unknown[:, 0], unknown[:, 1])
    dent = indentation(points_J, reference_z, pitch_mm=jig.markers.pitch_mm)
    noise = _noise_scales(points_J, dent, reference, jig)
    candidates = contact_candidates(dent)
    minimum = jig.sensing.min_points
    if candidates.sum() < minimum:
        raise EstimationError(
            f"no contact: only {int(candidates.sum())} of {len(points_J)} matched markers are pushed in "
            f"beyond the noise ({_mm(dent.noise_mm)}); at least {minimum} are needed (sensing.min_points). "
            "Is a part pressed onto the jig?"
        )
    # Contact: under the known face (when the part's size is given), or grown from the deepest pushed-in
    # markers over the neighbours on their plane; planes are fitted robustly, with an inlier distance set
    # by the markers' own depth noise.
    threshold = CONTACT_INLIER_SIGMAS * noise.plane_sigma_mm

    def fit(points: np.ndarray) -> tuple[np.ndarray, PlaneFit]:
        try:
            robust = fit_plane_robust(points, threshold_mm=threshold, min_inliers=min(minimum, len(points)))
        except InputError as exc:
            raise EstimationError(f"no plane could be fitted to the pushed-in markers: {exc}") from None
        return robust.inliers, robust.plane

    # The robust fits draw random triples by position in the list: in the reference markers' order, two
    # runs whose markers differ only by rounding (the fast and the straightforward implementation, whose
    # detections are listed by slightly different responses) draw the same triples.
    order = _canonical_order(identities.ids, points_J)
    in_order = Indentation(dent.depth_mm[order], dent.zero_mm, dent.noise_mm)

    def size_free_contact() -> tuple[np.ndarray, PlaneFit]:
        return grow_contact(
            points_J[order],
            in_order,
            candidates[order],
            pitch_mm=jig.markers.pitch_mm,
            fit_plane=fit,
            threshold_mm=threshold,
            min_points=minimum,
        )

    if part_diameter_mm is not None:
        used_in_order, plane, rival = _contact_under_known_face(
            points_J[order],
            in_order,
            candidates[order],
            part_diameter_mm / 2.0,
            fit,
            minimum,
            jig,
            noise.indentation_sigma_mm,
            threshold,
            size_free_contact,
        )
    else:
        (used_in_order, plane), rival = size_free_contact(), None
    used = np.empty_like(used_in_order)
    used[order] = used_in_order
    if used.sum() < minimum:
        raise EstimationError(
            f"only {int(used.sum())} markers are in contact; at least {minimum} are needed "
            "(sensing.min_points)"
        )
    if part_diameter_mm is None:  # under a known face, the plane is already the SVD fit of points_J[used]
        plane = _fit_or_fail(points_J[used], minimum)
    grown = used
    clearance = LIFT_OFF_SIGMAS * noise.face_depth_sigma_mm
    used, plane = drop_lifted_off(
        points_J,
        dent,
        used,
        plane,
        clearance_mm=clearance,
        fit_plane=lambda points: _fit_or_fail(points, minimum),
        min_points=minimum,
    )
    uncertainty = normal_uncertainty(points_J[used], plane, floor_mm=UNCERTAINTY_FLOOR_MM)
    plane_depth = face_depth_mm(points_J, dent, plane)  # used twice below
    narrow, wide = ambiguous_selection(
        points_J,
        dent,
        used,
        grown & ~used,
        plane,
        clearance_mm=clearance,
        margin_mm=noise.face_depth_sigma_mm,
        face_depth=plane_depth,
    )
    if narrow.sum() >= minimum and not np.array_equal(narrow, wide):
        # ``plane`` is the fit of ``points_J[used]``: not fitted again where a selection is ``used``.
        uncertainty = with_spread_between(
            uncertainty,
            plane.normal if np.array_equal(narrow, used) else _fit_or_fail(points_J[narrow], minimum).normal,
            plane.normal if np.array_equal(wide, used) else _fit_or_fail(points_J[wide], minimum).normal,
        )
    uncertainty = inflated(uncertainty, MODEL_ERROR_FACTOR)
    split = split_halves(
        points_J[used],
        point_sigma_mm=max(noise.plane_sigma_mm, UNCERTAINTY_FLOOR_MM),
        noise_factor=MODEL_ERROR_FACTOR,
    )
    if split is not None and split.excess_rad > 0:  # what the halves show beyond their noise
        uncertainty = with_spread_between(
            uncertainty, split.normal_a, split.normal_b, share=split.excess_rad / split.angle_rad
        )
    uncertainty = with_angle_floor(uncertainty, plane.normal, np.radians(NORMAL_ANGLE_FLOOR_DEG))
    if observation.frame.source != "fiducials" and calibration is None:
        # The cameras' poses are the config's, not measured: the stereo head's rotation error (its
        # tolerance per axis, tolerances.camera_rotation_deg) tilts the normal by as much, about x and y.
        head_rad = np.radians(jig.tolerances.camera_rotation_deg)
        uncertainty = with_angle_floor(uncertainty, plane.normal, math.sqrt(2.0) * head_rad)
    outside = just_outside(points_J[:, :2], used, jig.markers.pitch_mm)
    contact = describe_contact(
        points_J[used, :2],
        plane,
        jig,
        noise_mm=dent.noise_mm,
        part_diameter_mm=part_diameter_mm,
        edge_face_depth_mm=plane_depth[outside],
    )
    part_centre = (
        None
        if part_diameter_mm is None
        else face_centre_xy(
            points_J[used, :2], contact, plane, part_diameter_mm / 2.0, pitch_mm=jig.markers.pitch_mm
        )
    )
    warnings = list(observation.warnings)
    n_used = int(used.sum())  # too few to check: a "suspect" reason (_suspicions)
    if contact.partial:
        warnings.append(
            f"partial contact: the part lifts off towards azimuth {contact.lift_azimuth_deg:.0f} deg; only "
            "the markers in contact were fitted"
        )
    suspect = _suspicions(
        split,
        contact_violations(
            points_J, used, plane, threshold_mm=threshold, pitch_mm=jig.markers.pitch_mm, dent=dent
        ),
        plane,
        contact,
        part_diameter_mm,
        jig,
        n_used,
        minimum,
    )
    if rival is not None:
        suspect.append(
            f"suspect: another contact fits the frame as well, its normal "
            f"{np.degrees(rival.angle_rad):.1f} deg from this one's ({rival.sigmas:.0f} times their noise): "
            "the frame may show the membrane's wall beside a small contact"
        )
    n_candidates = int(candidates.sum())
    if part_diameter_mm is None and n_used < MIN_CANDIDATE_SHARE * n_candidates:  # size-free only:
        suspect.append(
            f"suspect: only {n_used} of the {n_candidates} clearly pushed-in markers were fitted: a face "
            "presses most of its dent, the plane may be a strip of the membrane's wall"
        )
    warnings.extend(suspect)
    push = _reference_height_at_axis(reference, jig.markers.pitch_mm) - dent.zero_mm - plane.z_at(0.0, 0.0)
    estimate = Estimate(
        quality="suspect" if suspect else "ok",
        push_depth_mm=float(push),
        tilt_sigma_x_deg=float(np.degrees(uncertainty.tilt_sigma_x_rad)),
        tilt_sigma_y_deg=float(np.degrees(uncertainty.tilt_sigma_y_rad)),
        tilt_sigma_deg=float(np.degrees(uncertainty.tilt_sigma_rad)),
        normal_covariance=tuple(tuple(float(v) for v in row) for row in uncertainty.covariance),
        contact_area_mm2=contact.area_mm2,
        contact_centroid_xy_mm=contact.centroid_xy_mm,
        contact_outline_xy_mm=tuple((float(x), float(y)) for x, y in contact.outline_xy_mm),
        contact_partial=contact.partial,
        part_centre_xy_mm=part_centre,
        lift_azimuth_deg=contact.lift_azimuth_deg,
        indentation_reference=reference.source,
        **_common_fields(observation, plane, calibration, "refractive", part_diameter_mm, n_used, warnings),
    )
    return SensingResult(
        estimate,
        observation.left,
        observation.right,
        matches,
        points_J,
        used,
        plane,
        observation.frame,
        identities,
        dent,
        contact,
        uncertainty,
    )


def _suspicions(
    split: SplitCheck | None,
    violations: int,
    plane: PlaneFit,
    contact: ContactRegion | None,
    part_diameter_mm: float | None,
    jig: JigConfig,
    n_used: int,
    minimum: int,
) -> list[str]:
    """The reasons (warnings starting with ``"suspect: "``) why an estimate may be wrong, from the frame's
    own evidence (:mod:`softjig.sensing.selfcheck`); none for an estimate that passed every check. An
    estimate the checks cannot verify (too few markers to split) is suspect too."""
    reasons = []
    fewest = max(SELF_CHECK_MIN_POINTS, 2 * minimum)
    if n_used < fewest or split is None:
        reasons.append(
            f"suspect: only {n_used} markers were fitted, too few to check that they are one flat face "
            f"(at least {fewest} are needed): a few markers of the membrane's wall fit a plane as well"
        )
    if split is not None and split.suspect:
        reasons.append(
            f"suspect: the two halves of the contact are tilted {np.degrees(split.angle_rad):.1f} deg apart "
            f"({split.sigmas:.0f} times their noise): the markers fitted are not one flat face (the "
            "membrane's wall?)"
        )
    if violations > 0:
        reasons.append(
            f"suspect: {violations} markers in or beside the contact lie above the fitted face or far below "
            "it, beyond what the noise explains: the plane may not be the part's face"
        )
    if plane.normal[2] < np.cos(np.radians(MAX_PLAUSIBLE_TILT_DEG)):
        reasons.append(
            f"suspect: the plane is tilted {np.degrees(np.arccos(plane.normal[2])):.0f} deg, steeper than a "
            f"part pressed into a soft jig stands ({MAX_PLAUSIBLE_TILT_DEG:g} deg)"
        )
    if part_diameter_mm is not None and contact is not None:
        largest = np.pi * (part_diameter_mm / 2.0 + CONTACT_AREA_SLACK_PITCHES * jig.markers.pitch_mm) ** 2
        if contact.area_mm2 > largest:
            reasons.append(
                f"suspect: the contact ({contact.area_mm2:.0f} mm^2) is larger than the {part_diameter_mm:g} "
                f"mm part's face could press ({largest:.0f} mm^2): is the part's size right?"
            )
    return reasons


@dataclass(frozen=True)
class NoiseScales:
    """The noise of each quantity the refractive method thresholds, measured in the frame itself (mm).

    A threshold is set from the noise of the quantity it thresholds (issue 13): the three differ when the
    bead pack's speckle is the same in the reference and the loaded frame (as in a real jig, whose beads
    do not move). A marker's image then carries the same speckle bias in both frames while it stays put,
    which the reference-differenced indentation cancels, but not its absolute position, nor its position
    once the part has moved it onto other beads.

    Attributes
    ----------
    indentation_sigma_mm : the reference-differenced indentation's noise (:attr:`Indentation.noise_mm`):
        which markers are pushed in at all.
    plane_sigma_mm : the absolute 3-D scatter of this frame's markers about a smooth surface (their
        neighbour-differenced heights above the nominal rest shape), at least the indentation's noise and
        :data:`UNCERTAINTY_FLOOR_MM`: the inlier band of the contact plane.
    face_depth_sigma_mm : the noise of a face depth (:func:`~softjig.sensing.contact.face_depth_mm`,
        ``reference_z - zero - plane_z``, in which the loaded marker's own height cancels): the reference's
        own scatter about the rest shape (a reference frame's; the indentation noise for the rest shape),
        at least the indentation's noise: the lift-off clearance and its margin.
    """

    indentation_sigma_mm: float
    plane_sigma_mm: float
    face_depth_sigma_mm: float


def _noise_scales(
    points_J: np.ndarray, dent: Indentation, reference: ReferenceMarkers, jig: JigConfig
) -> NoiseScales:
    """Measure :class:`NoiseScales` for one frame (a reference frame's own scatter is kept with it)."""
    pitch = jig.markers.pitch_mm
    sigma = float(dent.noise_mm) if np.isfinite(dent.noise_mm) else UNCERTAINTY_FLOOR_MM
    if reference.source == "rest shape":  # the indentation is already the absolute height's
        return NoiseScales(sigma, max(sigma, UNCERTAINTY_FLOOR_MM), sigma)
    rest_z = rest_inner_height_mm(jig, points_J[:, 0], points_J[:, 1])
    scatter = indentation(points_J, rest_z, pitch_mm=pitch).noise_mm
    key = ("scatter", pitch)
    if key not in reference._cache:
        xyz = reference.xyz_mm
        own = indentation(xyz, rest_inner_height_mm(jig, xyz[:, 0], xyz[:, 1]), pitch_mm=pitch).noise_mm
        reference._cache[key] = float(own) if np.isfinite(own) else 0.0
    face = reference._cache[key]
    scatter = float(scatter) if np.isfinite(scatter) else sigma
    return NoiseScales(sigma, max(scatter, sigma, UNCERTAINTY_FLOOR_MM), max(face, sigma))


def _canonical_order(ids: np.ndarray, points_J: np.ndarray) -> np.ndarray:
    """The markers ordered by their reference marker's index; those without one last, by ``x`` then ``y``."""
    if ids.min(initial=0) >= 0:  # the usual case: every marker identified (ids are one-to-one)
        return np.argsort(ids, kind="stable")
    return np.lexsort((points_J[:, 1], points_J[:, 0], np.where(ids >= 0, ids, np.iinfo(np.intp).max)))


class _StageClock:
    """Records the wall time of consecutive stages into a dict, when one is given."""

    def __init__(self, timings: dict[str, float] | None) -> None:
        self.timings = timings
        self.last = time.perf_counter()

    def lap(self, stage: str) -> None:
        if self.timings is not None:
            now = time.perf_counter()
            self.timings[stage] = now - self.last
            self.last = now


def _on_fiducials(quads_px: np.ndarray) -> Callable[[np.ndarray], np.ndarray]:
    """``xy -> bool mask``: which points lie on a fiducial (its black and white cells look like blobs to
    the LoG), for :func:`detect_markers`' ``exclude``: they are dropped before the sub-pixel fit."""
    return lambda xy: inside_fiducials(xy, quads_px)


def _as_u8(image: np.ndarray, gray: np.ndarray) -> np.ndarray:
    """The 8-bit gray image ArUco needs, from the checked gray (:func:`_checked_pair`): a ``uint8`` gray
    as it is, ``uint16`` and float rounded to the nearest 8-bit level."""
    return gray if gray.dtype == np.uint8 else _to_u8(gray)


def _to_u8(gray: np.ndarray) -> np.ndarray:
    """``uint16`` (``round(x / 257)``, in integers) or float in [0, 1] (``round(255 x)``) to ``uint8``."""
    if gray.dtype == np.uint16:
        # x / 257 is never a half-integer, so floor((x + 128) / 257) is the nearest level
        return ((gray.astype(np.uint32) + 128) // 257).astype(np.uint8)
    return np.clip(np.rint(gray * 255.0), 0, 255).astype(np.uint8)
