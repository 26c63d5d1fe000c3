"""The plain values' coercion without pydantic (softjig.cli.coercion) against Typer's own, on every option of
every command: the same value, or the same error."""

from __future__ import annotations

import importlib
import subprocess
import sys
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from softjig.cli import coercion
from softjig.cli.app import COMMANDS, _click_command

typer_coercion = pytest.importorskip("typer._coercion", reason="a Typer without runtime coercion")
typer_core = pytest.importorskip("typer._click.core")


def _params():
    """Every Typer parameter of every command (subcommands of a group included), with its command."""
    found = []
    for name, (module, _) in COMMANDS.items():
        importlib.import_module(module)
        command = _click_command(name)
        for sub in [command, *getattr(command, "commands", {}).values()]:
            for param in sub.params:
                if hasattr(param, "type_descriptor"):
                    found.append((sub, param))
    return found


PARAMS = _params()


def _outcome(coerce, value, param, ctx):
    try:
        return ("value", coerce(value, param=param, ctx=ctx))
    except Exception as exc:  # BadParameter and the like
        return ("error", type(exc).__name__, str(exc))


def _both(command, param, value):
    """Typer's own outcome and the light one for ``value``."""
    ctx = typer_core.Context(command)
    typer_side = typer_coercion.build_runtime_param(param.type_descriptor)
    light = coercion.LightCoercion(param.type_descriptor)
    saved = param._runtime_param
    try:
        return _outcome(typer_side.coerce, value, param, ctx), _outcome(light.coerce, value, param, ctx)
    finally:
        param._runtime_param = saved


def _samples(param, tmp: Path) -> list:
    samples = [None, param.default, "", "abc", "1", "-2", "0.5", "1e3", "1_000", " 7", "nan", "inf", "1e400"]
    samples += ["10000001", "-181", "65536", "0", "+3", "007", "2.0", ".5", "5."]
    samples += [str(tmp), str(tmp / "missing.toml"), str(tmp / "file.txt"), "-", "~/x"]
    choices = getattr(param.type_descriptor, "choices", None) or ()
    for choice in choices:
        samples += [
            choice,
            str(getattr(choice, "value", choice)),
            str(getattr(choice, "value", choice)).upper(),
        ]
    if param.multiple or param.nargs == -1:
        samples = [None, (), ("a.png", "b.png"), [str(tmp)], ("1", "x"), *samples[2:5]]
    return samples


def test_every_option_of_every_command_coerces_as_typer_does(tmp_path):
    (tmp_path / "file.txt").write_text("x")
    assert len(PARAMS) > 100  # every command's options were found
    compared = 0
    for command, param in PARAMS:
        for value in _samples(param, tmp_path):
            typer_side, light = _both(command, param, value)
            assert repr(light) == repr(typer_side), (command.name, param.name, value)
            compared += 1
    assert compared > 1000


def _assert_as_typer(text: str, *kinds: type) -> None:
    """The light coercion of ``text`` is Typer's for every option annotated with one of ``kinds``."""
    for command, param in PARAMS:
        if param.type_descriptor.annotation in kinds:
            typer_side, light = _both(command, param, text)
            assert repr(light) == repr(typer_side), (param.name, text)


@settings(max_examples=300, deadline=None)
@given(st.floats(allow_nan=False, allow_infinity=False), st.sampled_from(["repr", "e", "f"]))
def test_float_texts_as_typer_reads_them(number, style):
    text = {"repr": repr(number), "e": f"{number:.17e}", "f": f"{number:.6f}"}[style]
    _assert_as_typer(text, float)


@settings(max_examples=200, deadline=None)
@given(st.from_regex(r"\A\s?[+-]?\d*[._]?\d*([eE][+-]?\d+)?\Z"))
def test_number_like_texts_as_typer_reads_them(text):
    _assert_as_typer(text, float, int)


@settings(max_examples=200, deadline=None)
@given(st.from_regex(r"\A[+-]?\d{1,30}\Z"))
def test_integer_texts_as_typer_reads_them(text):
    _assert_as_typer(text, int)


def test_a_single_estimate_builds_no_pydantic_adapter_for_its_options(tmp_path):
    """Every option of a pair's estimate is a plain value: Typer's adapters are never built (they cost
    30-60 ms of the command's start)."""
    script = (
        "import sys, typer._coercion as co\n"
        "built = []\n"
        "original = co.build_runtime_param\n"
        "co.build_runtime_param = lambda d: built.append(d) or original(d)\n"
        "import typer.core; typer.core.build_runtime_param = co.build_runtime_param\n"
        "from softjig.cli import app\n"
        "try:\n"
        "    app(['estimate', 'L.png', 'R.png', '--config', sys.argv[1], '--part-diameter', '50', '--json'],"
        " prog_name='softjig')\n"
        "except SystemExit:\n"
        "    pass\n"
        "print(len(built))\n"
    )
    config = tmp_path / "missing.toml"
    done = subprocess.run([sys.executable, "-c", script, str(config)], capture_output=True, text=True)
    assert done.stdout.strip().splitlines()[-1] == "0", done.stderr
