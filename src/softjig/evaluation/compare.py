"""The paper's method and ours side by side on one tilt sweep, on frames no calibration saw.

Both methods estimate every frame of the dataset. The paper's method is calibrated (pooled ``Ox, Oy, S``)
on the even steps of ``theta`` and evaluated on the odd ones, as ``softjig demo`` does; ours (the
refractive method, indentations against the dataset's unloaded reference frame) is evaluated on the same
odd frames uncalibrated, and calibrated the same way. On the same frames, ours also reports how often the
true tilt error lies within its 1-sigma (``coverage``: about 68 % expected), and how far the contact's
centroid lies from the part's true centre on the jig (the part's position).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from softjig.calibration.sweep import fit_sweep_calibration, sweep_samples
from softjig.calibration.tilt import TiltCalibration
from softjig.evaluation.metrics import RmseGrid, commanded_tilt_angles_deg
from softjig.evaluation.tilt_sweep import evaluate_sweep
from softjig.io.dataset import Dataset
from softjig.sensing.batch import BatchSettings, dataset_reference, estimate_dataset


@dataclass(frozen=True)
class MethodComparison:
    """RMSE grids (deg) on the held-out (odd-theta) frames, and ours' uncertainty and position figures.

    Attributes
    ----------
    paper_calibrated : the paper's method, calibrated on the even-theta frames.
    ours_uncalibrated, ours_calibrated : the refractive method, without and with the same calibration.
    ours_calibration : the paper's ``(Ox, Oy, S)`` fitted to ours on the even-theta frames: a sensor that
        needs no calibration has ``S = 1`` and ``O = 0``.
    coverage_x, coverage_y : share of loaded frames whose |Ax| / |Ay| error is within ours' 1-sigma.
    position_rms_mm : RMS distance between ours' contact centroid and the part's true centre (mm).
    n_frames : held-out frames; ``n_failed_paper``, ``n_failed_ours``: sweep frames without an estimate.
    """

    paper_calibrated: RmseGrid
    ours_uncalibrated: RmseGrid
    ours_calibrated: RmseGrid
    ours_calibration: TiltCalibration
    coverage_x: float
    coverage_y: float
    position_rms_mm: float
    n_frames: int
    n_failed_paper: int
    n_failed_ours: int


def compare_methods(
    dataset: Dataset, *, workers: int | None = None, on_row: Callable[[dict], None] | None = None
) -> MethodComparison:
    """Estimate a sweep dataset with both methods and compare them on its odd-theta frames."""
    jig = dataset.jig
    frames = list(dataset)
    paper_rows = list(
        estimate_dataset(dataset, BatchSettings(jig=jig, method="paper"), workers=workers, on_row=on_row)
    )
    reference = dataset_reference(dataset, jig)
    ours_rows = list(
        estimate_dataset(
            dataset,
            BatchSettings(jig=jig, method="refractive", reference=reference),
            workers=workers,
            on_row=on_row,
        )
    )
    paper = sweep_samples(frames, paper_rows)
    ours = sweep_samples(frames, ours_rows)
    paper_grid = evaluate_sweep(paper, fit_sweep_calibration(paper, selection="even").pooled, selection="odd")
    ours_cal = fit_sweep_calibration(ours, selection="even").pooled
    ours_grid = evaluate_sweep(ours, ours_cal, selection="odd")  # both grids: calibrated and raw
    coverage_x, coverage_y, position = _uncertainty_and_position(frames, ours_rows)
    return MethodComparison(
        paper_calibrated=paper_grid.calibrated,
        ours_uncalibrated=ours_grid.uncalibrated,
        ours_calibrated=ours_grid.calibrated,
        ours_calibration=ours_cal,
        coverage_x=coverage_x,
        coverage_y=coverage_y,
        position_rms_mm=position,
        n_frames=ours_grid.n_frames,
        n_failed_paper=paper.n_failed,
        n_failed_ours=ours.n_failed,
    )


def _uncertainty_and_position(frames: list, rows: list[dict]) -> tuple[float, float, float]:
    """Coverage of the 1-sigma tilt errors and RMS position error, over every loaded frame estimated."""
    by_index = {row["index"]: row for row in rows}
    inside_x, inside_y, distances = [], [], []
    for frame in frames:
        row = by_index.get(frame.index, {})
        if frame.reference or "tilt_sigma_x_deg" not in row or frame.alpha_deg is None:
            continue
        cmd_x, cmd_y = commanded_tilt_angles_deg(np.array([frame.alpha_deg]), np.array([frame.theta_deg]))
        inside_x.append(abs(row["raw_tilt_x_deg"] - cmd_x[0]) <= row["tilt_sigma_x_deg"])
        inside_y.append(abs(row["raw_tilt_y_deg"] - cmd_y[0]) <= row["tilt_sigma_y_deg"])
        if frame.truth is not None and frame.truth.T_J_part is not None:
            centre = np.asarray(frame.truth.T_J_part)[:2, 3]
            distances.append(float(np.hypot(*(np.asarray(row["contact_centroid_xy_mm"]) - centre))))

    def mean(values: list) -> float:
        return float(np.mean(values)) if values else float("nan")

    return (
        mean(inside_x),
        mean(inside_y),
        float(np.sqrt(np.mean(np.square(distances)))) if distances else float("nan"),
    )
