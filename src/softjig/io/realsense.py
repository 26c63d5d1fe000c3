"""One Intel RealSense D4xx's two infrared imagers as the stereo pair: modes, device look-up, and the
conversion of the device's calibration (intrinsics, IR1 -> IR2 extrinsics) into a rig config.

The D4xx rectifies its infrared pair on the chip: both streams share one set of intrinsics, have no
distortion, and the right imager (infrared 2) lies on infrared 1's ``+x`` axis, about 50 mm away (D435).
librealsense's conventions: intrinsics ``fx, fy, ppx, ppy`` (px, the centre of pixel (0, 0) at (0, 0));
extrinsics ``get_extrinsics_to`` from stream A to stream B map a point of A's frame into B's,
``p_B = R p_A + t``, ``R`` column-major (9 floats), ``t`` in metres. Camera frames are OpenCV's.

:func:`rig_from_realsense` is pure; the other functions talk to librealsense (``pyrealsense2``, the
optional ``realsense`` extra).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from softjig.config import CameraConfig, JigConfig, StereoConfig
from softjig.errors import CameraError, InputError

__all__ = [
    "IR_FPS",
    "IR_MODES",
    "IRIntrinsics",
    "check_ir_mode",
    "config_from_realsense",
    "find_device",
    "infrared_profiles",
    "read_realsense_rig",
    "rig_from_realsense",
]

#: The D4xx infrared modes softjig streams (width, height), px, and the frame rates offered (Hz).
IR_MODES = ((848, 480), (1280, 720))
IR_FPS = (6, 15, 30, 60, 90)


@dataclass(frozen=True)
class IRIntrinsics:
    """One infrared stream's intrinsics as librealsense reports them (px; ``coeffs`` its 5 distortion
    coefficients, Brown-Conrady ``k1, k2, p1, p2, k3``, zero for the D4xx's rectified infrared)."""

    width: int
    height: int
    fx: float
    fy: float
    ppx: float
    ppy: float
    coeffs: tuple[float, float, float, float, float] = (0.0, 0.0, 0.0, 0.0, 0.0)


def check_ir_mode(width_px: int, height_px: int, fps: int) -> None:
    """Refuse a mode the D4xx's infrared does not offer (:class:`InputError` naming those it does)."""
    if (width_px, height_px) not in IR_MODES:
        modes = " or ".join(f"{w}x{h}" for w, h in IR_MODES)
        raise InputError(f"the RealSense infrared pair streams {modes}, not {width_px}x{height_px}")
    if fps not in IR_FPS:
        raise InputError(f"the RealSense infrared pair runs at {', '.join(map(str, IR_FPS))} fps, not {fps}")
    if (width_px, height_px) == (1280, 720) and fps > 30:
        raise InputError("the RealSense infrared pair runs 1280x720 at up to 30 fps (848x480 up to 90)")


def rig_from_realsense(
    base: JigConfig,
    left: IRIntrinsics,
    right: IRIntrinsics,
    rotation: Sequence[float],
    translation_m: Sequence[float],
) -> JigConfig:
    """The base jig with its cameras replaced by the D4xx's infrared pair.

    Parameters
    ----------
    base : the jig whose left camera's pose in J is kept (the runtime fiducials measure the real one).
    left, right : infrared 1's and infrared 2's intrinsics.
    rotation, translation_m : the extrinsics from infrared 1 to infrared 2 (librealsense's: ``p_2 = R
        p_1 + t``, ``R`` column-major 9 floats, ``t`` in m).

    Returns
    -------
    JigConfig
        ``cameras.rectified`` is true when the pair is the rectified one the D4xx delivers (same
        intrinsics, no distortion, no rotation, right imager on the left's ``+x`` axis), false otherwise
        (then the estimator rectifies).
    """
    R_21 = np.asarray(rotation, float).reshape(3, 3, order="F")
    t_21 = np.asarray(translation_m, float).reshape(3) * 1000.0  # mm
    T_1_2 = np.eye(4)  # infrared 2's pose in infrared 1's frame
    T_1_2[:3, :3] = R_21.T
    T_1_2[:3, 3] = -R_21.T @ t_21
    T_J_left = base.cameras.left.T_J_cam
    T_J_right = T_J_left @ T_1_2
    rectified = bool(
        left == right
        and not any(left.coeffs)
        and np.allclose(R_21, np.eye(3), atol=1e-9)
        and T_1_2[0, 3] > 0
        and abs(T_1_2[1, 3]) <= 1e-6 * abs(T_1_2[0, 3])
        and abs(T_1_2[2, 3]) <= 1e-6 * abs(T_1_2[0, 3])
    )

    def camera(intr: IRIntrinsics, T_J_cam: np.ndarray, like: CameraConfig) -> CameraConfig:
        from scipy.spatial.transform import Rotation

        rot = (
            like.rotation_deg
            if rectified
            else tuple(float(a) for a in Rotation.from_matrix(T_J_cam[:3, :3]).as_rotvec(degrees=True))
        )
        return CameraConfig(
            width_px=int(intr.width),
            height_px=int(intr.height),
            fx_px=float(intr.fx),
            fy_px=float(intr.fy),
            cx_px=float(intr.ppx),
            cy_px=float(intr.ppy),
            distortion=tuple(float(c) for c in intr.coeffs),  # type: ignore[arg-type]
            position_mm=tuple(float(x) for x in T_J_cam[:3, 3]),  # type: ignore[arg-type]
            rotation_deg=rot,  # type: ignore[arg-type]
        )

    left_cam = camera(left, T_J_left, base.cameras.left)
    right_cam = camera(right, T_J_right, base.cameras.left)
    return base.replace(cameras=StereoConfig(left=left_cam, right=right_cam, rectified=rectified))


# ------------------------------------------------------------------------------------- librealsense


def rs_module() -> Any:
    """``pyrealsense2``, or a :class:`~softjig.errors.CameraError` saying how to install it."""
    try:
        import pyrealsense2 as rs
    except ImportError:
        raise CameraError("RealSense cameras need pyrealsense2: pip install 'softjig[realsense]'") from None
    return rs


def find_device(serial: str | None = None) -> Any:
    """The connected RealSense device of that serial number, or the only one connected (a
    :class:`~softjig.errors.CameraError` naming those connected otherwise)."""
    rs = rs_module()
    devices = {d.get_info(rs.camera_info.serial_number): d for d in rs.context().query_devices()}
    if serial is None:
        if not devices:
            raise CameraError(
                "no RealSense camera is connected (check the USB 3 cable; rs-enumerate-devices lists them)"
            )
        if len(devices) > 1:  # pragma: no cover - needs two real D4xx
            raise CameraError(
                f"found {len(devices)} RealSense cameras ({', '.join(sorted(devices)) or 'none'}); "
                "name the one to use: realsense-ir:SERIAL"
            )
        return next(iter(devices.values()))  # pragma: no cover - needs a real D4xx
    if serial not in devices:
        raise CameraError(
            f"RealSense camera {serial} not found; connected: {', '.join(sorted(devices)) or 'none'} "
            "(check the cable and the serial number)"
        )
    return devices[serial]  # pragma: no cover - needs a real D4xx


def infrared_profiles(device: Any, width_px: int, height_px: int, fps: int) -> tuple[Any, Any, Any]:
    """The sensor that streams both infrared imagers and its Y8 profiles ``(sensor, ir1, ir2)`` of that
    mode; a :class:`~softjig.errors.CameraError` naming the modes it has otherwise."""
    rs = rs_module()
    offered = set()
    for sensor in device.query_sensors():
        found = {}
        for p in sensor.get_stream_profiles():
            if p.stream_type() != rs.stream.infrared or p.format() != rs.format.y8:
                continue
            v = p.as_video_stream_profile()
            offered.add((v.width(), v.height(), p.fps()))
            if (v.width(), v.height(), p.fps()) == (width_px, height_px, fps):
                found[p.stream_index()] = p
        if 1 in found and 2 in found:
            return sensor, found[1], found[2]
    modes = ", ".join(f"{w}x{h}@{f}" for w, h, f in sorted(offered)) or "none"
    raise CameraError(
        f"the RealSense device has no Y8 infrared 1 and 2 at {width_px}x{height_px}@{fps} (it offers {modes})"
    )


def _intrinsics(profile: Any) -> IRIntrinsics:
    i = profile.as_video_stream_profile().get_intrinsics()
    return IRIntrinsics(i.width, i.height, i.fx, i.fy, i.ppx, i.ppy, tuple(float(c) for c in i.coeffs[:5]))


def read_realsense_rig(base: JigConfig, device: Any, width_px: int = 848, height_px: int = 480) -> JigConfig:
    """The rig of a device's infrared pair at that resolution (its factory calibration, read without
    streaming); see :func:`rig_from_realsense`."""
    for fps in (30, *IR_FPS):
        try:
            _, p1, p2 = infrared_profiles(device, width_px, height_px, fps)
            break
        except CameraError:
            continue
    else:
        infrared_profiles(device, width_px, height_px, 30)  # raises, naming the modes offered
    e = p1.get_extrinsics_to(p2)
    return rig_from_realsense(base, _intrinsics(p1), _intrinsics(p2), list(e.rotation), list(e.translation))


def config_from_realsense(
    base: JigConfig, serial: str | None, width_px: int = 848, height_px: int = 480
) -> JigConfig:
    """``softjig config --from-realsense``: the rig of a connected device's infrared pair."""
    device = find_device(serial)
    return read_realsense_rig(base, device, width_px, height_px)  # pragma: no cover - needs a real D4xx
