"""A chessboard seen by a camera with lens distortion: the oracle of the stereo calibration's tests.

Rendering is by inverse mapping: each pixel is split into ``S x S`` sub-samples at the centres of its
cells; each sub-sample is undistorted (:func:`softjig.optics.undistort_normalized`, exact to machine
precision), turned into a ray from the camera's centre, and intersected with the board's plane; the
board's colour there (black or white square, the white paper margin, a grey background beyond) is
averaged over the sub-samples. Straight edges are thus area-sampled, and a corner's image is where the
exact projection of the board's corner puts it, to the sub-pixel accuracy the supersampling allows (the
coverage is quantised in steps of ``1 / S^2``). The cameras are in air: no refraction.

Frames: the board's frame has its origin at the first inner corner, ``x`` along a row of inner corners
(``cols`` of them, ``square_mm`` apart), ``y`` along a column (``rows``) and ``z = x × y``; corner ``k``
lies at ``((k % cols) s, (k // cols) s, 0)``, the order of
:meth:`softjig.calibration.stereo.Board.object_points`. The board is seen from either side (the square
at ``i, j`` with ``i + j`` even is black, ``i, j`` the square's indices from -1).
Pixels ``(u, v)`` with the centre of pixel ``(0, 0)`` at ``(0.0, 0.0)``.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from softjig.config import CameraConfig
from softjig.geometry import invert_pose
from softjig.optics import undistort_normalized

__all__ = ["board_corners_px", "camera_rays", "render_chessboard_view"]

_BLACK, _WHITE, _BACKGROUND = 0.06, 0.9, 0.35


def camera_rays(camera: CameraConfig, supersampling: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """The undistorted normalised coordinates ``(x, y)`` (the ray ``(x, y, 1)`` in the camera frame) of
    every sub-sample of every pixel: two ``(H, W, S*S)`` float32 read-only arrays, cached per camera and
    ``S``."""
    return _camera_rays(
        camera.width_px,
        camera.height_px,
        camera.fx_px,
        camera.fy_px,
        camera.cx_px,
        camera.cy_px,
        tuple(camera.distortion),
        int(supersampling),
    )


@lru_cache(maxsize=8)
def _camera_rays(w, h, fx, fy, cx, cy, dist, s) -> tuple[np.ndarray, np.ndarray]:
    # The exact undistortion at every pixel centre (and a one-pixel border); the sub-samples between are
    # interpolated bilinearly: the undistortion is smooth, so the error is ~1e-4 px for strong lenses.
    u = np.arange(-1, w + 1, dtype=float)
    v = np.arange(-1, h + 1, dtype=float)
    uu, vv = np.meshgrid(u, v)
    xy = np.stack([(uu - cx) / fx, (vv - cy) / fy], axis=-1).reshape(-1, 2)
    q = undistort_normalized(xy, np.asarray(dist, float)) if any(dist) else xy
    grid = q.reshape(h + 2, w + 2, 2)
    offsets = (np.arange(s) + 0.5) / s - 0.5
    qx = np.empty((h, w, s * s), np.float32)
    qy = np.empty((h, w, s * s), np.float32)
    for a, dv in enumerate(offsets):
        bv = int(np.floor(dv))
        fv = dv - bv
        for b, du in enumerate(offsets):
            bu = int(np.floor(du))
            fu = du - bu
            g00 = grid[1 + bv : 1 + bv + h, 1 + bu : 1 + bu + w]
            g01 = grid[1 + bv : 1 + bv + h, 2 + bu : 2 + bu + w]
            g10 = grid[2 + bv : 2 + bv + h, 1 + bu : 1 + bu + w]
            g11 = grid[2 + bv : 2 + bv + h, 2 + bu : 2 + bu + w]
            val = (1 - fv) * ((1 - fu) * g00 + fu * g01) + fv * ((1 - fu) * g10 + fu * g11)
            qx[:, :, a * s + b] = val[..., 0]
            qy[:, :, a * s + b] = val[..., 1]
    qx.flags.writeable = False
    qy.flags.writeable = False
    return qx, qy


def render_chessboard_view(
    camera: CameraConfig,
    T_cam_board: np.ndarray,
    cols: int,
    rows: int,
    square_mm: float,
    *,
    margin_squares: float = 1.0,
    supersampling: int = 4,
    blur_sigma_px: float = 0.0,
    noise_std: float = 0.0,
    rng: np.random.Generator | int | None = None,
) -> np.ndarray:
    """Render a chessboard of ``cols x rows`` inner corners as ``camera`` sees it.

    Parameters
    ----------
    camera : intrinsics and distortion (its pose fields are not used: ``T_cam_board`` places the board).
    T_cam_board : (4, 4) the board's pose in the camera frame (mm).
    cols, rows : inner corners as OpenCV counts them (the board has ``(cols + 1) x (rows + 1)`` squares).
    square_mm : side of a square (mm).
    margin_squares : white paper around the squares, in squares.
    supersampling : ``S``, sub-samples per pixel side.
    blur_sigma_px : optional Gaussian blur (optics, focus) after sampling (px).
    noise_std : optional Gaussian sensor noise (fraction of full scale).
    rng : seed or generator of the noise.

    Returns
    -------
    (H, W) uint8 image. Rays that miss the board's plane (or meet it behind the camera) see the background.
    """
    qx, qy = camera_rays(camera, supersampling)
    T_board_cam = invert_pose(np.asarray(T_cam_board, float))
    R, t = T_board_cam[:3, :3], T_board_cam[:3, 3]
    f = np.float32
    dz = qx * f(R[2, 0]) + qy * f(R[2, 1]) + f(R[2, 2])  # ray directions in the board frame
    with np.errstate(divide="ignore", invalid="ignore"):
        lam = f(-t[2]) / dz
    x = (f(t[0]) + lam * (qx * f(R[0, 0]) + qy * f(R[0, 1]) + f(R[0, 2]))) / f(square_mm)  # in squares
    y = (f(t[1]) + lam * (qx * f(R[1, 0]) + qy * f(R[1, 1]) + f(R[1, 2]))) / f(square_mm)
    i = np.floor(x)  # square index: -1 .. cols-1 on the board
    j = np.floor(y)
    on_squares = (i >= -1) & (i <= cols - 1) & (j >= -1) & (j <= rows - 1)
    m = 1.0 + margin_squares
    on_paper = (x >= -m) & (x <= cols + margin_squares) & (y >= -m) & (y <= rows + margin_squares)
    black = on_squares & ((i + j).astype(np.int32) % 2 == 0)
    value = np.where(
        on_paper, np.where(black, np.float32(_BLACK), np.float32(_WHITE)), np.float32(_BACKGROUND)
    )
    value[~(lam > 0)] = _BACKGROUND
    image = value.mean(axis=2)
    if blur_sigma_px > 0:
        import cv2

        image = cv2.GaussianBlur(image, (0, 0), blur_sigma_px)
    if noise_std > 0:
        image = image + np.random.default_rng(rng).normal(0.0, noise_std, image.shape)
    return np.clip(np.round(image * 255.0), 0, 255).astype(np.uint8)


def board_corners_px(
    camera: CameraConfig, T_cam_board: np.ndarray, cols: int, rows: int, square_mm: float
) -> np.ndarray:
    """Exact image positions ``(cols*rows, 2)`` of the inner corners (px, with the camera's distortion)."""
    import cv2

    grid = np.mgrid[0:cols, 0:rows].T.reshape(-1, 2) * square_mm
    pts = np.column_stack([grid, np.zeros(len(grid))])
    T = np.asarray(T_cam_board, float)
    rvec, _ = cv2.Rodrigues(T[:3, :3])
    px, _ = cv2.projectPoints(pts, rvec, T[:3, 3], camera.K, np.asarray(camera.distortion, float))
    return px.reshape(-1, 2)
