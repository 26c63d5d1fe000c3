"""Jigs people build: dome profiles, marker layouts, part kinds and placements, exact TOML round trips."""

import math
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from softjig.config import (
    BoxPart,
    ConvexPolygonPart,
    CylinderPart,
    PartPlacement,
    RegularPolygonPart,
    default_jig,
    dumps_jig,
    exact_jig,
    jig_from_dict,
    jig_to_dict,
    loads_jig,
    part_from_dict,
    part_to_dict,
    placement_from_dict,
    validate_part,
)
from softjig.errors import ConfigError
from softjig.jig_shape import (
    marker_layout_xy,
    rest_inner_height_mm,
    rest_marker_points_mm,
    rest_outer_height_mm,
    rest_profile_mm,
    rest_slope,
)
from softjig.sensing.identities import rest_shape_reference
from softjig.sim.membrane import deform
from softjig.sim.parts import PartPose, bottom_face_rim, bottom_face_samples, under_bottom_face

JIG = exact_jig()


def _membrane(**changes):
    return JIG.replace(membrane=replace(JIG.membrane, **changes))


def _markers(**changes):
    return JIG.replace(markers=replace(JIG.markers, **changes))


# ------------------------------------------------------------------------------- the default is unchanged


def test_default_layout_and_rest_shape_equal_the_first_versions():
    """The first versions' formulas, written out: the default jig's numbers must not move by a bit."""
    jig = default_jig()
    xy = marker_layout_xy(jig)
    i, j = np.meshgrid(np.arange(-12, 13), np.arange(-12, 13), indexing="xy")
    old = np.stack([i.ravel() * 8.0, j.ravel() * 8.0], axis=1)
    old = old[np.hypot(old[:, 0], old[:, 1]) <= 87.0]
    assert np.array_equal(xy, old) and len(xy) == 373
    x = np.array([0.0, 10.0, -33.3, 60.0, 87.0, 94.99, 95.0, 120.0])
    y = np.array([0.0, 5.0, 20.0, -45.0, 0.0, 0.0, 0.0, 3.0])
    r = np.hypot(x, y) / 95.0
    h_old = np.where(r < 1.0, 30.0 * (1.0 - np.minimum(r, 1.0) ** 4.0), 0.0)
    assert np.array_equal(rest_inner_height_mm(jig, x, y), h_old)
    dh = -30.0 * 4.0 * np.minimum(r, 1.0) ** 3 / 95.0
    with np.errstate(invalid="ignore", divide="ignore"):
        gx = np.where(np.hypot(x, y) < 95, dh * np.where(r > 0, x / np.hypot(x, y), 0.0), 0.0)
        gy = np.where(np.hypot(x, y) < 95, dh * np.where(r > 0, y / np.hypot(x, y), 0.0), 0.0)
    assert np.array_equal(rest_slope(jig, x, y)[0], gx) and np.array_equal(rest_slope(jig, x, y)[1], gy)
    assert np.array_equal(rest_outer_height_mm(jig, x, y), h_old + 0.7 * np.sqrt(1 + gx**2 + gy**2))
    assert np.array_equal(rest_marker_points_mm(jig)[:, 2], rest_inner_height_mm(jig, *xy.T))
    assert np.array_equal(rest_shape_reference(jig).xyz_mm, rest_marker_points_mm(jig))


# ---------------------------------------------------------------------------------------- dome profiles


def test_paraboloid_power_profile():
    jig = _membrane(dome_profile="paraboloid_power", dome_exponent=0.5)
    r = np.array([0.0, 30.0, 60.0, 90.0, 95.0, 100.0])
    h, dh = rest_profile_mm(jig, r)
    assert np.allclose(h, np.where(r < 95, 30 * np.sqrt(np.clip(1 - (r / 95) ** 2, 0, None)), 0.0))
    # the slope is the derivative of the height (central differences)
    e = 1e-5
    inner = r[1:4]
    numeric = (rest_profile_mm(jig, inner + e)[0] - rest_profile_mm(jig, inner - e)[0]) / (2 * e)
    assert np.allclose(dh[1:4], numeric, rtol=1e-5)
    assert dh[0] == 0 and dh[-1] == 0
    # a vertical wall at the rim: the outer face's offset stays finite
    assert np.isfinite(rest_outer_height_mm(jig, np.array([94.9999999]), np.array([0.0]))).all()
    p1 = _membrane(dome_profile="paraboloid_power", dome_exponent=1.0)
    assert rest_profile_mm(p1, np.array([47.5]))[0][0] == pytest.approx(30 * 0.75)


def test_measured_table_profile_is_smooth_monotone_and_flat_on_top():
    r = np.linspace(0.0, 87.0, 12)
    h = rest_profile_mm(JIG, r)[0]
    jig = _membrane(dome_profile="table", profile_r_mm=tuple(r), profile_h_mm=tuple(h))
    rr = np.linspace(0.0, 95.0, 400)
    ht, dht = rest_profile_mm(jig, rr)
    assert np.all(np.diff(ht) <= 1e-12)  # monotone: never rises away from the axis
    assert dht[0] == pytest.approx(0.0, abs=1e-12)  # flat on top, no cone at the axis
    assert np.allclose(ht[rr <= 87], rest_profile_mm(JIG, rr[rr <= 87])[0], atol=0.05)
    assert ht[-1] == pytest.approx(0.0)  # continued to the clamped rim
    numeric = np.gradient(ht, rr)
    assert np.allclose(dht[5:-5], numeric[5:-5], atol=0.02)
    assert loads_jig(dumps_jig(jig)) == jig


@pytest.mark.parametrize(
    ("changes", "field"),
    [
        (
            {"dome_profile": "table", "profile_r_mm": [0, 40, 80], "profile_h_mm": [30, 31, 5]},
            "profile_h_mm\\[1\\]",
        ),
        (
            {"dome_profile": "table", "profile_r_mm": [0, 40, 30], "profile_h_mm": [30, 20, 5]},
            "profile_r_mm\\[2\\]",
        ),
        ({"dome_profile": "table", "profile_r_mm": [5, 40], "profile_h_mm": [30, 20]}, "profile_r_mm"),
        ({"dome_profile": "table", "profile_r_mm": [0, 40], "profile_h_mm": [29, 20]}, "profile_h_mm"),
        ({"dome_profile": "table", "profile_r_mm": [0, 40, 99], "profile_h_mm": [30, 20, 0]}, "profile_r_mm"),
        ({"dome_profile": "table", "profile_r_mm": [0, 40], "profile_h_mm": [30]}, "profile_h_mm"),
        ({"dome_profile": "power", "profile_r_mm": [0, 40], "profile_h_mm": [30, 3]}, "profile_r_mm"),
        ({"dome_profile": "paraboloid_power", "dome_exponent": 2.0}, "dome_exponent"),
        ({"dome_profile": "cone"}, "dome_profile"),
    ],
)
def test_bad_dome_profile_names_the_field(changes, field):
    data = jig_to_dict(JIG)
    data["membrane"].update(changes)
    with pytest.raises(ConfigError, match=f"membrane\\.{field}"):
        jig_from_dict(data)


def test_non_monotone_table_says_so():
    data = jig_to_dict(JIG)
    data["membrane"].update(dome_profile="table", profile_r_mm=[0, 40, 80], profile_h_mm=[30, 31, 5])
    with pytest.raises(ConfigError, match="not monotone"):
        jig_from_dict(data)


def test_every_profile_works_in_the_membrane_contact():
    r = np.linspace(0.0, 87.0, 10)
    jigs = [
        JIG,
        _membrane(dome_profile="paraboloid_power", dome_exponent=0.3),
        _membrane(
            dome_profile="table", profile_r_mm=tuple(r), profile_h_mm=tuple(30 * (1 - (r / 95) ** 2) ** 0.7)
        ),
    ]
    for jig in jigs:
        xy = marker_layout_xy(jig)
        T = PartPose(math.radians(5), 0.3, 3.0).T_J_part(jig)
        state = deform(jig, xy, CylinderPart(50.0), T)
        assert state.in_contact.sum() >= 20
        c = state.in_contact
        # in contact the inner face lies on the part's face, one thickness below it
        assert np.allclose(state.indentation_mm[~c & (np.hypot(*xy.T) > 60)], 0.0, atol=0.05)
        assert np.all(np.isfinite(state.marker_xyz_mm))
        # the contact starts at the outer rest face: the face's centre is 3 mm below it
        assert T[2, 3] == pytest.approx(rest_outer_height_mm(jig, np.zeros(1), np.zeros(1))[0] - 3.0)


# --------------------------------------------------------------------------------------- marker layouts


@pytest.mark.parametrize("layout", ["square", "hex"])
def test_rotated_offset_grid(layout):
    jig = _markers(layout=layout, rotation_deg=15.0, offset_mm=(2.0, -3.0), pitch_mm=6.0)
    xy = marker_layout_xy(jig)
    assert np.hypot(*xy.T).max() <= 87.0
    assert np.min(np.hypot(*(xy - [2.0, -3.0]).T)) == pytest.approx(0.0, abs=1e-12)
    # the grid's axes are turned by 15 degrees: every marker's offset from the centre, turned back, is
    # on the unturned grid
    a = math.radians(-15.0)
    back = (xy - [2.0, -3.0]) @ np.array([[math.cos(a), math.sin(a)], [-math.sin(a), math.cos(a)]])
    row = 6.0 * math.sqrt(3) / 2 if layout == "hex" else 6.0
    j = np.round(back[:, 1] / row)
    assert np.allclose(back[:, 1], j * row, atol=1e-9)
    shift = 0.5 * (j % 2) if layout == "hex" else 0.0
    assert np.allclose(back[:, 0] / 6.0 - shift, np.round(back[:, 0] / 6.0 - shift), atol=1e-9)
    d = np.linalg.norm(xy[:, None] - xy[None], axis=2) + np.eye(len(xy)) * 1e9
    assert d.min() == pytest.approx(6.0)
    # the whole disc is covered: as many markers as the area says (within the rim's rounding)
    cell = 36.0 * (math.sqrt(3) / 2 if layout == "hex" else 1.0)
    assert abs(len(xy) - math.pi * 87.0**2 / cell) < 0.05 * len(xy)
    assert loads_jig(dumps_jig(jig)) == jig


def test_fine_hex_grid_reaches_the_rim():
    """The first versions' hex grid stopped short of the rim in y for fine pitches."""
    jig = _markers(layout="hex", pitch_mm=4.0, diameter_mm=2.0)
    xy = marker_layout_xy(jig)
    assert np.abs(xy[:, 1]).max() > 83.0


def _explicit(xy, **more):
    return _markers(layout="explicit", centers_mm=tuple(map(tuple, xy)), **more)


def test_explicit_layout_with_measured_heights():
    xy = marker_layout_xy(JIG) + 0.3
    z = rest_inner_height_mm(JIG, *xy.T) - 0.2
    jig = _explicit(xy, centers_z_mm=tuple(z))
    assert np.array_equal(marker_layout_xy(jig), xy)
    assert np.array_equal(rest_marker_points_mm(jig), np.column_stack([xy, z]))
    assert np.array_equal(rest_shape_reference(jig).xyz_mm, np.column_stack([xy, z]))  # the estimator's
    assert loads_jig(dumps_jig(jig)) == jig
    plain = _explicit(xy)
    assert np.array_equal(rest_marker_points_mm(plain)[:, 2], rest_inner_height_mm(JIG, *xy.T))


def test_overlapping_markers_are_refused_naming_them():
    xy = marker_layout_xy(JIG).copy()
    xy[7] = xy[6] + [1.0, 1.0]  # 1.4 mm from its neighbour, markers of 3 mm
    data = jig_to_dict(_explicit(marker_layout_xy(JIG)))
    data["markers"]["centers_mm"] = xy.tolist()
    with pytest.raises(ConfigError, match=r"markers\.centers_mm\[7\]: overlaps markers\.centers_mm\[6\]"):
        jig_from_dict(data)


@pytest.mark.parametrize(
    ("changes", "field"),
    [
        ({"centers_mm": [[0, 0], [8, 0]]}, "markers.centers_mm"),  # too few
        ({"centers_mm": [[0, 0], [8, 0], [0, 8], [100, 0]]}, r"markers.centers_mm\[3\]"),  # off the membrane
        ({"centers_mm": [[0, 0], [8, 0], [0, 8]], "centers_z_mm": [30, 29]}, "markers.centers_z_mm"),
        (
            {"centers_mm": [[0, 0], [8, 0], [0, 8]], "centers_z_mm": [30, 29, -1]},
            r"markers.centers_z_mm\[2\]",
        ),
        ({"centers_mm": [[0, 0], [8, 0], [0, 8]], "rotation_deg": 10.0}, "markers.rotation_deg"),
        ({"centers_mm": [[0, 0], [20, 0], [0, 20]]}, "markers.pitch_mm"),
    ],
)
def test_bad_explicit_layout_names_the_field(changes, field):
    data = jig_to_dict(JIG)
    data["markers"].update(layout="explicit", **changes)
    with pytest.raises(ConfigError, match=field.replace(".", r"\.")):
        jig_from_dict(data)


@pytest.mark.parametrize(
    ("changes", "field"),
    [
        ({"offset_mm": [90.0, 0.0]}, "markers.offset_mm"),
        ({"centers_mm": [[0, 0]]}, "markers.centers_mm"),
        ({"pitch_mm": 1.05, "diameter_mm": 1.0}, "markers.pitch_mm"),  # 22600 markers: capped
    ],
)
def test_bad_grid_names_the_field(changes, field):
    data = jig_to_dict(JIG)
    data["markers"].update(changes)
    with pytest.raises(ConfigError, match=field.replace(".", r"\.")):
        jig_from_dict(data)


# ------------------------------------------------------------------------------------------------ parts

HEXAGON = RegularPolygonPart(n_sides=6, across_flats_mm=40.0)
QUAD = ConvexPolygonPart(vertices_mm=((-20.0, -20.0), (25.0, -15.0), (10.0, 25.0), (-15.0, 18.0)))
PARTS = [CylinderPart(50.0), BoxPart(40.0, 60.0, 20.0), HEXAGON, RegularPolygonPart(5, 36.0, 10.0), QUAD]


@pytest.mark.parametrize("part", PARTS, ids=lambda p: p.kind)
def test_every_part_kind(part):
    assert part_from_dict(part_to_dict(part)) == part
    validate_part(part, JIG)
    outline = part.outline_mm()
    assert outline.ndim == 2 and outline.shape[1] == 2
    # the inscribed circle about the origin touches the outline, and is inside it
    radius = part.diameter_mm / 2.0
    assert np.hypot(*outline.T).max() == pytest.approx(part.circumradius_mm())
    pose = PartPose(math.radians(6), math.radians(40), 3.0, center_xy_mm=(12.0, -7.0), yaw_rad=0.7)
    T = pose.T_J_part(JIG)
    ring = np.linspace(0, 2 * np.pi, 50, endpoint=False)
    inside = (radius - 1e-6) * np.column_stack([np.cos(ring), np.sin(ring), 0 * ring]) @ T[:3, :3].T + T[
        :3, 3
    ]
    assert under_bottom_face(part, T, inside[:, 0], inside[:, 1]).all()
    beyond = (part.circumradius_mm() + 0.1) * np.column_stack([np.cos(ring), np.sin(ring), 0 * ring])
    beyond = beyond @ T[:3, :3].T + T[:3, 3]
    assert not under_bottom_face(part, T, beyond[:, 0], beyond[:, 1]).any()
    # samples lie on the face and under it; the rim is on its edge
    samples = bottom_face_samples(part, T, 2.0)
    assert len(samples) > 50 and under_bottom_face(part, T, samples[:, 0], samples[:, 1]).all()
    rim = bottom_face_rim(part, T, 0.5)
    local = (rim - T[:3, 3]) @ T[:3, :3]
    assert np.allclose(local[:, 2], 0.0, atol=1e-9)
    # the membrane conforms to the face where it is pressed, wherever the part is
    xy = marker_layout_xy(JIG)
    state = deform(JIG, xy, part, T)
    assert state.in_contact.sum() >= 10
    assert under_bottom_face(part, T, *xy[state.in_contact].T).all()
    centre = np.hypot(*(xy - [12.0, -7.0]).T) < radius - 8
    assert state.in_contact[centre].all()


def test_polygon_geometry():
    hexagon = HEXAGON.outline_mm()
    assert len(hexagon) == 6
    assert np.hypot(*hexagon.T) == pytest.approx(np.full(6, 20.0 / math.cos(math.pi / 6)))
    assert hexagon[:, 0].max() == pytest.approx(20.0)  # a side faces +x: 40 mm across flats
    square = RegularPolygonPart(4, 30.0).outline_mm()
    assert np.allclose(np.sort(np.abs(square), axis=0), 15.0)  # a square is an axis-aligned box
    clockwise = ConvexPolygonPart(vertices_mm=QUAD.vertices_mm[::-1])
    assert np.array_equal(clockwise.outline_mm(), QUAD.outline_mm())
    assert QUAD.diameter_mm == pytest.approx(2 * 17.22, abs=0.01)


@pytest.mark.parametrize(
    ("vertices", "message"),
    [
        (((-20, -20), (20, -20), (0, -5), (20, 20), (-20, 20)), r"part\.vertices_mm\[2\].*not convex"),
        (((-20, -20), (20, 20), (20, -20), (-20, 20)), r"part\.vertices_mm"),  # a bow tie: crosses itself
        (
            tuple((20 * math.cos(a), 20 * math.sin(a)) for a in np.arange(5) * 4 * math.pi / 5),
            r"part\.vertices_mm.*crosses itself",
        ),  # a pentagram: every turn the same way, twice around
        (((0, 0), (10, 0), (0, 10)), r"part\.vertices_mm.*origin"),
        (((-1, -1), (1, -1)), r"part\.vertices_mm"),
        (((-1, -1), (1, -1), (1, -1), (0, 1)), r"part\.vertices_mm\[1\]"),
    ],
)
def test_bad_convex_polygon_is_refused(vertices, message):
    with pytest.raises(ConfigError, match=message):
        part_from_dict({"kind": "convex", "vertices_mm": [list(v) for v in vertices]})


@pytest.mark.parametrize(
    "part",
    [
        CylinderPart(200.0),
        BoxPart(150.0, 150.0, 10.0),
        RegularPolygonPart(6, 180.0),
        ConvexPolygonPart(((-100.0, -10.0), (100.0, -10.0), (0.0, 30.0))),
    ],
    ids=lambda p: p.kind,
)
def test_part_wider_than_the_membrane_is_refused(part):
    with pytest.raises(ConfigError, match="wider than the membrane"):
        validate_part(part, JIG)


def test_placement():
    placement = placement_from_dict({"center_xy_mm": [10.0, -5.0], "yaw_deg": 30.0, "push_depth_mm": 3.0})
    assert placement == PartPlacement((10.0, -5.0), 30.0)
    validate_part(HEXAGON, JIG, placement)
    with pytest.raises(ConfigError, match=r"pose\.center_xy_mm"):
        validate_part(HEXAGON, JIG, PartPlacement((80.0, 0.0)))
    with pytest.raises(ConfigError, match=r"pose\.yaw_deg"):
        placement_from_dict({"yaw_deg": float("nan")})
    pose = PartPose.placed(placement, push_depth_mm=2.0)
    assert pose.center_xy_mm == (10.0, -5.0) and pose.yaw_rad == pytest.approx(math.radians(30.0))


@pytest.mark.parametrize(
    ("data", "field"),
    [
        ({"kind": "polygon", "n_sides": 2, "across_flats_mm": 30}, "part.n_sides"),
        ({"kind": "polygon", "n_sides": 6, "across_flats_mm": -3}, "part.across_flats_mm"),
        ({"kind": "polygon", "n_sides": 6}, "part.across_flats_mm"),
        ({"kind": "cylinder", "diameter_mm": float("nan")}, "part.diameter_mm"),
        ({"kind": "box", "size_x_mm": 3, "size_y_mm": float("inf"), "height_mm": 3}, "part.size_y_mm"),
    ],
)
def test_bad_part_names_the_field(data, field):
    with pytest.raises(ConfigError, match=field.replace(".", r"\.")):
        part_from_dict(data)


# ----------------------------------------------------------------------------------- exact round trips

finite = st.floats(min_value=-1e3, max_value=1e3, allow_nan=False, allow_infinity=False)


@st.composite
def real_jigs(draw):
    jig = JIG
    profile = draw(st.sampled_from(["power", "paraboloid_power", "table"]))
    if profile == "power":
        membrane = replace(jig.membrane, dome_exponent=draw(st.floats(1.0, 8.0)))
    elif profile == "paraboloid_power":
        membrane = replace(jig.membrane, dome_profile=profile, dome_exponent=draw(st.floats(0.05, 1.0)))
    else:
        n = draw(st.integers(2, 12))
        steps = draw(st.lists(st.floats(0.5, 9.0), min_size=n - 1, max_size=n - 1))
        drops = draw(st.lists(st.floats(0.0, 2.0), min_size=n - 1, max_size=n - 1))
        r = np.concatenate([[0.0], np.cumsum(steps)])
        h = 30.0 - np.concatenate([[0.0], np.cumsum(drops)])
        membrane = replace(
            jig.membrane,
            dome_profile="table",
            profile_r_mm=tuple(map(float, r)),
            profile_h_mm=tuple(map(float, h)),
        )
    layout = draw(st.sampled_from(["square", "hex", "explicit"]))
    if layout == "explicit":
        n = draw(st.integers(3, 30))
        angle = np.arange(n) * 2 * np.pi / n + draw(st.floats(0, 1))
        radius = draw(st.floats(20.0, 80.0))
        xy = radius * np.column_stack([np.cos(angle), np.sin(angle)])
        xy += np.array(draw(st.lists(st.floats(-0.5, 0.5), min_size=2 * n, max_size=2 * n))).reshape(n, 2)
        spacing = float(np.median(np.sort(np.linalg.norm(xy[:, None] - xy[None], axis=2), axis=1)[:, 1]))
        with_z = draw(st.booleans())
        markers = replace(
            jig.markers,
            layout="explicit",
            pitch_mm=spacing,
            diameter_mm=min(3.0, 0.5 * spacing),
            centers_mm=tuple((float(a), float(b)) for a, b in xy),
            centers_z_mm=tuple(draw(st.floats(0.1, 40.0)) for _ in range(n)) if with_z else (),
        )
    else:
        markers = replace(
            jig.markers,
            layout=layout,
            rotation_deg=draw(finite),
            offset_mm=(draw(st.floats(-20, 20)), draw(st.floats(-20, 20))),
        )
    return jig.replace(membrane=membrane, markers=markers)


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(real_jigs())
def test_toml_round_trip_is_exact_for_every_new_field(jig):
    text = dumps_jig(jig)
    back = loads_jig(text)
    assert back == jig
    assert dumps_jig(back) == text
    assert np.array_equal(marker_layout_xy(back), marker_layout_xy(jig))


@st.composite
def parts(draw):
    kind = draw(st.sampled_from(["cylinder", "box", "polygon", "convex"]))
    size = st.floats(1.0, 150.0)
    if kind == "cylinder":
        return CylinderPart(draw(size), draw(size))
    if kind == "box":
        return BoxPart(draw(size), draw(size), draw(size))
    if kind == "polygon":
        return RegularPolygonPart(draw(st.integers(3, 64)), draw(size), draw(size))
    n = draw(st.integers(3, 16))
    angle = np.sort(np.array(draw(st.lists(st.floats(0, 2 * np.pi), min_size=n, max_size=n, unique=True))))
    angle = angle[np.concatenate([[True], np.diff(angle) > 0.05]) & (angle < 2 * np.pi - 0.05)]
    if len(angle) < 3 or np.max(np.diff(np.concatenate([angle, [angle[0] + 2 * np.pi]]))) >= np.pi - 0.05:
        angle = np.array([0.0, 2.0, 4.0])
    radius = draw(size)
    vertices = tuple((float(radius * np.cos(a)), float(radius * np.sin(a))) for a in angle)
    return ConvexPolygonPart(vertices, draw(size))


@settings(max_examples=60, deadline=None)
@given(parts())
def test_part_dict_round_trip_is_exact(part):
    import json

    assert part_from_dict(json.loads(json.dumps(part_to_dict(part)))) == part


def test_dataset_with_a_non_convex_part_exits_2(tmp_path):
    import json

    from typer.testing import CliRunner

    from softjig.cli import app
    from softjig.io.simulated import simulate_dataset
    from softjig.sim.scenarios import FrameSpec

    out = tmp_path / "ds"
    simulate_dataset(
        out, [FrameSpec(None, None, {"reference": True})], JIG, seed=0, workers=1, progress=False
    )
    frames = out / "frames.jsonl"
    first = json.loads(frames.read_text().splitlines()[0])
    bad = {
        **{k: first[k] for k in ("left", "right")},
        "index": 1,
        "part": {"kind": "convex", "vertices_mm": [[-20, -20], [20, -20], [0, -5], [20, 20], [-20, 20]]},
    }
    frames.write_text(frames.read_text() + json.dumps(bad) + "\n")
    result = CliRunner().invoke(app, ["estimate", str(out), "--out", str(tmp_path / "est.jsonl")])
    assert result.exit_code == 2, result.output
    assert "part.vertices_mm[2]" in result.output and "not convex" in result.output
