"""Held-out residuals and shape parameters of a joint's model (no I/O).

Each joint's sliding samples are dealt into folds of contiguous time blocks (:mod:`.prepare`). Every
held-out residual comes from a model fitted on the other folds, and every shape parameter of a candidate
(Stribeck velocity, ripple period, delay, drift time constant) is chosen on the training folds only.
"""

from __future__ import annotations

import numpy as np

from wamctl.analysis.diagnosis.candidates import (
    DELAY_GRID_S,
    DRIFT_T_GRID_FRACTION,
    RIPPLE_MAX_HARMONICS,
    RIPPLE_MIN_PERIODS,
    RIPPLE_PERIOD_MAX_RAD,
    RIPPLE_PERIOD_MIN_RAD,
    STRIBECK_VS_GRID_RAD_S,
    ripple_columns,
)
from wamctl.analysis.diagnosis.design import (
    Design,
    JointData,
    at_fold,
    columns,
    delay_of,
    fit_theta,
    target_and_design,
)
from wamctl.analysis.diagnosis.stats import (
    MIN_EFFECT,
    effective_tau,
    lstsq,
    orth_basis,
    project_out,
    projection_gain,
)


# ---------------------------------------------------------------------------------------------- shapes
def shape_grid(des: Design, name: str) -> list:
    """Shape parameters searched for candidate ``name`` ([None]: it has none; []: searched otherwise)."""
    if name == "stribeck":
        return list(STRIBECK_VS_GRID_RAD_S)
    if name == "delay":
        return list(DELAY_GRID_S)
    if name == "friction_drift":
        return list(DRIFT_T_GRID_FRACTION * max(des.sig.duration_s, 1e-3))
    if name == "position_ripple":
        return []  # searched, see select_ripple_period
    return [None]


def default_shape(des: Design, name: str | None):
    """Shape parameter of a fold with no samples of its own: the middle of the grid."""
    if name is None:
        return None
    if name == "position_ripple":
        return 0.2, 1
    g = shape_grid(des, name)
    return g[len(g) // 2] if g else 0.2


def first_shape(term: dict):
    """A term's shape parameter on all data before it is refitted: the median of its per-fold values."""
    hs = [h for h in term["h_fold"] if h is not None]
    if not hs:
        return None
    if isinstance(hs[0], (tuple, str)):
        return hs[0]
    return float(np.median(hs))


def select_shape(des: Design, name: str, jd: JointData, rows: np.ndarray, Xb: np.ndarray, y: np.ndarray,
                 terms=()):
    """Shape parameter of candidate ``name`` that best explains the current residual on ``rows``.

    ``Xb`` (m, p) and ``y`` (m,) are the design and target of the current model; ``terms`` the other terms,
    with ``h_all`` set (the delay's grid changes the whole design)."""
    if name == "delay":
        return select_delay(des, jd, rows, terms)
    if name == "position_ripple":
        return select_ripple_period(des, jd, rows, Xb, y)
    grid = shape_grid(des, name)
    if len(grid) == 1:
        return grid[0]
    d = delay_of(terms)
    U = orth_basis(Xb[rows])
    r = project_out(U, y[rows])
    gains = [projection_gain(U, r, columns(des, name, jd, h, d)[rows]) for h in grid]
    return grid[int(np.argmax(gains))]


def select_delay(des: Design, jd: JointData, rows: np.ndarray, terms=()) -> float:
    """Delay (s) that minimises the residual sum of squares on ``rows``: every fourth value of the grid,
    then the neighbours of the best, then a parabola through the best three (a delay between grid points)."""
    def ssr(d):
        yd, X = target_and_design(des, jd, list(terms) + [{"name": "delay", "h_all": d}], None)
        th = lstsq(X[rows], yd[rows])
        r = yd[rows] - X[rows] @ th
        return float(r @ r)

    grid = DELAY_GRID_S
    coarse = list(range(0, len(grid), 4)) + [len(grid) - 1]
    scores = {i: ssr(grid[i]) for i in coarse}
    i0 = min(scores, key=scores.get)
    for i in range(max(0, i0 - 3), min(len(grid), i0 + 4)):
        if i not in scores:
            scores[i] = ssr(grid[i])
    i0 = min(scores, key=scores.get)
    if 0 < i0 < len(grid) - 1:
        s0, s1, s2 = scores[i0 - 1], scores[i0], scores[i0 + 1]
        den = s0 - 2 * s1 + s2
        if den > 0:
            step = grid[1] - grid[0]
            d = float(grid[i0] + 0.5 * step * (s0 - s2) / den)
            if ssr(d) < s1:
                return d
    return float(grid[i0])


def select_ripple_period(des: Design, jd: JointData, rows: np.ndarray, Xb: np.ndarray,
                         y_all: np.ndarray) -> tuple[float, int]:
    """Shape ``(period (rad), harmonics H)`` of the strongest position-periodic component of the base residual on
    ``rows``: a fundamental and its harmonics 2 .. H (a Fourier series in the angle).

    1. The residual is binned over the joint angle (bins of a tenth of the shortest period) and its periodogram
       over the angle taken by FFT (zero-padded 4x); the highest peaks are compared by the exact least-squares
       gain of one filter-attenuated sinusoid (see ``ripple_columns``) and the best is refined.
    2. The strongest peak may be the fundamental or one of its harmonics (a harmonic can be stronger than the
       fundamental): the candidate fundamentals are its frequency divided by 1 .. ``RIPPLE_MAX_HARMONICS``.
    3. Fundamental and H are chosen together by BIC over the series' in-sample gain, with the effective sample
       count of the residual: each harmonic (2 columns) must be worth its columns, and a longer period ``m P``
       must explain more than its harmonics that make the series of ``P``, by at least ``MIN_EFFECT`` of its gain
       (else the ripple's period is ``P``: a fundamental that carries next to nothing is not the period). The
       chosen period is then refined.
    Periods are searched up to the joint's travel over ``RIPPLE_MIN_PERIODS`` (a longer one cannot be shown to
    repeat, see :func:`wamctl.analysis.diagnosis.joint.plausible`)."""
    sub = rows[:: max(1, len(rows) // 6000)]
    Us = orth_basis(Xb[sub])
    rs = project_out(Us, y_all[sub])
    # the band: up to the joint's whole travel over RIPPLE_MIN_PERIODS (the angles visited are the design, not the
    # held-out outcome: a fold whose training blocks happen to miss an end must not lose the true period)
    lo = max(1 / RIPPLE_PERIOD_MAX_RAD, RIPPLE_MIN_PERIODS / max(float(np.ptp(jd.q_rad)), 1e-9))
    hi = 1 / RIPPLE_PERIOD_MIN_RAD
    ks, step = _ripple_peaks(jd.q_rad[rows], project_out(orth_basis(Xb[rows]), y_all[rows]), lo)
    if not len(ks):
        return 1 / lo, 1
    q, qd = jd.q_rad[sub], jd.qd_rad_s[sub]
    sig = des.sig

    def gains(k: float, nh: int) -> np.ndarray:
        """(nh,) in-sample gain of the series at fundamental ``k`` (cycles/rad) with 1 .. nh harmonics."""
        Z = project_out(Us, ripple_columns(q, qd, 1 / k, sig.window, sig.gauss, sig.dt_s, nh))
        return nested_gains(Z, rs)

    peak = ks[int(np.argmax([gains(k, 1)[0] for k in ks]))]
    peak = float(np.clip(_refine_peak(lambda kk: gains(kk, 1)[0], peak, step), lo, hi))
    table = {m: gains(peak / m, RIPPLE_MAX_HARMONICS) for m in range(1, RIPPLE_MAX_HARMONICS + 1)
             if lo <= peak / m <= hi}
    ss0 = float(rs @ rs)
    # the residual's effective sample count, once the fullest series is fitted (the ripple itself would count as
    # autocorrelation)
    m_full = max(table, key=lambda m: table[m][-1])
    Z = project_out(Us, ripple_columns(q, qd, m_full / peak, sig.window, sig.gauss, sig.dt_s, RIPPLE_MAX_HARMONICS))
    n_eff = len(sub) / max(effective_tau(project_out(orth_basis(Z), rs), jd.fold[sub]), 1.0)
    crit = {(m, nh): n_eff * np.log(max(ss0 - table[m][nh - 1], 1e-300 * ss0) / ss0) + 2 * nh * np.log(n_eff)
            for m in table for nh in range(1, RIPPLE_MAX_HARMONICS + 1) if _fundamental_carries(table, m, nh)}
    m, nh = min(crit, key=crit.get)
    return 1.0 / _refine_peak(lambda kk: gains(kk, nh)[-1], peak / m, 0.25 * step / m), int(nh)


def _refine_peak(f, k: float, half_width: float, rounds: int = 3) -> float:
    """The maximum of a smooth peak ``f`` near ``k`` (within ``2 half_width``): five points over ``k +- half_width``,
    the best one the centre of the next five at half the width (``rounds`` times), then the vertex of the parabola
    through the best and its neighbours (kept when it is better)."""
    seen = {}

    def val(x):
        if x not in seen:
            seen[x] = f(x)
        return seen[x]

    hw = half_width
    for _ in range(rounds):
        ks = k + hw * np.linspace(-1.0, 1.0, 5)
        g = np.array([val(kk) for kk in ks])
        i = int(np.argmax(g))
        k = float(ks[i])
        if 0 < i < 4:
            hw /= 2
    if 0 < i < 4:
        den = g[i - 1] - 2 * g[i] + g[i + 1]
        if den < 0:
            kv = float(ks[i] + 0.5 * (ks[1] - ks[0]) * (g[i - 1] - g[i + 1]) / den)
            if val(kv) > g[i]:
                return kv
    return k


def _fundamental_carries(table: dict, m: int, nh: int) -> bool:
    """Whether the series at fundamental ``peak / m`` with ``nh`` harmonics (``table[m]``: its prefix gains)
    explains at least ``MIN_EFFECT`` of its gain beyond its harmonics that make the series of a shorter period
    ``peak / (m / d)`` (every divisor ``d`` of ``m``)."""
    g = table[m][nh - 1]
    for d in range(2, m + 1):
        if m % d == 0 and (m // d) in table:
            g_short = table[m // d][nh // d - 1] if nh // d >= 1 else 0.0
            if g - g_short < MIN_EFFECT * g:
                return False
    return True


def _ripple_peaks(q: np.ndarray, r: np.ndarray, lo: float) -> tuple[np.ndarray, float]:
    """Candidate ripple frequencies (cycles/rad, from ``lo``) of the residual ``r`` (m,) over the angle ``q`` (m,):
    the eight highest peaks of its periodogram over the angle (in the band of periods searched); and the
    periodogram's frequency resolution."""
    dq = RIPPLE_PERIOD_MIN_RAD / 10
    q0 = float(q.min())
    nb = int(np.ptp(q) / dq) + 2
    rb = np.bincount(((q - q0) / dq).astype(int), weights=r, minlength=nb)
    L = 1 << int(np.ceil(np.log2(4 * nb)))
    L = min(L, 1 << 22)
    power = np.abs(np.fft.rfft(rb, L)) ** 2
    k = np.arange(len(power)) / (L * dq)                      # cycles per rad
    hi = 1 / RIPPLE_PERIOD_MIN_RAD
    band = (k >= lo) & (k <= hi)
    step = 1.0 / (L * dq)
    if not band.any():
        return np.zeros(0), step
    pb = np.where(band, power, -1.0)
    peak = (pb[1:-1] >= pb[:-2]) & (pb[1:-1] >= pb[2:]) & band[1:-1]
    cand = np.flatnonzero(peak) + 1
    if len(cand) == 0:
        cand = np.array([int(np.argmax(pb))])
    return k[cand[np.argsort(pb[cand])[-8:]]], step


def nested_gains(Z: np.ndarray, r: np.ndarray) -> np.ndarray:
    """(p / 2,) drop of the sum of squares of ``r`` when the first 2, 4, ... columns of ``Z`` (m, p; already
    orthogonal to the model ``r`` is the residual of) are added: the gains of nested column blocks, from one
    Cholesky-like pass over their Gram matrix (ill-conditioned directions dropped)."""
    G = Z.T @ Z
    a = Z.T @ r
    out = []
    for n in range(2, Z.shape[1] + 1, 2):
        lam, V = np.linalg.eigh(G[:n, :n])
        keep = lam > max(lam.max(), 1e-300) * 1e-10
        b = V[:, keep].T @ a[:n]
        out.append(float(b @ (b / lam[keep])) if keep.any() else 0.0)
    return np.maximum.accumulate(np.array(out))


# ---------------------------------------------------------------------------------------------- held out
def unpredictable(jd: JointData, trr: np.ndarray, te_i: np.ndarray) -> np.ndarray:
    """Held-out samples (indices among ``te_i``) no model of the joint fitted on ``trr`` can predict: in a
    direction the training folds never moved in, or at a speed outside the training speeds of that
    direction (by more than 25 %). They test extrapolation of the friction law, not an effect, and are left
    out of every held-out figure (NaN)."""
    qd = jd.qd_rad_s
    bad = np.zeros(len(te_i), bool)
    for sgn in (1.0, -1.0):
        tr_v = np.abs(qd[trr][np.sign(qd[trr]) == sgn])
        te_m = np.sign(qd[te_i]) == sgn
        if len(tr_v) < 20:
            bad |= te_m
            continue
        v = np.abs(qd[te_i])
        bad |= te_m & ((v > 1.25 * tr_v.max()) | (v < tr_v.min() / 1.25))
    return te_i[bad]


def _fold_design(des: Design, jd: JointData, terms: list[dict], f: int, trr: np.ndarray, cand: str | None,
                 fixed_h):
    """Target, design and the candidate's shape parameter of fold ``f`` (chosen on the rows ``trr``)."""
    y, Xb = target_and_design(des, jd, terms, f)
    if cand is None:
        return y, Xb, None
    here = at_fold(terms, f)
    if cand == "delay":
        h = select_delay(des, jd, trr, here)
        y, X = target_and_design(des, jd, terms + [{"name": "delay", "h_fold": [h] * des.n_folds}], f)
        return y, X, h
    if cand == "stribeck" and isinstance(fixed_h, tuple):      # a Stribeck shape measured elsewhere
        shaped = {"name": "stribeck", "h_fold": [fixed_h] * des.n_folds, "fixed_h": fixed_h}
        y, X = target_and_design(des, jd, terms + [shaped], f)
        return y, X, fixed_h
    h = fixed_h if fixed_h is not None else select_shape(des, cand, jd, trr, Xb, y, here)
    return y, np.hstack([Xb, columns(des, cand, jd, h, delay_of(here))]), h


def cv_residual(des: Design, jd: JointData, terms: list[dict], cand: str | None = None,
                fixed_h=None) -> tuple[np.ndarray, list]:
    """Held-out residuals (m,) of ``friction + terms (+ cand)`` and the candidate's per-fold shape parameters.

    ``fixed_h`` fixes the candidate's shape parameter instead of choosing it on each fold's training data."""
    e = np.zeros(jd.n)
    h_fold = []
    for f in range(des.n_folds):
        te = jd.fold == f
        if not te.any():
            h_fold.append(h_fold[-1] if h_fold else default_shape(des, cand))
            continue
        trr, te_i = np.flatnonzero(~te), np.flatnonzero(te)
        bad = unpredictable(jd, trr, te_i)
        y, X, h = _fold_design(des, jd, terms, f, trr, cand, fixed_h)
        h_fold.append(h)
        if len(trr) < X.shape[1] + 5:
            e[te] = y[te] - (np.mean(y[trr]) if len(trr) else 0.0)
            continue
        e[te] = y[te] - X[te] @ fit_theta(X[trr], y[trr], des.bounded)
        e[bad] = np.nan
    return e, h_fold


def cv_terms(des: Design, jd: JointData, terms: list[dict]) -> np.ndarray:
    """Held-out residual (m,) of ``friction + terms`` with the terms' per-fold shape parameters."""
    e = np.zeros(jd.n)
    for f in range(des.n_folds):
        te = jd.fold == f
        if not te.any():
            continue
        trr, te_i = np.flatnonzero(~te), np.flatnonzero(te)
        y, X = target_and_design(des, jd, terms, f)
        if len(trr) < X.shape[1] + 5:
            e[te] = np.nan
            continue
        e[te] = y[te] - X[te] @ fit_theta(X[trr], y[trr], des.bounded)
        e[unpredictable(jd, trr, te_i)] = np.nan
    return e


def fit_all(des: Design, jd: JointData, terms: list[dict]) -> tuple[list[dict], np.ndarray]:
    """Refit on all data: shape parameters chosen one term at a time with the others fixed.

    Returns the terms with ``h_all`` set and the coefficients (p,) of ``friction + terms``."""
    terms = [dict(t) for t in terms]
    for t in terms:
        t.setdefault("h_all", first_shape(t))
    rows = np.arange(jd.n)
    for i, t in enumerate(terms):
        if t.get("fixed_h") is not None:
            t["h_all"] = t["fixed_h"]
            continue
        others = terms[:i] + terms[i + 1:]
        y, Xb = target_and_design(des, jd, others, None)
        t["h_all"] = select_shape(des, t["name"], jd, rows, Xb, y, others)
    y, X = target_and_design(des, jd, terms, None)
    return terms, fit_theta(X, y, des.bounded)
