"""Typer's coercion of an option's value, without pydantic for the plain cases (start-up, issue 14).

Typer (0.2x) turns every parameter's value into its annotated type through a pydantic ``TypeAdapter``,
built for every parameter of the command that runs, whether it was given or not: a single-pair
``softjig estimate`` built 16 of them, 30-60 ms of its start-up. :func:`install` gives each parameter of
a command a :class:`LightCoercion` instead, which converts the plain values itself, the way Typer's
adapters do:

- ``None`` (an option not given): ``None``, or ``()`` for a multi-value parameter, as Typer's own;
- a ``str`` for ``str``; a ``bool`` for ``bool`` (Typer does not coerce those either);
- a decimal literal (``12``, ``-0.5``, ``1e-3``) or a value of the exact type for ``int`` and ``float``,
  inside the option's ``min``/``max``;
- any text for a ``Path`` (``Path(text)``), then Typer's own checks of the path
  (``exists``, ``dir_okay``, ``readable``, ...: ``typer._param_types.coerce_cli_path``);
- an enum's member, or its exact value for a case-sensitive choice;
- a list or tuple of those for a ``list[...]``.

Anything else (a value out of range, ``nan``, ``1_000``, a case-insensitive choice, a parser or file
option, a type not listed) goes to Typer's own coercion, built then: its conversions and its error
messages are Typer's. ``tests/test_cli_coercion.py`` checks that both give the same value for every
option of every command. With a Typer whose parameters have no ``_runtime_param`` (before 0.2x)
:func:`install` does nothing.
"""

from __future__ import annotations

import re
from enum import Enum
from pathlib import Path
from typing import Any, get_args, get_origin

__all__ = ["LightCoercion", "install"]

#: A decimal number as Python's ``float`` and pydantic read it alike (ASCII digits: no ``_``, spaces, ``inf``,
#: ``nan``, nor the other scripts' digits that Python reads and pydantic refuses).
_FLOAT_TEXT = re.compile(r"[+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?")
#: A decimal integer as Python's ``int`` and pydantic read it alike.
_INT_TEXT = re.compile(r"[+-]?[0-9]+")
#: What :func:`_plain` returns for a value it leaves to Typer.
_TYPER = object()


def install(params: Any) -> None:
    """Give every parameter of ``params`` (a click command's, built by Typer) a :class:`LightCoercion`,
    unless it already has its runtime coercion; nothing with a Typer that has no such thing."""
    for param in params:
        descriptor = getattr(param, "type_descriptor", None)
        if descriptor is None or getattr(param, "_runtime_param", _TYPER) is not None:
            continue
        param._runtime_param = LightCoercion(descriptor)


class LightCoercion:
    """A parameter's coercion (Typer's ``RuntimeParam.coerce``): plain values here, the rest by Typer's
    own, built on first need and kept on the parameter in its place."""

    __slots__ = ("descriptor",)

    def __init__(self, descriptor: Any) -> None:
        self.descriptor = descriptor

    def coerce(self, value: Any, param: Any, ctx: Any) -> Any:
        """``value`` in the parameter's type, or the error Typer gives for it."""
        if value is None:
            return () if param.multiple or param.nargs == -1 else None
        converted = _plain(value, self.descriptor, param, ctx)
        if converted is not _TYPER:
            return converted
        from typer._coercion import build_runtime_param

        runtime = build_runtime_param(self.descriptor)
        param._runtime_param = runtime
        return runtime.coerce(value, param=param, ctx=ctx)


def _plain(value: Any, descriptor: Any, param: Any, ctx: Any) -> Any:
    """``value`` converted as Typer's adapter would, or :data:`_TYPER` to leave it to Typer."""
    info = descriptor.parameter_info
    if info.parser is not None or descriptor.file_annotation is not None:
        return _TYPER
    annotation = descriptor.annotation
    if get_origin(annotation) is list:
        (item_type,) = get_args(annotation) or (Any,)
        if not isinstance(value, list | tuple):
            return _TYPER
        items = [_leaf(item, item_type, info, param, ctx) for item in value]
        return _TYPER if any(item is _TYPER for item in items) else items
    return _leaf(value, annotation, info, param, ctx)


def _leaf(value: Any, annotation: Any, info: Any, param: Any, ctx: Any) -> Any:
    """One value of a plain type (see the module docstring), or :data:`_TYPER`."""
    if annotation is str or annotation is bool:
        return value if type(value) is annotation else _TYPER
    if annotation is float or annotation is int:
        return _number(value, annotation, info)
    if isinstance(annotation, type) and issubclass(annotation, Enum):
        return _choice(value, annotation, info, ctx)
    if annotation is Path and info.path_type in (None, Path):
        return _path(value, info, param, ctx)
    return _TYPER


def _number(value: Any, kind: type, info: Any) -> Any:
    if type(value) is kind:
        number = value
    elif type(value) is str and (_FLOAT_TEXT if kind is float else _INT_TEXT).fullmatch(value):
        try:
            number = kind(value)
        except ValueError:  # an integer of more digits than Python converts
            return _TYPER
    else:
        return _TYPER
    if number != number:  # NaN: Typer's adapter decides (a range lets it through)
        return _TYPER
    if (info.min is not None and number < info.min) or (info.max is not None and number > info.max):
        return _TYPER  # Typer's message (or its clamp)
    return number


def _choice(value: Any, enum: type[Enum], info: Any, ctx: Any) -> Any:
    if isinstance(value, enum):
        return value
    if type(value) is not str or not info.case_sensitive or getattr(ctx, "token_normalize_func", None):
        return _TYPER
    for member in enum:
        if str(member.value) == value:
            return member
    return _TYPER  # not a choice: Typer's message lists them


def _path(value: Any, info: Any, param: Any, ctx: Any) -> Any:
    if isinstance(value, str):
        value = Path(value)
    if not isinstance(value, Path):
        return _TYPER
    try:
        from typer._param_types import coerce_cli_path
    except ImportError:  # another Typer: its own coercion
        return _TYPER
    return coerce_cli_path(value, info, path_type=Path, param=param, ctx=ctx)
