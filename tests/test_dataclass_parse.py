"""`parse_dataclass` against pydantic (the oracle it replaced on the start-up path): the same values from
the same configs, and a refusal of every config pydantic refuses, naming the same field."""

from __future__ import annotations

import copy
import math
from dataclasses import replace

import pytest
from pydantic import TypeAdapter, ValidationError

from softjig.config import (
    BoxPart,
    ConvexPolygonPart,
    CylinderPart,
    JigConfig,
    PartPlacement,
    RegularPolygonPart,
    default_jig,
    jig_to_dict,
    part_to_dict,
)
from softjig.dataclass_parse import parse_dataclass
from softjig.errors import ConfigError
from softjig.sim.zoo import draw_designs

PARTS = [
    CylinderPart(diameter_mm=40.0),
    BoxPart(size_x_mm=30.0, size_y_mm=20.0, height_mm=10.0),
    RegularPolygonPart(n_sides=6, across_flats_mm=35.0),
    ConvexPolygonPart(vertices_mm=((0.0, 0.0), (20.0, 0.0), (5.0, 15.0))),
]


def _configs() -> list[tuple[type, dict]]:
    """Plain dicts of real configs: the default jig, a hand-made one, 8 zoo designs (profiles, layouts
    and optics the zoo draws), the four part kinds and a placement."""
    base = default_jig()
    hand_made = replace(  # a measured dome and an explicit marker list: no zoo design has them
        base,
        membrane=replace(base.membrane, dome_profile="table", profile_r_mm=(0.0, 40.0, 80.0),
                         profile_h_mm=(30.0, 22.0, 0.0)),
        markers=replace(base.markers, layout="explicit", centers_mm=((0.0, 0.0), (8.0, 0.0)),
                        centers_z_mm=(30.0, 29.5)),
    )  # fmt: skip
    jigs = [base, hand_made, *(design.jig for design in draw_designs(8, seed=3, frames=1))]
    cases = [(JigConfig, jig_to_dict(jig)) for jig in jigs]
    cases += [(type(part), {k: v for k, v in part_to_dict(part).items()}) for part in PARTS]
    cases.append((PartPlacement, {"center_xy_mm": [2, -3.5], "yaw_deg": 15}))
    return cases


CONFIGS = _configs()


ADAPTERS = {cls: TypeAdapter(cls) for cls in {cls for cls, _ in CONFIGS}}


def _pydantic(cls: type, data: dict):
    """pydantic's reading, or the dotted location of its first error."""
    try:
        return ADAPTERS[cls].validate_python(data), None
    except ValidationError as exc:
        return None, ".".join(str(part) for part in exc.errors()[0]["loc"])


def _ours(cls: type, data: dict):
    try:
        return parse_dataclass(cls, data), None
    except ConfigError as exc:
        return None, str(exc).split(":", 1)[0]


def _leaves(data, path=()):
    """Every (path, value) of a nested dict/list."""
    if isinstance(data, dict):
        for key, value in data.items():
            yield from _leaves(value, (*path, key))
    elif isinstance(data, list | tuple) and data:
        for index, value in enumerate(data):
            yield from _leaves(value, (*path, index))
    else:
        yield path, data


def _set(data, path, value):
    changed = copy.deepcopy(data)
    node = changed
    for key in path[:-1]:
        node = node[key]
    if isinstance(node, tuple):
        raise TypeError  # jig_to_dict gives lists
    node[path[-1]] = value
    return changed


def _listify(data):
    """Tuples as lists, as TOML gives them."""
    if isinstance(data, dict):
        return {k: _listify(v) for k, v in data.items()}
    if isinstance(data, list | tuple):
        return [_listify(v) for v in data]
    return data


@pytest.mark.agreement
@pytest.mark.parametrize("case", range(len(CONFIGS)))
def test_the_same_configs_give_the_same_values(case):
    cls, data = CONFIGS[case]
    data = _listify(data)
    ours, error = _ours(cls, data)
    theirs, their_error = _pydantic(cls, data)
    assert error is None and their_error is None
    assert ours == theirs and repr(ours) == repr(theirs)  # float fields hold floats, tuples are tuples
    assert ours == parse_dataclass(cls, _listify(data))


# Values that do not fit a field: both refuse them (1e300 and 2.5 fit a float field, and are compared
# there; 10**400, an integer beyond the floats, fits an int field). A bool or a string where a number
# belongs is refused by us always (pydantic reads True as 1 and "8" as 8 in its lax mode); a float with
# no fractional part in an int field is read by both.
WRONG = [None, "x", math.nan, math.inf, -math.inf, 1e300, 2.5, 10**400, [1.0], {"a": 1}]


@pytest.mark.agreement
@pytest.mark.parametrize("case", range(len(CONFIGS)))
def test_the_same_values_are_refused_at_the_same_field(case):
    cls, data = CONFIGS[case]
    data = _listify(data)
    tried = 0
    leaves = list(_leaves(data))
    for path, _value in leaves:
        for wrong in WRONG:
            changed = _set(data, path, wrong)
            theirs, their_error = _pydantic(cls, changed)
            ours, error = _ours(cls, changed)
            if their_error is None:  # allowed by the type (None in an optional field)
                assert ours == theirs, (path, wrong)
                continue
            tried += 1
            assert error == their_error, (path, wrong, error, their_error)
    assert tried >= 4 * len(leaves)  # most wrong values were tried, not waved through


@pytest.mark.agreement
@pytest.mark.parametrize("case", range(len(CONFIGS)))
def test_integers_written_as_floats_are_read_alike(case):
    """Every integer of a config written as a float (``8.0``, as a TOML file may): both read the same
    value, an integer ``Literal`` (the bit depth) included."""
    cls, data = CONFIGS[case]
    data = _listify(data)
    integers = [path for path, value in _leaves(data) if type(value) is int]
    changed = data
    for path in integers:
        changed = _set(changed, path, float(_value_at(data, path)))
    ours, error = _ours(cls, changed)
    theirs, their_error = _pydantic(cls, changed)
    assert error is None and their_error is None, (error, their_error)
    assert repr(ours) == repr(theirs) == repr(parse_dataclass(cls, data))


def _value_at(data, path):
    for key in path:
        data = data[key]
    return data


@pytest.mark.agreement
@pytest.mark.parametrize("case", [0, len(CONFIGS) - 6])
def test_unknown_and_missing_keys_are_named(case):
    cls, data = CONFIGS[case]
    data = _listify(data)
    sections = [key for key, value in data.items() if isinstance(value, dict)] or [None]
    for section in sections:
        changed = copy.deepcopy(data)
        (changed[section] if section else changed)["colour"] = 1
        assert (
            _ours(cls, changed)[1]
            == _pydantic(cls, changed)[1]
            == ".".join(str(p) for p in (section, "colour") if p)
        )


@pytest.mark.exceptions
def test_strict_where_pydantic_is_lax():
    """Bools and strings are not numbers, nor numbers bools (pydantic's lax mode reads them)."""
    data = _listify(jig_to_dict(default_jig()))
    for path, value in _leaves(data):
        if isinstance(value, float):
            for wrong in (True, str(value)):
                with pytest.raises(ConfigError, match=r"must be a number"):
                    parse_dataclass(JigConfig, _set(data, path, wrong))
    with pytest.raises(ConfigError, match=r"^markers\.layout: must be one of 'square', 'hex'"):
        parse_dataclass(JigConfig, _set(data, ("markers", "layout"), "triangle"))
    with pytest.raises(ConfigError, match=r"^part\.n_sides: must be an integer, got 6\.5"):
        parse_dataclass(RegularPolygonPart, {"n_sides": 6.5, "across_flats_mm": 30.0}, "part")
    assert parse_dataclass(RegularPolygonPart, {"n_sides": 6.0, "across_flats_mm": 30}).n_sides == 6
