"""The run that shows backlash behind a motor-side encoder: slow crossings of the pose where the joint's gravity
torque changes sign (no I/O).

With the encoder on the motor and a gap ``2 b`` between motor and link, the link hangs ``b`` from the motor on the
side gravity pulls it to: ``q_link = q_motor - b sgn(g_j)``. The torque the motor gives is the gravity of the link
where it is, and the model evaluates it where the encoder says: the residual is ``g_j(q_link) - g_j(q_motor) ~
-b sgn(g_j) dg_j/dq_j``. Where ``g_j`` keeps one sign over a run this is a constant, which the fitted friction's
offset absorbs (the run cannot tell the gap from nothing); where ``g_j`` changes sign the link falls through the
gap and the residual steps by ``2 b |dg_j/dq_j|``, which no friction (tied to the velocity's sign) or offset
reproduces. The design puts the crossing in the middle of a slow back-and-forth motion of the joint alone.

:func:`signature`: that residual on a trajectory's sliding samples; :func:`separation`: what the nuisance fit
(Coulomb per direction, viscous, offset) leaves of it, RMS in noise floors; :func:`design_crossing`: the pose with
the steepest gravity crossing within the joint's range (the other joints at the run's pose, or a few poses of the
shoulder and elbow) and the slow two-harmonic motion about it, scaled within excite's limits.

Where gravity is small (the wrist) that step stays near the floor even for a large gap, and the same slow motion
shows the gap another way: at each of its reversals, where the link comes to rest held only by its own friction
(the torque the rigid link needs there, ``rnea_j - armature_j qdd_j``, is below the link's share of the joint's
Coulomb friction), the link stays put while the motor turns round and crosses the gap with only its own inertia:
the measurement leads the link by the gap, which the backlash onset test
(:mod:`wamctl.analysis.diagnosis.backlash`) sees against its resolution (``MIN_BAND_TOLERANCES`` detection
tolerances). :func:`reversal_leads` predicts those leads, :func:`reversal_separation` their RMS over a
trajectory's reversals in units of that resolution; the design is scored on both and says which.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from wamctl.analysis.diagnosis.backlash import MIN_BAND_TOLERANCES
from wamctl.model.friction import classic_friction_columns

MIN_SPEED_RAD_S = 0.005          # sliding samples (a slow crossing)
CROSSING_PERIOD_S = 16.0         # slow: the link falls through the gap while the motor barely moves
CROSSING_AMPLITUDE_RAD = 0.25    # the motion about the crossing pose
FD_STEP_RAD = 1e-4
# the share of a joint's Coulomb friction assumed on the link side of a gap (bearings and seals after the gear):
# not known from one run; a low share makes fewer reversals count as crossings (a conservative prediction)
LINK_FRICTION_SHARE = 0.2
CROSSING_PERIODS = 8             # periods of the designed run: two reversals each, sixteen in all


def gravity_and_slope(dynamics, q: np.ndarray, j: int) -> tuple[np.ndarray, np.ndarray]:
    """(n,) joint ``j``'s gravity torque at the poses ``q`` (n, 7) and its derivative along ``q_j`` (central
    difference)."""
    dq = np.zeros(q.shape[1])
    dq[j] = FD_STEP_RAD
    g = dynamics.gravity_many(q)[:, j]
    s = (dynamics.gravity_many(q + dq)[:, j] - dynamics.gravity_many(q - dq)[:, j]) / (2 * FD_STEP_RAD)
    return g, s


def signature(dynamics, q: np.ndarray, qd: np.ndarray, j: int, gap_rad: float) -> tuple[np.ndarray, np.ndarray]:
    """(m,) the residual a total gap ``gap_rad`` behind the encoder gives at joint ``j``'s sliding samples, and
    (m,) their speeds."""
    m = np.abs(qd[:, j]) > MIN_SPEED_RAD_S
    g, s = gravity_and_slope(dynamics, q[m], j)
    return -0.5 * gap_rad * np.sign(g) * s, qd[m, j]


def separation(dynamics, q: np.ndarray, qd: np.ndarray, j: int, gap_rad: float, noise_Nm: float) -> float:
    """What friction and an offset refitted cannot reproduce of the gap's residual (:func:`signature`) on a
    trajectory, RMS in units of the noise floor ``noise_Nm`` (0 when the joint does not slide)."""
    y, v = signature(dynamics, q, qd, j, gap_rad)
    if len(y) < 10:
        return 0.0
    X = np.column_stack([classic_friction_columns(v), np.ones(len(v))])
    th, *_ = np.linalg.lstsq(X, y, rcond=None)
    return float(np.sqrt(np.mean((y - X @ th) ** 2)) / noise_Nm)


def reversal_leads(dynamics, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray, j: int, gap_rad: float,
                   fc_Nm: float, share: float = LINK_FRICTION_SHARE) -> np.ndarray:
    """(k,) the lead (rad) a total gap ``gap_rad`` behind a motor-side encoder gives at each of the k reversals of
    joint ``j`` along a trajectory sampled as ``q, qd, qdd`` (n, 7): ``gap_rad`` where the torque the rigid link
    needs at the turning point, ``rnea_j - armature_j qdd_j``, is below ``share x fc_Nm`` (the link comes to rest
    on its own friction and the motor crosses the gap to drive it back), else 0 (the drive keeps pressing the
    link on one flank through the turn). A reversal: the joint's velocity changes sign between samples faster than
    ``MIN_SPEED_RAD_S`` (a dwell at rest, or a measured joint's noise at rest, is not one); its turning point the
    slower of the two samples about the change."""
    v = qd[:, j]
    keep = np.flatnonzero(np.abs(v) > MIN_SPEED_RAD_S)
    if len(keep) < 2:
        return np.zeros(0)
    s = np.sign(v[keep])
    ch = np.flatnonzero(s[1:] != s[:-1])
    if not len(ch):
        return np.zeros(0)
    a, b = keep[ch], keep[ch + 1]
    k = np.where(np.abs(v[a]) <= np.abs(v[b]), a, b)
    need = dynamics.inverse_dynamics_many(q[k], qd[k], qdd[k])[:, j] - dynamics.armature_kg_m2[j] * qdd[k, j]
    return np.where(np.abs(need) < share * max(float(fc_Nm), 0.0), float(gap_rad), 0.0)


def reversal_separation(dynamics, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray, j: int, gap_rad: float,
                        fc_Nm: float, tol_rad: float) -> tuple[float, int, int]:
    """(separation, crossings, reversals): the RMS over joint ``j``'s reversals of the leads
    :func:`reversal_leads` predicts, in units of the backlash onset test's resolution (``MIN_BAND_TOLERANCES``
    detection tolerances ``tol_rad``: without a gap a light joint's measurement may lead by up to about four), with
    the number of reversals where the gap is crossed and of reversals (0, 0, 0 without reversals)."""
    lead = reversal_leads(dynamics, q, qd, qdd, j, gap_rad, fc_Nm)
    if not len(lead) or tol_rad <= 0:
        return 0.0, 0, int(len(lead))
    return (float(np.sqrt(np.mean(lead ** 2)) / (MIN_BAND_TOLERANCES * tol_rad)), int(np.count_nonzero(lead)),
            int(len(lead)))


def crossing_poses(dynamics, q0_rad: np.ndarray, j: int, q_min: np.ndarray, q_max: np.ndarray,
                   margin_rad: float = CROSSING_AMPLITUDE_RAD + 0.05) -> list[tuple[np.ndarray, float]]:
    """Poses (7,) at which joint ``j``'s gravity torque changes sign with ``q_j`` at least ``margin_rad`` inside
    its range, with ``|dg_j/dq_j|`` there; the other joints at ``q0_rad``, or the shoulder (joint 2) and elbow
    (joint 4) moved to a few poses within their ranges. Steepest first."""
    others = [np.asarray(q0_rad, float)]
    for q2 in (-1.0, 0.0, 1.0):
        for q4 in (0.5, 1.5, 2.5):
            p = np.asarray(q0_rad, float).copy()
            if j != 1:
                p[1] = np.clip(q2, q_min[1], q_max[1])
            if j != 3:
                p[3] = np.clip(q4, q_min[3], q_max[3])
            others.append(p)
    grid = np.linspace(q_min[j] + margin_rad, q_max[j] - margin_rad, 181)
    out = []
    for p in others:
        Q = np.tile(p, (len(grid), 1))
        Q[:, j] = grid
        g, _ = gravity_and_slope(dynamics, Q, j)
        for k in np.flatnonzero(np.sign(g[:-1]) * np.sign(g[1:]) < 0):
            qz = grid[k] - g[k] * (grid[k + 1] - grid[k]) / (g[k + 1] - g[k])
            pose = p.copy()
            pose[j] = qz
            _, s = gravity_and_slope(dynamics, pose[None, :], j)
            out.append((pose, float(abs(s[0]))))
    return sorted(out, key=lambda x: -x[1])


def level_poses(dynamics, q0_rad: np.ndarray, j: int, q_min: np.ndarray, q_max: np.ndarray,
                amplitude_rad: float = CROSSING_AMPLITUDE_RAD, margin_rad: float = CROSSING_AMPLITUDE_RAD + 0.05,
                n: int = 3) -> list[np.ndarray]:
    """Poses (7,) about which joint ``j`` can move back and forth with the least gravity torque at its ends (where
    the link must rest on its own friction for a gap to be crossed): ``q_j`` on a grid ``margin_rad`` inside its
    range, the other joints at ``q0_rad`` or the shoulder (joint 2) and elbow (joint 4) moved to a few poses
    (as :func:`crossing_poses`); the ``n`` whose largest ``|g_j|`` over ``q_j +- 1.3 amplitude_rad`` (the
    two-harmonic series' ends) is smallest, smallest first."""
    q0_rad = np.asarray(q0_rad, float)
    others = [q0_rad]
    for q2 in (-1.0, 0.0, 1.0):
        for q4 in (0.5, 1.5, 2.5):
            p = q0_rad.copy()
            if j != 1:
                p[1] = np.clip(q2, q_min[1], q_max[1])
            if j != 3:
                p[3] = np.clip(q4, q_min[3], q_max[3])
            others.append(p)
    lo, hi = q_min[j] + margin_rad, q_max[j] - margin_rad
    if hi < lo:
        return []
    grid = np.r_[np.clip(q0_rad[j], lo, hi), np.linspace(lo, hi, 7)]
    ends = 1.3 * amplitude_rad * np.array([-1.0, -0.5, 0.0, 0.5, 1.0])
    scored = []
    for p in others:
        for v in grid:
            Q = np.tile(p, (len(ends), 1))
            Q[:, j] = v + ends
            pose = p.copy()
            pose[j] = v
            scored.append((float(np.abs(dynamics.gravity_many(Q)[:, j]).max()), pose))
    scored.sort(key=lambda x: x[0])
    return [pose for _, pose in scored[:n]]


@dataclass
class CrossingRun:
    """The designed trajectory (a :class:`~wamctl.analysis.identification.excitation.FourierTrajectory`), its
    separation and the run's (noise floors; the larger of the two ways the gap shows, ``seen_by``), the gravity
    slope at the crossing (N m/rad, 0 about a pose where gravity need not change sign), the limits it uses, and
    per way: the gravity step's separation (``torque_separation``, ``torque_original``) and the reversals' leads
    (``reversals``, ``reversals_original``: :func:`reversal_separation`'s (separation, crossings, reversals), the
    designed run's over ``CROSSING_PERIODS`` periods; None when no detection tolerance was given)."""

    trajectory: object
    separation: float
    original: float
    slope_Nm_rad: float
    limit_use: object
    torque_separation: float = 0.0
    torque_original: float = 0.0
    reversals: tuple | None = None
    reversals_original: tuple | None = None
    seen_by: str = "torque"


def design_crossing(dynamics, friction, q0_rad, j: int, gap_rad: float, noise_Nm: float, limits,
                    run_q: np.ndarray, run_qd: np.ndarray, period_s: float = CROSSING_PERIOD_S,
                    amplitude_rad: float = CROSSING_AMPLITUDE_RAD, fill: float = 0.95, n_poses: int = 4,
                    rate_hz: float = 25.0, tol_rad: float | None = None, fc_Nm: float | None = None,
                    run_qdd: np.ndarray | None = None) -> CrossingRun:
    """Joint ``j`` alone moving slowly about the steepest gravity crossings (:func:`crossing_poses`, the first
    ``n_poses``): ``q_j = q* + A (sin wt - sin 2wt / 2)`` (excite's two-harmonic series, at rest at its ends),
    scaled to ``fill`` of its closest limit by excite's check; the pose whose separation is largest wins. The run's
    own separation from ``run_q, run_qd`` (n, 7).

    With the joint's detection tolerance ``tol_rad`` and Coulomb level ``fc_Nm`` (and the run's ``run_qdd``), the
    reversals' leads are scored too (:func:`reversal_separation`), each candidate's separation is the larger of
    the two, and poses where gravity need not change sign (:func:`level_poses`) are candidates as well: a wrist
    whose gravity is too small for the step, or whose crossing lies outside its range, still shows the gap at its
    reversals. Raises ValueError when no pose is a candidate (the joint's gravity never changes sign within its
    range and no tolerance was given) or no candidate keeps within the limits."""
    from wamctl.analysis.diagnosis.discriminate import scaled_to_limits
    from wamctl.analysis.identification.excitation import FourierTrajectory

    leads = tol_rad is not None and fc_Nm is not None
    poses = crossing_poses(dynamics, q0_rad, j, limits.q_min_rad, limits.q_max_rad)[:n_poses]
    if leads:
        poses += [(p, 0.0) for p in level_poses(dynamics, q0_rad, j, limits.q_min_rad, limits.q_max_rad,
                                                amplitude_rad)]
    if not poses:
        raise ValueError(f"joint {j + 1}'s gravity torque does not change sign within its range")
    w = 2 * np.pi / period_s
    t = np.arange(int(period_s * rate_hz)) / rate_hz
    best = None
    for pose, slope in poses:
        a = np.zeros((len(pose), 2))
        b = np.zeros((len(pose), 2))
        a[j] = [amplitude_rad * w, -amplitude_rad * w]        # q_j - q* = A (sin wt - sin 2wt / 2)
        got = scaled_to_limits(FourierTrajectory(pose, period_s, a, b), limits, dynamics, friction, fill)
        if got is None:
            continue
        traj, use = got
        q, qd, qdd = traj.evaluate(t)
        sep = separation(dynamics, q, qd, j, gap_rad, noise_Nm)
        cand = CrossingRun(traj, sep, 0.0, slope, use, torque_separation=sep)
        if leads:
            rs, nc, nr = reversal_separation(dynamics, q, qd, qdd, j, gap_rad, fc_Nm, tol_rad)
            cand.reversals = (rs, nc * CROSSING_PERIODS, nr * CROSSING_PERIODS)
            if rs > sep:
                cand.separation, cand.seen_by = rs, "reversals"
        if best is None or cand.separation > best.separation:
            best = cand
    if best is None:
        raise ValueError("no crossing trajectory keeps within the limits")
    best.torque_original = separation(dynamics, run_q, run_qd, j, gap_rad, noise_Nm)
    best.original = best.torque_original
    if leads and run_qdd is not None:
        best.reversals_original = reversal_separation(dynamics, run_q, run_qd, run_qdd, j, gap_rad, fc_Nm, tol_rad)
        if best.seen_by == "reversals":
            best.original = best.reversals_original[0]
    return best
