r"""Sub-pixel marker centres from a prewhitened least-squares fit of the marker's image model.

The model is the simulator's (:mod:`softjig.sim.render`): a white hemisphere of image radius ``R`` seen
head-on, shaded ``1/2 + 1/2 cos(beta)`` (``cos(beta) = sqrt(1 - r^2 / R^2)``, so 1 at the centre and
1/2 at the rim, 0 outside), blurred by a Gaussian of standard deviation ``b`` (px), on a flat
background:

.. math:: \mu_k(u, v, A, B) = B + A\, f(x_k - u, y_k - v)

with ``f`` that blurred unit profile sampled at the pixel centres ``(x_k, y_k)`` of a square window.
The noise is the simulator's too (:func:`noise_covariance`): multiplicative bead speckle (relative
standard deviation ``s``, spatially correlated), shot and read noise and quantisation, so the pixel
covariance is ``C = diag(mu / N_e + r^2 + q^2) + s^2 diag(mu) K diag(mu)`` with ``K`` the speckle's
correlation matrix.

The estimator (:func:`refine_centres`) is Gauss-Newton on the generalised least-squares cost
``(y - mu)^T C^{-1} (y - mu)``, i.e. the maximum-likelihood estimate under Gaussian noise of known
covariance, which reaches the Cramer-Rao bound (:mod:`softjig.evaluation.cramer_rao`) at high SNR. It
is linearised in the centre only (``mu`` is linear in ``A`` and ``B``): about a reference centre
``c0``, ``y ~ B + A f_0 + (A du) (-df/dx) + (A dv) (-df/dy)`` is linear in ``(B, A, A du, A dv)``, so
each step is a fixed ``4 x n^2`` weight matrix ``W = (J^T C^{-1} J)^{-1} J^T C^{-1}`` applied to the
window. The weights depend smoothly on the reference centre; they are computed once per model
(:func:`fit_tables`, 0.3-1 s; kept on disk) for reference centres every 1/4 px within 1 px of the window's
central pixel, with the covariance taken at the nominal amplitude, and fitted by a cubic polynomial in the
reference centre's offset. One product of each marker's window with the polynomial's coefficients
(``n^2 x 30``) then gives ``(A, A du, A dv)`` about any reference centre as a cubic of its offset, so
finding the reference centre where the estimated offset ``(A du, A dv)`` vanishes (the Gauss-Newton
fixed point; Newton's steps on the cubic, to 1e-6 px) costs little. The whole fit is one compiled loop
(:mod:`softjig.sensing._subpixel_kernels`), most of its time the products. Noise-free, on the model's own
markers, the fit is unbiased to the polynomials' error for a blur of at least ``MIN_MODEL_BLUR_PX``; with
noise drawn from its covariance it reaches the Cramer-Rao bound (``tests/test_cramer_rao.py``).

The fit does not model the hemisphere's obliquity (its image is asymmetric about the base centre, see
:mod:`softjig.sim.render`): that bias, which grows as the square of the viewing angle, remains.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
import scipy
import scipy.linalg

from softjig.checks import finite_float
from softjig.disk_cache import cached_array
from softjig.errors import InputError

__all__ = [
    "MIN_MODEL_BLUR_PX",
    "MarkerModel",
    "SubpixelFit",
    "fit_tables",
    "kernel_tables",
    "marker_profile",
    "noise_covariance",
    "refine_centres",
    "speckle_correlation_1d",
]

#: The weight tables are accurate for markers blurred by at least this (px): the offset polynomials need
#: a profile smooth at the pixel scale (sharper markers are fitted with a bias of a few hundredths of a px).
MIN_MODEL_BLUR_PX = 1.0
_SUPERSAMPLE = 8  # sub-samples per pixel side when rendering the profile
_MAX_SHIFT_PX = 2.5  # a fit that moves further from its start than this failed: the start is kept
_DERIVATIVE_STEP_PX = 0.05  # central differences of the profile (marker_profile's derivatives)


@dataclass(frozen=True)
class MarkerModel:
    """A marker's image and the noise on it, in pixels and fractions of full scale.

    Attributes
    ----------
    radius_px : image radius of the hemisphere's rim (px).
    blur_px : standard deviation of the Gaussian blur (px); the fit is accurate from
        ``MIN_MODEL_BLUR_PX`` up.
    background : gray level of the membrane around the marker (fraction of full scale).
    amplitude : marker centre's excess over the background (fraction of full scale).
    speckle_std : relative standard deviation of the multiplicative speckle (0 for none).
    speckle_corr_px : speckle correlation length, one bead diameter projected (px).
    read_noise : standard deviation of the read noise (fraction of full scale).
    full_well : electrons at full scale (shot noise variance ``I / full_well``); ``inf`` for none.
    bit_depth : 8 or 16: quantisation noise variance ``1 / (12 (2^bits - 1)^2)``.
    half_width_px : the fit window is ``2 half_width_px + 1`` px square, centred on a pixel.
    """

    radius_px: float = 8.0
    blur_px: float = 3.0
    background: float = 0.08
    amplitude: float = 0.47
    speckle_std: float = 0.04
    speckle_corr_px: float = 5.5
    read_noise: float = 0.008
    full_well: float = 6000.0
    bit_depth: int = 8
    half_width_px: int = 12

    def __post_init__(self) -> None:
        if not float(self.full_well) > 0:  # math.inf: no shot noise
            raise InputError(
                f"MarkerModel.full_well must be > 0 (inf for no shot noise), got {self.full_well}."
            )
        for name in ("radius_px", "amplitude", "speckle_corr_px"):
            if not finite_float(getattr(self, name), name) > 0:
                raise InputError(f"MarkerModel.{name} must be > 0, got {getattr(self, name)}.")
        for name in ("blur_px", "background", "speckle_std", "read_noise"):
            if not finite_float(getattr(self, name), name) >= 0:
                raise InputError(f"MarkerModel.{name} must be >= 0, got {getattr(self, name)}.")
        if self.bit_depth not in (8, 16):
            raise InputError(f"MarkerModel.bit_depth must be 8 or 16, got {self.bit_depth}.")
        if not (isinstance(self.half_width_px, int | np.integer) and self.half_width_px >= 2):
            raise InputError(
                f"MarkerModel.half_width_px must be an integer >= 2, got {self.half_width_px!r}."
            )

    @property
    def size_px(self) -> int:
        """Side of the fit window (px)."""
        return 2 * int(self.half_width_px) + 1

    @classmethod
    def for_sigma(cls, sigma_px: float, **kwargs) -> MarkerModel:
        """The nominal-proportion marker (blur = 0.4 radius) whose matched LoG scale is ``sigma_px``.

        Inverts :func:`softjig.sensing.detect.log_sigma_px` for ``b = 0.4 rho``:
        ``sigma^2 = rho^2 (1 + sqrt(1 + 16 * 0.4^4)) / 4``. The window half-width defaults to
        ``ceil(R + b)``.
        """
        sigma = finite_float(sigma_px, "sigma_px")
        rho = sigma / math.sqrt((1.0 + math.sqrt(1.0 + 16.0 * 0.4**4)) / 4.0)
        kwargs.setdefault("half_width_px", max(2, math.ceil(1.4 * rho)))
        return cls(radius_px=rho, blur_px=0.4 * rho, **kwargs)


@dataclass(frozen=True)
class SubpixelFit:
    """Result of :func:`refine_centres` for N markers.

    Attributes
    ----------
    xy_px : (N, 2) refined centres ``(u, v)`` (px); the starting point where the fit failed.
    amplitude : (N,) fitted amplitude ``A`` (fraction of full scale).
    ok : (N,) whether the fit converged to a bright marker within ``_MAX_SHIFT_PX`` of its start.
    """

    xy_px: np.ndarray
    amplitude: np.ndarray
    ok: np.ndarray


def marker_profile(
    model: MarkerModel, offsets_px: np.ndarray, *, derivatives: bool = False
) -> np.ndarray | tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unit-amplitude blurred marker profile ``f`` in the fit window, for centres at sub-pixel offsets.

    Parameters
    ----------
    model : the marker (``radius_px``, ``blur_px``, ``half_width_px``).
    offsets_px : (M, 2) centre ``(du, dv)`` relative to the window's central pixel (px).
    derivatives : also return ``df/du`` and ``df/dv`` (derivatives with respect to the centre).

    Returns
    -------
    (M, n, n) float64 profile (rows ``v``, columns ``u``), and with ``derivatives`` its two derivatives
    (same shape), by central differences of step 0.05 px.
    """
    offsets = np.asarray(offsets_px, dtype=np.float64).reshape(-1, 2)
    if not derivatives:
        return np.stack([_profile_one(model, float(du), float(dv)) for du, dv in offsets])
    h = _DERIVATIVE_STEP_PX
    f = np.stack([_profile_one(model, float(du), float(dv)) for du, dv in offsets])
    fu = np.stack(
        [(_profile_one(model, du + h, dv) - _profile_one(model, du - h, dv)) / (2 * h) for du, dv in offsets]
    )
    fv = np.stack(
        [(_profile_one(model, du, dv + h) - _profile_one(model, du, dv - h)) / (2 * h) for du, dv in offsets]
    )
    return f, fu, fv


def _profile_one(model: MarkerModel, du: float, dv: float) -> np.ndarray:
    """One (n, n) profile: supersampled shaded disc, area-averaged to pixels, then blurred (like the
    renderer: a Gaussian truncated at 3 sigma and normalised)."""
    n = model.size_px
    pad = math.ceil(3.0 * model.blur_px)
    m = n + 2 * pad
    s = _SUPERSAMPLE
    sub = (np.arange(m * s) + 0.5) / s - 0.5 - (m // 2)  # fine sample coordinates, centre pixel at 0
    x = sub[None, :] - du
    y = sub[:, None] - dv
    q2 = (x * x + y * y) / model.radius_px**2
    shade = np.where(q2 < 1.0, 0.5 + 0.5 * np.sqrt(np.maximum(1.0 - q2, 0.0)), 0.0)
    pixels = shade.reshape(m, s, m, s).mean(axis=(1, 3))
    if model.blur_px > 0 and pad > 0:
        k = np.arange(-pad, pad + 1, dtype=np.float64)
        g = np.exp(-0.5 * (k / model.blur_px) ** 2)
        g /= g.sum()
        pixels = cv2.sepFilter2D(pixels, cv2.CV_64F, g, g, borderType=cv2.BORDER_CONSTANT)
    return pixels[pad : pad + n, pad : pad + n]


def speckle_correlation_1d(n: int, corr_px: float) -> np.ndarray:
    """(n, n) correlation of the simulator's speckle along one image axis, averaged over grid phase.

    The renderer draws white noise on a grid ``f = round(corr / 2)`` times coarser, smooths it with a
    Gaussian of ``corr / (2 f)`` coarse px (``cv2.GaussianBlur``'s kernel), normalises it and resizes
    it up bilinearly (``cv2.resize``, half-pixel centres). Every step is separable and linear in the
    white noise, so the 2-D covariance is the Kronecker product of this matrix with itself. The
    upsampling makes the field cyclo-stationary with period ``f``; since a marker falls at any phase,
    the covariance is averaged over the ``f`` phases (a mixture: still a valid covariance).
    """
    f = max(1, round(corr_px / 2.0))
    sigma = max(corr_px / (2.0 * f), 0.3)
    ksize = round(sigma * 4 * 2 + 1) | 1  # cv2's automatic size for float32 images (4 sigma each side)
    g = cv2.getGaussianKernel(ksize, sigma, cv2.CV_64F).ravel()
    half = ksize // 2
    n_fine = n + f
    n_coarse = n_fine // f + 3
    # coarse smoothed field = S @ white, S banded (interior: no border effects)
    total = n_coarse + 2 * half
    smooth = np.zeros((n_coarse, total))
    for j in range(n_coarse):
        smooth[j, j : j + ksize] = g
    coarse_cov = smooth @ smooth.T
    coarse_cov /= coarse_cov[n_coarse // 2, n_coarse // 2]  # normalised to unit variance
    # bilinear upsampling: fine x at coarse coordinate (x + 0.5) / f - 0.5, shifted by one coarse cell
    x = (np.arange(n_fine) + 0.5) / f - 0.5 + 1.0
    i0 = np.floor(x).astype(int)
    w1 = x - i0
    up = np.zeros((n_fine, n_coarse))
    up[np.arange(n_fine), i0] = 1.0 - w1
    up[np.arange(n_fine), i0 + 1] += w1
    fine = up @ coarse_cov @ up.T
    return np.mean([fine[p : p + n, p : p + n] for p in range(f)], axis=0)


def noise_covariance(model: MarkerModel, mu: np.ndarray, *, speckle_correlated: bool = True) -> np.ndarray:
    """(n^2, n^2) pixel noise covariance of the window whose mean image is ``mu`` (fractions of full scale).

    ``diag(mu / full_well + read_noise^2 + q^2) + speckle_std^2 diag(mu) K diag(mu)``, ``K`` the speckle
    correlation (:func:`speckle_correlation_1d`, Kronecker square) or, with
    ``speckle_correlated=False``, the identity (speckle treated as white: what a naive bound assumes).
    """
    mu = np.asarray(mu, dtype=np.float64).ravel()
    n = model.size_px
    quant = 1.0 / (12.0 * (2.0**model.bit_depth - 1.0) ** 2)
    shot = 0.0 if math.isinf(model.full_well) else 1.0 / model.full_well
    white = np.maximum(mu, 0.0) * shot + model.read_noise**2 + quant
    cov = np.diag(white)
    if model.speckle_std > 0:
        if speckle_correlated:
            k1 = speckle_correlation_1d(n, model.speckle_corr_px)
            cov += model.speckle_std**2 * np.kron(k1, k1) * np.outer(mu, mu)
        else:
            cov += np.diag(model.speckle_std**2 * mu * mu)
    return cov


def _poly_terms(t: np.ndarray, degree: int) -> np.ndarray:
    """(M, K) monomials ``u^i v^j`` (``i + j <= degree``) of offsets ``t`` (M, 2), graded order."""
    u, v = t[:, 0], t[:, 1]
    return np.column_stack([u**i * v ** (d - i) for d in range(degree + 1) for i in range(d, -1, -1)])


def _poly_derivative_terms(t: np.ndarray, degree: int) -> tuple[np.ndarray, np.ndarray]:
    """d/du and d/dv of :func:`_poly_terms`."""
    u, v = t[:, 0], t[:, 1]
    du, dv = [], []
    for d in range(degree + 1):
        for i in range(d, -1, -1):
            j = d - i
            du.append(i * u ** max(i - 1, 0) * v**j)
            dv.append(j * u**i * v ** max(j - 1, 0))
    return np.column_stack(du), np.column_stack(dv)


_PROFILE_DEGREE = 5  # profile vs offset: a quintic holds it to ~1e-5 of the amplitude over +-1 px
_WEIGHT_DEGREE = 3  # weights vs offset
_TABLE_RANGE_PX = 1.0  # the weights are fitted for offsets within this of the window's central pixel
_TABLE_STEP_PX = 0.25  # the offsets the profile and the weights are computed at, every this (px)
_GRID_SLACK = 1e-9  # rounding slack of the offset grid's ends (px)
_FULL_SCALE = {np.dtype(np.uint8): 255.0, np.dtype(np.uint16): 65535.0}


#: Version of :func:`fit_tables`'s algorithm and output layout: bump it whenever a change to this module
#: changes the tables, so that tables cached on disk by an older version are not used.
TABLES_FORMAT_VERSION = 1


def _tables_key(model: MarkerModel) -> str:
    """Everything :func:`fit_tables` depends on, as exact text (the key of its cache on disk)."""
    fields = ", ".join(f"{name}={getattr(model, name)!r}" for name in model.__dataclass_fields__)
    constants = (
        f"supersample={_SUPERSAMPLE!r} derivative_step={_DERIVATIVE_STEP_PX!r} "
        f"profile_degree={_PROFILE_DEGREE!r} weight_degree={_WEIGHT_DEGREE!r} range={_TABLE_RANGE_PX!r} "
        f"step={_TABLE_STEP_PX!r}"
    )
    libraries = f"numpy={np.__version__} scipy={scipy.__version__} opencv={cv2.__version__}"
    return f"format={TABLES_FORMAT_VERSION}\nMarkerModel({fields})\n{constants}\n{libraries}"


def fit_tables(model: MarkerModel) -> np.ndarray:
    """Gauss-Newton weights as a polynomial in the reference centre's offset (see the module docstring).

    Built once per model and machine: the tables (0.3-1 s to build) are kept in the user's cache folder
    (:func:`softjig.disk_cache.cached_array`, keyed by :func:`_tables_key`: the model, this module's
    table constants, ``TABLES_FORMAT_VERSION`` and the numerical libraries' versions), so a command's
    start-up reads them (about 1 ms) instead.

    Returns
    -------
    (n^2, 3 K) float32 with ``K = 10`` cubic monomials ``u^i v^j`` of the reference centre's offset
    ``(u, v)`` from the window's central pixel (``|u|, |v| <= 1`` px): ``window @ tables`` reshaped to
    ``(K, 3)`` are the coefficients of the polynomial whose value at ``(u, v)`` is
    ``(A, A du, A dv)`` of the linearised generalised least-squares estimate of ``(B, A, A du, A dv)``
    about that centre (the background ``B`` is estimated, but not returned).

    Notes
    -----
    The profile is rendered at offsets every 1/4 px in ``[-1.25, 1.25]^2`` and fitted per pixel by a
    polynomial of degree 5 in the offset, which gives its derivatives; the weights, computed every
    1/4 px in ``[-1, 1]^2``, are fitted by a cubic. The covariance is taken at the nominal amplitude
    and centred: it varies little with the sub-pixel offset.
    """
    return cached_array("subpixel-tables", _tables_key(model), lambda: _build_tables(model))


def _build_tables(model: MarkerModel) -> np.ndarray:
    """:func:`fit_tables` computed (no cache)."""
    reach = _TABLE_RANGE_PX + _TABLE_STEP_PX  # the profile one step beyond the weights, for its derivatives
    grid = np.arange(-reach, reach + _GRID_SLACK, _TABLE_STEP_PX)
    tu, tv = np.meshgrid(grid, grid)
    t_prof = np.column_stack([tu.ravel(), tv.ravel()])
    profiles = marker_profile(model, t_prof).reshape(len(t_prof), -1)
    n2 = profiles.shape[1]
    coef_f = np.linalg.lstsq(_poly_terms(t_prof, _PROFILE_DEGREE), profiles, rcond=None)[0]
    inner = np.abs(t_prof).max(axis=1) <= _TABLE_RANGE_PX + _GRID_SLACK
    t_w = t_prof[inner]
    f = _poly_terms(t_w, _PROFILE_DEGREE) @ coef_f
    dterm_u, dterm_v = _poly_derivative_terms(t_w, _PROFILE_DEGREE)
    fu, fv = dterm_u @ coef_f, dterm_v @ coef_f
    centre = profiles[len(t_prof) // 2]
    chol = scipy.linalg.cholesky(
        noise_covariance(model, model.background + model.amplitude * centre), lower=True
    )
    m = len(t_w)
    jac = np.stack([np.ones((m, n2)), f, fu, fv], axis=2)  # (m, n^2, 4)
    whitened = scipy.linalg.solve_triangular(chol, jac.transpose(1, 0, 2).reshape(n2, 4 * m), lower=True)
    whitened = whitened.reshape(n2, m, 4).transpose(1, 0, 2)  # L^-1 J per offset
    gls = np.linalg.pinv(whitened)  # (m, 4, n^2): (J^T C^-1 J)^-1 J^T L^-T
    # W = (J^T C^-1 J)^-1 J^T C^-1 = gls L^-1, i.e. W^T = L^-T gls^T: one triangular solve for all
    weights = scipy.linalg.solve_triangular(
        chol.T, gls.transpose(2, 0, 1).reshape(n2, 4 * m), lower=False
    )  # (n^2, m*4)
    weights = weights.reshape(n2, m, 4).transpose(1, 2, 0).reshape(m, 4 * n2)
    coef_w = np.linalg.lstsq(_poly_terms(t_w, _WEIGHT_DEGREE), weights, rcond=None)[0]  # (K, 4 n^2)
    k = coef_w.shape[0]
    # the background's row is not needed by the steps: (n^2, K, 3) -> (n^2, 3 K)
    tables = np.ascontiguousarray(coef_w.reshape(k, 4, n2)[:, 1:].transpose(2, 0, 1).reshape(n2, 3 * k))
    tables = tables.astype(np.float32)
    tables.flags.writeable = False
    return tables


def refine_centres(
    image: np.ndarray,
    start_xy_px: np.ndarray,
    model: MarkerModel,
    *,
    iterations: int = 20,
    tables: np.ndarray | None = None,
) -> SubpixelFit:
    """Refine marker centres by the prewhitened model fit.

    Parameters
    ----------
    image : (H, W) uint8, uint16 or float32 gray image (float scaled to [0, 1]; float64 is converted).
    start_xy_px : (N, 2) starting centres ``(u, v)`` (px), within about a pixel of the marker.
    model : the marker and noise model (:class:`MarkerModel`).
    iterations : at most this many Newton steps per window; they stop when a step is below 1e-6 px
        (3 to 5 steps from the window's centre).
    tables : :func:`kernel_tables` of ``model`` (read here when not given: a detector reads them once).

    Returns
    -------
    SubpixelFit

    Notes
    -----
    A window is the ``(2 h + 1)^2`` pixels centred on one pixel ``c``. It is read once and multiplied by
    the weights' polynomial coefficients (:func:`fit_tables`); Newton's steps on that cubic, from the
    window's centre, give its fit ``f_c``, a function of the window's pixels only. Each marker is fitted
    in the window at the pixel nearest its start; if the fit lies nearer another pixel, in the window
    there too (up to three windows), and the centre is the fit lying nearest its own window's centre.
    Windows reaching past the image edge are read with the edge pixels repeated (those markers are
    biased; the detector's border margin discards most of them).

    A window's fit depends a little on the window (the model does not fit a real marker exactly, and
    each window cuts its rim elsewhere), so two starts that round to different pixels can give centres a
    few hundredths of a pixel apart for a marker near a boundary between pixels. Blending the
    neighbouring windows' fits would remove that dependence but does not bring the centres closer to the
    truth (see benchmarks/RESULTS.md).
    """
    from softjig.sensing._subpixel_kernels import refine_all  # Numba is imported on first use

    start = np.asarray(start_xy_px, dtype=np.float64)
    if start.size == 0:
        start = start.reshape(0, 2)
    if start.ndim != 2 or start.shape[1] != 2:
        raise InputError(f"start_xy_px must be an (N, 2) array of pixel positions (x, y), got {start.shape}.")
    if not np.isfinite(start).all():  # N markers, not the image's pixels: cheap
        raise InputError("start_xy_px contains NaN or infinite positions: drop those markers first.")
    start = np.ascontiguousarray(start)
    if int(iterations) < 0:
        raise InputError(f"iterations must be >= 0, got {iterations}.")
    arr = np.asarray(image)
    if arr.ndim != 2 or arr.size == 0:
        raise InputError(f"refine_centres needs a non-empty gray (H, W) image, got shape {arr.shape}.")
    if arr.dtype not in _FULL_SCALE and arr.dtype not in (np.dtype(np.float32), np.dtype(np.float64)):
        raise InputError(
            f"refine_centres needs a uint8, uint16 or float (in [0, 1]) image, got dtype {arr.dtype}; "
            "pass the camera's frame or gray_image()'s."
        )
    if arr.dtype == np.float64:
        arr = arr.astype(np.float32)
    arr = np.ascontiguousarray(arr)
    scale = 1.0 / _FULL_SCALE.get(arr.dtype, 1.0)
    xy = np.empty_like(start)
    amp = np.empty(len(start))
    ok = np.empty(len(start), np.bool_)
    tables = tables if tables is not None else kernel_tables(model)
    half = int(model.half_width_px)
    refine_all(arr, start, tables, half, scale, _TABLE_RANGE_PX, _MAX_SHIFT_PX, int(iterations), xy, amp, ok)
    return SubpixelFit(xy_px=xy, amplitude=amp, ok=ok)


_BLOCK_ROWS = 5  # table rows per block of the kernels' product: the 30 coefficients, no padding


def kernel_tables(model: MarkerModel) -> np.ndarray:
    """:func:`fit_tables` transposed, ``(3 K, n^2)`` padded with zero rows to a multiple of 5, float32
    (read-only): what :func:`refine_centres` takes as ``tables`` (read from disk: a detector
    makes them once).

    One row per coefficient, contiguous over the window's pixels: the layout of :func:`_block_product`.
    """
    tables = fit_tables(model)
    rows = -(-tables.shape[1] // _BLOCK_ROWS) * _BLOCK_ROWS
    out = np.zeros((rows, tables.shape[0]), np.float32)
    out[: tables.shape[1]] = tables.T
    out.flags.writeable = False
    return out
