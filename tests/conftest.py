"""Shared fixtures: the default scenes of :mod:`scenes`, rendered once a session, and a small dataset.

The session fixtures' arrays are read-only, so a test that would write into one fails instead of changing
what every later test sees (copy first: ``scene.left.copy()``); the dataset's files are checked unchanged
when the session ends.

Fixtures
--------
default_jig_config : the default jig (:func:`softjig.config.default_jig`), nominal.
default_scene : the default pair: a 50 mm cylinder tilted 10 deg towards +x, 3 mm in, in the default jig
    as built with seed 0, rendered with seed 0 (the first pair of ``benchmarks/bench_estimate.py``).
unloaded_scene : the same as-built jig with no part (a reference frame), rendered with seed 99.
small_dataset : DESIGN.md's small sweep on disk (a reference frame and 4 frames of a 50 mm part at 10 deg,
    every 90 deg, seed 2); copy it to ``tmp_path`` to change it.

The property tests (Hypothesis) draw the same examples on every run (profile ``repeatable``,
``derandomize``), so a run's verdict depends on the code alone, not on a lucky draw; run them with
``HYPOTHESIS_PROFILE=explore`` to draw new examples (and add an ``@example`` for any failure they find).
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

import pytest
from hypothesis import settings

from scenes import UNLOADED_SEED, Scene, read_only, render_scene
from softjig.config import JigConfig, default_jig

SMALL_DATASET_SEED = 2

settings.register_profile("repeatable", derandomize=True)
settings.register_profile("explore", derandomize=False)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "repeatable"))


def _digest(root: Path) -> dict[str, str]:
    """SHA-256 of every file under ``root``, by relative path."""
    return {
        str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(root.rglob("*"))
        if p.is_file()
    }


@pytest.fixture(scope="session")
def default_jig_config() -> JigConfig:
    return default_jig()


@pytest.fixture(scope="session")
def default_scene(default_jig_config: JigConfig) -> Scene:
    return read_only(render_scene(default_jig_config))


@pytest.fixture(scope="session")
def unloaded_scene(default_jig_config: JigConfig) -> Scene:
    return read_only(render_scene(default_jig_config, None, seed=UNLOADED_SEED))


@pytest.fixture(scope="session")
def small_dataset(tmp_path_factory) -> Path:
    from softjig.io.simulated import simulate_dataset
    from softjig.sim.scenarios import paper_sweep

    out = tmp_path_factory.mktemp("shared") / "sweep"
    specs = list(paper_sweep(diameters_mm=(50,), alphas_deg=(10,), theta_step_deg=90))
    simulate_dataset(out, specs, default_jig(), seed=SMALL_DATASET_SEED, workers=1, progress=False)
    before = _digest(out)
    yield out
    changed = sorted(set(before.items()) ^ set(_digest(out).items()))
    assert not changed, f"a test changed the shared dataset (copy it first): {changed[:5]}"
