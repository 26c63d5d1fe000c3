"""The options several commands share, written once: the same name, type, default and help everywhere.

Each is an ``Annotated`` type to give a parameter (Typer reads the option from it)::

    config: ConfigOption = None,
    method: MethodOption = DEFAULT_METHOD,

``estimate``, ``live``, ``serve``, ``convert`` and ``survey`` take the jig's config; the estimating ones
also the part's diameter, a tilt calibration and the method; ``live`` and ``serve`` the camera source or a
replay. Like :mod:`softjig.cli.choices`, this module is light (no NumPy, no softjig internals).
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from softjig.cli.choices import Method, ReplayRate

__all__ = [
    "CalibrationOption",
    "ConfigOption",
    "FpsOption",
    "LeftTopicOption",
    "MethodOption",
    "PartDiameterOption",
    "ReplayOption",
    "ReplayRateOption",
    "RightTopicOption",
    "SourceOption",
    "StampToleranceOption",
]

#: Frames per second of cameras, and of a replay's frames that were recorded without a time.
DEFAULT_FPS = 30.0

ConfigOption = Annotated[
    Path | None,
    typer.Option(
        help="The nominal jig (rig.toml). A stereo pair needs one; a dataset, a bag or a replay has its "
        "own rig.toml, used by default; cameras get the paper's default jig (with a warning).",
        show_default=False,
    ),
]

PartDiameterOption = Annotated[
    float | None,
    typer.Option(
        help="Diameter of the part's base in mm: the paper's crop (--method paper needs it); the "
        "refractive method finds the contact itself and uses it only to judge partial contact.",
        show_default="each frame's part, as its dataset names it",
    ),
]

CalibrationOption = Annotated[
    Path | None,
    typer.Option(
        help="Tilt calibration JSON (offset_x_deg, offset_y_deg, scale; softjig calibrate) to apply.",
        show_default=False,
    ),
]

MethodOption = Annotated[
    Method,
    typer.Option(
        help="refractive: ours (refraction-aware, contact found from the indentation, robust plane, "
        "uncertainty, position; needs no tilt calibration); paper: the paper's method exactly as "
        "published."
    ),
]

ReplayOption = Annotated[
    Path | None,
    typer.Option(help="Replay this dataset as if it were the cameras.", show_default=False),
]

SourceOption = Annotated[
    str | None,
    typer.Option(
        help="Cameras: realsense-ir[:SERIAL] (one D4xx's infrared pair), realsense, "
        "realsense:LEFT_SERIAL,RIGHT_SERIAL, or opencv:LEFT,RIGHT (device numbers, /dev paths or "
        "video files).",
        show_default=False,
    ),
]

ReplayRateOption = Annotated[
    ReplayRate,
    typer.Option(
        help="Replay: 'recorded' (its own rate; busy frames are dropped, as with cameras) or "
        "'fast' (every frame, as fast as possible)."
    ),
]

FpsOption = Annotated[
    float,
    typer.Option(min=0.1, help="Camera frame rate; a replay's rate for frames without time_s (Hz)."),
]

#: A bag's stereo pairs: the largest header-stamp difference of a pair (s); the same as
#: :data:`softjig.io.rosbag.DEFAULT_STAMP_TOLERANCE_S` (this module does not import the bag reader).
DEFAULT_STAMP_TOLERANCE_S = 0.015

LeftTopicOption = Annotated[
    str | None, typer.Option(help="BAG: topic of the left images.", show_default="picked by name")
]
RightTopicOption = Annotated[
    str | None, typer.Option(help="BAG: topic of the right images.", show_default="picked by name")
]
StampToleranceOption = Annotated[
    float, typer.Option(min=0.0, help="BAG: largest header stamp difference of a stereo pair (s).")
]
