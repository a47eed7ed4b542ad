"""Tool-point kinematics of the WAM with a palm-down BarrettHand and the differential inverse kinematics.

Frames and conventions
----------------------
* **Frame 0** is the WAM base frame of :mod:`wamctl.model.dynamics`: origin at the shoulder, z up (gravity along
  -z0), x forward (the direction the arm reaches at q1 = 0), y to the arm's left.
* **Tool point**: the grasp centre of the BarrettHand, ``tool_offset_m`` along the link-7 z axis from the wrist
  flange (DH frame 7). All Cartesian quantities (hand position, hit test, workspace bounds) refer to it.
* **Palm down**: the link-7 z axis points along -z0 (the hand grasps from above, thesis Figure 6.20 a). The whole
  orientation ``R_ref`` (palm down plus a fixed yaw, that of the start pose) is held; ``tilt`` is the angle between
  the link-7 z axis and -z0.

One IK step is weighted damped least squares on the pose error of the tool point (closed-loop IK), with joint
limits respected by a weighting that slows joints near their limits, a null-space pull towards a rest posture, a
joint-speed cap and a final clamp with a margin. The step runs in a numba kernel (:meth:`HandKinematics.step`);
:func:`orientation_error`, :func:`limit_weights`, :func:`dls_step` and :meth:`HandKinematics.tool_jacobian` are the
same formulas in numpy, the reference the kernel is tested against.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numba import njit

from wamctl.model import params as P
from wamctl.model.dynamics import WamDynamics

#: Grasp centre of the BarrettHand BH-280 from the wrist flange along link-7 z (palm ~0.09 m, fingers ~0.12 m;
#: our estimate of where a closed hand holds a small object).
TOOL_OFFSET_M = 0.15
#: Palm-down yaw of the default start pose: link-7 x along -x0 (q = [0, 1, 0, 1.5, 0, 0.6, 0] has this pose).
PALM_DOWN_YAW_RAD = math.pi
#: Seed of the start-pose IK: elbow up, forearm pointing down at the table.
IK_SEED_Q_RAD = np.array([0.0, 1.1, 0.0, 2.0, 0.0, 0.1, 0.0])

#: Joint-limit weighting of the IK: weight 1 beyond this distance from a limit, falling to the floor at it.
LIMIT_ZONE_RAD = 0.3
LIMIT_WEIGHT_FLOOR = 0.05


# --------------------------------------------------------------------------------------------------
# Orientation of the hand


def palm_down_rotation(yaw_rad: float) -> np.ndarray:
    """Rotation (3, 3) of a palm-down hand: link-7 z along -z0, link-7 x at ``yaw_rad`` in the table plane."""
    c, s = math.cos(yaw_rad), math.sin(yaw_rad)
    return np.array([[c, s, 0.0], [s, -c, 0.0], [0.0, 0.0, -1.0]])


def orientation_error(R: np.ndarray, R_ref: np.ndarray) -> np.ndarray:
    """Rotation error (3,) in frame 0 that turns ``R`` towards ``R_ref`` (``0.5 sum_i r_i x r_ref_i``), rad.

    Equal to ``sin(angle) * axis``: exact direction, magnitude ~ the angle for small errors.
    """
    return 0.5 * (np.cross(R[:, 0], R_ref[:, 0]) + np.cross(R[:, 1], R_ref[:, 1]) + np.cross(R[:, 2], R_ref[:, 2]))


def tilt_rad(R: np.ndarray) -> float:
    """Angle between the link-7 z axis and -z0 (0 = palm exactly down), rad."""
    return math.acos(max(-1.0, min(1.0, -float(R[2, 2]))))


# --------------------------------------------------------------------------------------------------
# Differential inverse kinematics


def dls_step(J: np.ndarray, e: np.ndarray, damping: float, weights: np.ndarray | None = None) -> np.ndarray:
    """Weighted damped least squares ``dq = W J^T (J W J^T + lambda^2 I)^-1 e``.

    Parameters
    ----------
    J : (m, n) Jacobian.
    e : (m,) task-space error or velocity.
    damping : float
        ``lambda``; trades accuracy for bounded joint motion near singularities.
    weights : (n,) diagonal of W (1 = free joint, small = joint that should move little), or None.

    Returns
    -------
    (n,) joint displacement or velocity.
    """
    JW = J if weights is None else J * weights[None, :]
    A = JW @ J.T
    A[np.diag_indices_from(A)] += damping * damping
    return JW.T @ np.linalg.solve(A, e)


def limit_weights(q: np.ndarray, zone_rad: float = LIMIT_ZONE_RAD, floor: float = LIMIT_WEIGHT_FLOOR) -> np.ndarray:
    """Per-joint DLS weights (7,): 1 away from the limits, falling linearly to ``floor`` at a limit."""
    margin = np.minimum(q - P.Q_MIN_RAD, P.Q_MAX_RAD - q)
    return np.clip(margin / zone_rad, floor, 1.0)


@njit(cache=True)
def _cholesky_solve(A, b, L, y, x):
    """Solve ``A x = b`` for a small SPD ``A`` (m, m) by Cholesky; ``L``, ``y`` are work arrays."""
    m = A.shape[0]
    for i in range(m):
        for j in range(i + 1):
            s = A[i, j]
            for k in range(j):
                s -= L[i, k] * L[j, k]
            if i == j:
                L[i, i] = math.sqrt(s)
            else:
                L[i, j] = s / L[j, j]
    for i in range(m):
        s = b[i]
        for k in range(i):
            s -= L[i, k] * y[k]
        y[i] = s / L[i, i]
    for i in range(m - 1, -1, -1):
        s = y[i]
        for k in range(i + 1, m):
            s -= L[k, i] * x[k]
        x[i] = s / L[i, i]


@njit(cache=True)
def _ik_kernel(J7, T, tool_offset, p_target, R_target, q, q_rest, q_min, q_max, q_lo, q_hi, damping, null_gain,
               cap, zone, floor, q_out, e_out):
    """One weighted-DLS IK step of the tool point with null-space posture, speed cap and clamp (see
    :meth:`HandKinematics.step`); writes ``q_out`` (7,) and the pose error ``e_out`` (6,)."""
    n = q.shape[0]
    J = np.empty((6, n))
    r0 = tool_offset * T[0, 2]
    r1 = tool_offset * T[1, 2]
    r2 = tool_offset * T[2, 2]
    for j in range(n):  # v_tool = v_flange + w x r
        J[0, j] = J7[0, j] + J7[4, j] * r2 - J7[5, j] * r1
        J[1, j] = J7[1, j] + J7[5, j] * r0 - J7[3, j] * r2
        J[2, j] = J7[2, j] + J7[3, j] * r1 - J7[4, j] * r0
        for i in range(3, 6):
            J[i, j] = J7[i, j]
    e_out[0] = p_target[0] - (T[0, 3] + r0)
    e_out[1] = p_target[1] - (T[1, 3] + r1)
    e_out[2] = p_target[2] - (T[2, 3] + r2)
    for i in range(3):
        e_out[3 + i] = 0.0
    for c in range(3):  # 0.5 sum_c R[:, c] x R_target[:, c]
        a0, a1, a2 = T[0, c], T[1, c], T[2, c]
        b0, b1, b2 = R_target[0, c], R_target[1, c], R_target[2, c]
        e_out[3] += 0.5 * (a1 * b2 - a2 * b1)
        e_out[4] += 0.5 * (a2 * b0 - a0 * b2)
        e_out[5] += 0.5 * (a0 * b1 - a1 * b0)
    w = np.empty(n)
    for j in range(n):
        margin = min(q[j] - q_min[j], q_max[j] - q[j])
        w[j] = min(max(margin / zone, floor), 1.0)
    A = np.empty((6, 6))
    for i in range(6):
        for k in range(i + 1):
            s = 0.0
            for j in range(n):
                s += J[i, j] * w[j] * J[k, j]
            A[i, k] = s
            A[k, i] = s
        A[i, i] += damping * damping
    L = np.zeros((6, 6))
    y = np.empty(6)
    x = np.empty(6)
    _cholesky_solve(A, e_out, L, y, x)
    dq = np.empty(n)
    for j in range(n):
        s = 0.0
        for i in range(6):
            s += J[i, j] * x[i]
        dq[j] = w[j] * s
    if null_gain > 0.0:  # dq += (I - W J^T A^-1 J) z,  z = null_gain W (q_rest - q)
        z = np.empty(n)
        for j in range(n):
            z[j] = null_gain * w[j] * (q_rest[j] - q[j])
        jz = np.empty(6)
        for i in range(6):
            s = 0.0
            for j in range(n):
                s += J[i, j] * z[j]
            jz[i] = s
        _cholesky_solve(A, jz, L, y, x)
        for j in range(n):
            s = 0.0
            for i in range(6):
                s += J[i, j] * x[i]
            dq[j] += z[j] - w[j] * s
    peak = 0.0
    for j in range(n):
        peak = max(peak, abs(dq[j]))
    scale = cap / peak if peak > cap else 1.0
    for j in range(n):
        q_out[j] = min(max(q[j] + scale * dq[j], q_lo[j]), q_hi[j])


class HandKinematics:
    """Tool-point kinematics of the WAM with a palm-down hand, and the DLS inverse-kinematics step.

    Parameters
    ----------
    dynamics : WamDynamics or None
        The kinematic model (a private instance is built if None).
    tool_offset_m : float
        Tool point along the link-7 z axis from the flange, m.
    damping : float
        DLS damping (metres and radians mixed: 0.01 costs ~1e-4 relative accuracy per step, corrected by the loop).
    limit_margin_rad : float
        ``q_ik`` stays this far inside the joint limits.
    qd_max_rad_s : float
        Joint speed cap of the IK reference (well below the backend's 2 rad/s velocity fault).
    null_gain : float
        Fraction of the distance to the rest posture recovered per step in the null space.
    """

    def __init__(self, dynamics: WamDynamics | None = None, *, tool_offset_m: float = TOOL_OFFSET_M,
                 damping: float = 0.01, limit_margin_rad: float = 0.05, qd_max_rad_s: float = 1.0,
                 null_gain: float = 0.05) -> None:
        self.dynamics = dynamics if dynamics is not None else WamDynamics()
        self.tool_offset_m = float(tool_offset_m)
        self.damping = float(damping)
        self.limit_margin_rad = float(limit_margin_rad)
        self.qd_max_rad_s = float(qd_max_rad_s)
        self.null_gain = float(null_gain)
        self._q_lo = P.Q_MIN_RAD + self.limit_margin_rad
        self._q_hi = P.Q_MAX_RAD - self.limit_margin_rad

    def tool_pose(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Tool point (3,) and hand orientation (3, 3) in frame 0."""
        T = self.dynamics.link7_pose(q)
        R = T[:3, :3]
        return T[:3, 3] + self.tool_offset_m * R[:, 2], R

    def tool_jacobian(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(J (6, 7), p (3,), R (3, 3))``: geometric Jacobian of the tool point (rows vx vy vz wx wy wz) and pose."""
        J = self.dynamics.link7_jacobian(q)  # also leaves the frames placed at q
        T = self.dynamics.link7_pose(q)
        R = T[:3, :3]
        r = self.tool_offset_m * R[:, 2]
        # v_tool = v_flange + w x r
        Jv = J[:3] + np.vstack([J[4] * r[2] - J[5] * r[1], J[5] * r[0] - J[3] * r[2], J[3] * r[1] - J[4] * r[0]])
        return np.vstack([Jv, J[3:]]), T[:3, 3] + r, R

    def step(self, q: np.ndarray, p_target: np.ndarray, R_target: np.ndarray, dt_s: float,
             q_rest: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """One closed-loop IK step: ``q_next`` that brings the tool pose of ``q`` to the target.

        Parameters
        ----------
        q : (7,) current joint reference.
        p_target : (3,) tool-point target, m.
        R_target : (3, 3) hand orientation target.
        dt_s : float
            Duration of the step (for the joint-speed cap).
        q_rest : (7,) or None
            Rest posture pulled towards in the null space of the task.

        Returns
        -------
        q_next : (7,) within the limits minus the margin.
        error : (6,) pose error of ``q`` before the step (position m, orientation rad).
        """
        J7 = self.dynamics.link7_jacobian(q)
        T = self.dynamics.link7_pose(q)
        q_next = np.empty(P.N_JOINTS)
        e = np.empty(6)
        _ik_kernel(J7, T, self.tool_offset_m, np.asarray(p_target, float), np.asarray(R_target, float),
                   np.asarray(q, float), q if q_rest is None else np.asarray(q_rest, float), P.Q_MIN_RAD, P.Q_MAX_RAD,
                   self._q_lo, self._q_hi, self.damping, 0.0 if q_rest is None else self.null_gain,
                   self.qd_max_rad_s * dt_s, LIMIT_ZONE_RAD, LIMIT_WEIGHT_FLOOR, q_next, e)
        return q_next, e

    def solve(self, p_target: Sequence[float], R_target: np.ndarray, q_seed: Sequence[float] | None = None, *,
              tol_m: float = 1e-5, tol_rad: float = 1e-4, max_iter: int = 500) -> tuple[np.ndarray, float, float]:
        """Iterate :meth:`step` to convergence (offline: start pose, reachability checks).

        Returns
        -------
        q : (7,) solution.
        position_error_m, orientation_error_rad : float
            Residual errors of ``q``.
        """
        q = np.array(IK_SEED_Q_RAD if q_seed is None else q_seed, float)
        p_target = np.asarray(p_target, float)
        rest = q.copy()
        for _ in range(max_iter):
            q_next, e = self.step(q, p_target, R_target, dt_s=0.05, q_rest=rest)
            if np.linalg.norm(e[:3]) < tol_m and np.linalg.norm(e[3:]) < tol_rad:
                break
            q = q_next
        p, R = self.tool_pose(q)
        return q, float(np.linalg.norm(p_target - p)), float(np.linalg.norm(orientation_error(R, R_target)))

