"""The ``wamctl`` command line: typer only. Parse -> load spec -> call the library -> map errors to exit codes.

Errors a user can cause end in one line (``error: ...``) and exit code 2, without a traceback;
an interrupted run exits 130.
"""

from __future__ import annotations

import logging
import sys

import typer
from rich.console import Console

from wamctl import __version__
from wamctl.errors import WamctlError

app = typer.Typer(
    name="wamctl",
    help="Lab tool for the 7-DOF Barrett WAM: run experiments from YAML specs on the simulated arm or the real "
         "one over CAN, identify friction, tune PIDs, diagnose model errors, run the gaze HMI, and report.",
    no_args_is_help=True, pretty_exceptions_enable=False, add_completion=False,
)
err_console = Console(stderr=True)


def _version(value: bool):
    if value:
        typer.echo(f"wamctl {__version__}")
        raise typer.Exit()


@app.callback()
def _root(verbose: bool = typer.Option(False, "--verbose", "-v", help="Log progress details to stderr."),
          version: bool = typer.Option(False, "--version", callback=_version, is_eager=True,
                                       help="Print the version and exit.")):
    logging.basicConfig(level=logging.INFO if verbose else logging.WARNING,
                        format="%(levelname)s %(name)s: %(message)s", stream=sys.stderr)


def _register() -> None:
    """Every command module adds its commands to ``app`` (in the order of ``--help``)."""
    import importlib

    from wamctl.commands import COMMAND_MODULES

    for name in COMMAND_MODULES:
        importlib.import_module(f"wamctl.commands.{name}").register(app)


def main() -> None:
    _register()
    try:
        app()  # usage errors, --help and typer.Exit are handled by typer itself
    except WamctlError as exc:
        for line in str(exc).splitlines() or [type(exc).__name__]:
            err_console.print(f"[bold red]error:[/] {line}", highlight=False, markup=True, soft_wrap=True)
        sys.exit(exc.exit_code)
    except KeyboardInterrupt:
        err_console.print("interrupted")
        sys.exit(130)


if __name__ == "__main__":
    main()
