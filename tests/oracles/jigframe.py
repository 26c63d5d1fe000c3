"""The jig frame the straightforward way: ArUco's detector on the whole images, SciPy's least squares."""

from __future__ import annotations

import cv2
import numpy as np
from scipy.optimize import least_squares

from softjig.config import JigConfig
from softjig.geometry import invert_pose, pose_from_rotvec_translation
from softjig.optics import project_points
from softjig.sensing.fiducials import detect_fiducials, fiducial_corners_J
from softjig.sensing.jigframe import JigFrame


def jig_frame(left_u8: np.ndarray, right_u8: np.ndarray, jig: JigConfig) -> JigFrame | None:
    """The cameras' poses in J minimising every fiducial corner's reprojection error in both images (the
    right camera at its configured pose relative to the left one), with the ids found in both images and
    the RMS error (quads in the config's order); ``None`` if fewer than two fiducials are found in either
    image."""
    found = [detect_fiducials(image, jig.fiducials) for image in (left_u8, right_u8)]
    if min(len(f) for f in found) < 2:
        return None
    corners_J = dict(zip(jig.fiducials.ids, fiducial_corners_J(jig.fiducials), strict=True))
    cams = (jig.cameras.left, jig.cameras.right)
    T_left_right = invert_pose(cams[0].T_J_cam) @ cams[1].T_J_cam
    obj = [np.concatenate([corners_J[i] for i in f]) for f in found]
    img = [np.concatenate([f[i] for i in f]) for f in found]

    def residuals(x: np.ndarray) -> np.ndarray:
        T_J_left = invert_pose(pose_from_rotvec_translation(x[:3], x[3:]))
        out = []
        for cam, T, points, pixels in zip(cams, (T_J_left, T_J_left @ T_left_right), obj, img, strict=True):
            out.append((project_points(points, cam.K, cam.distortion, T, None) - pixels).ravel())
        return np.concatenate(out)

    T0 = invert_pose(cams[0].T_J_cam)  # start from the config's pose
    x0 = np.concatenate([cv2.Rodrigues(T0[:3, :3])[0].ravel(), T0[:3, 3]])
    fit = least_squares(residuals, x0, xtol=1e-15, ftol=1e-15, gtol=1e-15)
    rms = float(np.sqrt(np.mean(fit.fun**2)))
    both = tuple(sorted(set(found[0]) & set(found[1])))
    T_J_left = invert_pose(pose_from_rotvec_translation(fit.x[:3], fit.x[3:]))
    quads = [np.array([f[i] for i in jig.fiducials.ids if i in f]).reshape(-1, 4, 2) for f in found]
    return JigFrame(T_J_left, T_J_left @ T_left_right, "fiducials", rms, both, quads[0], quads[1])


def inside_fiducials(xy, quads, quiet_zone=1.0 / 3.0):
    """Which points lie on a grown quad: on the same side of all four edges of any of them, vectorised."""
    centres = quads.mean(axis=1, keepdims=True)
    grown = centres + (quads - centres) * (1.0 + quiet_zone)
    edges = np.roll(grown, -1, axis=1) - grown
    rel = xy[:, None, None, :] - grown[None]
    cross = edges[None, ..., 0] * rel[..., 1] - edges[None, ..., 1] * rel[..., 0]
    return (np.all(cross >= 0, axis=2) | np.all(cross <= 0, axis=2)).any(axis=1)
