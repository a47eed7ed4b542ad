"""Friction identification (thesis chapter 4.2): constant-velocity stages -> friction-velocity map -> models.

Pipeline (no I/O; the caller loads a :class:`~wamctl.runs.measured.RunData`)
----------------------------------------------------------------------
1. **Moves** of each joint: where its reference moves (``q_ref``, a hint: it gives the windows and the
   commanded speed), or, without a reference, where the measured position travels (:func:`detect_moves`).
2. **Constant-velocity stage** of each move, from the measured positions alone
   (:func:`constant_velocity_stage`): a line is fitted to the middle of the move and the stage grown outwards
   while the position stays within a band around the line whose width comes from the data's own noise
   (quantisation + noise + the real jitter of the motion). Acceleration phases, the stuck start of a slow
   move (the joint waits until the PD error exceeds the breakaway torque), oscillating transients and the
   creep after the reference stops all leave the line quadratically or exponentially and fall outside.
   Stages that are too short, or whose two halves move at different speeds, are rejected with a reason.
3. **Per stage**: mean velocity = slope of the line (robust to quantisation), its spread from a
   Savitzky-Golay velocity; friction torque per sample = logged torque minus the declared rigid-body model,
   ``tau - inverse_dynamics(q, qd, qdd)`` (with gravity compensation on, the logged torque is the applied
   one, PD + g(q); the model's g(q) cancels it); mean, standard deviation and a 95 % confidence interval
   by batch means (the samples are autocorrelated).
4. **Models** (scikit-learn style estimators, ``fit(map) -> self``, fitted attributes end in ``_``):
   :class:`ClassicFriction` per direction (thesis eq. 4.1, Table 4.1 layout), symmetric, and
   :class:`StribeckFriction` (eq. 2.8, per direction Fc, Fs, sigma2, shared vs and delta), by
   ``scipy.optimize.least_squares`` with an optional robust loss (``soft_l1``, ``huber``, ``cauchy``);
   parameter standard errors from the Jacobian, ``cov = s^2 (J^T J)^-1``.
5. **Selection** (:func:`select_model`): k-fold over segments (stratified by direction and speed), the
   held-out residuals scored by an information criterion, ``BIC = n ln(SSE_cv / n) + k ln n`` (or AIC,
   ``+ 2k``); the smallest wins.

Sign convention: friction is the torque the motor supplies to keep moving (positive for positive velocity),
as in :class:`wamctl.model.friction.FrictionModel`; Coulomb and breakaway levels are reported as magnitudes.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field

import numpy as np
import pandas as pd
from scipy import stats
from scipy.optimize import least_squares
from scipy.signal import savgol_filter

from wamctl.errors import DataFormatError
from wamctl.model import params as P
from wamctl.model.friction import FrictionModel

log = logging.getLogger(__name__)

MODEL_NAMES = ("classic", "classic_symmetric", "stribeck")
MAP_COLUMNS = ["joint", "move", "direction", "v_cmd_rad_s", "t_start_s", "t_end_s", "n_samples",
               "velocity_rad_s", "velocity_std_rad_s", "velocity_ci95_rad_s", "friction_Nm", "friction_std_Nm",
               "friction_se_Nm", "friction_ci95_Nm", "stick_fraction", "accepted", "reason"]


# ================================================================================================ signals
def savgol_derivative(x: np.ndarray, dt_s: float, window_s: float, polyorder: int = 1, deriv: int = 1) -> np.ndarray:
    """Savitzky-Golay derivative of ``x`` ((n,) or (n, m), along axis 0) over a window of ``window_s``.

    polyorder 1 is a sliding linear fit (its slope is the velocity); returns the same shape as ``x``.
    """
    n = x.shape[0]
    w = int(round(window_s / dt_s)) | 1
    w = max(w, polyorder + 2 + (polyorder % 2 == 0))
    if w % 2 == 0:
        w += 1
    if n < w:
        w = n if n % 2 else n - 1
    if w <= polyorder:
        return np.zeros_like(x, dtype=float)
    return savgol_filter(x, w, polyorder, deriv=deriv, delta=dt_s, axis=0, mode="interp")


def position_noise_rad(q: np.ndarray) -> float:
    """Per-sample position noise (rad) of a signal that is smooth at the sample rate: quantisation + noise.

    From second differences, ``var(d2) = 6 sigma^2`` for white noise; the largest 1 % (accelerations,
    steps) are left out. Quantised, noise-free data give about ``step / sqrt(12)`` when the signal moves.
    """
    d2 = np.diff(np.asarray(q, float), 2)
    if len(d2) < 10:
        return 0.0
    a = np.abs(d2)
    cut = np.quantile(a, 0.99)
    kept = d2[a <= cut]
    return float(np.sqrt(np.mean(kept ** 2) / 6.0)) if len(kept) else 0.0


def quantisation_step_rad(q: np.ndarray) -> float:
    """Smallest recurring non-zero step of ``q`` (rad), 0 if none is evident (noisy or continuous data)."""
    d = np.abs(np.diff(np.asarray(q, float)))
    d = d[d > 1e-12]
    if len(d) < 10:
        return 0.0
    small = np.quantile(d, 0.05)
    near = d[d <= 1.5 * small]
    # a quantised signal repeats the same step: most small steps agree within 1 %
    if len(near) > 0.02 * len(d) and np.std(near) <= 0.02 * small:
        return float(np.median(near))
    return 0.0


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """Maximal runs of True as (start, stop) index pairs (stop exclusive)."""
    m = np.concatenate([[False], np.asarray(mask, bool), [False]])
    d = np.diff(m.astype(np.int8))
    return list(zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1)))


# ================================================================================================ moves
@dataclass
class Move:
    """One move of one joint: samples ``[i0, i1)`` where the stage is searched, its direction, and the
    commanded speed when a reference is known (NaN otherwise)."""

    i0: int
    i1: int
    direction: int
    v_cmd_rad_s: float = float("nan")


def moves_from_reference(t_s: np.ndarray, q_ref: np.ndarray, min_travel_rad: float = 1e-4,
                         creep_s: float = 2.0) -> list[Move]:
    """Moves of one joint from its reference (the commanded schedule as a hint).

    Each window runs from the start of a reference move to the start of the next one, but at most
    ``creep_s`` (or half the move's duration, if longer) past the end of the reference move: a joint under PD
    creeps on after its reference stops. ``q_ref`` (n,).
    """
    dq = np.diff(q_ref)
    moving = np.abs(dq) > 1e-12
    sgn = np.sign(dq)
    out = []
    starts = []
    for a, b in _runs(moving):
        # split where the direction flips without a hold
        cuts = [a] + [k for k in range(a + 1, b) if sgn[k] != sgn[k - 1] and sgn[k] != 0] + [b]
        for s0, s1 in zip(cuts[:-1], cuts[1:]):
            travel = q_ref[s1] - q_ref[s0]
            if abs(travel) < min_travel_rad:
                continue
            dt = np.diff(t_s[s0:s1 + 1])
            v = float(np.max(np.abs(dq[s0:s1] / dt)))
            starts.append((s0, s1, int(np.sign(travel)), v * np.sign(travel)))
    for k, (s0, s1, d, v) in enumerate(starts):
        end = starts[k + 1][0] if k + 1 < len(starts) else len(q_ref)
        t_end = t_s[s1] + max(creep_s, 0.5 * (t_s[s1] - t_s[s0]))
        end = min(end, int(np.searchsorted(t_s, t_end)))
        out.append(Move(int(s0), int(end), d, float(v)))
    return out


def detect_moves(t_s: np.ndarray, q: np.ndarray, sigma_q: float | None = None, min_duration_s: float = 0.3,
                 min_travel_rad: float | None = None, gap_s: float = 0.3) -> list[Move]:
    """Moves of one joint from its measured position alone (no reference): sign-consistent runs of a
    heavily smoothed velocity above a noise-based threshold; runs of one sign separated by short stops
    (stick-slip) are merged. ``q`` (n,)."""
    dt = float(np.median(np.diff(t_s)))
    sigma_q = position_noise_rad(q) if sigma_q is None else sigma_q
    step = quantisation_step_rad(q)
    sig = max(sigma_q, step / math.sqrt(12.0), 1e-7)
    w_s = 0.25
    v = savgol_derivative(q, dt, w_s, 1)
    nw = max(3, int(round(w_s / dt)))
    sigma_v = sig * math.sqrt(12.0 / (nw * (nw ** 2 - 1))) / dt
    thr = max(8.0 * sigma_v, 2e-4)
    if min_travel_rad is None:
        min_travel_rad = max(30.0 * sig, 2e-3)
    out: list[Move] = []
    for sign in (1, -1):
        runs = _runs(sign * v > thr)
        merged: list[list[int]] = []
        for a, b in runs:
            if merged and (t_s[a] - t_s[merged[-1][1] - 1]) <= gap_s:
                merged[-1][1] = b
            else:
                merged.append([a, b])
        for a, b in merged:
            if t_s[b - 1] - t_s[a] < min_duration_s or abs(q[b - 1] - q[a]) < min_travel_rad:
                continue
            out.append(Move(int(a), int(b), sign))
    return sorted(out, key=lambda m: m.i0)


# ================================================================================================ stages
@dataclass
class Stage:
    """The constant-velocity stage ``[s0, s1)`` of a move, or why there is none (``s0 == s1``)."""

    s0: int
    s1: int
    reason: str = ""

    @property
    def ok(self) -> bool:
        return self.s1 > self.s0 and not self.reason


def _line(t, q):
    """Least-squares line q = a + b (t - t.mean()); returns (a, b, tm)."""
    tm = t.mean()
    tt = t - tm
    den = float(tt @ tt)
    b = float(tt @ (q - q.mean()) / den) if den > 0 else 0.0
    return float(q.mean()), b, tm


def constant_velocity_stage(t_s: np.ndarray, q: np.ndarray, i0: int, i1: int, sigma_q: float,
                            step_rad: float = 0.0, min_stage_s: float = 0.2, guard_s: float = 0.02,
                            consistency: float = 0.05, band_sigmas: float = 4.0) -> Stage:
    """The constant-velocity stage of the move in samples ``[i0, i1)`` of one joint, from positions alone.

    A line is fitted to the middle third of the samples where the joint travels (the part between 10 % and
    90 % of the move's travel), and the stage grows outwards while ``|q - line|`` stays within
    ``band_sigmas`` times the residual scale (robust std of the residual in the current stage, at least the
    noise/quantisation floor); refitted three times. A guard of ``guard_s`` is cut at each end. Rejected
    (``reason`` set) when shorter than ``min_stage_s`` or when its two halves' slopes differ by more than
    ``consistency`` (relative) plus their noise: no constant velocity was reached.

    Parameters
    ----------
    t_s, q : (n,) time and measured position of the joint.
    i0, i1 : window of the move (i1 exclusive).
    sigma_q : per-sample position noise (rad); ``step_rad`` the quantisation step if known.
    """
    t, x = t_s[i0:i1], q[i0:i1]
    if len(x) < 20:
        return Stage(i0, i0, "too few samples")
    dt = float(np.median(np.diff(t)))
    travel = x - x[0]
    total = travel[np.argmax(np.abs(travel))]
    if abs(total) < max(10 * sigma_q, 3 * step_rad, 1e-6):
        return Stage(i0, i0, "the joint did not move")
    frac = travel / total
    inside = np.flatnonzero((frac > 0.1) & (frac < 0.9))
    if len(inside) < 10:
        return Stage(i0, i0, "no travel between 10 % and 90 % of the move")
    a, b = inside[0], inside[-1] + 1
    third = (b - a) // 3
    lo, hi = a + third, b - third
    if hi - lo < 5:
        lo, hi = a, b
    floor = max(sigma_q, step_rad / math.sqrt(12.0), 1e-9)
    for _ in range(4):
        c, v, tm = _line(t[lo:hi], x[lo:hi])
        r = x - (c + v * (t - tm))
        rs = r[lo:hi]
        scale = max(1.4826 * float(np.median(np.abs(rs - np.median(rs)))), floor)
        band = band_sigmas * scale + 0.5 * step_rad
        ok = np.abs(r) <= band
        # grow from the centre of the current stage while inside the band (single outliers tolerated)
        centre = (lo + hi) // 2
        ok_s = np.convolve(ok.astype(float), np.ones(5) / 5, mode="same") >= 0.6
        if not ok_s[centre]:
            break
        new_lo = centre
        while new_lo > 0 and ok_s[new_lo - 1]:
            new_lo -= 1
        new_hi = centre + 1
        while new_hi < len(x) and ok_s[new_hi]:
            new_hi += 1
        if (new_lo, new_hi) == (lo, hi):
            break
        lo, hi = new_lo, new_hi
    g = int(round(guard_s / dt))
    lo, hi = lo + g, hi - g
    if (hi - lo) * dt < min_stage_s:
        return Stage(i0 + max(lo, 0), i0 + max(lo, 0), f"constant-velocity stage shorter than {min_stage_s} s")
    # the two halves must agree: an exponential approach or a drift is not a constant velocity
    mid = (lo + hi) // 2
    _, v1, _ = _line(t[lo:mid], x[lo:mid])
    _, v2, _ = _line(t[mid:hi], x[mid:hi])
    n_half = (hi - lo) / 2
    noise_v = band_sigmas * floor * math.sqrt(12.0 / max(n_half ** 3, 1.0)) / dt
    vbar = abs(v1 + v2) / 2
    if abs(v1 - v2) > consistency * vbar + noise_v:
        return Stage(i0 + lo, i0 + lo, f"velocity not constant ({v1:.4g} vs {v2:.4g} rad/s in the two halves)")
    return Stage(i0 + lo, i0 + hi)


def batch_mean_se(x: np.ndarray, blocks: int = 10) -> tuple[float, float]:
    """Standard error of the mean of an autocorrelated series by batch means, and the half-width of its 95 %
    confidence interval (Student t with blocks - 1 degrees of freedom). NaN for fewer than 60 samples."""
    n = len(x)
    k = min(blocks, n // 20)
    if k < 3:
        return float("nan"), float("nan")
    means = np.array([b.mean() for b in np.array_split(x, k)])
    se = float(means.std(ddof=1) / math.sqrt(k))
    return se, float(stats.t.ppf(0.975, k - 1) * se)


# ================================================================================================ map
@dataclass
class MapOptions:
    """Settings of segment detection (defaults suit 500 Hz WAM data)."""

    use_reference: bool = True      # take move windows (and commanded speeds) from q_ref when present
    min_stage_s: float = 0.2
    guard_s: float = 0.02
    consistency: float = 0.05
    band_sigmas: float = 4.0
    # Savitzky-Golay window of qd, qdd for the inverse dynamics; short, because a longer one smooths away the
    # decaying oscillation after a blend and biases the inertial correction of short, fast stages
    derivative_window_s: float = 0.04
    stick_fraction_max: float = 0.1   # reject stages where the joint stands still more than this
    velocity_tolerance: float = 0.03  # with a commanded speed: reject stages off it by more (not steady)


def friction_samples(t_s: np.ndarray, q: np.ndarray, tau: np.ndarray, rows: np.ndarray, dynamics,
                     window_s: float = 0.04) -> np.ndarray:
    """Friction torque at the samples ``rows``: ``tau - inverse_dynamics(q, qd, qdd)``, all joints.

    Parameters
    ----------
    t_s : (n,); q, tau : (n, 7) measured position and logged (applied) torque.
    rows : (m,) sample indices. dynamics : a :class:`~wamctl.model.dynamics.WamDynamics` (the declared model).

    Returns
    -------
    (m, 7) friction torque, N m (the torque the motor supplied beyond the rigid body's needs).
    """
    dt = float(np.median(np.diff(t_s)))
    qd = savgol_derivative(q, dt, window_s, 2, 1)
    qdd = savgol_derivative(q, dt, window_s, 2, 2)
    out = np.empty((len(rows), q.shape[1]))
    for k, i in enumerate(rows):
        out[k] = tau[i] - dynamics.inverse_dynamics(q[i], qd[i], qdd[i])
    return out


def friction_map(t_s: np.ndarray, q: np.ndarray, tau: np.ndarray, q_ref: np.ndarray | None, joints,
                 dynamics, options: MapOptions | None = None) -> pd.DataFrame:
    """The friction-velocity map: one row per move of each joint (columns :data:`MAP_COLUMNS`).

    Parameters
    ----------
    t_s : (n,) time; q, tau : (n, 7) measured positions and logged torques; q_ref : (n, 7) reference or None.
    joints : 1-based joint numbers to analyse. dynamics : the declared rigid-body model.
    """
    o = options or MapOptions()
    t_s = np.asarray(t_s, float)
    dt = float(np.median(np.diff(t_s)))
    rows = []
    stage_rows: list[np.ndarray] = []
    for j in joints:
        x = q[:, j - 1]
        sig = position_noise_rad(x)
        step = quantisation_step_rad(x)
        if q_ref is not None and o.use_reference:
            moves = moves_from_reference(t_s, q_ref[:, j - 1])
        else:
            moves = detect_moves(t_s, x, sig)
        v_fine = savgol_derivative(x, dt, 0.05, 1)
        for k, m in enumerate(moves):
            st = constant_velocity_stage(t_s, x, m.i0, m.i1, sig, step, o.min_stage_s, o.guard_s,
                                         o.consistency, o.band_sigmas)
            row = {"joint": j, "move": k, "direction": m.direction, "v_cmd_rad_s": m.v_cmd_rad_s,
                   "t_start_s": float(t_s[st.s0]) if st.s0 < len(t_s) else float("nan"),
                   "t_end_s": float(t_s[st.s1 - 1]) if st.s1 > st.s0 else float("nan"),
                   "n_samples": st.s1 - st.s0, "accepted": st.ok, "reason": st.reason}
            if st.ok:
                sl = slice(st.s0, st.s1)
                _, v, _ = _line(t_s[sl], x[sl])
                # velocity spread and the CI of the mean velocity from block slopes
                nb = min(10, (st.s1 - st.s0) // 25)
                if nb >= 3:
                    blocks = np.array_split(np.arange(st.s0, st.s1), nb)
                    bv = np.array([_line(t_s[b], x[b])[1] for b in blocks])
                    v_ci = float(stats.t.ppf(0.975, nb - 1) * bv.std(ddof=1) / math.sqrt(nb))
                else:
                    v_ci = float("nan")
                vf = v_fine[sl]
                still = float(np.mean(np.abs(vf) < 0.1 * abs(v)))
                row.update(velocity_rad_s=v, velocity_std_rad_s=float(np.std(vf)), velocity_ci95_rad_s=v_ci,
                           stick_fraction=still)
                if np.sign(v) != m.direction:
                    row.update(accepted=False, reason="moved against the commanded direction")
                elif np.isfinite(m.v_cmd_rad_s) and abs(v / m.v_cmd_rad_s - 1) > o.velocity_tolerance:
                    off = abs(v / m.v_cmd_rad_s - 1)
                    row.update(accepted=False, reason=f"mean velocity {v:.4g} rad/s is {off:.0%} off the commanded "
                                                      f"{m.v_cmd_rad_s:.4g}: not in steady state")
                elif still > o.stick_fraction_max:
                    row.update(accepted=False, reason=f"stands still {still:.0%} of the stage (stick-slip)")
                stage_rows.append(np.arange(st.s0, st.s1))
            rows.append(row)
    df = pd.DataFrame(rows, columns=MAP_COLUMNS)
    if not len(df):
        return df
    # friction torque of every stage, in one pass of inverse dynamics
    all_rows = np.concatenate(stage_rows) if stage_rows else np.zeros(0, int)
    if len(all_rows):
        f = friction_samples(t_s, q, tau, all_rows, dynamics, o.derivative_window_s)
        pos = 0
        for idx in df.index[df["n_samples"] > 0]:
            if pd.isna(df.at[idx, "velocity_rad_s"]):
                continue
            n = int(df.at[idx, "n_samples"])
            fj = f[pos:pos + n, int(df.at[idx, "joint"]) - 1]
            pos += n
            df.at[idx, "friction_Nm"] = float(fj.mean())
            df.at[idx, "friction_std_Nm"] = float(fj.std(ddof=1))
            df.at[idx, "friction_se_Nm"], df.at[idx, "friction_ci95_Nm"] = batch_mean_se(fj)
    df["accepted"] = df["accepted"].astype(bool)
    return df


# ================================================================================================ models
def _as_vf(data) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(velocity, friction, sigma) arrays from a map DataFrame (accepted rows; ``sigma_Nm`` if present, else
    ones) or a ``(v, F)`` / ``(v, F, sigma)`` tuple."""
    if isinstance(data, pd.DataFrame):
        d = data[data["accepted"].astype(bool)] if "accepted" in data else data
        s = d["sigma_Nm"].to_numpy(float) if "sigma_Nm" in d else np.ones(len(d))
        return d["velocity_rad_s"].to_numpy(float), d["friction_Nm"].to_numpy(float), s
    v, f, *rest = data
    v, f = np.asarray(v, float), np.asarray(f, float)
    s = np.asarray(rest[0], float) if rest and rest[0] is not None else np.ones(len(v))
    return v, f, s


@dataclass
class _Solution:
    """A least-squares solution in the shape of scipy's result: ``x``, ``jac`` (of the weighted residuals)."""

    x: np.ndarray
    jac: np.ndarray
    cost: float = 0.0


class _LsqFriction:
    """Base of the friction estimators: a least-squares fit of ``F(v)`` with parameter standard errors."""

    name = "base"
    param_names: tuple[str, ...] = ()

    def __init__(self, loss: str = "linear", f_scale: float | None = None):
        self.loss = loss
        self.f_scale = f_scale

    # subclasses: _predict(p, v), _x0(v, f), _bounds()
    def _predict(self, p, v):  # pragma: no cover - abstract
        raise NotImplementedError

    @property
    def n_params(self) -> int:
        return len(self.param_names)

    def _check(self, v, f, s):
        if len(v) != len(f) or len(s) != len(v) or not np.all(np.isfinite(v)) or not np.all(np.isfinite(f)):
            raise ValueError("velocity and friction must be finite arrays of one length")
        if not np.all(np.isfinite(s)) or (s <= 0).any():
            raise ValueError("sigma must be positive and finite")
        for side, m in (("positive", v > 0), ("negative", v < 0)):
            if m.sum() < self._min_per_side:
                raise ValueError(f"{self.name}: needs {self._min_per_side} points at {side} velocity, "
                                 f"got {int(m.sum())}")

    _min_per_side = 2

    def _jac(self, p, v):  # pragma: no cover - abstract
        """(n, k) derivative of F(v) with respect to the parameters."""
        raise NotImplementedError

    def _solve(self, v, f, s, x0, bounds):
        """Minimise sum(rho(((F(v) - f) / s)^2)) from ``x0`` (analytic Jacobian)."""
        scale = self.f_scale
        if self.loss != "linear" and scale is None:
            z0 = (self._predict(np.asarray(x0, float), v) - f) / s
            scale = max(1.4826 * float(np.median(np.abs(z0 - np.median(z0)))), 1e-9)
        return least_squares(lambda p: (self._predict(p, v) - f) / s, x0,
                             jac=lambda p: self._jac(p, v) / s[:, None], bounds=bounds, loss=self.loss,
                             f_scale=scale if scale else 1.0, method="trf", x_scale="jac", max_nfev=500)

    def _finish(self, res, v, f, s):
        """Fitted attributes; the covariance scales (J^T J)^-1 by the reduced chi-square (the weights are
        relative, as ``scipy.optimize.curve_fit`` with ``absolute_sigma=False``)."""
        self.params_ = np.asarray(res.x, float)
        r = self._predict(self.params_, v) - f
        z = r / s
        self.residuals_ = r
        self.n_points_ = len(v)
        dof = max(len(v) - self.n_params, 1)
        self.chi2_ = float(np.sum(z ** 2))
        scale2 = self.chi2_ / dof
        jac = np.asarray(res.jac, float)
        jtj = jac.T @ jac
        self.cov_ = np.linalg.pinv(jtj) * scale2
        self.params_std_ = np.sqrt(np.clip(np.diag(self.cov_), 0, None))
        if np.linalg.matrix_rank(jac) < self.n_params:   # a parameter the data do not determine
            self.params_std_ = np.where(np.diag(jtj) > 1e-12 * max(np.diag(jtj).max(), 1e-300),
                                        self.params_std_, np.inf)
        self.rss_ = float(np.sum(r ** 2))
        self.sigma_ = float(np.sqrt(self.rss_ / dof))
        return self

    def predict(self, v) -> np.ndarray:
        """F(v), N m, same shape as ``v``."""
        return self._predict(self.params_, np.asarray(v, float))

    def information_criteria(self, known_sigma: bool = True) -> dict:
        """In-sample Gaussian AIC and BIC: with the points' sigma known, ``chi2 + 2k`` and ``chi2 + k ln n``;
        otherwise (sigma estimated from the residuals) ``n ln(chi2 / n) + 2k`` and ``+ k ln n``."""
        n, k = self.n_points_, self.n_params
        ll = self.chi2_ if known_sigma else n * math.log(max(self.chi2_ / n, 1e-300))
        return {"aic": ll + 2 * k, "bic": ll + k * math.log(n)}

    def params(self) -> dict:
        return {n: float(x) for n, x in zip(self.param_names, self.params_)}

    def params_std(self) -> dict:
        return {n: float(x) for n, x in zip(self.param_names, self.params_std_)}

    def to_dict(self) -> dict:
        return {"model": self.name, "loss": self.loss, "params": self.params(), "std": self.params_std(),
                "n_points": self.n_points_, "rmse_Nm": math.sqrt(self.rss_ / self.n_points_),
                **self.information_criteria()}


class ClassicFriction(_LsqFriction):
    """Classic model (thesis eq. 4.1) per direction, Table 4.1 layout:
    ``F = fc_pos + sigma2_pos v`` (v > 0), ``F = -fc_neg + sigma2_neg v`` (v < 0); with
    ``symmetric=True`` one ``fc`` and one ``sigma2``.

    Fitted attributes: ``params_`` (fc_pos, sigma2_pos, fc_neg, sigma2_neg) or (fc, sigma2), ``params_std_``,
    ``cov_``, ``residuals_``, ``sigma_``; the Table 4.1 view ``fc_pos_``, ``fc_neg_``, ``sigma2_pos_``,
    ``sigma2_neg_`` and their ``*_std_``.
    """

    def __init__(self, symmetric: bool = False, loss: str = "linear", f_scale: float | None = None):
        super().__init__(loss, f_scale)
        self.symmetric = symmetric
        self.name = "classic_symmetric" if symmetric else "classic"
        self.param_names = ("fc", "sigma2") if symmetric else ("fc_pos", "sigma2_pos", "fc_neg", "sigma2_neg")
        self._min_per_side = 1 if symmetric else 2

    def _design(self, v):
        """(n, k) design matrix: the classic model is linear, F = A(v) p."""
        if self.symmetric:
            return np.column_stack([np.sign(v), v])
        pf, nf = (v > 0).astype(float), (v < 0).astype(float)
        return np.column_stack([pf, pf * v, -nf, nf * v])

    def _predict(self, p, v):
        return self._design(np.asarray(v, float)) @ np.asarray(p, float)

    def _jac(self, p, v):
        return self._design(v)

    def fit(self, data) -> ClassicFriction:
        """Fit on a map (DataFrame with ``velocity_rad_s``, ``friction_Nm`` [, ``sigma_Nm``, ``accepted``]) or
        a ``(v, F[, sigma])`` tuple of (n,) arrays; returns self."""
        v, f, s = _as_vf(data)
        self._check(v, f, s)
        # linear least squares; it starts the fit when the loss is robust
        a = self._design(v) / s[:, None]
        x0 = np.linalg.lstsq(a, f / s, rcond=None)[0]
        if self.loss == "linear":
            res = _Solution(x0, a)
        else:
            res = self._solve(v, f, s, x0, (-np.inf, np.inf))
        self._finish(res, v, f, s)
        p, s = self.params_, self.params_std_
        if self.symmetric:
            self.fc_pos_ = self.fc_neg_ = float(p[0])
            self.sigma2_pos_ = self.sigma2_neg_ = float(p[1])
            self.fc_pos_std_ = self.fc_neg_std_ = float(s[0])
            self.sigma2_pos_std_ = self.sigma2_neg_std_ = float(s[1])
        else:
            self.fc_pos_, self.sigma2_pos_, self.fc_neg_, self.sigma2_neg_ = map(float, p)
            self.fc_pos_std_, self.sigma2_pos_std_, self.fc_neg_std_, self.sigma2_neg_std_ = map(float, s)
        return self

    def joint_params(self) -> dict:
        """This fit in friction-model-file terms (magnitudes; viscous as fitted, clipped at 0)."""
        return {"fc_pos_Nm": max(self.fc_pos_, 0.0), "fc_neg_Nm": max(self.fc_neg_, 0.0),
                "viscous_pos_Nm_s_rad": max(self.sigma2_pos_, 0.0),
                "viscous_neg_Nm_s_rad": max(self.sigma2_neg_, 0.0)}


class StribeckFriction(_LsqFriction):
    """Stribeck model (thesis eq. 2.8) per direction with shared ``vs`` and ``delta``:
    ``F = s (fc_s + (fs_s - fc_s) exp(-|v / vs|^delta)) + sigma2_s v`` with s the sign of v.

    The breakaway level is at least the Coulomb level (``fs = fc + dfs``, ``dfs >= 0``: the Stribeck effect
    is friction rising towards rest); ``vs`` lies between a fifth of the slowest and half the fastest speed
    measured (beyond the data it would only bend the viscous line); ``delta`` in [0.5, 4] (``fit_delta=False``
    keeps ``delta``). Non-linear least squares started from a (vs, delta) grid.

    Fitted attributes as :class:`ClassicFriction`, plus ``fs_pos_``, ``fs_neg_``, ``vs_``, ``delta_`` and
    their ``*_std_`` (``fs`` by the delta method).
    """

    name = "stribeck"

    def __init__(self, loss: str = "linear", f_scale: float | None = None, fit_delta: bool = True,
                 delta: float = 2.0):
        super().__init__(loss, f_scale)
        self.fit_delta = fit_delta
        self.delta = delta
        self.param_names = ("fc_pos", "dfs_pos", "sigma2_pos", "fc_neg", "dfs_neg", "sigma2_neg", "vs") + \
            (("delta",) if fit_delta else ())
        self._min_per_side = 3

    def _unpack(self, p):
        d = p[7] if self.fit_delta else self.delta
        return p[0], p[1], p[2], p[3], p[4], p[5], p[6], d

    def _predict(self, p, v):
        fcp, dfp, bp, fcn, dfn, bn, vs, d = self._unpack(p)
        e = np.exp(-np.abs(v / vs) ** d)
        return np.where(v > 0, fcp + dfp * e + bp * v, np.where(v < 0, -(fcn + dfn * e) + bn * v, 0.0))

    def _jac(self, p, v):
        fcp, dfp, bp, fcn, dfn, bn, vs, d = self._unpack(p)
        pos, neg = (v > 0).astype(float), (v < 0).astype(float)
        x = np.abs(v) / vs
        xd = x ** d
        e = np.exp(-xd)
        de_dvs = e * d * xd / vs
        de_dd = -e * xd * np.log(np.where(x > 0, x, 1.0))
        df = pos * dfp - neg * dfn          # the signed level of the Stribeck term
        cols = [pos, pos * e, pos * v, -neg, -neg * e, neg * v, df * de_dvs]
        if self.fit_delta:
            cols.append(df * de_dd)
        return np.column_stack(cols)

    def _linear_part(self, v, f, s, vs, d):
        """Given vs and delta the model is linear in (fc, dfs, sigma2) per direction: the least-squares
        solution (levels clipped at 0) and its weighted cost (variable projection)."""
        e = np.exp(-np.abs(v / vs) ** d)
        pos, neg = (v > 0).astype(float), (v < 0).astype(float)
        a = np.column_stack([pos, pos * e, pos * v, -neg, -neg * e, neg * v]) / s[:, None]
        x = np.linalg.lstsq(a, f / s, rcond=None)[0]
        x[[0, 1, 3, 4]] = np.maximum(x[[0, 1, 3, 4]], 0.0)
        r = a @ x - f / s
        return x, float(r @ r)

    def fit(self, data) -> StribeckFriction:
        """As :meth:`ClassicFriction.fit`. Starts from the best point of a (vs, delta) grid where the rest of
        the parameters are solved linearly, then refines all of them together."""
        v, f, s = _as_vf(data)
        self._check(v, f, s)
        vmin = max(np.abs(v[v != 0]).min(), 1e-4)
        vmax = 0.5 * min(np.abs(v[v > 0]).max(), np.abs(v[v < 0]).max())
        vs_lo, vs_hi = 0.2 * vmin, max(vmax, 2 * vmin)
        lo = [0, 0, -np.inf, 0, 0, -np.inf, vs_lo] + ([0.5] if self.fit_delta else [])
        hi = [np.inf, np.inf, np.inf, np.inf, np.inf, np.inf, vs_hi] + ([4.0] if self.fit_delta else [])
        deltas = (0.5, 1.0, 1.5, 2.0, 3.0, 4.0) if self.fit_delta else (self.delta,)
        grid = [(self._linear_part(v, f, s, vs, d), vs, d)
                for vs in np.geomspace(vs_lo * 1.01, vs_hi * 0.99, 24) for d in deltas]
        starts = sorted(grid, key=lambda g: g[0][1])[:2]
        best = None
        for (x_lin, _), vs0, d0 in starts:
            x0 = np.concatenate([x_lin, [vs0], [d0] if self.fit_delta else []])
            x0 = np.clip(x0, np.array(lo, float) + 1e-12, np.array(hi, float) - 1e-12)
            try:
                res = self._solve(v, f, s, x0, (lo, hi))
            except (ValueError, np.linalg.LinAlgError):
                continue
            if best is None or res.cost < best.cost:
                best = res
        if best is None:
            raise ValueError("stribeck: the fit did not converge")
        self._finish(best, v, f, s)
        p, sd, cov = self.params_, self.params_std_, self.cov_
        self.fc_pos_, self.sigma2_pos_, self.fc_neg_, self.sigma2_neg_, self.vs_ = map(float, p[[0, 2, 3, 5, 6]])
        self.fs_pos_, self.fs_neg_ = float(p[0] + p[1]), float(p[3] + p[4])
        (self.fc_pos_std_, self.sigma2_pos_std_, self.fc_neg_std_, self.sigma2_neg_std_,
         self.vs_std_) = map(float, sd[[0, 2, 3, 5, 6]])
        self.fs_pos_std_ = float(np.sqrt(max(cov[0, 0] + cov[1, 1] + 2 * cov[0, 1], 0.0)))
        self.fs_neg_std_ = float(np.sqrt(max(cov[3, 3] + cov[4, 4] + 2 * cov[3, 4], 0.0)))
        if not (np.isfinite(sd[0]) and np.isfinite(sd[1])):
            self.fs_pos_std_ = float("inf")
        if not (np.isfinite(sd[3]) and np.isfinite(sd[4])):
            self.fs_neg_std_ = float("inf")
        self.delta_ = float(p[7]) if self.fit_delta else float(self.delta)
        self.delta_std_ = float(sd[7]) if self.fit_delta else 0.0
        return self

    def params(self) -> dict:
        out = super().params()
        out.update(fs_pos=self.fs_pos_, fs_neg=self.fs_neg_)
        return out

    def params_std(self) -> dict:
        out = super().params_std()
        out.update(fs_pos=self.fs_pos_std_, fs_neg=self.fs_neg_std_)
        return out

    def joint_params(self) -> dict:
        return {"fc_pos_Nm": max(self.fc_pos_, 0.0), "fc_neg_Nm": max(self.fc_neg_, 0.0),
                "viscous_pos_Nm_s_rad": max(self.sigma2_pos_, 0.0),
                "viscous_neg_Nm_s_rad": max(self.sigma2_neg_, 0.0),
                "fs_pos_Nm": self.fs_pos_, "fs_neg_Nm": self.fs_neg_, "vs_rad_s": self.vs_,
                "stribeck_delta": self.delta_}


def make_estimator(name: str, loss: str = "linear"):
    """A fresh estimator by model name (:data:`MODEL_NAMES`)."""
    if name == "classic":
        return ClassicFriction(False, loss)
    if name == "classic_symmetric":
        return ClassicFriction(True, loss)
    if name == "stribeck":
        return StribeckFriction(loss)
    raise ValueError(f"unknown friction model {name!r}; choose from {', '.join(MODEL_NAMES)}")


# ================================================================================================ selection
def fold_labels(v: np.ndarray, folds: int) -> np.ndarray:
    """k-fold labels (n,) stratified by direction and speed: within each direction, points sorted by speed
    are dealt to the folds in turn, so every fold keeps slow and fast points of both directions."""
    labels = np.zeros(len(v), int)
    offset = 0
    for m in (v > 0, v < 0):
        idx = np.flatnonzero(m)
        order = idx[np.argsort(np.abs(v[idx]))]
        labels[order] = (np.arange(len(order)) + offset) % folds
        offset += len(order)
    return labels


def segment_sigma(v: np.ndarray, f: np.ndarray, se: np.ndarray, rel_floor: float = 0.005,
                  reference: str = "stribeck", iterations: int = 14) -> np.ndarray:
    """Per-segment standard deviation of the map points: ``sqrt(se_i^2 + (rel_floor F_i)^2 + tau^2)``.

    ``se_i`` is the segment's standard error (batch means). ``rel_floor`` stands for the systematic errors
    the within-segment spread cannot show (at slow speeds the encoder-count kicks of the PD make a joint
    jitter, which biases its mean friction by a few tenths of a percent on the wrist joints); without it,
    micro-newton-metre structure would count as evidence for a richer model. ``tau^2`` is the between-segment
    variance that even the ``reference`` model (the richest one compared; as sigma^2 of Mallows' Cp is taken
    from the full model) leaves unexplained, set (Paule-Mandel, by bisection) so that its fit has
    ``chi^2 = n - k``; zero when it fits within the segments' own precision. (n,) arrays.
    """
    se = np.asarray(se, float).copy()
    good = np.isfinite(se) & (se > 0)
    if not good.any():
        se = np.zeros(len(v))
    else:
        se[~good] = 3.0 * np.nanmax(se[good])
    se = np.sqrt(se ** 2 + (rel_floor * np.abs(f)) ** 2)
    se = np.maximum(se, 1e-6 * max(np.abs(f).max(), 1e-9))

    def chi2(tau2):
        return make_estimator(ref).fit((v, f, np.sqrt(se ** 2 + tau2))).chi2_

    for ref in (reference, "classic"):
        try:
            dof = len(v) - make_estimator(ref).n_params
            if dof <= 0:
                continue
            if chi2(0.0) <= dof:
                return se
            lo, hi = 0.0, max(float(np.var(f)), float(np.median(se)) ** 2, 1e-12)
            while chi2(hi) > dof and hi < 1e8:
                hi *= 10.0
            lo = hi / 1e6
            for _ in range(iterations):     # bisection in log tau^2
                mid = math.sqrt(lo * hi)
                lo, hi = (mid, hi) if chi2(mid) > dof else (lo, mid)
            return np.sqrt(se ** 2 + hi)
        except ValueError:
            continue
    return se


def select_model(data, models=MODEL_NAMES, folds: int = 5, criterion: str = "bic",
                 loss: str = "linear", weighting: str = "se", margin: float = 2.0) -> tuple[pd.DataFrame, str, dict]:
    """Held-out model selection over segments.

    Each model is fitted on k-1 folds and predicts the held-out fold. With ``weighting="se"`` every point has
    a known sigma (:func:`segment_sigma`) and the held-out residuals give ``chi2_cv = sum(((F_i - f_i) /
    sigma_i)^2)``, scored as ``aic_cv = chi2_cv + 2k`` or ``bic_cv = chi2_cv + k ln n``. With
    ``weighting="none"`` (the thesis' unweighted least squares, eq. 4.2) sigma is unknown and the score is
    ``n ln(SSE_cv / n) + 2k`` (or ``+ k ln n``). k parameters, n points. The smallest score wins, except that
    a simpler model within ``margin`` of it is preferred (a difference below 2 is "not worth more than a bare
    mention", Kass and Raftery 1995). Every model is refitted on all points.

    Parameters
    ----------
    data : map DataFrame of one joint (``velocity_rad_s``, ``friction_Nm``, ``friction_se_Nm``,
        ``accepted``) or a ``(v, F[, se])`` tuple.

    Returns
    -------
    table : DataFrame indexed by model: ``k, n, cv_rmse_Nm, aic_cv, bic_cv, rmse_Nm, aic, bic, chosen``.
    chosen : name of the winner.
    fitted : model name -> estimator fitted on all points (models that cannot be fitted are left out).
    """
    if isinstance(data, pd.DataFrame):
        d = data[data["accepted"].astype(bool)] if "accepted" in data else data
        v, f = d["velocity_rad_s"].to_numpy(float), d["friction_Nm"].to_numpy(float)
        se = d["friction_se_Nm"].to_numpy(float) if "friction_se_Nm" in d else np.full(len(d), np.nan)
    else:
        v, f, se = _as_vf(data)
    known = weighting == "se"
    richest = max(models, key=lambda m: make_estimator(m).n_params)
    sigma = segment_sigma(v, f, se, reference=richest) if known else np.ones(len(v))
    labels = fold_labels(v, folds)
    rows, fitted = [], {}
    n = len(v)
    for name in models:
        try:
            full = make_estimator(name, loss).fit((v, f, sigma))
        except ValueError as exc:
            log.info("model %s not fitted: %s", name, exc)
            continue
        fitted[name] = full
        pred = np.full(n, np.nan)
        for k in range(folds):
            test = labels == k
            if not test.any():
                continue
            try:
                est = make_estimator(name, loss).fit((v[~test], f[~test], sigma[~test]))
            except ValueError:
                continue
            pred[test] = est.predict(v[test])
        kpar = full.n_params
        if np.isfinite(pred).all() and n > 0:
            s_cv = float(np.sum(((pred - f) / sigma) ** 2))
            ll = s_cv if known else n * math.log(max(s_cv / n, 1e-300))
            aic_cv, bic_cv = ll + 2 * kpar, ll + kpar * math.log(n)
            cv_rmse = math.sqrt(float(np.mean((pred - f) ** 2)))
        else:  # some folds could not be fitted (too few points): not comparable
            aic_cv = bic_cv = cv_rmse = float("inf")
        ic = full.information_criteria(known)
        rows.append({"model": name, "k": kpar, "n": n, "cv_rmse_Nm": cv_rmse, "aic_cv": aic_cv, "bic_cv": bic_cv,
                     "rmse_Nm": math.sqrt(full.rss_ / n), "aic": ic["aic"], "bic": ic["bic"]})
    if not rows:
        raise ValueError("no friction model could be fitted (too few accepted segments)")
    table = pd.DataFrame(rows).set_index("model")
    key = f"{criterion}_cv"
    if np.isfinite(table[key]).any():
        best = float(table[key].min())
        close = table[table[key] <= best + margin]
        chosen = str(close.sort_values(["k", key]).index[0])
    else:
        chosen = "classic_symmetric" if "classic_symmetric" in table.index else str(table.index[0])
    table["chosen"] = table.index == chosen
    return table, chosen, fitted


# ================================================================================================ identify
@dataclass
class JointIdentification:
    joint: int
    chosen: str
    selection: pd.DataFrame
    fits: dict            # model name -> fitted estimator
    n_segments: int
    n_rejected: int


@dataclass
class FrictionIdentification:
    """Everything the identification produced: the map, per-joint fits and selection, the chosen model."""

    map: pd.DataFrame
    joints: dict[int, JointIdentification] = field(default_factory=dict)
    model: FrictionModel = field(default_factory=FrictionModel.zero)
    options: dict = field(default_factory=dict)

    def table_4_1(self, model: str | None = None) -> pd.DataFrame:
        """Table 4.1 layout per joint (Fc+/Fc-, sigma2+/sigma2- with standard errors) of the chosen model, or
        of ``model`` for every joint."""
        rows = []
        for j, ji in sorted(self.joints.items()):
            name = model or ji.chosen
            est = ji.fits.get(name)
            if est is None:
                continue
            row = {"joint": j, "model": name,
                   "fc_pos_Nm": est.fc_pos_, "fc_pos_std_Nm": est.fc_pos_std_,
                   "fc_neg_Nm": est.fc_neg_, "fc_neg_std_Nm": est.fc_neg_std_,
                   "sigma2_pos_Nm_s_rad": est.sigma2_pos_, "sigma2_pos_std": est.sigma2_pos_std_,
                   "sigma2_neg_Nm_s_rad": est.sigma2_neg_, "sigma2_neg_std": est.sigma2_neg_std_}
            if name == "stribeck":
                row.update(fs_pos_Nm=est.fs_pos_, fs_neg_Nm=est.fs_neg_, vs_rad_s=est.vs_, delta=est.delta_)
            rows.append(row)
        return pd.DataFrame(rows).set_index("joint") if rows else pd.DataFrame()

    def selection_table(self) -> pd.DataFrame:
        frames = [ji.selection.reset_index().assign(joint=j) for j, ji in sorted(self.joints.items())]
        if not frames:
            return pd.DataFrame()
        return pd.concat(frames, ignore_index=True).set_index(["joint", "model"])

    def file_extra(self) -> dict:
        """Extra keys of ``friction_model.yaml``: per joint the chosen model, standard errors, segments."""
        out = {}
        for j, ji in sorted(self.joints.items()):
            est = ji.fits[ji.chosen]
            out[j] = {"model": ji.chosen, "n_segments": ji.n_segments,
                      "std": {k: (float(s) if np.isfinite(s) else None) for k, s in est.params_std().items()}}
        return {"identification": {"criterion": self.options.get("criterion", "bic"),
                                   "loss": self.options.get("loss", "linear"), "joints": out}}

    def to_dict(self) -> dict:
        return {"options": self.options,
                "joints": {str(j): {"chosen": ji.chosen, "n_segments": ji.n_segments, "n_rejected": ji.n_rejected,
                                    "selection": json_records(ji.selection.reset_index()),
                                    "fits": {k: est.to_dict() for k, est in ji.fits.items()}}
                           for j, ji in sorted(self.joints.items())},
                "model": self.model.to_dict()}


def json_records(df: pd.DataFrame) -> list[dict]:
    out = []
    for rec in df.to_dict(orient="records"):
        out.append({k: (None if isinstance(v, float) and not math.isfinite(v) else
                        (v.item() if hasattr(v, "item") else v)) for k, v in rec.items()})
    return out


def identify_from_map(fmap: pd.DataFrame, models=MODEL_NAMES, folds: int = 5, criterion: str = "bic",
                      loss: str = "linear", weighting: str = "se") -> FrictionIdentification:
    """Fit and select per joint on an existing map; the chosen models as one :class:`FrictionModel`
    (joints without enough segments keep zero friction)."""
    result = FrictionIdentification(fmap, options={"models": list(models), "folds": folds,
                                                   "criterion": criterion, "loss": loss, "weighting": weighting})
    arrays = {k: np.zeros(P.N_JOINTS) for k in ("fc_pos_Nm", "fc_neg_Nm", "viscous_pos_Nm_s_rad",
                                                 "viscous_neg_Nm_s_rad")}
    arrays.update({k: np.full(P.N_JOINTS, np.nan) for k in ("fs_pos_Nm", "fs_neg_Nm", "vs_rad_s")})
    arrays["stribeck_delta"] = np.full(P.N_JOINTS, 2.0)
    for j in sorted(fmap["joint"].unique()) if len(fmap) else []:
        mj = fmap[(fmap["joint"] == j)]
        acc = mj[mj["accepted"] & mj["friction_Nm"].notna()]
        try:
            table, chosen, fitted = select_model(acc, models, folds, criterion, loss, weighting)
        except ValueError as exc:
            log.warning("joint %d: %s", j, exc)
            continue
        result.joints[int(j)] = JointIdentification(int(j), chosen, table, fitted, len(acc), len(mj) - len(acc))
        for k, val in fitted[chosen].joint_params().items():
            arrays[k][int(j) - 1] = val
    result.model = FrictionModel(**arrays)
    return result


def identify(run, options: dict | None = None, map_options: MapOptions | None = None) -> FrictionIdentification:
    """Identify friction from a recorded sweep (:class:`~wamctl.runs.measured.RunData`): map, fits, selection.

    ``options``: ``loss``, ``criterion``, ``folds``, ``models`` (as the spec's ``identification`` section).
    The declared rigid-body model includes the payload the metadata declare.
    """
    from wamctl.model.dynamics import Payload, WamDynamics

    o = {"loss": "linear", "criterion": "bic", "folds": 5, "models": list(MODEL_NAMES), "weighting": "se"}
    o.update(options or {})
    meta = run.meta
    joints = list(meta.experiment.joints) or list(range(1, P.N_JOINTS + 1))
    pl = meta.payload
    dyn = WamDynamics(Payload(pl.mass_kg, tuple(pl.com_m)) if pl and pl.mass_kg > 0 else None)
    q_ref = run.col("q_ref")
    fmap = friction_map(run.t_s, run.col("q"), run.col("tau"), q_ref, joints, dyn, map_options)
    if not len(fmap) or not fmap["accepted"].any():
        raise DataFormatError(f"{run.source}: no constant-velocity stage found in the data of joints {joints}; "
                              "is this a friction sweep (moves at constant velocities)?")
    return identify_from_map(fmap, o["models"], o["folds"], o["criterion"], o["loss"], o["weighting"])
