"""Building blocks every experiment kind shares: the backend, the plant, the controller, a closed-loop stage.

Experiment modules (one per kind) expose::

    plan(spec, base_dir) -> Plan            describe: the reference and what will be checked, nothing moves
    execute(spec, plan, run, progress)      run it on the backend, recording into the run directory
    report(run_path) -> Document            analyse the run directory and build the report
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from wamctl.backends.base import ArmBackend
from wamctl.control.controllers import JointController, friction_feedforward_Nm
from wamctl.control.trajectory import Reference
from wamctl.errors import SpecError
from wamctl.experiments.engine import LoopRecorder, run_loop
from wamctl.io import resolve_path
from wamctl.model import params as P
from wamctl.model.dynamics import Payload, WamDynamics
from wamctl.model.plant import resolve_friction
from wamctl.model.robots import get_robot
from wamctl.runs.store import RunDir
from wamctl.specs import Common, check_positions
from wamctl.specs.common import link_parameters
from wamctl.specs.load import load_model_links

log = logging.getLogger(__name__)


@dataclass
class Plan:
    """What an experiment will do: its reference, a human summary, and the torque it will feed forward."""

    reference: Reference
    summary: list[str] = field(default_factory=list)
    feedforward_Nm: np.ndarray | None = None
    torque_check: Callable[[], str] | None = None
    """Checks the torque the reference needs against the limits (:func:`check_planned_torque`): returns the
    check made, raises SpecError naming the move that would saturate. Called by :meth:`check_limits`."""
    robot: str | None = None
    """The arm (a spec's ``robot``; None: the wam7): its limits check the reference."""

    @property
    def duration_s(self) -> float:
        return float(len(self.reference) * P.CONTROL_RATE_HZ ** -1)

    def check_limits(self) -> list[str]:
        """Every setpoint against the position and torque limits; returns the checks made, raises SpecError."""
        r = get_robot(self.robot)
        try:
            check_positions(self.reference.q_rad, "reference", r)
        except ValueError as exc:
            raise SpecError(str(exc)) from None
        done = [f"{len(self.reference)} position setpoints within the joint limits"]
        speed = np.abs(self.reference.qd_rad_s).max(axis=0)
        over = speed > r.qd_max_rad_s
        if over.any():
            j = int(np.argmax(over))
            raise SpecError(f"reference: joint {j + 1} velocity {speed[j]:.3f} rad/s reaches the velocity limit "
                            f"{r.qd_max_rad_s[j]} rad/s (max {speed[j]:.9g}: the safety check faults above it): "
                            "plan a slower motion")
        if speed.max() > 0:
            done.append(f"reference speeds within {r.qd_max_rad_s[0]} rad/s (max {speed.max():.3f} rad/s)")
        else:   # poses only (e.g. an HMI block): the motion between them is made while running
            done.append(f"poses only, no planned motion: speeds are limited while running ({r.qd_max_rad_s[0]} "
                        "rad/s fault limit)")
        if self.feedforward_Nm is not None:
            ff = np.abs(self.feedforward_Nm).max(axis=0)
            if (ff > r.tau_max_Nm).any():
                j = int(np.argmax(ff > r.tau_max_Nm))
                raise SpecError(f"controller.friction_ff: joint {j + 1} feed-forward {ff[j]:.2f} N m exceeds the "
                                f"torque limit {r.tau_max_Nm[j]} N m")
            done.append("feed-forward torques within the torque limits")
        if self.torque_check is not None:
            done.append(self.torque_check())
        return done


def declared_dynamics(spec: Common, base_dir: Path | None = None) -> WamDynamics:
    """The model the controller knows: the rigid body of ``controller.declared_links`` (the datasheet's by
    default; a model file's ``links:``, e.g. an identified arm) and a declared payload, if any."""
    p = spec.controller.declared_payload
    return WamDynamics(Payload(p.mass_kg, tuple(p.com_m)) if p else None,
                       declared_links(spec.controller.declared_links, base_dir, getattr(spec, "robot", None)))


def declared_links(value, base_dir: Path | None = None, robot=None) -> P.LinkParameters:
    """:class:`LinkParameters` of a ``declared_links`` value: None (the datasheet of ``robot``, default the
    wam7), a links mapping, or a model file with a ``links:`` section (relative to ``base_dir`` or the working
    directory)."""
    if isinstance(value, str):
        value = load_model_links(resolve_path(value, base_dir))
    try:
        return link_parameters(value, robot)
    except ValueError as exc:
        raise SpecError(f"controller.declared_links: {exc}") from None


def feedforward_for(spec: Common, reference: Reference, base_dir: Path | None) -> np.ndarray | None:
    """Eq. 4.3 feed-forward over the whole reference for ``pd_g_ff``; None otherwise."""
    c = spec.controller
    if c.kind != "pd_g_ff":
        return None
    return declared_feedforward_Nm(spec, reference, resolve_friction(c.friction_ff, base_dir, _n_joints(spec)),
                                   c.ff_inertia)


def _n_joints(spec: Common) -> int:
    return get_robot(getattr(spec, "robot", None)).n_joints


def declared_feedforward_Nm(spec: Common, reference: Reference, friction, with_inertia: bool) -> np.ndarray:
    """Eq. 4.3 over ``reference`` with ``friction`` (a FrictionModel) and, ``with_inertia``, the ``m qdd_r`` term
    of the declared rigid body's diagonal inertia at ``q0``."""
    inertia = np.diag(declared_dynamics(spec).mass_matrix(np.asarray(spec.q0_rad))) if with_inertia else None
    return friction_feedforward_Nm(reference.qd_rad_s, reference.qdd_rad_s2, friction, inertia)


def planning_dynamics(spec: Common, base_dir: Path | None = None) -> WamDynamics:
    """The rigid body a plan is checked with: the declared links, and the payload the spec puts at the wrist
    (the plant's, else the declared one: the friction sweep's gravity check makes the same choice)."""
    p = spec.plant.effects.payload or spec.controller.declared_payload
    return WamDynamics(Payload(p.mass_kg, tuple(p.com_m)) if p else None,
                       declared_links(spec.controller.declared_links, base_dir, getattr(spec, "robot", None)))


def _declared_friction(spec: Common, base_dir: Path | None):
    """The friction the spec declares (``plant.friction``); none when it cannot be read (a missing file is
    :func:`wamctl.specs.common.check_files`' to name, or the run's: the torque check does not pre-empt it)."""
    from wamctl.errors import WamctlError
    from wamctl.model.friction import FrictionModel
    try:
        return resolve_friction(spec.plant.friction, base_dir, _n_joints(spec))
    except WamctlError:
        return FrictionModel.zero(_n_joints(spec))


def planned_torque_Nm(spec: Common, reference: Reference, base_dir: Path | None = None,
                      friction=None) -> np.ndarray:
    """(n, 7) torque the reference needs at every pose, N m: rigid body (gravity, Coriolis, acceleration) of
    :func:`planning_dynamics` plus the spec's friction (``friction``, default ``plant.friction``: the Coulomb
    level in the direction of motion and the viscous term)."""
    dyn = planning_dynamics(spec, base_dir)
    friction = _declared_friction(spec, base_dir) if friction is None else friction
    return (dyn.inverse_dynamics_many(reference.q_rad, reference.qd_rad_s, reference.qdd_rad_s2)
            + friction.friction_torque(reference.qd_rad_s))


def check_planned_torque(spec: Common, reference: Reference, base_dir: Path | None = None,
                         field_name: str = "plan") -> str:
    """The torque every pose of ``reference`` needs (:func:`planned_torque_Nm`) against the torque limits.

    A joint that needs more than its limit would sit at the limit, off its reference, until the pose changes
    (the demo's joint 2 before issue 32: -17.2 N m of gravity and 3.56 N m of Coulomb friction against 20 N m),
    so the plan is refused, as the friction sweep refuses one whose gravity load leaves too little: a SpecError
    naming the first such move (its index among the plan's moves, label, times), the joint, the torque needed
    (gravity, friction, the rest) and the limit. Returns the check made."""
    friction = _declared_friction(spec, base_dir)
    need = planned_torque_Nm(spec, reference, base_dir, friction)
    tau_max = get_robot(getattr(spec, "robot", None)).tau_max_Nm
    ratio = np.abs(need) / tau_max
    over = ratio > 1.0
    if not over.any():
        k, j = np.unravel_index(int(np.argmax(ratio)), ratio.shape)
        return (f"torque needed at most {ratio[k, j]:.0%} of a limit (joint {j + 1}: {need[k, j]:+.1f} of "
                f"{tau_max[j]:g} N m at {reference.t_s[k]:.2f} s)")
    bounds = [i for i, _ in reference.segments] + [len(reference)]
    moving = np.abs(reference.qd_rad_s).max(axis=1) > 0
    bad, move_no = [], 0
    for (i0, label), i1 in zip(reference.segments, bounds[1:]):
        is_move = bool(moving[i0:i1].any())
        move_no += is_move
        if over[i0:i1].any():
            bad.append((i0, i1, label, move_no if is_move else None))
    n_moves = move_no
    i0, i1, label, move_no = bad[0]
    k, j = np.unravel_index(int(np.argmax(ratio[i0:i1])), ratio[i0:i1].shape)
    k += i0
    gravity = planning_dynamics(spec, base_dir).gravity(reference.q_rad[k])[j]
    coulomb = friction.friction_torque(reference.qd_rad_s[k])[j]
    rest = need[k, j] - gravity - coulomb
    where = f"move {move_no} of {n_moves}" if move_no else "hold"
    more = f"; {len(bad) - 1} more segment{'s' if len(bad) > 2 else ''} too" if len(bad) > 1 else ""
    raise SpecError(f"{field_name}: {where} ({label}, {reference.t_s[i0]:.2f}-{reference.t_s[i1 - 1]:.2f} s) "
                    f"would saturate joint {j + 1}: it needs {need[k, j]:+.2f} N m at {reference.t_s[k]:.2f} s "
                    f"(gravity {gravity:+.2f}, friction {coulomb:+.2f}, acceleration {rest:+.2f}) against its"
                    f" {tau_max[j]:g} N m torque limit{more}; change q0_rad, the direction or "
                    "size of the move")


def make_joint_controller(spec: Common, feedforward_Nm: np.ndarray | None = None) -> JointController:
    kp, kd, ki = spec.controller.gains()
    gravity = declared_dynamics(spec).gravity_view if spec.controller.gravity_compensation else None
    return JointController(kp, kd, ki, 1.0 / P.CONTROL_RATE_HZ, gravity=gravity, feedforward_Nm=feedforward_Nm)


def closed_loop_stage(backend: ArmBackend, controller: JointController, reference: Reference,
                      run: RunDir | None, progress=None, table: str = "data",
                      t_offset_s: float = 0.0) -> np.ndarray:
    """Run one reference on an open backend; every sample reaches ``run/table`` even if the stage raises.

    Returns the recorded rows (n, columns) as in :func:`wamctl.experiments.engine.data_columns`.
    """
    truth = hasattr(backend, "truth")
    writer = None
    if run is not None:
        from wamctl.experiments.engine import data_columns
        writer = run.table(table, data_columns(truth, backend.n_joints))
    rec = LoopRecorder(len(reference), truth, writer, t_offset_s, n_joints=backend.n_joints)
    try:
        run_loop(backend, controller, reference, rec, progress)
    finally:
        rec.flush()
        if writer is not None:
            writer.close()
        if run is not None:
            _record_backend_state(backend, run, t_offset_s)
            _record_loop_events(rec, backend, run)
    return rec.result()


def _record_loop_events(rec: LoopRecorder, backend: ArmBackend, run: RunDir) -> None:
    """After a stage (even a failed one): each stretch of a joint held at its torque limit (the backend's) or
    off its reference becomes one event of the run (:mod:`wamctl.analysis.loop_events`). The same on every
    backend: the rows are the loop's, with the torque the backend applied."""
    import pandas as pd

    from wamctl.analysis.loop_events import loop_events_of_table
    try:
        data = pd.DataFrame(rec.result(), columns=rec.columns)
        for e in loop_events_of_table(data, backend.limits.tau_max_Nm):
            run.event(e.start_s, e.kind, e.joint, e.detail)
    except Exception:  # noqa: BLE001 - bookkeeping must not mask the stage's own outcome
        log.exception("recording the loop's events failed")


def _record_backend_state(backend: ArmBackend, run: RunDir, t_offset_s: float) -> None:
    """After a stage (even a failed one): refresh the manifest's backend entry (the CAN backend's loop
    statistics and watchdog verdict change during a run) and record the events the backend reports through
    an optional ``drain_events() -> [(t_s, kind, joint, detail)]`` (overruns, link faults)."""
    try:
        run.update_manifest(backend=backend.describe())
        for t_s, kind, joint, detail in getattr(backend, "drain_events", list)():
            run.event(t_offset_s + t_s, kind, joint, detail)
    except Exception:  # noqa: BLE001 - bookkeeping must not mask the stage's own outcome
        log.exception("recording the backend's state failed")
