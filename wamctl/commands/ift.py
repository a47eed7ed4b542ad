"""wamctl tune-ift: iterative feedback tuning of the joint PIDs (thesis chapter 5)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer

from wamctl.cli import app
from wamctl.commands.common import console, emit_json, err_console, progress_bar
from wamctl.commands.run import JsonOpt, OutOpt, QuietOpt, SpecArg, print_document_tables, run_and_report


@app.command("tune-ift")
def tune_ift(spec: SpecArg, out: OutOpt = None,
             resume: Annotated[Optional[Path], typer.Option(
                 "--resume", help="Continue the tuning in this run directory from its last completed iteration "
                                  "(same spec; only ift.plant.runs may grow).", show_default=False)] = None,
             dry_run: Annotated[bool, typer.Option("--dry-run", help="Print the plan and check the limits; move "
                                                   "nothing.")] = False,
             quiet: QuietOpt = False, json: JsonOpt = False):
    """Tune each joint's PID gains [Kp, Kd, Ki] by iterative feedback tuning (IFT, thesis chapter 5).

    Per iteration and joint: the first experiment on the plant (the simulated arm, the CAN arm, or recorded
    measured runs) gives J = 1/(2N) sum e^2; the second, on the model, gives the gradient; BFGS or Gauss-Newton
    gives the step. Every proposal is simulated on the model before it reaches the plant. Then the task is run under
    PD + gravity, PD + gravity + feed-forward friction and the tuned PID (thesis section 5.4). The run directory
    holds every experiment (iter-NNN-exp1/exp2.parquet), iterations.csv (Table 5.1), tuned_gains.yaml and the
    report. Exit code 0 when completed, 1 when failed, 2 for a bad spec, 130 when interrupted (resume with
    --resume RUN_DIR).
    """
    if resume is None:
        run_and_report(spec, out, dry_run, quiet, json, expect_kind="ift")
        return
    from wamctl.errors import SpecError
    from wamctl.experiments import ift
    from wamctl.experiments.runner import write_report
    from wamctl.specs import load_spec

    s = load_spec(spec)
    if s.kind != "ift":
        raise SpecError(f"{spec}: kind: this command runs `ift` specs, not `{s.kind}`")
    if dry_run:
        raise SpecError("--dry-run and --resume exclude each other")
    with progress_bar(f"ift {s.name} (resumed)", enabled=not (quiet or json)) as progress:
        outcome = ift.resume(resume, s, spec.resolve().parent, progress)
    doc = write_report(outcome.path) if outcome.status == "completed" else None
    if json:
        emit_json({"run_dir": str(outcome.path), "status": outcome.status, "reason": outcome.reason,
                   "report": doc.to_json() if doc else None})
        return
    if doc is not None and not quiet:
        print_document_tables(doc)
    colour = "green" if outcome.status == "completed" else "red"
    msg = f"[{colour}]{outcome.status}[/]" + (f": {outcome.reason}" if outcome.reason else "")
    (console if outcome.status == "completed" else err_console).print(f"{msg}  run directory: {outcome.path}",
                                                                      highlight=False)
    if outcome.status != "completed":
        raise typer.Exit(1)
