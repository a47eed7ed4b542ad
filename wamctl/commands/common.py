"""What every command shares: the consoles, JSON output, progress bars, the report's tables on the terminal,
common options, and running a spec and showing its outcome (``run``, ``friction-id``, ``tune-ift``,
``hmi-session``)."""

from __future__ import annotations

import json
import sys
from contextlib import contextmanager
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

console = Console()
err_console = Console(stderr=True)


@contextmanager
def progress_bar(description: str, enabled: bool = True):
    """Yields a callback ``progress(done, total)`` drawing a rich bar on stderr (a no-op when disabled)."""
    if not enabled:
        yield None
        return
    with Progress(TextColumn("{task.description}"), BarColumn(), TextColumn("{task.percentage:>3.0f}%"),
                  TimeElapsedColumn(), TimeRemainingColumn(), console=err_console, transient=True) as prog:
        task = prog.add_task(description, total=None)

        def update(done: int, total: int, label: str | None = None):
            prog.update(task, completed=done, total=total, **({"description": label} if label else {}))
        update.progress = prog  # lets a terminal prompt pause the bar
        yield update


def emit_json(obj) -> None:
    sys.stdout.write(json.dumps(obj, indent=2, default=str) + "\n")


SpecArg = Annotated[Path, typer.Argument(help="Experiment spec (YAML); its `kind` selects the experiment.",
                                         show_default=False)]
OutOpt = Annotated[Path | None, typer.Option("--out", help="Parent directory of the run directory "
                                                "(default: the spec's out_dir, normally runs/).")]
QuietOpt = Annotated[bool, typer.Option("--quiet", "-q", help="No progress bar and no tables.")]
JsonOpt = Annotated[bool, typer.Option("--json", help="Print a JSON summary on stdout (for scripts).")]
YesOpt = Annotated[bool, typer.Option("--yes", "-y", help="Real arm: answer the session's questions with yes (the "
                                      "arm is at its home pose for zeroing); Shift-Activate stays the operator's.")]


def print_document_tables(doc) -> None:
    """The tables of a report :class:`~wamctl.report.document.Document` on the terminal."""
    from rich.table import Table

    for kind, obj in doc.blocks:
        if kind != "table":
            continue
        name, df, caption, digits = obj
        t = Table(title=f"{doc.title}: {name}", caption=caption or None)
        frame = df.reset_index() if df.index.name else df
        for c in frame.columns:
            t.add_column(str(c).replace("_", " "), justify="right", overflow="fold")
        for row in frame.itertuples(index=False):
            t.add_row(*[f"{v:.{digits}f}" if isinstance(v, float) else str(v) for v in row])
        console.print(t)


def run_and_report(spec_path: Path, out: Path | None, dry_run: bool, quiet: bool, as_json: bool,
                   expect_kind: str | None = None, files=None, yes: bool = False) -> None:
    """Shared by `run` and the per-kind commands (`friction-id`, `tune-ift`, `hmi-session`).

    ``files(run_path) -> {name: path}`` names products of the run to show (e.g. the friction model file)."""
    from wamctl.errors import SpecError
    from wamctl.experiments.runner import plan_only, run_spec
    from wamctl.specs import load_spec

    spec = load_spec(spec_path)
    if expect_kind and spec.kind != expect_kind:
        raise SpecError(f"{spec_path}: kind: this command runs `{expect_kind}` specs, not `{spec.kind}`")
    base = spec_path.resolve().parent
    if dry_run:
        summary, checks = plan_only(spec, base)
        if as_json:
            emit_json({"spec": str(spec_path), "kind": spec.kind, "plan": summary, "checks": checks})
        else:
            console.print("\n".join(summary), highlight=False)
            for c in checks:
                console.print(f"[green]ok[/] {c}")
            console.print("dry run: nothing moved")
        return
    from wamctl.backends.can.operator import use_operator
    from wamctl.commands.terminal_operator import TerminalOperator

    label = f"{spec.kind} {spec.name}"
    with progress_bar(label, enabled=not (quiet or as_json)) as progress, \
            use_operator(TerminalOperator(yes=yes, progress=progress, label=label)):  # the CAN session's operator
        outcome = run_spec(spec, base, out, progress, make_report=False)
    show_outcome(outcome, quiet, as_json, files(outcome.path) if files else None)


def show_outcome(outcome, quiet: bool, as_json: bool, files: dict | None = None) -> None:
    """A finished run on the terminal: write its report, print its tables (or a JSON summary) and the status;
    exit code 1 unless it completed."""
    from wamctl.report import write_report

    doc = write_report(outcome.path) if outcome.status == "completed" else None
    shown = {k: (str(v) if v is not None and Path(v).exists() else None) for k, v in (files or {}).items()}
    if as_json:
        emit_json({"run_dir": str(outcome.path), "status": outcome.status, "reason": outcome.reason, **shown,
                   "report": doc.to_json() if doc else None})
    else:
        if doc is not None and not quiet:
            print_document_tables(doc)
        colour = "green" if outcome.status == "completed" else "red"
        msg = f"[{colour}]{outcome.status}[/]" + (f": {outcome.reason}" if outcome.reason else "")
        lines = [f"{msg}  run directory: {outcome.path}"] + [f"{k.replace('_', ' ')}: {v}" for k, v in shown.items()
                                                             if v is not None]
        (console if outcome.status == "completed" else err_console).print("\n".join(lines), highlight=False,
                                                                          soft_wrap=True)
    if outcome.status != "completed":
        raise typer.Exit(1)
