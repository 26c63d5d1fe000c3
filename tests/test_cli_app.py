"""The command line's shared machinery: lazy command registry, plain flags in help, start-up imports."""

from __future__ import annotations

import ast
import importlib
import inspect
import subprocess
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

from softjig.cli import app
from softjig.cli.app import COMMANDS, _click_command

CLI_DIR = Path(__file__).resolve().parents[1] / "src" / "softjig" / "cli"


def _registered_names(path: Path) -> set[str]:
    """Names a command module registers on the top-level app, read from its source (no import)."""
    names: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.FunctionDef):
            for dec in node.decorator_list:
                if (
                    isinstance(dec, ast.Call)
                    and isinstance(dec.func, ast.Attribute)
                    and isinstance(dec.func.value, ast.Name)
                    and dec.func.value.id == "app"
                    and dec.func.attr == "command"
                ):
                    arg = dec.args[0].value if dec.args else node.name.replace("_", "-")
                    names.add(arg)
        if (
            isinstance(node, ast.Call)
            and isinstance(node.func, ast.Attribute)
            and node.func.attr == "add_typer"
            and isinstance(node.func.value, ast.Name)
            and node.func.value.id == "app"
        ):
            names |= {kw.value.value for kw in node.keywords if kw.arg == "name"}
    return names


def test_every_command_module_is_in_the_registry():
    """A command registered on ``app`` but missing from COMMANDS would vanish from ``softjig --help``."""
    found = {}
    for path in sorted(CLI_DIR.glob("*.py")):
        for name in _registered_names(path):
            found[name] = f"softjig.cli.{path.stem}"
    assert found == {name: module for name, (module, _) in COMMANDS.items()}


@pytest.mark.parametrize("name", list(COMMANDS))
def test_registry_help_is_the_commands_first_docstring_line(name):
    module, short_help = COMMANDS[name]
    importlib.import_module(module)
    command = _click_command(name)
    doc = command.help if command.help else ""
    assert inspect.cleandoc(doc).splitlines()[0] == short_help


def test_help_lists_every_command_without_importing_them():
    code = (  # the modules loaded when the console entry point ends (it runs the atexit handlers)
        "import atexit, sys\n"
        "LIGHT = ('softjig.cli.app', 'softjig.cli.coercion')  # what every command shares\n"
        "def heavy():\n"
        "    names = sorted(m for m in sys.modules if m.split('.')[0] in ('numpy', 'scipy', 'cv2', 'numba')\n"
        "                   or m.startswith('softjig.cli.') and m not in LIGHT)\n"
        "    print('HEAVY', names)\n"
        "atexit.register(heavy)\n"
        "from softjig.cli import main\n"
        "sys.argv = ['softjig', '--help']\n"
        "main()\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=True)
    assert "HEAVY []" in out.stdout
    for name in COMMANDS:
        assert f" {name} " in out.stdout


def _all_help_pages():
    runner = CliRunner()
    pages = {"softjig": runner.invoke(app, ["--help"], terminal_width=200).output}
    for name in COMMANDS:
        result = runner.invoke(app, [name, "--help"], terminal_width=200)
        assert result.exit_code == 0, result.output
        pages[name] = result.output
        sub = _click_command(name)
        for sub_name in getattr(sub, "commands", {}):
            result = runner.invoke(app, [name, sub_name, "--help"], terminal_width=200)
            pages[f"{name} {sub_name}"] = result.output
    return pages


def test_no_bool_metavar_in_any_help():
    pages = _all_help_pages()
    assert len(pages) > len(COMMANDS)
    for name, text in pages.items():
        assert "<bool>" not in text, name
        assert "--help" in text, name


def test_unknown_command_suggests_the_close_one():
    result = CliRunner().invoke(app, ["estimat"])
    assert result.exit_code == 2
    assert "estimate" in result.output


def test_choice_enums_mirror_the_librarys_lists():
    from softjig.calibration.sweep import SELECTIONS
    from softjig.cli.choices import DEFAULT_METHOD, FrameSelection, Method
    from softjig.sensing.pipeline import DEFAULT_METHOD as LIB_DEFAULT
    from softjig.sensing.pipeline import METHODS

    assert [m.value for m in Method] == list(METHODS)
    assert DEFAULT_METHOD.value == LIB_DEFAULT
    assert [f.value for f in FrameSelection] == list(SELECTIONS)


def test_calibrate_lists_its_choices_and_refuses_others_before_any_work(tmp_path):
    runner = CliRunner()
    text = runner.invoke(app, ["calibrate", "--help"], terminal_width=200).output
    assert "refractive|paper" in text and "all|even|odd" in text
    missing = tmp_path / "no-such-dataset"  # refused on the choice, not on the dataset
    for option, value in (("--method", "svd"), ("--frames", "middle")):
        result = runner.invoke(app, ["calibrate", str(missing), option, value])
        assert result.exit_code == 2
        assert "svd" in result.output or "middle" in result.output
        assert "does not exist" not in result.output


def test_nan_and_inf_are_refused_in_every_number_option(tmp_path):
    runner = CliRunner()
    for args in (
        ["sweep-plan", "--push-depth", "nan"],
        ["sweep-plan", "--clearance", "inf"],
        ["align-jig", str(tmp_path / "x.png"), "--camera", "c", "--flange", "f", "--prior-yaw-deg", "nan"],
    ):
        result = runner.invoke(app, [*args, "--out", str(tmp_path / "out.json")])
        assert result.exit_code == 2, (args, result.output)
        assert not (tmp_path / "out.json").exists()


def test_a_signal_raised_inside_a_compiled_kernels_callback_ends_the_command_as_the_signal():
    """A SIGTERM handler's exception raised while a Numba kernel calls back into Python reaches the command
    as a SystemError caused by it (seen: a study's SIGTERM exited 1 with a traceback instead of 143)."""
    program = """
from softjig.cli.app import handle_errors
from softjig.io.workers import Terminated

@handle_errors
def command():
    try:
        raise Terminated(15)
    except Terminated as exc:
        raise SystemError("returned a result with an exception set") from exc

command()
"""
    done = subprocess.run([sys.executable, "-c", program], capture_output=True, text=True, timeout=120)
    assert done.returncode == 143, done.stderr
    assert "terminated by SIGTERM" in done.stderr and "Traceback" not in done.stderr


def test_a_ctrl_c_inside_a_compiled_kernels_callback_is_an_interruption():
    import typer

    from softjig.cli.app import EXIT_INTERRUPTED, handle_errors

    @handle_errors
    def command():
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt as exc:
            raise SystemError("returned a result with an exception set") from exc

    with pytest.raises(typer.Exit) as exited:
        command()
    assert exited.value.exit_code == EXIT_INTERRUPTED


def test_a_system_error_of_no_signal_is_not_taken_for_one():
    from softjig.cli.app import handle_errors

    @handle_errors
    def command():
        raise SystemError("a bug")

    with pytest.raises(SystemError, match="a bug"):
        command()


def test_a_system_error_whose_causes_loop_is_raised_not_followed_forever():
    from softjig.cli.app import handle_errors

    first, second = SystemError("a bug"), ValueError("its cause")
    first.__cause__, second.__cause__ = second, first

    @handle_errors
    def command():
        raise first

    with pytest.raises(SystemError, match="a bug"):
        command()
