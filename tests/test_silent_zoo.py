"""The design zoo's silent failures, each one rendered again and estimated the way that failed.

Each case is one loaded frame of ``benchmarks/bench_zoo.py``'s zoo (seed 0, 20 frames per design: the
design and its frames are drawn exactly as there), rendered with its design's unloaded reference frame
and estimated the way the benchmark found a silent failure (an error over 3 deg and over 4 times its
``tilt_sigma_deg`` with quality ``"ok"``). The pattern: a part 15-19 mm off the jig axis, tilted 12-20
deg, whose few contact markers lost to a strip of the membrane's wall beside them. The estimate must now
be right, honest about its error, or suspect.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import pytest

from softjig.config import JigConfig, default_jig
from softjig.errors import EstimationError
from softjig.sensing.fitting import PARTIAL_CONTACT_MIN_POINTS
from softjig.sensing.pipeline import estimate_pair, reference_from_pair
from softjig.sim.asbuilt import draw_as_built
from softjig.sim.render import render_pair
from softjig.sim.scenarios import frame_truth, paper_sweep
from softjig.sim.zoo import (
    ZooRanges,
    _draw_design,
    damaged_image_model,
    gentle_wall_model,
    stirred_image_model,
)

ZOO_SEED = 0
ZOO_FRAMES = 20  # the benchmark's frames per design: the frames are drawn in sequence
SILENT_ERROR_DEG = 3.0  # bench_zoo's definition of a silent failure
SILENT_SIGMAS = 4.0


def _silent(error_deg: float, estimate) -> bool:
    """bench_zoo's silent failure: "ok", over :data:`SILENT_ERROR_DEG` off and over
    :data:`SILENT_SIGMAS` times its ``tilt_sigma_deg``."""
    return (
        estimate.quality == "ok"
        and error_deg > SILENT_ERROR_DEG
        and error_deg > SILENT_SIGMAS * estimate.tilt_sigma_deg
    )


def _estimate(
    design_index: int,
    frame: int,
    *,
    with_size: bool,
    with_reference: bool,
    seed: int = ZOO_SEED,
    render_jig: Callable[[JigConfig], JigConfig] | None = None,
    estimate_jig: Callable[[JigConfig], JigConfig] | None = None,
):
    """Render a zoo design's reference frame and one loaded frame as ``bench_zoo.evaluate_design`` does
    (with the image model ``render_jig`` makes of the design's jig, default its own), and estimate it (with
    the jig ``estimate_jig`` makes of the design's, default its own): ``(error_deg, estimate)``."""
    design = _draw_design(design_index, seed, ZOO_FRAMES, ZooRanges())
    rendered_jig = render_jig(design.jig) if render_jig else design.jig
    as_built = draw_as_built(
        rendered_jig, np.random.default_rng(np.random.SeedSequence(design.seed, spawn_key=(0,)))
    )

    def rendered(index):
        spec = design.specs[index]
        rng = np.random.default_rng(np.random.SeedSequence(design.seed, spawn_key=(1, index)))
        return spec, render_pair(as_built, spec.part, spec.pose, rng)

    reference = None
    if with_reference:
        _, unloaded = rendered(0)
        reference = reference_from_pair(unloaded.left, unloaded.right, design.jig)
    spec, pair = rendered(frame)
    estimate = estimate_pair(
        pair.left,
        pair.right,
        estimate_jig(design.jig) if estimate_jig else design.jig,
        part_diameter_mm=spec.part.diameter_mm if with_size else None,
        reference=reference,
    ).estimate
    truth = np.asarray(frame_truth(as_built.jig, spec.pose)["normal"], dtype=float)
    cosine = float(np.dot(estimate.normal, truth) / np.linalg.norm(truth))
    return math.degrees(math.acos(min(1.0, max(-1.0, cosine)))), estimate


# (design, frame, with the part's size, with the reference frame): the silent failures of the zoo
# (seed 0) before the holes beside the contact and the rival contacts were checked, and the error each
# had (deg).
CASES = [
    pytest.param(2, 15, True, True, id="d2f15-size-reference-33.8deg"),
    pytest.param(4, 7, True, True, id="d4f7-size-reference-15.7deg"),
    pytest.param(11, 3, False, True, id="d11f3-nosize-reference-19.7deg"),
    pytest.param(15, 10, True, True, id="d15f10-size-reference-13.0deg"),
    pytest.param(16, 8, False, True, id="d16f8-nosize-reference-24.5deg"),
    pytest.param(18, 19, True, False, id="d18f19-size-rest-29.2deg"),
    pytest.param(18, 19, False, False, id="d18f19-nosize-rest-29.1deg"),  # right since main's robust fits
    pytest.param(29, 18, False, True, id="d29f18-nosize-reference-12.8deg"),
    pytest.param(42, 4, False, False, id="d42f4-nosize-rest-15.9deg"),
    # Size-free, the wall beside the lowered edge of a small contact and the face meet in a V at the
    # deepest markers: the fit takes the wall, and the face's five deepest markers, just outside it, lie
    # 2.6-4.8 sigmas below its plane (holes beside it, at 1.5 inlier thresholds).
    pytest.param(42, 4, False, True, id="d42f4-nosize-reference-16.6deg"),
    pytest.param(11, 4, True, True, id="d11f4-size-reference-9.1deg"),
    pytest.param(14, 14, True, False, id="d14f14-size-rest-8.8deg"),
]


@pytest.mark.parametrize(("design", "frame", "with_size", "with_reference"), CASES)
def test_a_wall_beside_an_off_centre_contact_is_not_a_silent_answer(design, frame, with_size, with_reference):
    error, estimate = _estimate(design, frame, with_size=with_size, with_reference=with_reference)
    assert not _silent(error, estimate), (
        f"{error:.1f} deg off with tilt_sigma_deg {estimate.tilt_sigma_deg:.2f} and quality 'ok' "
        f"({estimate.n_points} markers fitted)"
    )
    if estimate.quality == "suspect":
        assert any(w.startswith("suspect: ") for w in estimate.warnings)


@pytest.mark.parametrize("with_reference", [True, False], ids=["reference", "rest-shape"])
def test_the_wall_beside_a_lowered_edge_has_the_face_as_its_rival(with_reference):
    """Zoo seed 3, design 34, frame 20, size-free: a 44 mm box 7.5 mm off the axis, tilted 16 deg. The
    wall beside the face's lowered edge (16 markers) and the face's four deepest markers make a contact
    of 20 markers that no marker contradicts, 25 deg off: the face's other markers lie above its plane,
    where the membrane outside a face may lie. It was "ok" with a sigma of 1.2-1.6 deg. The face (the
    other arm of the V, 15-16 markers, as flat) is now its rival, and the estimate is suspect."""
    error, estimate = _estimate(34, 20, with_size=False, with_reference=with_reference, seed=3)
    if error > SILENT_ERROR_DEG:  # the wall (nothing ranks the two arms of the V): suspect, and why
        assert estimate.quality == "suspect", (error, estimate.tilt_sigma_deg)
        assert any("another contact fits the frame as well" in w for w in estimate.warnings)


@pytest.mark.parametrize("with_reference", [True, False], ids=["reference", "rest-shape"])
def test_a_large_face_whose_markers_the_beads_ripple_is_fitted_whole(with_reference):
    """Zoo seed 4, design 30, frame 5, size-free: a 64 mm square 17 mm off the axis on a 4.3 mm grid, 163
    markers in contact. The beads behind the membrane ripple the markers on the face by 0.1 mm, twice
    the scatter of the membrane at rest (0.047 mm) that set the inlier band (0.12 mm): the growth kept a
    strip of 14 markers, and its plane lay 35 deg off (suspect, both ways). Where the band kept too few of
    the pushed-in markers, the contact is grown again with a band set from their own scatter: the face
    is fitted whole, and the estimate stays suspect, saying why. With the reference frame, the face (139
    markers) is also the larger arm of the V the strip makes with it, and is reported as such before the
    band is widened: suspect, with the strip as its rival."""
    error, estimate = _estimate(30, 5, with_size=False, with_reference=with_reference, seed=4)
    assert error < 1.0, (error, estimate.n_points, estimate.warnings)
    assert estimate.n_points > 100
    assert estimate.quality == "suspect"
    why = "another contact fits the frame as well" if with_reference else "the pushed-in markers' own scatter"
    assert any(why in w for w in estimate.warnings), estimate.warnings


@pytest.mark.parametrize("frame", [32, 85])
def test_the_drapes_curvature_does_not_widen_a_small_contacts_band(frame):
    """The paper sweep (azimuth step 30 deg), size-free: a 30 mm part at 15 deg (frame 32) and a 40 mm part
    at 20 deg (frame 85) on the default 8 mm grid, 8-14 markers fitted (suspect: a small share of the
    dent). The pushed-in markers' scatter there is the drape's curvature (a band of 0.8-1.5 mm against
    0.3), not a face's ripple: the contact they grow holds under ``FACE_SCATTER_MIN_POINTS`` markers and
    is not taken (taken, it moved the sweep's size-free RMSE from 3.778 to 3.823 deg)."""
    specs = list(paper_sweep(theta_step_deg=30.0))
    jig = default_jig()
    as_built = draw_as_built(jig, np.random.default_rng(np.random.SeedSequence(0, spawn_key=(0,))))
    unloaded, pair = (
        render_pair(
            as_built,
            specs[index].part,
            specs[index].pose,
            np.random.default_rng(np.random.SeedSequence(0, spawn_key=(1, index))),
        )
        for index in (0, frame)
    )
    assert specs[0].part is None  # the sweep's unloaded reference frame
    reference = reference_from_pair(unloaded.left, unloaded.right, jig)
    estimate = estimate_pair(pair.left, pair.right, jig, reference=reference).estimate
    assert not any("own scatter" in w for w in estimate.warnings), estimate.warnings


def test_a_large_face_a_few_markers_contradict_is_still_the_walls_rival():
    """Zoo seed 7, design 1, frame 10, size-free with the reference (a noisy 4.6 mm grid): a 74 mm square
    13 mm off the axis, tilted 14 deg, 133 markers in contact. The growth took the wall beside its lowered
    edge (67 markers); the other arm of the V, the face (160 markers), had 12 markers above its plane
    where 8 are tolerated, so it was no rival: "ok", 20 deg off, sigma 1.05 deg. A rival is a doubt, not a
    choice: contradicted by no more than 5 % of its markers beyond the tolerated ones, it stays one."""
    error, estimate = _estimate(1, 10, with_size=False, with_reference=True, seed=7)
    if error > SILENT_ERROR_DEG:
        assert estimate.quality == "suspect", (error, estimate.tilt_sigma_deg)
        assert any("another contact fits the frame as well" in w for w in estimate.warnings)


def test_a_rise_inside_a_ring_of_wall_markers_is_a_violation():
    """Zoo seed 2, design 23, frame 8, size-free: the contact grew into a ring of wall markers around a rise
    of membrane, whose plane lay 18 deg off the face's; the rise's markers inside the contact's core lay
    5.6-7.7 sigmas above that plane, and being two they were tolerated as noise: an "ok" estimate 18 deg
    off with a sigma of 0.67 deg. Of the markers as far above the plane as a hole lies below it, only one
    is tolerated (a mismatched marker)."""
    error, estimate = _estimate(23, 8, with_size=False, with_reference=True, seed=2)
    assert not _silent(error, estimate), (error, estimate.tilt_sigma_deg, estimate.warnings)


def test_the_larger_cut_contact_is_still_taken_when_a_small_face_rivals_it():
    """Zoo seed 1, design 3, frame 3: a 35 mm part 18 mm off the axis at 20 deg. The face searched from
    the axis holds 10 markers (too few to check) and lies 34 deg off; the size-free contact cut to the
    face is right. Both are contradicted by no marker: the cut is reported, and the estimate is suspect
    (when the small face was kept instead, this frame came out 34.7 deg off)."""
    error, estimate = _estimate(3, 3, with_size=True, with_reference=True, seed=1)
    assert error < 1.5
    assert estimate.quality == "suspect"
    assert any("another contact fits the frame as well" in w for w in estimate.warnings)


def test_no_plane_where_the_rival_is_searched_does_not_refuse_the_estimate():
    """The paper sweep (azimuth step 60 deg), frame 16: a 30 mm part at 15 deg. The rival face searched
    from the dent's centroid has no plane of ``min_points`` inliers; that is no rival, and the estimate
    stands (it was refused: "no plane could be fitted to the pushed-in markers")."""
    spec = list(paper_sweep(theta_step_deg=60.0))[16]
    jig = default_jig()
    as_built = draw_as_built(jig, np.random.default_rng(np.random.SeedSequence(0, spawn_key=(0,))))
    pair = render_pair(
        as_built, spec.part, spec.pose, np.random.default_rng(np.random.SeedSequence(0, spawn_key=(1, 16)))
    )
    estimate = estimate_pair(pair.left, pair.right, jig, part_diameter_mm=spec.part.diameter_mm).estimate
    truth = np.asarray(frame_truth(as_built.jig, spec.pose)["normal"], dtype=float)
    assert math.degrees(math.acos(min(1.0, float(np.dot(estimate.normal, truth))))) < 3.0


@pytest.mark.parametrize("frame", [6, 9])
@pytest.mark.parametrize("with_size", [True, False], ids=["size", "no-size"])
def test_points_matched_to_the_next_marker_of_their_row_are_left_out(frame, with_size):
    """Zoo seed 4, design 32 (a jig 145 mm from cameras 43 mm apart): a 44 mm triangle 15 mm off the
    axis, tilted 16-17 deg, against the rest shape. Six markers whose partners were not detected are
    matched to the next marker along their row and triangulate 20-30 mm deep, off the membrane; they
    outvoted the face, and the estimate was "ok" and 15-17 deg off, with the part's size and without
    it. They are now left out, with a warning."""
    error, estimate = _estimate(32, frame, with_size=with_size, with_reference=False, seed=4)
    assert any("left out: they lie off the membrane" in w for w in estimate.warnings)
    assert not _silent(error, estimate), (error, estimate.tilt_sigma_deg, estimate.n_points)


@pytest.mark.parametrize("design_index", [17, 32])
def test_a_reference_frame_keeps_no_point_off_the_membrane(design_index):
    """Zoo seed 4, designs 17 and 32: their unloaded reference frames held 11 and 9 mismatched points,
    20-30 mm from every marker (six of design 17's in a block just above the plate), which were the
    reference of the markers beside them. Every reference marker now lies where a marker is."""
    design = _draw_design(design_index, 4, ZOO_FRAMES, ZooRanges())
    as_built = draw_as_built(
        design.jig, np.random.default_rng(np.random.SeedSequence(design.seed, spawn_key=(0,)))
    )
    rng = np.random.default_rng(np.random.SeedSequence(design.seed, spawn_key=(1, 0)))
    unloaded = render_pair(as_built, design.specs[0].part, design.specs[0].pose, rng)
    reference = reference_from_pair(unloaded.left, unloaded.right, design.jig)
    gap = np.linalg.norm(reference.xyz_mm[:, None, :] - unloaded.markers.xyz_mm[None, :, :], axis=2).min(
        axis=1
    )
    assert len(reference.xyz_mm) > 300
    assert gap.max() < 5.0, f"{int((gap >= 5.0).sum())} reference points lie 5 mm or more from every marker"


def test_the_wall_beside_a_deep_level_face_has_the_face_as_its_rival():
    """Zoo seed 5, design 32, frame 4, with the part's size and the reference: a 42 x 52 mm box 19 mm
    off the axis, level (1 deg), pushed 7.8 mm. The search from the jig axis settled on 27 markers of
    the wall beside its edge, which meet the face in a V: the face's markers lie above that plane, and
    nothing contradicted it ("ok", 18 deg off, sigma 1.5 deg). The face, deeper than most of the wall's
    markers, is now its rival."""
    error, estimate = _estimate(32, 4, with_size=True, with_reference=True, seed=5)
    if error > SILENT_ERROR_DEG:
        assert estimate.quality == "suspect", (error, estimate.tilt_sigma_deg)
        assert any("another contact fits the frame as well" in w for w in estimate.warnings)


# (seed, design, frame, with the reference frame): size-free, a small part 12-20 mm off the axis, tilted
# 9-20 deg, whose few contact markers (4-11) and the membrane's wall beside its lowered edge were fitted
# as one partial contact of 15-18 markers that passed the split check: "ok", 7-32 deg off, sigma 0.5-2.3
# deg (the silent failures of zoo seeds 3, 9 and 11 before the ninth session).
SMALL_PARTIAL_CONTACTS = [
    pytest.param(9, 24, 7, True, id="s9d24f7-reference-16.4deg"),
    pytest.param(9, 24, 16, False, id="s9d24f16-rest-11.2deg"),
    pytest.param(3, 18, 8, False, id="s3d18f8-rest-32.2deg"),
    pytest.param(11, 41, 3, True, id="s11d41f3-reference-10.2deg"),
]


@pytest.mark.parametrize(("seed", "design", "frame", "with_reference"), SMALL_PARTIAL_CONTACTS)
def test_a_small_partial_contact_found_without_the_size_is_suspect(seed, design, frame, with_reference):
    """Under ``PARTIAL_CONTACT_MIN_POINTS`` markers, a partial contact grown without the part's size is
    suspect, and says the part's size settles it; with the size, that reason is never given (or no face
    of that size is found, and the frame is refused)."""
    error, estimate = _estimate(design, frame, with_size=False, with_reference=with_reference, seed=seed)
    assert estimate.quality == "suspect", (error, estimate.n_points, estimate.warnings)
    assert any(
        "partial contact, found without the part's size" in w or "too few to check" in w
        for w in estimate.warnings
    ), estimate.warnings
    try:
        _, with_size = _estimate(design, frame, with_size=True, with_reference=with_reference, seed=seed)
    except EstimationError:  # no face of that size in the contact (seed 9, design 24, frame 7): refused
        return
    assert not any("found without the part's size" in w for w in with_size.warnings)


def test_a_small_partial_contact_that_replaces_a_doubted_face_under_the_known_size_is_suspect():
    """Zoo seed 12, design 8, frame 16, with the size and the reference: a 37 mm hexagon 13 mm off the axis,
    tilted 19 deg, 10 markers in contact. The face searched under the known size failed its checks, and
    the size-free contact (16 markers of the face and the wall beside its lowered edge, a partial contact
    that passed the split check) replaced it: "ok", 28.3 deg off, sigma 2.65 deg. Grown without the size,
    that contact is suspect under ``PARTIAL_CONTACT_MIN_POINTS`` markers even as the fallback, and says so.
    (Keeping the face instead, 1.0 deg off here, made 31 other estimates of the zoo 4-29 deg off.)"""
    error, estimate = _estimate(8, 16, with_size=True, with_reference=True, seed=12)
    assert not _silent(error, estimate), (
        error,
        estimate.tilt_sigma_deg,
        estimate.n_points,
        estimate.warnings,
    )
    if estimate.n_points < PARTIAL_CONTACT_MIN_POINTS:
        assert any("doubted only for its few markers in partial contact" in w for w in estimate.warnings)


@pytest.mark.parametrize(("seed", "design_index", "frame"), [(15, 0, 12), (9, 22, 10)])
def test_a_sized_face_that_the_size_free_contact_contradicts_is_suspect(seed, design_index, frame):
    """With the size and the reference. Zoo seed 15, design 0, frame 12: a 42 mm cylinder 20 mm off the
    axis, tilted 7 deg, 34 markers in contact. The face searched under the known size settled on 12 of
    them and 19 of the membrane draped beside its lifted edge: "ok", 10.7 deg off, sigma 2.5 deg. Seed 9,
    design 22, frame 10: a 35 mm cylinder 18 mm off the axis, tilted 3 deg: "ok", 12.2 deg off, sigma
    3.2 deg. In both, the contact grown without the size passes every check too (1.3 and 0.3 deg off)
    and lies beyond both their noise from it, so the sized estimate is suspect and says why; the
    size-free way stays right."""
    error, estimate = _estimate(design_index, frame, with_size=True, with_reference=True, seed=seed)
    assert not _silent(error, estimate), (
        error,
        estimate.tilt_sigma_deg,
        estimate.n_points,
        estimate.warnings,
    )
    if error > SILENT_ERROR_DEG:
        assert estimate.quality == "suspect"
        assert any("passes every check too" in w for w in estimate.warnings), estimate.warnings
    free_error, free = _estimate(design_index, frame, with_size=False, with_reference=True, seed=seed)
    assert free.quality == "ok" and free_error < SILENT_ERROR_DEG, (free_error, free.warnings)


def test_a_size_free_contact_that_is_neither_the_face_nor_its_rival_is_suspect():
    """Zoo seed 0, design 39, frame 18, with the size, against the rest shape, rendered with a damaged
    membrane, bubbles and glints (``bench_zoo.py --image-model damaged``): a 51 mm cylinder 10 mm off the
    axis, tilted 8 deg, 67 markers in contact, two of them mislocated 2-3 mm deep by the defects. The face
    under the known size and its rival lie 3.4 deg apart (suspect); the size-free contact (25 markers, 20
    of them the wall) passed every check and replaced them: "ok", 15.6 deg off, sigma 1.1 deg. A third
    plane is no resolution of the doubt: it is reported, but suspect, and says why."""
    error, estimate = _estimate(
        39, 18, with_size=True, with_reference=False, seed=0, render_jig=damaged_image_model
    )
    assert not _silent(error, estimate), (error, estimate.tilt_sigma_deg, estimate.warnings)
    if error > SILENT_ERROR_DEG:
        assert any("more plausible faces than one" in w for w in estimate.warnings), estimate.warnings


# (seed, design, frame, with the reference): with the size, the part's face and the strip of the
# membrane's wall beside its lowered edge were two plausible faces, and the wall was reported, suspect,
# with the face as its rival (the error each had, deg).
RIVALS = [
    pytest.param(8, 30, 3, True, id="s8d30f3-reference-27.5deg"),
    pytest.param(8, 30, 3, False, id="s8d30f3-rest-27.5deg"),
    pytest.param(1, 14, 4, False, id="s1d14f4-rest-26.2deg"),
    pytest.param(5, 32, 4, True, id="s5d32f4-reference-18.0deg"),
    pytest.param(12, 28, 4, True, id="s12d28f4-reference-17.4deg"),
]


@pytest.mark.parametrize(("seed", "design_index", "frame", "with_reference"), RIVALS)
def test_of_two_plausible_faces_of_the_parts_size_the_one_both_other_searches_prefer_is_reported(
    seed, design_index, frame, with_reference
):
    """Cylinders, boxes and polygons 32-45 mm across, 17-20 mm off the axis, tilted 1-13 deg. Both
    contacts are planes that no marker contradicts, so the estimate stays suspect; the one reported is
    now the rival that the contact found without the size lies nearer and whose plane, placed as a face
    of the part's size, the membrane under it fits better (``footprint_misfit``): the part's face, not
    the wall."""
    error, estimate = _estimate(design_index, frame, with_size=True, with_reference=with_reference, seed=seed)
    assert error < SILENT_ERROR_DEG, (error, estimate.warnings)
    assert estimate.quality == "suspect"
    assert any("of two plausible faces of the part's size" in w for w in estimate.warnings), estimate.warnings


def test_a_point_a_mismatch_put_deep_beside_the_face_is_off_the_membrane():
    """Damaged image model, zoo seed 3, design 32, frame 1, with the part's size and the reference: a
    marker matched to a glint or a bubble's highlight triangulated 11 mm deep beside the face, 8 mm
    deeper than its deepest neighbour 5.9 mm away. Judged at the markers' heights' noise (0.44 mm) a
    45-deg step joined it to them, and it was a hole beside the face, which lost to a strip of the
    wall: "ok" and 13.5 deg off, sigma 1.4 deg. At the depths' own noise (0.25 mm) it is off the
    membrane, and the face is found."""
    error, estimate = _estimate(
        32, 1, with_size=True, with_reference=True, seed=3, render_jig=damaged_image_model
    )
    assert any("left out: they lie off the membrane" in w for w in estimate.warnings)
    assert error < SILENT_ERROR_DEG, (error, estimate.tilt_sigma_deg, estimate.n_points)


# (design, frame, the way): damaged image model; a marker under a glint or a bubble's rim in one image, its
# centre pulled 3-4 px towards it (a point 2-3 mm deep), or its model fit failed and kept at the LoG peak (a
# glint matched to a marker: 11-20 mm), was a hole beside the face, which lost to a strip of the wall:
# "ok", the error (deg) in the id, sigma 1.1-1.7 deg.
LOPSIDED = [
    pytest.param(
        39, 18, {"seed": 0, "with_size": False, "with_reference": False}, id="s0d39f18-nosize-rest-15.6deg"
    ),
    pytest.param(
        18, 20, {"seed": 3, "with_size": True, "with_reference": False}, id="s3d18f20-size-rest-31.1deg"
    ),
]


@pytest.mark.parametrize(("design_index", "frame", "way"), LOPSIDED)
def test_a_marker_that_a_glint_or_a_bubble_makes_lopsided_is_left_out(design_index, frame, way):
    error, estimate = _estimate(design_index, frame, render_jig=damaged_image_model, **way)
    assert any("they do not look like a marker" in w for w in estimate.warnings)
    assert error < SILENT_ERROR_DEG, (error, estimate.tilt_sigma_deg, estimate.n_points)


# The silent failures left (benchmarks/RESULTS.md, 7 Dec 2026; seed, design, frame, with the size, with
# the reference, image model). In the first five, the membrane's wall beside a steeply tilted part's
# lowered edge and a few of the face's markers are fitted as one plane that nothing contradicts, "ok". In
# the last (a damaged membrane, bubbles and glints), a 41 mm part pushed 3.1 mm on a 10.2 mm grid whose
# depths scatter 0.7 mm touches 7 markers, and the wall wins though the points its glints and bubbles
# mislocated are left out.
# Strict: a fix makes one pass, and then it moves to the tests above. Two more of the bead-pack zoo,
# size-free, are left out: seed 9, design 48, frame 11 (3.0 deg off) and seed 13, design 4, frame 20
# (4.7 deg off, 4.05 sigmas) lie a hair over the line, where a last-digit change would flip them.
def test_a_head_that_finds_no_fiducials_is_levelled_on_the_frames_markers_at_rest():
    """Seed 3, design 37, frame 2, size-free against the rest shape: no fiducials in view and no reference
    frame, so the config's camera poses, which the as-built head departs from, put 229 of the 251 points
    over 1 mm from their markers; the estimate was "ok" and 19.4 deg off with a sigma of 2.3 deg. Levelled
    on the frame's own markers away from the contact, 36 are."""
    error, estimate = _estimate(37, 2, with_size=False, with_reference=False, seed=3)
    assert estimate.frame_source == "membrane at rest"
    assert any("levelled on" in warning for warning in estimate.warnings)
    assert not _silent(error, estimate), (error, estimate.tilt_sigma_deg)


@pytest.mark.parametrize(
    ("seed", "design_index", "frame"),
    [pytest.param(0, 29, 3, id="s0d29f3-was-unlevelled"), pytest.param(6, 4, 1, id="s6d4f1-was-aliased")],
)
def test_a_head_whose_alignment_lies_over_a_pitch_away_is_levelled_to_it(seed, design_index, frame):
    """The reference frame's level searched for the head's alignment only within a pitch of the config's
    poses, and a head tilted over a degree shifts the membrane further than that. Seed 0, design 29 (head
    tilted 1.54 deg, 11.6 mm pitch): two aliases fitted as well, the head was not levelled, and frame 3 was
    2.15 deg off in the config's poses. Seed 6, design 4 (1.24 deg, 4.5 mm pitch): an alias tilted 0.55
    deg won with a sigma of 0.02 deg, and its frames without fiducials were 1.5-2.6 deg off with sigmas of
    0.12-1.0 deg, 39 of 40 "ok" in the two reference ways (frame 1: 2.0 deg, sigma 0.17). Searched over
    three of the mounting's lateral sigmas, the alignments refined before they are compared, both are
    levelled to within 0.1 deg."""
    error, estimate = _estimate(design_index, frame, with_size=True, with_reference=True, seed=seed)
    assert estimate.frame_source == "membrane"
    assert error < 0.5 and error < 2 * estimate.tilt_sigma_deg, (error, estimate.tilt_sigma_deg)


def test_a_head_whose_reference_frame_fits_as_well_in_two_places_keeps_a_sigma_of_their_tilts():
    """Seed 0, design 42: the reference frame's markers fit the rest markers about as well in two places
    (alignments tilting the head 0.45 and 1.99 deg), so the head is not levelled, and the loaded frames
    without fiducials keep the config's poses. Their sigma is the alignments' RMS tilt times the oil's
    index, not the mounting tolerance's floor (1.1 deg): frame 2 is 1.3 deg off."""
    error, estimate = _estimate(42, 2, with_size=True, with_reference=True, seed=0)
    assert estimate.frame_source == "config"
    assert any("two places" in w for w in estimate.warnings)
    assert estimate.tilt_sigma_deg > 2.0 and error < estimate.tilt_sigma_deg, (error, estimate.tilt_sigma_deg)


@pytest.mark.parametrize(
    ("design_index", "frame", "with_reference"),
    [
        pytest.param(12, 14, True, id="s4d12f14-size-reference-11deg"),
        pytest.param(12, 14, False, id="s4d12f14-size-rest-12deg"),
    ],
)
def test_a_stretch_of_drape_fitted_far_from_the_dents_deepest_markers_is_suspect(
    design_index, frame, with_reference
):
    """A bead pack whose walls slope at 20 deg (``gentle_wall_model``), seed 4. Design 12, frame 14: a box
    tilted 17 deg pressed its lowered edge 12 mm deep, and the fit took 53 markers of the drape beside it,
    none in contact, 11-12 deg off and "ok" (sigma 0.7-1.6 deg). With the reference, 44 markers of the dent
    lie 1.7-9.6 pitches from them, all out of reach of the holes beside the contact, 1.9-5.5 mm below the
    plane where it would still press into the membrane, and deeper than any marker fitted: holes in the
    dent (:func:`~softjig.sensing.contact.holes_in_the_dent`)."""
    error, estimate = _estimate(
        design_index,
        frame,
        with_size=True,
        with_reference=with_reference,
        seed=4,
        render_jig=gentle_wall_model,
    )
    assert error > 3.0  # the drape is still what is fitted; the check makes it suspect, not right
    assert estimate.quality == "suspect"
    assert any("markers of the dent" in w for w in estimate.warnings), estimate.warnings


@pytest.mark.parametrize(
    ("design_index", "frame"),
    [
        pytest.param(0, 3, id="s4d0f3-was-38deg"),
        pytest.param(5, 5, id="s4d5f5-was-24deg"),
        pytest.param(20, 10, id="s4d20f10-was-33deg"),
    ],
)
def test_of_two_plausible_arms_of_a_v_the_larger_is_reported(design_index, frame):
    """Seed 4, size-free against the reference frame: the face of a part tilted 15-19 deg and the wall
    beside its lowered edge meet in a V, both plausible. The growth took the wall and kept the face as its
    rival (s4d0f3: 14 markers against 19, 38.4 deg off; s4d5f5 24.0, s4d20f10 33.1; all suspect), where
    the rest shape took the face (0.4-0.5 deg). The larger arm is now reported, the wall its rival: still
    suspect, and right."""
    error, estimate = _estimate(design_index, frame, with_size=False, with_reference=True, seed=4)
    assert error < 2.0, (error, estimate.n_points)
    assert estimate.quality == "suspect"
    assert any("another contact fits the frame as well" in w for w in estimate.warnings)


def test_a_sized_face_with_holes_in_its_dent_gives_way_to_the_contact_found_without_the_size():
    """Gentle walls, seed 4, design 39, frame 5, with the size and the reference: the face searched under
    the part's 65 mm size was a stretch of drape, 9 deg off and "ok", with 16 holes in its dent. Suspect
    for them, it gives way to the contact found without the size, the face: 0.7 deg and suspect for the
    other arm of its V at 4743428; 1.5 deg and "ok" with a sigma of 1.9 deg since the growth of that arm
    stays on the seed's depth (it is no longer a rival)."""
    error, estimate = _estimate(
        39, 5, with_size=True, with_reference=True, seed=4, render_jig=gentle_wall_model
    )
    assert error < 2.0, (error, estimate.n_points)
    assert not _silent(error, estimate)
    assert any("failed its checks" in w and "markers of the dent" in w for w in estimate.warnings), (
        estimate.warnings
    )


@pytest.mark.parametrize(
    ("design_index", "frame", "with_size"),
    [
        pytest.param(17, 10, False, id="s5d17f10-nosize-was-8.5deg-ok"),
        pytest.param(17, 7, False, id="s5d17f7-nosize-was-11deg"),
        pytest.param(32, 4, True, id="s5d32f4-size-was-11deg-ok"),
    ],
)
def test_a_level_face_whose_drape_meets_its_plane_far_off_is_not_a_silent_answer(
    design_index, frame, with_size
):
    """Gentle walls, seed 5, against the reference frame: the broad, shallow drape around a face tilted
    1-2 deg falls through the face's plane far from it, the growth over every pushed-in marker followed it
    there and was contradicted, and a strip of drape beside the face was fitted instead (s5d17f10: 101
    markers, 22 in contact, 8.5 deg off and "ok"; s5d17f7: 11 deg, suspect). Kept to the seed's depth,
    the growth stays on the face (:func:`~softjig.sensing.contact.grow_contact`). With the size
    (s5d32f4: 27 markers, 11 deg off and "ok"), the contact found without it is now the face, and
    contradicts the face searched under the size."""
    error, estimate = _estimate(
        design_index,
        frame,
        with_size=with_size,
        with_reference=True,
        seed=5,
        render_jig=gentle_wall_model,
    )
    assert not _silent(error, estimate), (error, estimate.tilt_sigma_deg, estimate.n_points)
    if with_size:
        assert any("the contact found without the part's size" in w for w in estimate.warnings)
    else:
        assert error < 1.0, (error, estimate.n_points)


SILENT_FAILURES_LEFT = [
    pytest.param(15, 15, 10, False, True, None, id="s15d15f10-nosize-reference-32deg"),
    pytest.param(2, 43, 9, True, True, stirred_image_model, id="stirred-s2d43f9-size-reference-13deg"),
    pytest.param(5, 47, 18, True, True, stirred_image_model, id="stirred-s5d47f18-size-reference-19deg"),
    pytest.param(5, 32, 2, False, False, stirred_image_model, id="stirred-s5d32f2-nosize-rest-16deg"),
    pytest.param(3, 18, 14, True, True, damaged_image_model, id="damaged-s3d18f14-size-reference-19deg"),
    # A bead pack whose wall stands at 20 deg (the zoo's designs: 35): beside a part tilted 17-18 deg the
    # wall slopes about as the face does (benchmarks/RESULTS.md, sixteenth session).
    pytest.param(4, 12, 8, False, True, gentle_wall_model, id="gentle-walls-s4d12f8-nosize-reference-17deg"),
]


@pytest.mark.xfail(
    strict=True,
    raises=AssertionError,
    reason="issue 13: silent failures not yet caught (benchmarks/RESULTS.md)",
)
@pytest.mark.parametrize(
    ("seed", "design_index", "frame", "with_size", "with_reference", "render_jig"), SILENT_FAILURES_LEFT
)
def test_the_silent_failures_left_are_not_silent(
    seed, design_index, frame, with_size, with_reference, render_jig
):
    error, estimate = _estimate(
        design_index,
        frame,
        with_size=with_size,
        with_reference=with_reference,
        seed=seed,
        render_jig=render_jig,
    )
    assert not _silent(error, estimate), (error, estimate.tilt_sigma_deg, estimate.n_points)
