"""Live view and ``.rrd`` log through Rerun (the ``rerun`` extra: ``pip install 'softjig[rerun]'``).

:class:`RerunViewer` is a sink of the live loop (:mod:`softjig.live.loop`), beside the Foxglove one. Per
processed pair it logs, on the timelines ``frame`` (the source's pair counter) and ``capture_time``
(the pair's host wall-clock time):

=================================  ==============  ===============================================
entity                             archetype       content
=================================  ==============  ===============================================
``cameras/{left,right}/image``     ``Image``       the image (``L`` gray or ``RGB``)
``cameras/{left,right}/markers``   ``Points2D``    detected markers (yellow)
``cameras/{left,right}/fitted``    ``Points2D``    those fitted (green)
``jig/markers``                    ``Points3D``    triangulated markers in J (mm); fitted green
``jig/contact``                    ``LineStrips3D`` the contact footprint's outline on the fitted
                                                   plane (``refractive``)
``jig/normal``                     ``Arrows3D``    the reported normal, 40 mm long, from the face
                                                   point (the contact centroid on the plane)
``jig/cam_left``, ``jig/cam_right``  ``Transform3D``  the cameras' poses in J
``estimate/...``                   ``Scalars``     tilt_x_deg, tilt_y_deg, push_depth_mm, latency_ms
``log``                            ``TextLog``     frames without an estimate (the error), health
=================================  ==============  ===============================================

Units: J in millimetres (``DESIGN.md`` §1; Rerun has no unit). Pixels: softjig puts the centre of
pixel ``(0, 0)`` at ``(0, 0)``, Rerun at ``(0.5, 0.5)``; markers are shifted by half a pixel here, at
the edge. ``rerun`` is imported only when a viewer is created.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from softjig.errors import InputError

__all__ = ["NORMAL_ARROW_MM", "RERUN_PIXEL_OFFSET", "RerunViewer"]

#: Rerun's image coordinates of softjig's pixel ``(u, v)`` are ``(u, v) + RERUN_PIXEL_OFFSET``.
RERUN_PIXEL_OFFSET = 0.5
#: Length of the drawn normal (mm).
NORMAL_ARROW_MM = 40.0

_YELLOW, _GREEN, _GREY = (255, 217, 0), (26, 230, 51), (150, 150, 150)


def _import_rerun() -> Any:
    try:
        import rerun
    except ImportError:
        raise InputError("the Rerun view needs the Rerun SDK: pip install 'softjig[rerun]'") from None
    return rerun


class RerunViewer:
    """Log the live loop to Rerun: a spawned viewer, an ``.rrd`` file, or both.

    Parameters
    ----------
    save_path : the ``.rrd`` file to write (the recording is streamed into it as it goes, so a killed
        run leaves what was logged until then).
    spawn : start a Rerun viewer and stream to it.
    images : log the images (the bulk of the data).
    overwrite : replace an existing ``.rrd`` file (never anything else).
    application_id : Rerun's application id of the recording.
    """

    def __init__(
        self,
        *,
        save_path: str | Path | None = None,
        spawn: bool = False,
        images: bool = True,
        overwrite: bool = False,
        application_id: str = "softjig",
    ) -> None:
        if save_path is None and not spawn:
            raise InputError("a Rerun view needs a viewer (--rerun), a file (--rerun-save FILE.rrd), or both")
        path = None if save_path is None else Path(save_path)
        if path is not None:
            if path.suffix != ".rrd":
                raise InputError(f"--rerun-save {path}: give a file name ending in .rrd")
            if path.is_dir():
                raise InputError(f"--rerun-save {path} is a folder: give a file name such as run.rrd")
            if path.exists() and not overwrite:
                raise InputError(f"{path} exists: choose another .rrd file name or pass --overwrite")
            path.parent.mkdir(parents=True, exist_ok=True)
        rr = _import_rerun()
        self._rr = rr
        self.images = images
        self.path = path
        self.rec = rr.RecordingStream(application_id)
        sinks = []
        if path is not None:
            sinks.append(rr.FileSink(str(path)))
        if spawn:  # pragma: no cover - starts a GUI viewer process
            try:
                self.rec.spawn(connect=False)
            except Exception as exc:  # the SDK raises its own error types
                raise InputError(f"cannot start the Rerun viewer: {exc}") from None
            sinks.append(rr.GrpcSink())
        self.rec.set_sinks(*sinks)
        self.rec.log("jig", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)

    # -- sink interface
    def on_frame(self, outcome: Any, message: dict[str, Any]) -> None:
        """Log one processed pair: images, markers, points, contact outline, normal and scalars."""
        rr, rec = self._rr, self.rec
        frame = outcome.frame
        rec.set_time("frame", sequence=int(frame.seq))
        rec.set_time("capture_time", timestamp=float(frame.wall_time_s))
        if self.images:
            for side, image in (("left", frame.left), ("right", frame.right)):
                model = "L" if np.ndim(image) == 2 else "RGB"
                rec.log(f"cameras/{side}/image", rr.Image(np.ascontiguousarray(image), color_model=model))
        if outcome.latency_s is not None:
            rec.log("estimate/latency_ms", rr.Scalars(1000.0 * float(outcome.latency_s)))
        result = outcome.result
        if result is None:
            rec.log("log", rr.TextLog(f"frame {frame.seq}: {outcome.error}", level="WARN"))
            return
        used = np.asarray(result.used, dtype=bool)
        li = result.matches.left_index[used]
        ri = result.matches.right_index[used]
        for side, markers, idx in (("left", result.left, li), ("right", result.right, ri)):
            xy = np.asarray(markers.xy_px, dtype=float) + RERUN_PIXEL_OFFSET
            rec.log(f"cameras/{side}/markers", rr.Points2D(xy, colors=_YELLOW, radii=2.5))
            rec.log(f"cameras/{side}/fitted", rr.Points2D(xy[idx], colors=_GREEN, radii=4.0))
        points = np.asarray(result.points_J, dtype=float)
        colors = np.where(used[:, None], np.array(_GREEN), np.array(_GREY)).astype(np.uint8)
        rec.log("jig/markers", rr.Points3D(points, colors=colors, radii=0.4))
        plane = result.plane
        contact = result.contact
        if contact is not None and len(contact.outline_xy_mm) >= 3:
            xy = np.asarray(contact.outline_xy_mm, dtype=float)
            ring = np.column_stack([xy, plane.heights_mm(xy[:, 0], xy[:, 1])])
            rec.log("jig/contact", rr.LineStrips3D([np.vstack([ring, ring[:1]])], colors=(255, 120, 0)))
            cx, cy = contact.centroid_xy_mm
        else:
            rec.log("jig/contact", rr.Clear(recursive=False))
            cx, cy = 0.0, 0.0
        est = result.estimate
        origin = np.array([cx, cy, plane.z_at(cx, cy)])
        normal = np.asarray(est.normal, dtype=float)
        rec.log(
            "jig/normal",
            rr.Arrows3D(origins=[origin], vectors=[NORMAL_ARROW_MM * normal], colors=(255, 77, 26)),
        )
        for name, T in (("cam_left", result.frame.T_J_left), ("cam_right", result.frame.T_J_right)):
            T = np.asarray(T, dtype=float)
            rec.log(f"jig/{name}", rr.Transform3D(translation=T[:3, 3], mat3x3=T[:3, :3]))
        for key in ("tilt_x_deg", "tilt_y_deg", "push_depth_mm"):
            rec.log(f"estimate/{key}", rr.Scalars(float(getattr(est, key))))

    def on_health(self, message: dict[str, Any]) -> None:
        """Log a health message as a text line."""
        self.rec.log("log", self._rr.TextLog(json.dumps(message, default=str), level="INFO"))

    def close(self) -> None:
        """Flush and finish the recording (idempotent)."""
        rec, self.rec = self.rec, None
        if rec is not None:
            rec.flush()
            rec.disconnect()
