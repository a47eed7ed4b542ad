"""The ``wamctl`` command line: typer only. Parse -> load spec -> call the library -> map errors to exit codes.

Errors a user can cause end in one line (``error: ...``) and exit code 2, without a traceback;
an interrupted command (Ctrl-C, SIGTERM, SIGHUP) ends in one line and exit code 130, its run directory marked
``interrupted``.

Start-up stays light: ``wamctl --help`` and ``--version`` import typer and the command modules only (every
command imports the library it calls inside its function), and help is click's plain text, wrapped to the
terminal (typer's rich help would import a Markdown parser on every call).
"""

from __future__ import annotations

import signal
import sys
import threading

import typer

from wamctl import __version__
from wamctl.errors import WamctlError

app = typer.Typer(
    name="wamctl",
    help="Lab tool for the 7-DOF Barrett WAM: run experiments from YAML specs on the simulated arm or the real "
         "one over CAN, identify friction, tune PIDs, diagnose model errors, run the gaze HMI, and report.",
    no_args_is_help=True, pretty_exceptions_enable=False, add_completion=False, rich_markup_mode=None,
)


def _version(value: bool):
    if value:
        typer.echo(f"wamctl {__version__}")
        raise typer.Exit()


@app.callback()
def _root(verbose: bool = typer.Option(False, "--verbose", "-v", help="Log progress details to stderr."),
          version: bool = typer.Option(False, "--version", callback=_version, is_eager=True,
                                       help="Print the version and exit.")):
    import logging

    logging.basicConfig(level=logging.INFO if verbose else logging.WARNING,
                        format="%(levelname)s %(name)s: %(message)s", stream=sys.stderr)


def short_help(doc: str | None) -> str | None:
    """The first sentence of a command's docstring, whole (click would cut it at 45 characters, and at
    abbreviations such as "ch. 4"): up to the first ". " before a capital or the first ": " outside
    parentheses."""
    if not doc:
        return None
    first = " ".join(doc.strip().split("\n\n")[0].split())
    depth = 0
    for i, ch in enumerate(first):
        depth += {"(": 1, ")": -1}.get(ch, 0)
        nxt = first[i + 1: i + 3]
        if ch == "." and (nxt == "" or (nxt[:1] == " " and nxt[1:].isupper())):
            return first[:i]
        if ch == ":" and depth == 0 and nxt[:1] == " ":
            return first[:i]
    return first


def _register() -> None:
    """Every command module adds its commands to ``app`` (in the order of ``--help``)."""
    import importlib
    import inspect

    from wamctl.commands import COMMAND_MODULES

    if app.registered_commands:
        return
    for name in COMMAND_MODULES:
        importlib.import_module(f"wamctl.commands.{name}").register(app)
    for info in app.registered_commands:
        if info.short_help is None:
            info.short_help = short_help(info.help or inspect.getdoc(info.callback))


def _print_error(exc: WamctlError) -> None:
    from rich.console import Console
    from rich.text import Text

    err = Console(stderr=True)
    for line in str(exc).splitlines() or [type(exc).__name__]:
        err.print(Text.assemble(("error:", "bold red"), " ", line), highlight=False, soft_wrap=True)


_command = None   # the click command built from ``app`` (once per process: typer builds it from signatures)
_STOP_SIGNALS = ("SIGINT", "SIGTERM", "SIGHUP")


def _termination_as_interrupt(signum, frame):
    raise KeyboardInterrupt(signal.Signals(signum).name)


def _interrupt_behind(exc: BaseException) -> KeyboardInterrupt | None:
    """The KeyboardInterrupt behind an exit: typer turns one into ``Exit(130)``, silently."""
    seen = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, KeyboardInterrupt):
            return exc
        seen.add(id(exc))
        exc = exc.__cause__ or exc.__context__
    return None


def _report_complete(path) -> bool:
    return all((path / f"report.{ext}").is_file() for ext in ("md", "html", "json"))


def _interrupted(exc: KeyboardInterrupt) -> None:
    """One line for an interrupt that reached the command line, exit 130: a run directory of this process
    still running is marked ``interrupted`` (its tables consolidated); a run that completed but whose report
    was cut short is named with the command that writes it. Further signals are ignored meanwhile."""
    if threading.current_thread() is threading.main_thread():
        for name in _STOP_SIGNALS:
            if hasattr(signal, name):
                signal.signal(getattr(signal, name), signal.SIG_IGN)
    by = exc.args[0] if exc.args and isinstance(exc.args[0], str) else "Ctrl-C"
    line = f"interrupted by {by}"
    store = sys.modules.get("wamctl.runs.store")   # not imported: no run directory was made
    if store is not None:
        ended = store.end_open_runs(f"stopped by {by}")
        if ended:
            line = f"{ended[-1]}: interrupted by {by}; the data recorded so far are readable"
        elif store.FINISHED_RUNS and store.FINISHED_RUNS[-1][1] == "completed" \
                and not _report_complete(store.FINISHED_RUNS[-1][0]):
            path = store.FINISHED_RUNS[-1][0]
            line = (f"{path}: completed, but its report was interrupted (stopped by {by}); "
                    f"`wamctl report {path}` writes it")
    _print_error(WamctlError(line))
    sys.exit(130)


def main() -> None:
    global _command
    from wamctl.commands.common import reset_consoles

    if _command is None:
        _register()
        _command = typer.main.get_command(app)
    reset_consoles()
    sigs = [getattr(signal, n) for n in _STOP_SIGNALS if hasattr(signal, n)]
    main_thread = threading.current_thread() is threading.main_thread()
    old = {s: signal.getsignal(s) for s in sigs} if main_thread else {}
    try:
        for s in sigs[1:] if main_thread else ():   # SIGTERM and SIGHUP end a command as Ctrl-C does
            if old[s] is not signal.SIG_IGN:             # nohup keeps SIGHUP ignored
                signal.signal(s, _termination_as_interrupt)
        try:
            _command()  # usage errors, --help and typer.Exit are handled by click itself (exit codes 2 and 0)
        except WamctlError as exc:
            _print_error(exc)
            sys.exit(exc.exit_code)
        except KeyboardInterrupt as exc:
            _interrupted(exc)
        except SystemExit as exc:
            interrupt = _interrupt_behind(exc) if exc.code == 130 else None
            if interrupt is None:
                raise
            _interrupted(interrupt)
    finally:   # the handlers as they were (main() called in-process, e.g. by the tests)
        for s, h in old.items():
            if h is not None:
                signal.signal(s, h)


if __name__ == "__main__":
    main()
