"""wamctl sweep: one spec with a ``vary:`` section, many runs, on a Dask cluster."""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Annotated

import typer

from wamctl.commands.common import console, emit_json, err_console, print_frame, progress_bar


def sweep(
    spec: Annotated[Path | None, typer.Argument(
        help="Spec (YAML) of any kind with a `vary:` section (grid / zip / points over dotted paths). "
             "Optional with --resume (the sweep directory keeps its spec).", show_default=False)] = None,
    out: Annotated[Path | None, typer.Option(
        "--out", help="Parent directory of the sweep directory (default: the spec's out_dir, normally runs/).")]
    = None,
    scheduler: Annotated[str | None, typer.Option(
        "--scheduler", help="Address of a running Dask scheduler (tcp://host:8786); default: a local cluster. "
                            "The sweep directory must be on a file system the workers share.")] = None,
    tls_ca: Annotated[Path | None, typer.Option(
        "--tls-ca", help="With a tls:// scheduler: the CA certificate (PEM) that signed the scheduler's; without "
                         "the three --tls-* options Dask's own TLS configuration is used.")] = None,
    tls_cert: Annotated[Path | None, typer.Option(
        "--tls-cert", help="With a tls:// scheduler: this client's certificate (PEM).")] = None,
    tls_key: Annotated[Path | None, typer.Option(
        "--tls-key", help="With a tls:// scheduler: this client's private key (PEM).")] = None,
    workers: Annotated[int | None, typer.Option(
        "--workers", min=1, metavar="<int>",
        help="Worker processes of the local cluster (default: one per core).")] = None,
    resume: Annotated[Path | None, typer.Option(
        "--resume", help="Finish an interrupted sweep directory: its completed points are skipped.")] = None,
    dry_run: Annotated[bool, typer.Option(
        "--dry-run", help="Validate every point and list them; run nothing.")] = False,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="No progress bar and no tables.")] = False,
    json: Annotated[bool, typer.Option("--json", help="Print a JSON summary on stdout (for scripts).")] = False,
):
    """Run every point of a sweep as an ordinary run directory, on Dask, and index them in a sweep directory.

    The sweep directory (runs/<UTC time>-<name>-sweep/) holds the spec, a manifest, index.csv/json (point,
    parameter values, status, run directory, error, key figures) and a combined report; the runs are under
    runs/<point>/. A failed point is recorded with its error and the others go on. Ctrl-C writes the index;
    --resume DIR then runs only the points not completed. Exit code 0 when every point completed, 1 when some
    failed, 2 for a bad spec, 130 when interrupted.
    """
    from wamctl.experiments.sweep.cluster import import_distributed, tls_security
    from wamctl.experiments.sweep.index import sweep_to_run
    from wamctl.experiments.sweep.run import run_sweep

    sw = sweep_to_run(spec, resume)
    if dry_run:
        from wamctl.experiments.sweep.run import check_plans
        _dry_run(sw, check_plans(sw), json)
        return
    security = tls_security(scheduler, tls_ca, tls_cert, tls_key)
    if not logging.getLogger().isEnabledFor(logging.INFO):  # without --verbose: only dask's errors
        import_distributed()  # it configures its loggers on import
        logging.getLogger("distributed").setLevel(logging.ERROR)
    show = not (quiet or json)
    failures: list[dict] = []

    def on_point(row: dict) -> None:
        if row["status"] == "failed" and show:
            failures.append(row)
            err_console.print(f"[red]failed[/] {row['point']}: {row.get('error')}", highlight=False)

    with progress_bar(f"sweep {sw.name}", enabled=show) as progress:
        result = run_sweep(sw, out, resume_dir=resume, scheduler=scheduler, n_workers=workers, security=security,
                           progress=progress, on_point=on_point)
    _show_result(sw, result, quiet, json)
    if not result.ok:
        raise typer.Exit(1)


def _show_result(sw, result, quiet: bool, json: bool) -> None:
    if json:
        emit_json({"sweep_dir": str(result.sweep_dir), "counts": result.counts, "points": len(sw.points),
                   "ran": result.ran, "skipped": result.skipped, "wall_s": result.wall_s,
                   "n_workers": result.n_workers, "max_concurrent": result.max_concurrent,
                   "efficiency": result.efficiency, "report": [str(p) for p in result.report]})
    elif not quiet:
        import pandas as pd

        eff = f"{100 * result.efficiency:.0f} %" if result.efficiency is not None else "-"
        row = {"completed": result.counts["completed"], "failed": result.counts["failed"], "ran now": result.ran,
               "skipped": result.skipped, "workers": result.n_workers, "at once": result.max_concurrent,
               "wall (s)": round(result.wall_s, 1), "busy": eff}
        print_frame(f"sweep {sw.name}: {len(sw.points)} points", pd.DataFrame([row]))
        _show_summary(sw, result.sweep_dir)
    if not json:
        colour = "green" if result.ok else "red"
        report = [p for p in result.report if Path(p).suffix == ".html"]
        (console if result.ok else err_console).print(
            f"[{colour}]{'completed' if result.ok else 'some points failed'}[/]  sweep directory: "
            f"{result.sweep_dir}" + (f"\nreport: {report[0]}" if report else ""), highlight=False, soft_wrap=True)


def _show_summary(sw, sweep_dir: Path) -> None:
    """The result of the sweep (the tables its report shows first): the key figures over the completed points
    and their means per value of each swept parameter."""
    from wamctl.report.sweep import read_index, summary_tables, sweep_parameters

    idx = read_index(sweep_dir)
    _, params = sweep_parameters(sweep_dir, idx)
    tables = summary_tables(idx, params)
    for _, heading, table, caption in tables:
        print_frame(f"sweep {sw.name}: {heading}", table, caption)
    if not tables:
        console.print("no key figures: no point completed with a report", highlight=False)


def _dry_run(sw, checks: list[str], as_json: bool) -> None:
    if as_json:
        emit_json({"spec": sw.source, "kind": sw.kind, "name": sw.name, "parameters": sw.parameters,
                   "checks": checks, "points": [{"point": p.point_id, **p.values} for p in sw.points]})
        return
    import json as _json

    import pandas as pd

    def cell(v):
        return _json.dumps(v) if isinstance(v, (list, dict)) else v
    rows = [{"point": p.point_id, **{k: cell(p.values.get(k)) for k in sw.parameters}} for p in sw.points[:50]]
    print_frame(f"sweep {sw.name}: {len(sw.points)} points of {sw.kind}",
                pd.DataFrame(rows, columns=["point", *sw.parameters]), key="point")
    if len(sw.points) > 50:
        console.print(f"... {len(sw.points) - 50} more points")
    console.print(f"[green]ok[/] every point planned; first point: {'; '.join(checks)}", highlight=False)
    console.print(f"{sw.source}: {len(sw.points)} valid points; dry run: nothing run")


def register(app: typer.Typer) -> None:
    app.command()(sweep)
