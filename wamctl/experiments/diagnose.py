"""``wamctl diagnose`` as a pipeline: read a measured run and the declared model, fit
:class:`~wamctl.analysis.diagnosis.estimator.ModelDiagnosis` (handing it the closed loop on the simulated arm),
and write a run directory (kind ``diagnosis``)::

    spec.yaml, manifest.json    what was diagnosed, with which options
    diagnosis.json              the result, format wamctl-diagnosis/1 (docs/diagnosis-report.md)
    model.yaml                  the augmented model, format wamctl-model/1 (usable as ``plant: model.yaml``)
    residuals.parquet           held-out torque residuals before/after, per joint, at sliding and stall samples
    positions.parquet           measured and re-simulated positions before/after (held-out traces)
    report.md/.html/.json, *.png
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

log = logging.getLogger(__name__)


def declared_model(path: Path | None):
    """The declared model from ``--model``: a friction file (wamctl-friction/1) or a model file
    (wamctl-model/1: friction, effects, sensors, links, e.g. from `wamctl identify`). None: classic friction
    fitted from the data."""
    from pydantic import ValidationError

    from wamctl.analysis.diagnosis.estimator import DeclaredModel
    from wamctl.errors import SpecError
    from wamctl.io import load_yaml
    from wamctl.model.dynamics import Payload
    from wamctl.model.friction import FRICTION_FILE_FORMAT, FrictionModel
    from wamctl.model.plant import resolve_friction
    from wamctl.specs import PlantSpec, format_validation_error, load_model_file
    from wamctl.specs.common import link_parameters

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
    links = link_parameters(plant.links) if plant.links else None
    return DeclaredModel(friction=friction, payload=payload, effects=effects,
                         sensors=plant.sensors.model_dump(mode="json"), source=str(path), links=links)


def diagnose_to_run_dir(data_path: Path, model: Path | None = None, out: Path = Path("runs"),
                        name: str | None = None, formats=("md", "html", "json"), progress=None):
    """Diagnose ``data_path`` and write a run directory under ``out``; returns (run path, diagnosis dict,
    report Document)."""
    import pandas as pd
    import yaml

    from wamctl.analysis.diagnosis.augmented import model_file
    from wamctl.analysis.diagnosis.estimator import ModelDiagnosis
    from wamctl.report import write_report
    from wamctl.runs.measured import load_run_data
    from wamctl.runs.store import RunDir

    data = load_run_data(data_path)
    decl = declared_model(model)
    def fitting(fraction, label):
        if progress:
            progress(round(80 * fraction), 100, f"diagnose: {label}")
    diag = ModelDiagnosis(declared=decl, simulator=simulate_positions).fit(data, fitting)
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
        progress(80, 100, "diagnose: writing the report")
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
        progress(100, 100, "diagnose: done")
    return run.path, result, doc


def simulate_positions(plant: dict, meta, t_s: np.ndarray, q_ref: np.ndarray, q0: np.ndarray,
                       feedforward: np.ndarray | None = None, payload=None, seed: int = 0,
                       qd0: np.ndarray | None = None, t0_s: float = 0.0) -> np.ndarray:
    """Measured positions (n, 7) of the simulated arm ``plant`` driven along ``q_ref`` by the run's controller,
    from position ``q0`` and velocity ``qd0`` (default: at rest) at run time ``t0_s`` (what a drifting friction
    reads). A controller's integral starts at zero.

    A simulation that trips a safety limit (an unstable model) returns NaN from there on."""
    from wamctl.backends.sim import SimBackend
    from wamctl.control.controllers import JointController
    from wamctl.control.trajectory import Reference
    from wamctl.errors import SafetyLimitError
    from wamctl.experiments.engine import LoopRecorder, run_loop
    from wamctl.model import params as P
    from wamctl.model.dynamics import WamDynamics
    from wamctl.model.plant import Plant
    from wamctl.specs import PlantSpec

    N7 = P.N_JOINTS

    n = len(t_s)
    kp, kd = np.asarray(meta.controller.kp, float), np.asarray(meta.controller.kd, float)
    ki = np.asarray(meta.controller.ki, float) if (meta.controller.kind == "pid" and meta.controller.ki) \
        else np.zeros(N7)
    dt = 1.0 / float(meta.sample_rate_hz)
    gravity = WamDynamics(payload).gravity_view if meta.gravity_compensation else None
    ctl = JointController(kp, kd, ki, dt, gravity=gravity, feedforward_Nm=feedforward)
    backend = SimBackend(Plant(PlantSpec.model_validate(plant)), q0, np.random.default_rng(seed), 2)
    if abs(dt - backend.control_period_s) > 1e-12:       # a log at another rate than the arm's 500 Hz
        backend.control_period_s = dt
        backend.h_s = dt / backend.substeps
    if qd0 is not None:
        backend.truth()[1][:] = qd0          # the true velocity, a view the backend updates in place
    backend._t = float(t0_s)                  # the plant's clock (a friction drift), the sim backend's own
    ref = Reference(np.arange(n) * dt, q_ref, np.zeros_like(q_ref), np.zeros_like(q_ref), [])
    rec = LoopRecorder(n, False)
    try:
        with backend:
            run_loop(backend, ctl, ref, rec)
    except SafetyLimitError as exc:
        log.info("simulation of the model stopped at sample %d: %s", rec.n, exc)
    out = np.full((n, N7), np.nan)
    rows = rec.result()
    out[: len(rows)] = rows[:, 8:15]
    return out
