"""Signal helpers of the friction identification: Savitzky-Golay derivatives, the position noise floor and
quantisation step of an encoder signal, a least-squares line and batch-means standard errors."""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np
from scipy import stats
from scipy.signal import savgol_filter


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


def fit_line(t: np.ndarray, q: np.ndarray) -> tuple[float, float, float]:
    """Least-squares line ``q = a + b (t - t.mean())``; returns ``(a, b, t.mean())``."""
    tm = t.mean()
    tt = t - tm
    den = float(tt @ tt)
    b = float(tt @ (q - q.mean()) / den) if den > 0 else 0.0
    return float(q.mean()), b, tm


def batch_mean_se(x: np.ndarray, blocks: int = 10) -> tuple[float, float]:
    """Standard error of the mean of an autocorrelated series by batch means, and the half-width of its 95 %
    confidence interval (Student t with blocks - 1 degrees of freedom). NaN for fewer than 60 samples."""
    n = len(x)
    k = min(blocks, n // 20)
    if k < 3:
        return float("nan"), float("nan")
    means = np.array([b.mean() for b in np.array_split(x, k)])
    se = float(means.std(ddof=1) / math.sqrt(k))
    return se, t975(k - 1) * se


@lru_cache(maxsize=64)
def t975(dof: int) -> float:
    """The 97.5 % quantile of Student's t with ``dof`` degrees of freedom (kept: scipy's ``ppf`` costs half a
    millisecond a call, and a long run's friction map asks for the same few hundreds of times)."""
    return float(stats.t.ppf(0.975, dof))
