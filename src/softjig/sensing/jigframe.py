"""The cameras' pose in the jig frame J: from the fiducials on the base plate, or fixed in the config.

The paper transforms the triangulated markers into the jig frame with fiducials on the base plate. Ours
are ArUco markers on the plate's bottom face (``fiducials.z_mm``, default ``-5``): the cameras see them
through air only, so a plain pinhole model is exact for them. Both cameras' views are used at once: the
stereo head's pose is the one that minimises the reprojection error of every fiducial corner found in
either image (OpenCV's PnP for the start, then a joint Levenberg-Marquardt refinement with SciPy), with the
right camera held at its configured pose relative to the left one.

When the fiducials are not visible, or the user calibrated the extrinsics once, the poses in the config
are used instead (``sensing.extrinsics``); the result says which source was used.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import cv2
import numpy as np
from scipy.optimize import least_squares

from softjig.config import CameraConfig, JigConfig
from softjig.errors import EstimationError
from softjig.geometry import invert_pose, pose_from_rotvec_translation
from softjig.optics import project_points
from softjig.sensing.fiducials import detect_fiducials, fiducial_corners_J

MIN_FIDUCIALS_PER_IMAGE = 2  # 8 corners: a well-conditioned planar PnP
MAX_FIDUCIAL_RMS_PX = 2.0  # above this, a corner was misread or a fiducial moved: the pose is rejected


@dataclass(frozen=True)
class JigFrame:
    """Both cameras' poses in J and where they came from.

    Attributes
    ----------
    T_J_left, T_J_right : (4, 4) the cameras' poses in J (mm).
    source : ``"fiducials"`` (measured in these images) or ``"config"`` (fixed extrinsics).
    reprojection_rms_px : RMS reprojection error of the fiducial corners (``nan`` for ``"config"``).
    fiducial_ids : ids found in both images (empty for ``"config"``).
    fiducial_quads_left_px, fiducial_quads_right_px : (M, 4, 2) where each fiducial is in each image
        (found, or projected from the config's poses): markers detected there are not membrane markers.
    """

    T_J_left: np.ndarray
    T_J_right: np.ndarray
    source: str
    reprojection_rms_px: float
    fiducial_ids: tuple[int, ...]
    fiducial_quads_left_px: np.ndarray
    fiducial_quads_right_px: np.ndarray


def _projected_quads(jig: JigConfig, camera: CameraConfig, T_J_cam: np.ndarray) -> np.ndarray:
    corners = fiducial_corners_J(jig.fiducials).reshape(-1, 3)
    return _project(camera, invert_pose(T_J_cam), corners).reshape(-1, 4, 2)


@lru_cache(maxsize=16)
def jig_frame_from_config(jig: JigConfig) -> JigFrame:
    """The fixed extrinsics written in the config (computed once per jig: every frame asks for them, if
    only for where its fiducials should be; the arrays are read-only)."""
    left, right = jig.cameras.left, jig.cameras.right
    arrays = [
        left.T_J_cam,
        right.T_J_cam,
        _projected_quads(jig, left, left.T_J_cam),
        _projected_quads(jig, right, right.T_J_cam),
    ]
    for array in arrays:
        array.flags.writeable = False
    return JigFrame(arrays[0], arrays[1], "config", float("nan"), (), arrays[2], arrays[3])


def inside_fiducials(xy_px: np.ndarray, quads_px: np.ndarray, *, quiet_zone: float = 1.0 / 3.0) -> np.ndarray:
    """Which points lie on a fiducial or its white quiet zone (each quad grown by ``quiet_zone`` of its
    size about its centre; ArUco 4x4 markers are 6 cells wide, so one cell each side is 1/3).

    A fiducial's image is a convex quadrilateral: a point is inside when it lies on the same side of all
    four edges (vectorised over points and quads).
    """
    xy = np.asarray(xy_px, dtype=float).reshape(-1, 2)
    if len(quads_px) == 0 or len(xy) == 0:
        return np.zeros(len(xy), dtype=bool)
    quads = np.asarray(quads_px, dtype=float).reshape(-1, 4, 2)
    centres = quads.mean(axis=1, keepdims=True)
    grown = centres + (quads - centres) * (1.0 + quiet_zone)  # (Q, 4, 2)
    edges = np.roll(grown, -1, axis=1) - grown  # (Q, 4, 2)
    rel = xy[:, None, None, :] - grown[None]  # (N, Q, 4, 2)
    cross = edges[None, ..., 0] * rel[..., 1] - edges[None, ..., 1] * rel[..., 0]  # (N, Q, 4)
    inside = np.all(cross >= 0, axis=2) | np.all(cross <= 0, axis=2)
    return inside.any(axis=1)


def _project(camera: CameraConfig, T_cam_J: np.ndarray, points_J: np.ndarray) -> np.ndarray:
    """Pinhole projection (with the camera's distortion) of points in J into a camera at ``T_cam_J``."""
    return project_points(points_J, camera.K, camera.distortion, invert_pose(T_cam_J), None)


def jig_frame_from_fiducials(left_u8: np.ndarray, right_u8: np.ndarray, jig: JigConfig) -> JigFrame | None:
    """Measure the stereo head's pose in J from the fiducials seen in an 8-bit gray stereo pair.

    Returns ``None`` when fewer than :data:`MIN_FIDUCIALS_PER_IMAGE` configured fiducials are found in
    either image, or when the fitted pose does not explain the corners (the fit did not converge or the
    RMS reprojection error exceeds :data:`MAX_FIDUCIAL_RMS_PX`).
    """
    fid = jig.fiducials
    corners_J = dict(zip(fid.ids, fiducial_corners_J(fid), strict=True))
    expected = jig_frame_from_config(jig)
    found = [
        detect_fiducials(left_u8, fid, expected_quads_px=expected.fiducial_quads_left_px),
        detect_fiducials(right_u8, fid, expected_quads_px=expected.fiducial_quads_right_px),
    ]
    if min(len(f) for f in found) < MIN_FIDUCIALS_PER_IMAGE:
        return None
    cams = (jig.cameras.left, jig.cameras.right)
    # The right camera's pose relative to the left one is fixed by the config (the stereo calibration).
    T_left_right = invert_pose(cams[0].T_J_cam) @ cams[1].T_J_cam
    obj = [np.concatenate([corners_J[i] for i in f]) for f in found]
    img = [np.concatenate([f[i] for i in f]) for f in found]

    ok, rvec, tvec = cv2.solvePnP(
        obj[0], img[0], cams[0].K, np.asarray(cams[0].distortion, float), flags=cv2.SOLVEPNP_IPPE
    )
    if not ok:
        return None

    # The residual is evaluated ~30 times per frame: OpenCV's projectPoints and composeRT work on the
    # rotation vectors directly (measured: 22 ms per frame with optics.project_points, ~3 ms with these).
    T_right_left = invert_pose(T_left_right)
    rvec_rl = cv2.Rodrigues(T_right_left[:3, :3])[0]
    tvec_rl = T_right_left[:3, 3].reshape(3, 1)
    dist = [np.asarray(cam.distortion, float) for cam in cams]

    def residuals(x: np.ndarray) -> np.ndarray:
        rvec_l, tvec_l = x[:3].reshape(3, 1), x[3:].reshape(3, 1)
        rvec_r, tvec_r = cv2.composeRT(rvec_l, tvec_l, rvec_rl, tvec_rl)[:2]
        left_px = cv2.projectPoints(obj[0], rvec_l, tvec_l, cams[0].K, dist[0])[0].reshape(-1, 2)
        right_px = cv2.projectPoints(obj[1], rvec_r, tvec_r, cams[1].K, dist[1])[0].reshape(-1, 2)
        return np.concatenate([(left_px - img[0]).ravel(), (right_px - img[1]).ravel()])

    fit = least_squares(residuals, np.concatenate([rvec.ravel(), tvec.ravel()]), method="lm")
    rms = float(np.sqrt(np.mean(fit.fun**2)))
    if not fit.success or not np.isfinite(rms) or rms > MAX_FIDUCIAL_RMS_PX:
        return None  # a misread corner or a moved fiducial: do not trust this pose
    T_left_J = pose_from_rotvec_translation(fit.x[:3], fit.x[3:])
    T_J_left = invert_pose(T_left_J)
    both = tuple(sorted(set(found[0]) & set(found[1])))
    quads = [np.array(list(f.values())).reshape(-1, 4, 2) for f in found]
    return JigFrame(T_J_left, T_J_left @ T_left_right, "fiducials", rms, both, quads[0], quads[1])


def resolve_jig_frame(
    left_u8: np.ndarray, right_u8: np.ndarray, jig: JigConfig
) -> tuple[JigFrame, list[str]]:
    """The jig frame as ``sensing.extrinsics`` asks, with any warning to report.

    ``"fiducials"`` requires them; ``"config"`` uses the fixed extrinsics; ``"auto"`` measures them when
    found and falls back to the config with a warning.

    Raises
    ------
    EstimationError
        ``sensing.extrinsics == "fiducials"`` and the fiducials were not found.
    """
    mode = jig.sensing.extrinsics
    if mode == "config":
        return jig_frame_from_config(jig), []
    frame = jig_frame_from_fiducials(left_u8, right_u8, jig)
    if frame is not None:
        return frame, []
    message = (
        f"the fiducials {list(jig.fiducials.ids)} were not found (at least {MIN_FIDUCIALS_PER_IMAGE} in each "
        f"image, reprojecting within {MAX_FIDUCIAL_RMS_PX} px)"
    )
    if mode == "fiducials":
        raise EstimationError(
            f"{message} and sensing.extrinsics is 'fiducials': make them visible, or set "
            "sensing.extrinsics = 'config' to use the calibrated camera poses in the config"
        )
    return jig_frame_from_config(jig), [f"{message}: used the camera poses in the config instead"]
