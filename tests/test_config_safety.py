"""Config safety (issue 14): no silent default jig, no NaN or infinity, no resolution beyond memory."""

import math
import re
from dataclasses import fields, is_dataclass, replace

import pytest
from typer.testing import CliRunner

from softjig.cli import app
from softjig.config import (
    MAX_IMAGE_PIXELS,
    REQUIRED_KEYS,
    default_jig,
    dumps_jig,
    jig_from_dict,
    jig_to_dict,
    load_jig,
    load_marker_csv,
    loads_jig,
    marker_csv_text,
    save_jig,
    validate_jig,
)
from softjig.errors import ConfigError, InputError
from softjig.jig_shape import marker_layout_xy

runner = CliRunner()


def _float_fields(obj, path=""):
    """Every float-valued field of a config (dotted path, and the index inside a tuple of floats)."""
    for f in fields(obj):
        value = getattr(obj, f.name)
        where = f"{path}.{f.name}" if path else f.name
        if is_dataclass(value):
            yield from _float_fields(value, where)
        elif isinstance(value, float):
            yield where, None
        elif isinstance(value, tuple) and value:
            first = value[0]
            if isinstance(first, float):
                yield where, (0,)
            elif isinstance(first, tuple) and isinstance(first[0], float):
                yield where, (0, 0)


FLOAT_FIELDS = [
    *_float_fields(default_jig()),
    ("sensing.log_sigma_px", None),
    ("sensing.detection_threshold", None),
]


def _set(data, dotted, index, value):
    *path, last = dotted.split(".")
    node = data
    for key in path:
        node = node[key]
    if index is None:
        node[last] = value
    elif len(index) == 1:
        node[last][0] = value
    else:
        node[last][0][0] = value


@pytest.mark.parametrize(("field", "index"), FLOAT_FIELDS, ids=[f for f, _ in FLOAT_FIELDS])
@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf], ids=["nan", "inf", "-inf"])
def test_nan_and_inf_refused_in_every_float_field_loaded(field, index, bad):
    data = jig_to_dict(default_jig())
    _set(data, field, index, bad)
    with pytest.raises(ConfigError, match=field.replace(".", r"\.")):
        jig_from_dict(data)


@pytest.mark.parametrize(("field", "index"), FLOAT_FIELDS, ids=[f for f, _ in FLOAT_FIELDS])
def test_nan_refused_in_every_float_field_built_in_python(field, index):
    """A jig built in Python (no pydantic) is checked by validate_jig too."""
    jig = default_jig()
    *path, last = field.split(".")
    sections = [jig]
    for key in path:
        sections.append(getattr(sections[-1], key))
    value = getattr(sections[-1], last)
    if index is None:
        new = math.nan
    elif len(index) == 1:
        new = (math.nan, *value[1:])
    else:
        new = ((math.nan, *value[0][1:]), *value[1:])
    node = replace(sections[-1], **{last: new})
    for parent, key in zip(reversed(sections[:-1]), reversed(path), strict=True):
        node = replace(parent, **{key: node})
    with pytest.raises(ConfigError, match=field.replace(".", r"\.")):
        validate_jig(node)


def test_toml_nan_literal_is_named(tmp_path):
    text = dumps_jig(default_jig()).replace("thickness_mm = 0.7", "thickness_mm = nan")
    with pytest.raises(ConfigError, match=r"membrane\.thickness_mm.*finite"):
        loads_jig(text)


def test_empty_config_is_an_error(tmp_path):
    empty = tmp_path / "rig.toml"
    empty.write_text("")
    with pytest.raises(ConfigError, match=r"empty.*softjig config --out rig\.toml"):
        load_jig(empty)
    result = runner.invoke(app, ["config", "--config", str(empty), "--out", str(tmp_path / "x.toml")])
    assert result.exit_code == 2 and "empty" in result.output
    assert not (tmp_path / "x.toml").exists()


@pytest.mark.parametrize("key", REQUIRED_KEYS)
def test_every_section_is_required(key):
    data = jig_to_dict(default_jig())
    *path, last = key.split(".")
    node = data
    for k in path:
        node = node[k]
    del node[last]
    pattern = "^" + re.escape(key) + ": missing from the config.*softjig config"
    with pytest.raises(ConfigError, match=pattern):
        jig_from_dict(data)


def test_config_without_cameras_exits_2(tmp_path):
    rig = tmp_path / "rig.toml"
    text = dumps_jig(default_jig())
    rig.write_text(text[: text.index("[cameras")] + text[text.index("[tolerances]") :])
    result = runner.invoke(app, ["simulate", "--config", str(rig), "--out", str(tmp_path / "ds")])
    assert result.exit_code == 2, result.output
    assert "cameras" in result.output and "missing" in result.output
    assert not (tmp_path / "ds").exists()


def test_fields_missing_inside_a_section_take_defaults():
    """Files written before a field existed keep loading: only sections are required."""
    data = jig_to_dict(default_jig())
    for key in ("dome_profile", "profile_r_mm", "profile_h_mm"):
        del data["membrane"][key]
    for key in ("rotation_deg", "offset_mm", "centers_mm", "centers_z_mm"):
        del data["markers"][key]
    assert jig_from_dict(data) == default_jig()


def test_files_written_by_save_jig_load(tmp_path):
    save_jig(default_jig(), tmp_path / "rig.toml")
    assert load_jig(tmp_path / "rig.toml") == default_jig()


def _camera_size(width, height):
    data = jig_to_dict(default_jig())
    for side in ("left", "right"):
        data["cameras"][side].update(
            width_px=width, height_px=height, cx_px=(width - 1) / 2, cy_px=(height - 1) / 2
        )
    return data


@pytest.mark.parametrize(
    ("width", "height", "field"),
    [
        (200000, 200000, "cameras.left.width_px"),
        (12800, 7200, "cameras.left.width_px"),
        (640, 9000, "height_px"),
    ],
)
def test_huge_resolution_is_refused(width, height, field):
    with pytest.raises(ConfigError, match=field.replace(".", r"\.")):
        jig_from_dict(_camera_size(width, height))


def test_large_real_sensors_are_accepted():
    for width, height in ((4096, 3000), (4096, 4096), (1920, 1200)):
        assert width * height <= MAX_IMAGE_PIXELS
        jig = jig_from_dict(_camera_size(width, height))
        assert jig.cameras.left.width_px == width


def test_huge_resolution_exits_2_from_the_cli(tmp_path):
    rig = tmp_path / "rig.toml"
    rig.write_text(dumps_jig(default_jig()).replace("width_px = 1280", "width_px = 200000"))
    result = runner.invoke(app, ["simulate", "--config", str(rig), "--out", str(tmp_path / "ds")])
    assert result.exit_code == 2 and "width_px" in result.output


# ------------------------------------------------------------------------------ config --markers-csv


def test_config_from_markers_csv(tmp_path):
    xy = marker_layout_xy(default_jig())[::3] + 0.25
    csv = tmp_path / "markers.csv"
    csv.write_text(marker_csv_text(xy))
    out = tmp_path / "rig.toml"
    result = runner.invoke(app, ["config", "--markers-csv", str(csv), "--out", str(out)])
    assert result.exit_code == 0, result.output
    jig = load_jig(out)
    assert jig.markers.layout == "explicit" and jig.markers.centers_z_mm == ()
    assert [list(c) for c in jig.markers.centers_mm] == xy.tolist()
    assert "[markers]" in out.read_text() and "centers_mm" in out.read_text()  # inline: self-contained
    # not over an existing file without --overwrite
    result = runner.invoke(app, ["config", "--markers-csv", str(csv), "--out", str(out)])
    assert result.exit_code == 2


def test_markers_csv_that_overlap_exit_2(tmp_path):
    csv = tmp_path / "markers.csv"
    csv.write_text("x_mm,y_mm\n0,0\n8,0\n0,8\n1,1\n8,8\n")
    result = runner.invoke(app, ["config", "--markers-csv", str(csv), "--out", str(tmp_path / "rig.toml")])
    assert result.exit_code == 2 and "overlaps" in result.output
    assert not (tmp_path / "rig.toml").exists()


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("", "empty"),
        ("x,y\n1,2\n", "header"),
        ("x_mm,y_mm\n1,2\n3\n", "line 3"),
        ("x_mm,y_mm\n1,nan\n", "finite"),
        ("x_mm,y_mm,z_mm\n1,2,abc\n", "not numbers"),
        ("x_mm,y_mm\n", "no markers"),
    ],
)
def test_bad_markers_csv(tmp_path, text, message):
    csv = tmp_path / "m.csv"
    csv.write_text(text)
    with pytest.raises(InputError, match=message):
        load_marker_csv(csv)


def test_markers_csv_round_trip_with_z(tmp_path):
    xy = marker_layout_xy(default_jig())[:20] + 1 / 3
    z = 20 + xy[:, 0] / 7
    csv = tmp_path / "m.csv"
    csv.write_text(marker_csv_text(xy, z))
    centers, heights = load_marker_csv(csv)
    assert [list(c) for c in centers] == xy.tolist() and list(heights) == z.tolist()
