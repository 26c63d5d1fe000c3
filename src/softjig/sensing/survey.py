"""Self-survey: the unloaded jig's triangulated markers become the rig's measured layout and rest shape.

A jig is never built as drawn: the mould places each marker a little off its grid, the bag settles into
its own dome. A stereo pair of the *unloaded* jig, triangulated like any frame, measures where every
visible marker really is. :func:`survey_markers` turns those points into a rig whose markers are an
explicit layout at the measured ``(x, y)`` with the measured inner-face heights (``markers.centers_z_mm``,
which the estimator's rest-shape reference then uses, :func:`softjig.jig_shape.rest_marker_points_mm`),
and whose dome is a measured ``(r, h)`` table fitted to them, and reports how far the nominal rig was off
at each marker. The surveyed rig's cameras are at the pose measured on the first frame: by its
fiducials, or, when they were not seen, levelled on its membrane (:mod:`softjig.sensing.levelling`).

Pure: points in, a config and a report out (the images are triangulated by the caller, e.g.
:func:`softjig.sensing.pipeline.reference_from_pair`).

Loaded frames
-------------
A survey of a frame with a part pressed in would write the dent into the rest shape. The measured
heights are compared with the nominal rest shape after removing what the stereo head's residual pose
and depth-scale errors explain (a plane: offset and tilt, fitted robustly with Tukey's biweight). A part
pushes markers *in*, over a compact patch: a frame is refused as loaded when at least
:data:`MIN_DENT_MARKERS` neighbouring markers (within 1.5 pitches of each other) lie deeper than
``max(DENT_SIGMAS * sigma, MIN_DENT_MM)`` below it, ``sigma`` the frame's height noise measured from
neighbouring markers' differences (:func:`softjig.sensing.contact.indentation`, blind to smooth
departures). No more flexible model is removed, on purpose: a quadratic or radial term absorbs a large
flat face pushed in on the axis (measured: 80 mm pushed 3 mm passed), and one frame cannot tell such a
push from a dome built lower on top. So a jig whose rest shape is really that far from its drawing is
refused too: the message says so, and ``max_deviation_mm`` (``softjig survey --max-deviation``) accepts
departures up to a stated depth as the jig's own.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from softjig.config import JigConfig, with_explicit_markers
from softjig.errors import InputError
from softjig.jig_shape import rest_marker_points_mm
from softjig.sensing.identities import ReferenceMarkers, identify_markers
from softjig.sensing.levelling import HeadLevel, levelled_jig

DENT_SIGMAS = 5.0
MIN_DENT_MM = 0.5  # below this a departure is within what a bag's settling does between two fills
MIN_DENT_MARKERS = 4

__all__ = ["DentCheck", "Survey", "check_unloaded", "survey_markers"]


@dataclass(frozen=True)
class DentCheck:
    """How the frame's heights depart from the nominal rest shape, once smooth build errors are removed.

    Attributes
    ----------
    residual_mm : (K,) indentation of each matched marker below the smooth fit (positive: pushed in).
    sigma_mm : robust scatter of the residuals (mm).
    threshold_mm : depth beyond which a marker counts as dented (mm).
    dented : (K,) the markers of the largest compact group beyond the threshold.
    """

    residual_mm: np.ndarray
    sigma_mm: float
    threshold_mm: float
    dented: np.ndarray

    @property
    def loaded(self) -> bool:
        """Whether a part seems to be pressed in."""
        return int(self.dented.sum()) >= MIN_DENT_MARKERS


@dataclass(frozen=True)
class Survey:
    """A survey of the unloaded jig.

    Attributes
    ----------
    jig : the surveyed rig: the nominal one with an explicit layout at the measured markers (with
        their heights) and, if asked, a measured dome table.
    measured_xyz_mm : (K, 3) the surveyed markers in J (mm), in the nominal layout's order.
    nominal_xyz_mm : (K, 3) the same markers in the nominal rig (its rest-shape reference).
    nominal_index : (K,) each surveyed marker's index in the nominal layout.
    n_nominal : markers in the nominal layout.
    n_unmatched : triangulated points with no nominal marker within half a pitch (left out), in all.
    dent : the loaded-frame check (of the first frame).
    n_frames : how many unloaded frames were combined.
    head_level : the stereo head's error measured on the first frame, by its fiducials or levelled on its
        membrane when they were not seen (:mod:`softjig.sensing.levelling`): the surveyed rig's cameras
        are then the measured ones.
    """

    jig: JigConfig
    measured_xyz_mm: np.ndarray
    nominal_xyz_mm: np.ndarray
    nominal_index: np.ndarray
    n_nominal: int
    n_unmatched: int
    dent: DentCheck
    n_frames: int = 1
    head_level: HeadLevel | None = None

    @property
    def offset_mm(self) -> np.ndarray:
        """(K, 3) measured minus nominal position of each marker (mm)."""
        return self.measured_xyz_mm - self.nominal_xyz_mm

    def summary(self) -> dict[str, float | int]:
        """Median and maximum offsets (lateral, vertical, 3-D, mm) and the marker counts."""
        off = self.offset_mm
        lateral = np.hypot(off[:, 0], off[:, 1])
        vertical = np.abs(off[:, 2])
        total = np.linalg.norm(off, axis=1)
        return {
            "markers_surveyed": len(off),
            "markers_nominal": self.n_nominal,
            "markers_not_seen": self.n_nominal - len(off),
            "points_unmatched": self.n_unmatched,
            "lateral_median_mm": float(np.median(lateral)),
            "lateral_max_mm": float(lateral.max()),
            "vertical_median_mm": float(np.median(vertical)),
            "vertical_max_mm": float(vertical.max()),
            "offset_median_mm": float(np.median(total)),
            "offset_max_mm": float(total.max()),
            "noise_mm": self.dent.sigma_mm,
            "frames": self.n_frames,
            **(
                {}
                if self.head_level is None
                else {
                    "head_rotation_deg": self.head_level.rotation_deg,
                    "head_shift_mm": [float(v) for v in self.head_level.shift_mm],
                    "head_level_sigma_deg": self.head_level.tilt_sigma_deg,
                }
            ),
        }

    def to_dict(self) -> dict:
        """The JSON-ready report: the summary and one entry per surveyed marker."""
        rows = []
        for k, i in enumerate(self.nominal_index):
            rows.append(
                {
                    "nominal_index": int(i),
                    "nominal_mm": [float(v) for v in self.nominal_xyz_mm[k]],
                    "measured_mm": [float(v) for v in self.measured_xyz_mm[k]],
                    "offset_mm": [float(v) for v in self.offset_mm[k]],
                }
            )
        return {"summary": self.summary(), "markers": rows}


def check_unloaded(
    points_J: np.ndarray, nominal_z_mm: np.ndarray, jig: JigConfig, *, max_deviation_mm: float = 0.0
) -> DentCheck:
    """Compare matched markers with the nominal rest heights; see the module docstring.

    Parameters
    ----------
    points_J : (K, 3) matched markers in J (mm).
    nominal_z_mm : (K,) their nominal rest heights (mm).
    jig : the nominal jig (its pitch).
    max_deviation_mm : departures up to this depth are the jig's own (mm; raises the threshold).
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    from softjig.sensing.contact import indentation

    points = np.asarray(points_J, dtype=float)
    depth = np.asarray(nominal_z_mm, dtype=float) - points[:, 2]
    scale = jig.membrane.footprint_radius_mm
    basis = np.column_stack([np.ones(len(points)), points[:, 0] / scale, points[:, 1] / scale])
    noise = indentation(points, np.asarray(nominal_z_mm, dtype=float), pitch_mm=jig.markers.pitch_mm).noise_mm
    sigma = float(noise) if np.isfinite(noise) and noise > 0 else 1e-3
    weight = np.ones(len(depth))
    residual = depth - np.median(depth)
    for _ in range(20):  # Tukey's biweight by iteratively reweighted least squares
        spread = max(1.4826 * float(np.median(np.abs(residual - np.median(residual)))), sigma)
        u = residual / (4.685 * spread)
        weight = np.where(np.abs(u) < 1, (1 - u**2) ** 2, 0.0)
        sw = np.sqrt(weight)
        coef = np.linalg.lstsq(basis * sw[:, None], depth * sw, rcond=None)[0]
        new = depth - basis @ coef
        if np.max(np.abs(new - residual)) < 1e-4 * sigma:
            residual = new
            break
        residual = new
    threshold = max(DENT_SIGMAS * sigma, MIN_DENT_MM, float(max_deviation_mm))
    deep = np.flatnonzero(residual > threshold)
    dented = np.zeros(len(depth), dtype=bool)
    if len(deep):
        pairs = cKDTree(points[deep, :2]).query_pairs(1.5 * jig.markers.pitch_mm, output_type="ndarray")
        graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(deep), len(deep)))
        _, label = connected_components(graph, directed=False)
        dented[deep[label == np.bincount(label).argmax()]] = True
    return DentCheck(residual, sigma, threshold, dented)


SMOOTHING_RADIUS_PITCHES = 2.5


def smoothed_heights(points_J: np.ndarray, pitch_mm: float) -> np.ndarray:
    """Each marker's height from a quadratic surface ``z(x, y)`` fitted to the markers within
    :data:`SMOOTHING_RADIUS_PITCHES` pitches of it (itself included), evaluated at it (mm).

    The membrane's inner face is smooth at the pitch's scale (a 0.7 mm silicone sheet on beads), so a
    marker's height is the surface's at its ``(x, y)``: the local fit keeps the dome's curvature and
    averages the triangulation's noise over the neighbours (about half the noise with the 20 or so
    neighbours of a grid). Markers with fewer than 9 neighbours keep their own height.
    """
    from scipy.spatial import cKDTree

    xyz = np.asarray(points_J, dtype=float)
    out = xyz[:, 2].copy()
    tree = cKDTree(xyz[:, :2])
    for k, members in enumerate(tree.query_ball_point(xyz[:, :2], SMOOTHING_RADIUS_PITCHES * pitch_mm)):
        if len(members) < 9:
            continue
        d = xyz[members, :2] - xyz[k, :2]
        basis = np.column_stack(
            [np.ones(len(d)), d[:, 0], d[:, 1], d[:, 0] ** 2, d[:, 0] * d[:, 1], d[:, 1] ** 2]
        )
        out[k] = np.linalg.lstsq(basis, xyz[members, 2], rcond=None)[0][0]
    return out


def _profile_table(points_J: np.ndarray, jig: JigConfig) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """A monotone ``(r, h)`` table from the markers: the median height in rings one pitch wide, made
    non-increasing by isotonic regression (weighted by the ring's count), from ``r = 0``."""
    from scipy.optimize import isotonic_regression

    r = np.hypot(points_J[:, 0], points_J[:, 1])
    h = points_J[:, 2]
    pitch = jig.markers.pitch_mm
    ring = np.floor(r / pitch + 0.5).astype(int)  # ring 0: within half a pitch of the axis
    radii, heights, counts = [], [], []
    for k in np.unique(ring):
        members = ring == k
        radii.append(0.0 if k == 0 else float(np.median(r[members])))
        heights.append(float(np.median(h[members])))
        counts.append(int(members.sum()))
    if radii[0] != 0.0:  # no marker near the axis: a flat top from the innermost ring
        radii.insert(0, 0.0)
        heights.insert(0, heights[0])
        counts.insert(0, 1)
    fitted = isotonic_regression(np.array(heights), weights=np.array(counts, float), increasing=False).x
    radius = jig.membrane.footprint_radius_mm
    keep = np.array(radii) < radius
    return tuple(float(v) for v in np.array(radii)[keep]), tuple(float(max(v, 0.0)) for v in fitted[keep])


#: An unloaded frame must match at least 1/MIN_MATCHED_SHARE of the rig's markers (a real unloaded pair
#: of the simulated rig matches ~3/4 of them; a pair of noise images ~1/30).
MIN_MATCHED_SHARE = 4


def min_matched_markers(jig: JigConfig, n_nominal: int) -> int:
    """The fewest markers of an unloaded frame that must lie within half a pitch of one of the rig's
    ``n_nominal``: enough for the dent check and the fit (``sensing.min_points``), and a quarter of the
    rig's (:data:`MIN_MATCHED_SHARE`): an image of noise triangulates a dozen points, most of them within
    half a pitch of some marker laterally, and too scattered for the dent check to flag."""
    return max(jig.sensing.min_points, MIN_DENT_MARKERS + 3, -(-n_nominal // MIN_MATCHED_SHARE))


def _matched(points_J: np.ndarray, nominal: JigConfig, nominal_xyz: np.ndarray, where: str):
    """A frame's finite points above the plate matched to the nominal markers: (points, nominal indices,
    unmatched). A point on or below the plate's top face (``z <= 0``) is not on the membrane (a fiducial's
    corner on the plate, say) and counts as unmatched."""
    points = np.asarray(points_J, dtype=float).reshape(-1, 3)
    finite = points[np.all(np.isfinite(points), axis=1)]
    points = finite[finite[:, 2] > 0.0]
    off_membrane = len(finite) - len(points)
    ids = identify_markers(
        points, ReferenceMarkers(nominal_xyz, "rest shape"), max_lateral_mm=nominal.markers.pitch_mm / 2.0
    ).ids
    known = ids >= 0
    if known.sum() < min_matched_markers(nominal, len(nominal_xyz)):
        raise InputError(
            f"{where}only {int(known.sum())} triangulated markers lie within half a pitch of a nominal "
            "marker: is this a pair of the unloaded jig, and the right rig.toml?"
        )
    order = np.argsort(ids[known], kind="stable")
    return points[known][order], ids[known][order], int((~known).sum()) + off_membrane


def survey_markers(
    reference: ReferenceMarkers | np.ndarray | Sequence[ReferenceMarkers | np.ndarray],
    nominal: JigConfig,
    *,
    fit_profile: bool = True,
    smooth: bool = True,
    max_deviation_mm: float = 0.0,
) -> Survey:
    """Survey the unloaded jig from its triangulated markers.

    Parameters
    ----------
    reference : the unloaded jig's triangulated markers in J (mm), ``(M, 3)`` or a
        :class:`ReferenceMarkers` (e.g. from :func:`softjig.sensing.pipeline.reference_from_pair`), or a
        list of them (several unloaded frames: each marker is the median of its positions in the frames
        that saw it).
    nominal : the rig as configured.
    fit_profile : also replace the dome by a measured ``(r, h)`` table (``membrane.dome_profile =
        "table"``); otherwise keep the nominal profile (used where no surveyed marker is).
    smooth : write each marker's height from a local fit of its neighbours (:func:`smoothed_heights`)
        rather than its own triangulated height (``(x, y)`` are always the marker's own).
    max_deviation_mm : departures from the nominal rest shape up to this depth (mm) are accepted as the
        jig's own, not taken for a part pressed in.

    Returns
    -------
    Survey

    Raises
    ------
    InputError
        A loaded frame (a part pressed in: see the module docstring), or fewer matched markers than
        ``sensing.min_points``.
    """
    frames = list(reference) if isinstance(reference, list | tuple) else [reference]
    if not frames:
        raise InputError("a survey needs at least one frame of the unloaded jig")
    nominal_xyz = rest_marker_points_mm(nominal)
    matched, dents, unmatched = [], [], 0
    for k, frame in enumerate(frames):
        where = f"frame {k + 1} of {len(frames)}: " if len(frames) > 1 else ""
        points, index, n_unmatched = _matched(getattr(frame, "xyz_mm", frame), nominal, nominal_xyz, where)
        dent = check_unloaded(points, nominal_xyz[index, 2], nominal, max_deviation_mm=max_deviation_mm)
        if dent.loaded:
            centre = points[dent.dented, :2].mean(axis=0)
            raise InputError(
                f"{where}this frame is loaded: {int(dent.dented.sum())} neighbouring markers around "
                f"({centre[0]:.0f}, {centre[1]:.0f}) mm are pushed in by up to {dent.residual_mm.max():.1f} "
                f"mm (noise {dent.sigma_mm:.2f} mm, threshold {dent.threshold_mm:.2f} mm): a part is pressed "
                "onto the jig. Survey a pair of the unloaded jig (its reference frame). If no part is "
                "pressed, the jig's rest shape is that far from the rig's: accept it with --max-deviation "
                "(mm)"
            )
        matched.append((points, index))
        dents.append(dent)
        unmatched += n_unmatched
    index = np.unique(np.concatenate([i for _, i in matched]))
    stack = np.full((len(frames), len(nominal_xyz), 3), np.nan)
    for k, (points, i) in enumerate(matched):
        stack[k, i] = points
    measured = np.nanmedian(stack[:, index], axis=0) if len(frames) > 1 else stack[0, index]
    nominal_at = nominal_xyz[index]
    if smooth:
        measured = np.column_stack([measured[:, :2], smoothed_heights(measured, nominal.markers.pitch_mm)])
    jig = with_explicit_markers(nominal, measured[:, :2], measured[:, 2])
    level = getattr(frames[0], "head_level", None)
    if level is not None:  # the markers were triangulated in the measured poses: so are the cameras
        jig = levelled_jig(jig, level)
    if fit_profile:
        r, h = _profile_table(measured, jig)
        membrane = replace(
            jig.membrane, dome_profile="table", dome_height_mm=h[0], profile_r_mm=r, profile_h_mm=h
        )
        jig = jig.replace(membrane=membrane)
    return Survey(
        jig=jig,
        measured_xyz_mm=measured,
        nominal_xyz_mm=nominal_at,
        nominal_index=index,
        n_nominal=len(nominal_xyz),
        n_unmatched=unmatched,
        dent=dents[0],
        n_frames=len(frames),
        head_level=level,
    )
