"""A design study: the study file, its dotted config paths, and every design built and validated up front.

A study file (TOML) names a base jig, the config fields to vary, the frames each design is tested on,
the seeds and the estimation methods::

    [study]
    name = "pitch-vs-baseline"
    seeds = [0, 1]
    config = "rig.toml"            # optional, relative to the study file; default: the paper's jig
    [vary]                         # dotted config paths; the study is the product of the lists
    "markers.pitch_mm" = [6.0, 8.0, 10.0]
    "cameras.baseline_mm" = { start = 20.0, stop = 60.0, num = 5 }
    [frames]                       # the paper sweep's poses (softjig.sim.scenarios.paper_sweep)
    diameters_mm = [40, 60]
    alphas_deg = [5, 10, 20]
    theta_step_deg = 30
    push_depth_mm = 3.0            # optional
    # or [[frames.poses]] tables (explicit poses), or random zoo frames drawn from each seed:
    # zoo = { count = 20 }         # ranges optional: part_kinds, part_size_mm, tilt_deg, ...
    [estimate]
    methods = ["refractive"]

A path in ``[vary]`` is any leaf field of :class:`~softjig.config.JigConfig` as the config file spells it
(``section.field`` or ``cameras.left.field``), or one of the documented aliases of :data:`ALIASES` for a
quantity derived from several fields (a baseline moves both cameras). A value is a list, or a range
``{start, stop, num}`` (``num`` values from ``start`` to ``stop`` inclusive, as :func:`numpy.linspace`).
The designs are the product of the lists, row-major in file order (the last path varies fastest):
design ``i`` is :func:`build_designs`'s ``i``-th. Real fields are set first, then aliases, in file order
(so ``cameras.distance_mm`` measures from the design's own plate).

Everything that can be wrong is found by :func:`load_study` before any work starts, with the field named:
an unknown key or path (with the nearest valid names), an empty list, a range with ``num < 1``, a value of
the wrong type or outside what the field allows, a combination that makes an impossible design (every
design's :class:`~softjig.config.JigConfig` is built and validated by :func:`softjig.config.validate_jig`),
a part that does not fit a design's membrane or would reach its plate. Errors are
:class:`~softjig.errors.ConfigError` (exit code 2).

The study's identity is :attr:`StudySpec.study_hash`, the SHA-256 of its canonical JSON form (the base
jig's full config included, not its file name): two files that describe the same study have the same
hash, and ``--resume`` requires it.
"""

from __future__ import annotations

import dataclasses
import difflib
import hashlib
import itertools
import json
import math
import os
import tomllib
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import ConfigDict, Field, TypeAdapter, ValidationError

from softjig.config import (
    CylinderPart,
    JigConfig,
    default_jig,
    jig_to_dict,
    load_jig,
    validate_jig,
    validate_part,
)
from softjig.errors import ConfigError, InputError
from softjig.files import read_text_file

__all__ = [
    "ALIASES",
    "Design",
    "FramesSpec",
    "PoseSpec",
    "Study",
    "StudySpec",
    "ZooFramesSpec",
    "build_designs",
    "load_study",
    "parse_study",
]

_STRICT = ConfigDict(extra="forbid", allow_inf_nan=False)


def _parse(cls: type, data: Any, where: str) -> Any:
    """A study file's section ``data`` as the pydantic-validated ``cls`` (its fields' constraints
    included); a ConfigError naming the first offending key below ``where``."""
    try:
        return TypeAdapter(cls).validate_python(data)
    except ValidationError as exc:
        err = exc.errors()[0]
        loc = ".".join(str(x) for x in (where, *err["loc"]) if x != "")
        more = f" (and {exc.error_count() - 1} more)" if exc.error_count() > 1 else ""
        raise ConfigError(f"{loc}: {err['msg']}{more}") from None


#: The estimation methods a study may name (:data:`softjig.sensing.pipeline.METHODS`).
STUDY_METHODS = ("refractive", "paper")
#: Loaded frames per task at most: a task renders its chunk's frames plus the unloaded reference frame,
#: so the reference costs at most 1/96 extra; a design with more frames is split into chunks.
DEFAULT_FRAMES_PER_TASK = 96

Scalar = float | int | str | bool
Value = Scalar | tuple[Any, ...]


# ------------------------------------------------------------------------------------------ the file


@dataclass(frozen=True)
class _Range:
    __pydantic_config__ = _STRICT
    start: float
    stop: float
    num: int


@dataclass(frozen=True)
class _StudySection:
    __pydantic_config__ = _STRICT
    name: str
    seeds: tuple[int, ...] = (0,)
    config: str | None = None
    frames_per_task: int = DEFAULT_FRAMES_PER_TASK


@dataclass(frozen=True)
class PoseSpec:
    """One explicit frame: a cylinder (30 mm high) of ``diameter_mm`` centred on the jig axis, pushed in
    by ``push_depth_mm`` and tilted by ``alpha_deg`` towards the azimuth ``theta_deg`` (from J's +x
    towards +y), as ``softjig simulate --scenario single`` renders it."""

    __pydantic_config__ = _STRICT
    diameter_mm: Annotated[float, Field(gt=0)]
    alpha_deg: Annotated[float, Field(ge=0, lt=90)]
    theta_deg: Annotated[float, Field(ge=0, lt=360)] = 0.0
    push_depth_mm: Annotated[float, Field(gt=0)] = 3.0


#: ``[frames]`` keys of the paper sweep (exclusive with ``poses`` and ``zoo``).
SWEEP_KEYS = ("diameters_mm", "alphas_deg", "theta_step_deg", "push_depth_mm")
#: Random zoo frames a study may draw per seed at most (each is rendered for every design): the zoo's own
#: limit, :data:`softjig.sim.zoo.MAX_ZOO_FRAMES` (not imported: sim.zoo loads the renderer's modules; the
#: two are tested equal); also the paper sweep's frames per design at most.
MAX_ZOO_FRAMES = 10_000
#: ``SeedSequence(seed, spawn_key=(ZOO_FRAMES_SPAWN_KEY,))`` draws a seed's zoo frames; a task draws its
#: as-built jig from ``spawn_key=(0,)`` and its frames' noise from ``(1, index)`` (softjig.study.run).
ZOO_FRAMES_SPAWN_KEY = 2
#: The zoo's part ranges a study may narrow (:class:`softjig.sim.zoo.ZooRanges`'s fields of those names).
ZOO_PART_RANGES = ("part_kinds", "part_size_mm", "tilt_deg", "max_offset_mm", "push_mm")

_Positive = Annotated[float, Field(gt=0)]
_Tilt = Annotated[float, Field(ge=0, lt=90)]


@dataclass(frozen=True)
class ZooFramesSpec:
    """Random frames as ``softjig simulate --scenario zoo`` draws a design's (:func:`softjig.sim.zoo.
    draw_frames`): ``count`` loaded frames of cylinders, boxes and regular polygons ``part_size_mm`` across,
    tilted by ``tilt_deg`` towards any azimuth, spun by any angle, their face's centre up to
    ``max_offset_mm`` off the jig axis, pushed in by ``push_mm``. Unset ranges are the zoo's
    (:class:`softjig.sim.zoo.ZooRanges`: 30-90 mm, 0-20 deg, 20 mm, 2-8 mm, all three kinds).

    The frames are drawn from each study seed, fitted to the study's base jig, and are the same for every
    design of that seed, so designs compare on equal terms."""

    __pydantic_config__ = _STRICT
    count: Annotated[int, Field(ge=1, le=MAX_ZOO_FRAMES)]
    part_kinds: tuple[Literal["cylinder", "box", "polygon"], ...] | None = None
    part_size_mm: tuple[_Positive, _Positive] | None = None
    tilt_deg: tuple[_Tilt, _Tilt] | None = None
    max_offset_mm: Annotated[float, Field(ge=0)] | None = None
    push_mm: tuple[_Positive, _Positive] | None = None

    def ranges(self) -> Any:
        """The :class:`~softjig.sim.zoo.ZooRanges` the frames are drawn over."""
        from softjig.sim.zoo import ZooRanges

        given = {name: getattr(self, name) for name in ZOO_PART_RANGES if getattr(self, name) is not None}
        return ZooRanges(**given)

    def canonical(self) -> dict[str, Any]:
        """The count and the effective part ranges (the zoo's where unset), JSON-ready."""
        ranges = self.ranges()
        return {"count": self.count, **{name: _plain(getattr(ranges, name)) for name in ZOO_PART_RANGES}}

    def draw(self, jig: JigConfig, seed: int) -> list:
        """The reference frame, then the seed's ``count`` random frames, fitted to ``jig``."""
        from softjig.sim.zoo import draw_frames

        rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(ZOO_FRAMES_SPAWN_KEY,)))
        try:
            return draw_frames(jig, self.count, rng, self.ranges())
        except InputError as exc:
            raise ConfigError(f"frames.zoo: {exc}") from None


@dataclass(frozen=True)
class FramesSpec:
    """The poses each design is tested on: the paper sweep (:func:`softjig.sim.scenarios.paper_sweep`),
    cylinders of ``diameters_mm`` centred on the jig axis, pushed in by ``push_depth_mm`` and tilted by
    each of ``alphas_deg`` towards azimuths ``0, theta_step_deg, ...`` below 360 degrees; or, when
    ``poses`` is given (and none of the sweep's keys), exactly those poses in their order; or, when
    ``zoo`` is given (alone), random parts and poses drawn from each seed (:class:`ZooFramesSpec`)."""

    __pydantic_config__ = _STRICT
    diameters_mm: tuple[float, ...] = (40.0, 60.0)
    alphas_deg: tuple[float, ...] = (5.0, 10.0, 20.0)
    theta_step_deg: float = 30.0
    push_depth_mm: float = 3.0
    poses: tuple[PoseSpec, ...] = ()
    zoo: ZooFramesSpec | None = None

    def canonical(self) -> dict[str, Any]:
        """JSON-ready: the poses or the zoo alone when given, else the sweep (so a sweep's hash is what it
        was)."""
        if self.zoo is not None:
            return {"zoo": self.zoo.canonical()}
        if self.poses:
            return {"poses": [_plain(dataclasses.asdict(p)) for p in self.poses]}
        return _plain({k: v for k, v in dataclasses.asdict(self).items() if k not in ("poses", "zoo")})

    def parts_and_poses(self) -> list[tuple[float, float, float, float]]:
        """``(diameter_mm, alpha_deg, theta_deg, push_depth_mm)`` of each distinct part and tilt to check
        on a design (the sweep's at azimuth 0: the jig is symmetric about its axis)."""
        if self.poses:
            return sorted({(p.diameter_mm, p.alpha_deg, 0.0, p.push_depth_mm) for p in self.poses})
        return [(d, a, 0.0, self.push_depth_mm) for d in self.diameters_mm for a in self.alphas_deg]


@dataclass(frozen=True)
class _EstimateSection:
    __pydantic_config__ = _STRICT
    methods: tuple[str, ...] = ("refractive",)


@dataclass(frozen=True)
class StudySpec:
    """A validated study (see the module docstring).

    Attributes
    ----------
    name : the study's name.
    seeds : the seeds each design is run with (the as-built jig and every frame's noise).
    vary : ``(path, values)`` in file order; a range is already expanded into its values.
    frames : the poses each design is tested on.
    methods : the estimation methods, each run on every rendered frame.
    base : the base jig every design starts from.
    frames_per_task : loaded frames per task at most.
    """

    name: str
    seeds: tuple[int, ...]
    vary: tuple[tuple[str, tuple[Value, ...]], ...]
    frames: FramesSpec
    methods: tuple[str, ...]
    base: JigConfig = field(default_factory=default_jig)
    frames_per_task: int = DEFAULT_FRAMES_PER_TASK

    @property
    def paths(self) -> tuple[str, ...]:
        """The varied paths, in file order (the results' column names)."""
        return tuple(path for path, _ in self.vary)

    @property
    def numeric_paths(self) -> tuple[str, ...]:
        """The varied paths whose values are all numbers (float64 columns; the others are strings)."""
        return tuple(path for path, values in self.vary if all(_is_number(v) for v in values))

    @property
    def n_designs(self) -> int:
        """Designs in the study: the product of the lists' lengths (1 when nothing varies)."""
        return math.prod(len(values) for _, values in self.vary)

    def canonical(self) -> dict[str, Any]:
        """The study's canonical, JSON-ready form (what :attr:`study_hash` hashes)."""
        return {
            "study": {
                "name": self.name,
                "seeds": list(self.seeds),
                "frames_per_task": self.frames_per_task,
            },
            "vary": {path: [_plain(v) for v in values] for path, values in self.vary},
            "frames": self.frames.canonical(),
            "estimate": {"methods": list(self.methods)},
            "base": jig_to_dict(self.base),
        }

    @property
    def study_hash(self) -> str:
        """SHA-256 (hex) of the canonical form's JSON with sorted keys."""
        text = json.dumps(self.canonical(), sort_keys=True, separators=(",", ":"))
        return hashlib.sha256(text.encode("utf-8")).hexdigest()

    @property
    def n_frames(self) -> int:
        """Loaded frames per design and seed (the zoo's count, without drawing its frames)."""
        return self.frames.zoo.count if self.frames.zoo is not None else len(self.frame_specs()) - 1

    def frame_specs(self, seed: int | None = None) -> list:
        """The unloaded reference frame, then the loaded frames (:func:`~softjig.sim.scenarios.paper_sweep`
        order: diameter, alpha, theta; or the explicit poses in their order; or the zoo frames ``seed``
        draws, default the first seed's); loaded frame ``k`` is the list's ``k + 1``. Only zoo frames
        depend on the seed, and never on the design."""
        from softjig.sim.scenarios import FrameSpec, paper_sweep, single

        f = self.frames
        if f.zoo is not None:
            return f.zoo.draw(self.base, self.seeds[0] if seed is None else int(seed))
        try:
            if f.poses:
                frames = [
                    single(_cylinder(p.diameter_mm), p.alpha_deg, p.theta_deg, p.push_depth_mm)[0]
                    for p in f.poses
                ]
                return [FrameSpec(None, None, {"reference": True}), *frames]
            return list(
                paper_sweep(f.diameters_mm, f.alphas_deg, f.theta_step_deg, f.push_depth_mm, reference=True)
            )
        except InputError as exc:
            raise ConfigError(f"frames: {exc}") from None


def _cylinder(diameter_mm: float) -> CylinderPart:
    from softjig.sim.scenarios import CYLINDER_HEIGHT_MM

    return CylinderPart(diameter_mm=float(diameter_mm), height_mm=CYLINDER_HEIGHT_MM)


def _parse_frames(data: Any) -> FramesSpec:
    """``[frames]``: the paper sweep's keys, or ``poses`` (a list of tables), or ``zoo`` (a table), one."""
    if isinstance(data, dict) and "zoo" in data:
        given = [k for k in (*SWEEP_KEYS, "poses") if k in data]
        if given:
            raise ConfigError(
                f"frames: give either zoo, poses or the paper sweep's {', '.join(SWEEP_KEYS)}, one of them "
                f"(also given: {', '.join(given)})"
            )
        frames = _parse(FramesSpec, data, "frames")
        for name in ("part_size_mm", "tilt_deg", "push_mm"):
            bounds = getattr(frames.zoo, name)
            if bounds is not None and bounds[0] > bounds[1]:
                raise ConfigError(f"frames.zoo.{name}: [{bounds[0]:g}, {bounds[1]:g}] needs low <= high")
        if frames.zoo.part_kinds is not None and not frames.zoo.part_kinds:
            raise ConfigError(
                "frames.zoo.part_kinds: an empty list draws no part; give cylinder, box or polygon"
            )
        return frames
    if isinstance(data, dict) and "poses" in data:
        given = [k for k in SWEEP_KEYS if k in data]
        if given:
            raise ConfigError(
                f"frames: give either poses or the paper sweep's {', '.join(SWEEP_KEYS)}, not both "
                f"(also given: {', '.join(given)})"
            )
        if not data["poses"]:
            raise ConfigError("frames.poses: an empty list gives no frame; give at least one pose")
        return _parse(FramesSpec, data, "frames")
    from softjig.sim.scenarios import theta_count

    frames = _parse(FramesSpec, data, "frames")
    step = frames.theta_step_deg
    if math.isfinite(step) and 0.0 < step <= 360.0:  # else the sweep's own check (frame_specs) says why
        n = len(frames.diameters_mm) * len(frames.alphas_deg) * theta_count(step)
        if n > MAX_ZOO_FRAMES:
            raise ConfigError(
                f"frames.theta_step_deg: {step:g} gives {n:,} sweep frames per design, over the "
                f"{MAX_ZOO_FRAMES:,} a study may render; give a larger step"
            )
    return frames


def _is_number(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


def _plain(value: Any) -> Any:
    if isinstance(value, tuple | list):
        return [_plain(v) for v in value]
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    return value


_SECTIONS = ("study", "vary", "frames", "estimate")


def load_study(path: str | os.PathLike[str]) -> Study:
    """Read and validate a study file and build every design (see the module docstring); ``[study] config``
    is read relative to the file's folder.

    Raises
    ------
    InputError
        A missing or unreadable file (or base config file).
    ConfigError
        Invalid TOML or any invalid entry, naming it (``vary.markers.pitch_mm``, ``frames.alphas_deg``).
    """
    path = Path(path)
    text = read_text_file(path, "study")
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path} is not valid TOML: {exc}") from None
    try:
        spec = parse_study(data, folder=path.parent)
        return Study(spec, build_designs(spec))
    except ConfigError as exc:
        raise ConfigError(f"{path}: {exc}") from None


def parse_study(data: dict[str, Any], *, folder: Path | None = None) -> StudySpec:
    """Validate a study's dict form (a parsed study file); ``folder`` resolves ``[study] config``.

    The designs are not built here: :func:`build_designs` builds and validates them (``load_study`` does
    both).
    """
    for key in data:
        if key not in _SECTIONS:
            raise ConfigError(f"{key}: unknown section; a study file has {', '.join(_SECTIONS)}")
    if "study" not in data:
        raise ConfigError('study: missing; give [study] with at least name = "..."')
    section = _parse(_StudySection, data["study"], "study")
    if not section.seeds:
        raise ConfigError("study.seeds: give at least one seed")
    for seed in section.seeds:
        if seed < 0:
            raise ConfigError(f"study.seeds: a seed is a non-negative integer, got {seed}")
    if len(set(section.seeds)) != len(section.seeds):
        raise ConfigError("study.seeds: seeds must be distinct")
    if section.frames_per_task < 1:
        raise ConfigError(f"study.frames_per_task: must be at least 1, got {section.frames_per_task}")
    base = _base_jig(section.config, folder)
    frames = _parse_frames(data.get("frames", {}))
    methods = _parse(_EstimateSection, data.get("estimate", {}), "estimate").methods
    _check_methods(methods)
    vary = _parse_vary(data.get("vary", {}))
    spec = StudySpec(section.name, section.seeds, vary, frames, methods, base, section.frames_per_task)
    spec.frame_specs()  # the sweep's own checks (diameters, alphas, step)
    return spec


def _base_jig(config: str | None, folder: Path | None) -> JigConfig:
    if config is None:
        return default_jig()
    path = Path(config)
    if not path.is_absolute() and folder is not None:
        path = folder / path
    try:
        return load_jig(path)
    except ConfigError as exc:
        raise ConfigError(f"study.config ({path}): {exc}") from None


def _check_methods(methods: Sequence[str]) -> None:
    if not methods:
        raise ConfigError(f"estimate.methods: give at least one of {', '.join(STUDY_METHODS)}")
    for method in methods:
        if method not in STUDY_METHODS:
            valid = ", ".join(STUDY_METHODS)
            raise ConfigError(f"estimate.methods: unknown method {method!r}; valid: {valid}")
    if len(set(methods)) != len(methods):
        raise ConfigError("estimate.methods: methods must be distinct")


#: The most designs one study may hold. Every design's jig is built and kept before any work starts
#: (about 1 ms each), so a product of millions would run for hours and fill the memory before saying
#: anything; a larger study is split into several, each with its own ``--out``.
MAX_DESIGNS = 20_000


def _parse_vary(table: Any) -> tuple[tuple[str, tuple[Value, ...]], ...]:
    if not isinstance(table, dict):
        raise ConfigError("vary: must be a table of dotted config paths")
    out = []
    designs = 1
    for path, raw in _flatten(table, ""):
        if isinstance(raw, dict):
            values = _expand_range(path, raw)
        elif isinstance(raw, list):
            if not raw:
                raise ConfigError(f"vary.{path}: an empty list gives no design; give at least one value")
            values = tuple(_frozen(v) for v in raw)
        else:
            raise ConfigError(
                f"vary.{path}: give a list of values or a range {{start, stop, num}}, got {raw!r}"
            )
        designs *= len(values)
        if designs > MAX_DESIGNS:
            raise ConfigError(
                f"vary.{path}: the study would hold {designs:,} designs or more, over the {MAX_DESIGNS:,} "
                "one study may hold; split it into several studies, each with its own --out"
            )
        resolve_path(path)
        out.append((path, tuple(check_value(path, value) for value in values)))
    return tuple(out)


_RANGE_KEYS = frozenset({"start", "stop", "num"})


def _flatten(table: dict[str, Any], prefix: str) -> list[tuple[str, Any]]:
    """``(dotted path, list or range)`` of a ``[vary]`` table, whose keys may be quoted dotted paths
    (``"markers.pitch_mm" = [...]``) or TOML's own dotted keys and sub-tables (``markers.pitch_mm = [...]``
    parses as ``{"markers": {"pitch_mm": [...]}}``); a table of only ``start``, ``stop``, ``num`` is a
    range."""
    out = []
    for key, value in table.items():
        path = f"{prefix}{key}"
        if isinstance(value, dict) and value and not set(value) <= _RANGE_KEYS:
            out.extend(_flatten(value, f"{path}."))
        else:
            out.append((path, value))
    return out


def _frozen(value: Any) -> Value:
    if isinstance(value, list):
        return tuple(_frozen(v) for v in value)
    if isinstance(value, float) and not math.isfinite(value):
        raise ConfigError(f"a value must be finite, got {value}")
    return value


def _expand_range(path: str, raw: dict[str, Any]) -> tuple[float, ...]:
    r = _parse(_Range, raw, f"vary.{path}")
    if r.num < 1:
        raise ConfigError(f"vary.{path}: a range needs num >= 1 values, got num = {r.num}")
    if r.num > MAX_DESIGNS:
        raise ConfigError(
            f"vary.{path}: num = {r.num:,} values is over the {MAX_DESIGNS:,} designs one study may hold"
        )
    return tuple(float(v) for v in np.linspace(r.start, r.stop, r.num))


# ------------------------------------------------------------------------------------------ paths


@dataclass(frozen=True)
class Alias:
    """A derived quantity set through the fields it is made of.

    Attributes
    ----------
    help : what it is, with its unit.
    apply : ``(jig, value) -> jig`` (not validated: the design is validated once, whole).
    kind : ``"number"`` or ``"pair"`` (two integers).
    """

    help: str
    apply: Callable[[JigConfig, Any], JigConfig]
    kind: str = "number"


def _set_cameras(jig: JigConfig, **changes: Any) -> JigConfig:
    cams = jig.cameras
    left, right = replace(cams.left, **changes), replace(cams.right, **changes)
    return replace(jig, cameras=replace(cams, left=left, right=right))


def _baseline(jig: JigConfig, value: float) -> JigConfig:
    left, right = jig.cameras.left, jig.cameras.right
    centre = (left.position_mm[0] + right.position_mm[0]) / 2.0
    half = float(value) / 2.0
    cams = replace(
        jig.cameras,
        left=replace(left, position_mm=(centre - half, *left.position_mm[1:])),
        right=replace(right, position_mm=(centre + half, *right.position_mm[1:])),
    )
    return replace(jig, cameras=cams)


def _distance(jig: JigConfig, value: float) -> JigConfig:
    z = -(jig.plate.thickness_mm + float(value))
    cams = jig.cameras
    cams = replace(
        cams,
        left=replace(cams.left, position_mm=(*cams.left.position_mm[:2], z)),
        right=replace(cams.right, position_mm=(*cams.right.position_mm[:2], z)),
    )
    return replace(jig, cameras=cams)


def _focal(jig: JigConfig, value: float) -> JigConfig:
    return _set_cameras(jig, fx_px=float(value), fy_px=float(value))


def _resolution(jig: JigConfig, value: tuple[int, int]) -> JigConfig:
    w, h = (int(v) for v in value)
    return _set_cameras(jig, width_px=w, height_px=h, cx_px=(w - 1) / 2.0, cy_px=(h - 1) / 2.0)


#: Derived quantities a study may vary by name (``[vary]`` keys), each set through the fields it is made
#: of. They apply to both cameras of the pair, which stays rectified.
ALIASES: dict[str, Alias] = {
    "cameras.baseline_mm": Alias(
        "distance between the optical centres (mm), along x, about their midpoint", _baseline
    ),
    "cameras.distance_mm": Alias(
        "distance from the optical centres up to the plate's bottom face (mm): z = -(plate.thickness_mm + d)",
        _distance,
    ),
    "cameras.focal_px": Alias("both cameras' focal length fx = fy (px)", _focal),
    "cameras.resolution_px": Alias(
        "both cameras' [width, height] (px), the principal point at the image centre", _resolution, "pair"
    ),
}


def _fields(cls: Any) -> dict[str, dataclasses.Field]:
    return {f.name: f for f in dataclasses.fields(cls)}


def resolve_path(path: str) -> tuple[str, ...]:
    """The field names along a dotted config path (an alias: its name alone).

    Raises
    ------
    ConfigError
        An unknown path, naming where it goes wrong and the nearest valid names.
    """
    if path in ALIASES:
        return (path,)
    parts = path.split(".")
    node: Any = JigConfig
    for k, part in enumerate(parts):
        where = ".".join(parts[:k]) or "the config"
        if not (dataclasses.is_dataclass(node) and isinstance(node, type)):
            parent = ".".join(parts[:k])
            raise ConfigError(f"vary.{path}: {parent} is a value, not a section: it has no {part!r}")
        known = _fields(node)
        if part not in known:
            names = [".".join([*parts[:k], n]) for n in known]
            if k == 0:
                names += list(ALIASES)
            close = difflib.get_close_matches(".".join(parts[: k + 1]), names, n=3)
            hint = f"; did you mean {', '.join(close)}?" if close else f"; {where} has {', '.join(known)}"
            raise ConfigError(f"vary.{path}: unknown config field {part!r} in {where}{hint}")
        node = _field_type(node, part)
    if dataclasses.is_dataclass(node) and isinstance(node, type):
        raise ConfigError(f"vary.{path}: is a section; name one of its fields ({', '.join(_fields(node))})")
    return tuple(parts)


def _field_type(cls: type, name: str) -> Any:
    import typing

    hints = typing.get_type_hints(cls)
    return hints[name]


def check_value(path: str, value: Value) -> Value:
    """Check one value of a path on its own, by its type in the config model (pydantic), and return it as
    the model holds it (an integer for a float field becomes a float, a list a tuple). Whether the value
    is allowed (a positive pitch, markers narrower than their pitch) is for :func:`design_jig`, since it
    may depend on the other fields.

    Raises
    ------
    ConfigError
        ``vary.<path> = <value>: <problem>``.
    """
    if path in ALIASES:
        alias = ALIASES[path]
        ok = (
            _is_number(value)
            if alias.kind == "number"
            else isinstance(value, tuple) and len(value) == 2 and all(isinstance(v, int) for v in value)
        )
        if not ok:
            want = "a number" if alias.kind == "number" else "a pair of integers [width, height]"
            raise ConfigError(f"vary.{path} = {_plain(value)!r}: must be {want} ({ALIASES[path].help})")
        return float(value) if alias.kind == "number" else tuple(int(v) for v in value)
    parts = resolve_path(path)
    node: Any = JigConfig
    for part in parts[:-1]:
        node = _field_type(node, part)
    try:
        coerced = TypeAdapter(_field_type(node, parts[-1]), config=_STRICT).validate_python(
            list(value) if isinstance(value, tuple) else value
        )
    except ValidationError as exc:
        raise ConfigError(f"vary.{path} = {_plain(value)!r}: {exc.errors()[0]['msg']}") from None
    return _frozen(coerced) if isinstance(coerced, list) else coerced


# ------------------------------------------------------------------------------------------ designs


@dataclass(frozen=True)
class Design:
    """One design of a study.

    Attributes
    ----------
    design_id : its index in the study's product (row-major over ``[vary]`` in file order).
    values : the varied values, in the order of :attr:`StudySpec.paths`.
    jig : the design's validated nominal jig.
    """

    design_id: int
    values: tuple[Value, ...]
    jig: JigConfig


def _replaced(node: Any, parts: tuple[str, ...], value: Value) -> Any:
    """``node`` (a config dataclass) with the field at ``parts`` set to ``value`` (not validated)."""
    if len(parts) == 1:
        return replace(node, **{parts[0]: value})
    return replace(node, **{parts[0]: _replaced(getattr(node, parts[0]), parts[1:], value)})


def design_jig(spec: StudySpec, values: Sequence[Value]) -> JigConfig:
    """The validated jig of one combination of values (real fields first, then aliases, in file order).

    The values were type-checked by :func:`check_value`; the jig is validated once, whole
    (:func:`softjig.config.validate_jig`: about 1 ms).

    Raises
    ------
    ConfigError
        The combination is not a valid jig, naming the field and the design's values.
    """
    jig = spec.base
    pairs = list(zip(spec.paths, values, strict=True))
    for path, value in pairs:
        if path not in ALIASES:
            jig = _replaced(jig, resolve_path(path), value)
    for path, value in pairs:
        if path in ALIASES:
            jig = ALIASES[path].apply(jig, value)
    try:
        validate_jig(jig)
    except ConfigError as exc:
        raise ConfigError(f"vary: the design {_where(spec, values)} is impossible: {exc}") from None
    return jig


def _where(spec: StudySpec, values: Sequence[Value]) -> str:
    text = ", ".join(f"{p} = {_plain(v)!r}" for p, v in zip(spec.paths, values, strict=True))
    return text or "(the base jig)"


def _check_frames(
    spec: StudySpec, jig: JigConfig, values: Sequence[Value], zoo_frames: dict[int, list]
) -> None:
    """Every part of ``[frames]`` fits the design's membrane and stays clear of its plate (``zoo_frames``:
    each seed's zoo frames, when the frames are the zoo's)."""
    from softjig.sim.parts import PartPose
    from softjig.sim.scenarios import FrameSpec, check_reachable

    if spec.frames.zoo is not None:
        _check_zoo_frames(spec, jig, values, zoo_frames)
        return
    for d, a, t, depth in spec.frames.parts_and_poses():
        part = _cylinder(d)
        try:
            validate_part(part, jig)
            pose = PartPose(alpha_rad=math.radians(a), theta_rad=math.radians(t), push_depth_mm=depth)
            check_reachable(jig, FrameSpec(part, pose))
        except InputError as exc:
            raise ConfigError(
                f"frames: the {d:g} mm part does not fit the design {_where(spec, values)}: {exc}"
            ) from None


def _check_zoo_frames(
    spec: StudySpec, jig: JigConfig, values: Sequence[Value], zoo_frames: dict[int, list]
) -> None:
    """Every seed's zoo frame (drawn to fit the base jig) fits the design's membrane and plate too."""
    from softjig.sim.scenarios import check_reachable

    for seed, frames in zoo_frames.items():
        for k, frame in enumerate(frames[1:]):
            part, pose = frame.part, frame.pose
            try:
                validate_part(part, jig)
                if (
                    math.hypot(*pose.center_xy_mm) + part.circumradius_mm()
                    >= jig.membrane.footprint_radius_mm
                ):
                    raise InputError("it overhangs the membrane")
                check_reachable(jig, frame)
            except InputError as exc:
                raise ConfigError(
                    f"frames.zoo: frame {k} of seed {seed} (a {part.kind} {part.diameter_mm:.0f} mm across, "
                    f"{math.degrees(pose.alpha_rad):.1f} deg, {math.hypot(*pose.center_xy_mm):.0f} mm off "
                    f"the axis) does not fit the design {_where(spec, values)}: {exc}; narrow "
                    "frames.zoo.part_size_mm or max_offset_mm"
                ) from None


def build_designs(spec: StudySpec) -> tuple[Design, ...]:
    """Every design of the study, in order, each jig validated and every frame's part checked on it.

    Raises
    ------
    ConfigError
        The first impossible design, naming the field and the design's values.
    """
    designs = []
    checked: set[tuple[Any, ...]] = set()  # the parts' fit depends on the membrane and the plate only
    # A seed's zoo frames are the same for every design (drawn on the base jig): drawn once, not per check.
    zoo_frames = {seed: spec.frame_specs(seed) for seed in spec.seeds} if spec.frames.zoo is not None else {}
    for design_id, values in enumerate(itertools.product(*(v for _, v in spec.vary))):
        jig = design_jig(spec, values)
        key = (jig.membrane, jig.plate)
        if key not in checked:
            _check_frames(spec, jig, values, zoo_frames)
            checked.add(key)
        designs.append(Design(design_id, tuple(values), jig))
    return tuple(designs)


@dataclass(frozen=True)
class Study:
    """A validated study and its designs (:func:`load_study`)."""

    spec: StudySpec
    designs: tuple[Design, ...] = field(repr=False)
