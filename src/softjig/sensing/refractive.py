"""Refraction-aware triangulation: each marker's two refracted rays in the oil, intersected.

The paper triangulates as if the cameras looked through air, so depths come out compressed (by about the
oil's index) and a scale ``S`` must be calibrated with a robot. Here each detected marker is
back-projected through the flat layers of the jig (air, plate, oil: :func:`softjig.rig.flat_layers`)
with Snell's law at each interface (:func:`softjig.optics.backproject_pixels`), from each camera's pose
in J (measured from the fiducials, or the config's), and the point is the midpoint of the two rays'
closest approach. The rays' gap at that point measures how well the two detections agree (a wrong match
or a bad calibration shows there first). Stereo tactile sensors that model refraction (GelStereo 2.0,
StereoTacTip) do the same.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from softjig.config import JigConfig
from softjig.optics import backproject_pixels
from softjig.rig import flat_layers
from softjig.sensing.jigframe import JigFrame


@dataclass(frozen=True)
class RefractedPoints:
    """Triangulated markers.

    Attributes
    ----------
    points_J : (M, 3) the markers in J (mm).
    ray_gap_mm : (M,) distance between the two refracted rays at their closest approach (mm).
    """

    points_J: np.ndarray
    ray_gap_mm: np.ndarray


def closest_points_of_rays(
    origins_a: np.ndarray, directions_a: np.ndarray, origins_b: np.ndarray, directions_b: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Midpoint and gap of the closest approach of pairs of rays (unit directions), ``(M, 3)``, ``(M,)``.

    Parallel rays (no unique closest approach) give NaN; callers drop them.
    """
    w0 = origins_a - origins_b
    b = np.einsum("ij,ij->i", directions_a, directions_b)
    d = np.einsum("ij,ij->i", directions_a, w0)
    e = np.einsum("ij,ij->i", directions_b, w0)
    denominator = 1.0 - b * b
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.where(denominator > 1e-12, (b * e - d) / denominator, np.nan)
        t = np.where(denominator > 1e-12, (e - b * d) / denominator, np.nan)
    pa = origins_a + s[:, None] * directions_a
    pb = origins_b + t[:, None] * directions_b
    return (pa + pb) / 2.0, np.linalg.norm(pa - pb, axis=1)


def triangulate_refracted(
    left_xy_px: np.ndarray, right_xy_px: np.ndarray, jig: JigConfig, frame: JigFrame
) -> RefractedPoints:
    """Triangulate matched markers through the jig's refracting layers.

    Parameters
    ----------
    left_xy_px, right_xy_px : (M, 2) matched marker centres in the left and right images (px).
    jig : the nominal jig: its cameras' intrinsics and distortion, and its layers' thicknesses and indices.
    frame : the cameras' poses in J (from the fiducials or the config).

    Returns
    -------
    RefractedPoints
    """
    if len(left_xy_px) == 0:
        return RefractedPoints(np.zeros((0, 3)), np.zeros(0))
    layers = flat_layers(jig)
    left, right = jig.cameras.left, jig.cameras.right
    origin_l, direction_l = backproject_pixels(left_xy_px, left.K, left.distortion, frame.T_J_left, layers)
    origin_r, direction_r = backproject_pixels(
        right_xy_px, right.K, right.distortion, frame.T_J_right, layers
    )
    points, gap = closest_points_of_rays(origin_l, direction_l, origin_r, direction_r)
    return RefractedPoints(points, gap)
