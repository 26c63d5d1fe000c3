"""ArUco fiducials on the base plate: their dictionaries, their corners in J, and finding them in images.

Two ways to find them: OpenCV's ArUco detector (:func:`detect_fiducials`, anywhere in the image), and a
fast search near where they are expected (:func:`locate_fiducials_near`): the stereo head's placement is
known to about a millimetre, so each fiducial lies within a few to ~40 pixels of its projection with the
config's poses, and its four edges, corners and cells can be read there directly. Both refine the corners
with the same iteration (OpenCV's ``cornerSubPix`` with ArUco's window, to convergence), so they give
the same corners (to ~1e-3 px, their convergence tolerance).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache

import cv2
import numpy as np

from softjig.aruco import aruco_dictionary
from softjig.config import FiducialConfig
from softjig.errors import InputError
from softjig.sensing.detect import gray_image


def fiducial_corners_J(fiducials: FiducialConfig) -> np.ndarray:
    """The four corners of each fiducial in J, ``(M, 4, 3)`` (mm), in ArUco's order (top-left, top-right,
    bottom-right, bottom-left as seen in the marker image), the marker's image ``x`` along J's ``+x`` and
    its image ``y`` along J's ``+y``, matching how the cameras below the plate see it (DESIGN.md §1)."""
    half = fiducials.size_mm / 2.0
    offsets = np.array([[-half, -half], [half, -half], [half, half], [-half, half]])
    centers = np.asarray(fiducials.centers_mm, dtype=float)
    xy = centers[:, None, :] + offsets[None, :, :]
    z = np.full((*xy.shape[:2], 1), fiducials.z_mm)
    return np.concatenate([xy, z], axis=2)


MIN_SEARCH_WINDOW_PX = 8  # a search window narrower than this (cut by the image's edge) is skipped
_U16_PER_U8 = 257  # 65535 / 255: a uint16 level per uint8 level
_U8_MAX = 255


def fiducial_gray_u8(image: np.ndarray, *, name: str | None = None) -> np.ndarray:
    """The 8-bit gray image ArUco needs, from any image softjig accepts, or an InputError naming it.

    A C-contiguous ``(H, W)`` uint8 gray comes back as it is (no copy, no scan: the estimator's path).
    Other images are checked and converted by :func:`~softjig.sensing.detect.gray_image` (RGB to gray;
    ``uint16`` such as mono16 infrared frames, float32/float64 in [0, 1]; empty, NaN and other dtypes
    refused), then scaled as the estimator scales them: ``uint16`` as ``round(x / 257)``, float as
    ``round(255 x)``.
    """
    arr = np.asarray(image)
    if arr.dtype == np.uint8 and arr.ndim == 2 and arr.size and arr.flags.c_contiguous:
        return arr
    try:
        gray, _ = gray_image(arr)
    except InputError as exc:
        raise InputError(f"{name}: {exc}" if name else str(exc)) from None
    return gray_to_u8(gray)


def gray_to_u8(gray: np.ndarray) -> np.ndarray:
    """An already checked gray image (:func:`~softjig.sensing.detect.gray_image`) as 8 bits: ``uint8`` as
    it is, ``uint16`` as ``round(x / 257)`` in integers, float in [0, 1] as ``round(255 x)``."""
    if gray.dtype == np.uint8:
        return gray
    if gray.dtype == np.uint16:  # x / 257 is never a half-integer: floor((x + 128) / 257) is the nearest
        return ((gray.astype(np.uint32) + _U16_PER_U8 // 2) // _U16_PER_U8).astype(np.uint8)
    return np.clip(np.rint(gray * float(_U8_MAX)), 0, _U8_MAX).astype(np.uint8)


def detect_fiducials(
    gray_u8: np.ndarray, fiducials: FiducialConfig, *, expected_quads_px: np.ndarray | None = None
) -> dict[int, np.ndarray]:
    """Find the configured fiducials in one gray image with OpenCV's ArUco detector.

    Parameters
    ----------
    gray_u8 : (H, W) uint8 image; other images softjig accepts (``uint16`` such as mono16, float in
        [0, 1], RGB) are converted to it by :func:`fiducial_gray_u8`, others refused.
    fiducials : which markers to look for.
    expected_quads_px : (M, 4, 2) where the fiducials should be (e.g. projected with the config's
        camera poses). When given, each is first searched in a window around its expected place (a
        fraction of the cost of the whole image); the whole image is searched only if one is missing.

    Returns
    -------
    dict
        ``{id: (4, 2) corners in px}`` for each configured id found (sub-pixel corners, ArUco order);
        ids not in the config are ignored.

    Raises
    ------
    InputError
        An image that is not a gray or RGB image of a supported dtype, empty, or float outside [0, 1].
    """
    gray_u8 = fiducial_gray_u8(gray_u8)
    found: dict[int, np.ndarray] = {}
    if expected_quads_px is not None:
        h, w = gray_u8.shape
        for quad in np.asarray(expected_quads_px, dtype=float):
            side = float(np.ptp(quad, axis=0).max())
            lo = np.floor(quad.min(axis=0) - side).astype(int).clip(0, [w, h])
            hi = np.ceil(quad.max(axis=0) + side).astype(int).clip(0, [w, h])
            if np.any(hi - lo < MIN_SEARCH_WINDOW_PX):
                continue
            window = np.ascontiguousarray(gray_u8[lo[1] : hi[1], lo[0] : hi[0]])
            for marker_id, corners in _detect(window, fiducials).items():
                found.setdefault(marker_id, corners + lo)
        if set(fiducials.ids) <= set(found):
            return found
    for marker_id, corners in _detect(gray_u8, fiducials).items():
        found.setdefault(marker_id, corners)
    return found


# The as-built head is off by ~1 mm / 0.5 deg (up to ~3 sigma: ~35 px in the image, and the fiducials
# shift differently: the head's tilt is a perspective change): each side of each expected quad is
# searched within +-CAPTURE_PX along its normal, on a few central scanlines.
CAPTURE_PX = 40
CAPTURE_STEP_PX = 2  # samples along a scanline: a rise over 2 px holds an edge split between two pixels,
# and half the samples halve the cache misses (each sample of a vertical scanline is another image row)
CAPTURE_SCANLINES = (0.3, 0.4, 0.5, 0.6, 0.7)  # fractions along each side (one that misses it, where
# the fiducial moved along the side, is outvoted)
MIN_SCANLINES = 3  # that agree on where the side is
CORNER_CRITERIA = (cv2.TERM_CRITERIA_MAX_ITER | cv2.TERM_CRITERIA_EPS, 100, 1e-3)  # converged (px)
MIN_CELL_CONTRAST = 40.0  # gray levels between the white and black cells of a fiducial that was read
SCANLINE_AGREEMENT_PX = 2.0  # a side's scanlines agree when this close to their median
MAX_SIZE_CHANGE_PX = 6.0  # opposite sides must move alike to this (else one took another edge)
_CELL_JITTER = np.array([[-0.2, 0.0], [0.0, 0.0], [0.2, 0.0]])  # samples per cell (in cells), along a row


def locate_fiducials_near(
    gray_u8: np.ndarray, fiducials: FiducialConfig, expected_quads_px: np.ndarray
) -> dict[int, np.ndarray] | None:
    """Find every configured fiducial near where it is expected, without the ArUco detector.

    1. Capture: on five scanlines across each side of each expected quad, the side is the outermost
       sharp black-to-white rise within +-:data:`CAPTURE_PX` (the fiducial's border against its white
       quiet zone; membrane markers are blurred, the cells' rises lie inside the border). Each side
       moves along its normal; the moved sides meet at corners ~1 px from the fiducial's.
    2. Corners: OpenCV's ``cornerSubPix`` iteration from there, with ArUco's window, to convergence.
    3. Identity: all 36 cells read from the refined quads (border and bits, in the expected
       orientation) must match the ids in the dictionary.

    Parameters
    ----------
    gray_u8 : (H, W) uint8 image.
    fiducials : the markers to look for, in the order of ``expected_quads_px``.
    expected_quads_px : (M, 4, 2) where each fiducial should be (px, ArUco corner order).

    Returns
    -------
    dict or None
        ``{id: (4, 2) corners in px}`` for every configured id, or ``None`` if any one was not found
        there as expected (then search with :func:`detect_fiducials`). Both refine the corners with the
        same iteration to convergence, so they give the same corners to its tolerance.
    """
    gray_u8 = np.asarray(gray_u8)
    quads = np.asarray(expected_quads_px, dtype=float).reshape(-1, 4, 2)
    if gray_u8.dtype != np.uint8 or gray_u8.ndim != 2 or len(quads) != len(fiducials.ids):
        return None
    corners = locate_quads_near(np.ascontiguousarray(gray_u8), fiducials, quads.tobytes())
    return None if corners is None else dict(zip(fiducials.ids, corners, strict=True))


def locate_quads_near(
    gray_u8: np.ndarray,
    fiducials: FiducialConfig,
    expected_quads: bytes,
    *,
    table: CaptureTable | None = None,
    white: np.ndarray | None = None,
) -> np.ndarray | None:
    """:func:`locate_fiducials_near` for a C-contiguous uint8 image and the expected quads as the bytes of a
    float64 (M, 4, 2) array, giving the (M, 4, 2) corners or ``None``. ``table`` (:func:`capture_table`
    of these quads and the image's shape) and ``white`` (:func:`cell_patterns` of the fiducials) are made
    here when not given (a frame finder makes them once)."""
    n_quads = len(expected_quads) // (8 * 8)
    table = table if table is not None else capture_table(expected_quads, n_quads, gray_u8.shape)
    if table is None:
        return None
    corners = np.empty((n_quads, 4, 2))
    if white is None:
        white = cell_patterns(fiducials.dictionary, tuple(fiducials.ids))
    from softjig.sensing._fiducial_kernels import locate  # Numba is imported on first use

    found = locate(
        gray_u8,
        table.index,
        table.shape[2],
        table.shape[3],
        table.midpoints,
        table.normals,
        table.offsets,
        MIN_CELL_CONTRAST / 2,
        MIN_SCANLINES,
        SCANLINE_AGREEMENT_PX,
        MAX_SIZE_CHANGE_PX,
        table.window,
        CORNER_CRITERIA[1],
        CORNER_CRITERIA[2],
        _cell_weights(),
        white,
        MIN_CELL_CONTRAST,
        corners,
    )
    return corners if found else None


@dataclass(frozen=True)
class CaptureTable:
    """What the capture step needs of a set of expected quads in an image of a given size (cached).

    Attributes
    ----------
    index : flat image indices of the scanlines' samples, ``(Q * 4 * S * L,)``.
    shape : ``(Q, 4, S, L)``.
    midpoints : (L - 1,) offsets halfway between consecutive samples along the outward normals (px).
    normals, offsets : (Q, 4, 2) each side's outward unit normal and (Q, 4) its line's offset
        (``normal . p = offset`` on the side, px).
    window : ArUco's ``cornerSubPix`` half-window for quads of this size (px).
    """

    index: np.ndarray
    shape: tuple[int, int, int, int]
    midpoints: np.ndarray
    normals: np.ndarray
    offsets: np.ndarray
    window: int


def capture_table(quads_bytes: bytes, n_quads: int, image_shape: tuple[int, int]) -> CaptureTable | None:
    """The capture step's constants for these expected quads (``None`` if a scanline leaves the image)."""
    quads = np.frombuffer(quads_bytes, dtype=float).reshape(n_quads, 4, 2)
    along = quads[:, [1, 2, 3, 0]] - quads  # side k runs from corner k to corner k + 1
    normal = np.stack([along[..., 1], -along[..., 0]], axis=-1)
    normal /= np.linalg.norm(normal, axis=-1, keepdims=True)
    centre_of_quad = quads.mean(axis=1, keepdims=True)
    outward = np.sign(np.einsum("qki,qki->qk", normal, quads + along / 2 - centre_of_quad))
    normal *= outward[..., None]
    steps = np.arange(-CAPTURE_PX, CAPTURE_PX + 1, CAPTURE_STEP_PX, dtype=float)
    t = np.asarray(CAPTURE_SCANLINES)
    on_side = quads[:, :, None, :] + t[None, None, :, None] * along[:, :, None, :]  # (Q, 4, S, 2)
    # The samples (Q, 4, S, L) of each coordinate on its own: a trailing axis of 2 would make every
    # broadcast loop two elements long.
    u, v = (
        np.rint(on_side[..., c, None] + steps * normal[:, :, None, None, c]).astype(np.intp) for c in (0, 1)
    )
    h, w = image_shape
    if min(u.min(), v.min()) < 0 or u.max() >= w or v.max() >= h:
        return None
    table = CaptureTable(
        index=(v * w + u).ravel(),
        shape=u.shape,
        midpoints=(steps[:-1] + steps[1:]) / 2,
        normals=normal,
        offsets=np.einsum("qki,qki->qk", normal, quads),
        window=_refinement_window(quads),
    )
    for value in (table.index, table.midpoints, table.normals, table.offsets):
        value.flags.writeable = False
    return table


def _refinement_window(quads: np.ndarray) -> int:
    """ArUco's ``cornerSubPix`` half-window: 0.3 cell (OpenCV's ``relativeCornerRefinmentWinSize``),
    at most ``cornerRefinementWinSize`` (5) px; cells are a sixth of a 4x4 marker's side."""
    params = _detector_parameters()
    perimeter = np.linalg.norm(quads - quads[:, [1, 2, 3, 0]], axis=-1).sum(axis=-1)
    module = float(perimeter.min()) / (4 * 6)
    return int(
        min(params.cornerRefinementWinSize, max(1, round(params.relativeCornerRefinmentWinSize * module)))
    )


@cache
def _cell_weights() -> np.ndarray:
    """(36 * 3, 4) bilinear weights of the corners (TL, TR, BR, BL) at the cells' sample points."""
    grid = (np.arange(6) + 0.5) / 6.0
    u = (grid[None, :, None] + _CELL_JITTER[None, None, :, 0] / 6.0) + np.zeros((6, 1, 1))
    v = (grid[:, None, None] + _CELL_JITTER[None, None, :, 1] / 6.0) + np.zeros((1, 6, 1))
    weights = np.stack([(1 - u) * (1 - v), u * (1 - v), u * v, (1 - u) * v], axis=-1).reshape(-1, 4)
    weights.flags.writeable = False
    return weights


def cell_patterns(dictionary: str, ids: tuple[int, ...]) -> np.ndarray:
    """(M, 36) which cells of each fiducial are white (1.0; border included, row by row), as drawn."""
    d = aruco_dictionary(dictionary)
    size = d.markerSize + 2
    patterns = np.array([d.generateImageMarker(i, size, borderBits=1) > 127 for i in ids], dtype=float)
    patterns = patterns.reshape(len(ids), -1)
    patterns.flags.writeable = False
    return patterns


def _detect(gray_u8: np.ndarray, fiducials: FiducialConfig) -> dict[int, np.ndarray]:
    corners, ids, _ = _detector(fiducials.dictionary).detectMarkers(gray_u8)
    wanted = set(fiducials.ids)
    found: dict[int, np.ndarray] = {}
    if ids is None:
        return found
    for marker_id, c in zip(ids.ravel().tolist(), corners, strict=True):
        if marker_id in wanted and marker_id not in found:
            found[marker_id] = c.reshape(4, 2).astype(float)
    return found


def _detector(dictionary: str) -> cv2.aruco.ArucoDetector:
    return cv2.aruco.ArucoDetector(aruco_dictionary(dictionary), _detector_parameters())


def _detector_parameters() -> cv2.aruco.DetectorParameters:
    """ArUco's defaults, with its sub-pixel corner refinement iterated to convergence (OpenCV's default
    stops once a step is below 0.1 px, which leaves the corners up to ~0.03 px and the head's pose up to
    ~0.002 deg from where they converge, depending on the contour's corner pixel it started from)."""
    params = cv2.aruco.DetectorParameters()
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    params.cornerRefinementMaxIterations = CORNER_CRITERIA[1]
    params.cornerRefinementMinAccuracy = CORNER_CRITERIA[2]
    return params
