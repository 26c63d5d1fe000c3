"""The paper's experiments end to end on the simulated jig, as one library function: :func:`run_experiment`.

1. **Simulate** the tilt sweep (cylinders of each diameter, each tilt ``alpha``, ``theta`` through a full
   turn, plus the unloaded reference) and the cube experiment, both with one seed, hence on one as-built
   jig (camera misalignment, plate and oil refraction...: what the calibration has to absorb).
2. **Estimate** every frame on the nominal jig, uncalibrated, on every core, with the paper's method and
   with softjig's default (``refractive``: indentations against the unloaded reference frame). Frames
   that give no estimate are counted and reported, never fatal.
   Steps 1-2 go in chunks of ``chunk_frames`` frames, recorded in the run folder's manifest
   (:mod:`softjig.evaluation.run_folder`): an interrupted run resumes at the first unfinished chunk, and a
   chunk's images are deleted once estimated (unless ``keep_data``; the reference frames and the example
   pair's candidates are kept). Frame ``k`` of a dataset is rendered from the seed and ``k`` whatever the
   chunks, so a resumed run gives the results of an uninterrupted one.
3. **Calibrate** (the paper's ``Ox, Oy, S``, pooled over every part as the paper; per diameter as well)
   on the even ``theta`` steps of each sweep, and
4. **evaluate** on the odd ones (held out, ``split="alternate"``; ``split="none"`` calibrates and
   evaluates on every frame): the RMSE grid diameter x tilt, calibrated and uncalibrated; the default
   method the same way, uncalibrated and with its own calibration fitted on the same frames.
5. **Motion capture**: the cube's true poses are exported as a Motive CSV (jig and cube rigid bodies in
   a y-up mocap frame, as Motive's), read back with :func:`softjig.evaluation.mocap.read_motive_csv`, and
   the mocap normals ``n_d = R_d z`` with ``T_d = inv(T_j) T_o`` are compared with the jig's estimates.
6. **Figures and report**: PNGs, ``report.md``, a self-contained ``report.html``, ``summary.json``,
   ``calibration.json`` in ``out_dir``.

Layout of ``out_dir``::

    manifest.json  report.md  report.html  summary.json
    calibration.json  calibration-per-diameter.json  calibration-refractive.json
    figures/   methods.png  tilt_methods.png  cube_methods.png  (the methods side by side)
               tilt_before.png  tilt_after.png  rmse_grid.png  cube_normals.png  stereo_pair.png
               stereo_pair_refractive.png      (the paper's method; the default method's example pair)
    data/sweep/  data/cube/   each a dataset (frames.jsonl, rig.toml...) whose frames lie in chunks/NNN/,
                              with estimates.jsonl (paper) and estimates-refractive.jsonl;
                              data/cube/mocap.csv
"""

from __future__ import annotations

import json
import os
import shutil
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from softjig.calibration.sweep import (
    SweepCalibration,
    SweepSamples,
    fit_sweep_calibration,
    save_sweep_calibration,
    sweep_samples,
)
from softjig.calibration.tilt import TiltCalibration
from softjig.config import JigConfig
from softjig.errors import InputError
from softjig.evaluation.metrics import TiltErrorSummary, tilt_error_summary
from softjig.evaluation.run_folder import DiskUse, RunFolder, delete_frame_files, disk_use
from softjig.evaluation.tilt_sweep import SweepEvaluation, evaluate_sweep
from softjig.geometry import normal_from_tilt_angles, pose_from_rotation_translation
from softjig.io.files import write_text_atomic

__all__ = [
    "SPLITS",
    "CubeComparison",
    "DefaultMethodResult",
    "ExperimentResult",
    "ExperimentSettings",
    "compare_with_mocap",
    "quick_settings",
    "run_experiment",
]

SPLITS = ("alternate", "none")
JIG_BODY, CUBE_BODY = "SoftJig", "Cube"
DEFAULT_METHOD = "refractive"  # softjig's default (softjig.sensing.pipeline.DEFAULT_METHOD)
#: The estimate files of each method in a dataset folder.
ESTIMATES = {"paper": "estimates.jsonl", DEFAULT_METHOD: f"estimates-{DEFAULT_METHOD}.jsonl"}


@dataclass(frozen=True)
class ExperimentSettings:
    """What :func:`run_experiment` does.

    Attributes
    ----------
    out_dir : the run folder (created). An unfinished run in it with the same options is resumed; a
        finished one, or an unfinished one with other options, is refused unless ``overwrite``; a
        non-empty folder that is not a run is always refused.
    seed : seed of the as-built jig and of every frame's noise (both experiments share the jig).
    diameters_mm, alphas_deg, theta_step_deg, push_depth_mm : the sweep (the paper's by default).
    cube_frames : loaded frames of the cube experiment (0: skip it).
    split : ``"alternate"``: calibrate on the even theta steps, evaluate on the odd ones;
        ``"none"``: calibrate and evaluate on every frame (optimistic).
    jig : the nominal jig (the paper's default jig if ``None``).
    workers : processes for rendering and estimation (default: every CPU).
    progress : progress bars on stderr.
    quick : only recorded in the report (a reduced run).
    keep_data : keep every rendered image and truth file (else deleted once estimated).
    overwrite : replace a finished run (or an unfinished one with other options) in ``out_dir``.
    chunk_frames : frames rendered, estimated and recorded together (the unit of resumption).
    """

    out_dir: Path
    seed: int = 0
    diameters_mm: tuple[float, ...] = (30.0, 40.0, 50.0, 60.0, 70.0, 80.0)
    alphas_deg: tuple[float, ...] = (5.0, 10.0, 15.0, 20.0)
    theta_step_deg: float = 10.0
    push_depth_mm: float = 3.0
    cube_frames: int = 60
    split: str = "alternate"
    jig: JigConfig | None = None
    workers: int | None = None
    progress: bool = True
    quick: bool = False
    keep_data: bool = False
    overwrite: bool = False
    chunk_frames: int = 64

    def fingerprint(self, jig: JigConfig) -> dict[str, Any]:
        """What must match for a run folder to be resumed: every option that changes the results."""
        import hashlib

        from softjig.config import dumps_jig

        return {
            "seed": self.seed,
            "diameters_mm": list(self.diameters_mm),
            "alphas_deg": list(self.alphas_deg),
            "theta_step_deg": self.theta_step_deg,
            "push_depth_mm": self.push_depth_mm,
            "cube_frames": self.cube_frames,
            "split": self.split,
            "quick": self.quick,
            "keep_data": self.keep_data,
            "chunk_frames": self.chunk_frames,
            "jig_sha256": hashlib.sha256(dumps_jig(jig).encode()).hexdigest(),
        }


def quick_settings(out_dir: Path, *, seed: int = 0, **kwargs: Any) -> ExperimentSettings:
    """A small run (about 1/10 of the frames): D = 30, 50, 80 mm, alpha = 10, 20 deg, theta step 30 deg,
    10 cube frames."""
    params: dict[str, Any] = {
        "diameters_mm": (30.0, 50.0, 80.0),
        "alphas_deg": (10.0, 20.0),
        "theta_step_deg": 30.0,
        "cube_frames": 10,
        "quick": True,
    }
    params.update(kwargs)
    return ExperimentSettings(out_dir=Path(out_dir), seed=seed, **params)


@dataclass(frozen=True, eq=False)
class CubeComparison:
    """The jig's estimates of the cube against motion capture.

    Attributes
    ----------
    index : (n,) dataset frame indices compared (estimate and mocap both present).
    raw_normals, calibrated_normals, truth_normals : (n, 3) normals in J.
    raw, calibrated : error summaries against the mocap normals.
    n_failed : cube frames that gave no estimate; n_untracked : frames without mocap.
    """

    index: np.ndarray
    raw_normals: np.ndarray
    calibrated_normals: np.ndarray
    truth_normals: np.ndarray
    raw: TiltErrorSummary
    calibrated: TiltErrorSummary
    n_failed: int
    n_untracked: int


@dataclass(frozen=True, eq=False)
class DefaultMethodResult:
    """softjig's default method on the same frames as the paper's.

    Attributes
    ----------
    method : its name (``refractive``).
    samples : the sweep's frames joined with its estimates.
    calibration : the paper's ``(Ox, Oy, S)`` fitted to it on the same frames as the paper's calibration
        (a sensor that needs none has ``S = 1``, ``O = 0``).
    evaluation : its RMSE grids with that calibration and uncalibrated, on the paper's evaluation frames.
    cube : its motion-capture comparison, uncalibrated and with its calibration.
    """

    method: str
    samples: SweepSamples
    calibration: SweepCalibration
    evaluation: SweepEvaluation
    cube: CubeComparison | None


@dataclass(frozen=True, eq=False)
class ExperimentResult:
    """What :func:`run_experiment` found and wrote.

    Attributes
    ----------
    settings : what was run.
    samples : the sweep's frames joined with their estimates.
    calibration : the pooled calibration (the paper's), fitted on ``calibration.selection``.
    per_diameter : the per-diameter calibration, same frames.
    evaluation : RMSE grids (pooled calibration and uncalibrated) on ``evaluation.selection``.
    per_diameter_evaluation : the same with the per-diameter calibration.
    cube : the motion-capture comparison (``None`` without cube frames).
    timings_s : wall time of each stage (s) and ``total``.
    paths : the files written, by name (``report``, ``summary``, ``calibration``, figures...).
    failed_examples : a few ``(frame index, error)`` of frames that gave no estimate.
    default_method : softjig's default method on the same frames (``None`` only for old callers).
    disk : what the run folder holds at the end (measured); ``rendered``: what the run rendered, over
        every resumption (measured before deleting).
    resumed : this call continued an interrupted run; ``chunks_now``: chunks rendered by this call.
    """

    settings: ExperimentSettings
    samples: SweepSamples
    calibration: SweepCalibration
    per_diameter: SweepCalibration
    evaluation: SweepEvaluation
    per_diameter_evaluation: SweepEvaluation
    cube: CubeComparison | None
    timings_s: dict[str, float] = field(default_factory=dict)
    paths: dict[str, Path] = field(default_factory=dict)
    failed_examples: tuple[tuple[int, str], ...] = ()
    default_method: DefaultMethodResult | None = None
    disk: DiskUse | None = None
    rendered: DiskUse | None = None
    resumed: bool = False
    chunks_now: int = 0


# ----------------------------------------------------------------------------------------- pieces


#: What the experiment reads of an estimate row (:func:`sweep_samples`, :func:`compare_with_mocap`); the
#: whole rows stay in the estimate files and only these keys are kept in memory.
_ROW_KEYS = ("index", "raw_tilt_x_deg", "raw_tilt_y_deg", "error", "exit_code", "reference", "method")


def _read_rows(path: Path) -> list[dict]:
    """The rows of an estimates file, reduced to :data:`_ROW_KEYS`."""
    rows = []
    with open(path, encoding="utf-8") as fh:
        for line in fh:
            if line.strip():
                row = json.loads(line)
                rows.append({k: row[k] for k in _ROW_KEYS if k in row})
    return rows


def _chunk_name(c: int) -> str:
    return f"chunks/{c:03d}"


def _render_and_estimate(
    name: str,
    specs: list,
    jig: JigConfig,
    settings: ExperimentSettings,
    run: RunFolder,
    keep: set[int],
    stage: Callable[[str], None],
) -> tuple[Path, int]:
    """Render and estimate (both methods) ``specs`` into ``data/<name>`` chunk by chunk, skipping the chunks
    the manifest has as done, deleting each chunk's images once estimated (but those of ``keep``, global
    indices) unless ``keep_data``; then write the dataset's merged index. Returns its folder and how many
    chunks this call rendered."""
    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from softjig.io.batch import BatchSettings, dataset_reference, estimate_dataset_to_file
    from softjig.io.dataset import Dataset
    from softjig.sim.scenarios import simulate_dataset

    root = Path(settings.out_dir) / "data" / name
    size = int(settings.chunk_frames)
    starts = list(range(0, len(specs), size))
    reference = None
    rendered_now = 0
    columns = (
        TextColumn(f"{name}: render + estimate"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
    )
    with Progress(*columns, console=Console(stderr=True), disable=not settings.progress) as bar:
        task = bar.add_task(name, total=len(specs))
        for c, first in enumerate(starts):
            key, part = f"{name}/{c:03d}", root / _chunk_name(c)
            n = min(size, len(specs) - first)
            if run.done(key):
                bar.advance(task, n)
                continue
            stage(f"{name}: frames {first}-{first + n - 1} of {len(specs)} (chunk {c + 1} of {len(starts)})")
            if part.is_dir():  # an unfinished chunk of this run (the manifest says so): ours, start it over
                shutil.rmtree(part)
            simulate_dataset(
                part,
                specs[first : first + n],
                jig,
                seed=settings.seed,
                workers=settings.workers,
                progress=False,
                first_index=first,
            )
            rendered_now += 1
            chunk = Dataset.open(part)
            if reference is None:  # the unloaded frame, first of chunk 0: kept whatever keep_data says
                reference = dataset_reference(Dataset.open(root / _chunk_name(0)), jig)
            for method, file_name in ESTIMATES.items():
                batch = BatchSettings(
                    jig=chunk.jig, method=method, reference=reference if method == DEFAULT_METHOD else None
                )
                estimate_dataset_to_file(chunk, batch, part / file_name, workers=settings.workers)
            written = disk_use(part)
            deleted = 0
            if not settings.keep_data:
                deleted = delete_frame_files(part, {i - first for i in keep if first <= i < first + n})
            run.finish_chunk(
                key,
                first=first,
                n=n,
                rendered_files=written.files,
                rendered_bytes=written.bytes,
                deleted_files=deleted,
            )
            bar.advance(task, n)
    _merge_chunks(root, starts)
    return root, rendered_now


def _merge_chunks(root: Path, starts: list[int]) -> None:
    """Write ``root``'s own dataset index over its chunks: ``frames.jsonl`` with the run's frame numbers
    and paths into ``chunks/NNN/``, the chunks' ``rig.toml`` and as-built files, and each method's
    estimates with the run's frame numbers."""
    from softjig.io.dataset import AS_BUILT_MARKERS_NAME, AS_BUILT_NAME, FRAMES_NAME, RIG_NAME
    from softjig.io.files import write_bytes_atomic

    first_chunk = root / _chunk_name(0)
    for member in (RIG_NAME, AS_BUILT_NAME, AS_BUILT_MARKERS_NAME):
        if (first_chunk / member).is_file():
            write_bytes_atomic(root / member, (first_chunk / member).read_bytes(), durable=False)
    frames: list[str] = []
    rows: dict[str, list[str]] = {m: [] for m in ESTIMATES}
    for c, first in enumerate(starts):
        chunk = _chunk_name(c)
        with open(root / chunk / FRAMES_NAME, encoding="utf-8") as fh:
            for line in fh:
                if not line.strip():
                    continue
                record = json.loads(line)
                record["index"] += first
                record["left"], record["right"] = f"{chunk}/{record['left']}", f"{chunk}/{record['right']}"
                truth = record.get("truth")
                if isinstance(truth, dict) and isinstance(truth.get("markers"), str):
                    truth["markers"] = f"{chunk}/{truth['markers']}"
                frames.append(json.dumps(record, separators=(",", ":")))
        for method, file_name in ESTIMATES.items():
            with open(root / chunk / file_name, encoding="utf-8") as fh:
                for line in fh:
                    if line.strip():
                        row = json.loads(line)
                        row["index"] += first
                        rows[method].append(json.dumps(row, allow_nan=False))
    write_text_atomic(root / FRAMES_NAME, "\n".join(frames) + "\n")
    for method, file_name in ESTIMATES.items():
        write_text_atomic(root / file_name, "\n".join(rows[method]) + "\n")


def _keep_indices(specs: list, selection: str, *, n_candidates: int = 5) -> tuple[set[int], list[int]]:
    """Frames whose images the report needs, by spec number: the unloaded reference frames, and the
    candidates for the example pair (:func:`_stereo_pair_figure`), best first, among ``selection``."""
    from softjig.calibration.sweep import alternate_theta_mask

    reference = {k for k, spec in enumerate(specs) if spec.part is None}
    loaded = [k for k, spec in enumerate(specs) if spec.part is not None]
    if not loaded or n_candidates < 1:
        return reference, []
    d = np.array([float(specs[k].meta["part"]["diameter_mm"]) for k in loaded])
    a = np.array([float(specs[k].meta["alpha_deg"]) for k in loaded])
    t = np.array([float(specs[k].meta["theta_deg"]) for k in loaded])
    chosen = np.ones(len(loaded), bool)
    if selection in ("even", "odd"):
        even = alternate_theta_mask(d, a, t)
        chosen = even if selection == "even" else ~even
    score = np.abs(d - 50.0) * 10 + np.abs(a - 10.0) * 5 + np.abs(np.mod(t - 30.0 + 180.0, 360.0) - 180.0)
    score = np.where(chosen, score, np.inf)
    order = [loaded[k] for k in np.argsort(score, kind="stable")[:n_candidates] if np.isfinite(score[k])]
    return reference | set(order), order


def _normals_from_rows(rows: Sequence[dict], calibration: TiltCalibration | None) -> np.ndarray:
    """(n, 3) normals from the rows' raw tilt angles, after ``calibration`` if given."""
    ax = np.radians([row["raw_tilt_x_deg"] for row in rows])
    ay = np.radians([row["raw_tilt_y_deg"] for row in rows])
    if calibration is not None:
        ax, ay = calibration.apply(ax, ay)
    return np.array([normal_from_tilt_angles(x, y) for x, y in zip(ax, ay, strict=True)]).reshape(-1, 3)


#: The simulated mocap frame: y up (as Motive's), the jig 1.2 m in front of the origin, turned 30 deg.
def _T_mocap_jig() -> np.ndarray:
    from scipy.spatial.transform import Rotation

    z_up_to_y_up = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])  # J z -> mocap y
    yaw = Rotation.from_euler("y", 30.0, degrees=True).as_matrix()
    return pose_from_rotation_translation(yaw @ z_up_to_y_up, np.array([150.0, 740.0, -1200.0]))


def write_simulated_mocap(dataset: Any, path: Path) -> None:
    """Write a Motive CSV of a simulated dataset's truth: the jig and the part as rigid bodies (the part's
    rigid-body frame is ``T_J_part``'s, its ``z`` the bottom face's normal), Motive frame = dataset index.
    The mocap is exact (no marker noise): the comparison measures the jig alone."""
    from softjig.evaluation.mocap import write_motive_csv

    T_J_part: dict[int, np.ndarray] = {}  # one pass over the frames, keeping only the poses
    n = 0
    for frame in dataset:
        n = max(n, frame.index + 1)
        if frame.truth is not None and frame.truth.T_J_part is not None:
            T_J_part[frame.index] = frame.truth.T_J_part
    T_j = np.repeat(_T_mocap_jig()[None], n, axis=0)
    T_o = np.full((n, 4, 4), np.nan)
    for index, pose in T_J_part.items():
        T_o[index] = T_j[index] @ pose
    write_motive_csv(path, {JIG_BODY: T_j, CUBE_BODY: T_o}, units="Meters", take_name=dataset.root.name)


def compare_with_mocap(
    dataset: Any,
    rows: Sequence[dict],
    mocap_csv: str | os.PathLike[str],
    calibration: TiltCalibration,
    *,
    jig_body: str = JIG_BODY,
    object_body: str = CUBE_BODY,
    frame_offset: int = 0,
) -> CubeComparison:
    """Evaluate a dataset's estimates against a Motive CSV export (the paper's cube experiment).

    Parameters
    ----------
    dataset : the dataset (its loaded frames are compared; reference frames skipped).
    rows : its estimate rows (``raw_tilt_x_deg``, ``raw_tilt_y_deg``, or ``error``).
    mocap_csv : the Motive export with the jig's and the object's rigid bodies.
    calibration : applied to the raw tilt angles for the calibrated comparison.
    jig_body, object_body : the rigid bodies' names in the take.
    frame_offset : Motive frame number = dataset frame index + ``frame_offset`` (frames are matched by
        number; recordings with ``time_s`` could be matched by time with
        :func:`softjig.evaluation.mocap.normals_at`).

    Raises
    ------
    InputError
        An unreadable CSV, unknown body names, or no frame with both an estimate and mocap.
    """
    from softjig.evaluation.mocap import normals_at, read_motive_csv

    take = read_motive_csv(mocap_csv)
    by_index = {row["index"]: row for row in rows}
    loaded = [f.index for f in dataset if not f.reference and f.part is not None]
    ok_rows = [by_index.get(i) for i in loaded]
    n_failed = sum(1 for r in ok_rows if r is None or "error" in r)
    pairs = [(i, r) for i, r in zip(loaded, ok_rows, strict=True) if r is not None and "error" not in r]
    index = np.array([i for i, _ in pairs], dtype=int)
    truth = normals_at(take, jig_body=jig_body, object_body=object_body, frames=index + frame_offset)
    tracked = np.isfinite(truth).all(axis=1)
    if not tracked.any():
        raise InputError(
            f"no frame of {dataset.root} has both an estimate and mocap in {mocap_csv}: check "
            "the rigid-body names and the frame offset"
        )
    kept = [r for (_, r), t in zip(pairs, tracked, strict=True) if t]
    raw = _normals_from_rows(kept, None)
    cal = _normals_from_rows(kept, calibration)
    return CubeComparison(
        index=index[tracked],
        raw_normals=raw,
        calibrated_normals=cal,
        truth_normals=truth[tracked],
        raw=tilt_error_summary(raw, truth[tracked]),
        calibrated=tilt_error_summary(cal, truth[tracked]),
        n_failed=n_failed,
        n_untracked=int((~tracked).sum()),
    )


def _stereo_pair_figure(
    dataset: Any,
    candidates: Sequence[int],
    samples: SweepSamples,
    path: Path,
    *,
    method: str = "paper",
    reference: Any = None,
) -> int | None:
    """Overlay of the markers and the normal on the first of ``candidates`` (frame indices, best first)
    that ``samples`` has an estimate of; returns its index (``None`` if every candidate fails)."""
    from softjig.errors import EstimationError
    from softjig.evaluation.overlay import draw_overlay
    from softjig.io.dataset import encode_png
    from softjig.io.files import write_bytes_atomic
    from softjig.sensing.estimator import Estimator

    diameters = {int(i): float(d) for i, d in zip(samples.index, samples.diameter_mm, strict=True)}
    estimator = Estimator(
        dataset.jig, method=method, reference=reference if method == DEFAULT_METHOD else None
    )
    wanted = [i for i in candidates if i in diameters]
    frames = {f.index: f for f in dataset if f.index in set(wanted)}  # one pass, the candidates kept
    for index in wanted:
        frame = frames[index]
        try:
            left, right = frame.load_left(), frame.load_right()
            result = estimator.estimate(left, right, part_diameter_mm=diameters[index])
        except (EstimationError, InputError):
            continue
        write_bytes_atomic(path, encode_png(draw_overlay(left, right, result, dataset.jig)))
        return frame.index
    return None


def _common_cube_frames(*comparisons: CubeComparison) -> np.ndarray:
    """Frame indices every comparison has."""
    common = set(comparisons[0].index.tolist())
    for c in comparisons[1:]:
        common &= set(c.index.tolist())
    return np.array(sorted(common), dtype=int)


def _at(comparison: CubeComparison, index: np.ndarray, which: str) -> np.ndarray:
    position = {int(i): k for k, i in enumerate(comparison.index)}
    values = getattr(comparison, which)
    return np.array([values[position[int(i)]] for i in index]).reshape(-1, 3)


# ----------------------------------------------------------------------------------------- the run


def run_experiment(
    settings: ExperimentSettings, *, on_stage: Callable[[str], None] | None = None
) -> ExperimentResult:
    """Run the paper's experiments on the simulated jig and write the report (see the module docstring).

    Parameters
    ----------
    settings : what to run.
    on_stage : called with a one-line description as each stage (and each chunk) starts, e.g. to print
        it. An exception it raises (KeyboardInterrupt) stops the run there, resumable.

    Returns
    -------
    ExperimentResult

    Raises
    ------
    InputError
        Bad settings (an unknown split, an invalid sweep), or an output folder that holds something
        other than a run, a finished run (without ``overwrite``), or an unfinished run with other options
        (without ``overwrite``).
    """
    from softjig.config import default_jig
    from softjig.evaluation import figures, report
    from softjig.io.batch import dataset_reference
    from softjig.io.dataset import Dataset
    from softjig.sim.scenarios import cube_experiment, paper_sweep

    if settings.split not in SPLITS:
        raise InputError(f"unknown split {settings.split!r}; valid: {', '.join(SPLITS)}")
    if int(settings.chunk_frames) < 1:
        raise InputError(f"chunk_frames must be at least 1, got {settings.chunk_frames}")
    stage = on_stage or (lambda _text: None)
    t_start = time.perf_counter()
    timings: dict[str, float] = {}
    out = Path(settings.out_dir)
    fig_dir = out / "figures"
    jig = settings.jig or default_jig()
    specs = list(
        paper_sweep(
            settings.diameters_mm,
            settings.alphas_deg,
            settings.theta_step_deg,
            push_depth_mm=settings.push_depth_mm,
        )
    )
    cube_specs = []
    if settings.cube_frames > 0:
        cube_specs = cube_experiment(
            settings.cube_frames, rng=settings.seed, push_depth_mm=settings.push_depth_mm
        )
    fit_on, eval_on = ("even", "odd") if settings.split == "alternate" else ("all", "all")
    keep, candidates = _keep_indices(specs, eval_on)
    cube_keep, _ = _keep_indices(cube_specs, "all", n_candidates=0) if cube_specs else (set(), [])

    run = RunFolder(out, settings.fingerprint(jig), overwrite=settings.overwrite)
    if run.resumed:
        done = sum(1 for c in run.chunks().values() if c.get("done"))
        stage(f"resuming the unfinished run in {out}: {done} chunks already done")

    def lap(name: str, t0: float) -> None:
        timings[name] = time.perf_counter() - t0

    t0 = time.perf_counter()
    stage(
        f"the tilt sweep: {len(specs)} stereo pairs (seed {settings.seed}), rendered and estimated with "
        f"the paper's method and the {DEFAULT_METHOD} one (nominal jig, uncalibrated)"
    )
    sweep_root, chunks_now = _render_and_estimate("sweep", specs, jig, settings, run, keep, stage)
    cube_ds = None
    if cube_specs:
        stage(f"the cube experiment: {len(cube_specs)} stereo pairs (same seed, same as-built jig)")
        cube_root, n = _render_and_estimate("cube", cube_specs, jig, settings, run, cube_keep, stage)
        chunks_now += n
        cube_ds = Dataset.open(cube_root)
    sweep = Dataset.open(sweep_root)
    rows = _read_rows(sweep_root / ESTIMATES["paper"])
    rows_default = _read_rows(sweep_root / ESTIMATES[DEFAULT_METHOD])
    lap("simulate_estimate", t0)

    t0 = time.perf_counter()
    stage(f"calibrating on the {fit_on} theta steps, evaluating on the {eval_on} ones")
    samples = sweep_samples(sweep, rows)
    pooled = fit_sweep_calibration(samples, mode="pooled", selection=fit_on)
    per_d = fit_sweep_calibration(samples, mode="per-diameter", selection=fit_on)
    samples_default = sweep_samples(sweep, rows_default)
    cal_default = fit_sweep_calibration(samples_default, mode="pooled", selection=fit_on)
    source = {
        "dataset": str(sweep.root.resolve()),
        "results": str((sweep.root / ESTIMATES["paper"]).resolve()),
        "method": "paper",
        "seed": settings.seed,
    }
    paths: dict[str, Path] = {
        "calibration": out / "calibration.json",
        "calibration_per_diameter": out / "calibration-per-diameter.json",
        "calibration_default": out / f"calibration-{DEFAULT_METHOD}.json",
    }
    save_sweep_calibration(pooled, paths["calibration"], source=source)
    save_sweep_calibration(per_d, paths["calibration_per_diameter"], source=source)
    save_sweep_calibration(
        cal_default,
        paths["calibration_default"],
        source={
            **source,
            "results": str((sweep.root / ESTIMATES[DEFAULT_METHOD]).resolve()),
            "method": DEFAULT_METHOD,
        },
    )
    evaluation = evaluate_sweep(samples, pooled.pooled, selection=eval_on)
    per_d_eval = evaluate_sweep(samples, per_d, selection=eval_on)
    eval_default = evaluate_sweep(samples_default, cal_default.pooled, selection=eval_on)
    cube = cube_default = None
    if cube_ds is not None:
        paths["mocap"] = cube_ds.root / "mocap.csv"
        write_simulated_mocap(cube_ds, paths["mocap"])
        for method, cal in (("paper", pooled.pooled), (DEFAULT_METHOD, cal_default.pooled)):
            try:
                found = compare_with_mocap(
                    cube_ds, _read_rows(cube_ds.root / ESTIMATES[method]), paths["mocap"], cal
                )
            except InputError as exc:  # every cube frame failed: say so in the report, do not crash
                stage(f"cube comparison ({method}) skipped: {exc}")
                continue
            if method == "paper":
                cube = found
            else:
                cube_default = found
    default = DefaultMethodResult(
        method=DEFAULT_METHOD,
        samples=samples_default,
        calibration=cal_default,
        evaluation=eval_default,
        cube=cube_default,
    )
    lap("calibrate_evaluate", t0)

    t0 = time.perf_counter()
    stage("drawing the figures and writing the report")
    paths["methods"] = fig_dir / "methods.png"
    cube_bars = []
    if cube is not None:
        cube_bars += [("paper, uncal.", cube.raw.rmse_deg), ("paper, calibrated", cube.calibrated.rmse_deg)]
    if cube_default is not None:
        cube_bars += [
            (f"{DEFAULT_METHOD}, uncal.", cube_default.raw.rmse_deg),
            (f"{DEFAULT_METHOD}, own cal.", cube_default.calibrated.rmse_deg),
        ]
    figures.methods_figure(
        [
            ("paper's method, calibrated", evaluation.calibrated),
            (f"{DEFAULT_METHOD} (default), uncalibrated", eval_default.uncalibrated),
            (f"{DEFAULT_METHOD}, its own calibration", eval_default.calibrated),
        ],
        paths["methods"],
        cube_bars,
        title=f"RMSE of the tilt angles (deg), {eval_on} frames: the paper's method beside softjig's default",
    )
    paths["tilt_methods"] = fig_dir / "tilt_methods.png"
    figures.tilt_methods_figure(
        [
            ("paper, calibrated", samples, pooled.pooled),
            (f"{DEFAULT_METHOD}, uncalibrated", samples_default, None),
        ],
        paths["tilt_methods"],
        title="Tilt angles over the sweep: the paper's method (calibrated) and "
        f"{DEFAULT_METHOD} (uncalibrated)",
    )
    paths["tilt_before"] = fig_dir / "tilt_before.png"
    paths["tilt_after"] = fig_dir / "tilt_after.png"
    paths["rmse_grid"] = fig_dir / "rmse_grid.png"
    figures.tilt_sweep_figure(samples, None, paths["tilt_before"])
    figures.tilt_sweep_figure(
        samples,
        pooled.pooled,
        paths["tilt_after"],
        title="Tilt angles after calibration (one Ox, Oy, S for all parts)",
    )
    figures.rmse_grid_figure(
        [
            (f"calibrated (pooled), {eval_on} frames", evaluation.calibrated),
            (f"uncalibrated, {eval_on} frames", evaluation.uncalibrated),
        ],
        paths["rmse_grid"],
        title="The paper's method: RMSE of the tilt angles against the commanded ones (deg)",
    )
    if cube is not None:
        paths["cube_normals"] = fig_dir / "cube_normals.png"
        figures.normal_projection_figure(
            [("uncalibrated", cube.raw_normals), ("calibrated", cube.calibrated_normals)],
            cube.truth_normals,
            paths["cube_normals"],
            index=cube.index,
        )
    if cube is not None and cube_default is not None:
        common = _common_cube_frames(cube, cube_default)
        if len(common):
            paths["cube_methods"] = fig_dir / "cube_methods.png"
            figures.normal_projection_figure(
                [
                    ("paper, calibrated", _at(cube, common, "calibrated_normals")),
                    (f"{DEFAULT_METHOD}, uncalibrated", _at(cube_default, common, "raw_normals")),
                ],
                _at(cube, common, "truth_normals"),
                paths["cube_methods"],
                index=common,
                title="Cube: the paper's method (calibrated) and the default one (uncalibrated) against "
                "motion capture",
            )
    evaluated = samples.select(eval_on)
    pair_index = _stereo_pair_figure(sweep, candidates, evaluated, fig_dir / "stereo_pair.png")
    if pair_index is not None:
        paths["stereo_pair"] = fig_dir / "stereo_pair.png"
    pair_default = _stereo_pair_figure(
        sweep,
        candidates,
        samples_default.select(eval_on),
        fig_dir / f"stereo_pair_{DEFAULT_METHOD}.png",
        method=DEFAULT_METHOD,
        reference=dataset_reference(sweep, sweep.jig),
    )
    if pair_default is not None:
        paths["stereo_pair_default"] = fig_dir / f"stereo_pair_{DEFAULT_METHOD}.png"
    if not settings.keep_data:  # the example pairs are drawn: the other candidates' images can go
        used = {k for k, spec in enumerate(specs) if spec.part is None} | {pair_index, pair_default}
        size = int(settings.chunk_frames)
        for c, first in enumerate(range(0, len(specs), size)):
            local = {i - first for i in used if i is not None and first <= i < first + size}
            delete_frame_files(sweep_root / _chunk_name(c), local)
    lap("figures", t0)

    failed = tuple((int(i), e) for i, e in zip(samples.failed_index, samples.failed_errors, strict=True))
    paths["report"], paths["summary"] = out / "report.md", out / "summary.json"
    paths["report_html"] = out / "report.html"
    chunks = run.chunks()
    rendered = DiskUse(
        sum(int(c.get("rendered_files", 0)) for c in chunks.values()),
        sum(int(c.get("rendered_bytes", 0)) for c in chunks.values()),
    )
    timings["total"] = time.perf_counter() - t_start
    result = ExperimentResult(
        settings=settings,
        samples=samples,
        calibration=pooled,
        per_diameter=per_d,
        evaluation=evaluation,
        per_diameter_evaluation=per_d_eval,
        cube=cube,
        timings_s=timings,
        paths=paths,
        failed_examples=failed[:10],
        default_method=default,
        rendered=rendered,
        resumed=run.resumed,
        chunks_now=chunks_now,
    )
    pairs = {"paper": pair_index, DEFAULT_METHOD: pair_default}
    write_text_atomic(
        paths["report"], report.experiment_report_markdown(result, stereo_pair_index=pair_index)
    )
    write_text_atomic(paths["report_html"], report.experiment_report_html(result, stereo_pairs=pairs))
    write_text_atomic(paths["summary"], json.dumps(report.experiment_summary(result), indent=2) + "\n")
    run.finish()
    from dataclasses import replace

    return replace(result, disk=disk_use(out))
