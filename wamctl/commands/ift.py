"""wamctl tune-ift: iterative feedback tuning of the joint PIDs (thesis chapter 5)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from wamctl.commands.common import (
    JsonOpt,
    OutOpt,
    QuietOpt,
    YesOpt,
    progress_bar,
    run_and_report,
    show_outcome,
)

IftSpecArg = Annotated[Path, typer.Argument(help="An IFT spec (YAML, kind: ift; e.g. configs/ift.yaml).",
                                            show_default=False)]


def tune_ift(spec: IftSpecArg, out: OutOpt = None,
             resume: Annotated[Path | None, typer.Option(
                 "--resume", help="Continue the tuning in this run directory from its last completed iteration "
                                  "(same spec; only ift.plant.runs may grow).", show_default=False)] = None,
             dry_run: Annotated[bool, typer.Option("--dry-run", help="Print the plan and check the limits; move "
                                                   "nothing.")] = False,
             quiet: QuietOpt = False, json: JsonOpt = False, yes: YesOpt = False):
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
        run_and_report(spec, out, dry_run, quiet, json, expect_kind="ift", yes=yes)
        return
    from wamctl.errors import SpecError
    from wamctl.experiments import ift
    from wamctl.specs import load_spec

    s = load_spec(spec)
    if s.kind != "ift":
        raise SpecError(f"{spec}: kind: this command runs `ift` specs, not `{s.kind}`")
    if dry_run:
        raise SpecError("--dry-run and --resume exclude each other")
    from wamctl.runs.catalog import ready_to_resume
    ready_to_resume(resume)             # a live run refused; an abandoned one recorded first, its samples kept
    from wamctl.backends.can.operator import use_operator
    from wamctl.commands.terminal_operator import TerminalOperator

    label = f"ift {s.name} (resumed)"
    with progress_bar(label, enabled=not (quiet or json)) as progress, \
            use_operator(TerminalOperator(yes=yes, progress=progress, label=label)):  # a CAN arm's questions
        outcome = ift.resume(resume, s, spec.resolve().parent, progress)
    show_outcome(outcome, quiet, json)


def register(app: typer.Typer) -> None:
    app.command("tune-ift")(tune_ift)
