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

import functools
import math
import os
import tomllib
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any, Literal

import numpy as np

from softjig.dataclass_parse import parse_dataclass
from softjig.errors import ConfigError, InputError
from softjig.files import read_text_file, write_text_atomic

# Files are read by :func:`~softjig.dataclass_parse.parse_dataclass`, which refuses unknown keys, NaN and
# infinities (TOML has ``nan`` and ``inf`` literals); values built in Python are checked for finiteness by
# :func:`validate_jig` as well. ``__pydantic_config__`` (pydantic's ``ConfigDict``, a plain dict) gives the
# same rules to pydantic where a study validates one field's values (:mod:`softjig.study.spec`).
_STRICT = {"extra": "forbid", "allow_inf_nan": False}

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

    The rest shape of the membrane's *inner* face (where the markers are) is a dome of height
    ``H = dome_height_mm`` on the axis, clamped to the plate at ``R = footprint_radius_mm``, with
    ``s = r / R`` and ``p = dome_exponent``; ``dome_profile`` says which:

    - ``"power"`` (the default): ``h = H (1 - s^p)``, ``p >= 1``; a larger exponent gives a flatter top
      and a steeper rim (2 is a paraboloid, 4 the bag of jammed beads of the paper's jig);
    - ``"paraboloid_power"``: ``h = H (1 - s^2)^p``, ``0 < p <= 1``; 1 is a paraboloid, 1/2 a
      half-ellipsoid, smaller ones are flatter with a wall that meets the plate steeply;
    - ``"table"``: a measured profile, the heights ``profile_h_mm`` (inner face above the plate, mm) at
      the radii ``profile_r_mm`` (mm from the axis): ``r`` starts at 0 and increases, ``h`` never
      increases and starts at ``dome_height_mm``; it is interpolated by a monotone cubic (PCHIP,
      mirrored about the axis so the dome is flat on top), and continued to ``(R, 0)`` when the table
      stops short of the rim. ``dome_exponent`` is not used.

    Read the rest shape only through :mod:`softjig.jig_shape`, which knows every profile.
    """

    __pydantic_config__ = _STRICT
    dome_height_mm: float = 30.0
    footprint_radius_mm: float = 95.0
    dome_exponent: float = 4.0
    thickness_mm: float = 0.7
    decay_length_mm: float = 5.0  # how fast the surface returns to rest around a shallow contact
    max_wall_slope_deg: float = 35.0  # no steeper than the bead pack's angle of repose
    dome_profile: Literal["power", "paraboloid_power", "table"] = "power"
    profile_r_mm: tuple[float, ...] = ()  # "table" only: radii from the axis (mm), from 0, increasing
    profile_h_mm: tuple[float, ...] = ()  # "table" only: inner-face heights at those radii (mm)

    @functools.cached_property
    def table_spline(self) -> Any:
        """The measured table's interpolant ``h(r)`` (a SciPy PCHIP over ``[-R, R]``), made once per config
        (building it takes about 0.8 ms, evaluating it 20 us, measured); read it through
        :mod:`softjig.jig_shape`. The table is continued to ``(footprint_radius_mm, 0)`` when it stops
        short of the rim and mirrored about the axis, where PCHIP's slope is then 0 (a flat top)."""
        from scipy.interpolate import PchipInterpolator

        r = np.asarray(self.profile_r_mm, dtype=float)
        h = np.asarray(self.profile_h_mm, dtype=float)
        if r[-1] < self.footprint_radius_mm:
            r, h = np.append(r, self.footprint_radius_mm), np.append(h, 0.0)
        return PchipInterpolator(np.concatenate([-r[:0:-1], r]), np.concatenate([h[:0:-1], h]))


@dataclass(frozen=True)
class MarkerConfig:
    """White hemispherical markers on the membrane's inner face, at known ``(x, y)`` in J.

    ``layout`` is a grid (``"square"`` or ``"hex"``, of spacing ``pitch_mm``) or ``"explicit"``:

    - a grid has a marker at ``offset_mm`` (mm, in J) and is turned by ``rotation_deg`` about it
      (counter-clockwise seen from above, ``+x`` towards ``+y``); only its markers within
      ``footprint_radius_mm - rim_margin_mm`` of the jig axis are made;
    - an explicit layout lists every marker's centre, ``centers_mm`` (``(x, y)`` in J, mm), for a
      hand-made membrane or one surveyed by ``softjig survey``; ``centers_z_mm`` optionally gives each
      marker's measured inner-face height in J (mm, one per centre, or empty): the estimator's rest
      shape at the markers is then the measured one (:func:`softjig.jig_shape.rest_marker_points_mm`).
      ``rotation_deg``, ``offset_mm`` and ``rim_margin_mm`` do not apply; ``pitch_mm`` is then the
      typical distance between neighbouring markers, which the estimator uses for its neighbourhoods
      (it must be within a third of the layout's median nearest-neighbour distance).

    Markers must not overlap: centres at least one ``diameter_mm`` apart.
    """

    __pydantic_config__ = _STRICT
    diameter_mm: float = 3.0
    pitch_mm: float = 8.0
    layout: Literal["square", "hex", "explicit"] = "square"
    rim_margin_mm: float = 8.0  # no markers closer than this to the membrane's clamped rim
    rotation_deg: float = 0.0  # grids: turn of the grid about offset_mm (degrees, +x towards +y)
    offset_mm: Vec2 = (0.0, 0.0)  # grids: where the grid's central marker is, in J (mm)
    centers_mm: tuple[Vec2, ...] = ()  # "explicit": each marker's (x, y) in J (mm)
    centers_z_mm: tuple[float, ...] = ()  # "explicit", optional: each marker's measured height (mm)


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
    # Air bubbles lodged in the bead pack (a jig filled without degassing the oil), fixed where they are
    # (drawn from speckle_seed: the same pack): each refracts the light away at its rim, a dark ring over
    # whatever lies behind it, and shows a small bright reflection of the lights. 0: none (a degassed fill).
    bubbles: int = 0
    # A bubble's typical radius (mm); each one's is drawn in [0.5, 1.5] times this.
    bubble_radius_mm: float = 1.0


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
    # Share of the markers whose paint has flaked off (a worn or damaged membrane): they are not seen, in
    # any frame (drawn from marker_brightness_seed). 0: every marker is there.
    missing_marker_fraction: float = 0.0
    # Specular glints in each image: the lights reflected by the plate's faces and by the beads, small
    # saturated spots fixed in each camera's image (other places in the other camera). 0: none.
    glints: int = 0


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

    def depth_scale_error(self, oil_refractive_index: float) -> float:
        """The relative error (1 sigma) of every depth a refractive triangulation measures, the same for all
        markers: the oil's index (a depth in the oil is its apparent depth times the index, so a relative
        error of ``refractive_index / n_oil``) and the cameras' focal length (depth from disparity scales
        with it), in quadrature. The plate's index shifts every depth by the same amount, which tilts no
        plane; a scale error tilts a face tilted by ``alpha`` by about its value times
        ``sin(alpha) cos(alpha)``."""
        return math.hypot(self.refractive_index / oil_refractive_index, self.focal_fraction)


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
    # The marker detector, by name (softjig.sensing.stages.DETECTORS; "log": the LoG and the model fit).
    detector: str = "log"


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
#
# A part is the shape of its flat bottom face (and its height), in the part frame: origin at the face's
# centre, ``z`` along the face's normal into the part (:mod:`softjig.sim.parts`). Where the part is on
# the jig is not part of its shape: a frame says it (``pose`` in ``frames.jsonl``: ``center_xy_mm``,
# ``yaw_deg``; :class:`PartPlacement`). Every kind has a ``diameter_mm``, the diameter of the largest
# circle centred on the part frame's origin inside the bottom face (a cylinder's diameter, a box's shorter
# side, a regular polygon's size across flats): the crop the estimator may use (``--part-diameter``).
# :meth:`outline_mm` gives the face's outline for footprints, :meth:`circumradius_mm` its reach.

CIRCLE_OUTLINE_POINTS = 72  # a cylinder's outline as a polygon: 0.1 % short of the circle at worst
MAX_POLYGON_SIDES = 64  # more sides than this: a cylinder describes it as well
MAX_POLYGON_VERTICES = 1000


def _circle_outline(radius_mm: float, n: int) -> np.ndarray:
    angle = np.linspace(0.0, 2 * np.pi, n, endpoint=False)
    return np.column_stack([radius_mm * np.cos(angle), radius_mm * np.sin(angle)])


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

    def outline_mm(self, circle_points: int = CIRCLE_OUTLINE_POINTS) -> np.ndarray:
        """The bottom face's outline, ``(M, 2)`` counter-clockwise in the part frame (mm): the circle
        sampled at ``circle_points`` points, the first on ``+x``."""
        return _circle_outline(self.diameter_mm / 2.0, circle_points)

    def circumradius_mm(self) -> float:
        """Farthest point of the bottom face from the part frame's origin (mm)."""
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

    def outline_mm(self, circle_points: int = CIRCLE_OUTLINE_POINTS) -> np.ndarray:
        """The four corners, ``(4, 2)`` counter-clockwise from ``(-x, -y)``, in the part frame (mm)."""
        hx, hy = self.size_x_mm / 2.0, self.size_y_mm / 2.0
        return np.array([[-hx, -hy], [hx, -hy], [hx, hy], [-hx, hy]])

    def circumradius_mm(self) -> float:
        """Half the face's diagonal (mm)."""
        return math.hypot(self.size_x_mm, self.size_y_mm) / 2.0


@dataclass(frozen=True)
class RegularPolygonPart:
    """A prism on a regular polygon of ``n_sides``, ``across_flats_mm`` between opposite sides (for an odd
    number of sides: twice the distance from the centre to a side). One side faces the part frame's
    ``+x`` (a square is a box of side ``across_flats_mm``; a hexagon has two corners on ``+y`` and ``-y``).
    """

    __pydantic_config__ = _STRICT
    n_sides: int
    across_flats_mm: float
    height_mm: float = 30.0
    kind: Literal["polygon"] = "polygon"

    @property
    def diameter_mm(self) -> float:
        """Diameter of the inscribed circle: the size across flats (mm)."""
        return self.across_flats_mm

    @property
    def base_radius_mm(self) -> float:
        """Radius of the inscribed circle (mm)."""
        return self.across_flats_mm / 2.0

    def outline_mm(self, circle_points: int = CIRCLE_OUTLINE_POINTS) -> np.ndarray:
        """The corners, ``(n_sides, 2)`` counter-clockwise in the part frame (mm)."""
        n = self.n_sides
        angle = (np.arange(n) + 0.5) * 2 * np.pi / n
        return self.circumradius_mm() * np.column_stack([np.cos(angle), np.sin(angle)])

    def circumradius_mm(self) -> float:
        """Distance from the centre to a corner (mm)."""
        return self.across_flats_mm / 2.0 / math.cos(math.pi / self.n_sides)


@dataclass(frozen=True)
class ConvexPolygonPart:
    """A prism on any convex polygon: its corners ``vertices_mm`` (``(x, y)`` in the part frame, mm, in
    either winding), around the part frame's origin, which must lie inside the face (it is the point the
    part is placed and tilted about)."""

    __pydantic_config__ = _STRICT
    vertices_mm: tuple[Vec2, ...]
    height_mm: float = 30.0
    kind: Literal["convex"] = "convex"

    @property
    def diameter_mm(self) -> float:
        """Diameter of the largest circle centred on the origin inside the face (mm)."""
        return 2.0 * float(_edge_distances(self.outline_mm()).min())

    @property
    def base_radius_mm(self) -> float:
        """Radius of that circle (mm)."""
        return self.diameter_mm / 2.0

    def outline_mm(self, circle_points: int = CIRCLE_OUTLINE_POINTS) -> np.ndarray:
        """The corners, ``(M, 2)`` counter-clockwise in the part frame (mm)."""
        v = np.asarray(self.vertices_mm, dtype=float).reshape(-1, 2)
        return v if _signed_area(v) >= 0 else v[::-1].copy()

    def circumradius_mm(self) -> float:
        """Farthest corner from the origin (mm)."""
        return float(np.hypot(*np.asarray(self.vertices_mm, dtype=float).reshape(-1, 2).T).max())


Part = CylinderPart | BoxPart | RegularPolygonPart | ConvexPolygonPart
_PART_KINDS: dict[str, type] = {
    "cylinder": CylinderPart,
    "box": BoxPart,
    "polygon": RegularPolygonPart,
    "convex": ConvexPolygonPart,
}


def _signed_area(v: np.ndarray) -> float:
    x, y = v[:, 0], v[:, 1]
    return 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))


def _edge_distances(ccw: np.ndarray) -> np.ndarray:
    """Signed distance from the origin to each edge's line of a counter-clockwise polygon (positive:
    the origin is on the inner side)."""
    edge = np.roll(ccw, -1, axis=0) - ccw
    normal = np.column_stack([edge[:, 1], -edge[:, 0]]) / np.hypot(edge[:, 0], edge[:, 1])[:, None]
    return np.sum(normal * ccw, axis=1)


def cube(side_mm: float = 50.0) -> BoxPart:
    """The paper's cube."""
    return BoxPart(size_x_mm=side_mm, size_y_mm=side_mm, height_mm=side_mm)


def part_to_dict(part: Part) -> dict[str, Any]:
    """The JSON/TOML form of a part, with its ``kind``."""
    return asdict(part)


def part_from_dict(data: dict[str, Any]) -> Part:
    """Parse a part written by :func:`part_to_dict`; raises :class:`ConfigError` naming the problem."""
    kind = data.get("kind") if isinstance(data, dict) else None
    if kind not in _PART_KINDS:
        raise ConfigError(f"part.kind must be one of {sorted(_PART_KINDS)}, got {kind!r}")
    part = parse_dataclass(_PART_KINDS[kind], data, "part")
    validate_part(part)
    return part


@dataclass(frozen=True)
class PartPlacement:
    """Where a part's bottom face is on the jig: its centre ``center_xy_mm`` (``(x, y)`` in J, mm) and its
    spin ``yaw_deg`` about its own axis (degrees, ``+x`` towards ``+y``). A frame's ``pose`` entry in
    ``frames.jsonl`` carries these keys (with the simulator's ``push_depth_mm``, ignored here)."""

    __pydantic_config__ = _STRICT
    center_xy_mm: Vec2 = (0.0, 0.0)
    yaw_deg: float = 0.0


def placement_from_dict(data: dict[str, Any]) -> PartPlacement:
    """A :class:`PartPlacement` from a frame's ``pose`` entry (other keys ignored); ConfigError naming
    ``pose.<field>`` if a value is not a finite number."""
    if not isinstance(data, dict):
        raise ConfigError(f"pose must be a table of center_xy_mm and yaw_deg, got {data!r}")
    known = {k: data[k] for k in ("center_xy_mm", "yaw_deg") if k in data}
    return parse_dataclass(PartPlacement, known, "pose")


# ----------------------------------------------------------------------------------------- validation


def _fail(field_path: str, problem: str) -> None:
    raise ConfigError(f"{field_path}: {problem}")


def _positive(value: float, field_path: str) -> None:
    if not (math.isfinite(value) and value > 0):
        _fail(field_path, f"must be a positive finite number, got {value!r}")


def _non_negative(value: float, field_path: str) -> None:
    if not (math.isfinite(value) and value >= 0):
        _fail(field_path, f"must be zero or positive, got {value!r}")


def validate_part(part: Part, jig: JigConfig | None = None, placement: PartPlacement | None = None) -> None:
    """Check a part on its own and, when ``jig`` is given, that it fits the membrane (centred, or at
    ``placement``: whatever its spin, its bottom face must stay inside the membrane's footprint).

    Raises
    ------
    ConfigError
        Naming the field (``part.<field>``) and the problem.
    """
    _check_numbers(part, "part")
    if isinstance(part, CylinderPart):
        _positive(part.diameter_mm, "part.diameter_mm")
    elif isinstance(part, BoxPart):
        _positive(part.size_x_mm, "part.size_x_mm")
        _positive(part.size_y_mm, "part.size_y_mm")
    elif isinstance(part, RegularPolygonPart):
        if not 3 <= part.n_sides <= MAX_POLYGON_SIDES:
            _fail("part.n_sides", f"must be between 3 and {MAX_POLYGON_SIDES}, got {part.n_sides}")
        _positive(part.across_flats_mm, "part.across_flats_mm")
    elif isinstance(part, ConvexPolygonPart):
        _validate_convex(part.vertices_mm, "part.vertices_mm")
    else:
        raise ConfigError(f"part: unknown part type {type(part).__name__}")
    _positive(part.height_mm, "part.height_mm")
    if jig is None:
        return
    radius = part.circumradius_mm()
    if 2 * radius >= 2 * jig.membrane.footprint_radius_mm:
        _fail(
            "part",
            f"its bottom face ({2 * radius:.1f} mm across) is wider than the membrane "
            f"({2 * jig.membrane.footprint_radius_mm:.1f} mm): use a larger jig or a smaller part",
        )
    if placement is not None:
        _check_numbers(placement, "pose")
        off = math.hypot(*placement.center_xy_mm)
        if off + radius >= jig.membrane.footprint_radius_mm:
            _fail(
                "pose.center_xy_mm",
                f"a part reaching {radius:.1f} mm from its centre, placed {off:.1f} mm off the jig axis, "
                f"overhangs the membrane (radius {jig.membrane.footprint_radius_mm:g} mm): move it inwards",
            )


def _validate_convex(vertices: tuple[Vec2, ...], where: str) -> None:
    """A convex, simple polygon with positive area around the origin."""
    if not 3 <= len(vertices) <= MAX_POLYGON_VERTICES:
        _fail(where, f"needs between 3 and {MAX_POLYGON_VERTICES} corners, got {len(vertices)}")
    v = np.asarray(vertices, dtype=float).reshape(-1, 2)
    edge = np.roll(v, -1, axis=0) - v
    length = np.hypot(edge[:, 0], edge[:, 1])
    scale = float(length.max())
    for k in np.flatnonzero(length <= 1e-9 * max(scale, 1.0)):
        _fail(f"{where}[{k}]", f"repeats the next corner {tuple(map(float, v[(k + 1) % len(v)]))}: remove it")
    area = _signed_area(v)
    if abs(area) <= 1e-12 * scale**2:
        _fail(where, "the corners enclose no area")
    sign = 1.0 if area > 0 else -1.0
    nxt = np.roll(edge, -1, axis=0)
    cross = sign * (edge[:, 0] * nxt[:, 1] - edge[:, 1] * nxt[:, 0])
    for k in np.flatnonzero(cross < -1e-12 * scale**2):
        _fail(
            f"{where}[{(k + 1) % len(v)}]",
            f"the polygon turns the other way at corner {(k + 1) % len(v)} "
            f"{tuple(float(c) for c in v[(k + 1) % len(v)])}: it is not convex (give the corners of a "
            "convex face in order around it)",
        )
    turning = float(np.sum(np.arctan2(cross, np.sum(edge * nxt, axis=1))))
    if abs(turning - 2 * math.pi) > 1e-6:
        _fail(
            where,
            f"the outline winds {turning / (2 * math.pi):.0f} times around: it crosses itself (give the "
            "corners of a convex face once, in order around it)",
        )
    ccw = v if sign > 0 else v[::-1]
    if _edge_distances(ccw).min() <= 0:
        _fail(
            where,
            "the part frame's origin (0, 0) is not inside the face: give the corners about the face's "
            "centre (the point the part is placed and tilted about)",
        )


def _check_numbers(obj: Any, where: str) -> None:
    """Every float in a config dataclass (recursively, tuples included) is finite, and every field
    declared ``int`` holds an integer (not a bool): a config built in Python (``replace``) is not parsed,
    and a count of 2.5 would fail deep in the code that uses it."""
    import dataclasses

    def walk(value: Any, path: str) -> None:
        if dataclasses.is_dataclass(value) and not isinstance(value, type):
            for f in dataclasses.fields(value):
                field_value = getattr(value, f.name)
                field_path = f"{path}.{f.name}" if path else f.name
                if f.type in ("int", int) and (
                    isinstance(field_value, bool) or not isinstance(field_value, int | np.integer)
                ):
                    _fail(field_path, f"must be an integer, got {field_value!r}")
                walk(field_value, field_path)
        elif isinstance(value, tuple | list):
            for k, item in enumerate(value):
                walk(item, f"{path}[{k}]")
        elif isinstance(value, float | np.floating) and not math.isfinite(value):
            _fail(path, f"must be a finite number, got {value!r}")

    walk(obj, where)


#: Circles the jig-to-robot alignment needs at least (a PnP pose from fewer is ambiguous).
MIN_ALIGNMENT_CIRCLES = 4
#: Refractive indices a plate or medium may have, ``[low, high)``: air up to beyond any optical glass.
REFRACTIVE_INDEX_RANGE = (1.0, 3.0)
#: Render supersampling factors per pixel side the simulator accepts, inclusive.
SUPERSAMPLING_RANGE = (1, 16)
#: Fewest points a plane fit takes.
MIN_PLANE_POINTS = 3
#: Rounding slack (mm) of "on the plate" for the fiducials' height.
_ON_PLATE_SLACK_MM = 1e-9


def validate_jig(jig: JigConfig) -> None:
    """Check every section of a jig and their consistency.

    Raises
    ------
    ConfigError
        Naming the field (as in the TOML file, e.g. ``markers.diameter_mm``) and the problem.
    """
    if jig.version != CONFIG_VERSION:
        _fail("version", f"this softjig reads config version {CONFIG_VERSION}, got {jig.version}")
    _check_numbers(jig, "")
    _validate_resolution(jig.cameras)
    _validate_plate_and_membrane(jig.plate, jig.membrane)
    _validate_markers(jig)
    _validate_fiducials(jig.fiducials, jig.plate)
    _validate_alignment(jig.alignment, jig.plate)
    _validate_media(jig.medium, jig.plate)
    _validate_imaging(jig.imaging)
    _validate_image_model(jig.medium, jig.imaging)
    for side in ("left", "right"):
        _validate_camera(getattr(jig.cameras, side), f"cameras.{side}", jig)
    if jig.cameras.baseline_mm <= 0:
        _fail("cameras", "the two cameras are at the same place: no baseline")
    if jig.cameras.rectified:
        _validate_rectified(jig.cameras)
    for name, value in asdict(jig.tolerances).items():
        _non_negative(value, f"tolerances.{name}")
    scale = jig.tolerances.depth_scale_error(jig.medium.oil_refractive_index)
    if not scale < 1.0:
        _fail(
            "tolerances",
            f"refractive_index / the oil's index and focal_fraction are relative errors of every depth, "
            f"{scale:.3g} combined: they must be well below 1 (one sigma of the as-built error, "
            "e.g. 0.005 and 0.001)",
        )
    _validate_sensing(jig.sensing)


def _validate_plate_and_membrane(p: PlateConfig, m: MembraneConfig) -> None:
    """The plate's sizes, the membrane's shape, and that the membrane fits on the plate."""
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
    _validate_profile(m)
    if 2 * m.footprint_radius_mm > min(p.size_x_mm, p.size_y_mm):
        _fail(
            "membrane.footprint_radius_mm",
            f"the membrane ({2 * m.footprint_radius_mm} mm across) does not fit on the plate "
            f"({p.size_x_mm} x {p.size_y_mm} mm)",
        )


def _validate_markers(jig: JigConfig) -> None:
    """The markers' size and pitch, their margin to the rim, and the explicit layout if any."""
    mk = jig.markers
    _positive(mk.diameter_mm, "markers.diameter_mm")
    _positive(mk.pitch_mm, "markers.pitch_mm")
    if mk.diameter_mm >= mk.pitch_mm:
        _fail(
            "markers.diameter_mm",
            f"markers ({mk.diameter_mm} mm) are as wide as or wider than their pitch "
            f"({mk.pitch_mm} mm): they would merge; reduce the diameter or increase the pitch",
        )
    _non_negative(mk.rim_margin_mm, "markers.rim_margin_mm")
    if mk.rim_margin_mm >= jig.membrane.footprint_radius_mm:
        _fail("markers.rim_margin_mm", "leaves no room for markers on the membrane")
    _validate_layout(jig)


def _validate_fiducials(f: FiducialConfig, p: PlateConfig) -> None:
    """One distinct id per fiducial, a positive size, a height on the plate, a known ArUco dictionary."""
    from softjig.aruco import aruco_dictionary_names  # OpenCV, imported when a config is checked

    if len(f.ids) != len(f.centers_mm):
        _fail("fiducials.ids", f"{len(f.ids)} ids for {len(f.centers_mm)} centres: give one id each")
    if len(set(f.ids)) != len(f.ids):
        _fail("fiducials.ids", "ids must be distinct")
    _positive(f.size_mm, "fiducials.size_mm")
    if not (-p.thickness_mm - _ON_PLATE_SLACK_MM <= f.z_mm <= _ON_PLATE_SLACK_MM):
        _fail("fiducials.z_mm", f"must lie on the plate (between {-p.thickness_mm} and 0), got {f.z_mm}")
    if f.dictionary not in aruco_dictionary_names():
        _fail(
            "fiducials.dictionary",
            f"unknown ArUco dictionary {f.dictionary!r}; valid: {', '.join(aruco_dictionary_names())}",
        )


def _validate_alignment(al: AlignmentConfig, p: PlateConfig) -> None:
    """Enough alignment circles, each whole on the plate."""
    if len(al.circle_centers_mm) < MIN_ALIGNMENT_CIRCLES:
        _fail(
            "alignment.circle_centers_mm",
            f"PnP needs at least {MIN_ALIGNMENT_CIRCLES} circles, got {len(al.circle_centers_mm)}",
        )
    _positive(al.circle_diameter_mm, "alignment.circle_diameter_mm")
    half_x, half_y = p.size_x_mm / 2.0, p.size_y_mm / 2.0
    for k, (x, y) in enumerate(al.circle_centers_mm):
        if abs(x) + al.circle_diameter_mm / 2 > half_x or abs(y) + al.circle_diameter_mm / 2 > half_y:
            _fail(
                f"alignment.circle_centers_mm[{k}]",
                f"({x}, {y}) is not on the {p.size_x_mm} x {p.size_y_mm} mm plate",
            )


def _validate_media(md: MediumConfig, p: PlateConfig) -> None:
    """The refractive indices of the plate, the oil and the beads; the beads' size and the blur."""
    low, high = REFRACTIVE_INDEX_RANGE
    for name in ("oil_refractive_index", "bead_refractive_index"):
        if not low <= getattr(md, name) < high:
            _fail(
                f"medium.{name}",
                f"must be a refractive index in [{low:g}, {high:g}), got {getattr(md, name)}",
            )
    if not low <= p.refractive_index < high:
        _fail("plate.refractive_index", f"must be in [{low:g}, {high:g}), got {p.refractive_index}")
    _positive(md.bead_diameter_mm, "medium.bead_diameter_mm")
    _non_negative(md.blur_coefficient, "medium.blur_coefficient")
    _non_negative(md.speckle_std, "medium.speckle_std")


def _validate_imaging(im: ImagingConfig) -> None:
    """Levels as fractions of full scale (markers brighter), fall-off, sensor noise, supersampling."""
    for name in ("background_level", "marker_level"):
        if not 0.0 <= getattr(im, name) <= 1.0:
            _fail(f"imaging.{name}", f"must be a fraction of full scale in [0, 1], got {getattr(im, name)}")
    if im.marker_level <= im.background_level:
        _fail("imaging.marker_level", "must be brighter than imaging.background_level")
    if not 0.0 <= im.illumination_falloff < 1.0:
        _fail("imaging.illumination_falloff", f"must be in [0, 1), got {im.illumination_falloff}")
    _positive(im.full_well_electrons, "imaging.full_well_electrons")
    _non_negative(im.read_noise, "imaging.read_noise")
    low, high = SUPERSAMPLING_RANGE
    if not low <= im.supersampling <= high:
        _fail("imaging.supersampling", f"must be between {low} and {high}, got {im.supersampling}")


def _validate_sensing(s: SensingConfig) -> None:
    """The detector's and matcher's parameters, and enough points for a plane."""
    if s.log_sigma_px is not None:
        _positive(s.log_sigma_px, "sensing.log_sigma_px")
    if s.detection_threshold is not None:
        _positive(s.detection_threshold, "sensing.detection_threshold")
    _positive(s.row_tolerance_px, "sensing.row_tolerance_px")
    _non_negative(s.disparity_margin_px, "sensing.disparity_margin_px")
    if s.min_points < MIN_PLANE_POINTS:
        _fail("sensing.min_points", f"a plane needs at least {MIN_PLANE_POINTS} points, got {s.min_points}")
    if s.min_points > MAX_MARKERS:
        _fail(
            "sensing.min_points",
            f"{s.min_points}, more than the {MAX_MARKERS} markers softjig handles: no frame could give an "
            "estimate",
        )


#: The most bubbles or glints an image model may hold (each is drawn over the whole image).
MAX_IMAGE_DEFECTS = 1000


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
    for section, name, value in (
        ("medium", "bubbles", md.bubbles),
        ("imaging", "glints", im.glints),
    ):
        if not 0 <= value <= MAX_IMAGE_DEFECTS:
            _fail(f"{section}.{name}", f"must be a count in [0, {MAX_IMAGE_DEFECTS}], got {value}")
    if not 0.05 <= md.bubble_radius_mm <= 10.0:
        _fail("medium.bubble_radius_mm", f"must be a radius in [0.05, 10] mm, got {md.bubble_radius_mm}")
    if not 0.0 <= im.missing_marker_fraction <= 0.5:
        _fail(
            "imaging.missing_marker_fraction",
            f"must be a fraction in [0, 0.5] (more is not a membrane one can sense with), "
            f"got {im.missing_marker_fraction}",
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


MAX_IMAGE_SIDE_PX = 8192
MAX_IMAGE_PIXELS = 4096 * 3072  # 12.6 Mpx: the 12 Mpx machine-vision sensors (4096 x 3000, 4000 x 3000)


def _validate_resolution(stereo: StereoConfig) -> None:
    """Image sizes whose buffers fit in memory: at most :data:`MAX_IMAGE_SIDE_PX` a side and
    :data:`MAX_IMAGE_PIXELS` in all.

    Rendering then estimating one pair peaked at 260 MB for 1280 x 720, 408 MB for 2560 x 1440 and
    824 MB for 3840 x 2160 (process peak RSS, measured with ``/usr/bin/time``; about 90 bytes per pixel
    at the top), so the cap keeps one process near 1.3 GB, and two simulation workers within a 4 GB
    machine; 12800 x 7200 px took 3.1 GB and 200000 x 200000 px could not be allocated at all.
    """
    for side in ("left", "right"):
        cam = getattr(stereo, side)
        for name in ("width_px", "height_px"):
            value = getattr(cam, name)
            if value > MAX_IMAGE_SIDE_PX:
                _fail(
                    f"cameras.{side}.{name}",
                    f"{value} px is above the {MAX_IMAGE_SIDE_PX} px a side softjig handles "
                    "(a frame's buffers must fit in memory): bin or crop the images",
                )
        if cam.width_px > 0 and cam.height_px > 0 and cam.width_px * cam.height_px > MAX_IMAGE_PIXELS:
            _fail(
                f"cameras.{side}.width_px",
                f"{cam.width_px} x {cam.height_px} px ({cam.width_px * cam.height_px / 1e6:.1f} Mpx) is "
                "above "
                f"the {MAX_IMAGE_PIXELS / 1e6:.1f} Mpx softjig handles (about 90 bytes per pixel to "
                "render or estimate one pair): bin or crop the images",
            )


def _validate_profile(m: MembraneConfig) -> None:
    """The dome profile's parameters (see :class:`MembraneConfig`)."""
    if m.dome_profile == "power" and m.dome_exponent < 1:
        _fail("membrane.dome_exponent", f"must be >= 1 for a power-law dome, got {m.dome_exponent}")
    if m.dome_profile == "paraboloid_power" and not 0 < m.dome_exponent <= 1:
        _fail(
            "membrane.dome_exponent",
            f"must be in (0, 1] for dome_profile = 'paraboloid_power' (h = H (1 - (r/R)^2)^p), "
            f"got {m.dome_exponent}",
        )
    if m.dome_profile != "table":
        for name in ("profile_r_mm", "profile_h_mm"):
            if getattr(m, name):
                _fail(f"membrane.{name}", "is only used with dome_profile = 'table': remove it or set that")
        return
    r, h = np.asarray(m.profile_r_mm, dtype=float), np.asarray(m.profile_h_mm, dtype=float)
    if len(r) < 2:
        _fail("membrane.profile_r_mm", f"a measured profile needs at least 2 points, got {len(r)}")
    if len(h) != len(r):
        _fail("membrane.profile_h_mm", f"{len(h)} heights for {len(r)} radii: give one height per radius")
    if r[0] != 0:
        _fail("membrane.profile_r_mm", f"must start at the axis (r = 0), got {r[0]}")
    for k in np.flatnonzero(np.diff(r) <= 0):
        _fail(f"membrane.profile_r_mm[{k + 1}]", f"radii must increase: {r[k + 1]} after {r[k]}")
    if r[-1] > m.footprint_radius_mm:
        _fail(
            "membrane.profile_r_mm",
            f"reaches r = {r[-1]} mm, beyond the membrane's footprint ({m.footprint_radius_mm} mm)",
        )
    for k in np.flatnonzero(np.diff(h) > 0):
        _fail(
            f"membrane.profile_h_mm[{k + 1}]",
            f"the profile is not monotone: h rises from {h[k]} to {h[k + 1]} mm between r = {r[k]} and "
            f"{r[k + 1]} mm; a dome's height never increases away from its axis",
        )
    if h[-1] < 0:
        _fail("membrane.profile_h_mm", f"heights must be zero or positive, got {h[-1]}")
    if r[-1] == m.footprint_radius_mm and h[-1] != 0:
        _fail(
            "membrane.profile_h_mm",
            f"the membrane is clamped to the plate at the rim: h(R) must be 0, got {h[-1]}",
        )
    if not math.isclose(h[0], m.dome_height_mm, rel_tol=1e-9, abs_tol=1e-9):
        _fail(
            "membrane.profile_h_mm",
            f"starts at {h[0]} mm on the axis but membrane.dome_height_mm is {m.dome_height_mm}: "
            "they are the same height, make them agree",
        )


MAX_MARKERS = 20000  # a 1.5 mm marker on a 2 mm grid fills a 190 mm membrane with ~7000


def _validate_layout(jig: JigConfig) -> None:
    """Grid parameters, or an explicit list of centres inside the membrane and not overlapping."""
    mk, m = jig.markers, jig.membrane
    if mk.layout != "explicit":
        for name in ("centers_mm", "centers_z_mm"):
            if getattr(mk, name):
                _fail(f"markers.{name}", "is only used with layout = 'explicit': remove it or set that")
        limit = m.footprint_radius_mm - mk.rim_margin_mm
        if math.hypot(*mk.offset_mm) >= limit:
            _fail(
                "markers.offset_mm",
                f"{mk.offset_mm} lies outside the {limit:g} mm the markers cover: the grid's "
                "central marker must be on the membrane",
            )
        cell = mk.pitch_mm**2 * (math.sqrt(3) / 2 if mk.layout == "hex" else 1.0)
        estimate = math.pi * limit**2 / cell
        if estimate > MAX_MARKERS:
            _fail(
                "markers.pitch_mm",
                f"a {mk.pitch_mm:g} mm grid puts about {estimate:.0f} markers on the membrane, more than "
                f"the {MAX_MARKERS} softjig handles: increase the pitch",
            )
        return
    if mk.rotation_deg != 0 or tuple(mk.offset_mm) != (0.0, 0.0):
        _fail(
            "markers.rotation_deg" if mk.rotation_deg != 0 else "markers.offset_mm",
            "does not apply to an explicit layout (its centres are in J already): set it to 0",
        )
    xy = np.asarray(mk.centers_mm, dtype=float).reshape(-1, 2)
    if len(xy) < 3:
        _fail("markers.centers_mm", f"an explicit layout needs at least 3 markers, got {len(xy)}")
    if len(xy) > MAX_MARKERS:
        _fail("markers.centers_mm", f"{len(xy)} markers: softjig handles at most {MAX_MARKERS}")
    reach = m.footprint_radius_mm - mk.diameter_mm / 2.0
    r = np.hypot(xy[:, 0], xy[:, 1])
    for k in np.flatnonzero(r > reach):
        _fail(
            f"markers.centers_mm[{k}]",
            f"({xy[k, 0]:g}, {xy[k, 1]:g}) is {r[k]:.1f} mm off the axis: a marker must lie on the membrane "
            f"(within {reach:g} mm)",
        )
    from scipy.spatial import cKDTree

    distance, neighbour = cKDTree(xy).query(xy, k=2)
    close = np.flatnonzero(distance[:, 1] < mk.diameter_mm)
    if len(close):
        i = int(close[0])
        j = int(neighbour[i, 1])
        i, j = min(i, j), max(i, j)
        _fail(
            f"markers.centers_mm[{j}]",
            f"overlaps markers.centers_mm[{i}]: centres {distance[i, 1]:.2f} mm apart, closer than a "
            f"marker's diameter (markers.diameter_mm = {mk.diameter_mm:g})",
        )
    spacing = float(np.median(distance[:, 1]))
    if not 0.75 * spacing <= mk.pitch_mm <= 4.0 / 3.0 * spacing:
        _fail(
            "markers.pitch_mm",
            f"{mk.pitch_mm:g} mm, but the explicit markers' median nearest-neighbour distance is "
            f"{spacing:.2f} mm: set pitch_mm to about that (the estimator's neighbourhoods use it)",
        )
    if mk.centers_z_mm:
        z = np.asarray(mk.centers_z_mm, dtype=float)
        if len(z) != len(xy):
            _fail(
                "markers.centers_z_mm",
                f"{len(z)} heights for {len(xy)} centres: give one per centre, or none",
            )
        for k in np.flatnonzero(z <= 0):
            _fail(f"markers.centers_z_mm[{k}]", f"must be above the plate (z > 0), got {z[k]}")


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


def jig_to_dict(jig: JigConfig) -> dict[str, Any]:
    """The plain-dict (TOML/JSON) form of a jig; ``None`` values are left out (TOML has no null)."""

    def clean(value: Any) -> Any:
        if isinstance(value, dict):
            return {k: clean(v) for k, v in value.items() if v is not None}
        if isinstance(value, tuple | list):
            return [clean(v) for v in value]
        return value

    return clean(asdict(jig))


#: What a config file must name: every top-level key and section, and both cameras. Within a section a
#: missing field takes its default (so files from before a field was added keep loading), but a missing
#: section is an error: an empty file, or one without ``[cameras]``, would otherwise silently be the
#: default jig, whose numbers are not the user's.
REQUIRED_KEYS: tuple[str, ...] = (
    "name",
    "version",
    "plate",
    "membrane",
    "markers",
    "fiducials",
    "alignment",
    "medium",
    "imaging",
    "cameras",
    "cameras.left",
    "cameras.right",
    "tolerances",
    "sensing",
)


def _check_complete(data: Any) -> None:
    """Refuse a config dict that leaves out a required key or section (:data:`REQUIRED_KEYS`)."""
    hint = "write a complete one with `softjig config --out rig.toml` and edit it"
    if not isinstance(data, dict) or not data:
        raise ConfigError(f"the config is empty: a config names every section of the jig; {hint}")
    missing = []
    for key in REQUIRED_KEYS:
        node: Any = data
        for part in key.split("."):
            node = node.get(part) if isinstance(node, dict) else None
        if node is None:
            missing.append(key)
    if missing:
        what = ", ".join(f"[{k}]" if k not in ("name", "version") else k for k in missing)
        raise ConfigError(
            f"{missing[0]}: missing from the config ({what}): a config must name every section, or it "
            f"would silently describe the default jig instead of yours; {hint}"
        )


def jig_from_dict(data: dict[str, Any]) -> JigConfig:
    """Build and validate a jig from its dict form; raises :class:`ConfigError` naming the field.

    Every key of :data:`REQUIRED_KEYS` must be there; fields left out of a section take their defaults.
    """
    _check_complete(data)
    jig = parse_dataclass(JigConfig, data)
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
    import tomli_w  # only writing needs it: not imported by every command (start-up, issue 14)

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


# ------------------------------------------------------------------------------------ marker CSV files

MARKER_CSV_COLUMNS = ("x_mm", "y_mm", "z_mm")


def load_marker_csv(path: str | os.PathLike[str]) -> tuple[tuple[Vec2, ...], tuple[float, ...]]:
    """Marker centres from a CSV file with a header ``x_mm,y_mm`` or ``x_mm,y_mm,z_mm`` (J, mm; ``z_mm``
    a measured inner-face height, as ``softjig survey --markers-csv`` writes).

    Returns
    -------
    centers, z
        For :class:`MarkerConfig`'s ``centers_mm`` and ``centers_z_mm`` (``z`` empty without the column).

    Raises
    ------
    InputError
        A missing or unreadable file, another header, a value that is not a finite number (naming the
        line).
    """
    import csv

    path = Path(path)
    text = read_text_file(path, "marker", encoding="utf-8-sig")
    rows = [row for row in csv.reader(text.splitlines()) if row and any(c.strip() for c in row)]
    if not rows:
        raise InputError(f"{path} is empty: give a header x_mm,y_mm (optionally z_mm) and one marker a line")
    header = tuple(c.strip() for c in rows[0])
    if header not in (MARKER_CSV_COLUMNS[:2], MARKER_CSV_COLUMNS):
        raise InputError(f"{path}: the header must be x_mm,y_mm or x_mm,y_mm,z_mm, got {','.join(header)}")
    values = []
    for line, row in enumerate(rows[1:], start=2):
        if len(row) != len(header):
            raise InputError(f"{path}, line {line}: {len(row)} values for the {len(header)} columns")
        try:
            numbers = [float(c) for c in row]
        except ValueError:
            raise InputError(f"{path}, line {line}: not numbers: {','.join(row)}") from None
        if not all(math.isfinite(v) for v in numbers):
            raise InputError(f"{path}, line {line}: values must be finite, got {','.join(row)}")
        values.append(numbers)
    if not values:
        raise InputError(f"{path} has a header but no markers")
    centers = tuple((v[0], v[1]) for v in values)
    z = tuple(v[2] for v in values) if len(header) == 3 else ()
    return centers, z


def marker_csv_text(xy_mm: np.ndarray, z_mm: np.ndarray | None = None) -> str:
    """The CSV text of marker centres (and heights), as :func:`load_marker_csv` reads it (``repr``
    precision: the round trip is exact)."""
    xy = np.asarray(xy_mm, dtype=float).reshape(-1, 2)
    columns = MARKER_CSV_COLUMNS if z_mm is not None else MARKER_CSV_COLUMNS[:2]
    lines = [",".join(columns)]
    for k, (x, y) in enumerate(xy):
        row = [repr(float(x)), repr(float(y))]
        if z_mm is not None:
            row.append(repr(float(np.asarray(z_mm, dtype=float)[k])))
        lines.append(",".join(row))
    return "\n".join(lines) + "\n"


def with_explicit_markers(jig: JigConfig, centers: Any, z: Any = ()) -> JigConfig:
    """``jig`` with an explicit marker layout at ``centers`` (``(N, 2)``, J, mm) and optional measured
    heights ``z`` (``(N,)``); ``markers.pitch_mm`` becomes the centres' typical spacing, the median
    distance from each to its four nearest neighbours (rounded to 1 um: the first shell of a square or
    hexagonal grid, and less biased by placement errors than the nearest one alone; kept within the
    third of the median nearest distance that validation allows), the other marker fields are kept.
    Validated (ConfigError naming the field)."""
    xy = np.asarray(centers, dtype=float).reshape(-1, 2)
    pitch = jig.markers.pitch_mm
    if len(xy) >= 2:
        from scipy.spatial import cKDTree

        distance = cKDTree(xy).query(xy, k=min(5, len(xy)))[0][:, 1:]
        nearest = float(np.median(distance[:, 0]))
        # within what _validate_layout accepts (a sparse, irregular layout's fourth neighbour is far)
        pitch = round(float(np.clip(np.median(distance), 0.76 * nearest, 1.32 * nearest)), 3) or pitch
    markers = replace(
        jig.markers,
        layout="explicit",
        pitch_mm=pitch,
        rotation_deg=0.0,
        offset_mm=(0.0, 0.0),
        centers_mm=tuple((float(a), float(b)) for a, b in xy),
        centers_z_mm=tuple(float(v) for v in np.asarray(z, dtype=float).ravel()),
    )
    return jig.replace(markers=markers)
