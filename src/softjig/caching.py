"""A cache keyed by an object's identity, for constants derived from a config on the hot path.

``functools.lru_cache`` hashes its argument: for a :class:`~softjig.config.JigConfig` that walks the whole
frozen config, 10-70 us per call (measured, cold caches), too much at camera rate. The config is immutable
and the same object is passed for every frame, so its identity is a sound key; the object itself is kept
with the entry, so an identity reused after garbage collection is never mistaken for it.
"""

from __future__ import annotations

from collections.abc import Callable
from functools import wraps
from typing import TypeVar

K = TypeVar("K")
V = TypeVar("V")


def cached_by_identity(maxsize: int = 16) -> Callable[[Callable[[K], V]], Callable[[K], V]]:
    """Decorate ``build(obj) -> value`` to build once per object (by identity); the cache is emptied when
    it holds ``maxsize`` objects."""

    def decorate(build: Callable[[K], V]) -> Callable[[K], V]:
        entries: dict[int, tuple[K, V]] = {}

        @wraps(build)
        def cached(obj: K) -> V:
            hit = entries.get(id(obj))
            if hit is not None and hit[0] is obj:
                return hit[1]
            value = build(obj)
            if len(entries) >= maxsize:
                entries.clear()
            entries[id(obj)] = (obj, value)
            return value

        return cached

    return decorate
