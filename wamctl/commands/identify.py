"""wamctl excite / identify: design an exciting trajectory, and identify the arm's own inertial parameters from
measured runs (the pipelines are :mod:`wamctl.experiments.excitation` and :mod:`wamctl.experiments.identify`)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from wamctl.commands.common import JsonOpt, QuietOpt, console, emit_json

REJECTED_EXIT_CODE = 3      # identify: the held-out check did not pass; the model is not written as model.yaml


def excite(spec: Annotated[Path, typer.Argument(help="An excitation spec (YAML, kind: excitation).",
                                                show_default=False)],
           out: Annotated[Path | None, typer.Option("--out", help="Parent folder of the new <time>-<name>-design "
                                                    "folder with the designed spec and its report (default: the "
                                                    "spec's out_dir, runs/).",
                                                    show_default=False)] = None,
           payload_schedule: Annotated[bool, typer.Option(
               "--payload-schedule", help="Also write the payload schedule: four specs of the one trajectory "
                                          "to run loaded, bare, bare, loaded (ABBA) for `wamctl identify "
                                          "--payload`; a spec with coefficients is not redesigned.")] = False,
           quiet: QuietOpt = False, json: JsonOpt = False):
    """Design an exciting trajectory for `wamctl identify` (finite Fourier series per joint).

    Minimises a criterion of the base regressor (d_optimal or condition, the spec's excitation.design) under the
    limits over the whole trajectory: joint range with margin, speed, acceleration, the declared model's torque
    with margin, and the wrist's speed. Writes excitation.yaml (the spec with its coefficients: run it with
    `wamctl run`), design.json and a report of the condition number and the limits reached.
    """
    from wamctl.commands.common import print_document_tables, progress_bar
    from wamctl.experiments.excitation import excite as run_excite
    from wamctl.experiments.excitation import limits_summary

    if payload_schedule:
        from wamctl.experiments.identify import payload_schedule as write_schedule

        folder, specs = write_schedule(spec, out)
        if json:
            emit_json({"out": str(folder), "schedule": [str(p) for p in specs]})
            return
        console.print("payload schedule (run in this order):\n" + "\n".join(f"  {p}" for p in specs)
                      + f"\nthen: wamctl identify --payload --loaded RUN1 --loaded RUN4 --bare RUN2 --bare RUN3"
                      f"\n({folder / 'schedule.md'})", highlight=False, soft_wrap=True)
        return
    with progress_bar("excitation design", enabled=not (quiet or json)) as progress:
        path, design, use = run_excite(spec, out, progress)
    import json as json_module

    outlook = json_module.loads((path / "design.json").read_text())["instruments_outlook"]
    if json:
        emit_json({"out": str(path), "spec": str(path / "excitation.yaml"), "condition_number":
                   design.condition_number, "criterion": design.criterion, "limits_used": {
                       k: (v.tolist() if hasattr(v, "tolist") else v) for k, v in use.used.items()},
                   "instruments_outlook": outlook,
                   "world": json_module.loads((path / "design.json").read_text())["world"]})
        return
    if not quiet:
        from wamctl.report.document import Document
        from wamctl.report.excitation import limits_table

        shares = limits_table(use)[[c for c in limits_table(use).columns if c.endswith("_used_pct")]]
        print_document_tables(Document("Excitation design").table("limits used (%)", shares.rename(
            columns=lambda c: c.removesuffix("_used_pct")), digits=1))
    console.print(outlook["statement"], highlight=False)
    if design.clearance is not None:
        console.print("world: " + design.clearance.statement(), highlight=False)
    console.print(f"condition number {design.condition_number:.4g} ({design.criterion}, {design.n_target} base "
                  f"parameters); limits used: {limits_summary(use)}\ndesigned spec: {path / 'excitation.yaml'} "
                  f"(run it with `wamctl run`)  report: {path / 'report.md'}", highlight=False)


def identify(data: Annotated[list[Path] | None, typer.Argument(help="Measured runs (measured-run directories or "
                                                                "run directories), any sample rate.",
                                                                show_default=False)] = None,
             validate: Annotated[list[Path] | None, typer.Option(
                 "--validate", metavar="<path>",
                 help="Held-out runs (best: another trajectory); repeat the option. Default: the "
                      "last quarter of each run is held out.", show_default=False)] = None,
             model: Annotated[Path | None, typer.Option(
                 "--model", help="Declared arm: a model file (links, friction) or a friction file. Default: "
                                 "the datasheet and Table 4.1.", show_default=False)] = None,
             out: Annotated[Path, typer.Option("--out", help="Parent directory of the run directory.")]
             = Path("runs"),
             force: Annotated[bool, typer.Option("--force", help="Write model.yaml even when the held-out check "
                                                 "finds the model worse than the declared arm (or cannot check "
                                                 "it); the verdict is still reported.")] = False,
             payload: Annotated[bool, typer.Option("--payload", help="Identify a payload at the wrist from one "
                                                   "trajectory run loaded (--loaded) and bare (--bare), best in "
                                                   "the order of `wamctl excite SPEC --payload-schedule`; writes "
                                                   "payload.yaml (docs/payload.md).")] = False,
             loaded: Annotated[list[Path] | None, typer.Option("--loaded", metavar="<path>",
                                                               help="--payload: a run with the "
                                                                    "payload; repeat the option.",
                                                               show_default=False)] = None,
             bare: Annotated[list[Path] | None, typer.Option("--bare", metavar="<path>",
                                                             help="--payload: a run without it; "
                                                                  "repeat the option.", show_default=False)] = None,
             static: Annotated[bool, typer.Option("--static", help="--payload from held poses (the reference at "
                                                  "rest >= 1 s): mass and centre of mass only.")] = False,
             quiet: QuietOpt = False, json: JsonOpt = False):
    """Identify the arm's own inertial parameters (base parameters, armature and friction) from measured runs.

    Rigid body from pinocchio's regressor, numerical base parameters, instrumental variables on the reference
    (the closed loop's noise would bias least squares), per-joint weights, HAC intervals, a physically consistent
    estimate (every link's pseudo-inertia positive definite, an SDP), validated on held-out data against the
    nominal model. What the data cannot determine is named, not printed. Writes a run directory with model.yaml
    (usable as plant:, controller.declared_links:, diagnose --model), identification.json, parameters.csv and a
    report. The runs name their arm (robot: wam7 or wam4, all the same); a wam4's model.yaml says robot: wam4 and
    no URDF is written for it. Runs whose torque is the controller's output (torque: controller, gravity not
    logged) use only the joints whose gravity torque is constant; the others are named with the reason.

    Held-out check: the identified model must predict held-out torque (the --validate runs, else the last quarter
    of each run) at least as well as the declared arm with friction fitted on the same data, on every joint that
    moves, or be above it by less than the fit's uncertainty and the held-out data can tell (Diebold-Mariano,
    one-sided, 5 %; said with the ratio and p); better only where some joint is significantly better. If it is
    significantly worse (or cannot be checked), the model is written as model_rejected.yaml, not model.yaml
    (unless --force), and the command exits with code 3. Exit code 2 for unusable data.

    With --payload: a payload at the wrist from one trajectory run loaded (--loaded) and bare (--bare), best in
    the ABBA order of `wamctl excite SPEC --payload-schedule`: mass, centre of mass and the inertia the trajectory
    excites (the rest named not identified), 95 % HAC intervals, payload.yaml for plant.effects.payload,
    controller.declared_payload and --model (docs/payload.md); --static from held poses (mass, centre of mass).
    """
    from wamctl.commands.common import print_document_tables, progress_bar
    from wamctl.experiments.identify import identify_to_run_dir

    if payload or loaded or bare or static:
        _identify_payload(data, loaded, bare, model, out, static, quiet, json)
        return
    if not data:
        raise typer.BadParameter("give measured runs (or --payload --loaded RUN --bare RUN)", param_hint="DATA")
    with progress_bar("identify", enabled=not (quiet or json)) as progress:
        path, result, doc = identify_to_run_dir(data, validate, model, out, progress=progress, force=force)
    check = result["held_out_check"]
    code = 0 if check["model_written"] else REJECTED_EXIT_CODE
    if json:
        emit_json({"run_dir": str(path), "model": str(path / "model.yaml") if check["model_written"] else None,
                   "model_file": str(path / result["model_file"]), "held_out_check": check,
                   "instruments": result["instruments"], "instruments_detail": result["instruments_detail"],
                   "consistent": result["consistent"], "identifiability": result["identifiability"],
                   "validation": result["validation"]})
        raise typer.Exit(code)
    if not quiet:
        from wamctl.report.document import Document

        short = Document(doc.title, [b for b in doc.blocks if b[0] == "table" and b[1][0] == "validation"])
        print_document_tables(short)
    ident = result["identifiability"]
    und = ident["undetermined"]
    console.print(f"rank {ident['rank']} of {ident['n_base']} base parameters"
                  + (f"; not identified: {', '.join(und)}" if und else "")
                  + f"; physically consistent: {'yes' if result['consistent'] else 'no'}\n"
                  f"instruments: {result['instruments']}", highlight=False)
    style = {"better": None, "no_worse": "yellow"}.get(check["verdict"], "bold red")
    console.print(check["statement"], style=style, highlight=False)
    if check["model_written"]:
        console.print(("model (written because of --force): " if check["forced"] else "model: ")
                      + f"{path / 'model.yaml'}\nrun directory: {path}", highlight=False, soft_wrap=True)
    else:
        console.print(f"model NOT written as model.yaml (kept as {path / result['model_file']}; --force writes it)"
                      f"\nrun directory: {path}", highlight=False, soft_wrap=True)
    raise typer.Exit(code)


def _identify_payload(data, loaded, bare, model, out, static, quiet, json):
    """``identify --payload``: see :func:`wamctl.experiments.identify.identify_payload_to_run_dir`."""
    from wamctl.commands.common import print_document_tables
    from wamctl.errors import SpecError
    from wamctl.experiments.identify import identify_payload_to_run_dir

    if data:
        raise SpecError("identify --payload takes its runs as --loaded RUN and --bare RUN, not as arguments")
    if not loaded or not bare:
        raise SpecError("identify --payload: give at least one --loaded RUN and one --bare RUN")
    path, result, doc = identify_payload_to_run_dir(list(loaded), list(bare), model, out, static=static)
    if json:
        emit_json({"run_dir": str(path), "payload_file": str(path / "payload.yaml"),
                   **{k: result[k] for k in ("method", "mass_kg", "mass_ci95_kg", "com_m", "com_ci95_m",
                                             "inertia_about_com_kg_m2", "inertia_ci95_kg_m2", "not_identified",
                                             "order")}})
        return
    if not quiet:
        print_document_tables(doc)
    und = result["not_identified"]
    console.print(f"{result['order']}\nnot identified: {', '.join(und) if und else 'none'}\npayload file: "
                  f"{path / 'payload.yaml'}\nrun directory: {path}", highlight=False, soft_wrap=True)


def register(app: typer.Typer) -> None:
    app.command("excite")(excite)
    app.command("identify")(identify)
