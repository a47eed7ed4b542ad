"""Arm side of the gaze HMI (thesis 6.1.1, issue 7): the hand moves over the table, palm down, on gaze commands.

Frames and conventions
----------------------
* **Frame 0** is the WAM base frame of :mod:`wamctl.model.dynamics`: origin at the shoulder, z up (gravity along
  -z0), x forward (the direction the arm reaches at q1 = 0), y to the arm's left.
* **Table plane**: the horizontal plane ``z = table_z_m`` (frame 0). Positions on the table are frame-0
  ``(x_m, y_m)``; the hand moves at a constant height above it.
* **Tool point**: the grasp centre of the BarrettHand, ``tool_offset_m`` along the link-7 z axis from the wrist
  flange (DH frame 7). All Cartesian quantities (hand position, hit test, workspace bounds) refer to it.
* **Palm down**: the link-7 z axis points along -z0 (the hand grasps from above, thesis Figure 6.20 a). The whole
  orientation ``R_ref`` (palm down plus a fixed yaw, that of the start pose) is held; ``tilt`` is the angle between
  the link-7 z axis and -z0.
* **Command frame -> table plane**: a :class:`~wamctl.hmi.strategy.HandCommand` velocity is in the command frame
  of the scene image (+x image right, +y image up). The head-mounted scene camera (:class:`SceneCamera`) looks
  at the table from the subject's seat; image right is the camera's right vector projected on the table
  (``right_xy``), image up is its horizontal viewing direction (``forward_xy``: away from the subject, as a point
  further away on the table appears higher in the image). So ``v_table = vx * right_xy + vy * forward_xy``. With
  the default seat (the subject at the arm's left, +y side, looking along -y, thesis 6.5.1) image right is -x0
  (towards the arm's base) and image up is -y0.

Control
-------
Differential inverse kinematics at ``ik_rate_hz`` (100 Hz by default): a Cartesian reference (tool position in
the plane, constant height, orientation ``R_ref``) integrates the commanded velocity (acceleration-limited, clamped
to the workspace box), and one damped-least-squares step per IK period brings a kinematic joint reference
``q_ik`` onto it (closed-loop IK: the pose error of ``q_ik`` itself is fed back, so it never drifts). Joint limits
are respected by a weighting that slows joints near their limits, a null-space pull towards a rest posture, a
joint-speed cap and a final clamp with a margin. The joint reference is interpolated linearly to the 500 Hz
control rate and tracked by the backend's :class:`~wamctl.control.controllers.JointController`.

Safety holds (the reference velocity ramps to zero at ``accel_m_s2``): the session has not been started by the
supervisor; a command holds (eyes closed, no gaze, session ended); the command is the stop region; the last fresh
command is older than ``watchdog_s`` (stall); the hand is closing or opening. Joint-space moves (to the start
pose, home) are LSPB moves (thesis eqs. 3.3-3.5) from the current joint reference.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numba import njit

from wamctl.control.trajectory import ReferenceBuilder
from wamctl.hmi.gaze import CENTER_X_PX, CENTER_Y_PX, IMAGE_HEIGHT_PX, IMAGE_WIDTH_PX, SCENE_PX_PER_DEG
from wamctl.hmi.strategy import EventKind, HandCommand, Hold, Motion
from wamctl.model import params as P
from wamctl.model.dynamics import WamDynamics

logger = logging.getLogger(__name__)

#: Table top in frame 0. The WAM stands on a pedestal beside the table with its shoulder 5 cm above the table top.
#: Why so high: with the 20 N m joint-2 torque limit of :mod:`wamctl.model.params`, a palm-down hand near the
#: table can be held only within about 0.5 m of the shoulder axis (gravity on joint 2: ~16 N m at 0.45 m with the
#: hand at shoulder height, ~19 N m at 0.45 m and 25 cm lower); with the arm bolted on the table (shoulder 0.346 m
#: above it) joint 2 saturates over most of the table and the arm sags. The BarrettHand's own 1.2 kg are not in
#: the model (add them as a plant payload and keep the spots closer).
TABLE_Z_M = -0.05
#: Grasp centre of the BarrettHand BH-280 from the wrist flange along link-7 z (palm ~0.09 m, fingers ~0.12 m;
#: our estimate of where a closed hand holds a small object).
TOOL_OFFSET_M = 0.15
#: Height of the grasp centre above the table while reaching (a small object grasped about 5 cm up).
GRASP_HEIGHT_M = 0.05
#: Closing / opening time of the BarrettHand (BH-280 fingers: about 1 s from open to closed).
HAND_CLOSE_S = 1.0
HAND_OPEN_S = 1.0
#: Focal length of the scene camera in pixels, from gaze.SCENE_PX_PER_DEG (12 px/deg, ~64 deg over 768 px).
SCENE_FOCAL_PX = SCENE_PX_PER_DEG * 180.0 / math.pi
#: Palm-down yaw of the default start pose: link-7 x along -x0 (q = [0, 1, 0, 1.5, 0, 0.6, 0] has this pose).
PALM_DOWN_YAW_RAD = math.pi
#: Seed of the start-pose IK: elbow up, forearm pointing down at the table.
IK_SEED_Q_RAD = np.array([0.0, 1.1, 0.0, 2.0, 0.0, 0.1, 0.0])

#: Joint-limit weighting of the IK: weight 1 beyond this distance from a limit, falling to the floor at it.
LIMIT_ZONE_RAD = 0.3
LIMIT_WEIGHT_FLOOR = 0.05


# --------------------------------------------------------------------------------------------------
# Geometry: orientation, camera, workspace


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


@dataclass(frozen=True)
class CommandMapping:
    """Command frame (+x image right, +y image up) to table-plane directions; unit vectors (2,) in frame 0.

    ``v_table = vx * right_xy + vy * forward_xy``.
    """

    right_xy: tuple[float, float]
    forward_xy: tuple[float, float]

    def to_table(self, vx: float, vy: float) -> tuple[float, float]:
        """Command-frame vector -> table-plane vector (same units)."""
        r, f = self.right_xy, self.forward_xy
        return vx * r[0] + vy * f[0], vx * r[1] + vy * f[1]

    def to_command(self, dx: float, dy: float) -> tuple[float, float]:
        """Table-plane vector -> command-frame components (along image right, along image up)."""
        r, f = self.right_xy, self.forward_xy
        return dx * r[0] + dy * r[1], dx * f[0] + dy * f[1]


@dataclass(frozen=True)
class SceneCamera:
    """Pinhole model of the head-mounted scene camera (thesis 6.1.2: 768 x 576 px).

    Parameters
    ----------
    position_m : (3,) sequence
        Camera (the subject's eyes) in frame 0, m.
    look_at_m : (3,) sequence
        Point in frame 0 at the image centre (the subject keeps the head still, looking at the workspace).
    focal_px : float
        Focal length in pixels (principal point at the image centre, square pixels, no distortion).

    Notes
    -----
    Image coordinates are those of the tracker: origin upper-left, u right, v down. The camera has no roll: its
    right vector is horizontal.
    """

    position_m: tuple[float, float, float]
    look_at_m: tuple[float, float, float]
    focal_px: float = SCENE_FOCAL_PX

    def __post_init__(self) -> None:
        d = np.asarray(self.look_at_m, float) - np.asarray(self.position_m, float)
        if np.hypot(d[0], d[1]) < 1e-6:
            raise ValueError("the scene camera must not look straight down (its image right would be undefined)")
        fwd = d / np.linalg.norm(d)
        right = np.cross(fwd, [0.0, 0.0, 1.0])
        right /= np.linalg.norm(right)
        down = np.cross(fwd, right)  # image v axis
        object.__setattr__(self, "_rdf", tuple(tuple(float(c) for c in v) for v in (right, down, fwd)))

    def _axes(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return tuple(np.array(v) for v in self._rdf)

    def project(self, p_m: Sequence[float]) -> tuple[float, float]:
        """Image pixels ``(u, v)`` of a point (3,) in frame 0 (NaN behind the camera)."""
        (r0, r1, r2), (d0, d1, d2), (f0, f1, f2) = self._rdf
        c = self.position_m
        x, y, z = float(p_m[0]) - c[0], float(p_m[1]) - c[1], float(p_m[2]) - c[2]
        depth = x * f0 + y * f1 + z * f2
        if depth <= 1e-6:
            return math.nan, math.nan
        return (CENTER_X_PX + self.focal_px * (x * r0 + y * r1 + z * r2) / depth,
                CENTER_Y_PX + self.focal_px * (x * d0 + y * d1 + z * d2) / depth)

    def in_image(self, p_m: Sequence[float], margin_px: float = 0.0) -> bool:
        """True when the point projects inside the image (with a margin)."""
        u, v = self.project(p_m)
        return margin_px <= u <= IMAGE_WIDTH_PX - margin_px and margin_px <= v <= IMAGE_HEIGHT_PX - margin_px

    def mapping(self) -> CommandMapping:
        """The command-frame mapping this camera implies (see the module docstring)."""
        right, _, fwd = self._axes()
        f = np.array([fwd[0], fwd[1]])
        f /= np.linalg.norm(f)
        return CommandMapping((float(right[0]), float(right[1])), (float(f[0]), float(f[1])))


@dataclass(frozen=True)
class Workspace:
    """Box of allowed tool-point positions on the table plane, m (frame 0)."""

    x_m: tuple[float, float]
    y_m: tuple[float, float]

    def __post_init__(self) -> None:
        if not (self.x_m[0] < self.x_m[1] and self.y_m[0] < self.y_m[1]):
            raise ValueError(f"workspace bounds must be increasing, got x {self.x_m}, y {self.y_m}")

    def contains(self, x_m: float, y_m: float, margin_m: float = 0.0) -> bool:
        return (self.x_m[0] + margin_m <= x_m <= self.x_m[1] - margin_m
                and self.y_m[0] + margin_m <= y_m <= self.y_m[1] - margin_m)

    def clamp(self, x_m: float, y_m: float) -> tuple[float, float, bool]:
        """``(x, y, clamped)``: the point moved into the box."""
        cx = min(max(x_m, self.x_m[0]), self.x_m[1])
        cy = min(max(y_m, self.y_m[0]), self.y_m[1])
        return cx, cy, (cx != x_m or cy != y_m)


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


# --------------------------------------------------------------------------------------------------
# The hand


class BarrettHandSim:
    """A simulated BarrettHand: finger closure from 0 (open) to 1 (closed) at a constant rate.

    Parameters
    ----------
    close_time_s, open_time_s : float
        Time from fully open to fully closed and back.
    """

    def __init__(self, *, close_time_s: float = HAND_CLOSE_S, open_time_s: float = HAND_OPEN_S) -> None:
        if close_time_s <= 0 or open_time_s <= 0:
            raise ValueError("close_time_s and open_time_s must be > 0")
        self.close_time_s = close_time_s
        self.open_time_s = open_time_s
        self.closure = 0.0
        self.target = 0.0
        self._t_s: float | None = None

    def close(self, t_s: float) -> None:
        self.update(t_s)
        self.target = 1.0

    def open(self, t_s: float) -> None:
        self.update(t_s)
        self.target = 0.0

    def update(self, t_s: float) -> None:
        """Advance the fingers to time ``t_s``."""
        if self._t_s is not None and t_s > self._t_s:
            dt = t_s - self._t_s
            if self.target > self.closure:
                self.closure = min(self.target, self.closure + dt / self.close_time_s)
            elif self.target < self.closure:
                self.closure = max(self.target, self.closure - dt / self.open_time_s)
        self._t_s = t_s

    @property
    def moving(self) -> bool:
        return self.closure != self.target

    @property
    def is_closed(self) -> bool:
        return self.closure >= 1.0

    @property
    def is_open(self) -> bool:
        return self.closure <= 0.0


# --------------------------------------------------------------------------------------------------
# The arm driver


@dataclass
class ArmEvent:
    """Something the arm side did (for the events table)."""

    t_s: float
    kind: str
    detail: str = ""


@dataclass
class _JointMove:
    q_rad: np.ndarray  # (n, 7) per tick
    label: str
    then: str  # "teleop" or "ended"
    i: int = 0


class HandArm:
    """Drives the hand from :class:`~wamctl.hmi.strategy.HandCommand` s on an open backend, tick by tick.

    Parameters
    ----------
    backend : ArmBackend
        Open backend (simulated or real); the arm starts holding its measured position.
    controller : JointController
        Joint controllers at the control rate (``backend.control_period_s``).
    kinematics : HandKinematics
        Tool-point kinematics and IK step.
    workspace : Workspace
        Bounds of the tool point on the table.
    mapping : CommandMapping
        Command frame -> table plane.
    z_tool_m : float
        Height of the tool point while reaching, frame 0.
    R_ref : (3, 3)
        Hand orientation held (palm down).
    q_rest : (7,)
        Rest posture for the IK null space (the start pose).
    home_q_rad : (7,)
        Where the arm goes at the end of a session (three voluntary blinks).
    ik_rate_hz : float
        Rate of the IK steps; must divide the control rate.
    watchdog_s : float
        Hold still when the last fresh command is older than this.
    accel_m_s2 : float
        Acceleration limit of the Cartesian reference velocity (stops from 0.075 m/s in 75 ms at 1 m/s^2).
    joint_speed_rad_s, joint_blend_s : float
        Cruise speed and blend time of the LSPB joint moves.
    gripper : BarrettHandSim or None
        The hand (a fresh one if None).
    teleop : bool
        If True the arm is taken to be in its working pose already (palm down at ``z_tool_m``) and gaze commands
        may move it once started; otherwise it holds its joint positions until the first :meth:`move_to_joints`
        has brought it to one (a joint move always ends in the working pose, except the move home).
    friction_ff : FrictionModel or None
        For a ``pd_g_ff`` controller: friction feed-forward of the IK reference velocity, written into
        ``ff_buffer`` (the controller's one-row ``feedforward_Nm``) at each IK step.
    ff_buffer : (1, 7) array or None
        See ``friction_ff``.
    """

    def __init__(self, backend, controller, kinematics: HandKinematics, *, workspace: Workspace,
                 mapping: CommandMapping, z_tool_m: float, R_ref: np.ndarray, q_rest: np.ndarray,
                 home_q_rad: np.ndarray, ik_rate_hz: float = 100.0, watchdog_s: float = 0.2,
                 accel_m_s2: float = 1.0, joint_speed_rad_s: float = 0.5, joint_blend_s: float = 0.5,
                 gripper: BarrettHandSim | None = None, teleop: bool = False, friction_ff=None,
                 ff_buffer: np.ndarray | None = None) -> None:
        self.backend = backend
        self.controller = controller
        self.kin = kinematics
        self.workspace = workspace
        self.mapping = mapping
        self.z_tool_m = float(z_tool_m)
        self.R_ref = np.asarray(R_ref, float).copy()
        self.q_rest = np.asarray(q_rest, float).copy()
        self.home_q_rad = np.asarray(home_q_rad, float).copy()
        self.dt_s = float(backend.control_period_s)
        n_ik = round(1.0 / (ik_rate_hz * self.dt_s))
        if n_ik < 1 or abs(n_ik * ik_rate_hz * self.dt_s - 1.0) > 1e-9:
            raise ValueError(f"ik_rate_hz {ik_rate_hz} must divide the control rate {1.0 / self.dt_s:g} Hz")
        self.n_ik = int(n_ik)
        self.dt_ik_s = self.n_ik * self.dt_s
        self.watchdog_s = float(watchdog_s)
        self.accel_m_s2 = float(accel_m_s2)
        self.joint_speed_rad_s = float(joint_speed_rad_s)
        self.joint_blend_s = float(joint_blend_s)
        self.gripper = gripper if gripper is not None else BarrettHandSim()
        self.friction_ff = friction_ff
        self.ff_buffer = ff_buffer

        q = np.array(backend.read_positions(), float)
        self.q_meas = q
        self.q_ik = q.copy()
        self._q_prev_ik = q.copy()
        self._dq_ik = np.zeros(P.N_JOINTS)
        self.q_ref = q.copy()
        p, _ = self.kin.tool_pose(q)
        self.p_ref = np.array([p[0], p[1]])
        self.v_ref = np.zeros(2)
        self.v_des = np.zeros(2)
        self.t_s = 0.0
        self._k = 0
        self.started = False
        self.ended = False
        self._mode = "teleop" if teleop else "joint_hold"
        self._move: _JointMove | None = None
        self._last_fresh_s: float | None = None
        self._command: HandCommand | None = None
        self.hold_reason = "not_started"
        self._at_bound = False
        self.events: list[ArmEvent] = []
        self.ik_error = np.zeros(6)

    # -- supervisor and commands --------------------------------------------------------------------

    def start(self) -> None:
        """Supervisor start: gaze commands move the hand from now on."""
        if not self.started:
            self.started = True
            self._last_fresh_s = None
            self._event("start")

    def stop(self) -> None:
        """Supervisor stop: the hand holds still until :meth:`start`."""
        if self.started:
            self.started = False
            self._event("stop")

    @property
    def busy(self) -> bool:
        """True during a joint-space move (gaze commands are ignored)."""
        return self._move is not None

    def apply(self, command: HandCommand, *, fresh: bool = True) -> None:
        """Take a gaze command (``fresh``: it answers a new sample and feeds the watchdog).

        Gripper events toggle the hand (ignored during a joint move or before the start); ``GO_HOME`` ends the
        session and sends the arm home.
        """
        if fresh:
            self._last_fresh_s = self.t_s
        self._command = command
        for ev in command.events:
            if ev.kind is EventKind.GO_HOME:
                self.go_home()
            elif ev.kind in (EventKind.GRIPPER_CLOSE, EventKind.GRIPPER_OPEN):
                if self.busy or not self.started or self.ended:
                    self._event("gripper_ignored", ev.kind.value)
                elif ev.kind is EventKind.GRIPPER_CLOSE:
                    self.close_hand()
                else:
                    self.open_hand()

    def close_hand(self) -> None:
        self.gripper.close(self.t_s)
        self._event("gripper_closing")

    def open_hand(self) -> None:
        self.gripper.open(self.t_s)
        self._event("gripper_opening")

    def move_to_joints(self, q_target: Sequence[float], label: str = "move", *, then: str = "teleop",
                       settle_s: float = 0.3) -> float:
        """Start an LSPB joint move from the current joint reference; returns its duration, s."""
        q_target = np.asarray(q_target, float)
        delta = q_target - self.q_ref
        amp = float(np.max(np.abs(delta)))
        b = ReferenceBuilder(self.q_ref, self.dt_s)
        if amp > 1e-9:
            # LSPB needs t_f = t_c + amp / v >= 2 t_c: short moves cruise slower, keeping the blend time.
            tc = self.joint_blend_s
            speed = min(self.joint_speed_rad_s, amp / tc)
            b.move({j: float(delta[j]) for j in range(P.N_JOINTS)}, speed, tc, label)
        b.hold(max(settle_s, 2 * self.dt_s), "settle")
        ref = b.build()
        q = ref.q_rad.copy()
        q[-1] = q_target
        self._move = _JointMove(q, label, then)
        self._mode = "joint"
        self.v_ref[:] = 0.0
        self._event("joint_move", f"{label}: {len(q) * self.dt_s:.2f} s")
        return len(q) * self.dt_s

    def go_home(self) -> None:
        """End the session: LSPB to the home pose; the hand stays as it is."""
        if self.ended:
            return
        self.ended = True
        self._event("going_home")
        self.move_to_joints(self.home_q_rad, "home", then="ended")

    # -- state ------------------------------------------------------------------------------------

    def hand_pose(self, q: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Tool point (3,) and orientation of the measured (or given) joint positions."""
        return self.kin.tool_pose(self.q_meas if q is None else q)

    def _event(self, kind: str, detail: str = "") -> None:
        self.events.append(ArmEvent(self.t_s, kind, detail))

    def drain_events(self) -> list[ArmEvent]:
        out, self.events = self.events, []
        return out

    # -- the control period -------------------------------------------------------------------------

    def tick(self) -> None:
        """One control period: reference, joint controllers, torques, wait for the next period."""
        move = self._move
        if move is not None:
            np.copyto(self.q_ref, move.q_rad[move.i])
            move.i += 1
            if self._k % self.n_ik == 0:
                self._update_gripper()
            if move.i >= len(move.q_rad):
                self._end_move(move)
        elif self._mode == "teleop":
            phase = self._k % self.n_ik
            if phase == 0:
                self._ik_update()
            np.multiply(self._dq_ik, (phase + 1) / self.n_ik, out=self.q_ref)
            self.q_ref += self._q_prev_ik
        elif self._k % self.n_ik == 0:  # joint hold, or home reached: the reference stands still
            self._update_gripper()
        q = self.backend.read_positions()
        tau = self.controller.update(self.q_ref, q)
        self.backend.command_torques(tau)
        self.backend.wait_next_cycle()
        self.q_meas = q
        self._k += 1
        self.t_s = self._k * self.dt_s

    def run(self, duration_s: float) -> None:
        """Tick for ``duration_s`` (rounded to whole periods)."""
        for _ in range(int(round(duration_s / self.dt_s))):
            self.tick()

    def _end_move(self, move: _JointMove) -> None:
        self._move = None
        q_end = move.q_rad[-1]
        self.q_ik[:] = q_end
        self._q_prev_ik[:] = q_end
        self._dq_ik[:] = 0.0
        p, _ = self.kin.tool_pose(q_end)
        self.p_ref[:] = p[:2]
        self.v_ref[:] = 0.0
        self._event("joint_move_done", move.label)
        if move.then == "ended":
            self._mode = "ended"
            self._event("home_reached")
        else:
            self._mode = "teleop"

    def _hold(self) -> str:
        """Why the hand must hold still now ('' when the gaze may move it)."""
        if self._mode == "ended" or self.ended:
            return "session_ended"
        if not self.started:
            return "not_started"
        cmd = self._command
        if cmd is None or self._last_fresh_s is None or self.t_s - self._last_fresh_s > self.watchdog_s:
            return "stall"
        if cmd.hold is not Hold.NONE:
            return cmd.hold.value
        if self.gripper.moving:
            return "gripper"
        if cmd.motion is Motion.STOP:
            return "stop"
        return ""

    def _update_gripper(self) -> None:
        was_moving = self.gripper.moving
        self.gripper.update(self.t_s)
        if was_moving and not self.gripper.moving:
            self._event("gripper_closed" if self.gripper.is_closed else "gripper_opened")

    @property
    def mode(self) -> str:
        """``joint_hold`` (before the first move), ``joint`` (LSPB move), ``teleop`` or ``ended``."""
        return self._mode

    def _ik_update(self) -> None:
        self._update_gripper()
        reason = self._hold()
        if reason != self.hold_reason:
            if reason == "stall" and self.hold_reason not in ("not_started", "session_ended"):
                self._event("stall", f"no fresh gaze command for more than {self.watchdog_s:.3f} s")
            self.hold_reason = reason
        if reason:
            self.v_des[:] = 0.0
        else:
            cmd = self._command
            vx, vy = self.mapping.to_table(cmd.vx_m_s, cmd.vy_m_s)
            self.v_des[0], self.v_des[1] = vx, vy
        # acceleration-limited reference velocity
        dv = self.v_des - self.v_ref
        n = math.hypot(dv[0], dv[1])
        step = self.accel_m_s2 * self.dt_ik_s
        if n > step:
            dv *= step / n
        self.v_ref += dv
        x = self.p_ref[0] + self.v_ref[0] * self.dt_ik_s
        y = self.p_ref[1] + self.v_ref[1] * self.dt_ik_s
        x, y, clamped = self.workspace.clamp(x, y)
        if clamped:
            ws = self.workspace
            if x in ws.x_m:
                self.v_ref[0] = 0.0
            if y in ws.y_m:
                self.v_ref[1] = 0.0
            if not self._at_bound:
                self._event("bound", f"hand clamped at the workspace bound ({x:.3f}, {y:.3f}) m")
        self._at_bound = clamped
        self.p_ref[0], self.p_ref[1] = x, y
        target = np.array([x, y, self.z_tool_m])
        self._q_prev_ik[:] = self.q_ik
        q_next, self.ik_error = self.kin.step(self.q_ik, target, self.R_ref, self.dt_ik_s, self.q_rest)
        np.subtract(q_next, self.q_ik, out=self._dq_ik)
        self.q_ik[:] = q_next
        if self.friction_ff is not None and self.ff_buffer is not None:
            self.ff_buffer[0] = self.friction_ff.friction_torque(self._dq_ik / self.dt_ik_s)
