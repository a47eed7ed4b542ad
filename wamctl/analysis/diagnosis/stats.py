"""Statistics of the model diagnosis: cross-validated least squares, nested-model tests, whiteness (no I/O).

Residuals of smoothed signals are autocorrelated, so a test that counts every sample as independent would
call any faint structure significant. Every test here therefore uses an *effective* sample size,
``n_eff = n / tau_int``, with ``tau_int`` the integrated autocorrelation time of the residual (Geyer's initial
positive sequence), and is made on held-out (cross-validated) residuals: the model with the extra effect
must predict samples it was not fitted on better than the declared model does.
"""

from __future__ import annotations

import numpy as np
from scipy import stats


def orth_basis(X: np.ndarray, rtol: float = 1e-10) -> np.ndarray:
    """Orthonormal basis (m, r) of the column space of ``X`` (m, p); rank-deficient directions dropped.

    Built from the Gram matrix (``p`` is small, ``m`` large): ``X V diag(1/sqrt(lambda))``, then
    re-orthonormalised once the same way for accuracy (no QR of the tall matrix: it is slow here).
    """
    if X.shape[1] == 0:
        return X
    scale = np.sqrt((X ** 2).sum(axis=0))
    live = scale > 0
    if not live.any():
        return X[:, :0]
    Xs = X[:, live] / scale[live]
    lam, V = np.linalg.eigh(Xs.T @ Xs)
    keep = lam > lam.max() * rtol
    B = Xs @ (V[:, keep] / np.sqrt(lam[keep]))
    lam2, V2 = np.linalg.eigh(B.T @ B)
    return B @ (V2 / np.sqrt(np.maximum(lam2, 1e-300))) @ V2.T


def _column_scale(X: np.ndarray) -> np.ndarray:
    """(p,) Euclidean norm of each column of ``X`` (m, p), 1 for an all-zero column."""
    scale = np.sqrt((X ** 2).sum(axis=0))
    scale[scale == 0] = 1.0
    return scale


def lstsq(X: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Minimum-norm least squares (normal equations on scaled columns, pseudo-inverse for rank deficiency)."""
    G = X.T @ X                    # the Gram matrix of the scaled columns from the unscaled one (one pass)
    scale = np.sqrt(np.diag(G))
    scale[scale == 0] = 1.0
    G = G / np.outer(scale, scale)
    lam, V = np.linalg.eigh(G)
    keep = lam > max(lam.max(), 1e-300) * 1e-12
    theta = V[:, keep] @ ((V[:, keep].T @ ((X.T @ y) / scale)) / lam[keep])
    return theta / scale


def lstsq_bounded(X: np.ndarray, y: np.ndarray, lower: np.ndarray | None = None) -> np.ndarray:
    """Least squares with lower bounds on some coefficients (``-inf`` where free): the unconstrained solution
    when it respects them, else a bounded-variable solve (scipy's BVLS)."""
    theta = lstsq(X, y)
    if lower is None or np.all(theta >= lower - 1e-12):
        return theta
    from scipy.optimize import lsq_linear

    scale = _column_scale(X)
    res = lsq_linear(X / scale, y, bounds=(np.asarray(lower) * scale, np.full(X.shape[1], np.inf)),
                     method="bvls", lsmr_tol="auto")
    return res.x / scale


def project_out(U: np.ndarray, Y: np.ndarray) -> np.ndarray:
    """``Y`` (m,) or (m, p) less its projection on the orthonormal basis ``U`` (m, r): the residual of a fit."""
    return Y - U @ (U.T @ Y)


def projection_gain(U: np.ndarray, r: np.ndarray, Z: np.ndarray) -> float:
    """Drop of the sum of squares of ``r`` (residual of a fit on basis ``U``) when columns ``Z`` are added."""
    Zr = project_out(U, Z)
    G = Zr.T @ Zr
    a = Zr.T @ r
    lam, V = np.linalg.eigh(G)
    keep = lam > max(lam.max(), 1e-300) * 1e-10
    if not keep.any():
        return 0.0
    b = V[:, keep].T @ a
    return float(b @ (b / lam[keep]))


def finite_ss(e: np.ndarray) -> float:
    """Sum of squares of the finite entries of ``e`` (held-out residuals are NaN where no model can predict)."""
    return float(np.nansum(np.asarray(e, float) ** 2))


def integrated_autocorr_time(e: np.ndarray, max_lag: int | None = None) -> float:
    """Integrated autocorrelation time ``1 + 2 sum rho_k`` (Geyer's initial positive sequence), >= 1."""
    e = np.asarray(e, float)
    e = e[np.isfinite(e)]
    e = e - np.mean(e) if len(e) else e
    n = len(e)
    if n < 8 or not np.any(e):
        return 1.0
    max_lag = min(max_lag or n // 4, n - 1)
    nfft = 1 << int(np.ceil(np.log2(2 * n)))
    f = np.fft.rfft(e, nfft)
    acf = np.fft.irfft(f * np.conj(f), nfft)[: max_lag + 1]
    acf = acf / acf[0]
    # pairs Gamma_m = rho_{2m} + rho_{2m+1}, summed while positive (and monotonised)
    tau = -1.0
    prev = np.inf
    for m in range(0, max_lag // 2):
        g = acf[2 * m] + acf[2 * m + 1]
        if g <= 0:
            break
        g = min(g, prev)
        prev = g
        tau += 2 * g
    return float(max(tau, 1.0))


MIN_EFFECT = 0.05   # an effect must explain at least this fraction of the residual variance to matter
DECIDED_FLOORS = 1.0   # the losing hypothesis' excess residual (RMS, noise floors) that decides between two


def excess_floors(worse: float, better: float) -> float:
    """What the worse of two fits leaves beyond the better one, in noise floors (the better one's residual RMS):
    ``sqrt(worse^2 - better^2) / better`` (0 when it leaves nothing more)."""
    return float(np.sqrt(max(worse ** 2 - better ** 2, 0.0)) / max(better, 1e-12))


def effective_tau(e: np.ndarray, groups: np.ndarray | None = None, min_group: int = 30) -> float:
    """Integrated autocorrelation time of a held-out residual: the median over its folds (``groups``) of the
    per-fold time, so that one fold a model extrapolates badly into does not set the sample count of all."""
    e = np.asarray(e, float)
    if groups is None:
        return integrated_autocorr_time(e)
    taus = []
    for g in np.unique(groups):
        x = e[groups == g]
        if np.isfinite(x).sum() >= min_group:
            taus.append(integrated_autocorr_time(x))
    return float(np.median(taus)) if taus else integrated_autocorr_time(e)


def nested_test(e0: np.ndarray, e1: np.ndarray, p_extra: int, k1: int, min_effect: float = MIN_EFFECT,
                groups: np.ndarray | None = None, independent: bool = False) -> dict:
    """Nested-model F-test and BIC change between held-out residuals of two models.

    The null hypothesis is that the effect explains at most ``min_effect`` of the residual variance (a
    minimum-effect test: the F statistic against a non-central F with ``lambda = n_eff f0^2``,
    ``f0^2 = min_effect / (1 - min_effect)``), so that a trace of structure that a very long record makes
    "significant" but that would not change the model is not called an effect. ``min_effect = 0`` gives the
    classical F-test.

    Parameters
    ----------
    e0, e1 : (m,) held-out residuals of the declared (nested) model and of the model with the effect.
    p_extra : parameters the effect adds (its columns plus one per shape parameter chosen on a grid).
    k1 : parameters of the larger model.
    groups : fold of each sample (the autocorrelation time is taken per fold, see :func:`effective_tau`).
    independent : the samples are separate events (onsets seconds apart): no autocorrelation correction
        (estimating one from a handful of events would only add noise).

    Returns
    -------
    dict with ``p_value``, ``delta_bic`` (negative: the effect is worth its parameters), ``F``, ``n``,
    ``n_eff``, ``tau_int``, ``ssr_ratio`` (held-out SSR with / without the effect).
    """
    e0 = np.asarray(e0, float)
    e1 = np.asarray(e1, float)
    ok = np.isfinite(e0) & np.isfinite(e1)
    e0, e1 = e0[ok], e1[ok]
    n = len(e0)
    ssr0 = float(e0 @ e0)
    ssr1 = float(e1 @ e1)
    tau = 1.0 if independent else effective_tau(e1, None if groups is None else np.asarray(groups)[ok])
    n_eff = max(n / tau, k1 + 2.0)
    ratio = ssr1 / ssr0 if ssr0 > 0 else 1.0
    df2 = max(n_eff - k1, 1.0)
    if ssr1 >= ssr0 or ssr0 == 0:
        F, p = 0.0, 1.0
    elif ssr1 <= 1e-300:              # the larger model is exact on held-out data
        F, p = float("inf"), 0.0
    else:
        F = ((ssr0 - ssr1) / p_extra) / (ssr1 / df2)
        if min_effect > 0:
            lam = n_eff * min_effect / (1.0 - min_effect)
            p = float(stats.ncf.sf(F, p_extra, df2, lam))
        else:
            p = float(stats.f.sf(F, p_extra, df2))
        if not np.isfinite(p):
            p = 0.0 if F > p_extra else 1.0
    dbic = n_eff * np.log(max(ratio, 1e-300)) + p_extra * np.log(n_eff)
    return {"p_value": p, "delta_bic": float(dbic), "F": float(F), "n": int(n), "n_eff": float(n_eff),
            "tau_int": float(tau), "ssr_ratio": float(ratio)}


def whiteness_p(e: np.ndarray, spacing: int, lags: int = 10) -> float:
    """Ljung-Box p-value of a residual taken every ``spacing`` samples (the smoothing window), so that the
    filter's own correlation does not count as structure. NaN when there are too few samples."""
    x = np.asarray(e, float)
    x = x[np.isfinite(x)][:: max(1, spacing)]
    if len(x) < 3 * lags or not np.any(x - x.mean()):
        return float("nan")
    x = x - x.mean()
    n = len(x)
    k = np.arange(1, lags + 1)
    rho = np.array([x[:-i] @ x[i:] for i in k]) / (x @ x)      # autocorrelations (biased, as statsmodels' acf)
    q = n * (n + 2) * float(np.sum(rho ** 2 / (n - k)))
    return float(stats.chi2.sf(q, lags))
