"""Stereo camera calibration from views of a chessboard or a ChArUco board (OpenCV).

A user who builds a jig calibrates its two cameras once: intrinsics, lens distortion, the right camera's
pose relative to the left one (hence the baseline) and the rectification that makes the pair a rectified
one. This module is the pure part: images (arrays) in, a :class:`StereoCalibration` out; reading files
and printing are the command line's (:mod:`softjig.cli.calibrate_stereo`).

Conventions
-----------
- Pixels ``(u, v) = (column, row)``, OpenCV's, with the centre of pixel ``(0, 0)`` at ``(0.0, 0.0)``.
- Camera frames are OpenCV's (``x`` right, ``y`` down, ``z`` along the optical axis).
- ``R``, ``T`` are OpenCV's stereo extrinsics: ``p_right = R @ p_left + T`` (mm), i.e. the pose
  ``T_right_left``; :attr:`StereoCalibration.T_left_right` is its inverse, the right camera's pose in the
  left camera's frame (``DESIGN.md`` §1 naming). For a correctly ordered pair the right camera's centre
  lies on the left camera's ``+x`` side.
- Distortion: OpenCV's ``(k1, k2, p1, p2, k3)``, the five coefficients :class:`~softjig.config.CameraConfig`
  stores.

Boards
------
A *chessboard* is named by its **inner** corners as OpenCV counts them, ``cols x rows`` (a board of
7 x 10 squares has 6 x 9 inner corners); corners are found with ``cv2.findChessboardCornersSB`` (sector
based), falling back to ``cv2.findChessboardCorners``, then refined by ``cv2.cornerSubPix``. A
chessboard's corner order is ambiguous up to a 180° turn of the board, and the two cameras of a pair
may pick different orders; a pair's right corners are reversed when their first-to-last direction
opposes the left's (the two cameras of a stereo head look the same way, so the board turns by far less
than 90° between them). A *ChArUco* board's corners carry ids, so the two views are matched by id and
partial views are usable.
"""

from __future__ import annotations

from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Literal

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from softjig.aruco import aruco_dictionary, aruco_dictionary_names
from softjig.config import CameraConfig, JigConfig, StereoConfig
from softjig.errors import EstimationError, InputError
from softjig.geometry import invert_pose, pose_from_rotation_translation

__all__ = [
    "Board",
    "BoardView",
    "StereoCalibration",
    "calibrate_stereo",
    "detect_board",
    "parse_board_size",
    "rig_from_calibration",
]

MIN_VIEWS = 3
OUTLIER_FACTOR = 2.0  # a view is an outlier when its RMS exceeds this times the median view's ...
OUTLIER_FLOOR_PX = 0.3  # ... and exceeds the median by more than this (sub-pixel spreads are normal)


# ------------------------------------------------------------------------------------------- boards

#: A ChArUco marker's side as a fraction of its square's when the board does not say (OpenCV's samples).
DEFAULT_MARKER_FRACTION = 0.75
#: Fewest ChArUco corners a view must show to be used (OpenCV's pose from a board needs a few more than 4).
MIN_CHARUCO_CORNERS = 6
#: cornerSubPix's half window (px) as a fraction of a square's side in the image: a chessboard corner's
#: saddle fills its squares; a ChArUco corner's window stays within the white between it and the nearest
#: marker (this fraction of that inset). Clipped to :data:`SUBPIX_HALF_WINDOW_PX`.
CHESSBOARD_WINDOW_FRACTION, CHARUCO_WINDOW_FRACTION = 0.35, 0.8
SUBPIX_HALF_WINDOW_PX = (2, 11)
#: cornerSubPix's stopping rule: at most 50 iterations, or a step below 1e-4 px.
_SUBPIX_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-4)


@dataclass(frozen=True)
class Board:
    """A planar calibration target.

    Attributes
    ----------
    cols, rows : for ``"chessboard"``, inner corners per row and per column as OpenCV counts them; for
        ``"charuco"``, *squares* per row and per column (the ChArUco convention; inner corners are one
        fewer each way).
    square_mm : side of one square (mm).
    kind : ``"chessboard"`` or ``"charuco"``.
    marker_mm : ChArUco only: side of the ArUco marker inside a white square (mm); default 0.75 square.
    dictionary : ChArUco only: the ArUco dictionary's OpenCV name.
    legacy : ChArUco only: the board has the pattern OpenCV drew before 4.6 (``setLegacyPattern``); it
        differs from the current one only for an even number of rows, and the two cannot be told apart
        from a partial view, so it is the user's to say.
    """

    cols: int
    rows: int
    square_mm: float
    kind: Literal["chessboard", "charuco"] = "chessboard"
    marker_mm: float | None = None
    dictionary: str = "DICT_4X4_50"
    legacy: bool = False

    def __post_init__(self) -> None:
        if self.kind not in ("chessboard", "charuco"):
            raise InputError(f"board kind must be 'chessboard' or 'charuco', got {self.kind!r}")
        least = 2 if self.kind == "chessboard" else 3
        if self.cols < least or self.rows < least:
            raise InputError(
                f"a {self.kind} needs at least {least}x{least} "
                f"{'inner corners' if self.kind == 'chessboard' else 'squares'}, got {self.cols}x{self.rows}"
            )
        if not (np.isfinite(self.square_mm) and self.square_mm > 0):
            raise InputError(f"the square size must be a positive number of mm, got {self.square_mm}")
        if self.kind == "charuco" and not 0 < self.marker_side_mm < self.square_mm:
            raise InputError(f"the ChArUco marker ({self.marker_side_mm} mm) must be smaller than a square")
        if self.kind == "charuco" and self.dictionary not in aruco_dictionary_names():
            raise InputError(
                f"unknown ArUco dictionary {self.dictionary!r}; valid: {', '.join(aruco_dictionary_names())}"
            )

    @property
    def marker_side_mm(self) -> float:
        """ChArUco marker side (mm)."""
        return self.marker_mm if self.marker_mm is not None else DEFAULT_MARKER_FRACTION * self.square_mm

    @property
    def n_corners(self) -> int:
        """How many corners a full view of the board has."""
        if self.kind == "chessboard":
            return self.cols * self.rows
        return (self.cols - 1) * (self.rows - 1)

    def object_points(self) -> np.ndarray:
        """``(n_corners, 3)`` float32 corners in the board's frame (mm, ``z = 0``), in the order of the
        corner ids (``detect_board``'s ``ids`` index this array).

        Chessboard: row-major, ``cols`` corners per row, corner ``k`` at ``((k % cols) s, (k // cols) s)``.
        """
        if self.kind == "chessboard":
            grid = np.mgrid[0 : self.cols, 0 : self.rows].T.reshape(-1, 2)
            pts = np.zeros((self.n_corners, 3), np.float32)
            pts[:, :2] = grid * self.square_mm
            return pts
        return np.asarray(_charuco_board(self).getChessboardCorners(), dtype=np.float32).reshape(-1, 3)


def parse_board_size(text: str) -> tuple[int, int]:
    """``"6x9"`` -> ``(6, 9)``; an :class:`InputError` with the expected form otherwise."""
    parts = text.lower().replace("*", "x").split("x")
    try:
        cols, rows = (int(p) for p in parts)
    except ValueError:
        raise InputError(
            f"--board expects COLSxROWS (inner corners as OpenCV counts them, e.g. 6x9), got {text!r}"
        ) from None
    return cols, rows


def _charuco_board(board: Board) -> cv2.aruco.CharucoBoard:
    """OpenCV's ChArUco board for ``board``, built on each call: it is cheap next to a detection, and a
    cache would be module state shared by every caller."""
    cv_board = cv2.aruco.CharucoBoard(
        (board.cols, board.rows), board.square_mm, board.marker_side_mm, aruco_dictionary(board.dictionary)
    )
    cv_board.setLegacyPattern(board.legacy)
    return cv_board


# ---------------------------------------------------------------------------------------- detection


@dataclass(frozen=True)
class BoardView:
    """The board's corners found in one image.

    Attributes
    ----------
    corners_px : (N, 2) float sub-pixel corners (px).
    ids : (N,) int indices into :meth:`Board.object_points`.
    """

    corners_px: np.ndarray
    ids: np.ndarray


def _gray_u8(image: np.ndarray, name: str) -> np.ndarray:
    img = np.asarray(image)
    if img.ndim == 3 and img.shape[2] == 3:
        img = cv2.cvtColor(img, cv2.COLOR_RGB2GRAY)
    if img.ndim != 2:
        raise InputError(f"{name}: expected a (H, W) gray or (H, W, 3) RGB image, got shape {img.shape}")
    if img.dtype == np.uint16:
        img = (img >> 8).astype(np.uint8)
    if img.dtype != np.uint8:
        raise InputError(f"{name}: expected a uint8 or uint16 image, got {img.dtype}")
    return img


def detect_board(image: np.ndarray, board: Board, *, name: str = "image") -> BoardView | None:
    """Find the board's corners in one image.

    Parameters
    ----------
    image : (H, W) or (H, W, 3) uint8/uint16 image.
    board : the target.
    name : how to name the image in messages.

    Returns
    -------
    BoardView or None
        ``None`` when the board is not found (a chessboard must be seen whole; a ChArUco board needs at
        least :data:`MIN_CHARUCO_CORNERS` corners).
    """
    gray = _gray_u8(image, name)
    if board.kind == "charuco":
        corners, ids, _, _ = cv2.aruco.CharucoDetector(_charuco_board(board)).detectBoard(gray)
        if ids is None or len(ids) < MIN_CHARUCO_CORNERS:
            return None
        # Refine again with cornerSubPix in a window that stays within the white between a corner and
        # the nearest marker (80 % of it): OpenCV 4.8-4.10's detector returns corners 0.5 px off in u and v
        # (rendered truth), 5.0's are unbiased; refined, both agree (RMS 0.14 px on rendered boards).
        pts = corners.reshape(-1, 2).astype(np.float32)
        gaps = np.linalg.norm(pts[:, None] - pts[None], axis=2)
        np.fill_diagonal(gaps, np.inf)
        step = float(np.median(gaps.min(axis=1)))  # one square (px), neighbouring corners' distance
        inset = (board.square_mm - board.marker_side_mm) / 2.0 / board.square_mm
        half = int(np.clip(round(CHARUCO_WINDOW_FRACTION * inset * step), *SUBPIX_HALF_WINDOW_PX))
        pts = cv2.cornerSubPix(gray, pts.reshape(-1, 1, 2), (half, half), (-1, -1), _SUBPIX_CRITERIA)
        return BoardView(pts.reshape(-1, 2).astype(float), ids.ravel().astype(int))
    size = (board.cols, board.rows)
    ok, corners = cv2.findChessboardCornersSB(gray, size, flags=0)
    if not ok:
        flags = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
        ok, corners = cv2.findChessboardCorners(gray, size, flags=flags)
    if not ok:
        return None
    # Refine with the saddle-point search of cornerSubPix, its window scaled to the squares' size in the
    # image: on rendered boards (known truth) it halves the sector-based detector's error (to ~0.05 px).
    grid = corners.reshape(board.rows, board.cols, 2)
    step = min(
        np.linalg.norm(np.diff(grid, axis=0), axis=2).min(),
        np.linalg.norm(np.diff(grid, axis=1), axis=2).min(),
    )
    half = int(np.clip(CHESSBOARD_WINDOW_FRACTION * step, *SUBPIX_HALF_WINDOW_PX))
    corners = cv2.cornerSubPix(gray, corners.astype(np.float32), (half, half), (-1, -1), _SUBPIX_CRITERIA)
    return BoardView(corners.reshape(-1, 2).astype(float), np.arange(board.n_corners))


def _pair_views(left: BoardView, right: BoardView, board: Board) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Object points and the two views' corners, matched corner for corner."""
    obj = board.object_points()
    if board.kind == "chessboard":
        r = right.corners_px
        if np.dot(left.corners_px[-1] - left.corners_px[0], r[-1] - r[0]) < 0:
            r = r[::-1]  # the two detections ordered the board's corners from opposite ends
        return obj, left.corners_px, r
    common, il, ir = np.intersect1d(left.ids, right.ids, return_indices=True)
    return obj[common], left.corners_px[il], right.corners_px[ir]


# -------------------------------------------------------------------------------------- calibration


@dataclass(frozen=True)
class StereoCalibration:
    """A calibrated stereo pair (OpenCV conventions, see the module docstring).

    Attributes
    ----------
    image_size : ``(width, height)`` (px).
    K_left, K_right : (3, 3) intrinsic matrices (px).
    dist_left, dist_right : (5,) distortion ``(k1, k2, p1, p2, k3)``.
    R : (3, 3), T_mm : (3,) ``p_right = R p_left + T`` (mm).
    rms_px : RMS reprojection error over every corner of both cameras (px).
    view_names : the name of each view used (e.g. its left file).
    view_rms_px : (V,) RMS reprojection error of each view, both cameras together (px).
    view_rms_left_px, view_rms_right_px : (V,) the same per camera.
    outliers : indices (into ``view_names``) of views whose error is far above the others.
    skipped : names of views not used and why (board not found in one image, ...).
    R1, R2 : (3, 3) rectifying rotations (``p_rect = R1 p_left``), P1, P2 : (3, 4) rectified projection
        matrices, Q : (4, 4) disparity-to-depth matrix (``cv2.stereoRectify``, zero disparity at infinity).
    """

    image_size: tuple[int, int]
    K_left: np.ndarray
    dist_left: np.ndarray
    K_right: np.ndarray
    dist_right: np.ndarray
    R: np.ndarray
    T_mm: np.ndarray
    rms_px: float
    view_names: tuple[str, ...]
    view_rms_px: np.ndarray
    view_rms_left_px: np.ndarray
    view_rms_right_px: np.ndarray
    outliers: tuple[int, ...]
    skipped: tuple[str, ...]
    R1: np.ndarray = field(repr=False)
    R2: np.ndarray = field(repr=False)
    P1: np.ndarray = field(repr=False)
    P2: np.ndarray = field(repr=False)
    Q: np.ndarray = field(repr=False)

    @property
    def baseline_mm(self) -> float:
        """Distance between the two optical centres (mm)."""
        return float(np.linalg.norm(self.T_mm))

    @property
    def T_left_right(self) -> np.ndarray:
        """(4, 4) the right camera's pose in the left camera's frame (``p_left = T_left_right p_right``)."""
        return invert_pose(pose_from_rotation_translation(self.R, self.T_mm))

    @property
    def right_is_on_left(self) -> bool:
        """True when the "right" camera's centre lies on the left camera's ``-x`` side: the two image sets
        were given the wrong way round (or the images are mirrored)."""
        return bool(self.T_left_right[0, 3] < 0)

    def warnings(self) -> list[str]:
        """What a user should know about this calibration (outliers, swapped cameras, skipped views)."""
        out = []
        med = float(np.median(self.view_rms_px))
        for k in self.outliers:
            out.append(
                f"view {self.view_names[k]} has an RMS reprojection error of {self.view_rms_px[k]:.3f} px "
                f"(median {med:.3f} px): check it for blur or a misdetected board, and remove it if so"
            )
        if self.right_is_on_left:
            out.append(
                f"the right camera lies {abs(self.T_left_right[0, 3]):.1f} mm on the LEFT (-x) of the left "
                "one: the two image sets look swapped; run again with RIGHT_GLOB and LEFT_GLOB exchanged"
            )
        for s in self.skipped:
            out.append(f"skipped {s}")
        return out

    def to_dict(self) -> dict:
        """JSON form: scalars in px and mm, matrices as nested lists."""
        pos = self.T_left_right[:3, 3]
        rot = Rotation.from_matrix(self.T_left_right[:3, :3]).as_rotvec(degrees=True)
        return {
            "rms_px": self.rms_px,
            "fx_px": float(self.K_left[0, 0]),
            "fy_px": float(self.K_left[1, 1]),
            "cx_px": float(self.K_left[0, 2]),
            "cy_px": float(self.K_left[1, 2]),
            "baseline_mm": self.baseline_mm,
            "image_size": list(self.image_size),
            "left": _camera_dict(self.K_left, self.dist_left),
            "right": _camera_dict(self.K_right, self.dist_right),
            "right_in_left_position_mm": pos.tolist(),
            "right_in_left_rotation_deg": rot.tolist(),
            "views": [
                {
                    "name": n,
                    "rms_px": float(a),
                    "rms_left_px": float(b),
                    "rms_right_px": float(c),
                    "outlier": k in self.outliers,
                }
                for k, (n, a, b, c) in enumerate(
                    zip(
                        self.view_names,
                        self.view_rms_px,
                        self.view_rms_left_px,
                        self.view_rms_right_px,
                        strict=True,
                    )
                )
            ],
            "skipped": list(self.skipped),
            "rectification": {
                "R1": self.R1.tolist(),
                "R2": self.R2.tolist(),
                "P1": self.P1.tolist(),
                "P2": self.P2.tolist(),
                "Q": self.Q.tolist(),
            },
            "warnings": self.warnings(),
        }


def _camera_dict(K: np.ndarray, dist: np.ndarray) -> dict:
    return {
        "fx_px": float(K[0, 0]),
        "fy_px": float(K[1, 1]),
        "cx_px": float(K[0, 2]),
        "cy_px": float(K[1, 2]),
        "distortion": [float(d) for d in dist],
    }


def calibrate_stereo(
    left_images: Sequence[np.ndarray],
    right_images: Sequence[np.ndarray],
    board: Board,
    *,
    names: Sequence[str] | None = None,
    fix_k3: bool = False,
    drop_outliers: bool = False,
    workers: int = 2,
) -> StereoCalibration:
    """Calibrate a stereo pair from views of a board (``cv2.calibrateCamera`` per camera for a start,
    then ``cv2.stereoCalibrateExtended`` refining everything together, then ``cv2.stereoRectify``).

    Parameters
    ----------
    left_images, right_images : the pairs' images, one pair per index (gray or RGB, uint8/uint16).
    board : the target seen in every view.
    names : a name per pair for messages (default ``"pair 0"``, ...).
    fix_k3 : hold ``k3 = 0`` (advisable with few views or a narrow lens, where ``k3`` is poorly
        determined).
    drop_outliers : calibrate again without the outlier views (see :attr:`StereoCalibration.outliers`).
    workers : threads for board detection (OpenCV releases the GIL).

    Returns
    -------
    StereoCalibration

    Raises
    ------
    InputError
        Different numbers of left and right images, images of different sizes, or fewer than
        :data:`MIN_VIEWS` pairs in which the board is found in both images (wrong ``--board``?).
    EstimationError
        OpenCV's calibration failed to converge (degenerate views, e.g. all fronto-parallel).
    """
    if len(left_images) != len(right_images):
        raise InputError(
            f"{len(left_images)} left images but {len(right_images)} right ones: "
            "give one right image per left"
        )
    names = list(names) if names is not None else [f"pair {k}" for k in range(len(left_images))]
    sizes = {np.asarray(im).shape[:2] for im in (*left_images, *right_images)}
    if len(sizes) > 1:
        raise InputError(f"the images differ in size ({sorted(sizes)}): give the views of one stereo camera")
    if not sizes:
        raise InputError("no images given")
    h, w = sizes.pop()
    with ThreadPoolExecutor(max(1, workers)) as pool:
        found_l = list(
            pool.map(lambda a: detect_board(a[0], board, name=a[1]), zip(left_images, names, strict=True))
        )
        found_r = list(
            pool.map(lambda a: detect_board(a[0], board, name=a[1]), zip(right_images, names, strict=True))
        )
    obj, img_l, img_r, used, skipped = [], [], [], [], []
    for name, fl, fr in zip(names, found_l, found_r, strict=True):
        if fl is None or fr is None:
            where = (
                "either image" if fl is None and fr is None else ("the left" if fl is None else "the right")
            )
            skipped.append(f"{name}: board not found in {where} image")
            continue
        o, a, b = _pair_views(fl, fr, board)
        if len(o) < 6:
            skipped.append(f"{name}: only {len(o)} corners seen by both cameras")
            continue
        obj.append(o.astype(np.float32))
        img_l.append(a.astype(np.float32).reshape(-1, 1, 2))
        img_r.append(b.astype(np.float32).reshape(-1, 1, 2))
        used.append(name)
    if len(used) < MIN_VIEWS:
        what = (
            f"{board.cols}x{board.rows} inner corners"
            if board.kind == "chessboard"
            else f"a {board.cols}x{board.rows}-square ChArUco board"
        )
        raise InputError(
            f"the board ({what}) was found in both images of only {len(used)} of {len(names)} pairs; "
            f"calibration needs at least {MIN_VIEWS} (10-20 advisable). Check --board (inner corners as "
            "OpenCV counts them, i.e. squares minus one each way) and that the whole board is in view"
            + (
                f"; a ChArUco board with an even number of rows printed by OpenCV < 4.6 has the legacy "
                f"pattern: try {'without' if board.legacy else 'with'} --legacy-pattern"
                if board.kind == "charuco" and board.rows % 2 == 0
                else ""
            )
        )
    cal = _calibrate(obj, img_l, img_r, (w, h), used, fix_k3)
    if drop_outliers and cal.outliers and len(used) - len(cal.outliers) >= MIN_VIEWS:
        keep = [k for k in range(len(used)) if k not in cal.outliers]
        dropped = [f"{used[k]}: outlier ({cal.view_rms_px[k]:.3f} px), dropped" for k in cal.outliers]
        cal = _calibrate(
            [obj[k] for k in keep],
            [img_l[k] for k in keep],
            [img_r[k] for k in keep],
            (w, h),
            [used[k] for k in keep],
            fix_k3,
        )
        skipped += dropped
    return _with_skipped(cal, tuple(skipped))


def _with_skipped(cal: StereoCalibration, skipped: tuple[str, ...]) -> StereoCalibration:
    from dataclasses import replace

    return replace(cal, skipped=skipped)


def _calibrate(obj, img_l, img_r, size, names, fix_k3) -> StereoCalibration:
    flags = cv2.CALIB_FIX_K3 if fix_k3 else 0
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-9)
    try:
        _, K1, d1, _, _ = cv2.calibrateCamera(obj, img_l, size, None, None, flags=flags, criteria=crit)
        _, K2, d2, _, _ = cv2.calibrateCamera(obj, img_r, size, None, None, flags=flags, criteria=crit)
        out = cv2.stereoCalibrateExtended(
            obj,
            img_l,
            img_r,
            K1,
            d1,
            K2,
            d2,
            size,
            None,
            None,
            flags=flags | cv2.CALIB_USE_INTRINSIC_GUESS,
            criteria=crit,
        )
    except cv2.error as exc:
        raise EstimationError(
            f"OpenCV's calibration failed ({exc.msg.strip() if hasattr(exc, 'msg') else exc}): take views "
            "with the board tilted in different directions and covering the whole image"
        ) from None
    rms, K1, d1, K2, d2, R, T = out[:7]
    per_view = np.asarray(out[-1], dtype=float).reshape(-1, 2)
    if not np.isfinite(rms) or not np.all(np.isfinite(K1)) or not np.all(np.isfinite(K2)):
        raise EstimationError(
            "the calibration did not converge: take more views, tilted in different directions"
        )
    view_rms = np.sqrt(np.mean(per_view**2, axis=1))
    med = float(np.median(view_rms))
    outliers = tuple(
        int(k)
        for k in np.flatnonzero((view_rms > OUTLIER_FACTOR * med) & (view_rms > med + OUTLIER_FLOOR_PX))
    )
    R1, R2, P1, P2, Q, _, _ = cv2.stereoRectify(
        K1, d1, K2, d2, size, R, T, flags=cv2.CALIB_ZERO_DISPARITY, alpha=0
    )
    return StereoCalibration(
        image_size=(int(size[0]), int(size[1])),
        K_left=K1,
        dist_left=np.asarray(d1, float).ravel()[:5],
        K_right=K2,
        dist_right=np.asarray(d2, float).ravel()[:5],
        R=R,
        T_mm=np.asarray(T, float).ravel(),
        rms_px=float(rms),
        view_names=tuple(names),
        view_rms_px=view_rms,
        view_rms_left_px=per_view[:, 0],
        view_rms_right_px=per_view[:, 1],
        outliers=outliers,
        skipped=(),
        R1=R1,
        R2=R2,
        P1=P1,
        P2=P2,
        Q=Q,
    )


# --------------------------------------------------------------------------------------- rig config


def _camera_config(
    K: np.ndarray, dist: np.ndarray, size: tuple[int, int], T_J_cam: np.ndarray
) -> CameraConfig:
    rot = Rotation.from_matrix(T_J_cam[:3, :3]).as_rotvec(degrees=True)
    return CameraConfig(
        width_px=int(size[0]),
        height_px=int(size[1]),
        fx_px=float(K[0, 0]),
        fy_px=float(K[1, 1]),
        cx_px=float(K[0, 2]),
        cy_px=float(K[1, 2]),
        distortion=tuple(float(d) for d in dist),  # type: ignore[arg-type]
        position_mm=tuple(float(x) for x in T_J_cam[:3, 3]),  # type: ignore[arg-type]
        rotation_deg=tuple(float(x) for x in rot),  # type: ignore[arg-type]
    )


def rig_from_calibration(base: JigConfig, cal: StereoCalibration) -> JigConfig:
    """The base jig with its cameras replaced by the calibrated ones (``cameras.rectified = false``).

    The left camera keeps the base config's pose in J (the runtime fiducials measure the real one); the
    right camera's pose is the left's composed with the calibrated relative pose,
    ``T_J_right = T_J_left @ T_left_right``.

    Raises
    ------
    ConfigError
        If the calibrated cameras do not fit the jig (e.g. they do not see the jig axis from the base
        config's pose): the message names the field.
    """
    T_J_left = base.cameras.left.T_J_cam
    left = _camera_config(cal.K_left, cal.dist_left, cal.image_size, T_J_left)
    right = _camera_config(cal.K_right, cal.dist_right, cal.image_size, T_J_left @ cal.T_left_right)
    return base.replace(cameras=StereoConfig(left=left, right=right, rectified=False))
