"""The identity-keyed cache of per-config constants."""

from softjig.caching import cached_by_identity
from softjig.config import default_jig


def test_builds_once_per_object_and_never_confuses_two_objects():
    calls = []

    @cached_by_identity(maxsize=2)
    def build(jig):
        calls.append(jig)
        return len(calls)

    a, b = default_jig(), default_jig()  # equal, but distinct objects
    assert build(a) == 1 and build(a) == 1
    assert build(b) == 2 and build(a) == 1
    c = default_jig()
    assert build(c) == 3  # full: emptied, then c stored
    assert build(a) == 4 and len(calls) == 4
