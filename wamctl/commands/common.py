"""What every command shares: the consoles, JSON output, progress bars, the report's tables on the terminal,
common options, and running a spec and showing its outcome (``run``, ``friction-id``, ``tune-ift``,
``hmi-session``)."""

from __future__ import annotations

import json
import sys
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

if TYPE_CHECKING:
    from rich.console import Console


class _LazyConsole:
    """A rich Console made on first use, so that ``wamctl --help`` does not import rich."""

    def __init__(self, stderr: bool = False):
        self._stderr = stderr
        self._console = None

    def _get(self) -> Console:
        if self._console is None:
            from rich.console import Console
            self._console = Console(stderr=self._stderr)
        return self._console

    def __getattr__(self, name):
        return getattr(self._get(), name)


console = _LazyConsole()
err_console = _LazyConsole(stderr=True)


def reset_consoles() -> None:
    """Forget the consoles made so far (a new command line: the terminal's width is read again)."""
    console._console = err_console._console = None


CTRL_C_ECHO_COLUMNS = 2
"""Columns a progress bar leaves free at the right of the terminal: the ``^C`` a terminal echoes on Ctrl-C then
stays on the bar's line, which stopping the bar erases. A bar as wide as the terminal (80 columns: the
description, the bar and the times fill it) had the echo wrap to a line of its own, and the stopped bar, frozen
at its last percentage, stayed above the lines printed after it."""


@contextmanager
def progress_bar(description: str, enabled: bool = True):
    """Yields a callback ``progress(done, total)`` drawing a rich bar on stderr (None when disabled, or when stderr
    is not a terminal: a log file would get only the blank line the bar leaves when it stops). The bar is
    :data:`CTRL_C_ECHO_COLUMNS` narrower than the terminal."""
    if not enabled or not err_console._get().is_terminal:
        yield None
        return
    from rich.constrain import Constrain
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

    out = err_console._get()

    class NarrowProgress(Progress):
        def get_renderables(self):        # the terminal's width read at each refresh
            yield Constrain(self.make_tasks_table(self.tasks), max(1, out.width - CTRL_C_ECHO_COLUMNS))

    with NarrowProgress(TextColumn("{task.description}"), BarColumn(), TextColumn("{task.percentage:>3.0f}%"),
                        TimeElapsedColumn(), TimeRemainingColumn(), console=out, transient=True) as prog:
        task = prog.add_task(description, total=None)

        def update(done: int, total: int, label: str | None = None):
            prog.update(task, completed=done, total=total, **({"description": label} if label else {}))
        update.progress = prog  # lets a terminal prompt pause the bar
        yield update


def interrupt_notice(progress=None):
    """The runner's ``on_interrupt(by, rows)`` (:func:`wamctl.experiments.runner.record_outcome`): stops the
    progress bar made by :func:`progress_bar` (if any), then says on stderr that the interrupt was caught and
    what is being saved, e.g. ``interrupted by Ctrl-C: saving 1,312,500 samples ...`` (the seconds a long run's
    tables take to write would otherwise pass in silence, the bar's clock still counting)."""
    def notice(by: str, rows: int) -> None:
        if progress is not None:
            progress.progress.stop()
        err_console.print(f"interrupted by {by}: saving {rows:,} sample{'' if rows == 1 else 's'} ...",
                          highlight=False, markup=False)
    return notice


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


def status_line(status: str | None, reason: str | None, run_dir) -> str:
    """How a run ended, in one line (rich markup): the status in colour, the reason, the run directory (printed
    with ``soft_wrap=True`` so that a long path stays whole and can be copied)."""
    colour = "green" if status == "completed" else "red"
    return f"[{colour}]{status}[/]" + (f": {reason}" if reason else "") + f"  run directory: {run_dir}"


def show_written_document(doc, written, as_json: bool = False, quiet: bool = False) -> None:
    """A report just written (``compare``, ``friction-id --compare``): its JSON and files with ``--json``, else its
    tables (unless ``--quiet``) and the files written, one whole path a line."""
    if as_json:
        emit_json({"report": doc.to_json(), "written": [str(p) for p in written]})
        return
    if not quiet:
        print_document_tables(doc)
    for p in written:
        console.print(f"wrote {p}", highlight=False, soft_wrap=True)


def print_document_tables(doc, out: Console | None = None) -> None:
    """The tables of a report :class:`~wamctl.report.document.Document` on the terminal, then its warnings.

    Each column keeps the report's one number format (:func:`wamctl.report.document.format_column`); a table
    wider than the terminal is split into parts that each repeat the key column, so that no number and no word
    is ever cut."""
    out = out or console
    for kind, obj in doc.blocks:
        if kind == "table" and len(obj.df):        # an empty table is a title over nothing: the report says why
            print_table(f"{doc.title}: {obj.name}", obj, out)
    print_warnings(doc, out)


def print_warnings(doc, out: Console | None = None) -> None:
    """The warnings of a report (shown even with --quiet: they ask the user to act)."""
    from rich.text import Text

    for kind, obj in doc.blocks:
        if kind == "warn":
            (out or console).print(Text.assemble(("warning: ", "bold yellow"), str(obj)))


def print_frame(title: str, df, caption: str = "", key: str | None = None, out: Console | None = None) -> None:
    """A pandas frame as a terminal table (:func:`print_table`): its index, ``key`` or first column as key."""
    from wamctl.report.document import DEFAULT_DIGITS, Table

    print_table(title, Table(title, df, caption, DEFAULT_DIGITS, (key,) if key else ()), out)


_TEXT_MIN_CAP = 40     # a text column narrower than its longest word wraps; words longer than this may fold


def _words(s: str) -> int:
    return max((len(w) for w in s.split()), default=0)


def print_table(title: str, table, out: Console | None = None) -> None:
    """One :class:`~wamctl.report.document.Table` as one or more rich tables that fit the terminal width: the
    title and caption as paragraphs, each column wide enough for its longest number (numbers never wrap) and its
    longest word."""
    from rich import box
    from rich.table import Table
    from rich.text import Text

    from wamctl.report.document import column_label

    out = out or console
    names, rows, is_key = table.cells(na="-")
    numeric = table.numeric()
    heads = [column_label(n) for n in names]            # units with their slash: speed peak (rad/s)
    units = [len(h) - h.rfind(" (") - 1 if h.endswith(")") and " (" in h else 0 for h in heads]  # kept whole
    no_wrap = [k or num for k, num in zip(is_key, numeric)]   # sized to their longest cell: never wrapped
    least, natural = [], []
    for c, head in enumerate(heads):
        cells = [r[c] for r in rows]
        longest = max((len(x) for x in cells), default=0)
        body = longest if no_wrap[c] else min(max((_words(x) for x in cells), default=0), _TEXT_MIN_CAP)
        least.append(max(body, _words(head), units[c], 1))
        natural.append(max(longest, len(head), 1))
    parts = pack_columns(least, is_key, out.width)
    out.print(Text(title, style="bold"), soft_wrap=False)
    for i, cols in enumerate(parts):
        widths = _widen({c: least[c] for c in cols}, natural, out.width)
        t = Table(box=box.SIMPLE_HEAD, title=Text(f"({i + 1}/{len(parts)})") if len(parts) > 1 else None,
                  pad_edge=False, show_edge=False)
        for c in cols:
            t.add_column(Text(heads[c]), justify="left" if (is_key[c] or not numeric[c]) else "right",
                         width=widths[c], overflow="fold")
        for r in rows:
            t.add_row(*[Text(r[c]) for c in cols])
        out.print(t)
    if table.caption:
        out.print(Text(table.caption, style="dim"))
    out.print()


def _overhead(n: int) -> int:
    """Characters rich's SIMPLE_HEAD table without edges adds around ``n`` columns: a space either side of a
    column and a separator between columns, none at the edges."""
    return max(0, 3 * n - 3) if n else 0


def _widen(widths: dict[int, int], natural: list[int], total: int) -> dict[int, int]:
    """Give the columns of one part the room left, smallest shortfall first, up to their natural widths."""
    room = total - sum(widths.values()) - _overhead(len(widths))
    for c in sorted(widths, key=lambda c: natural[c] - widths[c]):
        add = max(0, min(natural[c] - widths[c], room))
        widths[c] += add
        room -= add
    return widths


def pack_columns(widths: list[int], is_key: list[bool], total: int) -> list[list[int]]:
    """Split columns (by index) into as few parts as fit ``total`` characters, of similar widths, each part
    starting with the key columns."""
    keys = [c for c, k in enumerate(is_key) if k]
    rest = [c for c, k in enumerate(is_key) if not k]

    def greedy(cap: int) -> list[list[int]]:
        parts, cur = [], list(keys)
        for c in rest:
            if sum(widths[x] for x in cur + [c]) + _overhead(len(cur) + 1) > cap and len(cur) > len(keys):
                parts.append(cur)
                cur = list(keys)
            cur.append(c)
        return parts + [cur]

    parts = greedy(total)
    if len(parts) > 1:   # same number of parts, evened out: the smallest width that still needs no more parts
        lo = sum(widths[c] for c in keys) + _overhead(len(keys) + 1) + max(widths[c] for c in rest)
        for cap in range(lo, total):
            if len(greedy(cap)) == len(parts):
                return greedy(cap)
    return parts


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
        outcome = run_spec(spec, base, out, progress, make_report=False, on_interrupt=interrupt_notice(progress))
    show_outcome(outcome, quiet, as_json, files(outcome.path) if files else None)


def show_outcome(outcome, quiet: bool, as_json: bool, files: dict | None = None) -> None:
    """A finished run on the terminal: write its report, print its tables (or a JSON summary) and the status;
    exit code 0 when it completed, 2 when it was refused before anything moved, else 1."""
    from wamctl.report import write_report
    from wamctl.report.loop_warnings import run_warnings

    doc = write_report(outcome.path) if outcome.status == "completed" else None
    shown = {k: (str(v) if v is not None and Path(v).exists() else None) for k, v in (files or {}).items()}
    loop_warnings = run_warnings(outcome.path)   # torque limit, tracking error: any kind, any status
    if as_json:
        emit_json({"run_dir": str(outcome.path), "status": outcome.status, "reason": outcome.reason, **shown,
                   "warnings": loop_warnings, "report": doc.to_json() if doc else None})
    else:
        if doc is not None:
            (print_warnings if quiet else print_document_tables)(doc)
        from rich.text import Text
        said = set((doc.data.get("warnings") or []) if doc is not None else [])
        for line in loop_warnings:
            if line not in said:
                console.print(Text.assemble(("warning: ", "bold yellow"), line))
        lines = [status_line(outcome.status, outcome.reason, outcome.path)] + [
            f"{k.replace('_', ' ')}: {v}" for k, v in shown.items() if v is not None]
        (console if outcome.status == "completed" else err_console).print("\n".join(lines), highlight=False,
                                                                          soft_wrap=True)
    if outcome.status != "completed":
        raise typer.Exit(outcome.exit_code or 1)
