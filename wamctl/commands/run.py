"""wamctl run / validate."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer
from rich.table import Table

from wamctl.cli import app
from wamctl.commands.common import console, emit_json, err_console, progress_bar
from wamctl.report.document import Document

SpecArg = Annotated[Path, typer.Argument(help="Experiment spec (YAML); its `kind` selects the experiment.",
                                         show_default=False)]
OutOpt = Annotated[Optional[Path], typer.Option("--out", help="Parent directory of the run directory "
                                                "(default: the spec's out_dir, normally runs/).")]
QuietOpt = Annotated[bool, typer.Option("--quiet", "-q", help="No progress bar and no tables.")]
JsonOpt = Annotated[bool, typer.Option("--json", help="Print a JSON summary on stdout (for scripts).")]


def print_document_tables(doc: Document) -> None:
    """The report's tables on the terminal."""
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
                   expect_kind: str | None = None, files=None) -> None:
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
    with progress_bar(f"{spec.kind} {spec.name}", enabled=not (quiet or as_json)) as progress:
        outcome = run_spec(spec, base, out, progress, make_report=False)
    show_outcome(outcome, quiet, as_json, files(outcome.path) if files else None)


def show_outcome(outcome, quiet: bool, as_json: bool, files: dict | None = None) -> None:
    """A finished run on the terminal: write its report, print its tables (or a JSON summary) and the status;
    exit code 1 unless it completed."""
    from wamctl.experiments.runner import write_report

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


@app.command()
def run(spec: SpecArg, out: OutOpt = None,
        dry_run: Annotated[bool, typer.Option("--dry-run", help="Print the plan and check every setpoint "
                                              "against the limits; move nothing.")] = False,
        quiet: QuietOpt = False, json: JsonOpt = False):
    """Run any experiment spec (rotation, friction_sweep, ift, hmi_block) into a new run directory, then report.

    The run directory (runs/<UTC time>-<name>/) holds the resolved spec, a manifest (seed, versions, git
    revision, backend, status), the data as Parquet and CSV, events, and the report. Exit code 0 when the run
    completed, 1 when it failed (safety limit, device), 2 for a bad spec, 130 when interrupted.
    """
    run_and_report(spec, out, dry_run, quiet, json)


@app.command()
def validate(spec: SpecArg,
             json: JsonOpt = False):
    """Check a spec without running it: schema, joint numbers, limits of every setpoint.

    Prints the resolved spec (every default filled in) on success; one line per problem and exit code 2
    otherwise.
    """
    import yaml

    from wamctl.experiments.runner import plan_only
    from wamctl.specs import load_spec, load_yaml

    raw = load_yaml(spec)
    if isinstance(raw, dict) and "vary" in raw:  # a sweep spec: every point (wamctl.sweep, issue 10)
        from wamctl.sweep import check_plans, load_sweep
        sw = load_sweep(spec)
        checks = check_plans(sw)
        if json:
            emit_json({"valid": True, "sweep": True, "kind": sw.kind, "points": len(sw.points),
                       "parameters": sw.parameters, "checks": checks})
        else:
            console.print(f"{spec}: valid sweep of {len(sw.points)} {sw.kind} points over "
                          f"{', '.join(sw.parameters)}; every point within the limits", highlight=False)
        return
    s = load_spec(spec)
    summary, checks = plan_only(s, spec.resolve().parent)
    if json:
        emit_json({"valid": True, "spec": s.model_dump(mode="json"), "checks": checks})
    else:
        console.print(yaml.safe_dump(s.model_dump(mode="json"), sort_keys=False), highlight=False)
        for c in checks:
            console.print(f"[green]ok[/] {c}")
        console.print(f"{spec}: valid {s.kind} spec")
