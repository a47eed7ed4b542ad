"""The run's arrays the diagnosis fits on: rigid-body torque, the declared model's torque, each joint's samples
(no I/O).

``y = tau - rnea(q, qd, qdd) - known`` is what friction and any missing effect must supply at a joint's
sliding samples; ``known`` is what a declared model file adds beyond the rigid body (friction with its
Stribeck and drift terms, ripple). Each joint's sliding samples (in time order) are cut into ``n_blocks``
contiguous blocks of equal size, dealt into ``n_folds`` folds (block ``b`` -> fold ``b % n_folds``): a joint
that moves in one part of the run only still has every fold populated.
"""

from __future__ import annotations

import numpy as np

from wamctl.analysis.diagnosis.candidates import payload_basis, ripple_columns
from wamctl.analysis.diagnosis.design import Design, JointData
from wamctl.analysis.diagnosis.signals import GridSignal, Signals
from wamctl.model.dynamics import WamDynamics
from wamctl.model.effects import friction_drift_scale, ripple_series, ripple_torque_Nm
from wamctl.model.friction import FrictionModel

MAX_SAMPLES_PER_JOINT = 8000      # decimation above this (smoothed signals: little information is lost)
MAX_RNEA_GRID = 30000             # full-rate rigid-body torque: interpolated from at most this many samples
MAX_STIFFNESS_GRID = 3000         # gravity stiffness: computed at about this many samples, interpolated
# the last link's columns of the joint torque regressor (m, m c, inertia): link 7's (60:70) on the wam7, link 4's
# on the wam4 (a payload sits on the last link)
PAYLOAD_REGRESSOR = slice(-10, None)


def declared_delay_s(effects: dict | None) -> float:
    """The measurement delay (s) a declared model's ``effects`` mapping gives (0 without one)."""
    return float(((effects or {}).get("delay") or {}).get("delay_s", 0.0))


def prepare_design(sig: Signals, dyn: WamDynamics, friction_given: FrictionModel | None, effects: dict | None,
                   n_blocks: int, n_folds: int, want_payload: bool) -> tuple[Design, dict[int, JointData]]:
    """The run's :class:`Design` and {0-based joint: :class:`JointData`} of every diagnosed joint.

    ``dyn`` is the declared rigid body; ``friction_given``/``effects`` the declared model file's friction
    (None: fitted) and effects; ``want_payload`` adds the payload regressor rows to each joint's data."""
    dec = 1
    n_mov = max(int(sig.moving[:, j].sum()) for j in sig.joints)
    if n_mov > MAX_SAMPLES_PER_JOINT:
        dec = int(np.ceil(n_mov / MAX_SAMPLES_PER_JOINT))
    keep = np.zeros(sig.n, bool)
    keep[::dec] = True
    union = np.flatnonzero(keep & sig.moving[:, sig.joints].any(axis=1))
    rnea, reg = _rigid_body_rows(dyn, sig, union, want_payload)
    coarse = union[:: max(1, len(union) // MAX_STIFFNESS_GRID)]
    dgdq_c = _gravity_stiffness(dyn, sig, coarse)
    known, known_other = declared_torque(sig, friction_given, effects)
    delay = declared_delay_s(effects)
    des = Design(sig, _rigid_body_full(dyn, sig), known, known_other, None, friction_given, n_folds, dec, union)
    des.robot = dyn.robot.name        # the run's arm (its payload frame, base parameters: arm.robot_of)
    jds = {}
    for j in sig.joints:
        idx = np.flatnonzero(keep & sig.moving[:, j])
        u = np.searchsorted(union, idx)          # the joint's samples among the union's
        block = np.minimum((np.arange(len(idx)) * n_blocks) // max(len(idx), 1), n_blocks - 1)
        tau_j = sig.at("tau", idx, -delay / sig.dt_s, j)      # a declared delay: the torque d earlier
        y = tau_j - rnea[u, j] - known[idx, j]
        qdd_j = sig.at("qdd", idx, joint=j)
        extra = {"t_rel": sig.t_s[idx] - sig.t_s[0], "block": block, "tau": tau_j,
                 "dgdq_full": GridSignal(coarse, dgdq_c[:, [j]])}
        if want_payload:
            extra["payload"] = reg[u, j, PAYLOAD_REGRESSOR]
            extra["payload_basis"] = payload_basis(extra["payload"])
            extra["links_base"] = link_base_rows(reg[u, j, :], qdd_j, j, dyn.robot.name)
        jds[j] = JointData(j, idx, sig.t_s[idx], sig.at("q", idx, joint=j), sig.qd_rad_s[idx, j], qdd_j, y,
                           block % n_folds, extra)
    if want_payload:
        del reg
    return des, jds


def _rigid_body_rows(dyn: WamDynamics, sig: Signals, rows: np.ndarray,
                     want_payload: bool) -> tuple[np.ndarray, np.ndarray | None]:
    """Rigid-body torque (r, 7) at the samples ``rows`` (r,), and the inertial regressor (r, 7, 70) there."""
    q, qd, qdd = sig.at("q", rows), sig.at("qd", rows), sig.at("qdd", rows)
    return dyn.inverse_dynamics_many(q, qd, qdd), (dyn.torque_regressor(q, qd, qdd) if want_payload else None)


def link_base_rows(inertial: np.ndarray, qdd_j: np.ndarray, j: int, robot=None) -> np.ndarray:
    """(m, nb) the rigid-body base columns (links and armature; :mod:`wamctl.analysis.identification.base`) of
    joint ``j``'s torque rows, from its inertial regressor rows (m, 10 n) and its acceleration (m,): what a refit
    of the arm's own parameters (``robot``'s, default the wam7) can change in that joint's torque."""
    from wamctl.analysis.identification.base import base_parameters

    base = base_parameters(robot)
    n_inertial, n = 10 * base.n_joints, base.n_joints
    Y = np.zeros((len(inertial), base.n_standard))
    Y[:, :n_inertial] = inertial
    Y[:, n_inertial + j] = qdd_j
    cols = base.independent < n_inertial + n          # not the friction, which each joint's model fits
    return base.regressor(Y)[:, cols]


def _rigid_body_full(dyn: WamDynamics, sig: Signals) -> GridSignal:
    """Rigid-body torque (n, 7) at every sample (interpolated from a uniform grid: the delay shifts it in time)."""
    stride = max(1, sig.n // MAX_RNEA_GRID)
    grid = np.arange(0, sig.n, stride)
    if grid[-1] != sig.n - 1:
        grid = np.append(grid, sig.n - 1)
    q, qd, qdd = sig.at("q", grid), sig.at("qd", grid), sig.at("qdd", grid)
    return GridSignal(grid, dyn.inverse_dynamics_many(q, qd, qdd))


def _gravity_stiffness(dyn: WamDynamics, sig: Signals, rows: np.ndarray, eps: float = 1e-4) -> np.ndarray:
    """(r, 7) gravity stiffness ``dg_j / dq_j`` of the diagnosed joints at the samples ``rows`` (r,) (backlash:
    the link sits w/2 away from the encoder), by forward differences."""
    q = sig.at("q", rows)
    out = np.zeros((len(rows), q.shape[1]))
    g0 = dyn.gravity_many(q)
    for j in sig.joints:
        qj = q.copy()
        qj[:, j] += eps
        out[:, j] = (dyn.gravity_many(qj)[:, j] - g0[:, j]) / eps
    return out


def declared_torque(sig: Signals, friction: FrictionModel | None, effects: dict | None) -> tuple[np.ndarray,
                                                                                                 np.ndarray]:
    """(n, 7) torque of the declared model beyond the rigid body when a model file gives it (friction,
    ripple; zero when friction is fitted from the data), and (n, 7) its part that is not friction (at rest,
    the friction is what the stall analysis estimates)."""
    nj = sig.q_raw_rad.shape[1]      # (q_rad would compute the full-rate smoothed position: other numbers)
    if friction is None:       # nothing declared beyond the rigid body: read-only zeros, no memory
        zero = np.broadcast_to(0.0, (sig.n, nj))
        return zero, zero
    out = np.zeros((sig.n, nj))
    other = np.zeros((sig.n, nj))
    fx = effects or {}
    fr = friction
    if fx.get("stribeck"):
        s = fx["stribeck"]
        m = np.zeros(nj, bool)
        m[[j - 1 for j in s["joints"]]] = True
        r = float(s.get("breakaway_ratio", 1.6))
        fr = fr.with_stribeck(np.where(m, fr.fc_pos_Nm * r, np.nan), np.where(m, fr.fc_neg_Nm * r, np.nan),
                              np.where(m, float(s.get("vs_rad_s", 0.05)), np.nan), float(s.get("delta", 2.0)))
    f = fr.friction_torque(sig.qd_rad_s)
    if fx.get("friction_drift"):
        s = fx["friction_drift"]
        scale = friction_drift_scale(sig.t_s - sig.t_s[0], float(s.get("fraction", -0.4)),
                                     float(s.get("time_constant_s", 20.0)))
        for jj in s["joints"]:
            f[:, jj - 1] *= scale
    out += f
    if fx.get("position_ripple"):
        s = fx["position_ripple"]
        per = float(s.get("period_rad", 0.2))
        amps, phases = ripple_series(s.get("amplitude_Nm", 0.5), s.get("phase_rad", 0.0), s.get("harmonics"))
        sin_cos = np.ravel(np.column_stack([amps * np.cos(phases), amps * np.sin(phases)]))
        for jj in s["joints"]:
            j = jj - 1
            q = sig.q_rad[:, j]
            # the model's torque is smoothed like the measured one: each harmonic as the filter leaves it
            out[:, j] -= ripple_columns(q, sig.qd_rad_s[:, j], per, sig.window, sig.gauss, sig.dt_s,
                                        len(amps)) @ sin_cos
            other[:, j] -= ripple_torque_Nm(q, amps, 2 * np.pi / per, phases)
    return out, other
