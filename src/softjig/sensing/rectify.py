"""Rectify a raw (unrectified) stereo pair with the calibration in the config.

A jig whose ``cameras.rectified`` is false (a calibration written by ``softjig calibrate-stereo``) gives
each camera its own intrinsics, distortion and orientation. The paper's method needs a rectified pair,
so the raw images are warped (``cv2.stereoRectify`` + ``cv2.initUndistortRectifyMap`` + ``cv2.remap``,
bilinear) into the images of two *virtual* cameras that share the optical centres of the real ones but
have the same intrinsics, the same orientation, no distortion, and the right camera on the left one's
``+x`` axis. The rectified jig returned describes those virtual cameras (their poses in J included), so
it satisfies :func:`softjig.config.validate_jig`'s rules for a rectified pair and the rest of the pipeline
(refraction model, fiducials, disparity window) works on it unchanged.

Frames (``DESIGN.md`` §1): ``R1`` maps the left camera's frame to the rectified one
(``p_rect = R1 p_left``), so ``T_J_rect = T_J_left @ [R1^T | 0]``; the right virtual camera has the same
orientation and sits ``baseline`` along the rectified ``x``. The maps and the rectified jig are computed
once per camera configuration and cached.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from softjig.config import CameraConfig, JigConfig, StereoConfig
from softjig.errors import InputError
from softjig.geometry import invert_pose, pose_from_rotation_translation

__all__ = ["Rectification", "T_rect_raw", "rectification", "rectified_jig", "rectify_images", "rectify_pair"]


@dataclass(frozen=True)
class Rectification:
    """The rectification of one stereo configuration.

    Attributes
    ----------
    cameras : the rectified virtual cameras (``rectified = True``).
    R1, R2 : (3, 3) rotations from each real camera's frame to its rectified frame.
    P1, P2 : (3, 4) the rectified projection matrices (OpenCV's).
    maps_left, maps_right : ``(map_x, map_y)`` float32 ``(H, W)`` arrays for ``cv2.remap``: where each
        rectified pixel comes from in the raw image.
    """

    cameras: StereoConfig
    R1: np.ndarray
    R2: np.ndarray
    P1: np.ndarray
    P2: np.ndarray
    maps_left: tuple[np.ndarray, np.ndarray]
    maps_right: tuple[np.ndarray, np.ndarray]


def rectification(cameras: StereoConfig, *, alpha: float = 0.0) -> Rectification:
    """Compute the rectification of a stereo configuration (tens of ms: an estimator computes it once).

    Parameters
    ----------
    cameras : the raw cameras (intrinsics, distortion, poses in J).
    alpha : OpenCV's free scaling: 0 keeps only valid pixels (zooms in), 1 keeps every raw pixel (black
        borders).

    Raises
    ------
    InputError
        The two cameras have different image sizes, or the right camera lies on the left one's ``-x``
        side (the pair is swapped: exchange ``cameras.left`` and ``cameras.right``).
    """
    return _rectification(cameras, float(alpha))


def _rectification(cameras: StereoConfig, alpha: float) -> Rectification:
    left, right = cameras.left, cameras.right
    if (left.width_px, left.height_px) != (right.width_px, right.height_px):
        raise InputError(
            f"cameras.left is {left.width_px}x{left.height_px} px but cameras.right is "
            f"{right.width_px}x{right.height_px}: rectification needs two images of one size"
        )
    size = (left.width_px, left.height_px)
    T_right_left = invert_pose(right.T_J_cam) @ left.T_J_cam  # p_right = R p_left + T (OpenCV's R, T)
    R = np.ascontiguousarray(T_right_left[:3, :3])
    T = np.ascontiguousarray(T_right_left[:3, 3]).reshape(3, 1)
    if (invert_pose(left.T_J_cam) @ right.T_J_cam)[0, 3] <= 0:
        raise InputError(
            "cameras.right lies on the -x side of cameras.left: the pair is swapped; exchange the two "
            "cameras (and the images), or calibrate again with the right images second"
        )
    d1, d2 = np.asarray(left.distortion, float), np.asarray(right.distortion, float)
    R1, R2, P1, P2, _, _, _ = cv2.stereoRectify(
        left.K, d1, right.K, d2, size, R, T, flags=cv2.CALIB_ZERO_DISPARITY, alpha=alpha
    )
    maps_left = cv2.initUndistortRectifyMap(left.K, d1, R1, P1[:3, :3], size, cv2.CV_32FC1)
    maps_right = cv2.initUndistortRectifyMap(right.K, d2, R2, P2[:3, :3], size, cv2.CV_32FC1)
    f, cx, cy = float(P1[0, 0]), float(P1[0, 2]), float(P1[1, 2])
    baseline = -float(P2[0, 3]) / float(P2[0, 0])
    R_J_rect = left.T_J_cam[:3, :3] @ R1.T
    from scipy.spatial.transform import Rotation  # on first use: a slow import for one call

    rot_deg = tuple(float(x) for x in Rotation.from_matrix(R_J_rect).as_rotvec(degrees=True))
    common = dict(
        width_px=size[0],
        height_px=size[1],
        fx_px=f,
        fy_px=f,
        cx_px=cx,
        cy_px=cy,
        distortion=(0.0, 0.0, 0.0, 0.0, 0.0),
        rotation_deg=rot_deg,
    )
    left_rect = CameraConfig(position_mm=left.position_mm, **common)  # type: ignore[arg-type]
    # The right centre is put exactly on the rectified x axis (as the rotation_deg round trip gives it).
    R_exact = left_rect.T_J_cam[:3, :3]
    right_pos = np.asarray(left.position_mm, float) + R_exact @ np.array([baseline, 0.0, 0.0])
    right_rect = CameraConfig(position_mm=tuple(float(x) for x in right_pos), **common)  # type: ignore[arg-type]
    for m in (*maps_left, *maps_right):
        m.flags.writeable = False
    return Rectification(
        cameras=StereoConfig(left=left_rect, right=right_rect, rectified=True),
        R1=R1,
        R2=R2,
        P1=P1,
        P2=P2,
        maps_left=maps_left,
        maps_right=maps_right,
    )


def rectified_jig(jig: JigConfig, *, alpha: float = 0.0) -> JigConfig:
    """``jig`` with its raw cameras replaced by the rectified virtual ones (unchanged if already rectified).

    Raises
    ------
    InputError
        See :func:`rectification`.
    ConfigError
        The rectified cameras do not satisfy the jig's rules (e.g. they no longer see the jig axis).
    """
    if jig.cameras.rectified:
        return jig
    return jig.replace(cameras=rectification(jig.cameras, alpha=alpha).cameras)


def rectify_pair(
    left: np.ndarray, right: np.ndarray, jig: JigConfig, *, alpha: float = 0.0
) -> tuple[np.ndarray, np.ndarray, JigConfig]:
    """Rectify a raw stereo pair with the calibration in ``jig``.

    Parameters
    ----------
    left, right : (H, W) or (H, W, 3) uint8/uint16 (or float in [0, 1]) raw images of
        ``jig.cameras.left`` and ``.right``.
    jig : a jig with ``cameras.rectified = False`` (a rectified one is returned as is, images untouched).
    alpha : see :func:`rectification`.

    Returns
    -------
    left_rect, right_rect : the rectified images (same size and dtype; bilinear; black outside the raw
        image).
    rectified_jig : the jig whose cameras are the rectified virtual cameras, poses in J included.

    Raises
    ------
    InputError
        The images do not have the cameras' size or are not gray/RGB images of a supported dtype, or see
        :func:`rectification`.
    """
    if jig.cameras.rectified:
        return left, right, jig
    rect = rectification(jig.cameras, alpha=alpha)
    left, right = rectify_images(left, right, jig, rect)
    return left, right, jig.replace(cameras=rect.cameras)


#: The dtypes of the images :func:`rectify_images` remaps (as the estimator accepts them).
_IMAGE_DTYPES = frozenset(np.dtype(t) for t in (np.uint8, np.uint16, np.float32, np.float64))


def rectify_images(
    left: np.ndarray, right: np.ndarray, jig: JigConfig, rect: Rectification
) -> tuple[np.ndarray, np.ndarray]:
    """Rectify a raw stereo pair of ``jig``'s raw cameras with their ``rect`` (:func:`rectification`),
    as :func:`rectify_pair` does; an estimator computes ``rect`` once.

    Raises
    ------
    InputError
        The images do not have the cameras' size, or are not gray/RGB images of a supported dtype.
    """
    out = []
    for name, image, cam, maps in (
        ("left", left, jig.cameras.left, rect.maps_left),
        ("right", right, jig.cameras.right, rect.maps_right),
    ):
        image = np.asarray(image)
        if image.dtype not in _IMAGE_DTYPES or not (image.ndim == 2 or image.shape[2:] == (3,)):
            raise InputError(
                f"the {name} image must be an (H, W) gray or (H, W, 3) RGB image of dtype uint8, uint16, "
                f"float32 or float64, got dtype {image.dtype} and shape {image.shape}: pass the camera's "
                "raw frame"
            )
        if image.shape[:2] != (cam.height_px, cam.width_px):
            raise InputError(
                f"the {name} image is {image.shape[1] if image.ndim > 1 else '?'}x{image.shape[0]} px but "
                f"cameras.{name} is {cam.width_px}x{cam.height_px}: pass the config of the cameras that "
                "took the images"
            )
        out.append(cv2.remap(image, maps[0], maps[1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT))
    return out[0], out[1]


def T_rect_raw(jig: JigConfig, side: str, *, alpha: float = 0.0) -> np.ndarray:
    """(4, 4) the pose that maps a raw camera's frame to its rectified virtual camera's (a pure rotation)."""
    rect = rectification(jig.cameras, alpha=alpha)
    return pose_from_rotation_translation(rect.R1 if side == "left" else rect.R2, np.zeros(3))
