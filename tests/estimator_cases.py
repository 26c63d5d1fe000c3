"""Shared cases for the estimator's trust tests: jig designs other than the default.

Their bead speckle is the simulator's static one (``medium.speckle_static``, the default): the same bead
pack in every frame, as in a real jig, re-packed only where the membrane moved.
"""

from __future__ import annotations

from dataclasses import replace

from softjig.config import CameraConfig, JigConfig, StereoConfig, default_jig


def stereo_cameras(
    width: int, height: int, focal_px: float, baseline_mm: float, gap_mm: float
) -> StereoConfig:
    """A rectified pair below the plate, centred on the jig axis."""

    def camera(x_mm: float) -> CameraConfig:
        return CameraConfig(
            width_px=width,
            height_px=height,
            fx_px=focal_px,
            fy_px=focal_px,
            cx_px=(width - 1) / 2,
            cy_px=(height - 1) / 2,
            position_mm=(x_mm, 0.0, -gap_mm),
        )

    return StereoConfig(left=camera(-baseline_mm / 2), right=camera(baseline_mm / 2))


def fine_grid_jig() -> JigConfig:
    """1024x768 px, a 5 mm pitch of 2 mm markers: the design where the size-free estimate fitted the wall."""
    jig = default_jig()
    return jig.replace(
        cameras=stereo_cameras(1024, 768, 740.0, 30.0, 155.0),
        markers=replace(jig.markers, pitch_mm=5.0, diameter_mm=2.0),
    )


def oil_above_plate_jig() -> JigConfig:
    """A PMMA plate (n = 1.49) under an oil of higher index (1.56), a 50 mm baseline at 180 mm."""
    jig = default_jig()
    return jig.replace(
        cameras=stereo_cameras(1280, 800, 800.0, 50.0, 180.0),
        plate=replace(jig.plate, refractive_index=1.49, thickness_mm=4.0),
        fiducials=replace(jig.fiducials, z_mm=-4.0),
        medium=replace(jig.medium, oil_refractive_index=1.56, bead_refractive_index=1.56),
    )


def coarse_jig() -> JigConfig:
    """640x480 px, a 10 mm pitch of 4 mm markers."""
    jig = default_jig()
    return jig.replace(
        cameras=stereo_cameras(640, 480, 430.0, 25.0, 140.0),
        markers=replace(jig.markers, pitch_mm=10.0, diameter_mm=4.0),
    )
