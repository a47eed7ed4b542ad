"""Moves and their constant-velocity stages, per joint, from the reference or the measured position alone.

A move is a window of samples where one joint travels in one direction (:class:`Move`); its constant-velocity
stage (:class:`Stage`) is the part where the measured position follows a straight line within its own noise.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from wamctl.analysis.friction_id.signals import fit_line, position_noise_rad, quantisation_step_rad, savgol_derivative


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """Maximal runs of True as (start, stop) index pairs (stop exclusive)."""
    m = np.concatenate([[False], np.asarray(mask, bool), [False]])
    d = np.diff(m.astype(np.int8))
    return list(zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1)))


@dataclass
class Move:
    """One move of one joint: samples ``[i0, i1)`` where the stage is searched, its direction, and the
    commanded speed when a reference is known (NaN otherwise)."""

    i0: int
    i1: int
    direction: int
    v_cmd_rad_s: float = float("nan")


def moves_from_reference(t_s: np.ndarray, q_ref: np.ndarray, min_travel_rad: float = 1e-4,
                         creep_s: float = 2.0, max_moves: int | None = None) -> list[Move]:
    """Moves of one joint from its reference (the commanded schedule as a hint).

    Each window runs from the start of a reference move to the start of the next one, but at most
    ``creep_s`` (or half the move's duration, if longer) past the end of the reference move: a joint under PD
    creeps on after its reference stops. ``q_ref`` (n,). ``max_moves``: at most this many, evenly spread over
    the run (:func:`spread`; the commanded speed is only computed for those kept).
    """
    dq = np.diff(q_ref)
    moving = np.abs(dq) > 1e-12
    sgn = np.sign(dq)
    out = []
    starts = []
    for a, b in _runs(moving):
        # split where the direction flips without a hold
        flips = a + 1 + np.flatnonzero((sgn[a + 1:b] != sgn[a:b - 1]) & (sgn[a + 1:b] != 0))
        cuts = [a, *flips.tolist(), b]
        for s0, s1 in zip(cuts[:-1], cuts[1:]):
            travel = q_ref[s1] - q_ref[s0]
            if abs(travel) < min_travel_rad:
                continue
            starts.append((s0, s1, np.sign(travel)))
    for k in spread(len(starts), max_moves):
        s0, s1, direction = starts[k]
        end = starts[k + 1][0] if k + 1 < len(starts) else len(q_ref)
        t_end = t_s[s1] + max(creep_s, 0.5 * (t_s[s1] - t_s[s0]))
        end = min(end, int(np.searchsorted(t_s, t_end)))
        v = cruise_speed_rad_s(t_s[s0:s1 + 1], q_ref[s0:s1 + 1]) * direction
        out.append(Move(int(s0), int(end), int(direction), float(v)))
    return out


def spread(n: int, at_most: int | None) -> list[int]:
    """Indices of ``n`` items, at most ``at_most`` (None: all) evenly spread from the first to the last."""
    if at_most is None or n <= at_most:
        return list(range(n))
    return [int(i) for i in np.unique(np.linspace(0, n - 1, at_most).round().astype(int))]


def cruise_speed_rad_s(t_s: np.ndarray, q_ref: np.ndarray, baseline_s: float = 0.05) -> float:
    """The commanded cruise speed of one reference move (``t_s``, ``q_ref`` (m,)): the speed over a baseline of
    ``baseline_s`` at the move's top (the median of those within 2 % of the fastest). Over one sample, a log's
    jittered time stamps (a logger's jitter of 20 % of a period is common) would inflate the fastest speed by as
    much; over 50 ms they move it by a fraction of a percent."""
    dt = float(np.median(np.diff(t_s)))
    m = int(min(max(1, round(baseline_s / dt)), len(t_s) - 1))
    s = np.abs(q_ref[m:] - q_ref[:-m]) / (t_s[m:] - t_s[:-m])
    return float(np.median(s[s >= 0.98 * s.max()]))


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


@dataclass
class Stage:
    """The constant-velocity stage ``[s0, s1)`` of a move, or why there is none (``s0 == s1``)."""

    s0: int
    s1: int
    reason: str = ""

    @property
    def ok(self) -> bool:
        return self.s1 > self.s0 and not self.reason


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
        c, v, tm = fit_line(t[lo:hi], x[lo:hi])
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
        out_lo = np.flatnonzero(~ok_s[:centre])
        new_lo = int(out_lo[-1]) + 1 if len(out_lo) else 0
        out_hi = np.flatnonzero(~ok_s[centre + 1:])
        new_hi = centre + 1 + int(out_hi[0]) if len(out_hi) else len(x)
        if (new_lo, new_hi) == (lo, hi):
            break
        lo, hi = new_lo, new_hi
    g = int(round(guard_s / dt))
    lo, hi = lo + g, hi - g
    if (hi - lo) * dt < min_stage_s:
        return Stage(i0 + max(lo, 0), i0 + max(lo, 0), f"constant-velocity stage shorter than {min_stage_s} s")
    # the two halves must agree: an exponential approach or a drift is not a constant velocity
    mid = (lo + hi) // 2
    _, v1, _ = fit_line(t[lo:mid], x[lo:mid])
    _, v2, _ = fit_line(t[mid:hi], x[mid:hi])
    n_half = (hi - lo) / 2
    noise_v = band_sigmas * floor * math.sqrt(12.0 / max(n_half ** 3, 1.0)) / dt
    vbar = abs(v1 + v2) / 2
    if abs(v1 - v2) > consistency * vbar + noise_v:
        return Stage(i0 + lo, i0 + lo, f"velocity not constant ({v1:.4g} vs {v2:.4g} rad/s in the two halves)")
    return Stage(i0 + lo, i0 + hi)


