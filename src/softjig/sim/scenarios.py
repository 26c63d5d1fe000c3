"""What to render: the paper's experiments as lists of frames, and the simulator that writes them.

A scenario is a sequence of :class:`FrameSpec` (a part, its pose and the frame's metadata), a pure
description with nothing rendered. :func:`simulate_dataset` draws an as-built jig from a seed, renders
every spec with :func:`softjig.sim.render.render_pair` and writes a dataset (:mod:`softjig.io.dataset`)
with the ground truth of each frame.

Ground truth written per frame (``truth`` in ``frames.jsonl``)
---------------------------------------------------------------
- ``normal``: the part's true principal normal in J, ``T_J_part[:3, 2]`` (its bottom face's normal).
- ``push_depth_mm`` (``DESIGN.md`` §1: how far the markers' plane lies below the undeformed membrane on
  the jig axis): ``h_rest_inner(0, 0) - (z_face(0, 0) - t / n_z)``, where ``h_rest_inner`` is the rest
  height of the membrane's inner face (where the markers are), ``z_face(0, 0)`` the height of the plane of
  the part's bottom face above the jig axis, ``t`` the membrane thickness and ``n_z`` the normal's ``z``.
  In contact the inner face lies on the face's plane shifted down by ``t / n_z``
  (:mod:`softjig.sim.membrane`), so ``z_face(0, 0) - t / n_z`` is where the markers' plane crosses the
  axis. For a part centred on the axis this is ``push_depth_mm + t (1 / cos(alpha) - 1)``: the commanded
  push depth (measured on the outer face) plus a small tilt term.
- ``T_J_part``: the part's true 4x4 pose in J; ``markers``: the frame's truth ``.npz``.

Random numbers: the as-built jig is drawn from ``SeedSequence(seed, spawn_key=(0,))`` and frame ``i`` is
rendered with ``SeedSequence(seed, spawn_key=(1, i))``, so a dataset depends on the seed only, never on
the number of worker processes.
"""

from __future__ import annotations

import contextlib
import itertools
import math
import os
import time
from collections import deque
from collections.abc import Iterable, Iterator, Sequence
from concurrent.futures import Future, ProcessPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from softjig.config import CylinderPart, JigConfig, Part, cube, part_to_dict, validate_jig, validate_part
from softjig.errors import InputError
from softjig.io.dataset import DatasetWriter, encode_png
from softjig.io.workers import worker_pool
from softjig.jig_shape import rest_inner_height_mm
from softjig.sim.asbuilt import AsBuiltJig, draw_as_built
from softjig.sim.parts import PartPose, bottom_face_rim, bottom_plane_height_mm

__all__ = [
    "FrameSpec",
    "cube_experiment",
    "frame_truth",
    "paper_sweep",
    "simulate_dataset",
    "single",
]

PAPER_DIAMETERS_MM = (30.0, 40.0, 50.0, 60.0, 70.0, 80.0)
PAPER_ALPHAS_DEG = (5.0, 10.0, 15.0, 20.0)
CYLINDER_HEIGHT_MM = 30.0


@dataclass(frozen=True)
class FrameSpec:
    """One frame to render: a part and its pose (both ``None`` for the unloaded jig) and the metadata to
    write in ``frames.jsonl`` (degrees at this edge: ``alpha_deg``, ``theta_deg``, ``part``, ...)."""

    part: Part | None
    pose: PartPose | None
    meta: dict[str, Any] = field(default_factory=dict, hash=False)

    def __post_init__(self) -> None:
        if (self.part is None) != (self.pose is None):
            raise ValueError("FrameSpec needs both a part and a pose, or neither (the unloaded jig)")


def _reference() -> FrameSpec:
    return FrameSpec(None, None, {"reference": True})


def _loaded(part: Part, pose: PartPose) -> FrameSpec:
    meta = {
        "alpha_deg": math.degrees(pose.alpha_rad),
        "theta_deg": math.degrees(pose.theta_rad),
        "part": part_to_dict(part),
        "pose": {
            "push_depth_mm": pose.push_depth_mm,
            "center_xy_mm": list(pose.center_xy_mm),
            "yaw_deg": math.degrees(pose.yaw_rad),
        },
    }
    return FrameSpec(part, pose, meta)


def _check_alpha(alpha_deg: float) -> None:
    if not (math.isfinite(alpha_deg) and 0.0 <= alpha_deg < 90.0):
        raise InputError(f"a tilt alpha must be in [0, 90) degrees, got {alpha_deg}")


def _check_push(push_depth_mm: float) -> None:
    if not (math.isfinite(push_depth_mm) and push_depth_mm > 0):
        raise InputError(
            f"the push depth must be a positive number of mm (the part must touch the membrane), "
            f"got {push_depth_mm}"
        )


MIN_FACE_HEIGHT_MM = 2.0  # the membrane and its markers need this much room above the plate


def check_reachable(jig: JigConfig, spec: FrameSpec) -> None:
    """Raise :class:`InputError` if a spec's part would push its bottom face down into the plate.

    The lowest point of the face's edge must stay :data:`MIN_FACE_HEIGHT_MM` above the plate's top face
    (the membrane and its hemispherical markers lie between them).
    """
    if spec.part is None or spec.pose is None:
        return
    T = spec.pose.T_J_part(jig)
    lowest = float(bottom_face_rim(spec.part, T, 2.0)[:, 2].min())
    if lowest < MIN_FACE_HEIGHT_MM:
        raise InputError(
            f"a {spec.part.kind} of {spec.part.diameter_mm:g} mm tilted by "
            f"{math.degrees(spec.pose.alpha_rad):g} deg and pushed {spec.pose.push_depth_mm:g} mm would "
            f"reach z = {lowest:.1f} mm, into the plate (the membrane needs {MIN_FACE_HEIGHT_MM:g} mm): "
            "reduce the push depth or the tilt"
        )


def theta_values_deg(theta_step_deg: float) -> list[float]:
    """The azimuths ``0, step, 2 step, ...`` below 360 degrees."""
    if not (math.isfinite(theta_step_deg) and 0.0 < theta_step_deg <= 360.0):
        raise InputError(f"the theta step must be in (0, 360] degrees, got {theta_step_deg}")
    n = math.ceil(360.0 / theta_step_deg - 1e-9)
    return [i * theta_step_deg for i in range(n)]


def paper_sweep(
    diameters_mm: Sequence[float] = PAPER_DIAMETERS_MM,
    alphas_deg: Sequence[float] = PAPER_ALPHAS_DEG,
    theta_step_deg: float = 10.0,
    push_depth_mm: float = 3.0,
    reference: bool = True,
) -> Iterator[FrameSpec]:
    """The paper's tilt sweep: each cylinder (30 mm high), centred on the jig axis, pushed in by
    ``push_depth_mm`` and tilted about the centre of its bottom face by each ``alpha`` while ``theta``
    turns through ``[0, 360)`` in steps of ``theta_step_deg``.

    Yields the unloaded reference frame first (if ``reference``), then the frames in the order diameter,
    alpha, theta: ``1 + len(diameters) * len(alphas) * ceil(360 / step)`` frames (865 by default).

    Raises
    ------
    InputError
        A diameter that is not positive, an alpha outside ``[0, 90)``, a step outside ``(0, 360]``.
    """
    diameters = [float(d) for d in diameters_mm]
    alphas = [float(a) for a in alphas_deg]
    thetas = theta_values_deg(float(theta_step_deg))
    _check_push(push_depth_mm)
    if not diameters:
        raise InputError("the paper sweep needs at least one part diameter")
    if not alphas:
        raise InputError("the paper sweep needs at least one tilt alpha")
    for d in diameters:
        if not (math.isfinite(d) and d > 0):
            raise InputError(f"a part diameter must be a positive number of mm, got {d}")
    for a in alphas:
        _check_alpha(a)
    if reference:
        yield _reference()
    for d in diameters:
        part = CylinderPart(diameter_mm=d, height_mm=CYLINDER_HEIGHT_MM)
        for a in alphas:
            for t in thetas:
                pose = PartPose(
                    alpha_rad=math.radians(a), theta_rad=math.radians(t), push_depth_mm=float(push_depth_mm)
                )
                yield _loaded(part, pose)


def cube_experiment(
    n_frames: int = 60,
    side_mm: float = 50.0,
    max_alpha_deg: float = 15.0,
    rng: np.random.Generator | int | None = None,
    *,
    push_depth_mm: float = 3.0,
    max_offset_mm: float = 3.0,
    reference: bool = True,
) -> list[FrameSpec]:
    """The paper's motion-capture experiment: the cube pressed in at varied random orientations.

    Each of the ``n_frames`` loaded frames draws, independently and uniformly, a tilt ``alpha`` in
    ``[0, max_alpha_deg]``, an azimuth ``theta`` in ``[0, 360)``, a yaw about the cube's own axis in
    ``[0, 90)`` degrees (the cube's symmetry) and an offset of the bottom face's centre from the jig axis
    uniform in the disc of radius ``max_offset_mm``; the push depth is ``push_depth_mm``. The unloaded
    reference frame comes first if ``reference`` (so ``n_frames + 1`` frames).
    """
    if n_frames < 1:
        raise InputError(f"the cube experiment needs at least one frame, got {n_frames}")
    _check_alpha(max_alpha_deg)
    _check_push(push_depth_mm)
    if not (math.isfinite(max_offset_mm) and max_offset_mm >= 0):
        raise InputError(f"the cube's offset must be zero or positive, got {max_offset_mm}")
    part = cube(float(side_mm))
    validate_part(part)
    rng = np.random.default_rng(rng)
    specs = [_reference()] if reference else []
    for _ in range(int(n_frames)):
        alpha = rng.uniform(0.0, math.radians(max_alpha_deg))
        theta = rng.uniform(0.0, 2 * math.pi)
        yaw = rng.uniform(0.0, math.pi / 2)
        radius = max_offset_mm * math.sqrt(rng.uniform())
        phi = rng.uniform(0.0, 2 * math.pi)
        pose = PartPose(
            alpha_rad=float(alpha),
            theta_rad=float(theta),
            push_depth_mm=float(push_depth_mm),
            center_xy_mm=(radius * math.cos(phi), radius * math.sin(phi)),
            yaw_rad=float(yaw),
        )
        specs.append(_loaded(part, pose))
    return specs


def single(
    part: Part, alpha_deg: float, theta_deg: float, push_depth_mm: float = 3.0, *, reference: bool = False
) -> list[FrameSpec]:
    """One part, centred on the jig axis, tilted by ``alpha_deg`` towards ``theta_deg`` (one frame; the
    unloaded reference frame first if ``reference``)."""
    _check_alpha(float(alpha_deg))
    _check_push(push_depth_mm)
    validate_part(part)
    pose = PartPose(
        alpha_rad=math.radians(alpha_deg),
        theta_rad=math.radians(theta_deg),
        push_depth_mm=float(push_depth_mm),
    )
    return [*([_reference()] if reference else []), _loaded(part, pose)]


# ---------------------------------------------------------------------------------------- truth


def frame_truth(jig: JigConfig, pose: PartPose) -> dict[str, Any]:
    """The ``truth`` entry of a loaded frame (JSON-ready): ``normal``, ``push_depth_mm``, ``T_J_part``.

    See the module docstring for the push depth's exact definition.
    """
    T = pose.T_J_part(jig)
    n = T[:3, 2]
    zero = np.zeros(1)
    h_rest = float(rest_inner_height_mm(jig, zero, zero)[0])
    z_markers_plane = float(bottom_plane_height_mm(T, zero, zero)[0]) - jig.membrane.thickness_mm / n[2]
    return {
        "normal": [float(v) for v in n],
        "push_depth_mm": h_rest - z_markers_plane,
        "T_J_part": T.tolist(),
    }


# ------------------------------------------------------------------------------------- rendering

_WORKER_AS_BUILT: AsBuiltJig | None = None


def _init_worker(as_built: AsBuiltJig) -> None:
    global _WORKER_AS_BUILT
    _WORKER_AS_BUILT = as_built


def _frame_seed(seed: int, index: int) -> np.random.SeedSequence:
    return np.random.SeedSequence(seed, spawn_key=(1, index))


def _render_one(
    as_built: AsBuiltJig, spec: FrameSpec, seed: int, index: int, color: bool
) -> tuple[bytes, bytes, dict[str, np.ndarray]]:
    """Render one frame and encode it: (left PNG, right PNG, truth arrays)."""
    from softjig.sim.render import render_pair

    rng = np.random.default_rng(_frame_seed(seed, index))
    pair = render_pair(as_built, spec.part, spec.pose, rng, color=color)
    m = pair.markers
    truth = {
        "xyz_mm": m.xyz_mm,
        "axis": m.axis,
        "in_contact": m.in_contact,
        "left_px": m.left_px,
        "right_px": m.right_px,
        "visible_left": m.visible_left,
        "visible_right": m.visible_right,
        "fiducial_corners_left_px": pair.fiducial_corners_left_px,
        "fiducial_corners_right_px": pair.fiducial_corners_right_px,
    }
    return encode_png(pair.left), encode_png(pair.right), {k: np.asarray(v) for k, v in truth.items()}


def _render_in_worker(
    spec: FrameSpec, seed: int, index: int, color: bool
) -> tuple[bytes, bytes, dict[str, np.ndarray]]:
    assert _WORKER_AS_BUILT is not None, "worker not initialised"
    return _render_one(_WORKER_AS_BUILT, spec, seed, index, color)


def _warm_up() -> None:
    from softjig.sim import render  # noqa: F401 - import once per worker, before the first frame


def simulate_dataset(
    out_dir: str | os.PathLike[str],
    specs: Iterable[FrameSpec],
    nominal_jig: JigConfig,
    *,
    seed: int,
    workers: int | None = None,
    progress: bool = True,
    overwrite: bool = False,
    color: bool = False,
    first_index: int = 0,
) -> Path:
    """Render every spec on an as-built jig drawn from ``seed`` and write a dataset with ground truth.

    Parameters
    ----------
    out_dir : the dataset folder to write.
    specs : the frames (:func:`paper_sweep`, :func:`cube_experiment`, :func:`single`).
    nominal_jig : the jig as designed; written as ``rig.toml``. The images come from an as-built jig
        drawn from its tolerances (:func:`softjig.sim.asbuilt.draw_as_built`), stored as
        ``as_built.toml`` for analysis only.
    seed : the run's seed; the same seed gives the same dataset whatever ``workers`` is.
    workers : rendering processes (default: ``os.cpu_count()``); 1 renders in this process.
    progress : show a progress bar on stderr.
    overwrite : replace an existing dataset in ``out_dir``.
    color : render RGB images instead of gray.
    first_index : the first spec's number in a longer run (frame ``k`` draws its noise from the seed and
        ``first_index + k``): the run's frames written in parts (``softjig demo``'s chunks) are the
        frames of the whole run at once. The dataset still numbers its frames from 0.

    Returns
    -------
    Path
        ``out_dir``.

    Raises
    ------
    InputError
        An existing dataset without ``overwrite``, an invalid spec or seed.
    """
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or seed < 0:
        raise InputError(f"the seed must be a non-negative integer, got {seed!r}")
    seed = int(seed)
    validate_jig(nominal_jig)
    specs = list(specs)
    for spec in specs:
        if spec.part is not None:
            validate_part(spec.part, nominal_jig)
            check_reachable(nominal_jig, spec)
    n_workers = (os.cpu_count() or 1) if workers is None else int(workers)
    if n_workers < 1:
        raise InputError(f"the number of workers must be at least 1, got {workers}")
    n_workers = min(n_workers, max(1, len(specs)))
    from softjig.sim import render  # noqa: F401 - fail early; forked workers inherit the import

    as_built = draw_as_built(nominal_jig, np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(0,))))
    out = Path(out_dir)
    with contextlib.ExitStack() as stack:
        # A simulation can be rendered again from its seed: files are written atomically (a killed run
        # leaves only complete frames) but not fsynced, which would cost ~30 ms of disk per frame here.
        writer = stack.enter_context(
            DatasetWriter(out, nominal_jig, as_built=as_built, overwrite=overwrite, durable=False)
        )
        pool = None
        if n_workers > 1:
            # Workers die with this process; an exception (Ctrl-C, SIGTERM) ends them at once (io.workers).
            pool = stack.enter_context(worker_pool(n_workers, initializer=_init_worker, initargs=(as_built,)))
            # Start every worker before the progress bar's thread exists (workers are forked).
            for f in [pool.submit(_warm_up) for _ in range(n_workers)]:
                f.result()
        advance = stack.enter_context(_progress_bar(progress, len(specs)))
        for index, (left, right, truth_markers) in enumerate(
            _rendered(as_built, specs, seed, pool, n_workers, color, int(first_index))
        ):
            spec = specs[index]
            meta = dict(spec.meta)
            if spec.pose is not None:
                meta["truth"] = frame_truth(as_built.jig, spec.pose)
            writer.add_frame(left, right, meta, truth_markers=truth_markers)
            advance()
    return out


def _rendered(
    as_built: AsBuiltJig,
    specs: list[FrameSpec],
    seed: int,
    pool: ProcessPoolExecutor | None,
    n_workers: int,
    color: bool,
    first_index: int = 0,
) -> Iterator[tuple[bytes, bytes, dict[str, np.ndarray]]]:
    """The rendered frames, in order; in a pool, a bounded window of frames is in flight."""
    if pool is None:
        for index, spec in enumerate(specs, start=first_index):
            yield _render_one(as_built, spec, seed, index, color)
        return
    todo = iter(enumerate(specs, start=first_index))
    pending: deque[Future[tuple[bytes, bytes, dict[str, np.ndarray]]]] = deque(
        pool.submit(_render_in_worker, spec, seed, index, color)
        for index, spec in itertools.islice(todo, 8 * n_workers)  # absorbs fsync stalls
    )
    try:
        while pending:
            result = pending.popleft().result()
            for index, spec in itertools.islice(todo, 1):
                pending.append(pool.submit(_render_in_worker, spec, seed, index, color))
            yield result
    finally:
        for f in pending:
            f.cancel()


class _progress_bar:
    """A rich progress bar on stderr (or nothing); entering gives the ``advance()`` callable."""

    def __init__(self, enabled: bool, total: int) -> None:
        self.enabled, self.total = enabled, total
        self._progress: Any = None
        self._task: Any = None
        self._t0 = time.perf_counter()

    def __enter__(self):
        if not self.enabled:
            return lambda: None
        from rich.console import Console
        from rich.progress import (
            BarColumn,
            MofNCompleteColumn,
            Progress,
            TextColumn,
            TimeElapsedColumn,
            TimeRemainingColumn,
        )

        self._progress = Progress(
            TextColumn("rendering"),
            BarColumn(),
            MofNCompleteColumn(),
            TimeElapsedColumn(),
            TimeRemainingColumn(),
            console=Console(stderr=True),
            transient=False,
        )
        self._progress.start()
        self._task = self._progress.add_task("render", total=self.total)
        return lambda: self._progress.advance(self._task)

    def __exit__(self, *exc: object) -> None:
        if self._progress is not None:
            self._progress.stop()
