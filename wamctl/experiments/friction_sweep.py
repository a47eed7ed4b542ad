"""The friction sweep (thesis chapter 4.2): each joint driven at several constant velocities, both directions,
under PD + gravity compensation; the identification then turns the constant-velocity stages into a
friction-velocity map and fitted friction models (:mod:`wamctl.analysis.friction_id`).

Schedule
--------
For every joint of ``sweep.joints`` and every speed of its velocity list (ascending), the joint holds for
``settle_s`` and makes an LSPB move (blend time ``tc_s``) in ``first_direction``, holds again and moves back
at the same speed, so it returns to ``q0``: two directions per speed and the arm ends where it started. A
move travels ``min(travel_rad, v * cruise_s)``: slow moves are short (a few seconds at constant velocity),
fast moves are capped by the travel. The other joints hold ``q0``.

With ``validation`` set, the run continues after the identification with the thesis' rotation test
(section 4.4) twice, under ``pd_g`` and under ``pd_g_ff`` fed by the friction model just identified, so that
the report shows both (tables ``validation_pd_g`` and ``validation_pd_g_ff`` of the run directory).
"""

from __future__ import annotations

import logging
from pathlib import Path

from wamctl.backends import make_backend
from wamctl.control.trajectory import ReferenceBuilder
from wamctl.experiments.common import (
    Plan,
    check_planned_torque,
    closed_loop_stage,
    declared_dynamics,
    feedforward_for,
    make_joint_controller,
)
from wamctl.model import params as P
from wamctl.runs.store import RunDir, json_default
from wamctl.specs.friction_sweep import DEFAULT_VELOCITIES_RAD_S, FrictionSweepSpec  # noqa: F401
from wamctl.specs.rotation import RotationSpec

# what friction-id reads (wamctl.runs.measured.load_run_data): any registered robot, a controller-only torque on the
# joints whose gravity torque is constant, and a log without a reference (the measured motion stands in for it)
READER = {"reader": "friction-id", "any_robot": True, "controller_ok": True, "stand_in": True}

log = logging.getLogger(__name__)

MODEL_FILE = "friction_model.yaml"
MAP_FILE = "friction_map.csv"
IDENT_FILE = "identification.json"
VALIDATION_TABLES = {"pd_g": "validation_pd_g", "pd_g_ff": "validation_pd_g_ff"}


# ------------------------------------------------------------------------------------------------ plan
def build_reference(spec: FrictionSweepSpec):
    """The whole sweep as one Reference, and the list of moves ``(index, joint, velocity_rad_s, travel_rad)``
    (signed velocity and travel), in order."""
    s = spec.sweep
    kp = spec.controller.gains()[0]
    b = ReferenceBuilder(spec.q0_rad, 1.0 / P.CONTROL_RATE_HZ)
    moves = []
    for j in s.joints:
        sign = spec.first_sign(j)
        for v in s.speeds(j):
            d = s.move_travel(j, v, kp)
            for direction in (sign, -sign):
                b.hold(s.settle_s, f"settle joint {j}")
                b.move({j - 1: direction * d}, v, s.tc_s, f"joint {j} v={direction * v:+.4g} rad/s")
                moves.append((j, direction * v, direction * d))
    ref = b.hold(s.settle_s, "final hold").build()
    starts = [i for i, label in ref.segments if label.startswith("joint ")]
    return ref, [(i, *m) for i, m in zip(starts, moves)]


def plan(spec: FrictionSweepSpec, base_dir: Path | None = None) -> Plan:
    ref, moves = build_reference(spec)
    s = spec.sweep
    kp = spec.controller.gains()[0]
    arm_s = len(ref) / P.CONTROL_RATE_HZ
    summary = [f"friction sweep: joints {s.joints}, {len(moves)} moves "
               f"({len(moves) // max(1, len(s.joints))} per joint: each speed out and back)",
               ("" if spec.robot == "wam7" else f"robot {spec.robot}, ")
               + f"controller {spec.controller.kind}, backend {spec.backend.kind}, "
               f"plant effects: {', '.join(spec.plant.effects.names()) or 'none'}",
               f"blend {s.tc_s} s, settle {s.settle_s} s, travel <= {s.travel_rad} rad, cruise <= {s.cruise_s} s",
               f"{len(ref)} ticks at {P.CONTROL_RATE_HZ:.0f} Hz = {arm_s:.1f} s of arm time"]
    for j in s.joints:
        summary.append(f"  joint {j}: first {'+' if spec.first_sign(j) > 0 else '-'}, speeds {s.speeds(j)} rad/s, "
                       "travel " + ", ".join(f"{s.move_travel(j, v, kp):.3g}" for v in s.speeds(j)) + " rad")
    val = {}
    if spec.validation is not None:
        val = validation_specs(spec, None)
        extra = sum(len(_rotation_plan(v).reference) for v in val.values()) / P.CONTROL_RATE_HZ
        summary.append(f"then the rotation test under pd_g and pd_g_ff (identified model): {extra:.1f} s more")

    def torque_check() -> str:   # the sweep's and the validation rotation's poses, as a rotation test's
        checks = [check_planned_torque(spec, ref, base_dir, "sweep")]
        if val:
            v = next(iter(val.values()))    # both strategies run the same reference
            checks.append("validation: " + check_planned_torque(v, _rotation_plan(v).reference, base_dir,
                                                                "validation"))
        return "; ".join(checks)
    return Plan(ref, summary, feedforward_for(spec, ref, base_dir), torque_check=torque_check, robot=spec.robot)


# ------------------------------------------------------------------------------------------------ execute
def execute(spec: FrictionSweepSpec, plan: Plan, run: RunDir, progress=None, base_dir: Path | None = None) -> None:
    """Run the sweep, identify, write ``friction_model.yaml`` (and the map), then the optional validation."""
    from wamctl.analysis.friction_id.identify import identify
    from wamctl.runs.measured import load_run_data

    ref = plan.reference
    for i, label in ref.segments:
        if not label.startswith("joint "):
            run.event(ref.t_s[i], "segment", None, label, planned=True)
    for i, j, v, d in build_reference(spec)[1]:
        run.event(ref.t_s[i], "move", j, f"velocity_rad_s={v:.6g} travel_rad={d:.6g}", planned=True)
    run.flush_events()
    n_total = len(ref)
    val_specs = validation_specs(spec, run.path) if spec.validation is not None else {}
    # the references do not depend on the controller: size the progress bar before the model file exists
    n_val = sum(len(_rotation_plan(v).reference) for v in validation_specs(spec, None).values()) \
        if val_specs else 0

    def sub_progress(offset, label):
        if progress is None:
            return None
        return lambda done, total, _l=None: progress(offset + done, n_total + n_val, label)

    controller = make_joint_controller(spec, plan.feedforward_Nm)  # built before the arm is live
    with make_backend(spec, base_dir) as backend:
        closed_loop_stage(backend, controller, ref, run, sub_progress(0, "friction sweep"))
    result = identify(load_run_data(run.path, **READER), spec.identification.model_dump(),
                      dynamics=declared_dynamics(spec, base_dir))
    write_identification(run.path, result)
    offset = n_total
    for kind, rspec in val_specs.items():
        rp = _rotation_plan(rspec, base_dir)
        controller = make_joint_controller(rspec, rp.feedforward_Nm)
        with make_backend(rspec, base_dir, seed=spec.seed + 1) as backend:
            closed_loop_stage(backend, controller, rp.reference, run,
                              sub_progress(offset, f"rotation test {kind}"), table=VALIDATION_TABLES[kind])
        offset += len(rp.reference)


def write_identification(path: Path, result) -> None:
    """``friction_model.yaml``, ``friction_map.csv`` and ``identification.json`` into ``path``."""
    import json

    import yaml

    path = Path(path)
    data, header = result.model_file()
    (path / MODEL_FILE).write_text(header + yaml.safe_dump(data, sort_keys=False))
    result.map.to_csv(path / MAP_FILE, index=False)
    (path / IDENT_FILE).write_text(json.dumps(result.to_dict(), indent=2, default=json_default))


def validation_specs(spec: FrictionSweepSpec, run_path: Path | None) -> dict[str, RotationSpec]:
    """The two rotation specs of the validation: pd_g, and pd_g_ff fed by the run's ``friction_model.yaml``."""
    v = spec.validation
    common = spec.model_dump(include={"name", "robot", "seed", "backend", "plant", "q0_rad", "out_dir"})
    ctl = spec.controller.model_dump()
    rot = {"joints": v.joints, "mode": "one_at_a_time", "amplitude_rad": v.amplitude_rad,
           "velocity_rad_s": v.velocity_rad_s, "tc_s": v.tc_s, "settle_s": v.settle_s, "hold_s": v.hold_s}
    ff_file = str(Path(run_path) / MODEL_FILE) if run_path is not None else "table_4_1"
    out = {}
    for kind in ("pd_g", "pd_g_ff"):
        c = dict(ctl, kind=kind, ki=None, friction_ff=ff_file if kind == "pd_g_ff" else None)
        out[kind] = RotationSpec.model_validate(dict(common, kind="rotation", controller=c, rotation=rot))
    return out


def _rotation_plan(rspec: RotationSpec, base_dir: Path | None = None) -> Plan:
    from wamctl.experiments import rotation
    return rotation.plan(rspec, base_dir)



# ------------------------------------------------------------------------------------------------ recorded data
def _model_dynamics(model: Path, rd):
    """The rigid body of a model file's ``links`` with the run's declared payload."""
    from wamctl.experiments.common import declared_links
    from wamctl.model.dynamics import Payload, WamDynamics

    pl = rd.meta.payload
    return WamDynamics(Payload(pl.mass_kg, tuple(pl.com_m)) if pl and pl.mass_kg > 0 else None,
                       declared_links(str(model)))


def analyse_recorded(source: Path, out: Path | None = None, name: str | None = None, options: dict | None = None,
                     model: Path | None = None):
    """Identify friction from a recorded sweep (a measured-run directory or a run directory). ``model``: a model
    file whose ``links`` (an identified arm, ``wamctl identify``) replace the datasheet's rigid body.

    A new run directory of kind ``friction_sweep`` is created under ``out`` (default ``runs/``: ``--out`` means
    the parent of the run directory, as for a spec) holding the samples (so that ``wamctl report`` takes it
    again), the friction model, the map and the report.

    Returns
    -------
    (directory written, FrictionIdentification, Document)
    """
    from wamctl.analysis.friction_id.identify import identify
    from wamctl.report.friction import friction_document
    from wamctl.runs.measured import load_run_data
    from wamctl.runs.store import open_run

    source = Path(source)
    rd = load_run_data(source, **READER)   # DataFormatError naming the file, key, column or row
    ident = identify(rd, options, dynamics=_model_dynamics(model, rd) if model is not None else None)
    src_spec: dict = {}
    src_backend = "measured"
    if (source / "manifest.json").is_file():
        manifest, src_spec = open_run(source)
        src_backend = (manifest.get("backend") or {}).get("name", "measured")
        name = name or manifest.get("name")
    meta = rd.meta.model_dump(mode="json")
    spec = {"kind": "friction_sweep", "name": name or source.name, "q0_rad": meta.get("q0"),
            "controller": {"kind": rd.meta.controller.kind, "kp": rd.meta.controller.kp,
                           "kd": rd.meta.controller.kd, "gravity_compensation": rd.meta.gravity_compensation},
            "identification": dict(options or {}), "measured_meta": meta}
    if rd.truth is not None:
        spec["plant"] = rd.truth   # keeps the simulated truth for the report
    run = RunDir.create(Path(out) if out is not None else Path("runs"), spec["name"], spec, None, "friction_sweep",
                        {"backend": {"name": "sim" if rd.truth is not None else src_backend},
                         "analysed_from": str(source.resolve())})
    run.write_table("data", rd.data)
    target = run.path
    write_identification(target, ident)
    run.finish("completed", None)    # after the friction model: an interrupt before it leaves the run `interrupted`
    header = f"Recorded sweep {source} ({'run directory' if src_spec else 'measured run'})."
    doc = friction_document(rd, ident, target, f"Friction identification: {name or source.name}", header)
    doc.write(target, "report")
    return target, ident, doc
