"""The arm backend protocol, and the safety that every backend shares.

A backend is a context manager. Inside it, a control loop calls, once per control period::

    q = backend.read_positions()          # measured joint positions, checked against limits
    backend.command_torques(tau)          # saturated at the torque limits, then sent
    backend.wait_next_cycle()             # the simulator integrates, the CAN arm waits for its deadline

Safety lives here, once, for every backend: torque saturation, joint position limits, a joint velocity
fault limit (on the libbarrett low-pass velocity estimate), and zero torque on shutdown (safe to call twice).
A breach raises :class:`~wamctl.errors.SafetyLimitError`; the run ends as failed with that reason and the
backend's ``shutdown()`` sends zero torque.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, field

import numpy as np
from numba import njit

from wamctl.errors import SafetyLimitError
from wamctl.model import params as P


@dataclass
class SafetyLimits:
    """Limits enforced by every backend. Arrays (n,), one entry per joint of the arm (the wam7's by default;
    :meth:`for_robot` another arm's); the velocity filter is libbarrett's (w = 180 rad/s)."""

    tau_max_Nm: np.ndarray = field(default_factory=lambda: P.TAU_MAX_NM.copy())
    q_min_rad: np.ndarray = field(default_factory=lambda: P.Q_MIN_RAD.copy())
    q_max_rad: np.ndarray = field(default_factory=lambda: P.Q_MAX_RAD.copy())
    qd_max_rad_s: np.ndarray = field(default_factory=lambda: P.QD_MAX_RAD_S.copy())
    velocity_filter_rad_s: float = 180.0

    @classmethod
    def for_robot(cls, robot=None) -> SafetyLimits:
        """The limits of an arm of :mod:`wamctl.model.robots` (a Robot or its name; None: the wam7)."""
        from wamctl.model.robots import get_robot

        r = get_robot(robot)
        return cls(np.array(r.tau_max_Nm), np.array(r.q_min_rad), np.array(r.q_max_rad), np.array(r.qd_max_rad_s))

    @property
    def n_joints(self) -> int:
        return len(self.tau_max_Nm)


@njit(cache=True)
def record_row(rows, i, t, q_ref, q, tau, q_true, qd_true):
    """Write one control tick into row i of the loop's table (columns: ``t_s``, the reference, the measured
    position, the applied torque, and the truth only when the table has those columns): the one layout the
    engine's Python loop and the compiled simulator loop both write."""
    n = q.shape[0]
    rows[i, 0] = t
    for j in range(n):
        rows[i, 1 + j] = q_ref[j]
        rows[i, 1 + n + j] = q[j]
        rows[i, 1 + 2 * n + j] = tau[j]
    if rows.shape[1] > 1 + 3 * n:
        for j in range(n):
            rows[i, 1 + 3 * n + j] = q_true[j]
            rows[i, 1 + 4 * n + j] = qd_true[j]


@njit(cache=True)
def _saturate(tau, tau_max, out):
    """Clip to +-tau_max into ``out``; return the 1-based joint with a non-finite torque, or 0."""
    for j in range(tau.shape[0]):
        t = tau[j]
        if not np.isfinite(t):
            return j + 1
        out[j] = min(max(t, -tau_max[j]), tau_max[j])
    return 0


@njit(cache=True)
def _check_state(q, q_prev, v_filt, q_min, q_max, qd_max, dt, w):
    """Update the filtered velocity; return +j for a position breach of joint j, -j for velocity, 0 if fine."""
    for j in range(q.shape[0]):
        if not (q_min[j] <= q[j] <= q_max[j]):
            return j + 1
        v_filt[j] = (v_filt[j] + w * dt * (q[j] - q_prev[j]) / dt) / (1.0 + w * dt)
        q_prev[j] = q[j]
        if abs(v_filt[j]) > qd_max[j]:
            return -(j + 1)
    return 0


class ArmBackend(ABC):
    """Base of every backend: lifecycle, safety, and the three calls of the control loop."""

    name = "abstract"
    control_period_s = 1.0 / P.CONTROL_RATE_HZ

    def __init__(self, limits: SafetyLimits | None = None):
        self.limits = limits or SafetyLimits()
        self._opened = False
        self._closed = False
        self._tau_applied = np.zeros(self.limits.n_joints)
        self._q_prev: np.ndarray | None = None
        self._v_filt = np.zeros(self.limits.n_joints)

    @property
    def n_joints(self) -> int:
        """The arm's joints (its limits' length): the width of every vector the loop reads and sends."""
        return self.limits.n_joints

    # ---------------------------------------------------------------- lifecycle
    def __enter__(self) -> ArmBackend:
        self.open()
        return self

    def __exit__(self, *exc) -> None:
        self.shutdown()

    def open(self) -> None:
        if self._opened:
            return
        self._open()
        self._opened = True

    def shutdown(self) -> None:
        """Zero torque, then release the device. Safe to call twice, and after a failed open."""
        if self._closed:
            return
        self._closed = True
        try:
            if self._opened:
                self._tau_applied[:] = 0.0
                self._send_torques(self._tau_applied)
        finally:
            self._close()

    @property
    def is_open(self) -> bool:
        return self._opened and not self._closed

    # ---------------------------------------------------------------- loop
    def read_positions(self) -> np.ndarray:
        """Measured joint positions (n_joints,), rad; raises SafetyLimitError on a position or velocity breach."""
        q = self._read_positions()
        if self._q_prev is None:
            self._q_prev = q.copy()
        code = _check_state(q, self._q_prev, self._v_filt, self.limits.q_min_rad, self.limits.q_max_rad,
                            self.limits.qd_max_rad_s, self.control_period_s, self.limits.velocity_filter_rad_s)
        if code > 0:
            j = code - 1
            raise SafetyLimitError(f"joint {code} position {q[j]:.4f} rad outside its limits "
                                   f"[{self.limits.q_min_rad[j]}, {self.limits.q_max_rad[j]}] rad")
        if code < 0:
            j = -code - 1
            raise SafetyLimitError(f"joint {-code} velocity {self._v_filt[j]:.3f} rad/s above the fault limit "
                                   f"{self.limits.qd_max_rad_s[j]} rad/s")
        return q

    def command_torques(self, tau_Nm: np.ndarray) -> np.ndarray:
        """Saturate at the torque limits and send; returns the applied torque (n_joints,), N m."""
        bad = _saturate(np.asarray(tau_Nm, float), self.limits.tau_max_Nm, self._tau_applied)
        if bad:
            self._tau_applied[:] = 0.0
            self._send_torques(self._tau_applied)
            raise SafetyLimitError(f"joint {bad}: non-finite torque command")
        self._send_torques(self._tau_applied)
        return self._tau_applied

    def wait_next_cycle(self) -> None:
        self._wait_next_cycle()

    @property
    @abstractmethod
    def time_s(self) -> float:
        """Time since open, s."""

    def describe(self) -> dict:
        """What the manifest records about this backend."""
        return {"name": self.name}

    # ---------------------------------------------------------------- per backend
    @abstractmethod
    def _open(self) -> None: ...

    @abstractmethod
    def _close(self) -> None: ...

    @abstractmethod
    def _read_positions(self) -> np.ndarray: ...

    @abstractmethod
    def _send_torques(self, tau_Nm: np.ndarray) -> None: ...

    @abstractmethod
    def _wait_next_cycle(self) -> None: ...
