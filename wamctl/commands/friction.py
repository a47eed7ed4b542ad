"""wamctl friction-id: run a friction sweep and identify, or identify from a recorded sweep."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from wamctl.commands.common import YesOpt, console, emit_json, show_written_document


def friction_id(
    spec: Annotated[Path | None, typer.Argument(help="A friction_sweep spec (YAML).", show_default=False)] = None,
    data: Annotated[Path | None, typer.Option("--data", help="Analyse a recorded sweep instead: a measured-run "
                                                 "directory (meta.yaml + data) or a run directory.",
                                                 show_default=False)] = None,
    out: Annotated[Path | None, typer.Option("--out", help="Parent directory of the new directory written (a "
                                                "run directory with a spec or --data, a comparison folder with "
                                                "--compare); default: the spec's out_dir, else runs/.",
                                                show_default=False)] = None,
    compare: Annotated[list[Path] | None, typer.Option("--compare", metavar="<path>",
                                                       help="Compare two rotation runs, pd_g "
                                                            "then pd_g_ff (give the option twice); writes "
                                                            "<out>/<UTC time>-ff-comparison/.",
                                                          show_default=False)] = None,
    loss: Annotated[str | None, typer.Option("--loss", help="With --data: least-squares loss, linear (default), "
                                                "soft_l1, huber or cauchy (robust to outlying segments).",
                                                show_default=False)] = None,
    criterion: Annotated[str | None, typer.Option("--criterion", help="With --data: bic (default) or aic for "
                                                     "the held-out model selection.", show_default=False)] = None,
    model: Annotated[Path | None, typer.Option("--model", help="With --data: a model file whose links (e.g. from "
                                                "`wamctl identify`) replace the datasheet's rigid body.",
                                                show_default=False)] = None,
    dry_run: Annotated[bool, typer.Option("--dry-run", help="Print the sweep plan and check every setpoint "
                                          "against the limits; move nothing.")] = False,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="No progress bar and no tables.")] = False,
    json: Annotated[bool, typer.Option("--json", help="Print a JSON summary on stdout (for scripts).")] = False,
    yes: YesOpt = False,
):
    """Identify joint friction (thesis ch. 4): constant-velocity sweeps in both directions, the friction-velocity
    map, fitted classic / symmetric / Stribeck models chosen by a held-out information criterion.

    Writes friction_model.yaml (usable as controller.friction_ff, plant.friction, or a declared model), the
    map (friction_map.csv), identification.json and the report (Table 4.1 layout, maps, selection) into a new
    run directory under --out, from a spec as from --data: --out is always the parent folder.
    Exit code 0 on success, 1 when the run failed, 2 for a bad spec or data file, 130 when interrupted.
    """
    from wamctl.errors import SpecError

    given = [x for x in (spec, data, compare) if x]
    if len(given) != 1:
        raise SpecError("friction-id: give exactly one of SPEC.yaml, --data MEASURED_RUN, or --compare PD FF")
    if compare:
        return _compare(compare, out, quiet, json)
    if data is not None:
        options = {}
        if loss is not None:
            if loss not in ("linear", "soft_l1", "huber", "cauchy"):
                raise SpecError(f"--loss: {loss!r}; choose linear, soft_l1, huber or cauchy")
            options["loss"] = loss
        if criterion is not None:
            if criterion not in ("bic", "aic"):
                raise SpecError(f"--criterion: {criterion!r}; choose bic or aic")
            options["criterion"] = criterion
        return _from_data(data, out, quiet, json, options, model)
    if model is not None:
        raise SpecError("--model goes with --data; a spec declares its arm in controller.declared_links")
    if loss is not None or criterion is not None:
        raise SpecError("--loss/--criterion go with --data; a spec sets them in its identification: section")
    return _from_spec(spec, out, dry_run, quiet, json, yes)


def _from_spec(spec_path: Path, out: Path | None, dry_run: bool, quiet: bool, as_json: bool, yes: bool) -> None:
    from wamctl.commands.common import run_and_report
    from wamctl.experiments.friction_sweep import MODEL_FILE

    run_and_report(spec_path, out, dry_run, quiet, as_json, expect_kind="friction_sweep",
                   files=lambda run_path: {"friction_model": run_path / MODEL_FILE}, yes=yes)


def _from_data(data: Path, out: Path | None, quiet: bool, as_json: bool, options: dict,
               model: Path | None = None) -> None:
    from wamctl.commands.common import print_document_tables
    from wamctl.experiments.friction_sweep import MODEL_FILE, analyse_recorded

    target, ident, doc = analyse_recorded(data, out, options=options, model=model)
    swept = {int(j) for j in ident.map["joint"].unique()} if len(ident.map) else set()
    missing = {j: why for j, why in ident.not_identified().items() if j in swept or j in ident.refused}
    if not ident.joints:
        from wamctl.errors import DataFormatError
        if not (quiet or as_json):
            print_document_tables(doc)          # the rejected moves and why, above the error
        raise DataFormatError(f"{data}: no joint could be identified (" + "; ".join(
            f"joint {j}: {why}" for j, why in missing.items()) + f"); the friction map and the report are "
            f"in {target}")
    if as_json:
        emit_json({"run_dir": str(target), "out": str(target), "friction_model": str(target / MODEL_FILE),
                   "report": doc.to_json()})
        return
    if not quiet:
        print_document_tables(doc)
    for j, why in missing.items():
        console.print(f"joint {j} not identified: {why}", highlight=False)
    console.print(f"identified from {data}\nrun directory: {target}\nfriction model: {target / MODEL_FILE}",
                  highlight=False, soft_wrap=True)      # paths whole, to be copied


def _compare(runs: list[Path], out: Path | None, quiet: bool, as_json: bool) -> None:
    from wamctl.errors import SpecError
    from wamctl.report.friction import comparison_document
    from wamctl.runs.store import new_stamped_dir

    if len(runs) != 2:
        raise SpecError("--compare: give two rotation runs, the pd_g run then the pd_g_ff run")
    target = new_stamped_dir(out if out is not None else Path("runs"), "ff-comparison")
    doc = comparison_document(runs[0], runs[1], target)
    written = doc.write(target, "ff_comparison")
    show_written_document(doc, written, as_json, quiet)


def register(app: typer.Typer) -> None:
    app.command("friction-id")(friction_id)
