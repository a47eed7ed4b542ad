"""Effects seen where a joint starts to move: backlash, and Stribeck at the breakaways (no I/O).

* backlash: the signed hidden travel ``d`` at reversals (:func:`wamctl.analysis.diagnosis.backlash.signed_travel`:
  positive when the measurement lags the link, negative when it leads it), ``d = c + v [reversal]`` against
  ``d = c`` (on the logarithmic scale of ``d`` when it leads; ``c`` only when there are same-direction onsets
  to estimate it); the dead band ``w`` (:func:`~wamctl.analysis.diagnosis.backlash.band_width`) at least
  ``MIN_BAND_TOLERANCES`` detection tolerances; its sign says on which side of the gap the encoder is;
* Stribeck at breakaway (when the torque residual did not already keep it): the log breakaway ratio
  ``l = log(rho)``, ``l = c`` against ``l = 0``, at every onset (at same-direction onsets only when backlash
  was kept: a dead band also delays the measured breakaway at reversals).

Both are nested tests on held-out onsets (:func:`wamctl.analysis.diagnosis.backlash.onset_test`), with the
threshold of the torque tests.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from wamctl.analysis.diagnosis.backlash import (
    MIN_BAND_TOLERANCES,
    MIN_ONSETS,
    MIN_REVERSALS,
    band_width,
    log_travel,
    onset_test,
)
from wamctl.analysis.diagnosis.candidates import MAX_BREAKAWAY_RATIO
from wamctl.analysis.diagnosis.crossval import cv_residual
from wamctl.analysis.diagnosis.joint import (
    EVIDENCE_KEYS,
    UNTESTED,
    breakaway_shape,
    set_after,
    set_rms,
    why_rejected,
)
from wamctl.analysis.diagnosis.onsets import (
    direction_breakaway_ratio,
    direction_levels_Nm,
    geometric_mean,
    joint_onsets,
    onset_model,
    stall_residual,
)
from wamctl.analysis.diagnosis.stats import MIN_EFFECT, finite_ss

MIN_BREAKAWAY_RATIO = 1.2     # the breakaway is seen a sample or two late: a joint without Stribeck reads ~1.1


def _stribeck_log_ratio_plausible(coef: float) -> bool:
    """A breakaway clearly above the Coulomb level (``MIN_BREAKAWAY_RATIO``: below, the detection's own lateness
    can account for it), by at most ``MAX_BREAKAWAY_RATIO`` (``coef``: its log)."""
    return np.log(MIN_BREAKAWAY_RATIO) <= coef <= np.log(MAX_BREAKAWAY_RATIO)


def _public(r: dict) -> dict:
    """An onset test without its coefficients (what the joint's candidate table shows)."""
    return {k: v for k, v in r.items() if k not in ("coef", "coef_fold")}


def onset_candidate(values: np.ndarray, rev: np.ndarray | None, fold: np.ndarray, n_folds: int, threshold: float,
                    plausible, why_not) -> dict:
    """Nested test at onsets of one candidate on ``values`` (k,) over ``fold`` (k,).

    ``rev is None`` tests a common offset against zero; otherwise ``rev`` (k,) bool marks reversals and a
    reversal term is tested against a common offset (or zero without same-direction onsets). ``plausible``
    (coef -> bool) and ``why_not`` (coef -> str) judge the fitted coefficient of a passing candidate."""
    n = len(values)
    if n < MIN_ONSETS or (rev is not None and rev.sum() < MIN_REVERSALS):
        what = "onsets" if rev is None else "reversals"
        have = n if rev is None else int(rev.sum())
        need = MIN_ONSETS if rev is None else MIN_REVERSALS
        return dict(UNTESTED, kept=False, reason=f"not testable: {have} {what} measured (at least {need} needed)")
    X0, X1 = _onset_design(n, rev)
    t = onset_test(values, X0, X1, fold, n_folds, MIN_EFFECT)
    coef = float(t["coef"][-1])
    out = {k: v for k, v in t.items() if k not in ("e0", "e1", "coef", "coef_fold")}
    out["coef"] = coef
    out["coef_fold"] = t["coef_fold"]
    kept = t["p_value"] < threshold and t["delta_bic"] < 0
    if kept and not plausible(coef):
        out.update(kept=False, reason=why_not(coef))
    else:
        out.update(kept=kept, reason="kept (seen at onsets)" if kept else why_rejected(t, threshold))
    return out


def _onset_design(n: int, rev: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """(X0, X1) of an onset test over ``n`` onsets: a common offset against zero (``rev is None``), or a reversal
    term against a common offset (zero without two same-direction onsets to estimate it)."""
    if rev is None:
        return np.zeros((n, 0)), np.ones((n, 1))
    X0 = np.ones((n, 1)) if (~rev).sum() >= 2 else np.zeros((n, 0))
    return X0, np.column_stack([X0, rev.astype(float)])


def stribeck_at_breakaways(diag, j: int, extra_delay_s: float = 0.0, test_only: bool = False,
                           model=None) -> tuple[dict, dict] | dict | None:
    """(test, onsets) when the breakaway ratios of 0-based joint ``j`` under the declared model show a
    Stribeck effect, else None. ``extra_delay_s``: a measurement delay added to the declared model (a late
    measurement makes every breakaway look later, at a higher torque); ``test_only``: the test whatever it says
    (None when there are too few onsets); ``model``: an :class:`~wamctl.analysis.diagnosis.onsets.OnsetModel`
    other than the declared one."""
    model = model or onset_model(diag, j, declared=True)
    if extra_delay_s:
        model = replace(model, delay_s=model.delay_s + float(extra_delay_s))
    ons = joint_onsets(diag.design_, diag.dynamics_, diag.jd_[j], model)
    ratio = ons["breakaway_ratio"]
    ok = np.isfinite(ratio)
    if ok.sum() < MIN_ONSETS:
        return None
    r = onset_candidate(np.log(ratio[ok]), None, ons["fold"][ok], diag.n_folds, diag.threshold_,
                        _stribeck_log_ratio_plausible, lambda c: "")
    if test_only:
        return r
    return (r, ons) if r["kept"] else None


def onset_tests(diag, j: int, tests: list[str]) -> None:
    """Test the onset effects among ``tests`` at 0-based joint ``j`` of a fitted ``ModelDiagnosis``, add the
    ones found to the joint's model, and add the torque residual at the stalls to its held-out figures."""
    res = diag.joints_[j]
    ons = joint_onsets(diag.design_, diag.dynamics_, diag.jd_[j], onset_model(diag, j))
    diag.onsets_[j] = ons
    rev = ons["reversal"]
    found = []
    if "backlash" in tests:
        r = _test_backlash(diag, ons)
        res.candidates["backlash"] = _public(r)
        if r["kept"]:
            found.append(("backlash", r))
    stribeck_kept = any(t["name"] == "stribeck" for t in res.kept)
    if "stribeck" in tests and not stribeck_kept:
        r = _test_stribeck(diag, ons, exclude_reversals=bool(found))
        if r["kept"]:
            found.append(("stribeck", r))
        elif "stribeck" in res.candidates:
            res.candidates["stribeck"]["onset_test"] = {k: r[k] for k in ("p_value", "delta_bic", "reason")
                                                        if k in r}
    if "stribeck" in tests and stribeck_kept:
        # Stribeck kept from the sliding samples: the breakaways measure its static level directly
        use = np.isfinite(ons["breakaway_ratio"]) & (~rev if found else True)
        t = next(t for t in res.kept if t["name"] == "stribeck")
        if use.sum() >= MIN_ONSETS and not t.get("onset_ratio") and not isinstance(t.get("fixed_h"), tuple):
            rho = geometric_mean(ons["breakaway_ratio"][use])
            if 1.0 < rho <= MAX_BREAKAWAY_RATIO:
                t["onset_ratio"] = rho
    ons["fold_coef"] = {}
    for name, r in sorted(found, key=lambda x: x[1]["ssr_ratio"]):
        add_onset_effect(diag, j, name, r, ons)
        ons["fold_coef"][name] = r.get("coef_fold", {})
    _stribeck_levels_per_direction(res, ons, backlash=any(n == "backlash" for n, _ in found))
    # the torque residual at the stalls (set-valued friction at rest) joins the sliding residual
    res.stall_before = stall_residual(diag, j, ons, after=False)
    res.stall_after = stall_residual(diag, j, ons, after=True)
    set_rms(res)


def _test_backlash(diag, ons: dict) -> dict:
    """The backlash decision (:func:`backlash_decision`) on a joint's onsets ``ons``; onsets where the model's link
    never moved are left out."""
    ok = np.isfinite(ons["travel_rad"])
    return backlash_decision(ons["travel_rad"][ok], ons["reversal"][ok], ons["fold"][ok], ons["tol_rad"],
                             diag.n_folds, diag.threshold_)


def backlash_decision(d: np.ndarray, rev: np.ndarray, fold: np.ndarray, tol: float, n_folds: int,
                      threshold: float) -> dict:
    """Signed hidden travel ``d`` (k,) rad at onsets (``rev`` (k,): reversals; ``fold`` (k,): their folds) beyond the
    same-direction onsets': a dead band behind the encoder (the measurement lags: positive) or a gap on the motor
    side (it leads: negative) of at least ``MIN_BAND_TOLERANCES`` detection tolerances ``tol``. A dead band behind
    the encoder is crossed by the same amount at every reversal: the travel is tested as it is; a gap on the motor
    side is crossed where the torque passed to the link changes sign, wholly, partly or not at all: tested on its
    logarithmic scale. Each side is tested one way (the fitted term must have that side's sign), so the pair keeps
    the false-alarm rate of one test. The rule the diagnosis applies, and the one a designed run's power is
    predicted for (:mod:`wamctl.analysis.diagnosis.backlash_design`)."""
    d, rev, fold = np.asarray(d, float), np.asarray(rev, bool), np.asarray(fold)
    w = band_width(d, rev) if rev.any() else 0.0
    side = "motor" if w < 0 else "link"
    r = onset_candidate(log_travel(d, tol) if side == "motor" else d, rev, fold, n_folds, threshold,
                        lambda c: True, lambda c: "")
    if "coef" not in r:
        return r
    same_sign = np.sign(r["coef"]) == np.sign(w)
    r.update(coef=w, coef_fold={f: band_width(d[fold != f], rev[fold != f]) for f in np.unique(fold)},
             encoder_side=side)
    if not r["kept"]:
        return r
    if not same_sign:
        r.update(kept=False, reason="the reversal term and the dead band fitted disagree on its sign")
    elif abs(w) < MIN_BAND_TOLERANCES * tol:
        r.update(kept=False, reason=(f"fitted dead band {abs(w):.2g} rad is below {MIN_BAND_TOLERANCES:g} detection "
                                     f"tolerances ({MIN_BAND_TOLERANCES * tol:.2g} rad)"))
    else:
        where = ("the measurement leads the link at reversals: the encoder is on the motor side of the gap"
                 if side == "motor" else "the measurement lags the link at reversals: a dead band behind the encoder")
        r["reason"] = f"kept (seen at onsets: {where})"
    return r


def backlash_decision_many(D: np.ndarray, rev: np.ndarray, fold: np.ndarray, tol: float, n_folds: int,
                           threshold: float) -> dict:
    """:func:`backlash_decision` on many draws at once: ``D`` (r, k) signed hidden travels (rad) of r runs sharing
    the onsets' pattern ``rev`` (k,) and folds ``fold`` (k,), all finite (a designed run's power, predicted by
    Monte Carlo: :func:`~wamctl.analysis.diagnosis.backlash_design.reversal_power`). The same rule, its held-out
    fits written as the linear maps they are (the design matrices do not change between draws).
    ``{"kept", "motor", "F", "p_value", "width_rad"}``, each (r,): the decision, whether it is the motor side's,
    its F statistic, p-value and the signed dead band."""
    from scipy import stats as st

    D = np.atleast_2d(np.asarray(D, float))
    rev, fold = np.asarray(rev, bool), np.asarray(fold)
    r, k = D.shape
    none = {"kept": np.zeros(r, bool), "motor": np.zeros(r, bool), "F": np.zeros(r), "p_value": np.ones(r),
            "width_rad": np.full(r, np.nan)}
    if k < MIN_ONSETS or rev.sum() < MIN_REVERSALS:
        return none
    # band_width, row by row
    n_same = int((~rev).sum())
    c = D[:, ~rev].mean(axis=1) if n_same >= 2 else np.zeros(r)
    dr = D[:, rev]
    lag = (dr - c[:, None]).mean(axis=1) >= 0
    c = np.where(lag, np.maximum(c, 0.0), np.minimum(c, 0.0))
    v = np.sort(dr - c[:, None], axis=1)
    half = (int(rev.sum()) + 1) // 2
    w = np.where(lag, v.mean(axis=1), np.minimum(v[:, :half].mean(axis=1), 0.0))
    motor = w < 0
    Y = np.where(motor[:, None], log_travel(D, tol), D)
    X0, X1 = _onset_design(k, rev)

    def heldout(X):
        A = np.eye(k)
        for f in range(n_folds):
            te = fold == f
            if not te.any() or X.shape[1] == 0:
                continue
            tr = ~te
            A[np.ix_(te, tr)] -= X[te] @ np.linalg.pinv(X[tr])
            A[np.ix_(te, te)] = np.eye(int(te.sum()))
        return A

    e0, e1 = Y @ heldout(X0).T, Y @ heldout(X1).T
    ssr0, ssr1 = (e0 ** 2).sum(axis=1), (e1 ** 2).sum(axis=1)
    k1 = X1.shape[1]
    n_eff = max(float(k), k1 + 2.0)
    df2 = max(n_eff - k1, 1.0)
    better = (ssr1 < ssr0) & (ssr0 > 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        F = np.where(better, (ssr0 - ssr1) / np.maximum(ssr1, 1e-300) * df2, 0.0)
        ratio = np.where(ssr0 > 0, ssr1 / ssr0, 1.0)
    lam = n_eff * MIN_EFFECT / (1.0 - MIN_EFFECT)
    p = np.where(better, st.ncf.sf(F, 1, df2, lam), 1.0)
    p = np.where(np.isfinite(p), p, np.where(F > 1, 0.0, 1.0))
    dbic = n_eff * np.log(np.maximum(ratio, 1e-300)) + np.log(n_eff)
    coef = Y @ np.linalg.pinv(X1)[-1]
    kept = (p < threshold) & (dbic < 0) & (np.sign(coef) == np.sign(w)) & (np.abs(w) >= MIN_BAND_TOLERANCES * tol)
    return {"kept": kept, "motor": motor, "F": F, "p_value": p, "width_rad": w}


def _test_stribeck(diag, ons: dict, exclude_reversals: bool) -> dict:
    """Log breakaway ratio above zero at the onsets (same-direction ones only when backlash was kept:
    reversals are not clean breakaways then)."""
    same = np.isfinite(ons["breakaway_ratio"])
    if exclude_reversals:
        same &= ~ons["reversal"]
    return onset_candidate(
        np.log(ons["breakaway_ratio"][same]), None, ons["fold"][same], diag.n_folds, diag.threshold_,
        _stribeck_log_ratio_plausible,
        lambda coef: (f"breakaway ratio {np.exp(coef):.2f} is not between {MIN_BREAKAWAY_RATIO:g} (the lateness of "
                      f"the detection) and {MAX_BREAKAWAY_RATIO:g}"))


def _stribeck_levels_per_direction(res, ons: dict, backlash: bool) -> None:
    """The breakaway level of each direction on its own, for a kept Stribeck term: a joint that sticks and
    slips one way only has few sliding samples there, and a ratio shared by both directions would inherit
    their Coulomb fit."""
    t = next((t for t in res.kept if t["name"] == "stribeck"), None)
    if t is None:
        return
    use = np.isfinite(ons["breakaway_ratio"]) & (~ons["reversal"] if backlash else True)
    if isinstance(t.get("fixed_h"), tuple):
        if "breakaways" in t.get("seen", ""):
            # the levels the joint withstood, in N m: not a ratio times a Coulomb level the sliding samples of
            # a direction may not determine (:func:`~wamctl.analysis.diagnosis.onsets.breakaway_reference_Nm`)
            t["breakaway_levels_Nm"] = {key: direction_levels_Nm(ons, sgn, use)
                                        for key, sgn in (("pos", 1.0), ("neg", -1.0))}
            t["breakaway_Nm"] = {key: geometric_mean(v) for key, v in t["breakaway_levels_Nm"].items()
                                 if len(v) >= 2}
        return
    ons["use_breakaway"] = use
    rho = {key: direction_breakaway_ratio(ons, sgn) for key, sgn in (("pos", 1.0), ("neg", -1.0))}
    rho = {key: r for key, r in rho.items() if r is not None}
    if rho:
        t["onset_ratio_dir"] = rho


def add_onset_effect(diag, j: int, name: str, r: dict, ons: dict) -> None:
    """Add an effect found at onsets to the joint's model (its torque-domain part refitted)."""
    res, jd, des = diag.joints_[j], diag.jd_[j], diag.design_
    ev = {k: v for k, v in r.items() if k in EVIDENCE_KEYS}
    extra = {}
    if name == "backlash":
        extra.update(width_rad=abs(float(r["coef"])), encoder_side=r["encoder_side"])
    else:
        extra["fixed_h"] = breakaway_shape(ons, float(np.exp(r["coef"])), des.sig.dt_s)
        extra.update(onset_test=True, seen="breakaways")
    if extra.get("encoder_side") == "motor":
        # a gap on the motor side leaves the sliding samples as they are (the link follows the measurement at
        # a constant offset on the driven flank): no torque-domain term
        e1, h_fold = res.e_after, [None] * des.n_folds
        diag.warnings_.append(f"joint {j + 1}: backlash with the encoder on the motor side of the gap (the "
                              "measurement leads the link at reversals); the plant's backlash effect (a dead band "
                              "between link and encoder) cannot represent it, so model.yaml leaves it out")
    else:
        e1, h_fold = cv_residual(des, jd, res.kept, name, extra.get("fixed_h"))
    term = {"name": name, "h_fold": h_fold, "evidence": ev, "gain": 1.0 - r["ssr_ratio"], **extra}
    if finite_ss(e1) > finite_ss(res.e_after):
        e1 = res.e_after
    set_after(des, res, jd, res.kept + [term], e1)
    res.candidates[name] = _public(r)
