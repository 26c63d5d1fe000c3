"""The peer marker detectors of the benchmark suite, each written independently of softjig's code.

Every detector takes one camera image (``(H, W)`` ``uint8``/``uint16`` as rendered or recorded) and
returns the marker centres as an ``(N, 2)`` float64 array of ``(u, v)`` = (column, row) pixels, with the
centre of pixel ``(0, 0)`` at ``(0, 0)``. The conversion of the image is part of each one's time.

* :func:`plain_log`: the obvious full-resolution detector: scale-normalised LoG (OpenCV Gaussian then
  5-point Laplacian), a square non-maximum suppression by grey dilation, a threshold, and a 3x3
  least-squares quadratic fit around each peak.
* :func:`skimage_blob_log`: ``skimage.feature.blob_log`` over a small sigma range around the markers'
  scale; integer centres (its output).
* :func:`cv2_blob`: ``cv2.SimpleBlobDetector`` for bright blobs of the markers' area and roundness; its
  centres are the mean of the binary regions' centroids over a series of thresholds (sub-pixel).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np


def _as_float(image: np.ndarray) -> np.ndarray:
    scale = 65535.0 if image.dtype == np.uint16 else 255.0
    return image.astype(np.float32) * np.float32(1.0 / scale)


def plain_log(image: np.ndarray, *, sigma_px: float, threshold: float) -> np.ndarray:
    """Full-resolution scale-normalised LoG maxima above ``threshold``, refined by a 3x3 quadratic fit.

    ``sigma_px``: LoG scale (px); ``threshold``: minimum of ``-sigma^2 LoG`` on the [0, 1] image.
    """
    gray = _as_float(image)
    smooth = cv2.GaussianBlur(gray, (0, 0), sigma_px, borderType=cv2.BORDER_REFLECT)
    response = -(sigma_px**2) * cv2.Laplacian(smooth, cv2.CV_32F, ksize=1, borderType=cv2.BORDER_REFLECT)
    half = max(1, int(2 * sigma_px))
    dilated = cv2.dilate(response, np.ones((2 * half + 1, 2 * half + 1), np.uint8))
    border = int(np.ceil(np.sqrt(2) * sigma_px))
    peak = (response >= dilated) & (response > threshold)
    peak[:border], peak[-border:], peak[:, :border], peak[:, -border:] = False, False, False, False
    rows, cols = np.nonzero(peak)
    # z = a + b x + c y + d x^2 + e x y + f y^2 on the 3x3 window; the centre is its stationary point.
    dy, dx = (g.ravel() for g in np.mgrid[-1:2, -1:2])
    design = np.column_stack([np.ones(9), dx, dy, dx * dx, dx * dy, dy * dy])
    window = response[rows[:, None] + dy, cols[:, None] + dx].astype(np.float64)
    _, b, c, d, e, f = (window @ np.linalg.pinv(design).T).T
    det = 4 * d * f - e * e
    ok = (d < 0) & (det > 0)
    det = np.where(ok, det, 1.0)
    x, y = (e * c - 2 * f * b) / det, (e * b - 2 * d * c) / det
    ok &= (np.abs(x) <= 1) & (np.abs(y) <= 1)
    return np.column_stack([cols + np.where(ok, x, 0.0), rows + np.where(ok, y, 0.0)])


def skimage_blob_log(
    image: np.ndarray, *, min_sigma: float, max_sigma: float, num_sigma: int, threshold: float
) -> np.ndarray:
    """``skimage.feature.blob_log`` on the [0, 1] image (its own scale normalisation); integer centres."""
    from skimage.feature import blob_log

    blobs = blob_log(
        _as_float(image),
        min_sigma=min_sigma,
        max_sigma=max_sigma,
        num_sigma=num_sigma,
        threshold=threshold,
        exclude_border=int(np.ceil(np.sqrt(2) * min_sigma)),
    )
    return np.column_stack([blobs[:, 1], blobs[:, 0]]).astype(np.float64) if len(blobs) else np.empty((0, 2))


@dataclass(frozen=True)
class BlobParams:
    """The settings of ``cv2.SimpleBlobDetector`` the suite tunes (grey levels of an 8-bit image, px^2)."""

    min_threshold: float = 50.0
    max_threshold: float = 220.0
    threshold_step: float = 10.0
    min_area_px2: float = 40.0
    max_area_px2: float = 700.0
    min_circularity: float = 0.6
    min_dist_px: float = 6.0


def cv2_blob(image: np.ndarray, *, params: BlobParams) -> np.ndarray:
    """``cv2.SimpleBlobDetector`` for bright round blobs (the image reduced to 8 bits first)."""
    gray = (image >> 8).astype(np.uint8) if image.dtype == np.uint16 else image
    p = cv2.SimpleBlobDetector_Params()
    p.filterByColor, p.blobColor = True, 255
    p.minThreshold, p.maxThreshold, p.thresholdStep = (
        params.min_threshold,
        params.max_threshold,
        params.threshold_step,
    )
    p.minRepeatability = 2
    p.filterByArea, p.minArea, p.maxArea = True, params.min_area_px2, params.max_area_px2
    p.filterByCircularity, p.minCircularity = True, params.min_circularity
    p.filterByInertia, p.minInertiaRatio = True, 0.3
    p.filterByConvexity, p.minConvexity = True, 0.8
    p.minDistBetweenBlobs = params.min_dist_px
    keypoints = cv2.SimpleBlobDetector_create(p).detect(gray)
    return np.array([kp.pt for kp in keypoints], dtype=np.float64).reshape(-1, 2)
