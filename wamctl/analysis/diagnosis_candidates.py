"""Candidate effect signatures for the model diagnosis: one per effect name of the diagnosis vocabulary.

Every candidate turns the prepared signals of one joint into extra regressor columns, linear in its
parameters once a few shape parameters (a grid) are fixed, so that "declared model + effect" is a linear model
that nests the declared one. Shape parameters are chosen on training data only (see
:mod:`wamctl.analysis.diagnosis`). Signs follow the residual ``y = tau - rnea(q, qd, qdd)``: what friction and
the missing effects must supply.

=================  ===============================================================  ========  ============
name               columns                                                          grid      count
=================  ===============================================================  ========  ============
stribeck           [qd>0] e^-(qd/vs)^2, -[qd<0] e^-(qd/vs)^2                        vs        2
position_ripple    G(|qd|/P) [sin 2 pi q/P, cos 2 pi q/P] (G: smoothing filter gain)  period P  2
payload            link-7 columns of the joint torque regressor (m, m c_x, m c_y, m c_z) none      4
delay              tau(t) - tau(t - d) (the logged torque now vs d earlier)           d         1
friction_drift     classic friction columns x exp(-t / T)                           T         4
backlash           sigma_new exp(-(t - t_r) / T_k) after each direction reversal t_r,  none      4
                   k = 1..3, and the gravity stiffness dg_j/dq_j x direction
=================  ===============================================================  ========  ============
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from wamctl.analysis.diagnosis_signals import savgol_gain
from wamctl.model import params as P

EFFECT_NAMES = ("stribeck", "position_ripple", "payload", "delay", "friction_drift", "backlash")

STRIBECK_VS_GRID_RAD_S = np.geomspace(0.004, 0.4, 21)
RIPPLE_PERIOD_MIN_RAD = 0.01
RIPPLE_PERIOD_MAX_RAD = 2.0
DELAY_GRID_S = np.arange(2, 41) * 0.5e-3                # 1 to 20 ms
DRIFT_T_GRID_FRACTION = np.geomspace(0.05, 4.0, 12)    # time constants as fractions of the run length
BACKLASH_TIME_CONSTANTS_S = (0.015, 0.05, 0.15)
BACKLASH_WINDOW_FACTOR = 4.0                            # a reversal term lasts 4 x its time constant
D7_M = float(P.DH_D_M[6])


@dataclass
class JointData:
    """The samples of one joint that the torque residual uses (decimated, sliding only).

    Attributes
    ----------
    j : 0-based joint.
    idx : (m,) indices into the full-rate signals.
    t_s, q_rad, qd_rad_s, qdd_rad_s2, y_Nm : (m,) the joint's samples; ``y`` = tau - rnea.
    fold : (m,) fold number of each sample (contiguous time blocks).
    extra : per-run precomputed arrays keyed by name (payload regressor rows, shifted torques, ...).
    """

    j: int
    idx: np.ndarray
    t_s: np.ndarray
    q_rad: np.ndarray
    qd_rad_s: np.ndarray
    qdd_rad_s2: np.ndarray
    y_Nm: np.ndarray
    fold: np.ndarray
    extra: dict = field(default_factory=dict)

    @property
    def n(self) -> int:
        return len(self.idx)


def friction_columns(qd: np.ndarray) -> np.ndarray:
    """Classic per-direction friction regressor (m, 4): [fc_pos, fc_neg, b_pos, b_neg] (levels as magnitudes)."""
    pos = qd > 0
    neg = qd < 0
    return np.column_stack([pos, -1.0 * neg, qd * pos, qd * neg]).astype(float)


def stribeck_columns(qd: np.ndarray, vs: float) -> np.ndarray:
    e = np.exp(-(qd / vs) ** 2)
    return np.column_stack([(qd > 0) * e, -1.0 * (qd < 0) * e])


def ripple_columns(q: np.ndarray, qd: np.ndarray, period: float, window: int, dt_s: float) -> np.ndarray:
    """sin/cos of 2 pi q / period, attenuated as the smoothing filter attenuates them at the current speed."""
    gain = savgol_gain(window, np.abs(qd) * dt_s / period)
    ph = 2 * np.pi * q / period
    return np.column_stack([gain * np.sin(ph), gain * np.cos(ph)])


def drift_columns(qd: np.ndarray, t_rel: np.ndarray, T: float) -> np.ndarray:
    return friction_columns(qd) * np.exp(-t_rel / T)[:, None]


def reversal_times(t_s: np.ndarray, qd: np.ndarray, moving: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Times where a joint starts sliding opposite to its previous sliding direction, and the new direction.

    Parameters
    ----------
    t_s, qd, moving : (n,) full-rate time, smoothed velocity and sliding mask of one joint.
    """
    sl = np.flatnonzero(moving)
    if len(sl) == 0:
        return np.zeros(0), np.zeros(0)
    sgn = np.sign(qd[sl])
    starts = np.flatnonzero(np.diff(sl) > 1) + 1            # first sample of each sliding stretch
    ch = np.flatnonzero(sgn[1:] != sgn[:-1]) + 1             # sign flips inside the sliding samples
    ev = np.union1d(starts, ch)
    ev = ev[sgn[ev] != sgn[ev - 1]]
    return t_s[sl[ev]], sgn[ev]


def backlash_columns(t_s: np.ndarray, qd: np.ndarray, events_t: np.ndarray, events_sign: np.ndarray,
                     dgdq: np.ndarray) -> np.ndarray:
    """Reversal terms: for each time constant T_k, sigma_new exp(-(t - t_r)/T_k) over 4 T_k after the last
    reversal t_r, plus the gravity stiffness times the direction (the link sits w/2 off the encoder)."""
    cols = []
    if len(events_t):
        k = np.searchsorted(events_t, t_s, side="right") - 1
        has = k >= 0
        since = np.where(has, t_s - events_t[np.maximum(k, 0)], np.inf)
        sgn = np.where(has, events_sign[np.maximum(k, 0)], 0.0)
    else:
        since = np.full(len(t_s), np.inf)
        sgn = np.zeros(len(t_s))
    for T in BACKLASH_TIME_CONSTANTS_S:
        inside = since < BACKLASH_WINDOW_FACTOR * T
        cols.append(np.where(inside, sgn * np.exp(-np.where(inside, since, 0.0) / T), 0.0))
    cols.append(dgdq * np.sign(qd))
    return np.column_stack(cols)
