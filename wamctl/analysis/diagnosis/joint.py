"""Diagnosis of one joint: forward selection of the torque-domain candidates, and their plausibility (no I/O).

Each candidate is tested as a nested model against the current model on the held-out residuals
(:func:`wamctl.analysis.diagnosis.stats.nested_test`); the best passing candidate (largest held-out gain)
that is physically plausible is added, and the rest are tested again against the augmented model, until none
passes. From the second step on, the minimum effect is a share of the declared model's residual, so that the
imperfections of a strong effect's model are not named as further effects.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from wamctl.analysis.diagnosis.candidates import (
    DELAY_GRID_S,
    MAX_BREAKAWAY_RATIO,
    RIPPLE_MIN_PERIODS,
    STRIBECK_VS_GRID_RAD_S,
)
from wamctl.analysis.diagnosis.crossval import cv_residual, cv_terms, fit_all
from wamctl.analysis.diagnosis.design import (
    N_COLUMNS,
    N_FRICTION,
    Design,
    JointData,
    columns,
    declared_levels,
    drift_offset,
    fit_theta,
    levels,
    ncols,
    split_coefs,
    target_and_design,
)
from wamctl.analysis.diagnosis.headtohead import p_extra, passes, tournament
from wamctl.analysis.diagnosis.onsets import slip_vs
from wamctl.analysis.diagnosis.stats import MIN_EFFECT, finite_ss, nested_test, whiteness_p
from wamctl.model import params as P

EVIDENCE_KEYS = ("p_value", "delta_bic", "F", "n", "n_eff", "ssr_ratio")
UNTESTED = {"p_value": float("nan"), "delta_bic": float("nan")}


@dataclass
class JointResult:
    """Diagnosis of one joint (0-based ``j``)."""

    j: int
    kept: list[dict] = field(default_factory=list)           # name, h_fold, h_all, coef, evidence, gain
    candidates: dict = field(default_factory=dict)           # name -> test dict + kept + reason
    theta_before: np.ndarray | None = None                   # classic friction fitted on all data
    theta_after: np.ndarray | None = None                    # all coefficients of the final model
    columns_after: list[tuple[str, int]] = field(default_factory=list)   # (term name, n columns)
    e_before: np.ndarray | None = None                        # held-out residuals (JointData order)
    e_base: np.ndarray | None = None                          # held-out residual of the fitted declared model
    stall_before: np.ndarray | None = None                    # torque residual at stalls (set-valued friction)
    stall_after: np.ndarray | None = None
    stall_t: np.ndarray | None = None                         # their times, s
    e_after: np.ndarray | None = None
    torque_rms_before_Nm: float = float("nan")
    torque_rms_after_Nm: float = float("nan")
    whiteness_p_before: float = float("nan")
    whiteness_p_after: float = float("nan")
    position_rms_before_rad: float = float("nan")
    position_rms_after_rad: float = float("nan")
    position_not_checked: str | None = None      # why the position check did not score the joint
    effects: list[dict] = field(default_factory=list)         # report-ready: name, params, evidence
    ambiguous: list[dict] = field(default_factory=list)       # groups no member of which won: names, evidence
    unexplained: dict | None = None                           # what the final residual still correlates with


def joint_baseline(des: Design, jd: JointData) -> JointResult:
    """The declared model of a joint: its held-out residual and its classic friction fitted on all data
    (also kept as ``jd.extra["theta_before"]``, the shape a drift scales)."""
    res = JointResult(jd.j)
    e_base, _ = cv_residual(des, jd, [])
    # a given model is not refitted: its residual is the target itself
    res.e_before = e_base if des.bounded else jd.y_Nm.copy()
    res.e_base = e_base
    res.theta_before = fit_theta(columns(des, "friction", jd, None), jd.y_Nm, des.bounded)
    jd.extra["theta_before"] = res.theta_before
    return res


def forward_select(des: Design, jd: JointData, res: JointResult, tests: list[str], threshold: float,
                   max_steps: int, pre: dict | None = None, rejected: dict | None = None,
                   onset_recheck=None) -> JointResult:
    """Forward selection of the torque-domain candidates ``tests`` at one joint, from ``joint_baseline``.

    At each step every remaining candidate is tested against the current model; the plausible ones that pass
    meet head to head (:mod:`wamctl.analysis.diagnosis.headtohead`): one is kept only when it wins clearly,
    otherwise the group is reported as ambiguous (``res.ambiguous``) and kept out of the named model.
    ``pre``: ``{"breakaways": (test, onsets) or None, "map": test or None}`` when the breakaways under the
    declared model (:func:`wamctl.analysis.diagnosis.onset_tests.stribeck_at_breakaways`) or the friction map of
    steady segments (:func:`wamctl.analysis.diagnosis.sweeps.map_evidence`) show a Stribeck effect: at the first
    step that Stribeck candidate replaces the one fitted on the sliding samples. ``rejected`` maps candidates
    excluded beforehand to the reason. ``onset_recheck``: see
    :func:`wamctl.analysis.diagnosis.headtohead.beyond_tests`."""
    rejected = dict(rejected or {})
    terms: list[dict] = []
    hidden: list[dict] = []            # terms of ambiguous groups: in the model searched from, never named
    current = res.e_base
    remaining = [c for c in tests if c not in rejected]
    last: dict = {}
    res.ambiguous = []
    base_ssr = finite_ss(res.e_base)
    for step in range(max_steps):
        model_terms = terms + hidden
        entries = _entries(des, jd, model_terms, remaining, res.e_base, current, step, last)
        if step == 0 and pre and "stribeck" in remaining:
            entries["stribeck"] = _stribeck_seen_elsewhere(des, jd, model_terms, pre)
            seen = entries["stribeck"]["term"]["seen"]
            last["stribeck"] = dict(entries["stribeck"]["test"], step=step, reason=f"kept (seen {seen})")
        passing = sorted((c for c, en in entries.items() if passes(en["test"], threshold)),
                         key=lambda c: finite_ss(entries[c]["e"]))
        plaus = _plausible_all(des, jd, model_terms, passing, entries, last, remaining)
        if not plaus:
            break
        winner, group, records = tournament(des, jd, model_terms, [entries[c] for c in plaus], res.e_base,
                                            threshold, onset_recheck)
        for c, recs in records.items():
            if recs:
                last[c]["head_to_head"] = recs
        if winner is None:
            names = [g["name"] for g in group]
            res.ambiguous.append({"names": names, "step": step,
                                  "evidence": {g["name"]: _evidence(g["test"]) for g in group}})
            for g in group:
                last[g["name"]]["reason"] = ("ambiguous: neither of " + " and ".join(names)
                                             + " explains the held-out residual clearly better than the other")
                remaining.remove(g["name"])
            hidden += [g["term"] for g in group]
            current = cv_terms(des, jd, terms + hidden)
            continue
        c = winner["name"]
        gain = (finite_ss(current) - finite_ss(winner["e"])) / base_ssr if base_ssr > 0 else 0.0
        if winner["term"].get("onset_test"):      # its evidence is where it was seen, not the sliding samples
            gain = max(gain, 1.0 - winner["test"].get("ssr_ratio", 1.0))
        term = dict(winner["term"], evidence=_evidence(winner["test"]), gain=gain,
                    rms_before_Nm=rms(current), rms_after_Nm=rms(winner["e"]))
        terms.append(term)
        current = winner["e"]
        remaining.remove(c)
    terms, dropped = _backward(des, jd, terms, hidden, res.e_base, threshold)
    for c, why in dropped.items():
        last[c] = dict(last.get(c, UNTESTED), reason=why)
    e_after = current if not (hidden or dropped) else cv_terms(des, jd, terms)
    set_after(des, res, jd, terms, e_after)
    res.candidates = _candidate_table(res, tests, rejected, last, threshold)
    return res


def _backward(des: Design, jd: JointData, terms: list[dict], hidden: list[dict], e_base: np.ndarray,
              threshold: float) -> tuple[list[dict], dict]:
    """Backward check of the effects kept (one was kept before a later one that explains the same part of the
    residual better): each must still add to the model with all the others, at the run's threshold; the weakest
    that does not is dropped, and so on. Effects seen at the breakaways or on the friction map are judged there.
    Returns the terms kept and {name: why} of the dropped ones."""
    dropped = {}
    while len(terms) >= 2:
        e_full = cv_terms(des, jd, terms + hidden)
        worst, worst_p = None, -1.0
        for i, t in enumerate(terms):
            if t.get("onset_test"):
                continue
            others = terms[:i] + terms[i + 1:]
            e0 = cv_terms(des, jd, others + hidden)
            k1 = N_FRICTION + sum(ncols(x) for x in terms + hidden)
            share = finite_ss(e_base) / max(finite_ss(e0), 1e-300)
            test = nested_test(e0, e_full, p_extra(t["name"], t), k1, min(MIN_EFFECT * share, 0.9), jd.fold)
            if not passes(test, threshold) and test["p_value"] > worst_p:
                worst, worst_p = i, test["p_value"]
        if worst is None:
            break
        t = terms.pop(worst)
        dropped[t["name"]] = ("does not add to the other effects found (" + ", ".join(x["name"] for x in terms)
                              + f"): p = {worst_p:.3g} once they are in the model")
    return terms, dropped


def rms(e: np.ndarray) -> float:
    """Root mean square of the finite entries of a held-out residual."""
    e = np.asarray(e, float)
    e = e[np.isfinite(e)]
    return float(np.sqrt(np.mean(e ** 2))) if len(e) else float("nan")


def _evidence(t: dict) -> dict:
    return {k: t[k] for k in EVIDENCE_KEYS if k in t}


def _entries(des: Design, jd: JointData, terms: list[dict], remaining: list[str], e_base: np.ndarray,
             current: np.ndarray, step: int, last: dict) -> dict:
    """{candidate: entry} of each remaining candidate added to ``friction + terms``: its test against the current
    model, its term and held-out residual (see :func:`wamctl.analysis.diagnosis.headtohead.tournament`)."""
    out = {}
    for c in remaining:
        if c == "payload" and "payload" not in jd.extra:
            continue
        e1, h_fold = cv_residual(des, jd, terms, c)
        term = {"name": c, "h_fold": h_fold}
        extra = ncols(term) if c == "position_ripple" else N_COLUMNS[c]     # a ripple: 2 per harmonic
        k1 = N_FRICTION + sum(ncols(t) for t in terms) + extra
        # the minimum effect is a share of what the declared model left, not of what is left now: after a
        # strong effect, the traces of its imperfect model are not new effects
        share = finite_ss(e_base) / max(finite_ss(current), 1e-300)
        t = nested_test(current, e1, p_extra(c, term), k1, min(MIN_EFFECT * share, 0.9), jd.fold)
        out[c] = {"name": c, "test": t, "e": e1, "term": term}
        last[c] = dict(t, step=step)
    return out


def _stribeck_seen_elsewhere(des: Design, jd: JointData, terms: list[dict], pre: dict) -> dict:
    """The Stribeck candidate seen on the friction map of steady segments or at the breakaways: an entry with
    that test as its evidence (the smaller p-value of the two), the shape measured there (the map's fit when the
    map shows the hump; else the breakaway ratio of each direction and the velocity from the slips after the
    breakaways) and the held-out residual with it."""
    mp, br = pre.get("map"), pre.get("breakaways")
    if mp is not None:
        shape, seen, test = mp["shape"], "on the friction map of steady segments", mp
    else:
        r, ons = br
        shape, seen, test = breakaway_shape(ons, float(np.exp(r["coef"])), des.sig.dt_s), "at the breakaways", r
        shape = _sliding_shape(des, jd, terms, shape)
    if mp is not None and br is not None and br[0]["p_value"] < mp["p_value"]:
        test = br[0]
    e1, h_fold = cv_residual(des, jd, terms, "stribeck", shape)
    term = {"name": "stribeck", "h_fold": h_fold, "fixed_h": shape, "onset_test": True, "seen": seen}
    if br is not None:
        term["onsets"] = br[1]           # the onsets its shape was measured at (for its intervals)
    return {"name": "stribeck", "test": dict(_evidence(test), seen=seen), "e": e1, "term": term}


SHAPE_DELTAS = (1.0, 1.5, 2.0)


def _sliding_shape(des: Design, jd: JointData, terms: list[dict], shape: tuple) -> tuple:
    """The breakaway ratios measured at the onsets, with the Stribeck velocity and exponent that best fit the
    joint's sliding samples (the friction levels refitted): the slips after the breakaways give a velocity for
    one exponent only, and the decay of real friction is not always Gaussian."""
    rp, rn, vs0, _ = shape
    best, arg = np.inf, shape
    for delta in SHAPE_DELTAS:
        for vs in np.r_[STRIBECK_VS_GRID_RAD_S, vs0]:
            cand = (rp, rn, float(vs), delta)
            y, X = target_and_design(des, jd, terms + [{"name": "stribeck", "fixed_h": cand, "h_all": cand}], None)
            r = y - X @ fit_theta(X, y, des.bounded)
            ssr = float(r @ r)
            if ssr < best:
                best, arg = ssr, cand
    return arg


def breakaway_shape(ons: dict, ratio: float, dt_s: float) -> tuple[float, float, float, float]:
    """(ratio_pos, ratio_neg, vs, delta) of a Stribeck effect seen at the onsets ``ons``: the breakaway ratio of
    each direction where it has two onsets or more (else the common ``ratio``), the velocity that best
    reproduces the slips after the breakaways, the shape exponent 2."""
    ok = np.isfinite(ons["breakaway_ratio"])
    per = []
    for sgn in (1.0, -1.0):
        m = ok & (ons["sign"] == sgn)
        per.append(float(np.clip(np.exp(np.mean(np.log(ons["breakaway_ratio"][m]))), 1.0, MAX_BREAKAWAY_RATIO))
                   if m.sum() >= 2 else ratio)
    vs = slip_vs(ons["windows"], dt_s, ratio) or float(np.median(STRIBECK_VS_GRID_RAD_S))
    return per[0], per[1], float(vs), 2.0


def _plausible_all(des: Design, jd: JointData, terms: list[dict], passing: list[str], entries: dict, last: dict,
                   remaining: list[str]) -> list[str]:
    """The passing candidates that are plausible once fitted on all data (in the order given); the implausible
    ones are dropped from ``remaining`` with their reason in ``last``."""
    out = []
    for c in passing:
        fitted, theta = fit_all(des, jd, terms + [entries[c]["term"]])
        ok, why = plausible(des, c, jd, fitted, theta)
        if ok:
            out.append(c)
            continue
        last[c]["reason"] = why
        remaining.remove(c)
    return out


def _candidate_table(res: JointResult, tests: list[str], rejected: dict, last: dict, threshold: float) -> dict:
    """{candidate: its last test, whether it was kept and why (not)} of the joint."""
    out = {}
    kept_names = {t["name"] for t in res.kept}
    for c in tests:
        if c in rejected:
            out[c] = dict(last.get(c, UNTESTED), kept=False, reason=rejected[c])
        elif c not in last:
            out[c] = dict(UNTESTED, kept=False, reason="not testable on this joint")
        elif c in kept_names:
            ev = next(k["evidence"] for k in res.kept if k["name"] == c)
            out[c] = dict(ev, kept=True, reason="kept")
            if "head_to_head" in last[c]:
                out[c]["head_to_head"] = last[c]["head_to_head"]
        else:
            t = last[c]
            out[c] = dict(t, kept=False, reason=t.get("reason") or why_rejected(t, threshold))
    return out


def why_rejected(t: dict, threshold: float) -> str:
    """Why the nested test ``t`` does not keep its candidate."""
    if t["ssr_ratio"] >= 1:
        return "does not predict held-out data better than the model without it"
    if t["p_value"] >= threshold:
        return f"p = {t['p_value']:.3g} not below the threshold {threshold:.3g}"
    return f"BIC does not drop (delta {t['delta_bic']:.1f})"


def set_rms(res: JointResult) -> None:
    """Held-out torque RMS over the sliding samples and (once the onsets are analysed) the stalls."""
    for which in ("before", "after"):
        e = getattr(res, f"e_{which}")
        e = e[np.isfinite(e)]
        st = getattr(res, f"stall_{which}")
        both = np.concatenate([e, st]) if st is not None else e
        setattr(res, f"torque_rms_{which}_Nm", float(np.sqrt(np.mean(both ** 2))) if len(both) else float("nan"))


def set_after(des: Design, res: JointResult, jd: JointData, terms: list[dict], e_after: np.ndarray) -> None:
    """Refit the final model of a joint on all data and record the held-out figures."""
    spacing = max(1, 2 * des.sig.reach // des.decimation)
    fitted, theta = fit_all(des, jd, terms)
    res.kept = fitted
    res.theta_after = theta
    res.columns_after = [("friction", N_FRICTION)] + [(t["name"], ncols(t)) for t in fitted]
    res.e_after = e_after
    set_rms(res)
    res.whiteness_p_before = whiteness_p(res.e_before, spacing)
    res.whiteness_p_after = whiteness_p(e_after, spacing)


# ---------------------------------------------------------------------------------------------- plausible
def plausible(des: Design, name: str, jd: JointData, terms: list[dict], theta: np.ndarray) -> tuple[bool, str]:
    """Whether candidate ``name``, fitted on all data with ``terms`` (coefficients ``theta``), is a physical
    effect, and why not."""
    if name == "stribeck":
        if any(t["name"] == "stribeck" and isinstance(t.get("fixed_h"), tuple) for t in terms):
            return True, ""            # its levels were measured (and judged) where they were seen
        return _stribeck_plausible(jd, split_coefs(terms, theta))
    if name == "position_ripple":
        return _ripple_plausible(des, jd, terms)
    if name == "delay":
        return _delay_plausible(next(t["h_all"] for t in terms if t["name"] == "delay"), des.sig.dt_s)
    if name == "friction_drift":
        return _drift_plausible(des, jd, terms, theta)
    return True, ""


def _drift_plausible(des: Design, jd: JointData, terms: list[dict], theta: np.ndarray) -> tuple[bool, str]:
    """A friction drift changes the joint's friction torque by at least the minimum effect (5 %) over the run: a
    smaller trend is within the friction model's own accuracy (with a time constant far beyond the run, the two
    drift columns can otherwise follow any slow trend of a residual near the noise floor)."""
    c = split_coefs(terms, theta)
    T = float(next(t["h_all"] for t in terms if t["name"] == "friction_drift"))
    F = columns(des, "friction", jd, None)
    f0 = F @ levels(des.friction_given, jd.j, c["friction"])
    f1 = F @ drift_offset(c["friction_drift"], declared_levels(des, jd)) * -np.expm1(-des.sig.duration_s / T)
    size = float(np.linalg.norm(f1) / max(np.linalg.norm(f0), 1e-300))
    if size >= MIN_EFFECT:
        return True, ""
    return False, (f"the drift changes the friction torque by {size:.1%} over the run, less than the "
                   f"{MIN_EFFECT:.0%} a friction model is identified to")


def _stribeck_plausible(jd: JointData, c: dict) -> tuple[bool, str]:
    """A breakaway above the Coulomb level, by at most ``MAX_BREAKAWAY_RATIO``, in the directions seen."""
    coef = c["stribeck"]
    w = np.array([(jd.qd_rad_s > 0).sum(), (jd.qd_rad_s < 0).sum()], float)
    if (coef * w).sum() <= 0:
        return False, "fitted breakaway below the Coulomb level (not a Stribeck effect)"
    fc = c["friction"][:2]
    seen = w > 0
    ratio = (fc + coef)[seen] / np.maximum(fc[seen], 1e-9)
    if np.any(ratio > MAX_BREAKAWAY_RATIO):
        return False, (f"fitted breakaway {ratio.max():.3g} times the Coulomb level: beyond a physical "
                       f"Stribeck effect (at most {MAX_BREAKAWAY_RATIO:g})")
    return True, ""


def _ripple_plausible(des: Design, jd: JointData, terms: list[dict]) -> tuple[bool, str]:
    """Torque periodic in the angle is the same whichever way the joint turns; a periodic trace of the
    control loop (hunting at a speed-dependent frequency) is not."""
    i = [t["name"] for t in terms].index("position_ripple")
    h = float(terms[i]["h_all"][0])
    k = N_FRICTION + sum(ncols(t) for t in terms[:i])
    coefs = []                           # the sin/cos coefficients of every harmonic, per direction
    for m in (jd.qd_rad_s > 0, jd.qd_rad_s < 0):
        if m.sum() < 100 or np.ptp(jd.q_rad[m]) < h:
            continue
        y, X = target_and_design(des, jd, terms, None)
        th = fit_theta(X[m], y[m], des.bounded)
        coefs.append(th[k:k + ncols(terms[i])])
    if len(coefs) == 2:
        a0, a1 = (float(np.linalg.norm(c)) for c in coefs)
        if np.linalg.norm(coefs[0] - coefs[1]) > 0.5 * max(a0, a1):
            return False, (f"the ripple differs between the two directions of motion (amplitudes {a0:.3g} and "
                           f"{a1:.3g} N m): not a torque periodic in the angle")
    return _ripple_repeats(des, jd, terms, h)


ANGLE_FOLDS = 4


def _ripple_repeats(des: Design, jd: JointData, terms: list[dict], period: float) -> tuple[bool, str]:
    """A torque periodic in the angle repeats: fitted on part of the joint's range of angles, it predicts the rest
    better than the model without it. A smooth trend over the range (a link's mass or centre of mass off its
    declared value), which a sinusoid of a period close to the travel can follow, does not extrapolate to angles
    it was not fitted on.

    Over two periods of travel or more, the range is cut in up to ``ANGLE_FOLDS`` parts of a period or more and
    each is predicted from the others. Over ``RIPPLE_MIN_PERIODS`` to two periods, the angles beyond the first
    period from each end are predicted from that one period (what it predicts there is the torque one period
    away); one period determines a periodic torque, so there the ripple must also keep ``ENDS_RECOVERY`` of what
    it explains at those angles when fitted on the whole range (a trend followed by a sinusoid keeps much less)."""
    travel = float(np.ptp(jd.q_rad))
    if travel < RIPPLE_MIN_PERIODS * period * (1 + 1e-3):     # at the end of the periods searched, or beyond
        return False, (f"the joint's travel ({travel:.3g} rad) covers no more than {RIPPLE_MIN_PERIODS:g} periods of "
                       f"{period:.3g} rad: a torque periodic in the angle cannot be told from a trend over the range")
    folds = min(ANGLE_FOLDS, int(travel // period))
    q0, q1 = float(jd.q_rad.min()), float(jd.q_rad.max())
    if folds >= 2:
        edges = np.linspace(q0, q1, folds + 1)        # angle ranges of a period or more
        part = np.clip(np.searchsorted(edges, jd.q_rad, side="right") - 1, 0, folds - 1)
        held = [part == a for a in range(folds)]
    else:
        held = [jd.q_rad > q0 + period, jd.q_rad < q1 - period]
    ss = _angle_held_out(des, jd, terms, held)
    (ss1, ss0), (in1, in0) = ss["out"], ss["in"]
    if ss0 > 0 and ss1 >= ss0 * (1.0 - MIN_EFFECT):
        return False, (f"a ripple of period {period:.3g} rad fitted on part of the joint's range does not predict "
                       f"the rest (held-out angle ranges: {ss1 / ss0:.2f} of the residual without it): a trend "
                       "over the range, not a torque periodic in the angle")
    if folds < 2 and ss0 - ss1 < ENDS_RECOVERY * (in0 - in1):
        return False, (f"a ripple of period {period:.3g} rad fitted on one period of the joint's range explains "
                       f"{(ss0 - ss1) / max(in0 - in1, 1e-300):.2f} of what it explains at the other angles when "
                       "fitted on all of them: a trend over the range, not a torque periodic in the angle")
    return True, ""


ENDS_RECOVERY = 0.75


def _angle_held_out(des: Design, jd: JointData, terms: list[dict], held: list[np.ndarray]) -> dict:
    """Residual sums of squares over the angle ranges ``held`` of the model with the ripple and without it:
    ``out``: each range predicted by the models fitted on the other angles; ``in``: by the models fitted on all."""
    others = [t for t in terms if t["name"] != "position_ripple"]
    y1, X1 = target_and_design(des, jd, terms, None)
    y0, X0 = target_and_design(des, jd, others, None)
    th1, th0 = fit_theta(X1, y1, des.bounded), fit_theta(X0, y0, des.bounded)
    out, inside = np.zeros(2), np.zeros(2)
    for te in held:
        tr = ~te
        if te.sum() < 20 or tr.sum() < X1.shape[1] + 20:
            continue
        for k, (y, X, th) in enumerate(((y1, X1, th1), (y0, X0, th0))):
            r = y[te] - X[te] @ fit_theta(X[tr], y[tr], des.bounded)
            out[k] += float(r @ r)
            r = y[te] - X[te] @ th
            inside[k] += float(r @ r)
    return {"out": tuple(out), "in": tuple(inside)}


MIN_DELAY_S = 1.5e-3       # three quarters of a control period: below, the loop's own timing (ZOH, ticks)


def _delay_plausible(h: float, dt_s: float) -> tuple[bool, str]:
    """A delay inside the range searched and longer than the timing conventions of the loop and the log can
    account for (``MIN_DELAY_S``; at a log of the loop's rate or faster, one sample period)."""
    if h >= DELAY_GRID_S[-1] - 1e-12:
        return False, f"fitted delay at the end of the range searched ({h * 1e3:.1f} ms): not a delay"
    floor = max(MIN_DELAY_S, min(dt_s, 1.0 / P.CONTROL_RATE_HZ))
    if h < floor * (1 + 1e-9):
        return False, (f"fitted delay {h * 1e3:.1f} ms is not longer than {floor * 1e3:.1f} ms: within the "
                       "timing conventions of the control loop and the log")
    return True, ""
