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
of two rays (:func:`closest_points_of_rays`); :func:`triangulate_refracted` runs both for all markers in
one compiled loop (:func:`softjig.sensing._refractive_kernels.triangulate`). The general trace through
each interface (:func:`softjig.optics.backproject_pixels`) is the tests' oracle.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from softjig.config import CameraConfig, JigConfig
from softjig.errors import InputError
from softjig.optics import FlatLayers, layer_constants, pixels_to_normalized
from softjig.rig import flat_layers
from softjig.sensing._refractive_kernels import PARALLEL_SIN2, triangulate
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
    pixels = [left_xy, right_xy]
    for i, camera in enumerate(k.distorted):  # undistorted first; the kernel's intrinsics are then 1
        if camera is not None:
            pixels[i] = pixels_to_normalized(pixels[i], camera.K, camera.distortion)
    poses = np.stack([frame.T_J_left, frame.T_J_right])
    below = poses[:, 2, 3] < k.z_if[0]
    if not below.all():
        raise ValueError(
            f"camera centre z = {poses[:, 2, 3].max()} mm must lie in region 0, strictly below the lowest "
            f"interface z = {k.z_if[0]} mm"
        )
    points = np.empty((len(left_xy), 3))
    gap = np.empty(len(left_xy))
    triangulate(pixels[0], pixels[1], k.intrinsics, poses, k.z_if, k.ratio, points, gap)
    return RefractedPoints(points, gap)


@dataclass(frozen=True)
class KernelConstants:
    """Per jig: each camera's ``(fx, fy, cx, cy)`` (px; ``(1, 1, 0, 0)`` for a camera with distortion,
    whose pixels are undistorted first), those cameras (or ``None``), and the layers' interface heights
    (mm) and ``n_0 / n_i`` per region."""

    intrinsics: np.ndarray
    distorted: tuple[CameraConfig | None, CameraConfig | None]
    z_if: np.ndarray
    ratio: np.ndarray


def kernel_constants(
    jig: JigConfig, layers: FlatLayers | None = None, *, arrays: dict[str, np.ndarray] | None = None
) -> KernelConstants:
    """The kernel's constants of this jig (an estimator builds them once) from its :func:`kernel_arrays`
    (derived here when not given, with ``layers``: its :func:`~softjig.rig.flat_layers`, made here when
    not given)."""
    a = arrays if arrays is not None else kernel_arrays(jig, layers)
    cams = jig.cameras.left, jig.cameras.right
    distorted = tuple(cam if any(cam.distortion) else None for cam in cams)
    return KernelConstants(
        a["triangulation.intrinsics"], distorted, a["triangulation.z_if"], a["triangulation.ratio"]
    )


def kernel_arrays(jig: JigConfig, layers: FlatLayers | None = None) -> dict[str, np.ndarray]:
    """The arrays of :func:`kernel_constants`, by name (``triangulation.*``), read-only: each camera's
    ``(fx, fy, cx, cy)`` (``(1, 1, 0, 0)`` for a camera with distortion), the layers' interface heights
    and ``n_0 / n_i`` per region."""
    cams = jig.cameras.left, jig.cameras.right
    intrinsics = np.array(
        [(1.0, 1.0, 0.0, 0.0) if any(c.distortion) else (c.fx_px, c.fy_px, c.cx_px, c.cy_px) for c in cams]
    )
    intrinsics.flags.writeable = False
    z_if, ratio, _, _ = layer_constants(layers if layers is not None else flat_layers(jig))
    return {"triangulation.intrinsics": intrinsics, "triangulation.z_if": z_if, "triangulation.ratio": ratio}


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
