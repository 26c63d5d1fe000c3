"""The renderer built once per jig (:class:`softjig.sim.render.Renderer`) and its compiled kernels.

Groups: agreement with the renderer before it (stored reference frames, ``tests/render_golden.py``) and
with straightforward NumPy/OpenCV oracles of each kernel; the public functions as thin wrappers; no hidden
per-jig state (no caches, no thread-local buffers) and a renderer shared by threads.
"""

from __future__ import annotations

import functools
import threading
from concurrent.futures import ThreadPoolExecutor
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest

import softjig.sim.membrane as membrane
import softjig.sim.render as render
from render_golden import CASES, SEED, small_jig
from softjig.config import CylinderPart, default_jig
from softjig.optics import project_points, rays_in_top_region
from softjig.rig import distortion_of, flat_layers
from softjig.sim import _kernels
from softjig.sim.asbuilt import draw_as_built
from softjig.sim.membrane import deform
from softjig.sim.parts import PartPose
from softjig.sim.render import Renderer, render_pair

GOLDEN = Path(__file__).parent / "data" / "render_golden.npz"
# The stored frames were composed in another order of the same float32 products: a grey level may differ
# where a value lies within float rounding of a rounding boundary (measured: 0-3 pixels of 921600).
MAX_DIFFERING_FRACTION = 1e-3
TRUTH_PX_TOLERANCE = 1e-9  # px: float rounding of the projection (measured: <= 3e-13 px)

POSE = PartPose(alpha_rad=np.radians(10.0), theta_rad=np.radians(30.0))
PART = CylinderPart(diameter_mm=50.0)


@pytest.fixture(scope="module")
def small_as_built():
    return draw_as_built(small_jig(), rng=SEED)


# ------------------------------------------------------------------------------------------- agreement


@pytest.mark.parametrize("name", list(CASES))
def test_frames_match_the_renderer_before(name):
    golden = np.load(GOLDEN)
    changes, pose = CASES[name]
    pair = render_pair(draw_as_built(small_jig(**changes), rng=SEED), PART, pose, SEED)
    # the projection is compiled now (sim._kernels.project_refracted): the same model, to ~1e-12 px
    px = golden[f"{name}/left_px"]
    np.testing.assert_allclose(pair.markers.left_px, px, rtol=0, atol=TRUTH_PX_TOLERANCE)
    np.testing.assert_array_equal(pair.markers.visible_left, golden[f"{name}/visible_left"])
    for side in ("left", "right"):
        if f"{name}/{side}" not in golden:
            continue
        ref = golden[f"{name}/{side}"]
        image = getattr(pair, side)
        assert image.dtype == ref.dtype and image.shape == ref.shape
        diff = np.abs(image.astype(np.int64) - ref.astype(np.int64))
        level = 1 if ref.dtype == np.uint8 else 2  # a 16-bit level is 1/257 of an 8-bit one: float rounding
        assert diff.max() <= level, f"{name} {side}: max difference {diff.max()}"
        assert np.mean(diff > 0) <= MAX_DIFFERING_FRACTION, f"{name} {side}: {np.mean(diff > 0):.2e} differ"


def _numpy_cast(optics, idx, origin, size, ss, disc):
    """The shading factor by brute force: every sub-sample of every patch pixel, then a block mean."""
    q = size * ss
    sub = (np.arange(q) + 0.5) / ss - 0.5
    du = ((origin[:, 0] - optics.px[idx, 0])[:, None] + sub).astype(np.float32)[:, None, :]
    dv = ((origin[:, 1] - optics.px[idx, 1])[:, None] + sub).astype(np.float32)[:, :, None]
    a0, a1, a2 = (optics.quad[idx, k].astype(np.float32)[:, None, None] for k in range(3))
    cos_axis = np.maximum(optics.cos_axis[idx], 1e-6)
    l0, l1 = ((optics.lin[idx, k] / cos_axis).astype(np.float32)[:, None, None] for k in range(2))
    c = np.sqrt(np.maximum(1.0 - a2 * dv * dv - a1 * dv * du - a0 * du * du, 0.0))
    w = -l1 * dv - l0 * du
    value = (np.abs(w) < c).astype(np.float32) if disc else np.where(c > np.maximum(w, 0.0), 1.0 + c, 0.0)
    out = value.reshape(len(idx), size, ss, size, ss).mean(axis=(2, 4))
    return out * (2.0 * cos_axis)[:, None, None] if disc else out


@pytest.mark.parametrize("disc", [False, True])
def test_cast_kernel_matches_brute_force(disc):
    jig = default_jig()
    as_built = draw_as_built(jig, rng=0)
    state = deform(jig, as_built.marker_xy_mm, PART, POSE.T_J_part(jig), rng=0)
    optics = render._marker_optics(jig, jig.cameras.left, state, flat_layers(jig))
    half = int(np.ceil(np.nanmax(optics.radius_px)))
    idx = np.flatnonzero(optics.near)[::7]
    origin = np.rint(optics.px[idx]).astype(np.int64) - half
    got = render._cast_marker_patches(optics, idx, origin, 2 * half + 1, 4, disc=disc)
    want = _numpy_cast(optics, idx, origin, 2 * half + 1, 4, disc)
    assert got.shape == want.shape
    # float32 sums in another order; a sub-sample exactly on the rim may fall either way (1/16 of a pixel)
    assert np.max(np.abs(got - want)) < 1e-5
    assert np.sum(got > 0) == np.sum(want > 0)


def _sensor(image, im, rng, gain):
    """The sensor alone on a radiance ``image``: :func:`softjig.sim.render._compose` without markers."""
    return render._compose(image, image, None, render._NO_PATCHES, render._NO_ORIGINS, im, rng, gain)


@pytest.mark.parametrize("bit_depth", [8, 16])
def test_sensor_kernel_matches_opencv_oracle(bit_depth):
    rng = np.random.default_rng(3)
    image = rng.uniform(-0.05, 1.05, (64, 96)).astype(np.float32)
    im = replace(default_jig().imaging, bit_depth=bit_depth)
    got = _sensor(image.copy(), im, np.random.default_rng(11), 1.1)
    # the oracle: the same deviates, then one OpenCV/NumPy operation per step
    hi, lo = render._random_bytes(np.random.default_rng(11), image.shape)
    z = render._NORMAL_OFFSET[hi] + render._NORMAL_SLOPE[hi] * lo.astype(np.float32)
    v = np.maximum(image, 0.0)
    v = np.maximum(
        v + np.sqrt(v / np.float32(im.full_well_electrons) + np.float32(im.read_noise**2)) * z, 0.0
    )
    if bit_depth == 8:
        want = cv2.convertScaleAbs(v, alpha=255.0 * 1.1)
    else:
        want = np.minimum(v * np.float32(65535.0 * 1.1) + np.float32(0.5), 65535.0).astype(np.uint16)
    assert got.dtype == want.dtype
    diff = np.abs(got.astype(np.int64) - want.astype(np.int64))
    assert diff.max() <= 1 and np.mean(diff > 0) < 1e-3


def test_projection_kernel_matches_optics():
    """The compiled projection of the markers is :func:`softjig.optics.project_points`'s model."""
    jig = default_jig()
    layers = flat_layers(jig)
    rng = np.random.default_rng(2)
    xy = rng.uniform(-70, 70, (2000, 2))
    points = np.column_stack([xy, rng.uniform(-8, 40, 2000)])
    distorted = replace(jig.cameras.left, distortion=(-0.12, 0.03, 0.001, -0.002, 0.004))
    for camera in (jig.cameras.left, jig.cameras.right, distorted):
        want = project_points(points, camera.K, distortion_of(camera), camera.T_J_cam, layers)
        got = render._project(points, camera, layers)
        np.testing.assert_allclose(got, want, rtol=0, atol=TRUTH_PX_TOLERANCE)


def test_compose_kernel_matches_numpy_paste_then_sensor():
    """One pass band by band (patches, a box of its own radiance and gain) = the image composed whole in
    NumPy, then the sensor."""
    rng = np.random.default_rng(8)
    h, w, p = 150, 200, 23
    base, gain = (rng.uniform(0.02, 0.6, (h, w)).astype(np.float32) for _ in range(2))
    patches = rng.uniform(0.0, 0.4, (40, p, p)).astype(np.float32)
    origin = np.column_stack([rng.integers(-p // 2, w - p // 2, 40), rng.integers(-p // 2, h - p // 2, 40)])
    box = render._Box(*(rng.uniform(0.02, 0.6, (61, 77)).astype(np.float32) for _ in range(2)), 90, 33)
    im = default_jig().imaging
    got = render._compose(base, gain, box, patches, origin, im, np.random.default_rng(1), 1.05)
    image, g = base.copy(), gain.copy()
    image[33:94, 90:167], g[33:94, 90:167] = box.radiance, box.gain
    for patch, (x, y) in zip(patches, origin, strict=True):
        ys, xs = slice(max(y, 0), min(y + p, h)), slice(max(x, 0), min(x + p, w))
        image[ys, xs] += patch[ys.start - y : ys.stop - y, xs.start - x : xs.stop - x] * g[ys, xs]
    want = _sensor(image, im, np.random.default_rng(1), 1.05)
    diff = np.abs(got.astype(int) - want.astype(int))
    assert diff.max() <= 1 and np.mean(diff > 0) < 1e-3  # overlapping patches: sums in another order


def test_compose_kernel_ignores_patches_outside_the_image():
    """A patch wholly left, right, above or below the image adds nothing: the image equals the one composed
    without it (a patch ending left of column 0 once gave a negative slice stop that wrapped round, and the
    compiled loop read memory past the patch)."""
    rng = np.random.default_rng(9)
    h, w, p = 120, 160, 21
    base, gain = (rng.uniform(0.02, 0.6, (h, w)).astype(np.float32) for _ in range(2))
    inside = np.array([[5, 7], [100, 40], [-10, 90], [150, 110]])
    outside = np.array([[-p, 30], [-p - 40, 60], [w, 20], [w + 5, 0], [40, -p], [70, h], [-p, -p]])
    patches = rng.uniform(0.0, 0.4, (len(inside) + len(outside), p, p)).astype(np.float32)
    im = default_jig().imaging

    def compose(patches, origin):
        return render._compose(base, gain, None, patches, origin, im, np.random.default_rng(1), 1.0)

    got = compose(patches, np.vstack([inside, outside]))
    np.testing.assert_array_equal(got, compose(patches[: len(inside)], inside))


def test_rest_heights_held_once_give_the_same_membrane():
    jig = default_jig()
    as_built = draw_as_built(jig, rng=0)
    rest = membrane.rest_heights(jig, as_built.marker_xy_mm)
    a = deform(jig, as_built.marker_xy_mm, PART, POSE.T_J_part(jig), ripple_mm=0.05, rng=3, rest=rest)
    b = deform(jig, as_built.marker_xy_mm, PART, POSE.T_J_part(jig), ripple_mm=0.05, rng=3)
    for field in ("marker_xyz_mm", "marker_axis", "in_contact", "indentation_mm"):
        np.testing.assert_array_equal(getattr(a, field), getattr(b, field))
    with pytest.raises(ValueError, match="rest heights of"):
        deform(jig, as_built.marker_xy_mm[:-1], PART, POSE.T_J_part(jig), rest=rest)


@pytest.mark.parametrize("contacts", [1, 7, 8, 9, 300])  # chunks of 8 contacts: partial, whole, several
def test_membrane_envelope_kernel_matches_numpy(contacts):
    rng = np.random.default_rng(contacts)
    q = rng.uniform(-60, 60, (500, 2)).astype(np.float32)
    c = rng.uniform(-25, 25, (contacts, 2)).astype(np.float32)
    log_depth = np.log(rng.uniform(0.01, 3.0, contacts)).astype(np.float32)
    inverse_decay = (1.0 / rng.uniform(5.0, 12.0, contacts)).astype(np.float32)
    d = np.hypot(q[:, None, 0] - c[None, :, 0], q[:, None, 1] - c[None, :, 1])
    want = np.max(log_depth - d * inverse_decay, axis=1)
    got = _kernels.log_envelope(
        q[:, 0].copy(), q[:, 1].copy(), c[:, 0].copy(), c[:, 1].copy(), log_depth, inverse_decay
    )
    np.testing.assert_array_equal(got, want)


def test_ray_kernel_matches_optics():
    """The markers' compiled oil rays are :func:`softjig.optics.rays_in_top_region`'s, and fail alike."""
    jig = default_jig()
    layers = flat_layers(jig)
    pixels = np.random.default_rng(3).uniform([-100, -100], [1380, 820], (2000, 2))
    distorted = replace(jig.cameras.left, distortion=(-0.12, 0.03, 0.001, -0.002, 0.004))
    for camera in (jig.cameras.left, jig.cameras.right, distorted):
        want = rays_in_top_region(pixels, camera.K, distortion_of(camera), camera.T_J_cam, layers)
        got = render._rays(pixels, camera, layers)
        for a, b in zip(got, want, strict=True):
            np.testing.assert_allclose(a, b, rtol=0, atol=1e-9)
    tilted = replace(jig.cameras.left, fx_px=100.0, rotation_deg=(0.0, 60.0, 0.0))  # some rays point down
    with pytest.raises(ValueError, match="upwards"):
        rays_in_top_region(pixels, tilted.K, None, tilted.T_J_cam, layers)
    with pytest.raises(ValueError, match="upwards"):
        render._rays(pixels, tilted, layers)


def test_redrawn_speckle_region_equals_the_whole_texture_resized(small_as_built, monkeypatch):
    """Only the fine pixels around the re-packed beads are recomputed: they equal a resize of the whole
    coarse texture (with the same redraw) there, and every pixel outside equals the static texture."""
    jig = small_as_built.jig
    view = Renderer(small_as_built)._views["left"]
    state = deform(jig, small_as_built.marker_xy_mm, PART, POSE.T_J_part(jig), rng=0)
    optics = render._marker_optics(jig, jig.cameras.left, state, view.layers)
    moved = optics.near & (np.abs(state.indentation_mm) > jig.medium.speckle_redraw_displacement_mm)
    assert moved.any()
    grid, shape = view.speckle, view.base.shape
    resize = render._upsample
    crops = []
    monkeypatch.setattr(
        render, "_upsample", lambda coarse, *args: crops.append(coarse.copy()) or resize(coarse, *args)
    )
    factor, x0, y0 = render._redrawn_speckle(jig, grid, optics, moved, np.random.default_rng(5), shape)
    (crop,) = crops
    f, std = grid.factor, jig.medium.speckle_std
    changed = grid.texture.copy()  # the redrawn coarse crop starts one coarse pixel before the fine region
    ya, xa = max(y0 // f - 1, 0), max(x0 // f - 1, 0)
    changed[ya : ya + crop.shape[0], xa : xa + crop.shape[1]] = crop
    whole = resize(changed, f, shape, std)
    static = resize(grid.texture, f, shape, std)
    h, w = factor.shape
    np.testing.assert_array_equal(factor, whole[y0 : y0 + h, x0 : x0 + w])
    outside = np.ones(shape, dtype=bool)
    outside[y0 : y0 + h, x0 : x0 + w] = False
    np.testing.assert_array_equal(whole[outside], static[outside])
    assert np.any(factor != static[y0 : y0 + h, x0 : x0 + w])


# ------------------------------------------------------------------------------------ thin wrappers


def test_reused_renderer_equals_render_pair(small_as_built):
    renderer = Renderer(small_as_built)
    assert renderer.jig is small_as_built.jig
    for seed, pose in enumerate([POSE, PartPose(alpha_rad=0.3, theta_rad=2.0), PartPose()]):
        a = renderer.render_pair(PART, pose, seed)
        b = render_pair(small_as_built, PART, pose, seed)
        np.testing.assert_array_equal(a.left, b.left)
        np.testing.assert_array_equal(a.right, b.right)
        np.testing.assert_array_equal(a.markers.right_px, b.markers.right_px)
        np.testing.assert_array_equal(a.fiducial_corners_left_px, b.fiducial_corners_left_px)
    unloaded = renderer.render_pair(None, None, 0)
    np.testing.assert_array_equal(unloaded.left, render_pair(small_as_built, None, None, 0).left)


def test_render_view_is_the_renderers_camera(small_as_built):
    jig = small_as_built.jig
    state = deform(jig, small_as_built.marker_xy_mm, PART, POSE.T_J_part(jig), rng=np.random.default_rng(4))
    image, px, visible = render.render_view(jig, jig.cameras.right, state, 9)
    view = Renderer(small_as_built)._views["right"]
    result = view.render(
        jig,
        state,
        render.marker_brightness(jig.imaging, len(px)),
        np.random.default_rng(9),
        False,
        render._Timer(None),
        render._Scratch(),
    )
    np.testing.assert_array_equal(image, result.image)
    np.testing.assert_array_equal(visible, result.visible)


# ------------------------------------------------------------------------------------- hidden state


@pytest.mark.parametrize("module", [render, membrane, _kernels])
def test_no_hidden_per_jig_state(module):
    """No module-level cache keyed on the config and no thread-local buffers (issue 16) defined here."""
    for name, value in vars(module).items():
        if getattr(value, "__module__", module.__name__) != module.__name__:
            continue  # imported (other modules' caches are theirs)
        assert not isinstance(value, functools._lru_cache_wrapper), f"{module.__name__}.{name} is a cache"
        assert not isinstance(value, threading.local), f"{module.__name__}.{name} is thread-local"
        assert not (isinstance(value, type) and issubclass(value, threading.local)), name


def test_renderer_holds_read_only_arrays(small_as_built):
    renderer = Renderer(small_as_built)
    for view in renderer._views.values():
        for array in (view.base, view.gain, view.corners_px, view.speckle.texture):
            assert not array.flags.writeable
        for fid in view.fiducials:
            assert not fid.cover.flags.writeable


def test_renderer_shared_by_threads(small_as_built):
    renderer = Renderer(small_as_built)
    poses = [PartPose(alpha_rad=0.05 * k, theta_rad=0.7 * k) for k in range(6)]
    alone = [renderer.render_pair(PART, pose, k) for k, pose in enumerate(poses)]
    with ThreadPoolExecutor(2) as pool:
        together = list(pool.map(lambda k: renderer.render_pair(PART, poses[k], k), range(len(poses))))
    for a, b in zip(alone, together, strict=True):
        np.testing.assert_array_equal(a.left, b.left)
        np.testing.assert_array_equal(a.right, b.right)
