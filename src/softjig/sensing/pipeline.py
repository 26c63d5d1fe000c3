"""The paper's optical sensing, end to end: a rectified stereo pair -> the part's principal normal.

Stages (Sakuma et al., section "Optical Sensing"), each in its own module:

1. markers in each image: LoG at the scale implied by the markers' size in the image, local maxima,
   least-squares quadratic sub-pixel refinement (:mod:`softjig.sensing.detect`);
2. stereo matching on rows within a tolerance and a disparity window implied by the jig's geometry, as
   a one-to-one global assignment, and pinhole triangulation (:mod:`softjig.sensing.stereo`);
3. the points moved into the jig frame J with the pose measured from the fiducials, or the fixed one of
   the config (:mod:`softjig.sensing.jigframe`);
4. the points within the part's base radius of the jig axis kept, and a plane fitted by SVD
   (:func:`softjig.geometry.fit_plane_svd`): its normal is the principal normal, its tilt angles
   ``Ax, Ay`` and push depth follow (``DESIGN.md`` §1); a tilt calibration ``(Ox, Oy, S)`` is applied
   when given.

As in the paper, triangulation ignores refraction: depths come out compressed (by about the oil's index),
which is what the paper's scale ``S`` absorbs. The push depth is measured from the rest membrane as the
same triangulation sees it (the rest apex projected through the real layers and triangulated as a
pinhole pair), so zero push reads zero; it stays compressed by the same factor.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass
from functools import lru_cache

import numpy as np

from softjig.calibration.tilt import TiltCalibration
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
from softjig.sensing.detect import Markers, check_image_content, detect_markers, log_sigma_px, to_gray_float
from softjig.sensing.jigframe import JigFrame, inside_fiducials, resolve_jig_frame
from softjig.sensing.stereo import StereoMatches, match_rectified, triangulate_rectified

METHODS = ("paper",)


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
    method : the estimation method (``"paper"``).
    calibrated : whether a tilt calibration was applied.
    raw_tilt_x_deg, raw_tilt_y_deg : tilt angles before calibration (deg).
    part_diameter_mm : the crop diameter used.
    n_markers_left, n_markers_right, n_matches : detections and stereo matches.
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
    part_diameter_mm: float
    n_markers_left: int
    n_markers_right: int
    n_matches: int

    def to_dict(self) -> dict:
        """The JSON form (``DESIGN.md``'s command-line contract): plain floats, lists and strings."""
        data = asdict(self)
        data["normal"] = list(self.normal)
        data["warnings"] = list(self.warnings)
        return data


@dataclass(frozen=True)
class SensingResult:
    """Everything one run of the pipeline found, for overlays and analysis.

    Attributes
    ----------
    estimate : the reported estimate.
    left, right : the markers detected in each image.
    matches : the stereo matches (indices into ``left`` and ``right``).
    points_J : (M, 3) the triangulated matches in J (mm), one per match.
    used : (M,) which of them lay within the crop and were fitted.
    plane : the fitted plane (uncalibrated).
    frame : the cameras' pose in J and its source.
    """

    estimate: Estimate
    left: Markers
    right: Markers
    matches: StereoMatches
    points_J: np.ndarray
    used: np.ndarray
    plane: PlaneFit
    frame: JigFrame


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
    """

    sigma_px: float
    threshold: float | None
    min_disparity_px: float
    max_disparity_px: float
    rest_apex_z_mm: float


def sensing_setup(jig: JigConfig) -> SensingSetup:
    """Derive the detection scale, disparity window and push-depth reference from the nominal jig."""
    return _sensing_setup_cached(jig)


@lru_cache(maxsize=16)
def _sensing_setup_cached(jig: JigConfig) -> SensingSetup:
    left, right = jig.cameras.left, jig.cameras.right
    layers = flat_layers(jig)
    apex = np.array([[0.0, 0.0, jig.membrane.dome_height_mm]])
    if jig.sensing.log_sigma_px is not None:
        sigma = jig.sensing.log_sigma_px
    else:
        # px per mm at the apex (mean singular value of the projection's Jacobian in the marker's plane)
        jac = projection_jacobian(apex, left.K, left.distortion, left.T_J_cam, layers)[0][:, :2]
        px_per_mm = float(np.mean(np.linalg.svd(jac, compute_uv=False)))
        blur_mm = jig.medium.blur_coefficient * jig.membrane.dome_height_mm**1.5
        sigma = log_sigma_px(jig.markers.diameter_mm * px_per_mm, blur_sigma_px=blur_mm * px_per_mm)
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


def _checked_pair(left: np.ndarray, right: np.ndarray, jig: JigConfig) -> tuple[np.ndarray, np.ndarray]:
    grays = []
    for name, image in (("left", left), ("right", right)):
        try:
            gray = to_gray_float(image)
        except InputError as exc:
            raise InputError(f"{name} image: {exc}") from None
        grays.append(gray)
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
    if np.array_equal(grays[0], grays[1]):
        raise InputError("the left and right images are the same image: pass the two views of a stereo pair")
    return grays[0], grays[1]


def estimate_pair(
    left: np.ndarray,
    right: np.ndarray,
    jig: JigConfig,
    *,
    part_diameter_mm: float,
    calibration: TiltCalibration | None = None,
    method: str = "paper",
    timings: dict[str, float] | None = None,
) -> SensingResult:
    """Estimate the principal normal of the part on the jig from one rectified stereo pair.

    Parameters
    ----------
    left, right : (H, W) or (H, W, 3) uint8 or uint16 images of the nominal jig's cameras (RGB).
    jig : the nominal jig (the estimator never knows the as-built one).
    part_diameter_mm : diameter of the part's base (the paper's crop: markers within half of it from the
        jig axis are fitted).
    calibration : the paper's tilt calibration to apply, if any.
    method : ``"paper"``: the method exactly as published.
    timings : if given, filled with each stage's wall time in seconds (``checks``, ``frame``,
        ``detect``, ``match``, ``triangulate``, ``fit``).

    Returns
    -------
    SensingResult
        The estimate and what led to it.

    Raises
    ------
    InputError
        Bad images (size, dtype, blank or saturated), an unrectified config, a bad diameter or method.
    EstimationError
        Too few markers in the crop (fewer than ``sensing.min_points``), points that do not define a
        plane, or fiducials required but not found.
    """
    if method not in METHODS:
        raise InputError(f"unknown method {method!r}; valid: {', '.join(METHODS)}")
    if not (np.isfinite(part_diameter_mm) and part_diameter_mm > 0):
        raise InputError(f"the part diameter must be a positive number of mm, got {part_diameter_mm}")
    if not jig.cameras.rectified:
        raise InputError(
            "the config's cameras are not a rectified pair (cameras.rectified = false): the paper's method "
            "needs rectified images"
        )
    clock = _StageClock(timings)
    gray_left, gray_right = _checked_pair(left, right, jig)
    setup = sensing_setup(jig)
    clock.lap("checks")
    warnings: list[str] = []

    kwargs = {"sigma_px": setup.sigma_px}
    if setup.threshold is not None:
        kwargs["threshold"] = setup.threshold
    frame, frame_warnings = resolve_jig_frame(_to_u8(gray_left), _to_u8(gray_right), jig)
    warnings += frame_warnings
    clock.lap("frame")
    markers_left = _off_fiducials(detect_markers(gray_left, **kwargs), frame.fiducial_quads_left_px)
    markers_right = _off_fiducials(detect_markers(gray_right, **kwargs), frame.fiducial_quads_right_px)
    clock.lap("detect")
    matches = match_rectified(
        markers_left.xy_px,
        markers_right.xy_px,
        row_tolerance_px=jig.sensing.row_tolerance_px,
        min_disparity_px=setup.min_disparity_px,
        max_disparity_px=setup.max_disparity_px,
    )
    clock.lap("match")
    xy_left = markers_left.xy_px[matches.left_index]
    xy_right = markers_right.xy_px[matches.right_index]
    points_cam = _triangulate(xy_left, xy_right, jig) if len(matches) else np.zeros((0, 3))
    points_J = transform_points(frame.T_J_left, points_cam)
    clock.lap("triangulate")

    radius = part_diameter_mm / 2.0
    used = np.hypot(points_J[:, 0], points_J[:, 1]) < radius
    n_used = int(used.sum())
    minimum = jig.sensing.min_points
    if n_used < minimum:
        raise EstimationError(
            f"only {n_used} markers lie within {radius:g} mm of the jig axis (the part's base radius); at "
            f"least {minimum} are needed (sensing.min_points). Detected {len(markers_left)} left / "
            f"{len(markers_right)} right, matched {len(matches)}: is a part on the jig, centred, and is the "
            "part diameter right?"
        )
    try:
        plane = fit_plane_svd(points_J[used], min_points=minimum)
    except InputError as exc:
        raise EstimationError(f"no plane could be fitted: {exc}") from None

    raw_ax, raw_ay = tilt_angles(plane.normal)
    if calibration is not None and not calibration.is_identity():
        ax, ay = calibration.apply(raw_ax, raw_ay)
        normal = normal_from_tilt_angles(float(ax), float(ay))
    else:
        ax, ay, normal = raw_ax, raw_ay, plane.normal
    if n_used < 2 * minimum:
        warnings.append(f"only {n_used} markers under the part: the estimate is noisy")
    if len(matches) < 0.5 * min(len(markers_left), len(markers_right)):
        warnings.append(
            f"only {len(matches)} of {min(len(markers_left), len(markers_right))} markers were matched "
            "between the images: check the rectification and sensing.row_tolerance_px"
        )
    estimate = Estimate(
        normal=tuple(float(v) for v in normal),
        tilt_x_deg=float(np.degrees(ax)),
        tilt_y_deg=float(np.degrees(ay)),
        push_depth_mm=setup.rest_apex_z_mm - plane.z_at(0.0, 0.0),
        n_points=n_used,
        rms_residual_mm=plane.rms_residual_mm,
        frame_source=frame.source,
        warnings=tuple(warnings),
        method=method,
        calibrated=calibration is not None and not calibration.is_identity(),
        raw_tilt_x_deg=float(np.degrees(raw_ax)),
        raw_tilt_y_deg=float(np.degrees(raw_ay)),
        part_diameter_mm=float(part_diameter_mm),
        n_markers_left=len(markers_left),
        n_markers_right=len(markers_right),
        n_matches=len(matches),
    )
    clock.lap("fit")
    return SensingResult(estimate, markers_left, markers_right, matches, points_J, used, plane, frame)


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


def _off_fiducials(markers: Markers, quads_px: np.ndarray) -> Markers:
    """The markers that are not on a fiducial (its black and white cells look like blobs to the LoG)."""
    keep = ~inside_fiducials(markers.xy_px, quads_px)
    return Markers(xy_px=markers.xy_px[keep], response=markers.response[keep], sigma_px=markers.sigma_px)


def _to_u8(gray: np.ndarray) -> np.ndarray:
    return np.clip(np.rint(gray * 255.0), 0, 255).astype(np.uint8)
