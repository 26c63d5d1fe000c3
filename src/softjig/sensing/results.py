"""What an estimate is and what led to it: the result types of :mod:`softjig.sensing.estimator`.

:class:`Estimate` is what users and robots get (its JSON form is ``DESIGN.md``'s command-line contract);
:class:`SensingResult` adds the markers, matches and fits behind it, for overlays and analysis;
:class:`Observation` is what both methods' front end found; :class:`Refusal` is an expected outcome that
gives no result ("too few markers"), returned with its reason instead of raised.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np

from softjig.geometry import PlaneFit
from softjig.sensing.contact import ContactRegion, Indentation
from softjig.sensing.detect import Markers
from softjig.sensing.identities import MarkerIdentities
from softjig.sensing.jigframe import JigFrame
from softjig.sensing.stereo import StereoMatches
from softjig.sensing.uncertainty import NormalUncertainty

#: How the self-check's reasons begin among an :class:`Estimate`'s ``warnings`` (its ``quality`` is
#: ``"suspect"`` when there is one).
SUSPECT_PREFIX = "suspect: "

__all__ = ["Estimate", "Markers", "Observation", "Refusal", "SensingResult"]


@dataclass(frozen=True)
class Estimate:
    """One stereo pair's estimate of the part's orientation, as reported to users and robots.

    Attributes
    ----------
    normal : unit principal normal in J, pointing into the part (calibrated when ``calibrated``).
    tilt_x_deg, tilt_y_deg : tilt angles ``Ax = atan2(-n_y, n_z)``, ``Ay = atan2(n_x, n_z)`` (deg).
    push_depth_mm : how far the fitted plane lies below the rest membrane on the jig axis (mm).
    n_points : markers used in the plane fit.
    rms_residual_mm : RMS distance of those markers to the plane (mm).
    frame_source : ``"fiducials"``, ``"membrane"`` (the config's, levelled on the unloaded reference
        frame) or ``"config"``: where the cameras' pose in J came from.
    warnings : things a user should know about this estimate.
    method : ``"refractive"`` or ``"paper"``.
    calibrated : whether a tilt calibration was applied.
    raw_tilt_x_deg, raw_tilt_y_deg : tilt angles before calibration (deg).
    part_diameter_mm : the part's base diameter given by the user (mm), or ``None``.
    n_markers_left, n_markers_right, n_matches : detections and stereo matches.
    tilt_sigma_x_deg, tilt_sigma_y_deg : 1-sigma errors of the tilt angles (``refractive`` only).
    tilt_sigma_deg : 1-sigma angle between the estimated and the true normal (deg), with what the
        self-check's split halves show beyond the noise; for ``paper``, of its (compressed) raw normal.
    normal_covariance : (3, 3) covariance of the normal, as nested lists (``refractive`` only).
    contact_area_mm2, contact_centroid_xy_mm, contact_outline_xy_mm : the contact footprint: area,
        centroid ``(x, y)`` in J (the part's position on the jig) and outline (``refractive`` only).
    contact_partial : whether the part lifts off on some side (``refractive`` only).
    part_centre_xy_mm : where the centre of the part's face lies, ``(x, y)`` in J (mm), when the part's
        diameter is known (``refractive`` only): the contact's centroid in full contact, one radius uphill
        of the face's rim in partial contact (:func:`~softjig.sensing.contact.face_centre_xy`).
    lift_azimuth_deg : towards which azimuth it lifts off, if it does.
    indentation_reference : what indentations were measured against (``"reference frame"`` or
        ``"rest shape"``).
    quality : ``"ok"``, or ``"suspect"`` when a self-check of the frame's own evidence says the estimate
        may be wrong; the reasons are among ``warnings`` (they start with ``"suspect: "``). The exit code
        is 0 either way: a robot should not act on a suspect estimate without a second look.
    """

    normal: tuple[float, float, float]
    tilt_x_deg: float
    tilt_y_deg: float
    push_depth_mm: float
    n_points: int
    rms_residual_mm: float
    frame_source: str
    warnings: tuple[str, ...]
    method: str
    calibrated: bool
    raw_tilt_x_deg: float
    raw_tilt_y_deg: float
    part_diameter_mm: float | None
    n_markers_left: int
    n_markers_right: int
    n_matches: int
    tilt_sigma_x_deg: float | None = None
    tilt_sigma_y_deg: float | None = None
    tilt_sigma_deg: float | None = None
    normal_covariance: tuple[tuple[float, ...], ...] | None = None
    contact_area_mm2: float | None = None
    contact_centroid_xy_mm: tuple[float, float] | None = None
    contact_outline_xy_mm: tuple[tuple[float, float], ...] | None = None
    contact_partial: bool | None = None
    part_centre_xy_mm: tuple[float, float] | None = None
    lift_azimuth_deg: float | None = None
    indentation_reference: str | None = None
    quality: str = "ok"

    def to_dict(self) -> dict:
        """The JSON form (``DESIGN.md``'s command-line contract): plain floats, lists and strings."""

        def plain(value):
            if isinstance(value, tuple | list):
                return [plain(v) for v in value]
            return value

        return {key: plain(value) for key, value in asdict(self).items()}


@dataclass(frozen=True)
class SensingResult:
    """Everything one run of the pipeline found, for overlays and analysis.

    Attributes
    ----------
    estimate : the reported estimate.
    left, right : the markers detected in each image (fiducials excluded).
    matches : the stereo matches (indices into ``left`` and ``right``).
    points_J : (M, 3) the triangulated matches in J (mm), one per match.
    used : (M,) which of them were fitted (the paper's crop, or the contact found).
    plane : the fitted plane (uncalibrated).
    frame : the cameras' pose in J and its source.
    identities : each point's reference marker and displacement (``refractive``).
    indentation : each point's indentation (``refractive``).
    contact : the contact footprint (``refractive``).
    uncertainty : the normal's uncertainty (``refractive``).
    """

    estimate: Estimate
    left: Markers
    right: Markers
    matches: StereoMatches
    points_J: np.ndarray
    used: np.ndarray
    plane: PlaneFit
    frame: JigFrame
    identities: MarkerIdentities | None = None
    indentation: Indentation | None = None
    contact: ContactRegion | None = None
    uncertainty: NormalUncertainty | None = None


@dataclass(frozen=True)
class Observation:
    """What both methods share: the detected markers, their matches and the cameras' pose.

    Attributes
    ----------
    left, right : markers detected in each image, fiducials excluded.
    matches : the stereo matches.
    frame : the cameras' poses in J.
    warnings : from the front end (e.g. fiducials not found).
    """

    left: Markers
    right: Markers
    matches: StereoMatches
    frame: JigFrame
    warnings: tuple[str, ...] = field(default=())

    @property
    def left_xy_px(self) -> np.ndarray:
        """(M, 2) matched centres in the left image."""
        return self.left.xy_px[self.matches.left_index]

    @property
    def right_xy_px(self) -> np.ndarray:
        """(M, 2) matched centres in the right image."""
        return self.right.xy_px[self.matches.right_index]

    def lopsided(self) -> np.ndarray:
        """(M,) which matches do not look like a marker in either image
        (:meth:`~softjig.sensing.detect.Markers.lopsided`): their points are in doubt."""
        return self.left.lopsided()[self.matches.left_index] | self.right.lopsided()[self.matches.right_index]


@dataclass(frozen=True)
class Refusal:
    """An expected outcome that gives no result, and why (e.g. too few markers under a face).

    Falsy, so that ``found = search(...); if not found: ...`` reads as it means; the estimator raises
    :class:`~softjig.errors.EstimationError` with ``reason`` only when no other way is left.
    """

    reason: str

    def __bool__(self) -> bool:
        return False
