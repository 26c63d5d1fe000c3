"""Straightforward stages of the estimator, to compose into an :class:`~softjig.sensing.estimator.Estimator`
beside the standard ones (:mod:`softjig.sensing.stages`): full-resolution LoG candidates, the general
ArUco path for the jig frame, the matching's definition as one dense assignment, rays traced interface by
interface. Used by the agreement tests and ``benchmarks/bench_agreement.py``."""

from __future__ import annotations

import numpy as np

from oracles.jigframe import jig_frame
from oracles.refracted_rays import traced_triangulation
from oracles.stereo_assignment import dense_assignment
from softjig.sensing.estimator import Estimator
from softjig.sensing.stages import LogDetector
from softjig.sensing.stereo import StereoMatches


class FullArucoFrameFinder:
    """The straightforward jig frame: ArUco's detector on the whole images, SciPy's least squares
    (:func:`oracles.jigframe.jig_frame`)."""

    def __init__(self, jig):
        self.jig = jig

    def find(self, left_u8, right_u8):
        return jig_frame(left_u8, right_u8, self.jig), []


class DenseMatcher:
    """The matching's definition: one dense max-cardinality min-cost assignment."""

    def __init__(self, model):
        setup = model.setup
        self.args = (model.jig.sensing.row_tolerance_px, setup.min_disparity_px, setup.max_disparity_px)

    def match(self, left, right):
        li, rj, _ = dense_assignment(left.xy_px, right.xy_px, *self.args)
        lx, rx = left.xy_px[li], right.xy_px[rj]
        return StereoMatches(li, rj, lx[:, 1] - rx[:, 1], lx[:, 0] - rx[:, 0])


class TracedTriangulator:
    """Each ray traced interface by interface through the layers."""

    def __init__(self, jig):
        self.jig = jig

    def triangulate(self, left_xy_px, right_xy_px, frame):
        if len(left_xy_px) == 0:
            return np.zeros((0, 3))
        return traced_triangulation(left_xy_px, right_xy_px, self.jig, frame).points_J


def straightforward_estimator(standard: Estimator) -> Estimator:
    """An estimator of ``standard``'s jig, method and reference whose front end and triangulation are the
    straightforward stages (its plane fitter is the same: it has one implementation)."""
    model = standard.model
    return Estimator(
        model.raw_jig,
        method=standard.method,
        reference=standard.reference.markers if standard.reference.scatter_mm is not None else None,
        calibration=standard.calibration,
        model=model,
        detector=LogDetector.from_model(model, candidates="full"),
        frame_finder=FullArucoFrameFinder(model.jig),
        matcher=DenseMatcher(model),
        triangulator=TracedTriangulator(model.jig) if standard.method == "refractive" else None,
    )
