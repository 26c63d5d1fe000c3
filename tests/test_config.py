"""Config: defaults, exact TOML round trip, and every validation error naming its field."""

from dataclasses import replace

import numpy as np
import pytest

from softjig.config import (
    BoxPart,
    CameraConfig,
    CylinderPart,
    default_jig,
    dumps_jig,
    exact_jig,
    jig_from_dict,
    jig_to_dict,
    load_jig,
    loads_jig,
    part_from_dict,
    part_to_dict,
    save_jig,
    validate_jig,
    validate_part,
)
from softjig.errors import ConfigError, InputError


def test_default_is_the_papers_jig():
    jig = default_jig()
    assert jig.plate.size_x_mm == 220 and jig.plate.thickness_mm == 5
    assert jig.membrane.dome_height_mm == 30 and jig.membrane.thickness_mm == pytest.approx(0.7)
    assert jig.cameras.baseline_mm == pytest.approx(30.0)
    assert jig.cameras.left.width_px == 1280 and jig.cameras.left.height_px == 720
    assert jig.cameras.left.position_mm[2] == -155.0  # 150 mm below the plate's bottom face


def test_toml_round_trip_is_exact(tmp_path):
    jig = default_jig().replace(
        cameras=replace(
            default_jig().cameras,
            left=replace(default_jig().cameras.left, fx_px=925.123456789012, rotation_deg=(0.1, -0.2, 0.3)),
            right=replace(default_jig().cameras.right, fx_px=925.123456789012, rotation_deg=(0.1, -0.2, 0.3)),
            rectified=False,
        )
    )
    path = tmp_path / "rig.toml"
    save_jig(jig, path)
    assert load_jig(path) == jig
    assert loads_jig(dumps_jig(jig)) == jig
    assert dumps_jig(load_jig(path)) == path.read_text()


def test_exact_jig_has_no_tolerances():
    assert exact_jig().tolerances.is_zero()
    assert not default_jig().tolerances.is_zero()


def _with(section: str, **changes):
    data = jig_to_dict(default_jig())
    node = data
    *path, last = section.split(".")
    for key in path:
        node = node[key]
    node[last].update(changes)
    return data


@pytest.mark.parametrize(
    ("section", "changes", "field"),
    [
        ("plate", {"thickness_mm": -1.0}, "plate.thickness_mm"),
        ("membrane", {"thickness_mm": -0.7}, "membrane.thickness_mm"),
        ("membrane", {"footprint_radius_mm": 150.0}, "membrane.footprint_radius_mm"),
        ("membrane", {"dome_exponent": 0.5}, "membrane.dome_exponent"),
        ("markers", {"diameter_mm": 9.0}, "markers.diameter_mm"),
        ("markers", {"layout": "spiral"}, "markers.layout"),
        ("fiducials", {"ids": [0, 1]}, "fiducials.ids"),
        ("fiducials", {"ids": [0, 0, 1, 2]}, "fiducials.ids"),
        ("fiducials", {"dictionary": "DICT_NOPE"}, "fiducials.dictionary"),
        ("fiducials", {"z_mm": 3.0}, "fiducials.z_mm"),
        ("medium", {"oil_refractive_index": 0.9}, "medium.oil_refractive_index"),
        ("imaging", {"marker_level": 0.01}, "imaging.marker_level"),
        ("imaging", {"bit_depth": 12}, "imaging.bit_depth"),
        ("cameras.left", {"position_mm": [300.0, 0.0, -155.0]}, "cameras.left"),
        ("cameras.left", {"position_mm": [-15.0, 0.0, 10.0]}, "cameras.left.position_mm"),
        ("cameras.left", {"rotation_deg": [180.0, 0.0, 0.0]}, "cameras.left.rotation_deg"),
        ("cameras.right", {"fx_px": 900.0}, "cameras.right.fx_px"),
        ("cameras.right", {"position_mm": [15.0, 3.0, -155.0]}, "cameras.right.position_mm"),
        ("cameras.left", {"fx_px": "wide"}, "cameras.left.fx_px"),
        ("tolerances", {"camera_position_mm": -1.0}, "tolerances.camera_position_mm"),
        # every depth off by over 100 %: the sigma's depth scale error would flip the normal
        ("tolerances", {"focal_fraction": 1.2}, "tolerances"),
        ("tolerances", {"refractive_index": 2.0}, "tolerances"),
        ("sensing", {"min_points": 2}, "sensing.min_points"),
        ("sensing", {"min_points": 10**40}, "sensing.min_points"),  # no frame could have so many markers
        ("markers", {"pitch_mm": 10**400}, "markers.pitch_mm"),  # an int beyond the floats: no OverflowError
        ("sensing", {"extrinsics": "guess"}, "sensing.extrinsics"),
    ],
)
def test_validation_names_the_field(section, changes, field):
    with pytest.raises(ConfigError, match=field.replace(".", r"\.")):
        jig_from_dict(_with(section, **changes))


def test_unknown_key_is_named():
    data = jig_to_dict(default_jig())
    data["membrane"]["thicknes_mm"] = 1.0
    with pytest.raises(ConfigError, match=r"membrane\.thicknes_mm"):
        jig_from_dict(data)


def test_camera_that_does_not_see_the_axis():
    jig = default_jig()
    bad = replace(jig.cameras, left=replace(jig.cameras.left, cx_px=-800.0), rectified=False)
    with pytest.raises(ConfigError, match="does not see the jig axis"):
        validate_jig(replace(jig, cameras=bad))


def test_file_errors(tmp_path):
    with pytest.raises(InputError, match="does not exist"):
        load_jig(tmp_path / "nope.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text("[plate\nx=1")
    with pytest.raises(ConfigError, match="not valid TOML"):
        load_jig(bad)


def test_parts():
    jig = default_jig()
    for part in (CylinderPart(50.0), BoxPart(50.0, 50.0, 50.0)):
        assert part_from_dict(part_to_dict(part)) == part
        validate_part(part, jig)
    with pytest.raises(ConfigError, match="wider than the membrane"):
        validate_part(CylinderPart(200.0), jig)
    with pytest.raises(ConfigError, match=r"part\.diameter_mm"):
        validate_part(CylinderPart(-5.0))
    with pytest.raises(ConfigError, match=r"part\.kind"):
        part_from_dict({"kind": "sphere"})
    cam = CameraConfig(position_mm=(1.0, 2.0, -150.0), rotation_deg=(0.0, 0.0, 90.0))
    assert np.allclose(cam.K, [[925.0, 0.0, 639.5], [0.0, 925.0, 359.5], [0.0, 0.0, 1.0]])
    assert np.allclose(cam.T_J_cam[:3, 3], [1.0, 2.0, -150.0])
    assert np.allclose(cam.T_J_cam[:3, :3] @ [1.0, 0.0, 0.0], [0.0, 1.0, 0.0])  # 90 deg about z
