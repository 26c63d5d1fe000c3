"""`softjig fiducials check` names an image size that is not the rig's (issue 14: it blamed the fiducials)."""

from __future__ import annotations

import numpy as np
from typer.testing import CliRunner

from softjig.cli import app
from softjig.config import default_jig, save_jig
from softjig.io.dataset import encode_png


def test_an_image_of_another_size_is_named(tmp_path):
    jig = default_jig()
    cam = jig.cameras.left
    small = np.zeros((cam.height_px // 2, cam.width_px // 2), np.uint8)
    (tmp_path / "l.png").write_bytes(encode_png(small))
    (tmp_path / "r.png").write_bytes(encode_png(small))
    save_jig(jig, tmp_path / "rig.toml")
    result = CliRunner().invoke(
        app,
        [
            "fiducials",
            "check",
            str(tmp_path / "l.png"),
            str(tmp_path / "r.png"),
            "--config",
            str(tmp_path / "rig.toml"),
        ],
    )
    assert result.exit_code == 2, result.output
    assert f"is {cam.width_px // 2} x {cam.height_px // 2} px" in result.output
    assert f"{cam.width_px} x {cam.height_px}" in result.output
