"""A plain dict (TOML, JSON) to a frozen dataclass of typed fields, checked field by field.

:func:`parse_dataclass` is what :mod:`softjig.config` reads a jig, a part and a pose with. Written here
rather than through pydantic: importing pydantic and building a ``TypeAdapter`` of the jig's tree of
dataclasses costs about 80 ms at every start of the command line, a tenth of a single-pair estimate
(``benchmarks/bench_startup.py``), for a handful of types that a short function converts alike
(``tests/test_dataclass_parse.py`` checks that both read the same configs to the same values and refuse
the same ones, naming the same field).

The field types understood are the ones the configs use: ``float``, ``int``, ``str``, ``bool``,
``Literal[...]``, ``X | None``, ``tuple[X, ...]``, fixed-length ``tuple[X, Y, ...]`` and nested dataclasses.
Numbers are finite; ``bool`` is not a number; an ``int`` field (and an integer ``Literal``) takes a float
with no fractional part within the 64-bit integers; a tuple is given as a list or a tuple; a dataclass as
a dict whose unknown keys are refused and whose missing keys take the field's default.
"""

from __future__ import annotations

import dataclasses
import math
import types
import typing
from typing import Any, Literal

from softjig.errors import ConfigError

__all__ = ["parse_dataclass"]


class _FieldError(Exception):
    """A value that does not fit its field: the path below the field (keys, indices) and the message."""

    def __init__(self, path: tuple[str | int, ...], message: str) -> None:
        super().__init__(message)
        self.path = path
        self.message = message


def parse_dataclass(cls: type, data: Any, where: str = "") -> Any:
    """An instance of the dataclass ``cls`` from ``data``, a dict of its fields' plain values.

    Parameters
    ----------
    cls : type
        A dataclass whose fields are annotated with the types listed in the module's docstring.
    data : Any
        Its fields by name (nested dataclasses as dicts, tuples as lists).
    where : str
        The dotted name of ``data`` in the file it came from (``"part"``), the prefix of every error's
        field name; ``""`` at the top level.

    Returns
    -------
    Any
        ``cls(**fields)``, each field converted to its annotated type (``int`` to ``float``, lists to
        tuples, dicts to dataclasses).

    Raises
    ------
    ConfigError
        ``"<dotted.field>: <problem>"`` for the first value that does not fit (in the fields' order), a
        required field left out or an unknown key.
    """
    try:
        return _convert(cls, data)
    except _FieldError as exc:
        location = ".".join(str(part) for part in (where, *exc.path) if part != "")
        raise ConfigError(f"{location}: {exc.message}" if location else exc.message) from None


def _convert(annotation: Any, value: Any) -> Any:
    """``value`` as the type ``annotation``, or :class:`_FieldError` (path relative to ``value``)."""
    if dataclasses.is_dataclass(annotation):
        return _convert_dataclass(annotation, value)
    origin = typing.get_origin(annotation)
    if origin is Literal:
        options = typing.get_args(annotation)
        if _integral_float(value) and any(type(option) is int for option in options):
            value = int(value)  # as an int field reads it
        if not any(value == option and type(value) is type(option) for option in options):
            raise _FieldError((), f"must be one of {', '.join(repr(o) for o in options)}, got {value!r}")
        return value
    if origin is types.UnionType or origin is typing.Union:
        members = typing.get_args(annotation)
        if value is None and type(None) in members:
            return None
        (member,) = (m for m in members if m is not type(None))  # only `X | None` is used
        return _convert(member, value)
    if origin is tuple:
        return _convert_tuple(typing.get_args(annotation), value)
    if annotation is float:
        return _convert_float(value)
    if annotation is int:
        return _convert_int(value)
    if annotation is str or annotation is bool:
        if type(value) is not annotation:
            raise _FieldError((), f"must be a {annotation.__name__}, got {value!r}")
        return value
    raise TypeError(f"parse_dataclass does not know the field type {annotation!r}")  # a bug of ours


def _convert_float(value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise _FieldError((), f"must be a number, got {value!r}")
    try:
        number = float(value)
    except OverflowError:  # an int beyond the floats (TOML integers have any number of digits here)
        raise _FieldError(
            (), f"must be a finite number, got an integer of {len(str(value))} digits"
        ) from None
    if not math.isfinite(number):
        raise _FieldError((), f"must be a finite number, got {value!r}")
    return number


def _integral_float(value: Any) -> bool:
    """A float with no fractional part within the 64-bit integers (a larger one is refused, as pydantic
    refuses it, rather than read as an integer of hundreds of digits)."""
    return isinstance(value, float) and value.is_integer() and abs(value) < 2.0**63


def _convert_int(value: Any) -> int:
    if _integral_float(value):
        return int(value)
    if isinstance(value, bool) or not isinstance(value, int):
        raise _FieldError((), f"must be an integer, got {value!r}")
    return value


def _convert_tuple(items: tuple[Any, ...], value: Any) -> tuple[Any, ...]:
    if not isinstance(value, list | tuple):
        raise _FieldError((), f"must be a list, got {value!r}")
    if len(items) == 2 and items[1] is Ellipsis:
        item_types = (items[0],) * len(value)
    elif len(value) != len(items):
        raise _FieldError((), f"must have {len(items)} items, got {len(value)}")
    else:
        item_types = items
    converted = []
    for index, (item_type, item) in enumerate(zip(item_types, value, strict=True)):
        try:
            converted.append(_convert(item_type, item))
        except _FieldError as exc:
            raise _FieldError((index, *exc.path), exc.message) from None
    return tuple(converted)


def _convert_dataclass(cls: type, value: Any) -> Any:
    if isinstance(value, cls):
        return value
    if not isinstance(value, dict):
        raise _FieldError((), f"must be a table of {cls.__name__}'s fields, got {value!r}")
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}
    hints = typing.get_type_hints(cls)
    converted = {}
    for name, spec in fields.items():  # the fields first, in their order, then any unknown key
        if name not in value:
            if spec.default is dataclasses.MISSING and spec.default_factory is dataclasses.MISSING:
                raise _FieldError((name,), "required, missing")
            continue
        try:
            converted[name] = _convert(hints[name], value[name])
        except _FieldError as exc:
            raise _FieldError((name, *exc.path), exc.message) from None
    unknown = [key for key in value if key not in fields]
    if unknown:
        raise _FieldError((str(unknown[0]),), f"unknown key (the known ones: {', '.join(fields)})")
    return cls(**converted)
