"""The simulated arm's closed loop compiled whole: K control ticks of ``run_loop`` in one numba call.

One tick of the Python path (:func:`wamctl.experiments.engine.run_loop` on a :class:`SimBackend`) is
``read_positions`` (the position and velocity checks of :class:`~wamctl.backends.base.ArmBackend`),
``JointController.update`` (PID + the declared model's gravity + feed-forward), ``command_torques``
(saturation, torque noise), the row written, and ``wait_next_cycle`` (the physics of
``SimBackend._advance_physics`` - ``B^-1`` once per period, ``substeps`` semi-implicit steps with the coupled
implicit friction, ripple and drift - then the sensor chain: delay line, backlash, quantisation, position noise).
:func:`_fused_ticks` does the same, in the same order, on the same state arrays (the backend's, the controller's,
the recorder's, updated in place), with the rigid body from :mod:`wamctl.model.chain_kernels` in place of the
pinocchio calls (they agree to ~1e-15).

Random draws come from the backend's generator, drawn before each chunk in the order the Python path draws them
(per tick: torque noise, then position noise, each only when its sigma > 0: ``normal(0, s)`` is
``0 + s * standard_normal()``, so the numbers are the same).

Faults: the kernel stops *before* a tick that would fault (a position or velocity breach, a non-finite torque),
with every state as it was before that tick and the generator wound back to the draws of the ticks done; the
caller then runs that tick on the Python path, which raises the same error with the same message.
"""

from __future__ import annotations

from collections import deque

import numpy as np
from numba import njit

from wamctl.backends.base import ArmBackend, _check_state, _saturate, record_row
from wamctl.backends.sim import ROW_SCALE, SimBackend, _physics_step
from wamctl.control.controllers import JointController, _pid_kernel
from wamctl.model.chain_kernels import cholesky_inverse, crba, rnea
from wamctl.model.dynamics import WamDynamics
from wamctl.model.transmission import _counts_to_joint_rad_row, _joint_rad_to_counts_row

# The loop's methods as defined (captured at import): a backend whose class, or SimBackend itself, has any of them
# replaced (a subclass with other physics, a test's hook counting ticks) keeps the Python path.
_LOOP_METHODS = {name: getattr(SimBackend, name) for name in (
    "_advance_physics", "_wait_next_cycle", "_read_positions", "_send_torques", "read_positions",
    "command_torques", "wait_next_cycle")}
_BASE_METHODS = {name: getattr(ArmBackend, name) for name in ("read_positions", "command_torques",
                                                              "wait_next_cycle")}


def fused_supported(backend, controller) -> bool:
    """True when the compiled loop reproduces the Python path: a :class:`SimBackend` whose loop methods are its
    own (not a subclass overriding ``_advance_physics``, reads or sends, nor a hook in place of one), and a plain
    :class:`JointController` whose gravity (if any) is a :class:`WamDynamics`' ``gravity``/``gravity_view``; and the
    arm a wam7 (the compiled chain is the wam7's: another robot, e.g. the wam4, runs the Python loop)."""
    if not isinstance(backend, SimBackend) or type(controller) is not JointController:
        return False
    # the chain kernels (model/chain_kernels.py) are the wam7's
    if getattr(getattr(backend.plant, "robot", None), "name", "wam7") != "wam7":
        return False
    cls = type(backend)
    if any(getattr(cls, name) is not f for name, f in _LOOP_METHODS.items()):
        return False
    if any(getattr(cls, name) is not f for name, f in _BASE_METHODS.items()):
        return False
    g = controller.gravity
    if g is None:
        return True
    return isinstance(getattr(g, "__self__", None), WamDynamics) and getattr(g, "__func__", None) in (
        WamDynamics.gravity, WamDynamics.gravity_view)


@njit(cache=True, nogil=True)     # the diagnosis' position check runs its simulations side by side
def _fused_ticks(k0, k1, row0, rows, t_ref, q_ref, ff, has_ff,
                 # declared model (gravity compensation)
                 g_on, g_rot, g_trans, g_inertia, g_arm, g_grav,
                 # plant rigid body
                 p_rot, p_trans, p_inertia, p_arm, p_grav,
                 # controller state
                 kp, kd, ki, dt_ctl, e_prev, i_state, kc,
                 # safety
                 tau_max, q_min, q_max, qd_max, dt_safety, w_filt, q_prev, v_filt, tau_applied,
                 # plant state
                 q, qd, tau, pp, work, t, period, h, substeps, sweeps, drift_on, drift_fraction, drift_tc,
                 # sensors
                 q_meas, hist, hist_head, hist_len, lag_k, lag_frac, play, half_band, has_backlash,
                 quant_on, j2mp, m2jp, counts_per_rad, sig_tau, sig_pos, z):
    """Advance ticks ``k0 .. k1-1``; returns ``(ticks done, t, controller tick count, delay-line head, length)``.

    Stops early, before a tick that would fault, leaving that tick's state untouched."""
    n = q.shape[0]
    wr = np.zeros((n, 4, 6))
    wc = np.zeros((n, 6, 6))
    M = np.empty((n, n))
    L = np.empty((n, n))
    minv = np.empty((n, n))
    zero = np.zeros(n)
    nle = np.empty(n)
    extra = np.empty(n)
    u = np.empty(n)
    vf_save = np.empty(n)
    qp_save = np.empty(n)
    ep_save = np.empty(n)
    is_save = np.empty(n)
    cnt = np.empty(n)
    qm = np.empty(n)
    nh = hist.shape[0]
    nz = 0
    if sig_tau > 0:
        nz += n
    for k in range(k0, k1):
        r = k - k0
        # ---------------------------------------------------------------- read_positions (safety)
        for j in range(n):
            vf_save[j] = v_filt[j]
            qp_save[j] = q_prev[j]
        code = _check_state(q_meas, q_prev, v_filt, q_min, q_max, qd_max, dt_safety, w_filt)
        if code != 0:
            for j in range(n):
                v_filt[j] = vf_save[j]
                q_prev[j] = qp_save[j]
            return r, t, kc, hist_head, hist_len
        # ---------------------------------------------------------------- controller
        if g_on:
            rnea(g_rot, g_trans, g_inertia, g_arm, g_grav, q_meas, zero, zero, extra, wr)
        else:
            for j in range(n):
                extra[j] = 0.0
        if has_ff:
            kf = min(kc, ff.shape[0] - 1)
            for j in range(n):
                extra[j] = extra[j] + ff[kf, j]
        for j in range(n):
            ep_save[j] = e_prev[j]
            is_save[j] = i_state[j]
        _pid_kernel(q_ref[k], q_meas, kp, kd, ki, dt_ctl, e_prev, i_state, kc == 0, extra, u)
        # ---------------------------------------------------------------- command_torques
        bad = _saturate(u, tau_max, tau_applied)
        if bad:
            for j in range(n):
                v_filt[j] = vf_save[j]
                q_prev[j] = qp_save[j]
                e_prev[j] = ep_save[j]
                i_state[j] = is_save[j]
            return r, t, kc, hist_head, hist_len
        kc += 1
        for j in range(n):
            tau[j] = tau_applied[j]
        if sig_tau > 0:
            for j in range(n):
                tau[j] += 0.0 + sig_tau * z[r, j]
        # ---------------------------------------------------------------- the row (truth before the step)
        record_row(rows, row0 + r, t_ref[k], q_ref[k], q_meas, tau_applied, q, qd)
        # ---------------------------------------------------------------- physics (SimBackend._advance_physics)
        crba(p_rot, p_trans, p_inertia, p_arm, q, M, wc)
        cholesky_inverse(M, L, minv)
        if drift_on:
            for j in range(n):
                pp[ROW_SCALE, j] = 1.0 + drift_fraction[j] * (1.0 - np.exp(-t / drift_tc))
        for _ in range(substeps):
            rnea(p_rot, p_trans, p_inertia, p_arm, p_grav, q, qd, zero, nle, wr)
            _physics_step(q, qd, tau, nle, minv, h, pp, work, sweeps)
            if nh > 0:
                hist_head = (hist_head + 1) % nh
                for j in range(n):
                    hist[hist_head, j] = q[j]
                if hist_len < nh:
                    hist_len += 1
        t += period
        # ---------------------------------------------------------------- sensors (SensorChain.measure)
        if nh > 0:
            inew = (hist_head - lag_k) % nh
            iold = (hist_head - lag_k - 1) % nh
            for j in range(n):
                qm[j] = (1 - lag_frac) * hist[inew, j] + lag_frac * hist[iold, j]
        else:
            for j in range(n):
                qm[j] = q[j]
        if has_backlash:
            for j in range(n):
                play[j] = min(max(play[j], qm[j] - half_band[j]), qm[j] + half_band[j])
                if half_band[j] > 0:
                    qm[j] = play[j]
        if quant_on:
            _joint_rad_to_counts_row(qm, j2mp, counts_per_rad, cnt)
            _counts_to_joint_rad_row(cnt, m2jp, counts_per_rad, qm, cnt)
        if sig_pos > 0:
            for j in range(n):
                qm[j] = qm[j] + (0.0 + sig_pos * z[r, nz + j])
        for j in range(n):
            q_meas[j] = qm[j]
    return k1 - k0, t, kc, hist_head, hist_len


class FusedLoop:
    """The compiled loop bound to one backend and controller: ``advance(k0, k1, q_ref, t_ref, recorder)``."""

    def __init__(self, backend: SimBackend, controller: JointController):
        self.b, self.c = backend, controller
        n = len(backend._q)
        g = controller.gravity
        if g is not None:
            self.g_arrays = tuple(np.ascontiguousarray(a, float) for a in g.__self__.chain_arrays())
        else:
            self.g_arrays = (np.zeros((n, 3, 3)), np.zeros((n, 3)), np.zeros((n, 6, 6)), np.zeros(n), np.zeros(3))
        self.p_arrays = tuple(np.ascontiguousarray(a, float) for a in backend.dynamics.chain_arrays())
        ff = controller.feedforward_Nm
        self.ff = np.ascontiguousarray(ff, float) if ff is not None else np.zeros((1, n))
        s = backend.sensors
        self.sig_tau = float(backend.plant.sensors.torque_noise_Nm)
        self.sig_pos = float(backend.plant.sensors.position_noise_rad)
        self.nz = (n if self.sig_tau > 0 else 0) + (n if self.sig_pos > 0 else 0)
        if s._hist is not None:
            lag = backend.plant.delay_s / s._dt
            self.lag_k = int(np.floor(lag))
            self.lag_frac = lag - self.lag_k
        else:
            self.lag_k, self.lag_frac = 0, 0.0
        self.quant_on = s._counts_per_rad is not None
        self.cpr = s._counts_per_rad if self.quant_on else np.ones(n)

    def advance(self, k0: int, k1: int, q_ref: np.ndarray, t_ref: np.ndarray, recorder) -> int:
        """Run ticks k0 .. k1-1 (stopping before a faulting one); returns the number done. The recorder's row
        count, the backend's and controller's state and the generator are left as the Python path leaves them."""
        b, c, s = self.b, self.c, self.b.sensors
        n = len(b._q)
        rng = b.rng
        state = rng.bit_generator.state if self.nz else None
        z = rng.standard_normal((k1 - k0, self.nz)) if self.nz else np.zeros((k1 - k0, 1))
        if b._q_prev is None:
            b._q_prev = b._q_meas.copy()
        q_meas = np.array(b._q_meas, float)
        if s._hist is not None:
            hist = np.array(s._hist, float)
            head, length = len(hist) - 1, len(hist)
        else:
            hist, head, length = np.zeros((0, n)), 0, 0
        play = np.array(s._play, float)
        lim = b.limits
        done, t, kc, head, length = _fused_ticks(
            k0, k1, recorder.n, recorder.rows, t_ref, q_ref, self.ff, c.feedforward_Nm is not None,
            c.gravity is not None, *self.g_arrays, *self.p_arrays,
            c.kp, c.kd, c.ki, c.dt_s, c._e_prev, c._i, c._k,
            lim.tau_max_Nm, lim.q_min_rad, lim.q_max_rad, lim.qd_max_rad_s, b.control_period_s,
            float(lim.velocity_filter_rad_s), b._q_prev, b._v_filt, b._tau_applied,
            b._q, b._qd, b._tau, b._pp, b._work, b._t, b.control_period_s, b.h_s, b.substeps,
            b.FRICTION_SWEEPS, b.plant.has_drift, b.plant.drift_fraction, float(b.plant.drift_time_constant_s),
            q_meas, hist, head, length, self.lag_k, self.lag_frac, play, s._half_band, s._has_backlash,
            self.quant_on, s._j2mp, s._m2jp, self.cpr, self.sig_tau, self.sig_pos, z)
        recorder.n += done
        b._t = t
        c._k = kc
        if done:
            b._q_meas = q_meas
            s._play = play
            if s._hist is not None:
                order = [(head - length + 1 + i) % len(hist) for i in range(length)]
                s._hist = deque([hist[i].copy() for i in order], maxlen=s._hist.maxlen)
        if done < k1 - k0 and self.nz:      # stopped before a fault: keep only the draws of the ticks done
            rng.bit_generator.state = state
            if done:
                rng.standard_normal((done, self.nz))
        return done
