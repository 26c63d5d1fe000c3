"""Argument checks shared by the public functions: they convert, validate and return, or raise
:class:`~softjig.errors.InputError` naming the parameter."""

from __future__ import annotations

import math

from softjig.errors import InputError


def finite_float(value: object, name: str) -> float:
    """``float(value)``, or an InputError naming the parameter if it is not a finite number."""
    try:
        out = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise InputError(f"{name} must be a number, got {value!r}.") from None
    if not math.isfinite(out):
        raise InputError(f"{name} must be finite, got {out}.")
    return out


def positive_float(value: object, name: str) -> float:
    """A finite number > 0, or an InputError naming the parameter."""
    out = finite_float(value, name)
    if out <= 0.0:
        raise InputError(f"{name} must be > 0, got {out}.")
    return out
