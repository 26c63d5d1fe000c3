"""Tests of softjig.evaluation.cramer_rao against Monte-Carlo runs of an efficient estimator."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from numpy.testing import assert_allclose

from softjig.evaluation.cramer_rao import bound_window_half_width, centre_crb_px, fisher_information
from softjig.sensing.subpixel import MarkerModel, marker_profile, noise_covariance, refine_centres

OFFSET = np.array([0.1, -0.15])


def monte_carlo_rmse(model: MarkerModel, n_markers: int, seed: int) -> float:
    """2-D RMS error of the prewhitened fit over markers whose windows carry noise of exactly the
    model's covariance (windows side by side, each with its own draw)."""
    rng = np.random.default_rng(seed)
    n = model.size_px
    mu = (model.background + model.amplitude * marker_profile(model, OFFSET[None])[0]).ravel()
    chol = np.linalg.cholesky(noise_covariance(model, mu))
    noise = (chol @ rng.standard_normal((n * n, n_markers))).T.reshape(n_markers, n, n)
    image = (mu.reshape(n, n)[None] + noise).reshape(n_markers * n, n).astype(np.float32)
    truth = np.column_stack([np.full(n_markers, n // 2), np.arange(n_markers) * n + n // 2]) + OFFSET
    fit = refine_centres(image, truth, model)
    assert fit.ok.mean() > 0.99
    return float(np.sqrt(np.mean(np.sum((fit.xy_px - truth) ** 2, axis=1))))


def test_white_noise_blob_ml_estimator_reaches_the_bound():
    # White Gaussian noise, no speckle, no shot noise: the fit is the ML estimator, efficient here.
    model = MarkerModel(
        radius_px=6.0, blur_px=2.0, speckle_std=0.0, full_well=math.inf, read_noise=0.04, half_width_px=8
    )
    bound = centre_crb_px(model, tuple(OFFSET), half_width_px=model.half_width_px)
    rmse = monte_carlo_rmse(model, 3000, seed=0)
    print(f"white noise: Monte-Carlo RMSE {rmse:.4f} px, bound {bound:.4f} px")
    assert 0.05 < bound < 0.2
    assert rmse == pytest.approx(bound, rel=0.08)


def test_correlated_speckle_prewhitened_fit_reaches_the_bound():
    # The simulator's noise (correlated multiplicative speckle, shot, read), drawn from its covariance.
    model = MarkerModel(radius_px=8.0, blur_px=3.1, half_width_px=10)
    bound = centre_crb_px(model, tuple(OFFSET), half_width_px=model.half_width_px, covariance_term=False)
    rmse = monte_carlo_rmse(model, 3000, seed=1)
    print(f"correlated speckle: Monte-Carlo RMSE {rmse:.4f} px, bound {bound:.4f} px")
    assert rmse == pytest.approx(bound, rel=0.08)


def test_bound_scaling_and_treatment_of_the_speckle():
    white = MarkerModel(radius_px=6.0, blur_px=2.0, speckle_std=0.0, full_well=math.inf, read_noise=0.01)
    b1 = centre_crb_px(white, half_width_px=10)
    assert_allclose(centre_crb_px(replace(white, read_noise=0.02), half_width_px=10), 2 * b1, rtol=0.01)
    assert_allclose(
        centre_crb_px(replace(white, amplitude=2 * white.amplitude), half_width_px=10), b1 / 2, rtol=0.02
    )
    model = MarkerModel(radius_px=8.0, blur_px=3.1)
    correlated = centre_crb_px(model, half_width_px=12)
    as_white = centre_crb_px(model, half_width_px=12, speckle_correlated=False)
    no_speckle = centre_crb_px(replace(model, speckle_std=0.0), half_width_px=12)
    # measured: 0.137, 0.034, 0.025 px: correlated speckle mimics a shifted edge
    assert correlated > 3 * as_white > 3 * no_speckle
    assert_allclose(centre_crb_px(model, half_width_px=12, covariance_term=False), correlated, rtol=0.03)
    # a larger window never holds less information
    assert centre_crb_px(model, half_width_px=8) > centre_crb_px(model, half_width_px=10) > correlated


def test_fisher_information_is_symmetric_positive_definite():
    model = MarkerModel(radius_px=8.0, blur_px=3.1)
    info = fisher_information(model, (0.3, 0.2), half_width_px=10)
    assert info.shape == (4, 4)
    assert_allclose(info, info.T, rtol=1e-10)
    assert np.linalg.eigvalsh(info).min() > 0
    assert bound_window_half_width(model) == math.ceil(8.0 + 4 * 3.1) + 2
