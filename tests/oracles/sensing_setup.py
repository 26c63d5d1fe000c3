"""Oracle of :func:`softjig.sensing.setup.sensing_setup`'s projections: each set of points projected by a
call of its own (:func:`softjig.optics.project_points`, :func:`softjig.optics.projection_jacobian`), as the
set-up did before it solved them together."""

from __future__ import annotations

import numpy as np

from softjig.config import JigConfig
from softjig.geometry import transform_points
from softjig.jig_shape import marker_layout_xy, rest_inner_height_mm
from softjig.optics import project_points, projection_jacobian
from softjig.rig import flat_layers
from softjig.sensing.setup import pinhole_triangulation


def setup_projections(jig: JigConfig) -> tuple[float, float, float, float]:
    """The apex's px per mm (left camera), the markers' smallest and largest disparity between the rest
    membrane and the plate (px, before the margin), and the rest apex's height as the pinhole
    triangulation sees it (mm)."""
    left, right = jig.cameras.left, jig.cameras.right
    layers = flat_layers(jig)
    apex = np.array([[0.0, 0.0, jig.membrane.dome_height_mm]])
    jac = projection_jacobian(apex, left.K, left.distortion, left.T_J_cam, layers)[0][:, :2]
    px_per_mm = float(np.mean(np.linalg.svd(jac, compute_uv=False)))
    xy = marker_layout_xy(jig)
    z_rest = rest_inner_height_mm(jig, xy[:, 0], xy[:, 1])
    points = np.concatenate([np.column_stack([xy, z_rest]), np.column_stack([xy, np.zeros(len(xy))])])
    u_left = project_points(points, left.K, left.distortion, left.T_J_cam, layers)
    u_right = project_points(points, right.K, right.distortion, right.T_J_cam, layers)
    disparity = u_left[:, 0] - u_right[:, 0]
    pl = project_points(apex, left.K, left.distortion, left.T_J_cam, layers)
    pr = project_points(apex, right.K, right.distortion, right.T_J_cam, layers)
    apex_z = float(transform_points(left.T_J_cam, pinhole_triangulation(pl, pr, jig))[0, 2])
    return px_per_mm, float(disparity.min()), float(disparity.max()), apex_z
