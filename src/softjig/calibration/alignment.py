"""Jig-to-robot alignment: the jig's pose in the robot's base frame from a hand-eye camera's image.

The paper aligns the jig with the robot by viewing four white circular markers on the jig with a
hand-eye camera and solving a perspective-n-point problem (Sakuma et al., "Jig Coordinate Calibration",
Fig. "Setup to jig coordinate calibration"). Here:

1. **Circles**: the image is thresholded (Otsu; then a few fixed levels if that fails); every bright
   blob whose contour an ellipse fits (``cv2.fitEllipse``; area ratio and mean contour residual) is a
   candidate; the ``n`` candidates of most similar size are kept (``n`` = the configured circles).
2. **Ordering**: the configured circles (``alignment.circle_centers_mm``, in J) and the detections are
   each sorted by angle about their centroid; of the ``2 n`` cyclic assignments (both turning
   directions), each is solved by PnP (``cv2.SOLVEPNP_IPPE`` then Levenberg-Marquardt); solutions with
   the camera below the plate are rejected (the camera views the top face), and among those whose
   reprojection error is within ``max(0.5 px, 2 x best)`` of the best one the solution whose
   ``T_robot_jig`` rotation is closest to the prior (``R_robot_jig_prior``, default identity: the jig's
   axes roughly parallel to the robot base's) wins. The default layout is a square, symmetric under
   turns of 90°: the image alone cannot tell its circles apart, so **the prior decides, and the ordering
   is unambiguous whenever the prior's rotation is within 45° of the truth**; an asymmetric layout is
   decided by the image alone.
3. **Perspective bias**: the centre of a circle's image (an ellipse) is not the image of its centre. With
   the first pose, each circle's outline is projected and fitted exactly as the image was; the offset of
   that ellipse's centre from the projected centre is subtracted from the detection and PnP is solved
   again (twice).
4. ``T_robot_jig = T_robot_flange @ T_flange_cam @ T_cam_jig`` (``DESIGN.md`` §1 naming): the flange's
   pose from the robot's kinematics, the camera's on the flange from a hand-eye calibration.
5. **Credibility**: a robot acts on the pose, so one that the image does not support is refused
   (:class:`~softjig.errors.EstimationError`), not written with a warning. The inputs are checked first
   (:func:`check_intrinsics`: positive focal lengths, principal point inside the image, finite
   distortion, the image of the camera's size; the poses' rotations orthonormal with determinant +1 and
   everything finite, :func:`check_pose`). Then the circles' reprojection RMS must be at most
   ``max_reprojection_px`` (default :data:`MAX_REPROJECTION_PX` = 2 px) and each detected circle's size
   must match its projection at the pose found (area ratio within :data:`SIZE_RATIO_RANGE`).
   *Why 2 px*: a circle's centre is fitted to its whole contour, so its noise is a small fraction of a
   pixel (``tests/test_alignment.py``'s rendered views with noise; figures in benchmarks/RESULTS.md);
   a calibrated camera's own reprojection error is typically 0.1-0.5 px, and a machining tolerance of
   0.2 mm on the circles' positions is about 0.3 px at 420 mm with f = 560 px. A credible pose thus
   reprojects within about 1 px (where a warning starts); 2 px leaves a margin of two, while wrong
   inputs are far beyond it: a noise image, a stereo camera's image of the markers, a flange matrix that
   is not a rotation or a negative focal length gave 64-128 px.

Units: mm, pixels ``(u, v)`` OpenCV's.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from softjig.config import CameraConfig, JigConfig
from softjig.errors import EstimationError, InputError
from softjig.geometry import invert_pose, pose_from_rotvec_translation

__all__ = [
    "MAX_REPROJECTION_PX",
    "SIZE_RATIO_RANGE",
    "Alignment",
    "align_jig_to_robot",
    "check_intrinsics",
    "check_pose",
    "detect_circles",
]

#: Default refusal threshold of the circles' reprojection RMS (px); see the module docstring, step 5.
MAX_REPROJECTION_PX = 2.0
_WARN_REPROJECTION_PX = 1.0
#: A detected circle's area over its projection's at the pose found: the thresholded blob of a blurred
#: circle is a little smaller or larger than its outline (a pixel of its rim is 15 % of a 27 px circle's
#: area), never twice or half.
SIZE_RATIO_RANGE = (0.5, 2.0)
#: Poses whose RMS is within ``max(_TIE_RMS_PX, _TIE_RMS_FACTOR * best)`` of the best one are ties (a
#: symmetric layout): the prior rotation decides between them.
_TIE_RMS_PX, _TIE_RMS_FACTOR = 0.5, 2.0
#: A blob is a circle's image when its contour's area is within this range of its fitted ellipse's (a
#: blob of another shape fills its ellipse less, or more) and the ellipse's minor axis is at least
#: :data:`MIN_AXIS_RATIO` times its major one (a circle seen up to ~70 deg from its normal); a contour of
#: fewer points than ``_MIN_CONTOUR_POINTS`` is too small a blob to fit an ellipse to reliably.
ELLIPSE_FILL_RANGE = (0.8, 1.2)
MIN_AXIS_RATIO = 0.3
_MIN_CONTOUR_POINTS = 8
#: Points on each circle's projected outline, and rounds of the ellipse-centre bias correction.
_OUTLINE_POINTS, _CENTRE_BIAS_ITERATIONS = 72, 2
#: A tie chosen this far (deg) from the prior rotation gets a warning (a square layout's orders are 90 apart).
_SYMMETRY_WARN_DEG = 30.0
#: Largest deviation of ``R^T R`` from the identity accepted for a pose's rotation: a matrix typed or
#: printed with 4 decimals is within 2e-4; it is then made exactly orthonormal (its nearest rotation).
ROTATION_TOLERANCE = 1e-3
#: Largest translation accepted in a pose (mm): 10 m, beyond the reach of any robot arm (a unit mistake).
MAX_TRANSLATION_MM = 10_000.0


def check_pose(T: np.ndarray, what: str) -> np.ndarray:
    """A credible 4x4 rigid pose (mm) from ``T``, or :class:`InputError` naming ``what`` and the problem.

    Every entry finite, the last row ``(0, 0, 0, 1)``, the rotation orthonormal (``|R^T R - I| <=``
    :data:`ROTATION_TOLERANCE`) with determinant +1 (not a reflection), the translation within
    :data:`MAX_TRANSLATION_MM`. Returns the pose with its rotation replaced by the nearest rotation.
    """
    T = np.asarray(T, dtype=float)
    if T.shape != (4, 4):
        raise InputError(f"{what} must be a 4x4 matrix, got shape {T.shape}")
    if not np.all(np.isfinite(T)):
        raise InputError(f"{what} contains NaN or inf: give a finite 4x4 pose (mm)")
    if not np.allclose(T[3], [0.0, 0.0, 0.0, 1.0], atol=1e-9):
        raise InputError(f"{what}: the last row of a homogeneous pose must be 0 0 0 1, got {T[3].tolist()}")
    R = T[:3, :3]
    deviation = float(np.abs(R.T @ R - np.eye(3)).max())
    if deviation > ROTATION_TOLERANCE:
        raise InputError(
            f"{what}: its 3x3 rotation is not orthonormal (R^T R differs from the identity by "
            f"{deviation:.3g}, more than {ROTATION_TOLERANCE:g}): give the pose's rotation matrix, not a "
            "scaled or sheared one"
        )
    if np.linalg.det(R) < 0:
        raise InputError(f"{what}: its 3x3 rotation has determinant -1 (a reflection, not a rotation)")
    distance = float(np.linalg.norm(T[:3, 3]))
    if distance > MAX_TRANSLATION_MM:
        raise InputError(
            f"{what}: its translation is {distance:.4g} mm from the origin, beyond {MAX_TRANSLATION_MM:g} mm "
            "(no robot reaches that far): poses are in millimetres"
        )
    u, _, vt = np.linalg.svd(R)
    out = T.copy()
    out[:3, :3] = u @ vt
    return out


def check_intrinsics(camera: CameraConfig, image_shape: tuple[int, ...] | None = None) -> None:
    """:class:`InputError` unless ``camera``'s intrinsics are usable (and match the image's size).

    Focal lengths finite and positive, the principal point finite and inside the image, five finite
    distortion coefficients; with ``image_shape``, the image is ``height_px x width_px``.
    """
    for name in ("fx_px", "fy_px", "cx_px", "cy_px", "width_px", "height_px"):
        value = getattr(camera, name)
        if isinstance(value, bool) or not isinstance(value, int | float) or not np.isfinite(value):
            raise InputError(f"the hand-eye camera's {name} must be a finite number, got {value!r}")
    for name in ("fx_px", "fy_px", "width_px", "height_px"):
        if not getattr(camera, name) > 0:
            raise InputError(f"the hand-eye camera's {name} must be positive, got {getattr(camera, name)}")
    if not (0 <= camera.cx_px <= camera.width_px and 0 <= camera.cy_px <= camera.height_px):
        raise InputError(
            f"the hand-eye camera's principal point ({camera.cx_px}, {camera.cy_px}) px lies outside its "
            f"{camera.width_px} x {camera.height_px} image"
        )
    dist = np.asarray(camera.distortion, dtype=float)
    if dist.shape != (5,) or not np.all(np.isfinite(dist)):
        raise InputError(
            f"the hand-eye camera's distortion must be 5 finite numbers, got {camera.distortion}"
        )
    if image_shape is not None:
        h, w = image_shape[:2]
        if (w, h) != (camera.width_px, camera.height_px):
            raise InputError(
                f"the hand-eye image is {w} x {h} px but the camera's intrinsics are for "
                f"{camera.width_px} x {camera.height_px}: use the image of that camera, or its intrinsics"
            )


@dataclass(frozen=True)
class Alignment:
    """The jig's pose in the robot's base frame and how it was found.

    Attributes
    ----------
    T_robot_jig : (4, 4) J in the robot base frame (mm).
    T_cam_jig : (4, 4) J in the hand-eye camera's frame (mm).
    circles_px : (n, 2) the circles' bias-corrected image centres, in the config's order (px).
    reprojection_rms_px : RMS reprojection error of the circles' centres (px).
    ambiguous_orders : how many circle orders fitted the image as well as the chosen one (1 for an
        asymmetric layout; 4 for the default square, decided by the prior).
    warnings : what a user should know.
    """

    T_robot_jig: np.ndarray
    T_cam_jig: np.ndarray
    circles_px: np.ndarray
    reprojection_rms_px: float
    ambiguous_orders: int
    warnings: tuple[str, ...]

    def to_dict(self) -> dict:
        """JSON form."""
        return {
            "T_robot_jig": self.T_robot_jig.tolist(),
            "T_cam_jig": self.T_cam_jig.tolist(),
            "circles_px": self.circles_px.tolist(),
            "reprojection_rms_px": self.reprojection_rms_px,
            "ambiguous_orders": self.ambiguous_orders,
            "warnings": list(self.warnings),
        }


def _gray_u8(image: np.ndarray) -> np.ndarray:
    img = np.asarray(image)
    if img.ndim == 3 and img.shape[2] == 3:
        img = cv2.cvtColor(img, cv2.COLOR_RGB2GRAY)
    if img.ndim != 2 or img.dtype not in (np.uint8, np.uint16):
        raise InputError(
            f"the hand-eye image must be (H, W) or (H, W, 3) uint8/uint16, got {img.shape} {img.dtype}"
        )
    return (img >> 8).astype(np.uint8) if img.dtype == np.uint16 else img


def _ellipse_candidates(binary: np.ndarray, min_area_px: float) -> list[tuple[np.ndarray, float]]:
    contours, _ = cv2.findContours(binary, cv2.RETR_LIST, cv2.CHAIN_APPROX_NONE)
    out = []
    for c in contours:
        if len(c) < _MIN_CONTOUR_POINTS:
            continue
        area = cv2.contourArea(c)
        if area < min_area_px:
            continue
        (cx, cy), (a, b), _ = cv2.fitEllipse(c)
        ellipse_area = np.pi * a * b / 4
        fill_low, fill_high = ELLIPSE_FILL_RANGE
        if not fill_low < area / max(ellipse_area, 1e-9) < fill_high or min(a, b) < MIN_AXIS_RATIO * max(
            a, b
        ):
            continue
        out.append((np.array([cx, cy]), float(ellipse_area)))
    return out


def detect_circles(image: np.ndarray, n: int = 4, *, min_area_px: float = 12.0) -> np.ndarray:
    """The centres ``(n, 2)`` (px) of the ``n`` bright elliptical blobs of most similar size.

    The ellipse is fitted to the blob's contour at the threshold (sub-pixel through the fit over many
    contour points). Raises :class:`EstimationError` when fewer than ``n`` are found.
    """
    return _detect_circles(image, n, min_area_px=min_area_px)[0]


def _detect_circles(image: np.ndarray, n: int, *, min_area_px: float = 12.0) -> tuple[np.ndarray, np.ndarray]:
    """:func:`detect_circles`, and the (n,) areas of the ellipses fitted (px^2)."""
    gray = _gray_u8(image)
    otsu, _ = cv2.threshold(gray, 0, 255, cv2.THRESH_BINARY | cv2.THRESH_OTSU)
    best: list[tuple[np.ndarray, float]] = []
    for level in (otsu, 128, 160, 200, 100):
        _, binary = cv2.threshold(gray, level, 255, cv2.THRESH_BINARY)
        cands = _ellipse_candidates(binary, min_area_px)
        if len(cands) >= n:
            best = cands
            break
        if len(cands) > len(best):
            best = cands
    if len(best) < n:
        raise EstimationError(
            f"found {len(best)} of the {n} white alignment circles in the hand-eye image: make all of them "
            "visible, evenly lit and in focus (bright on a dark plate)"
        )
    areas = np.log([a for _, a in best])
    order = np.argsort(areas)
    # the window of n consecutive sizes (in log) with the smallest spread
    spreads = [areas[order[k + n - 1]] - areas[order[k]] for k in range(len(best) - n + 1)]
    k = int(np.argmin(spreads))
    chosen = order[k : k + n]
    return np.array([best[i][0] for i in chosen]), np.array([best[i][1] for i in chosen])


def _angle_order(points: np.ndarray) -> np.ndarray:
    c = points.mean(axis=0)
    return np.argsort(np.arctan2(points[:, 1] - c[1], points[:, 0] - c[0]))


def _solve(obj: np.ndarray, img: np.ndarray, K: np.ndarray, dist: np.ndarray) -> list[np.ndarray]:
    """Every IPPE solution ``T_cam_jig``, refined by LM."""
    _, rvecs, tvecs, _ = cv2.solvePnPGeneric(obj, img, K, dist, flags=cv2.SOLVEPNP_IPPE)
    out = []
    for r, t in zip(rvecs, tvecs, strict=True):
        r, t = cv2.solvePnPRefineLM(obj, img, K, dist, r.copy(), t.copy())
        out.append(pose_from_rotvec_translation(r.ravel(), t.ravel()))
    return out


def _project(T_cam_jig: np.ndarray, pts: np.ndarray, K: np.ndarray, dist: np.ndarray) -> np.ndarray:
    rvec, _ = cv2.Rodrigues(T_cam_jig[:3, :3])
    px, _ = cv2.projectPoints(pts, rvec, T_cam_jig[:3, 3], K, dist)
    return px.reshape(-1, 2)


def _rotation_angle(Ra: np.ndarray, Rb: np.ndarray) -> float:
    return float(np.arccos(np.clip((np.trace(Ra.T @ Rb) - 1) / 2, -1.0, 1.0)))


def align_jig_to_robot(
    image: np.ndarray,
    jig: JigConfig,
    camera: CameraConfig,
    T_robot_flange: np.ndarray,
    T_flange_cam: np.ndarray,
    *,
    R_robot_jig_prior: np.ndarray | None = None,
    max_reprojection_px: float = MAX_REPROJECTION_PX,
) -> Alignment:
    """Find ``T_robot_jig`` from one hand-eye image of the jig's alignment circles (module docstring).

    Parameters
    ----------
    image : the hand-eye camera's image (gray or RGB, uint8/uint16), raw (with its lens distortion).
    jig : the jig (``alignment``: circle centres in J, diameter, ``z_mm``).
    camera : the hand-eye camera's intrinsics and distortion (pose fields unused).
    T_robot_flange : (4, 4) the flange's pose in the robot base frame when the image was taken (mm).
    T_flange_cam : (4, 4) the camera's pose on the flange (hand-eye calibration, mm).
    R_robot_jig_prior : (3, 3) roughly how the jig is turned in the robot frame (default: identity);
        decides between the orders a symmetric layout leaves open (must be within 45° for a square).
    max_reprojection_px : a pose whose circles reproject with a larger RMS is refused (module docstring,
        step 5).

    Raises
    ------
    InputError
        Intrinsics or poses that are not credible (:func:`check_intrinsics`, :func:`check_pose`).
    EstimationError
        Too few circles found, no pose puts the camera above the plate, or the pose found is not
        credible: its reprojection RMS above ``max_reprojection_px``, or circles whose size does not
        match their projection.
    """
    if not (np.isfinite(max_reprojection_px) and max_reprojection_px > 0):
        raise InputError(f"max_reprojection_px must be positive, got {max_reprojection_px}")
    img_arr = np.asarray(image)
    check_intrinsics(camera, img_arr.shape)
    T_robot_flange = check_pose(T_robot_flange, "T_robot_flange (the flange's pose)")
    T_flange_cam = check_pose(T_flange_cam, "T_flange_cam (the camera's pose on the flange)")
    prior = _check_prior(R_robot_jig_prior)
    al = jig.alignment
    n = len(al.circle_centers_mm)
    K, dist = camera.K, np.asarray(camera.distortion, float)
    detected, detected_area = _detect_circles(img_arr, n)
    obj = np.column_stack([np.asarray(al.circle_centers_mm, float), np.full(n, al.z_mm)])
    obj_sorted = obj[_angle_order(obj[:, :2])]
    det_order = _angle_order(detected)
    T_robot_cam = T_robot_flange @ T_flange_cam
    candidates = _pose_candidates(obj_sorted, detected, detected_area, det_order, K, dist, z_mm=al.z_mm)
    if not candidates:
        raise EstimationError(
            "no pose of the jig puts the hand-eye camera above the plate: check the circles"
        )
    best_rms = min(c[0] for c in candidates)
    good = [c for c in candidates if c[0] <= best_rms + max(_TIE_RMS_PX, _TIE_RMS_FACTOR * best_rms)]
    rms, T_cam_jig, img, _, areas = min(
        good, key=lambda c: _rotation_angle((T_robot_cam @ c[1])[:3, :3], prior)
    )
    T_cam_jig, corrected, projected_area = _corrected_for_centre_bias(
        T_cam_jig, img, obj_sorted, al.circle_diameter_mm / 2, K, dist
    )
    res = _project(T_cam_jig, obj_sorted, K, dist) - corrected
    rms = float(np.sqrt(np.mean(np.sum(res**2, axis=1))))
    _check_credible(rms, max_reprojection_px, areas / np.maximum(projected_area, 1e-9), al.circle_diameter_mm)
    # back to the config's order
    sorted_idx = _angle_order(obj[:, :2])
    circles = np.empty_like(corrected)
    circles[sorted_idx] = corrected
    T_robot_jig = T_robot_cam @ T_cam_jig
    warnings = []
    if rms > _WARN_REPROJECTION_PX:
        warnings.append(
            f"the circles' reprojection error is {rms:.2f} px: check the hand-eye camera's intrinsics and "
            "alignment.circle_centers_mm"
        )
    angle = np.degrees(_rotation_angle(T_robot_jig[:3, :3], prior))
    n_orders = len({c[3] for c in good})
    if n_orders > 1 and angle > _SYMMETRY_WARN_DEG:
        warnings.append(
            f"the circles' layout is symmetric and the chosen jig rotation is {angle:.0f} deg from the "
            "prior: "
            "give a prior rotation closer to the truth (within 45 deg) or the order may be wrong"
        )
    return Alignment(T_robot_jig, T_cam_jig, circles, rms, n_orders, tuple(warnings))


def _check_prior(R_robot_jig_prior: np.ndarray | None) -> np.ndarray:
    """The prior rotation of the jig in the robot frame, checked (identity by default)."""
    prior = np.eye(3) if R_robot_jig_prior is None else np.asarray(R_robot_jig_prior, float)
    if prior.shape != (3, 3):
        raise InputError(f"R_robot_jig_prior must be a 3x3 rotation, got shape {prior.shape}")
    prior_pose = np.eye(4)
    prior_pose[:3, :3] = prior
    return check_pose(prior_pose, "R_robot_jig_prior")[:3, :3]


def _pose_candidates(obj_sorted, detected, detected_area, det_order, K, dist, *, z_mm: float) -> list[tuple]:
    """Every pose of every assignment of the detected circles to the layout's (both turning directions,
    each cyclic shift) that puts the camera above the plate: ``(rms_px, T_cam_jig, image points, (direction,
    shift), detected areas)``."""
    candidates = []
    n = len(obj_sorted)
    for direction in (1, -1):
        for shift in range(n):
            idx = np.roll(det_order[::direction], shift)
            img = detected[idx]
            for T_cam_jig in _solve(obj_sorted, img, K, dist):
                cam_in_J = invert_pose(T_cam_jig)[:3, 3]
                if cam_in_J[2] <= z_mm:
                    continue
                rms = float(
                    np.sqrt(np.mean(np.sum((_project(T_cam_jig, obj_sorted, K, dist) - img) ** 2, 1)))
                )
                candidates.append((rms, T_cam_jig, img, (direction, shift), detected_area[idx]))
    return candidates


def _corrected_for_centre_bias(T_cam_jig, img, obj_sorted, radius_mm: float, K, dist):
    """Correct the perspective bias of the ellipse centres with the pose found, and solve again
    (:data:`_CENTRE_BIAS_ITERATIONS` times): ``(T_cam_jig, corrected image points, each circle's projected
    area (px²))``."""
    outline = np.linspace(0, 2 * np.pi, _OUTLINE_POINTS, endpoint=False)
    corrected = img
    projected_area = np.zeros(len(obj_sorted))
    for _ in range(_CENTRE_BIAS_ITERATIONS):
        offsets = []
        for k, p in enumerate(obj_sorted):
            ring = p + radius_mm * np.column_stack([np.cos(outline), np.sin(outline), np.zeros_like(outline)])
            (ex, ey), (ea, eb), _ = cv2.fitEllipse(_project(T_cam_jig, ring, K, dist).astype(np.float32))
            offsets.append(np.array([ex, ey]) - _project(T_cam_jig, p[None], K, dist)[0])
            projected_area[k] = np.pi * ea * eb / 4
        corrected = img - np.array(offsets)
        sols = _solve(obj_sorted, corrected, K, dist)
        previous = T_cam_jig
        T_cam_jig = min(sols, key=lambda T: _rotation_angle(T[:3, :3], previous[:3, :3]))
    return T_cam_jig, corrected, projected_area


def _check_credible(rms: float, max_reprojection_px: float, ratio: np.ndarray, diameter_mm: float) -> None:
    """An EstimationError if the pose reprojects the circles too badly, or if a detected circle's area is
    not what its circle's would be at that pose (``ratio``: detected over projected area)."""
    if not np.isfinite(rms) or rms > max_reprojection_px:
        raise EstimationError(
            f"no credible pose: the circles reproject with an RMS of {rms:.3g} px, above "
            f"{max_reprojection_px:g} px (a right pose reprojects within about 1 px): check that the image "
            "is the hand-eye camera's view of the four alignment circles, its intrinsics, T_flange_cam and "
            "alignment.circle_centers_mm"
        )
    if not np.all((ratio >= SIZE_RATIO_RANGE[0]) & (ratio <= SIZE_RATIO_RANGE[1])):
        worst = float(ratio[np.argmax(np.abs(np.log(np.maximum(ratio, 1e-12))))])
        raise EstimationError(
            f"no credible pose: a detected circle is {worst:.2g} times the area its "
            f"{diameter_mm:g} mm circle would have at the pose found: these blobs are not the "
            "alignment circles (or alignment.circle_diameter_mm is wrong)"
        )
