"""The paper's experiment on the simulated jig: its settings, its results, and the motion-capture comparison.

:func:`softjig.experiments.paper.run_experiment` runs it (simulate, estimate, calibrate, evaluate, report;
its module docstring has the steps and the run folder's layout); this module holds what it is configured
with (:class:`ExperimentSettings`) and what it returns (:class:`ExperimentResult`), which the report
renders (:mod:`softjig.evaluation.report`), and the pure pieces: which frames the report needs
(:func:`frames_to_keep`) and the cube's estimates against motion capture (:func:`compare_with_mocap`,
:func:`write_simulated_mocap`).
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from softjig.calibration.sweep import (
    SweepCalibration,
    SweepSamples,
    alternate_theta_mask,
)
from softjig.calibration.tilt import TiltCalibration
from softjig.config import JigConfig
from softjig.errors import InputError
from softjig.evaluation.metrics import TiltErrorSummary, tilt_error_summary
from softjig.evaluation.mocap import normals_at, read_motive_csv, write_motive_csv
from softjig.evaluation.run_folder import DiskUse
from softjig.evaluation.tilt_sweep import SweepEvaluation
from softjig.geometry import normal_from_tilt_angles, pose_from_rotation_translation

__all__ = [
    "SPLITS",
    "CubeComparison",
    "DefaultMethodResult",
    "ExperimentResult",
    "ExperimentSettings",
    "compare_with_mocap",
    "frames_to_keep",
    "quick_settings",
    "write_simulated_mocap",
]

SPLITS = ("alternate", "none")
JIG_BODY, CUBE_BODY = "SoftJig", "Cube"
DEFAULT_METHOD = "refractive"  # softjig's default (softjig.sensing.pipeline.DEFAULT_METHOD)
#: The estimate files of each method in a dataset folder.
ESTIMATES = {"paper": "estimates.jsonl", DEFAULT_METHOD: f"estimates-{DEFAULT_METHOD}.jsonl"}


@dataclass(frozen=True)
class ExperimentSettings:
    """What :func:`softjig.experiments.paper.run_experiment` does.

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
    """What :func:`softjig.experiments.paper.run_experiment` found and wrote.

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


#: The example pair the report draws: the loaded frame nearest to this part diameter (mm), tilt and tilt
#: direction (deg), a mid-size part at a moderate tilt; the weights (per mm, per deg of alpha, per deg of
#: theta) rank the diameter first, then the tilt, then the direction.
EXAMPLE_DIAMETER_MM, EXAMPLE_ALPHA_DEG, EXAMPLE_THETA_DEG = 50.0, 10.0, 30.0
EXAMPLE_WEIGHTS = (10.0, 5.0, 1.0)


def frames_to_keep(specs: list, selection: str, *, n_candidates: int = 5) -> tuple[set[int], list[int]]:
    """Frames whose images the report needs, by spec number: the unloaded reference frames, and the
    ``n_candidates`` candidates for the example pair (nearest to :data:`EXAMPLE_DIAMETER_MM`,
    :data:`EXAMPLE_ALPHA_DEG`, :data:`EXAMPLE_THETA_DEG`), best first, among ``selection``."""
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
    w_d, w_a, w_t = EXAMPLE_WEIGHTS
    theta_off = np.abs(np.mod(t - EXAMPLE_THETA_DEG + 180.0, 360.0) - 180.0)
    score = w_d * np.abs(d - EXAMPLE_DIAMETER_MM) + w_a * np.abs(a - EXAMPLE_ALPHA_DEG) + w_t * theta_off
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
