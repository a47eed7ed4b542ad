"""Friction under stick-slip: the friction-velocity map of steady segments (thesis chapter 4) as evidence for a
Stribeck effect on sweep-like data (no I/O).

Where a joint sticks and slips at every slow speed the instantaneous torque residual has few sliding samples left,
but the mean torque over a whole segment at constant commanded speed is still the mean friction there (over whole
stick-slip cycles the mean acceleration is nil): the hump of a Stribeck curve shows in the map. The map, the fits
and their held-out comparison are the friction identification's own (:mod:`wamctl.analysis.friction_id`: segment
detection, :func:`~wamctl.analysis.friction_id.velocity_map.friction_map`, the per-segment sigmas and the folds of
:mod:`~wamctl.analysis.friction_id.selection`) and the formulas :mod:`wamctl.model.friction`'s: one friction model
code path for both tools. Here the
segments of a joint that sticks and slips are kept (the identification rejects them, as it wants the friction at
one speed, not the mean over a cycle).

The test (:func:`map_evidence`): the held-out chi-square of the classic model against the classic model with a
hump at low speed, on the map points. A Stribeck effect must also be one: breakaway above the Coulomb level in the
direction(s) that show it, by at most ``MAX_BREAKAWAY_RATIO``.
"""

from __future__ import annotations

import logging

import numpy as np
from scipy import stats

from wamctl.analysis.diagnosis.candidates import MAX_BREAKAWAY_RATIO
from wamctl.model.friction import classic_friction_columns, stribeck_decay

log = logging.getLogger(__name__)

MIN_POINTS_PER_DIRECTION = 4      # the Stribeck fit needs three per direction; one more to hold out
MIN_SPEEDS = 3                    # distinct speeds (within 20 %) per direction
MIN_EXCESS = 0.05                 # a breakaway at least 5 % above the Coulomb level (below: not a hump)
MAX_MOVES = 60                    # moves per joint on the map at most (a long run: evenly spread)
MAX_STAGE_SAMPLES = 100           # a segment's mean friction from at most this many of its samples
MAX_MAP_SAMPLES = 300_000         # the map of a long run is made from its first ten minutes (at 500 Hz)


def map_options():
    """Segment detection for the diagnosis: the identification's, keeping segments that stick and slip."""
    from wamctl.analysis.friction_id.velocity_map import MapOptions

    return MapOptions(stick_fraction_max=1.0, velocity_tolerance=0.5, consistency=0.5, max_moves=MAX_MOVES,
                      max_stage_samples=MAX_STAGE_SAMPLES)


def _distinct_speeds(v: np.ndarray) -> int:
    v = np.sort(np.abs(v))
    return int(1 + np.sum(v[1:] > 1.2 * v[:-1])) if len(v) else 0


def friction_map_of(diag, j: int):
    """The friction-velocity map (accepted rows) of 0-based joint ``j`` of a fitted ``ModelDiagnosis`` (the map
    of every diagnosed joint is made once, on first use, and kept as ``diag.friction_map_``)."""
    from wamctl.analysis.friction_id.velocity_map import friction_map

    fmap = getattr(diag, "friction_map_", None)
    if fmap is None:
        sig = diag.signals_
        n = min(sig.n, MAX_MAP_SAMPLES)
        has_ref = np.ptp(sig.q_ref_rad[:n, sig.joints], axis=0).max() > 0
        fmap = friction_map(sig.t_s[:n], sig.q_raw_rad[:n], sig.tau_raw_Nm[:n], sig.q_ref_rad[:n] if has_ref else None,
                            [jj + 1 for jj in sig.joints], diag.dynamics_, map_options())
        if sig.gaps_s and len(fmap):     # a segment across a gap of the log is interpolated there: not a measurement
            bad, m = np.zeros(len(fmap), bool), 2 * sig.reach * sig.dt_s
            for a, b in sig.gaps_s:
                bad |= (fmap["t_start_s"].to_numpy() <= b + m) & (fmap["t_end_s"].to_numpy() >= a - m)
            fmap = fmap.assign(accepted=fmap["accepted"].to_numpy() & ~bad)
        diag.friction_map_ = fmap
    if not len(fmap):
        return fmap
    return fmap[(fmap["joint"] == j + 1) & fmap["accepted"] & fmap["friction_Nm"].notna()]


HUMP_VS_GRID_RAD_S = np.geomspace(0.005, 0.2, 9)


def hump_columns(v: np.ndarray, vs: float) -> np.ndarray:
    """(n, 2) the Stribeck excess per direction at map speeds ``v``: ``[v>0] S, -[v<0] S`` with the exponential
    shape ``S = exp(-|v / vs|)`` (delta 1: a hump seen through stick-slip means is blunt, whatever the law)."""
    e = stribeck_decay(v, vs, 1.0)
    return np.column_stack([(v > 0) * e, -1.0 * (v < 0) * e])


def _weighted_fit(X: np.ndarray, f: np.ndarray, w: np.ndarray) -> np.ndarray:
    return np.linalg.lstsq(X * w[:, None], f * w, rcond=None)[0]


def _hump_fit(v, f, w, rows):
    """(coefficients, vs, weighted SSR) of classic + hump on ``rows``, vs from the grid."""
    best = None
    C = classic_friction_columns(v)
    for vs in HUMP_VS_GRID_RAD_S:
        X = np.hstack([C, hump_columns(v, vs)])
        th = _weighted_fit(X[rows], f[rows], w[rows])
        r = (X[rows] @ th - f[rows]) * w[rows]
        if best is None or r @ r < best[2]:
            best = (th, vs, float(r @ r))
    return best


def map_evidence(diag, j: int) -> dict | None:
    """Stribeck evidence on the friction map of joint ``j``, or None when the map cannot tell (too few segments,
    directions or speeds: not a sweep).

    The nested comparison: classic friction per direction (four levels) against classic plus a hump per
    direction (two levels and its velocity, chosen on the training folds), each predicting the segments held
    out (folds stratified by direction and speed, :func:`~wamctl.analysis.friction_id.selection.fold_labels`);
    sigmas per segment from :func:`~wamctl.analysis.friction_id.selection.segment_sigma` (batch-means standard
    error, a relative floor and the between-segment variance the classic model leaves), so that the held-out
    chi-square difference is a chi-square with three degrees of freedom when there is no hump.

    Returns a test dict (``p_value``, ``delta_bic``, ``F`` (the chi-square difference), ``n``, ``n_eff``,
    ``ssr_ratio``) with ``shape`` = (ratio_pos, ratio_neg, vs, delta) of the fit on every segment, ``plausible``
    and ``reason``, and the ``map`` itself."""
    from wamctl.analysis.friction_id.selection import segment_sigma

    fmap = friction_map_of(diag, j)
    if not len(fmap):
        return None
    v = fmap["velocity_rad_s"].to_numpy(float)
    f = fmap["friction_Nm"].to_numpy(float)
    for m in (v > 0, v < 0):
        if m.sum() < MIN_POINTS_PER_DIRECTION or _distinct_speeds(v[m]) < MIN_SPEEDS:
            return None
    n = len(v)
    w = 1.0 / segment_sigma(v, f, fmap["friction_se_Nm"].to_numpy(float), reference="classic")
    C = classic_friction_columns(v)
    th0 = _weighted_fit(C, f, w)
    r0 = (f - C @ th0) * w
    th, vs, ssr1 = _hump_fit(v, f, w, np.arange(n))
    ssr0 = float(r0 @ r0)
    k1 = 7                     # four classic levels, two hump levels, the hump's velocity
    d = max(ssr0 - ssr1, 0.0)
    F = (d / 3) / (ssr1 / max(n - k1, 1)) if ssr1 > 0 else np.inf
    p = float(stats.f.sf(F, 3, max(n - k1, 1))) if d > 0 else 1.0
    fc = np.maximum(th[:2], 1e-9)
    ratio = 1.0 + th[4:6] / fc
    out = {"p_value": p, "delta_bic": float(n * np.log(max(ssr1, 1e-300) / max(ssr0, 1e-300)) + 3 * np.log(n)),
           "F": float(F), "n": int(n), "n_eff": float(n), "ssr_ratio": ssr1 / ssr0 if ssr0 > 0 else 1.0,
           "shape": (float(max(ratio[0], 1.0)), float(max(ratio[1], 1.0)), float(vs), 1.0), "map": fmap}
    seen = (v > 0).any(), (v < 0).any()
    if max(ratio) < 1 + MIN_EXCESS:
        out.update(plausible=False, reason=f"the map's breakaway levels are within {MIN_EXCESS:.0%} of the "
                                           "Coulomb levels: no hump")
    elif min(ratio[list(seen)]) < 1 - MIN_EXCESS:
        out.update(plausible=False, reason="the map dips at low speed in one direction: not a Stribeck hump")
    elif max(ratio) > MAX_BREAKAWAY_RATIO or (th[:2] <= 0).any():
        out.update(plausible=False, reason=f"fitted breakaway {max(ratio):.3g} times the Coulomb level: beyond "
                                           f"a physical Stribeck effect (at most {MAX_BREAKAWAY_RATIO:g})")
    else:
        out.update(plausible=True, reason="")
    return out


def map_bootstrap(ev: dict, n_boot: int, rng: np.random.Generator) -> tuple[list, list]:
    """Breakaway ratios (positive, negative) and hump velocities of the map's fit over its segments resampled
    with replacement (within each direction), for the intervals of a Stribeck effect seen on the map."""
    from wamctl.analysis.friction_id.selection import segment_sigma

    fmap = ev["map"]
    v = fmap["velocity_rad_s"].to_numpy(float)
    f = fmap["friction_Nm"].to_numpy(float)
    w = 1.0 / segment_sigma(v, f, fmap["friction_se_Nm"].to_numpy(float), reference="classic")
    pos, neg = np.flatnonzero(v > 0), np.flatnonzero(v < 0)
    ratios, vss = [], []
    for _ in range(n_boot):
        rows = np.r_[rng.choice(pos, len(pos)), rng.choice(neg, len(neg))]
        th, vs, _ = _hump_fit(v, f, w, rows)
        fc = np.maximum(th[:2], 1e-9)
        r = 1.0 + th[4:6] / fc
        ratios.append((float(r[0]), float(r[1])))
        vss.append(float(vs))
    return ratios, vss
