"""wamctl report."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from wamctl.commands.common import console, emit_json, status_line


def report(run_dirs: Annotated[list[Path] | None, typer.Argument(help="One or more run directories.",
                                                                    show_default=False)] = None,
           hmi_results: Annotated[list[Path] | None, typer.Option(
               "--hmi-results", metavar="<path>",
               help="An HMI results CSV (raw trials: subject,condition,location,attempt,hit,time_s; "
                    "or per-unit summaries); repeatable. Reported with ANOVA tables beside the runs.")] = None,
           out: Annotated[Path | None, typer.Option("--out", help="Write the report(s) here instead of "
                                                       "into each run directory.")] = None,
           format: Annotated[str, typer.Option("--format", help="Comma-separated: md, html, json.")] = "md,html,json",
           quiet: Annotated[bool, typer.Option("--quiet", "-q", help="No tables on the terminal.")] = False,
           json: Annotated[bool, typer.Option("--json", help="Print the report data as JSON on stdout.")] = False):
    """Analyse run directories and write their reports (tables, figures; Markdown, HTML, JSON).

    Each run is recognised by the kind in its manifest (rotation, friction_sweep, ift, diagnosis, hmi_block,
    or an imported measured run). With several runs, a combined report is written too. HMI results files
    (--hmi-results) get per-unit tables (mean, SD, SEM), the one-way ANOVA table, and for per-subject data the
    repeated-measures ANOVA with Mauchly's test, Greenhouse-Geisser correction and Holm-corrected pairs.
    """
    from wamctl.commands.common import print_document_tables
    from wamctl.errors import WamctlError
    from wamctl.report.combined import Reported, report_runs

    formats = tuple(f.strip() for f in format.split(",") if f.strip())
    bad = [f for f in formats if f not in ("md", "html", "json")]
    if bad:
        raise WamctlError(f"--format: unknown format(s) {', '.join(bad)}; choose from md, html, json")
    if not run_dirs and not hmi_results:
        raise WamctlError("nothing to report: give run directories and/or --hmi-results FILE.csv")
    done = report_runs(run_dirs, out, formats) if run_dirs else Reported()
    from wamctl.runs.catalog import shown_status  # a `running` run whose process is gone: abandoned
    done.runs = [(p, {**m, "status": shown_status(m)}) for p, m in done.runs]
    docs, written = done.docs, done.written
    for csv in hmi_results or []:
        from wamctl.report.hmi_stats import hmi_results_report
        dest = Path(out or csv.parent)
        doc = hmi_results_report(csv, dest)
        docs.append(doc)
        written += doc.write(dest, f"{csv.stem}_report", formats)
    if json:
        emit_json({"reports": [d.to_json() for d in docs], "written": [str(p) for p in written],
                   "runs": [{"run_dir": str(p), "status": m.get("status"), "reason": m.get("reason")}
                            for p, m in done.runs],
                   "skipped": [{"path": str(p), "why": why} for p, why in done.skipped]})
        return
    for p, why in done.skipped:
        console.print(f"skipped ({why}): {p}", highlight=False, soft_wrap=True)   # the path last, whole
    ended = [(p, m) for p, m in done.runs if m.get("status") != "completed"]
    for p, m in ended:     # first: a report of a run that did not complete reads as one that did
        console.print(status_line(m.get("status"), m.get("reason"), p), highlight=False, soft_wrap=True)
    if not quiet:
        for d in docs:
            print_document_tables(d)
    for p in written:
        console.print(f"wrote {p}", highlight=False, soft_wrap=True)


def register(app: typer.Typer) -> None:
    app.command()(report)
