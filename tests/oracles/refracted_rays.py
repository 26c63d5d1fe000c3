"""Oracle of :func:`softjig.sensing.refractive.triangulate_refracted`: every interface traced one refraction
at a time (:func:`softjig.optics.backproject_pixels`, the general path, validated against Snell's law and
the forward projection), then the closest approach of the two rays."""

from __future__ import annotations

import numpy as np

from softjig.config import JigConfig
from softjig.optics import backproject_pixels
from softjig.rig import flat_layers
from softjig.sensing.jigframe import JigFrame
from softjig.sensing.refractive import RefractedPoints, closest_points_of_rays


def traced_triangulation(
    left_xy_px: np.ndarray, right_xy_px: np.ndarray, jig: JigConfig, frame: JigFrame
) -> RefractedPoints:
    """The markers in J (mm) and their rays' gaps, each ray traced interface by interface."""
    layers = flat_layers(jig)
    rays = [
        backproject_pixels(np.asarray(xy, dtype=float), cam.K, cam.distortion, T_J_cam, layers)
        for xy, cam, T_J_cam in (
            (left_xy_px, jig.cameras.left, frame.T_J_left),
            (right_xy_px, jig.cameras.right, frame.T_J_right),
        )
    ]
    points, gap = closest_points_of_rays(*rays[0], *rays[1])
    return RefractedPoints(points, gap)
