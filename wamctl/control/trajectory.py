"""Reference trajectories, sampled at the control rate.

LSPB (linear segment with parabolic blends) exactly as thesis eqs. 3.3-3.5: with blend time ``t_c``
(1 s on the real system) and final time ``t_f``,

    qdd_c = 4 (q_f - q_i) / (t_f^2 - (-2 (t_c - 0.5 t_f))^2) = (q_f - q_i) / (t_c (t_f - t_c))   (3.4)
    qd_c  = qdd_c t_c                                                                         (3.5)

The thesis prints (3.4) as the velocity and (3.5) as ``qdd_c = qd_c``: both hold for its t_c = 1 s. For other
blend times the right-hand side of (3.4) has the units of an acceleration (the trajectory is continuous only
with ``qd_c = qdd_c t_c``, the thesis' own definition), so it is read as ``qdd_c`` here; at t_c = 1 s the
numbers are the thesis' exactly.

and q(t) parabolic up to t_c, linear to t_f - t_c, parabolic to t_f (3.3). A move is specified by its
amplitude and cruise velocity; ``t_f = t_c + |q_f - q_i| / v``.

Arrays: time ``(n,)`` in s; positions, velocities, accelerations ``(n, joints)`` (the width of ``q0``) in rad,
rad/s, rad/s^2.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from wamctl.errors import SpecError


@dataclass
class Reference:
    """A sampled joint reference: ``t_s`` (n,), ``q_rad``, ``qd_rad_s``, ``qdd_rad_s2`` (n, joints: 7 on the wam7,
    4 on the wam4), and the sample indices where each segment (move or hold) starts, with its label, for reports
    and segment detection."""

    t_s: np.ndarray
    q_rad: np.ndarray
    qd_rad_s: np.ndarray
    qdd_rad_s2: np.ndarray
    segments: list[tuple[int, str]]

    def __len__(self) -> int:
        return len(self.t_s)


def lspb_final_time_s(amplitude_rad: float, velocity_rad_s: float, tc_s: float = 1.0) -> float:
    """t_f of an LSPB move of the given amplitude and cruise speed."""
    return tc_s + abs(amplitude_rad) / abs(velocity_rad_s)


def lspb(t_s: np.ndarray, q_i: float, q_f: float, t_f: float, tc_s: float = 1.0):
    """Thesis eq. 3.3 sampled at ``t_s`` (clamped to [0, t_f]).

    Returns
    -------
    q, qd, qdd : arrays shaped like ``t_s``.
    """
    if not 0 < 2 * tc_s <= t_f:
        raise ValueError(f"LSPB needs 0 < 2 t_c <= t_f (t_c={tc_s}, t_f={t_f})")
    t = np.clip(np.asarray(t_s, float), 0.0, t_f)
    qdd_c = 4.0 * (q_f - q_i) / (t_f**2 - (-2.0 * (tc_s - 0.5 * t_f)) ** 2)  # eq. 3.4 (see module doc)
    qd_c = qdd_c * tc_s                                                      # eq. 3.5, qd_c = qdd_c t_c
    first, last = t <= tc_s, t > t_f - tc_s
    mid = ~first & ~last
    q = np.where(first, q_i + 0.5 * qdd_c * t**2,
                 np.where(mid, 0.5 * (q_f + q_i - qd_c * t_f) + qd_c * t, q_f - 0.5 * qdd_c * (t_f - t) ** 2))
    qd = np.where(first, qdd_c * t, np.where(mid, qd_c, qdd_c * (t_f - t)))
    qdd = np.where(first, qdd_c, np.where(mid, 0.0, -qdd_c))
    inside = (np.asarray(t_s) >= 0) & (np.asarray(t_s) <= t_f)
    return q, np.where(inside, qd, 0.0), np.where(inside, qdd, 0.0)


class ReferenceBuilder:
    """Chains holds and LSPB moves into one :class:`Reference` sampled every ``dt_s``.

    >>> ref = ReferenceBuilder(q0, dt_s=0.002).hold(0.5).move({0: 0.5}, 0.083).hold(2.0).build()
    """

    def __init__(self, q0_rad, dt_s: float):
        self.dt_s = dt_s
        self._q = np.asarray(q0_rad, float).copy()
        self._parts: list[tuple[np.ndarray, np.ndarray, np.ndarray, str]] = []

    def hold(self, duration_s: float, label: str = "hold") -> ReferenceBuilder:
        n = int(round(duration_s / self.dt_s))
        if n > 0:
            zeros = np.zeros((n, self._q.size))
            self._parts.append((np.tile(self._q, (n, 1)), zeros, zeros.copy(), label))
        return self

    def move(self, deltas_rad: dict[int, float], velocity_rad_s: float, tc_s: float = 1.0,
             label: str = "move") -> ReferenceBuilder:
        """LSPB move of several joints (0-based index -> displacement) that start and end together.

        Every joint uses the same t_f, set by the largest displacement at ``velocity_rad_s``.
        """
        amp = max(abs(d) for d in deltas_rad.values())
        if not (velocity_rad_s > 0 and 0 < tc_s <= amp / velocity_rad_s):   # eq. 3.3 needs 2 t_c <= t_f
            raise SpecError(f"{label}: a move of {amp:g} rad at {velocity_rad_s:g} rad/s cruises "
                            f"{amp / velocity_rad_s if velocity_rad_s > 0 else float('nan'):.3g} s, less than its "
                            f"blend time tc_s = {tc_s:g} s; use a smaller tc_s, a larger amplitude or a lower velocity")
        t_f = lspb_final_time_s(amp, velocity_rad_s, tc_s)
        n = int(round(t_f / self.dt_s))
        t = np.arange(1, n + 1) * self.dt_s
        q = np.tile(self._q, (n, 1))
        qd = np.zeros((n, self._q.size))
        qdd = np.zeros((n, self._q.size))
        for j, d in deltas_rad.items():
            q[:, j], qd[:, j], qdd[:, j] = lspb(t, self._q[j], self._q[j] + d, t_f, tc_s)
        self._parts.append((q, qd, qdd, label))
        self._q = q[-1].copy()
        return self

    def build(self) -> Reference:
        if not self._parts:
            raise SpecError("the plan is empty: nothing to move and no time to hold")
        segments, start = [], 0
        for part in self._parts:
            segments.append((start, part[3]))
            start += len(part[0])
        q = np.concatenate([p[0] for p in self._parts])
        return Reference(np.arange(len(q)) * self.dt_s, q, np.concatenate([p[1] for p in self._parts]),
                         np.concatenate([p[2] for p in self._parts]), segments)
