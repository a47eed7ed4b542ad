"""wamctl runs: the run directories at a glance (issue 30)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from wamctl.commands.common import JsonOpt, console, emit_json, show_written_document


def runs(dirs: Annotated[list[Path] | None, typer.Argument(help="Folders of run directories (default: ./runs).",
                                                           show_default=False)] = None,
         kind: Annotated[str | None, typer.Option("--kind", help="Only runs of this kind.")] = None,
         status: Annotated[str | None, typer.Option("--status", help="Only runs with this status (completed, "
                                                    "failed, interrupted, running, abandoned).")] = None,
         since: Annotated[str | None, typer.Option("--since", help="Only runs started on or after this date "
                                                   "(2026-11-26, or 2026-11-26T14:00 UTC).")] = None,
         mark_abandoned: Annotated[bool, typer.Option("--mark-abandoned", help="Record every abandoned run (its "
                                                      "process is gone) as interrupted, its samples consolidated."
                                                      )] = False,
         html: Annotated[bool, typer.Option("--html", help="Rewrite index.html in each folder.")] = False,
         json: JsonOpt = False):
    """List runs, newest first: start, kind, name, status, duration, backend and the kind's figure.

    The figure: largest RPE (rotation), J summed over the joints before -> after tuning (ift), hits and mean
    execution time (hmi_block), effects found (diagnosis), joints identified (friction_sweep), the held-out
    verdict (identification). Kinds are shortened on the terminal (friction_sweep: friction, hmi_block: hmi,
    identification: identify); --json and --kind use the full names.

    A run whose manifest says `running` but whose process is gone is shown `abandoned`; a running run of another
    host `running? (host X)` (never marked).
    """
    from rich.table import Table
    from rich.text import Text

    from wamctl.runs import catalog

    folders = list(dirs or [Path("runs")])
    after = catalog.parse_since(since) if since else None
    entries = catalog.list_runs(folders, kind, status, after)
    marked = []
    if mark_abandoned:
        for e in entries:
            if e.status == catalog.ABANDONED and catalog.mark_abandoned(Path(e.path)):
                marked.append(e.path)
        if marked:
            entries = catalog.list_runs(folders, kind, status, after)
    written = []
    if html:
        from wamctl.report.index_page import write_index
        written = [write_index(Path(f)) for f in folders if Path(f).is_dir()]
    if json:
        emit_json({"runs": [e.to_json() for e in entries], "marked_abandoned": marked,
                   "written": [str(p) for p in written]})
        return
    width = console.width
    cells = []
    for e in entries:      # `running? (host X)`: the host goes to the figure's column, the status stays narrow
        status, fig = e.status, e.headline or "-"
        if status.startswith("running? ("):
            status, fig = "running?", status[len("running? "):] + ("" if fig == "-" else f" {fig}")
        cells.append([catalog.format_start(e.start_utc, short=True), catalog.KIND_LABELS.get(e.kind, e.kind),
                      e.name, status, catalog.format_duration(e.duration_s), e.backend, fig])
    heads = ["start (UTC)", "kind", "name", "status", "time", "bknd", "figure"]
    w = [max([len(h)] + [len(r[i]) for r in cells]) for i, h in enumerate(heads)]
    room = width - sum(w[:2]) - sum(w[3:6]) - 6          # one space between columns
    w[2] = max(min(w[2], 16), min(w[2], room - w[6]))    # the name gives way to the figure, down to 16
    w[6] = max(8, room - w[2])
    t = Table(box=None, pad_edge=False, show_edge=False, header_style="bold", padding=(0, 1, 0, 0))
    for i, h in enumerate(heads):
        t.add_column(h, no_wrap=True, overflow="ellipsis", width=w[i], justify="right" if i == 4 else "left")
    colour = {"completed": "green", "failed": "red", "abandoned": "red", "interrupted": "yellow"}
    for e, r in zip(entries, cells):
        t.add_row(*r[:3], Text(r[3], colour.get(e.status, "")), *r[4:])
    if entries:
        console.print(t)
    console.print(f"{len(entries)} run{'s' if len(entries) != 1 else ''}", highlight=False)
    for p in marked:
        console.print(f"marked interrupted ({catalog.ABANDONED_REASON}): {p}", highlight=False, soft_wrap=True)
    for p in written:
        console.print(f"wrote {p}", highlight=False, soft_wrap=True)


def compare(run_dirs: Annotated[list[Path], typer.Argument(help="Two or more run directories of one kind.",
                                                          show_default=False)],
            out: Annotated[Path | None, typer.Option("--out", help="Where to write compare.md/.html/.json and the "
                                                     "figures (default: compare/ beside the first run).")] = None,
            quiet: Annotated[bool, typer.Option("--quiet", "-q", help="No tables on the terminal.")] = False,
            json: JsonOpt = False):
    """Put runs of one kind side by side: spec differences, each table with the differences to the first run,
    figures overlaid (rotation error traces, friction maps), and a test of the difference with its 95 % interval
    where the runs have repeated measures (an HMI block's trials). Runs of different kinds are refused (exit 2).
    """
    from wamctl.report.compare import compare as compare_runs

    dest = out or Path(run_dirs[0]).parent / "compare"
    doc = compare_runs(run_dirs, dest)
    written = doc.write(dest, "compare")
    if not json:
        for skipped in doc.data["skipped"]:   # runs/* holds the index page and earlier comparisons
            console.print(f"skipped ({skipped['why']}): {skipped['path']}", highlight=False, soft_wrap=True)
    show_written_document(doc, written, json, quiet)


def register(app: typer.Typer) -> None:
    app.command()(runs)
    app.command()(compare)
