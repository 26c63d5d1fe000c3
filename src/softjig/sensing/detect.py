"""Marker detection: Laplacian-of-Gaussian blobs with sub-pixel quadratic refinement.

The sensing soft jig images white hemispherical markers on a black membrane. Each marker
appears as a bright, blurred, roughly circular blob. Following Sakuma et al., markers are
found as local maxima of the scale-normalised negative Laplacian of Gaussian (LoG) whose
scale is matched to the marker size in the image, and each maximum is refined to sub-pixel
accuracy by a least-squares 2-D quadratic fit to the response around it.

Conventions
-----------
* Images are ``numpy`` arrays of dtype ``uint8`` or ``uint16``, shape ``(H, W)`` (gray) or
  ``(H, W, 3)`` (RGB); float images already scaled to [0, 1] (the output of
  :func:`to_gray_float`) are accepted too.
* Pixel coordinates are ``(u, v) = (column, row)`` in float64, with the centre of pixel
  ``(0, 0)`` at ``(0.0, 0.0)``.

Everything here is pure: arrays in, frozen dataclasses out.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import cv2
import numpy as np
import numpy.typing as npt
from scipy.spatial import cKDTree

from softjig.checks import finite_float
from softjig.errors import InputError

__all__ = [
    "DEFAULT_THRESHOLD",
    "Markers",
    "check_image_content",
    "detect_markers",
    "log_sigma_px",
    "to_gray_float",
]

#: Default threshold on the scale-normalised response ``R = -sigma^2 * LoG(I)`` of the
#: [0, 1]-scaled image. See :func:`detect_markers`, Notes.
DEFAULT_THRESHOLD: float = 0.05

_FULL_SCALE = {np.dtype(np.uint8): 255.0, np.dtype(np.uint16): 65535.0}
_BLANK_STD = 1e-3  # std below this fraction of full scale: blank image
_SATURATED_FRACTION = 0.5  # more than this fraction of pixels at full scale: saturated
_REFINE_METHODS = ("quadratic", None)
_FIT_HALF_WIDTH = 1  # quadratic fit on the (2*1+1) x (2*1+1) = 3x3 neighbourhood
_MAX_REFINE_OFFSET_PX = 1.0


def _quadratic_fit_pinv(half_width: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Offsets of the fit window and the pseudo-inverse of its quadratic design matrix."""
    r = np.arange(-half_width, half_width + 1, dtype=np.float64)
    dy, dx = np.meshgrid(r, r, indexing="ij")  # row-major window, same order as the gather
    dx, dy = dx.ravel(), dy.ravel()
    design = np.column_stack([np.ones_like(dx), dx, dy, dx * dx, dx * dy, dy * dy])
    return dx.astype(np.intp), dy.astype(np.intp), np.linalg.pinv(design)


_FIT_DX, _FIT_DY, _FIT_PINV = _quadratic_fit_pinv(_FIT_HALF_WIDTH)


@dataclass(frozen=True, eq=False)
class Markers:
    """Markers detected in one image.

    Attributes
    ----------
    xy_px : numpy.ndarray, shape (N, 2), float64
        Marker centres ``(u, v)`` in pixels, sorted by decreasing ``response``.
    response : numpy.ndarray, shape (N,), float64
        Scale-normalised negative LoG response ``R = -sigma^2 * LoG(I)`` at each peak
        (dimensionless, image scaled to [0, 1]); at the refined sub-pixel peak when the
        quadratic refinement succeeded.
    sigma_px : float
        LoG scale used for the detection, in pixels.

    Notes
    -----
    Instances are immutable: the arrays are read-only. Equality is identity (arrays do
    not support ``==`` as a truth value); compare fields with ``numpy.testing``.
    """

    xy_px: np.ndarray
    response: np.ndarray
    sigma_px: float

    def __post_init__(self) -> None:
        xy = np.array(self.xy_px, dtype=np.float64).reshape(-1, 2)
        response = np.array(self.response, dtype=np.float64).reshape(-1)
        if len(xy) != len(response):
            raise InputError(
                f"Markers: xy_px has {len(xy)} rows but response has {len(response)} "
                "values; pass one response per marker."
            )
        xy.setflags(write=False)
        response.setflags(write=False)
        object.__setattr__(self, "xy_px", xy)
        object.__setattr__(self, "response", response)
        object.__setattr__(self, "sigma_px", float(self.sigma_px))

    def __len__(self) -> int:
        return int(self.xy_px.shape[0])


def to_gray_float(image: npt.ArrayLike) -> np.ndarray:
    """Convert a camera image to a float32 gray image scaled to [0, 1].

    Parameters
    ----------
    image : array_like, shape (H, W) or (H, W, 3), dtype uint8, uint16, float32 or float64
        Gray or RGB image. ``uint8`` is divided by 255 and ``uint16`` by 65535. Float
        images must already be scaled to [0, 1] (e.g. the output of this function, which
        is returned unchanged, so converting twice costs nothing).

    Returns
    -------
    numpy.ndarray, shape (H, W), float32
        Gray image in [0, 1] (1.0 is full scale of the input dtype).

    Raises
    ------
    InputError
        If the array is not 2-D gray or 3-channel RGB, its dtype is not one of the above,
        it is empty, or a float image has values outside [0, 1] (or NaN).

    Notes
    -----
    RGB is converted once, in the input dtype, with ``cv2.cvtColor(..., COLOR_RGB2GRAY)``
    (``Y = 0.299 R + 0.587 G + 0.114 B``, rounded to the input dtype), so a gray image and
    the RGB image with that gray in all three channels give bit-identical results. The
    scaling is exact in the sense that a ``uint8`` image and the same image as ``uint16``
    (``x * 257``) give bit-identical float32 outputs.
    """
    arr = np.asarray(image)
    if arr.ndim == 3 and arr.shape[2] == 3:
        is_rgb = True
    elif arr.ndim == 2:
        is_rgb = False
    else:
        raise InputError(
            f"expected a gray image of shape (H, W) or an RGB image of shape (H, W, 3), "
            f"got an array of shape {arr.shape}; pass a single gray or RGB frame "
            "(convert RGBA/BGR or stacks of frames first)."
        )
    is_float = arr.dtype in (np.dtype(np.float32), np.dtype(np.float64))
    if arr.dtype not in _FULL_SCALE and not is_float:
        raise InputError(
            f"unsupported image dtype {arr.dtype}; supported dtypes are uint8 and uint16 "
            "(camera frames) and float32/float64 scaled to [0, 1]. Pass the camera's raw "
            "frame."
        )
    if arr.size == 0:
        raise InputError(f"the image is empty (shape {arr.shape}); check that the frame was read correctly.")
    if is_float:
        arr = np.ascontiguousarray(arr, dtype=np.float32)
        low, high = float(arr.min()), float(arr.max())
        if not (low >= 0.0 and high <= 1.0):  # also rejects NaN
            raise InputError(
                f"a float image must be scaled to [0, 1], got values in [{low}, {high}]; "
                "pass the camera's integer frame or divide by its full scale."
            )
        return cv2.cvtColor(arr, cv2.COLOR_RGB2GRAY) if is_rgb else arr
    arr = np.ascontiguousarray(arr)
    if is_rgb:
        arr = cv2.cvtColor(arr, cv2.COLOR_RGB2GRAY)
    return arr.astype(np.float32) / np.float32(_FULL_SCALE[arr.dtype])


def check_image_content(gray: npt.ArrayLike, *, name: str = "the image") -> None:
    """Reject images that cannot contain usable markers: blank or saturated.

    Parameters
    ----------
    gray : array_like, shape (H, W), float
        Gray image scaled to [0, 1], as returned by :func:`to_gray_float`.
    name : str, optional
        What to call the image in messages, e.g. ``"the left image"``.

    Raises
    ------
    InputError
        If the image is blank (standard deviation below 1e-3 of full scale: no light,
        lens cap, dead camera) or saturated (more than half of the pixels at full scale:
        overexposed).

    Notes
    -----
    :func:`detect_markers` does not call this: a valid image without markers simply
    gives an empty result. Call it where a blank or saturated frame means a faulty setup.
    """
    arr = np.asarray(gray)
    if arr.ndim != 2 or arr.size == 0 or not np.issubdtype(arr.dtype, np.floating):
        raise InputError(
            f"{name} must be a non-empty float gray image of shape (H, W) scaled to "
            f"[0, 1], got dtype {arr.dtype} and shape {arr.shape}; convert it with "
            "to_gray_float() first."
        )
    # A 1-in-4 subsample decides blank or saturated as well as every pixel, at a sixteenth of the cost.
    sample = np.ascontiguousarray(arr[::4, ::4], dtype=np.float32)
    mean, std = (float(v) for v in np.ravel(cv2.meanStdDev(sample)))
    if std < _BLANK_STD:
        raise InputError(
            f"{name} is blank: its gray levels vary by only {std:.2e} of full scale "
            f"(mean {mean:.3f}); check the lighting/exposure, "
            "the lens cap and the camera connection."
        )
    saturated = float(np.count_nonzero(sample >= 1.0)) / sample.size
    if saturated > _SATURATED_FRACTION:
        raise InputError(
            f"{name} is saturated: {100.0 * saturated:.0f}% of its pixels are at full "
            "scale; reduce the exposure time, gain or illumination."
        )


def log_sigma_px(marker_diameter_px: float, *, blur_sigma_px: float = 0.0) -> float:
    """LoG scale that gives the strongest response at the centre of a marker.

    Parameters
    ----------
    marker_diameter_px : float
        Diameter of the marker's bright disc in the image, in pixels (> 0).
    blur_sigma_px : float, optional
        Standard deviation of any additional Gaussian blur of the marker image (optics,
        defocus), in pixels (>= 0). Default 0: a sharp disc.

    Returns
    -------
    float
        LoG standard deviation ``sigma`` in pixels.

    Raises
    ------
    InputError
        If the diameter is not positive and finite or the blur is negative.

    Notes
    -----
    For a sharp disc of radius ``rho`` the centre response of the scale-normalised LoG,
    ``A (rho/sigma)^2 exp(-rho^2 / (2 sigma^2))``, is largest at ``rho = sqrt(2) sigma``,
    the relation used by ``skimage.feature.blob_log``. With an extra Gaussian blur ``b``
    the centre response is ``A rho^2 sigma^2 / t^2 exp(-rho^2 / (2 t))`` with
    ``t = sigma^2 + b^2``, which is largest at

    ``sigma^2 = (rho^2 + sqrt(rho^4 + 16 b^4)) / 4``

    (reducing to ``rho^2 / 2`` for ``b = 0``). For the nominal markers (15 px diameter,
    blur 3 px) this gives 5.55 px instead of 5.30 px; callers may also pass their own
    sigma to :func:`detect_markers`.

    Examples
    --------
    >>> round(log_sigma_px(15.0), 3)
    5.303
    >>> round(log_sigma_px(15.0, blur_sigma_px=3.0), 3)
    5.546
    """
    d = finite_float(marker_diameter_px, "marker_diameter_px")
    b = finite_float(blur_sigma_px, "blur_sigma_px")
    if d <= 0.0:
        raise InputError(f"marker_diameter_px must be > 0, got {d}.")
    if b < 0.0:
        raise InputError(f"blur_sigma_px must be >= 0, got {b}.")
    rho2 = (0.5 * d) ** 2
    return math.sqrt((rho2 + math.sqrt(rho2 * rho2 + 16.0 * b**4)) / 4.0)


def detect_markers(
    image: npt.ArrayLike,
    *,
    sigma_px: float,
    threshold: float = DEFAULT_THRESHOLD,
    min_distance_px: float | None = None,
    border_px: int | None = None,
    refine: Literal["quadratic"] | None = "quadratic",
) -> Markers:
    """Detect bright circular markers as maxima of the scale-normalised LoG.

    Parameters
    ----------
    image : array_like, shape (H, W) or (H, W, 3)
        Camera image, ``uint8`` or ``uint16``, or a float image scaled to [0, 1] such as
        the output of :func:`to_gray_float` (see there).
    sigma_px : float
        LoG scale in pixels (> 0), typically ``log_sigma_px(marker_diameter_px)``.
    threshold : float, optional
        Minimum response ``R`` of a marker (>= 0, dimensionless, see Notes). The default
        0.05 detects nominal markers down to a contrast of about 0.15 of full scale and
        rejects camera noise and bead speckle.
    min_distance_px : float, optional
        Non-maximum suppression radius in pixels (>= 1): a peak is kept only if it is the
        largest response within the square of half-width ``floor(min_distance_px)``
        around it (Chebyshev distance, like ``skimage.feature.peak_local_max``); of
        equal peaks closer than that, the first in row-major order is kept. Default
        ``2 * sigma_px``: LoG responses of blobs closer than about ``2 sigma`` merge into
        one peak anyway, and markers are much farther apart.
    border_px : int, optional
        Peaks closer than this to the image edge are discarded (>= 0). Default
        ``ceil(sqrt(2) * sigma_px)``, one matched marker radius, so that markers cut by
        the image edge (biased centres) are not reported. At least 1 is always used,
        because the refinement needs the 3x3 neighbourhood.
    refine : {"quadratic", None}, optional
        ``"quadratic"`` (default): sub-pixel centre from a least-squares fit of
        ``z = a + b x + c y + d x^2 + e x y + f y^2`` to the 3x3 response neighbourhood
        of each peak; the centre is the stationary point of the fit. If the fit is not a
        maximum (``d < 0`` and ``4 d f - e^2 > 0``) or the stationary point is more than
        1 px from the peak pixel in ``u`` or ``v``, the integer peak is kept (the marker
        is not dropped). The response is smooth at the marker scale, so a 5x5 window
        was measured to be no more accurate (bias below 0.005 px RMS for both).
        ``None``: integer peak positions.

    Returns
    -------
    Markers
        Centres (``(u, v)`` px, sorted by decreasing response), responses and the sigma
        used. Empty (``xy_px.shape == (0, 2)``) if nothing exceeds the threshold.

    Raises
    ------
    InputError
        For an invalid image (see :func:`to_gray_float`) or invalid parameters.

    Notes
    -----
    The response is ``R = -sigma^2 (d^2/du^2 + d^2/dv^2) (G_sigma * I)`` on the image
    ``I`` scaled to [0, 1], so the threshold does not depend on the image dtype. It is
    computed with ``cv2.GaussianBlur`` (kernel truncated at 4 sigma) followed by the
    5-point discrete Laplacian (``cv2.Laplacian``, ``ksize=1``), which underestimates the
    continuous LoG by about ``1 / (8 sigma^2)`` (3% at ``sigma = 2`` px, 0.4% at 5.5 px).
    Bright blobs give positive ``R``. Centre values of the continuous response for a
    blob of contrast ``A`` (fraction of full scale) over a flat background:

    * Gaussian blob ``A exp(-r^2 / (2 s^2))``:
      ``R = 2 A sigma^2 s^2 / (sigma^2 + s^2)^2``, i.e. ``A / 2`` at ``sigma = s``.
    * Disc of radius ``rho`` blurred by a Gaussian of std ``b``, with
      ``t = sigma^2 + b^2``: ``R = A (rho^2 sigma^2 / t^2) exp(-rho^2 / (2 t))``, i.e.
      ``2 A / e = 0.736 A`` for a sharp disc at ``sigma = rho / sqrt(2)``.

    For the nominal markers (``rho = 7.5`` px, ``b = 3`` px, ``sigma = 5.55`` px)
    ``R = 0.540 A``: the nominal contrast 120/255 gives ``R = 0.25``, a contrast of
    0.15 gives ``R = 0.081``. Bead speckle (std 10/255, correlation length about 1 px)
    plus camera noise (std 3/255) give a response of std 0.009 at this scale, whose
    maximum over a 1280 x 720 background is 0.04-0.05. The default threshold 0.05 thus
    sits about 3 standard deviations of the speckle response below the weakest markers
    of interest and at the top of the background maxima. Raise it if the speckle is
    coarser (at a correlation length of 1.5 px the background maxima reach 0.07), lower
    it for fainter markers on a cleaner background.

    Speckle on and around a marker also shifts its LoG peak: with the nominal speckle
    the centre error is about 0.35 px RMS at contrast 120/255 (0.03 px with camera noise
    alone), growing to about 1 px at contrast 0.15.
    """
    sigma = finite_float(sigma_px, "sigma_px")
    if sigma <= 0.0:
        raise InputError(f"sigma_px must be > 0, got {sigma}; use log_sigma_px() to choose it.")
    thr = finite_float(threshold, "threshold")
    if thr < 0.0:
        raise InputError(f"threshold must be >= 0 (a bright-blob response), got {thr}.")
    if min_distance_px is None:
        min_distance_px = 2.0 * sigma
    min_dist = finite_float(min_distance_px, "min_distance_px")
    if min_dist < 1.0:
        raise InputError(f"min_distance_px must be >= 1, got {min_dist}.")
    if border_px is None:
        border_px = math.ceil(math.sqrt(2.0) * sigma)
    if isinstance(border_px, bool) or not isinstance(border_px, int | np.integer):
        raise InputError(f"border_px must be an integer number of pixels, got {border_px!r}.")
    if border_px < 0:
        raise InputError(f"border_px must be >= 0, got {border_px}.")
    if refine not in _REFINE_METHODS:
        raise InputError(f"unknown refine method {refine!r}; valid values are 'quadratic' and None.")

    gray = to_gray_float(image)
    response = _log_response(gray, sigma)
    rows, cols = _local_maxima(
        response, threshold=thr, half_width=int(min_dist), border=max(int(border_px), 1)
    )
    peak = response[rows, cols].astype(np.float64)
    xy = np.column_stack([cols, rows]).astype(np.float64)
    if refine == "quadratic" and len(rows) > 0:
        offset, peak_fit, ok = _refine_quadratic(response, rows, cols)
        xy[ok] += offset[ok]
        peak[ok] = peak_fit[ok]
    order = np.argsort(-peak, kind="stable")
    return Markers(xy_px=xy[order], response=peak[order], sigma_px=sigma)


def _log_response(gray: np.ndarray, sigma: float) -> np.ndarray:
    """Scale-normalised negative LoG ``-sigma^2 * LoG(gray)``, float32, same shape."""
    smoothed = cv2.GaussianBlur(gray, (0, 0), sigmaX=sigma, sigmaY=sigma, borderType=cv2.BORDER_REFLECT)
    lap = cv2.Laplacian(smoothed, cv2.CV_32F, ksize=1, borderType=cv2.BORDER_REFLECT)
    lap *= np.float32(-sigma * sigma)
    return lap


def _local_maxima(
    response: np.ndarray, *, threshold: float, half_width: int, border: int
) -> tuple[np.ndarray, np.ndarray]:
    """Rows and columns of the peaks of ``response`` (square NMS, threshold, border)."""
    h, w = response.shape
    if h <= 2 * border or w <= 2 * border:
        return np.empty(0, np.intp), np.empty(0, np.intp)
    inner = response[border : h - border, border : w - border]
    rows, cols = np.nonzero(inner > threshold)  # few pixels: markers' cores only
    if len(rows) == 0:
        return rows, cols
    rows += border
    cols += border
    kernel = np.ones((2 * half_width + 1, 2 * half_width + 1), np.uint8)
    dilated = cv2.dilate(response, kernel, borderType=cv2.BORDER_REFLECT)
    is_peak = response[rows, cols] >= dilated[rows, cols]
    rows, cols = rows[is_peak], cols[is_peak]  # row-major order
    # Plateaus (exactly equal neighbouring values) give several pixels per peak: keep the
    # first of each group in row-major order.
    if len(rows) > 1:
        pairs = cKDTree(np.column_stack([rows, cols])).query_pairs(
            r=half_width, p=np.inf, output_type="ndarray"
        )
        if len(pairs):
            keep = np.ones(len(rows), bool)
            for i, j in pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))]:
                if keep[i]:
                    keep[j] = False
            rows, cols = rows[keep], cols[keep]
    return rows, cols


def _refine_quadratic(
    response: np.ndarray, rows: np.ndarray, cols: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Vectorised least-squares quadratic fit around each peak.

    Returns the sub-pixel offsets ``(du, dv)`` (N, 2), the fitted peak values (N,) and a
    mask of the fits that are a maximum within ``_MAX_REFINE_OFFSET_PX`` of the pixel.
    """
    window = response[rows[:, None] + _FIT_DY, cols[:, None] + _FIT_DX].astype(np.float64)
    a, b, c, d, e, f = (window @ _FIT_PINV.T).T
    # Stationary point: [2d e; e 2f] [x y]^T = -[b c]^T.
    det = 4.0 * d * f - e * e
    is_max = (d < 0.0) & (det > 0.0)
    safe_det = np.where(is_max, det, 1.0)
    x = (e * c - 2.0 * f * b) / safe_det
    y = (e * b - 2.0 * d * c) / safe_det
    ok = is_max & (np.abs(x) <= _MAX_REFINE_OFFSET_PX) & (np.abs(y) <= _MAX_REFINE_OFFSET_PX)
    value = a + b * x + c * y + d * x * x + e * x * y + f * y * y
    return np.column_stack([x, y]), value, ok
