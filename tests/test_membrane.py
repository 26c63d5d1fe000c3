"""Membrane contact physics: conformity, smooth decay, and loss of contact by geometry alone."""

import numpy as np
import pytest

from softjig.config import BoxPart, CylinderPart, default_jig, exact_jig
from softjig.jig_shape import marker_layout_xy, rest_inner_height_mm, rest_outer_height_mm
from softjig.sim.membrane import deform
from softjig.sim.parts import PartPose, under_bottom_face
from softjig.sim.zoo import GENTLE_WALL_SLOPE_DEG, gentle_wall_model

JIG = exact_jig()
XY = marker_layout_xy(JIG)


def _pressed(diameter, alpha_deg, theta_deg=0.0, push=3.0, part=None):
    part = part or CylinderPart(diameter)
    T = PartPose(np.radians(alpha_deg), np.radians(theta_deg), push).T_J_part(JIG)
    return part, T, deform(JIG, XY, part, T)


def test_rest_shape_and_layout():
    assert rest_inner_height_mm(JIG, np.array([0.0]), np.array([0.0]))[0] == pytest.approx(30.0)
    assert rest_inner_height_mm(JIG, np.array([95.0]), np.array([0.0]))[0] == pytest.approx(0.0)
    assert rest_outer_height_mm(JIG, np.array([0.0]), np.array([0.0]))[0] == pytest.approx(30.7)
    assert 300 < len(XY) < 500  # "a few hundred" markers at 8 mm pitch
    d = np.linalg.norm(XY[:, None] - XY[None], axis=2) + np.eye(len(XY)) * 1e9
    assert d.min() == pytest.approx(8.0)


def test_unloaded_jig_is_at_rest():
    state = deform(JIG, XY)
    assert not state.in_contact.any()
    assert np.allclose(state.indentation_mm, 0.0)
    assert np.all(state.marker_axis[:, 2] < 0)  # hemispheres point down into the oil


def test_flat_push_conforms_to_the_face():
    _, T, state = _pressed(50, 0.0, push=3.0)
    c = state.in_contact
    r = np.hypot(*XY.T)
    assert c.sum() == (r <= 25).sum()  # all markers under the face touch it
    # in contact, the inner face lies one membrane thickness below the part's face
    assert np.allclose(state.marker_xyz_mm[c, 2], T[2, 3] - JIG.membrane.thickness_mm)
    assert np.allclose(state.marker_axis[c], [0, 0, -1])


def test_decay_is_smooth_and_monotone():
    _, _, state = _pressed(50, 0.0, push=3.0)
    r = np.hypot(*XY.T)
    out = ~state.in_contact & (r > 25)
    order = np.argsort(r[out])
    w = state.indentation_mm[out][order]
    # the indentation just outside the face is a good part of the push, then decays to ~0 far away
    assert 0.5 < w[0] < 3.0
    assert np.all(np.diff(w[r[out][order] < 60]) <= 1e-9 + 0.5)  # no jumps upward
    assert w[-1] < 0.01
    near = (r > 25) & (r < 33)
    assert np.all(state.indentation_mm[near] > 0.05)  # not a step: the neighbours are pulled down


def test_large_part_tilted_far_loses_contact_on_its_raised_side():
    theta = np.radians(30)
    part, T, state = _pressed(80, 20.0, theta_deg=30.0)
    under = under_bottom_face(part, T, XY[:, 0], XY[:, 1])
    along = XY @ [np.cos(theta), np.sin(theta)]  # the face descends towards +theta
    raised = under & (along < -15)
    lowered = under & (along > 15)
    assert raised.sum() > 5 and not state.in_contact[raised].any()
    assert state.in_contact[lowered].all()


def test_small_part_small_tilt_keeps_full_contact():
    part, T, state = _pressed(30, 5.0, theta_deg=123.0)
    under = under_bottom_face(part, T, XY[:, 0], XY[:, 1])
    assert under.sum() >= 9 and state.in_contact[under].all()


def test_box_and_ripple_determinism():
    part = BoxPart(50, 50, 50)
    T = PartPose(np.radians(8), np.radians(200), 3.0, yaw_rad=0.4).T_J_part(JIG)
    a = deform(JIG, XY, part, T, ripple_mm=0.1, rng=3)
    b = deform(JIG, XY, part, T, ripple_mm=0.1, rng=3)
    flat = deform(JIG, XY, part, T)
    assert np.array_equal(a.marker_xyz_mm, b.marker_xyz_mm)
    dz = (a.marker_xyz_mm - flat.marker_xyz_mm)[a.in_contact, 2]
    assert 0.05 < dz.std() < 0.15
    assert np.array_equal(a.in_contact, flat.in_contact)


def test_edge_conformity_pulls_edge_markers_off_the_face():
    part, T, state = _pressed(60, 0.0)
    lax = deform(default_jig(), XY, part, T, edge_conformity_mm=0.3)
    dz = state.marker_xyz_mm[:, 2] - lax.marker_xyz_mm[:, 2]
    r = np.hypot(*XY.T)
    c = state.in_contact
    assert dz[c & (r > 24)].mean() > dz[c & (r < 8)].mean() > 0


def test_a_gentle_walled_bead_pack_rises_beside_a_deep_contact_no_steeper_than_its_angle():
    """The wall beside a face pushed 6 mm in rises at the bead pack's angle of repose at most: the
    default's 35 deg, and 20 deg in :func:`gentle_wall_model` (a wider, gentler drape)."""

    def steepest_wall_deg(jig):
        part = CylinderPart(50)
        xy = np.column_stack([np.arange(0.0, 60.0, 0.5), np.zeros(120)])  # a ray of markers
        w = deform(jig, xy, part, PartPose(0.0, 0.0, 6.0).T_J_part(jig)).indentation_mm
        return np.degrees(np.arctan(np.max(-np.diff(w) / 0.5)))

    gentle = steepest_wall_deg(gentle_wall_model(JIG))
    assert gentle <= GENTLE_WALL_SLOPE_DEG + 1.0 < steepest_wall_deg(JIG)
