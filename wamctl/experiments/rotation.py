"""The rotation test (thesis chapter 3): each joint rotated 0.5 rad at 0.083 rad/s, one at a time or all
together, under PD + gravity, PD + gravity + feed-forward friction, or PID."""

from __future__ import annotations

from pathlib import Path

from wamctl.backends import make_backend
from wamctl.control.trajectory import ReferenceBuilder
from wamctl.experiments.common import (
    Plan,
    check_planned_torque,
    closed_loop_stage,
    feedforward_for,
    make_joint_controller,
)
from wamctl.model import params as P
from wamctl.runs.store import RunDir
from wamctl.specs.rotation import RotationSpec


def plan(spec: RotationSpec, base_dir: Path | None = None) -> Plan:
    r = spec.rotation
    b = ReferenceBuilder(spec.q0_rad, 1.0 / P.CONTROL_RATE_HZ)
    if r.mode == "all_together":
        b.hold(r.settle_s, "settle").move({j - 1: r.amplitude_rad for j in r.joints}, r.velocity_rad_s, r.tc_s,
                                          "move joints " + ",".join(map(str, r.joints))).hold(r.hold_s, "hold")
    else:
        for j in r.joints:
            b.hold(r.settle_s, f"settle joint {j}")
            b.move({j - 1: r.amplitude_rad}, r.velocity_rad_s, r.tc_s, f"move joint {j}")
            b.hold(r.hold_s, f"hold joint {j}")
            if r.return_to_start:
                b.move({j - 1: -r.amplitude_rad}, r.velocity_rad_s, r.tc_s, f"return joint {j}")
    ref = b.build()
    summary = [f"rotation test, {r.mode.replace('_', ' ')}: joints {r.joints}, {r.amplitude_rad} rad at "
               f"{r.velocity_rad_s} rad/s (LSPB, t_c = {r.tc_s} s)",
               ("" if spec.robot == "wam7" else f"robot {spec.robot}, ")
               + f"controller {spec.controller.kind}, backend {spec.backend.kind}, "
               f"plant effects: {', '.join(spec.plant.effects.names()) or 'none'}",
               f"{len(ref)} ticks at {P.CONTROL_RATE_HZ:.0f} Hz = {len(ref) / P.CONTROL_RATE_HZ:.1f} s of arm time"]
    summary += [f"  {ref.t_s[i]:7.2f} s  {label}" for i, label in ref.segments]
    return Plan(ref, summary, feedforward_for(spec, ref, base_dir),
                torque_check=lambda: check_planned_torque(spec, ref, base_dir, "rotation"), robot=spec.robot)


def execute(spec: RotationSpec, plan: Plan, run: RunDir, progress=None, base_dir: Path | None = None) -> None:
    for i, label in plan.reference.segments:
        run.event(plan.reference.t_s[i], "segment", None, label, planned=True)
    controller = make_joint_controller(spec, plan.feedforward_Nm)  # built before the arm is live (no heartbeat gap)
    with make_backend(spec, base_dir) as backend:
        closed_loop_stage(backend, controller, plan.reference, run, progress)
