"""wamctl diagnose: find what the declared model lacks in a measured run, add it, and prove the fix
(the pipeline is :mod:`wamctl.experiments.diagnose`)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from wamctl.commands.common import console, emit_json

DataArg = Annotated[list[Path], typer.Argument(
    help="A measured-run directory (meta.yaml + data) or a run directory; several runs of one arm are diagnosed "
         "together (pooled).", show_default=False)]


def diagnose(data: DataArg,
             model: Annotated[Path | None, typer.Option(
                 "--model", help="Declared model: a friction file (wamctl-friction/1) or a model file "
                                 "(wamctl-model/1). Default: classic friction fitted from the data.")] = None,
             out: Annotated[Path, typer.Option("--out", help="Parent directory of the run directory.")]
             = Path("runs"),
             quiet: Annotated[bool, typer.Option("--quiet", "-q", help="No tables on the terminal.")] = False,
             json: Annotated[bool, typer.Option("--json", help="Print diagnosis.json on stdout.")] = False,
             jobs: Annotated[int | None, typer.Option(
                 "--jobs", min=1, metavar="<int>", help="Worker processes for the joints (the same diagnosis; 1: "
                                                        "none). Default: the CPUs available, on a long run.",
                 show_default=False)] = None):
    """Find what the declared model (rigid body + armature + classic friction) lacks in a measured run.

    The torque residual (inverse dynamics on Savitzky-Golay derivatives) is tested against one signature per
    effect (stribeck, position_ripple, payload, delay, friction_drift, backlash) with nested F-tests and BIC
    on held-out time blocks; kept effects are added and refitted, and both models are re-simulated in closed
    loop with the run's reference and controller. Writes a run directory with diagnosis.json, the augmented
    model (model.yaml, usable as `plant: model.yaml`) and a report. Exit code 2 for unusable data.

    Several runs of one arm (e.g. a run that could not tell and its next_experiment.yaml run) are pooled: each is
    diagnosed alone, then the payload, the link errors and each joint's effects are decided on all of them (shared
    coefficients, each run's own friction, gains and start state); the report says which run decided what. Runs
    of different arms are refused.
    """
    from wamctl.commands.common import print_document_tables, progress_bar
    from wamctl.experiments.diagnose import diagnose_to_run_dir

    if len(data) > 1:
        _pooled(data, model, out, quiet, json, jobs)
        return
    data = data[0]
    with progress_bar("diagnose", enabled=not (quiet or json)) as progress:
        path, result, doc = diagnose_to_run_dir(data, model, out, progress=progress, jobs=jobs)
    if json:
        emit_json(dict(result, run_dir=str(path)))
        return
    from wamctl.commands.common import print_warnings

    if not quiet:     # the summary and the effects (then the report's warnings); every candidate is in the report
        from wamctl.report.document import Document
        short = Document(doc.title, [b for b in doc.blocks if b[0] == "warn" or b[0] == "table" and b[1][0] in (
            "summary", "effects", "ambiguous", "unexplained")])
        print_document_tables(short)
    else:
        print_warnings(doc)
    from wamctl.report.diagnosis import (
        found_line,
        next_experiment_line,
        not_diagnosed,
        not_named_lines,
        position_span,
    )

    span = position_span(result)
    # which part of the run the position check covered; every joint not diagnosed, with why (also --quiet)
    for line in ([span] if span and not quiet else []) + not_diagnosed(result):
        console.print(line, highlight=False)
    if result.get("conclusive"):        # findings seen and not named, structured residuals: said, with why
        for line in not_named_lines(result) + [x for x in [next_experiment_line(result)] if x]:
            console.print(line, highlight=False)
    console.print(found_line(result), highlight=False)
    console.print(f"run directory: {path}", highlight=False, soft_wrap=True)     # alone and whole: to be copied


def _pooled(data: list[Path], model: Path | None, out: Path, quiet: bool, json: bool, jobs: int | None) -> None:
    """``wamctl diagnose RUN1 RUN2 ...``: the runs pooled."""
    from wamctl.commands.common import print_document_tables, print_warnings, progress_bar
    from wamctl.experiments.diagnose import diagnose_runs_to_run_dir
    from wamctl.report.diagnosis import found_line
    from wamctl.report.diagnosis_pooled import decided_lines

    with progress_bar("diagnose", enabled=not (quiet or json)) as progress:
        path, result, doc = diagnose_runs_to_run_dir(data, model, out, progress=progress, jobs=jobs)
    if json:
        emit_json(dict(result, run_dir=str(path)))
        return
    if not quiet:
        from wamctl.report.document import Document
        print_document_tables(Document(doc.title, [b for b in doc.blocks if b[0] == "warn" or b[0] == "table"
                                                   and b[1][0] in ("summary", "payload")]))
    else:
        print_warnings(doc)
    for line in decided_lines(result):
        console.print(line, highlight=False)
    console.print(found_line(result), highlight=False)
    console.print(f"run directory: {path}", highlight=False, soft_wrap=True)


def register(app: typer.Typer) -> None:
    app.command("diagnose")(diagnose)
