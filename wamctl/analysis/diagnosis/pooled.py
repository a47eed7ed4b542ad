"""Several runs of one arm diagnosed together (no I/O): shared effects and link parameters, per-run friction.

A run that cannot tell (a payload seen by one joint's sweep, an effect barely above the noise) and the run
designed to decide (``next_experiment.yaml``) are pooled: every run is first diagnosed on its own
(:class:`~wamctl.analysis.diagnosis.estimator.ModelDiagnosis`), then the decisions that concern the arm are made
again on all runs stacked:

* each (run, joint) keeps **its own** columns: the classic friction (Coulomb and viscous per direction, so a
  friction that drifted between runs is fitted per run) and the joint-own effects that run kept; a run's gains
  and start state are its own (its closed loop, its log);
* **shared** by every run: the arm's payload (ten inertial parameters), the arm's link errors (the base
  parameters of the rigid body, :mod:`wamctl.analysis.diagnosis.rigid`), and the coefficients of a joint-own
  effect (Stribeck, ripple, drift, dead band) kept at that joint in some run, with the shape parameter the run
  with the strongest evidence chose.

Held-out figures: each run's own folds of time blocks, the shared part fitted without the fold in every run at
once. Every decision is also made on each run alone (the same statistic, its rows only) and, from three runs
on, without each run, so that the result says which run decided what and which run added nothing.
"""

from __future__ import annotations

from dataclasses import dataclass
from types import SimpleNamespace

import numpy as np

from wamctl.analysis.diagnosis.arm import N_PAYLOAD, PAYLOAD_COM_BOX_M, payload_intervals
from wamctl.analysis.diagnosis.candidates import payload_from_pi
from wamctl.analysis.diagnosis.crossval import unpredictable
from wamctl.analysis.diagnosis.design import FRICTION_KEYS, columns, levels, ncols, target_and_design
from wamctl.analysis.diagnosis.stats import MIN_EFFECT, lstsq, nested_test
from wamctl.errors import DataFormatError

JOINT_OWN = ("stribeck", "position_ripple", "friction_drift", "backlash")
KEY = 10            # pooled key of (run r, 0-based joint j): KEY * r + j


class PoolingError(DataFormatError):
    """Runs that cannot be pooled (another arm, a run given twice); the message is one line."""


# ------------------------------------------------------------------------------------------------ the arm
def arm_identity(meta, truth: dict | None) -> dict:
    """What makes a run's arm: the robot, the arm a log names (``arm`` in meta.yaml, e.g. a serial number), the
    payload it declares it carries, and for a run of the simulated arm the plant's links and friction."""
    extra = meta.model_extra or {}
    p = meta.payload
    out = {"robot": meta.robot, "arm": extra.get("arm"),
           "declared payload": None if p is None or p.mass_kg <= 0 else (round(p.mass_kg, 6),
                                                                          tuple(round(c, 6) for c in p.com_m))}
    if truth:
        out["simulated plant links"] = truth.get("links")
        out["simulated plant friction"] = truth.get("friction")
    return out


def different_arm(metas: list, truths: list, labels: list[str]) -> str | None:
    """Why the runs are not of one arm (one line), or None."""
    ids = [arm_identity(m, t) for m, t in zip(metas, truths)]
    for k in ids[0]:
        vals = [i[k] for i in ids]
        if k.startswith("simulated") and any(not t for t in truths):
            continue
        if k == "arm" and any(v is None for v in vals):
            continue
        if any(v != vals[0] for v in vals[1:]):
            seen = ", ".join(f"{lab}: {v}" for lab, v in zip(labels, vals))
            return f"runs of different arms cannot be pooled: {k} differs ({seen})"
    return None


# ------------------------------------------------------------------------------------------------ stacks
@dataclass
class _Member:
    """One (run, joint) of the stack."""

    key: int
    r: int
    j: int
    des: object
    jd: object
    res: object


def _members(diags: list) -> list[_Member]:
    out = []
    for r, d in enumerate(diags):
        if not d.conclusive_:
            continue
        for j, res in sorted(d.joints_.items()):
            out.append(_Member(KEY * r + j, r, j, d.design_, d.jd_[j], res))
    return out


def _own_terms(res, drop=("payload", "link_parameters"), delay: dict | None = None) -> list[dict]:
    """A member's kept terms but ``drop`` (its friction stays its own: a drift between runs); with ``delay`` (the
    delay the runs pooled decided, a term) that delay in place of the run's own."""
    if delay is None:
        return [t for t in res.kept if t["name"] not in drop]
    return [t for t in res.kept if t["name"] not in drop + ("delay",)] + [delay]


def _stack_cv(ms: list[_Member], own: dict, shared: dict, w: dict, n_folds: int):
    """Held-out residuals {key: (m,)} of every member's own columns plus ``shared`` columns ({key: (m, s)}, one
    coefficient vector for all members; empty: none), fitted without each fold in every run at once; the
    coefficients on all data (own blocks then shared) and the stacked system ``(X, y, w_rows, groups)``."""
    keys = [m.key for m in ms]
    p_own = {k: own[k][1].shape[1] for k in keys}
    s = next(iter(shared.values())).shape[1] if shared else 0
    n_own = sum(p_own.values())
    X = np.zeros((sum(len(own[k][0]) for k in keys), n_own + s))
    y, wr, groups, fold = [], [], [], []
    r0, c0 = 0, 0
    for m in ms:
        yk, Xk = own[m.key]
        n = len(yk)
        X[r0:r0 + n, c0:c0 + p_own[m.key]] = Xk
        if s:
            X[r0:r0 + n, n_own:] = shared[m.key]
        y.append(yk)
        wr.append(np.full(n, w[m.key]))
        groups.append(np.column_stack([np.full(n, m.key), m.jd.extra["block"]]))
        fold.append(m.jd.fold)
        r0 += n
        c0 += p_own[m.key]
    y, wr, groups, fold = np.concatenate(y), np.concatenate(wr), np.vstack(groups), np.concatenate(fold)
    ok = np.isfinite(y) & np.isfinite(X).all(axis=1)
    Xw, yw = X * wr[:, None], y * wr
    e = np.full(len(y), np.nan)
    for f in range(n_folds):
        tr, te = ok & (fold != f), ok & (fold == f)
        if te.any() and tr.sum() > X.shape[1]:
            e[te] = y[te] - X[te] @ lstsq(Xw[tr], yw[tr])
    out, r0 = {}, 0
    for m in ms:        # samples a fit without the fold cannot predict (speeds never trained on) left out
        n = len(own[m.key][0])
        ek = e[r0:r0 + n]
        for f in range(n_folds):
            te = np.flatnonzero(m.jd.fold == f)
            ek[unpredictable(m.jd, np.flatnonzero(m.jd.fold != f), te)] = np.nan
        out[m.key] = ek
        r0 += n
    theta = lstsq(Xw[ok], yw[ok])
    return out, theta, (X[ok], y[ok], wr[ok], groups[ok])


def _test(ms, e0: dict, e1: dict, w: dict, p_extra: int, k1: int, min_effect: float = MIN_EFFECT) -> dict:
    """Nested test of the weighted held-out residuals ``e1`` against ``e0`` over the members ``ms``."""
    keys = [m.key for m in ms]
    a = np.concatenate([e0[k] * w[k] for k in keys])
    b = np.concatenate([e1[k] * w[k] for k in keys])
    g = np.concatenate([m.jd.fold + 100 * m.key for m in ms])
    t = nested_test(a, b, p_extra, k1, min_effect, g)
    return {k: float(t[k]) for k in ("p_value", "delta_bic", "F", "n", "n_eff", "ssr_ratio")}


def _passes(t: dict | None, threshold: float) -> bool:
    return t is not None and t["p_value"] < threshold and t["delta_bic"] < 0


def _subsets(runs: list[int], labels: list[str]) -> dict:
    """{name: runs} of the stacks every decision is made on: pooled, each run alone (``<label> alone``), and
    without each run (``without <label>``, from three runs on)."""
    out = {"pooled": runs}
    for r in runs:
        out[alone_key(labels[r])] = [r]
    if len(runs) >= 3:
        for r in runs:
            out[without_key(labels[r])] = [x for x in runs if x != r]
    return out


def alone_key(label: str) -> str:
    return f"{label} alone"


def without_key(label: str) -> str:
    return f"without {label}"


# ------------------------------------------------------------------------------------------------ the estimator
def effects_in_order(findings: list[dict]) -> list[str]:
    """The names of the findings named pooled, smallest pooled p-value first; a finding the pooled test did not
    name (an effect seen at the onsets only, p-value None, or kept on another basis: a Stribeck effect a run named
    at the breakaways) after those, smallest p-value of the run that named it first (``run_p_value``): its pooled
    p-value is not what named it."""
    found = [f for f in findings if f["pooled"]["named"]]

    def key(f):
        p = f["pooled"]["p_value"]
        if p is not None and "basis" not in f["pooled"]:
            return (0, p)
        return (1, f.get("run_p_value", 1.0))
    found.sort(key=key)
    return list(dict.fromkeys(f["name"] for f in found))


class PooledDiagnosis:
    """Diagnose several runs of one arm together.

    ``diagnoses`` are the runs' own :class:`~wamctl.analysis.diagnosis.estimator.ModelDiagnosis`, fitted, in
    order; ``labels`` name the runs (their directories). Attributes after :meth:`fit`: ``effects_found_``
    (strongest evidence first), ``ambiguous_``, ``findings_`` (each decision per stack), ``payload_``,
    ``friction_``, ``runs_``, ``conclusive_``, ``reason_``."""

    def __init__(self, diagnoses: list, labels: list[str], datas: list):
        self.diags = diagnoses
        self.labels = labels
        self.datas = datas

    def fit(self) -> PooledDiagnosis:
        from wamctl.analysis.blas import single_threaded_blas

        why = different_arm([d.meta for d in self.datas], [d.truth for d in self.datas], self.labels)
        if why:
            raise PoolingError(why)
        with single_threaded_blas():
            return self._fit()

    def _fit(self) -> PooledDiagnosis:
        diags = self.diags
        self.runs_ = [self._run_summary(r) for r in range(len(diags))]
        self.effects_found_, self.ambiguous_, self.findings_ = [], [], []
        self.payload_, self.friction_, self.payload_or_links_ = None, {}, None
        ms = _members(diags)
        runs = sorted({m.r for m in ms})
        self.conclusive_ = bool(runs)
        self.reason_ = None if runs else "no run could be diagnosed: " + "; ".join(
            f"{lab}: {d.reason_}" for lab, d in zip(self.labels, diags))
        if not runs:
            return self
        self.n_folds = diags[runs[0]].n_folds
        self.threshold_ = min(diags[r].threshold_ for r in runs)
        self.w_ = {}
        for m in ms:
            e = m.res.e_after
            self.w_[m.key] = 1.0 / max(float(np.sqrt(np.nanmean(e ** 2))) if np.isfinite(e).any() else 1.0, 1e-9)
        self.delay_term_ = None
        self._delay_or_inertia(runs)        # first: a delay decided is every run's own model's in what follows
        self._arm(ms, runs)
        self._joint_effects(ms, runs)
        self._joint_ambiguities(ms, runs)
        self._friction(ms, runs)
        self.effects_found_ = effects_in_order(self.findings_)
        return self

    # -------------------------------------------------------------------------------- runs
    def _run_summary(self, r: int) -> dict:
        d, data = self.diags[r], self.datas[r]
        meta = data.meta
        gains = getattr(d, "gains_", None)
        if gains and gains.get("kp") is not None:
            kp, kd, src = gains["kp"], gains["kd"], gains.get("source") or "estimated from the log"
        else:
            kp, kd, src = meta.controller.kp, meta.controller.kd, "as the run's meta.yaml gives them"
        return {"label": self.labels[r], "run": r, "robot": meta.robot,
                "q0_rad": [None if v is None else float(v) for v in meta.q0],
                "joints_diagnosed": [j + 1 for j in sorted(d.joints_)] if d.conclusive_ else [],
                "samples": int(len(data.data)), "controller": {"kind": meta.controller.kind, "kp": kp, "kd": kd,
                                                               "source": src},
                "alone": {"conclusive": bool(d.conclusive_), "reason": d.reason_,
                          "effects_found": list(d.effects_found_),
                          "ambiguous": [list(g) for g in getattr(d, "ambiguous_", [])],
                          "payload_or_links": (getattr(d, "payload_vs_links_", None) or {}).get("outcome")}}

    # -------------------------------------------------------------------------------- the arm: payload or links
    def _arm(self, ms: list[_Member], runs: list[int]) -> None:
        from wamctl.analysis.diagnosis.links import WIDE_PRIOR, _excited_rank, payload_excess_floors, payload_outcome
        from wamctl.analysis.diagnosis.rigid import (
            arm_cv,
            arm_system,
            determined_parameters,
            payload_cone,
            payload_map,
            plausible_link_map,
        )

        ms = [m for m in ms if "links_base" in m.jd.extra]
        if not ms:
            return
        d0 = self.diags[runs[0]]
        link_map = plausible_link_map(d0.declared_.links, d0.payload_declared_)
        own = {m.key: target_and_design(m.des, m.jd, _own_terms(m.res, delay=self.delay_term_), None)
               for m in ms}
        jds = {m.key: m.jd for m in ms}
        cone, rays = payload_cone(PAYLOAD_COM_BOX_M)
        nl, nc = link_map.shape[1], cone.shape[1]
        pos = (np.zeros(nc), np.full(nc, np.inf))
        stacks = {}
        for label, rs in _subsets(sorted({m.r for m in ms}), self.labels).items():
            sub = [m for m in ms if m.r in rs]
            sys_ = arm_system(SimpleNamespace(n_folds=self.n_folds), jds, {m.key: own[m.key] for m in sub},
                              {m.key: 1.0 for m in sub})
            e_own, _, _ = arm_cv(sys_, jds, None)
            sys_.w = {m.key: 1.0 / max(float(np.sqrt(np.nanmean(e_own[m.key] ** 2))), 1e-9) for m in sub}
            k_own = sum(own[m.key][1].shape[1] for m in sub)
            p_pay = max(_excited_rank(jds, [m.key for m in sub], payload_map()[:, :4]), 1)
            tests, e_links, excess = {}, None, {}
            for name, scale in (("links", 1.0), ("wide_links", WIDE_PRIOR)):
                lim = np.full(nl, scale)
                e_l = arm_cv(sys_, jds, link_map, (-lim, lim))[0]
                e_pl = arm_cv(sys_, jds, np.hstack([cone, link_map]), (np.r_[pos[0], -lim], np.r_[pos[1], lim]))[0]
                if e_links is None:
                    e_links, excess = e_l, payload_excess_floors(e_l, e_pl)
                t = _test(sub, e_l, e_pl, sys_.w, p_pay, k_own + p_pay)
                t["passes"] = _passes(t, self.threshold_)
                tests["beyond_" + name] = t
                if not t["passes"]:
                    break
            outcome = payload_outcome({k: t["passes"] for k, t in tests.items()}, excess)
            # is there anything rigid-body at all? link errors within the declared accuracy against the own models
            rank = max(determined_parameters(sys_)[1], 1)
            t_any = _test(sub, e_own, e_links, sys_.w, rank, k_own + rank)
            t_any["passes"] = _passes(t_any, self.threshold_)
            if outcome == "link_parameters" and not t_any["passes"]:
                outcome = "none"
            stacks[label] = {"runs": [self.labels[r] for r in rs], "outcome": outcome, "tests": tests,
                             "excess_noise_floors": {f"{self.labels[k // KEY]} joint {k % KEY + 1}": v
                                                     for k, v in excess.items()},
                             "rigid_body_beyond_own_models": t_any, "payload_combinations_seen": int(p_pay)}
            if outcome == "payload" or label == "pooled" or len(rs) == 1:
                stacks[label]["payload"] = self._payload_estimate(sub, own, sys_.w)
        self.payload_or_links_ = stacks
        if all(st["outcome"] == "none" for st in stacks.values()):
            return              # nothing rigid-body to decide, pooled or in any run
        pooled = stacks["pooled"]
        outcome = pooled["outcome"]
        if outcome == "payload":
            self.payload_ = pooled["payload"]
        if outcome == "ambiguous":
            self.ambiguous_.append(["link_parameters", "payload"])
        name = {"payload": "payload", "link_parameters": "link_parameters"}.get(outcome)
        per = {}
        for label, st in stacks.items():
            tt = st["tests"].get("beyond_wide_links") or st["tests"]["beyond_links"]
            if outcome == "link_parameters":
                tt = st["rigid_body_beyond_own_models"]
            per[label] = {"outcome": st["outcome"], "p_value": tt["p_value"], "delta_bic": tt["delta_bic"],
                          "ssr_ratio": tt["ssr_ratio"],
                          "named": st["outcome"] == outcome and outcome in ("payload", "link_parameters"),
                          "not_identified": (st.get("payload") or {}).get("not_identified")}
        finding = {"name": name or "payload_or_links", "joint": None, "what": "the arm: a wrist payload or its own "
                   "link parameters (shared by every run)",
                   "pooled": dict(per["pooled"], named=name is not None),
                   "per_stack": {k: v for k, v in per.items() if k != "pooled"}}
        finding["decided_by"], finding["added_nothing"] = self._who_decided(finding, runs, payload=True)
        self.findings_.append(finding)

    def _payload_estimate(self, sub: list[_Member], own: dict, w: dict) -> dict:
        """The arm's payload fitted over the members ``sub`` (shared ten inertial parameters, each member's own
        columns): mass and centre of mass with 95 % intervals (a bootstrap over every member's time blocks, widened
        by the declared links' systematic share) and what these runs cannot determine."""
        from wamctl.analysis.diagnosis.uncertainty import estimable, group_bootstrap

        shared = {m.key: m.jd.extra["payload"] for m in sub}
        _, theta, (X, y, wr, groups) = _stack_cv(sub, own, shared, w, self.n_folds)
        n_own = X.shape[1] - N_PAYLOAD
        ok = estimable(X * wr[:, None], [n_own + k for k in range(4)])
        est = payload_from_pi(theta[n_own:])
        reps = group_bootstrap(X, y, groups, rng=np.random.default_rng(6000), w=wr)
        ests = [payload_from_pi(pi) for pi in reps[:, n_own:]]
        ci, ni = payload_intervals(est, ests, len(np.unique(groups, axis=0)), ok)
        params = {"mass_kg": est["mass_kg"], "com_x_m": est["com_m"][0], "com_y_m": est["com_m"][1],
                  "com_z_m": est["com_m"][2]}
        for k in ni:                # what these runs cannot determine: no number (nor interval)
            params[k] = None
        return {"params": params, "params_ci": ci, "not_identified": ni}

    # -------------------------------------------------------------------------------- joint-own effects
    def _joint_effects(self, ms: list[_Member], runs: list[int]) -> None:
        """Each joint-own effect kept at a joint in some run, tested on that joint in every run that diagnosed it,
        with the shape the run with the strongest evidence chose: its columns' coefficients shared by the runs, or
        (a Stribeck effect measured at the breakaways or on the friction map, which shapes the friction columns)
        each run's friction levels shaped alike. A run's own naming is recorded beside each statistic; an effect
        whose evidence is at the onsets only (a dead band behind a motor-side encoder) is not tested again: it
        stays named from the runs that named it, and says so."""
        wanted = {}
        for m in ms:
            for t in m.res.kept:
                if t["name"] in JOINT_OWN:
                    p = float(t["evidence"].get("p_value", 1.0))
                    if (m.j, t["name"]) not in wanted or p < wanted[(m.j, t["name"])][0]:
                        wanted[(m.j, t["name"])] = (p, m.r, t)
        for (j, name), (_, r_best, term) in sorted(wanted.items()):
            sub_all = [m for m in ms if m.j == j]
            named_alone = {m.r: any(t["name"] == name for t in m.res.kept) for m in sub_all}
            shaped = ncols(term) == 0 and name == "stribeck"
            onsets_only = ncols(term) == 0 and not shaped
            own, own1, shared = {}, {}, {}
            for m in sub_all:
                terms = _own_terms(m.res, ("payload", "link_parameters", name), self.delay_term_)
                own[m.key] = target_and_design(m.des, m.jd, terms, None)
                if shaped:
                    own1[m.key] = target_and_design(m.des, m.jd, terms + [term], None)
                elif not onsets_only:
                    shared[m.key] = columns(m.des, name, m.jd, term["h_all"])
            per = {}
            for label, rs in _subsets(sorted({m.r for m in sub_all}), self.labels).items():
                sub = [m for m in sub_all if m.r in rs]
                alone = {"named_by_the_run_alone": named_alone[rs[0]]} if len(rs) == 1 else {}
                if onsets_only:
                    per[label] = dict(alone, p_value=None, delta_bic=None, ssr_ratio=None,
                                      named=any(named_alone[r] for r in rs))
                    continue
                e0, _, _ = _stack_cv(sub, own, {}, self.w_, self.n_folds)
                if shaped:          # ratio per direction and Stribeck velocity
                    e1, _, _ = _stack_cv(sub, own1, {}, self.w_, self.n_folds)
                    p_extra = 3
                else:
                    e1, _, _ = _stack_cv(sub, own, {m.key: shared[m.key] for m in sub}, self.w_, self.n_folds)
                    p_extra = shared[sub[0].key].shape[1] + (0 if name == "backlash" else 1)
                k1 = sum(own[m.key][1].shape[1] for m in sub) + p_extra
                t = _test(sub, e0, e1, self.w_, p_extra, k1)
                per[label] = dict(t, named=_passes(t, self.threshold_), **alone)
            how = ("its evidence is at the onsets only: not tested again, named from the runs that named it"
                   if onsets_only else "each run's friction levels shaped alike" if shaped else
                   "coefficients shared by every run")
            finding = {"name": name, "joint": j + 1, "run_p_value": wanted[(j, name)][0],
                       "what": f"joint {j + 1}: {name} (shape from {self.labels[r_best]}; {how})",
                       "pooled": per["pooled"], "per_stack": {k: v for k, v in per.items() if k != "pooled"}}
            at_onsets = [self.labels[m.r] for m in sub_all for t in m.res.kept
                         if t["name"] == name and "breakaways" in t.get("seen", "")]
            if shaped and not per["pooled"]["named"] and at_onsets:
                # the breakaways decided it in a run that named it (seen "at the breakaways" in the selection, or
                # "breakaways" when added from the onsets after it); the sliding samples pooled do not contradict
                # it unless they say so: kept, with why
                finding["pooled"] = dict(per["pooled"], named=True, basis=(
                    f"named at the breakaways by {', '.join(at_onsets)}; "
                    "the sliding samples pooled do not show it on their own"))
            if name == "backlash" and onsets_only and per["pooled"]["named"] and self.delay_term_ is not None:
                self._gap_or_delay(finding, j, runs)
            finding["decided_by"], finding["added_nothing"] = self._who_decided(finding, runs)
            self.findings_.append(finding)

    def _gap_or_delay(self, finding: dict, j: int, runs: list[int]) -> None:
        """A gap behind a motor-side encoder named from a run's onsets while the runs pooled named a delay: both
        make the measurement part from the model's link where the joint starts again, and the delay is the arm's
        (one for all runs): the onsets of every run that diagnosed the joint decide between them with that delay
        (:func:`~wamctl.analysis.diagnosis.delay_backlash.pooled_head_to_head`). A name kept from one run gives
        way when the runs pooled prefer the delay very strongly (:data:`~wamctl.analysis.diagnosis.delay_backlash.
        OVERTURN_LOG_RATIO`); recorded under ``delay_vs_gap``."""
        from wamctl.analysis.diagnosis.delay_backlash import OVERTURN_LOG_RATIO, pooled_head_to_head

        h2h = pooled_head_to_head([self.diags[r] for r in runs], [self.labels[r] for r in runs], j,
                                  float(self.delay_term_["h_all"]))
        finding["delay_vs_gap"] = h2h
        if h2h["log_ratio"] <= -OVERTURN_LOG_RATIO:
            finding["pooled"] = dict(finding["pooled"], named=False, basis=(
                f"the {h2h['delay_s'] * 1e3:.1f} ms delay named pooled explains the onsets of joint {j + 1} better "
                f"than a gap (n log(RSS ratio) {h2h['log_ratio']:+.1f} over the runs' onsets stacked, "
                f"{-OVERTURN_LOG_RATIO:g} overturns a run's name)"))

    # -------------------------------------------------------------------------------- ambiguous joint-own groups
    def _joint_ambiguities(self, ms: list[_Member], runs: list[int]) -> None:
        """A group of joint-own effects some run left ambiguous at a joint (neither explained its residual clearly
        better than the other, e.g. a friction drift and a Stribeck effect) decided again on every run that
        diagnosed the joint, stacked: the same head to head as one run's (:mod:`~wamctl.analysis.diagnosis.
        headtohead`), each member's columns shared by the runs (a drift starting again with each run), each (run,
        joint) its own friction and other effects. ``a`` wins when it adds to the model with ``b`` and ``b`` does
        not add to the model with ``a``: ``b``'s finding is then not named (and ``a``'s named, with a finding of
        its own when no run kept it); neither adding beyond the other keeps the group ambiguous (neither named);
        both adding leaves each member's own finding. The record goes to ``head_to_head`` of the findings."""
        from wamctl.analysis.diagnosis.headtohead import p_extra
        from wamctl.analysis.diagnosis.stats import finite_ss

        groups = {}
        for m in ms:
            for g in m.res.ambiguous:
                names = tuple(sorted(g["names"]))
                if len(names) == 2 and all(n in JOINT_OWN for n in names):
                    groups.setdefault((m.j, names), m)
        for (j, (a, b)), m0 in sorted(groups.items(), key=lambda x: (x[0][0], x[0][1])):
            sub = [m for m in ms if m.j == j]
            terms = {n: self._group_term(sub, m0, n, (a, b)) for n in (a, b)}
            if any(t is None or (ncols(t) == 0 and not (n == "stribeck" and isinstance(t.get("fixed_h"), tuple)))
                   for n, t in terms.items()):
                continue        # a member seen at the onsets only: no sliding-sample head to head
            systems = {}
            for key, names in (("own", ()), ("a", (a,)), ("b", (b,)), ("ab", (a, b))):
                own, shared = {}, {}
                for m in sub:
                    base = _own_terms(m.res, ("payload", "link_parameters", a, b), self.delay_term_)
                    shaped = [terms[n] for n in names if ncols(terms[n]) == 0]
                    own[m.key] = target_and_design(m.des, m.jd, base + shaped, None)
                    cols = [columns(m.des, n, m.jd, terms[n]["h_all"]) for n in names if ncols(terms[n]) > 0]
                    if cols:
                        shared[m.key] = np.hstack(cols)
                e, _, _ = _stack_cv(sub, own, shared, self.w_, self.n_folds)
                k = sum(own[m.key][1].shape[1] for m in sub) + (next(iter(shared.values())).shape[1] if shared else 0)
                systems[key] = (e, k)

            def ss(e, sub=sub):
                return sum(finite_ss(e[m.key] * self.w_[m.key]) for m in sub)

            e_own, e_ab, k_ab = systems["own"][0], *systems["ab"]
            tests = {}
            for x, y in ((a, b), (b, a)):       # does x add to the model with y?
                e_y = systems["b" if y == b else "a"][0]
                share = ss(e_own) / max(ss(e_y), 1e-300)
                t = _test(sub, e_y, e_ab, self.w_, p_extra(x, terms[x]), k_ab, min(MIN_EFFECT * share, 0.9))
                tests[x] = dict(t, named=_passes(t, self.threshold_))
            a_adds, b_adds = tests[a]["named"], tests[b]["named"]
            outcome = {(True, False): a, (False, True): b, (True, True): "both",
                       (False, False): "ambiguous"}[(a_adds, b_adds)]
            record = {"vs": [a, b], "outcome": outcome, f"{a}_beyond_{b}": tests[a], f"{b}_beyond_{a}": tests[b],
                      "left_ambiguous_by": sorted({self.labels[m.r] for m in sub
                                                   if any(sorted(g["names"]) == [a, b] for g in m.res.ambiguous)})}
            found = {f["name"]: f for f in self.findings_ if f["joint"] == j + 1 and f["name"] in (a, b)}
            if outcome == "ambiguous":
                self.ambiguous_.append([a, b])
                for f in found.values():
                    f["pooled"] = dict(f["pooled"], named=False, basis=(
                        f"ambiguous with {b if f['name'] == a else a} on the runs pooled: neither adds to the model "
                        "with the other"))
            elif outcome in (a, b):
                loser = b if outcome == a else a
                if loser in found:
                    found[loser]["pooled"] = dict(found[loser]["pooled"], named=False, basis=(
                        f"{outcome} explains it on the runs pooled: {loser} adds nothing beyond {outcome}"))
                if outcome not in found:
                    t_w = systems["a" if outcome == a else "b"]
                    t = _test(sub, e_own, t_w[0], self.w_, p_extra(outcome, terms[outcome]), t_w[1])
                    found[outcome] = {"name": outcome, "joint": j + 1,
                                      "what": f"joint {j + 1}: {outcome} (left ambiguous with {loser} by "
                                              f"{', '.join(record['left_ambiguous_by'])}; decided pooled)",
                                      "pooled": dict(t, named=_passes(t, self.threshold_)), "per_stack": {},
                                      "decided_by": [self.labels[r] for r in runs], "added_nothing": []}
                    self.findings_.append(found[outcome])
            for f in found.values():
                f["head_to_head"] = record

    def _group_term(self, sub: list[_Member], m0: _Member, name: str, group: tuple) -> dict | None:
        """The term of effect ``name`` at a joint: as kept by the run with the strongest evidence for it, else
        fitted on the run ``m0`` that left it ambiguous (its shape chosen as the diagnosis chooses it, beside that
        run's other kept effects)."""
        from wamctl.analysis.diagnosis.crossval import cv_residual, fit_all

        kept = [(float(t["evidence"].get("p_value", 1.0)), t) for m in sub for t in m.res.kept if t["name"] == name]
        if kept:
            return min(kept, key=lambda x: x[0])[1]
        others = _own_terms(m0.res, ("payload", "link_parameters") + group, self.delay_term_)
        _, h_fold = cv_residual(m0.des, m0.jd, others, name)
        fitted, _ = fit_all(m0.des, m0.jd, others + [{"name": name, "h_fold": h_fold}])
        return next(t for t in fitted if t["name"] == name)

    # -------------------------------------------------------------------------------- a delay or inertia errors
    def _delay_or_inertia(self, runs: list[int]) -> None:
        """A measurement delay against joint inertia errors (:func:`~wamctl.analysis.diagnosis.delay_inertia.
        decide_pooled`): the delay one for all runs, each run's own friction and offset per joint; made when some
        run's own diagnosis named a delay or left it ambiguous (:func:`~wamctl.analysis.diagnosis.delay_inertia.
        leaves_room`) and some run's residual holds an effect either explains (by at least a noise floor beyond
        friction). The finding is named ``delay`` or ``inertia`` when decided, ``delay_or_inertia`` (ambiguous)
        when not."""
        from wamctl.analysis.diagnosis import delay_inertia as DI
        from wamctl.model.dynamics import WamDynamics

        if not any(DI.leaves_room(self.diags[r], unexplained=False) for r in runs):
            return      # no run named a delay or left it ambiguous (a residual one run leaves unexplained may be
                        # what another names: a payload moved by one joint looks like that joint's inertia)
        parts, suspected = [], False
        for r in runs:
            d = self.diags[r]
            chk = DI.check_run(d, WamDynamics(d.payload_declared_, d.declared_.links))
            if not chk.rows.joints:
                continue
            suspected |= chk.suspected
            parts.append(DI.RunPart(self.labels[r], chk.rows, chk.y, chk.decision,
                                    named="delay" if "delay" in d.effects_found_ else None))
        if not suspected:
            return
        d0 = self.diags[runs[0]]
        dec = DI.decide_pooled(parts, d0.n_blocks, d0.n_folds)
        out = dec["outcome"]
        if out == "delay" and not any(p["excess_noise_floors"] >= DI.DECIDED_FLOORS for p in dec["per_run"]):
            out = dec["outcome"] = self._delay_kept_or_gap(dec, runs)
        if out == "delay":
            d = float(dec["delay_s"])
            self.delay_term_ = {"name": "delay", "h_all": d, "h_fold": [d] * self.n_folds, "shared": True}
        if out == "ambiguous":
            self.ambiguous_.append(["backlash", "delay"] if "gave_way_to" in dec else ["delay", "inertia"])
        t = dec["test"]
        per = {}
        for p in dec["per_run"]:        # each run alone: its own decision (no nested test: the two do not nest)
            a = p["alone"]
            per[alone_key(p["label"])] = {"outcome": a["outcome"], "p_value": None, "delta_bic": None,
                                          "ssr_ratio": None, "named": a["outcome"] == out != "ambiguous",
                                          "named_by_the_run_alone": a["outcome"] != "ambiguous",
                                          "excess_noise_floors": a["excess_noise_floors"]}
        self.findings_.append({
            "name": out if out != "ambiguous" else "delay_or_inertia", "joint": None,
            "what": "the arm: a measurement delay (one for all runs) or joint inertia errors (shared by the runs), "
                    "each run's own friction and offset",
            "pooled": {"outcome": out, "p_value": t["p_value"], "delta_bic": t["delta_bic"],
                       "ssr_ratio": t["ssr_ratio"], "named": out != "ambiguous"},
            "per_stack": per, "decided_by": dec["decided_by"], "added_nothing": dec["added_nothing"],
            "delay_or_inertia": dec})

    def _delay_kept_or_gap(self, dec: dict, runs: list[int]) -> str:
        """A delay kept pooled only because a run named it (:func:`~wamctl.analysis.diagnosis.delay_inertia.
        decide_pooled`'s keep rule: no run's evidence decided it) gives way where some run kept a gap behind a
        motor-side encoder and the onsets of the runs pooled, with the delay fitted pooled, prefer the gap very
        strongly (:data:`~wamctl.analysis.diagnosis.delay_backlash.OVERTURN_LOG_RATIO`)
        (:func:`~wamctl.analysis.diagnosis.delay_backlash.pooled_head_to_head`): ``"ambiguous"``, with
        ``gave_way_to`` in the record; else ``"delay"``."""
        from wamctl.analysis.diagnosis.delay_backlash import (
            OVERTURN_LOG_RATIO,
            motor_gap_joints,
            pooled_head_to_head,
        )

        gaps = sorted({j for r in runs for j in motor_gap_joints(self.diags[r])})
        for j in gaps:
            h2h = pooled_head_to_head([self.diags[r] for r in runs], [self.labels[r] for r in runs], j,
                                      float(dec["fitted_delay_s"]))
            if h2h["log_ratio"] >= OVERTURN_LOG_RATIO:
                dec["gave_way_to"] = dict(h2h, name="backlash")
                dec["decided_by"] = []
                return "ambiguous"
        return "delay"

    def _who_decided(self, finding: dict, runs: list[int], payload: bool = False) -> tuple[list[str], list[str]]:
        """The runs that decided a finding (alone named as pooled, or needed for it: without them the pooled
        result is not reached), and those that added nothing (the result without them is the same)."""
        pooled, per = finding["pooled"], finding["per_stack"]

        def same(st):
            if st is None:
                return False
            if st["named"] != pooled["named"] or st.get("outcome") != pooled.get("outcome"):
                return False
            return not payload or sorted(st.get("not_identified") or []) == sorted(pooled.get("not_identified")
                                                                                  or [])

        decided, nothing = [], []
        for r in runs:
            alone = per.get(alone_key(self.labels[r]))
            if len(runs) == 1:
                return [self.labels[r]], []
            without = per.get(without_key(self.labels[r])) if len(runs) >= 3 else \
                per.get(alone_key(self.labels[next(x for x in runs if x != r)]))
            if alone is None:       # the run did not diagnose this joint
                nothing.append(self.labels[r])
            elif same(alone) and pooled["named"] or not same(without):
                decided.append(self.labels[r])
            elif same(without):
                nothing.append(self.labels[r])
        return decided, nothing

    # -------------------------------------------------------------------------------- per-run friction
    def _friction(self, ms: list[_Member], runs: list[int]) -> None:
        """Each run's classic friction per joint, fitted in the pooled stack of that joint (its own levels, the
        shared effects named there), with 95 % intervals; and the change from the first run (drift between runs)."""
        from wamctl.analysis.diagnosis.uncertainty import group_bootstrap, percentile_ci

        named = {(f["joint"], f["name"]) for f in self.findings_ if f["pooled"]["named"] and f["joint"]}
        for j in sorted({m.j for m in ms}):
            sub = [m for m in ms if m.j == j]
            own, shared = {}, {}
            for m in sub:
                terms = _own_terms(m.res, ("payload", "link_parameters") + JOINT_OWN, self.delay_term_)
                for (jj, name) in sorted(named):        # the joint's effects named pooled, in every run's model
                    t = next((t for mm in sub for t in mm.res.kept if t["name"] == name), None) \
                        if jj == j + 1 else None
                    if t is not None:
                        terms = terms + [t]
                own[m.key] = target_and_design(m.des, m.jd, terms, None)
                if self.payload_ is not None:
                    shared[m.key] = m.jd.extra.get("payload")
            if any(v is None for v in shared.values()):
                shared = {}
            _, theta, (X, yy, wr, groups) = _stack_cv(sub, own, shared, self.w_, self.n_folds)
            reps = group_bootstrap(X, yy, groups, rng=np.random.default_rng(7000 + j), w=wr)
            ng = len(np.unique(groups, axis=0))
            out, c0, first = {}, 0, None
            for m in sub:
                fr = levels(m.des.friction_given, j, theta[c0:c0 + 4])
                frs = np.array([levels(m.des.friction_given, j, rep[c0:c0 + 4]) for rep in reps])
                row = {"levels": {k: float(v) for k, v in zip(FRICTION_KEYS, fr)},
                       "levels_ci": {k: percentile_ci(frs[:, i], center=fr[i], n_groups=ng)
                                     for i, k in enumerate(FRICTION_KEYS)}}
                if first is None:
                    first = (fr, frs)
                else:
                    dd, dds = fr - first[0], frs - first[1]
                    row["change_from_first"] = {k: float(v) for k, v in zip(FRICTION_KEYS, dd)}
                    row["change_from_first_ci"] = {k: percentile_ci(dds[:, i], center=dd[i], n_groups=ng)
                                                   for i, k in enumerate(FRICTION_KEYS)}
                    # Coulomb and viscous trade against each other where a direction ran at one speed; the friction
                    # torque at the run's median sliding speed of each direction is what the data determine
                    qd = m.jd.qd_rad_s
                    at = {}
                    for d, sgn, (ic, iv) in (("pos", 1.0, (0, 2)), ("neg", -1.0, (1, 3))):
                        v = np.abs(qd[np.sign(qd) == sgn])
                        if len(v) < 20:
                            continue
                        vm = float(np.median(v))
                        c, cs = dd[ic] + dd[iv] * vm, dds[:, ic] + dds[:, iv] * vm
                        at[d] = {"speed_rad_s": vm, "change_Nm": float(c),
                                 "change_ci_Nm": percentile_ci(cs, center=c, n_groups=ng)}
                    row["torque_change_at_median_speed"] = at
                out[self.labels[m.r]] = row
                c0 += own[m.key][1].shape[1]
            self.friction_[str(j + 1)] = out

    # -------------------------------------------------------------------------------- result
    def to_dict(self, data_paths: list[str]) -> dict:
        """The pooled ``diagnosis.json`` mapping (format wamctl-diagnosis/1, ``pooled`` true)."""
        from wamctl.analysis.diagnosis.serialise import FORMAT, _num

        def clean(x):
            if isinstance(x, dict):
                return {k: clean(v) for k, v in x.items()}
            if isinstance(x, (list, tuple)):
                return [clean(v) for v in x]
            if isinstance(x, (bool, np.bool_)):
                return bool(x)
            if isinstance(x, (float, np.floating, int, np.integer)) and not isinstance(x, bool):
                return _num(x) if isinstance(x, (float, np.floating)) else int(x)
            return x

        out = {"format": FORMAT, "pooled": True, "data": list(data_paths), "runs": self.runs_,
               "effects_found": list(self.effects_found_), "ambiguous": [list(g) for g in self.ambiguous_],
               "conclusive": bool(self.conclusive_), "reason": self.reason_}
        if self.conclusive_:
            out.update(findings=self.findings_, payload_or_links=self.payload_or_links_, payload=self.payload_,
                       friction_per_run=self.friction_, test_threshold_p=self.threshold_,
                       method=("each run diagnosed alone; then every arm decision and every joint-own effect kept "
                               "in some run made again on the runs stacked: per (run, joint) its own friction "
                               "levels and effects, shared payload, link errors and effect coefficients; "
                               "held-out residuals over each run's folds; the same test on each run alone"
                               + (" and without each run" if len(self.runs_) >= 3 else "")))
        return clean(out)
