"""The cameras' pose in the jig frame J: from the fiducials on the base plate, or fixed in the config.

The paper transforms the triangulated markers into the jig frame with fiducials on the base plate. Ours
are ArUco markers on the plate's bottom face (``fiducials.z_mm``, default ``-5``): the cameras see them
through air only, so a plain pinhole model is exact for them. Both cameras' views are used at once: the
stereo head's pose is the one that minimises the reprojection error of every fiducial corner found in
either image, with the right camera held at its configured pose relative to the left one.

Two paths give that pose, tried in turn. The fast one (every frame of a working rig) reads the fiducials
near where the config's poses put them (:func:`softjig.sensing.fiducials.locate_fiducials_near`) and
solves the joint stereo PnP by Gauss-Newton from the config's pose, with an analytic Jacobian (distorted
cameras: with SciPy's LM). The general one (fiducials far off or partly hidden; some fifty times slower)
runs OpenCV's ArUco detector, OpenCV's PnP for the start and a Levenberg-Marquardt refinement with SciPy.
Both refine the corners with the same iteration to convergence and minimise the same error, so they agree
to the iterations' tolerance (``tests/test_jigframe.py``); the fast one falls back to the general one
whenever it does not find every fiducial or its fit does not explain the corners.

When the fiducials are not visible, or the user calibrated the extrinsics once, the poses in the config
are used instead (``sensing.extrinsics``); the result says which source was used.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from types import MappingProxyType

import cv2
import numpy as np

from softjig.config import CameraConfig, JigConfig
from softjig.errors import EstimationError
from softjig.geometry import invert_pose, pose_from_rotvec_translation
from softjig.optics import project_points
from softjig.sensing.fiducials import (
    CaptureTable,
    capture_table,
    cell_patterns,
    detect_fiducials,
    fiducial_corners_J,
    fiducial_gray_u8,
    locate_quads_near,
)

MIN_FIDUCIALS_PER_IMAGE = 2  # 8 corners: a well-conditioned planar PnP
MAX_FIDUCIAL_RMS_PX = 2.0  # above this, a corner was misread or a fiducial moved: the pose is rejected
GAUSS_NEWTON_MAX_STEPS = 10
GAUSS_NEWTON_TOLERANCE = 1e-8  # stop after a step below this (rad, and mm / 100): it is then ~1e-16


@dataclass(frozen=True)
class JigFrame:
    """Both cameras' poses in J and where they came from.

    Attributes
    ----------
    T_J_left, T_J_right : (4, 4) the cameras' poses in J (mm).
    source : ``"fiducials"`` (measured in these images), ``"membrane"`` (the config's extrinsics levelled
        on the unloaded reference frame: :mod:`softjig.sensing.levelling`), ``"reference fiducials"``
        (measured by the reference frame's fiducials, for a frame that lost them), ``"membrane at rest"``
        (the config's extrinsics levelled on the frame's own markers away from the contact, without a
        reference frame) or ``"config"`` (fixed extrinsics).
    reprojection_rms_px : RMS reprojection error of the fiducial corners (``nan`` unless ``"fiducials"``).
    fiducial_ids : ids found in both images (empty unless ``"fiducials"``).
    fiducial_quads_left_px, fiducial_quads_right_px : (M, 4, 2) where each fiducial is in each image
        (found, or projected from the config's poses): markers detected there are not membrane markers.
    """

    T_J_left: np.ndarray
    T_J_right: np.ndarray
    source: str
    reprojection_rms_px: float
    fiducial_ids: tuple[int, ...]
    fiducial_quads_left_px: np.ndarray
    fiducial_quads_right_px: np.ndarray


def _projected_quads(jig: JigConfig, camera: CameraConfig, T_J_cam: np.ndarray) -> np.ndarray:
    corners = fiducial_corners_J(jig.fiducials).reshape(-1, 3)
    return _project(camera, invert_pose(T_J_cam), corners).reshape(-1, 4, 2)


def jig_frame_from_config(jig: JigConfig) -> JigFrame:
    """The fixed extrinsics written in the config (the arrays are read-only; an estimator builds them once,
    in :func:`frame_constants`)."""
    left, right = jig.cameras.left, jig.cameras.right
    arrays = [
        left.T_J_cam,
        right.T_J_cam,
        _projected_quads(jig, left, left.T_J_cam),
        _projected_quads(jig, right, right.T_J_cam),
    ]
    for array in arrays:
        array.flags.writeable = False
    return JigFrame(arrays[0], arrays[1], "config", float("nan"), (), arrays[2], arrays[3])


def inside_fiducials(xy_px: np.ndarray, quads_px: np.ndarray, *, quiet_zone: float = 1.0 / 3.0) -> np.ndarray:
    """Which points lie on a fiducial or its white quiet zone (each quad grown by ``quiet_zone`` of its
    size about its centre; ArUco 4x4 markers are 6 cells wide, so one cell each side is 1/3).

    A fiducial's image is a convex quadrilateral: a point is inside when it lies on the same side of all
    four edges (a compiled loop, with a bounding-box test first).
    """
    xy = np.ascontiguousarray(np.asarray(xy_px, dtype=float).reshape(-1, 2))
    if len(quads_px) == 0 or len(xy) == 0:
        return np.zeros(len(xy), dtype=bool)
    quads = np.asarray(quads_px, dtype=float).reshape(-1, 4, 2)
    centres = quads.mean(axis=1, keepdims=True)
    grown = np.ascontiguousarray(centres + (quads - centres) * (1.0 + quiet_zone))  # (Q, 4, 2)
    from softjig.sensing._jigframe_kernels import inside_quads  # Numba is imported on first use

    return inside_quads(xy, grown)


def _project(camera: CameraConfig, T_cam_J: np.ndarray, points_J: np.ndarray) -> np.ndarray:
    """Pinhole projection (with the camera's distortion) of points in J into a camera at ``T_cam_J``."""
    return project_points(points_J, camera.K, camera.distortion, invert_pose(T_cam_J), None)


class FiducialMemory:
    """Where the general path last found every fiducial of one jig (the bytes of (M, 4, 2) float64 quads
    in each image, in the config's order), or ``None``: the fast path's second guess when the as-built
    head is too far from the config's poses for the capture (> CAPTURE_PX), so that only the first frame
    of such a rig takes the general path. The fast path's result does not depend on where it starts (the
    corners and the fit are iterated to convergence): this only saves time. An estimator owns one.
    ``tables`` are the capture tables of those quads (made on their first use)."""

    __slots__ = ("quads", "tables")

    def __init__(self) -> None:
        self.quads: tuple[bytes, bytes] | None = None
        self.tables: tuple[CaptureTable | None, CaptureTable | None] | None = None


def jig_frame_from_fiducials(
    left_u8: np.ndarray,
    right_u8: np.ndarray,
    jig: JigConfig,
    *,
    constants: FrameConstants | None = None,
    memory: FiducialMemory | None = None,
) -> JigFrame | None:
    """Measure the stereo head's pose in J from the fiducials seen in an 8-bit gray stereo pair.

    The fast path first (fiducials read near where they are expected, Gauss-Newton), then, if it does
    not find every fiducial or its fit fails, the general one (ArUco's detector, SciPy's
    Levenberg-Marquardt); see the module's notes.

    Parameters
    ----------
    left_u8, right_u8 : (H, W) uint8 images; other images softjig accepts (``uint16`` such as mono16,
        float in [0, 1], RGB) are converted by :func:`~softjig.sensing.fiducials.fiducial_gray_u8`.
    jig : the nominal jig: its fiducials and cameras (intrinsics, and poses to start from).
    constants : :func:`frame_constants` of ``jig`` (built here when not given: an estimator builds them
        once).
    memory : where the general path last found the fiducials (read and updated), if kept.

    Returns ``None`` when fewer than :data:`MIN_FIDUCIALS_PER_IMAGE` configured fiducials are found in
    either image, or when the fitted pose does not explain the corners (the fit did not converge or the
    RMS reprojection error exceeds :data:`MAX_FIDUCIAL_RMS_PX`).

    Raises
    ------
    InputError
        An image that is not a gray or RGB image of a supported dtype, empty, or float outside [0, 1].
    """
    left_u8 = fiducial_gray_u8(left_u8, name="the left image")
    right_u8 = fiducial_gray_u8(right_u8, name="the right image")
    k = constants if constants is not None else frame_constants(jig)
    frame = _jig_frame_fast(left_u8, right_u8, jig, k, k.fast.expected_quads, k.fast.capture_tables)
    if frame is None and memory is not None and memory.quads is not None:
        if memory.tables is None:
            memory.tables = _capture_tables(memory.quads, k.fast.image_shape)
        frame = _jig_frame_fast(left_u8, right_u8, jig, k, memory.quads, memory.tables)
    if frame is not None:
        return frame
    fid = jig.fiducials
    expected = k.config_frame
    found = [
        detect_fiducials(left_u8, fid, expected_quads_px=expected.fiducial_quads_left_px),
        detect_fiducials(right_u8, fid, expected_quads_px=expected.fiducial_quads_right_px),
    ]
    if min(len(f) for f in found) < MIN_FIDUCIALS_PER_IMAGE:
        return None
    frame = _frame_from_corners(found, jig, _fit_pose_lm, k)
    if memory is not None and frame is not None and all(set(f) == set(fid.ids) for f in found):
        memory.quads = tuple(np.array([f[i] for i in fid.ids], dtype=float).tobytes() for f in found)
        memory.tables = None
    return frame


def _jig_frame_fast(
    left_u8: np.ndarray,
    right_u8: np.ndarray,
    jig: JigConfig,
    constants: FrameConstants,
    expected_quads: tuple[bytes, bytes],
    tables: tuple[CaptureTable | None, CaptureTable | None],
) -> JigFrame | None:
    """The fast path: every fiducial read near its expected place (the bytes of (M, 4, 2) float64 quads
    in each image), and a Gauss-Newton fit; ``None`` if a fiducial is not there or the fit fails."""
    k = constants.fast
    images = [np.asarray(image) for image in (left_u8, right_u8)]
    if any(image.dtype != np.uint8 or image.ndim != 2 for image in images):
        return None
    if any(image.shape != k.image_shape for image in images):  # not the cameras' images: tables made here
        tables = tuple(
            capture_table(q, len(q) // 64, image.shape)
            for q, image in zip(expected_quads, images, strict=True)
        )
    if tables[0] is None or tables[1] is None:  # a scanline leaves the image: not found there
        return None
    corners = [
        locate_quads_near(np.ascontiguousarray(image), jig.fiducials, quads, table=table, white=k.white)
        for image, quads, table in zip(images, expected_quads, tables, strict=True)
    ]
    if corners[0] is None or corners[1] is None:
        return None
    if k.distorted:  # the Gauss-Newton fit is for pinholes: SciPy's LM with OpenCV's distortion model
        found = [dict(zip(jig.fiducials.ids, c, strict=True)) for c in corners]
        return _frame_from_corners(found, jig, _fit_pose_lm, constants)
    observed = np.concatenate([corners[0].reshape(-1, 2), corners[1].reshape(-1, 2)])
    fit = _gauss_newton(k.points_J, observed, k.n_left, k.pinhole)
    if fit is None:
        return None
    T_left_J, residuals = fit
    rms = float(np.sqrt(residuals @ residuals / len(residuals)))
    if not rms <= MAX_FIDUCIAL_RMS_PX:
        return None
    T_J_left = np.eye(4)
    T_J_left[:3, :3] = T_left_J[:3, :3].T
    T_J_left[:3, 3] = -(T_left_J[:3, :3].T @ T_left_J[:3, 3])
    return JigFrame(
        T_J_left, T_J_left @ k.T_left_right, "fiducials", rms, k.sorted_ids, corners[0], corners[1]
    )


def levelled_frame(
    jig: JigConfig, config_frame: JigFrame, T_correction: np.ndarray, source: str = "membrane"
) -> JigFrame:
    """The config's frame with both cameras moved by the head's measured error ``T_correction`` (4, 4, in
    J: :class:`softjig.sensing.levelling.HeadLevel`), its fiducial quads projected from there, named
    ``source`` (how the error was measured: a key of :data:`FALLBACK_NAMES`). Arrays read-only."""
    left, right = T_correction @ config_frame.T_J_left, T_correction @ config_frame.T_J_right
    arrays = [
        left,
        right,
        _projected_quads(jig, jig.cameras.left, left),
        _projected_quads(jig, jig.cameras.right, right),
    ]
    for array in arrays:
        array.flags.writeable = False
    return JigFrame(arrays[0], arrays[1], source, float("nan"), (), arrays[2], arrays[3])


#: How a fallback frame is named in the warning that fiducials were not found.
FALLBACK_NAMES = MappingProxyType(
    {
        "config": "the camera poses in the config",
        "membrane": "the camera poses in the config levelled on the unloaded reference frame",
        "reference fiducials": "the camera poses the reference frame's fiducials measured",
        "membrane at rest": "the camera poses in the config levelled on the frame's own markers at rest",
    }
)


@dataclass(frozen=True)
class _FastConstants:
    """What the fast path needs of a jig, computed once: the expected quads (bytes of (M, 4, 2) float64
    arrays, left and right), every corner in J in the order they are found (left image, then right),
    the right camera's pose in the left one's frame, and the Gauss-Newton constants."""

    expected_quads: tuple[bytes, bytes]
    points_J: np.ndarray
    n_left: int
    T_left_right: np.ndarray
    sorted_ids: tuple[int, ...]
    distorted: bool
    pinhole: _PinholeConstants
    image_shape: tuple[int, int]
    capture_tables: tuple[CaptureTable | None, CaptureTable | None]
    white: np.ndarray


@dataclass(frozen=True)
class FrameConstants:
    """What finding the jig frame needs of a jig, built once by :func:`frame_constants`: the config's
    frame (the expected fiducial quads), the right camera's pose relative to the left one (read-only),
    each fiducial's corners in J ((4, 3) mm, read-only) and the fast path's constants."""

    config_frame: JigFrame
    T_left_right: np.ndarray
    corners_J_by_id: dict[int, np.ndarray]
    fast: _FastConstants


def frame_arrays(jig: JigConfig) -> dict[str, np.ndarray]:
    """The arrays :func:`frame_constants` derives from a jig, by name, read-only: the config's frame
    (``T_J_left``, ``T_J_right``, the expected fiducial quads ``quads_left``, ``quads_right``), the right
    camera's pose in the left one's frame, each fiducial's corners in J and every corner in the order
    they are found (``points_J``), the Gauss-Newton fit's constants (``pinhole.*``), the fiducials' cells
    (``white``) and the capture tables of the expected quads in each image (``capture_left.*``,
    ``capture_right.*``; absent when a scanline leaves the image).

    A function of the jig alone: an estimator reads them from the disk cache
    (:meth:`softjig.sensing.setup.JigModel.build`) rather than project the fiducials again.
    """
    expected = jig_frame_from_config(jig)
    T_left_right = invert_pose(expected.T_J_left) @ expected.T_J_right
    T_left_right.flags.writeable = False
    corners = fiducial_corners_J(jig.fiducials)
    corners.flags.writeable = False
    points = np.concatenate([corners.reshape(-1, 3)] * 2)  # the corners found in the left image, then right
    points.flags.writeable = False
    n = 4 * len(corners)
    pinhole = _pinhole_constants(jig, expected, T_left_right, n, n)
    arrays = {
        "T_J_left": expected.T_J_left,
        "T_J_right": expected.T_J_right,
        "quads_left": expected.fiducial_quads_left_px,
        "quads_right": expected.fiducial_quads_right_px,
        "T_left_right": T_left_right,
        "corners_J": corners,
        "points_J": points,
        **{name: getattr(pinhole, name[len("pinhole.") :]) for name in _PINHOLE_ARRAYS},
        "white": cell_patterns(jig.fiducials.dictionary, tuple(jig.fiducials.ids)),
    }
    image_shape = (jig.cameras.left.height_px, jig.cameras.left.width_px)
    for side in ("left", "right"):
        quads = np.ascontiguousarray(arrays[f"quads_{side}"], dtype=float)
        table = capture_table(quads.tobytes(), len(quads), image_shape)
        if table is not None:
            meta = np.array([table.window, *table.shape], dtype=np.int64)
            meta.flags.writeable = False
            arrays[f"capture_{side}.meta"] = meta
            for name in ("index", "midpoints", "normals", "offsets"):
                arrays[f"capture_{side}.{name}"] = getattr(table, name)
    return arrays


def frame_constants(jig: JigConfig, arrays: dict[str, np.ndarray] | None = None) -> FrameConstants:
    """The jig-frame constants of this jig (an estimator builds them once), from its
    :func:`frame_arrays` (derived here when not given)."""
    a = arrays if arrays is not None else frame_arrays(jig)
    quads = a["quads_left"], a["quads_right"]  # float64 (projected)
    expected = JigFrame(a["T_J_left"], a["T_J_right"], "config", float("nan"), (), *quads)
    fast = _FastConstants(
        expected_quads=(quads[0].tobytes(), quads[1].tobytes()),
        points_J=a["points_J"],
        n_left=len(a["points_J"]) // 2,
        T_left_right=a["T_left_right"],
        sorted_ids=tuple(sorted(jig.fiducials.ids)),
        distorted=any(jig.cameras.left.distortion) or any(jig.cameras.right.distortion),
        pinhole=_PinholeConstants(*(a[name] for name in _PINHOLE_ARRAYS)),
        image_shape=(jig.cameras.left.height_px, jig.cameras.left.width_px),
        capture_tables=(_table_of(a, "left"), _table_of(a, "right")),
        white=a["white"],
    )
    corners_by_id = dict(zip(jig.fiducials.ids, a["corners_J"], strict=True))
    return FrameConstants(expected, a["T_left_right"], corners_by_id, fast)


def _table_of(arrays: dict[str, np.ndarray], side: str) -> CaptureTable | None:
    """The capture table :func:`frame_arrays` stored for ``side``, or ``None`` when there is none."""
    meta = arrays.get(f"capture_{side}.meta")
    if meta is None:
        return None
    window, *shape = meta.tolist()
    return CaptureTable(
        index=arrays[f"capture_{side}.index"],
        shape=tuple(shape),
        midpoints=arrays[f"capture_{side}.midpoints"],
        normals=arrays[f"capture_{side}.normals"],
        offsets=arrays[f"capture_{side}.offsets"],
        window=window,
    )


def _capture_tables(
    quads: tuple[bytes, bytes], image_shape: tuple[int, int]
) -> tuple[CaptureTable | None, CaptureTable | None]:
    """The capture tables of the quads expected in each image
    (:func:`~softjig.sensing.fiducials.capture_table`)."""
    return tuple(capture_table(q, len(q) // 64, image_shape) for q in quads)


PoseFit = Callable[
    [list[np.ndarray], list[np.ndarray], JigConfig, "FrameConstants | None"],
    "tuple[np.ndarray, np.ndarray] | None",
]


def _frame_from_corners(
    found: list[dict[int, np.ndarray]], jig: JigConfig, fit: PoseFit, constants: FrameConstants
) -> JigFrame | None:
    """The JigFrame of the corners found in both images, with the pose from ``fit`` (or ``None``)."""
    corners_J = constants.corners_J_by_id
    obj = [np.concatenate([corners_J[i] for i in f]) for f in found]
    img = [np.concatenate([f[i] for i in f]) for f in found]
    result = fit(obj, img, jig, constants)
    if result is None:
        return None
    T_left_J, residuals = result
    rms = float(np.sqrt(np.mean(residuals**2)))
    if not np.isfinite(rms) or rms > MAX_FIDUCIAL_RMS_PX:
        return None  # a misread corner or a moved fiducial: do not trust this pose
    T_J_left = invert_pose(T_left_J)
    both = tuple(sorted(set(found[0]) & set(found[1])))
    quads = [np.array(list(f.values())).reshape(-1, 4, 2) for f in found]
    return JigFrame(T_J_left, T_J_left @ constants.T_left_right, "fiducials", rms, both, quads[0], quads[1])


def _fit_pose_lm(
    obj: list[np.ndarray], img: list[np.ndarray], jig: JigConfig, constants: FrameConstants | None = None
) -> tuple[np.ndarray, np.ndarray] | None:
    """The left camera's pose ``T_left_J`` minimising both images' reprojection errors, and the residuals
    (px): OpenCV's IPPE PnP in the left image for the start, then SciPy's Levenberg-Marquardt."""
    cams = (jig.cameras.left, jig.cameras.right)
    ok, rvec, tvec = cv2.solvePnP(
        obj[0], img[0], cams[0].K, np.asarray(cams[0].distortion, float), flags=cv2.SOLVEPNP_IPPE
    )
    if not ok:
        return None

    # The residual is evaluated ~30 times per frame: OpenCV's projectPoints and composeRT work on the
    # rotation vectors directly, several times faster than optics.project_points on poses.
    k = constants if constants is not None else frame_constants(jig)
    T_right_left = invert_pose(k.T_left_right)
    rvec_rl = cv2.Rodrigues(T_right_left[:3, :3])[0]
    tvec_rl = T_right_left[:3, 3].reshape(3, 1)
    dist = [np.asarray(cam.distortion, float) for cam in cams]

    def residuals(x: np.ndarray) -> np.ndarray:
        rvec_l, tvec_l = x[:3].reshape(3, 1), x[3:].reshape(3, 1)
        rvec_r, tvec_r = cv2.composeRT(rvec_l, tvec_l, rvec_rl, tvec_rl)[:2]
        left_px = cv2.projectPoints(obj[0], rvec_l, tvec_l, cams[0].K, dist[0])[0].reshape(-1, 2)
        right_px = cv2.projectPoints(obj[1], rvec_r, tvec_r, cams[1].K, dist[1])[0].reshape(-1, 2)
        return np.concatenate([(left_px - img[0]).ravel(), (right_px - img[1]).ravel()])

    from scipy.optimize import least_squares  # on first use: scipy.optimize is a slow import

    fit = least_squares(residuals, np.concatenate([rvec.ravel(), tvec.ravel()]), method="lm")
    if not fit.success:
        return None
    return pose_from_rotvec_translation(fit.x[:3], fit.x[3:]), fit.fun


def _fit_pose_gauss_newton(
    obj: list[np.ndarray], img: list[np.ndarray], jig: JigConfig, constants: FrameConstants | None = None
) -> tuple[np.ndarray, np.ndarray] | None:
    """As :func:`_fit_pose_lm` for distortion-free cameras, by Gauss-Newton from the config's pose.

    The head's pose is updated as ``T <- exp(omega, v) T``: a point at ``X`` in the left camera moves by
    ``omega x X + v``, in the right camera by ``R_rl`` of that, and its pixel by the pinhole's Jacobian
    ``[[fx / z, 0, -fx x / z^2], [0, fy / z, -fy y / z^2]]``. Each step solves the 6x6 normal equations;
    from the config's pose (~1 mm, 0.5 deg away) it converges in 3-4 steps
    (:func:`softjig.sensing._jigframe_kernels.gauss_newton`).
    """
    c = constants if constants is not None else frame_constants(jig)
    k = _pinhole_constants(jig, c.config_frame, c.T_left_right, len(obj[0]), len(obj[1]))
    return _gauss_newton(np.concatenate(obj), np.concatenate(img), len(obj[0]), k)


def _gauss_newton(
    points_J: np.ndarray, observed_px: np.ndarray, n_left: int, k: _PinholeConstants
) -> tuple[np.ndarray, np.ndarray] | None:
    """``T_left_J`` and the residuals (px) of the compiled Gauss-Newton steps
    (:func:`softjig.sensing._jigframe_kernels.gauss_newton`), or ``None`` if they did not converge."""
    from softjig.sensing._jigframe_kernels import gauss_newton  # Numba is imported on first use

    R, t, residuals, converged = gauss_newton(
        points_J,
        observed_px,
        n_left,
        k.focal,
        k.centre,
        k.R_start,
        k.t_start,
        k.R_rl,
        k.t_rl,
        GAUSS_NEWTON_MAX_STEPS,
        GAUSS_NEWTON_TOLERANCE,
    )
    if not converged:
        return None
    T_left_J = np.eye(4)
    T_left_J[:3, :3], T_left_J[:3, 3] = R, t
    return T_left_J, residuals


@dataclass(frozen=True)
class _PinholeConstants:
    """Per jig and corner count: the start pose (``T_left_J`` from the config), the right camera's pose
    in the left one's frame, and each corner's focal lengths and principal point (px)."""

    R_start: np.ndarray
    t_start: np.ndarray
    R_rl: np.ndarray
    t_rl: np.ndarray
    focal: np.ndarray
    centre: np.ndarray


#: The names of the :class:`_PinholeConstants` arrays in :func:`frame_arrays`, in field order.
_PINHOLE_ARRAYS = tuple(f"pinhole.{name}" for name in _PinholeConstants.__dataclass_fields__)


def _pinhole_constants(
    jig: JigConfig, config_frame: JigFrame, T_left_right: np.ndarray, n_left: int, n_right: int
) -> _PinholeConstants:
    T_left_J = invert_pose(config_frame.T_J_left)
    T_rl = invert_pose(T_left_right)
    left, right = jig.cameras.left, jig.cameras.right
    counts = [n_left, n_right]
    focal = np.repeat([[left.fx_px, left.fy_px], [right.fx_px, right.fy_px]], counts, axis=0)
    centre = np.repeat([[left.cx_px, left.cy_px], [right.cx_px, right.cy_px]], counts, axis=0)
    arrays = (T_left_J[:3, :3], T_left_J[:3, 3], T_rl[:3, :3], T_rl[:3, 3], focal, centre)
    for array in arrays:
        array.flags.writeable = False
    return _PinholeConstants(*arrays)


def resolve_jig_frame(
    left_u8: np.ndarray,
    right_u8: np.ndarray,
    jig: JigConfig,
    *,
    constants: FrameConstants | None = None,
    memory: FiducialMemory | None = None,
    fallback: JigFrame | Callable[[], JigFrame] | None = None,
) -> tuple[JigFrame, list[str]]:
    """The jig frame as ``sensing.extrinsics`` asks, with any warning to report.

    ``"fiducials"`` requires them; ``"config"`` uses the fixed extrinsics; ``"auto"`` measures them when
    found and falls back to ``fallback`` (default: the config's frame; a function is called only then)
    with a warning. See
    :func:`jig_frame_from_fiducials`, which also says what ``constants`` and ``memory`` are.

    Raises
    ------
    EstimationError
        ``sensing.extrinsics == "fiducials"`` and the fiducials were not found.
    """
    mode = jig.sensing.extrinsics
    k = constants if constants is not None else frame_constants(jig)
    if mode == "config":
        return k.config_frame, []
    frame = jig_frame_from_fiducials(left_u8, right_u8, jig, constants=k, memory=memory)
    if frame is not None:
        return frame, []
    message = (
        f"the fiducials {list(jig.fiducials.ids)} were not found (at least {MIN_FIDUCIALS_PER_IMAGE} in each "
        f"image, reprojecting within {MAX_FIDUCIAL_RMS_PX} px)"
    )
    if mode == "fiducials":
        raise EstimationError(
            f"{message} and sensing.extrinsics is 'fiducials': make them visible, or set "
            "sensing.extrinsics = 'config' to use the calibrated camera poses in the config"
        )
    used = k.config_frame if fallback is None else fallback() if callable(fallback) else fallback
    return used, [f"{message}: used {FALLBACK_NAMES[used.source]} instead"]
