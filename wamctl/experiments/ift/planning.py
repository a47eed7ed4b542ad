"""The plan of an IFT run: the task reference of each joint, the model of the second experiment, the summary."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from pydantic import ValidationError

from wamctl.control.trajectory import Reference, ReferenceBuilder
from wamctl.errors import SpecError
from wamctl.experiments.common import Plan, check_planned_torque, declared_feedforward_Nm
from wamctl.io import resolve_path
from wamctl.model import params as P
from wamctl.model.friction import FrictionModel
from wamctl.model.plant import Plant, resolve_friction
from wamctl.specs import PayloadEffect, PlantSpec, SensorSpec, format_validation_error, load_model_file
from wamctl.specs.ift import GAIN_UNITS, IftSpec, gain_bounds, initial_gains

DT_S = 1.0 / P.CONTROL_RATE_HZ


def task_reference(spec: IftSpec, joint: int, with_return: bool) -> tuple[Reference, int]:
    """The first experiment's reference for ``joint`` (1-based) and the number of samples J covers."""
    t = spec.ift.task

    def build(back: bool) -> Reference:
        b = ReferenceBuilder(spec.q0_rad, DT_S)
        b.hold(t.settle_s, f"settle joint {joint}")
        b.move({joint - 1: t.amplitude_rad}, t.velocity_rad_s, t.tc_s, f"move joint {joint}")
        b.hold(t.hold_s, f"hold joint {joint}")
        if back:
            b.move({joint - 1: -t.amplitude_rad}, t.velocity_rad_s, t.tc_s, f"return joint {joint}")
        return b.build()
    task = build(False)
    return (build(True) if with_return else task), len(task)


def returns_to_start(spec: IftSpec) -> bool:
    r = spec.ift.task.return_to_start
    return (spec.backend.kind != "sim") if r is None else bool(r)


def model_plant_spec(spec: IftSpec, base_dir: Path | None) -> tuple[PlantSpec, Path | None]:
    """The model of the second experiment and of the safeguards, and the folder its friction path is relative to.

    A declared payload (``controller.declared_payload``) is part of the model unless the model has its own."""
    m = spec.ift.model
    model_dir = base_dir
    if m is None:
        ps = PlantSpec(friction=spec.ift.identified_friction, sensors=SensorSpec(encoder_counts_per_rev=0))
    elif isinstance(m, str):
        path = resolve_path(m, base_dir)
        try:
            ps = PlantSpec(**load_model_file(path))
        except ValidationError as exc:
            raise SpecError(format_validation_error(exc, f"ift.model {path}")) from None
        model_dir = path.parent
    else:
        ps = m
    dp = spec.controller.declared_payload
    if dp is not None and ps.effects.payload is None:
        fx = ps.effects.model_copy(update={"payload": PayloadEffect(mass_kg=dp.mass_kg, com_m=list(dp.com_m))})
        ps = ps.model_copy(update={"effects": fx})
    return ps, model_dir


def comparison_feedforward_Nm(spec: IftSpec, reference: Reference, friction: FrictionModel) -> np.ndarray:
    """Eq. 4.3 over ``reference`` with the identified friction: the feed-forward of the ``pd_g_ff`` strategy of
    the comparison (with the ``m qdd_r`` term of the declared rigid body at q0 when ``comparison.ff_inertia``)."""
    return declared_feedforward_Nm(spec, reference, friction, spec.ift.comparison.ff_inertia)


def plan(spec: IftSpec, base_dir: Path | None = None) -> Plan:
    """Every tuned joint's task once (the reference the limits are checked on), the comparison's feed-forward
    (checked against the torque limits), and the summary; the model and the measured runs must resolve."""
    s = spec.ift
    ret = returns_to_start(spec)
    refs = [task_reference(spec, j, ret)[0] for j in s.joints]
    q = np.concatenate([r.q_rad for r in refs])   # every joint's experiment once, for the limit checks
    starts = np.cumsum([0] + [len(r) for r in refs[:-1]])
    ref = Reference(np.arange(len(q)) * DT_S, q, np.concatenate([r.qd_rad_s for r in refs]),
                    np.concatenate([r.qdd_rad_s2 for r in refs]),
                    [(int(i0 + i), label) for i0, r in zip(starts, refs) for i, label in r.segments])
    # the model and the measured runs must resolve now (a dry run names a missing file)
    mspec, mdir = model_plant_spec(spec, base_dir)
    Plant(mspec, mdir)
    friction = resolve_friction(s.identified_friction, base_dir)
    ff = None
    if s.comparison.enabled and s.plant.source == "backend":
        ff = comparison_feedforward_Nm(spec, ref, friction)
    if s.plant.source == "measured":
        for r in s.plant.runs:
            p = resolve_path(r, base_dir)
            if not p.is_dir():
                raise SpecError(f"ift.plant.runs: {r}: no such directory")
    return Plan(ref, _summary(spec, mspec), ff,
                torque_check=lambda: check_planned_torque(spec, ref, base_dir, "ift.task"))


def _summary(spec: IftSpec, mspec: PlantSpec) -> list[str]:
    s = spec.ift
    lo, hi = gain_bounds(spec)
    g0 = initial_gains(spec)
    n_task = task_reference(spec, s.joints[0], False)[1]
    summary = [
        f"IFT of the PIDs of joints {s.joints}: per joint {s.task.amplitude_rad} rad at {s.task.velocity_rad_s} "
        f"rad/s (LSPB, t_c = {s.task.tc_s} s), settle {s.task.settle_s} s, hold {s.task.hold_s} s: "
        f"{n_task} samples = {n_task * DT_S:.1f} s of arm time per experiment",
        "first experiment: " + (f"backend {spec.backend.kind}" + (
            f", plant friction {spec.plant.friction if isinstance(spec.plant.friction, str) else 'inline'}, "
            f"effects: {', '.join(spec.plant.effects.names()) or 'none'}" if spec.backend.kind == "sim" else "")
            if s.plant.source == "backend" else f"{len(s.plant.runs)} measured run(s)"),
        f"second experiment ({s.second_experiment}, eps = {s.perturbation}) on the model: friction "
        f"{mspec.friction if isinstance(mspec.friction, str) else 'inline'}, effects: "
        f"{', '.join(mspec.effects.names()) or 'none'}",
        "schedule: " + ", ".join(f"{st.method} gamma={st.gamma}" + (f" x{st.iterations}" if st.iterations else "")
                                 for st in s.schedule) + f"; at most {s.max_iterations} iterations; J compared at "
        f"{s.stop_digits} digits; objective on {s.objective_signal} positions",
        f"gravity compensation: {spec.controller.gravity_compensation}",
        "gains: " + ", ".join(f"{g} in {u}" for g, u in GAIN_UNITS.items()),
    ]
    for j in s.joints:
        summary.append(f"  joint {j}: initial kp={g0[j - 1, 0]:g} kd={g0[j - 1, 1]:g} ki={g0[j - 1, 2]:g}; bounds "
                       f"kp [{lo[j - 1, 0]:g}, {hi[j - 1, 0]:g}] kd [{lo[j - 1, 1]:g}, {hi[j - 1, 1]:g}] "
                       f"ki [{lo[j - 1, 2]:g}, {hi[j - 1, 2]:g}]")
    if s.comparison.enabled and s.plant.source == "backend":
        summary.append(f"then the comparison (thesis 5.4): PD+g, PD+g+ff ({s.identified_friction}), tuned PID")
    return summary
