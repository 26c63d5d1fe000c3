"""Reference pairs of the renderer as it was before :class:`softjig.sim.render.Renderer` (commit e23b5b0,
where each frame was composed step by step in NumPy and OpenCV): small frames of the default jig's physics
and of the other image-model branches, stored in ``tests/data/render_golden.npz`` so that
``tests/test_render_engine.py`` can show the faster renderer draws the same images.

Regenerate (only if the image model itself changes, deliberately) with the renderer to compare against::

    PYTHONPATH=/path/to/that/src python tests/render_golden.py tests/data/render_golden.npz
"""

from __future__ import annotations

import sys
from dataclasses import replace

import numpy as np

from softjig.config import CylinderPart, JigConfig, default_jig
from softjig.sim.asbuilt import draw_as_built
from softjig.sim.parts import PartPose

SCALE = 0.2  # 256 x 144 images: markers ~2 px in radius, every step of the model still in play
SEED = 7


def small_jig(**changes: dict) -> JigConfig:
    """The default jig with cameras scaled by ``SCALE`` (focal length too) and the given config sections'
    fields changed (``{"imaging": {...}, "medium": {...}}``)."""
    jig = default_jig()
    w, h = int(1280 * SCALE), int(720 * SCALE)

    def cam(c):
        return replace(
            c,
            width_px=w,
            height_px=h,
            fx_px=c.fx_px * SCALE,
            fy_px=c.fy_px * SCALE,
            cx_px=(w - 1) / 2,
            cy_px=(h - 1) / 2,
        )

    jig = jig.replace(cameras=replace(jig.cameras, left=cam(jig.cameras.left), right=cam(jig.cameras.right)))
    return jig.replace(**{k: replace(getattr(jig, k), **v) for k, v in changes.items()})


CASES = {
    # the default physics: hemispheres, static speckle redrawn where the part moved beads, 8 bits
    "default": ({}, PartPose(alpha_rad=np.radians(12.0), theta_rad=np.radians(40.0), push_depth_mm=3.0)),
    # painted discs, a speckle drawn anew every frame, 16 bits
    "disc-dynamic-16": (
        {"imaging": {"marker_appearance": "disc", "bit_depth": 16}, "medium": {"speckle_static": False}},
        PartPose(alpha_rad=np.radians(5.0), theta_rad=np.radians(200.0), push_depth_mm=2.0),
    ),
}


def render_cases() -> dict[str, np.ndarray]:
    from softjig.sim.render import render_pair

    out = {}
    for name, (changes, pose) in CASES.items():
        as_built = draw_as_built(small_jig(**changes), rng=SEED)
        pair = render_pair(as_built, CylinderPart(diameter_mm=50.0), pose, SEED)
        out[f"{name}/left"] = pair.left
        if pair.right.dtype == np.uint8:  # a 16-bit image is twice the bytes: its left one shows enough
            out[f"{name}/right"] = pair.right
        out[f"{name}/left_px"], out[f"{name}/visible_left"] = pair.markers.left_px, pair.markers.visible_left
    return out


if __name__ == "__main__":
    np.savez_compressed(sys.argv[1], **render_cases())
