"""The estimator's stages as small protocols, and the standard implementation of each.

An :class:`~softjig.sensing.estimator.Estimator` runs, per stereo pair: a :class:`MarkerDetector` on each
image, a :class:`FrameFinder` (the cameras' pose in J), a :class:`Matcher` (stereo correspondences), a
:class:`Triangulator` (matched pixels to points in J) and a :class:`PlaneFitter` (which markers the part
touches, and their plane). ``"paper"`` and ``"refractive"`` are two compositions of them
(:data:`softjig.sensing.estimator.METHODS`). Each stage is built once from the
:class:`~softjig.sensing.setup.JigModel` and keeps what it needs of it.

A new marker detector is one class with a ``from_model(model)`` constructor and a ``detect`` method,
named in :data:`DETECTORS`; a jig selects it with ``sensing.detector`` (docs/jig-config.md).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from types import MappingProxyType
from typing import TYPE_CHECKING, Protocol

import numpy as np

from softjig.errors import ConfigError
from softjig.geometry import transform_points
from softjig.sensing.detect import Markers, detect_markers
from softjig.sensing.jigframe import FiducialMemory, JigFrame, inside_fiducials, resolve_jig_frame
from softjig.sensing.refractive import triangulate_refracted
from softjig.sensing.setup import JigModel, pinhole_triangulation
from softjig.sensing.stereo import StereoMatches, match_rectified
from softjig.sensing.subpixel import kernel_tables

if TYPE_CHECKING:
    from softjig.sensing.results import Observation, Refusal, SensingResult

__all__ = [
    "DETECTORS",
    "FiducialFrameFinder",
    "FrameFinder",
    "LogDetector",
    "MarkerDetector",
    "Matcher",
    "PinholeTriangulator",
    "PlaneFitter",
    "RefractedTriangulator",
    "RowMatcher",
    "Triangulator",
    "detector_for",
]

#: ``xy (N, 2) px -> (N,) bool``: which candidate centres to drop before the sub-pixel fit.
Exclusion = Callable[[np.ndarray], np.ndarray]


class MarkerDetector(Protocol):
    """Finds the membrane's markers in one gray image (rectified, ``uint8``/``uint16``/float)."""

    def detect(self, gray: np.ndarray, exclude: Exclusion | None = None) -> Markers:
        """The markers (px), none where ``exclude`` says (the fiducials)."""
        ...


class FrameFinder(Protocol):
    """Finds both cameras' poses in J for one pair of 8-bit gray images."""

    def find(self, left_u8: np.ndarray, right_u8: np.ndarray) -> tuple[JigFrame, list[str]]:
        """The frame and any warning to report (e.g. fiducials not found, the config's poses used)."""
        ...


class Matcher(Protocol):
    """Stereo correspondences between the markers of the left and right rectified images."""

    def match(self, left: Markers, right: Markers) -> StereoMatches:
        """One-to-one matches (indices into ``left`` and ``right``)."""
        ...


class Triangulator(Protocol):
    """Matched rectified pixels to points in J."""

    def triangulate(self, left_xy_px: np.ndarray, right_xy_px: np.ndarray, frame: JigFrame) -> np.ndarray:
        """(M, 3) points in J (mm), one per match."""
        ...


class PlaneFitter(Protocol):
    """Which markers the part touches, their plane, and the estimate made from them."""

    def fit(
        self, observation: Observation, points_J: np.ndarray, part_diameter_mm: float | None
    ) -> SensingResult | Refusal:
        """The result, or a :class:`~softjig.sensing.results.Refusal` saying why there is none."""
        ...


class LogDetector:
    """The LoG detector at the scale of a marker at the membrane's apex, refined by the marker model's
    fit (:func:`~softjig.sensing.detect.detect_markers`, :mod:`softjig.sensing.subpixel`).

    Parameters
    ----------
    sigma_px, threshold, candidates, refine, model : as :func:`~softjig.sensing.detect.detect_markers`
        takes them (``threshold=None``: its default).
    tables : the model fit's tables of ``model`` (:func:`~softjig.sensing.subpixel.kernel_tables`; read
        here, from disk, when not given).
    """

    def __init__(
        self, *, sigma_px: float, threshold: float | None, candidates: str, refine, model, tables=None
    ) -> None:
        self._kwargs = {"sigma_px": sigma_px, "candidates": candidates, "refine": refine}
        if threshold is not None:
            self._kwargs["threshold"] = threshold
        if model is not None:
            self._kwargs["model"] = model
            if refine == "model":  # the model fit's weight tables, read once
                self._kwargs["tables"] = tables if tables is not None else kernel_tables(model)

    @classmethod
    def from_model(cls, model: JigModel, *, candidates: str | None = None) -> LogDetector:
        """The jig's detector (``candidates``: ``"pyramid"`` or ``"full"``; the setup's when ``None``)."""
        setup = model.setup
        return cls(
            sigma_px=setup.sigma_px,
            threshold=setup.threshold,
            candidates=candidates or setup.candidates,
            refine=setup.refine,
            model=setup.marker,
            tables=model.marker_tables,
        )

    def detect(self, gray: np.ndarray, exclude: Exclusion | None = None) -> Markers:
        return detect_markers(gray, exclude=exclude, **self._kwargs)


#: The marker detectors a jig may name in ``sensing.detector``: name -> class with ``from_model``.
DETECTORS: Mapping[str, type] = MappingProxyType({"log": LogDetector})


def detector_for(model: JigModel) -> MarkerDetector:
    """The detector the jig's ``sensing.detector`` names.

    Raises
    ------
    ConfigError
        It names no detector of :data:`DETECTORS`.
    """
    name = model.jig.sensing.detector
    if name not in DETECTORS:
        raise ConfigError(
            f"sensing.detector = {name!r} is not a known marker detector; known: "
            f"{', '.join(sorted(DETECTORS))}"
        )
    return DETECTORS[name].from_model(model)


class FiducialFrameFinder:
    """The cameras' pose as ``sensing.extrinsics`` asks (:func:`~softjig.sensing.jigframe.resolve_jig_frame`),
    remembering where the general path found the fiducials for the next frames (its own
    :class:`~softjig.sensing.jigframe.FiducialMemory`); ``fallback`` is the frame used when the fiducials
    are not found (default: the config's; an estimator with a levelled reference passes a function making
    its levelled frame, called when a frame first needs it: frames that find their fiducials never do).
    """

    def __init__(self, model: JigModel, fallback: JigFrame | Callable[[], JigFrame] | None = None) -> None:
        self._jig = model.jig
        self._constants = model.frame
        self._memory = FiducialMemory()
        self._fallback = fallback

    def find(self, left_u8: np.ndarray, right_u8: np.ndarray) -> tuple[JigFrame, list[str]]:
        return resolve_jig_frame(
            left_u8,
            right_u8,
            self._jig,
            constants=self._constants,
            memory=self._memory,
            fallback=self._fallback_frame if self._fallback is not None else None,
        )

    def _fallback_frame(self) -> JigFrame:
        """The fallback frame, made by its function the first time it is needed, then kept."""
        if callable(self._fallback):
            self._fallback = self._fallback()
        return self._fallback


class RowMatcher:
    """Markers matched along rows within ``sensing.row_tolerance_px`` and the jig's disparity window, as
    a one-to-one global assignment (:func:`~softjig.sensing.stereo.match_rectified`)."""

    def __init__(self, model: JigModel) -> None:
        self._kwargs = {
            "row_tolerance_px": model.jig.sensing.row_tolerance_px,
            "min_disparity_px": model.setup.min_disparity_px,
            "max_disparity_px": model.setup.max_disparity_px,
        }

    def match(self, left: Markers, right: Markers) -> StereoMatches:
        return match_rectified(left.xy_px, right.xy_px, **self._kwargs)


class PinholeTriangulator:
    """The paper's triangulation: as if the cameras looked through air (depths compressed by about the
    oil's index), in the left camera's frame, then into J."""

    def __init__(self, model: JigModel) -> None:
        self._jig = model.jig

    def triangulate(self, left_xy_px: np.ndarray, right_xy_px: np.ndarray, frame: JigFrame) -> np.ndarray:
        if len(left_xy_px) == 0:
            return np.zeros((0, 3))
        return transform_points(frame.T_J_left, pinhole_triangulation(left_xy_px, right_xy_px, self._jig))


class RefractedTriangulator:
    """Each marker's two rays refracted through the plate and the oil by Snell's law, intersected
    (:func:`~softjig.sensing.refractive.triangulate_refracted`): metric depths."""

    def __init__(self, model: JigModel) -> None:
        self._jig = model.jig
        self._constants = model.triangulation

    def triangulate(self, left_xy_px: np.ndarray, right_xy_px: np.ndarray, frame: JigFrame) -> np.ndarray:
        return triangulate_refracted(
            left_xy_px, right_xy_px, self._jig, frame, constants=self._constants
        ).points_J


def on_fiducials(quads_px: np.ndarray) -> Exclusion:
    """``xy -> bool mask``: which points lie on a fiducial (its black and white cells look like blobs to
    the LoG), for a detector's ``exclude``: they are dropped before the sub-pixel fit."""
    return lambda xy: inside_fiducials(xy, quads_px)
