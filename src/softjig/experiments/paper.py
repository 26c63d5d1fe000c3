"""The paper's experiments end to end on the simulated jig, as one library function: :func:`run_experiment`.

What it fits, evaluates and returns is defined in :mod:`softjig.evaluation.experiment` (the settings,
the result types and the motion-capture comparison); this module runs it: it renders and writes datasets,
estimates them in worker processes and writes the figures and the report.

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
import shutil
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

from softjig.calibration.sweep import (
    SweepCalibration,
    SweepSamples,
    fit_sweep_calibration,
    save_sweep_calibration,
    sweep_samples,
)
from softjig.config import JigConfig, default_jig
from softjig.errors import EstimationError, InputError
from softjig.evaluation import figures, report
from softjig.evaluation.experiment import (
    DEFAULT_METHOD,
    ESTIMATES,
    SPLITS,
    CubeComparison,
    DefaultMethodResult,
    ExperimentResult,
    ExperimentSettings,
    compare_with_mocap,
    frames_to_keep,
    write_simulated_mocap,
)
from softjig.evaluation.overlay import draw_overlay
from softjig.evaluation.run_folder import DiskUse, RunFolder, delete_frame_files, disk_use
from softjig.evaluation.tilt_sweep import SweepEvaluation, evaluate_sweep
from softjig.files import write_bytes_atomic, write_text_atomic
from softjig.io.batch import BatchSettings, dataset_reference, estimate_dataset_to_file
from softjig.io.dataset import (
    AS_BUILT_MARKERS_NAME,
    AS_BUILT_NAME,
    FRAMES_NAME,
    RIG_NAME,
    Dataset,
    encode_png,
)
from softjig.io.simulated import simulate_dataset
from softjig.io.workers import signals_unwrapped
from softjig.sensing.estimator import Estimator
from softjig.sim.scenarios import FrameSpec, cube_experiment, paper_sweep

__all__ = ["run_experiment"]

#: Frames that gave no estimate quoted in the report, with their errors.
FAILED_EXAMPLES = 10

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
    diameters = {int(i): float(d) for i, d in zip(samples.index, samples.diameter_mm, strict=True)}
    wanted = [i for i in candidates if i in diameters]
    frames = {f.index: f for f in dataset if f.index in set(wanted)}  # one pass, the candidates kept
    estimator = Estimator(
        dataset.jig, method=method, reference=reference if method == DEFAULT_METHOD else None
    )
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


@dataclass(frozen=True)
class _Plan:
    """The frames of a run: the sweep's and the cube's specs, the calibration and evaluation selections,
    and the frames whose images the report needs (``keep``: spec numbers; ``candidates``: the example
    pair's, best first)."""

    specs: list[FrameSpec]
    cube_specs: list[FrameSpec]
    fit_on: str
    eval_on: str
    keep: set[int]
    candidates: list[int]
    cube_keep: set[int]


@dataclass(frozen=True, eq=False)
class _Estimated:
    """The run's datasets and their estimate rows, once rendered and estimated."""

    sweep: Dataset
    cube: Dataset | None
    rows: list[dict]
    rows_default: list[dict]
    chunks_now: int


@dataclass(frozen=True, eq=False)
class _Fitted:
    """The calibrations fitted on ``fit_on`` and their evaluations on ``eval_on``, both methods."""

    samples: SweepSamples
    pooled: SweepCalibration
    per_diameter: SweepCalibration
    evaluation: SweepEvaluation
    per_diameter_evaluation: SweepEvaluation
    cube: CubeComparison | None
    default: DefaultMethodResult


def _plan(settings: ExperimentSettings) -> _Plan:
    """Check the settings and list the run's frames (the paper's sweep, then the cube experiment)."""
    if settings.split not in SPLITS:
        raise InputError(f"unknown split {settings.split!r}; valid: {', '.join(SPLITS)}")
    if int(settings.chunk_frames) < 1:
        raise InputError(f"chunk_frames must be at least 1, got {settings.chunk_frames}")
    specs = list(
        paper_sweep(
            settings.diameters_mm,
            settings.alphas_deg,
            settings.theta_step_deg,
            push_depth_mm=settings.push_depth_mm,
        )
    )
    cube_specs: list[FrameSpec] = []
    if settings.cube_frames > 0:
        cube_specs = cube_experiment(
            settings.cube_frames, rng=settings.seed, push_depth_mm=settings.push_depth_mm
        )
    fit_on, eval_on = ("even", "odd") if settings.split == "alternate" else ("all", "all")
    keep, candidates = frames_to_keep(specs, eval_on)
    cube_keep, _ = frames_to_keep(cube_specs, "all", n_candidates=0) if cube_specs else (set(), [])
    return _Plan(specs, cube_specs, fit_on, eval_on, keep, candidates, cube_keep)


def _simulate_and_estimate(
    plan: _Plan, jig: JigConfig, settings: ExperimentSettings, run: RunFolder, stage: Callable[[str], None]
) -> _Estimated:
    """Steps 1-2 of the module docstring, for the sweep and the cube experiment."""
    stage(
        f"the tilt sweep: {len(plan.specs)} stereo pairs (seed {settings.seed}), rendered and estimated "
        f"with the paper's method and the {DEFAULT_METHOD} one (nominal jig, uncalibrated)"
    )
    sweep_root, chunks_now = _render_and_estimate("sweep", plan.specs, jig, settings, run, plan.keep, stage)
    cube = None
    if plan.cube_specs:
        stage(f"the cube experiment: {len(plan.cube_specs)} stereo pairs (same seed, same as-built jig)")
        cube_root, n = _render_and_estimate(
            "cube", plan.cube_specs, jig, settings, run, plan.cube_keep, stage
        )
        chunks_now += n
        cube = Dataset.open(cube_root)
    return _Estimated(
        sweep=Dataset.open(sweep_root),
        cube=cube,
        rows=_read_rows(sweep_root / ESTIMATES["paper"]),
        rows_default=_read_rows(sweep_root / ESTIMATES[DEFAULT_METHOD]),
        chunks_now=chunks_now,
    )


def _calibrate_and_evaluate(
    data: _Estimated,
    plan: _Plan,
    settings: ExperimentSettings,
    paths: dict[str, Path],
    stage: Callable[[str], None],
) -> _Fitted:
    """Steps 3-5: fit the calibrations on ``plan.fit_on``, write them, evaluate on ``plan.eval_on`` and
    compare the cube's estimates with its (simulated) motion capture."""
    stage(f"calibrating on the {plan.fit_on} theta steps, evaluating on the {plan.eval_on} ones")
    out = Path(settings.out_dir)
    sweep = data.sweep
    samples = sweep_samples(sweep, data.rows)
    pooled = fit_sweep_calibration(samples, mode="pooled", selection=plan.fit_on)
    per_d = fit_sweep_calibration(samples, mode="per-diameter", selection=plan.fit_on)
    samples_default = sweep_samples(sweep, data.rows_default)
    cal_default = fit_sweep_calibration(samples_default, mode="pooled", selection=plan.fit_on)
    source = {
        "dataset": str(sweep.root.resolve()),
        "results": str((sweep.root / ESTIMATES["paper"]).resolve()),
        "method": "paper",
        "seed": settings.seed,
    }
    default_source = {
        **source,
        "results": str((sweep.root / ESTIMATES[DEFAULT_METHOD]).resolve()),
        "method": DEFAULT_METHOD,
    }
    paths["calibration"] = out / "calibration.json"
    paths["calibration_per_diameter"] = out / "calibration-per-diameter.json"
    paths["calibration_default"] = out / f"calibration-{DEFAULT_METHOD}.json"
    save_sweep_calibration(pooled, paths["calibration"], source=source)
    save_sweep_calibration(per_d, paths["calibration_per_diameter"], source=source)
    save_sweep_calibration(cal_default, paths["calibration_default"], source=default_source)
    cubes: dict[str, CubeComparison | None] = {"paper": None, DEFAULT_METHOD: None}
    if data.cube is not None:
        paths["mocap"] = data.cube.root / "mocap.csv"
        write_simulated_mocap(data.cube, paths["mocap"])
        for method, cal in (("paper", pooled.pooled), (DEFAULT_METHOD, cal_default.pooled)):
            rows = _read_rows(data.cube.root / ESTIMATES[method])
            try:
                cubes[method] = compare_with_mocap(data.cube, rows, paths["mocap"], cal)
            except InputError as exc:  # every cube frame failed: say so in the report, do not crash
                stage(f"cube comparison ({method}) skipped: {exc}")
    default = DefaultMethodResult(
        method=DEFAULT_METHOD,
        samples=samples_default,
        calibration=cal_default,
        evaluation=evaluate_sweep(samples_default, cal_default.pooled, selection=plan.eval_on),
        cube=cubes[DEFAULT_METHOD],
    )
    return _Fitted(
        samples=samples,
        pooled=pooled,
        per_diameter=per_d,
        evaluation=evaluate_sweep(samples, pooled.pooled, selection=plan.eval_on),
        per_diameter_evaluation=evaluate_sweep(samples, per_d, selection=plan.eval_on),
        cube=cubes["paper"],
        default=default,
    )


def _methods_figures(fit: _Fitted, eval_on: str, fig_dir: Path, paths: dict[str, Path]) -> None:
    """The two methods side by side: RMSE bars, and the tilt angles over the sweep."""
    cube, dflt = fit.cube, fit.default
    cube_bars = []
    if cube is not None:
        cube_bars += [("paper, uncal.", cube.raw.rmse_deg), ("paper, calibrated", cube.calibrated.rmse_deg)]
    if dflt.cube is not None:
        cube_bars += [
            (f"{DEFAULT_METHOD}, uncal.", dflt.cube.raw.rmse_deg),
            (f"{DEFAULT_METHOD}, own cal.", dflt.cube.calibrated.rmse_deg),
        ]
    paths["methods"] = fig_dir / "methods.png"
    figures.methods_figure(
        [
            ("paper's method, calibrated", fit.evaluation.calibrated),
            (f"{DEFAULT_METHOD} (default), uncalibrated", dflt.evaluation.uncalibrated),
            (f"{DEFAULT_METHOD}, its own calibration", dflt.evaluation.calibrated),
        ],
        paths["methods"],
        cube_bars,
        title=f"RMSE of the tilt angles (deg), {eval_on} frames: the paper's method beside softjig's default",
    )
    paths["tilt_methods"] = fig_dir / "tilt_methods.png"
    figures.tilt_methods_figure(
        [
            ("paper, calibrated", fit.samples, fit.pooled.pooled),
            (f"{DEFAULT_METHOD}, uncalibrated", dflt.samples, None),
        ],
        paths["tilt_methods"],
        title="Tilt angles over the sweep: the paper's method (calibrated) and "
        f"{DEFAULT_METHOD} (uncalibrated)",
    )


def _paper_figures(fit: _Fitted, eval_on: str, fig_dir: Path, paths: dict[str, Path]) -> None:
    """The paper's method alone: tilt angles before and after calibration, its RMSE grid, the cube."""
    paths["tilt_before"] = fig_dir / "tilt_before.png"
    paths["tilt_after"] = fig_dir / "tilt_after.png"
    paths["rmse_grid"] = fig_dir / "rmse_grid.png"
    figures.tilt_sweep_figure(fit.samples, None, paths["tilt_before"])
    figures.tilt_sweep_figure(
        fit.samples,
        fit.pooled.pooled,
        paths["tilt_after"],
        title="Tilt angles after calibration (one Ox, Oy, S for all parts)",
    )
    figures.rmse_grid_figure(
        [
            (f"calibrated (pooled), {eval_on} frames", fit.evaluation.calibrated),
            (f"uncalibrated, {eval_on} frames", fit.evaluation.uncalibrated),
        ],
        paths["rmse_grid"],
        title="The paper's method: RMSE of the tilt angles against the commanded ones (deg)",
    )
    if fit.cube is not None:
        paths["cube_normals"] = fig_dir / "cube_normals.png"
        figures.normal_projection_figure(
            [("uncalibrated", fit.cube.raw_normals), ("calibrated", fit.cube.calibrated_normals)],
            fit.cube.truth_normals,
            paths["cube_normals"],
            index=fit.cube.index,
        )


def _cube_methods_figure(fit: _Fitted, fig_dir: Path, paths: dict[str, Path]) -> None:
    """The cube's normals of both methods against motion capture, on the frames both estimated."""
    cube, cube_default = fit.cube, fit.default.cube
    if cube is None or cube_default is None:
        return
    common = _common_cube_frames(cube, cube_default)
    if not len(common):
        return
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


def _example_pairs(
    data: _Estimated, plan: _Plan, fit: _Fitted, fig_dir: Path, paths: dict[str, Path]
) -> dict[str, int | None]:
    """Draw each method's example pair (the first candidate it estimated); their frame indices."""
    sweep = data.sweep
    pair_index = _stereo_pair_figure(
        sweep, plan.candidates, fit.samples.select(plan.eval_on), fig_dir / "stereo_pair.png"
    )
    if pair_index is not None:
        paths["stereo_pair"] = fig_dir / "stereo_pair.png"
    pair_default = _stereo_pair_figure(
        sweep,
        plan.candidates,
        fit.default.samples.select(plan.eval_on),
        fig_dir / f"stereo_pair_{DEFAULT_METHOD}.png",
        method=DEFAULT_METHOD,
        reference=dataset_reference(sweep, sweep.jig),
    )
    if pair_default is not None:
        paths["stereo_pair_default"] = fig_dir / f"stereo_pair_{DEFAULT_METHOD}.png"
    return {"paper": pair_index, DEFAULT_METHOD: pair_default}


def _delete_unused_candidates(
    plan: _Plan, settings: ExperimentSettings, sweep_root: Path, pairs: dict[str, int | None]
) -> None:
    """Once the example pairs are drawn, delete the other candidates' images (unless ``keep_data``)."""
    if settings.keep_data:
        return
    used = {k for k, spec in enumerate(plan.specs) if spec.part is None} | set(pairs.values())
    size = int(settings.chunk_frames)
    for c, first in enumerate(range(0, len(plan.specs), size)):
        local = {i - first for i in used if i is not None and first <= i < first + size}
        delete_frame_files(sweep_root / _chunk_name(c), local)


def _write_report(result: ExperimentResult, pairs: dict[str, int | None]) -> None:
    """Write ``report.md``, ``report.html`` and ``summary.json`` (their paths are in ``result.paths``)."""
    paths = result.paths
    markdown = report.experiment_report_markdown(result, stereo_pair_index=pairs["paper"])
    write_text_atomic(paths["report"], markdown)
    write_text_atomic(paths["report_html"], report.experiment_report_html(result, stereo_pairs=pairs))
    write_text_atomic(paths["summary"], json.dumps(report.experiment_summary(result), indent=2) + "\n")


def _rendered_disk_use(run: RunFolder) -> DiskUse:
    """What the run rendered over every resumption, from its manifest."""
    chunks = run.chunks()
    return DiskUse(
        sum(int(c.get("rendered_files", 0)) for c in chunks.values()),
        sum(int(c.get("rendered_bytes", 0)) for c in chunks.values()),
    )


@signals_unwrapped()  # a Ctrl-C inside a compiled kernel is a KeyboardInterrupt here too, resumable
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
    plan = _plan(settings)
    stage = on_stage or (lambda _text: None)
    t_start = time.perf_counter()
    timings: dict[str, float] = {}
    out = Path(settings.out_dir)
    fig_dir = out / "figures"
    jig = settings.jig or default_jig()
    run = RunFolder(out, settings.fingerprint(jig), overwrite=settings.overwrite)
    if run.resumed:
        done = sum(1 for c in run.chunks().values() if c.get("done"))
        stage(f"resuming the unfinished run in {out}: {done} chunks already done")

    t0 = time.perf_counter()
    data = _simulate_and_estimate(plan, jig, settings, run, stage)
    timings["simulate_estimate"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    paths: dict[str, Path] = {}
    fit = _calibrate_and_evaluate(data, plan, settings, paths, stage)
    timings["calibrate_evaluate"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    stage("drawing the figures and writing the report")
    _methods_figures(fit, plan.eval_on, fig_dir, paths)
    _paper_figures(fit, plan.eval_on, fig_dir, paths)
    _cube_methods_figure(fit, fig_dir, paths)
    pairs = _example_pairs(data, plan, fit, fig_dir, paths)
    _delete_unused_candidates(plan, settings, data.sweep.root, pairs)
    timings["figures"] = time.perf_counter() - t0

    samples = fit.samples
    failed = tuple((int(i), e) for i, e in zip(samples.failed_index, samples.failed_errors, strict=True))
    paths["report"], paths["summary"] = out / "report.md", out / "summary.json"
    paths["report_html"] = out / "report.html"
    timings["total"] = time.perf_counter() - t_start
    result = ExperimentResult(
        settings=settings,
        samples=samples,
        calibration=fit.pooled,
        per_diameter=fit.per_diameter,
        evaluation=fit.evaluation,
        per_diameter_evaluation=fit.per_diameter_evaluation,
        cube=fit.cube,
        timings_s=timings,
        paths=paths,
        failed_examples=failed[:FAILED_EXAMPLES],
        default_method=fit.default,
        rendered=_rendered_disk_use(run),
        resumed=run.resumed,
        chunks_now=data.chunks_now,
    )
    _write_report(result, pairs)
    run.finish()
    return replace(result, disk=disk_use(out))
