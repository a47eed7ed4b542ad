"""Uncertainty and identifiability of the effects found: a 95 % interval for every parameter, and what the
excitation in the data cannot determine (no I/O).

* **Coefficients** (levels, amplitudes, fractions, a payload's mass and first moments): a bootstrap over the
  joint's contiguous time blocks (the held-out blocks of the cross-validation; resampling whole blocks keeps the
  residual's autocorrelation), ``N_BOOT`` replicates refitted by least squares with the shape parameters fixed;
  percentile intervals. Each replicate is a weighted sum of per-block normal equations, so it costs nothing.
* **Shape parameters** (a Stribeck velocity, a ripple period, a delay, a drift time constant): the profile
  likelihood, ``{h : n_eff ln(SSR(h) / SSR_min) <= chi2_1(0.95)}`` with ``n_eff`` the effective sample count of
  the residual (its integrated autocorrelation time divided out); an end of the interval at the end of the range
  searched is open (``None``).
* **At onsets** (a dead band, breakaway ratios, a Stribeck velocity from the slips): a bootstrap over the onsets.
* **Not identified**: a payload's mass or a component of its centre of mass whose first moment is not in the row
  space of the regressor (the joints that moved cannot feel it: e.g. the offset along the axes of the only joints
  moving), or whose interval is wider than the physical range; a shape parameter whose profile interval is open at
  both ends. Those keys are set to ``None`` in ``params`` and listed in ``not_identified``.
"""

from __future__ import annotations

import numpy as np
from scipy import stats

N_BOOT = 200
LEVEL = 0.95
ESTIMABLE_TOL = 1e-3          # a direction of parameter space farther than this from the row space: not determined
RANK_RTOL = 1e-4              # singular values below this share of the largest: the data do not excite them


def group_bootstrap(X: np.ndarray, y: np.ndarray, groups: np.ndarray, n_boot: int = N_BOOT,
                    rng: np.random.Generator | None = None, w: np.ndarray | None = None) -> np.ndarray:
    """(n_boot, p) least-squares coefficients of ``y ~ X`` refitted on ``groups`` resampled with replacement
    (within each stratum when ``groups`` is a 2-column array ``(stratum, group)``). ``w`` (m,) row weights."""
    rng = rng or np.random.default_rng(0)
    if w is not None:
        X, y = X * w[:, None], y * w
    g2 = np.atleast_2d(np.asarray(groups).T).T
    keys = [tuple(r) for r in g2]
    uniq = sorted(set(keys))
    index = {k: i for i, k in enumerate(uniq)}
    gi = np.array([index[k] for k in keys])
    scale = np.sqrt((X ** 2).sum(axis=0))
    scale[scale == 0] = 1.0
    Xs = X / scale
    G = np.stack([Xs[gi == i].T @ Xs[gi == i] for i in range(len(uniq))])
    c = np.stack([Xs[gi == i].T @ y[gi == i] for i in range(len(uniq))])
    strata = {}
    for i, k in enumerate(uniq):
        strata.setdefault(k[:-1], []).append(i)
    out = np.empty((n_boot, X.shape[1]))
    for b in range(n_boot):
        counts = np.zeros(len(uniq))
        for members in strata.values():
            pick = rng.choice(members, size=len(members), replace=True)
            np.add.at(counts, pick, 1.0)
        Gb = np.tensordot(counts, G, 1)
        cb = counts @ c
        lam, V = np.linalg.eigh(Gb)
        keep = lam > max(lam.max(), 1e-300) * 1e-12
        out[b] = (V[:, keep] @ ((V[:, keep].T @ cb) / lam[keep])) / scale
    return out


def percentile_ci(samples, level: float = LEVEL, center: float | None = None,
                  n_groups: int | None = None) -> list[float | None]:
    """[low, high] percentile interval of finite ``samples`` (None without enough of them).

    With ``center`` (the estimate) and ``n_groups`` (the blocks resampled), the distances of the percentiles from
    the estimate are widened by ``t_{n_groups-1} / z`` (a bootstrap over few blocks underestimates the spread),
    and the interval always contains the estimate."""
    x = np.asarray([s for s in samples if s is not None], float)
    x = x[np.isfinite(x)]
    if len(x) < 10:
        return [None, None]
    a = (1 - level) / 2
    lo, hi = float(np.quantile(x, a)), float(np.quantile(x, 1 - a))
    if center is None or not np.isfinite(center):
        return [lo, hi]
    f = stats.t.ppf(1 - a, max(n_groups - 1, 1)) / stats.norm.ppf(1 - a) if n_groups else 1.0
    return [float(center - f * max(center - lo, 0.0)), float(center + f * max(hi - center, 0.0))]


def profile_ci(hs: np.ndarray, ssr: np.ndarray, n_eff: float, level: float = LEVEL) -> list[float | None]:
    """Profile-likelihood interval of a shape parameter from ``ssr`` (k,) at the values ``hs`` (k, sorted): the
    values within ``chi2_1(level)`` of the best, an end at the first or last value searched open (None)."""
    hs, ssr = np.asarray(hs, float), np.asarray(ssr, float)
    ok = np.isfinite(ssr) & (ssr > 0)
    if ok.sum() < 3:
        return [None, None]
    hs, ssr = hs[ok], ssr[ok]
    crit = stats.chi2.ppf(level, 1)
    inside = np.flatnonzero(n_eff * np.log(ssr / ssr.min()) <= crit)
    lo, hi = inside.min(), inside.max()
    return [None if lo == 0 else float(hs[lo]), None if hi == len(hs) - 1 else float(hs[hi])]


def estimable(X: np.ndarray, cols: list[int]) -> list[bool]:
    """Whether each parameter ``cols`` of the model ``y ~ X`` is determined by the data: its unit vector lies in
    the row space of ``X`` (columns scaled to unit norm; singular values below ``RANK_RTOL`` of the largest
    count as not excited)."""
    scale = np.sqrt((X ** 2).sum(axis=0))
    live = scale > 0
    Xs = X[:, live] / scale[live]
    _, sv, Vt = np.linalg.svd(Xs, full_matrices=False)
    V = Vt[sv > sv.max() * RANK_RTOL].T
    pos = np.cumsum(live) - 1
    out = []
    for c in cols:
        if not live[c]:
            out.append(False)
            continue
        e = np.zeros(Xs.shape[1])
        e[pos[c]] = 1.0
        out.append(bool(np.linalg.norm(e - V @ (V.T @ e)) < ESTIMABLE_TOL))
    return out
