"""The 3-D side's house rules (issue 16): one production path per stage, Numba only in the private
``_kernels`` modules next to their users, plane least squares written once."""

from __future__ import annotations

import ast
import inspect
from pathlib import Path

import pytest

import softjig

SRC = Path(softjig.__file__).parent
THREE_D = [
    "sensing/stereo.py",
    "sensing/refractive.py",
    "sensing/identities.py",
    "sensing/robust.py",
    "geometry.py",
    "optics.py",
]
#: The estimator's contact, self-check and uncertainty stages: Numba only in their kernel modules too.
ESTIMATOR = ["sensing/contact.py", "sensing/selfcheck.py", "sensing/uncertainty.py"]
KERNELS = [
    "sensing/_stereo_kernels.py",
    "sensing/_refractive_kernels.py",
    "sensing/_identities_kernels.py",
    "sensing/_robust_kernels.py",
    "_geometry_kernels.py",
    "sensing/_contact_kernels.py",
    "sensing/_selfcheck_kernels.py",
]


def _tree(relative: str) -> ast.Module:
    return ast.parse((SRC / relative).read_text(encoding="utf-8"))


def _imports(tree: ast.Module) -> set[str]:
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update(alias.name.split(".")[0] for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module:
            names.add(node.module.split(".")[0])
    return names


@pytest.mark.parametrize("module", THREE_D + ESTIMATOR)
def test_numba_only_in_the_kernel_modules(module):
    assert "numba" not in _imports(_tree(module))


@pytest.mark.parametrize("module", KERNELS)
def test_kernel_modules_hold_only_compiled_functions(module):
    functions = [node for node in _tree(module).body if isinstance(node, ast.FunctionDef)]
    assert functions
    for function in functions:
        assert any("njit" in ast.unparse(decorator) for decorator in function.decorator_list), function.name


@pytest.mark.parametrize("module", THREE_D)
def test_no_second_implementation_switch(module):
    """No ``fast=`` or boolean ``reference=`` parameter selects a second implementation (``reference``
    remains only as the unloaded jig's markers, :class:`softjig.sensing.identities.ReferenceMarkers`)."""
    for node in ast.walk(_tree(module)):
        if isinstance(node, ast.FunctionDef):
            arguments = node.args.args + node.args.kwonlyargs
            defaults = dict(
                zip([a.arg for a in node.args.kwonlyargs], node.args.kw_defaults, strict=True)
            ) | dict(zip([a.arg for a in node.args.args][::-1], node.args.defaults[::-1], strict=False))
            for argument in arguments:
                assert argument.arg != "fast", node.name
                default = defaults.get(argument.arg)
                is_flag = isinstance(default, ast.Constant) and isinstance(default.value, bool)
                assert not (argument.arg == "reference" and is_flag), node.name


def test_plane_least_squares_is_written_once():
    """Only the one plane-fit kernel takes a scatter matrix's eigenvectors or the points' SVD, with its own
    3x3 solvers (no LAPACK call compiled into a kernel: its checks and copies are hundreds of symbols that
    each new process loads, issue 14)."""
    for module in THREE_D + KERNELS:
        source = (SRC / module).read_text(encoding="utf-8")
        assert source.count("linalg.eigh(") + source.count("linalg.svd(") == 0, module
        solvers = source.count("def symmetric_eigen_3x3(") + source.count("def right_singular_3(")
        assert solvers == (2 if module == "_geometry_kernels.py" else 0), module
        if module != "_geometry_kernels.py":
            assert "symmetric_eigen_3x3(" not in source and "right_singular_3(" not in source, module


def test_the_stage_functions_take_no_implementation_choice():
    from softjig.sensing.refractive import triangulate_refracted
    from softjig.sensing.stereo import match_rectified

    assert "reference" not in inspect.signature(match_rectified).parameters
    assert "reference" not in inspect.signature(triangulate_refracted).parameters
