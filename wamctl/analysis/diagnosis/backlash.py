"""Backlash test of the model diagnosis: lost motion at direction reversals (no I/O).

A dead band of width ``w`` in the drive is nearly invisible in the torque residual: once the joint slides, the
measurement is the link position shifted by ``w/2``. It shows where the joint reverses, in one of two ways:

* the dead band lies between the link and its encoder (a play operator on the measured position): the
  measurement stands still while the link crosses the band, it *lags* the link;
* the encoder sits on the motor and the gap lies between motor and link (a two-inertia drive): the motor
  crosses the gap with only its own inertia and friction before it takes the link along, the measurement
  *leads* the link.

For every *onset* (the measured position stands still, then moves again) the joint's own dynamics are
integrated from rest with the logged torque and the fitted friction (stick until the torque beats the Coulomb
level, then slide; the same implicit stick/slip step the simulator uses)::

    B_jj x'' = u(t) - F(x'),     u = tau - rnea_j(q, qd, qdd with joint j's own velocity and acceleration zeroed)

and compared with the measured travel (:func:`signed_travel`): when the model's link moved first, ``d`` is how
far it had travelled when the measurement moved (the existing *hidden travel*, positive); when the measurement
moved first, ``d`` is minus how far the measurement had travelled from its turning point when the model's link
started (a lead, negative). Without backlash ``d`` is about zero (a count or two); with backlash it is about
``+w`` (encoder behind the band) or ``-w`` (encoder on the motor) at reversals, and unchanged at onsets in the
same direction as the previous motion (a gravity-loaded drive may also keep one flank through a reversal). Onsets
are dealt into the same time folds as the samples; the nested tests are made on held-out onsets:

* backlash: ``d = c + v [reversal]`` against the model without the reversal term; when the measurement leads,
  on the logarithmic scale ``l = sign(d) log(1 + |d| / tol)`` (the lead varies with where in a reversal the gap
  is crossed, wholly, partly or not at all, and a handful of onsets carries the test: large values must not
  swamp it); the width is :func:`band_width`;
* Stribeck, seen at breakaway (stick-slip leaves few sliding samples for the torque residual): ``d = c`` at
  every onset against ``d = 0``: the model breaks away too early, the joint withstood more than ``Fc``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from wamctl.analysis.diagnosis.signals import measured_steps
from wamctl.analysis.diagnosis.stats import nested_test
from wamctl.model.friction import stribeck_decay

MIN_ONSETS = 4
MIN_REVERSALS = 3
TRAVEL_CAP_RAD = 0.1        # the model's link is stopped here: beyond, the travel says nothing more
# A dead band must be at least this many detection tolerances (ten measurement steps) wide: a measurement that
# moves a sample or two before the model's link does (a light joint reverses within a few milliseconds) leads
# it by up to about four tolerances without any gap.
MIN_BAND_TOLERANCES = 5.0


@dataclass
class Onset:
    """One measured stall and restart of a joint (full-rate sample indices)."""

    start: int          # first sample of the measured stall
    end: int            # first sample where the measurement has left the stall value
    reversal: bool      # the new direction is opposite to the previous motion
    sign_new: float
    t_s: float
    turn: int = -1      # the measured turning point of a reversal (the old direction's extreme), else ``start``


def resolution_rad(q_raw: np.ndarray, min_steps: int = 1) -> float:
    """Typical smallest measured step of a joint (encoder count through the transmission), rad, from its
    measured positions (n,); 0 when fewer than ``min_steps`` steps were measured."""
    nz = measured_steps(q_raw)
    if len(nz) < max(min_steps, 1):
        return 0.0
    return float(np.percentile(nz, 10))


def sliding_stretches(q_raw: np.ndarray, qd_s: np.ndarray, v_stick: float, tol: float,
                      min_len: int) -> list[tuple[int, int, float]]:
    """Stretches of real motion: the smoothed speed above ``v_stick`` for at least ``min_len`` samples and
    the measured position travelling at least ``5 tol``. Returns (first, last + 1, direction) per stretch."""
    moving = np.abs(qd_s) >= v_stick
    edges = np.flatnonzero(np.diff(np.r_[False, moving, False].astype(np.int8)))
    out = []
    for s0, s1 in zip(edges[::2], edges[1::2]):
        if s1 - s0 < min_len:
            continue
        travel = q_raw[s1 - 1] - q_raw[s0]
        if abs(travel) < 5 * tol:
            continue
        out.append((int(s0), int(s1), float(np.sign(travel))))
    return out


def find_onsets(t_s: np.ndarray, q_raw: np.ndarray, qd_s: np.ndarray, v_stick: float, tol: float,
                min_len: int = 10) -> list[Onset]:
    """Measured stalls of one joint between two stretches of real motion, and whether the motion reverses.

    Parameters
    ----------
    t_s, q_raw, qd_s : (n,) time, measured position, smoothed velocity.
    v_stick : speed below which the smoothed velocity counts as stopped.
    tol : position change that counts as the measurement having moved (a few counts / noise sigmas).
    min_len : shortest stretch of motion that counts (samples; about a filter window).
    """
    st = sliding_stretches(q_raw, qd_s, v_stick, tol, min_len)
    if len(st) < 2:
        return []
    q = np.ascontiguousarray(q_raw, dtype=float)
    bounds = np.array([(s0, s1) for s0, s1, _ in st], dtype=np.int64)
    dirs = np.array([d for _, _, d in st], dtype=float)
    k_pair, a, b, turn = _onsets_kernel(q, bounds, dirs, float(tol), int(min_len))
    out = []
    for k, a_k, b_k, t_k in zip(k_pair.tolist(), a.tolist(), b.tolist(), turn.tolist()):
        d_new = float(dirs[k + 1])
        rev = d_new != float(dirs[k])
        out.append(Onset(a_k, b_k, rev, d_new, float(t_s[b_k]), t_k if rev else a_k))
    return out


@njit(cache=True)
def _onsets_kernel(q_raw, bounds, dirs, tol, min_len):
    """The stalls between consecutive stretches ``bounds`` (m, 2) of motion in directions ``dirs`` (m,):
    (pair index, start, end, turning point) per onset kept (see :func:`find_onsets`; the turning point -1 where
    the motion does not reverse)."""
    n = len(q_raw)
    m = len(bounds)
    k_out = np.empty(max(m - 1, 0), np.int64)
    a_out = np.empty(max(m - 1, 0), np.int64)
    b_out = np.empty(max(m - 1, 0), np.int64)
    t_out = np.empty(max(m - 1, 0), np.int64)
    c = 0
    for k in range(m - 1):
        p0, p1 = bounds[k, 0], bounds[k, 1]
        s0, s1 = bounds[k + 1, 0], bounds[k + 1, 1]
        d_prev, d_new = dirs[k], dirs[k + 1]
        # the stall value: the measured position where the two stretches meet (quantised, so the median)
        lo, hi = max(p1 - min_len, p0), min(s0 + min_len, s1)
        med = np.median(q_raw[p1:s0 + 1])
        mid_i = lo
        best = np.inf
        for i in range(lo, hi):
            e = abs(q_raw[i] - med)
            if e < best:
                best, mid_i = e, i
        q_stall = q_raw[mid_i]
        # within this pair of stretches only: the last sample off the stall value before it, the first after
        a = p0
        for i in range(mid_i - 1, p0 - 1, -1):
            if abs(q_raw[i] - q_stall) > tol:
                a = i + 1
                break
        b = s1
        for i in range(mid_i, s1):
            if abs(q_raw[i] - q_stall) > tol:
                b = i
                break
        if b >= min(s1, n) or b - a < 2:
            continue
        if np.sign(q_raw[b] - q_stall) != d_new:
            continue
        turn = turning_point(q_raw, a, b, d_new, min_len) if d_new != d_prev else -1
        k_out[c], a_out[c], b_out[c], t_out[c] = k, a, b, turn
        c += 1
    return k_out[:c], a_out[:c], b_out[:c], t_out[:c]


@njit(cache=True)
def turning_point(q_raw: np.ndarray, start: int, end: int, sign_new: float, reach: int) -> int:
    """The measured turning point of a reversal: the last sample where the measured position (n,) is furthest
    in the old direction, from ``reach`` samples before the stall's ``start`` to its ``end`` (a motor that
    crosses a gap may reverse before the measured speed counts as stopped)."""
    turn, low = end, sign_new * q_raw[end]
    for i in range(end - 1, max(start - reach, 0) - 1, -1):
        if sign_new * q_raw[i] < low:
            low, turn = sign_new * q_raw[i], i
    return turn


def signed_travel(x: np.ndarray, q: np.ndarray, stall: int, q_turn: float, sign: float, tol: float) -> float:
    """Signed hidden travel of one onset, rad (NaN when the model's link never moves in the window).

    ``x`` (m,) is the model's link travel from rest, ``q`` (m,) the measured travel from the window's start,
    ``stall`` the first sample where the measurement has moved, ``q_turn`` the measured position of the turning
    point (relative to the start), ``sign`` the new direction, ``tol`` the detection tolerance. Positive: the
    model's link had travelled that far beyond ``tol`` when the measurement moved (the measurement lags).
    Negative: the measurement had travelled that far beyond ``tol`` from its turning point when the model's link
    moved by ``tol`` (it leads)."""
    moved = np.flatnonzero(sign * x >= tol)
    if not len(moved):
        return float("nan")
    k = int(moved[0])
    if k < stall:
        return float(sign * x[stall - 1] - tol)
    return float(-(sign * (q[k] - q_turn) - tol))


def band_width(d: np.ndarray, rev: np.ndarray) -> float:
    """Signed dead band (rad) from the signed travel ``d`` (k,) of onsets and whether each reversed ``rev`` (k,),
    beyond the same-direction onsets' mean (when there are two or more, and only where it goes the reversals'
    way): the mean over the reversals when the measurement lags (a dead band behind the encoder is crossed at
    every reversal); when it leads, the mean over the larger half of the leads (a gap on the motor side is crossed
    only where the torque the drive passes to the link changes sign, and gravity may keep one flank through a
    reversal: a dead band bounds the lead)."""
    d, rev = np.asarray(d, float), np.asarray(rev, bool)
    c = float(np.mean(d[~rev])) if (~rev).sum() >= 2 else 0.0
    if not rev.any():
        return float("nan")
    lag = float(np.mean(d[rev] - c)) >= 0
    # the baseline explains part of the reversals' travel where it goes their way; one of the other sign (the
    # model ahead of the measurement at same-direction onsets, when the reversals' measurement leads) is a
    # mismatch of the onsets' model, not more band
    c = max(c, 0.0) if lag else min(c, 0.0)
    v = np.sort(d[rev] - c)
    w = float(np.mean(v))
    return w if lag else min(float(np.mean(v[: (len(v) + 1) // 2])), 0.0)


def log_travel(d: np.ndarray, tol: float) -> np.ndarray:
    """Signed travel (k,) on the logarithmic scale of the backlash test: ``sign(d) log(1 + |d| / tol)``."""
    d = np.asarray(d, float)
    return np.sign(d) * np.log1p(np.abs(d) / tol)


def reversal_leads_tol(d: np.ndarray, rev: np.ndarray, tol: float) -> np.ndarray:
    """(r,) how far the measurement led the model's link at each of the onsets' ``r`` reversals, in detection
    tolerances ``tol``, beyond the same-direction onsets (their median, where there are two or more and only where
    it leads too: a same-direction onset whose model ran ahead is no lead taken back): positive for a lead. From the
    signed travel ``d`` (k,) (NaN: given up, left out) and ``rev`` (k,). A gap on the motor side crossed at a
    reversal, wholly or partly, leads there and not at same-direction onsets."""
    d, rev = np.asarray(d, float), np.asarray(rev, bool)
    ok = np.isfinite(d)
    same = d[ok & ~rev]
    c = min(float(np.median(same)), 0.0) if len(same) >= 2 else 0.0
    return -(d[ok & rev] - c) / tol


def hidden_travel(u_Nm: np.ndarray, dt_s: float, inertia: float, fc_pos: float, fc_neg: float,
                  b_pos: float, b_neg: float, fs_pos: float | None = None, fs_neg: float | None = None,
                  substeps: int = 4, vs_rad_s: float = 0.0) -> np.ndarray:
    """Link position (m,) integrated from rest through a stall with the implicit stick/slip friction step.

    ``u_Nm`` (m,) is the torque available to the joint (zero-order hold per sample); ``fs_*`` are breakaway
    levels (default: the Coulomb levels); with ``vs_rad_s > 0`` the level decays from ``fs`` to ``fc`` with
    speed as ``exp(-(v/vs)^2)`` (Stribeck), otherwise the breakaway level only holds a joint at rest.
    """
    fs_pos = fc_pos if fs_pos is None else fs_pos
    fs_neg = fc_neg if fs_neg is None else fs_neg
    return _travel_kernel(np.ascontiguousarray(u_Nm, dtype=float), float(dt_s), float(inertia), float(fc_pos),
                          float(fc_neg), float(b_pos), float(b_neg), float(fs_pos), float(fs_neg), int(substeps),
                          float(vs_rad_s), TRAVEL_CAP_RAD)


@njit(cache=True)
def _travel_kernel(u_Nm, dt_s, inertia, fc_pos, fc_neg, b_pos, b_neg, fs_pos, fs_neg, substeps, vs, cap):
    h = dt_s / substeps
    k = h / inertia
    x = 0.0
    v = 0.0
    out = np.empty(len(u_Nm))
    stick = min(fs_pos, fs_neg)
    for i in range(len(u_Nm)):
        u = u_Nm[i]
        if (v == 0.0 and abs(u) < stick) or abs(x) >= cap:   # stuck, or far enough
            out[i] = x
            continue
        for _ in range(substeps):
            vf = v + k * u
            pos = vf > 0 if v == 0 else v > 0
            if v == 0:
                level = fs_pos if pos else fs_neg
            elif vs > 0:
                fc = fc_pos if pos else fc_neg
                fs = fs_pos if pos else fs_neg
                level = fc + (fs - fc) * stribeck_decay(v, vs, 2.0)
            else:
                level = fc_pos if pos else fc_neg
            b = b_pos if pos else b_neg
            if abs(vf) <= k * level:
                v = 0.0
            else:
                v = (vf - np.sign(vf) * k * level) / (1.0 + k * b)
            x += h * v
        out[i] = x
    return out


def breakaway_ratio(u_Nm: np.ndarray, dt_s: float, inertia: float, fc_pos: float, fc_neg: float,
                    b_pos: float, b_neg: float, tol: float, lo: float = 0.25, hi: float = 10.0) -> float:
    """Smallest ratio ``rho`` of breakaway to Coulomb level for which the model's link, started at rest, moves
    no more than ``tol`` through the stall (bisection; ``rho`` is about 1 when the joint broke away at its
    Coulomb level, and ``Fs / Fc`` with a Stribeck effect)."""
    return float(_breakaway_kernel(np.ascontiguousarray(u_Nm, dtype=float), float(dt_s), float(inertia),
                                   float(fc_pos), float(fc_neg), float(b_pos), float(b_neg), float(tol), float(lo),
                                   float(hi), TRAVEL_CAP_RAD))


@njit(cache=True)
def _moved(u_Nm, dt_s, inertia, fc_pos, fc_neg, b_pos, b_neg, rho, tol, cap):
    x = _travel_kernel(u_Nm, dt_s, inertia, fc_pos, fc_neg, b_pos, b_neg, rho * fc_pos, rho * fc_neg, 4, 0.0, cap)
    return np.max(np.abs(x)) > tol


@njit(cache=True)
def _breakaway_kernel(u_Nm, dt_s, inertia, fc_pos, fc_neg, b_pos, b_neg, tol, lo, hi, cap):
    if not _moved(u_Nm, dt_s, inertia, fc_pos, fc_neg, b_pos, b_neg, lo, tol, cap):
        return lo
    if _moved(u_Nm, dt_s, inertia, fc_pos, fc_neg, b_pos, b_neg, hi, tol, cap):
        return hi
    for _ in range(14):
        mid = np.sqrt(lo * hi)
        if _moved(u_Nm, dt_s, inertia, fc_pos, fc_neg, b_pos, b_neg, mid, tol, cap):
            lo = mid
        else:
            hi = mid
    return np.sqrt(lo * hi)


def onset_test(travel: np.ndarray, X0: np.ndarray, X1: np.ndarray, fold: np.ndarray, n_folds: int,
               min_effect: float) -> dict:
    """Nested test on held-out onsets: hidden travel ``d = X0 b0`` against ``d = X1 b1`` (X1 nests X0).

    Returns the :func:`nested_test` dict plus ``coef`` (``X1`` fitted on all onsets), ``coef_fold`` (the last
    coefficient fitted without each fold) and the held-out residuals ``e0``, ``e1``.
    """
    travel = np.asarray(travel, float)

    coef_fold = {}

    def cv(X, keep=False):
        e = np.empty(len(travel))
        for f in range(n_folds):
            te = fold == f
            tr = ~te
            if not te.any():
                continue
            if X.shape[1] == 0:
                e[te] = travel[te]
                continue
            th = np.linalg.lstsq(X[tr], travel[tr], rcond=None)[0]
            e[te] = travel[te] - X[te] @ th
            if keep:
                coef_fold[f] = float(th[-1])
        return e

    e0, e1 = cv(X0), cv(X1, keep=True)
    t = nested_test(e0, e1, X1.shape[1] - X0.shape[1], X1.shape[1], min_effect, independent=True)
    t["coef"] = np.linalg.lstsq(X1, travel, rcond=None)[0]
    t["coef_fold"] = coef_fold
    t["e0"], t["e1"] = e0, e1
    return t
