"""A measurement delay against a gap behind a motor-side encoder, told apart at a joint's onsets (no I/O).

Both make the measurement lead the model's link where a joint starts to move again (issue 28, D8): a delay
``d`` because the torque that moved the link to the measured position acted ``d`` earlier, a gap ``w`` on the
motor side because the motor crosses the gap before it drives the link. What parts them:

* a delay shifts the *whole* signal: its lead at an onset is the measured travel over ``d`` after the link
  started, so it grows with the approach (a fast reversal, a steep torque slew) and it shows at onsets in the same
  direction as well; the onset model run with the delay (:func:`~wamctl.analysis.diagnosis.onsets.joint_onsets`
  with ``delay_s``) leaves no lead anywhere;
* a gap is crossed only where the torque the drive passes to the link changes sign (reversals), by at most the
  gap, whatever the speed: one width at the reversals, nothing at the other onsets.

Each hypothesis is fitted to the signed hidden travel of every onset of the joint, on the backlash test's
logarithmic scale (:func:`~wamctl.analysis.diagnosis.backlash.log_travel`):

* ``H_D``: the travel under the onset model with one delay (on :data:`DELAY_GRID_S`, or about the delay the
  torque residual chose), a common offset (with two or more same-direction onsets to set it);
* ``H_G``: the travel under the onset model without a delay, the common offset and one width at the reversals,
  a lead (a reversal term that says the measurement lags is not a gap behind a motor-side encoder: the offset
  alone then).

Each has one parameter beyond the offset, so the log-likelihood ratio ``n log(RSS_D / RSS_G)`` (Gaussian onsets,
``n`` of them) is the evidence, as a difference of BIC (Kass & Raftery 1995: 6 is strong): ``backlash`` when it
is at least :data:`DECIDED_LOG_RATIO`, ``delay`` when at most minus that, else ``ambiguous``. Where the run's
onsets are all alike (a sweep's reversals at one speed) the two fit alike and the outcome is ``ambiguous``: a run
with reversals at clearly different speeds tells them (:func:`reversal_speed_spread`).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from wamctl.analysis.diagnosis.backlash import MIN_REVERSALS, log_travel

DELAY_GRID_S = np.arange(1, 21) * 1e-3          # 1 to 20 ms (a longer delay makes libbarrett's PD loop unstable)
DECIDED_LOG_RATIO = 6.0                         # n log(RSS ratio) that decides: a BIC difference of 6, "strong"
NEAR_FACTORS = (0.5, 0.75, 1.0, 1.25, 1.5)      # about a delay the torque chose: these multiples of it
OVERTURN_LOG_RATIO = 10.0                       # runs pooled overturn a name a run made on "very strong" evidence
                                                # only (a BIC difference above 10, Kass & Raftery 1995)


def _onsets_at(diag, j: int, delay_s: float) -> dict:
    """The onsets of 0-based joint ``j`` under its final model without a kept delay, with ``delay_s`` added to the
    declared one (:func:`~wamctl.analysis.diagnosis.onsets.joint_onsets`)."""
    from wamctl.analysis.diagnosis.onsets import joint_onsets, onset_model

    m = onset_model(diag, j, exclude=("delay", "backlash"))
    m = replace(m, delay_s=m.delay_declared_s + float(delay_s))
    return joint_onsets(diag.design_, diag.dynamics_, diag.jd_[j], m)


def _rss(v: np.ndarray, X: np.ndarray) -> float:
    if X.shape[1] == 0:
        return float(v @ v)
    e = v - X @ np.linalg.lstsq(X, v, rcond=None)[0]
    return float(e @ e)


def compare(travel: dict, rev: np.ndarray, tol, run: np.ndarray | None = None) -> dict:
    """``H_D`` against ``H_G`` on the signed travels ``travel`` ({delay s: (k,) rad}, 0 included: the travel
    without a delay) of ``k`` onsets (``rev`` (k,) bool: reversals; ``tol`` the detection tolerance, rad): the
    onsets finite under every delay, each fitted by least squares on the logarithmic scale. Returns ``outcome``,
    ``log_ratio`` (``n log(RSS_D / RSS_G)``: positive prefers the gap), both RSS, the delay ``H_D`` chose, the
    width ``H_G`` fitted (rad, negative: the measurement leads), ``n`` and the reversals used. Several runs
    stacked: ``run`` (k,) labels each onset's run (each run its own offset, from two same-direction onsets; one
    width and one delay for all: the arm's), ``tol`` a float or (k,) per onset."""
    ok = np.all([np.isfinite(t) for t in travel.values()], axis=0)
    rev = np.asarray(rev, bool)
    tol = np.broadcast_to(np.asarray(tol, float), rev.shape)[ok]
    run = np.zeros(len(rev), int) if run is None else np.asarray(run)
    n, n_rev = int(ok.sum()), int((rev & ok).sum())
    out = {"n": n, "reversals": n_rev}
    if n_rev < MIN_REVERSALS or n < 4:
        return dict(out, outcome="untestable", log_ratio=float("nan"),
                    why=f"{n_rev} reversals with a travel under every delay (at least {MIN_REVERSALS} needed)")
    r, ro = rev[ok].astype(float), run[ok]
    X0 = np.column_stack([np.zeros(n)] + [(ro == u).astype(float) for u in np.unique(ro)
                                          if ((ro == u) & (r == 0)).sum() >= 2])[:, 1:]
    v0 = log_travel(travel[0.0][ok], tol)
    rss_none = _rss(v0, X0)
    Xg = np.column_stack([X0, r])
    coef = np.linalg.lstsq(Xg, v0, rcond=None)[0]
    # a gap on the motor side makes the measurement lead (negative travel): a reversal term of the other sign is
    # not this hypothesis, which then explains no more than the offset
    rss_g = _rss(v0, Xg) if coef[-1] < 0 else rss_none
    delays = [d for d in travel if d > 0]
    rss_d = {d: _rss(log_travel(travel[d][ok], tol), X0) for d in delays}
    d_best = min(rss_d, key=rss_d.get)
    floor = 1e-6 * max(rss_none, 1e-12)
    lr = n * float(np.log(max(rss_d[d_best], floor) / max(rss_g, floor)))
    lead = float(np.mean(travel[0.0][ok][rev[ok]]))
    outcome = "backlash" if lr >= DECIDED_LOG_RATIO else "delay" if lr <= -DECIDED_LOG_RATIO else "ambiguous"
    return dict(out, outcome=outcome, log_ratio=lr, rss_delay=rss_d[d_best], rss_gap=rss_g, rss_neither=rss_none,
                delay_s=float(d_best), gap_log_coef=float(min(coef[-1], 0.0)), mean_reversal_travel_rad=lead)


def head_to_head(diag, j: int, delay_s: float | None = None) -> dict:
    """:func:`compare` at 0-based joint ``j`` of a fitted diagnosis: ``H_D`` on :data:`DELAY_GRID_S`, or with
    ``delay_s`` (the arm's delay the torque residual chose) on :data:`NEAR_FACTORS` of it (one delay for all the
    samples: the onsets' delay must be the torque's). Adds ``joint`` (1-based), ``speed_spread``
    (:func:`reversal_speed_spread`)."""
    grid = DELAY_GRID_S if delay_s is None or delay_s <= 0 else np.array(NEAR_FACTORS) * float(delay_s)
    base = _onsets_at(diag, j, 0.0)
    travel = {0.0: base["travel_rad"]}
    for d in grid:
        travel[float(d)] = _onsets_at(diag, j, float(d))["travel_rad"]
    out = compare(travel, base["reversal"], float(base["tol_rad"]))
    out.update(joint=j + 1, speed_spread=reversal_speed_spread(diag, j, base))
    return out


def reversal_speed_spread(diag, j: int, ons: dict) -> float:
    """How different the joint's approaches to its reversals are: the ratio of the largest to the smallest mean
    speed over the measured stall's reach after each reversal (:func:`reversal_speeds`; 1: all alike, a delay's
    lead and a gap's then look alike), NaN without two reversals."""
    v = reversal_speeds(diag, j, ons)[np.asarray(ons["reversal"], bool)[:len(ons.get("windows", []))]]
    v = v[np.isfinite(v) & (v > 0)]
    return float(v.max() / v.min()) if len(v) >= 2 else float("nan")


def arm_delay_s(diag) -> float | None:
    """The delay the run's torque residual kept (the median over the joints that kept it), None when none did."""
    d = [t["h_all"] for r in diag.joints_.values() for t in r.kept if t["name"] == "delay"]
    return float(np.median(d)) if d else None


def motor_gap_joints(diag) -> list[int]:
    """0-based joints where a gap behind a motor-side encoder was kept."""
    return [j for j, r in diag.joints_.items()
            if any(t["name"] == "backlash" and t.get("encoder_side") == "motor" for t in r.kept)]


def reversal_speeds(diag, j: int, ons: dict) -> np.ndarray:
    """(k,) the joint's mean measured speed (rad/s) over the reach of the smoothing filter after each onset (NaN
    where fewer than two samples follow it)."""
    sig = diag.design_.sig
    out = []
    for w in ons.get("windows", []):
        ii = np.arange(w["end"], min(w["end"] + 2 * sig.reach, sig.n))
        out.append(float(np.mean(np.abs(sig.qd_rad_s[ii, j]))) if len(ii) >= 2 else np.nan)
    return np.asarray(out, float)


# ------------------------------------------------------------------------------------------------- one run
def settle(diag, torque_tests: list[str], tests: list[str]) -> list[dict]:
    """Where a run's diagnosis kept both a delay (from the torque residual, anywhere in the arm) and a gap behind a
    motor-side encoder at a joint (from its onsets), the two are put head to head at that joint
    (:func:`head_to_head` with the delay the torque chose): ``delay`` drops the gap there (the onsets' lead is the
    delay's, said in the joint's backlash candidate); ``backlash`` diagnoses the joint again without the delay
    (its onsets contradict the delay the torque residual chose: the measurement leads where the delay would make
    it lag); ``ambiguous`` drops the gap and leaves the pair an ambiguous group at the joint. Returns the
    records (also in ``diag.delay_vs_gap_``)."""
    from wamctl.analysis.diagnosis.onset_tests import onset_tests

    records = []
    d_t = arm_delay_s(diag)
    if d_t is None:
        diag.delay_vs_gap_ = records
        return records
    for j in motor_gap_joints(diag):
        r = head_to_head(diag, j, d_t)
        r["delay_torque_s"] = d_t
        records.append(r)
        res = diag.joints_[j]
        if r["outcome"] == "backlash":
            if any(t["name"] == "delay" for t in res.kept):
                why = (f"its onsets prefer a gap behind a motor-side encoder to the {d_t * 1e3:.1f} ms delay "
                       f"(n log(RSS ratio) {r['log_ratio']:+.1f} over {r['n']} onsets)")
                diag._rediagnose(j, torque_tests, "delay", why)
                onset_tests(diag, j, tests)
            continue
        _drop_gap(diag, j, r)
        if r["outcome"] == "ambiguous":
            res.ambiguous.append({"names": ["backlash", "delay"], "evidence": {
                "log_ratio": r["log_ratio"], "n_onsets": r["n"], "reversals": r["reversals"]}})
    diag.delay_vs_gap_ = records
    return records


def _drop_gap(diag, j: int, r: dict) -> None:
    """The motor-side gap at 0-based joint ``j`` left out (no torque-domain term: the kept list only), with why."""
    res = diag.joints_[j]
    res.kept = [t for t in res.kept if t["name"] != "backlash"]
    why = ("the delay explains the onsets" if r["outcome"] == "delay" else
           "ambiguous with the delay at the onsets") + (f" (n log(RSS ratio) {r['log_ratio']:+.1f} over {r['n']} "
                                                      f"onsets, {DECIDED_LOG_RATIO:g} decides)")
    from wamctl.analysis.diagnosis.joint import set_rms
    from wamctl.analysis.diagnosis.onsets import stall_residual

    if j in getattr(diag, "onsets_", {}):
        res.stall_after = stall_residual(diag, j, diag.onsets_[j], after=True)
        set_rms(res)
    c = res.candidates.get("backlash")
    if c is not None:
        c.update(kept=False, reason=why, delay_vs_gap=r["outcome"])
    diag.warnings_ = [w for w in diag.warnings_ if not (w.startswith(f"joint {j + 1}: backlash with the encoder "
                                                                     "on the motor side"))]


# ------------------------------------------------------------------------------------------------- runs pooled
def pooled_head_to_head(diags: list, labels: list[str], j: int, delay_s: float | None) -> dict:
    """:func:`compare` at 0-based joint ``j`` on the onsets of every run that diagnosed it, stacked: one gap
    width and one delay for all the runs (the arm's: a gap does not change between runs, nor does the delay; each
    run its own offset), the delay about ``delay_s`` (the delay the runs pooled chose; None: the grid). A run
    whose reversals lag cannot have the others' lead: the shared width weighs every run's onsets. ``per_run``:
    each run's onsets counted."""
    grid = DELAY_GRID_S if delay_s is None or delay_s <= 0 else np.array(NEAR_FACTORS) * float(delay_s)
    keys = [0.0] + [float(d) for d in grid]
    travel, rev, tol, run, per = {k: [] for k in keys}, [], [], [], {}
    for r, (d, lab) in enumerate(zip(diags, labels)):
        if not getattr(d, "conclusive_", False) or j not in d.joints_:
            continue
        try:
            ons = {k: _onsets_at(d, j, k) for k in keys}
        except (KeyError, ValueError, IndexError):        # a run without onset data at the joint: not counted
            continue
        base = ons[0.0]
        for k in keys:
            travel[k].append(ons[k]["travel_rad"])
        rev.append(base["reversal"])
        tol.append(np.full(len(base["reversal"]), float(base["tol_rad"])))
        run.append(np.full(len(base["reversal"]), r))
        per[lab] = {"onsets": int(len(base["reversal"])), "reversals": int(np.sum(base["reversal"]))}
    if not per:
        return {"joint": j + 1, "outcome": "untestable", "log_ratio": float("nan"), "delay_s": delay_s,
                "per_run": per}
    out = compare({k: np.concatenate(v) for k, v in travel.items()}, np.concatenate(rev), np.concatenate(tol),
                  np.concatenate(run))
    return dict(out, joint=j + 1, delay_s=delay_s if out.get("delay_s") is None else out["delay_s"],
                delay_pooled_s=delay_s, per_run=per)


# ------------------------------------------------------------------------------------------------- the design
DESIGN_RATE_HZ = 500.0          # the reversals' accelerations read at the control rate
PERIODS_S = (1.5, 3.0, 6.0)     # base periods tried: a slow and a fast harmonic give reversals at several rates
DESIGN_PERIODS = 10             # periods of the designed run (scored over them, and written so)


def predicted_leads(qdd_rad_s2: np.ndarray, delay_s: float, tol_rad: float) -> np.ndarray:
    """The lag a delay ``delay_s`` makes at reversals of accelerations ``qdd_rad_s2`` (k,) as the onset test
    measures it (:func:`~wamctl.analysis.diagnosis.backlash.signed_travel`): the link leaves its turning point as
    ``x = a t^2 / 2`` and has moved ``tol`` at ``t0 = sqrt(2 tol / a)``; the measurement shows that ``d`` later,
    when the link has travelled ``x(t0 + d)``: ``x(t0 + d) - tol = a t0 d + a d^2 / 2``."""
    a = np.maximum(np.abs(np.asarray(qdd_rad_s2, float)), 1e-9)
    t0 = np.sqrt(2.0 * tol_rad / a)
    return a * t0 * delay_s + 0.5 * a * delay_s ** 2


def separation(qdd_rad_s2: np.ndarray, delay_s: float, gap_rad: float, tol_rad: float) -> dict:
    """T-criterion of reversals with accelerations ``qdd_rad_s2`` (k,): each hypothesis true, the other refitted
    (the gap one width, the delay one ``tau`` on a fine grid up to 20 ms), what it cannot reproduce, RMS per
    reversal in detection tolerances (the onset test's resolution); ``separation`` the smaller, ``total`` it
    times the square root of the reversals (what the onset head to head sums)."""
    a = np.asarray(qdd_rad_s2, float)
    if len(a) < MIN_REVERSALS:
        return {"delay_true": 0.0, "gap_true": 0.0, "separation": 0.0, "total": 0.0, "reversals": len(a)}
    lead_d = predicted_leads(a, delay_s, tol_rad) / tol_rad
    delay_true = float(np.sqrt(np.mean((lead_d - lead_d.mean()) ** 2)))
    g = gap_rad / tol_rad
    taus = np.linspace(0.0, 0.02, 81)
    gap_true = min(float(np.sqrt(np.mean((g - predicted_leads(a, t, tol_rad) / tol_rad) ** 2))) for t in taus)
    sep = min(delay_true, gap_true)
    return {"delay_true": delay_true, "gap_true": gap_true, "separation": sep, "total": sep * np.sqrt(len(a)),
            "reversals": len(a)}


def reversal_accelerations(q_rad: np.ndarray, qd_rad_s: np.ndarray, qdd_rad_s2: np.ndarray) -> np.ndarray:
    """(k,) the acceleration at each reversal of a trajectory's joint (its speed changes sign)."""
    s = np.sign(qd_rad_s)
    k = np.flatnonzero(s[1:] * s[:-1] < 0)
    return np.abs(qdd_rad_s2[k])


def design_two_speeds(dynamics, friction, q0_rad, j: int, limits, delay_s: float, gap_rad: float, tol_rad: float,
                      periods: int = DESIGN_PERIODS, harmonics: int = 5, per_period: int = 4, fill: float = 0.95,
                      seed: int = 0):
    """T-optimal choice among Fourier candidates of 0-based joint ``j`` alone (excite's parametrisation, seeded,
    ``per_period`` per base period of :data:`PERIODS_S`, each scaled within excite's limits): the one whose
    reversals part a delay ``delay_s`` from a gap ``gap_rad`` most (:func:`separation` over ``periods`` periods).
    Returns ``(trajectory, separation dict, scored [(period s, separation)])``; ValueError when no candidate keeps
    within the limits."""
    from wamctl.analysis.diagnosis.discriminate import best_within_limits, coarse_scaled
    from wamctl.analysis.identification.excitation import FourierTrajectory

    rng = np.random.default_rng(seed)

    def score(traj):
        t = np.arange(int(traj.period_s * DESIGN_RATE_HZ) * periods) / DESIGN_RATE_HZ
        q, qd, qdd = traj.evaluate(t)
        return separation(reversal_accelerations(q[:, j], qd[:, j], qdd[:, j]), delay_s, gap_rad, tol_rad)

    cands, label = [], {}
    for period in PERIODS_S:
        for _ in range(per_period):
            x = rng.normal(size=(1, 2 * (harmonics - 1))) / np.tile(np.arange(2, harmonics + 1), 2)
            got = coarse_scaled(FourierTrajectory.from_free(q0_rad, period, [j], x, harmonics), limits, dynamics,
                                friction, fill, rate_hz=50.0)
            if got is None:
                continue
            label[len(cands)] = float(period)
            cands.append((score(got[0])["separation"], got[0], len(cands)))
    best = best_within_limits(cands, score, limits, dynamics, friction, fill)
    if best is None:
        raise ValueError("no candidate trajectory keeps within the limits")
    traj, sep, _, checked = best
    scored = [(label[k], float(checked[k] if checked.get(k) is not None else s)) for s, _, k in cands
              if not (k in checked and checked[k] is None)]
    return traj, sep, scored


def ambiguous_joints(diag) -> list[int]:
    """0-based joints where the run left a delay and a motor-side gap ambiguous (:func:`settle`)."""
    return [j for j, r in diag.joints_.items()
            if any(sorted(g["names"]) == ["backlash", "delay"] for g in r.ambiguous)]
