"""The jig's optical setup for :mod:`softjig.optics`: its flat refractive layers and camera matrices."""

from __future__ import annotations

import numpy as np

from softjig.config import CameraConfig, JigConfig
from softjig.optics import FlatLayers

AIR_REFRACTIVE_INDEX = 1.000293


def flat_layers(jig: JigConfig) -> FlatLayers:
    """Air below the plate, the plate (``-thickness < z < 0``), the oil above it (``DESIGN.md`` §2).

    ``FlatLayers`` is immutable and cheap to make; an estimator makes it once."""
    return FlatLayers(
        interfaces_z_mm=(-jig.plate.thickness_mm, 0.0),
        refractive_indices=(
            AIR_REFRACTIVE_INDEX,
            jig.plate.refractive_index,
            jig.medium.oil_refractive_index,
        ),
    )


def distortion_of(camera: CameraConfig) -> np.ndarray:
    """OpenCV distortion coefficients ``(k1, k2, p1, p2, k3)`` of a camera."""
    return np.asarray(camera.distortion, dtype=float)
