"""The jig seen from above by a robot's hand-eye camera: the oracle of the jig-to-robot alignment tests.

The scene is the base plate's top face (``z = alignment.z_mm`` in J) with the four white alignment
circles (``alignment.circle_centers_mm``, ``alignment.circle_diameter_mm``), the black membrane's
footprint in the middle (its dome is not modelled: the circles lie outside its footprint, so it hides
none of them from a camera above the jig), the grey plate around it and a lighter table beyond the
plate. Rendering is by inverse mapping with ``S x S`` sub-samples per pixel, each undistorted exactly
(:func:`softjig.sim.chessboard.camera_rays`), cast from the camera's centre and intersected with the
plate's plane, so the circles' images (ellipses) are area-sampled and exact. The cameras are in air.
"""

from __future__ import annotations

import numpy as np

from softjig.config import CameraConfig, JigConfig
from softjig.sim.chessboard import camera_rays

__all__ = ["render_handeye_view"]

_CIRCLE, _PLATE, _MEMBRANE, _TABLE = 0.9, 0.22, 0.05, 0.45


def render_handeye_view(
    jig: JigConfig,
    camera: CameraConfig,
    T_J_cam: np.ndarray,
    *,
    supersampling: int = 4,
    noise_std: float = 0.0,
    rng: np.random.Generator | int | None = None,
) -> np.ndarray:
    """Render the hand-eye camera's view of the jig from above.

    Parameters
    ----------
    jig : the jig (plate size, membrane footprint, alignment circles).
    camera : the hand-eye camera's intrinsics and distortion (its pose fields are not used).
    T_J_cam : (4, 4) the hand-eye camera's pose in J (mm); it must be above the plate, looking down.
    supersampling : sub-samples per pixel side.
    noise_std : Gaussian sensor noise (fraction of full scale).
    rng : seed or generator of the noise.

    Returns
    -------
    (H, W) uint8 image.
    """
    qx, qy = camera_rays(camera, supersampling)
    T = np.asarray(T_J_cam, float)
    R, c = T[:3, :3], T[:3, 3]
    f = np.float32
    al = jig.alignment
    dz = qx * f(R[2, 0]) + qy * f(R[2, 1]) + f(R[2, 2])
    with np.errstate(divide="ignore", invalid="ignore"):
        lam = f(al.z_mm - c[2]) / dz
    x = f(c[0]) + lam * (qx * f(R[0, 0]) + qy * f(R[0, 1]) + f(R[0, 2]))
    y = f(c[1]) + lam * (qx * f(R[1, 0]) + qy * f(R[1, 1]) + f(R[1, 2]))
    on_plate = (np.abs(x) <= jig.plate.size_x_mm / 2) & (np.abs(y) <= jig.plate.size_y_mm / 2)
    value = np.where(on_plate, f(_PLATE), f(_TABLE))
    value[x * x + y * y <= f(jig.membrane.footprint_radius_mm**2)] = _MEMBRANE
    r2 = f((al.circle_diameter_mm / 2) ** 2)
    for cx, cy in al.circle_centers_mm:
        value[(x - f(cx)) ** 2 + (y - f(cy)) ** 2 <= r2] = _CIRCLE
    value[~(lam > 0)] = _TABLE
    image = value.mean(axis=2)
    if noise_std > 0:
        image = image + np.random.default_rng(rng).normal(0.0, noise_std, image.shape)
    return np.clip(np.round(image * 255.0), 0, 255).astype(np.uint8)
