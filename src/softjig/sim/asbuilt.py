"""The as-built jig: the nominal config perturbed within its documented tolerances.

A real jig never matches its drawing; the paper's calibration (offsets ``Ox, Oy`` and scale ``S``) exists
for that. The simulator renders every run from an :class:`AsBuiltJig` drawn from a seed, while the
estimator only ever knows the nominal config. Each tolerance in :class:`~softjig.config.ToleranceConfig`
is the standard deviation of a zero-mean normal error, drawn independently per axis:

- the stereo head (both cameras, rigidly) is moved by ``camera_position_mm`` per axis and rotated about
  its centre by ``camera_rotation_deg`` per axis (how it sits under the plate);
- the focal lengths are scaled by ``1 + focal_fraction`` error and the principal point moved by
  ``principal_point_px`` (per axis), the same for both cameras: a rectified pair's images are resampled
  to one shared intrinsic matrix, so the stereo calibration's residual error is common to both views
  (the pair stays rectified; its depth scale and the image centre are off);
- the plate's and the oil's refractive indices are off by ``refractive_index``;
- each marker sits ``marker_placement_mm`` (per axis) away from its nominal place
  (:func:`softjig.jig_shape.marker_layout_xy`: the mould's grid, or an explicit or surveyed list); the
  rest shape is the nominal dome profile, whatever its kind (:mod:`softjig.jig_shape`).

The per-frame effects (membrane ripple, edge conformity) are applied by the renderer, from the same
tolerances.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.spatial.transform import Rotation

from softjig.config import CameraConfig, JigConfig, StereoConfig
from softjig.jig_shape import marker_layout_xy


@dataclass(frozen=True)
class AsBuiltJig:
    """A jig as it was built: its (perturbed) config and where each marker really is.

    Attributes
    ----------
    jig : the perturbed config (cameras, refractive indices).
    marker_xy_mm : (N, 2) each marker's real ``(x, y)`` on the rest membrane, in J (mm).
    """

    jig: JigConfig
    marker_xy_mm: np.ndarray


def nominal_as_built(jig: JigConfig) -> AsBuiltJig:
    """The jig exactly as designed (what a zero tolerance draws)."""
    return AsBuiltJig(jig=jig, marker_xy_mm=marker_layout_xy(jig))


def draw_as_built(nominal: JigConfig, rng: np.random.Generator | int | None = None) -> AsBuiltJig:
    """Draw an as-built jig from the nominal one and its ``tolerances`` (see the module docstring).

    Parameters
    ----------
    nominal : the jig as designed.
    rng : seed or generator; the same seed gives the same jig.
    """
    rng = np.random.default_rng(rng)
    tol = nominal.tolerances
    left, right = nominal.cameras.left, nominal.cameras.right
    head_center = (np.asarray(left.position_mm) + np.asarray(right.position_mm)) / 2.0
    head_rotation = Rotation.from_rotvec(np.radians(rng.normal(0.0, tol.camera_rotation_deg, 3)))
    head_shift = rng.normal(0.0, tol.camera_position_mm, 3)

    focal = 1.0 + rng.normal(0.0, tol.focal_fraction)
    principal = rng.normal(0.0, tol.principal_point_px, 2)

    def perturb(cam: CameraConfig) -> CameraConfig:
        position = head_center + head_rotation.apply(np.asarray(cam.position_mm) - head_center)
        rotation = head_rotation * Rotation.from_rotvec(np.radians(cam.rotation_deg))
        return replace(
            cam,
            position_mm=tuple(float(v) for v in position + head_shift),
            rotation_deg=tuple(float(v) for v in np.degrees(rotation.as_rotvec())),
            fx_px=cam.fx_px * focal,
            fy_px=cam.fy_px * focal,
            cx_px=cam.cx_px + float(principal[0]),
            cy_px=cam.cy_px + float(principal[1]),
        )

    cameras = StereoConfig(
        left=perturb(left),
        right=perturb(right),
        rectified=nominal.cameras.rectified,
    )
    plate = replace(
        nominal.plate, refractive_index=nominal.plate.refractive_index + rng.normal(0.0, tol.refractive_index)
    )
    medium = replace(
        nominal.medium,
        oil_refractive_index=nominal.medium.oil_refractive_index + rng.normal(0.0, tol.refractive_index),
    )
    xy = marker_layout_xy(nominal)
    xy = xy + rng.normal(0.0, tol.marker_placement_mm, xy.shape)
    jig = replace(nominal, name=f"{nominal.name} (as built)", cameras=cameras, plate=plate, medium=medium)
    return AsBuiltJig(jig=jig, marker_xy_mm=xy)
