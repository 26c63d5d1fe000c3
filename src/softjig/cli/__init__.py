"""The ``softjig`` command line: one module per command, all registered on :data:`app`.

Command modules are imported on first use (see :mod:`softjig.cli.app`, :data:`~softjig.cli.app.COMMANDS`).
"""

from softjig.cli.app import EXIT_BAD_INPUT, EXIT_NO_ESTIMATE, EXIT_OK, app, error, handle_errors, warn

__all__ = ["EXIT_BAD_INPUT", "EXIT_NO_ESTIMATE", "EXIT_OK", "app", "error", "handle_errors", "main", "warn"]


def main() -> None:
    """Console-script entry point (``softjig``)."""
    app(prog_name="softjig")
