"""wamctl export / import (the measured-run format, docs/measured-run.md)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from wamctl.commands.common import console


def export_cmd(run_dir: Annotated[Path, typer.Argument(help="A run directory.", show_default=False)],
               to: Annotated[Path, typer.Option("--to", help="Directory to write meta.yaml and data to.",
                                                show_default=False)],
               csv: Annotated[bool, typer.Option("--csv", help="Write data.csv instead of data.parquet.")] = False):
    """Export a run in the measured-run format (wamctl-measured/1): meta.yaml + data.parquet (or data.csv)."""
    from wamctl.runs.measured import export_run
    p = export_run(run_dir, to, "csv" if csv else "parquet")
    console.print(f"exported {run_dir} -> {p}", highlight=False)


def import_cmd(measured_dir: Annotated[Path, typer.Argument(help="A measured-run directory (meta.yaml + data).",
                                                            show_default=False)],
               out: Annotated[Path, typer.Option("--out", help="Parent directory of the new run directory.")]
               = Path("runs"),
               name: Annotated[str, typer.Option("--name", help="Run name (default: the directory's name).")] = ""):
    """Validate a measured run and store it as a run directory, so `report`, `diagnose` and the other analyses
    take it like a simulated run. Errors name the key, column or row."""
    from wamctl.runs.measured import import_measured
    p = import_measured(measured_dir, out, name or None)
    console.print(f"imported {measured_dir} -> {p}", highlight=False)


def register(app: typer.Typer) -> None:
    app.command("export")(export_cmd)
    app.command("import")(import_cmd)
