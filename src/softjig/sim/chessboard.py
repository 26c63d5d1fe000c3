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

__all__ = [
    "board_corners_px",
    "camera_rays",
    "charuco_corners_px",
    "charuco_pattern",
    "render_charuco_view",
    "render_chessboard_view",
]

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
    x_mm, y_mm, hit = _board_plane_coords(camera, T_cam_board, supersampling)
    x = x_mm / np.float32(square_mm)  # in squares
    y = y_mm / np.float32(square_mm)
    i = np.floor(x)  # square index: -1 .. cols-1 on the board
    j = np.floor(y)
    on_squares = (i >= -1) & (i <= cols - 1) & (j >= -1) & (j <= rows - 1)
    m = 1.0 + margin_squares
    on_paper = (x >= -m) & (x <= cols + margin_squares) & (y >= -m) & (y <= rows + margin_squares)
    black = on_squares & ((i + j).astype(np.int32) % 2 == 0)
    value = np.where(
        on_paper, np.where(black, np.float32(_BLACK), np.float32(_WHITE)), np.float32(_BACKGROUND)
    )
    value[~hit] = _BACKGROUND
    return _finish(value.mean(axis=2), blur_sigma_px, noise_std, rng)


def _board_plane_coords(
    camera: CameraConfig, T_cam_board: np.ndarray, supersampling: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Where each sub-sample's ray meets the board's plane ``z = 0``: ``x, y`` in the board's frame (mm,
    ``(H, W, S*S)`` float32; ``-1e6`` where it misses) and whether the ray meets it in front of the camera
    (bool, same shape)."""
    qx, qy = camera_rays(camera, supersampling)
    T_board_cam = invert_pose(np.asarray(T_cam_board, float))
    R, t = T_board_cam[:3, :3], T_board_cam[:3, 3]
    f = np.float32
    dz = qx * f(R[2, 0]) + qy * f(R[2, 1]) + f(R[2, 2])  # ray directions in the board frame
    with np.errstate(divide="ignore", invalid="ignore"):
        lam = f(-t[2]) / dz
        x = f(t[0]) + lam * (qx * f(R[0, 0]) + qy * f(R[0, 1]) + f(R[0, 2]))
        y = f(t[1]) + lam * (qx * f(R[1, 0]) + qy * f(R[1, 1]) + f(R[1, 2]))
    hit = lam > 0
    far = f(-1e6)  # off any board: misses get a finite coordinate (no NaN through the look-ups)
    return np.where(hit, x, far), np.where(hit, y, far), hit


def _finish(image: np.ndarray, blur_sigma_px: float, noise_std: float, rng) -> np.ndarray:
    """Blur, noise and quantisation of a ``[0, 1]`` float image to uint8."""
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


# ------------------------------------------------------------------------------------------ ChArUco
#
# A ChArUco board of ``cols x rows`` *squares* (OpenCV's convention): its frame is OpenCV's
# (``cv2.aruco.CharucoBoard``): origin at the outer top-left corner of the squares as the board's image
# (``generateImage``) shows it, ``x`` along a row (to the right), ``y`` down the columns, ``z = x × y``
# into the board; inner corner ``k`` at ``((k % (cols-1) + 1) s, (k // (cols-1) + 1) s, 0)``. The squares
# alternate black and white; an ArUco marker (its side ``marker_mm``, centred) sits in every white
# square, ids ``0, 1, ...`` in row-major order. Which squares are white is the one thing OpenCV changed:
# since 4.6 the top-left square is black (``(i + j)`` even black) whatever the size; before, and with
# ``setLegacyPattern(True)``, a board with an even number of rows starts with a marker (``(i + j)`` odd
# black). A board with an odd number of rows is the same in both.


def charuco_pattern(cols: int, rows: int, *, legacy: bool = False) -> np.ndarray:
    """``(rows, cols)`` int array: the marker id in each white square, ``-1`` in the black ones (the
    pattern above; ``legacy`` selects the pre-4.6 layout, which differs only for an even ``rows``)."""
    j, i = np.mgrid[0:rows, 0:cols]
    first_black = 1 if (legacy and rows % 2 == 0) else 0
    white = (i + j) % 2 != first_black
    ids = np.full((rows, cols), -1, dtype=np.int64)
    ids[white] = np.arange(int(white.sum()))
    return ids


def render_charuco_view(
    camera: CameraConfig,
    T_cam_board: np.ndarray,
    cols: int,
    rows: int,
    square_mm: float,
    marker_mm: float,
    dictionary: str = "DICT_4X4_50",
    *,
    legacy: bool = False,
    margin_squares: float = 0.5,
    supersampling: int = 4,
    blur_sigma_px: float = 0.0,
    noise_std: float = 0.0,
    rng: np.random.Generator | int | None = None,
) -> np.ndarray:
    """Render a ChArUco board of ``cols x rows`` squares as ``camera`` sees it (see the section's notes).

    The board is drawn from its definition (squares by parity, markers from the dictionary's bits), not
    from OpenCV's ``generateImage``, so a test can compare the two; edges are exact and area-sampled as
    for :func:`render_chessboard_view`.

    Parameters
    ----------
    camera : intrinsics and distortion (its pose fields are not used).
    T_cam_board : (4, 4) the board's pose in the camera frame (mm).
    cols, rows : squares per row and per column.
    square_mm, marker_mm : side of a square and of a marker (mm), ``0 < marker_mm < square_mm``.
    dictionary : the ArUco dictionary's OpenCV name.
    legacy : the pre-4.6 pattern (``CharucoBoard.setLegacyPattern(True)``).
    margin_squares : white paper around the squares, in squares.
    supersampling, blur_sigma_px, noise_std, rng : as for :func:`render_chessboard_view`.

    Returns
    -------
    (H, W) uint8 image.
    """
    from softjig.aruco import aruco_dictionary

    if not 0 < marker_mm < square_mm:
        raise ValueError(f"the marker ({marker_mm} mm) must be smaller than a square ({square_mm} mm)")
    ids = charuco_pattern(cols, rows, legacy=legacy)
    n_markers = int(ids.max()) + 1
    dic = aruco_dictionary(dictionary)
    if n_markers > len(dic.bytesList):
        raise ValueError(f"{dictionary} has {len(dic.bytesList)} markers, the board needs {n_markers}")
    cells = dic.markerSize + 2  # the bits and a one-bit black border
    import cv2

    bits = np.stack([cv2.aruco.generateImageMarker(dic, k, cells, borderBits=1) for k in range(n_markers)])
    bits = np.concatenate([bits, np.full((1, cells, cells), 255, np.uint8)]) > 127  # [-1]: all white

    x_mm, y_mm, hit = _board_plane_coords(camera, T_cam_board, supersampling)
    s = np.float32(square_mm)
    i = np.floor(x_mm / s).astype(np.int64)
    j = np.floor(y_mm / s).astype(np.int64)
    on_squares = (i >= 0) & (i < cols) & (j >= 0) & (j < rows)
    sq = ids[np.clip(j, 0, rows - 1), np.clip(i, 0, cols - 1)]
    # Inside a white square: the marker's cell, or the white around it.
    off = np.float32((square_mm - marker_mm) / 2.0)
    cell = np.float32(marker_mm / cells)
    a = np.floor((x_mm - i * s - off) / cell).astype(np.int64)  # cell column
    b = np.floor((y_mm - j * s - off) / cell).astype(np.int64)  # cell row
    in_marker = (a >= 0) & (a < cells) & (b >= 0) & (b < cells) & (sq >= 0)
    marker = np.where(in_marker, sq, n_markers)  # n_markers indexes the all-white stand-in
    white = np.where(sq >= 0, bits[marker, np.clip(b, 0, cells - 1), np.clip(a, 0, cells - 1)], False)
    m = margin_squares * square_mm
    on_paper = (x_mm >= -m) & (x_mm <= cols * square_mm + m) & (y_mm >= -m) & (y_mm <= rows * square_mm + m)
    value = np.where(on_squares & ~white, np.float32(_BLACK), np.float32(_WHITE))
    value = np.where(on_paper & hit, value, np.float32(_BACKGROUND))
    return _finish(value.mean(axis=2), blur_sigma_px, noise_std, rng)


def charuco_corners_px(
    camera: CameraConfig, T_cam_board: np.ndarray, cols: int, rows: int, square_mm: float
) -> np.ndarray:
    """Exact image positions ``((cols-1)*(rows-1), 2)`` of a ChArUco board's inner corners in id order
    (px, with the camera's distortion); the board's frame as above."""
    import cv2

    grid = (np.mgrid[1:cols, 1:rows].T.reshape(-1, 2)) * square_mm
    pts = np.column_stack([grid, np.zeros(len(grid))])
    T = np.asarray(T_cam_board, float)
    rvec, _ = cv2.Rodrigues(T[:3, :3])
    px, _ = cv2.projectPoints(pts, rvec, T[:3, 3], camera.K, np.asarray(camera.distortion, float))
    return px.reshape(-1, 2)
