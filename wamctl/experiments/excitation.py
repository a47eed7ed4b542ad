"""The ``excitation`` kind: an exciting trajectory for identification, designed (``wamctl excite``) and run.

``plan`` samples the Fourier series (designing it first when the spec carries no coefficients) between two
holds at ``q0_rad`` and checks it at the control rate against the joint limits and the spec's excitation limits
(range with margin, speed, acceleration, the declared model's torque with margin, wrist speed); ``execute``
drives it on the backend under the spec's controller, like any closed-loop stage.

:func:`excite` is the ``wamctl excite`` pipeline: design, then write the designed spec (the input with
``excitation.coefficients`` filled in) and a design report into a directory.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from wamctl.analysis.identification.excitation import (
    ExcitationDesign,
    ExcitationLimits,
    FourierTrajectory,
    LimitUse,
    World,
    WorldClearance,
    design_excitation,
    predicted_tracking_share,
    sampled_limit_use,
    world_clearance,
)
from wamctl.backends import make_backend
from wamctl.control.trajectory import Reference
from wamctl.errors import SpecError
from wamctl.experiments.common import Plan, closed_loop_stage, declared_dynamics, feedforward_for, make_joint_controller
from wamctl.model import collision as C
from wamctl.model import params as P
from wamctl.model.plant import resolve_friction
from wamctl.model.robots import get_robot
from wamctl.report.excitation import LABELS as LIMIT_LABELS
from wamctl.runs.store import RunDir
from wamctl.specs.excitation import ExcitationSpec

log = logging.getLogger(__name__)



def limits_of(spec: ExcitationSpec) -> ExcitationLimits:
    """The spec's limits on its robot's joints (the torque limits are the robot's: wam4.conf's on a wam4)."""
    lim = spec.excitation.limits
    q_min, q_max, qd, qdd = lim.arrays(spec.robot)
    return ExcitationLimits(q_min, q_max, qd, qdd, 1.0 - lim.torque_margin, lim.max_cartesian_speed_m_s,
                            world_of(spec), get_robot(spec.robot).tau_max_Nm.copy())


def world_of(spec: ExcitationSpec) -> World:
    """The spec's ``excitation.world``: capsules, table, box, clearance."""
    w = spec.excitation.world
    geometry = C.ArmGeometry.default(w.tool_length_m, w.table_z_m, w.radii_m.mapping(), spec.robot)
    box = w.box
    return World(geometry, w.self_collision, w.table_z_m, None if box is None else np.asarray(box.min_m, float),
                 None if box is None else np.asarray(box.max_m, float), w.clearance_m)


def declared_model(spec: ExcitationSpec, base_dir: Path | None):
    """(WamDynamics, FrictionModel) the torque limit is checked with: the controller's declared rigid body and
    ``excitation.design.declared_friction``."""
    return declared_dynamics(spec, base_dir), resolve_friction(spec.excitation.design.declared_friction, base_dir,
                                                               spec.n_joints)


def design(spec: ExcitationSpec, base_dir: Path | None = None, progress=None) -> ExcitationDesign:
    """Design the spec's trajectory (ignores any coefficients it carries). Raises SpecError if infeasible."""
    ex = spec.excitation
    dyn, friction = declared_model(spec, base_dir)
    try:
        return design_excitation(np.asarray(spec.q0_rad), [j - 1 for j in ex.joints], ex.period_s, ex.harmonics,
                                 limits_of(spec), dyn, friction, ex.design.criterion, ex.design.starts,
                                 ex.design.max_iterations, spec.seed, ex.design.grid_points, progress)
    except ValueError as exc:
        raise SpecError(f"excitation: {exc}") from None


def trajectory_of(spec: ExcitationSpec, base_dir: Path | None = None, progress=None) -> FourierTrajectory:
    """The spec's series: its coefficients, or a design when it has none."""
    ex = spec.excitation
    if ex.coefficients is None:
        log.info("excitation: no coefficients in the spec; designing them (seed %d)", spec.seed)
        return design(spec, base_dir, progress).trajectory
    a, b = np.zeros((spec.n_joints, ex.harmonics)), np.zeros((spec.n_joints, ex.harmonics))
    for j, c in ex.coefficients.items():
        a[j - 1], b[j - 1] = c.a_rad_s, c.b_rad_s
    return FourierTrajectory(np.asarray(spec.q0_rad, float), ex.period_s, a, b)


def reference_of(spec: ExcitationSpec, traj: FourierTrajectory) -> Reference:
    """Hold ``settle_s``, ``periods`` periods of the series, hold ``settle_s``; sampled at the control rate."""
    ex = spec.excitation
    dt = 1.0 / P.CONTROL_RATE_HZ
    n_hold = int(round(ex.settle_s / dt))
    n_move = int(round(ex.periods * ex.period_s / dt))
    q, qd, qdd = traj.evaluate(np.arange(n_move) * dt)
    hold = np.tile(traj.q0_rad, (n_hold, 1))
    zeros = np.zeros((n_hold, len(traj.q0_rad)))
    n = 2 * n_hold + n_move
    segments = [(0, "settle"), (n_hold, f"excitation: {ex.periods} x {ex.period_s:g} s, joints "
                                        f"{','.join(map(str, ex.joints))}"), (n_hold + n_move, "hold")]
    return Reference(np.arange(n) * dt, np.vstack([hold, q, hold]), np.vstack([zeros, qd, zeros]),
                     np.vstack([zeros, qdd, zeros]), segments)


@dataclass
class ExcitationPlan(Plan):
    """A plan whose limit check also covers the excitation's own limits."""

    trajectory: FourierTrajectory | None = None
    limit_use: LimitUse | None = None
    clearance: WorldClearance | None = None

    def check_limits(self) -> list[str]:
        done = super().check_limits()
        worst_kind, joint, share = self.limit_use.worst
        if share > 1.0 + 1e-9:
            where = f"joint {joint} " if joint else ""
            raise SpecError(f"excitation: {where}{LIMIT_LABELS[worst_kind]} at {share:.0%} of its limit; "
                            "redesign with `wamctl excite`")
        done.append("excitation within its limits over the whole trajectory: " + limits_summary(self.limit_use))
        if self.clearance is not None:
            if not self.clearance.respected:
                raise SpecError("excitation.world: " + clearance_failure(self.clearance)
                                + "; redesign with `wamctl excite`")
            done.append("excitation clear of the world over the whole trajectory: " + self.clearance.statement())
        return done


def clearance_failure(clear: WorldClearance) -> str:
    w = clear.worst
    return (f"{w.kind} distance {w.between} reaches {w.distance_m:.3f} m at t = {w.index * clear.dt_s:.3f} s "
            f"of the period (at least {w.distance_m - clear.sampling_bound_m:.3f} m between samples), below the "
            f"clearance {clear.clearance_m:g} m")


def instruments_outlook(spec: ExcitationSpec, traj: FourierTrajectory, base_dir: Path | None = None) -> dict:
    """What ``wamctl identify`` will do with a run of this trajectory under the spec's controller: the predicted
    tracking error per moving joint (:func:`predicted_tracking_share`) and which joints' rows the reference will
    instrument (at most ``TRACKING_SHARE`` of the motion) or least squares will fit, with one sentence."""
    from wamctl.analysis.identification.data import TRACKING_SHARE

    dyn, friction = declared_model(spec, base_dir)
    kp, kd, _ = spec.controller.gains()
    share = predicted_tracking_share(traj, dyn, friction, kp, kd)
    moving = [j + 1 for j in traj.moving]
    ls = [j for j in moving if not share[j - 1] <= TRACKING_SHARE]
    statement = ("identify will use instrumental variables (the reference) on every moving joint (predicted "
                 f"tracking error at most {100 * np.nanmax(share):.0f} % of the motion; the limit is "
                 f"{100 * TRACKING_SHARE:.0f} %)") if not ls else (
        "identify will fit joint(s) " + ", ".join(map(str, ls)) + " by least squares, not instrumental variables: "
        + "; ".join(f"joint {j}'s predicted tracking error is {100 * share[j - 1]:.0f} % of its motion under "
                    f"kp {kp[j - 1]:g}" for j in ls)
        + f" (the reference is an instrument up to {100 * TRACKING_SHARE:.0f} %; raise the gain or the amplitude)")
    return {"tracking_share_predicted": {j: float(share[j - 1]) for j in moving}, "threshold": TRACKING_SHARE,
            "least_squares_joints": ls, "statement": statement}


def limits_summary(use: LimitUse) -> str:
    parts = []
    for kind, label in LIMIT_LABELS.items():
        u = np.atleast_1d(use.used[kind])
        k = int(np.argmax(u))
        parts.append(f"{label} {u[k]:.0%}" + (f" (joint {k + 1})" if np.ndim(use.used[kind]) else ""))
    return ", ".join(parts)


def plan(spec: ExcitationSpec, base_dir: Path | None = None) -> ExcitationPlan:
    traj = trajectory_of(spec, base_dir)
    ref = reference_of(spec, traj)
    dyn, friction = declared_model(spec, base_dir)
    use = sampled_limit_use(traj, limits_of(spec), dyn, friction)
    world = world_of(spec)
    clear = world_clearance(traj, world, dyn, limits_of(spec)) if world.active else None
    ex = spec.excitation
    summary = [f"excitation: joints {ex.joints}, Fourier series of {ex.harmonics} harmonics, period "
               f"{ex.period_s:g} s x {ex.periods}, holds of {ex.settle_s:g} s at q0",
               f"coefficients: {'from the spec' if ex.coefficients is not None else 'designed now'} "
               f"({ex.design.criterion})",
               f"controller {spec.controller.kind}, backend {spec.backend.kind}",
               f"limits used: {limits_summary(use)}",
               "world: " + (clear.statement() if clear is not None else "none checked"),
               instruments_outlook(spec, traj, base_dir)["statement"],
               f"{len(ref)} ticks at {P.CONTROL_RATE_HZ:.0f} Hz = {len(ref) / P.CONTROL_RATE_HZ:.1f} s of arm time"]
    return ExcitationPlan(ref, summary, feedforward_for(spec, ref, base_dir), robot=spec.robot, trajectory=traj,
                          limit_use=use, clearance=clear)


def execute(spec: ExcitationSpec, plan: ExcitationPlan, run: RunDir, progress=None,
            base_dir: Path | None = None) -> None:
    for i, label in plan.reference.segments:
        run.event(plan.reference.t_s[i], "segment", None, label, planned=True)
    run.write_json("excitation.json", {"trajectory": plan.trajectory.to_dict(),
                                       "q0_rad": [float(v) for v in plan.trajectory.q0_rad],
                                       "limits_used": _use_dict(plan.limit_use),
                                       "world": plan.clearance.to_dict() if plan.clearance is not None else None})
    controller = make_joint_controller(spec, plan.feedforward_Nm)  # built before the arm is live (no heartbeat gap)
    with make_backend(spec, base_dir) as backend:
        closed_loop_stage(backend, controller, plan.reference, run, progress)


def _use_dict(use: LimitUse) -> dict:
    return {k: (np.asarray(v).tolist() if np.ndim(v) else float(v)) for k, v in use.used.items()}


def _files_absolute(value, base_dir: Path):
    """``value`` (a spec mapping, list or scalar) with every string that names an existing file relative to the
    spec's folder ``base_dir`` (a friction or model file) made absolute, so that the spec runs from another
    folder."""
    from wamctl.io import resolve_path

    if isinstance(value, dict):
        return {k: _files_absolute(v, base_dir) for k, v in value.items()}
    if isinstance(value, list):
        return [_files_absolute(v, base_dir) for v in value]
    if isinstance(value, str) and not Path(value).is_absolute() and Path(value).suffix:
        p = resolve_path(value, base_dir)
        if p.is_file():
            return str(p.resolve())
    return value


def designed_spec(raw: dict, traj: FourierTrajectory, base_dir: Path | None = None) -> dict:
    """The input spec mapping with the designed coefficients in ``excitation.coefficients`` (and, given the
    spec's folder ``base_dir``, the files it names made absolute: the designed spec is written elsewhere)."""
    out = dict(_files_absolute(raw, base_dir) if base_dir is not None else raw)
    ex = dict(out.get("excitation") or {})
    ex["coefficients"] = {j + 1: {"a_rad_s": [float(v) for v in traj.a[j]], "b_rad_s": [float(v) for v in traj.b[j]]}
                          for j in traj.moving}
    out["excitation"] = ex
    return out


def excite(spec_path: Path, out: Path | None = None, progress=None) -> tuple[Path, ExcitationDesign, LimitUse]:
    """``wamctl excite``: design the spec's trajectory, write ``excitation.yaml`` (the spec, designed, the files
    it names made absolute), ``design.json`` and the design report into a new folder
    ``<out>/<UTC timestamp>-<name>-design`` (``out`` as every command's ``--out``: the parent; default the
    spec's ``out_dir``, ``runs``).

    Returns (the directory, the design, the limits used at the control rate)."""
    from wamctl.io import load_yaml
    from wamctl.report.excitation import design_document
    from wamctl.runs.store import new_stamped_dir
    from wamctl.specs import load_spec

    spec_path = Path(spec_path)
    spec = load_spec(spec_path)
    if not isinstance(spec, ExcitationSpec):
        raise SpecError(f"{spec_path}: kind: {spec.kind!r}; `wamctl excite` designs specs of kind excitation")
    base_dir = spec_path.parent
    des = design(spec, base_dir, progress)
    dyn, friction = declared_model(spec, base_dir)
    use = sampled_limit_use(des.trajectory, limits_of(spec), dyn, friction)
    out = new_stamped_dir(out if out is not None else spec.out_dir, f"{spec.name}-design")
    raw = load_yaml(spec_path)
    designed = designed_spec(raw, des.trajectory, base_dir)
    header = (f"# designed by `wamctl excite {spec_path.name}`: {des.criterion}, condition number "
              f"{des.condition_number:.4g} over {des.n_target} base parameters\n")
    (out / "excitation.yaml").write_text(header + yaml.safe_dump(designed, sort_keys=False))
    outlook = instruments_outlook(spec, des.trajectory, base_dir)
    summary = {"spec": str(spec_path.resolve()), "criterion": des.criterion, "objective": des.objective,
               "instruments_outlook": outlook,
               "condition_number": des.condition_number, "base_parameters_targeted": des.n_target,
               "starts": des.starts, "limits_used": _use_dict(use), "trajectory": des.trajectory.to_dict(),
               "world": des.clearance.to_dict() if des.clearance is not None else None,
               "scaled_back_to": des.scaled_back}
    (out / "design.json").write_text(_json(summary))
    design_document(spec, des, use, limits_of(spec), out, outlook)
    return out, des, use


def _json(obj) -> str:
    import json

    from wamctl.runs.store import json_default
    return json.dumps(obj, indent=2, default=json_default)
