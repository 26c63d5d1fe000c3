"""A zoo of random jig designs: many jigs a user might build, to test the estimator beyond the paper's.

:func:`draw_designs` draws designs over the documented ranges of :class:`ZooRanges`. Each design is a
nominal jig (cameras, plate, oil, membrane, markers, image model) and a list of frames: the unloaded
reference frame first, then loaded frames of random parts (cylinders, boxes, regular polygons) at
random tilts, azimuths, spins, offsets and push depths. ``softjig simulate --scenario zoo`` renders each
design with :func:`softjig.io.simulated.simulate_dataset` into ``DIR/NNN/``, an ordinary dataset with
its full truth; ``benchmarks/bench_zoo.py`` renders them in memory.

A design that cannot be made physically is redrawn, not returned: one whose config does not validate
(:func:`softjig.config.validate_jig`), whose cameras do not both see at least
``ZooRanges.min_markers_seen`` markers of the rest membrane, whose markers image smaller than
``ZooRanges.min_marker_px`` (no detector finds them) or larger than ``max_marker_px``; a part that does
not fit the membrane (:func:`softjig.config.validate_part`) or would reach into the plate
(:func:`softjig.sim.scenarios.check_reachable`) is redrawn. A zoo whose ranges cannot be met within
``ZooRanges.max_attempts`` draws per design raises :class:`~softjig.errors.InputError`.

Randomness: design ``i`` of seed ``s`` is drawn from ``SeedSequence(s, spawn_key=(i,))`` only, so the
same seed gives the same designs whatever their number; each design carries its own dataset seed (the
as-built jig and every frame, :func:`softjig.io.simulated.simulate_dataset`), bead-pack speckle seed and
marker-brightness seed.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Iterator
from dataclasses import dataclass, field, fields, replace
from typing import Any

import numpy as np

from softjig.config import (
    BoxPart,
    CameraConfig,
    CylinderPart,
    FiducialConfig,
    ImagingConfig,
    JigConfig,
    MarkerConfig,
    MediumConfig,
    Part,
    PlateConfig,
    RegularPolygonPart,
    StereoConfig,
    default_jig,
    validate_jig,
    validate_part,
)
from softjig.errors import ConfigError, InputError
from softjig.jig_shape import rest_marker_points_mm
from softjig.optics import project_points
from softjig.rig import distortion_of, flat_layers
from softjig.sim.parts import PartPose
from softjig.sim.scenarios import FrameSpec, _loaded, _reference, check_reachable

__all__ = ["PLATE_MATERIALS", "ZooDesign", "ZooRanges", "draw_designs", "draw_frames"]

# Refractive indices at ~589 nm of the plate materials a jig is built from.
PLATE_MATERIALS: dict[str, float] = {"PET": 1.575, "PMMA": 1.491, "PC": 1.586, "glass": 1.517}

Range = tuple[float, float]


@dataclass(frozen=True)
class ZooRanges:
    """The ranges the zoo draws from (uniform within each unless said otherwise; mm, degrees, px).

    Cameras: ``resolutions`` (width, height) px, one chosen uniformly; ``baseline_mm`` between the two
    cameras (side by side along ``x``, a rectified pair); ``camera_gap_mm`` from the optical centres to
    the plate's bottom face; the focal length through ``half_field_mm``, the half-width of the image at
    the plate's top face (a pinhole through air): ``fx = (W / 2) * distance / half_field``.

    Plate: ``plate_materials`` (name and refractive index; :data:`PLATE_MATERIALS`), one chosen
    uniformly; ``plate_thickness_mm``. Oil: ``oil_index``, including values above the plate's.

    Membrane: ``dome_height_mm``, ``footprint_radius_mm``; the profile ``"power"`` with
    ``power_exponent`` or ``"paraboloid_power"`` with ``paraboloid_exponent`` (each half of the time).

    Markers: ``marker_diameter_mm``; ``marker_pitch_mm`` (at least ``min_pitch_diameters`` diameters);
    ``"square"`` or ``"hex"`` grids turned by ``grid_rotation_deg`` and offset by up to
    ``grid_offset_mm`` along each axis.

    Image model: ``blur_coefficient``, ``speckle_std``, ``read_noise``, ``full_well_electrons``,
    ``illumination_falloff``, ``marker_level``, ``background_level``, ``speckle_redraw_fraction``,
    ``marker_brightness_spread``, ``marker_appearance`` (one chosen uniformly), ``illumination_center``
    (each of u, v within +-), ``exposure`` and ``gain`` (each camera's, independently).

    Parts: ``part_kinds`` (uniformly); ``part_size_mm`` across (a cylinder's diameter, a box's shorter
    side with the longer up to ``box_aspect`` times it, a polygon's size across flats, of
    ``polygon_sides`` sides); ``tilt_deg`` (uniform in the angle); any azimuth and spin; the face's centre
    uniform in the disc of radius ``max_offset_mm``; ``push_mm``.

    Makeable designs: at least ``min_markers_seen`` rest markers inside both images; each marker's image
    at the apex between ``min_marker_px`` and ``max_marker_px`` across; at most ``max_attempts`` draws per
    design (and per part).
    """

    resolutions: tuple[tuple[int, int], ...] = (
        (640, 480),
        (800, 600),
        (1024, 768),
        (1280, 720),
        (1280, 1024),
        (1600, 1200),
        (1920, 1080),
        (1920, 1200),
    )
    baseline_mm: Range = (20.0, 60.0)
    camera_gap_mm: Range = (100.0, 200.0)
    half_field_mm: Range = (55.0, 110.0)
    plate_materials: tuple[tuple[str, float], ...] = tuple(PLATE_MATERIALS.items())
    plate_thickness_mm: Range = (3.0, 10.0)
    oil_index: Range = (1.45, 1.56)
    dome_height_mm: Range = (15.0, 35.0)
    footprint_radius_mm: Range = (75.0, 100.0)
    power_exponent: Range = (2.0, 6.0)
    paraboloid_exponent: Range = (0.3, 1.0)
    marker_diameter_mm: Range = (1.5, 4.0)
    marker_pitch_mm: Range = (4.0, 12.0)
    min_pitch_diameters: float = 2.0
    grid_rotation_deg: Range = (0.0, 90.0)
    grid_offset_mm: float = 3.0
    blur_coefficient: Range = (0.002, 0.006)
    speckle_std: Range = (0.02, 0.07)
    read_noise: Range = (0.004, 0.015)
    full_well_electrons: Range = (3000.0, 12000.0)
    illumination_falloff: Range = (0.1, 0.45)
    marker_level: Range = (0.4, 0.7)
    background_level: Range = (0.04, 0.12)
    speckle_redraw_fraction: Range = (0.1, 0.6)
    marker_brightness_spread: Range = (0.03, 0.15)
    marker_appearances: tuple[str, ...] = ("hemisphere", "disc")
    illumination_center: float = 0.2
    exposure: Range = (0.85, 1.1)
    gain: Range = (0.9, 1.15)
    part_kinds: tuple[str, ...] = ("cylinder", "box", "polygon")
    part_size_mm: Range = (30.0, 90.0)
    box_aspect: float = 1.5
    polygon_sides: tuple[int, int] = (3, 8)
    tilt_deg: Range = (0.0, 20.0)
    max_offset_mm: float = 20.0
    push_mm: Range = (2.0, 8.0)
    min_markers_seen: int = 30
    min_marker_px: float = 5.0
    max_marker_px: float = 60.0
    max_attempts: int = 200

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if (
                isinstance(value, tuple)
                and len(value) == 2
                and all(isinstance(v, int | float) for v in value)
            ):
                lo, hi = value
                if not (math.isfinite(lo) and math.isfinite(hi) and lo <= hi):
                    raise InputError(f"zoo range {f.name} = {value}: needs finite lo <= hi")
        for name in ("resolutions", "plate_materials", "marker_appearances", "part_kinds"):
            if not getattr(self, name):
                raise InputError(f"zoo range {name} is empty: give at least one choice")
        if self.max_attempts < 1:
            raise InputError(f"zoo max_attempts must be at least 1, got {self.max_attempts}")


@dataclass(frozen=True)
class ZooDesign:
    """One drawn design.

    Attributes
    ----------
    index : its number in the zoo (its folder ``NNN``).
    seed : the dataset's seed (the as-built jig and every frame,
        :func:`softjig.io.simulated.simulate_dataset`).
    family : a coarse label for grouping results: ``"<grid>-<resolution class>"`` (``sd`` below 1 Mpx,
        ``hd`` below 2 Mpx, ``fhd`` above).
    jig : the nominal jig.
    specs : the reference frame first, then the loaded frames.
    labels : what was drawn, JSON-ready (plate material, profile, grid, resolution, ...).
    """

    index: int
    seed: int
    family: str
    jig: JigConfig
    specs: list[FrameSpec] = field(hash=False)
    labels: dict[str, Any] = field(default_factory=dict, hash=False)


def draw_designs(
    n_designs: int, *, seed: int, frames: int = 20, ranges: ZooRanges | None = None
) -> Iterator[ZooDesign]:
    """Draw ``n_designs`` makeable designs with ``frames`` loaded frames each (see the module docstring).

    Raises
    ------
    InputError
        ``n_designs`` or ``frames`` below 1, a bad seed, or ranges no design can meet within
        ``ranges.max_attempts`` draws (naming the most frequent reason).
    """
    ranges = ranges or ZooRanges()
    if not _is_count(n_designs, 1):
        raise InputError(f"the zoo needs at least one design (--designs), got {n_designs!r}")
    _check_frames(frames)
    if not _is_count(seed, 0):
        raise InputError(f"the seed must be a non-negative integer, got {seed!r}")
    # Check that the zoo can be met before any design is handed out (and written).
    first = _draw_design(0, int(seed), int(frames), ranges)
    yield first
    for index in range(1, int(n_designs)):
        yield _draw_design(index, int(seed), int(frames), ranges)


def stirred_image_model(jig: JigConfig) -> JigConfig:
    """``jig`` rendered with the simulator's image model from before the bead pack's statistics: a new
    speckle in every frame (which a reference frame cannot cancel), identical markers, the illumination
    centred on the axis and identical cameras. A variant to check the estimator on image statistics
    other than the default ones (``benchmarks/bench_zoo.py --image-model stirred``)."""
    return jig.replace(
        medium=replace(jig.medium, speckle_static=False),
        imaging=replace(
            jig.imaging,
            marker_brightness_spread=0.0,
            marker_appearance="hemisphere",
            illumination_center=(0.0, 0.0),
            exposure=(1.0, 1.0),
            gain=(1.0, 1.0),
        ),
    )


#: How steeply the membrane's wall stands beside a contact in :func:`gentle_wall_model` (deg).
GENTLE_WALL_SLOPE_DEG = 20.0


def gentle_wall_model(jig: JigConfig) -> JigConfig:
    """``jig`` filled with beads whose wall beside a contact stands no steeper than
    :data:`GENTLE_WALL_SLOPE_DEG` (``membrane.max_wall_slope_deg``; every zoo design keeps the default 35
    deg). The bead pack's angle of repose sets how steeply the membrane rises beside a pressed face, and
    smooth beads lubricated by oil can slide at 20 deg: beside a part tilted 15-20 deg, the wall then
    slopes about as the face does. A variant to check the estimator on membrane mechanics that no design
    of the zoo has (``benchmarks/bench_zoo.py --image-model gentle-walls``); the estimator is not told."""
    return jig.replace(membrane=replace(jig.membrane, max_wall_slope_deg=GENTLE_WALL_SLOPE_DEG))


#: The damaged jig's defects (:func:`damaged_image_model`): share of markers lost, bubbles in the fill
#: and their typical radius (mm), glints per image.
DAMAGED_MISSING_MARKERS = 0.05
DAMAGED_BUBBLES = 8
DAMAGED_BUBBLE_RADIUS_MM = 1.0
DAMAGED_GLINTS = 12


def damaged_image_model(jig: JigConfig) -> JigConfig:
    """``jig`` worn and filled carelessly: :data:`DAMAGED_MISSING_MARKERS` of its markers' paint flaked
    off, :data:`DAMAGED_BUBBLES` air bubbles in its bead pack and :data:`DAMAGED_GLINTS` glints in each
    image (:mod:`softjig.sim.render`, step 5b), over its own bead-pack image model. A variant to check
    the estimator on image defects that no design of the zoo has (``benchmarks/bench_zoo.py
    --image-model damaged``)."""
    return jig.replace(
        medium=replace(jig.medium, bubbles=DAMAGED_BUBBLES, bubble_radius_mm=DAMAGED_BUBBLE_RADIUS_MM),
        imaging=replace(jig.imaging, missing_marker_fraction=DAMAGED_MISSING_MARKERS, glints=DAMAGED_GLINTS),
    )


def _is_count(value: object, least: int) -> bool:
    """Whether ``value`` is an integer (not a bool) of at least ``least``."""
    return not isinstance(value, bool) and isinstance(value, int | np.integer) and value >= least


#: Loaded frames a zoo design (or a study's seed) may have at most: all of a design's frames are drawn
#: before the first is written, so a mistyped count would hang the command with nothing to show.
MAX_ZOO_FRAMES = 10_000


def _check_frames(frames: object) -> None:
    """Refuse a number of loaded frames that is not an integer from 1 to :data:`MAX_ZOO_FRAMES`
    (InputError)."""
    if not _is_count(frames, 1):
        raise InputError(f"a zoo design needs at least one loaded frame (--frames), got {frames!r}")
    if int(frames) > MAX_ZOO_FRAMES:
        raise InputError(
            f"a zoo design may have at most {MAX_ZOO_FRAMES:,} loaded frames (--frames), got {int(frames):,}"
        )


def _draw_design(index: int, seed: int, frames: int, ranges: ZooRanges) -> ZooDesign:
    ss = np.random.SeedSequence(seed, spawn_key=(index,))
    rng = np.random.default_rng(ss)
    dataset_seed, speckle_seed, brightness_seed = (int(v) for v in ss.generate_state(3) % (2**31))
    reasons: Counter[str] = Counter()
    for _ in range(ranges.max_attempts):
        jig, labels = _draw_jig(rng, ranges, speckle_seed, brightness_seed)
        reason = _unmakeable(jig, ranges)
        if reason is not None:
            reasons[reason] += 1
            continue
        specs, reason = _draw_frames(rng, jig, ranges, frames)
        if reason is not None:
            reasons[reason] += 1
            continue
        family = f"{labels['grid']}-{labels['resolution_class']}"
        return ZooDesign(index, dataset_seed, family, jig, specs, labels)
    worst = ", ".join(f"{why} ({n})" for why, n in reasons.most_common(3))
    raise InputError(
        f"zoo design {index}: no makeable design in {ranges.max_attempts} draws from these ranges "
        f"(most frequent reasons: {worst}); widen the ranges"
    )


def _u(rng: np.random.Generator, r: Range) -> float:
    return float(rng.uniform(r[0], r[1]))


#: Bits per pixel of a zoo design's images (the 8-bit streams of common stereo cameras).
ZOO_BIT_DEPTH = 8
#: Megapixels below which a design's resolution is labelled ``sd``, then ``hd``; above, ``fhd``.
SD_MAX_MPX, HD_MAX_MPX = 1.0, 2.0
#: A marker counts as seen when its rest position projects this far (px) inside both images.
IMAGE_MARGIN_PX = 10.0


@dataclass(frozen=True)
class _Optics:
    """A design's plate and cameras as drawn (what the labels report of them)."""

    width_px: int
    height_px: int
    material: str
    plate_index: float
    thickness_mm: float
    gap_mm: float
    baseline_mm: float
    fx_px: float

    def camera(self, x_mm: float) -> CameraConfig:
        """A rectified camera of the design at ``x_mm`` along the baseline, below the plate."""
        w, h = self.width_px, self.height_px
        return CameraConfig(
            width_px=w,
            height_px=h,
            fx_px=self.fx_px,
            fy_px=self.fx_px,
            cx_px=(w - 1) / 2.0,
            cy_px=(h - 1) / 2.0,
            position_mm=(x_mm, 0.0, -(self.thickness_mm + self.gap_mm)),
        )


def _draw_optics(rng: np.random.Generator, zr: ZooRanges) -> _Optics:
    """Resolution, plate material and thickness, camera gap and baseline, and the focal length that gives
    the drawn half field of view at the plate."""
    w, h = zr.resolutions[int(rng.integers(len(zr.resolutions)))]
    material, plate_index = zr.plate_materials[int(rng.integers(len(zr.plate_materials)))]
    thickness = _u(rng, zr.plate_thickness_mm)
    gap = _u(rng, zr.camera_gap_mm)
    baseline = _u(rng, zr.baseline_mm)
    fx = (w / 2.0) * (thickness + gap) / _u(rng, zr.half_field_mm)
    return _Optics(int(w), int(h), material, float(plate_index), thickness, gap, baseline, fx)


def _draw_membrane(rng: np.random.Generator, zr: ZooRanges, base: JigConfig):
    """The dome: its profile, exponent, height and footprint."""
    profile = "power" if rng.uniform() < 0.5 else "paraboloid_power"
    exponent = _u(rng, zr.power_exponent if profile == "power" else zr.paraboloid_exponent)
    return replace(
        base.membrane,
        dome_height_mm=_u(rng, zr.dome_height_mm),
        footprint_radius_mm=_u(rng, zr.footprint_radius_mm),
        dome_profile=profile,
        dome_exponent=exponent,
    )


def _draw_markers(rng: np.random.Generator, zr: ZooRanges, base: JigConfig) -> MarkerConfig:
    """The marker grid: diameter, a pitch of at least ``min_pitch_diameters`` diameters, the grid's kind,
    rotation and offset."""
    diameter = _u(rng, zr.marker_diameter_mm)
    lo = max(zr.marker_pitch_mm[0], zr.min_pitch_diameters * diameter)
    pitch = _u(rng, (lo, zr.marker_pitch_mm[1])) if lo <= zr.marker_pitch_mm[1] else zr.marker_pitch_mm[1]
    grid = "square" if rng.uniform() < 0.5 else "hex"
    return MarkerConfig(
        diameter_mm=diameter,
        pitch_mm=pitch,
        layout=grid,
        rim_margin_mm=base.markers.rim_margin_mm,
        rotation_deg=_u(rng, zr.grid_rotation_deg),
        offset_mm=tuple(float(v) for v in rng.uniform(-zr.grid_offset_mm, zr.grid_offset_mm, 2)),
    )


def _draw_medium(rng: np.random.Generator, zr: ZooRanges, base: JigConfig, speckle_seed: int) -> MediumConfig:
    """The oil's index, the blur and the bead pack's speckle."""
    return MediumConfig(
        oil_refractive_index=_u(rng, zr.oil_index),
        bead_refractive_index=base.medium.bead_refractive_index,
        bead_diameter_mm=base.medium.bead_diameter_mm,
        blur_coefficient=_u(rng, zr.blur_coefficient),
        speckle_std=_u(rng, zr.speckle_std),
        speckle_static=True,
        speckle_seed=speckle_seed,
        speckle_redraw_fraction=_u(rng, zr.speckle_redraw_fraction),
        speckle_redraw_displacement_mm=base.medium.speckle_redraw_displacement_mm,
    )


def _draw_imaging(
    rng: np.random.Generator, zr: ZooRanges, base: JigConfig, brightness_seed: int
) -> ImagingConfig:
    """Levels, illumination, sensor noise, marker brightness and appearance, each camera's exposure and
    gain."""
    c = zr.illumination_center
    return ImagingConfig(
        background_level=_u(rng, zr.background_level),
        marker_level=_u(rng, zr.marker_level),
        illumination_falloff=_u(rng, zr.illumination_falloff),
        full_well_electrons=_u(rng, zr.full_well_electrons),
        read_noise=_u(rng, zr.read_noise),
        bit_depth=ZOO_BIT_DEPTH,
        supersampling=base.imaging.supersampling,
        marker_brightness_spread=_u(rng, zr.marker_brightness_spread),
        marker_brightness_seed=brightness_seed,
        marker_appearance=zr.marker_appearances[int(rng.integers(len(zr.marker_appearances)))],
        illumination_center=(float(rng.uniform(-c, c)), float(rng.uniform(-c, c))),
        exposure=(_u(rng, zr.exposure), _u(rng, zr.exposure)),
        gain=(_u(rng, zr.gain), _u(rng, zr.gain)),
    )


def _draw_jig(
    rng: np.random.Generator, zr: ZooRanges, speckle_seed: int, brightness_seed: int
) -> tuple[JigConfig, dict[str, Any]]:
    """One design and its labels. The draws come in a fixed order (optics, membrane, markers, medium,
    imaging): a seed gives the same designs as long as that order stays."""
    base = default_jig()
    optics = _draw_optics(rng, zr)
    membrane = _draw_membrane(rng, zr, base)
    markers = _draw_markers(rng, zr, base)
    medium = _draw_medium(rng, zr, base, speckle_seed)
    imaging = _draw_imaging(rng, zr, base, brightness_seed)
    half = optics.baseline_mm / 2.0
    jig = replace(
        base,
        name="zoo design",
        plate=PlateConfig(
            size_x_mm=base.plate.size_x_mm,
            size_y_mm=base.plate.size_y_mm,
            thickness_mm=optics.thickness_mm,
            refractive_index=optics.plate_index,
        ),
        membrane=membrane,
        markers=markers,
        fiducials=replace(FiducialConfig(), z_mm=-optics.thickness_mm),
        medium=medium,
        imaging=imaging,
        cameras=StereoConfig(left=optics.camera(-half), right=optics.camera(half), rectified=True),
    )
    mpx = optics.width_px * optics.height_px / 1e6
    labels = {
        "resolution": [optics.width_px, optics.height_px],
        "resolution_class": "sd" if mpx < SD_MAX_MPX else ("hd" if mpx < HD_MAX_MPX else "fhd"),
        "plate_material": optics.material,
        "plate_thickness_mm": optics.thickness_mm,
        "oil_above_plate": medium.oil_refractive_index > optics.plate_index,
        "baseline_mm": optics.baseline_mm,
        "camera_gap_mm": optics.gap_mm,
        "fx_px": optics.fx_px,
        "dome_profile": membrane.dome_profile,
        "grid": markers.layout,
        "marker_diameter_mm": markers.diameter_mm,
        "marker_pitch_mm": markers.pitch_mm,
        "marker_appearance": imaging.marker_appearance,
    }
    return jig, labels


def _unmakeable(jig: JigConfig, zr: ZooRanges) -> str | None:
    """Why the design cannot be built or used, or ``None``."""
    if jig.markers.pitch_mm < zr.min_pitch_diameters * jig.markers.diameter_mm:
        return f"markers closer than {zr.min_pitch_diameters:g} diameters (their blurred images merge)"
    try:
        validate_jig(jig)
    except ConfigError as exc:
        return f"config: {str(exc).split(':')[0]}"
    points = rest_marker_points_mm(jig)
    layers = flat_layers(jig)
    seen = np.ones(len(points), dtype=bool)
    for cam in (jig.cameras.left, jig.cameras.right):
        px = project_points(points, cam.K, distortion_of(cam), cam.T_J_cam, layers)
        margin = IMAGE_MARGIN_PX
        seen &= np.all((px > margin) & (px < [cam.width_px - margin, cam.height_px - margin]), axis=1)
    if int(seen.sum()) < zr.min_markers_seen:
        return "too few markers seen by both cameras"
    apex = points[np.argmin(np.hypot(points[:, 0], points[:, 1]))]
    cam = jig.cameras.left
    ends = np.stack([apex, apex + np.array([jig.markers.diameter_mm, 0.0, 0.0])])
    px = project_points(ends, cam.K, distortion_of(cam), cam.T_J_cam, layers)
    size = float(np.linalg.norm(px[1] - px[0]))
    if size < zr.min_marker_px:
        return "markers image too small"
    if size > zr.max_marker_px:
        return "markers image too large"
    return None


def _draw_part(rng: np.random.Generator, zr: ZooRanges) -> Part:
    kind = zr.part_kinds[int(rng.integers(len(zr.part_kinds)))]
    size = _u(rng, zr.part_size_mm)
    if kind == "cylinder":
        return CylinderPart(diameter_mm=size, height_mm=30.0)
    if kind == "box":
        return BoxPart(
            size_x_mm=size, size_y_mm=size * float(rng.uniform(1.0, zr.box_aspect)), height_mm=30.0
        )
    if kind == "polygon":
        lo, hi = zr.polygon_sides
        return RegularPolygonPart(n_sides=int(rng.integers(lo, hi + 1)), across_flats_mm=size, height_mm=30.0)
    raise InputError(f"zoo part kind {kind!r}: valid kinds are cylinder, box, polygon")


def _draw_frames(
    rng: np.random.Generator, jig: JigConfig, zr: ZooRanges, frames: int
) -> tuple[list[FrameSpec], str | None]:
    specs = [_reference()]
    for _ in range(frames):
        for _attempt in range(zr.max_attempts):
            part = _draw_part(rng, zr)
            radius = zr.max_offset_mm * math.sqrt(float(rng.uniform()))
            phi = float(rng.uniform(0.0, 2 * math.pi))
            pose = PartPose(
                alpha_rad=math.radians(_u(rng, zr.tilt_deg)),
                theta_rad=float(rng.uniform(0.0, 2 * math.pi)),
                push_depth_mm=_u(rng, zr.push_mm),
                center_xy_mm=(radius * math.cos(phi), radius * math.sin(phi)),
                yaw_rad=float(rng.uniform(0.0, 2 * math.pi)),
            )
            spec = _loaded(part, pose)
            try:
                validate_part(part, jig)
                if radius + part.circumradius_mm() >= jig.membrane.footprint_radius_mm:
                    raise InputError("overhangs the membrane")
                check_reachable(jig, spec)
            except (ConfigError, InputError):
                continue
            specs.append(spec)
            break
        else:
            return specs, "no part fits this design"
    return specs, None


def draw_frames(
    jig: JigConfig, frames: int, rng: np.random.Generator, ranges: ZooRanges | None = None
) -> list[FrameSpec]:
    """The unloaded reference frame, then ``frames`` loaded frames of random parts and poses drawn over
    ``ranges`` exactly as a zoo design's are (``softjig simulate --scenario zoo``), each fitting ``jig``
    (a part that does not is redrawn). Used by design studies to test every design on the same random
    frames.

    Raises
    ------
    InputError
        ``frames`` not an integer of at least 1, or no part of the ranges fits ``jig`` within
        ``ranges.max_attempts`` draws.
    """
    _check_frames(frames)
    ranges = ranges or ZooRanges()
    specs, reason = _draw_frames(rng, jig, ranges, int(frames))
    if reason is not None:
        raise InputError(
            f"no part of these ranges fits the jig within {ranges.max_attempts} draws (its size, offset, "
            "tilt and push against the membrane and the plate); narrow them"
        )
    return specs
