"""wamctl hmi-session: a block of gaze-controlled reach-and-grasp trials (thesis chapter 6, issue 7)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from wamctl.commands.common import (
    JsonOpt,
    OutOpt,
    QuietOpt,
    YesOpt,
    console,
    progress_bar,
    run_and_report,
    show_outcome,
)


def _console_prompt(message: str) -> None:
    """The supervisor's start: a line on the terminal, answered with Enter."""
    console.input(f"[bold]{message}[/] ")


def hmi_session(
        spec: Annotated[Path | None, typer.Argument(
            help="hmi_block spec (YAML). Optional with --resume (the run's own spec is used).",
            show_default=False)] = None,
        out: OutOpt = None,
        resume: Annotated[Path | None, typer.Option(
            "--resume", help="Continue the block in this run directory at its next trial.",
            show_default=False)] = None,
        dry_run: Annotated[bool, typer.Option("--dry-run", help="Print the plan (start pose, spots, trials) and "
                                              "check it; move nothing.")] = False,
        quiet: QuietOpt = False, json: JsonOpt = False, yes: YesOpt = False):
    """Run a block of gaze-controlled reach-and-grasp trials (kind hmi_block) and report hits and times.

    The gaze (a virtual subject by default, a recorded gaze file, or a live tracker on a serial port or any
    pyserial URL) steers the hand palm down over the table; a voluntary blink closes the hand; three voluntary
    blinks in a row end the session and send the arm home. Each trial is a hit when the hand closes within the hit
    radius of the object before the time-out; its execution time runs to the grasp. The run directory holds
    trials.csv (one row per trial), hmi_events.csv, the hand trajectory and the report (per-location table as
    thesis Tables 6.2-6.4). Exit code 0 when completed, 1 when failed, 2 for a bad spec, 130 when interrupted
    (continue with --resume RUN_DIR).
    """
    from wamctl.errors import SpecError
    from wamctl.experiments import hmi_block
    from wamctl.specs import load_spec

    if not (quiet or json):
        hmi_block.set_supervisor_prompt(_console_prompt)
    if resume is None:
        if spec is None:
            raise SpecError("give a spec (SPEC.yaml) or --resume RUN_DIR")
        run_and_report(spec, out, dry_run, quiet, json, expect_kind="hmi_block", yes=yes)
        return
    if dry_run:
        raise SpecError("--dry-run and --resume exclude each other")
    s = None
    if spec is not None:
        s = load_spec(spec)
        if s.kind != "hmi_block":
            raise SpecError(f"{spec}: kind: this command runs `hmi_block` specs, not `{s.kind}`")
    from wamctl.backends.can.operator import use_operator
    from wamctl.commands.terminal_operator import TerminalOperator
    from wamctl.runs.catalog import ready_to_resume

    ready_to_resume(resume)             # a live run refused; an abandoned one recorded first, its samples kept

    label = f"hmi_block {resume.name} (resumed)"
    with progress_bar(label, enabled=not (quiet or json)) as progress, \
            use_operator(TerminalOperator(yes=yes, progress=progress, label=label)):  # a CAN arm's questions
        outcome = hmi_block.resume(resume, s, progress)
    show_outcome(outcome, quiet, json)


def register(app: typer.Typer) -> None:
    app.command("hmi-session")(hmi_session)
