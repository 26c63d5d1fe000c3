"""The ``softjig`` command line: one module per command, all registered on :data:`app`."""

from softjig.cli import (  # noqa: F401 - importing a command's module registers it on the app
    align,
    calibrate,
    calibrate_stereo,
    compare,
    config_cmd,
    demo,
    estimate,
    fiducials_cmd,
    jig_cmd,
    live,
    simulate,
    survey,
    sweep_plan,
)
from softjig.cli.app import EXIT_BAD_INPUT, EXIT_NO_ESTIMATE, EXIT_OK, app, error, handle_errors, warn

__all__ = ["EXIT_BAD_INPUT", "EXIT_NO_ESTIMATE", "EXIT_OK", "app", "error", "handle_errors", "main", "warn"]


def main() -> None:
    """Console-script entry point (``softjig``)."""
    app(prog_name="softjig")
