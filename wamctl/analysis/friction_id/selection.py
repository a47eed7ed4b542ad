"""Held-out selection among the friction models of one joint: stratified k-fold over the map's segments,
per-segment standard deviations, and the information criteria of the held-out residuals."""

from __future__ import annotations

import logging
import math

import numpy as np
import pandas as pd

from wamctl.analysis.friction_id.models import MODEL_NAMES, as_vf, make_estimator

log = logging.getLogger(__name__)


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
    mention", Kass and Raftery 1995). Every model is refitted on all points, its standard errors at least what
    the points' own standard errors carry through it, with the error of the map's ``timing_shift_Nm`` (the
    rigid body's timing, shared by every point) (:meth:`~wamctl.analysis.friction_id.models._LsqFriction.
    _add_point_errors`).

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
    v, f, se = _map_points(data)
    shift = _map_shift(data, len(v))
    good = np.isfinite(se) & (se > 0)        # a stage too short for batch means: three times the largest's
    se_points = np.where(good, se, 3.0 * np.max(se[good]) if good.any() else 0.0)
    known = weighting == "se"
    richest = max(models, key=lambda m: make_estimator(m).n_params)
    sigma = segment_sigma(v, f, se, reference=richest) if known else np.ones(len(v))
    labels = fold_labels(v, folds)
    rows, fitted = [], {}
    for name in models:
        try:
            full = make_estimator(name, loss).fit((v, f, sigma), se_Nm=se_points, shift_Nm=shift)
        except ValueError as exc:
            log.info("model %s not fitted: %s", name, exc)
            continue
        fitted[name] = full
        pred = _held_out_prediction(name, loss, v, f, sigma, labels, folds)
        rows.append(_score(name, full, pred, f, sigma, known))
    if not rows:
        raise ValueError("no friction model could be fitted (too few accepted segments)")
    table = pd.DataFrame(rows).set_index("model")
    chosen = _choose(table, f"{criterion}_cv", margin)
    table["chosen"] = table.index == chosen
    return table, chosen, fitted


def _map_points(data) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(velocity, friction, standard error) of the accepted points of a map DataFrame (NaN standard errors
    without ``friction_se_Nm``), or of a ``(v, F[, se])`` tuple."""
    if isinstance(data, pd.DataFrame):
        d = data[data["accepted"].astype(bool)] if "accepted" in data else data
        v, f = d["velocity_rad_s"].to_numpy(float), d["friction_Nm"].to_numpy(float)
        se = d["friction_se_Nm"].to_numpy(float) if "friction_se_Nm" in d else np.full(len(d), np.nan)
        return v, f, se
    return as_vf(data)


def _map_shift(data, n: int) -> np.ndarray:
    """(n,) the accepted points' ``timing_shift_Nm`` (the systematic error of the rigid body's timing,
    :data:`wamctl.analysis.friction_id.velocity_map.TIMING_SE_PERIODS`); zeros for a map without it or a
    tuple."""
    if isinstance(data, pd.DataFrame) and "timing_shift_Nm" in data:
        d = data[data["accepted"].astype(bool)] if "accepted" in data else data
        return np.nan_to_num(d["timing_shift_Nm"].to_numpy(float))
    return np.zeros(n)


def _held_out_prediction(name: str, loss: str, v: np.ndarray, f: np.ndarray, sigma: np.ndarray,
                         labels: np.ndarray, folds: int) -> np.ndarray:
    """(n,) prediction of every point by the model fitted without its fold; NaN where that fit failed."""
    pred = np.full(len(v), np.nan)
    for k in range(folds):
        test = labels == k
        if not test.any():
            continue
        try:
            est = make_estimator(name, loss).fit((v[~test], f[~test], sigma[~test]))
        except ValueError:
            continue
        pred[test] = est.predict(v[test])
    return pred


def _score(name: str, full, pred: np.ndarray, f: np.ndarray, sigma: np.ndarray, known: bool) -> dict:
    """One row of the selection table: held-out and in-sample scores of model ``name``."""
    n, kpar = len(f), full.n_params
    if np.isfinite(pred).all() and n > 0:
        s_cv = float(np.sum(((pred - f) / sigma) ** 2))
        ll = s_cv if known else n * math.log(max(s_cv / n, 1e-300))
        aic_cv, bic_cv = ll + 2 * kpar, ll + kpar * math.log(n)
        cv_rmse = math.sqrt(float(np.mean((pred - f) ** 2)))
    else:  # some folds could not be fitted (too few points): not comparable
        aic_cv = bic_cv = cv_rmse = float("inf")
    ic = full.information_criteria(known)
    return {"model": name, "k": kpar, "n": n, "cv_rmse_Nm": cv_rmse, "aic_cv": aic_cv, "bic_cv": bic_cv,
            "rmse_Nm": math.sqrt(full.rss_ / n), "aic": ic["aic"], "bic": ic["bic"]}


def _choose(table: pd.DataFrame, key: str, margin: float) -> str:
    """The simplest model whose score ``key`` is within ``margin`` of the best. Without a finite score no model
    could be checked on held-out segments (too few of them, or of one direction): none is chosen (ValueError),
    rather than a model fitted to a handful of points printed as identified."""
    if not np.isfinite(table[key]).any():
        raise ValueError(f"too few usable segments ({int(table['n'].max())}) to check any model on held-out ones")
    if "classic" in table.index and not np.isfinite(table.loc["classic", key]):
        # the per-direction model could not be checked: a symmetric one, checked, would win by default and
        # average two directions the data never compared
        raise ValueError("too few usable segments in one direction to check the per-direction model on held-out "
                         "ones")
    best = float(table[key].min())
    close = table[table[key] <= best + margin]
    return str(close.sort_values(["k", key]).index[0])
