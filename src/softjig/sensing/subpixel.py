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
fixed point; Newton's steps on the cubic, to 1e-6 px) costs little. A window's fit depends a little on
the window (the model does not fit a real marker exactly, and each window cuts its rim elsewhere), so
the centre is a blend of the fits of the windows around it, which makes it a function of the image
only, not of where the fit started (see :func:`refine_centres`). The whole fit, one compiled loop,
takes about 0.5 ms for the ~290 markers of a default 1280x720 frame with 21x21 windows on one core of
this machine, 1.6-1.7 windows per marker, most of it the products (measured). Noise-free, on the
model's own markers, the fit is unbiased to 0.003 px RMS (the polynomials' error) for a blur of at
least ``MIN_MODEL_BLUR_PX``; with noise drawn from its covariance it reaches the Cramer-Rao bound
(``tests/test_cramer_rao.py``). On the simulator's default frames: 0.160 px RMS against 0.271 px for
the LoG's 3x3 quadratic fit.

The fit does not model the hemisphere's obliquity (its image is asymmetric about the base centre, see
:mod:`softjig.sim.render`): that bias, which grows as the square of the viewing angle, remains.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import cv2
import numba
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
    "marker_profile",
    "noise_covariance",
    "refine_centres",
    "speckle_correlation_1d",
]

#: The weight tables are accurate for markers blurred by at least this (px): noise-free bias 0.003 px
#: RMS at 1 px, 0.008 at 0.6, 0.024 for a sharp marker (measured; the offset polynomials need a profile
#: smooth at the pixel scale).
MIN_MODEL_BLUR_PX = 1.0
_SUPERSAMPLE = 8  # sub-samples per pixel side when rendering the profile
_MAX_STEP_PX = 0.5  # a window's Newton step is clipped to this, per axis
_MAX_SHIFT_PX = 2.5  # a fit that moves further from its start than this failed: the start is kept
_BLEND_PX = 0.12  # half-width of the weights' ramp across a boundary between windows (refine_centres)
_MAX_PASSES = 5  # rounds of window fits
_MAX_WINDOWS = 8  # windows fitted per marker, at most
_MAX_SOLVE_STEPS = 30  # Newton steps of the blend's fixed point per marker and round
_SOLVE_TOLERANCE_PX = 1e-9  # the blend's fixed point converged (the next step would be ~1e-18 px)
_MIN_PIVOT = 0.05  # Newton's determinant of I - dG/dx; below it, a plain fixed-point step
_EDGE = 1e-9  # a ramp weight this close to 0 or 1 is on the ramp's edge
_STEP_TOLERANCE_PX = 1e-6  # a window's Newton steps converged (its fit then within 1e-12 px)
_DERIVATIVE_STEP_PX = 0.05


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
    ksize = round(sigma * 4 * 2 + 1) | 1  # cv2's automatic size for float32 images
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


_PROFILE_DEGREE = 5  # profile vs offset: max error 2e-5 of the amplitude over +-1 px (measured)
_WEIGHT_DEGREE = 3  # weights vs offset
_TABLE_RANGE_PX = 1.0  # the weights are fitted for offsets within this of the window's central pixel
_FULL_SCALE = {np.dtype(np.uint8): 255.0, np.dtype(np.uint16): 65535.0}


#: Version of :func:`fit_tables`'s algorithm and output layout: bump it whenever a change to this module
#: changes the tables, so that tables cached on disk by an older version are not used.
TABLES_FORMAT_VERSION = 1


def _tables_key(model: MarkerModel) -> str:
    """Everything :func:`fit_tables` depends on, as exact text (the key of its cache on disk)."""
    fields = ", ".join(f"{name}={getattr(model, name)!r}" for name in model.__dataclass_fields__)
    constants = (
        f"supersample={_SUPERSAMPLE!r} derivative_step={_DERIVATIVE_STEP_PX!r} "
        f"profile_degree={_PROFILE_DEGREE!r} weight_degree={_WEIGHT_DEGREE!r} range={_TABLE_RANGE_PX!r}"
    )
    libraries = f"numpy={np.__version__} scipy={scipy.__version__} opencv={cv2.__version__}"
    return f"format={TABLES_FORMAT_VERSION}\nMarkerModel({fields})\n{constants}\n{libraries}"


@lru_cache(maxsize=16)
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
    grid = np.arange(-1.25, 1.25 + 1e-9, 0.25)
    tu, tv = np.meshgrid(grid, grid)
    t_prof = np.column_stack([tu.ravel(), tv.ravel()])
    profiles = marker_profile(model, t_prof).reshape(len(t_prof), -1)
    n2 = profiles.shape[1]
    coef_f = np.linalg.lstsq(_poly_terms(t_prof, _PROFILE_DEGREE), profiles, rcond=None)[0]
    inner = np.abs(t_prof).max(axis=1) <= _TABLE_RANGE_PX + 1e-9
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
    image: np.ndarray, start_xy_px: np.ndarray, model: MarkerModel, *, iterations: int = 20
) -> SubpixelFit:
    """Refine marker centres by the prewhitened model fit.

    Parameters
    ----------
    image : (H, W) uint8, uint16 or float32 gray image (float scaled to [0, 1]).
    start_xy_px : (N, 2) starting centres ``(u, v)`` (px), within about a pixel of the marker.
    model : the marker and noise model (:class:`MarkerModel`).
    iterations : at most this many Newton steps per window; they stop when a step is below 1e-6 px
        (3 to 5 steps from the window's centre).

    Returns
    -------
    SubpixelFit

    Notes
    -----
    *A window's fit.* A window is the ``(2 h + 1)^2`` pixels centred on one pixel ``c``. It is read
    once and multiplied by the weights' polynomial coefficients (:func:`fit_tables`); Newton's steps on
    that cubic, from the window's centre, give its fit ``f_c``, a function of the window's pixels only.
    Windows reaching past the image edge are read with the edge pixels repeated (those markers are
    biased; the detector's border margin discards most of them).

    *Which windows.* A window's fit depends a little on the window: the model does not fit a real marker
    exactly (its obliquity, the membrane's deformation) and each window cuts the marker's rim elsewhere.
    On the default sweep's 437,000 markers the fits of two neighbouring windows differ by 0.03 px
    (median), up to 0.24 px towards their own centres and 0.35 px away from them (measured). So taking
    the window whose fit lies nearest its centre is ill-posed near a boundary between two pixels: both
    windows can be consistent with their own fit (or neither), and where the fit started chose (0.3 %
    of the markers differed, by up to 0.12 px, between the pipeline's fast and full-resolution
    candidates). The centre is instead the fixed point ``x = G(x)`` of a blend of the windows' fits,

    .. math:: G(x) = \\frac{\\sum_c w_c(x) f_c}{\\sum_c w_c(x)}, \\quad
              w_c(x) = \\lambda(x_u - c_u) \\lambda(x_v - c_v),

    over the windows whose fit succeeded, with ``lambda`` 1 within ``1/2 - d`` px of the window's
    centre, 0 beyond ``1/2 + d``, linear between (``d = _BLEND_PX`` = 0.12 px): the weights are a
    partition of unity, so ``G`` is continuous. Deep inside one window's span (``|x - c| < 1/2 - d``
    on both axes) the centre is that window's fit, as with the former rule; within ``d`` of a boundary
    it is a blend of the two windows' fits (of four, near a corner). Fitting the windows it needs as it
    goes (one round of products per step: the window at the pixel nearest the start, then those the
    blend asks for), a marker takes Newton steps on ``x - G(x)`` one smooth piece at a time
    (:func:`_solve`).

    The fixed point is unique, so the centre is the image's, not the start's, when along each axis
    the fits of two neighbouring windows differ by less than ``2 d`` towards their centres (the ramp's
    slope times that difference is then below 1; a difference away from the centres is always fine).
    On the default sweep the blend of every marker has a single fixed point from ``d = 0.11`` px (10
    markers had several at 0.08, 2 at 0.10; measured); 0.12 leaves a little margin, each 0.01 px
    costing about 2 % more time, as the markers within ``d`` of a boundary need the neighbouring
    window: 1.64 windows per marker against 1.23 with the former rule (the sweep's frames, measured).
    Any start within about a pixel of a marker gives the same centre, to rounding: the fast and the
    full-resolution candidates now give the same markers to 6e-13 px on the sweep (measured). The
    blend also averages out the two windows' opposite biases near a boundary: 0.1619 px RMS against
    0.1627 with the former rule over 50,822 markers of the sweep, 0.1583 against 0.1602 for those
    within 0.12 px of a boundary (measured).

    *Speed.* All of it (gathers, products, steps, blends) is one compiled call (:func:`_refine_all`),
    with no per-call NumPy overhead and no BLAS: 0.51 ms of CPU time for the 293 markers of a sweep
    frame against 0.43 ms with the former rule (medians of 200 interleaved runs on 24 frames' images;
    0.54 against 0.45 ms on ``benchmarks/bench_estimate.py``'s pairs). The extra windows would cost
    more, but the products, in blocks of 4 windows x 5 rows, take 0.54 us a window against 0.61 us in
    the former blocks of 4 x 4, and Newton's steps are fewer than Gauss-Newton's (measured). The former
    rule's version against a NumPy gather, one OpenBLAS product (one thread) and Numba steps per
    window: 0.57 against 1.43 ms; multi-threaded OpenBLAS was worse still on this shared 2-core machine
    (up to 10x, its threads spinning). The compiled product sums in another order than BLAS: centres
    differ from that version's by up to 4e-6 px (float32 rounding; measured).
    """
    start = np.ascontiguousarray(np.asarray(start_xy_px, dtype=np.float64).reshape(-1, 2))
    arr = np.asarray(image)
    if arr.ndim != 2:
        raise InputError(f"refine_centres needs a gray (H, W) image, got shape {arr.shape}.")
    if arr.dtype not in _FULL_SCALE and arr.dtype != np.float32:
        arr = arr.astype(np.float32)
    arr = np.ascontiguousarray(arr)
    scale = 1.0 / _FULL_SCALE.get(arr.dtype, 1.0)
    xy = np.empty_like(start)
    amp = np.empty(len(start))
    ok = np.empty(len(start), np.bool_)
    _refine_all(
        arr,
        start,
        _kernel_tables(model),
        int(model.half_width_px),
        scale,
        int(iterations),
        xy,
        amp,
        ok,
    )
    return SubpixelFit(xy_px=xy, amplitude=amp, ok=ok)


_BLOCK_ROWS = 5  # table rows per block of _block_product: the 30 coefficients, no padding
_CHUNK = 32  # windows gathered at a time: 55 kB of float32 for 21x21 windows


@lru_cache(maxsize=16)
def _kernel_tables(model: MarkerModel) -> np.ndarray:
    """:func:`fit_tables` transposed, ``(3 K, n^2)`` padded with zero rows to a multiple of 5, float32.

    One row per coefficient, contiguous over the window's pixels: the layout of :func:`_block_product`.
    """
    tables = fit_tables(model)
    rows = -(-tables.shape[1] // _BLOCK_ROWS) * _BLOCK_ROWS
    out = np.zeros((rows, tables.shape[0]), np.float32)
    out[: tables.shape[1]] = tables.T
    out.flags.writeable = False
    return out


@numba.njit(cache=True, nogil=True)
def _refine_all(image, start, tables_t, half, scale, iterations, xy, amp, ok):
    """:func:`refine_centres` for all markers: writes the centres ``xy`` (N, 2), amplitudes ``amp`` and
    success ``ok``.

    In rounds (up to ``_MAX_PASSES``): the windows requested are gathered ``_CHUNK`` at a time,
    multiplied by the tables in blocks of 4 windows (:func:`_block_product`) and fitted
    (:func:`_steps`, from the window's central pixel); then each marker with new fits takes Newton steps
    towards the fixed point of the blend (:func:`_solve`) until it converges, or needs windows not
    fitted yet, which it requests for the next round (at most ``_MAX_WINDOWS`` per marker; a marker
    still unsolved after the last round failed). Round 1 fits each marker in the window at the pixel
    nearest its start, and the solve starts from that fit; a fit inside its own window's span, where
    that window has all the weight, is the result at once (52 % of the markers of the sweep's frames).
    """
    n_markers = start.shape[0]
    n = 2 * half + 1
    windows = np.zeros((_CHUNK, n * n), np.float32)  # zeros: the padding rows of a last block are finite
    coeffs = np.empty((_CHUNK, tables_t.shape[0]), np.float32)
    # each marker's fitted windows: central pixel, fit (u, v, amplitude) and success (1 or 0); one array,
    # for _solve's call costs reference counting per array argument: 0.15 us a call for 7 (measured)
    known = np.empty((n_markers, _MAX_WINDOWS, 6))
    n_known = np.zeros(n_markers, np.int64)
    point = np.empty((n_markers, 2))  # where each marker's solve stands
    missing = np.empty((3, 2), np.int64)
    todo_m = np.empty(3 * n_markers, np.int64)  # the windows to fit this round: marker, central pixel
    todo_c = np.empty((3 * n_markers, 2), np.int64)
    next_m = np.empty(3 * n_markers, np.int64)
    next_c = np.empty((3 * n_markers, 2), np.int64)
    inner = 0.5 - _BLEND_PX  # a fit this close to its window's centre is the result
    count = 0
    for m in range(n_markers):
        su, sv = start[m, 0], start[m, 1]
        xy[m, 0], xy[m, 1], amp[m], ok[m] = su, sv, 0.0, False
        if math.isfinite(su) and math.isfinite(sv):
            todo_m[count] = m
            todo_c[count, 0], todo_c[count, 1] = math.floor(su + 0.5), math.floor(sv + 0.5)
            count += 1
    for p in range(_MAX_PASSES):
        for c0 in range(0, count, _CHUNK):
            rows = min(_CHUNK, count - c0)
            for i in range(rows):
                _gather(image, todo_c[c0 + i, 0] - half, todo_c[c0 + i, 1] - half, n, windows[i])
            _block_product(windows, tables_t, coeffs, rows)
            for i in range(rows):
                m, cu, cv = todo_m[c0 + i], todo_c[c0 + i, 0], todo_c[c0 + i, 1]
                u, v, a, good = _steps(coeffs[i], cu, cv, scale, iterations)
                k = n_known[m]
                known[m, k, 0], known[m, k, 1], known[m, k, 2], known[m, k, 3] = cu, cv, u, v
                known[m, k, 4], known[m, k, 5] = a, 1.0 if good else 0.0
                n_known[m] = k + 1
        n_next = 0
        for r in range(count):
            m = todo_m[r]
            if r > 0 and todo_m[r - 1] == m:
                continue  # a marker's windows are consecutive: one solve per marker and round
            su, sv = start[m, 0], start[m, 1]
            if p == 0:
                u, v, a = known[m, 0, 2], known[m, 0, 3], known[m, 0, 4]
                if not a > 0.0:
                    continue  # not a bright marker: failed
                if abs(u - known[m, 0, 0]) < inner and abs(v - known[m, 0, 1]) < inner:
                    # inside its own window's span: the fixed point, as _solve would find (sooner)
                    if known[m, 0, 5] > 0.0 and abs(u - su) <= _MAX_SHIFT_PX and abs(v - sv) <= _MAX_SHIFT_PX:
                        xy[m, 0], xy[m, 1], amp[m], ok[m] = u, v, a, True
                    continue
                point[m, 0], point[m, 1] = u, v
            state, u, v, a = _solve(known, m, n_known[m], point[m, 0], point[m, 1], su, sv, missing)
            point[m, 0], point[m, 1] = u, v
            if state == 0:
                xy[m, 0], xy[m, 1], amp[m], ok[m] = u, v, a, True
            elif state > 0 and p + 1 < _MAX_PASSES and n_known[m] + state <= _MAX_WINDOWS:
                for j in range(state):
                    next_m[n_next] = m
                    next_c[n_next, 0], next_c[n_next, 1] = missing[j, 0], missing[j, 1]
                    n_next += 1
        todo_m, next_m = next_m, todo_m
        todo_c, next_c = next_c, todo_c
        count = n_next
        if count == 0:
            break


@numba.njit(cache=True, nogil=True)
def _solve(known, m, nk, xu, xv, su, sv, missing):
    """Newton steps on ``x = G(x)`` for marker ``m`` from ``(xu, xv)``, the blend ``G`` of the fits of its
    first ``nk`` windows ``known[m]`` (see :func:`_refine_all` and :func:`refine_centres`); ``(su, sv)`` is
    its start.

    ``G`` is smooth in each piece of the plane (along each axis: inside one window's span, where its
    weight is 1, or on the ramp between two) but has kinks between pieces, where plain Newton steps can
    jump to and fro over a ramp for ever (a marker whose windows' fits lie 0.3 px apart, away from their
    centres: measured on the sweep). So each step stays in its piece: it is cut short at the piece's
    edge, and from an edge the next piece is the one the residual points into. Where no window of
    nonzero weight fitted but they found a bright blob beyond their reach (a start more than a pixel
    off), the solve goes on from their fits, as the former rule did.

    Returns ``(state, u, v, amplitude)``: state 0, converged at ``(u, v)``; state ``k > 0``, the step
    needs ``k`` windows not fitted yet, whose central pixels are written to ``missing[:k]``, and ``(u,
    v)`` is where the solve stands; state -1, failed: moved more than ``_MAX_SHIFT_PX`` from the start,
    no window of nonzero weight fitted, or no convergence.
    """
    d = _BLEND_PX
    slope = 0.5 / d
    force_u = force_v = -1  # on an edge: the piece chosen after a step that could not leave it (1 ramp)
    for _ in range(_MAX_SOLVE_STEPS):
        if abs(xu - su) > _MAX_SHIFT_PX or abs(xv - sv) > _MAX_SHIFT_PX:
            return -1, xu, xv, 0.0
        # the weight of the window after the nearest boundary (b + 1/2), on the ramp |x - b - 1/2| < d;
        # on a ramp's edge (where a cut step ends) both windows are needed, to choose the next piece
        bu, bv = math.floor(xu), math.floor(xv)
        lu = (xu - bu - 0.5) * slope + 0.5
        lv = (xv - bv - 0.5) * slope + 0.5
        edge_u = abs(lu) <= _EDGE or abs(lu - 1.0) <= _EDGE
        edge_v = abs(lv) <= _EDGE or abs(lv - 1.0) <= _EDGE
        lu = (0.0 if lu < 0.5 else 1.0) if edge_u else min(max(lu, 0.0), 1.0)
        lv = (0.0 if lv < 0.5 else 1.0) if edge_v else min(max(lv, 0.0), 1.0)
        ramp_u = edge_u or 0.0 < lu < 1.0
        ramp_v = edge_v or 0.0 < lv < 1.0
        u0 = bu if ramp_u or lu <= 0.0 else bu + 1  # u0 == u1: one column of windows
        u1 = bu + 1 if ramp_u or lu >= 1.0 else bu
        v0 = bv if ramp_v or lv <= 0.0 else bv + 1
        v1 = bv + 1 if ramp_v or lv >= 1.0 else bv
        i00 = i10 = i01 = i11 = -1
        for k in range(nk):
            ku, kv = known[m, k, 0], known[m, k, 1]
            if kv == v0:
                if ku == u0:
                    i00 = k
                if ku == u1:
                    i10 = k
            if kv == v1:
                if ku == u0:
                    i01 = k
                if ku == u1:
                    i11 = k
        if i00 < 0 or i10 < 0 or i01 < 0 or i11 < 0:
            n_missing = 0
            if i00 < 0:
                missing[n_missing, 0], missing[n_missing, 1] = u0, v0
                n_missing += 1
            if i10 < 0 and u1 != u0:
                missing[n_missing, 0], missing[n_missing, 1] = u1, v0
                n_missing += 1
            if i01 < 0 and v1 != v0:
                missing[n_missing, 0], missing[n_missing, 1] = u0, v1
                n_missing += 1
            if i11 < 0 and u1 != u0 and v1 != v0 and n_missing < 3:  # else it waits for the next round
                missing[n_missing, 0], missing[n_missing, 1] = u1, v1
                n_missing += 1
            return n_missing, xu, xv, 0.0
        # the windows whose fit failed are left out, their weight shared among the others
        g00, g10, g01, g11 = known[m, i00, 5], known[m, i10, 5], known[m, i01, 5], known[m, i11, 5]
        w00, w10, w01, w11 = (
            (1.0 - lu) * (1.0 - lv) * g00,
            lu * (1.0 - lv) * g10,
            (1.0 - lu) * lv * g01,
            lu * lv * g11,
        )
        total = w00 + w10 + w01 + w11
        if not total > 0.0:
            # no window of nonzero weight fitted: if they found a bright blob beyond their reach (the
            # start more than a pixel off), go on from there (where the former rule went: 2 px starts)
            nu, nv, nw = 0.0, 0.0, 0.0
            for i, b in (
                (i00, (1.0 - lu) * (1.0 - lv)),
                (i10, lu * (1.0 - lv)),
                (i01, (1.0 - lu) * lv),
                (i11, lu * lv),
            ):
                if b > 0.0 and known[m, i, 4] > 0.0:
                    nu, nv, nw = nu + b * known[m, i, 2], nv + b * known[m, i, 3], nw + b
            if not nw > 0.0 or (nu / nw == xu and nv / nw == xv):
                return -1, xu, xv, 0.0
            xu, xv = nu / nw, nv / nw
            continue
        f00u, f00v = known[m, i00, 2], known[m, i00, 3]
        f10u, f10v = known[m, i10, 2], known[m, i10, 3]
        f01u, f01v = known[m, i01, 2], known[m, i01, 3]
        f11u, f11v = known[m, i11, 2], known[m, i11, 3]
        inv = 1.0 / total
        gu = (w00 * f00u + w10 * f10u + w01 * f01u + w11 * f11u) * inv
        gv = (w00 * f00v + w10 * f10v + w01 * f01v + w11 * f11v) * inv
        ru, rv = gu - xu, gv - xv
        # the piece: on a ramp, or on its edge with the residual pointing onto it (unless that piece's
        # step, turned by the other axis, pointed off it: then the other piece)
        on_u = 0.0 < lu < 1.0 or (edge_u and (ru > 0.0) == (lu == 0.0))
        on_v = 0.0 < lv < 1.0 or (edge_v and (rv > 0.0) == (lv == 0.0))
        if edge_u and force_u >= 0:
            on_u = force_u == 1
        if edge_v and force_v >= 0:
            on_v = force_v == 1
        # Jacobian of G in the piece (zero along an axis off a ramp): dG/dl = sum(dw/dl g (f - G)) / total
        ju = slope * inv if on_u else 0.0
        jv = slope * inv if on_v else 0.0
        e00u, e10u, e01u, e11u = g00 * (f00u - gu), g10 * (f10u - gu), g01 * (f01u - gu), g11 * (f11u - gu)
        e00v, e10v, e01v, e11v = g00 * (f00v - gv), g10 * (f10v - gv), g01 * (f01v - gv), g11 * (f11v - gv)
        guu = ((1.0 - lv) * (e10u - e00u) + lv * (e11u - e01u)) * ju
        guv = ((1.0 - lu) * (e01u - e00u) + lu * (e11u - e10u)) * jv
        gvu = ((1.0 - lv) * (e10v - e00v) + lv * (e11v - e01v)) * ju
        gvv = ((1.0 - lu) * (e01v - e00v) + lu * (e11v - e10v)) * jv
        det = (1.0 - guu) * (1.0 - gvv) - guv * gvu
        if det > _MIN_PIVOT:
            inv = 1.0 / det
            du = ((1.0 - gvv) * ru + guv * rv) * inv
            dv = (gvu * ru + (1.0 - guu) * rv) * inv
        else:  # G is not a contraction here (see _BLEND_PX): a plain fixed-point step
            du, dv = ru, rv
        # the piece's extent: the ramp, or the span where one window has all the weight
        cu = u0 if lu <= 0.0 else u1  # off a ramp: the window with all the weight
        cv = v0 if lv <= 0.0 else v1
        lo_u, hi_u = (bu + 0.5 - d, bu + 0.5 + d) if on_u else (cu - 0.5 + d, cu + 0.5 - d)
        lo_v, hi_v = (bv + 0.5 - d, bv + 0.5 + d) if on_v else (cv - 0.5 + d, cv + 0.5 - d)
        tau, cut = 1.0, 0  # the step's fraction inside the piece; the axis that leaves it first
        if xu + du > hi_u and du > 0.0:
            tau, cut = (hi_u - xu) / du, 1
        elif xu + du < lo_u and du < 0.0:
            tau, cut = (lo_u - xu) / du, 1
        if xv + dv > hi_v and dv > 0.0 and (hi_v - xv) / dv < tau:
            tau, cut = (hi_v - xv) / dv, 2
        elif xv + dv < lo_v and dv < 0.0 and (lo_v - xv) / dv < tau:
            tau, cut = (lo_v - xv) / dv, 2
        if cut == 0:
            xu, xv = xu + du, xv + dv
            if abs(du) <= _SOLVE_TOLERANCE_PX and abs(dv) <= _SOLVE_TOLERANCE_PX:
                a = w00 * known[m, i00, 4] + w10 * known[m, i10, 4] + w01 * known[m, i01, 4]
                return 0, xu, xv, (a + w11 * known[m, i11, 4]) / total
            force_u = force_v = -1
        elif tau > 0.0:  # to the piece's edge, exactly
            if cut == 1:
                xu, xv = (hi_u if du > 0.0 else lo_u), xv + tau * dv
            else:
                xu, xv = xu + tau * du, (hi_v if dv > 0.0 else lo_v)
            force_u = force_v = -1
        elif cut == 1 and edge_u and force_u < 0:  # stuck on an edge: the other piece
            force_u = 0 if on_u else 1
        elif cut == 2 and edge_v and force_v < 0:
            force_v = 0 if on_v else 1
        else:  # stuck in both pieces of an edge (or off edges): the step, whichever piece it leads to
            xu, xv = xu + du, xv + dv
            force_u = force_v = -1
    return -1, xu, xv, 0.0


@numba.njit(cache=True, nogil=True)
def _gather(image, u0, v0, n, window):
    """The ``n x n`` window of top-left pixel ``(u0, v0)``, row-major, into ``window`` (float32); pixels
    past the image edge are read as the nearest edge pixel."""
    h, w = image.shape
    if u0 >= 0 and v0 >= 0 and u0 + n <= w and v0 + n <= h:
        for r in range(n):
            row = image[v0 + r]
            for c in range(n):
                window[r * n + c] = row[u0 + c]
        return
    for r in range(n):
        row = image[min(max(v0 + r, 0), h - 1)]
        for c in range(n):
            window[r * n + c] = row[min(max(u0 + c, 0), w - 1)]


@numba.njit(cache=True, nogil=True, fastmath={"reassoc", "contract"})
def _block_product(windows, tables_t, coeffs, rows):
    """``coeffs[:rows] = windows[:rows] @ tables_t.T`` (float32), in blocks of 4 windows x 5 table rows.

    Twenty independent sums, vectorised over the pixels (``reassoc``), reuse each loaded value four or
    five times: 0.54 us per 21x21 window, against 0.61 us in blocks of 4 x 4 (the 30 rows padded to
    32), 0.8-1.1 us for other shapes (4 x 2, 2 x 4, 4 x 10, 8 x 5) and 1.4 us for one window at a time
    (measured, one thread). Rows past ``rows`` up to a multiple of 4 are computed and ignored (every
    window is summed in the same order, wherever it is in the block).
    """
    n = windows.shape[1]
    for i in range(0, rows, 4):
        x0, x1, x2, x3 = windows[i], windows[i + 1], windows[i + 2], windows[i + 3]
        for j in range(0, tables_t.shape[0], 5):
            t0, t1, t2, t3, t4 = (
                tables_t[j],
                tables_t[j + 1],
                tables_t[j + 2],
                tables_t[j + 3],
                tables_t[j + 4],
            )
            a00 = a01 = a02 = a03 = a04 = a10 = a11 = a12 = a13 = a14 = np.float32(0.0)
            a20 = a21 = a22 = a23 = a24 = a30 = a31 = a32 = a33 = a34 = np.float32(0.0)
            for k in range(n):
                p0, p1, p2, p3, p4 = t0[k], t1[k], t2[k], t3[k], t4[k]
                y = x0[k]
                a00, a01, a02, a03, a04 = a00 + y * p0, a01 + y * p1, a02 + y * p2, a03 + y * p3, a04 + y * p4
                y = x1[k]
                a10, a11, a12, a13, a14 = a10 + y * p0, a11 + y * p1, a12 + y * p2, a13 + y * p3, a14 + y * p4
                y = x2[k]
                a20, a21, a22, a23, a24 = a20 + y * p0, a21 + y * p1, a22 + y * p2, a23 + y * p3, a24 + y * p4
                y = x3[k]
                a30, a31, a32, a33, a34 = a30 + y * p0, a31 + y * p1, a32 + y * p2, a33 + y * p3, a34 + y * p4
            c = coeffs[i]
            c[j], c[j + 1], c[j + 2], c[j + 3], c[j + 4] = a00, a01, a02, a03, a04
            c = coeffs[i + 1]
            c[j], c[j + 1], c[j + 2], c[j + 3], c[j + 4] = a10, a11, a12, a13, a14
            c = coeffs[i + 2]
            c[j], c[j + 1], c[j + 2], c[j + 3], c[j + 4] = a20, a21, a22, a23, a24
            c = coeffs[i + 3]
            c[j], c[j + 1], c[j + 2], c[j + 3], c[j + 4] = a30, a31, a32, a33, a34


@numba.njit(cache=True, nogil=True)
def _steps(coeffs, cu, cv, scale, iterations):
    """Newton steps on ``(A du, A dv)(t) = 0`` from the central pixel ``(cu, cv)`` of the window, the
    weights' cubic (``coeffs``: 10 monomials in graded order, 3 values each) evaluated at the offset
    ``t`` from it.

    The fit is where the linearised estimate of the centre's offset from the reference ``t`` is zero,
    the fixed point of the Gauss-Newton steps ``t <- t + (A du, A dv) / A``; Newton's steps, with the
    cubic's exact Jacobian, get there in 3 or 4 steps from the window's centre (3.2 on average, the
    last one finding it converged) where those took 4 to 16 (7.2; the linearisation's Jacobian is not
    ``-A``; measured on a sweep frame's markers). Where the Jacobian is not that of a bright blob's
    centre (far from it), the step is the Gauss-Newton one. Every fit of a window
    starts at its centre, so it is a function of the window's pixels only (not of the marker's start nor
    of the order the windows are fitted in). The coefficients are read into scalars once: twice as fast
    as a monomial array (measured).

    Returns the centre ``(u, v)``, the amplitude and whether the fit succeeded (a bright marker, the
    steps converged inside their clamp).
    """
    a0, u0, v0 = np.float64(coeffs[0]), np.float64(coeffs[1]), np.float64(coeffs[2])
    a1, u1, v1 = np.float64(coeffs[3]), np.float64(coeffs[4]), np.float64(coeffs[5])
    a2, u2, v2 = np.float64(coeffs[6]), np.float64(coeffs[7]), np.float64(coeffs[8])
    a3, u3, v3 = np.float64(coeffs[9]), np.float64(coeffs[10]), np.float64(coeffs[11])
    a4, u4, v4 = np.float64(coeffs[12]), np.float64(coeffs[13]), np.float64(coeffs[14])
    a5, u5, v5 = np.float64(coeffs[15]), np.float64(coeffs[16]), np.float64(coeffs[17])
    a6, u6, v6 = np.float64(coeffs[18]), np.float64(coeffs[19]), np.float64(coeffs[20])
    a7, u7, v7 = np.float64(coeffs[21]), np.float64(coeffs[22]), np.float64(coeffs[23])
    a8, u8, v8 = np.float64(coeffs[24]), np.float64(coeffs[25]), np.float64(coeffs[26])
    a9, u9, v9 = np.float64(coeffs[27]), np.float64(coeffs[28]), np.float64(coeffs[29])
    lim = _TABLE_RANGE_PX + 0.25
    tu = 0.0
    tv = 0.0
    a = 0.0
    converged = False
    for _ in range(iterations):
        uu, uv, vv = tu * tu, tu * tv, tv * tv
        uuu, uuv, uvv, vvv = uu * tu, uu * tv, tu * vv, vv * tv
        a = a0 + a1 * tu + a2 * tv + a3 * uu + a4 * uv + a5 * vv + a6 * uuu + a7 * uuv + a8 * uvv + a9 * vvv
        if not a > 0.0:
            break
        au = u0 + u1 * tu + u2 * tv + u3 * uu + u4 * uv + u5 * vv + u6 * uuu + u7 * uuv + u8 * uvv + u9 * vvv
        av = v0 + v1 * tu + v2 * tv + v3 * uu + v4 * uv + v5 * vv + v6 * uuu + v7 * uuv + v8 * uvv + v9 * vvv
        # Jacobian of (au, av) with respect to t
        juu = u1 + 2.0 * u3 * tu + u4 * tv + 3.0 * u6 * uu + 2.0 * u7 * uv + u8 * vv
        juv = u2 + u4 * tu + 2.0 * u5 * tv + u7 * uu + 2.0 * u8 * uv + 3.0 * u9 * vv
        jvu = v1 + 2.0 * v3 * tu + v4 * tv + 3.0 * v6 * uu + 2.0 * v7 * uv + v8 * vv
        jvv = v2 + v4 * tu + 2.0 * v5 * tv + v7 * uu + 2.0 * v8 * uv + 3.0 * v9 * vv
        det = juu * jvv - juv * jvu
        if det > 0.0 and juu + jvv < 0.0:
            du = (juv * av - jvv * au) / det
            dv = (jvu * au - juu * av) / det
        else:
            du, dv = au / a, av / a
        du = min(max(du, -_MAX_STEP_PX), _MAX_STEP_PX)
        dv = min(max(dv, -_MAX_STEP_PX), _MAX_STEP_PX)
        if (abs(tu) == lim and du * tu > 0.0) or (abs(tv) == lim and dv * tv > 0.0):
            break  # pushing past the clamp: no centre in this window (a fiducial's square, a cut marker)
        tu = min(max(tu + du, -lim), lim)
        tv = min(max(tv + dv, -lim), lim)
        if abs(du) < _STEP_TOLERANCE_PX and abs(dv) < _STEP_TOLERANCE_PX:
            converged = True
            break
    # a fit up to 1.25 px off extrapolates the weights' cubic a little, but it only gets weight when the
    # other windows' fits are about as far off (markers the model does not fit)
    good = converged and a > 0.0 and abs(tu) < lim and abs(tv) < lim
    return cu + tu, cv + tv, a * scale, good
