"""Tests of the simulator's bead-pack image model: static speckle redrawn under the contact, per-marker
brightness, marker appearance, off-axis illumination, per-camera exposure and gain."""

from __future__ import annotations

from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace

import numpy as np
import pytest

from softjig.config import ConfigError, CylinderPart, JigConfig, default_jig, dumps_jig, exact_jig, loads_jig
from softjig.optics import project_points
from softjig.rig import distortion_of, flat_layers
from softjig.sim.asbuilt import nominal_as_built
from softjig.sim.parts import PartPose
from softjig.sim.render import bubbles_J, idealised, marker_brightness, render_pair
from softjig.sim.zoo import damaged_image_model

PART = CylinderPart(diameter_mm=50.0)
POSE = PartPose(alpha_rad=np.radians(10.0), theta_rad=np.radians(30.0), push_depth_mm=4.0)
TOP = 65535.0


def quiet_jig(**imaging) -> JigConfig:
    """No sensor noise, blur or fall-off, 16 bits, speckle on: every pixel is a deterministic function
    of the jig, the membrane's state and the frame's redrawn speckle."""
    jig = idealised(exact_jig(), blur=False, noise=False)
    return jig.replace(
        medium=replace(jig.medium, speckle_std=0.04),
        imaging=replace(
            jig.imaging,
            bit_depth=16,
            full_well_electrons=1e30,  # no shot noise at all (idealised leaves ~0.02 levels)
            illumination_falloff=0.0,
            exposure=(1.0, 1.0),
            gain=(1.0, 1.0),
            **imaging,
        ),
    )


def speckle_only_jig(jig: JigConfig) -> JigConfig:
    """Markers as dark as the membrane (to 1e-6): the image is the membrane's level times (1 + s)."""
    im = jig.imaging
    return jig.replace(imaging=replace(im, marker_level=im.background_level + 1e-6))


def test_defaults_are_the_realistic_model():
    jig = default_jig()
    assert jig.medium.speckle_static and jig.medium.speckle_std > 0
    assert 0 < jig.medium.speckle_redraw_fraction < 1
    assert jig.imaging.marker_brightness_spread > 0
    assert jig.imaging.marker_appearance == "hemisphere"
    assert jig.imaging.illumination_center != (0.0, 0.0)
    assert jig.imaging.exposure[0] != jig.imaging.exposure[1]
    assert jig.imaging.gain[0] != jig.imaging.gain[1]
    # a jig filled and kept well: no bubbles, glints or missing markers unless the config says so
    assert (jig.medium.bubbles, jig.imaging.glints, jig.imaging.missing_marker_fraction) == (0, 0, 0.0)
    assert loads_jig(dumps_jig(jig)) == jig
    assert loads_jig(dumps_jig(damaged_image_model(jig))) == damaged_image_model(jig)


@pytest.mark.parametrize(
    ("section", "field", "value"),
    [
        ("medium", "speckle_redraw_fraction", 1.5),
        ("medium", "speckle_redraw_displacement_mm", -0.1),
        ("medium", "speckle_seed", -1),
        ("imaging", "marker_brightness_spread", 0.9),
        ("imaging", "marker_brightness_seed", -3),
        ("imaging", "illumination_center", (1.5, 0.0)),
        ("imaging", "exposure", (1.0, 0.0)),
        ("imaging", "gain", (float("nan"), 1.0)),
        ("medium", "bubbles", -1),
        ("medium", "bubble_radius_mm", 0.0),
        ("imaging", "glints", 5000),
        ("imaging", "missing_marker_fraction", 0.7),
        # counts given in Python, where no parser checks their type: 2.5 bubbles would fail in the renderer
        ("medium", "bubbles", 2.5),
        ("imaging", "glints", True),
        ("medium", "speckle_seed", 1.5),
    ],
)
def test_image_model_validation_names_the_field(section, field, value):
    jig = default_jig()
    with pytest.raises(ConfigError, match=rf"{section}\.{field}"):
        jig.replace(**{section: replace(getattr(jig, section), **{field: value})})


def test_marker_appearance_must_be_known():
    text = dumps_jig(default_jig()).replace('marker_appearance = "hemisphere"', 'marker_appearance = "cube"')
    with pytest.raises(ConfigError, match=r"imaging\.marker_appearance"):
        loads_jig(text)


def _moved_pixels(pair_a, pair_b, moved: np.ndarray, reach_px: float, shape) -> np.ndarray:
    """Pixels of the left image within ``reach_px`` of any marker in ``moved`` (in either pair)."""
    h, w = shape
    yy, xx = np.mgrid[0:h, 0:w]
    near = np.zeros(shape, dtype=bool)
    for px in (pair_a.markers.left_px[moved], pair_b.markers.left_px[moved]):
        for u, v in px:
            near |= (xx - u) ** 2 + (yy - v) ** 2 < reach_px**2
    return near


def test_static_speckle_is_identical_away_from_the_contact():
    jig = quiet_jig()
    as_built = nominal_as_built(jig)
    ref = render_pair(as_built, rng=1)
    loaded = render_pair(as_built, PART, POSE, rng=2)
    moved = np.linalg.norm(loaded.markers.xyz_mm - ref.markers.xyz_mm, axis=1) > 1e-6
    assert moved.any()
    near = _moved_pixels(ref, loaded, moved, 60.0, ref.left.shape)
    away = ~near
    assert away.mean() > 0.1
    # every pixel away from a marker that moved is the same (the bead pack did not change there) ...
    assert np.array_equal(ref.left[away], loaded.left[away])
    # ... while a pack stirred between frames (the old model) changes everywhere
    stirred = nominal_as_built(jig.replace(medium=replace(jig.medium, speckle_static=False)))
    a, b = render_pair(stirred, rng=1), render_pair(stirred, PART, POSE, rng=2)
    assert np.mean(a.left[away] != b.left[away]) > 0.5


def test_static_speckle_depends_on_the_seed_and_the_camera():
    jig = speckle_only_jig(quiet_jig())
    a = render_pair(nominal_as_built(jig), rng=1)
    other = jig.replace(medium=replace(jig.medium, speckle_seed=5))
    b = render_pair(nominal_as_built(other), rng=1)
    bg = jig.imaging.background_level * TOP
    membrane = np.all([np.abs(im - bg) < 0.3 * bg for im in (a.left, b.left, a.right)], axis=0)
    sa = a.left[membrane].astype(float)
    assert np.corrcoef(sa, b.left[membrane].astype(float))[0, 1] < 0.1
    assert np.corrcoef(sa, a.right[membrane].astype(float))[0, 1] < 0.1


def _render_reference(jig: JigConfig) -> np.ndarray:
    return render_pair(nominal_as_built(jig), rng=123).left


def test_static_speckle_is_the_same_in_a_worker_process():
    jig = quiet_jig()
    here = _render_reference(jig)
    with ProcessPoolExecutor(max_workers=1) as pool:
        there = pool.submit(_render_reference, jig).result()
    assert np.array_equal(here, there)


@pytest.mark.parametrize("fraction", [0.3, 1.0])
def test_redrawn_fraction_under_the_contact(fraction):
    base = speckle_only_jig(quiet_jig())
    jig = base.replace(medium=replace(base.medium, speckle_redraw_fraction=fraction))
    as_built = nominal_as_built(jig)
    ref = render_pair(as_built, rng=1)
    loaded = render_pair(as_built, PART, POSE, rng=2)
    bg = jig.imaging.background_level * TOP
    s_ref, s_load = ref.left / bg - 1.0, loaded.left / bg - 1.0
    # deep inside the contact: within a pitch of markers in contact, far from those that are not moved
    contact = loaded.markers.in_contact & loaded.markers.visible_left
    inside = _moved_pixels(loaded, loaded, contact, 10.0, ref.left.shape)
    still = np.abs(loaded.markers.xyz_mm[:, 2] - ref.markers.xyz_mm[:, 2]) < 0.05
    inside &= ~_moved_pixels(ref, ref, still, 60.0, ref.left.shape)
    inside &= (ref.left > 0.5 * bg) & (ref.left < 1.5 * bg)  # not on a fiducial
    assert inside.sum() > 5000
    corr = np.corrcoef(s_ref[inside], s_load[inside])[0, 1]
    assert corr == pytest.approx(1.0 - fraction, abs=0.08)
    # the texture keeps its standard deviation where it is redrawn (a few hundred speckle grains: the
    # sample std of either is within ~10 % of the configured one)
    assert np.std(s_load[inside]) == pytest.approx(np.std(s_ref[inside]), rel=0.15)
    assert np.std(s_load[inside]) == pytest.approx(jig.medium.speckle_std, rel=0.2)


def _marker_light(
    pair, side: str, radius_px: float, bg: float, visible: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Excess light over the membrane (level ``bg``) summed in a disc around each visible marker (the
    truth's, or those of ``visible``), and which markers."""
    image = getattr(pair, side).astype(float) - bg
    m = pair.markers
    px = getattr(m, f"{side}_px")
    visible = getattr(m, f"visible_{side}") if visible is None else visible
    yy, xx = np.mgrid[0 : image.shape[0], 0 : image.shape[1]]
    idx = np.flatnonzero(visible)
    light = np.empty(len(idx))
    for k, i in enumerate(idx):
        u, v = px[i]
        y0, x0 = max(int(v - radius_px) - 1, 0), max(int(u - radius_px) - 1, 0)
        y1, x1 = int(v + radius_px) + 2, int(u + radius_px) + 2
        window = (xx[y0:y1, x0:x1] - u) ** 2 + (yy[y0:y1, x0:x1] - v) ** 2 <= radius_px**2
        light[k] = np.sum(image[y0:y1, x0:x1][window])
    return light, idx


def test_marker_brightness_spread_measured_from_the_image():
    spread = 0.12
    plain = quiet_jig(marker_brightness_spread=0.0)
    plain = plain.replace(medium=replace(plain.medium, speckle_std=0.0))
    varied = plain.replace(imaging=replace(plain.imaging, marker_brightness_spread=spread))
    bg = plain.imaging.background_level * TOP
    a = render_pair(nominal_as_built(plain), rng=0)
    b = render_pair(nominal_as_built(varied), rng=0)
    ratios = {}
    for side in ("left", "right"):
        la, idx = _marker_light(a, side, 10.0, bg)
        lb, _ = _marker_light(b, side, 10.0, bg)
        ratios[side] = dict(zip(idx.tolist(), (lb / la).tolist(), strict=True))
    common = sorted(set(ratios["left"]) & set(ratios["right"]))
    assert len(common) > 100
    left = np.array([ratios["left"][i] for i in common])
    right = np.array([ratios["right"][i] for i in common])
    # the measured spread is the configured one (~200 markers: the sample std is within ~10 %)
    assert np.std(left) == pytest.approx(spread, rel=0.2)
    assert np.mean(left) == pytest.approx(1.0, abs=0.03)
    # fixed per marker: the same factor in both cameras
    np.testing.assert_allclose(left, right, atol=0.01)


def _centroid_errors(pair, side: str) -> tuple[np.ndarray, np.ndarray]:
    """Background-subtracted centroid error (px) of each visible, isolated marker and its truth index."""
    image = getattr(pair, side).astype(float)
    m = pair.markers
    px, visible = getattr(m, f"{side}_px"), getattr(m, f"visible_{side}")
    bg = np.median(image)
    errors, which = [], []
    for i in np.flatnonzero(visible):
        u, v = px[i]
        x0, y0 = round(float(u)) - 12, round(float(v)) - 12
        win = image[y0 : y0 + 25, x0 : x0 + 25] - bg
        if win.shape != (25, 25):
            continue
        win = np.where(win > 0, win, 0.0)
        yy, xx = np.mgrid[0:25, 0:25]
        c = np.array([np.sum(xx * win), np.sum(yy * win)]) / np.sum(win) + [x0, y0]
        errors.append(np.linalg.norm(c - px[i]))
        which.append(i)
    return np.array(errors), np.array(which)


def test_flat_disc_markers_have_no_hemisphere_bias_and_flat_tops():
    hemi = quiet_jig(marker_brightness_spread=0.0)
    hemi = hemi.replace(medium=replace(hemi.medium, speckle_std=0.0))
    disc = hemi.replace(imaging=replace(hemi.imaging, marker_appearance="disc"))
    a = render_pair(nominal_as_built(hemi), rng=0)
    b = render_pair(nominal_as_built(disc), rng=0)
    ea, ia = _centroid_errors(a, "left")
    eb, ib = _centroid_errors(b, "left")
    assert np.array_equal(ia, ib)
    # the steep markers on the dome's shoulder: a hemisphere's centroid leans towards its apex
    z = a.markers.xyz_mm[ia, 2]
    steep = z < np.percentile(z, 30)
    assert np.median(ea[steep]) > 0.08
    assert np.median(eb[steep]) < 0.5 * np.median(ea[steep])
    # a hemisphere darkens towards its rim, a flat disc does not: more of a disc's pixels near its peak
    top_h = np.mean(a.left[a.left > 0.12 * TOP] > 0.45 * TOP)
    top_d = np.mean(b.left[b.left > 0.12 * TOP] > 0.45 * TOP)
    assert top_d > top_h + 0.1


def _fit_vertex(image: np.ndarray, bg: float, fiducials_px: np.ndarray) -> np.ndarray:
    """Vertex (u, v) of a paraboloid fitted to the membrane's pixels of an image without markers."""
    h, w = image.shape
    yy, xx = np.mgrid[0:h:4, 0:w:4]
    vals = image[::4, ::4].astype(float)
    keep = vals > 0.0
    for c in fiducials_px.mean(axis=1):  # not on a fiducial (its quiet zone included)
        keep &= np.hypot(xx - c[0], yy - c[1]) > 80.0
    x, y, z = xx[keep].astype(float), yy[keep].astype(float), vals[keep]
    A = np.stack([np.ones_like(x), x, y, x * x + y * y], axis=1)
    c = np.linalg.lstsq(A, z, rcond=None)[0]
    return np.array([-c[1] / (2 * c[3]), -c[2] / (2 * c[3])])


def test_illumination_centre_off_the_axis_mirrored_in_the_right_camera():
    base = speckle_only_jig(quiet_jig())
    jig = base.replace(
        medium=replace(base.medium, speckle_std=0.0),
        imaging=replace(base.imaging, illumination_falloff=0.3, illumination_center=(0.2, -0.1)),
    )
    pair = render_pair(nominal_as_built(jig), rng=0)
    h, w = pair.left.shape
    bg = jig.imaging.background_level * TOP
    half = np.array([(w - 1) / 2, (h - 1) / 2])
    left = _fit_vertex(pair.left, bg, pair.fiducial_corners_left_px)
    right = _fit_vertex(pair.right, bg, pair.fiducial_corners_right_px)
    np.testing.assert_allclose(left, half * [1.2, 0.9], atol=5.0)
    np.testing.assert_allclose(right, half * [0.8, 0.9], atol=5.0)


def test_per_camera_exposure_and_gain():
    base = speckle_only_jig(quiet_jig())
    # shot noise only (no read noise, no speckle): sigma^2 = e I / full_well, then times the gain
    jig = base.replace(
        medium=replace(base.medium, speckle_std=0.0),
        imaging=replace(
            base.imaging, full_well_electrons=2000.0, read_noise=0.0, exposure=(1.0, 0.8), gain=(1.0, 1.5)
        ),
    )
    pair = render_pair(nominal_as_built(jig), rng=0)
    patch = (slice(300, 420), slice(560, 720))  # the membrane around the image centre
    left, right = pair.left[patch].astype(float), pair.right[patch].astype(float)
    assert np.mean(right) / np.mean(left) == pytest.approx(0.8 * 1.5, rel=0.01)
    assert np.std(right) / np.std(left) == pytest.approx(1.5 * np.sqrt(0.8), rel=0.1)


def test_missing_markers_are_dark_in_every_frame_and_camera_and_not_visible_in_the_truth():
    plain = quiet_jig(marker_brightness_spread=0.0)
    damaged = plain.replace(imaging=replace(plain.imaging, missing_marker_fraction=0.1))
    factors = marker_brightness(damaged.imaging, 2000)
    assert np.mean(factors == 0.0) == pytest.approx(0.1, abs=0.02)
    bg = plain.imaging.background_level * TOP
    for rng, part in ((1, None), (2, PART)):
        pose = (part, POSE) if part else ()
        pair = render_pair(nominal_as_built(damaged), *pose, rng=rng)
        in_view = render_pair(nominal_as_built(plain), *pose, rng=rng).markers  # the same geometry
        missing = marker_brightness(damaged.imaging, len(pair.markers.xyz_mm)) == 0.0
        for side in ("left", "right"):
            seen = getattr(in_view, f"visible_{side}")
            light, idx = _marker_light(pair, side, 6.0, bg, visible=seen)
            assert missing[idx].sum() > 5
            # a missing marker leaves the membrane (its light is the speckle's, about nothing)
            assert np.max(np.abs(light[missing[idx]])) < 0.05 * np.median(light[~missing[idx]])
            # and the truth does not count it among the markers a camera sees
            np.testing.assert_array_equal(getattr(pair.markers, f"visible_{side}"), seen & ~missing)


def _bubble_pixels(jig: JigConfig, side: str) -> tuple[np.ndarray, np.ndarray]:
    """Each bubble's projected centre and radius (px) in one camera."""
    camera = getattr(jig.cameras, side)
    centres, radii = bubbles_J(jig)
    layers = flat_layers(jig)
    px, rim = (
        project_points(p, camera.K, distortion_of(camera), camera.T_J_cam, layers)
        for p in (centres, centres + radii[:, None] * np.array([1.0, 0.0, 0.0]))
    )
    return px, np.linalg.norm(rim - px, axis=1)


def test_bubbles_darken_their_rims_in_both_cameras_in_every_frame():
    plain = quiet_jig(marker_brightness_spread=0.0)
    plain = plain.replace(medium=replace(plain.medium, speckle_std=0.0))
    bubbly = plain.replace(medium=replace(plain.medium, bubbles=10, bubble_radius_mm=1.5))
    centres, radii = bubbles_J(bubbly)
    assert len(centres) == 10 and np.all((radii >= 0.75) & (radii <= 2.25))
    assert np.all(np.hypot(centres[:, 0], centres[:, 1]) <= bubbly.membrane.footprint_radius_mm)
    clear = render_pair(nominal_as_built(plain), rng=1)
    reference = render_pair(nominal_as_built(bubbly), rng=1)
    loaded = render_pair(nominal_as_built(bubbly), PART, POSE, rng=2)
    for side in ("left", "right"):
        px, radius_px = _bubble_pixels(bubbly, side)
        h, w = clear.left.shape
        yy, xx = np.mgrid[0:h, 0:w]
        seen = 0
        for (u, v), r in zip(px, radius_px, strict=True):
            if not (3 * r < u < w - 3 * r and 3 * r < v < h - 3 * r):
                continue
            rho = np.hypot(xx - u, yy - v) / r
            rim = (rho > 0.75) & (rho < 0.95)
            ratio = getattr(reference, side)[rim].astype(float) / getattr(clear, side)[rim]
            assert np.median(ratio) < 0.5  # the ring is dark over the membrane and the markers
            # where nothing moved, the bubble is the same in the loaded frame
            still = np.all(np.hypot(*(getattr(loaded.markers, f"{side}_px") - (u, v)).T) > 3 * r + 15)
            if still:
                assert np.array_equal(getattr(loaded, side)[rim], getattr(reference, side)[rim])
            seen += 1
        assert seen >= 5
        away = np.ones((h, w), dtype=bool)
        for (u, v), r in zip(px, radius_px, strict=True):
            away &= np.hypot(xx - u, yy - v) > 1.5 * r
        assert np.array_equal(getattr(reference, side)[away], getattr(clear, side)[away])


def test_glints_saturate_fixed_spots_of_each_camera():
    plain = quiet_jig(marker_brightness_spread=0.0)
    glinty = plain.replace(imaging=replace(plain.imaging, glints=20))
    clear = render_pair(nominal_as_built(plain), rng=1)
    reference = render_pair(nominal_as_built(glinty), rng=1)
    loaded = render_pair(nominal_as_built(glinty), PART, POSE, rng=2)
    left = (reference.left == TOP) & (clear.left < TOP)
    right = (reference.right == TOP) & (clear.right < TOP)
    assert left.any() and right.any()
    assert not np.array_equal(left, right)  # each camera sees its own reflections
    assert np.array_equal(left, (loaded.left == TOP) & (clear.left < TOP))  # and the same ones every frame
