"""The paper's method and ours side by side on one tilt sweep, on frames no calibration saw.

Both methods estimate every frame of the dataset. The paper's method is calibrated (pooled ``Ox, Oy, S``)
on the even steps of ``theta`` and evaluated on the odd ones, as ``softjig demo`` does; ours (the
refractive method, indentations against the dataset's unloaded reference frame) is evaluated on the same
odd frames uncalibrated, and calibrated the same way. On the same frames, ours also reports how often the
true tilt error lies within its 1-sigma (``coverage``: about 68 % expected), how far its contact's
centroid lies from the true contact's, and how far its estimate of the part's centre lies from the
truth (the part's position; in partial contact the contact's centroid is not the part's centre).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from softjig.calibration.sweep import check_sweep_design, fit_sweep_calibration, sweep_design, sweep_samples
from softjig.calibration.tilt import TiltCalibration
from softjig.evaluation.metrics import RmseGrid, commanded_tilt_angles_deg
from softjig.evaluation.tilt_sweep import evaluate_sweep
from softjig.geometry import fit_plane_svd
from softjig.io.batch import BatchSettings, dataset_reference, estimate_dataset
from softjig.io.dataset import Dataset
from softjig.sensing.contact import describe_contact


@dataclass(frozen=True)
class MethodComparison:
    """RMSE grids (deg) on the held-out (odd-theta) frames, and ours' uncertainty and position figures.

    Attributes
    ----------
    paper_calibrated : the paper's method, calibrated on the even-theta frames.
    ours_uncalibrated, ours_calibrated : the refractive method, without and with the same calibration.
    ours_without_part_size : the refractive method uncalibrated, not told the part's size: the contact is
        found from the indentations alone.
    ours_calibration : the paper's ``(Ox, Oy, S)`` fitted to ours on the even-theta frames: a sensor that
        needs no calibration has ``S = 1`` and ``O = 0``.
    coverage_x, coverage_y : share of loaded frames whose |Ax| / |Ay| error is within ours' 1-sigma.
    contact_centroid_rms_mm : RMS distance between ours' contact centroid and the true contact's (mm).
    contact_to_part_centre_rms_mm : RMS distance between ours' contact centroid and the part's true
        centre (mm): in partial contact the contact lies on the lowered side, away from the centre.
    part_centre_rms_mm : RMS distance between ours' estimate of the part's centre (the part's size is
        known in a sweep) and the truth (mm).
    n_frames : held-out frames; ``n_failed_paper``, ``n_failed_ours``: sweep frames without an estimate.
    """

    paper_calibrated: RmseGrid
    ours_uncalibrated: RmseGrid
    ours_calibrated: RmseGrid
    ours_calibration: TiltCalibration
    ours_without_part_size: RmseGrid
    coverage_x: float
    coverage_y: float
    contact_centroid_rms_mm: float
    contact_to_part_centre_rms_mm: float
    part_centre_rms_mm: float
    n_frames: int
    n_failed_paper: int
    n_failed_ours: int
    n_failed_ours_without_part_size: int


def compare_methods(
    dataset: Dataset, *, workers: int | None = None, on_row: Callable[[dict], None] | None = None
) -> MethodComparison:
    """Estimate a sweep dataset with both methods (ours with and without the part's size) and compare them
    on its odd-theta frames."""
    jig = dataset.jig
    frames = list(dataset)
    # Both calibrations are fitted on the even theta steps: refuse a sweep too coarse for that before
    # estimating it three times.
    check_sweep_design(*sweep_design(frames), selection="even")
    check_sweep_design(*sweep_design(frames), selection="odd")
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
    auto_rows = list(
        estimate_dataset(
            dataset,
            BatchSettings(jig=jig, method="refractive", reference=reference, frame_part_size=False),
            workers=workers,
            on_row=on_row,
        )
    )
    paper = sweep_samples(frames, paper_rows)
    ours = sweep_samples(frames, ours_rows)
    auto = sweep_samples(frames, auto_rows)
    paper_grid = evaluate_sweep(paper, fit_sweep_calibration(paper, selection="even").pooled, selection="odd")
    ours_cal = fit_sweep_calibration(ours, selection="even").pooled
    ours_grid = evaluate_sweep(ours, ours_cal, selection="odd")  # both grids: calibrated and raw
    coverage_x, coverage_y, to_centre, to_contact, part = _uncertainty_and_position(frames, ours_rows, jig)
    return MethodComparison(
        paper_calibrated=paper_grid.calibrated,
        ours_uncalibrated=ours_grid.uncalibrated,
        ours_calibrated=ours_grid.calibrated,
        ours_calibration=ours_cal,
        ours_without_part_size=evaluate_sweep(auto, None, selection="odd").uncalibrated,
        coverage_x=coverage_x,
        coverage_y=coverage_y,
        contact_to_part_centre_rms_mm=to_centre,
        contact_centroid_rms_mm=to_contact,
        part_centre_rms_mm=part,
        n_frames=ours_grid.n_frames,
        n_failed_paper=paper.n_failed,
        n_failed_ours=ours.n_failed,
        n_failed_ours_without_part_size=auto.n_failed,
    )


def _uncertainty_and_position(
    frames: list, rows: list[dict], jig
) -> tuple[float, float, float, float, float]:
    """Coverage of the 1-sigma tilt errors, and RMS position errors (mm) over every loaded frame estimated:
    the contact's centroid against the part's centre and against the true contact's centroid, and the
    part's centre (when the rows have one) against the truth."""
    by_index = {row["index"]: row for row in rows}
    inside_x, inside_y, to_centre, to_contact, part = [], [], [], [], []
    for frame in frames:
        row = by_index.get(frame.index, {})
        if frame.reference or "tilt_sigma_x_deg" not in row or frame.alpha_deg is None:
            continue
        cmd_x, cmd_y = commanded_tilt_angles_deg(np.array([frame.alpha_deg]), np.array([frame.theta_deg]))
        inside_x.append(abs(row["raw_tilt_x_deg"] - cmd_x[0]) <= row["tilt_sigma_x_deg"])
        inside_y.append(abs(row["raw_tilt_y_deg"] - cmd_y[0]) <= row["tilt_sigma_y_deg"])
        if frame.truth is None or frame.truth.T_J_part is None:
            continue
        centroid = np.asarray(row["contact_centroid_xy_mm"])
        centre = np.asarray(frame.truth.T_J_part)[:2, 3]
        to_centre.append(float(np.hypot(*(centroid - centre))))
        if row.get("part_centre_xy_mm") is not None:
            part.append(float(np.hypot(*(np.asarray(row["part_centre_xy_mm"]) - centre))))
        if frame.truth.markers is not None:
            true_contact = _true_contact_centroid(frame, jig)
            if true_contact is not None:
                to_contact.append(float(np.hypot(*(centroid - true_contact))))

    def mean(values: list) -> float:
        return float(np.mean(values)) if values else float("nan")

    def rms(values: list) -> float:
        return float(np.sqrt(np.mean(np.square(values)))) if values else float("nan")

    return mean(inside_x), mean(inside_y), rms(to_centre), rms(to_contact), rms(part)


def _true_contact_centroid(frame, jig) -> np.ndarray | None:
    """The centroid of the true contact's footprint, drawn as ours is (:func:`describe_contact` on the
    markers the simulator put in contact, at their true positions)."""
    truth = frame.load_truth_markers()
    contact = np.asarray(truth["in_contact"], dtype=bool)
    if contact.sum() < 3:
        return None
    xyz = np.asarray(truth["xyz_mm"])[contact]
    region = describe_contact(xyz[:, :2], fit_plane_svd(xyz), jig, noise_mm=0.0)
    return np.asarray(region.centroid_xy_mm)
