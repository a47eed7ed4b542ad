"""wamctl diagnose: find what the declared model lacks in a measured run, add it, and prove the fix.

The analysis is :class:`wamctl.analysis.diagnosis.ModelDiagnosis` (no I/O); this module reads the data and
the optional model file and writes the run directory (kind ``diagnosis``)::

    spec.yaml, manifest.json    what was diagnosed, with which options
    diagnosis.json              the result, format wamctl-diagnosis/1 (docs/diagnosis-report.md)
    model.yaml                  the augmented model, format wamctl-model/1 (usable as ``plant: model.yaml``)
    residuals.parquet           held-out torque residuals before/after, per joint, at sliding and stall samples
    positions.parquet           measured and re-simulated positions before/after (held-out traces)
    report.md/.html/.json, *.png
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer

from wamctl.cli import app
from wamctl.commands.common import console, emit_json

DataArg = Annotated[Path, typer.Argument(help="A measured-run directory (meta.yaml + data) or a run directory.",
                                         show_default=False)]


def declared_model(path: Path | None):
    """The declared model from ``--model``: a friction file (wamctl-friction/1) or a model file
    (wamctl-model/1: friction, effects, sensors). None: classic friction fitted from the data."""
    from pydantic import ValidationError

    from wamctl.analysis.diagnosis import DeclaredModel
    from wamctl.errors import SpecError
    from wamctl.model.dynamics import Payload
    from wamctl.model.friction import FRICTION_FILE_FORMAT, FrictionModel
    from wamctl.model.plant import resolve_friction
    from wamctl.specs import PlantSpec, format_validation_error, load_model_file, load_yaml

    if path is None:
        return None
    raw = load_yaml(path)
    if isinstance(raw, dict) and (raw.get("format") == FRICTION_FILE_FORMAT or "joints" in raw):
        return DeclaredModel(friction=FrictionModel.load(path), source=str(path))
    try:
        plant = PlantSpec.model_validate(load_model_file(path))
    except ValidationError as exc:
        raise SpecError(format_validation_error(exc, str(path))) from None
    friction = resolve_friction(plant.friction, path.parent)
    effects = {k: v for k, v in plant.effects.model_dump(mode="json").items() if v is not None}
    payload = Payload(plant.effects.payload.mass_kg, tuple(plant.effects.payload.com_m)) \
        if plant.effects.payload else None
    return DeclaredModel(friction=friction, payload=payload, effects=effects,
                         sensors=plant.sensors.model_dump(mode="json"), source=str(path))


def diagnose_to_run_dir(data_path: Path, model: Path | None = None, out: Path = Path("runs"),
                        name: str | None = None, formats=("md", "html", "json"), progress=None):
    """Diagnose ``data_path`` and write a run directory under ``out``; returns (run path, diagnosis dict,
    report Document)."""
    import pandas as pd
    import yaml

    from wamctl.analysis.diagnosis import ModelDiagnosis
    from wamctl.analysis.diagnosis_sim import model_file
    from wamctl.experiments.runner import write_report
    from wamctl.measured import load_run_data
    from wamctl.store import RunDir

    data = load_run_data(data_path)
    decl = declared_model(model)
    if progress:
        progress(0, 3, "diagnose: fitting")
    diag = ModelDiagnosis(declared=decl).fit(data)
    name = name or f"diagnose-{Path(data_path).name}"
    spec = {"kind": "diagnosis", "name": name, "data": str(Path(data_path).resolve()),
            "model": str(Path(model).resolve()) if model else None,
            "options": {"alpha": diag.alpha, "n_blocks": diag.n_blocks, "n_folds": diag.n_folds,
                        "candidates": list(diag.candidates)}}
    run = RunDir.create(out, name, spec, None, "diagnosis",
                        {"backend": {"name": "analysis"}, "source": str(Path(data_path).resolve())})
    result = diag.to_dict(str(data_path))
    run.write_json("diagnosis.json", result)
    if progress:
        progress(1, 3, "diagnose: writing")
    if diag.conclusive_:
        mf = model_file(diag, str(data_path))
        (run.path / "model.yaml").write_text(yaml.safe_dump(mf, sort_keys=False))
        rows = []
        for j, res in diag.joints_.items():
            jd = diag.jd_[j]
            rows.append(pd.DataFrame({"joint": j + 1, "t_s": jd.t_s, "at": "sliding",
                                      "residual_before_Nm": res.e_before, "residual_after_Nm": res.e_after}))
            if res.stall_before is not None and len(res.stall_before):
                rows.append(pd.DataFrame({"joint": j + 1, "t_s": res.stall_t, "at": "stall",
                                          "residual_before_Nm": res.stall_before,
                                          "residual_after_Nm": res.stall_after}))
        pd.concat(rows, ignore_index=True).to_parquet(run.path / "residuals.parquet", index=False)
        pc = diag.positions_
        if pc is not None:
            cols = {"t_s": pc["t_s"]}
            for j in range(7):
                cols[f"q_{j + 1}_rad"] = pc["q_meas"][:, j]
                cols[f"q_before_{j + 1}_rad"] = pc["q_before"][:, j]
                cols[f"q_after_{j + 1}_rad"] = pc["q_after"][:, j]
            pd.DataFrame(cols).to_parquet(run.path / "positions.parquet", index=False)
    run.finish("completed", None if diag.conclusive_ else diag.reason_,
               effects_found=result["effects_found"])
    doc = write_report(run.path, formats=formats)
    if progress:
        progress(3, 3, "diagnose: done")
    return run.path, result, doc


@app.command("diagnose")
def diagnose(data: DataArg,
             model: Annotated[Optional[Path], typer.Option(
                 "--model", help="Declared model: a friction file (wamctl-friction/1) or a model file "
                                 "(wamctl-model/1). Default: classic friction fitted from the data.")] = None,
             out: Annotated[Path, typer.Option("--out", help="Parent directory of the run directory.")]
             = Path("runs"),
             quiet: Annotated[bool, typer.Option("--quiet", "-q", help="No tables on the terminal.")] = False,
             json: Annotated[bool, typer.Option("--json", help="Print diagnosis.json on stdout.")] = False):
    """Find what the declared model (rigid body + armature + classic friction) lacks in a measured run.

    The torque residual (inverse dynamics on Savitzky-Golay derivatives) is tested against one signature per
    effect (stribeck, position_ripple, payload, delay, friction_drift, backlash) with nested F-tests and BIC
    on held-out time blocks; kept effects are added and refitted, and both models are re-simulated in closed
    loop with the run's reference and controller. Writes a run directory with diagnosis.json, the augmented
    model (model.yaml, usable as `plant: model.yaml`) and a report. Exit code 2 for unusable data.
    """
    from wamctl.commands.common import progress_bar
    from wamctl.commands.run import print_document_tables

    with progress_bar("diagnose", enabled=not (quiet or json)) as progress:
        path, result, doc = diagnose_to_run_dir(data, model, out, progress=progress)
    if json:
        emit_json(dict(result, run_dir=str(path)))
        return
    if not quiet:     # the summary and the effects; every candidate is in the report
        from wamctl.report.document import Document
        short = Document(doc.title, [b for b in doc.blocks if b[0] == "table" and b[1][0] in ("summary",
                                                                                              "effects")])
        print_document_tables(short)
    found = ", ".join(result["effects_found"]) or "none"
    msg = f"effects found: {found}" if result.get("conclusive") else f"nothing concluded: {result.get('reason')}"
    console.print(f"{msg}  run directory: {path}", highlight=False)
