"""Excitations: constant-velocity sweeps of one joint and finite Fourier series on several joints, designed on the
NOMINAL model (what the experimenter knows) within the joint, torque, Cartesian-speed and table limits."""

from __future__ import annotations

import math

import numpy as np
import pinocchio as pin

from .arm import Q_MAX, Q_MIN, TAU_MAX, N


class SweepRef:
    """Constant-velocity sweep of one joint (cosine velocity blends), other joints held at q0."""

    def __init__(self, q0, joint, segments):
        self.q0 = np.asarray(q0, float)
        self.j = joint  # 0-based
        self.seg = segments  # list of (t0, dur, v0, v1)
        self.t0 = np.array([s[0] for s in segments])
        p = 0.0
        self.p0 = []
        for (_, d, v0, v1) in segments:
            self.p0.append(p)
            p += 0.5 * (v0 + v1) * d
        self.p0 = np.array(self.p0)
        self.duration = segments[-1][0] + segments[-1][1]

    def __call__(self, t):
        t = np.atleast_1d(np.asarray(t, float))
        k = np.clip(np.searchsorted(self.t0, t, side="right") - 1, 0, len(self.seg) - 1)
        seg = np.array([self.seg[i] for i in range(len(self.seg))])
        t0, d, v0, v1 = seg[k, 0], seg[k, 1], seg[k, 2], seg[k, 3]
        tau = np.clip(t - t0, 0.0, d)
        w = np.pi / d
        pos = self.p0[k] + v0 * tau + 0.5 * (v1 - v0) * (tau - np.sin(w * tau) / w)
        vel = v0 + 0.5 * (v1 - v0) * (1.0 - np.cos(w * tau))
        acc = 0.5 * (v1 - v0) * w * np.sin(w * tau)
        past = t > self.duration
        vel[past] = 0.0
        acc[past] = 0.0
        q = np.tile(self.q0, (len(t), 1))
        qd = np.zeros_like(q)
        qdd = np.zeros_like(q)
        q[:, self.j] += pos
        qd[:, self.j] = vel
        qdd[:, self.j] = acc
        return q, qd, qdd


class FourierRef:
    """Finite Fourier series on several joints, faded in and out with a quintic window."""

    def __init__(self, q0, joints, wf, a, b, duration, t_fade=1.5, t_start=0.5):
        self.q0 = np.asarray(q0, float)
        self.joints = list(joints)
        self.wf, self.a, self.b = wf, np.asarray(a), np.asarray(b)  # a,b: (len(joints), K)
        self.duration, self.tf, self.ts = duration, t_fade, t_start

    def _window(self, t):
        u = np.clip((t - self.ts) / self.tf, 0, 1)
        e = np.clip((self.duration - t) / self.tf, 0, 1)
        def s(x):
            return 10 * x ** 3 - 15 * x ** 4 + 6 * x ** 5

        def ds(x):
            return 30 * x ** 2 - 60 * x ** 3 + 30 * x ** 4

        def dds(x):
            return 60 * x - 180 * x ** 2 + 120 * x ** 3

        w = s(u) * s(e)
        wd = ds(u) / self.tf * s(e) - s(u) * ds(e) / self.tf
        wdd = dds(u) / self.tf ** 2 * s(e) - 2 * ds(u) * ds(e) / self.tf ** 2 + s(u) * dds(e) / self.tf ** 2
        return w, wd, wdd

    def _series(self, t):
        K = self.a.shape[1]
        k = np.arange(1, K + 1)
        ph = np.outer(t, k) * self.wf  # (nt, K)
        s, c = np.sin(ph), np.cos(ph)
        d = s @ self.a.T + c @ self.b.T
        dd = (c * (k * self.wf)) @ self.a.T - (s * (k * self.wf)) @ self.b.T
        ddd = -(s * (k * self.wf) ** 2) @ self.a.T - (c * (k * self.wf) ** 2) @ self.b.T
        return d, dd, ddd

    def __call__(self, t):
        t = np.atleast_1d(np.asarray(t, float))
        w, wd, wdd = self._window(t)
        d, dd, ddd = self._series(t)
        q = np.tile(self.q0, (len(t), 1))
        qd = np.zeros_like(q)
        qdd = np.zeros_like(q)
        J = self.joints
        q[:, J] += w[:, None] * d
        qd[:, J] = wd[:, None] * d + w[:, None] * dd
        qdd[:, J] = wdd[:, None] * d + 2 * wd[:, None] * dd + w[:, None] * ddd
        return q, qd, qdd


class _Checker:
    """Design-time checks of a reference on the NOMINAL model (what the experimenter knows)."""

    def __init__(self, model):
        self.m = model
        self.d = model.createData()
        self.f_elbow = model.getFrameId("dh3")
        self.f_wrist = model.getFrameId("dh5")
        self.f_flange = model.getFrameId("dh7")

    def evaluate(self, ref, duration, dt=0.04, fric=None):
        """Check the reference; cheap tests first, stops at the first failure (``fail`` names it)."""
        t = np.arange(0.0, duration, dt)
        q, qd, qdd = ref(t)
        ev = dict(q=q, qd=qd, qdd=qdd, qmin=q.min(axis=0), qmax=q.max(axis=0), qdmax=np.abs(qd).max(axis=0),
                  tau_ratio=np.inf, zmin=-np.inf, vcart=np.inf, fail=None)
        inside = np.all(ev["qmin"] >= Q_MIN + MARGIN_Q - 1e-9) and np.all(ev["qmax"] <= Q_MAX - MARGIN_Q + 1e-9)
        if not inside or np.any(ev["qdmax"] > 1.95):
            ev["fail"] = "range"
            return ev
        tau = np.empty_like(q)
        for i in range(len(t)):
            tau[i] = pin.rnea(self.m, self.d, q[i], qd[i], qdd[i])
        if fric is not None:
            tau = np.abs(tau) + fric
        ev["tau_ratio_j"] = np.max(np.abs(tau), axis=0) / TAU_MAX
        ev["tau_ratio"] = float(ev["tau_ratio_j"].max())
        if ev["tau_ratio"] > 0.65:
            ev["fail"] = "torque"
            return ev
        zmin, vmax = np.inf, 0.0
        for i in range(len(t)):
            pin.forwardKinematics(self.m, self.d, q[i], qd[i])
            pin.updateFramePlacements(self.m, self.d)
            for f in (self.f_elbow, self.f_wrist, self.f_flange):
                zmin = min(zmin, self.d.oMf[f].translation[2])
            for f in (self.f_wrist, self.f_flange):
                lv = pin.getFrameVelocity(self.m, self.d, f, pin.LOCAL_WORLD_ALIGNED).linear
                vmax = max(vmax, math.sqrt(lv @ lv))
        ev["zmin"], ev["vcart"] = float(zmin), float(vmax)
        if zmin < ZMIN_TABLE:
            ev["fail"] = "table"
        elif vmax > 0.75:
            ev["fail"] = "cartesian_speed"
        return ev


Q_HOME_BOX = (np.array([-1.5, -1.1, -1.5, 0.3, -2.4, -1.0, -2.0]),
              np.array([1.5, 1.1, 1.5, 2.5, 0.4, 1.0, 2.0]))
MARGIN_Q = 0.15
ZMIN_TABLE = -0.25  # m below the shoulder; the mounting plate is 0.346 m below frame 0


def _ok(ev):
    return ev["fail"] is None


def design_sweep(rng, joint, checker, fric_mean):
    """joint 0-based. Returns (ref, info)."""
    base_speeds = np.array([0.005, 0.01, 0.03, 0.1, 0.3, 1.0])
    for attempt in range(60):
        q0 = rng.uniform(*Q_HOME_BOX)
        centre = 0.5 * (Q_MIN[joint] + Q_MAX[joint])
        half = 0.5 * (Q_MAX[joint] - Q_MIN[joint])
        q0[joint] = centre + rng.uniform(-0.25, 0.25) * half
        if joint == 1:  # shoulder pitch: keep near vertical so that gravity stays within limits
            q0[joint] = rng.uniform(-0.4, 0.4)
        if joint == 1:  # a folded elbow keeps the shoulder's gravity load within its limit
            q0[3] = rng.uniform(1.6, 2.8)
        R = min(q0[joint] - Q_MIN[joint], Q_MAX[joint] - q0[joint]) - MARGIN_Q - 0.05
        speeds = base_speeds * rng.uniform(0.85, 1.15, size=len(base_speeds))
        order = rng.permutation(len(speeds))
        top_scale = 1.0
        dmax = min(0.9, R)
        for _shrink in range(6):
            sp = speeds.copy()
            sp[-1] *= top_scale
            sp[-2] = min(sp[-2], sp[-1] * 0.5)
            segs, cruise, t = [], [], 0.5
            segs.append((0.0, 0.5, 0.0, 0.0))
            a_max = 2.0 if joint < 2 else 3.0
            for n_i, si in enumerate(order):
                s = sp[si]
                tr = max(0.08, math.pi * s / (2 * a_max))
                tc = 2.0 if s < 0.015 else 1.2
                tc = min(tc, max(0.1, dmax / s - tr))
                first = 1.0 if n_i % 2 == 0 else -1.0
                for sgn in (first, -first):
                    segs += [(t, tr, 0.0, sgn * s)]
                    t += tr
                    segs += [(t, tc, sgn * s, sgn * s)]
                    cruise.append((t, t + tc, float(sgn * s)))
                    t += tc
                    segs += [(t, tr, sgn * s, 0.0)]
                    t += tr
                    segs += [(t, 0.3, 0.0, 0.0)]
                    t += 0.3
            ref = SweepRef(q0, joint, segs)
            ev = checker.evaluate(ref, ref.duration, fric=fric_mean)
            if _ok(ev):
                return ref, dict(q0=q0, speeds=sorted(float(v) for v in sp), cruise=cruise, duration=ref.duration,
                                 excursion_rad=float(max(abs(ev["qmax"][joint] - q0[joint]),
                                                         abs(q0[joint] - ev["qmin"][joint]))),
                                 design=dict(tau_ratio=ev["tau_ratio"], vcart=ev["vcart"], zmin=ev["zmin"],
                                             attempts=attempt + 1))
            if ev["fail"] == "cartesian_speed":
                top_scale *= 0.75
            elif ev["fail"] == "torque":
                dmax *= 0.7
                top_scale *= 0.85
            else:
                break
    raise RuntimeError("sweep design failed")  # never seen; a design failure is a bug of this module


def design_free(rng, joints, checker, fric_mean):
    joints = sorted(joints)
    K = 5
    for attempt in range(80):
        q0 = rng.uniform(*Q_HOME_BOX)
        for j in joints:
            centre = 0.5 * (Q_MIN[j] + Q_MAX[j])
            half = 0.5 * (Q_MAX[j] - Q_MIN[j])
            q0[j] = centre + rng.uniform(-0.2, 0.2) * half
            if j == 1:
                q0[j] = rng.uniform(-0.3, 0.3)
        period = rng.uniform(6.0, 12.0)
        wf = 2 * np.pi / period
        duration = float(np.clip(2 * period + 1.0, 18.0, 26.0))
        kk = np.arange(1, K + 1)
        a = rng.normal(size=(len(joints), K)) / kk
        b = rng.normal(size=(len(joints), K)) / kk
        t = np.arange(0, period, 0.005)
        ref0 = FourierRef(np.zeros(N), joints, wf, a, b, 1e9, t_fade=1e-9, t_start=-1.0)
        d, dd, ddd = ref0._series(t)
        amp = np.array([min(q0[j] - Q_MIN[j], Q_MAX[j] - q0[j]) - MARGIN_Q - 0.02 for j in joints])
        amp = np.minimum(amp, 1.1) * rng.uniform(0.5, 1.0, size=len(joints))
        if np.any(amp <= 0.05):
            continue
        sc = amp / np.abs(d).max(axis=0)
        sc = np.minimum(sc, 1.3 / np.abs(dd).max(axis=0))     # < 1.3 rad/s before fading
        sc = np.minimum(sc, 6.0 / np.abs(ddd).max(axis=0))    # < 6 rad/s^2
        for _shrink in range(8):
            A = a * sc[:, None]
            B = b * sc[:, None]
            ref = FourierRef(q0, joints, wf, A, B, duration)
            ev = checker.evaluate(ref, duration, fric=fric_mean)
            if _ok(ev):
                return ref, dict(q0=q0, period_s=period, harmonics=K, duration=duration,
                                 design=dict(tau_ratio=ev["tau_ratio"], vcart=ev["vcart"], zmin=ev["zmin"],
                                             qd_max=ev["qdmax"][joints].tolist(), attempts=attempt + 1))
            if ev["fail"] == "table":
                break
            sc = sc * 0.8
    raise RuntimeError("free design failed")




# ----------------------------------------------------------------------------------------------------------------
# A designed run (``next_experiment.yaml``): the reference the spec describes, evaluated here.

class DesignedRef:
    """The reference of an excitation spec (wamctl's ``kind: excitation``, as ``wamctl diagnose`` writes
    ``next_experiment.yaml``): hold ``settle_s`` at ``q0``, ``periods`` periods of the finite Fourier series
    ``q_j(t) = q0_j + sum_l a_jl / (w l) sin(w l t) - b_jl / (w l) (cos(w l t) - 1)``, ``w = 2 pi / period_s``,
    then hold ``settle_s`` at ``q0`` again (the series starts and ends at rest at ``q0``: sum_l a_jl = 0 and
    sum_l l b_jl = 0). The formula is the spec's own documentation of its trajectory (wamctl/specs/excitation.py,
    ``ExcitationSection``), evaluated here with this module's numpy, not with wamctl's code. ``a``, ``b``: (7, L),
    rad/s, zero rows for the joints that hold."""

    def __init__(self, q0, period_s, a, b, periods, settle_s):
        self.q0 = np.asarray(q0, float)
        self.period = float(period_s)
        self.a, self.b = np.asarray(a, float), np.asarray(b, float)
        self.periods, self.settle = int(periods), float(settle_s)
        self.duration = 2 * self.settle + self.periods * self.period
        self.joints = [j for j in range(N) if np.any(self.a[j]) or np.any(self.b[j])]

    def __call__(self, t):
        t = np.atleast_1d(np.asarray(t, float))
        u = t - self.settle
        on = (u >= 0) & (u < self.periods * self.period)    # the series; holds before and after
        w = 2 * np.pi / self.period
        wl = w * np.arange(1, self.a.shape[1] + 1)
        ph = np.outer(np.where(on, u, 0.0), wl)
        s, c = np.sin(ph), np.cos(ph)
        q = self.q0 + s @ (self.a / wl).T - (c - 1.0) @ (self.b / wl).T
        qd = c @ self.a.T + s @ self.b.T
        qdd = -s @ (self.a * wl).T + c @ (self.b * wl).T
        q[~on], qd[~on], qdd[~on] = self.q0, 0.0, 0.0
        return q, qd, qdd


def designed_reference(spec: dict) -> DesignedRef:
    """The :class:`DesignedRef` of an excitation spec mapping (``yaml.safe_load`` of ``next_experiment.yaml``):
    ``q0_rad`` and ``excitation.{period_s, harmonics, periods, settle_s, coefficients}``; absent keys take the
    spec's defaults (period 10 s, 5 harmonics, 2 periods, 1 s settle). ValueError naming the field when the spec
    is not of that form (a spec without designed coefficients, another kind, another arm)."""
    if spec.get("kind") != "excitation":
        raise ValueError(f"kind: {spec.get('kind')!r}; a designed run follows an excitation spec")
    if spec.get("robot", "wam7") != "wam7":
        raise ValueError(f"robot: {spec.get('robot')!r}; this generator simulates the wam7")
    ex = spec.get("excitation") or {}
    coef = ex.get("coefficients")
    if not coef:
        raise ValueError("excitation.coefficients: absent (the spec is not designed)")
    q0 = spec.get("q0_rad")
    if q0 is None or len(q0) != N:
        raise ValueError(f"q0_rad: expected {N} values")
    L = int(ex.get("harmonics", 5))
    a, b = np.zeros((N, L)), np.zeros((N, L))
    for j, c in coef.items():
        j = int(j)
        if not 1 <= j <= N or len(c["a_rad_s"]) != L or len(c["b_rad_s"]) != L:
            raise ValueError(f"excitation.coefficients.{j}: joint 1..{N} with {L} values of a_rad_s and b_rad_s")
        a[j - 1], b[j - 1] = c["a_rad_s"], c["b_rad_s"]
    return DesignedRef(q0, float(ex.get("period_s", 10.0)), a, b, int(ex.get("periods", 2)),
                       float(ex.get("settle_s", 1.0)))
