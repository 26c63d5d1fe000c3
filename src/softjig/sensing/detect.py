"""Marker detection: Laplacian-of-Gaussian blobs with sub-pixel refinement.

The sensing soft jig images white hemispherical markers on a black membrane. Each marker
appears as a bright, blurred, roughly circular blob. Following Sakuma et al., markers are
found as local maxima of the scale-normalised negative Laplacian of Gaussian (LoG) whose
scale is matched to the marker size in the image. Two ways to find them:

* ``candidates="full"`` (the straightforward path, Sakuma et al.'s): the LoG of the whole
  image at full resolution;
* ``candidates="pyramid"`` (the default, an order of magnitude faster): the LoG of the image averaged down
  by 2 or 4 (``cv2.resize``, ``INTER_AREA``), at the correspondingly smaller scale; only
  the candidates are then refined at full resolution, in small windows.

Each maximum is refined to sub-pixel accuracy either by a prewhitened least-squares fit of
the marker's image model to the pixels around it (``refine="model"``, the default,
:mod:`softjig.sensing.subpixel`: within 1.5x the Cramer-Rao bound), or, as Sakuma et al.
do, by a least-squares 2-D quadratic fit to the LoG response around it
(``refine="quadratic"``). Each refined marker is then measured for how far it departs from point
symmetry about its centre (:func:`point_asymmetry`): a glint or a bubble's rim over one side of a
marker pulls its centre by pixels, and such markers are told apart (:meth:`Markers.lopsided`).

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
from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

import cv2
import numpy as np
import numpy.typing as npt

from softjig.checks import finite_float, positive_float
from softjig.errors import InputError
from softjig.sensing.subpixel import MarkerModel, refine_centres

__all__ = [
    "CANDIDATES",
    "DEFAULT_CANDIDATES",
    "DEFAULT_REFINE",
    "DEFAULT_THRESHOLD",
    "REFINE_METHODS",
    "Markers",
    "check_image_content",
    "detect_markers",
    "gray_image",
    "log_sigma_px",
    "point_asymmetry",
    "to_gray_float",
]

#: Default threshold on the scale-normalised response ``R = -sigma^2 * LoG(I)`` of the
#: [0, 1]-scaled image. See :func:`detect_markers`, Notes.
DEFAULT_THRESHOLD: float = 0.05

#: A marker whose :func:`point_asymmetry` exceeds this many times the image's median marker's does not
#: look like a marker (:meth:`Markers.lopsided`): the markers of a clean image stay within about twice
#: their median (measured: benchmarks/RESULTS.md).
LOPSIDED_MEDIANS = 3.0

_FULL_SCALE = {np.dtype(np.uint8): 255.0, np.dtype(np.uint16): 65535.0}
_BLANK_STD = 1e-3  # std below this fraction of full scale: blank image
_SATURATED_FRACTION = 0.5  # more than this fraction of pixels at full scale: saturated
#: How candidates are found and the default (see :func:`detect_markers`).
CANDIDATES = ("pyramid", "full")
DEFAULT_CANDIDATES = "pyramid"
#: Sub-pixel refinements and the default (see :func:`detect_markers`).
REFINE_METHODS = ("model", "quadratic", None)
DEFAULT_REFINE = "model"
_MIN_COARSE_SIGMA_PX = 1.2  # the pyramid level is the coarsest where the LoG scale stays above this
#: The 5-point discrete Laplacian of a Gaussian of scale ``s`` underestimates the continuous one by
#: about ``LAPLACIAN_BIAS / s^2``.
LAPLACIAN_BIAS = 0.125
_GAUSSIAN_TRUNCATION = 4  # cv2.GaussianBlur's kernel for float32 images reaches 4 sigma each side
_LOCAL_HALF_WIDTH = 3  # pyramid + quadratic: full-resolution LoG in 7x7 windows around the candidates
_CANDIDATE_MARGIN = 0.7  # pyramid + quadratic: coarse candidates down to this fraction of the threshold
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
    asymmetry : numpy.ndarray, shape (N,), float64, or None
        Each marker's departure from point symmetry about its centre (:func:`point_asymmetry`,
        a fraction of its fitted amplitude; with ``refine="quadratic"``, of its response, which
        is proportional to it); NaN where the model fit failed (the candidate was kept).
        ``None`` for integer centres (``refine=None``).

    Notes
    -----
    Instances are immutable: the arrays are read-only. Equality is identity (arrays do
    not support ``==`` as a truth value); compare fields with ``numpy.testing``.
    """

    xy_px: np.ndarray
    response: np.ndarray
    sigma_px: float
    asymmetry: np.ndarray | None = None

    def __post_init__(self) -> None:
        xy = np.array(self.xy_px, dtype=np.float64).reshape(-1, 2)
        xy.setflags(write=False)
        object.__setattr__(self, "xy_px", xy)
        object.__setattr__(self, "response", _one_per_marker(self.response, "response", len(xy)))
        object.__setattr__(self, "sigma_px", float(self.sigma_px))
        if self.asymmetry is not None:
            object.__setattr__(self, "asymmetry", _one_per_marker(self.asymmetry, "asymmetry", len(xy)))

    def lopsided(self) -> np.ndarray:
        """Which markers do not look like a marker, as booleans (N,): their model fit failed, or they
        depart from point symmetry more than :data:`LOPSIDED_MEDIANS` times the image's median marker
        does (a glint or a bubble's rim over one side, which pulls the centre towards it). None of them
        without :attr:`asymmetry`."""
        if self.asymmetry is None or not len(self.asymmetry):
            return np.zeros(len(self), dtype=bool)
        known = np.isfinite(self.asymmetry)
        if not known.any():
            return ~known
        typical = float(np.median(self.asymmetry[known]))
        return ~known | (self.asymmetry > LOPSIDED_MEDIANS * typical)

    def __len__(self) -> int:
        return int(self.xy_px.shape[0])


def _one_per_marker(values: npt.ArrayLike, name: str, n_markers: int) -> np.ndarray:
    """``values`` as a read-only float64 ``(N,)`` array, one per marker, or an InputError naming ``name``."""
    array = np.array(values, dtype=np.float64).reshape(-1)
    if len(array) != n_markers:
        raise InputError(
            f"Markers: xy_px has {n_markers} rows but {name} has {len(array)} values; pass one {name} per "
            "marker."
        )
    array.setflags(write=False)
    return array


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
    gray, full_scale = gray_image(image)
    if full_scale == 1.0:
        return gray
    return gray.astype(np.float32) / np.float32(full_scale)


def gray_image(image: npt.ArrayLike) -> tuple[np.ndarray, float]:
    """Validate a camera image and make it gray, keeping its dtype (no conversion to float).

    Parameters
    ----------
    image : array_like
        As for :func:`to_gray_float`.

    Returns
    -------
    gray : numpy.ndarray, shape (H, W)
        ``uint8`` or ``uint16`` for integer input (RGB converted with ``cv2.cvtColor``, as in
        :func:`to_gray_float`), float32 in [0, 1] for float input.
    full_scale : float
        The value of full scale: 255, 65535 or 1.0.

    Raises
    ------
    InputError
        As :func:`to_gray_float`.
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
        return (cv2.cvtColor(arr, cv2.COLOR_RGB2GRAY) if is_rgb else arr), 1.0
    arr = np.ascontiguousarray(arr)
    if is_rgb:
        arr = cv2.cvtColor(arr, cv2.COLOR_RGB2GRAY)
    return arr, _FULL_SCALE[arr.dtype]


#: The bit depths a camera packs into a 16-bit image's low bits (10-, 12- and 14-bit sensors), tried in
#: order: a ``uint16`` pair whose brightest pixel fits in one of them is taken to be of that depth.
PACKED_BIT_DEPTHS = (10, 12, 14)


def packed_bit_depth(*grays: np.ndarray) -> int | None:
    """The bit depth of ``uint16`` images whose values use only their low bits, or ``None``.

    A 10-, 12- or 14-bit camera writes its counts into 16-bit PNGs unscaled: full scale is then
    ``2**bits - 1``, not 65535, and a marker's contrast looks 4-64 times fainter than it is (no marker
    passes the detection threshold). Returns the least depth of :data:`PACKED_BIT_DEPTHS` whose full
    scale holds every pixel of every image, ``None`` for other dtypes or when the top bits are used.
    """
    if not grays or any(g.dtype != np.uint16 for g in grays):
        return None
    brightest = max(int(g.max()) for g in grays)
    for bits in PACKED_BIT_DEPTHS:
        if brightest < 2**bits:
            return bits
    return None


def unpack_bit_depth(gray: np.ndarray, bits: int) -> np.ndarray:
    """A ``uint16`` image of ``bits``-bit counts scaled to the 16-bit range (shifted left by
    ``16 - bits``, so that ``2**bits - 1`` maps to within one count step of 65535)."""
    return np.left_shift(gray, 16 - bits)


def check_image_content(gray: npt.ArrayLike, *, name: str = "the image") -> np.ndarray:
    """Reject images that cannot contain usable markers: blank or saturated.

    Parameters
    ----------
    gray : array_like, shape (H, W), uint8, uint16 or float
        Gray image: integer (full scale 255 or 65535, as returned by :func:`gray_image`) or
        float scaled to [0, 1] (as returned by :func:`to_gray_float`).
    name : str, optional
        What to call the image in messages, e.g. ``"the left image"``.

    Returns
    -------
    numpy.ndarray
        The contiguous subsample it read (every 8th pixel of each axis, a smaller step for an image
        under 256 px; ``uint8``, ``uint16`` or ``float32``): a cheap first test of two images' equality.

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
    full = _FULL_SCALE.get(arr.dtype, 1.0)
    if (
        arr.ndim != 2
        or arr.size == 0
        or not (arr.dtype in _FULL_SCALE or np.issubdtype(arr.dtype, np.floating))
    ):
        raise InputError(
            f"{name} must be a non-empty gray image of shape (H, W), uint8, uint16 or float scaled "
            f"to [0, 1], got dtype {arr.dtype} and shape {arr.shape}; convert it with "
            "gray_image() or to_gray_float() first."
        )
    # A 1-in-8 subsample (14,400 pixels of a 1280x720 frame; at least 32 rows and columns of a small
    # image) decides blank or saturated as well as every pixel, at a sixty-fourth of the cost.
    step = max(1, min(8, min(arr.shape) // 32))
    sample = np.ascontiguousarray(arr[::step, ::step])
    if sample.dtype not in (np.dtype(np.uint8), np.dtype(np.uint16), np.dtype(np.float32)):
        sample = sample.astype(np.float32)
    mean, std = (float(v) / full for v in np.ravel(cv2.meanStdDev(sample)))
    if std < _BLANK_STD:
        raise InputError(
            f"{name} is blank: its gray levels vary by only {std:.2e} of full scale "
            f"(mean {mean:.3f}); check the lighting/exposure, "
            "the lens cap and the camera connection."
        )
    saturated = float(np.count_nonzero(sample >= full)) / sample.size
    if saturated > _SATURATED_FRACTION:
        raise InputError(
            f"{name} is saturated: {100.0 * saturated:.0f}% of its pixels are at full "
            "scale; reduce the exposure time, gain or illumination."
        )
    return sample


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
    refine: Literal["model", "quadratic"] | None = DEFAULT_REFINE,
    candidates: Literal["pyramid", "full"] = DEFAULT_CANDIDATES,
    model: MarkerModel | None = None,
    exclude: Callable[[np.ndarray], np.ndarray] | None = None,
    tables: np.ndarray | None = None,
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
        because the refinement needs the 3x3 neighbourhood. With ``refine="model"`` the
        fitted centres are tested (the pixel nearest each), not the candidates, and a
        candidate whose fit failed within the fit's window of the edge is dropped: both
        ``candidates`` then keep the same markers.
    refine : {"model", "quadratic", None}, optional
        ``"model"`` (default): prewhitened least-squares fit of the marker's image model to
        the ``(2 h + 1)^2`` pixels around each peak (:func:`softjig.sensing.subpixel.refine_centres`,
        ``h = model.half_width_px``): near the Cramer-Rao bound, well below ``"quadratic"``'s
        error, which the bead speckle dominates (see Notes; the figures are in
        benchmarks/RESULTS.md). A fit that fails (not a bright marker, or moving more than
        2.5 px) keeps its candidate position.
        ``"quadratic"``: sub-pixel centre from a least-squares fit of
        ``z = a + b x + c y + d x^2 + e x y + f y^2`` to the 3x3 response neighbourhood
        of each peak; the centre is the stationary point of the fit. If the fit is not a
        maximum (``d < 0`` and ``4 d f - e^2 > 0``) or the stationary point is more than
        1 px from the peak pixel in ``u`` or ``v``, the integer peak is kept (the marker
        is not dropped). The response is smooth at the marker scale, so a larger window
        would be no more accurate.
        ``None``: integer peak positions.
    candidates : {"pyramid", "full"}, optional
        ``"pyramid"`` (default): peaks of the LoG of the image averaged down by ``F`` (4, or
        2 or 1 when ``sigma_px / F`` would fall below 1.2 px) at scale
        ``sqrt(sigma^2 - (F^2 - 1) / 12) / F`` (the box average's own blur subtracted); each
        peak's sub-pixel position (quadratic fit) mapped to full resolution starts the
        refinement there. With ``refine="quadratic"`` or ``None`` the LoG is then evaluated
        at full resolution in a 7x7 window around each candidate, so positions and
        responses are those of ``"full"``. ``"full"``: the LoG of the whole image at full
        resolution (the straightforward path; an order of magnitude slower).
    model : MarkerModel, optional
        The marker and noise model of ``refine="model"``. Default
        ``MarkerModel.for_sigma(sigma_px)``: the nominal marker (blur 0.4 of the radius)
        whose matched LoG scale is ``sigma_px``, with the simulator's default noise.
    exclude : callable, optional
        ``exclude(xy)`` with ``xy`` (M, 2) candidate centres (px) returns a boolean (M,) mask
        of the candidates to drop before the refinement (e.g. those on the fiducials); the
        refinement does not move a marker by more than 2.5 px, so testing the candidate
        is testing the marker.
    tables : numpy.ndarray, optional
        :func:`softjig.sensing.subpixel.kernel_tables` of ``model`` for ``refine="model"`` (read
        for each call when not given: a detector reads them once).

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

    With ``candidates="pyramid"`` and ``refine="model"``, ``R`` is that of the coarse
    level at its quadratically interpolated peak, times ``(1 + 1 / (8 s^2)) / (1 + 1 / (8
    sigma^2))`` (``s`` the coarse scale in coarse pixels), which undoes most of the coarser
    discrete Laplacian's larger underestimate: it is a few percent below the full-resolution
    ``R``, so the threshold means practically the same (the default markers' ``R`` is about
    0.25, five times the threshold).

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
    if refine not in REFINE_METHODS:
        raise InputError(f"unknown refine method {refine!r}; valid values are 'model', 'quadratic' and None.")
    if candidates not in CANDIDATES:
        raise InputError(f"unknown candidates {candidates!r}; valid values are 'pyramid' and 'full'.")
    if model is not None and not isinstance(model, MarkerModel):
        raise InputError(f"model must be a softjig.sensing.subpixel.MarkerModel, got {type(model).__name__}.")

    gray, full_scale = gray_image(image)
    border = max(int(border_px), 1)
    # The model fit's centres are tested against the border instead of the candidates, which differ
    # between the pyramid and the full-resolution LoG: markers at the image's edge would be kept by one
    # and not the other.
    model_fit = refine == "model"
    candidate_border = 1 if model_fit else border
    if candidates == "full":
        xy, peak = _full_candidates(gray, full_scale, sigma, thr, int(min_dist), candidate_border, refine)
    else:
        xy, peak = _pyramid_candidates(gray, full_scale, sigma, thr, int(min_dist), candidate_border, refine)
    if exclude is not None and len(xy) > 0:
        keep = ~np.asarray(exclude(xy), dtype=bool)
        xy, peak = xy[keep], peak[keep]
    if model_fit and len(xy) > 0:
        model = model if model is not None else MarkerModel.for_sigma(sigma)
        fit = refine_centres(gray, xy, model, tables=tables)
        xy = fit.xy_px
        # A failed fit keeps its candidate; one whose window was cut by the image's edge is dropped.
        h, w = gray.shape
        keep = _inside_border(xy, w, h, border) & (fit.ok | _inside_border(xy, w, h, model.half_width_px + 1))
        xy, peak = xy[keep], peak[keep]
        amplitude = np.where(fit.ok, fit.amplitude, np.nan)[keep]
        asymmetry = point_asymmetry(gray, xy, amplitude, radius_px=model.radius_px, full_scale=full_scale)
    elif refine == "quadratic" and len(xy) > 0:  # the response is proportional to the contrast
        radius_px = MarkerModel.for_sigma(sigma).radius_px
        asymmetry = point_asymmetry(gray, xy, peak, radius_px=radius_px, full_scale=full_scale)
    else:
        asymmetry = None
    order = np.argsort(-peak, kind="stable")
    return Markers(
        xy_px=xy[order],
        response=peak[order],
        sigma_px=sigma,
        asymmetry=None if asymmetry is None else asymmetry[order],
    )


def point_asymmetry(
    gray: np.ndarray, xy_px: np.ndarray, amplitude: np.ndarray, *, radius_px: float, full_scale: float
) -> np.ndarray:
    """Each marker's departure from point symmetry: the RMS difference between its pixels within
    ``radius_px`` of its centre ``xy_px`` and the image turned half a turn about that centre (bilinear),
    over its fitted ``amplitude`` (a fraction of full scale); NaN where the amplitude is not positive
    (or NaN), or where most of the disc lies outside the image.

    Why: a marker's image is a disc, whatever it looks like inside (a shaded hemisphere, a painted dot)
    and whatever the speckle behind it, so it is point-symmetric about its centre to the noise and the
    small obliquity of the view. A glint or a bubble's rim over one side of it is not, and it pulls the
    fitted centre towards it by pixels (a point millimetres off the membrane), which the fit alone does
    not tell. Compiled (:func:`softjig.sensing._detect_kernels.point_asymmetry`): half the disc per
    marker, one set of bilinear weights per marker.

    Parameters
    ----------
    gray : (H, W) gray image (:func:`gray_image`).
    xy_px : (N, 2) marker centres ``(u, v)`` (px).
    amplitude : (N,) each marker's fitted amplitude (fraction of full scale).
    radius_px : the markers' image radius (px): the disc compared.
    full_scale : the image's full scale (255 for uint8; 1 for a float image).

    Raises
    ------
    InputError
        A gray image that is not 2-D, centres not ``(N, 2)``, not one amplitude per centre, or a radius
        or full scale that is not a positive number (the compiled loop reads them unchecked).
    """
    from softjig.sensing._detect_kernels import point_asymmetry as kernel  # Numba is imported on first use

    gray = np.ascontiguousarray(gray)
    xy = np.ascontiguousarray(xy_px, dtype=np.float64)
    amplitude = np.ascontiguousarray(amplitude, dtype=np.float64).reshape(-1)
    if gray.ndim != 2:
        raise InputError(f"point_asymmetry needs a gray (H, W) image, got shape {gray.shape}.")
    if xy.ndim != 2 or xy.shape[1] != 2:
        raise InputError(f"point_asymmetry needs (N, 2) centres (u, v), got shape {xy.shape}.")
    if len(amplitude) != len(xy):
        raise InputError(
            f"point_asymmetry needs one amplitude per centre: {len(xy)} centres, {len(amplitude)} amplitudes."
        )
    radius, scale = positive_float(radius_px, "radius_px"), 1.0 / positive_float(full_scale, "full_scale")
    return kernel(gray, xy, amplitude, radius, scale)


def _full_candidates(
    gray: np.ndarray, full_scale: float, sigma: float, thr: float, half_width: int, border: int, refine
) -> tuple[np.ndarray, np.ndarray]:
    """Peaks of the full-resolution LoG: ``(u, v)`` and responses, quadratic-refined unless
    ``refine is None``."""
    image = gray if full_scale == 1.0 else gray.astype(np.float32) / np.float32(full_scale)
    response = _log_response(image, sigma)
    rows, cols = _local_maxima(response, threshold=thr, half_width=half_width, border=border)
    peak = response[rows, cols].astype(np.float64)
    xy = np.column_stack([cols, rows]).astype(np.float64)
    if refine is not None and len(rows) > 0:
        offset, peak_fit, ok = _refine_quadratic(response, rows, cols)
        peak[ok] = peak_fit[ok]
        xy[ok] += offset[ok]  # also the start of the model fit
    return xy, peak


def pyramid_factor(sigma_px: float) -> int:
    """The pyramid's reduction ``F`` (4, 2 or 1) for a LoG scale: the largest with a coarse scale of
    at least 1.2 coarse px (below, the discrete LoG of the coarse level is too rough)."""
    for factor in (4, 2):
        if _coarse_sigma(sigma_px, factor) >= _MIN_COARSE_SIGMA_PX:
            return factor
    return 1


def _coarse_sigma(sigma: float, factor: int) -> float:
    """LoG scale at the level averaged down by ``factor`` (coarse px): the ``factor x factor`` box
    average already blurs by a variance of ``(factor^2 - 1) / 12`` full-resolution px^2."""
    return math.sqrt(max(sigma * sigma - (factor * factor - 1) / 12.0, 0.0)) / factor


def _pyramid_candidates(
    gray: np.ndarray, full_scale: float, sigma: float, thr: float, half_width: int, border: int, refine
) -> tuple[np.ndarray, np.ndarray]:
    """Peaks found on the coarse level, at full-resolution coordinates, and their responses."""
    factor = pyramid_factor(sigma)
    small = gray
    for _ in range(factor.bit_length() - 1):  # halve with exact 2x2 means (cv2's fast INTER_AREA case)
        h, w = small.shape
        h2, w2 = h // 2, w // 2
        if h2 < 3 or w2 < 3:
            break
        small = cv2.resize(small[: 2 * h2, : 2 * w2], (w2, h2), interpolation=cv2.INTER_AREA)
    factor = gray.shape[0] // small.shape[0] if small is not gray else 1
    s_coarse = _coarse_sigma(sigma, factor)
    # -sigma^2 LoG in full-resolution px of the image scaled to [0, 1]: the coarse Laplacian is factor^2
    # times the fine one, and the coarser discrete Laplacian underestimates by 1/(8 s^2) instead of
    # 1/(8 sigma^2). Scales folded into the Laplacian's (one pass over the level instead of three).
    bias = (1.0 + LAPLACIAN_BIAS / s_coarse**2) / (1.0 + LAPLACIAN_BIAS / sigma**2)
    gain = (sigma / factor) ** 2 * bias / full_scale
    smoothed = _coarse_blur(small, s_coarse)
    response = cv2.Laplacian(smoothed, cv2.CV_32F, ksize=1, scale=-gain, borderType=cv2.BORDER_REFLECT)
    exact = refine != "model"  # positions and responses from the full-resolution LoG
    from softjig.sensing._detect_kernels import coarse_peaks  # Numba is imported on first use

    coarse_xy, peak = coarse_peaks(
        response,
        np.float32(thr * _CANDIDATE_MARGIN if exact else thr),
        max(1, half_width // factor),
        _FIT_PINV,
        _MAX_REFINE_OFFSET_PX,
    )
    xy = coarse_xy * factor + 0.5 * (factor - 1)  # coarse pixel centres in full-resolution px
    if exact:
        xy, peak = _full_resolution_peaks(gray, full_scale, sigma, thr, xy, refine)
    # the border margin, on the pixel nearest each candidate (as "full" does on its peak pixel)
    h, w = gray.shape
    keep = _inside_border(xy, w, h, border)
    return xy[keep], peak[keep]


def gaussian_ksize(sigma: float) -> int:
    """The (odd) kernel size ``cv2.GaussianBlur`` chooses for a float32 image and ``sigma`` (px)."""
    return round(sigma * _GAUSSIAN_TRUNCATION * 2 + 1) | 1


def _coarse_blur(small: np.ndarray, sigma: float) -> np.ndarray:
    """``cv2.GaussianBlur`` of ``small`` (any dtype) as float32 at ``sigma`` (px), reflected border.

    The same kernel (``cv2.getGaussianKernel`` of ``cv2.GaussianBlur``'s size for float32 images) applied
    by ``cv2.sepFilter2D`` straight from the integer level: the same values as blurring its float32
    copy (``tests/test_detect.py``), without making the copy.
    """
    kernel = cv2.getGaussianKernel(gaussian_ksize(sigma), sigma, cv2.CV_32F)
    return cv2.sepFilter2D(small, cv2.CV_32F, kernel, kernel, borderType=cv2.BORDER_REFLECT)


def _inside_border(xy: np.ndarray, w: int, h: int, border: int) -> np.ndarray:
    """Whether the pixel nearest each ``(u, v)`` is at least ``border`` px from the image's edges."""
    nearest = np.floor(xy + 0.5)
    u, v = nearest[:, 0], nearest[:, 1]
    return (u >= border) & (u < w - border) & (v >= border) & (v < h - border)


def _full_resolution_peaks(
    gray: np.ndarray, full_scale: float, sigma: float, thr: float, start_xy: np.ndarray, refine
) -> tuple[np.ndarray, np.ndarray]:
    """The full-resolution LoG's peak near each start, thresholded, quadratic-refined unless
    ``refine is None``; duplicates (two starts reaching the same peak) removed."""
    half = _LOCAL_HALF_WIDTH
    centre = np.rint(start_xy).astype(np.intp)
    windows = _local_log(gray, full_scale, sigma, centre, half + 1)  # (N, 2 h + 3, 2 h + 3)
    n = 2 * half + 1
    inner = windows[:, 1:-1, 1:-1].reshape(len(centre), -1)
    best = np.argmax(inner, axis=1)
    dr, dc = best // n + 1, best % n + 1  # in the padded window
    rows = centre[:, 1] + dr - (half + 1)
    cols = centre[:, 0] + dc - (half + 1)
    peak = inner[np.arange(len(best)), best].astype(np.float64)
    xy = np.column_stack([cols, rows]).astype(np.float64)
    if refine is not None:
        idx = np.arange(len(best))[:, None]
        nbhd = windows[idx, dr[:, None] + _FIT_DY, dc[:, None] + _FIT_DX].astype(np.float64)
        offset, peak_fit, ok = _quadratic_peak(nbhd)
        xy[ok] += offset[ok]
        peak[ok] = peak_fit[ok]
    keep = peak > thr
    _, first = np.unique(np.column_stack([rows, cols])[keep], axis=0, return_index=True)
    keep = np.flatnonzero(keep)[np.sort(first)]
    return xy[keep], peak[keep]


def _local_log(
    gray: np.ndarray, full_scale: float, sigma: float, centre: np.ndarray, half: int
) -> np.ndarray:
    """``-sigma^2 LoG`` at full resolution in ``(2 half + 1)^2`` windows around integer ``centre``
    (N, 2) ``(u, v)``: the same values as :func:`_log_response` of the whole image (same Gaussian
    kernel, 5-point Laplacian, reflected border), float32 ``(N, 2 half + 1, 2 half + 1)``."""
    ksize = gaussian_ksize(sigma)
    radius = ksize // 2
    kernel = cv2.getGaussianKernel(ksize, sigma, cv2.CV_32F).ravel()
    k = 2 * half + 3  # smoothed values needed: the window and a 1-px ring for the Laplacian
    m = k + 2 * radius
    pad = radius + half + 1
    image = gray if full_scale == 1.0 else gray.astype(np.float32) / np.float32(full_scale)
    padded = cv2.copyMakeBorder(image, pad, pad, pad, pad, cv2.BORDER_REFLECT)
    view = np.lib.stride_tricks.sliding_window_view(padded, (m, m))
    patches = view[centre[:, 1] - half - 1 - radius + pad, centre[:, 0] - half - 1 - radius + pad]
    band = np.zeros((k, m), np.float32)
    for i in range(k):
        band[i, i : i + ksize] = kernel
    smooth = band @ patches @ band.T  # (N, k, k)
    lap = (
        smooth[:, :-2, 1:-1]
        + smooth[:, 2:, 1:-1]
        + smooth[:, 1:-1, :-2]
        + smooth[:, 1:-1, 2:]
        - 4.0 * smooth[:, 1:-1, 1:-1]
    )
    lap *= np.float32(-sigma * sigma)
    return lap


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
    # The largest of the neighbours (centre excluded): a peak is >= it, and > it unless it ties.
    kernel = np.ones((2 * half_width + 1, 2 * half_width + 1), np.uint8)
    kernel[half_width, half_width] = 0
    neighbours = cv2.dilate(response, kernel, borderType=cv2.BORDER_REFLECT)
    value, around = response[rows, cols], neighbours[rows, cols]
    is_peak = value >= around
    tied = (value == around)[is_peak]
    rows, cols = rows[is_peak], cols[is_peak]  # row-major order
    # Plateaus (exactly equal neighbouring values) give several pixels per peak: keep the
    # first of each group in row-major order. Only tied peaks can be in one, so only those
    # go into the k-d tree.
    if np.count_nonzero(tied) > 1:
        tie = np.flatnonzero(tied)
        from scipy.spatial import cKDTree  # on first use: scipy.spatial costs 0.2 s to import

        pairs = cKDTree(np.column_stack([rows[tie], cols[tie]])).query_pairs(
            r=half_width, p=np.inf, output_type="ndarray"
        )
        if len(pairs):
            keep = np.ones(len(rows), bool)
            for i, j in tie[pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))]]:
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
    return _quadratic_peak(window)


def _quadratic_peak(window: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Quadratic fit to (N, 9) row-major 3x3 neighbourhoods: offsets, peak values and success mask."""
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
