r"""Cramer-Rao bound of a marker centre's localisation under the simulator's image model.

The marker's mean image in a window of pixels ``k`` is (:mod:`softjig.sensing.subpixel`)

.. math:: \mu_k(\theta) = B + A\, f(x_k - u, y_k - v), \qquad \theta = (u, v, A, B),

``f`` the simulator's shaded hemisphere of image radius ``R`` blurred by a Gaussian of ``b`` px,
``A`` and ``B`` nuisance parameters. The pixel noise is Gaussian with covariance
(:func:`softjig.sensing.subpixel.noise_covariance`)

.. math:: C(\theta) = \mathrm{diag}(\mu / N_e + r^2 + q^2) + s^2 \mathrm{diag}(\mu) K \mathrm{diag}(\mu),

shot noise (``N_e`` electrons at full scale), read noise ``r``, quantisation ``q^2 = 1 / (12 (2^n - 1)^2)``
and the multiplicative bead speckle of relative standard deviation ``s`` and correlation matrix ``K``.

How the speckle is treated
--------------------------
The renderer multiplies the image by ``1 + S``, ``S`` a zero-mean Gaussian field made by smoothing white
noise on a coarser grid and resizing it up bilinearly: separable and linear in the white noise, so its
covariance is known exactly (:func:`softjig.sensing.subpixel.speckle_correlation_1d`) up to the grid's
phase, over which it is averaged (a marker falls at any phase; the mixture is a valid covariance). To
first order in ``s`` the speckle on a pixel is ``mu_k S_k``: Gaussian, zero mean, covariance
``s^2 mu_k mu_l K_kl``. This *correlated* covariance gives the honest bound (``speckle_correlated=True``,
the default); treating the speckle as white (``False``) understates how much it can mimic a shift of the
marker and gives a lower, unreachable bound. Correlated speckle of a few pixels' correlation length
looks like a slightly displaced marker edge, so it costs more centre information than white noise of
the same variance.

Fisher information
------------------
For Gaussian data with mean ``mu(theta)`` and covariance ``C(theta)``:

.. math:: J_{ij} = \partial_i\mu^T C^{-1} \partial_j\mu
                   + \tfrac12 \mathrm{tr}(C^{-1}\partial_i C\, C^{-1} \partial_j C).

The second term (information carried by how the noise's *variance* moves with the marker) is included
with ``covariance_term=True``; it is small here (a few percent of the bound at most) because the
speckle's and the shot noise's variance change smoothly across the marker. The bound on the centre is
``sqrt(J^{-1}_{uu} + J^{-1}_{vv})``: the 2-D RMS error of any unbiased estimator, in px.

The bound ignores what no centre estimator can fix from one marker's pixels: the hemisphere's
asymmetric image when seen obliquely (a bias, see :mod:`softjig.sim.render`), the blur and size
varying across the image, and the illumination fall-off (pass the local amplitude in the model).
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import scipy.linalg

from softjig.errors import InputError
from softjig.sensing.subpixel import MarkerModel, marker_profile, noise_covariance

__all__ = ["bound_window_half_width", "centre_crb_px", "fisher_information"]


def bound_window_half_width(model: MarkerModel) -> int:
    """Half-width (px) of a window that holds all of the marker's information: ``ceil(R + 4 b) + 2``."""
    return math.ceil(model.radius_px + 4.0 * model.blur_px) + 2


def fisher_information(
    model: MarkerModel,
    offset_px: tuple[float, float] = (0.0, 0.0),
    *,
    half_width_px: int | None = None,
    speckle_correlated: bool = True,
    covariance_term: bool = True,
) -> np.ndarray:
    """Fisher information of ``(u, v, A, B)`` from one marker's window.

    Parameters
    ----------
    model : the marker and its noise (:class:`~softjig.sensing.subpixel.MarkerModel`); ``amplitude``
        and ``background`` are the true ``A`` and ``B`` (fractions of full scale).
    offset_px : the marker centre's sub-pixel offset ``(du, dv)`` from the window's central pixel.
    half_width_px : the window is ``2 h + 1`` px square; default :func:`bound_window_half_width`
        (everything the marker shows). Pass ``model.half_width_px`` for the bound of a fit in that window.
    speckle_correlated : use the speckle's correlation (the honest bound) or treat it as white.
    covariance_term : include the information in the covariance's dependence on ``theta``.

    Returns
    -------
    (4, 4) float64 in units of ``px^-2`` (centre), ``(full scale)^-2`` (``A``, ``B``) and mixed.
    """
    h = bound_window_half_width(model) if half_width_px is None else int(half_width_px)
    if h < 2:
        raise InputError(f"half_width_px must be >= 2, got {h}.")
    m = replace(model, half_width_px=h)
    du, dv = (float(x) for x in offset_px)
    f, fu, fv = (a[0].ravel() for a in marker_profile(m, np.array([[du, dv]]), derivatives=True))
    a, b = model.amplitude, model.background
    mu = b + a * f
    dmu = np.column_stack([a * fu, a * fv, f, np.ones_like(f)])  # d mu / d(u, v, A, B)
    cov = noise_covariance(m, mu, speckle_correlated=speckle_correlated)
    chol = scipy.linalg.cho_factor(cov, lower=True)
    info = dmu.T @ scipy.linalg.cho_solve(chol, dmu)
    if covariance_term:
        # dC/dtheta_i = diag(dmu_i) (white part: shot noise) + s^2 (diag(dmu_i) K diag(mu) + transpose)
        shot = 0.0 if math.isinf(model.full_well) else 1.0 / model.full_well
        speckle = noise_covariance(m, mu, speckle_correlated=speckle_correlated) - noise_covariance(
            replace(m, speckle_std=0.0), mu
        )
        safe_mu = np.where(np.abs(mu) > 1e-12, mu, 1e-12)
        kmat = speckle / np.outer(safe_mu, safe_mu)  # s^2 K
        inv_dc = []
        for i in range(4):
            d = dmu[:, i]
            dc = np.diag(d * shot) + kmat * (np.outer(d, mu) + np.outer(mu, d))
            inv_dc.append(scipy.linalg.cho_solve(chol, dc))
        for i in range(4):
            for j in range(i, 4):
                extra = 0.5 * float(np.sum(inv_dc[i] * inv_dc[j].T))
                info[i, j] += extra
                if j != i:
                    info[j, i] += extra
    return info


def centre_crb_px(
    model: MarkerModel,
    offset_px: tuple[float, float] = (0.0, 0.0),
    *,
    half_width_px: int | None = None,
    speckle_correlated: bool = True,
    covariance_term: bool = True,
) -> float:
    """Cramer-Rao bound of the marker centre: 2-D RMS error ``sqrt(var u + var v)`` in px.

    Parameters are those of :func:`fisher_information`; amplitude and background are estimated jointly
    (nuisance parameters).

    Examples
    --------
    A Gaussian-like blob in white noise (no speckle, no shot noise): the bound scales as noise / amplitude.

    >>> m = MarkerModel(radius_px=6.0, blur_px=2.0, speckle_std=0.0, full_well=math.inf, read_noise=0.01)
    >>> b1 = centre_crb_px(m)
    >>> b2 = centre_crb_px(replace(m, read_noise=0.02))
    >>> round(b2 / b1, 2)
    2.0
    """
    info = fisher_information(
        model,
        offset_px,
        half_width_px=half_width_px,
        speckle_correlated=speckle_correlated,
        covariance_term=covariance_term,
    )
    inv = np.linalg.inv(info)
    return float(math.sqrt(inv[0, 0] + inv[1, 1]))
