"""Building blocks every experiment kind shares: the backend, the plant, the controller, a closed-loop stage.

Experiment modules (one per kind) expose::

    plan(spec, base_dir) -> Plan            describe: the reference and what will be checked, nothing moves
    execute(spec, plan, run, progress)      run it on the backend, recording into the run directory
    report(run_path) -> Document            analyse the run directory and build the report
"""

from __future__ import annotations

import logging
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

    @property
    def duration_s(self) -> float:
        return float(len(self.reference) * P.CONTROL_RATE_HZ ** -1)

    def check_limits(self) -> list[str]:
        """Every setpoint against the position and torque limits; returns the checks made, raises SpecError."""
        try:
            check_positions(self.reference.q_rad, "reference")
        except ValueError as exc:
            raise SpecError(str(exc)) from None
        done = [f"{len(self.reference)} position setpoints within the joint limits"]
        speed = np.abs(self.reference.qd_rad_s).max(axis=0)
        over = speed > P.QD_MAX_RAD_S
        if over.any():
            j = int(np.argmax(over))
            raise SpecError(f"reference: joint {j + 1} velocity {speed[j]:.3f} rad/s above the limit "
                            f"{P.QD_MAX_RAD_S[j]} rad/s")
        done.append(f"reference speeds within {P.QD_MAX_RAD_S[0]} rad/s (max {speed.max():.3f})")
        if self.feedforward_Nm is not None:
            ff = np.abs(self.feedforward_Nm).max(axis=0)
            if (ff > P.TAU_MAX_NM).any():
                j = int(np.argmax(ff > P.TAU_MAX_NM))
                raise SpecError(f"controller.friction_ff: joint {j + 1} feed-forward {ff[j]:.2f} N m exceeds the "
                                f"torque limit {P.TAU_MAX_NM[j]} N m")
            done.append("feed-forward torques within the torque limits")
        return done


def declared_dynamics(spec: Common, base_dir: Path | None = None) -> WamDynamics:
    """The model the controller knows: the rigid body of ``controller.declared_links`` (the datasheet's by
    default; a model file's ``links:``, e.g. an identified arm) and a declared payload, if any."""
    p = spec.controller.declared_payload
    return WamDynamics(Payload(p.mass_kg, tuple(p.com_m)) if p else None,
                       declared_links(spec.controller.declared_links, base_dir))


def declared_links(value, base_dir: Path | None = None) -> P.LinkParameters:
    """:class:`LinkParameters` of a ``declared_links`` value: None (the datasheet), a links mapping, or a model
    file with a ``links:`` section (relative to ``base_dir`` or the working directory)."""
    if isinstance(value, str):
        value = load_model_links(resolve_path(value, base_dir))
    try:
        return link_parameters(value)
    except ValueError as exc:
        raise SpecError(f"controller.declared_links: {exc}") from None


def feedforward_for(spec: Common, reference: Reference, base_dir: Path | None) -> np.ndarray | None:
    """Eq. 4.3 feed-forward over the whole reference for ``pd_g_ff``; None otherwise."""
    c = spec.controller
    if c.kind != "pd_g_ff":
        return None
    return declared_feedforward_Nm(spec, reference, resolve_friction(c.friction_ff, base_dir), c.ff_inertia)


def declared_feedforward_Nm(spec: Common, reference: Reference, friction, with_inertia: bool) -> np.ndarray:
    """Eq. 4.3 over ``reference`` with ``friction`` (a FrictionModel) and, ``with_inertia``, the ``m qdd_r`` term
    of the declared rigid body's diagonal inertia at ``q0``."""
    inertia = np.diag(declared_dynamics(spec).mass_matrix(np.asarray(spec.q0_rad))) if with_inertia else None
    return friction_feedforward_Nm(reference.qd_rad_s, reference.qdd_rad_s2, friction, inertia)


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
        writer = run.table(table, data_columns(truth))
    rec = LoopRecorder(len(reference), truth, writer, t_offset_s)
    try:
        run_loop(backend, controller, reference, rec, progress)
    finally:
        rec.flush()
        if writer is not None:
            writer.close()
        if run is not None:
            _record_backend_state(backend, run, t_offset_s)
    return rec.result()


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
