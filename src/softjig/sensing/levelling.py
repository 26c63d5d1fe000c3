"""The stereo head levelled on the unloaded membrane: the cameras' pose in J measured without fiducials.

When the fiducials are out of view, the cameras' pose in J comes from the config, and the head is never
mounted exactly as drawn (a few tenths of a degree). A tilted head tilts every triangulated point, and
through the oil the error of the part's normal is about the oil's index times the head's tilt: no plane
fit can remove it (``benchmarks/RESULTS.md``, "where the accuracy goal stands").

The unloaded jig is itself a calibration target: its markers lie on the rest membrane, whose shape and
marker layout the config describes (drawn, or surveyed). Triangulated with the config's poses, the
reference frame's markers are the rest markers moved by the head's error: a rigid motion ``C`` of J, to
first order (the head's rotation about its own centre, and its shift, map every point the same way). So
``C`` is measured as the rigid motion that takes the triangulated markers onto the rest markers (nearest
neighbours in ``(x, y)``, a trimmed least-squares rigid fit, iterated as ICP), and the cameras' poses are
corrected to ``C @ T_J_cam``. Because the refraction at the plate depends on the cameras' pose relative to
it, the markers are triangulated again with the corrected poses and the fit repeated until the correction
is below its own uncertainty (two or three rounds).

The markers are a lattice, so the fit has aliases: shifted by a pitch and tilted to match, the markers fit
the rest markers almost as well, only the dome's heights tell them apart. ICP is therefore started from
shifts half a pitch apart over as far as the mounting's tolerances move the membrane (three lateral
sigmas, :meth:`HeadPrior.lateral_sigma_mm`), the best alignments are refined as above, and they are
compared by their posterior (the markers' fit and the prior of the head's mounting); a level about as
probable in two places is not used (:class:`AmbiguousLevel`).

What it measures: the tilt comes from the rest markers' heights across the membrane (a tilted head sees
one side of the dome higher than the other), the shift and the spin from the layout. A membrane whose
rest shape departs from the config symmetrically (a dome a little higher or lower) does not tilt the
level; an asymmetric departure does, by its slope across the membrane, as it would tilt any survey. The
fit's covariance (from its residuals) gives the level's own uncertainty, and a level less certain than
the head's mounting tolerance, or found with too few markers, is not used.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np

from softjig.config import CameraConfig, JigConfig
from softjig.errors import InputError
from softjig.geometry import pose_from_rotation_translation

if TYPE_CHECKING:
    from scipy.spatial import cKDTree

# scipy.spatial (0.1 s to import) is imported where a level is measured, not by every estimate's start-up.

#: Fewest rest markers a level is fitted to (six unknowns; a spread of markers over the membrane).
MIN_LEVEL_MARKERS = 12
#: Nearest-neighbour pairs farther apart than this share of the marker pitch are not the same marker.
MATCH_REACH_PITCHES = 0.5
#: Pairs whose residual exceeds this many times the median residual are dropped from the rigid fit.
TRIM_MEDIAN_FACTOR = 3.0
#: A fit whose markers lie farther than this share of the pitch (RMS) from the rest markers is refused.
MAX_RMS_PITCHES = 0.25
#: Two alignments whose -2 log posteriors differ by less than this are as probable (odds below e^5).
AMBIGUITY = 10.0
#: The residual RMS the alignments' scores are measured against is at least this (mm).
MIN_RMS_MM = 1e-3
ICP_MAX_STEPS = 20
LEVEL_MAX_ROUNDS = 4
#: The alignments are searched from shifts of the markers up to this many of the head's lateral sigmas
#: (:meth:`HeadPrior.lateral_sigma_mm`) each way, half a pitch apart.
SEARCH_LATERAL_SIGMAS = 3.0
#: The search's ICP runs on at most this many of the markers, spread over them (every k-th); the
#: alignments it finds are refined on all of them.
SEARCH_MARKERS = 150
#: The best alignments of the search (by the first-order score) that are refined and compared.
REFINED_ALIGNMENTS = 3
#: A round's correction below this (rad, and mm) ends the rounds: far below any level's uncertainty.
LEVEL_TOLERANCE = 1e-6
#: A level improves on the config's poses where the F test of its six parameters against none (nested
#: least squares: the markers' squared distances from the rest markers) rejects "no improvement" at this
#: level of significance (:func:`improves_on_the_config`).
IMPROVEMENT_SIGNIFICANCE = 1e-3


@dataclass(frozen=True)
class HeadLevel:
    """The stereo head's pose error measured on the unloaded reference frame.

    Attributes
    ----------
    T_correction : (4, 4) the rigid motion of J taking the config's camera poses to the measured ones:
        ``T_J_cam (measured) = T_correction @ T_J_cam (config)`` (read-only).
    n_markers : rest markers the last fit used (0 when measured by the fiducials).
    rms_residual_mm : RMS distance of those markers from the rest markers after the fit (mm): the layout's
        and the rest shape's own departures from the config, plus the triangulation's noise (``nan`` when
        measured by the fiducials).
    tilt_sigma_deg : 1-sigma uncertainty of the level's tilt (its rotation about x and y, root-sum-square),
        from the fit's covariance (deg; 0 when measured by the fiducials, whose poses carry none either).
    source : ``"membrane"`` (levelled on the unloaded membrane: :func:`level_head`) or ``"reference
        fiducials"`` (the pose the reference frame's fiducials gave, kept for frames that lose them:
        :func:`from_fiducials`).
    """

    T_correction: np.ndarray
    n_markers: int
    rms_residual_mm: float
    tilt_sigma_deg: float
    source: str = "membrane"

    @property
    def rotation_deg(self) -> float:
        """The angle of the head's rotation error (deg)."""
        cos = (np.trace(self.T_correction[:3, :3]) - 1.0) / 2.0
        return float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))

    @property
    def tilt_deg(self) -> float:
        """How far the correction turns J's z axis (deg): the head's tilt error, which tilts the normal
        (its spin about z does not)."""
        return _tilt_deg(self.T_correction)

    @property
    def shift_mm(self) -> np.ndarray:
        """``(3,)`` the correction's translation (mm): near J's axis, how far it moves the markers."""
        return self.T_correction[:3, 3].copy()


@dataclass(frozen=True)
class AmbiguousLevel:
    """Why the head could not be levelled when the markers fit the rest markers about as well in several
    places (a shift of about a pitch trades against a tilt), and how far each of those alignments tilts
    the head.

    Attributes
    ----------
    reason : what went wrong, as :func:`level_head`'s other refusals say it (also ``str(self)``).
    tilts_deg : for each alignment as probable as the best (within :data:`AMBIGUITY`), the tilt of its
        correction (deg, :attr:`HeadLevel.tilt_deg`): with the config's poses, the head is likely tilted
        by about that much, whichever is right.
    """

    reason: str
    tilts_deg: tuple[float, ...]

    def __str__(self) -> str:
        return self.reason

    @property
    def rms_tilt_deg(self) -> float:
        """The RMS of :attr:`tilts_deg` (deg): the head's likely tilt in the config's poses, as it is
        tilted about as much as one of the alignments, which one unknown."""
        return float(np.sqrt(np.mean(np.square(self.tilts_deg))))


def _tilt_deg(T: np.ndarray) -> float:
    """How far the rigid motion ``T`` (4, 4) turns J's z axis (deg)."""
    return float(np.degrees(np.arccos(np.clip(T[2, 2], -1.0, 1.0))))


@dataclass(frozen=True)
class _RigidFit:
    T: np.ndarray  # (4, 4): rest ~ T @ points
    n: int
    rms_mm: float
    fitted: np.ndarray  # (n, 3) the paired markers moved by T (mm)
    residuals: np.ndarray  # (n, 3) their offsets from their rest markers (mm)

    @property
    def covariance(self) -> np.ndarray:
        """(6, 6) of (rotation vector, translation) about the fitted points' centroid (computed for the
        chosen alignment only: most of the search's are discarded)."""
        return _fit_covariance(self.fitted, self.residuals)


def rigid_fit(points: np.ndarray, targets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The rotation ``R`` and translation ``t`` minimising ``sum |R p_i + t - q_i|^2``: Kabsch's solution,
    the SVD of the centred points' 3x3 cross-covariance with the reflection removed.

    Written out rather than SciPy's ``Rotation.align_vectors`` (the same rotation to 1e-15): 34 against
    98 us a call on 150 points, and the level's search makes about 80 such fits a frame.

    Parameters
    ----------
    points, targets : (N, 3) corresponding points (mm), ``N >= 3`` not all on a line.
    """
    p_mean, q_mean = points.mean(axis=0), targets.mean(axis=0)
    u, _, vt = np.linalg.svd((points - p_mean).T @ (targets - q_mean))
    reflection = np.sign(np.linalg.det(vt.T @ u.T))
    rotation = vt.T @ np.diag([1.0, 1.0, reflection]) @ u.T
    return rotation, q_mean - rotation @ p_mean


def _fit_covariance(fitted: np.ndarray, residuals: np.ndarray) -> np.ndarray:
    """Covariance of a rigid fit's six parameters (small rotation vector about the centroid, translation),
    from its residuals: ``s^2 (J^T J)^-1`` with ``J_i = [-[p_i]_x, I]`` and ``s^2`` the residuals' variance
    per coordinate (``3N - 6`` degrees of freedom)."""
    x, y, z = (fitted - fitted.mean(axis=0)).T
    zero, one = np.zeros_like(x), np.ones_like(x)
    # rows d(residual_k)/d(omega, t) of every point, stacked: (3N, 6)
    jacobian = np.stack(
        [
            np.column_stack([zero, z, -y, one, zero, zero]),
            np.column_stack([-z, zero, x, zero, one, zero]),
            np.column_stack([y, -x, zero, zero, zero, one]),
        ],
        axis=1,
    ).reshape(-1, 6)
    jtj = jacobian.T @ jacobian
    dof = max(3 * len(fitted) - 6, 1)
    s2 = float(np.sum(residuals**2)) / dof
    return s2 * np.linalg.pinv(jtj)


def _icp(
    points: np.ndarray, rest: cKDTree, rest_xyz: np.ndarray, reach_mm: float, start_xy_mm=(0.0, 0.0)
) -> _RigidFit | None:
    """Rigid motion taking ``points`` onto the rest markers: nearest neighbours in ``(x, y)`` within
    ``reach_mm``, the pairs beyond ``TRIM_MEDIAN_FACTOR`` median residuals dropped, refitted until the
    pairs no longer change; from a shift of ``start_xy_mm``."""
    T = pose_from_rotation_translation(np.eye(3), np.array([*start_xy_mm, 0.0]))
    previous: tuple[np.ndarray, np.ndarray] | None = None
    for _ in range(ICP_MAX_STEPS):
        moved = points @ T[:3, :3].T + T[:3, 3]
        distance, index = rest.query(moved[:, :2], distance_upper_bound=reach_mm)
        paired = np.isfinite(distance)
        residual = np.linalg.norm(moved[paired] - rest_xyz[index[paired]], axis=1)
        if paired.sum() < MIN_LEVEL_MARKERS:
            return None
        keep = np.flatnonzero(paired)[residual <= TRIM_MEDIAN_FACTOR * np.median(residual)]
        pairs = (keep, index[keep])
        if len(keep) < MIN_LEVEL_MARKERS:
            return None
        if (
            previous is not None
            and np.array_equal(pairs[0], previous[0])
            and np.array_equal(pairs[1], previous[1])
        ):
            break
        previous = pairs
        rotation, translation = rigid_fit(points[keep], rest_xyz[index[keep]])
        T = pose_from_rotation_translation(rotation, translation)
    fitted = points[keep] @ T[:3, :3].T + T[:3, 3]
    residuals = fitted - rest_xyz[index[keep]]
    rms = float(np.sqrt(np.mean(np.sum(residuals**2, axis=1))))
    return _RigidFit(T, len(keep), rms, fitted, residuals)


@dataclass(frozen=True)
class HeadPrior:
    """What the config says of the stereo head's mounting: where it is and how far it may be off.

    Attributes
    ----------
    centre_mm : (3,) the head's centre in J, midway between the config's cameras (mm).
    rotation_deg : its rotation error's standard deviation per axis (``tolerances.camera_rotation_deg``).
    position_mm : its placement error's standard deviation per axis (``tolerances.camera_position_mm``).
    """

    centre_mm: tuple[float, float, float]
    rotation_deg: float
    position_mm: float

    @classmethod
    def of(cls, jig: JigConfig) -> HeadPrior:
        """The prior of ``jig``'s head (its cameras and ``tolerances``)."""
        left, right = jig.cameras.left.position_mm, jig.cameras.right.position_mm
        centre = tuple(float((a + b) / 2.0) for a, b in zip(left, right, strict=True))
        tol = jig.tolerances
        return cls(centre, float(tol.camera_rotation_deg), float(tol.camera_position_mm))  # type: ignore[arg-type]

    def lateral_sigma_mm(self, height_mm: float) -> float:
        """How far the head's mounting error moves a point at ``height_mm`` in J sideways (1 sigma per
        axis, mm): its rotation's tolerance times the point's distance from the head's centre, and its
        placement's tolerance, in quadrature."""
        distance = float(height_mm) - self.centre_mm[2]
        return math.hypot(math.radians(self.rotation_deg) * distance, self.position_mm)

    def mahalanobis2(self, T_correction: np.ndarray) -> float:
        """The squared Mahalanobis distance of a correction from no error: its rotation, and how far it
        moves the head's centre, each against its tolerance (a zero tolerance: infinite)."""
        from scipy.spatial.transform import Rotation

        rotvec_deg = np.degrees(Rotation.from_matrix(T_correction[:3, :3]).as_rotvec())
        centre = np.asarray(self.centre_mm)
        moved = T_correction[:3, :3] @ centre + T_correction[:3, 3] - centre
        with np.errstate(divide="ignore", invalid="ignore"):
            rotation = np.sum(rotvec_deg**2) / np.float64(self.rotation_deg) ** 2
            position = np.sum(moved**2) / np.float64(self.position_mm) ** 2
        return float(np.nan_to_num(rotation + position, nan=np.inf))


def _candidates(
    points: np.ndarray, rest: cKDTree, rest_xyz: np.ndarray, reach_mm: float, span_mm: float
) -> list[_RigidFit]:
    """ICP from the config's poses and from shifts around them half a pitch (``reach_mm``) apart, up to
    ``span_mm`` each way (at least one step), the distinct alignments they reach (a tenth of the reach
    apart). A head tilted by a degree 150 mm below the membrane shifts it by 2.6 mm, over half a fine
    pitch: started only within a pitch, the search can miss the head's true alignment and take an alias
    of it a pitch away, tilted to match (zoo seed 6, design 4: a head tilted 1.24 deg levelled to 0.55
    deg with a sigma of 0.02)."""
    steps = max(1, math.ceil(span_mm / reach_mm))
    fits: list[_RigidFit] = []
    for i in range(-steps, steps + 1):
        for j in range(-steps, steps + 1):
            fit = _icp(points, rest, rest_xyz, reach_mm, (i * reach_mm, j * reach_mm))
            if fit is not None and all(
                np.linalg.norm(fit.T[:3, 3] - other.T[:3, 3]) > 0.1 * reach_mm for other in fits
            ):
                fits.append(fit)
    return fits


def _scores(
    moved: list[np.ndarray],
    corrections: list[np.ndarray],
    rms_mm: float,
    rest: cKDTree,
    rest_xyz: np.ndarray,
    reach_mm: float,
    prior: HeadPrior,
) -> np.ndarray:
    """Each alignment's ``-2 log`` posterior, up to a constant: every marker's squared distance from its
    nearest rest marker (capped at the reach: a marker no rest marker explains), against the best
    alignment's residual variance (``rms_mm``), plus the prior's Mahalanobis distance of its correction.
    ``moved[k]`` are the markers placed by alignment ``k`` (``corrections[k]``): the same markers for
    every alignment, so ones that pair fewer markers are not favoured."""
    # per coordinate; floored, so that markers that fit exactly (a rig surveyed from this very frame)
    # give finite scores
    variance = max(rms_mm, MIN_RMS_MM) ** 2 / 3.0
    scores = []
    for points, T in zip(moved, corrections, strict=True):
        _, index = rest.query(points[:, :2])
        distance2 = np.minimum(np.sum((points - rest_xyz[index]) ** 2, axis=1), reach_mm**2)
        scores.append(float(np.sum(distance2)) / variance + prior.mahalanobis2(T))
    return np.asarray(scores)


def _refined(
    triangulate: Callable[[np.ndarray], np.ndarray],
    correction: np.ndarray,
    rest: cKDTree,
    rest_xyz: np.ndarray,
    reach_mm: float,
) -> tuple[np.ndarray, _RigidFit, np.ndarray] | None:
    """An alignment refined with the markers triangulated again in its poses, round after round (the
    refraction moves with the poses), until its correction stops changing: ``(correction, last fit,
    the markers it places)``, or ``None`` where the markers leave the rest markers."""
    for _ in range(LEVEL_MAX_ROUNDS - 1):
        points = triangulate(correction)
        fit = _icp(points, rest, rest_xyz, reach_mm)
        if fit is None:
            return None
        correction = fit.T @ correction
        if max(np.linalg.norm(fit.T[:3, :3] - np.eye(3)), np.linalg.norm(fit.T[:3, 3])) < LEVEL_TOLERANCE:
            break
    return correction, fit, points @ fit.T[:3, :3].T + fit.T[:3, 3]


def from_fiducials(T_J_left_measured: np.ndarray, T_J_left_config: np.ndarray) -> HeadLevel:
    """The head's pose error a reference frame's fiducials measured (its left camera's pose against the
    config's: the right one is held at its configured pose relative to it), source ``"reference
    fiducials"``."""
    correction = T_J_left_measured @ np.linalg.inv(T_J_left_config)
    correction.flags.writeable = False
    return HeadLevel(correction, 0, float("nan"), 0.0, "reference fiducials")


def level_head(
    triangulate: Callable[[np.ndarray], np.ndarray],
    rest_xyz_mm: np.ndarray,
    *,
    pitch_mm: float,
    prior: HeadPrior,
) -> HeadLevel | AmbiguousLevel | str:
    """Measure the head's pose error on an unloaded frame (see the module docstring).

    Parameters
    ----------
    triangulate : ``T_correction -> (M, 3)``: the frame's matched markers triangulated in J with the
        config's camera poses corrected by ``T_correction`` (4, 4); markers not finite (rays that do not
        meet) are left out.
    rest_xyz_mm : (N, 3) the rest markers in J (mm): the config's layout on its rest shape.
    pitch_mm : the marker pitch (mm): pairs are matched within half of it.
    prior : the head's mounting tolerances: the first alignment is the most probable one given them, a
        level as probable in two places is not used (a small patch of a grid in view fits shifted by a
        pitch and tilted), nor one less certain than the tolerance.

    Returns
    -------
    HeadLevel
        The level; an :class:`AmbiguousLevel` where the markers fit as well in several places; else a
        ``str`` saying why none could be measured.
    """
    if not prior.rotation_deg > 0:
        return "the config's tolerances say the head is mounted exactly (tolerances.camera_rotation_deg = 0)"
    from scipy.spatial import cKDTree

    def triangulate_finite(T: np.ndarray) -> np.ndarray:  # a pair of parallel rays meets nowhere: NaN
        points = triangulate(T)
        return points[np.isfinite(points).all(axis=1)]

    rest_xyz = np.asarray(rest_xyz_mm, dtype=float)
    rest = cKDTree(rest_xyz[:, :2])
    reach = MATCH_REACH_PITCHES * pitch_mm
    points = triangulate_finite(np.eye(4))
    search = points[:: max(1, -(-len(points) // SEARCH_MARKERS))]  # every k-th: at most SEARCH_MARKERS
    span = SEARCH_LATERAL_SIGMAS * prior.lateral_sigma_mm(float(np.median(rest_xyz[:, 2])))
    fits = _candidates(search, rest, rest_xyz, reach, span)
    if not fits:
        return (
            f"fewer than {MIN_LEVEL_MARKERS} of the reference frame's markers lie within half a pitch of "
            "the config's rest markers, however the head is shifted"
        )
    # Ranked first to first order (the markers moved rigidly), then the best refined and ranked again:
    # a head's rotation also changes the refraction, which a rigid motion of the points leaves out.
    first_order = _scores(
        [search @ fit.T[:3, :3].T + fit.T[:3, 3] for fit in fits],
        [fit.T for fit in fits],
        min(fit.rms_mm for fit in fits),
        rest,
        rest_xyz,
        reach,
        prior,
    )
    refined = [
        found
        for k in np.argsort(first_order)[:REFINED_ALIGNMENTS]
        if (found := _refined(triangulate_finite, fits[k].T, rest, rest_xyz, reach)) is not None
    ]
    if not refined:
        return "the level did not converge: the markers left the rest markers when the head was moved"
    scores = _scores(
        [moved for _, _, moved in refined],
        [correction for correction, _, _ in refined],
        min(fit.rms_mm for _, fit, _ in refined),
        rest,
        rest_xyz,
        reach,
        prior,
    )
    order = np.argsort(scores)
    if len(refined) > 1 and scores[order[1]] - scores[order[0]] < AMBIGUITY:
        best, second = refined[order[0]][0], refined[order[1]][0]
        apart = np.linalg.norm(second[:3, 3] - best[:3, 3])
        return AmbiguousLevel(
            f"the markers in view fit the rest markers about as well in two places {apart:.1f} mm apart "
            "(too few markers, or too regular a patch of them, to tell)",
            tuple(_tilt_deg(refined[k][0]) for k in order if scores[k] - scores[order[0]] < AMBIGUITY),
        )
    correction, fit, _ = refined[order[0]]
    if fit.rms_mm > MAX_RMS_PITCHES * pitch_mm:
        return (
            f"the markers lie {fit.rms_mm:.2f} mm (RMS) from the config's rest markers after the best rigid "
            f"fit, more than {MAX_RMS_PITCHES} pitch: the config's layout or rest shape is not this jig's"
        )
    covariance = fit.covariance
    tilt_sigma_deg = float(np.degrees(np.sqrt(covariance[0, 0] + covariance[1, 1])))
    if tilt_sigma_deg >= prior.rotation_deg:
        return (
            f"the level's own uncertainty ({tilt_sigma_deg:.2f} deg) is no better than the head's mounting "
            f"tolerance ({prior.rotation_deg:.2f} deg)"
        )
    correction.flags.writeable = False
    return HeadLevel(correction, fit.n, fit.rms_mm, tilt_sigma_deg)


def improves_on_the_config(
    config_points_J: np.ndarray, levelled_points_J: np.ndarray, rest_xyz_mm: np.ndarray, *, pitch_mm: float
) -> bool:
    """Whether a level fits the markers to the rest markers better than the config's poses do, beyond
    chance: the F test of the rigid motion's six parameters against none, on the mean squared distance
    of the markers from their nearest rest markers (paired within half a pitch) with either pose, at
    :data:`IMPROVEMENT_SIGNIFICANCE`. Markers that pair with no rest marker in the config's poses (a head
    off by half a pitch) make it improve. Markers not finite with either pose are left out.

    Why: a rig whose cameras were levelled already (by ``softjig survey``, on the rest markers it then
    wrote) fits as well either way (F 0.2-0.4 on the default jig's two heads), and a level of a loaded
    frame there is the drape of the dent, not the head (0.54 -> 0.60 and 0.16 -> 0.32 deg off when it
    was used); a head off by its mounting tolerance gives F 15-380 (zoo and default jig).

    Parameters
    ----------
    config_points_J, levelled_points_J : (M, 3) the same markers triangulated with the config's poses and
        with the levelled ones (mm, J).
    rest_xyz_mm : (N, 3) the rest markers in J (mm).
    pitch_mm : the marker pitch (mm).

    Raises
    ------
    InputError
        Point sets that are not (M, 3) each, the same markers.
    """
    from scipy.spatial import cKDTree
    from scipy.special import fdtri  # scipy.stats would cost 0.4 s of import in the first such frame

    before_xyz = np.asarray(config_points_J, dtype=float)
    after_xyz = np.asarray(levelled_points_J, dtype=float)
    if before_xyz.ndim != 2 or before_xyz.shape[1] != 3 or before_xyz.shape != after_xyz.shape:
        raise InputError(
            "improves_on_the_config needs the same (M, 3) markers in both poses, got shapes "
            f"{before_xyz.shape} and {after_xyz.shape}"
        )
    finite = np.isfinite(before_xyz).all(axis=1) & np.isfinite(after_xyz).all(axis=1)
    rest_xyz = np.asarray(rest_xyz_mm, dtype=float)
    rest = cKDTree(rest_xyz[:, :2])

    def mean_square(points: np.ndarray) -> tuple[float, int]:
        distance, index = rest.query(points[:, :2], distance_upper_bound=MATCH_REACH_PITCHES * pitch_mm)
        paired = np.isfinite(distance)
        if not paired.any():
            return float("inf"), 0
        squares = np.sum((points[paired] - rest_xyz[index[paired]]) ** 2, axis=1)
        return float(np.mean(squares)), int(paired.sum())

    before, paired_before = mean_square(before_xyz[finite])
    after, paired = mean_square(after_xyz[finite])
    if paired <= 6:
        return False
    if paired_before < paired:  # markers the config's poses leave without a rest marker
        return True
    if after == 0.0:  # an exact fit (noiseless markers): any misfit before is an improvement
        return before > 0.0
    statistic = (paired - 6) / 6.0 * (before / after - 1.0)
    return bool(statistic > fdtri(6, paired - 6, 1.0 - IMPROVEMENT_SIGNIFICANCE))


def levelled_jig(jig: JigConfig, level: HeadLevel) -> JigConfig:
    """``jig`` with both cameras at their levelled poses (``level.T_correction @ T_J_cam``), the rest as
    it is: what ``softjig survey`` writes when the head was levelled."""

    from scipy.spatial.transform import Rotation

    def moved(camera: CameraConfig) -> CameraConfig:
        T = level.T_correction @ camera.T_J_cam
        rotvec_deg = np.degrees(Rotation.from_matrix(T[:3, :3]).as_rotvec())
        return replace(
            camera,
            position_mm=tuple(float(v) for v in T[:3, 3]),
            rotation_deg=tuple(float(v) for v in rotvec_deg),
        )

    cameras = jig.cameras
    return jig.replace(cameras=replace(cameras, left=moved(cameras.left), right=moved(cameras.right)))
