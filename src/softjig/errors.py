"""Exception hierarchy shared by all of softjig.

Every exception raised on purpose by softjig derives from :class:`SoftjigError`, and its
message says what went wrong and what the user can do about it. The command-line interface
maps :class:`InputError` to exit code 2 and :class:`EstimationError` to exit code 3.
"""

from __future__ import annotations

__all__ = ["CameraError", "ConfigError", "EstimationError", "InputError", "SoftjigError"]


class SoftjigError(Exception):
    """Base: an error a user can act on; message says what and what to do."""


class InputError(SoftjigError, ValueError):
    """Bad input (image, file, argument). CLI exit code 2."""


class ConfigError(InputError):
    """Invalid or inconsistent configuration; message names the field."""


class EstimationError(SoftjigError):
    """Valid input but no estimate possible (too few markers, no contact). CLI exit code 3."""


class CameraError(InputError):
    """A camera could not be opened or stopped delivering; the message names it and what to check."""
