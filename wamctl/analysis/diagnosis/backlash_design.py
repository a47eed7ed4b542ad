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
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from wamctl.model.friction import classic_friction_columns

MIN_SPEED_RAD_S = 0.005          # sliding samples (a slow crossing)
CROSSING_PERIOD_S = 16.0         # slow: the link falls through the gap while the motor barely moves
CROSSING_AMPLITUDE_RAD = 0.25    # the motion about the crossing pose
FD_STEP_RAD = 1e-4


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


@dataclass
class CrossingRun:
    """The designed trajectory (a :class:`~wamctl.analysis.identification.excitation.FourierTrajectory`), its
    separation and the run's (noise floors), the gravity slope at the crossing (N m/rad) and the limits it uses."""

    trajectory: object
    separation: float
    original: float
    slope_Nm_rad: float
    limit_use: object


def design_crossing(dynamics, friction, q0_rad, j: int, gap_rad: float, noise_Nm: float, limits,
                    run_q: np.ndarray, run_qd: np.ndarray, period_s: float = CROSSING_PERIOD_S,
                    amplitude_rad: float = CROSSING_AMPLITUDE_RAD, fill: float = 0.95, n_poses: int = 4,
                    rate_hz: float = 25.0) -> CrossingRun:
    """Joint ``j`` alone moving slowly about the steepest gravity crossings (:func:`crossing_poses`, the first
    ``n_poses``): ``q_j = q* + A (sin wt - sin 2wt / 2)`` (excite's two-harmonic series, at rest at its ends),
    scaled to ``fill`` of its closest limit by excite's check; the pose whose separation is largest wins. The run's
    own separation from ``run_q, run_qd`` (n, 7). Raises ValueError when the joint's gravity never changes sign
    within its range or no candidate keeps within the limits."""
    from wamctl.analysis.diagnosis.discriminate import scaled_to_limits
    from wamctl.analysis.identification.excitation import FourierTrajectory

    poses = crossing_poses(dynamics, q0_rad, j, limits.q_min_rad, limits.q_max_rad)[:n_poses]
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
        q, qd, _ = traj.evaluate(t)
        sep = separation(dynamics, q, qd, j, gap_rad, noise_Nm)
        if best is None or sep > best.separation:
            best = CrossingRun(traj, sep, 0.0, slope, use)
    if best is None:
        raise ValueError("no crossing trajectory keeps within the limits")
    best.original = separation(dynamics, run_q, run_qd, j, gap_rad, noise_Nm)
    return best
