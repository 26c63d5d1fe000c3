"""Tests of softjig.sensing.detect on synthetic marker images rendered here.

The renderer below is deliberately independent of softjig.sim: sharp discs at known
sub-pixel centres are rendered by supersampling, blurred by a Gaussian, put on a dark
background and corrupted by bead speckle (Gaussian-correlated texture) and camera noise
from a seeded generator, then quantised.

Nominal imaging (the jig's cameras): marker diameter 15 px, blur sigma 3 px, contrast
120/255 over a background of 20/255, camera noise sigma 3/255, speckle std 10/255 with a
correlation length of 1 px, markers on a 40 px grid.
"""

from __future__ import annotations

import math
import re

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from numpy.testing import assert_allclose, assert_array_equal
from scipy.spatial import cKDTree

from softjig.errors import InputError
from softjig.sensing._detect_kernels import coarse_peaks
from softjig.sensing.detect import (  # the compiled peak scan against the NumPy path
    _FIT_PINV,
    _MAX_REFINE_OFFSET_PX,
    DEFAULT_THRESHOLD,
    Markers,
    _coarse_blur,
    _refine_quadratic,
    check_image_content,
    detect_markers,
    gray_image,
    log_sigma_px,
    point_asymmetry,
    to_gray_float,
)

FRAME = (720, 1280)
DIAMETER_PX = 15.0
BLUR_PX = 3.0
SIGMA_PX = log_sigma_px(DIAMETER_PX, blur_sigma_px=BLUR_PX)


def render_markers(
    shape: tuple[int, int],
    centres_xy: np.ndarray,
    *,
    diameter_px: float = DIAMETER_PX,
    blur_sigma_px: float = BLUR_PX,
    background: float = 20 / 255,
    contrast: float = 120 / 255,
    noise_sigma: float = 3 / 255,
    speckle_sigma: float = 10 / 255,
    speckle_corr_px: float = 1.0,
    supersample: int = 8,
    seed: int = 0,
) -> np.ndarray:
    """Float image in [0, 1] (unclipped, unquantised) of bright discs at ``centres_xy``."""
    h, w = shape
    rng = np.random.default_rng(seed)
    radius = diameter_px / 2
    discs = np.zeros(shape)
    sub = (np.arange(supersample) + 0.5) / supersample - 0.5  # sample offsets in a pixel
    half = int(np.ceil(radius)) + 1
    for u, v in np.asarray(centres_xy, dtype=float).reshape(-1, 2):
        u0, v0 = round(u), round(v)
        cols = np.arange(u0 - half, u0 + half + 1)
        rows = np.arange(v0 - half, v0 + half + 1)
        du = (cols[:, None] + sub - u).ravel()
        dv = (rows[:, None] + sub - v).ravel()
        inside = dv[:, None] ** 2 + du[None, :] ** 2 <= radius**2
        coverage = inside.reshape(len(rows), supersample, len(cols), supersample).mean(axis=(1, 3))
        r_ok = (rows >= 0) & (rows < h)
        c_ok = (cols >= 0) & (cols < w)
        discs[np.ix_(rows[r_ok], cols[c_ok])] += coverage[np.ix_(r_ok, c_ok)]
    if blur_sigma_px > 0:
        discs = cv2.GaussianBlur(discs, (0, 0), blur_sigma_px, borderType=cv2.BORDER_REFLECT)
    image = background + contrast * discs
    if speckle_sigma > 0:
        speckle = cv2.GaussianBlur(rng.standard_normal(shape), (0, 0), speckle_corr_px)
        image += speckle_sigma * speckle / speckle.std()
    if noise_sigma > 0:
        image += noise_sigma * rng.standard_normal(shape)
    return image


def quantise(image: np.ndarray, dtype: type = np.uint8) -> np.ndarray:
    full = np.iinfo(dtype).max
    return np.clip(np.rint(image * full), 0, full).astype(dtype)


def marker_grid(
    shape: tuple[int, int], *, pitch_px: float = 40.0, margin_px: float = 30.0, seed: int = 1
) -> np.ndarray:
    """Grid of centres with uniform sub-pixel offsets in [-0.5, 0.5) px."""
    h, w = shape
    u, v = np.meshgrid(
        np.arange(margin_px, w - margin_px, pitch_px), np.arange(margin_px, h - margin_px, pitch_px)
    )
    xy = np.column_stack([u.ravel(), v.ravel()])
    return xy + np.random.default_rng(seed).uniform(-0.5, 0.5, xy.shape)


def associate(truth: np.ndarray, found: np.ndarray, radius_px: float) -> tuple[np.ndarray, int]:
    """Errors of the true markers found within ``radius_px``, and the number of extras."""
    dist, idx = cKDTree(found).query(truth, distance_upper_bound=radius_px)
    hit = np.isfinite(dist)
    assert len(np.unique(idx[hit])) == hit.sum(), "one detection claimed by two markers"
    return dist[hit], len(found) - int(hit.sum())


@pytest.fixture(scope="module")
def nominal_frame() -> tuple[np.ndarray, np.ndarray]:
    truth = marker_grid(FRAME)
    return truth, quantise(render_markers(FRAME, truth, seed=2))


# ---------------------------------------------------------------------------------------
# Detection and accuracy


@pytest.mark.accuracy
def test_nominal_grid_full_recall_no_false_positives(nominal_frame):
    truth, image = nominal_frame
    markers = detect_markers(image, sigma_px=SIGMA_PX)
    errors, extras = associate(truth, markers.xy_px, radius_px=2.0)
    assert len(errors) == len(truth) == 527
    assert extras == 0
    assert markers.xy_px.dtype == np.float64
    assert markers.sigma_px == SIGMA_PX
    assert np.all(np.diff(markers.response) <= 0), "sorted by decreasing response"


@pytest.mark.parametrize(("refine", "limit"), [("quadratic", 0.05), ("model", 0.07)])
def test_subpixel_rmse_camera_noise_only(refine, limit):
    # Measured: quadratic 0.032 px RMS, 0.09 px max (0.005 px RMS without any noise: the bias of
    # the 3x3 quadratic fit and the uint8 quantisation). The model fit assumes the jig's shaded
    # hemispheres and its speckle, not these flat discs in white noise: 0.052 px.
    truth = marker_grid(FRAME, seed=3)
    image = quantise(render_markers(FRAME, truth, speckle_sigma=0.0, seed=3))
    errors, extras = associate(truth, detect_markers(image, sigma_px=SIGMA_PX, refine=refine).xy_px, 1.0)
    rmse = float(np.sqrt(np.mean(errors**2)))
    print(f"sub-pixel RMSE, camera noise only, {refine}: {rmse:.4f} px")
    assert len(errors) == len(truth) and extras == 0
    assert rmse < limit


@pytest.mark.accuracy
def test_subpixel_rmse_nominal_speckle(nominal_frame):
    # Measured: 0.37 px RMS on this frame (0.35 px over 4 seeds). Bead speckle of std
    # 10/255 dominates the error: it shifts the LoG peak itself, whatever the refinement.
    truth, image = nominal_frame
    errors, _ = associate(truth, detect_markers(image, sigma_px=SIGMA_PX).xy_px, 2.0)
    rmse = float(np.sqrt(np.mean(errors**2)))
    print(f"sub-pixel RMSE, nominal speckle: {rmse:.3f} px")
    assert rmse < 0.5


@pytest.mark.parametrize(("refine", "limit"), [("quadratic", 0.01), ("model", 0.03)])
def test_noise_free_subpixel_bias_is_tiny(refine, limit):
    # The model fit's 0.023 px here is its template's mismatch to these flat discs (on the
    # simulator's own markers it is below 0.005 px: tests/test_subpixel.py).
    truth = marker_grid((240, 320), seed=4)
    image = quantise(render_markers((240, 320), truth, speckle_sigma=0, noise_sigma=0), np.uint16)
    errors, _ = associate(truth, detect_markers(image, sigma_px=SIGMA_PX, refine=refine).xy_px, 1.0)
    assert len(errors) == len(truth)
    assert np.sqrt(np.mean(errors**2)) < limit


def test_quadratic_refinement_beats_integer_peaks():
    truth = marker_grid((360, 640), seed=5)
    image = quantise(render_markers((360, 640), truth, speckle_sigma=0, seed=5))
    refined, _ = associate(truth, detect_markers(image, sigma_px=SIGMA_PX).xy_px, 1.5)
    integer = detect_markers(image, sigma_px=SIGMA_PX, refine=None)
    assert_array_equal(integer.xy_px, np.rint(integer.xy_px))
    whole, _ = associate(truth, integer.xy_px, 1.5)
    assert np.sqrt(np.mean(refined**2)) < 0.2 * np.sqrt(np.mean(whole**2))


@pytest.mark.accuracy
@settings(max_examples=60, deadline=None)
@given(
    u=st.floats(30.0, 34.0),
    v=st.floats(30.0, 34.0),
    contrast=st.floats(0.2, 0.8),
)
def test_single_blob_found_within_a_tenth_of_a_pixel(u, v, contrast):
    image = quantise(
        render_markers((64, 64), np.array([[u, v]]), contrast=contrast, speckle_sigma=0, noise_sigma=0)
    )
    markers = detect_markers(image, sigma_px=SIGMA_PX)
    assert len(markers) == 1
    assert np.hypot(*(markers.xy_px[0] - [u, v])) < 0.1


@pytest.mark.parametrize("candidates", ["full", "pyramid"])
@pytest.mark.parametrize(("refine", "atol"), [("quadratic", 0.02), ("model", 0.04)])
def test_blob_between_pixels_gives_one_detection(candidates, refine, atol):
    # Symmetric about a pixel corner: equal responses on the 2x2 central pixels.
    image = quantise(render_markers((64, 64), np.array([[31.5, 31.5]]), speckle_sigma=0, noise_sigma=0))
    markers = detect_markers(image, sigma_px=SIGMA_PX, candidates=candidates, refine=refine)
    assert len(markers) == 1
    assert_allclose(markers.xy_px[0], [31.5, 31.5], atol=atol)


def test_two_close_markers_resolved():
    truth = np.array([[40.0, 40.0], [40.0 + 16.5, 40.3]])  # ~ one diameter apart
    image = quantise(render_markers((80, 100), truth, speckle_sigma=0, noise_sigma=0))
    markers = detect_markers(image, sigma_px=SIGMA_PX)
    errors, extras = associate(truth, markers.xy_px, 1.0)
    assert len(errors) == 2 and extras == 0


def test_border_excludes_cut_markers():
    truth = np.array([[3.0, 50.0], [50.0, 50.0]])
    image = quantise(render_markers((100, 100), truth, speckle_sigma=0, noise_sigma=0))
    markers = detect_markers(image, sigma_px=SIGMA_PX)
    assert len(markers) == 1
    assert_allclose(markers.xy_px[0], [50.0, 50.0], atol=0.05)


def test_border_is_tested_on_fitted_centres_so_both_candidate_paths_keep_the_same_markers():
    """Markers straddling the border margin: the pyramid's and the full LoG's candidates lie on either
    side of it for some, their model fits do not."""
    sigma = SIGMA_PX
    border = math.ceil(math.sqrt(2.0) * sigma)
    v = border + np.linspace(-1.0, 1.0, 9)  # fitted centres on both sides of the margin
    truth = np.column_stack([40.0 + 30.0 * np.arange(9), v])
    image = quantise(render_markers((80, 300), truth, seed=3))
    found = [detect_markers(image, sigma_px=sigma, candidates=c).xy_px for c in ("pyramid", "full")]
    assert len(found[0]) == len(found[1]) > 0
    assert_allclose(np.sort(found[0], axis=0), np.sort(found[1], axis=0), atol=1e-9)
    assert np.all(np.floor(found[0][:, 1] + 0.5) >= border)


@pytest.mark.smoke
def test_full_frame_finds_every_marker_near_its_truth():
    # (its time is benchmarks/suite.py's, not a test's)
    truth = marker_grid(FRAME, pitch_px=46.0, margin_px=25.0)
    image = quantise(render_markers(FRAME, truth, seed=6))
    markers = detect_markers(image, sigma_px=SIGMA_PX)
    errors, extras = associate(truth, markers.xy_px, 2.0)
    assert len(errors) == len(truth) and extras == 0


# ---------------------------------------------------------------------------------------
# Response scale and threshold


@pytest.mark.parametrize("sigma", [3.0, 5.5, 8.0])
def test_response_of_gaussian_blob_is_half_its_amplitude(sigma):
    # R(centre) = 2 A sigma^2 s^2 / (sigma^2 + s^2)^2 = A / 2 at sigma = s.
    n = int(12 * sigma) | 1
    y, x = np.mgrid[:n, :n] - n // 2
    amplitude = 0.5
    image = 0.1 + amplitude * np.exp(-(x**2 + y**2) / (2 * sigma**2))
    markers = detect_markers(quantise(image, np.uint16), sigma_px=sigma, border_px=1, candidates="full")
    assert len(markers) == 1
    assert_allclose(markers.response[0], amplitude / 2, rtol=1.0 / (8 * sigma**2) + 0.005)
    # the pyramid's coarse response: 1-3.5 % low (measured)
    coarse = detect_markers(quantise(image, np.uint16), sigma_px=sigma, border_px=1)
    assert_allclose(coarse.response[0], amplitude / 2, rtol=0.04)


def test_response_of_blurred_disc_matches_formula():
    contrast = 0.4
    image = render_markers(
        (101, 101),
        np.array([[50.3, 50.6]]),
        contrast=contrast,
        speckle_sigma=0,
        noise_sigma=0,
        supersample=16,
    )
    markers = detect_markers(quantise(image, np.uint16), sigma_px=SIGMA_PX, candidates="full")
    rho2, t = (DIAMETER_PX / 2) ** 2, SIGMA_PX**2 + BLUR_PX**2
    expected = contrast * rho2 * SIGMA_PX**2 / t**2 * np.exp(-rho2 / (2 * t))
    assert_allclose(expected / contrast, 0.540, atol=5e-4)
    assert_allclose(markers.response[0], expected, rtol=0.02)


def test_default_threshold_keeps_faint_markers_and_rejects_speckle():
    assert DEFAULT_THRESHOLD == 0.05
    truth = marker_grid(FRAME, seed=7)
    faint = quantise(render_markers(FRAME, truth, contrast=0.15, seed=7))
    # Speckle shifts faint markers by up to ~3.5 px (about 1 px RMS), but none is lost.
    errors, extras = associate(truth, detect_markers(faint, sigma_px=SIGMA_PX).xy_px, 6.0)
    assert len(errors) == len(truth) and extras == 0
    for seed in range(3):
        background = quantise(render_markers(FRAME, np.empty((0, 2)), seed=10 + seed))
        assert len(detect_markers(background, sigma_px=SIGMA_PX)) == 0


@pytest.mark.shapes
def test_empty_result_on_dark_noisy_image():
    rng = np.random.default_rng(8)
    image = quantise(20 / 255 + 3 / 255 * rng.standard_normal(FRAME))
    markers = detect_markers(image, sigma_px=SIGMA_PX)
    assert len(markers) == 0
    assert markers.xy_px.shape == (0, 2)
    assert markers.response.shape == (0,)


def test_threshold_is_dtype_independent():
    # The same scene quantised independently to 8 and to 16 bits.
    truth = marker_grid((240, 320), seed=9)
    scene = render_markers((240, 320), truth, contrast=0.15, speckle_sigma=0, seed=9)
    for kwargs, max_dist in (({"candidates": "full", "refine": "quadratic"}, 0.05), ({}, 0.25)):
        m8 = detect_markers(quantise(scene, np.uint8), sigma_px=SIGMA_PX, **kwargs)
        m16 = detect_markers(quantise(scene, np.uint16), sigma_px=SIGMA_PX, **kwargs)
        assert len(m8) == len(m16) == len(truth)
        dist, partner = cKDTree(m16.xy_px).query(m8.xy_px)
        assert_array_equal(np.sort(partner), np.arange(len(m16)))
        # The model fit's window moves with the estimate: at contrast 0.15 the 8-bit rounding can
        # move a faint marker's window by a pixel (a different noise sample, ~0.1 px). Measured:
        # median 0.006 px.
        assert dist.max() < max_dist
        assert np.median(dist) < 0.02
        assert_allclose(m8.response, m16.response[partner], rtol=0.01 if kwargs else 0.03)


# ---------------------------------------------------------------------------------------
# Image formats


def test_uint8_and_uint16_versions_give_identical_results(nominal_frame):
    _, image8 = nominal_frame
    image16 = image8.astype(np.uint16) * 257
    assert_array_equal(to_gray_float(image8), to_gray_float(image16))
    m8 = detect_markers(image8, sigma_px=SIGMA_PX, candidates="full", refine="quadratic")
    m16 = detect_markers(image16, sigma_px=SIGMA_PX, candidates="full", refine="quadratic")
    assert_allclose(m16.xy_px, m8.xy_px, rtol=0, atol=1e-6)
    assert_allclose(m16.response, m8.response, rtol=0, atol=1e-9)
    # The pyramid averages in the image's dtype (8-bit rounding of the coarse level): the same
    # markers, the same fitted centres (the fit reads the full-resolution pixels), responses to 1e-3.
    m8 = detect_markers(image8, sigma_px=SIGMA_PX)
    m16 = detect_markers(image16, sigma_px=SIGMA_PX)
    dist, partner = cKDTree(m16.xy_px).query(m8.xy_px)
    assert_array_equal(np.sort(partner), np.arange(len(m16)))
    assert dist.max() < 1e-4
    assert_allclose(m16.response[partner], m8.response, rtol=0, atol=2e-3)


def test_float_input_is_the_converted_image(nominal_frame):
    _, image8 = nominal_frame
    kwargs = {"candidates": "full", "refine": "quadratic"}
    direct = detect_markers(image8, sigma_px=SIGMA_PX, **kwargs)
    converted = detect_markers(to_gray_float(image8), sigma_px=SIGMA_PX, **kwargs)
    assert_array_equal(converted.xy_px, direct.xy_px)
    assert_array_equal(converted.response, direct.response)
    direct = detect_markers(image8, sigma_px=SIGMA_PX)
    converted = detect_markers(to_gray_float(image8), sigma_px=SIGMA_PX)
    dist, partner = cKDTree(converted.xy_px).query(direct.xy_px)
    assert_array_equal(np.sort(partner), np.arange(len(converted)))
    assert dist.max() < 1e-4


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
def test_gray_and_rgb_give_identical_results(nominal_frame, dtype):
    _, image8 = nominal_frame
    gray = image8.astype(dtype) * (257 if dtype == np.uint16 else 1)
    rgb = np.repeat(gray[:, :, None], 3, axis=2)
    m_gray = detect_markers(gray, sigma_px=SIGMA_PX)
    m_rgb = detect_markers(rgb, sigma_px=SIGMA_PX)
    assert_allclose(m_rgb.xy_px, m_gray.xy_px, rtol=0, atol=1e-6)


def test_to_gray_float_scaling_and_rgb_weights():
    gray8 = np.array([[0, 51, 255]], np.uint8)
    assert_array_equal(to_gray_float(gray8), np.array([[0.0, 0.2, 1.0]], np.float32))
    assert to_gray_float(gray8).dtype == np.float32
    assert to_gray_float(np.array([[65535]], np.uint16))[0, 0] == 1.0
    red = np.zeros((1, 1, 3), np.uint8)
    red[..., 0] = 200  # RGB order: channel 0 is red
    assert_allclose(to_gray_float(red)[0, 0], round(0.299 * 200) / 255, atol=1e-7)
    gray = to_gray_float(gray8)
    assert to_gray_float(gray) is gray, "float32 gray passes through"
    assert_array_equal(to_gray_float(gray.astype(np.float64)), gray)
    assert_allclose(to_gray_float(np.full((2, 2, 3), 0.5)), 0.5, rtol=1e-6)
    non_contiguous = np.zeros((10, 10), np.uint8)[:, ::2]
    assert to_gray_float(non_contiguous).shape == (10, 5)


# ---------------------------------------------------------------------------------------
# Errors


@pytest.mark.exceptions
@pytest.mark.parametrize(
    ("image", "words"),
    [
        (np.zeros(10, np.uint8), "shape"),
        (np.zeros((4, 4, 4), np.uint8), "RGB"),
        (np.zeros((4, 4, 1), np.uint8), "(H, W, 3)"),
        (np.zeros((2, 4, 4, 3), np.uint8), "shape"),
        (np.full((4, 4), 2.0, np.float32), "scaled to [0, 1], got values in [2.0, 2.0]"),
        (np.full((4, 4, 3), np.nan), "scaled to [0, 1]"),
        (np.zeros((4, 4), np.float16), "uint8 and uint16"),
        (np.zeros((4, 4), np.int32), "uint8 and uint16"),
        (np.zeros((4, 4), bool), "uint8 and uint16"),
        (np.zeros((0, 0), np.uint8), "empty"),
        (np.zeros((0, 5, 3), np.uint16), "empty"),
        (None, "shape"),
    ],
)
def test_to_gray_float_rejects_bad_images(image, words):
    with pytest.raises(InputError, match=re.escape(words)):
        to_gray_float(image)
    with pytest.raises(InputError):
        detect_markers(image, sigma_px=SIGMA_PX)


def test_input_error_is_a_value_error():
    with pytest.raises(ValueError):
        to_gray_float(np.zeros((4, 4), np.int64))


def test_check_image_content():
    rng = np.random.default_rng(0)
    check_image_content(to_gray_float(quantise(0.1 + 0.02 * rng.standard_normal((50, 50)))))
    with pytest.raises(InputError, match=r"the left image is blank: .*lighting/exposure"):
        check_image_content(to_gray_float(np.full((50, 50), 20, np.uint8)), name="the left image")
    saturated = np.full((50, 50), 255, np.uint8)
    saturated[:20] = 100
    with pytest.raises(InputError, match=r"the right image is saturated: 6[0-9]%.*exposure"):
        check_image_content(to_gray_float(saturated), name="the right image")
    # integer images are checked in their own scale
    with pytest.raises(InputError, match="blank"):
        check_image_content(np.full((50, 50), 20, np.uint8))
    with pytest.raises(InputError, match="saturated"):
        check_image_content(saturated.astype(np.uint16) * 257)
    check_image_content(quantise(0.1 + 0.02 * rng.standard_normal((50, 50)), np.uint16))
    with pytest.raises(InputError, match="to_gray_float"):
        check_image_content(np.zeros((5, 5), np.int32))
    with pytest.raises(InputError, match="to_gray_float"):
        check_image_content(np.zeros((5, 5, 3), np.uint8))


@pytest.mark.exceptions
@pytest.mark.parametrize(
    ("kwargs", "words"),
    [
        ({"sigma_px": 0.0}, "sigma_px must be > 0"),
        ({"sigma_px": float("nan")}, "sigma_px must be finite"),
        ({"sigma_px": "big"}, "sigma_px must be a number"),
        ({"sigma_px": 5.0, "threshold": -0.1}, "threshold must be >= 0"),
        ({"sigma_px": 5.0, "min_distance_px": 0.5}, "min_distance_px must be >= 1"),
        ({"sigma_px": 5.0, "border_px": -1}, "border_px must be >= 0"),
        ({"sigma_px": 5.0, "border_px": 2.5}, "border_px must be an integer"),
        ({"sigma_px": 5.0, "refine": "gaussian"}, "'model', 'quadratic' and None"),
        ({"sigma_px": 5.0, "candidates": "dog"}, "'pyramid' and 'full'"),
        ({"sigma_px": 5.0, "model": "big"}, "MarkerModel"),
    ],
)
def test_detect_markers_rejects_bad_parameters(kwargs, words):
    with pytest.raises(InputError, match=words):
        detect_markers(np.zeros((32, 32), np.uint8), **kwargs)


def test_log_sigma_px():
    assert_allclose(log_sigma_px(15.0), 7.5 / np.sqrt(2))
    assert_allclose(log_sigma_px(15.0, blur_sigma_px=3.0), 5.546, atol=1e-3)
    with pytest.raises(InputError, match="marker_diameter_px must be > 0"):
        log_sigma_px(0.0)
    with pytest.raises(InputError, match="blur_sigma_px must be >= 0"):
        log_sigma_px(15.0, blur_sigma_px=-1.0)


def test_markers_is_immutable():
    markers = Markers(xy_px=[[1.0, 2.0]], response=[0.3], sigma_px=5)
    assert len(markers) == 1
    assert markers.xy_px.shape == (1, 2) and markers.xy_px.dtype == np.float64
    with pytest.raises(ValueError, match="read-only"):
        markers.xy_px[0, 0] = 3.0
    with pytest.raises(AttributeError):
        markers.sigma_px = 2.0  # type: ignore[misc]
    with pytest.raises(InputError, match="one response per marker"):
        Markers(xy_px=np.zeros((2, 2)), response=np.zeros(3), sigma_px=5.0)


def test_markers_asymmetry_is_one_per_marker_and_a_failed_fit_is_lopsided():
    markers = Markers(
        xy_px=np.zeros((5, 2)), response=np.ones(5), sigma_px=5.0, asymmetry=[0.03, np.nan, 0.02, 0.2, 0.04]
    )
    assert_array_equal(markers.lopsided(), [False, True, False, True, False])  # 0.2 > 3 x median 0.035
    with pytest.raises(ValueError, match="read-only"):
        markers.asymmetry[0] = 1.0
    assert not Markers(xy_px=np.zeros((2, 2)), response=np.ones(2), sigma_px=5.0).lopsided().any()
    with pytest.raises(InputError, match="one asymmetry per marker"):
        Markers(xy_px=np.zeros((2, 2)), response=np.ones(2), sigma_px=5.0, asymmetry=[0.1])


@pytest.mark.parametrize("speckle", [4 / 255, 10 / 255])
def test_a_glint_over_one_side_of_a_marker_makes_it_lopsided(speckle):
    """Markers are discs, point-symmetric about their centres to the noise and the speckle: none is
    lopsided. A saturated spot (a glint) over the rim of one marker pulls its fitted centre towards it
    by most of a pixel; that marker, and only it, is lopsided."""
    truth = marker_grid(FRAME)
    image = render_markers(FRAME, truth, seed=2, speckle_sigma=speckle)
    clean = detect_markers(quantise(image), sigma_px=SIGMA_PX)
    assert clean.asymmetry is not None and not clean.lopsided().any()
    k = len(truth) // 2
    rows, cols = np.mgrid[0 : FRAME[0], 0 : FRAME[1]]
    glint = np.exp(-((cols - truth[k, 0] - 6.0) ** 2 + (rows - truth[k, 1]) ** 2) / (2 * 1.5**2))
    markers = detect_markers(quantise(image + glint), sigma_px=SIGMA_PX)
    distance, nearest = cKDTree(markers.xy_px).query(truth[k])
    assert distance > 0.4  # pulled towards the glint
    assert np.flatnonzero(markers.lopsided()).tolist() == [nearest]


def test_point_asymmetry_of_a_clean_disc_is_small_and_unknown_without_an_amplitude():
    centres = np.array([[40.3, 30.6], [100.0, 30.0], [3.0, 3.0]])
    image = quantise(render_markers((64, 140), centres, noise_sigma=0.0, speckle_sigma=0.0))
    gray, full_scale = gray_image(image)
    contrast = 120 / 255
    asymmetry = point_asymmetry(
        gray, centres, [contrast, 0.0, contrast], radius_px=DIAMETER_PX / 2, full_scale=full_scale
    )
    assert asymmetry[0] < 0.02  # quantisation and interpolation only
    assert np.isnan(asymmetry[1])  # no amplitude
    assert np.isnan(asymmetry[2])  # most of the disc outside the image


@pytest.mark.parametrize(
    ("kwargs", "words"),
    [
        ({"amplitude": [0.5]}, "one amplitude per centre"),  # the loop would read past the array
        ({"radius_px": float("nan")}, "radius_px must be finite"),
        ({"radius_px": 0.0}, "radius_px must be > 0"),
        ({"full_scale": 0.0}, "full_scale must be > 0"),
        ({"gray": np.zeros((8, 8, 3), np.uint8)}, "gray (H, W) image"),
        ({"xy_px": np.zeros((3, 3))}, "(N, 2) centres"),
    ],
)
def test_point_asymmetry_refuses_inputs_its_loop_would_misread(kwargs, words):
    args = {
        "gray": np.zeros((64, 64), np.uint8),
        "xy_px": np.full((3, 2), 30.0),
        "amplitude": [0.5, 0.5, 0.5],
        "radius_px": 5.0,
        "full_scale": 255.0,
    } | kwargs
    gray, xy, amplitude = args.pop("gray"), args.pop("xy_px"), args.pop("amplitude")
    with pytest.raises(InputError, match=re.escape(words)):
        point_asymmetry(gray, xy, amplitude, **args)


# ---------------------------------------------------------------------------------------
# The fast path (pyramid candidates) against the straightforward one (full-resolution LoG)


@pytest.mark.agreement
@pytest.mark.parametrize("refine", ["model", "quadratic", None])
def test_pyramid_and_full_find_the_same_markers(nominal_frame, refine):
    truth, image = nominal_frame
    full = detect_markers(image, sigma_px=SIGMA_PX, candidates="full", refine=refine)
    fast = detect_markers(image, sigma_px=SIGMA_PX, candidates="pyramid", refine=refine)
    for markers in (full, fast):
        errors, extras = associate(truth, markers.xy_px, radius_px=2.0)
        assert len(errors) >= 0.99 * len(truth) and extras <= 0.01 * len(truth)
    dist, partner = cKDTree(full.xy_px).query(fast.xy_px)
    assert len(fast) == len(full)
    assert_array_equal(np.sort(partner), np.arange(len(full)))
    # The same refinement gives the same centres. The quadratic fit and the integer peaks use the
    # full-resolution LoG around each candidate (float32 products instead of cv2's blur: 0.002 px).
    # The model fit depends on its start only where the two starts round to different pixels near a
    # boundary whose windows fit the marker differently (here 4 of 527, whose flat disc and white speckle
    # do not match the model, up to 0.28 px; on the simulator's frames 9 of 4630, up to 0.08 px).
    if refine == "model":
        assert np.mean(dist < 1e-4) > 0.99
        assert dist.max() < 0.5
        assert_allclose(fast.response, full.response[partner], rtol=0.05)  # the coarse level's
    else:
        assert dist.max() < 0.005
        assert_allclose(fast.response, full.response[partner], rtol=1e-4)


def test_coarse_peaks_follow_their_rule():
    # The compiled scan of the pyramid against its documented rule, in plain Python, on a response with
    # exact plateaus (quantised values: ties between neighbours) and peaks next to the border.
    rng = np.random.default_rng(5)
    response = cv2.GaussianBlur(rng.normal(0.0, 1.0, (90, 160)).astype(np.float32), (0, 0), 1.5)
    response = np.round(response * 20.0) / np.float32(20.0)
    response[1, 40], response[45, 1] = 5.0, 5.0
    for half_width in (1, 2, 3):
        xy, peak = coarse_peaks(response, np.float32(0.05), half_width, _FIT_PINV, _MAX_REFINE_OFFSET_PX)
        rows, cols = [], []
        for r, c in zip(*np.nonzero(response[1:-1, 1:-1] > 0.05), strict=True):
            r, c = r + 1, c + 1
            top, left = max(r - half_width, 0), max(c - half_width, 0)
            win = response[top : r + half_width + 1, left : c + half_width + 1]
            first = np.flatnonzero(win.ravel() == win.max())[0]  # the first maximum in row-major order
            if response[r, c] == win.max() and first == np.ravel_multi_index((r - top, c - left), win.shape):
                rows.append(r)
                cols.append(c)
        rows, cols = np.array(rows), np.array(cols)
        offset, peak_fit, ok = _refine_quadratic(response, rows, cols)
        expected_xy = np.column_stack([cols, rows]).astype(np.float64)
        expected_xy[ok] += offset[ok]
        assert len(rows) > 20 and 0 < np.count_nonzero(ok) < len(rows) and {1, 45} <= set(rows)
        assert_allclose(xy, expected_xy, rtol=0, atol=1e-12)
        assert_allclose(peak, np.where(ok, peak_fit, response[rows, cols]), rtol=0, atol=1e-9)


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16, np.float32])
@pytest.mark.parametrize("sigma", [1.2, 1.447, 2.3])
def test_coarse_blur_is_cv2_gaussian_blur_of_the_float_copy(dtype, sigma):
    rng = np.random.default_rng(6)
    top = {np.uint8: 255, np.uint16: 65535, np.float32: 1}[dtype]
    small = (rng.uniform(0, 1, (180, 320)) * top).astype(dtype)
    expected = cv2.GaussianBlur(
        small.astype(np.float32), (0, 0), sigmaX=sigma, sigmaY=sigma, borderType=cv2.BORDER_REFLECT
    )
    assert_array_equal(_coarse_blur(small, sigma), expected)


def test_exclude_drops_candidates_before_refinement(nominal_frame):
    _, image = nominal_frame
    everything = detect_markers(image, sigma_px=SIGMA_PX)
    left_half = detect_markers(image, sigma_px=SIGMA_PX, exclude=lambda xy: xy[:, 0] > 640)
    assert 0 < len(left_half) < len(everything)
    assert np.all(left_half.xy_px[:, 0] <= 640 + 2.5)
    kept = everything.xy_px[everything.xy_px[:, 0] <= 630]
    dist, _ = cKDTree(left_half.xy_px).query(kept)
    assert dist.max() < 1e-9


@pytest.fixture(scope="module")
def default_pairs(default_scene):
    """The default pair and the benchmark's next two (the part turned 72 and 144 deg)."""
    from scenes import render_scene
    from softjig.sim.parts import PartPose

    turned = [
        render_scene(pose=PartPose(np.radians(10), np.radians(a), 3.0), seed=k)
        for k, a in ((1, 72), (2, 144))
    ]
    return default_scene.jig, [default_scene.pair, *(scene.pair for scene in turned)]


@pytest.mark.agreement
def test_pipeline_normals_fast_equal_straightforward(default_pairs):
    """The default estimator (pyramid candidates) against one whose detector takes the full-resolution
    LoG's, with the same refinement: plane normals within 0.05 deg (below 0.04 deg on the benchmark's 5
    pairs), and the two detectors do differ (the markers' pixels are not the same)."""
    from softjig.sensing.estimator import Estimator
    from softjig.sensing.setup import JigModel
    from softjig.sensing.stages import LogDetector

    jig, pairs = default_pairs
    model = JigModel.build(jig)
    assert model.setup.candidates == "pyramid" and model.setup.refine == "model"
    fast = Estimator(jig, model=model)
    full = Estimator(jig, model=model, detector=LogDetector.from_model(model, candidates="full"))
    differ = 0
    for pair in pairs:
        a, b = (e.estimate(pair.left, pair.right, part_diameter_mm=50) for e in (fast, full))
        angle = np.degrees(np.arccos(np.clip(np.dot(a.estimate.normal, b.estimate.normal), -1.0, 1.0)))
        assert angle < 0.05
        differ += not np.array_equal(a.left.xy_px, b.left.xy_px)
    assert differ > 0


def test_check_image_content_on_full_frames_reads_a_subsample_faithfully():
    """A 1280x720 frame is judged on a 1-in-64 subsample: the same verdicts as on every pixel."""
    rng = np.random.default_rng(1)
    frame = quantise(0.3 + 0.05 * rng.standard_normal((720, 1280)))
    check_image_content(frame)
    dark = np.full((720, 1280), 20, np.uint8)
    dark[::7, ::7] = 21  # varies, but by far less than 1e-3 of full scale on average
    with pytest.raises(InputError, match="blank"):
        check_image_content(dark)
    saturated = frame.copy()
    saturated[:400] = 255  # 56 % of the rows
    with pytest.raises(InputError, match=r"saturated: 5[5-7]%"):
        check_image_content(saturated)
    saturated[:300] = frame[:300]  # 42 %: overexposed in places, but usable
    check_image_content(saturated)
