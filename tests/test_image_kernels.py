"""The image side's structure (issue 16): Numba only in private ``_kernels`` modules next to their users,
loaded on first use, and one production path per stage (no ``fast=``/``reference=`` switch)."""

from __future__ import annotations

import ast
import importlib
import inspect
import subprocess
import sys
from pathlib import Path

import pytest

import softjig

SENSING = Path(softjig.__file__).parent / "sensing"
STAGES = ("detect", "subpixel", "fiducials", "jigframe", "rectify")
KERNELS = ("_detect_kernels", "_subpixel_kernels", "_fiducial_kernels", "_jigframe_kernels")


def _numba_uses(path: Path) -> list[str]:
    """Where a module imports Numba or decorates with it (``import numba``, ``from numba``, ``@numba.*``)."""
    uses = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import) and any(a.name.split(".")[0] == "numba" for a in node.names):
            uses.append(f"line {node.lineno}: import numba")
        elif isinstance(node, ast.ImportFrom) and (node.module or "").split(".")[0] == "numba":
            uses.append(f"line {node.lineno}: from {node.module} import ...")
        elif isinstance(node, ast.FunctionDef):
            for decorator in node.decorator_list:
                if "numba" in ast.unparse(decorator):
                    uses.append(f"line {node.lineno}: @{ast.unparse(decorator)} {node.name}")
    return uses


@pytest.mark.parametrize("stage", STAGES)
def test_numba_only_in_the_kernel_modules(stage):
    assert _numba_uses(SENSING / f"{stage}.py") == []


@pytest.mark.parametrize("module", KERNELS)
def test_kernel_modules_are_private_and_compiled(module):
    assert module.startswith("_")
    assert any("njit" in use for use in _numba_uses(SENSING / f"{module}.py"))


def test_the_detector_and_its_fits_import_without_numba():
    """Numba (~0.2 s to import, more to initialise) is loaded by the first kernel call, not by an import."""
    code = (
        "import sys\n"
        "import softjig.sensing.detect, softjig.sensing.subpixel, softjig.sensing.fiducials\n"
        "print('numba' in sys.modules)\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert done.stdout.strip() == "False"


@pytest.mark.parametrize("stage", STAGES)
def test_one_production_path_per_stage(stage):
    """Straightforward implementations are oracles in tests/oracles; genuine choices are named options."""
    module = importlib.import_module(f"softjig.sensing.{stage}")
    for name, function in inspect.getmembers(module, inspect.isfunction):
        if function.__module__ != module.__name__:
            continue
        switches = {"fast", "reference"} & set(inspect.signature(function).parameters)
        assert not switches, f"{stage}.{name} has an implementation switch {sorted(switches)}"
