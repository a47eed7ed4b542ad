"""wamctl run / validate."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from wamctl.commands.common import JsonOpt, OutOpt, QuietOpt, SpecArg, YesOpt, console, emit_json, run_and_report

RESUMABLE = ("ift", "hmi_block")
"""The kinds whose runs continue where they stopped (``--resume``); a sweep resumes with ``wamctl sweep``."""


def run(spec: Annotated[Path | None, typer.Argument(
            help="Experiment spec (YAML); its `kind` selects the experiment. With --resume: optional for an "
                 "hmi_block run (its own spec is used), required for an ift run.", show_default=False)] = None,
        out: OutOpt = None,
        resume: Annotated[Path | None, typer.Option(
            "--resume", help="Continue an interrupted or abandoned run of a kind that can (ift, hmi_block) in "
                             "its own directory.", show_default=False)] = None,
        dry_run: Annotated[bool, typer.Option("--dry-run", help="Print the plan and check every setpoint "
                                              "against the limits; move nothing.")] = False,
        quiet: QuietOpt = False, json: JsonOpt = False, yes: YesOpt = False):
    """Run any experiment spec (rotation, friction_sweep, ift, hmi_block, excitation) into a new run directory,
    then report.

    The run directory (runs/<UTC time>-<name>/) holds the resolved spec, a manifest (seed, versions, git
    revision, backend, status), the data as Parquet and CSV, events, and the report. Exit code 0 when the run
    completed, 1 when it failed (safety limit, device), 2 for a bad spec, 130 when interrupted. --resume RUN_DIR
    continues an ift or hmi_block run (as tune-ift / hmi-session --resume do).
    """
    from wamctl.errors import SpecError

    if resume is None:
        if spec is None:
            raise SpecError("give a spec (SPEC.yaml) or --resume RUN_DIR")
        run_and_report(spec, out, dry_run, quiet, json, yes=yes)
        return
    from wamctl.runs.catalog import read_json

    kind = read_json(resume / "manifest.json").get("kind")
    if kind is None:
        raise SpecError(f"{resume}: --resume needs a run directory (no readable manifest.json there)")
    if kind not in RESUMABLE:
        hint = "`wamctl sweep --resume SWEEP_DIR` for a sweep; " if kind == "sweep" else ""
        raise SpecError(f"{resume}: a {kind} run cannot be resumed ({hint}resumable: {', '.join(RESUMABLE)}); "
                        f"run its spec again")
    if kind == "ift":
        if spec is None:
            raise SpecError(f"{resume}: an ift run resumes with its spec: wamctl run SPEC.yaml --resume {resume}")
        from wamctl.commands.ift import tune_ift
        tune_ift(spec, out, resume=resume, dry_run=dry_run, quiet=quiet, json=json, yes=yes)
    else:
        from wamctl.commands.hmi import hmi_session
        hmi_session(spec, out, resume=resume, dry_run=dry_run, quiet=quiet, json=json, yes=yes)


def validate(spec: SpecArg,
             json: JsonOpt = False):
    """Check a spec without running it: schema, joint numbers, limits of every setpoint.

    Prints the resolved spec (every default filled in) on success; one line per problem and exit code 2
    otherwise.
    """
    import yaml

    from wamctl.experiments.runner import plan_only
    from wamctl.io import load_yaml
    from wamctl.specs import load_spec

    raw = load_yaml(spec)
    if isinstance(raw, dict) and "vary" in raw:  # a sweep spec: every point (wamctl.experiments.sweep, issue 10)
        from wamctl.experiments.sweep.run import check_plans
        from wamctl.specs.sweep import load_sweep
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
        console.print(_gains_said(yaml.safe_dump(s.model_dump(mode="json"), sort_keys=False), s.controller),
                      highlight=False)
        for c in checks:
            console.print(f"[green]ok[/] {c}")
        console.print(f"{spec}: valid {s.kind} spec")


def _gains_said(text: str, controller) -> str:
    """The resolved spec's text with each gain left unset (``kp: null``) followed by the gains it stands for."""
    kp, kd, ki = controller.gains()
    said = {"kp": f"libbarrett's: {kp.tolist()}", "kd": f"libbarrett's: {kd.tolist()}",
            "ki": f"libbarrett's: {ki.tolist()}" if controller.kind == "pid" else f"not used by {controller.kind}"}
    out, block = [], None
    for line in text.splitlines():
        if line and not line.startswith(" "):
            block = line.split(":")[0]
        key = line.strip().split(":")[0]
        if block == "controller" and line.startswith("  ") and line.strip().endswith(": null") and key in said:
            line = f"{line}  # {said[key]}"
        out.append(line)
    return "\n".join(out)


def register(app: typer.Typer) -> None:
    app.command()(run)
    app.command()(validate)
