"""ArUco fiducials on the base plate: their dictionaries, their corners in J, and finding them in images."""

from __future__ import annotations

from functools import cache

import cv2
import numpy as np

from softjig.config import FiducialConfig


@cache
def aruco_dictionary_names() -> tuple[str, ...]:
    """Names of the predefined ArUco dictionaries OpenCV offers (``DICT_4X4_50`` ...)."""
    return tuple(sorted(n for n in dir(cv2.aruco) if n.startswith("DICT_") and n[5].isdigit()))


def aruco_dictionary(name: str) -> cv2.aruco.Dictionary:
    """OpenCV's predefined dictionary of that name."""
    return cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, name))


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


def detect_fiducials(
    gray_u8: np.ndarray, fiducials: FiducialConfig, *, expected_quads_px: np.ndarray | None = None
) -> dict[int, np.ndarray]:
    """Find the configured fiducials in one 8-bit gray image with OpenCV's ArUco detector.

    Parameters
    ----------
    gray_u8 : (H, W) uint8 image.
    fiducials : which markers to look for.
    expected_quads_px : (M, 4, 2) where the fiducials should be (e.g. projected with the config's
        camera poses). When given, each is first searched in a window around its expected place (a
        fraction of the cost of the whole image); the whole image is searched only if one is missing.

    Returns
    -------
    dict
        ``{id: (4, 2) corners in px}`` for each configured id found (sub-pixel corners, ArUco order);
        ids not in the config are ignored.
    """
    found: dict[int, np.ndarray] = {}
    if expected_quads_px is not None:
        h, w = gray_u8.shape
        for quad in np.asarray(expected_quads_px, dtype=float):
            side = float(np.ptp(quad, axis=0).max())
            lo = np.floor(quad.min(axis=0) - side).astype(int).clip(0, [w, h])
            hi = np.ceil(quad.max(axis=0) + side).astype(int).clip(0, [w, h])
            if np.any(hi - lo < 8):
                continue
            window = np.ascontiguousarray(gray_u8[lo[1] : hi[1], lo[0] : hi[0]])
            for marker_id, corners in _detect(window, fiducials).items():
                found.setdefault(marker_id, corners + lo)
        if set(fiducials.ids) <= set(found):
            return found
    for marker_id, corners in _detect(gray_u8, fiducials).items():
        found.setdefault(marker_id, corners)
    return found


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


@cache
def _detector(dictionary: str) -> cv2.aruco.ArucoDetector:
    params = cv2.aruco.DetectorParameters()
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    return cv2.aruco.ArucoDetector(aruco_dictionary(dictionary), params)
