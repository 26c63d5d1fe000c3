"""The estimator: built once from a jig and a method, it turns stereo pairs into estimates.

An :class:`Estimator` owns everything derived from the jig (:class:`~softjig.sensing.setup.JigModel`:
the rectification, the layers, the detection scale and marker model, the fiducials' expected places, the
triangulation's constants, the rest shape) and from the reference frame
(:class:`~softjig.sensing.setup.ReferenceModel`), and runs the stages of :mod:`softjig.sensing.stages`
on each pair: detect, frame, match, triangulate, contact and plane. A method is a composition of them
(:data:`COMPOSITIONS`): ``"paper"`` triangulates as through air and fits the crop under the part's base,
``"refractive"`` triangulates through the layers and fits the contact found from the indentation.

Build one per jig and reuse it for every frame. Building one reads what the jig's model derives by
projecting the jig from the disk cache (:meth:`~softjig.sensing.setup.JigModel.build`), a fraction of a
frame's work; the first build of a jig by a version of the code derives it, about a frame's work. Nothing
is kept in memory on the side: two estimators of one jig share no object, and an estimator's only state
that changes is where its frame finder last found the fiducials (which only saves time).
"""

from __future__ import annotations

import functools
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, replace
from types import MappingProxyType

import numpy as np

from softjig.config import JigConfig
from softjig.errors import EstimationError, InputError
from softjig.sensing.contact import markers_at_rest, off_the_rest_membrane
from softjig.sensing.detect import (
    Markers,
    check_image_content,
    gray_image,
    packed_bit_depth,
    unpack_bit_depth,
)
from softjig.sensing.fiducials import gray_to_u8
from softjig.sensing.fitting import ContactPlaneFitter, PaperPlaneFitter
from softjig.sensing.identities import ReferenceMarkers
from softjig.sensing.jigframe import JigFrame, levelled_frame
from softjig.sensing.levelling import (
    AmbiguousLevel,
    HeadLevel,
    HeadPrior,
    from_fiducials,
    improves_on_the_config,
    level_head,
)
from softjig.sensing.rectify import rectify_images
from softjig.sensing.results import Observation, Refusal, SensingResult
from softjig.sensing.setup import JigModel, ReferenceModel
from softjig.sensing.stages import (
    FiducialFrameFinder,
    FrameFinder,
    MarkerDetector,
    Matcher,
    PinholeTriangulator,
    PlaneFitter,
    RefractedTriangulator,
    RowMatcher,
    Triangulator,
    detector_for,
    on_fiducials,
)
from softjig.sensing.stereo import StereoMatches
from softjig.tilt_calibration import TiltCalibration

# The best we have (DESIGN.md): on the paper's simulated sweep, uncalibrated, it beats the paper's method
# calibrated in most cells (`softjig compare`). `--method paper` keeps the published method exactly.
DEFAULT_METHOD = "refractive"
# Few matches: fewer than this share of the markers of the image with fewer are matched (a warning) ...
MIN_MATCHED_SHARE = 0.5
# ... and the images are refused as swapped when the markers matched with the images exchanged are at
# least this share of them ...
SWAPPED_MATCH_SHARE = 0.5
# ... and this many times the markers matched as given (a rectified pair's disparities are all positive).
SWAPPED_MATCH_FACTOR = 2.0
#: A head level measured on a loaded frame's markers at rest is used only where it tilts the head by no
#: more than this many of the head's mounting tolerances (``tolerances.camera_rotation_deg``, one sigma per
#: axis: a head tilted further is 1 in 90): beyond, it is rather the drape of a large dent over the
#: markers taken as at rest (zoo: levels of 1.6-1.8 deg beside 56-88 mm parts, 2.2-3.3 deg off after).
LOADED_LEVEL_TOLERANCES = 3.0


@dataclass(frozen=True)
class Composition:
    """A method: how its points are triangulated and its plane fitted (the front end is shared).

    Attributes
    ----------
    triangulator : ``model -> Triangulator``.
    fitter : ``(model, reference, calibration) -> PlaneFitter``.
    needs_part_size : whether the method needs the part's base diameter.
    uses_reference : whether the method measures against a reference frame (and takes the camera poses
        its reference levelled: :mod:`softjig.sensing.levelling`).
    """

    triangulator: Callable[[JigModel], Triangulator]
    fitter: Callable[[JigModel, ReferenceModel, TiltCalibration | None], PlaneFitter]
    needs_part_size: bool
    uses_reference: bool


COMPOSITIONS: Mapping[str, Composition] = MappingProxyType(
    {
        "refractive": Composition(
            RefractedTriangulator, ContactPlaneFitter, needs_part_size=False, uses_reference=True
        ),
        "paper": Composition(
            PinholeTriangulator,
            lambda model, _, calibration: PaperPlaneFitter(model, calibration),
            needs_part_size=True,
            uses_reference=False,
        ),
    }
)
METHODS = tuple(COMPOSITIONS)


class Estimator:
    """Estimates the principal normal of the part on one jig, pair after pair.

    Parameters
    ----------
    jig : the nominal jig (the estimator never knows the as-built one); raw (unrectified) cameras are
        rectified once here, and each pair with them.
    method : ``"refractive"`` (the default: ours) or ``"paper"`` (exactly as published).
    reference : the unloaded jig's markers (:meth:`reference_from_pair`), for ``"refractive"``; the
        nominal rest shape when ``None``. When it measured the head's pose (``reference.head_level``),
        frames without fiducials use it (``frame_source`` ``"membrane"`` or ``"reference fiducials"``).
        Without a reference (the refractive method, ``sensing.extrinsics = "auto"``, no calibration), a
        frame without fiducials levels the head on its own markers at rest (``"membrane at rest"``).
    calibration : the paper's tilt calibration to apply, if any (fitted to this method's estimates).
    model : the :class:`JigModel` of ``jig`` when already built (another estimator's ``model``).
    detector, frame_finder, matcher, triangulator : stages to use instead of the jig's and the method's
        (e.g. the straightforward implementations the tests check the standard ones against).

    Raises
    ------
    InputError
        An unknown method, or a calibration fitted to another method.
    ConfigError
        The jig names an unknown detector, or its raw cameras cannot be rectified.
    """

    def __init__(
        self,
        jig: JigConfig,
        *,
        method: str = DEFAULT_METHOD,
        reference: ReferenceMarkers | None = None,
        calibration: TiltCalibration | None = None,
        model: JigModel | None = None,
        detector: MarkerDetector | None = None,
        frame_finder: FrameFinder | None = None,
        matcher: Matcher | None = None,
        triangulator: Triangulator | None = None,
    ) -> None:
        if method not in COMPOSITIONS:
            raise InputError(f"unknown method {method!r}; valid: {', '.join(METHODS)}")
        if calibration is not None and calibration.method not in (None, method):
            raise InputError(
                f"the tilt calibration was fitted to the {calibration.method} method's estimates and does "
                f"not apply to the {method} method's: estimate with --method {calibration.method}, or "
                f"calibrate again with --method {method}"
            )
        self.model = model if model is not None else JigModel.build(jig)
        self.method = method
        self.calibration = calibration
        composition = COMPOSITIONS[method]
        self.needs_part_size = composition.needs_part_size
        used = self.model.jig
        self.reference = (
            self.model.rest_reference if reference is None else ReferenceModel.build(reference, used)
        )
        levels = reference is not None and composition.uses_reference
        # Without a reference frame, a frame that finds no fiducials levels the head on its own markers
        # at rest (a tilt calibration was fitted to the estimates made with the config's poses).
        self._levels_each_frame = (
            reference is None
            and composition.uses_reference
            and calibration is None
            and self.model.jig.sensing.extrinsics == "auto"
        )
        self.head_level = reference.head_level if levels else None
        self._level_note = reference.level_note if levels else None
        fallback = (  # the levelled frame, made only if a frame does not find its fiducials
            None
            if self.head_level is None
            else functools.partial(
                levelled_frame,
                used,
                self.model.frame.config_frame,
                self.head_level.T_correction,
                self.head_level.source,
            )
        )
        self.detector = detector if detector is not None else detector_for(self.model)
        self.frame_finder = (
            frame_finder if frame_finder is not None else FiducialFrameFinder(self.model, fallback)
        )
        self.matcher = matcher if matcher is not None else RowMatcher(self.model)
        self.triangulator = triangulator if triangulator is not None else composition.triangulator(self.model)
        self.fitter = composition.fitter(self.model, self.reference, calibration)

    @property
    def jig(self) -> JigConfig:
        """The jig the stages see (the nominal one, its cameras rectified when they were not)."""
        return self.model.jig

    def estimate(
        self,
        left: np.ndarray,
        right: np.ndarray,
        *,
        part_diameter_mm: float | None = None,
        timings: dict[str, float] | None = None,
    ) -> SensingResult:
        """Estimate the part's principal normal from one stereo pair.

        Parameters
        ----------
        left, right : (H, W) or (H, W, 3) uint8 or uint16 images of the jig's cameras (RGB); raw images
            when the config's cameras are not rectified (rectified here).
        part_diameter_mm : diameter of the part's base (mm). The paper's method needs it (markers within
            half of it from the jig axis are fitted); ours does not, and uses it to find the face.
        timings : if given, filled with each stage's wall time in seconds (``checks``, ``frame``,
            ``detect``, ``match``, ``triangulate``, ``fit``).

        Returns
        -------
        SensingResult
            The estimate and what led to it; pixel coordinates are in the rectified images.

        Raises
        ------
        InputError
            Bad images (size, dtype, blank or saturated, the same image twice, swapped) or diameter.
        EstimationError
            No contact or too few markers in it (fewer than ``sensing.min_points``), points that do not
            define a plane, or fiducials required but not found.
        """
        check_part_diameter(part_diameter_mm, self.jig)
        if self.needs_part_size and part_diameter_mm is None:
            raise InputError(
                f"the {self.method}'s method needs the part's base diameter (--part-diameter MM)"
            )
        clock = _StageClock(timings)
        observation = self.observe(left, right, clock)
        points_J = self.triangulator.triangulate(
            observation.left_xy_px, observation.right_xy_px, observation.frame
        )
        clock.lap("triangulate")
        result = self.fitter.fit(observation, points_J, part_diameter_mm)
        if (
            self._levels_each_frame
            and observation.frame.source == "config"
            and isinstance(result, SensingResult)
        ):
            result = self._levelled_on_markers_at_rest(observation, result, part_diameter_mm)
        clock.lap("fit")
        if isinstance(result, Refusal):
            raise EstimationError(result.reason)
        return result

    def observe(self, left: np.ndarray, right: np.ndarray, clock: _StageClock | None = None) -> Observation:
        """Check a stereo pair, find the jig frame, detect and match the markers (both methods' front end).

        Raises
        ------
        InputError
            Bad images (size, dtype, blank or saturated, the same image twice, swapped).
        EstimationError
            Fiducials required (``sensing.extrinsics = "fiducials"``) but not found.
        """
        clock = clock or _StageClock(None)
        if self.model.rectification is not None:
            left, right = rectify_images(left, right, self.model.raw_jig, self.model.rectification)
        gray_left, gray_right, image_warnings = checked_pair(left, right, self.jig)
        clock.lap("checks")
        frame, warnings = self.frame_finder.find(gray_to_u8(gray_left), gray_to_u8(gray_right))
        warnings = [*image_warnings, *warnings]
        if frame.source == "config" and self._level_note is not None:
            warnings.append(self._level_note)
        clock.lap("frame")
        markers_left = self.detector.detect(gray_left, on_fiducials(frame.fiducial_quads_left_px))
        markers_right = self.detector.detect(gray_right, on_fiducials(frame.fiducial_quads_right_px))
        clock.lap("detect")
        matches = self.matcher.match(markers_left, markers_right)
        fewest = min(len(markers_left), len(markers_right))
        if len(matches) < MIN_MATCHED_SHARE * fewest:
            self._refuse_swapped(markers_left, markers_right, matches)
            warnings.append(
                f"only {len(matches)} of {fewest} markers were matched between the images: check the "
                "rectification and sensing.row_tolerance_px"
            )
        clock.lap("match")
        return Observation(markers_left, markers_right, matches, frame, tuple(warnings))

    def reference_from_pair(self, left: np.ndarray, right: np.ndarray) -> ReferenceMarkers:
        """Triangulate a stereo pair of the unloaded jig (through the layers, whatever the method) into the
        reference for indentations and identities.

        When the fiducials are not found and ``sensing.extrinsics`` is ``"auto"``, the stereo head is
        levelled on the pair (:func:`~softjig.sensing.levelling.level_head`: the config's camera poses
        corrected so the markers lie on the rest markers) and the markers are triangulated with the
        levelled poses. When they are found, their pose is kept. Either way the reference carries the
        head's measured pose (``head_level``), which estimators built with it use for the frames whose
        fiducials are not found. Points off the membrane (stereo mismatches,
        :func:`~softjig.sensing.contact.off_the_rest_membrane`) are left out.

        Raises
        ------
        EstimationError
            Fewer markers than ``sensing.min_points`` were matched.
        """
        observation = self.observe(left, right)
        triangulator = RefractedTriangulator(self.model)

        def triangulate(frame: JigFrame) -> np.ndarray:
            return triangulator.triangulate(observation.left_xy_px, observation.right_xy_px, frame)

        frame, level, note, unlevelled_tilt_deg = observation.frame, None, None, None
        config = self.model.frame.config_frame
        if frame.source == "fiducials":  # kept for the frames that lose them
            level = from_fiducials(frame.T_J_left, config.T_J_left)
        elif self.jig.sensing.extrinsics == "auto":
            measured = level_head(
                lambda T: triangulate(levelled_frame(self.jig, config, T)),
                self.model.rest_shape.xyz_mm,
                pitch_mm=self.jig.markers.pitch_mm,
                prior=HeadPrior.of(self.jig),
            )
            if isinstance(measured, HeadLevel):
                level, frame = measured, levelled_frame(self.jig, config, measured.T_correction)
            else:
                frame = config
                note = f"the stereo head could not be levelled on the reference frame: {measured}"
                if isinstance(measured, AmbiguousLevel):
                    unlevelled_tilt_deg = measured.rms_tilt_deg
        points = triangulate(frame)
        points = points[~off_the_rest_membrane(points, self.jig)]  # mismatches along a row
        if len(points) < self.jig.sensing.min_points:
            raise EstimationError(
                f"the reference pair gave only {len(points)} markers: is it a pair of the unloaded jig?"
            )
        return ReferenceMarkers(
            points,
            "reference frame",
            head_level=level,
            level_note=note,
            unlevelled_tilt_deg=unlevelled_tilt_deg,
        )

    def _levelled_on_markers_at_rest(
        self, observation: Observation, first: SensingResult, part_diameter_mm: float | None
    ) -> SensingResult:
        """The estimate again with the stereo head levelled on the frame's markers at rest, where its
        fiducials were not found and no reference frame levelled it (else ``first`` as it is).

        Why: with the config's camera poses, the head's mounting error tilts every point, and the normal
        by about the oil's index times it (:mod:`softjig.sensing.levelling`); its spin and shift move the
        markers over the sloping rest shape, which misreads their depths. Away from the part, a loaded
        frame's markers lie on the rest membrane as an unloaded frame's do, so they level the head the
        same way (:func:`~softjig.sensing.levelling.level_head`): those far from the ``first`` estimate's
        pushed-in markers (:func:`~softjig.sensing.contact.markers_at_rest`; on every marker, the dent
        tilts the level). The level is used where it tilts the head by no more than
        :data:`LOADED_LEVEL_TOLERANCES` mounting tolerances and fits the markers at rest better than the
        config's poses beyond chance (:func:`~softjig.sensing.levelling.improves_on_the_config`: a rig
        whose cameras a survey levelled is left as it is). The estimate's uncertainty keeps the
        tolerance's floor (``ContactPlaneFitter._without_measured_frame``): the drape beyond the markers
        left out biases the level by an amount not measured here, so it is not claimed better than the
        mounting.
        """
        if first.indentation is None:  # no indentations to tell the markers at rest
            return first
        config = self.model.frame.config_frame
        at_rest = markers_at_rest(first.points_J, first.indentation, pitch_mm=self.jig.markers.pitch_mm)
        left, right = observation.left_xy_px[at_rest], observation.right_xy_px[at_rest]

        def triangulate(T: np.ndarray) -> np.ndarray:
            return self.triangulator.triangulate(left, right, levelled_frame(self.jig, config, T))

        rest_xyz, pitch = self.model.rest_shape.xyz_mm, self.jig.markers.pitch_mm
        level = level_head(triangulate, rest_xyz, pitch_mm=pitch, prior=HeadPrior.of(self.jig))
        tolerance_deg = self.jig.tolerances.camera_rotation_deg
        if not isinstance(level, HeadLevel) or level.tilt_deg > LOADED_LEVEL_TOLERANCES * tolerance_deg:
            return first
        frame = levelled_frame(self.jig, config, level.T_correction, "membrane at rest")
        points_J = self.triangulator.triangulate(observation.left_xy_px, observation.right_xy_px, frame)
        if not improves_on_the_config(first.points_J[at_rest], points_J[at_rest], rest_xyz, pitch_mm=pitch):
            return first
        note = (
            f"the stereo head was levelled on {level.n_markers} of this frame's markers at rest (away from "
            f"the contact): the config's camera poses tilted by {level.tilt_deg:.2f} deg "
            f"({level.rotation_deg:.2f} deg in all)"
        )
        levelled = replace(observation, frame=frame, warnings=(*observation.warnings, note))
        again = self.fitter.fit(levelled, points_J, part_diameter_mm)
        return again if isinstance(again, SensingResult) else first

    def with_reference(self, reference: ReferenceMarkers | None) -> Estimator:
        """This estimator with another reference (the jig's model shared, not rebuilt)."""
        return Estimator(
            self.model.raw_jig,
            method=self.method,
            reference=reference,
            calibration=self.calibration,
            model=self.model,
        )

    def _refuse_swapped(self, left: Markers, right: Markers, matches: StereoMatches) -> None:
        """Raise :class:`InputError` when the pair's markers match far better with the images swapped.

        In a rectified pair a point's disparity ``u_left - u_right`` is positive (the right camera sits at
        ``+x``): swapped images give every marker a negative one, outside the jig's disparity window, so
        few markers match, and the fiducials' poses disagree. Called only when few markers matched.
        """
        swapped = self.matcher.match(right, left)
        fewest = min(len(left), len(right))
        if len(swapped) >= SWAPPED_MATCH_SHARE * fewest and len(swapped) > SWAPPED_MATCH_FACTOR * len(
            matches
        ):
            raise InputError(
                f"the left and right images look swapped: {len(swapped)} of {fewest} markers match with a "
                f"positive disparity when the first image is taken as the right camera's, {len(matches)} as "
                "given; pass LEFT RIGHT in that order (the left camera's image first)"
            )


def check_part_diameter(part_diameter_mm: float | None, jig: JigConfig) -> None:
    """A part's base diameter must be a positive, finite number of mm smaller than the membrane."""
    if part_diameter_mm is None:
        return
    a_number = isinstance(part_diameter_mm, int | float | np.integer | np.floating)
    if isinstance(part_diameter_mm, bool) or not (
        a_number and np.isfinite(part_diameter_mm) and part_diameter_mm > 0
    ):
        raise InputError(f"the part diameter must be a positive number of mm, got {part_diameter_mm}")
    membrane = 2.0 * jig.membrane.footprint_radius_mm
    if part_diameter_mm >= membrane:
        raise InputError(
            f"the part diameter ({part_diameter_mm:g} mm) must be smaller than the membrane "
            f"(2 x membrane.footprint_radius_mm = {membrane:g} mm): give the diameter of the part's base "
            "in mm"
        )


def checked_pair(
    left: np.ndarray, right: np.ndarray, jig: JigConfig
) -> tuple[np.ndarray, np.ndarray, tuple[str, ...]]:
    """The pair's gray images in their own dtype (``uint8``/``uint16``, or float32 in [0, 1]), checked,
    and warnings.

    Nothing is converted to float: the content checks read a subsample, and the same-image test compares
    that subsample first. ``uint16`` images of a 10-, 12- or 14-bit camera (only the low bits used,
    :func:`~softjig.sensing.detect.packed_bit_depth`) are scaled to the 16-bit range, with a warning that
    names it.

    Raises
    ------
    InputError
        Bad images (size, dtype, blank or saturated, the same image twice) or an unrectified config.
    """
    if not jig.cameras.rectified:
        raise InputError(
            "the config's cameras are not a rectified pair (cameras.rectified = false): rectify the images "
            "first, with the stereo calibration of the cameras"
        )
    grays = []
    for name, image in (("left", left), ("right", right)):
        try:
            gray, _ = gray_image(image)
        except InputError as exc:
            raise InputError(f"{name} image: {exc}") from None
        grays.append(gray)
    warnings: tuple[str, ...] = ()
    bits = packed_bit_depth(*grays) if grays[0].shape == grays[1].shape else None
    if bits is not None:
        grays = [unpack_bit_depth(g, bits) for g in grays]
        warnings = (
            f"the 16-bit images use only their low {bits} bits (brightest value below {2**bits}): read as "
            f"{bits}-bit counts and scaled by {2 ** (16 - bits)} to the 16-bit range; save the camera's "
            "frames scaled to full range to silence this",
        )
    if grays[0].shape != grays[1].shape:
        raise InputError(
            f"the left image is {grays[0].shape[1]}x{grays[0].shape[0]} px but the right one is "
            f"{grays[1].shape[1]}x{grays[1].shape[0]}: pass the two images of one stereo pair"
        )
    cam = jig.cameras.left
    if grays[0].shape != (cam.height_px, cam.width_px):
        raise InputError(
            f"the images are {grays[0].shape[1]}x{grays[0].shape[0]} px but the config's cameras are "
            f"{cam.width_px}x{cam.height_px}: pass the rig.toml of the cameras that took them"
        )
    # The same-image test compares the content checks' contiguous subsamples first (different images
    # almost always differ there), a fifth of the cost of comparing strided views of the images.
    samples = [
        check_image_content(gray, name=f"the {name} image")
        for name, gray in zip(("left", "right"), grays, strict=True)
    ]
    same_sample = grays[0].dtype == grays[1].dtype and np.array_equal(samples[0], samples[1])
    if same_sample and np.array_equal(grays[0], grays[1]):
        raise InputError("the left and right images are the same image: pass the two views of a stereo pair")
    return grays[0], grays[1], warnings


class _StageClock:
    """Records the wall time of consecutive stages into a dict, when one is given."""

    def __init__(self, timings: dict[str, float] | None) -> None:
        self.timings = timings
        self.last = time.perf_counter()

    def lap(self, stage: str) -> None:
        if self.timings is not None:
            now = time.perf_counter()
            self.timings[stage] = now - self.last
            self.last = now
