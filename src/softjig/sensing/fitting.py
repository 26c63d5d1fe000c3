"""The two methods' last stage: which markers the part touches, their plane, and the estimate.

:class:`PaperPlaneFitter` is Sakuma et al.'s ("Optical Sensing"): the points within the part's base
radius of the jig axis and an SVD plane. :class:`ContactPlaneFitter` is ours: the contact found from each
marker's indentation against the unloaded jig (:mod:`softjig.sensing.contact`), fitted robustly
(:mod:`softjig.sensing.robust`), lifted-off markers dropped, with the normal's uncertainty
(:mod:`softjig.sensing.uncertainty`) and a self-check of the frame's own evidence
(:mod:`softjig.sensing.selfcheck`). Both are built once per estimator and return a
:class:`~softjig.sensing.results.SensingResult`, or a :class:`~softjig.sensing.results.Refusal` when the
frame gives no estimate (no contact, too few markers).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import NamedTuple

import numpy as np

from softjig.config import JigConfig
from softjig.errors import EstimationError, InputError
from softjig.geometry import PlaneFit, angle_between, fit_plane_svd, normal_from_tilt_angles, tilt_angles
from softjig.jig_shape import rest_inner_height_mm
from softjig.sensing.contact import (
    BESIDE_HOLE_THRESHOLDS,
    DENT_HOLE_MIN_MARKERS,
    MAX_TILT_DEG,
    NOISE_RADIUS_PITCHES,
    TOLERATED_VIOLATION_SHARE,
    ContactRegion,
    FootprintMisfit,
    Indentation,
    ambiguous_selection,
    contact_candidates,
    contact_violations,
    describe_contact,
    drop_lifted_off,
    face_centre_xy,
    face_depth_mm,
    footprint_misfit,
    grow_contact,
    holes_in_the_dent,
    indentation,
    indentations,
    just_outside,
    off_the_membrane,
    pushed_in_scatter_mm,
    under_face,
)
from softjig.sensing.identities import MarkerIdentities, identify_markers
from softjig.sensing.results import SUSPECT_PREFIX, Estimate, Observation, Refusal, SensingResult
from softjig.sensing.robust import fit_plane_robust
from softjig.sensing.selfcheck import MIN_HALF_POINTS, SplitCheck, agreement, rougher, split_halves
from softjig.sensing.setup import JigModel, ReferenceModel
from softjig.sensing.uncertainty import (
    NormalUncertainty,
    inflated,
    normal_uncertainty,
    with_angle_floor,
    with_depth_scale_error,
    with_spread_between,
)
from softjig.tilt_calibration import TiltCalibration

# Unmodelled, systematic errors of a triangulated marker (hemisphere seen obliquely, membrane ripple, the
# as-built cameras): the residual scale used for the normal's uncertainty is at least this.
UNCERTAINTY_FLOOR_MM = 0.05
CONTACT_INLIER_SIGMAS = 2.5  # a marker within this many depth-noise sigmas of the contact plane is on it
# The errors the first-order model leaves out (the obliquely seen hemispheres, the lift-off line's
# markers, the frame), as a factor on the normal's covariance; calibrated on varied designs for the
# 1-sigma coverage of tilt_sigma_deg (benchmarks/bench_zoo.py checks it).
MODEL_ERROR_FACTOR = 1.5
# The paper method's error of the normal that does not shrink with more markers (the as-built jig against
# the nominal one): added in quadrature, as an isotropic RMS angle (deg); the same calibration as above.
# The refractive method derives its own from the jig's tolerances (``ToleranceConfig.depth_scale_error``).
NORMAL_ANGLE_FLOOR_DEG = 0.1
# The face must lie this many depth-noise sigmas below the unloaded membrane at a marker to touch it.
LIFT_OFF_SIGMAS = 1.5
# Fewer fitted markers than this cannot be checked well enough (the split halves need 6 each, and the
# check's power grows with them), and such an estimate is suspect: a few markers of the membrane's wall
# beside a small part pass the split check.
SELF_CHECK_MIN_POINTS = 15
# A partial contact grown without the part's size (with no size given, or as the fallback of a face under
# the known size that failed its checks) is suspect under this many markers: there, the wall
# beside a small part's lowered edge and a few of its face's markers pass the split check as one face.
# Measured on the design zoo (seeds 0-13, 28,000 size-free estimates): "ok" partial contacts of 15-18
# markers were over 3 deg off 2.8 % of the time (12 of them silent failures), of 19-24 markers 0.8 %
# (none silent), of more 0.3 % (benchmarks/RESULTS.md, ninth session).
PARTIAL_CONTACT_MIN_POINTS = 19
# The words of that doubt (suspicions), by which the size-free fallback under a known size tells it apart.
PARTIAL_CONTACT_DOUBT = "in partial contact, found without the part's size"
# A contact of fewer than this share of the clearly pushed-in markers is suspect: a face presses most of
# its dent (the drape around it is shallower), a strip of wall fitted instead of a large face is a few
# of them. Size-free only: with the size, the contact is cut to the face and a steep part's drape is most
# of the dent.
MIN_CANDIDATE_SHARE = 0.2
# With the part's size known, a contact footprint larger than the part's face grown by this many marker
# pitches all round (the footprint is the markers' hull dilated by half a pitch, and the drape's first
# ring may join it) is not that part's.
CONTACT_AREA_SLACK_PITCHES = 1.0
# With the part's size known, the face's centre is searched where the contact is: at most this many
# rounds of (fit under the face, move its centre to where that contact puts it), ...
FACE_CENTRE_ROUNDS = 4
# ... ending when the centre moves by less than this many marker pitches (a quarter of a grid cell).
FACE_CENTRE_TOLERANCE_PITCHES = 0.25
# With the part's size, a dent whose centroid lies this many part radii or more from the jig axis is
# searched from there too (a centred face covers its own dent's centroid: a small part steeply tilted
# drags the membrane down mostly beside its lowered edge, 0.5-1 radius off).
OFF_AXIS_DENT_RADII = 1.0
# A dent whose centroid lies this many pitches or more off the axis (but under a radius) is also searched
# from there, as a rival only: a face searched from the axis that it contradicts makes the estimate suspect.
RIVAL_SEARCH_PITCHES = 1.0
# ... when the face found from the axis has fewer markers than SELF_CHECK_MIN_POINTS and one more half of
# the split check (MIN_HALF_POINTS): the self-check has little power there (the zoo's two such silent
# failures had 15), while a larger face is placed by its own markers (the default pair's 24-26 are not
# searched twice: a whole second search cost 1.1 ms there, measured).
# The search starts on the jig axis and stays there when the contact found puts the face's centre within
# this share of the part's radius of it.
CENTRED_SHARE = 0.5
# Rounds of (robust fit of the markers under the face, the face's footprint from that plane).
UNDER_FACE_ROUNDS = 3
# When the face found under the known size is suspect and markers contradict it, it is searched again
# from every placement on a square grid over the clearly pushed-in markers, this many part radii apart
# (at least one pitch): a search moves its face to where its contact puts it, so starts half a radius
# apart reach every face.
PLACEMENT_GRID_RADII = 0.5
# The contact grown from the pushed-in markers above the contact's plane (the other arm of a V) is its
# rival when it has at least this share of the contact's markers (two arms of a V, neither much the
# larger: a V's arms are a tilted face and the wall beside its lowered edge, as deep as each other) ...
OTHER_ARM_SHARE = 2.0 / 3.0
# ... and is not rougher than the contact at this significance (one-sided F test of their residuals'
# variances): a wall curves up to the rest shape, a face is flat.
ROUGHER_SIGNIFICANCE = 0.05
# A size-free contact grown again with the band of the pushed-in markers' own scatter must hold this many
# markers: twice the markers of one marker's neighbourhood in that scatter's quadratic fits (a disc of
# NOISE_RADIUS_PITCHES pitches, pi 2.5^2 = 20 markers), so that most of the measured markers' neighbourhoods
# lie on the face rather than across its edge, where the drape's curvature is measured instead.
FACE_SCATTER_MIN_POINTS = round(2.0 * math.pi * NOISE_RADIUS_PITCHES**2)
# Identities: a marker keeps the nearest reference marker within this share of the pitch sideways.
IDENTITY_REACH_PITCHES = 0.5

PlaneFitFunction = Callable[[np.ndarray], "tuple[np.ndarray, PlaneFit]"]
Contact = tuple[np.ndarray, PlaneFit]  # which markers (bool mask) and their plane


@dataclass(frozen=True)
class RivalCheck(SplitCheck):
    """A rival contact's agreement with the contact chosen (``normal_a`` the chosen's plane's normal,
    ``normal_b`` the rival's), with the rival ``contact`` itself (:meth:`ContactPlaneFitter._rival`)."""

    contact: Contact

    def seen_from(self, chosen: Contact) -> RivalCheck:
        """The same disagreement seen from the rival: ``chosen`` (the contact it was the rival of) becomes
        the rival, the normals swap (the check is symmetric)."""
        return RivalCheck(self.angle_rad, self.noise_rad, self.normal_b, self.normal_a, contact=chosen)


Found = tuple[Contact, RivalCheck | None] | Refusal  # a contact with its rival, or why none


# ------------------------------------------------------------------------------------------ shared


def fit_or_fail(points: np.ndarray, minimum: int) -> PlaneFit:
    """The SVD plane of ``points``; :class:`EstimationError` when they do not define one."""
    try:
        return fit_plane_svd(points, min_points=minimum)
    except InputError as exc:
        raise EstimationError(f"no plane could be fitted: {exc}") from None


def _mm(value: float) -> str:
    """A length for a message: ``"0.07 mm"``, or ``"unknown"`` (never ``nan mm``)."""
    return f"{value:.2f} mm" if np.isfinite(value) else "unknown"


def _calibrated(
    plane: PlaneFit, calibration: TiltCalibration | None
) -> tuple[float, float, float, float, np.ndarray]:
    """Raw and calibrated tilt angles (rad) and the calibrated normal."""
    raw_ax, raw_ay = (float(v) for v in tilt_angles(plane.normal))
    if calibration is None or calibration.is_identity():
        return raw_ax, raw_ay, raw_ax, raw_ay, plane.normal
    ax, ay = (float(v) for v in calibration.apply(raw_ax, raw_ay))
    return raw_ax, raw_ay, ax, ay, normal_from_tilt_angles(ax, ay)


def _common_fields(
    observation: Observation,
    plane: PlaneFit,
    calibration: TiltCalibration | None,
    method: str,
    part_diameter_mm: float | None,
    n_used: int,
    warnings: list[str],
) -> dict:
    """The :class:`Estimate` fields both methods fill alike."""
    raw_ax, raw_ay, ax, ay, normal = _calibrated(plane, calibration)
    return {
        "normal": tuple(np.asarray(normal, dtype=float).tolist()),
        "tilt_x_deg": float(np.degrees(ax)),
        "tilt_y_deg": float(np.degrees(ay)),
        "n_points": n_used,
        "rms_residual_mm": plane.rms_residual_mm,
        "frame_source": observation.frame.source,
        "warnings": tuple(warnings),
        "method": method,
        "calibrated": calibration is not None and not calibration.is_identity(),
        "raw_tilt_x_deg": float(np.degrees(raw_ax)),
        "raw_tilt_y_deg": float(np.degrees(raw_ay)),
        "part_diameter_mm": None if part_diameter_mm is None else float(part_diameter_mm),
        "n_markers_left": len(observation.left),
        "n_markers_right": len(observation.right),
        "n_matches": len(observation.matches),
    }


#: Two estimates' normals further apart than this many times their combined 1-sigma tilt are two planes.
DISTINCT_PLANE_SIGMAS = 3.0


def _angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    """The angle between two unit normals (deg; every normal here has ``n_z > 0``)."""
    return math.degrees(float(angle_between(a, b)))


def _distinct_planes(a: Estimate, b: Estimate) -> bool:
    """Whether two estimates of one frame found different planes: their normals further apart than
    :data:`DISTINCT_PLANE_SIGMAS` times their combined ``tilt_sigma_deg``."""
    return _angle_deg(a.normal, b.normal) > DISTINCT_PLANE_SIGMAS * math.hypot(
        a.tilt_sigma_deg, b.tilt_sigma_deg
    )


def _confident_and_distinct(free: Estimate, sized: Estimate) -> bool:
    """Whether the size-free estimate ``free`` is "ok" and of another plane than ``sized``."""
    return free.quality == "ok" and _distinct_planes(sized, free)


def _made_suspect(result: SensingResult, doubt: str) -> SensingResult:
    """``result`` with its estimate suspect for the reason ``doubt`` (a warning that says so)."""
    estimate = result.estimate
    return replace(
        result, estimate=replace(estimate, quality="suspect", warnings=(*estimate.warnings, doubt))
    )


def _beyond_the_rival(
    normal: np.ndarray, sigma_deg: float, rival_normal: np.ndarray, rival: SplitCheck
) -> bool:
    """Whether ``normal`` (of sigma ``sigma_deg``) lies further from a ``rival``'s ``rival_normal`` than
    :data:`DISTINCT_PLANE_SIGMAS` times their combined noise (the rival's own, ``rival.noise_rad``)."""
    angle = float(angle_between(normal, rival_normal))
    return angle > DISTINCT_PLANE_SIGMAS * math.hypot(math.radians(sigma_deg), rival.noise_rad)


def _third_plane(reported: SensingResult, face: SensingResult, rival: SplitCheck | None) -> SensingResult:
    """The size-free estimate ``reported`` in place of the ``face`` under the known size, made suspect
    where that face was doubted for its ``rival`` and the size-free plane lies beyond their noise
    (:data:`DISTINCT_PLANE_SIGMAS`) from the rival too; else as it is.

    Why: the search under the known size found two faces of that size that nothing contradicts; a
    size-free contact that agrees with neither is a third plane, not the resolution of the doubt
    (where it agrees with the rival, two searches found that plane, and it stands). Beside a part
    pushed off the axis, the size-free growth can take the membrane's wall: zoo seed 0 with a damaged
    membrane, bubbles and glints (``bench_zoo.py --image-model damaged``), design 39, frame 18, against
    the rest shape: a face and its rival 3.4 deg apart (two markers inside the face mislocated by the
    defects), and a size-free contact of 25 markers (20 of them the wall) 16.2 and 16.5 deg from them,
    "ok" and 15.6 deg off."""
    if rival is None:
        return reported
    # The planes' own normals (the estimates' are calibrated); the rival is the one farther from the face
    free, face_normal = reported.plane.normal, face.plane.normal
    other = max((rival.normal_a, rival.normal_b), key=lambda n: float(angle_between(n, face_normal)))
    if not _beyond_the_rival(free, reported.estimate.tilt_sigma_deg, other, rival):
        return reported
    return _made_suspect(
        reported,
        f"{SUSPECT_PREFIX}the face under the part's size and its rival, both plausible, lie "
        f"{_angle_deg(free, face_normal):.1f} and {_angle_deg(free, other):.1f} deg from this contact: the "
        "frame holds more plausible faces than one",
    )


def holds_too_few_of_the_dent(n_used: int, n_candidates: int) -> bool:
    """Whether a size-free contact of ``n_used`` markers holds under :data:`MIN_CANDIDATE_SHARE` of the
    ``n_candidates`` clearly pushed-in markers: a strip (of the membrane's wall, or of a face whose
    markers fell out of the band), not a face, which presses most of its dent."""
    return n_used < MIN_CANDIDATE_SHARE * n_candidates


def _doubts_beyond_a_small_partial_contact(estimate: Estimate) -> int:
    """How many of ``estimate``'s suspect reasons are not that of a small partial contact grown without
    the size (:data:`PARTIAL_CONTACT_MIN_POINTS`). That doubt alone does not keep the size-free contact
    from replacing a face under the known size that failed its checks; it keeps it suspect (the face
    kept instead was the worse estimate on the zoo: benchmarks/RESULTS.md, ninth session)."""
    return sum(w.startswith(SUSPECT_PREFIX) and PARTIAL_CONTACT_DOUBT not in w for w in estimate.warnings)


def fewest_to_check(min_points: int) -> int:
    """The fewest fitted markers whose flatness the self-check can check (:data:`SELF_CHECK_MIN_POINTS`,
    or twice ``sensing.min_points``: a split half needs as many as a fit)."""
    return max(SELF_CHECK_MIN_POINTS, 2 * min_points)


def suspicions(
    split: SplitCheck | None,
    violations: int,
    plane: PlaneFit,
    contact: ContactRegion | None,
    part_diameter_mm: float | None,
    jig: JigConfig,
    n_used: int,
    *,
    size_free_search: bool = False,
    dent_hole_gaps_mm: np.ndarray | None = None,
) -> list[str]:
    """The reasons (warnings starting with ``"suspect: "``) why an estimate may be wrong, from the frame's
    own evidence (:mod:`softjig.sensing.selfcheck`); none for an estimate that passed every check. An
    estimate the checks cannot verify (too few markers to split) is suspect too, and so is a partial
    contact of under :data:`PARTIAL_CONTACT_MIN_POINTS` markers grown without the part's size
    (``size_free_search``: without a size, or as the fallback of a face under the known size that
    failed its checks), and so is one with :data:`~softjig.sensing.contact.DENT_HOLE_MIN_MARKERS` or more
    holes in its dent, markers deeper than its face reaches (``dent_hole_gaps_mm``: how far below the
    plane each lies, :func:`~softjig.sensing.contact.holes_in_the_dent`)."""
    reasons = []
    fewest = fewest_to_check(jig.sensing.min_points)
    if n_used < fewest or split is None:
        reasons.append(
            f"suspect: only {n_used} markers were fitted, too few to check that they are one flat face "
            f"(at least {fewest} are needed): a few markers of the membrane's wall fit a plane as well"
        )
    elif size_free_search and contact is not None and contact.partial and n_used < PARTIAL_CONTACT_MIN_POINTS:
        hint = "; the part's size settles it" if part_diameter_mm is None else ""
        reasons.append(
            f"suspect: only {n_used} markers are {PARTIAL_CONTACT_DOUBT}: too few to tell the part's face "
            f"from the membrane's wall beside its lowered edge (at least {PARTIAL_CONTACT_MIN_POINTS} are "
            f"needed{hint})"
        )
    if split is not None and split.suspect:
        reasons.append(
            f"suspect: the two halves of the contact are tilted {np.degrees(split.angle_rad):.1f} deg apart "
            f"({split.sigmas:.0f} times their noise): the markers fitted are not one flat face (the "
            "membrane's wall?)"
        )
    if violations > 0:
        reasons.append(
            f"suspect: {violations} {'marker' if violations == 1 else 'markers'} in or beside the contact "
            f"{'lies' if violations == 1 else 'lie'} above the fitted face or far below it, beyond what the "
            "noise explains: the plane may not be the part's face"
        )
    if dent_hole_gaps_mm is not None and len(dent_hole_gaps_mm) >= DENT_HOLE_MIN_MARKERS:
        reasons.append(
            f"suspect: {len(dent_hole_gaps_mm)} markers of the dent are pushed in deeper than the fitted "
            f"face reaches at its contact, up to {np.max(dent_hole_gaps_mm):.1f} mm below it where it would "
            "press into the membrane: the part's face is deeper, beside the markers fitted (a stretch of "
            "the membrane's drape?)"
        )
    if plane.normal[2] < np.cos(np.radians(MAX_TILT_DEG)):
        reasons.append(
            f"suspect: the plane is tilted {np.degrees(np.arccos(plane.normal[2])):.0f} deg, steeper than a "
            f"part pressed into a soft jig stands ({MAX_TILT_DEG:g} deg)"
        )
    if part_diameter_mm is not None and contact is not None:
        largest = np.pi * (part_diameter_mm / 2.0 + CONTACT_AREA_SLACK_PITCHES * jig.markers.pitch_mm) ** 2
        if contact.area_mm2 > largest:
            reasons.append(
                f"suspect: the contact ({contact.area_mm2:.0f} mm^2) is larger than the {part_diameter_mm:g} "
                f"mm part's face could press ({largest:.0f} mm^2): is the part's size right?"
            )
    return reasons


# ------------------------------------------------------------------------------------------- paper


class PaperPlaneFitter:
    """The paper's plane: the points within the part's base radius of the jig axis, an SVD fit.

    Its uncalibrated tilts are compressed by about the oil's index (the pinhole triangulation), which its
    tilt calibration absorbs and no sigma covers; its push depth is measured from the rest apex as the
    same triangulation sees it, so zero push reads zero.
    """

    def __init__(self, model: JigModel, calibration: TiltCalibration | None) -> None:
        self._jig = model.jig
        self._rest_apex_z_mm = model.setup.rest_apex_z_mm
        self._calibration = calibration

    def fit(
        self, observation: Observation, points_J: np.ndarray, part_diameter_mm: float | None
    ) -> SensingResult | Refusal:
        jig, minimum = self._jig, self._jig.sensing.min_points
        radius = part_diameter_mm / 2.0
        used = np.hypot(points_J[:, 0], points_J[:, 1]) < radius
        n_used = int(used.sum())
        if n_used < minimum:
            return Refusal(
                f"only {n_used} markers lie within {radius:g} mm of the jig axis (the part's base radius); "
                f"at least {minimum} are needed (sensing.min_points). Detected {len(observation.left)} left"
                f" / {len(observation.right)} right, matched {len(observation.matches)}: is a part on the "
                "jig, centred, and is the part diameter right?"
            )
        points = points_J[used]
        plane = fit_or_fail(points, minimum)
        # The statistical uncertainty and the self-check of the crop's points (the crop is not robust: a
        # plane through the drape beside the face shows in its halves).
        sigma = inflated(normal_uncertainty(points, plane, floor_mm=UNCERTAINTY_FLOOR_MM), MODEL_ERROR_FACTOR)
        split = split_halves(points, point_sigma_mm=sigma.residual_sigma_mm, noise_factor=MODEL_ERROR_FACTOR)
        sigma_rad = sigma.tilt_sigma_rad
        if split is not None:
            sigma_rad = float(np.hypot(sigma_rad, 0.5 * split.excess_rad))
        sigma_rad = float(np.hypot(sigma_rad, np.radians(NORMAL_ANGLE_FLOOR_DEG)))
        suspect = suspicions(split, 0, plane, None, None, jig, n_used)
        warnings = [*observation.warnings, *suspect]
        estimate = Estimate(
            tilt_sigma_deg=float(np.degrees(sigma_rad)),
            quality="suspect" if suspect else "ok",
            push_depth_mm=self._rest_apex_z_mm - plane.z_at(0.0, 0.0),
            **_common_fields(
                observation, plane, self._calibration, "paper", part_diameter_mm, n_used, warnings
            ),
        )
        return SensingResult(
            estimate,
            observation.left,
            observation.right,
            observation.matches,
            points_J,
            used,
            plane,
            observation.frame,
        )


# -------------------------------------------------------------------------------------- refractive


@dataclass(frozen=True)
class NoiseScales:
    """The noise of each quantity the refractive method thresholds, measured in the frame itself (mm).

    A threshold is set from the noise of the quantity it thresholds: the three differ when the bead
    pack's speckle is the same in the reference and the loaded frame (as in a real jig, whose beads do
    not move). A marker's image then carries the same speckle bias in both frames while it stays put,
    which the reference-differenced indentation cancels, but not its absolute position, nor its position
    once the part has moved it onto other beads.

    Attributes
    ----------
    indentation_sigma_mm : the reference-differenced indentation's noise (:attr:`Indentation.noise_mm`):
        which markers are pushed in at all.
    plane_sigma_mm : the absolute 3-D scatter of this frame's markers about a smooth surface (their
        neighbour-differenced heights above the nominal rest shape), at least the indentation's noise and
        :data:`UNCERTAINTY_FLOOR_MM`: the inlier band of the contact plane (raised to the clearly pushed-in
        markers' own scatter, :func:`on_the_face`, where a size-free contact is grown again:
        :meth:`ContactPlaneFitter._grown_with_the_face_scatter`).
    face_depth_sigma_mm : the noise of a face depth (:func:`~softjig.sensing.contact.face_depth_mm`,
        ``reference_z - zero - plane_z``, in which the loaded marker's own height cancels): the reference's
        own scatter about the rest shape (a reference frame's; the indentation noise for the rest shape),
        at least the indentation's noise: the lift-off clearance and its margin.
    """

    indentation_sigma_mm: float
    plane_sigma_mm: float
    face_depth_sigma_mm: float

    @property
    def inlier_mm(self) -> float:
        """The contact plane's inlier distance: :data:`CONTACT_INLIER_SIGMAS` plane sigmas (mm)."""
        return CONTACT_INLIER_SIGMAS * self.plane_sigma_mm


def noise_scales(dent: Indentation, absolute: Indentation | None, reference: ReferenceModel) -> NoiseScales:
    """Measure :class:`NoiseScales` for one frame from its indentation against the reference and, with a
    reference frame, against the rest shape (``absolute``: its noise is the markers' absolute scatter);
    the reference's own scatter was measured once, with the :class:`ReferenceModel`."""
    sigma = float(dent.noise_mm) if np.isfinite(dent.noise_mm) else UNCERTAINTY_FLOOR_MM
    if reference.scatter_mm is None or absolute is None:  # the rest shape: already the absolute heights'
        return NoiseScales(sigma, max(sigma, UNCERTAINTY_FLOOR_MM), sigma)
    scatter = float(absolute.noise_mm) if np.isfinite(absolute.noise_mm) else sigma
    return NoiseScales(sigma, max(scatter, sigma, UNCERTAINTY_FLOOR_MM), max(reference.scatter_mm, sigma))


def on_the_face(
    noise: NoiseScales, points_J: np.ndarray, heights: Indentation, candidates: np.ndarray, pitch_mm: float
) -> NoiseScales:
    """``noise`` with the plane sigma at least the clearly pushed-in markers' own scatter
    (:func:`~softjig.sensing.contact.pushed_in_scatter_mm` of their ``heights`` above the rest shape): the
    markers on a face scatter about its plane more than the membrane at rest does."""
    scatter = pushed_in_scatter_mm(points_J, heights, candidates, pitch_mm=pitch_mm)
    if not scatter > noise.plane_sigma_mm:  # False where NaN (too few to measure)
        return noise
    return replace(noise, plane_sigma_mm=scatter)


def canonical_order(ids: np.ndarray, points_J: np.ndarray) -> np.ndarray:
    """The markers ordered by their reference marker's index; those without one last, by ``x`` then ``y``.

    The robust fits draw random triples by position in the list: in the reference markers' order, two
    runs whose markers differ only by rounding draw the same triples."""
    if ids.min(initial=0) >= 0:  # the usual case: every marker identified (ids are one-to-one)
        return np.argsort(ids, kind="stable")
    return np.lexsort((points_J[:, 1], points_J[:, 0], np.where(ids >= 0, ids, np.iinfo(np.intp).max)))


def _mean_xy(points_J: np.ndarray, selection: np.ndarray) -> np.ndarray:
    """The mean ``(x, y)`` of the selected markers (not none), as ``points_J[selection, :2].mean(axis=0)``
    computes it (a sum over the rows, divided by their count) without NumPy's ``mean`` wrapper."""
    return points_J[selection, :2].sum(axis=0) / np.count_nonzero(selection)


def placement_grid(xy_mm: np.ndarray, spacing_mm: float) -> np.ndarray:
    """``(K, 2)`` points (mm) of a square grid of ``spacing_mm`` over the bounding box of ``xy_mm``
    (``(N, 2)``, not empty), from its lower corner: where the face is searched from when every
    placement is tried."""
    low, high = xy_mm.min(axis=0), xy_mm.max(axis=0)
    xs = np.arange(low[0], high[0] + spacing_mm / 2.0, spacing_mm)
    ys = np.arange(low[1], high[1] + spacing_mm / 2.0, spacing_mm)
    return np.stack(np.meshgrid(xs, ys, indexing="ij"), axis=-1).reshape(-1, 2)


def _within(points_J: np.ndarray, centre_xy: np.ndarray, radius_mm: float) -> np.ndarray:
    return np.hypot(points_J[:, 0] - centre_xy[0], points_J[:, 1] - centre_xy[1]) < radius_mm


@dataclass(frozen=True)
class Dent:
    """One frame's markers against the unloaded jig, in the canonical order (:func:`canonical_order`).

    Attributes
    ----------
    points_J : (M, 3) the markers in J (mm), canonical order.
    indentation : their indentation (canonical order).
    candidates : (M,) the clearly pushed-in markers (:func:`~softjig.sensing.contact.contact_candidates`).
    noise : the frame's noise scales.
    threshold_mm : the contact plane's inlier distance (:data:`CONTACT_INLIER_SIGMAS` plane sigmas).
    """

    points_J: np.ndarray
    indentation: Indentation
    candidates: np.ndarray
    noise: NoiseScales
    threshold_mm: float


@dataclass(frozen=True)
class _Measured:
    """What :meth:`ContactPlaneFitter.fit` measures of a frame once, whatever size its contact is searched
    with: the markers' identities, their indentation (as matched, and in the canonical ``order`` as
    ``ordered``), their heights above the rest shape where the indentation is against a reference frame
    (``absolute``, as matched; ``None`` against the rest shape) and the part's size given (mm, or
    ``None``)."""

    observation: Observation
    points_J: np.ndarray
    identities: MarkerIdentities
    dent: Indentation
    absolute: Indentation | None
    ordered: Dent
    order: np.ndarray
    part_diameter_mm: float | None


class _InContact(NamedTuple):
    """A contact as matched: its markers as found (``grown``), those left once the lifted-off ones are
    dropped (``used``), and their plane."""

    grown: np.ndarray
    used: np.ndarray
    plane: PlaneFit


class ContactPlaneFitter:
    """Ours: the contact from the indentation, its plane fitted robustly, lifted-off markers dropped.

    The contact is found under the known face when the part's size is given (searched from the
    indentation, wherever the part stands), or grown from the deepest pushed-in markers over the
    neighbours on their plane (:func:`~softjig.sensing.contact.grow_contact`); planes are fitted robustly,
    with an inlier distance set by the markers' own depth noise. The normal comes with its covariance,
    and the frame's own evidence is checked (split halves, violations, plausibility).
    """

    def __init__(
        self, model: JigModel, reference: ReferenceModel, calibration: TiltCalibration | None
    ) -> None:
        self._jig = model.jig
        self._reference = reference
        self._calibration = calibration
        self._minimum = model.jig.sensing.min_points
        self._pitch = model.jig.markers.pitch_mm
        self._depth_scale_error = model.jig.tolerances.depth_scale_error(
            model.jig.medium.oil_refractive_index
        )

    def fit(
        self, observation: Observation, points_J: np.ndarray, part_diameter_mm: float | None
    ) -> SensingResult | Refusal:
        """Identify the markers, measure their indentation, find the contact (in the reference markers'
        order, :func:`canonical_order`), drop the lifted-off markers, and describe the result.

        With the part's size, the contact is searched under the known face; when that estimate fails its
        self-checks and markers contradict its contact, the face is searched again from every placement
        (:meth:`_placement_search`), and that estimate is reported instead. When it fails its checks
        too, the contact is searched without the size as well, and reported instead (with a warning that
        says so) when it passes every check, the part's size included (its area), and its plane is
        another one (:func:`_distinct_planes`): two searches that rest on different evidence, one of
        them confident (:meth:`_size_free_instead`; suspect where nothing contradicts the other either,
        or where the face was doubted for a rival and the size-free plane is neither: :func:`_third_plane`).
        Where both found the same plane, the doubt the search with the size raised stands (a rival
        contact, say), and so does the suspect estimate. An "ok" estimate under the known size is made
        suspect where the size-free contact passes every check too and lies on another plane
        (:meth:`_checked_without_the_size`). Without the size, a contact that kept too few of
        the pushed-in markers may be grown again with a band set from their own scatter
        (:meth:`_grown_with_the_face_scatter`).
        """
        identities = identify_markers(
            points_J, self._reference.markers, max_lateral_mm=IDENTITY_REACH_PITCHES * self._pitch
        )
        dent, absolute = self._indentation(points_J, identities.ids)
        noise = noise_scales(dent, absolute, self._reference)
        dent, absolute, observation = self._without_points_in_doubt(
            points_J, dent, absolute, observation, noise
        )
        candidates = contact_candidates(dent)
        if candidates.sum() < self._minimum:
            return Refusal(
                f"no contact: only {int(candidates.sum())} of {len(points_J)} matched markers are pushed in "
                f"beyond the noise ({_mm(dent.noise_mm)}); at least {self._minimum} are needed "
                "(sensing.min_points). Is a part pressed onto the jig?"
            )
        order = canonical_order(identities.ids, points_J)
        in_order = Indentation(dent.depth_mm[order], dent.zero_mm, dent.noise_mm)
        ordered = Dent(points_J[order], in_order, candidates[order], noise, noise.inlier_mm)
        measured = _Measured(
            observation, points_J, identities, dent, absolute, ordered, order, part_diameter_mm
        )
        first = self._contact(ordered, part_diameter_mm)
        result = self._fit(measured, first, search_size_mm=part_diameter_mm)
        if part_diameter_mm is None and isinstance(result, SensingResult):
            return self._grown_with_the_face_scatter(measured, result)
        if not isinstance(result, SensingResult):
            return result
        if result.estimate.quality == "ok":
            return self._checked_without_the_size(measured, result)
        face, rival = first
        found = self._contact(ordered, part_diameter_mm, first=first)
        searched = self._fit(measured, found, search_size_mm=part_diameter_mm)
        if isinstance(searched, SensingResult):
            result, (face, rival) = searched, found
            if result.estimate.quality == "ok":
                return self._checked_without_the_size(measured, result)
        try:
            size_free: Found | None = self._contact(ordered, None)
        except EstimationError:  # no plane grows without the size
            size_free = None
        reported = self._size_free_instead(measured, result, rival, size_free)
        if reported is result and rival is not None:  # the face under the known size, doubted for its rival
            return self._likelier_face(measured, result, face, rival, size_free)
        return reported

    def _checked_without_the_size(self, measured: _Measured, sized: SensingResult) -> SensingResult:
        """The ``sized`` estimate (under the known face, "ok"), made suspect where the contact found
        without the size passes every check too and lies on another plane (:func:`_distinct_planes`);
        else ``sized`` as it is.

        Why: the two searches rest on different evidence (a face of the known size placed where the
        indentation puts it; a plane grown from the deepest markers), and where both pass every check
        yet disagree beyond their noise, one of them is not the part's face (the size-free estimate is
        checked without the size, as the size-free way would report it). Under the known size, the
        search can settle on a face made of a few of the face's markers and the membrane draped beside
        its lifted edge, which nothing contradicts (zoo seed 15, design 0, frame 12: a 42 mm cylinder
        20 mm off the axis, 7 deg tilt; 12 of its 34 markers in contact and 19 of the drape, "ok" and
        10.7 deg off with a sigma of 2.5 deg; the size-free estimate, "ok", was 1.3 deg off). The
        size-free contact's rival (:meth:`_other_arm`, most of its cost) is looked for only where the
        two disagree without it.
        """
        ordered = measured.ordered
        without_the_size = replace(measured, part_diameter_mm=None)  # checked on its own evidence
        try:
            found = self._contact(ordered, None, other_arm=False)
            if not found:
                return sized
            in_contact = self._in_contact(without_the_size, found[0], None)
        except EstimationError:  # no plane grows without the size: nothing to check against
            return sized
        # Two planes within 3 of the sized estimate's sigmas are no two planes whatever the size-free
        # estimate's sigma (the description, half the cost, is skipped: the usual case).
        estimate = sized.estimate
        *_, normal = _calibrated(in_contact.plane, self._calibration)
        if _angle_deg(normal, estimate.normal) <= DISTINCT_PLANE_SIGMAS * estimate.tilt_sigma_deg:
            return sized
        free = self._described(without_the_size, in_contact, None, None).estimate
        if not _confident_and_distinct(free, estimate):
            return sized
        rival = self._other_arm(ordered, found[0], self._robust_fit(ordered.threshold_mm))
        if rival is not None:  # the size-free estimate is doubted too: is it still confident?
            free = self._described(without_the_size, in_contact, rival, None).estimate
            if not _confident_and_distinct(free, estimate):
                return sized
        angle_deg = _angle_deg(estimate.normal, free.normal)
        sigmas = angle_deg / math.hypot(estimate.tilt_sigma_deg, free.tilt_sigma_deg)
        return _made_suspect(
            sized,
            f"{SUSPECT_PREFIX}the contact found without the part's size ({free.n_points} markers) passes "
            f"every check too and lies {angle_deg:.1f} deg from this one ({sigmas:.0f} times their noise): "
            "one of the two is not the part's face",
        )

    def _grown_with_the_face_scatter(self, measured: _Measured, grown: SensingResult) -> SensingResult:
        """The size-free contact grown again with an inlier band set from the clearly pushed-in markers'
        own scatter (:func:`on_the_face`), where the ``grown`` one kept too few of them (under
        :data:`MIN_CANDIDATE_SHARE`) and they scatter more than the band allowed; reported when that
        contact passes every check, still suspect (with a warning that says why); else ``grown``.

        Why: the beads behind the membrane ripple the markers on a face (0.1 mm in the simulator; 0.10-0.20
        mm seen on another renderer), more than the membrane at rest scatters, from which the band is set.
        On a fine grid a large face's markers then fall out of the band, the growth keeps a strip, and the
        plane of a strip is any plane through it (zoo seed 4, design 30, frame 5: 14 of 163 markers in
        contact, 35 deg off). But the pushed-in markers' scatter includes the drape's curvature where the
        face is small against the grid (3-8x the noise on an 8-12 mm grid, measured), too loose a band for
        every frame: it stands in only for a contact already in doubt, where the contact it grows passes
        every check (the pushed-in markers' share among them) and holds :data:`FACE_SCATTER_MIN_POINTS`
        markers or more (a face on which most of the measured markers' neighbourhoods lie), and the
        estimate stays suspect."""
        ordered = measured.ordered
        n_candidates = int(ordered.candidates.sum())
        if not holds_too_few_of_the_dent(grown.estimate.n_points, n_candidates):
            return grown
        heights = measured.absolute if measured.absolute is not None else measured.dent
        heights = replace(heights, depth_mm=heights.depth_mm[measured.order])  # in the canonical order
        noise = on_the_face(ordered.noise, ordered.points_J, heights, ordered.candidates, self._pitch)
        if noise == ordered.noise:
            return grown
        widened = replace(ordered, noise=noise, threshold_mm=noise.inlier_mm)
        regrown = self._fit(
            replace(measured, ordered=widened), self._contact(widened, None), search_size_mm=None
        )
        if (
            not isinstance(regrown, SensingResult)
            or regrown.estimate.quality != "ok"  # too few of them again, or another check fails
            or regrown.estimate.n_points < FACE_SCATTER_MIN_POINTS  # the scatter was the drape's
        ):
            return grown
        return _made_suspect(
            regrown,
            f"{SUSPECT_PREFIX}the contact was grown with an inlier band of {noise.inlier_mm:.2f} mm, set "
            "from the pushed-in markers' own scatter: the band of the membrane at rest "
            f"({ordered.threshold_mm:.2f} mm) kept {grown.estimate.n_points} of the {n_candidates} pushed-in "
            "markers",
        )

    def _without_points_in_doubt(
        self,
        points_J: np.ndarray,
        dent: Indentation,
        absolute: Indentation | None,
        observation: Observation,
        noise: NoiseScales,
    ) -> tuple[Indentation, Indentation | None, Observation]:
        """The indentations with the points in doubt unknown (NaN: neither in contact nor contradicting
        it), and the observation with a warning that counts each kind:

        - off the membrane (:func:`~softjig.sensing.contact.off_the_membrane`: the steps between
          neighbours at the noise of the indentation, ``noise.indentation_sigma_mm``, the base plate at
          the noise of a marker's height, ``noise.plane_sigma_mm``);
        - seen in either image as no marker looks (:meth:`~softjig.sensing.detect.Markers.lopsided`: its
          fit failed, or it is lopsided, a glint or a bubble's rim over one side of it, which moves its
          point millimetres in depth but, on a coarse grid or with noisy depths, within a step of its
          neighbours).
        """
        off = off_the_membrane(
            points_J,
            dent.depth_mm,
            pitch_mm=self._pitch,
            noise_mm=noise.indentation_sigma_mm,
            height_noise_mm=noise.plane_sigma_mm,
            min_points=self._minimum,
        )
        lopsided = ~off & observation.lopsided()
        if not (off.any() or lopsided.any()):
            return dent, absolute, observation
        doubt = off | lopsided
        dent, absolute = (
            None if d is None else replace(d, depth_mm=np.where(doubt, np.nan, d.depth_mm))
            for d in (dent, absolute)
        )
        warnings = []
        if off.any():
            warnings.append(
                f"{int(off.sum())} matched markers were left out: they lie off the membrane (inside the "
                f"base plate, or deeper or higher than their neighbours by more than a face tilted "
                f"{MAX_TILT_DEG:g} deg explains): stereo mismatches along a row?"
            )
        if lopsided.any():
            warnings.append(
                f"{int(lopsided.sum())} matched markers were left out: in one image they do not look like a "
                "marker (their fit failed, or they are lopsided beyond what the image's markers are): a "
                "glint or a bubble over them?"
            )
        return dent, absolute, replace(observation, warnings=(*observation.warnings, *warnings))

    def _size_free_instead(
        self, measured: _Measured, suspect: SensingResult, rival: RivalCheck | None, found: Found | None
    ) -> SensingResult:
        """The estimate of the size-free contact ``found`` (``None``: none grows), with a warning, where it
        passes every check and found another plane than the ``suspect`` estimate under the known face;
        else that one.
        Where the face under the known size is suspect for its ``rival`` (another face of that size that
        nothing contradicts either) and the size-free plane is neither, the size-free estimate is
        reported but suspect (:func:`_third_plane`).

        Where that suspect estimate's one doubt is its few markers
        (:meth:`_doubted_only_for_its_few_markers`), nothing contradicts either contact: the size-free
        one, whose flatness was checked, is reported, but suspect, with the other as its rival. A
        size-free estimate whose one doubt is the other arm of its V (:meth:`_other_arm`) is
        reported too, suspect, unless the face under the known size is that other arm: two searches then
        found it, and the estimate under the face stands."""
        if found is None:  # no plane grows without the size: the suspect estimate stands
            return suspect
        size_free = self._fit(measured, found, search_size_mm=None)
        if not isinstance(size_free, SensingResult):
            return suspect
        free = size_free.estimate
        doubts = _doubts_beyond_a_small_partial_contact(free)
        if doubts and not self._doubted_only_for_an_arm_the_face_is_not(free, found, suspect):
            return suspect
        if not _distinct_planes(suspect.estimate, free):  # one plane, doubted with the size
            return suspect
        size = measured.part_diameter_mm
        if self._doubted_only_for_its_few_markers(suspect.estimate):  # two contacts, neither contradicted
            angle_deg = _angle_deg(suspect.estimate.normal, free.normal)
            return _made_suspect(
                size_free,
                f"{SUSPECT_PREFIX}the contact under the part's {size:g} mm face, {suspect.estimate.n_points} "
                f"markers that nothing contradicts (too few to check), lies {angle_deg:.1f} deg from this "
                "one: the frame may show the membrane's wall beside a small contact",
            )
        reason = next(w for w in suspect.estimate.warnings if w.startswith(SUSPECT_PREFIX))
        if doubts:  # the other arm of its V, the one doubt let through above
            passed = "doubted only for another contact beside it"
        elif free.quality == "ok":
            passed = "which passes them"
        else:
            passed = "doubted only for its few markers in partial contact"
        note = (
            f"the contact searched under the part's {size:g} mm face failed its checks "
            f"({reason.removeprefix(SUSPECT_PREFIX)}); the contact found without the size, {passed}, is "
            "reported"
        )
        reported = replace(size_free, estimate=replace(free, warnings=(*free.warnings, note)))
        return _third_plane(reported, suspect, rival)

    def _doubted_only_for_an_arm_the_face_is_not(
        self, free: Estimate, found: tuple[Contact, RivalCheck | None], suspect: SensingResult
    ) -> bool:
        """Whether the one reason the size-free estimate ``free`` is suspect is its rival, the other arm of
        its V (``found[1]``, :meth:`_other_arm`), and the ``suspect`` face under the known size is
        another plane than that arm (their planes' normals further apart than :data:`DISTINCT_PLANE_SIGMAS`
        times their combined noise: the face's plane, as the arm's, not its calibrated normal)."""
        rival = found[1]
        if rival is None or _doubts_beyond_a_small_partial_contact(free) != 1:
            return False
        return _beyond_the_rival(suspect.plane.normal, suspect.estimate.tilt_sigma_deg, rival.normal_b, rival)

    def _doubted_only_for_its_few_markers(self, estimate: Estimate) -> bool:
        """Whether the one reason ``estimate`` is suspect is that it has too few markers to check
        (:func:`suspicions`): no marker contradicts its contact, nor does a rival."""
        reasons = sum(w.startswith(SUSPECT_PREFIX) for w in estimate.warnings)
        return reasons == 1 and estimate.n_points < fewest_to_check(self._minimum)

    def _fit(
        self,
        measured: _Measured,
        found: Found,
        *,
        search_size_mm: float | None,
    ) -> SensingResult | Refusal:
        """:meth:`fit`'s estimate of the ``measured`` frame from the contact ``found`` by :meth:`_contact`
        (searched under a face of ``search_size_mm``, or without a size: ``None``), checked and described
        with the part's size."""
        if not found:
            return found
        return self._described(
            measured, self._in_contact(measured, found[0], search_size_mm), found[1], search_size_mm
        )

    def _in_contact(self, measured: _Measured, contact: Contact, search_size_mm: float | None) -> _InContact:
        """The ``contact``'s markers as matched (it is in the canonical order) and plane, its lifted-off
        markers dropped (:func:`~softjig.sensing.contact.drop_lifted_off`)."""
        points_J, order = measured.points_J, measured.order
        used_in_order, plane = contact
        used = np.empty_like(used_in_order)
        used[order] = used_in_order
        if search_size_mm is None:  # under a known face, the plane is already the SVD fit of points_J[used]
            plane = fit_or_fail(points_J[used], self._minimum)
        kept, plane = drop_lifted_off(
            points_J,
            measured.dent,
            used,
            plane,
            clearance_mm=LIFT_OFF_SIGMAS * measured.ordered.noise.face_depth_sigma_mm,
            fit_plane=lambda points: fit_or_fail(points, self._minimum),
            min_points=self._minimum,
        )
        return _InContact(used, kept, plane)

    def _described(
        self,
        measured: _Measured,
        in_contact: _InContact,
        rival: SplitCheck | None,
        search_size_mm: float | None,
    ) -> SensingResult:
        """The estimate of the markers ``in_contact``, checked and described (:meth:`_fit`)."""
        observation, points_J, dent, ordered = (
            measured.observation, measured.points_J, measured.dent, measured.ordered
        )  # fmt: skip
        part_diameter_mm, noise = measured.part_diameter_mm, ordered.noise
        grown, used, plane = in_contact
        plane_depth = face_depth_mm(points_J, dent, plane)
        uncertainty, split = self._uncertainty(points_J, dent, used, grown, plane, plane_depth, noise)
        uncertainty = self._without_measured_frame(uncertainty, plane, observation)
        outside = just_outside(points_J[:, :2], used, self._pitch)
        contact = describe_contact(
            points_J[used, :2],
            plane,
            self._jig,
            noise_mm=dent.noise_mm,
            part_diameter_mm=part_diameter_mm,
            edge_face_depth_mm=plane_depth[outside],
        )
        violations = self._violations_of_chosen(points_J, used, plane, ordered.threshold_mm, dent, outside)
        holes = holes_in_the_dent(
            points_J,
            dent,
            used,
            plane,
            threshold_mm=ordered.threshold_mm,
            pitch_mm=self._pitch,
            plane_depth_mm=plane_depth,
            outside=outside,
        )
        estimate = self._estimate(
            observation,
            points_J,
            plane,
            used,
            contact,
            uncertainty,
            split,
            violations,
            rival,
            dent,
            int(ordered.candidates.sum()),
            part_diameter_mm,
            size_free_search=search_size_mm is None,
            dent_hole_gaps_mm=(plane.centroid_mm - points_J[holes]) @ plane.normal,
        )
        return SensingResult(
            estimate,
            observation.left,
            observation.right,
            observation.matches,
            points_J,
            used,
            plane,
            observation.frame,
            measured.identities,
            dent,
            contact,
            uncertainty,
        )

    def _violations_of_chosen(
        self,
        points_J: np.ndarray,
        used: np.ndarray,
        plane: PlaneFit,
        threshold_mm: float,
        dent: Indentation,
        outside: np.ndarray,
    ) -> int:
        """The markers that contradict the contact chosen
        (:func:`~softjig.sensing.contact.contact_violations`), with the holes beside it at
        :data:`~softjig.sensing.contact.BESIDE_HOLE_THRESHOLDS` (the choice between contacts kept the
        deeper ones)."""
        return contact_violations(
            points_J,
            used,
            plane,
            threshold_mm=threshold_mm,
            pitch_mm=self._pitch,
            dent=dent,
            beside_thresholds=BESIDE_HOLE_THRESHOLDS,
            outside=outside,
        )

    def _indentation(self, points_J: np.ndarray, ids: np.ndarray) -> tuple[Indentation, Indentation | None]:
        """Each marker's indentation against its reference marker (the rest shape where none is near) and,
        with a reference frame, against the rest shape (whose noise is the markers' absolute scatter)."""
        reference_xyz = self._reference.markers.xyz_mm
        reference_z = (
            reference_xyz[np.maximum(ids, 0), 2] if len(reference_xyz) else np.full(len(ids), np.nan)
        )
        known = ids >= 0
        if not known.all():
            unknown = points_J[~known]
            reference_z[~known] = rest_inner_height_mm(self._jig, unknown[:, 0], unknown[:, 1])
        if self._reference.scatter_mm is None:  # against the rest shape already
            return indentation(points_J, reference_z, pitch_mm=self._pitch), None
        rest_z = rest_inner_height_mm(self._jig, points_J[:, 0], points_J[:, 1])
        dent, absolute = indentations(points_J, (reference_z, rest_z), pitch_mm=self._pitch)
        return dent, absolute

    def _robust_fit(self, threshold_mm: float) -> PlaneFitFunction:
        """``points -> (inliers, plane)``: the robust fit with the contact's inlier distance."""
        minimum = self._minimum

        def fit(points: np.ndarray) -> tuple[np.ndarray, PlaneFit]:
            try:
                robust = fit_plane_robust(
                    points, threshold_mm=threshold_mm, min_inliers=min(minimum, len(points))
                )
            except InputError as exc:
                raise EstimationError(f"no plane could be fitted to the pushed-in markers: {exc}") from None
            return robust.inliers, robust.plane

        return fit

    def _contact(
        self,
        dent: Dent,
        part_diameter_mm: float | None,
        *,
        first: Found | None = None,
        other_arm: bool = True,
    ) -> Found:
        """The contact's markers (canonical order) and plane, under the known face (searched from every
        placement, given the ``first`` contact found under it) or size-free, and its rival's agreement
        (:meth:`_contact_under_known_face`, :meth:`_placement_search`; size-free,
        :meth:`_other_arm`, unless ``other_arm`` is false)."""
        fit = self._robust_fit(dent.threshold_mm)

        def size_free() -> Contact:
            return grow_contact(
                dent.points_J,
                dent.indentation,
                dent.candidates,
                pitch_mm=self._pitch,
                fit_plane=fit,
                threshold_mm=dent.threshold_mm,
                min_points=self._minimum,
            )

        if part_diameter_mm is None:
            used, plane = size_free()
            rival = self._other_arm(dent, (used, plane), fit) if other_arm else None
            # Of the two arms of a V, both plausible, the one that holds more markers is reported (a face
            # presses flat more of the membrane than the strip of wall beside its lowered edge), the other
            # stays its rival (the estimate is suspect either way).
            if rival is not None and rival.contact[0].sum() > used.sum():
                (used, plane), rival = rival.contact, rival.seen_from((used, plane))
        elif first is not None:
            found = self._placement_search(dent, part_diameter_mm / 2.0, fit, first)
            if not found:
                return found
            (used, plane), rival = found
        else:
            found = self._contact_under_known_face(dent, part_diameter_mm / 2.0, fit, size_free)
            if not found:
                return found
            (used, plane), rival = found
        if used.sum() < self._minimum:
            return Refusal(
                f"only {int(used.sum())} markers are in contact; at least {self._minimum} are needed "
                "(sensing.min_points)"
            )
        return (used, plane), rival

    def _footprint_misfit(self, dent: Dent, radius_mm: float, contact: Contact) -> FootprintMisfit:
        """How far the markers under a face of ``radius_mm`` on ``contact``'s plane, placed where it puts
        the face, are from what the face makes of the membrane
        (:func:`~softjig.sensing.contact.footprint_misfit`)."""
        return footprint_misfit(
            dent.points_J,
            dent.indentation,
            contact[0],
            contact[1],
            radius_mm,
            self._jig,
            noise_mm=dent.noise.indentation_sigma_mm,
        )

    def _likelier_face(
        self,
        measured: _Measured,
        suspect: SensingResult,
        face: Contact,
        rival: RivalCheck,
        size_free: Found | None,
    ) -> SensingResult:
        """The ``suspect`` estimate of the ``face`` found under the known size, or the estimate of its
        ``rival`` (another face of that size that no marker contradicts either) where two independent
        pieces of evidence both prefer the rival: the contact found without the size (``size_free``,
        ``None`` where none grows) lies nearer it, and the membrane under it fits it better
        (:meth:`~softjig.sensing.contact.FootprintMisfit.fits_better_than`). That estimate is suspect
        for the face in turn and says why.

        Why: the frame holds two plausible faces, so the estimate is suspect whichever is reported, but
        the one reported should be the likelier. The searches under the size chose between them by the
        markers contradicting each (none) and their size, which cannot tell the part's face from the
        strip of the membrane's wall meeting it in a V at its lowered edge: the wall is often the larger.
        The size-free growth starts from the deepest markers instead; given the part's size, the face
        predicts where the membrane is pressed and where it is at rest, and the wall placed as a face
        does not. Either alone is right less often than the searches' choice; both together mostly
        (benchmarks/RESULTS.md). The choice changes no estimate's quality: an estimate of the rival that
        is not suspect is not reported."""
        dent, radius_mm = measured.ordered, measured.part_diameter_mm / 2.0
        other = rival.contact
        if other[0].sum() < self._minimum:
            return suspect
        if not size_free:  # no plane grows without the size: no second piece of evidence
            return suspect
        free_normal = size_free[0][1].normal
        to_other, to_face = (_angle_deg(free_normal, c[1].normal) for c in (other, face))
        if to_other >= to_face:
            return suspect
        misfit, face_misfit = (self._footprint_misfit(dent, radius_mm, contact) for contact in (other, face))
        if not misfit.fits_better_than(face_misfit):
            return suspect
        weighed = self._fit(
            measured, (other, rival.seen_from(face)), search_size_mm=measured.part_diameter_mm
        )
        if not isinstance(weighed, SensingResult) or weighed.estimate.quality != "suspect":
            return suspect
        note = (
            "of two plausible faces of the part's size, this one is reported: it lies nearer the contact "
            f"found without the size ({to_other:.1f} against {to_face:.1f} deg) and fits the membrane under "
            f"it better ({misfit.rms_sigmas:.1f} against {face_misfit.rms_sigmas:.1f} sigmas RMS)"
        )
        estimate = weighed.estimate
        return replace(weighed, estimate=replace(estimate, warnings=(*estimate.warnings, note)))

    def _other_arm(self, dent: Dent, chosen: Contact, fit: PlaneFitFunction) -> RivalCheck | None:
        """The other arm of a V, as the ``chosen`` contact's rival: the contact grown from the
        clearly pushed-in markers that lie above ``chosen``'s plane beyond the inlier distance, where it
        has at least :data:`OTHER_ARM_SHARE` of ``chosen``'s markers, few markers contradict it (beyond
        the tolerated ones, at most :data:`~softjig.sensing.contact.TOLERATED_VIOLATION_SHARE` of its
        own: a doubt asks less than a choice, for which none may), it is as flat as ``chosen``
        (:func:`~softjig.sensing.selfcheck.rougher`, at :data:`ROUGHER_SIGNIFICANCE`) and its normal
        disagrees beyond their noise (:meth:`_rival`); else ``None``.

        Why: beside the lowered edge of a tilted face, the membrane's wall rises from the face's deepest
        markers as the face does, and the two meet in a V. The growth takes the arm its seed's robust fit
        takes, which can be the wall; the face's markers then lie above the wall's plane, where the
        membrane outside a face may lie, so no marker contradicts it (zoo seed 3, design 34, frame 20:
        "ok" and 25 deg off). Seen from the face instead, the wall is a rougher surface (it curves up to
        the rest shape) or a smaller one, and is not a rival. Of two plausible arms, the size-free search
        (:meth:`_contact`) reports the larger."""
        points_J = dent.points_J
        used, plane = chosen
        above = points_J @ plane.normal + plane.offset_mm > dent.threshold_mm
        seed = dent.candidates & ~used & above
        if seed.sum() < max(self._minimum, OTHER_ARM_SHARE * used.sum()):
            return None
        try:
            other = grow_contact(
                points_J,
                dent.indentation,
                seed,
                pitch_mm=self._pitch,
                fit_plane=fit,
                threshold_mm=dent.threshold_mm,
                min_points=self._minimum,
            )
        except EstimationError:  # no plane grows there: no rival (never a reason to refuse the estimate)
            return None
        if other[0].sum() < OTHER_ARM_SHARE * used.sum():
            return None
        rival = self._rival(points_J, chosen, other, dent.threshold_mm)  # None below 4 markers a side
        if (
            rival is None
            or rougher(points_J[other[0]], other[1], points_J[used], plane) < ROUGHER_SIGNIFICANCE
        ):
            return None  # they agree, or the other is a curved wall beside the face
        # A doubt, not a choice: the other arm stays a rival where the markers contradicting it beyond
        # the tolerated few are no more than that share again (a 160-marker face with 12 markers above
        # it, 8 tolerated, lost to a 67-marker wall: zoo seed 7, design 1, frame 10, "ok", 20 deg off).
        contradicting = self._contradicting(dent, other)
        return None if contradicting > TOLERATED_VIOLATION_SHARE * other[0].sum() else rival

    def _contact_under_known_face(
        self, dent: Dent, radius_mm: float, fit: PlaneFitFunction, size_free: Callable[[], Contact]
    ) -> Found:
        """The contact when the part's base radius is known, wherever the part stands on the jig, and the
        agreement with a rival contact that no marker contradicts either but whose normal is far from it
        (``None`` when there is none: the estimate is suspect when there is).

        - **The face searched from the indentation** (:meth:`_search_face`): from the jig axis (the
          paper's setting) and, when the dent's centroid lies :data:`OFF_AXIS_DENT_RADII` radii or more
          off the axis, from there too, keeping the one whose plane fewer markers contradict
          (:func:`~softjig.sensing.contact.contact_violations`), then the larger contact: right where the
          size-free growth takes the wall beside a small, steeply tilted part.
        - When no search finds a face, or only one of fewer than :data:`SELF_CHECK_MIN_POINTS` markers
          (too few to check), **the size-free contact cut to the face** (:meth:`_size_free_cut`).
        - **Rivals** (:meth:`_rival`): two searched faces, or a search's face and the cut, that no marker
          contradicts but whose normals disagree beyond their noise
          (:func:`~softjig.sensing.selfcheck.agreement`): the frame holds two plausible faces (the part's
          and a strip of the membrane's wall beside a small contact), and the estimate is suspect
          whichever is reported. A dent :data:`RIVAL_SEARCH_PITCHES` pitches or more off the axis (but
          under :data:`OFF_AXIS_DENT_RADII` radii) is searched from its centroid too, as a rival only.
          Without another rival, the other arm of a V beside the face is one (:meth:`_deeper_arm`).
        """
        points_J, candidates = dent.points_J, dent.candidates
        dent_centre = _mean_xy(points_J, candidates) if candidates.any() else np.zeros(2)
        starts = [None] if np.hypot(*dent_centre) < OFF_AXIS_DENT_RADII * radius_mm else [None, dent_centre]
        searches = [s for s in (self._search_face(dent, radius_mm, fit, start) for start in starts) if s]
        rival = None
        if len(searches) > 1:  # the one whose plane fewer markers contradict, then the larger contact
            scores = [(self._contradicting(dent, search), -search[0].sum()) for search in searches]
            best = min(range(len(scores)), key=scores.__getitem__)
            if scores[1 - best][0] == 0:  # the other one no marker contradicts either
                rival = self._rival(points_J, searches[best], searches[1 - best], dent.threshold_mm)
            searches = [searches[best]]
        elif (
            len(searches) == 1
            and searches[0][0].sum() < SELF_CHECK_MIN_POINTS + MIN_HALF_POINTS
            and np.hypot(*dent_centre) >= RIVAL_SEARCH_PITCHES * self._pitch
        ):
            rival = self._rival_search(dent, radius_mm, fit, searches[0], dent_centre)
        if not searches or searches[0][0].sum() < SELF_CHECK_MIN_POINTS:
            search = searches[0] if searches else None
            cut = self._size_free_cut(dent, radius_mm, size_free, search=search)
            if cut:
                if search is not None:  # suspect if it contradicts a face no marker contradicts either
                    rival = self._plausible_rival(points_J, search, cut, dent)
                return cut, rival
        if not searches:
            return Refusal(
                f"no {2 * radius_mm:g} mm face was found in the contact: fewer than {self._minimum} "
                "pushed-in markers lie under it (sensing.min_points); is the part's size right?"
            )
        return searches[0], rival if rival is not None else self._deeper_arm(dent, searches[0], fit)

    def _deeper_arm(self, dent: Dent, face: Contact, fit: PlaneFitFunction) -> RivalCheck | None:
        """With the part's size, the other arm of the V beside the ``face`` found (:meth:`_other_arm`),
        looked for only where the pushed-in markers above the face's plane and deeper than its median
        marker are as many as that arm needs (:data:`OTHER_ARM_SHARE` of the face's).

        Why: a rigid face presses the deepest markers of its dent; the membrane it drags down around it
        lies above its plane but is shallower. Beside a level face pushed deep, the search from the jig
        axis can settle on the wall beside its edge, tilted like the wall and meeting the face in a V at
        its edge markers: the face's markers lie above that plane, and nothing contradicts it (zoo seed 5,
        design 32, frame 4: a 42 x 52 mm box 19 mm off the axis, 1 deg tilt, 7.8 mm push, "ok" and 18 deg
        off). A face that covers the deepest of its dent, as every centred part's does, is not looked at
        again (the growth costs as much as the search: 65 % of the default pair's time, measured)."""
        used, plane = face
        depth = dent.indentation.depth_mm  # NaN (unknown) is neither a candidate nor deeper
        deeper = dent.candidates & ~used & (depth > np.median(depth[used]))
        if deeper.sum() < OTHER_ARM_SHARE * used.sum():
            return None
        above = dent.points_J[deeper] @ plane.normal + plane.offset_mm > dent.threshold_mm
        return self._other_arm(dent, face, fit) if above.sum() >= OTHER_ARM_SHARE * used.sum() else None

    def _contradicting(self, dent: Dent, contact: Contact) -> int:
        """How many markers contradict ``contact``'s plane being the face, as the choice between contacts
        counts them (:func:`~softjig.sensing.contact.contact_violations`)."""
        used, plane = contact
        return contact_violations(
            dent.points_J,
            used,
            plane,
            threshold_mm=dent.threshold_mm,
            pitch_mm=self._pitch,
            dent=dent.indentation,
        )

    def _placement_search(
        self,
        dent: Dent,
        radius_mm: float,
        fit: PlaneFitFunction,
        first: Found,
    ) -> Found:
        """The contact under a face of ``radius_mm`` searched (:meth:`_search_face`) from every placement
        of a grid over the clearly pushed-in markers (:func:`placement_grid`) where markers contradict
        the ``first`` one (:meth:`_contact_under_known_face`'s, with its rival), and its rival's agreement
        (``None`` when there is none); a :class:`~softjig.sensing.results.Refusal` where nothing
        contradicts that one (the estimate made of it stands) or no search finds a face.

        The two searches from the axis and the dent's centroid miss a small, steeply tilted face far off
        the axis, whose contact is a few markers beside a wall of as many. But a contact that no marker
        contradicts stays: a grid contact is no better evidence (a strip of wall beside a small face is
        often larger than the face's contact). Else the contacts are ranked by the markers that
        contradict their plane (:func:`~softjig.sensing.contact.contact_violations`), then by their size,
        then by their markers' RMS distance from their plane; the first is the contact. A rival is
        another contact that no marker contradicts whose normal disagrees with the first's beyond their
        noise (:meth:`_rival`), as between the two searches of :meth:`_contact_under_known_face`, whose
        own rival stands when its contact is ranked first.
        """
        points_J, candidates = dent.points_J, dent.candidates
        if first and self._contradicting(dent, first[0]) == 0:  # the estimate made of it stands
            return Refusal("no marker contradicts the contact found first: no placement is searched")
        contacts = [first[0]] if first else []
        spacing = max(self._pitch, PLACEMENT_GRID_RADII * radius_mm)
        for start in placement_grid(points_J[candidates, :2], spacing):
            search = self._search_face(dent, radius_mm, fit, start)
            if search and not any(np.array_equal(search[0], used) for used, _ in contacts):
                contacts.append(search)
        if not contacts:
            return first
        scores = [(self._contradicting(dent, c), -int(c[0].sum()), c[1].rms_residual_mm) for c in contacts]
        ranked = sorted(range(len(contacts)), key=scores.__getitem__)
        best = contacts[ranked[0]]
        if first and ranked[0] == 0 and first[1] is not None:  # its own rival stands
            return first
        for k in ranked[1:]:
            rival = None if scores[k][0] else self._rival(points_J, best, contacts[k], dent.threshold_mm)
            if rival is not None:
                return best, rival
        return best, None

    def _rival_search(
        self, dent: Dent, radius_mm: float, fit: PlaneFitFunction, search: Contact, start_xy: np.ndarray
    ) -> RivalCheck | None:
        """The robust plane of the pushed-in markers within ``radius_mm`` of ``start_xy`` (one fit, not a
        :meth:`_search_face`), as a rival of ``search`` when the two disagree and no marker contradicts
        either; else ``None``."""
        points_J, thr = dent.points_J, dent.threshold_mm
        selection = (dent.indentation.depth_mm > dent.indentation.noise_mm) & _within(
            points_J, start_xy, radius_mm
        )
        if selection.sum() < self._minimum:
            return None
        try:
            inliers, plane = fit(points_J[selection])
        except EstimationError:  # no plane there: no rival (never a reason to refuse the estimate)
            return None
        used = np.zeros(len(points_J), dtype=bool)
        used[np.flatnonzero(selection)[inliers]] = True
        rival = None if used.sum() < self._minimum else self._rival(points_J, search, (used, plane), thr)
        if rival is None:
            return None  # they agree: the violations (0.2 ms) are not counted
        contradicted = self._contradicting(dent, rival.contact) or self._contradicting(dent, search)
        return None if contradicted else rival

    def _plausible_rival(
        self, points_J: np.ndarray, search: Contact, cut: Contact, dent: Dent
    ) -> RivalCheck | None:
        """The ``search``'s face's disagreement with the ``cut`` (:meth:`_rival`), when no marker
        contradicts the search's face either; else ``None``."""
        return (
            None
            if self._contradicting(dent, search)
            else self._rival(points_J, cut, search, dent.threshold_mm)
        )

    def _rival(
        self, points_J: np.ndarray, chosen: Contact, other: Contact, threshold_mm: float
    ) -> RivalCheck | None:
        """``other``'s agreement with the ``chosen`` contact, with ``other``, when it contradicts it
        (:func:`~softjig.sensing.selfcheck.agreement`), else ``None``."""
        check = agreement(
            points_J[chosen[0]],
            chosen[1].normal,
            points_J[other[0]],
            other[1].normal,
            point_sigma_mm=threshold_mm / CONTACT_INLIER_SIGMAS,
            noise_factor=MODEL_ERROR_FACTOR,
        )
        if check is None or not check.suspect:
            return None
        return RivalCheck(check.angle_rad, check.noise_rad, check.normal_a, check.normal_b, contact=other)

    def _size_free_cut(
        self, dent: Dent, radius_mm: float, size_free: Callable[[], Contact], *, search: Contact | None
    ) -> Contact | Refusal:
        """The size-free contact (made only when needed: it costs more than a search) cut to the face: the
        face placed where that contact puts it (:func:`~softjig.sensing.contact.face_centre_xy`), and that
        contact's markers under it. Beside a ``search``'s contact (too small to check), it is taken only
        when it has enough markers to check and passes the checks (no violations, halves that agree); the
        caller makes it suspect when it contradicts a search's face that no marker contradicts either."""
        points_J = dent.points_J
        try:
            grown, grown_plane = size_free()
        except EstimationError as exc:
            return Refusal(str(exc))
        if grown.sum() < self._minimum:
            return Refusal(f"only {int(grown.sum())} markers grew into a contact")
        region = describe_contact(
            points_J[grown, :2],
            grown_plane,
            self._jig,
            noise_mm=dent.noise.indentation_sigma_mm,
            part_diameter_mm=2 * radius_mm,
        )
        centre = face_centre_xy(points_J[grown, :2], region, grown_plane, radius_mm, pitch_mm=self._pitch)
        # Half a pitch of slack (the footprint's markers stand for grid cells); the markers are already
        # the inliers of a robust fit: a least-squares refit suffices.
        selection = grown & under_face(points_J, grown_plane, radius_mm + self._pitch / 2.0, centre)
        if search is None:
            if selection.sum() < self._minimum:
                return Refusal(f"only {int(selection.sum())} markers of the grown contact lie under the face")
            return selection, fit_or_fail(points_J[selection], self._minimum)
        if selection.sum() < SELF_CHECK_MIN_POINTS:
            return Refusal("the grown contact under the face is too small to check")
        cut = (selection, fit_or_fail(points_J[selection], self._minimum))
        check = split_halves(
            points_J[selection],
            point_sigma_mm=dent.threshold_mm / CONTACT_INLIER_SIGMAS,
            noise_factor=MODEL_ERROR_FACTOR,
        )
        if check is None or check.suspect or self._contradicting(dent, cut) > 0:
            return Refusal("the grown contact under the face fails the self-check")
        return cut  # a larger contact that passes the self-check

    def _search_face(
        self, dent: Dent, radius_mm: float, fit: PlaneFitFunction, start_xy: np.ndarray | None = None
    ) -> Contact | Refusal:
        """The contact under a face of ``radius_mm``, searched from the indentation (from ``start_xy``,
        when given, instead of the jig axis).

        The face is a tilted disc (a polygon's inscribed disc), so its footprint on the membrane is an
        ellipse, not the paper's circle, and it is centred where the part stands, not on the jig axis.
        The face's centre is first taken on the jig axis (the centroid of the clearly pushed-in markers
        when none lies under a face there); the pushed-in markers within ``radius_mm`` of it are fitted
        robustly (:meth:`_fit_under_face`). The centre is then moved to where the contact found puts the
        face (:func:`~softjig.sensing.contact.face_centre_xy`: the footprint's centroid in full contact,
        one radius uphill of the lowered rim in partial contact), and the whole repeated until it moves
        by less than :data:`FACE_CENTRE_TOLERANCE_PITCHES` pitches (at most :data:`FACE_CENTRE_ROUNDS`
        times); a face found on the axis stays there when the contact puts its centre within
        :data:`CENTRED_SHARE` radii of it (a small contact's centre is uncertain by a pitch). The
        membrane's wall beside the lowered edge lies outside the ellipse; where the part lifts off, the
        one-sided robust fit rejects the markers below the face.
        """
        points_J, candidates = dent.points_J, dent.candidates
        pushed = dent.indentation.depth_mm > dent.indentation.noise_mm  # False where NaN (unknown)
        tolerance = FACE_CENTRE_TOLERANCE_PITCHES * self._pitch
        centre = np.zeros(2) if start_xy is None else np.asarray(start_xy, dtype=float)
        found: Contact | None = None
        for round_ in range(FACE_CENTRE_ROUNDS):
            try:
                under = self._fit_under_face(points_J, pushed, centre, radius_mm, fit)
            except EstimationError as exc:  # the robust fit found no plane: this search found no face
                return Refusal(str(exc))
            if under is None:
                if round_ == 0 and candidates.any():  # nothing under a centred face: start where the dent is
                    centre = _mean_xy(points_J, candidates)
                    continue
                break
            found = under
            used, plane = found
            region = describe_contact(
                points_J[used, :2],
                plane,
                self._jig,
                noise_mm=dent.noise.indentation_sigma_mm,
                part_diameter_mm=2 * radius_mm,
            )
            moved_to = np.array(
                face_centre_xy(points_J[used, :2], region, plane, radius_mm, pitch_mm=self._pitch)
            )
            if np.hypot(*(moved_to - centre)) < tolerance:
                break
            if not centre.any() and np.hypot(*moved_to) < CENTRED_SHARE * radius_mm:
                break  # about centred: kept on the axis (a small contact's centre is uncertain by a pitch)
            centre = moved_to
        if found is None:
            return Refusal(
                f"only {int((pushed & _within(points_J, centre, radius_mm)).sum())} pushed-in markers lie "
                f"within {radius_mm:g} mm of the contact's centre ({centre[0]:+.1f}, {centre[1]:+.1f}) mm; "
                f"at least {self._minimum} are needed (sensing.min_points): is the part's size right?"
            )
        return found

    def _fit_under_face(
        self, points_J: np.ndarray, pushed: np.ndarray, centre_xy: np.ndarray, radius_mm: float, fit
    ) -> Contact | None:
        """The robust contact under a face of ``radius_mm`` centred above ``centre_xy`` (``None``: too few).

        The pushed-in markers within ``radius_mm`` of the centre are fitted robustly (their plane gives
        the tilt), then only those under the face (within ``radius_mm`` of its centre *measured in the
        face's plane*, :func:`~softjig.sensing.contact.under_face`), for :data:`UNDER_FACE_ROUNDS` rounds
        at most."""
        selection = pushed & _within(points_J, centre_xy, radius_mm)
        if selection.sum() < self._minimum:
            return None
        plane = None
        for _ in range(UNDER_FACE_ROUNDS):
            inliers, plane = fit(points_J[selection])
            used = np.zeros(len(points_J), dtype=bool)
            used[np.flatnonzero(selection)[inliers]] = True
            new_selection = pushed & under_face(points_J, plane, radius_mm, tuple(centre_xy))
            if np.array_equal(new_selection, selection) or new_selection.sum() < self._minimum:
                break
            selection = new_selection
        return used, plane

    def _uncertainty(
        self,
        points_J: np.ndarray,
        dent: Indentation,
        used: np.ndarray,
        grown: np.ndarray,
        plane: PlaneFit,
        plane_depth: np.ndarray,
        noise: NoiseScales,
    ) -> tuple[NormalUncertainty, SplitCheck | None]:
        """The normal's uncertainty: the fit's statistics, the spread between the narrowest and widest
        plausible contacts, the model-error factor, what the split halves show beyond their noise, and
        the depths' scale error (``ToleranceConfig.depth_scale_error``); and the split check itself."""
        minimum = self._minimum
        uncertainty = normal_uncertainty(points_J[used], plane, floor_mm=UNCERTAINTY_FLOOR_MM)
        narrow, wide = ambiguous_selection(
            points_J,
            dent,
            used,
            grown & ~used,
            plane,
            clearance_mm=LIFT_OFF_SIGMAS * noise.face_depth_sigma_mm,
            margin_mm=noise.face_depth_sigma_mm,
            face_depth=plane_depth,
        )
        if narrow.sum() >= minimum and not np.array_equal(narrow, wide):
            # ``plane`` is the fit of ``points_J[used]``: not fitted again where a selection is ``used``.
            uncertainty = with_spread_between(
                uncertainty,
                plane.normal
                if np.array_equal(narrow, used)
                else fit_or_fail(points_J[narrow], minimum).normal,
                plane.normal if np.array_equal(wide, used) else fit_or_fail(points_J[wide], minimum).normal,
            )
        uncertainty = inflated(uncertainty, MODEL_ERROR_FACTOR)
        split = split_halves(
            points_J[used],
            point_sigma_mm=max(noise.plane_sigma_mm, UNCERTAINTY_FLOOR_MM),
            noise_factor=MODEL_ERROR_FACTOR,
        )
        if split is not None and split.excess_rad > 0:  # what the halves show beyond their noise
            uncertainty = with_spread_between(
                uncertainty, split.normal_a, split.normal_b, share=split.excess_rad / split.angle_rad
            )
        uncertainty = with_depth_scale_error(uncertainty, plane.normal, self._depth_scale_error)
        return uncertainty, split

    def _without_measured_frame(
        self, uncertainty: NormalUncertainty, plane: PlaneFit, observation: Observation
    ) -> NormalUncertainty:
        """With the config's camera poses (not measured) and no calibration, the stereo head's rotation
        error (its tolerance per axis, ``tolerances.camera_rotation_deg``) tilts the normal about x and y
        by that much times the oil's index (an angle floor of ``sqrt(2) n_oil`` tolerances). With the
        poses measured on the reference frame (``"membrane"``, ``"reference fiducials"``), the
        measurement's own tilt uncertainty takes the tolerance's place. Where the reference frame could
        not level the head because its markers fit as well in several places, the RMS of those
        alignments' tilts takes it where larger (``ReferenceMarkers.unlevelled_tilt_deg``): the head is
        tilted about as much as one of them, which one unknown (zoo: the 13 such designs of seeds 0-9 had
        heads turned 0.32-1.57 deg, 11 over 0.75, against a tolerance of 0.5 deg per axis, and a 1-sigma
        coverage of 18-49 % with the tolerance's floor).

        Why the index: the cameras see the markers at their apparent depth (compressed by about
        ``1 / n_oil`` in the oil, paraxially), and a rotated head rotates that apparent scene; the
        refracted triangulation maps apparent depth back to true depth with slope ``n_oil`` in the oil,
        so a slope error ``delta`` of the apparent surface is ``n_oil delta`` of the true one (the zoo's
        coverage with and without the index: ``benchmarks/RESULTS.md``). A pose measured by the reference
        frame's fiducials carries no floor, as the fiducials' own poses in each frame carry none.
        """
        source = observation.frame.source
        if source == "fiducials" or self._calibration is not None:
            return uncertainty
        jig = self._jig
        markers = self._reference.markers
        level = markers.head_level
        if source != "config" and level is not None:  # the head's pose measured on the reference frame
            head_rad = np.radians(level.tilt_sigma_deg)  # already both axes' (root-sum-square)
        else:
            head_rad = math.sqrt(2.0) * np.radians(jig.tolerances.camera_rotation_deg)
            if source == "config" and markers.unlevelled_tilt_deg is not None:
                head_rad = max(head_rad, np.radians(markers.unlevelled_tilt_deg))
        return with_angle_floor(uncertainty, plane.normal, head_rad * jig.medium.oil_refractive_index)

    def _estimate(
        self,
        observation: Observation,
        points_J: np.ndarray,
        plane: PlaneFit,
        used: np.ndarray,
        contact: ContactRegion,
        uncertainty: NormalUncertainty,
        split: SplitCheck | None,
        violations: int,
        rival: SplitCheck | None,
        dent: Indentation,
        n_candidates: int,
        part_diameter_mm: float | None,
        *,
        size_free_search: bool,
        dent_hole_gaps_mm: np.ndarray,
    ) -> Estimate:
        """The reported estimate, with its warnings and the self-check's reasons (``size_free_search``: the
        contact was grown without the part's size; ``dent_hole_gaps_mm``: how far below the plane the holes
        in the dent lie, :func:`~softjig.sensing.contact.holes_in_the_dent`)."""
        part_centre = None
        if part_diameter_mm is not None:
            part_centre = face_centre_xy(
                points_J[used, :2], contact, plane, part_diameter_mm / 2.0, pitch_mm=self._pitch
            )
        warnings = list(observation.warnings)
        n_used = int(used.sum())
        if contact.partial:
            warnings.append(
                f"partial contact: the part lifts off towards azimuth {contact.lift_azimuth_deg:.0f} deg; "
                "only the markers in contact were fitted"
            )
        suspect = suspicions(
            split,
            violations,
            plane,
            contact,
            part_diameter_mm,
            self._jig,
            n_used,
            size_free_search=size_free_search,
            dent_hole_gaps_mm=dent_hole_gaps_mm,
        )
        if rival is not None:
            suspect.append(
                f"suspect: another contact fits the frame as well, its normal "
                f"{np.degrees(rival.angle_rad):.1f} deg from this one's ({rival.sigmas:.0f} times their "
                "noise): the frame may show the membrane's wall beside a small contact"
            )
        if size_free_search and holds_too_few_of_the_dent(n_used, n_candidates):
            suspect.append(
                f"suspect: only {n_used} of the {n_candidates} clearly pushed-in markers were fitted: a face "
                "presses most of its dent, the plane may be a strip of the membrane's wall"
            )
        warnings.extend(suspect)
        push = self._reference.height_at_axis_mm - dent.zero_mm - plane.z_at(0.0, 0.0)
        return Estimate(
            quality="suspect" if suspect else "ok",
            push_depth_mm=float(push),
            tilt_sigma_x_deg=float(np.degrees(uncertainty.tilt_sigma_x_rad)),
            tilt_sigma_y_deg=float(np.degrees(uncertainty.tilt_sigma_y_rad)),
            tilt_sigma_deg=float(np.degrees(uncertainty.tilt_sigma_rad)),
            normal_covariance=tuple(map(tuple, np.asarray(uncertainty.covariance, dtype=float).tolist())),
            contact_area_mm2=contact.area_mm2,
            contact_centroid_xy_mm=contact.centroid_xy_mm,
            contact_outline_xy_mm=tuple(map(tuple, np.asarray(contact.outline_xy_mm, dtype=float).tolist())),
            contact_partial=contact.partial,
            part_centre_xy_mm=part_centre,
            lift_azimuth_deg=contact.lift_azimuth_deg,
            indentation_reference=self._reference.markers.source,
            **_common_fields(
                observation, plane, self._calibration, "refractive", part_diameter_mm, n_used, warnings
            ),
        )
