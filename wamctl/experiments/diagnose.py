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


def load_diagnosable(path: Path, pooled: bool = False):
    """The run at ``path`` (:func:`wamctl.runs.measured.load_run_data`) when ``diagnose`` can take it: a run of any
    registered robot (its joints count from the run's robot) with every joint logged (without a logged reference
    the measurement stands in for it, :func:`wamctl.runs.measured.with_reference`), and tau the
    total command or the controller's output (``torque: controller``: the diagnosis then takes the joints whose
    gravity torque is constant over the run, :mod:`wamctl.model.controller_torque`); else DataFormatError in one
    line naming what. ``pooled``: the runs pooled know the wam7 and the total command only so far."""
    from wamctl.runs.measured import load_run_data

    return load_run_data(path, reader="diagnose of several runs" if pooled else "diagnose", any_robot=not pooled,
                         controller_ok=not pooled, stand_in=True)


def declared_model(path: Path | None, robot: str = "wam7"):
    """The declared model from ``--model``: a friction file (wamctl-friction/1) or a model file
    (wamctl-model/1: friction, effects, sensors, links, e.g. from `wamctl identify`). None: classic friction
    fitted from the data. ``robot``: the run's arm; a model of another arm (a model file's ``robot``, a friction
    file's joints) is refused in one line (SpecError)."""
    from pydantic import ValidationError

    from wamctl.analysis.diagnosis.estimator import DeclaredModel
    from wamctl.errors import SpecError, WamctlError
    from wamctl.io import load_yaml
    from wamctl.model.dynamics import Payload
    from wamctl.model.friction import FRICTION_FILE_FORMAT, FrictionModel
    from wamctl.model.plant import resolve_friction
    from wamctl.model.robots import get_robot
    from wamctl.specs import PlantSpec, format_validation_error, load_model_file
    from wamctl.specs.common import link_parameters

    if path is None:
        return None
    n = get_robot(robot).n_joints
    raw = load_yaml(path)
    if isinstance(raw, dict) and (raw.get("format") == FRICTION_FILE_FORMAT or "joints" in raw):
        try:
            return DeclaredModel(friction=FrictionModel.load(path, n), source=str(path))
        except WamctlError as exc:
            if robot == "wam7":
                raise
            raise SpecError(f"{exc}; the run is of a {robot} (joints 1..{n})") from None
    if isinstance(raw, dict) and raw.get("robot", "wam7") != robot:
        raise SpecError(f"{path}: robot: {raw.get('robot', 'wam7')}; the run is of a {robot}")
    try:
        plant = PlantSpec.model_validate(load_model_file(path))
    except ValidationError as exc:
        raise SpecError(format_validation_error(exc, str(path))) from None
    friction = resolve_friction(plant.friction, path.parent, n)
    effects = {k: v for k, v in plant.effects.model_dump(mode="json").items() if v is not None}
    payload = Payload(plant.effects.payload.mass_kg, tuple(plant.effects.payload.com_m)) \
        if plant.effects.payload else None
    links = link_parameters(plant.links, robot) if plant.links else None
    return DeclaredModel(friction=friction, payload=payload, effects=effects,
                         sensors=plant.sensors.model_dump(mode="json"), source=str(path), links=links)


def diagnose_to_run_dir(data_path: Path, model: Path | None = None, out: Path = Path("runs"),
                        name: str | None = None, formats=("md", "html", "json"), progress=None,
                        jobs: int | None = None):
    """Diagnose ``data_path`` and write a run directory under ``out``; returns (run path, diagnosis dict,
    report Document). ``jobs``: worker processes for the joints (``ModelDiagnosis(jobs=...)``, None: chosen)."""
    import pandas as pd
    import yaml

    from wamctl.analysis.diagnosis.augmented import model_file
    from wamctl.analysis.diagnosis.estimator import ModelDiagnosis
    from wamctl.report import write_report
    from wamctl.runs.store import RunDir

    data = load_diagnosable(data_path)
    decl = declared_model(model, data.meta.robot)
    def fitting(fraction, label):
        if progress:
            progress(round(80 * fraction), 100, f"diagnose: {label}")
    diag = ModelDiagnosis(declared=decl, simulator=simulate_positions, jobs=jobs).fit(data, fitting)
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
        mf = model_file(diag, str(data_path), result)
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
            for j in range(pc["q_meas"].shape[1]):
                cols[f"q_{j + 1}_rad"] = pc["q_meas"][:, j]
                cols[f"q_before_{j + 1}_rad"] = pc["q_before"][:, j]
                cols[f"q_after_{j + 1}_rad"] = pc["q_after"][:, j]
            pd.DataFrame(cols).to_parquet(run.path / "positions.parquet", index=False)
    nxt = None
    if diag.conclusive_ and data.meta.robot != "wam7":
        # the designs of a next run (payload against links, delay against inertia, backlash) know the wam7 only
        if diag.ambiguous_ or diag.arm_unnamed_:
            nxt = {"spec": None, "why": f"no next run designed: the design of the run that would tell them apart "
                                        f"knows the wam7 only, not the {data.meta.robot}"}
    elif diag.conclusive_:
        nxt = next_experiment(diag, data, Path(data_path), run.path)
        if nxt is None:       # a delay against inertia errors, backlash (wamctl/experiments/diagnose_next.py)
            from wamctl.experiments.diagnose_next import next_experiment_more
            nxt = next_experiment_more(diag, data, Path(data_path), run.path)
    if nxt is not None:
        result["next_experiment"] = nxt
        run.write_json("diagnosis.json", result)
    run.finish("completed", None if diag.conclusive_ else diag.reason_,
               effects_found=result["effects_found"])
    doc = write_report(run.path, formats=formats)
    if progress:
        progress(100, 100, "diagnose: done")
    return run.path, result, doc


def next_experiment(diag, data, data_path: Path, out_dir: Path, seed: int = 0) -> dict | None:
    """When the run cannot tell a wrist payload from the arm's link errors (the payload-or-links decision
    ambiguous, or link errors within the declared accuracy explaining a payload's torque as well, or a payload or
    link errors seen and not named), the excitation that separates them best
    (:func:`wamctl.analysis.diagnosis.discriminate.design_next_run`: T-optimal among Fourier candidates within
    excite's default limits) written as ``next_experiment.yaml`` (an excitation spec for the run's backend, plant and
    controller when the run directory names them); returns ``{"spec", "separation_noise_floors",
    "original_separation_noise_floors", "joints", "why", "noise_floor_Nm"}`` or None when nothing is to separate
    or no payload was fitted to design against."""

    from wamctl.analysis.diagnosis.arm import PAYLOAD_MASS_RANGE_KG
    from wamctl.analysis.diagnosis.discriminate import design_next_run, fitted_hypotheses, trajectory_rows
    from wamctl.analysis.diagnosis.links import WIDE_PRIOR
    from wamctl.analysis.diagnosis.rigid import plausible_link_map
    from wamctl.experiments.diagnose_next import design_setting, write_next_experiment

    dec = diag.payload_vs_links_
    unnamed = {u["name"] for u in diag.arm_unnamed_}
    cannot_tell = dec is not None and (dec["outcome"] in ("ambiguous", "link_parameters") or dec.get("grey_zone"))
    if not (cannot_tell or unnamed & {"payload", "link_parameters"}):
        return None
    cone = diag.payload_cone_fit_
    if not cone or cone["mass_kg"] <= 0:
        return None
    lo_kg, hi_kg = PAYLOAD_MASS_RANGE_KG
    if not lo_kg <= cone["mass_kg"] <= hi_kg:
        # a payload no WAM carries is no competitor for the links' errors: a run designed against it would cost
        # the lab a run and decide nothing (seen: 366 kg fitted to a wrist sweep with a measurement delay)
        return {"spec": None, "why": f"no run designed to tell a payload from link errors: the payload that would "
                                     f"compete with them here is {cone['mass_kg']:.3g} kg, not a wrist payload "
                                     f"({lo_kg:g} to {hi_kg:g} kg)"}
    sig = diag.signals_
    idx = np.unique(np.concatenate([diag.jd_[j].idx for j in diag.joints_]))
    idx = idx[:: max(1, int(round(1.0 / (sig.dt_s * 12.5))))]
    dyn, limits, q0, friction = design_setting(diag, data)
    rows_run = trajectory_rows(dyn, sig.at("q", idx), sig.at("qd", idx), sig.at("qdd", idx))
    hyp = fitted_hypotheses(rows_run, cone["mass_kg"], cone["com_m"],
                            plausible_link_map(diag.declared_.links, diag.payload_declared_), WIDE_PRIOR)
    noise = float(np.nanmedian([r.torque_rms_after_Nm for r in diag.joints_.values()]))
    ran = sorted(diag.joints_)
    sets = [ran, sorted(set(ran) | {4, 5, 6}), [1, 3, 4, 5], list(range(7))]
    try:
        nr = design_next_run(dyn, friction, q0, hyp, noise, rows_run, limits, sets, seed=seed)
    except ValueError as exc:       # no candidate within the limits at this q0: said, no spec written
        return {"spec": None, "why": f"no run designed to tell a payload from link errors: {exc} at the run's q0"}
    sep, orig_sep = float(nr.separation["separation"]), float(nr.original["separation"])
    named = "the payload is named on the declared link accuracy, but " if dec and dec.get("grey_zone") else ""
    why = (f"{named}the run cannot tell a {cone['mass_kg']:.2g} kg wrist payload from link errors within "
           f"{WIDE_PRIOR:g} times the declared accuracy (separation {orig_sep:.2g} noise floors of {noise:.3g} N m); "
           f"moving joints {', '.join(str(j + 1) for j in nr.trajectory.moving)} their predicted torques differ by "
           f"{sep:.2g} noise floors (RMS per sample, after each refits its own parameters)"
           + ("" if sep > 2 else ": still below 2, a longer run or a heavier test mass is needed to tell them"))
    write_next_experiment(data_path, out_dir, nr.trajectory, q0, [j + 1 for j in nr.trajectory.moving], 3, 1.0,
                          why, seed)
    return {"spec": "next_experiment.yaml", "separation_noise_floors": sep,
            "original_separation_noise_floors": orig_sep, "joints": [j + 1 for j in nr.trajectory.moving],
            "noise_floor_Nm": noise, "why": why, "candidates": [{"joints": js, "separation_noise_floors": float(v)}
                                                                for js, v in nr.scored]}


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
    from wamctl.model.dynamics import WamDynamics
    from wamctl.model.plant import Plant
    from wamctl.model.robots import get_robot
    from wamctl.specs import PlantSpec

    robot = get_robot(getattr(meta, "robot", None))     # the run's arm
    n_joints = robot.n_joints

    n = len(t_s)
    kp, kd = np.asarray(meta.controller.kp, float), np.asarray(meta.controller.kd, float)
    ki = np.asarray(meta.controller.ki, float) if (meta.controller.kind == "pid" and meta.controller.ki) \
        else np.zeros(n_joints)
    dt = 1.0 / float(meta.sample_rate_hz)
    gravity = WamDynamics(payload, robot=robot).gravity_view if meta.gravity_compensation else None
    ctl = JointController(kp, kd, ki, dt, gravity=gravity, feedforward_Nm=feedforward)
    backend = SimBackend(Plant(PlantSpec.model_validate(plant), None, robot), q0, np.random.default_rng(seed), 2)
    if abs(dt - backend.control_period_s) > 1e-12:       # a log at another rate than the arm's 500 Hz
        backend.control_period_s = dt
        backend.h_s = dt / backend.substeps
    if qd0 is not None:
        backend.truth()[1][:] = qd0          # the true velocity, a view the backend updates in place
    backend._t = float(t0_s)                  # the plant's clock (a friction drift), the sim backend's own
    ref = Reference(np.arange(n) * dt, q_ref, np.zeros_like(q_ref), np.zeros_like(q_ref), [])
    rec = LoopRecorder(n, False, n_joints=n_joints)
    try:
        with backend:
            run_loop(backend, ctl, ref, rec)
    except SafetyLimitError as exc:
        log.info("simulation of the model stopped at sample %d: %s", rec.n, exc)
    out = np.full((n, n_joints), np.nan)
    rows = rec.result()
    out[: len(rows)] = rows[:, 1 + n_joints:1 + 2 * n_joints]      # t, q_ref (n), q (n), ...
    return out


def diagnose_runs_to_run_dir(data_paths: list[Path], model: Path | None = None, out: Path = Path("runs"),
                             name: str | None = None, formats=("md", "html", "json"), progress=None,
                             simulate: bool = True, jobs: int | None = None):
    """Diagnose several runs of one arm together (:class:`wamctl.analysis.diagnosis.pooled.PooledDiagnosis`) and
    write a run directory under ``out`` (kind ``diagnosis``): ``diagnosis.json`` (``pooled: true``: the runs, each
    run's own result in brief, every decision per run and pooled, which run decided it, each run's friction), each
    run's own diagnosis as ``alone-<k>.json`` (k = 1, 2, ... in the order given) and the report. Runs of different
    arms (robot, an ``arm`` named in meta.yaml, the declared payload, a simulated plant's links or friction) or a
    run given twice are refused in one line before anything is fitted. ``simulate`` False skips each run's
    closed-loop position check. ``jobs``: worker processes for each run's joints (``ModelDiagnosis(jobs=...)``).
    Returns (run path, diagnosis dict, report Document)."""
    from wamctl.analysis.diagnosis.estimator import ModelDiagnosis
    from wamctl.analysis.diagnosis.pooled import PoolingError, different_arm

    paths = [Path(p) for p in data_paths]
    resolved = [p.resolve() for p in paths]
    twice = sorted({str(p) for p in paths if resolved.count(p.resolve()) > 1})
    if twice:
        raise PoolingError(f"run given more than once: {', '.join(twice)} (pooling needs distinct runs)")
    labels = [p.name for p in paths]
    if len(set(labels)) < len(labels):       # two runs of one name in different places: their place names them
        labels = [str(p) for p in paths]
    datas = [load_diagnosable(p, pooled=True) for p in paths]
    why = different_arm([d.meta for d in datas], [d.truth for d in datas], labels)
    if why:
        raise PoolingError(why)
    decl = declared_model(model)
    diags = []
    for k, data in enumerate(datas):
        def fitting(fraction, label, k=k):
            if progress:
                progress(round(80 * (k + fraction) / len(datas)), 100, f"diagnose {labels[k]}: {label}")
        diags.append(ModelDiagnosis(declared=decl, simulator=simulate_positions if simulate else None, jobs=jobs)
                     .fit(data, fitting))
    if progress:
        progress(80, 100, "diagnose: the runs pooled")
    path, result, doc = write_pooled(paths, labels, datas, diags, model, out, name, formats)
    if progress:
        progress(100, 100, "diagnose: done")
    return path, result, doc


def write_pooled(paths: list[Path], labels: list[str], datas: list, diags: list, model: Path | None = None,
                 out: Path = Path("runs"), name: str | None = None, formats=("md", "html", "json")):
    """The runs ``paths`` (loaded as ``datas``, each diagnosed alone as ``diags``) pooled and written as a run
    directory (see :func:`diagnose_runs_to_run_dir`); returns (run path, diagnosis dict, report Document)."""
    from wamctl.analysis.diagnosis.pooled import PooledDiagnosis
    from wamctl.report import write_report
    from wamctl.runs.store import RunDir

    paths = [Path(p) for p in paths]
    resolved = [p.resolve() for p in paths]
    pooled = PooledDiagnosis(diags, labels, datas).fit()
    name = name or "diagnose-" + "+".join(p.name for p in paths)
    spec = {"kind": "diagnosis", "name": name, "data": [str(p) for p in resolved],
            "model": str(Path(model).resolve()) if model else None,
            "options": {"alpha": diags[0].alpha, "n_blocks": diags[0].n_blocks, "n_folds": diags[0].n_folds,
                        "candidates": list(diags[0].candidates), "pooled": True}}
    run = RunDir.create(out, name, spec, None, "diagnosis",
                        {"backend": {"name": "analysis"}, "source": [str(p) for p in resolved]})
    result = pooled.to_dict([str(p) for p in paths])
    for k, (d, p) in enumerate(zip(diags, paths)):
        run.write_json(f"alone-{k + 1}.json", d.to_dict(str(p)))
        result["runs"][k]["diagnosis_file"] = f"alone-{k + 1}.json"
    run.write_json("diagnosis.json", result)
    run.finish("completed", None if pooled.conclusive_ else pooled.reason_, effects_found=result["effects_found"])
    return run.path, result, write_report(run.path, formats=formats)
