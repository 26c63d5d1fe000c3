"""Refraction-aware triangulation: each marker's two refracted rays in the oil, intersected.

The paper triangulates as if the cameras looked through air, so depths come out compressed (by about the
oil's index) and a scale ``S`` must be calibrated with a robot. Here each detected marker is
back-projected through the flat layers of the jig (air, plate, oil: :func:`softjig.rig.flat_layers`)
with Snell's law at each interface, from each camera's pose in J (measured from the fiducials, or the
config's), and the point is the midpoint of the two rays' closest approach. The rays' gap at that point
measures how well the two detections agree (a wrong match or a bad calibration shows there first). Stereo
tactile sensors that model refraction (GelStereo 2.0, StereoTacTip) do the same.

Back-projection through flat layers is closed form (:func:`softjig.optics.rays_in_top_region_normalized`:
a ray keeps its azimuth and Snell invariant through horizontal interfaces), and so is the closest approach
of two rays (:func:`closest_points_of_rays`). The general trace through each interface
(:func:`softjig.optics.backproject_pixels`) is the tests' oracle for both.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from softjig.config import JigConfig
from softjig.errors import InputError
from softjig.optics import FlatLayers, pixels_to_normalized, rays_in_top_region_normalized
from softjig.rig import flat_layers
from softjig.sensing.jigframe import JigFrame

#: Rays whose directions' cross product has a squared norm ``1 - (a . b)^2`` below this are parallel: they
#: have no unique closest approach (their midpoint is NaN).
PARALLEL_SIN2 = 1e-12


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
    skew = denominator > PARALLEL_SIN2
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.where(skew, (b * e - d) / denominator, np.nan)
        t = np.where(skew, (e - b * d) / denominator, np.nan)
    pa = origins_a + s[:, None] * directions_a
    pb = origins_b + t[:, None] * directions_b
    return (pa + pb) / 2.0, np.linalg.norm(pa - pb, axis=1)


def triangulate_refracted(
    left_xy_px: np.ndarray,
    right_xy_px: np.ndarray,
    jig: JigConfig,
    frame: JigFrame,
    *,
    constants: KernelConstants | None = None,
) -> RefractedPoints:
    """Triangulate matched markers through the jig's refracting layers.

    Parameters
    ----------
    left_xy_px, right_xy_px : (M, 2) matched marker centres in the left and right images (px).
    jig : the nominal jig: its cameras' intrinsics and distortion, and its layers' thicknesses and indices.
    frame : the cameras' poses in J (from the fiducials or the config).
    constants : :func:`kernel_constants` of ``jig`` (built here when not given: an estimator builds them
        once).

    Returns
    -------
    RefractedPoints

    Raises
    ------
    InputError
        The pixel arrays are not finite ``(M, 2)`` arrays of equal length.
    ValueError
        A camera is not below the plate, or a pixel's ray does not go up through the layers.
    """
    left_xy = _as_pixels(left_xy_px, "left_xy_px")
    right_xy = _as_pixels(right_xy_px, "right_xy_px")
    if len(left_xy) != len(right_xy):
        raise InputError(
            f"left_xy_px has {len(left_xy)} points but right_xy_px has {len(right_xy)}: pass matched pairs "
            "(row k of both is the same marker)"
        )
    if len(left_xy) == 0:
        return RefractedPoints(np.zeros((0, 3)), np.zeros(0))
    k = constants if constants is not None else kernel_constants(jig)
    normalized = np.stack(
        [
            pixels_to_normalized(xy, K, distortion)
            for xy, K, distortion in zip((left_xy, right_xy), k.K, k.distortion, strict=True)
        ]
    )
    poses = np.stack([frame.T_J_left, frame.T_J_right])
    origins, directions = rays_in_top_region_normalized(
        normalized, poses[:, :3, :3], poses[:, :3, 3], k.layers
    )
    points, gap = closest_points_of_rays(origins[0], directions[0], origins[1], directions[1])
    return RefractedPoints(points, gap)


@dataclass(frozen=True)
class KernelConstants:
    """Per jig: the two cameras' matrices ``K`` (px) and distortion coefficients (``None`` without
    distortion), and the refracting layers."""

    K: tuple[np.ndarray, np.ndarray]
    distortion: tuple[np.ndarray | None, np.ndarray | None]
    layers: FlatLayers


def kernel_constants(jig: JigConfig) -> KernelConstants:
    """The triangulation's constants of this jig (an estimator builds them once)."""
    cams = jig.cameras.left, jig.cameras.right
    K = tuple(np.asarray(cam.K, dtype=float) for cam in cams)
    distortion = tuple(
        np.asarray(cam.distortion, dtype=float) if np.any(cam.distortion) else None for cam in cams
    )
    for array in (*K, *(d for d in distortion if d is not None)):
        array.flags.writeable = False
    return KernelConstants(K, distortion, flat_layers(jig))


def _as_pixels(xy_px: np.ndarray, name: str) -> np.ndarray:
    """``xy_px`` as a finite float (M, 2) array, or an InputError naming the argument."""
    xy = np.asarray(xy_px, dtype=float)
    if xy.ndim == 1 and xy.size == 0:
        xy = xy.reshape(0, 2)
    if xy.ndim != 2 or xy.shape[1] != 2:
        raise InputError(f"{name} must be an (M, 2) array of pixel coordinates (u, v), got shape {xy.shape}")
    if not np.isfinite(xy).all():
        raise InputError(f"{name} contains NaN or infinite coordinates: drop those markers first")
    return xy
