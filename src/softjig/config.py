"""Configuration of a soft jig, its cameras and the parts it holds.

Everything is a frozen dataclass. The built-in default (:func:`default_jig`) is the paper's jig as far as
the paper says (``DESIGN.md`` §2); the rest are documented, physically motivated choices. A config is
written to and read from TOML (:func:`save_jig`, :func:`load_jig`) and the round trip is exact. Every value
is validated on load and on construction through :func:`validate_jig`, which raises
:class:`~softjig.errors.ConfigError` naming the field and the problem.

Frames and units follow ``DESIGN.md`` §1: millimetres inside the code, degrees only in names that say so,
jig frame J with its origin at the centre of the plate's top face and ``+z`` up through the membrane.
"""

from __future__ import annotations

import math
import os
import tomllib
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any, Literal

import numpy as np
import tomli_w
from pydantic import ConfigDict, TypeAdapter, ValidationError

from softjig.errors import ConfigError, InputError
from softjig.io.files import write_text_atomic

_STRICT = ConfigDict(extra="forbid")

CONFIG_VERSION = 1

Vec2 = tuple[float, float]
Vec3 = tuple[float, float, float]


@dataclass(frozen=True)
class PlateConfig:
    """The transparent base plate; its top face is ``z = 0`` in J."""

    __pydantic_config__ = _STRICT
    size_x_mm: float = 220.0
    size_y_mm: float = 220.0
    thickness_mm: float = 5.0
    refractive_index: float = 1.575  # PET


@dataclass(frozen=True)
class MembraneConfig:
    """The silicone membrane's rest shape and mechanics (see :mod:`softjig.sim.membrane`).

    The rest shape of the membrane's *inner* face (where the markers are) is the dome
    ``h(r) = dome_height_mm * (1 - (r / footprint_radius_mm) ** dome_exponent)`` for ``r`` below the
    footprint radius; a larger exponent gives a flatter top and a steeper rim.
    """

    __pydantic_config__ = _STRICT
    dome_height_mm: float = 30.0
    footprint_radius_mm: float = 95.0
    dome_exponent: float = 4.0
    thickness_mm: float = 0.7
    decay_length_mm: float = 5.0  # how fast the surface returns to rest around a shallow contact
    max_wall_slope_deg: float = 35.0  # no steeper than the bead pack's angle of repose


@dataclass(frozen=True)
class MarkerConfig:
    """White hemispherical markers on the membrane's inner face, laid out on a grid in ``(x, y)``."""

    __pydantic_config__ = _STRICT
    diameter_mm: float = 3.0
    pitch_mm: float = 8.0
    layout: Literal["square", "hex"] = "square"
    rim_margin_mm: float = 8.0  # no markers closer than this to the membrane's clamped rim


@dataclass(frozen=True)
class FiducialConfig:
    """Square ArUco fiducials fixed on the base plate, axis-aligned, at known positions in J."""

    __pydantic_config__ = _STRICT
    dictionary: str = "DICT_4X4_50"
    ids: tuple[int, ...] = (0, 1, 2, 3)
    centers_mm: tuple[Vec2, ...] = ((-72.0, -38.0), (72.0, -38.0), (72.0, 38.0), (-72.0, 38.0))
    size_mm: float = 14.0  # side of the black square including the marker's own border
    z_mm: float = -5.0  # the plate's bottom face: seen through air only, so plain PnP is exact


@dataclass(frozen=True)
class AlignmentConfig:
    """The four white circular markers on the jig that a robot's hand-eye camera sees to align the jig
    with the robot (the paper's Fig. "Setup to jig coordinate calibration" (c)), on the plate's top face."""

    __pydantic_config__ = _STRICT
    circle_centers_mm: tuple[Vec2, ...] = ((-100.0, -100.0), (100.0, -100.0), (100.0, 100.0), (-100.0, 100.0))
    circle_diameter_mm: float = 10.0
    z_mm: float = 0.0


@dataclass(frozen=True)
class MediumConfig:
    """The filling: glass beads in index-matched oil, and how it degrades the image.

    The bead pack scatters light by small angles; a marker seen through a path of length ``L`` (mm) in
    the pack is blurred by a Gaussian of standard deviation ``blur_coefficient * L ** 1.5`` mm in the
    plane of the marker (multiple small-angle scattering spreads as ``L^(3/2)``). The beads are not
    perfectly clear and transmit light unevenly: bead speckle multiplies the image by ``1 + s``, ``s`` a
    spatially correlated texture of standard deviation ``speckle_std`` and correlation length one bead
    diameter, projected into the image.

    The speckle is a property of *this* bead pack: the beads do not move between frames except where
    the part pushes the membrane into the pack, so each camera sees one fixed texture (a function of
    ``speckle_seed`` and the camera), the same in the unloaded reference frame and in every loaded
    frame. Where the membrane has moved by more than ``speckle_redraw_displacement_mm`` the beads next
    to it are pushed aside and re-pack, and a fraction ``speckle_redraw_fraction`` of the texture's
    variance is new in that frame (see :mod:`softjig.sim.render`, step 4).
    """

    __pydantic_config__ = _STRICT
    oil_refractive_index: float = 1.51
    bead_refractive_index: float = 1.52
    bead_diameter_mm: float = 1.0
    blur_coefficient: float = 0.0035  # mm^-1/2
    speckle_std: float = 0.04  # relative: ~5 gray levels on a marker, ~1 on the black membrane
    # True: the bead pack's fixed texture (a real jig); False: a new texture every frame (a pack stirred
    # between frames: an idealisation, and the simulator's behaviour before the static texture).
    speckle_static: bool = True
    speckle_seed: int = 0  # which bead pack: the static texture is drawn from this seed and the camera
    # Fraction of the speckle's variance redrawn where the membrane moved beads: only the beads next to
    # the membrane (a few of the ~20-30 bead layers along the optical path) re-pack, the rest of the
    # column stays put, so well below 1. The texture's correlation with the reference frame's there is
    # 1 - speckle_redraw_fraction (the kept layers' share of the variance).
    speckle_redraw_fraction: float = 0.3
    # How far (mm) the membrane must move to push a bead out of its pocket: about half a bead diameter.
    speckle_redraw_displacement_mm: float = 0.5


@dataclass(frozen=True)
class ImagingConfig:
    """Illumination, sensor noise and output format of the rendered images (fractions of full scale).

    Levels are radiances at an exposure of 1, as fractions of the sensor's full scale. The markers are
    hand-cast: each reflects ``1 + marker_brightness_spread * z`` times the nominal light (``z`` standard
    normal, fixed per marker and jig, drawn from ``marker_brightness_seed``). Each camera's light
    collection (its ``exposure``, relative: shutter time x aperture) scales the radiance before the
    sensor's shot and read noise; its ``gain`` (relative) scales the signal and its noise after.
    """

    __pydantic_config__ = _STRICT
    background_level: float = 0.08  # the black membrane
    marker_level: float = 0.55  # a marker's face lit head-on
    illumination_falloff: float = 0.3  # relative loss of light at the image corner
    full_well_electrons: float = 6000.0  # shot noise: sigma = sqrt(I * full_well) / full_well
    read_noise: float = 0.008
    bit_depth: Literal[8, 16] = 8
    supersampling: int = 4  # sub-samples per pixel side when rendering marker shapes
    marker_brightness_spread: float = 0.08  # relative std of a marker's brightness (paint, cast shape)
    marker_brightness_seed: int = 0  # which set of markers: each marker's brightness factor
    # "hemisphere": a cast white dome, shaded (1 + cos) / 2 by its normal; "disc": a flat painted disc
    # on the membrane, uniformly bright (Lambertian: times the cosine of its tilt to the view ray).
    marker_appearance: Literal["hemisphere", "disc"] = "hemisphere"
    # Centre of the illumination's fall-off, off the image centre: (u, v) as fractions of the half-width
    # and half-height, for the left camera; the right camera's is mirrored in u (one LED ring between the
    # two cameras lights each image's inner side more).
    illumination_center: Vec2 = (0.1, 0.05)
    exposure: Vec2 = (1.0, 0.93)  # (left, right) light collected, relative to the levels above
    gain: Vec2 = (1.0, 1.05)  # (left, right) sensor gain, relative: multiplies signal and noise


@dataclass(frozen=True)
class CameraConfig:
    """A pinhole camera with OpenCV distortion and its pose in the jig frame J.

    ``rotation_deg`` is the rotation vector (axis times angle, degrees) of ``R_J_cam``; with zero rotation
    the camera looks along J's ``+z`` with its ``x`` along J's ``x``.
    """

    __pydantic_config__ = _STRICT
    width_px: int = 1280
    height_px: int = 720
    fx_px: float = 925.0
    fy_px: float = 925.0
    cx_px: float = 639.5
    cy_px: float = 359.5
    distortion: tuple[float, float, float, float, float] = (0.0, 0.0, 0.0, 0.0, 0.0)
    position_mm: Vec3 = (0.0, 0.0, -155.0)
    rotation_deg: Vec3 = (0.0, 0.0, 0.0)

    @property
    def K(self) -> np.ndarray:
        """The 3x3 intrinsic matrix (px)."""
        return np.array([[self.fx_px, 0.0, self.cx_px], [0.0, self.fy_px, self.cy_px], [0, 0, 1.0]])

    @property
    def T_J_cam(self) -> np.ndarray:
        """The camera's pose in J, a 4x4 matrix mapping camera coordinates to J (mm)."""
        from softjig.geometry import pose_from_rotvec_translation

        return pose_from_rotvec_translation(np.radians(self.rotation_deg), self.position_mm)


def _default_left() -> CameraConfig:
    return CameraConfig(position_mm=(-15.0, 0.0, -155.0))


def _default_right() -> CameraConfig:
    return CameraConfig(position_mm=(15.0, 0.0, -155.0))


@dataclass(frozen=True)
class StereoConfig:
    """The two cameras. ``rectified`` says the images are a rectified pair (same intrinsics, same
    orientation, right camera displaced along the left camera's ``x``)."""

    __pydantic_config__ = _STRICT
    left: CameraConfig = field(default_factory=_default_left)
    right: CameraConfig = field(default_factory=_default_right)
    rectified: bool = True

    @property
    def baseline_mm(self) -> float:
        """Distance between the optical centres (mm)."""
        return float(np.linalg.norm(np.subtract(self.right.position_mm, self.left.position_mm)))


@dataclass(frozen=True)
class ToleranceConfig:
    """How far an as-built jig departs from its drawing (one standard deviation of each error).

    The simulator draws an as-built jig from these (see :mod:`softjig.sim.asbuilt`); set them all to zero
    for exact tests. The estimator never sees the as-built jig.
    """

    __pydantic_config__ = _STRICT
    camera_position_mm: float = 1.0  # the stereo head's placement under the plate
    camera_rotation_deg: float = 0.5  # the stereo head's orientation
    # A rectified pair's intrinsics come from a stereo calibration: what remains are its residual errors.
    focal_fraction: float = 0.001  # relative focal length error of each camera
    principal_point_px: float = 0.3
    refractive_index: float = 0.005  # of the plate and of the oil
    marker_placement_mm: float = 0.2  # where the mould put each marker
    membrane_ripple_mm: float = 0.1  # beads pressing through the membrane where it is in contact
    edge_conformity_mm: float = 0.0  # optional: how much the membrane fails to follow near a contact edge

    def is_zero(self) -> bool:
        """True when the as-built jig equals the nominal one."""
        return all(v == 0 for v in asdict(self).values())


@dataclass(frozen=True)
class SensingConfig:
    """Parameters of the estimator; ``None`` means "derive from the jig's geometry"."""

    __pydantic_config__ = _STRICT
    log_sigma_px: float | None = None
    detection_threshold: float | None = None
    row_tolerance_px: float = 3.0
    disparity_margin_px: float = 8.0
    min_points: int = 6  # fewer markers in the crop than this: no estimate (exit code 3)
    # Where the cameras' pose in J comes from: "fiducials" (measured in every pair, required), "config"
    # (the fixed extrinsics above, calibrated once), or "auto" (fiducials when found, else the config).
    extrinsics: Literal["auto", "fiducials", "config"] = "auto"


@dataclass(frozen=True)
class JigConfig:
    """A whole soft jig: its hardware, its as-built tolerances and the estimator's parameters."""

    __pydantic_config__ = _STRICT
    name: str = "paper-jig"
    version: int = CONFIG_VERSION
    plate: PlateConfig = field(default_factory=PlateConfig)
    membrane: MembraneConfig = field(default_factory=MembraneConfig)
    markers: MarkerConfig = field(default_factory=MarkerConfig)
    fiducials: FiducialConfig = field(default_factory=FiducialConfig)
    alignment: AlignmentConfig = field(default_factory=AlignmentConfig)
    medium: MediumConfig = field(default_factory=MediumConfig)
    imaging: ImagingConfig = field(default_factory=ImagingConfig)
    cameras: StereoConfig = field(default_factory=StereoConfig)
    tolerances: ToleranceConfig = field(default_factory=ToleranceConfig)
    sensing: SensingConfig = field(default_factory=SensingConfig)

    def replace(self, **sections: Any) -> JigConfig:
        """A copy with whole sections replaced, validated."""
        jig = replace(self, **sections)
        validate_jig(jig)
        return jig


# --------------------------------------------------------------------------------------------- parts


@dataclass(frozen=True)
class CylinderPart:
    """A cylinder standing on its flat circular bottom face."""

    __pydantic_config__ = _STRICT
    diameter_mm: float
    height_mm: float = 30.0
    kind: Literal["cylinder"] = "cylinder"

    @property
    def base_radius_mm(self) -> float:
        """Radius of the disc that contains the bottom face (what the paper crops to)."""
        return self.diameter_mm / 2.0


@dataclass(frozen=True)
class BoxPart:
    """A box standing on its rectangular bottom face (``size_x_mm`` by ``size_y_mm`` in the part frame)."""

    __pydantic_config__ = _STRICT
    size_x_mm: float
    size_y_mm: float
    height_mm: float
    kind: Literal["box"] = "box"

    @property
    def diameter_mm(self) -> float:
        """Diameter of the circle inscribed in the bottom face: the crop a user would give."""
        return min(self.size_x_mm, self.size_y_mm)

    @property
    def base_radius_mm(self) -> float:
        """Radius of the disc inscribed in the bottom face."""
        return self.diameter_mm / 2.0


Part = CylinderPart | BoxPart


def cube(side_mm: float = 50.0) -> BoxPart:
    """The paper's cube."""
    return BoxPart(size_x_mm=side_mm, size_y_mm=side_mm, height_mm=side_mm)


def part_to_dict(part: Part) -> dict[str, Any]:
    """The JSON/TOML form of a part, with its ``kind``."""
    return asdict(part)


def part_from_dict(data: dict[str, Any]) -> Part:
    """Parse a part written by :func:`part_to_dict`; raises :class:`ConfigError` naming the problem."""
    kinds = {"cylinder": CylinderPart, "box": BoxPart}
    kind = data.get("kind")
    if kind not in kinds:
        raise ConfigError(f"part.kind must be one of {sorted(kinds)}, got {kind!r}")
    part = _parse(kinds[kind], data, "part")
    validate_part(part)
    return part


# ----------------------------------------------------------------------------------------- validation


def _fail(field_path: str, problem: str) -> None:
    raise ConfigError(f"{field_path}: {problem}")


def _positive(value: float, field_path: str) -> None:
    if not (math.isfinite(value) and value > 0):
        _fail(field_path, f"must be a positive finite number, got {value!r}")


def _non_negative(value: float, field_path: str) -> None:
    if not (math.isfinite(value) and value >= 0):
        _fail(field_path, f"must be zero or positive, got {value!r}")


def validate_part(part: Part, jig: JigConfig | None = None) -> None:
    """Check a part on its own and, when ``jig`` is given, that it fits the membrane.

    Raises
    ------
    ConfigError
        Naming the field and the problem.
    """
    if isinstance(part, CylinderPart):
        _positive(part.diameter_mm, "part.diameter_mm")
    else:
        _positive(part.size_x_mm, "part.size_x_mm")
        _positive(part.size_y_mm, "part.size_y_mm")
    _positive(part.height_mm, "part.height_mm")
    if jig is not None:
        if isinstance(part, CylinderPart):
            width = part.diameter_mm
        else:
            width = math.hypot(part.size_x_mm, part.size_y_mm)
        if width >= 2 * jig.membrane.footprint_radius_mm:
            _fail(
                "part",
                f"its bottom face ({width:.1f} mm across) is wider than the membrane "
                f"({2 * jig.membrane.footprint_radius_mm:.1f} mm): use a larger jig or a smaller part",
            )


def validate_jig(jig: JigConfig) -> None:
    """Check every section of a jig and their consistency.

    Raises
    ------
    ConfigError
        Naming the field (as in the TOML file, e.g. ``markers.diameter_mm``) and the problem.
    """
    p, m, mk, f, md, im, tol = (
        jig.plate,
        jig.membrane,
        jig.markers,
        jig.fiducials,
        jig.medium,
        jig.imaging,
        jig.tolerances,
    )
    if jig.version != CONFIG_VERSION:
        _fail("version", f"this softjig reads config version {CONFIG_VERSION}, got {jig.version}")
    for name in ("size_x_mm", "size_y_mm", "thickness_mm"):
        _positive(getattr(p, name), f"plate.{name}")
    for name in (
        "dome_height_mm",
        "footprint_radius_mm",
        "dome_exponent",
        "thickness_mm",
        "decay_length_mm",
        "max_wall_slope_deg",
    ):
        _positive(getattr(m, name), f"membrane.{name}")
    if m.max_wall_slope_deg >= 90:
        _fail("membrane.max_wall_slope_deg", f"must be below 90 degrees, got {m.max_wall_slope_deg}")
    if m.dome_exponent < 1:
        _fail("membrane.dome_exponent", f"must be >= 1 for a dome, got {m.dome_exponent}")
    if 2 * m.footprint_radius_mm > min(p.size_x_mm, p.size_y_mm):
        _fail(
            "membrane.footprint_radius_mm",
            f"the membrane ({2 * m.footprint_radius_mm} mm across) does not fit on the plate "
            f"({p.size_x_mm} x {p.size_y_mm} mm)",
        )
    _positive(mk.diameter_mm, "markers.diameter_mm")
    _positive(mk.pitch_mm, "markers.pitch_mm")
    if mk.diameter_mm >= mk.pitch_mm:
        _fail(
            "markers.diameter_mm",
            f"markers ({mk.diameter_mm} mm) are as wide as or wider than their pitch "
            f"({mk.pitch_mm} mm): they would merge; reduce the diameter or increase the pitch",
        )
    _non_negative(mk.rim_margin_mm, "markers.rim_margin_mm")
    if mk.rim_margin_mm >= m.footprint_radius_mm:
        _fail("markers.rim_margin_mm", "leaves no room for markers on the membrane")
    if len(f.ids) != len(f.centers_mm):
        _fail("fiducials.ids", f"{len(f.ids)} ids for {len(f.centers_mm)} centres: give one id each")
    if len(set(f.ids)) != len(f.ids):
        _fail("fiducials.ids", "ids must be distinct")
    _positive(f.size_mm, "fiducials.size_mm")
    if not (-p.thickness_mm - 1e-9 <= f.z_mm <= 1e-9):
        _fail("fiducials.z_mm", f"must lie on the plate (between {-p.thickness_mm} and 0), got {f.z_mm}")
    from softjig.sensing.fiducials import aruco_dictionary_names

    if f.dictionary not in aruco_dictionary_names():
        _fail(
            "fiducials.dictionary",
            f"unknown ArUco dictionary {f.dictionary!r}; valid: {', '.join(aruco_dictionary_names())}",
        )
    al = jig.alignment
    if len(al.circle_centers_mm) < 4:
        _fail("alignment.circle_centers_mm", f"PnP needs at least 4 circles, got {len(al.circle_centers_mm)}")
    _positive(al.circle_diameter_mm, "alignment.circle_diameter_mm")
    half_x, half_y = p.size_x_mm / 2.0, p.size_y_mm / 2.0
    for k, (x, y) in enumerate(al.circle_centers_mm):
        if abs(x) + al.circle_diameter_mm / 2 > half_x or abs(y) + al.circle_diameter_mm / 2 > half_y:
            _fail(
                f"alignment.circle_centers_mm[{k}]",
                f"({x}, {y}) is not on the {p.size_x_mm} x {p.size_y_mm} mm plate",
            )
    for name in ("oil_refractive_index", "bead_refractive_index"):
        if not 1.0 <= getattr(md, name) < 3.0:
            _fail(f"medium.{name}", f"must be a refractive index in [1, 3), got {getattr(md, name)}")
    if not 1.0 <= p.refractive_index < 3.0:
        _fail("plate.refractive_index", f"must be in [1, 3), got {p.refractive_index}")
    _positive(md.bead_diameter_mm, "medium.bead_diameter_mm")
    _non_negative(md.blur_coefficient, "medium.blur_coefficient")
    _non_negative(md.speckle_std, "medium.speckle_std")
    for name in ("background_level", "marker_level"):
        if not 0.0 <= getattr(im, name) <= 1.0:
            _fail(f"imaging.{name}", f"must be a fraction of full scale in [0, 1], got {getattr(im, name)}")
    if im.marker_level <= im.background_level:
        _fail("imaging.marker_level", "must be brighter than imaging.background_level")
    if not 0.0 <= im.illumination_falloff < 1.0:
        _fail("imaging.illumination_falloff", f"must be in [0, 1), got {im.illumination_falloff}")
    _positive(im.full_well_electrons, "imaging.full_well_electrons")
    _non_negative(im.read_noise, "imaging.read_noise")
    if not 1 <= im.supersampling <= 16:
        _fail("imaging.supersampling", f"must be between 1 and 16, got {im.supersampling}")
    _validate_image_model(md, im)
    for side in ("left", "right"):
        _validate_camera(getattr(jig.cameras, side), f"cameras.{side}", jig)
    if jig.cameras.baseline_mm <= 0:
        _fail("cameras", "the two cameras are at the same place: no baseline")
    if jig.cameras.rectified:
        _validate_rectified(jig.cameras)
    for name, value in asdict(tol).items():
        _non_negative(value, f"tolerances.{name}")
    s = jig.sensing
    if s.log_sigma_px is not None:
        _positive(s.log_sigma_px, "sensing.log_sigma_px")
    if s.detection_threshold is not None:
        _positive(s.detection_threshold, "sensing.detection_threshold")
    _positive(s.row_tolerance_px, "sensing.row_tolerance_px")
    _non_negative(s.disparity_margin_px, "sensing.disparity_margin_px")
    if s.min_points < 3:
        _fail("sensing.min_points", f"a plane needs at least 3 points, got {s.min_points}")


def _validate_image_model(md: MediumConfig, im: ImagingConfig) -> None:
    """The simulated image model's fields (bead-pack speckle, marker brightness, illumination, sensors)."""
    if not 0.0 <= md.speckle_redraw_fraction <= 1.0:
        _fail(
            "medium.speckle_redraw_fraction",
            f"must be a fraction in [0, 1], got {md.speckle_redraw_fraction}",
        )
    _non_negative(md.speckle_redraw_displacement_mm, "medium.speckle_redraw_displacement_mm")
    if md.speckle_seed < 0:
        _fail("medium.speckle_seed", f"must be a non-negative integer, got {md.speckle_seed}")
    if im.marker_brightness_seed < 0:
        _fail(
            "imaging.marker_brightness_seed",
            f"must be a non-negative integer, got {im.marker_brightness_seed}",
        )
    if not 0.0 <= im.marker_brightness_spread <= 0.5:
        _fail(
            "imaging.marker_brightness_spread",
            f"must be a relative standard deviation in [0, 0.5], got {im.marker_brightness_spread}",
        )
    for k, value in enumerate(im.illumination_center):
        if not (math.isfinite(value) and abs(value) <= 1.0):
            _fail(
                f"imaging.illumination_center[{k}]",
                f"must lie in the image (a fraction of its half-size, in [-1, 1]), got {value}",
            )
    for name in ("exposure", "gain"):
        for k, value in enumerate(getattr(im, name)):
            if not (math.isfinite(value) and 0.05 <= value <= 20.0):
                _fail(f"imaging.{name}[{k}]", f"must be a relative factor in [0.05, 20], got {value}")


def _validate_camera(cam: CameraConfig, where: str, jig: JigConfig) -> None:
    _positive(cam.width_px, f"{where}.width_px")
    _positive(cam.height_px, f"{where}.height_px")
    _positive(cam.fx_px, f"{where}.fx_px")
    _positive(cam.fy_px, f"{where}.fy_px")
    if cam.position_mm[2] >= -jig.plate.thickness_mm:
        _fail(
            f"{where}.position_mm",
            f"the camera must be below the plate's bottom face "
            f"(z < {-jig.plate.thickness_mm} mm), got z = {cam.position_mm[2]}",
        )
    # The camera must see the jig axis: the membrane's apex must project inside the image. Refraction
    # through flat layers keeps a point on the same side, so the pinhole test is conservative enough.
    from softjig.geometry import invert_pose

    apex_J = np.array([0.0, 0.0, jig.membrane.dome_height_mm, 1.0])
    p_cam = invert_pose(cam.T_J_cam) @ apex_J
    if p_cam[2] <= 0:
        _fail(
            f"{where}.rotation_deg",
            "the camera does not look towards the membrane (the jig axis "
            "is behind it); with zero rotation a camera looks up along +z",
        )
    u = cam.fx_px * p_cam[0] / p_cam[2] + cam.cx_px
    v = cam.fy_px * p_cam[1] / p_cam[2] + cam.cy_px
    if not (0 <= u < cam.width_px and 0 <= v < cam.height_px):
        _fail(
            where,
            f"the camera does not see the jig axis (the membrane's apex would be at pixel "
            f"({u:.0f}, {v:.0f}), outside its {cam.width_px}x{cam.height_px} image): check its "
            "position_mm, rotation_deg and principal point",
        )


def _validate_rectified(stereo: StereoConfig) -> None:
    left, right = stereo.left, stereo.right
    for name in ("width_px", "height_px", "fx_px", "fy_px", "cx_px", "cy_px", "distortion", "rotation_deg"):
        if getattr(left, name) != getattr(right, name):
            _fail(
                f"cameras.right.{name}",
                f"differs from the left camera's ({getattr(right, name)} vs {getattr(left, name)}) "
                "but cameras.rectified is true: a rectified pair shares intrinsics and orientation",
            )
    if any(stereo.left.distortion):
        _fail("cameras.left.distortion", "a rectified pair has no distortion")
    offset_cam = invert_rotation_of(left) @ np.subtract(right.position_mm, left.position_mm)
    if abs(offset_cam[1]) > 1e-6 * stereo.baseline_mm or abs(offset_cam[2]) > 1e-6 * stereo.baseline_mm:
        _fail(
            "cameras.right.position_mm",
            "a rectified pair's right camera must lie on the left camera's x axis",
        )
    if offset_cam[0] <= 0:
        _fail("cameras.right.position_mm", "the right camera must be to the right (+x) of the left one")


def invert_rotation_of(cam: CameraConfig) -> np.ndarray:
    """``R_cam_J`` of a camera (3x3)."""
    return cam.T_J_cam[:3, :3].T


# ------------------------------------------------------------------------------------------ TOML I/O


def _parse(cls: type, data: Any, where: str) -> Any:
    try:
        return TypeAdapter(cls).validate_python(data)
    except ValidationError as exc:
        err = exc.errors()[0]
        loc = ".".join(str(x) for x in (where, *err["loc"]) if x != "")
        more = f" (and {exc.error_count() - 1} more)" if exc.error_count() > 1 else ""
        raise ConfigError(f"{loc}: {err['msg']}{more}") from None


def jig_to_dict(jig: JigConfig) -> dict[str, Any]:
    """The plain-dict (TOML/JSON) form of a jig; ``None`` values are left out (TOML has no null)."""

    def clean(value: Any) -> Any:
        if isinstance(value, dict):
            return {k: clean(v) for k, v in value.items() if v is not None}
        if isinstance(value, tuple | list):
            return [clean(v) for v in value]
        return value

    return clean(asdict(jig))


def jig_from_dict(data: dict[str, Any]) -> JigConfig:
    """Build and validate a jig from its dict form; raises :class:`ConfigError` naming the field."""
    jig = _parse(JigConfig, data, "")
    validate_jig(jig)
    return jig


def default_jig() -> JigConfig:
    """The paper's jig (``DESIGN.md`` §2), validated."""
    jig = JigConfig()
    validate_jig(jig)
    return jig


def exact_jig(jig: JigConfig | None = None) -> JigConfig:
    """``jig`` (default: :func:`default_jig`) with every as-built tolerance set to zero."""
    jig = jig or default_jig()
    return jig.replace(tolerances=ToleranceConfig(**{k: 0.0 for k in asdict(jig.tolerances)}))


def dumps_jig(jig: JigConfig) -> str:
    """The TOML text of a jig."""
    return tomli_w.dumps(jig_to_dict(jig))


def loads_jig(text: str, *, source: str = "<string>") -> JigConfig:
    """Parse TOML text into a validated jig."""
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{source} is not valid TOML: {exc}") from None
    return jig_from_dict(data)


def load_jig(path: str | os.PathLike[str]) -> JigConfig:
    """Read a jig from a TOML file.

    Raises
    ------
    InputError
        If the file is missing or unreadable.
    ConfigError
        If it is not valid TOML or a value is invalid; the message names the field.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise InputError(
            f"config file {path} does not exist: pass the rig.toml of your jig "
            "(or write the default one with `softjig config --out rig.toml`)"
        ) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"cannot read config file {path}: {exc}") from None
    return loads_jig(text, source=str(path))


def save_jig(jig: JigConfig, path: str | os.PathLike[str]) -> None:
    """Write a jig as TOML, atomically."""
    validate_jig(jig)
    write_text_atomic(path, dumps_jig(jig))
