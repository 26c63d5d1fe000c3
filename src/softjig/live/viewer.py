"""Live 3-D view and MCAP log through Foxglove (the ``viewer`` extra: ``pip install 'softjig[viewer]'``).

:class:`FoxgloveViewer` is a sink of the live loop (:mod:`softjig.live.loop`). It logs, per frame, on
Foxglove's well-known schemas:

========================  ======================  ================================================
topic                     schema                  content
========================  ======================  ================================================
``/left/image``           ``foxglove.RawImage``   the left image (``mono8``, ``mono16`` or ``rgb8``)
``/right/image``          ``foxglove.RawImage``   the right image
``/left/markers``         ``ImageAnnotations``    detected markers (yellow), those fitted (green)
``/right/markers``        ``ImageAnnotations``    the same in the right image
``/points``               ``foxglove.PointCloud`` triangulated markers in J (``x y z used``, float32)
``/plane``                ``SceneUpdate``         the fitted plane (a thin square) and the normal
                                                  (an arrow), both in J
``/tf``                   ``FrameTransforms``     the cameras' poses in J (``jig`` -> ``cam_left``...)
``/softjig/estimate``     JSON                    the estimate message of ``docs/live.md``
``/softjig/health``       JSON                    the health message
========================  ======================  ================================================

Foxglove's 3-D panel works in metres: positions are converted from softjig's millimetres here, at the
edge. The frame ``jig`` is J (``DESIGN.md`` §1). Sinks: an MCAP file (the log format ROS 2 and Foxglove
read; open it in the Foxglove app), a live WebSocket server the Foxglove app connects to
(``ws://127.0.0.1:8765``), or both. The WebSocket binds to the loopback interface unless
``allow_remote``. ``foxglove`` is imported only when a viewer is created.
"""

from __future__ import annotations

import ipaddress
from pathlib import Path
from typing import Any

import numpy as np

from softjig.errors import InputError

__all__ = ["FoxgloveViewer", "plane_square_pose"]

_MM = 1e-3  # metres per millimetre: Foxglove's unit is the metre


def _import_foxglove() -> Any:
    try:
        import foxglove
    except ImportError:
        raise InputError(
            "the live view and MCAP logs need the Foxglove SDK: pip install 'softjig[viewer]'"
        ) from None
    return foxglove


def plane_square_pose(normal: np.ndarray, point_mm: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Orientations that draw a plane and its normal (pure).

    Parameters
    ----------
    normal : (3,) unit normal in J.
    point_mm : (3,) a point of the plane in J (mm).

    Returns
    -------
    position_m : (3,) the point in metres.
    quat_plane_xyzw : the rotation taking ``+z`` to ``normal`` (a square's pose: its face is the plane).
    quat_arrow_xyzw : the rotation taking ``+x`` to ``normal`` (Foxglove's arrows point along ``+x``).
    """
    from scipy.spatial.transform import Rotation

    n = np.asarray(normal, dtype=float)
    n = n / np.linalg.norm(n)

    def align(axis: np.ndarray) -> np.ndarray:
        cross = np.cross(axis, n)
        dot = float(np.dot(axis, n))
        if np.linalg.norm(cross) < 1e-12:
            if dot > 0:
                return np.array([0.0, 0.0, 0.0, 1.0])
            perp = np.array([0.0, 1.0, 0.0]) if abs(axis[1]) < 0.9 else np.array([1.0, 0.0, 0.0])
            return Rotation.from_rotvec(np.pi * perp).as_quat()
        angle = np.arctan2(np.linalg.norm(cross), dot)
        return Rotation.from_rotvec(cross / np.linalg.norm(cross) * angle).as_quat()

    return (
        np.asarray(point_mm, dtype=float) * _MM,
        align(np.array([0.0, 0.0, 1.0])),
        align(np.array([1.0, 0.0, 0.0])),
    )


_MCAP_MAGIC = b"\x89MCAP"


def _is_mcap(path: Path) -> bool:
    """Whether ``path`` is a regular file starting with MCAP's magic bytes (or an empty file)."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(len(_MCAP_MAGIC))
    except OSError:
        return False
    return path.is_file() and head in (b"", _MCAP_MAGIC)


class FoxgloveViewer:
    """Log the live loop's images, markers, point cloud, plane and normal to Foxglove.

    Parameters
    ----------
    mcap_path : write an MCAP file there (refused if it exists unless ``overwrite``).
    serve : start a WebSocket server for the Foxglove app.
    host, port : where the server listens (``port=0``: any free port, see :attr:`port`).
    allow_remote : allow a non-loopback ``host``.
    images : log the images (large: 0.9 MB per gray 1280 x 720 image, before compression).
    overwrite : replace an existing MCAP file.
    """

    def __init__(
        self,
        *,
        mcap_path: str | Path | None = None,
        serve: bool = False,
        host: str = "127.0.0.1",
        port: int = 8765,
        allow_remote: bool = False,
        images: bool = True,
        overwrite: bool = False,
    ) -> None:
        if mcap_path is None and not serve:
            raise InputError("a viewer needs an MCAP file (--mcap FILE), a live server (--view), or both")
        try:
            loopback = host == "localhost" or ipaddress.ip_address(host).is_loopback
        except ValueError:
            loopback = False
        if not loopback and not allow_remote:
            raise InputError(
                f"the viewer would listen on {host}, reachable from other machines; use "
                "127.0.0.1, or pass --allow-remote on a trusted network"
            )
        foxglove = _import_foxglove()
        from foxglove import channels as ch

        self._fg = foxglove
        self.images = images
        self.context = foxglove.Context()
        self._mcap = None
        self._server = None
        if mcap_path is not None:
            path = Path(mcap_path)
            if path.exists() and not overwrite:
                raise InputError(f"{path} exists: choose another MCAP file name or overwrite it")
            if path.exists() and not _is_mcap(path):  # --overwrite replaces only what we wrote
                raise InputError(
                    f"{path} exists and is not an MCAP file: --overwrite replaces only an MCAP log; "
                    "choose another file name"
                )
            path.parent.mkdir(parents=True, exist_ok=True)
            self._mcap = foxglove.open_mcap(path, allow_overwrite=overwrite, context=self.context)
        if serve:
            try:
                self._server = foxglove.start_server(
                    name="softjig", host=host, port=port, context=self.context
                )
            except Exception as exc:  # the SDK raises its own error types
                self.close()
                raise InputError(f"cannot start the Foxglove server on {host}:{port}: {exc}") from None
        c = self.context
        self._image = {s: ch.RawImageChannel(f"/{s}/image", context=c) for s in ("left", "right")}
        self._markers = {s: ch.ImageAnnotationsChannel(f"/{s}/markers", context=c) for s in ("left", "right")}
        self._points = ch.PointCloudChannel("/points", context=c)
        self._scene = ch.SceneUpdateChannel("/plane", context=c)
        self._tf = ch.FrameTransformsChannel("/tf", context=c)
        self._estimate = foxglove.Channel(
            "/softjig/estimate", context=c, schema={"title": "softjig.estimate", "type": "object"}
        )
        self._health = foxglove.Channel(
            "/softjig/health", context=c, schema={"title": "softjig.health", "type": "object"}
        )

    @property
    def port(self) -> int | None:
        """The live server's port, or ``None`` without a server."""
        return None if self._server is None else int(self._server.port)

    # -- messages
    def _raw_image(self, image: np.ndarray, frame_id: str, stamp: Any) -> Any:
        from foxglove.messages import RawImage

        image = np.ascontiguousarray(image)
        if image.ndim == 2:
            encoding = "mono8" if image.dtype == np.uint8 else "mono16"
        else:
            encoding = "rgb8" if image.dtype == np.uint8 else "rgb16"
        if image.dtype == np.uint16:
            image = image.astype("<u2", copy=False)
        return RawImage(
            timestamp=stamp,
            frame_id=frame_id,
            width=image.shape[1],
            height=image.shape[0],
            encoding=encoding,
            step=image.strides[0],
            data=image.tobytes(),
        )

    def _annotations(self, xy_px: np.ndarray, used_xy_px: np.ndarray, text: str, stamp: Any) -> Any:
        from foxglove.messages import (
            Color,
            ImageAnnotations,
            Point2,
            PointsAnnotation,
            PointsAnnotationType,
            TextAnnotation,
        )

        def points(xy: np.ndarray, color: Any, thickness: float) -> Any:
            return PointsAnnotation(
                timestamp=stamp,
                type=PointsAnnotationType.Points,
                points=[Point2(x=float(u), y=float(v)) for u, v in xy],
                outline_color=color,
                fill_color=color,
                thickness=thickness,
            )

        return ImageAnnotations(
            points=[
                points(xy_px, Color(r=1.0, g=0.85, b=0.0, a=1.0), 5.0),
                points(used_xy_px, Color(r=0.1, g=0.9, b=0.2, a=1.0), 9.0),
            ],
            texts=[
                TextAnnotation(
                    timestamp=stamp,
                    position=Point2(x=20.0, y=40.0),
                    text=text,
                    font_size=28.0,
                    text_color=Color(r=1.0, g=1.0, b=1.0, a=1.0),
                    background_color=Color(r=0.0, g=0.0, b=0.0, a=0.6),
                )
            ],
        )

    def _point_cloud(self, points_mm: np.ndarray, used: np.ndarray, stamp: Any) -> Any:
        from foxglove.messages import PackedElementField, PackedElementFieldNumericType, PointCloud

        data = np.zeros((len(points_mm), 4), dtype="<f4")
        data[:, :3] = points_mm * _MM
        data[:, 3] = used
        f32 = PackedElementFieldNumericType.Float32
        fields = [PackedElementField(name=n, offset=4 * i, type=f32) for i, n in enumerate("xyz")]
        fields.append(PackedElementField(name="used", offset=12, type=f32))
        return PointCloud(
            timestamp=stamp, frame_id="jig", point_stride=16, fields=fields, data=data.tobytes()
        )

    def _scene_update(self, result: Any, stamp: Any) -> Any:
        from foxglove.messages import (
            ArrowPrimitive,
            Color,
            CubePrimitive,
            Pose,
            Quaternion,
            SceneEntity,
            SceneUpdate,
            Vector3,
        )

        est = result.estimate
        normal = np.asarray(est.normal, dtype=float)
        plane = result.plane
        point = np.array([0.0, 0.0, plane.z_at(0.0, 0.0)])
        position, q_plane, _ = plane_square_pose(plane.normal, point)  # the fitted plane's square
        _, _, q_normal = plane_square_pose(normal, point)  # the reported (calibrated) normal
        side_m = est.part_diameter_mm * _MM

        def pose(q: np.ndarray) -> Any:
            return Pose(
                position=Vector3(x=float(position[0]), y=float(position[1]), z=float(position[2])),
                orientation=Quaternion(x=float(q[0]), y=float(q[1]), z=float(q[2]), w=float(q[3])),
            )

        entity = SceneEntity(
            timestamp=stamp,
            frame_id="jig",
            id="plane",
            cubes=[
                CubePrimitive(
                    pose=pose(q_plane),
                    size=Vector3(x=side_m, y=side_m, z=0.3 * _MM),
                    color=Color(r=0.2, g=0.6, b=1.0, a=0.35),
                )
            ],
            arrows=[
                ArrowPrimitive(
                    pose=pose(q_normal),
                    shaft_length=40 * _MM,
                    shaft_diameter=1.5 * _MM,
                    head_length=8 * _MM,
                    head_diameter=4 * _MM,
                    color=Color(r=1.0, g=0.3, b=0.1, a=1.0),
                )
            ],
        )
        return SceneUpdate(entities=[entity])

    def _transforms(self, result: Any, stamp: Any) -> Any:
        from foxglove.messages import FrameTransform, FrameTransforms, Quaternion, Vector3
        from scipy.spatial.transform import Rotation

        out = []
        for name, T in (("cam_left", result.frame.T_J_left), ("cam_right", result.frame.T_J_right)):
            q = Rotation.from_matrix(np.asarray(T)[:3, :3]).as_quat()
            t = np.asarray(T)[:3, 3] * _MM
            out.append(
                FrameTransform(
                    timestamp=stamp,
                    parent_frame_id="jig",
                    child_frame_id=name,
                    translation=Vector3(x=float(t[0]), y=float(t[1]), z=float(t[2])),
                    rotation=Quaternion(x=float(q[0]), y=float(q[1]), z=float(q[2]), w=float(q[3])),
                )
            )
        return FrameTransforms(transforms=out)

    # -- sink interface
    def on_frame(self, outcome: Any, message: dict[str, Any]) -> None:
        """Log one processed pair, its markers, points, plane and normal, and the estimate message."""
        from foxglove.messages import Timestamp

        frame = outcome.frame
        log_time = int(frame.wall_time_s * 1e9)
        stamp = Timestamp.from_epoch_secs(frame.wall_time_s)
        if self.images:
            for side, image in (("left", frame.left), ("right", frame.right)):
                self._image[side].log(self._raw_image(image, f"cam_{side}", stamp), log_time=log_time)
        result = outcome.result
        if result is not None:
            est = result.estimate
            text = (
                f"Ax {est.tilt_x_deg:+.2f} deg  Ay {est.tilt_y_deg:+.2f} deg  "
                f"push {est.push_depth_mm:.2f} mm  n={est.n_points}"
            )
            li, ri = result.matches.left_index[result.used], result.matches.right_index[result.used]
            for side, markers, idx in (("left", result.left, li), ("right", result.right, ri)):
                annotations = self._annotations(markers.xy_px, markers.xy_px[idx], text, stamp)
                self._markers[side].log(annotations, log_time=log_time)
            self._points.log(self._point_cloud(result.points_J, result.used, stamp), log_time=log_time)
            self._scene.log(self._scene_update(result, stamp), log_time=log_time)
            self._tf.log(self._transforms(result, stamp), log_time=log_time)
        self._estimate.log(message, log_time=log_time)

    def on_health(self, message: dict[str, Any]) -> None:
        """Log a health message."""
        self._health.log(message, log_time=int(message["time_unix_s"] * 1e9))

    def close(self) -> None:
        """Finish the MCAP file (its summary and index) and stop the server."""
        if self._mcap is not None:
            self._mcap.close()
            self._mcap = None
        if self._server is not None:
            self._server.stop()
            self._server = None
