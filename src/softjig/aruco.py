"""OpenCV's predefined ArUco dictionaries, by name (``DICT_4X4_50`` ...).

Core, below the config: the config validates a fiducial or ChArUco dictionary's name against this list,
and sensing, calibration and the simulator draw or detect markers of the dictionary it names.
"""

from __future__ import annotations

from functools import cache

import cv2

__all__ = ["aruco_dictionary", "aruco_dictionary_names"]


@cache
def aruco_dictionary_names() -> tuple[str, ...]:
    """Names of the predefined ArUco dictionaries OpenCV offers (``DICT_4X4_50`` ...)."""
    return tuple(sorted(n for n in dir(cv2.aruco) if n.startswith("DICT_") and n[5].isdigit()))


def aruco_dictionary(name: str) -> cv2.aruco.Dictionary:
    """OpenCV's predefined dictionary of that name."""
    return cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, name))
