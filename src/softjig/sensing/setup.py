"""What an estimator derives once: from the nominal jig (:class:`JigModel`) and from the unloaded jig's
markers (:class:`ReferenceModel`).

Nothing here is kept in memory behind the caller's back: an :class:`~softjig.sensing.estimator.Estimator`
builds these once and hands them to the stages, so a frame's work depends only on the frame and on objects
the caller can see. What :meth:`JigModel.build` derives by projecting the jig (the detection scale and
disparity window, the fiducials' expected places and capture tables, the rest shape, the sub-pixel fit's
tables) is a function of the jig's content and of this code alone, and is read from the disk cache
(:func:`softjig.disk_cache.cached_arrays`, keyed by :func:`model_key`) when an earlier build stored it: a
one-shot estimator then costs little more than the frame it estimates.
"""

from __future__ import annotations

import functools
import hashlib
import os
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import scipy

from softjig.config import JigConfig
from softjig.disk_cache import cached_arrays
from softjig.geometry import transform_points
from softjig.jig_shape import marker_layout_xy, rest_inner_height_mm
from softjig.optics import FlatLayers, jacobian_stencil, project_point_sets, stencil_jacobian
from softjig.rig import flat_layers
from softjig.sensing.contact import indentation
from softjig.sensing.detect import DEFAULT_CANDIDATES, DEFAULT_REFINE, log_sigma_px
from softjig.sensing.identities import ReferenceMarkers, rest_shape_reference
from softjig.sensing.jigframe import FrameConstants, frame_arrays, frame_constants
from softjig.sensing.rectify import Rectification, rectification
from softjig.sensing.refractive import KernelConstants, kernel_arrays, kernel_constants
from softjig.sensing.stereo import triangulate_rectified
from softjig.sensing.subpixel import MIN_MODEL_BLUR_PX, MarkerModel, kernel_tables

# The model fit's window half-width, in marker radii (a 25x25 window on the default jig, whose error is
# 1.3 % above the bound of a larger one).
WINDOW_RADII = 1.25
# The reference membrane's height on the jig axis is the constant term of a quadratic surface through
# its markers within this many pitches of the axis, ...
AXIS_SURFACE_PITCHES = 2.5
# ... which needs at least this many of them (a quadratic in x, y has six coefficients); with fewer, the
# marker nearest the axis gives it.
AXIS_SURFACE_MIN_MARKERS = 6

#: Version of the layout of :func:`model_arrays`: bump it when the arrays stored change meaning.
MODEL_FORMAT_VERSION = 1
#: :func:`sensing_setup`'s numbers derived by projecting the jig, in the order :func:`setup_numbers` gives.
SETUP_NUMBERS = (
    "sigma_px",
    "radius_px",
    "blur_px",
    "speckle_corr_px",
    "min_disparity_px",
    "max_disparity_px",
    "rest_apex_z_mm",
)


@dataclass(frozen=True)
class SensingSetup:
    """What the estimator derives once from the nominal jig's geometry.

    Attributes
    ----------
    sigma_px : LoG scale matched to a marker at the membrane's apex, blur included (px).
    threshold : detection threshold on the scale-normalised LoG response.
    min_disparity_px, max_disparity_px : the disparity window of markers anywhere on the membrane.
    rest_apex_z_mm : height in J of the rest membrane's apex as the pinhole triangulation sees it: the
        push depth's zero. Refraction through flat layers puts a point of the oil at an apparent height in
        J (paraxially ``-t + t / n_plate + z / n_oil``) that does not depend on where the cameras are,
        so it is computed once, from the nominal geometry.
    marker : the marker and noise model of the sub-pixel fit (:mod:`softjig.sensing.subpixel`): a
        marker at the apex (radius and blur in px) and the config's imaging and medium (levels, speckle,
        shot and read noise, bit depth).
    candidates, refine : how :func:`~softjig.sensing.detect.detect_markers` finds and refines the markers
        (defaults: the pyramid and the model fit; ``"full"`` and ``"quadratic"`` are the straightforward
        path, Sakuma et al.'s). Markers blurred by less than ``MIN_MODEL_BLUR_PX`` (idealised
        simulations) are refined by the quadratic fit.
    """

    sigma_px: float
    threshold: float | None
    min_disparity_px: float
    max_disparity_px: float
    rest_apex_z_mm: float
    marker: MarkerModel | None = None
    candidates: str = DEFAULT_CANDIDATES
    refine: str | None = DEFAULT_REFINE


def sensing_setup(jig: JigConfig, layers: FlatLayers | None = None) -> SensingSetup:
    """Derive the detection scale, disparity window and push-depth reference from the nominal (rectified)
    jig (it projects every marker into both cameras through the layers, in one solve of the refracted
    rays: an estimator derives it once, or reads :func:`setup_numbers` from the disk cache)."""
    return setup_of(jig, setup_numbers(jig, layers))


def setup_numbers(jig: JigConfig, layers: FlatLayers | None = None) -> np.ndarray:
    """The numbers of :data:`SETUP_NUMBERS` (float64, px and mm) that :func:`sensing_setup` derives by
    projecting the jig's markers into both cameras (``layers``: :func:`~softjig.rig.flat_layers` of the
    jig, made here when not given)."""
    left, right = jig.cameras.left, jig.cameras.right
    layers = layers if layers is not None else flat_layers(jig)
    apex = np.array([[0.0, 0.0, jig.membrane.dome_height_mm]])
    # Disparities of markers anywhere between the rest membrane and the plate.
    xy = marker_layout_xy(jig)
    z_rest = rest_inner_height_mm(jig, xy[:, 0], xy[:, 1])
    points = np.concatenate([np.column_stack([xy, z_rest]), np.column_stack([xy, np.zeros(len(xy))])])
    left_pose = left.T_J_cam
    # one solve of the refracted rays for every projection below (each set as if projected alone)
    stencil, pl, pr, u_left, u_right = project_point_sets(
        [(jacobian_stencil(apex), 0), (apex, 0), (apex, 1), (points, 0), (points, 1)],
        [(cam.K, cam.distortion, pose) for cam, pose in ((left, left_pose), (right, right.T_J_cam))],
        layers,
    )
    # px per mm at the apex (mean singular value of the projection's Jacobian in the marker's plane)
    jac = stencil_jacobian(stencil)[0][:, :2]
    px_per_mm = float(np.mean(np.linalg.svd(jac, compute_uv=False)))
    blur_mm = jig.medium.blur_coefficient * jig.membrane.dome_height_mm**1.5
    if jig.sensing.log_sigma_px is not None:
        sigma = jig.sensing.log_sigma_px
    else:
        sigma = log_sigma_px(jig.markers.diameter_mm * px_per_mm, blur_sigma_px=blur_mm * px_per_mm)
    disparity = u_left[:, 0] - u_right[:, 0]
    margin = jig.sensing.disparity_margin_px
    # The rest apex as the pinhole triangulation sees it: the reference of the push depth.
    apex_J = transform_points(left_pose, pinhole_triangulation(pl, pr, jig))
    return np.array(
        [
            sigma,
            0.5 * jig.markers.diameter_mm * px_per_mm,
            blur_mm * px_per_mm,
            jig.medium.bead_diameter_mm * px_per_mm,
            max(disparity.min() - margin, 1.0),
            disparity.max() + margin,
            apex_J[0, 2],
        ],
        dtype=float,
    )


def setup_of(jig: JigConfig, numbers: np.ndarray) -> SensingSetup:
    """The :class:`SensingSetup` of ``jig`` whose projected numbers are ``numbers``
    (:func:`setup_numbers`); the rest is read off the config."""
    sigma, radius_px, blur_px, speckle_corr_px, low, high, apex_z = np.asarray(numbers, dtype=float).tolist()
    marker = MarkerModel(
        radius_px=radius_px,
        blur_px=blur_px,
        background=jig.imaging.background_level,
        amplitude=jig.imaging.marker_level - jig.imaging.background_level,
        speckle_std=jig.medium.speckle_std,
        speckle_corr_px=speckle_corr_px,
        read_noise=jig.imaging.read_noise,
        full_well=jig.imaging.full_well_electrons,
        bit_depth=jig.imaging.bit_depth,
        half_width_px=max(2, round(WINDOW_RADII * radius_px)),
    )
    return SensingSetup(
        sigma_px=sigma,
        threshold=jig.sensing.detection_threshold,
        min_disparity_px=low,
        max_disparity_px=high,
        rest_apex_z_mm=apex_z,
        marker=marker,
        # the model fit's weight tables need a profile smooth at the pixel scale (subpixel.MarkerModel)
        refine=DEFAULT_REFINE if marker.blur_px >= MIN_MODEL_BLUR_PX else "quadratic",
    )


def pinhole_triangulation(left_xy: np.ndarray, right_xy: np.ndarray, jig: JigConfig) -> np.ndarray:
    """(M, 3) matched rectified pixels triangulated as if the cameras looked through air, in the left
    camera's frame (mm): the paper's triangulation."""
    cam = jig.cameras.left
    return triangulate_rectified(
        left_xy,
        right_xy,
        fx_px=cam.fx_px,
        fy_px=cam.fy_px,
        cx_px=cam.cx_px,
        cy_px=cam.cy_px,
        baseline_mm=jig.cameras.baseline_mm,
    )


@dataclass(frozen=True)
class JigModel:
    """Everything an estimator derives once from the nominal jig.

    Attributes
    ----------
    jig : the jig the stages see: the nominal one, with its cameras rectified when they were not.
    raw_jig : the nominal jig as given.
    rectification : how raw images are rectified (``None`` when the config's cameras are rectified).
    setup : detection scale, disparity window, push-depth zero, marker model.
    frame : the constants of finding the cameras' pose in J (expected fiducials, fast path).
    triangulation : the refracted triangulation's constants.
    rest_shape : the nominal markers on the nominal rest membrane.
    rest_reference : the :class:`ReferenceModel` of ``rest_shape`` (an estimator without a reference
        frame measures against it).
    marker_tables : the sub-pixel model fit's tables of ``setup.marker``
        (:func:`~softjig.sensing.subpixel.kernel_tables`), ``None`` when the markers are refined otherwise.
    """

    jig: JigConfig
    raw_jig: JigConfig
    rectification: Rectification | None
    setup: SensingSetup
    frame: FrameConstants
    triangulation: KernelConstants
    rest_shape: ReferenceMarkers
    rest_reference: ReferenceModel
    marker_tables: np.ndarray | None

    @functools.cached_property
    def layers(self) -> FlatLayers:
        """The flat refracting layers (air, plate, oil) of ``jig`` (made on first use: the stages read
        only their constants, ``triangulation``)."""
        return flat_layers(self.jig)

    @classmethod
    def build(cls, jig: JigConfig) -> JigModel:
        """Derive it: its :func:`model_arrays` are read from the disk cache when an earlier build of the
        same jig by the same code stored them (the rectification's maps of a raw pair are made here).

        Raises
        ------
        InputError, ConfigError
            The raw cameras cannot be rectified (see :func:`softjig.sensing.rectify.rectification`).
        """
        rect = None if jig.cameras.rectified else rectification(jig.cameras)
        used = jig if rect is None else jig.replace(cameras=rect.cameras)
        key = model_key(used)
        derive = functools.partial(model_arrays, used)
        arrays = derive() if key is None else cached_arrays("jig-model", key, derive)
        rest_shape = ReferenceMarkers(arrays["rest_xyz_mm"], "rest shape")
        return cls(
            jig=used,
            raw_jig=jig,
            rectification=rect,
            setup=setup_of(used, arrays["setup"]),
            frame=frame_constants(used, arrays),
            triangulation=kernel_constants(used, arrays=arrays),
            rest_shape=rest_shape,
            rest_reference=ReferenceModel(rest_shape, float(arrays["rest_height_at_axis_mm"][0]), None),
            marker_tables=arrays.get("marker_tables"),
        )


def model_arrays(jig: JigConfig, layers: FlatLayers | None = None) -> dict[str, np.ndarray]:
    """The arrays :meth:`JigModel.build` derives from the (rectified) jig, by name, read-only: its
    :func:`setup_numbers` (``setup``), :func:`~softjig.sensing.jigframe.frame_arrays`, the rest shape's
    markers (``rest_xyz_mm``) and their height on the axis (``rest_height_at_axis_mm``), and the sub-pixel
    fit's tables (``marker_tables``, when the markers are refined by the model fit) and
    :func:`~softjig.sensing.refractive.kernel_arrays` (``layers``: the jig's
    :func:`~softjig.rig.flat_layers`, made here when not given)."""
    layers = layers if layers is not None else flat_layers(jig)
    numbers = setup_numbers(jig, layers)
    rest_shape = rest_shape_reference(jig)
    arrays = {
        "setup": numbers,
        **frame_arrays(jig),
        **kernel_arrays(jig, layers),
        "rest_xyz_mm": rest_shape.xyz_mm,
        "rest_height_at_axis_mm": np.array([ReferenceModel.build(rest_shape, jig).height_at_axis_mm]),
    }
    setup = setup_of(jig, numbers)
    if setup.refine == "model" and setup.marker is not None:
        arrays["marker_tables"] = kernel_tables(setup.marker)
    for array in arrays.values():
        array.flags.writeable = False
    return arrays


def _fingerprint(root: str) -> str | None:
    """A digest of every module under ``root`` (``relative path:size:mtime_ns`` of each ``.py`` file,
    sorted), or ``None`` if the folder cannot be read.

    Every module rather than a list of those that derive :func:`model_arrays`: a list must be kept in step
    with the imports by hand, and a module left off it (one the rest shape's indentation calls, say)
    would let an edit read arrays an older version of the code stored. Any edit derives the arrays again,
    once; the walk is made once per process.
    """
    entries = []
    for folder, subfolders, files in os.walk(root):  # an unreadable folder lists nothing
        subfolders[:] = [name for name in subfolders if name != "__pycache__"]
        for path in (os.path.join(folder, name) for name in files if name.endswith(".py")):
            try:
                stat = os.stat(path)
            except OSError:  # removed meanwhile
                return None
            entries.append(f"{os.path.relpath(path, root)}:{stat.st_size}:{stat.st_mtime_ns}")
    if not entries:
        return None
    return hashlib.blake2b("\n".join(sorted(entries)).encode(), digest_size=16).hexdigest()


# The code this process runs, read once at import (a constant: the modules loaded do not change while it
# runs, even when their files do).
_CODE = _fingerprint(str(Path(__file__).resolve().parent.parent))


def model_key(jig: JigConfig) -> str | None:
    """Everything :func:`model_arrays` depends on, as exact text (its key in the disk cache): the jig's
    content (its ``repr``: every field, floats exactly), :data:`MODEL_FORMAT_VERSION`, a digest of the
    package's modules (:func:`_fingerprint`) and the numerical libraries' versions; ``None`` (derive, do
    not cache) when the modules' files cannot be read."""
    if _CODE is None:
        return None
    libraries = f"numpy={np.__version__} scipy={scipy.__version__} opencv={cv2.__version__}"
    return f"format={MODEL_FORMAT_VERSION}\n{jig!r}\ncode={_CODE}\n{libraries}"


@dataclass(frozen=True)
class ReferenceModel:
    """The unloaded jig's markers and what the refractive method derives from them once.

    Attributes
    ----------
    markers : the reference markers (a reference frame's, or the nominal rest shape).
    height_at_axis_mm : the reference membrane's height on the jig axis (mm): the constant term of a
        quadratic surface through its markers within :data:`AXIS_SURFACE_PITCHES` pitches of the axis.
    scatter_mm : a reference frame's own scatter about the nominal rest shape (its neighbour-differenced
        heights, :func:`~softjig.sensing.contact.indentation`'s noise; 0 when unknown), ``None`` for the
        rest shape (the indentation is then already the absolute height's).
    """

    markers: ReferenceMarkers
    height_at_axis_mm: float
    scatter_mm: float | None

    @classmethod
    def build(cls, markers: ReferenceMarkers, jig: JigConfig) -> ReferenceModel:
        """Derive it from the reference markers of ``jig`` (the nominal, rectified jig)."""
        pitch = jig.markers.pitch_mm
        xyz = markers.xyz_mm
        radius = np.hypot(xyz[:, 0], xyz[:, 1])
        near = radius < AXIS_SURFACE_PITCHES * pitch
        if near.sum() < AXIS_SURFACE_MIN_MARKERS:
            height = float(xyz[np.argmin(radius), 2])
        else:
            x, y, z = xyz[near].T
            design = np.column_stack([np.ones_like(x), x, y, x * x, x * y, y * y])
            height = float(np.linalg.lstsq(design, z, rcond=None)[0][0])
        scatter = None
        if markers.source != "rest shape":
            own = indentation(xyz, rest_inner_height_mm(jig, xyz[:, 0], xyz[:, 1]), pitch_mm=pitch).noise_mm
            scatter = float(own) if np.isfinite(own) else 0.0
        return cls(markers, height, scatter)
