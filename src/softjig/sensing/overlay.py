"""A picture of what the pipeline did: markers, matches, the crop and the normal over the stereo pair.

Pure drawing: arrays in, an RGB ``uint8`` array out (the CLI writes it to a file). Like the paper's figure
of blurred markers, detections are circled; colours say what became of each marker:

- red circle: detected, not matched between the images;
- green circle: matched (the same colour in both images);
- yellow dot: matched and inside the crop, i.e. used in the plane fit;
- cyan outline: what was fitted: the paper's crop (the part's base radius around the jig axis, at the
  fitted plane's height), or the contact footprint found by the refractive method;
- magenta arrow: the fitted plane's normal (before any tilt calibration), 20 mm long, from the plane at
  the centre of the crop or of the contact.

Points in J are drawn where the method's own camera model puts them: through the refracting layers for
``refractive``, through air (the paper's pinhole model, the same space as its triangulated points) for
``paper``.
"""

from __future__ import annotations

import cv2
import numpy as np

from softjig.config import JigConfig
from softjig.optics import project_points
from softjig.rig import flat_layers
from softjig.sensing.detect import to_gray_float
from softjig.sensing.pipeline import SensingResult

RED, GREEN, YELLOW, CYAN, MAGENTA, WHITE = (
    (230, 40, 40),
    (40, 220, 60),
    (255, 230, 0),
    (0, 220, 255),
    (255, 0, 255),
    (255, 255, 255),
)
NORMAL_LENGTH_MM = 20.0


def _rgb8(image: np.ndarray) -> np.ndarray:
    gray = (to_gray_float(image) * 255.0 + 0.5).astype(np.uint8)
    return np.ascontiguousarray(np.repeat(gray[:, :, None], 3, axis=2))


def _project_left(points_J: np.ndarray, result: SensingResult, jig: JigConfig) -> np.ndarray:
    layers = flat_layers(jig) if result.estimate.method == "refractive" else None
    left = jig.cameras.left
    return project_points(points_J, left.K, left.distortion, result.frame.T_J_left, layers)


def _pt(xy: np.ndarray) -> tuple[int, int]:
    return round(float(xy[0])), round(float(xy[1]))


def draw_overlay(left: np.ndarray, right: np.ndarray, result: SensingResult, jig: JigConfig) -> np.ndarray:
    """Draw the pipeline's result over the stereo pair, side by side (left | right).

    Parameters
    ----------
    left, right : the input images (any dtype :func:`~softjig.sensing.detect.to_gray_float` accepts).
    result : what :func:`~softjig.sensing.pipeline.estimate_pair` returned for them.
    jig : the nominal jig the estimate used.

    Returns
    -------
    np.ndarray
        ``(H, 2 W, 3)`` RGB ``uint8`` image.
    """
    canvas_left, canvas_right = _rgb8(left), _rgb8(right)
    radius = max(round(float(np.sqrt(2.0) * result.left.sigma_px)), 2)
    matched_left = np.zeros(len(result.left), bool)
    matched_left[result.matches.left_index] = True
    matched_right = np.zeros(len(result.right), bool)
    matched_right[result.matches.right_index] = True
    for canvas, markers, matched in (
        (canvas_left, result.left, matched_left),
        (canvas_right, result.right, matched_right),
    ):
        for xy, ok in zip(markers.xy_px, matched, strict=True):
            cv2.circle(canvas, _pt(xy), radius, GREEN if ok else RED, 1, cv2.LINE_AA)
    for k in np.flatnonzero(result.used):
        cv2.circle(canvas_left, _pt(result.left.xy_px[result.matches.left_index[k]]), 2, YELLOW, -1)
        cv2.circle(canvas_right, _pt(result.right.xy_px[result.matches.right_index[k]]), 2, YELLOW, -1)

    est, plane = result.estimate, result.plane
    if result.contact is not None:
        outline = np.asarray(result.contact.outline_xy_mm, dtype=float)
        centre = np.asarray(result.contact.centroid_xy_mm, dtype=float)
    else:
        angles = np.linspace(0, 2 * np.pi, 73)
        radius = (est.part_diameter_mm or 0.0) / 2.0
        outline = radius * np.column_stack([np.cos(angles), np.sin(angles)])
        centre = np.zeros(2)
    ring = np.column_stack([outline, plane.heights_mm(outline[:, 0], outline[:, 1])])
    ring_px = _project_left(ring, result, jig)
    cv2.polylines(canvas_left, [np.round(ring_px).astype(np.int32)], True, CYAN, 1, cv2.LINE_AA)
    base = np.array([centre[0], centre[1], plane.z_at(*centre)])
    arrow = _project_left(np.array([base, base + NORMAL_LENGTH_MM * plane.normal]), result, jig)
    cv2.arrowedLine(canvas_left, _pt(arrow[0]), _pt(arrow[1]), MAGENTA, 2, cv2.LINE_AA, tipLength=0.2)
    text = (
        f"Ax {est.tilt_x_deg:+.2f} deg  Ay {est.tilt_y_deg:+.2f} deg  push {est.push_depth_mm:.2f} mm  "
        f"{est.n_points} pts  rms {est.rms_residual_mm:.3f} mm  frame: {est.frame_source}"
    )
    cv2.putText(canvas_left, text, (10, 24), cv2.FONT_HERSHEY_SIMPLEX, 0.6, WHITE, 1, cv2.LINE_AA)
    return np.concatenate([canvas_left, canvas_right], axis=1)
