"""Joint controllers at the control rate (500 Hz, zero-order hold on torque).

One discrete law serves every kind, libbarrett's PID form (wam7-params / libbarrett ``pid.h``), per joint::

    e[n]  = q_ref[n] - q[n]
    I    += ki * T * e[n-1]
    u     = kp * e[n] + I + kd * (e[n] - e[n-1]) / T  (+ g(q[n]) + tau_ff[n])

* ``pd_g``    PD + gravity compensation (thesis eq. 2.10 / 3.1): ki = 0.
* ``pid``     PID (eq. 2.11), gravity compensation on by default (libbarrett ran PID with it).
* ``pd_g_ff`` PD + gravity + feed-forward friction compensation (eqs. 4.3-4.4):
  ``tau_ff = m qdd_r + sigma2 qd_r + Fc(qd_r)``, with ``m`` the joint's diagonal inertia B_ii(q0)
  (the "single mass in motion" of section 4.3) and the declared friction model.

The output is saturated at the WAM torque limits by the backend (the one place for safety limits).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from wamctl.model.friction import FrictionModel


@njit(cache=True)
def _pid_kernel(q_ref, q, kp, kd, ki, dt, state_e_prev, state_i, first, extra, out):
    """libbarrett's discrete PID per joint plus ``extra`` torque (gravity + feed-forward), into ``out``.

    The one copy of the law: ``e = q_ref - q``; the integral accumulates ``ki dt e_prev``; the derivative is
    ``(e - e_prev) / dt`` with ``e_prev = e`` on the first tick."""
    for j in range(q.shape[0]):
        e = q_ref[j] - q[j]
        e_prev = e if first else state_e_prev[j]
        state_i[j] += ki[j] * dt * e_prev
        out[j] = kp[j] * e + state_i[j] + kd[j] * (e - e_prev) / dt + extra[j]
        state_e_prev[j] = e


@njit(cache=True)
def _pid_series_kernel(q_ref, q, kp, kd, ki, dt, out):
    e_prev = np.zeros(q.shape[1])
    i_state = np.zeros(q.shape[1])
    extra = np.zeros(q.shape[1])
    for k in range(q.shape[0]):
        _pid_kernel(q_ref[k], q[k], kp, kd, ki, dt, e_prev, i_state, k == 0, extra, out[k])


def pid_torque_series_Nm(q_ref: np.ndarray, q: np.ndarray, kp, kd, ki, dt_s: float) -> np.ndarray:
    """The PID torque (no gravity, no feed-forward) the controller commanded along a logged run, (k, n).

    What a log's torque minus this is the rest of the command (gravity, feed-forward): used to recover the
    feed-forward of a ``pd_g_ff`` run, and by anything that inverts the controller."""
    q_ref = np.ascontiguousarray(q_ref, dtype=float)
    q = np.ascontiguousarray(q, dtype=float)
    out = np.empty_like(q)
    _pid_series_kernel(q_ref, q, np.asarray(kp, float), np.asarray(kd, float), np.asarray(ki, float), float(dt_s),
                       out)
    return out


class JointController:
    """Discrete joint PID with optional gravity compensation and feed-forward torque.

    Parameters
    ----------
    kp, kd, ki : (n,) gains (N m/rad, N m s/rad, N m/(rad s)), one per joint of the arm (their length is the
        controller's joint count: 7 on the wam7, 4 on the wam4; a Robot's ``kp``, ``kd``, ``ki`` by default).
    dt_s : control period.
    gravity : callable q -> (n,) gravity torque, or None for no gravity compensation.
    feedforward_Nm : (k, n) precomputed feed-forward torque per tick, or None.
    """

    def __init__(self, kp, kd, ki, dt_s: float, gravity=None, feedforward_Nm: np.ndarray | None = None):
        self.kp = np.asarray(kp, float).copy()
        self.kd = np.asarray(kd, float).copy()
        self.ki = np.asarray(ki, float).copy()
        n = self.n_joints = len(self.kp)
        if self.kd.shape != (n,) or self.ki.shape != (n,):
            raise ValueError(f"kp, kd, ki: {n}, {self.kd.size} and {self.ki.size} gains; one per joint each")
        if feedforward_Nm is not None and np.shape(feedforward_Nm)[-1] != n:
            raise ValueError(f"feedforward_Nm: {np.shape(feedforward_Nm)[-1]} columns for {n} joints")
        self.dt_s = float(dt_s)
        self.gravity = gravity
        self.feedforward_Nm = feedforward_Nm
        self._e_prev = np.zeros(n)
        self._i = np.zeros(n)
        self._out = np.zeros(n)
        self._zero = np.zeros(n)
        self._k = 0

    def reset(self) -> None:
        self._e_prev[:] = 0.0
        self._i[:] = 0.0
        self._k = 0

    @property
    def integral_Nm(self) -> np.ndarray:
        return self._i.copy()

    def update(self, q_ref: np.ndarray, q_meas: np.ndarray) -> np.ndarray:
        """Torque command (n_joints,) for this tick (not yet saturated)."""
        extra = self._zero if self.gravity is None else self.gravity(q_meas)
        if self.feedforward_Nm is not None:
            extra = extra + self.feedforward_Nm[min(self._k, len(self.feedforward_Nm) - 1)]
        _pid_kernel(q_ref, q_meas, self.kp, self.kd, self.ki, self.dt_s, self._e_prev, self._i,
                    self._k == 0, extra, self._out)
        self._k += 1
        return self._out


def friction_feedforward_Nm(qd_ref: np.ndarray, qdd_ref: np.ndarray, friction: FrictionModel,
                            inertia_kg_m2: np.ndarray | None = None) -> np.ndarray:
    """Thesis eq. 4.3, ``tau_ff = m qdd_r + sigma2 qd_r + Fc(qd_r)`` for a whole reference.

    Parameters
    ----------
    qd_ref, qdd_ref : (k, n) reference velocity and acceleration, n the arm's joints.
    friction : declared (identified) friction model of the same n joints; supplies sigma2 and Fc per direction.
    inertia_kg_m2 : (n,) the joint's "single mass" m; None leaves the inertial term out.

    Returns
    -------
    (k, n) feed-forward torque, N m.
    """
    ff = friction.friction_torque(qd_ref)
    if inertia_kg_m2 is not None:
        ff = ff + qdd_ref * np.asarray(inertia_kg_m2)[None, :]
    return ff
