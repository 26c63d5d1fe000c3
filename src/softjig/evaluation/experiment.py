"""The paper's experiments end to end on the simulated jig, as one library function: :func:`run_experiment`.

1. **Simulate** the tilt sweep (cylinders of each diameter, each tilt ``alpha``, ``theta`` through a full
   turn, plus the unloaded reference) and the cube experiment, both with one seed, hence on one as-built
   jig (camera misalignment, plate and oil refraction...: what the calibration has to absorb).
2. **Estimate** every frame with the paper's method on the nominal jig, uncalibrated, on every core.
   Frames that give no estimate are counted and reported, never fatal.
3. **Calibrate** (the paper's ``Ox, Oy, S``, pooled over every part as the paper; per diameter as well)
   on the even ``theta`` steps of each sweep, and
4. **evaluate** on the odd ones (held out, ``split="alternate"``; ``split="none"`` calibrates and
   evaluates on every frame): the RMSE grid diameter x tilt, calibrated and uncalibrated.
5. **Motion capture**: the cube's true poses are exported as a Motive CSV (jig and cube rigid bodies in
   a y-up mocap frame, as Motive's), read back with :func:`softjig.evaluation.mocap.read_motive_csv`, and
   the mocap normals ``n_d = R_d z`` with ``T_d = inv(T_j) T_o`` are compared with the jig's estimates.
6. **Figures and report**: PNGs, ``report.md``, ``summary.json``, ``calibration.json`` in ``out_dir``.

Layout of ``out_dir``::

    report.md  summary.json  calibration.json  calibration-per-diameter.json
    figures/   tilt_before.png  tilt_after.png  rmse_grid.png  cube_normals.png  stereo_pair.png
    data/sweep/  data/cube/       the datasets, each with its estimates.jsonl (data/cube/mocap.csv)
"""

from __future__ import annotations

import json
import os
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
from softjig.evaluation.tilt_sweep import SweepEvaluation, evaluate_sweep
from softjig.geometry import normal_from_tilt_angles, pose_from_rotation_translation
from softjig.io.files import write_text_atomic

__all__ = [
    "SPLITS",
    "CubeComparison",
    "ExperimentResult",
    "ExperimentSettings",
    "compare_with_mocap",
    "quick_settings",
    "run_experiment",
]

SPLITS = ("alternate", "none")
JIG_BODY, CUBE_BODY = "SoftJig", "Cube"


@dataclass(frozen=True)
class ExperimentSettings:
    """What :func:`run_experiment` does.

    Attributes
    ----------
    out_dir : the folder to write (created; an earlier demo's datasets in it are replaced).
    seed : seed of the as-built jig and of every frame's noise (both experiments share the jig).
    diameters_mm, alphas_deg, theta_step_deg, push_depth_mm : the sweep (the paper's by default).
    cube_frames : loaded frames of the cube experiment (0: skip it).
    split : ``"alternate"``: calibrate on the even theta steps, evaluate on the odd ones;
        ``"none"``: calibrate and evaluate on every frame (optimistic).
    jig : the nominal jig (the paper's default jig if ``None``).
    workers : processes for rendering and estimation (default: every CPU).
    progress : progress bars on stderr.
    quick : only recorded in the report (a reduced run).
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


# ----------------------------------------------------------------------------------------- pieces


#: What the experiment reads of an estimate row (:func:`sweep_samples`, :func:`compare_with_mocap`); the
#: whole rows stream to ``estimates.jsonl`` and only these keys are kept in memory.
_ROW_KEYS = ("index", "raw_tilt_x_deg", "raw_tilt_y_deg", "error", "exit_code", "reference", "method")


def _estimate_rows(dataset: Any, *, workers: int | None, progress: bool, label: str) -> list[dict]:
    """Estimate every frame (paper's method, nominal jig, uncalibrated) with a progress bar; the rows
    stream to ``estimates.jsonl`` in the dataset's folder and come back reduced to :data:`_ROW_KEYS`."""
    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from softjig.sensing.batch import BatchSettings, estimate_dataset_to_file

    settings = BatchSettings(jig=dataset.jig, method="paper")
    columns = (TextColumn(label), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn())
    rows: list[dict] = []

    def keep(row: dict) -> None:
        rows.append({k: row[k] for k in _ROW_KEYS if k in row})
        bar.advance(task)

    with Progress(*columns, console=Console(stderr=True), disable=not progress) as bar:
        task = bar.add_task(label, total=len(dataset))
        estimate_dataset_to_file(
            dataset, settings, dataset.root / "estimates.jsonl", workers=workers, on_row=keep
        )
    return rows


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


def _stereo_pair_figure(dataset: Any, samples: SweepSamples, path: Path) -> int | None:
    """Overlay of the detected markers on one sweep frame near D = 50 mm, alpha = 10 deg, theta = 30 deg;
    returns its index (``None`` if every candidate fails)."""
    from softjig.errors import EstimationError
    from softjig.io.dataset import encode_png
    from softjig.io.files import write_bytes_atomic
    from softjig.sensing.overlay import draw_overlay
    from softjig.sensing.pipeline import estimate_pair

    if not len(samples):
        return None
    score = (
        np.abs(samples.diameter_mm - 50.0) * 10
        + np.abs(samples.alpha_deg - 10.0) * 5
        + np.abs(np.mod(samples.theta_deg - 30.0 + 180.0, 360.0) - 180.0)
    )
    candidates = np.argsort(score, kind="stable")[:5]
    wanted = {int(samples.index[k]) for k in candidates}
    frames = {f.index: f for f in dataset if f.index in wanted}  # one pass, the candidates kept
    for k in candidates:
        frame = frames[int(samples.index[k])]
        left, right = frame.load_left(), frame.load_right()
        try:
            result = estimate_pair(
                left, right, dataset.jig, part_diameter_mm=float(samples.diameter_mm[k]), method="paper"
            )
        except (EstimationError, InputError):
            continue
        write_bytes_atomic(path, encode_png(draw_overlay(left, right, result, dataset.jig)))
        return frame.index
    return None


# ----------------------------------------------------------------------------------------- the run


def run_experiment(
    settings: ExperimentSettings, *, on_stage: Callable[[str], None] | None = None
) -> ExperimentResult:
    """Run the paper's experiments on the simulated jig and write the report (see the module docstring).

    Parameters
    ----------
    settings : what to run.
    on_stage : called with a one-line description as each stage starts (e.g. to print it).

    Returns
    -------
    ExperimentResult

    Raises
    ------
    InputError
        Bad settings (an unknown split, an invalid sweep), or an output folder that holds something
        other than an earlier run.
    """
    from softjig.config import default_jig
    from softjig.evaluation import figures, report
    from softjig.io.dataset import Dataset
    from softjig.sim.scenarios import cube_experiment, paper_sweep, simulate_dataset

    if settings.split not in SPLITS:
        raise InputError(f"unknown split {settings.split!r}; valid: {', '.join(SPLITS)}")
    stage = on_stage or (lambda _text: None)
    t_start = time.perf_counter()
    timings: dict[str, float] = {}
    out = Path(settings.out_dir)
    out.mkdir(parents=True, exist_ok=True)
    fig_dir, data_dir = out / "figures", out / "data"
    jig = settings.jig or default_jig()
    specs = list(
        paper_sweep(
            settings.diameters_mm,
            settings.alphas_deg,
            settings.theta_step_deg,
            push_depth_mm=settings.push_depth_mm,
        )
    )

    def lap(name: str, t0: float) -> None:
        timings[name] = time.perf_counter() - t0

    t0 = time.perf_counter()
    stage(f"simulating the tilt sweep: {len(specs)} stereo pairs (seed {settings.seed})")
    simulate_dataset(
        data_dir / "sweep",
        specs,
        jig,
        seed=settings.seed,
        workers=settings.workers,
        progress=settings.progress,
        overwrite=True,
    )
    cube_specs = []
    if settings.cube_frames > 0:
        cube_specs = cube_experiment(
            settings.cube_frames, rng=settings.seed, push_depth_mm=settings.push_depth_mm
        )
        stage(
            f"simulating the cube experiment: {len(cube_specs)} stereo pairs (same seed, same as-built jig)"
        )
        simulate_dataset(
            data_dir / "cube",
            cube_specs,
            jig,
            seed=settings.seed,
            workers=settings.workers,
            progress=settings.progress,
            overwrite=True,
        )
    lap("simulate", t0)

    t0 = time.perf_counter()
    stage("estimating every frame (paper's method, nominal jig, uncalibrated)")
    sweep = Dataset.open(data_dir / "sweep")
    rows = _estimate_rows(
        sweep, workers=settings.workers, progress=settings.progress, label="estimating sweep"
    )
    cube_ds, cube_rows = None, []
    if cube_specs:
        cube_ds = Dataset.open(data_dir / "cube")
        cube_rows = _estimate_rows(
            cube_ds, workers=settings.workers, progress=settings.progress, label="estimating cube"
        )
    lap("estimate", t0)

    t0 = time.perf_counter()
    fit_on, eval_on = ("even", "odd") if settings.split == "alternate" else ("all", "all")
    stage(f"calibrating on the {fit_on} theta steps, evaluating on the {eval_on} ones")
    samples = sweep_samples(sweep, rows)
    pooled = fit_sweep_calibration(samples, mode="pooled", selection=fit_on)
    per_d = fit_sweep_calibration(samples, mode="per-diameter", selection=fit_on)
    source = {
        "dataset": str(sweep.root.resolve()),
        "results": str((sweep.root / "estimates.jsonl").resolve()),
        "method": "paper",
        "seed": settings.seed,
    }
    paths: dict[str, Path] = {
        "calibration": out / "calibration.json",
        "calibration_per_diameter": out / "calibration-per-diameter.json",
    }
    save_sweep_calibration(pooled, paths["calibration"], source=source)
    save_sweep_calibration(per_d, paths["calibration_per_diameter"], source=source)
    evaluation = evaluate_sweep(samples, pooled.pooled, selection=eval_on)
    per_d_eval = evaluate_sweep(samples, per_d, selection=eval_on)
    cube = None
    if cube_ds is not None:
        paths["mocap"] = cube_ds.root / "mocap.csv"
        write_simulated_mocap(cube_ds, paths["mocap"])
        try:
            cube = compare_with_mocap(cube_ds, cube_rows, paths["mocap"], pooled.pooled)
        except InputError as exc:  # every cube frame failed: say so in the report, do not crash
            stage(f"cube comparison skipped: {exc}")
    lap("calibrate_evaluate", t0)

    t0 = time.perf_counter()
    stage("drawing the figures and writing the report")
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
        title="RMSE of the tilt angles against the commanded ones (deg)",
    )
    if cube is not None:
        paths["cube_normals"] = fig_dir / "cube_normals.png"
        figures.normal_projection_figure(
            [("uncalibrated", cube.raw_normals), ("calibrated", cube.calibrated_normals)],
            cube.truth_normals,
            paths["cube_normals"],
        )
    pair_index = _stereo_pair_figure(sweep, samples.select(eval_on), fig_dir / "stereo_pair.png")
    if pair_index is not None:
        paths["stereo_pair"] = fig_dir / "stereo_pair.png"
    lap("figures", t0)
    timings["total"] = time.perf_counter() - t_start

    failed = tuple((int(i), e) for i, e in zip(samples.failed_index, samples.failed_errors, strict=True))
    paths["report"], paths["summary"] = out / "report.md", out / "summary.json"
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
    )
    write_text_atomic(
        paths["report"], report.experiment_report_markdown(result, stereo_pair_index=pair_index)
    )
    write_text_atomic(paths["summary"], json.dumps(report.experiment_summary(result), indent=2) + "\n")
    return result
