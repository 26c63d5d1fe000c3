"""The Estimator (issue 16): built once per jig, its stages composed per method, no hidden per-jig state."""

from __future__ import annotations

import importlib
import pkgutil
from types import MappingProxyType

import numpy as np
import pytest

import softjig.sensing
from oracles.stages import straightforward_estimator
from softjig.config import CylinderPart, SensingConfig, default_jig
from softjig.errors import ConfigError, EstimationError, InputError
from softjig.geometry import angle_between
from softjig.sensing import stages
from softjig.sensing.estimator import COMPOSITIONS, Estimator
from softjig.sensing.pipeline import Estimate, Markers, SensingResult, estimate_pair
from softjig.sensing.results import Refusal
from softjig.sensing.stages import LogDetector
from softjig.sim.asbuilt import draw_as_built
from softjig.sim.parts import PartPose
from softjig.sim.render import render_pair

JIG = default_jig()


@pytest.fixture(scope="module")
def pairs():
    as_built = draw_as_built(JIG, 3)
    return [
        render_pair(as_built, CylinderPart(d), PartPose(np.radians(a), np.radians(t), 3.0), seed)
        for seed, (d, a, t) in enumerate([(60, 15, 70), (40, 10, 200), (50, 5, 300)])
    ]


# ------------------------------------------------------------------------------------------ smoke


def test_result_types_are_re_exported_by_the_pipeline():
    from softjig.sensing import results

    assert Estimate is results.Estimate and SensingResult is results.SensingResult
    assert Markers is results.Markers


def test_methods_are_compositions_of_stages():
    assert set(COMPOSITIONS) == {"refractive", "paper"}
    refractive, paper = Estimator(JIG), Estimator(JIG, method="paper")
    assert isinstance(refractive.triangulator, stages.RefractedTriangulator)
    assert isinstance(paper.triangulator, stages.PinholeTriangulator)
    assert type(refractive.detector) is type(paper.detector) is LogDetector


def test_refusal_is_falsy_and_says_why():
    refusal = Refusal("too few points")
    assert not refusal and refusal.reason == "too few points"


# ----------------------------------------------------------------------------------- agreement


@pytest.mark.parametrize("method", ["refractive", "paper"])
def test_one_estimator_over_many_frames_equals_a_fresh_one_per_frame(pairs, method):
    """What an estimator keeps between frames (where the fiducials were) changes no number."""
    estimator = Estimator(JIG, method=method)
    for pair in [*pairs, *pairs]:
        kept = estimator.estimate(pair.left, pair.right, part_diameter_mm=50).estimate.to_dict()
        fresh = estimate_pair(pair.left, pair.right, JIG, part_diameter_mm=50, method=method)
        assert kept == fresh.estimate.to_dict()


@pytest.mark.parametrize("method", ["refractive", "paper"])
def test_the_straightforward_stages_find_the_same_markers_and_normal(pairs, method):
    """The standard stages (pyramid candidates, fiducials read near their expected place, the sparse
    matching, the closed-form refracted rays) against straightforward ones composed into the same
    estimator (full-resolution LoG candidates, full ArUco, the dense assignment, rays traced interface by
    interface): the same matched markers in J within 0.05 mm (the candidates start the sub-pixel fit a
    little differently: 0.03 mm at most on this pair), the same normal within 0.05 deg."""
    pair = pairs[0]
    standard = Estimator(JIG, method=method)
    oracle = straightforward_estimator(standard)
    fast = standard.estimate(pair.left, pair.right, part_diameter_mm=60)
    slow = oracle.estimate(pair.left, pair.right, part_diameter_mm=60)
    distance, _ = _nearest(fast.points_J, slow.points_J)
    assert len(fast.points_J) == len(slow.points_J) and np.all(distance < 0.05)
    assert np.degrees(angle_between(np.array(fast.estimate.normal), np.array(slow.estimate.normal))) < 0.05


def _nearest(a, b):
    from scipy.spatial import cKDTree

    return cKDTree(b).query(a)


# ------------------------------------------------------------------------------------ exceptions


def test_an_unknown_detector_is_refused_naming_the_field_and_the_known_ones():
    jig = JIG.replace(sensing=SensingConfig(detector="sift"))
    with pytest.raises(ConfigError, match=r"sensing\.detector = 'sift'.*known: log"):
        Estimator(jig)


def test_a_calibration_of_another_method_is_refused_when_the_estimator_is_built():
    from softjig.calibration.tilt import TiltCalibration

    calibration = TiltCalibration(offset_x_rad=0.0, offset_y_rad=0.0, scale=1.1, method="paper")
    with pytest.raises(InputError, match="paper method"):
        Estimator(JIG, calibration=calibration)


def test_an_empty_frame_is_an_estimation_error_with_the_refusals_reason(pairs):
    """No part on the jig: the contact fitter's refusal ("no contact") is what the caller reads."""
    rest = render_pair(draw_as_built(JIG, 3), None, None, 0)
    with pytest.raises(EstimationError, match="no contact"):
        Estimator(JIG).estimate(rest.left, rest.right)


# --------------------------------------------------------------------------------- new detector


class _ShiftedDetector:
    """A detector written as one class: the LoG's markers, moved right by half a pixel in both images
    (so that the disparities, and hence the estimate, stay nearly what they were)."""

    def __init__(self, inner):
        self.inner = inner

    @classmethod
    def from_model(cls, model):
        return cls(LogDetector.from_model(model))

    def detect(self, gray, exclude=None):
        markers = self.inner.detect(gray, exclude)
        return type(markers)(**{**markers.__dict__, "xy_px": markers.xy_px + np.array([0.5, 0.0])})


def test_a_new_detector_is_one_class_named_in_the_config(pairs, monkeypatch):
    monkeypatch.setattr(
        stages, "DETECTORS", MappingProxyType({**stages.DETECTORS, "shifted": _ShiftedDetector})
    )
    jig = JIG.replace(sensing=SensingConfig(detector="shifted"))
    estimator = Estimator(jig)
    assert isinstance(estimator.detector, _ShiftedDetector)
    pair = pairs[0]
    shifted = estimator.estimate(pair.left, pair.right, part_diameter_mm=60)
    plain = Estimator(JIG).estimate(pair.left, pair.right, part_diameter_mm=60)
    assert np.allclose(shifted.left.xy_px, plain.left.xy_px + np.array([0.5, 0.0]))
    assert np.degrees(angle_between(np.array(shifted.estimate.normal), np.array(plain.estimate.normal))) < 0.5


# ------------------------------------------------------------------------------- hidden state


# Caches keyed on small values that no config is (point counts, a seed, a dictionary's cell layout).
_VALUE_KEYED = {
    "softjig.sensing.robust._seeded_triples",
    "softjig.sensing.robust._student_quantile",
    "softjig.sensing.fiducials.aruco_dictionary_names",
    "softjig.sensing.fiducials._cell_weights",
}


def _sensing_modules():
    for info in pkgutil.iter_modules(softjig.sensing.__path__, "softjig.sensing."):
        yield importlib.import_module(info.name)
    yield importlib.import_module("softjig.rig")
    yield importlib.import_module("softjig.optics")


def test_no_cache_keyed_on_a_config_in_sensing():
    """Every functools cache in sensing/ (and rig, optics) is keyed on small values, none on a config or
    what is derived from it: that is data the Estimator builds once."""
    cached = {
        f"{module.__name__}.{name}"
        for module in _sensing_modules()
        for name, value in vars(module).items()
        if hasattr(value, "cache_info") and getattr(value, "__module__", None) == module.__name__
    }
    assert cached - _VALUE_KEYED == set(), sorted(cached - _VALUE_KEYED)


# Constant lookup tables (never written).
_CONSTANT_TABLES = {"softjig.sensing.detect._FULL_SCALE", "softjig.sensing.subpixel._FULL_SCALE"}


def test_no_module_level_mutable_state_in_sensing():
    """No module dict, list or set (such as the former jigframe._FOUND_BEFORE, keyed by id(jig)) and no
    identity-keyed cache (a plain function wrapping another) in sensing/: what an estimator learns
    between frames, it holds itself."""
    import inspect

    found = {
        f"{module.__name__}.{name}"
        for module in _sensing_modules()
        for name, value in vars(module).items()
        if not name.startswith("__")
        and (
            isinstance(value, dict | list | set)
            or (
                inspect.isfunction(value)
                and hasattr(value, "__wrapped__")
                and value.__module__ == module.__name__
            )
        )
    }
    assert found - _CONSTANT_TABLES == set(), sorted(found - _CONSTANT_TABLES)


def test_two_estimators_of_one_jig_share_nothing_they_derive():
    a, b = Estimator(JIG), Estimator(JIG)
    assert a.model is not b.model
    assert a.model.rest_shape is not b.model.rest_shape
    assert a.model.setup == b.model.setup


def test_the_reference_frame_is_measured_once_when_the_estimator_is_built(pairs):
    """A reference frame's height on the axis and its own scatter are derived when the estimator is
    built (ReferenceModel), not per frame."""
    rest = render_pair(draw_as_built(JIG, 3), None, None, 0)
    reference = Estimator(JIG).reference_from_pair(rest.left, rest.right)
    estimator = Estimator(JIG, reference=reference)
    assert estimator.reference.markers is reference
    assert estimator.reference.scatter_mm is not None and estimator.reference.scatter_mm > 0
    rest_shape = Estimator(JIG).reference
    assert rest_shape.scatter_mm is None
    # the rest membrane's apex is near the dome's height either way (mm)
    assert abs(estimator.reference.height_at_axis_mm - rest_shape.height_at_axis_mm) < 0.5
    result = estimator.estimate(pairs[0].left, pairs[0].right)
    assert result.estimate.indentation_reference == "reference frame"


def test_the_estimate_command_refuses_an_unknown_detector_with_exit_2(pairs, tmp_path):
    import cv2
    from typer.testing import CliRunner

    from softjig.cli import app
    from softjig.config import dumps_jig

    config = tmp_path / "rig.toml"
    config.write_text(dumps_jig(JIG.replace(sensing=SensingConfig(detector="sift"))))
    paths = [tmp_path / "l.png", tmp_path / "r.png"]
    for path, image in zip(paths, (pairs[0].left, pairs[0].right), strict=True):
        cv2.imwrite(str(path), image)
    result = CliRunner().invoke(app, ["estimate", *map(str, paths), "--config", str(config), "--json"])
    assert result.exit_code == 2
    assert "sensing.detector = 'sift'" in result.output and "known: log" in result.output
