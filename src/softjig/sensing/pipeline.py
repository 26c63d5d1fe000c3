"""From a rectified stereo pair to the part's principal normal: the paper's method and ours.

Both methods share the front end, each stage in its own module:

1. markers in each image: LoG at the scale implied by the markers' size in the image, local maxima
   (on a downsampled pyramid level), and a maximum-likelihood fit of the marker model for the sub-pixel
   centre (:mod:`softjig.sensing.detect`, :mod:`softjig.sensing.subpixel`; the paper's quadratic fit
   with ``refine="quadratic"``);
2. the cameras' pose in J from the fiducials, or the config's (:mod:`softjig.sensing.jigframe`), and the
   markers on the fiducials dropped;
3. stereo matching on rows within a tolerance and a disparity window implied by the jig's geometry, as
   a one-to-one global assignment (:mod:`softjig.sensing.stereo`).

``method="paper"`` then does exactly what Sakuma et al. publish ("Optical Sensing"): pinhole
triangulation as if the cameras looked through air, the points within the part's base radius of the jig
axis, an SVD plane. Its depths come out compressed (by about the oil's index), which the paper's tilt
calibration ``S`` absorbs; its push depth is measured from the rest membrane as the same triangulation
sees it, so zero push reads zero, and stays compressed by the same factor.

``method="refractive"`` (the default) fixes the paper's known weaknesses:

- each marker is triangulated through the plate and the oil by Snell's law
  (:mod:`softjig.sensing.refractive`): metric depths, no robot calibration needed for the tilt;
- the contact region is found from each marker's indentation against the unloaded jig (a reference
  frame, or the nominal rest shape), not from a part size (:mod:`softjig.sensing.contact`); when the
  part's size is given, only under the tilted face's elliptical footprint;
- the plane is fitted robustly, and the markers where the face would not reach below the unloaded
  membrane are dropped, so markers where the part lifts off do not pull it
  (:mod:`softjig.sensing.robust`, :func:`~softjig.sensing.contact.drop_lifted_off`), and partial contact
  is flagged;
- the normal comes with its covariance and 1-sigma tilt errors (:mod:`softjig.sensing.uncertainty`);
- the contact footprint gives the contact's position (x, y) on the jig, and, when the part's size is
  given, the centre of its face; every marker gets an identity and a 3-D displacement
  (:mod:`softjig.sensing.identities`).

The work is done by an :class:`~softjig.sensing.estimator.Estimator`, built once from the jig and the
method (:mod:`softjig.sensing.estimator`; its stages in :mod:`softjig.sensing.stages`, the plane fits in
:mod:`softjig.sensing.fitting`, the result types in :mod:`softjig.sensing.results`). The functions here
are the one-shot forms: each builds an estimator (about a frame's work), so a loop over frames builds one
:class:`~softjig.sensing.estimator.Estimator` and calls its ``estimate`` instead.
"""

from __future__ import annotations

import numpy as np

from softjig.config import JigConfig
from softjig.sensing.estimator import DEFAULT_METHOD, METHODS, Estimator
from softjig.sensing.fitting import NoiseScales
from softjig.sensing.identities import ReferenceMarkers
from softjig.sensing.results import Estimate, Markers, Observation, Refusal, SensingResult
from softjig.sensing.setup import SensingSetup, sensing_setup
from softjig.tilt_calibration import TiltCalibration

__all__ = [
    "DEFAULT_METHOD",
    "METHODS",
    "Estimate",
    "Estimator",
    "Markers",
    "NoiseScales",
    "Observation",
    "Refusal",
    "SensingResult",
    "SensingSetup",
    "estimate_pair",
    "observe_pair",
    "reference_from_pair",
    "sensing_setup",
]


def estimate_pair(
    left: np.ndarray,
    right: np.ndarray,
    jig: JigConfig,
    *,
    part_diameter_mm: float | None = None,
    calibration: TiltCalibration | None = None,
    method: str = DEFAULT_METHOD,
    reference: ReferenceMarkers | None = None,
    timings: dict[str, float] | None = None,
) -> SensingResult:
    """Estimate the principal normal of the part on the jig from one rectified stereo pair.

    A one-shot :class:`~softjig.sensing.estimator.Estimator` (``Estimator(jig, method=method,
    reference=reference, calibration=calibration).estimate(left, right, ...)``): see there for the
    parameters, results and errors. Building it reads the jig's model from the disk cache (a fraction of
    a frame's work; its first build derives it): a loop over frames builds one estimator all the same
    and calls ``estimate`` for each.
    """
    estimator = Estimator(jig, method=method, reference=reference, calibration=calibration)
    return estimator.estimate(left, right, part_diameter_mm=part_diameter_mm, timings=timings)


def observe_pair(left: np.ndarray, right: np.ndarray, jig: JigConfig) -> Observation:
    """Check a stereo pair, find the jig frame, detect and match the markers (both methods' front end):
    :meth:`Estimator.observe <softjig.sensing.estimator.Estimator.observe>` of a one-shot estimator."""
    return Estimator(jig).observe(left, right)


def reference_from_pair(left: np.ndarray, right: np.ndarray, jig: JigConfig) -> ReferenceMarkers:
    """Triangulate a stereo pair of the unloaded jig into the reference for indentations and identities:
    :meth:`Estimator.reference_from_pair <softjig.sensing.estimator.Estimator.reference_from_pair>` of a
    one-shot estimator.

    Raises
    ------
    EstimationError
        Fewer markers than ``sensing.min_points`` were matched.
    """
    return Estimator(jig).reference_from_pair(left, right)
