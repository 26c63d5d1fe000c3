"""A public scene generator for the tests (as kornia's tests build theirs on one).

:func:`render_scene` renders a stereo pair of a jig (the default one unless given) with a part pressed in
at a pose, from one seed, and returns it as a :class:`Scene` with everything a test compares against: the
nominal jig the estimator is given, the as-built jig that was rendered, and the ground truth.
``tests/conftest.py`` renders the default scenes once a session as fixtures (read-only, see
:func:`read_only`); a test that needs another scene calls :func:`render_scene` itself.
"""

from __future__ import annotations

from dataclasses import dataclass, fields, is_dataclass
from pathlib import Path

import numpy as np

from softjig.config import CylinderPart, JigConfig, Part, default_jig
from softjig.sim.asbuilt import AsBuiltJig, draw_as_built, nominal_as_built
from softjig.sim.parts import PartPose
from softjig.sim.render import RenderedPair, render_pair

DEFAULT_PART = CylinderPart(50.0)
DEFAULT_POSE = PartPose(np.radians(10.0), 0.0, 3.0)  # 10 deg towards +x, 3 mm in
DEFAULT_SEED = 0
DEFAULT_AS_BUILT_SEED = 0
UNLOADED_SEED = 99

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = REPO.parent / "shared" / "data"  # CI clones the repository with ../shared beside it


@dataclass(frozen=True)
class Scene:
    """One rendered stereo pair and what it was rendered from.

    Attributes
    ----------
    jig : JigConfig
        The nominal jig: what the estimator is given.
    as_built : AsBuiltJig
        The jig as built (perturbed cameras, markers' real rest positions): what was rendered.
    part : Part or None
        The part pressed in; ``None`` for an unloaded membrane.
    pose : PartPose or None
        Its pose (``None`` without a part).
    seed : int
        The render's seed (ripple, speckle, noise).
    pair : RenderedPair
        The images and their ground truth.
    """

    jig: JigConfig
    as_built: AsBuiltJig
    part: Part | None
    pose: PartPose | None
    seed: int
    pair: RenderedPair

    @property
    def left(self) -> np.ndarray:
        return self.pair.left

    @property
    def right(self) -> np.ndarray:
        return self.pair.right


def render_scene(
    jig: JigConfig | None = None,
    part: Part | None = DEFAULT_PART,
    pose: PartPose | None = DEFAULT_POSE,
    seed: int = DEFAULT_SEED,
    *,
    as_built_seed: int | None = DEFAULT_AS_BUILT_SEED,
) -> Scene:
    """Render one stereo pair of ``jig`` with ``part`` pressed in at ``pose``.

    Parameters
    ----------
    jig : JigConfig or None
        The nominal jig; ``None`` is the default jig.
    part : Part or None
        The part; ``None`` renders the unloaded membrane (and ignores ``pose``).
    pose : PartPose or None
        How the part is pressed in (``None``: centred, upright, 3 mm in).
    seed : int
        Seed of the render's random draws.
    as_built_seed : int or None
        Seed of the as-built draw (:func:`~softjig.sim.asbuilt.draw_as_built`); ``None`` renders the jig
        exactly as designed.
    """
    jig = default_jig() if jig is None else jig
    as_built = nominal_as_built(jig) if as_built_seed is None else draw_as_built(jig, rng=as_built_seed)
    pose = None if part is None else pose
    return Scene(jig, as_built, part, pose, seed, render_pair(as_built, part, pose, rng=seed))


def read_only(value):
    """Make every array in ``value`` (a scene, a pair, a dataclass tree of arrays) read-only, in place."""
    if isinstance(value, np.ndarray):
        value.flags.writeable = False
    elif is_dataclass(value) and not isinstance(value, type):
        for field in fields(value):
            read_only(getattr(value, field.name))
    elif isinstance(value, tuple | list):
        for item in value:
            read_only(item)
    return value
