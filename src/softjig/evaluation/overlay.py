"""A picture of what the pipeline did: markers, matches, the crop and the normal over the stereo pair.

Pure drawing: arrays in, an RGB ``uint8`` array out (the CLI writes it to a file). Like the paper's figure
of blurred markers, detections are circled; colours say what became of each marker:

- red circle: detected, not matched between the images;
- green circle: matched (the same colour in both images);
- yellow dot: matched and used in the plane fit (inside the paper's crop, or in contact);
- orange dot (``refractive``): inside the contact footprint and pushed in (by more than
  :data:`OUTLIER_SIGMAS` times the indentation noise), but rejected by the robust fit (an outlier);
- red cross (``refractive``): matched, but left out as in doubt (its depth unknown): its point lies off
  the membrane, or in one image it does not look like a marker (a glint or a bubble over it,
  :meth:`~softjig.sensing.detect.Markers.lopsided`);
- cyan outline: what was fitted: the paper's crop (the part's base radius around the jig axis, at the
  fitted plane's height), or the contact footprint found by the refractive method;
- magenta arrow: the fitted plane's normal (before any tilt calibration) from the plane at the centre of
  the crop or of the contact, its tilt exaggerated :data:`TILT_EXAGGERATION` times: the cameras look
  along the normal, so the true one projects to a few pixels. The tip is the point
  ``base + L (F n_x, F n_y, n_z)`` (``L`` = :data:`NORMAL_LENGTH_MM`, ``F`` the exaggeration), drawn
  at least :data:`MIN_ARROW_PX` long; a white ring marks the base.

A legend (the colours, the exaggeration, the method) is drawn in the top right corner of the right
image, and the estimate's numbers along the top of the left one.

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

RED, GREEN, YELLOW, ORANGE, CYAN, MAGENTA, WHITE = (
    (230, 40, 40),
    (40, 220, 60),
    (255, 230, 0),
    (255, 140, 0),
    (0, 220, 255),
    (255, 0, 255),
    (255, 255, 255),
)
NORMAL_LENGTH_MM = 30.0
#: How many times the drawn normal's tilt is exaggerated (its lateral component, see the module docstring).
TILT_EXAGGERATION = 5.0
#: A marker pushed in by more than this many indentation noise sigmas but not fitted is drawn as an
#: outlier (at one sigma, a sixth of the markers at rest would be).
OUTLIER_SIGMAS = 3.0
#: The drawn arrow's least length (px): a part pressed flat still shows where its normal starts.
MIN_ARROW_PX = 40


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

    if result.indentation is not None and result.contact is not None:
        # Inside the footprint, clearly pushed in, yet not fitted: the robust fit's outliers.
        pushed = np.asarray(result.indentation.depth_mm) > OUTLIER_SIGMAS * result.indentation.noise_mm
        footprint = np.asarray(result.contact.outline_xy_mm, dtype=np.float32).reshape(-1, 1, 2)
        for k in np.flatnonzero(pushed & ~np.asarray(result.used, bool)):
            x, y = (float(v) for v in result.points_J[k, :2])
            if cv2.pointPolygonTest(footprint, (x, y), False) < 0:
                continue
            cv2.circle(canvas_left, _pt(result.left.xy_px[result.matches.left_index[k]]), 2, ORANGE, -1)
            cv2.circle(canvas_right, _pt(result.right.xy_px[result.matches.right_index[k]]), 2, ORANGE, -1)
    if result.indentation is not None:
        for k in np.flatnonzero(np.isnan(result.indentation.depth_mm)):  # in doubt: left out
            for canvas, xy in (
                (canvas_left, result.left.xy_px[result.matches.left_index[k]]),
                (canvas_right, result.right.xy_px[result.matches.right_index[k]]),
            ):
                cv2.drawMarker(canvas, _pt(xy), RED, cv2.MARKER_TILTED_CROSS, 2 * radius, 2, cv2.LINE_AA)

    est, plane = result.estimate, result.plane
    if result.contact is not None:
        outline = np.asarray(result.contact.outline_xy_mm, dtype=float)
    else:
        angles = np.linspace(0, 2 * np.pi, 73)
        radius = (est.part_diameter_mm or 0.0) / 2.0
        outline = radius * np.column_stack([np.cos(angles), np.sin(angles)])
    ring = np.column_stack([outline, plane.heights_mm(outline[:, 0], outline[:, 1])])
    ring_px = _project_left(ring, result, jig)
    cv2.polylines(canvas_left, [np.round(ring_px).astype(np.int32)], True, CYAN, 1, cv2.LINE_AA)
    base_px, tip_px = normal_arrow_px(result, jig)
    cv2.circle(canvas_left, _pt(base_px), 6, WHITE, 2, cv2.LINE_AA)
    cv2.arrowedLine(canvas_left, _pt(base_px), _pt(tip_px), MAGENTA, 3, cv2.LINE_AA, tipLength=0.25)
    text = (
        f"Ax {est.tilt_x_deg:+.2f} deg  Ay {est.tilt_y_deg:+.2f} deg  push {est.push_depth_mm:.2f} mm  "
        f"{est.n_points} pts  rms {est.rms_residual_mm:.3f} mm  frame: {est.frame_source}"
    )
    _text(canvas_left, text, (10, 30), scale=0.8)
    _legend(canvas_right, est.method)
    return np.concatenate([canvas_left, canvas_right], axis=1)


def normal_arrow_px(result: SensingResult, jig: JigConfig) -> tuple[np.ndarray, np.ndarray]:
    """The drawn normal's base and tip in the left image (px): from the fitted plane above the contact's
    centroid (the jig axis for the paper's crop) along the normal with its tilt exaggerated
    :data:`TILT_EXAGGERATION` times, at least :data:`MIN_ARROW_PX` long (a flat part's arrow points
    along the image's ``+x`` then)."""
    plane = result.plane
    centre = np.zeros(2) if result.contact is None else np.asarray(result.contact.centroid_xy_mm, float)
    base = np.array([centre[0], centre[1], plane.z_at(*centre)])
    n = np.asarray(plane.normal, dtype=float)
    shown = np.array([TILT_EXAGGERATION * n[0], TILT_EXAGGERATION * n[1], n[2]])
    base_px, tip_px = _project_left(np.array([base, base + NORMAL_LENGTH_MM * shown]), result, jig)
    step = tip_px - base_px
    length = float(np.hypot(*step))
    if length < MIN_ARROW_PX:
        step = step / length * MIN_ARROW_PX if length > 1e-9 else np.array([MIN_ARROW_PX, 0.0])
    return base_px, base_px + step


def _text(canvas: np.ndarray, text: str, origin: tuple[int, int], colour=WHITE, scale: float = 0.6) -> None:
    """Text with a dark outline, readable on any background."""
    thick = max(round(scale / 0.5), 1)
    cv2.putText(canvas, text, origin, cv2.FONT_HERSHEY_SIMPLEX, scale, (0, 0, 0), thick + 2, cv2.LINE_AA)
    cv2.putText(canvas, text, origin, cv2.FONT_HERSHEY_SIMPLEX, scale, colour, thick, cv2.LINE_AA)


def _legend(canvas: np.ndarray, method: str) -> None:
    """The colours' meaning in a dark box in the top right corner of ``canvas`` (drawn in place)."""
    items = [
        ("circle", RED, "detected, not matched"),
        ("circle", GREEN, "matched left/right"),
        ("dot", YELLOW, "used in the plane fit" + (" (in contact)" if method == "refractive" else "")),
    ]
    if method == "refractive":
        items.append(("dot", ORANGE, "in contact, not fitted (outlier)"))
        items.append(("cross", RED, "matched, left out (in doubt)"))
    items += [
        ("line", CYAN, "contact outline" if method == "refractive" else "crop (part's radius)"),
        ("arrow", MAGENTA, f"normal, tilt x{TILT_EXAGGERATION:g}"),
    ]
    # Sized to the image (1.0 for 720 px high), so it stays readable when the pair is shown scaled down.
    f = max(canvas.shape[0] / 720.0, 0.5) * 1.3
    row_px, width_px = round(24 * f), round(330 * f)
    height_px = row_px * (len(items) + 1) + round(8 * f)
    w = canvas.shape[1]
    x0, y0 = max(w - width_px - 10, 0), 10
    box = canvas[y0 : y0 + height_px, x0 : x0 + width_px]
    box[:] = (box.astype(np.float32) * 0.25).astype(np.uint8)  # darkened, the markers still faintly seen
    _text(canvas, f"legend ({method} method)", (x0 + round(8 * f), y0 + round(20 * f)), scale=0.55 * f)
    for k, (kind, colour, label) in enumerate(items, start=1):
        cy, cx = y0 + round((20 + k * 24 - 5) * f), x0 + round(20 * f)
        if kind == "circle":
            cv2.circle(canvas, (cx, cy), round(7 * f), colour, max(round(f), 1), cv2.LINE_AA)
        elif kind == "dot":
            cv2.circle(canvas, (cx, cy), round(3 * f), colour, -1)
        elif kind == "cross":
            cv2.drawMarker(canvas, (cx, cy), colour, cv2.MARKER_TILTED_CROSS, round(12 * f), max(round(f), 1))
        elif kind == "line":
            cv2.line(
                canvas,
                (cx - round(10 * f), cy),
                (cx + round(10 * f), cy),
                colour,
                max(round(f), 1),
                cv2.LINE_AA,
            )
        else:
            cv2.arrowedLine(
                canvas,
                (cx - round(12 * f), cy),
                (cx + round(14 * f), cy),
                colour,
                3,
                cv2.LINE_AA,
                tipLength=0.4,
            )
        _text(canvas, label, (x0 + round(42 * f), cy + round(5 * f)), scale=0.5 * f)
