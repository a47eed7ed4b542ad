"""``wamctl diagnose``'s next experiment for a delay against an inertia error (issue 28 item 1): when a run's
residual holds an effect that a measurement delay and joint inertia errors explain alike, the excitation that
parts them best (:func:`wamctl.analysis.diagnosis.delay_inertia.design_next_run`) written as
``next_experiment.yaml``; when the run tells them apart, the decision. The same for a friction drift against a
Stribeck effect left ambiguous at a joint (:func:`next_experiment_friction`, :mod:`wamctl.analysis.diagnosis.
friction_design`) and for a gap behind a motor-side encoder (:func:`next_experiment_backlash`). A design whose
predicted separation stays below :data:`DESIGN_TARGET_FLOORS` is still written (delay, friction: ``decisive``
false, and its ``why`` says that run alone cannot decide); pooled (:mod:`wamctl.analysis.diagnosis.pooled`), each
run weighs its own evidence, and a name the first run made is kept unless a run's evidence contradicts it."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def next_experiment_delay(diag, data, data_path: Path, out_dir: Path, seed: int = 0) -> dict | None:
    """The delay-or-inertia check of a fitted diagnosis (:func:`~wamctl.analysis.diagnosis.delay_inertia.
    check_run`). None when the diagnosis leaves no room for either (:func:`delay_or_inertia_suspected`) or the
    residual holds no effect either explains (by at least the noise floor beyond friction). Decided on this run:
    ``{"spec": None, "hypotheses", "decision", "why"}``. Ambiguous: the designed run written as
    ``out_dir/next_experiment.yaml`` (an excitation spec for the run's backend, plant and controller when the run
    directory names them) and ``{"spec", "hypotheses", "decision", "separation_noise_floors",
    "original_separation_noise_floors", "joints", "period_s", "noise_floor_Nm", "why", "candidates"}``."""

    from wamctl.analysis.diagnosis import delay_inertia as DI

    if not (diag.joints_ and delay_or_inertia_suspected(diag)):
        return None
    dyn, limits, q0, friction = design_setting(diag, data)
    chk = DI.check_run(diag, dyn)
    if not chk.suspected:
        return None
    dec = chk.decision
    base = {"hypotheses": ["delay", "inertia"], "decision": dec}
    if dec["outcome"] != "ambiguous":
        return dict(base, spec=None, why="none needed, " + DI.decision_line(dec))
    noise = chk.floors
    ran = sorted(chk.rows.joints)
    sets = [ran, sorted(set(ran) | {3}), sorted(set(ran) | {1, 3}), list(range(7))]
    sets = [s for k, s in enumerate(sets) if s not in sets[:k]]
    try:
        nr = DI.design_next_run(dyn, friction, q0, chk.hyp, noise, chk.rows, limits, sets, seed=seed)
    except ValueError as exc:       # no candidate within the limits at this q0: said, no spec written
        return dict(base, spec=None, why=f"{DI.decision_line(dec)}; no run designed to tell them: {exc} at the "
                                         "run's q0")
    tr = nr.trajectory
    sep, orig_sep = float(nr.separation["separation"]), float(nr.original["separation"])
    joints = ", ".join(str(j + 1) for j in tr.moving)
    why = (f"the run cannot tell a {dec['delay_s'] * 1e3:.1f} ms measurement delay from inertia errors of joint"
           f"{'s' if len(ran) > 1 else ''} {', '.join(str(j + 1) for j in ran)} (a delay times the viscous friction "
           "acts as an inertia at one "
           f"speed; separation {orig_sep:.2g} noise floors, {_floors(dec)}); moving joints {joints} with "
           f"{tr.harmonics} harmonics of a {tr.period_s:g} s period (several speeds: the delay's apparent damping "
           f"grows with the square of the frequency, an inertia error's does not) their predicted torques differ by "
           f"{sep:.2g} noise floors (RMS per sample, after each refits its own parameters; the floor of a joint "
           "the run did not move assumed in proportion to its torque limit)"
           + ("" if sep > DI.DESIGN_TARGET_FLOORS else
              f": still below {DI.DESIGN_TARGET_FLOORS:g}, a longer run is needed to tell them"))
    write_next_experiment(data_path, out_dir, tr, q0, [j + 1 for j in tr.moving], 3, 1.0, why, seed)
    return dict(base, spec="next_experiment.yaml", separation_noise_floors=sep,
                original_separation_noise_floors=orig_sep, decisive=sep > DI.DESIGN_TARGET_FLOORS,
                joints=[j + 1 for j in tr.moving],
                period_s=float(tr.period_s), noise_floor_Nm={j + 1: v for j, v in noise.items()}, why=why,
                candidates=[{"joints": js, "period_s": p, "separation_noise_floors": float(v)}
                            for js, p, v in nr.scored])


def write_next_experiment(data_path: Path, out_dir: Path, trajectory, q0_rad, joints: list[int], periods: int,
                          settle_s: float, why: str, seed: int = 0) -> None:
    """``out_dir/next_experiment.yaml``: the excitation spec of the designed ``trajectory`` (excite's Fourier
    series) from ``q0_rad``, moving the 1-based ``joints`` for ``periods`` periods after ``settle_s``, for the
    run's backend, plant and controller where its directory names them (our own run: the same arm and simulated
    plant), with ``why`` as its first line."""
    import yaml

    from wamctl.experiments.excitation import designed_spec

    raw = {"kind": "excitation", "name": f"next-{Path(data_path).name}", "seed": seed,
           "q0_rad": [float(x) for x in q0_rad]}
    src = Path(data_path) / "spec.yaml"
    if src.is_file():
        orig = yaml.safe_load(src.read_text()) or {}
        raw.update({k: orig[k] for k in ("backend", "plant", "controller") if k in orig})
    raw["excitation"] = {"joints": list(joints), "period_s": float(trajectory.period_s),
                         "harmonics": int(trajectory.harmonics), "periods": int(periods), "settle_s": settle_s}
    spec = designed_spec(raw, trajectory)
    (Path(out_dir) / "next_experiment.yaml").write_text(
        f"# designed by wamctl diagnose: {why}\n" + yaml.safe_dump(spec, sort_keys=False))


def design_setting(diag, data):
    """What every designed run starts from: the declared rigid body (with the declared payload), excite's limits,
    the run's start pose (rad; 0 where the log does not say) and the declared friction (Table 4.1 when none)."""
    from wamctl.analysis.identification.excitation import ExcitationLimits
    from wamctl.model.dynamics import WamDynamics
    from wamctl.model.friction import FrictionModel
    from wamctl.specs.excitation import ExcitationLimitsSpec

    lim = ExcitationLimitsSpec()
    return (WamDynamics(diag.payload_declared_, diag.declared_.links),
            ExcitationLimits(*lim.arrays(), 1 - lim.torque_margin, lim.max_cartesian_speed_m_s),
            np.array([0.0 if v is None else float(v) for v in data.meta.q0]),
            diag.declared_.friction or FrictionModel.table_4_1())


def delay_or_inertia_suspected(diag) -> bool:
    """The diagnosis leaves room for a delay or an inertia error
    (:func:`wamctl.analysis.diagnosis.delay_inertia.leaves_room`)."""
    from wamctl.analysis.diagnosis.delay_inertia import leaves_room

    return leaves_room(diag)


def _floors(dec: dict) -> str:
    """The measured noise floors in words."""
    return ", ".join(f"{v:.2g} N m at joint {j}" for j, v in sorted(dec["floor_Nm"].items()))


DESIGN_TARGET_FLOORS = 2.0      # the predicted separation a designed run is asked for
BACKLASH_GAP_RAD = 0.008        # the total gap the crossing run is designed to show (the generator's medium: 4-8 mrad)


SUSPECT_P = 0.05                # a motor-side gap's onset test below this level, though not kept: suspected
# a partial lead (issue 28, B9): a gap crossed only partly at a reversal leads by less than the gap, and a run with
# few reversals cannot reach SUSPECT_P; a joint is suspected too where the measurement led the model's link by at
# least PARTIAL_LEAD_TOLERANCES detection tolerances (beyond the same-direction onsets) at a strict majority of at
# least MIN_PARTIAL_REVERSALS reversals. Without a gap a light joint's measurement leads by about one tolerance (a
# sample or two at a turn): on the dev split's 144 joints without a gap and without an effect of their own named
# (80 runs: backlash, other effects, clean and false-alarm runs) none led by 2 tolerances at a majority of its
# reversals, at most a quarter of them; on 40 more dev false-alarm runs one joint did (3 of 5 reversals, p 0.89):
# its designed run, pooled, named nothing (the run costs the user; the pooled decision names only what it shows).
PARTIAL_LEAD_TOLERANCES = 2.0
MIN_PARTIAL_REVERSALS = 2
# the smallest gap a suspect's run is designed for: the lead seen is a lower bound of the gap (a partial crossing
# shows less), and a gap below the test's resolution (MIN_BAND_TOLERANCES) is never named; twice that resolution
ASSUMED_MIN_GAP_TOLERANCES = 10.0
ARM_LEVEL = ("link_parameters", "payload")      # named for the arm, not a joint's own effect
# a gravity torque smaller than this is none: joint 1's axis is vertical, its gravity torque rounding (1e-16 N m, of
# one sign or the other as the other joints' pose has it), which must not read as gravity pressing the link on a flank
GRAVITY_NONE_NM = 1e-9


def _one_sign(g_Nm: np.ndarray) -> bool:
    """True when a joint's gravity torque ``g_Nm`` (its samples over a run) pressed its link on one flank throughout:
    of one sign and above rounding (:data:`GRAVITY_NONE_NM`)."""
    return bool(len(g_Nm) and (g_Nm.min() > GRAVITY_NONE_NM or g_Nm.max() < -GRAVITY_NONE_NM))


def backlash_suspects(diag) -> list[int]:
    """0-based joints where a gap behind a motor-side encoder cannot be excluded and the diagnosis left it open,
    most suspect first:

    * the backlash onset test saw the measurement lead the link at reversals by at least the test's resolution
      (``MIN_BAND_TOLERANCES`` detection tolerances) with a p-value below ``SUSPECT_P`` but not below the
      diagnosis' threshold (issue 28: "an effect is suspected but its parameters are not identified"; a run with
      few reversals cannot decide it, a run with more can), smallest p-value first; then those where it led by
      at least ``PARTIAL_LEAD_TOLERANCES`` tolerances at a strict majority of the reversals, at whatever p-value
      (a gap crossed partly leads by less than the gap, a few reversals cannot reach ``SUSPECT_P``: partial
      leads, :func:`_leading_joints`), smallest p-value first;
    * backlash in an ambiguous group, or a residual left structured and unexplained with nothing named at a joint
      whose gravity torque kept one sign over the run (the drive never let the link fall through a gap; issue 28:
      "a structured residual stays unexplained"; a gap is one of the things it could be, and the only one a
      one-sign run cannot show: the designed run tests it, and names nothing when it is something else)."""
    from wamctl.model.dynamics import WamDynamics

    dyn = WamDynamics(diag.payload_declared_, diag.declared_.links)
    leads = _leading_joints(diag)
    out = []
    for j, res in diag.joints_.items():
        if j in leads or any(t["name"] == "backlash" for t in res.kept):
            continue
        if not (any("backlash" in g["names"] for g in res.ambiguous) or (res.unexplained and not res.kept)):
            continue
        jd = diag.jd_[j]
        if _one_sign(dyn.gravity_many(diag.signals_.at("q", jd.idx[:: max(1, len(jd.idx) // 400)]))[:, j]):
            out.append(j)
    return sorted(leads, key=lambda j: (leads[j][2], leads[j][0])) + out


def _leading_joints(diag) -> dict[int, tuple[float, float, bool, int, int]]:
    """{0-based joint: (p-value, lead rad, partial, leading reversals, reversals)} where the backlash onset test
    was not kept and the measurement led the link at reversals (a gap on the motor side):

    * by at least ``MIN_BAND_TOLERANCES`` detection tolerances with a p-value below ``SUSPECT_P`` (``partial``
      False);
    * or, at whatever p-value (1 where the run had too few onsets or reversals for the test), by at least
      ``PARTIAL_LEAD_TOLERANCES`` tolerances beyond the same-direction onsets at a strict majority of at least
      ``MIN_PARTIAL_REVERSALS`` reversals (:func:`~wamctl.analysis.diagnosis.backlash.reversal_leads_tol`),
      with a positive lead overall, and no effect of the joint's own named there (``partial`` True): a gap crossed
      partly at a reversal leads by less than the gap, and a run with few reversals cannot reach ``SUSPECT_P``;
      a named Stribeck effect, friction drift or delay moves the model's onsets too (on the dev split its joints
      were the only ones without a gap that led so)."""
    from wamctl.analysis.diagnosis.backlash import MIN_BAND_TOLERANCES, reversal_leads_tol

    out = {}
    for j, res in diag.joints_.items():
        c = res.candidates.get("backlash") or {}
        if c.get("kept") or any(t["name"] == "backlash" for t in res.kept):
            continue
        lead = _motor_lead_rad(diag, j)
        if lead is None or not lead > 0:
            continue
        p = c.get("p_value")
        p = 1.0 if p is None or not np.isfinite(p) else float(p)
        ons = diag.onsets_[j]
        tol = float(ons["tol_rad"])
        by = reversal_leads_tol(ons["travel_rad"], ons["reversal"], tol)
        n_lead = int(np.count_nonzero(by >= PARTIAL_LEAD_TOLERANCES))
        if c.get("encoder_side") == "motor" and p < SUSPECT_P and lead >= MIN_BAND_TOLERANCES * tol:
            out[j] = (p, float(lead), False, n_lead, int(len(by)))
        elif (len(by) >= MIN_PARTIAL_REVERSALS and 2 * n_lead > len(by)
              and not any(t["name"] not in ARM_LEVEL for t in res.kept)):
            out[j] = (p, float(lead), True, n_lead, int(len(by)))
    return out


def _design_gap_rad(diag, j: int, lead_rad: float) -> float:
    """The gap a suspect's run is designed for: the lead seen at its reversals (a lower bound of the gap: a partial
    crossing shows less), at least ``ASSUMED_MIN_GAP_TOLERANCES`` of the joint's detection tolerances."""
    return max(float(lead_rad), ASSUMED_MIN_GAP_TOLERANCES * float(diag.onsets_[j]["tol_rad"]))


def _motor_lead_rad(diag, j: int) -> float | None:
    """How far the measurement of 0-based joint ``j`` led the model's link at the run's reversals (rad, minus the
    signed dead band of :func:`~wamctl.analysis.diagnosis.backlash.band_width`: positive for a lead); None
    without onset data or reversals."""
    from wamctl.analysis.diagnosis.backlash import band_width

    ons = (getattr(diag, "onsets_", None) or {}).get(j) or {}
    if not ons.get("tol_rad") or not len(ons.get("travel_rad", ())):
        return None
    ok = np.isfinite(ons["travel_rad"])
    if not ons["reversal"][ok].any():
        return None
    return float(-band_width(ons["travel_rad"][ok], ons["reversal"][ok]))


def next_experiment_backlash(diag, data, data_path: Path, out_dir: Path, joints: list[int] | None = None,
                             gap_rad: float = BACKLASH_GAP_RAD, seed: int = 0) -> dict | None:
    """A gap behind a motor-side encoder against nothing (:mod:`wamctl.analysis.diagnosis.backlash_design`): for the
    suspected ``joints`` (0-based; default :func:`backlash_suspects`, most suspect first) the slow back-and-forth of the
    joint alone that shows a gap best, about the pose where its gravity torque changes sign (the link falls through the
    gap: a torque step) or where it rests on its own friction at the reversals (the measurement leads the link by the
    gap), written as ``out_dir/next_experiment.yaml``. The gap designed for: the lead the run's onset test saw at the
    joint (a suspect for its lead, whole or partial: a lower bound of the gap), at least ``ASSUMED_MIN_GAP_TOLERANCES``
    detection tolerances (:func:`_design_gap_rad`), else ``gap_rad``. A reversal run is sized to the power
    ``POWER_TARGET`` of the diagnosis' own backlash decision on it (its threshold, the scatter of the run's onsets:
    :func:`~wamctl.analysis.diagnosis.backlash_design.size_reversal_run`) within ``MAX_RUN_S``, or says it cannot. The
    first suspect whose design decides (else the best). ``{"spec", "hypotheses", "joint", "gap_rad",
    "separation_noise_floors", "original_separation_noise_floors", "seen_by", "reversals", "power", "power_se",
    "periods", "duration_s", "decisive", "power_curve", "joints", "period_s", "crossing_pose_rad",
    "gravity_slope_Nm_rad", "noise_floor_Nm", "link_friction_share", "why"}``: ``power`` that of the backlash decision
    on the designed run (a gravity step's run too: it is named from the leads only); for a reversal run
    ``separation_noise_floors`` is the predicted median test statistic of the decision (the reversals' lead in its
    standard errors), and ``original_separation_noise_floors`` the one the run's own test gave. None when no joint is
    suspected; ``spec`` None with ``why`` when no crossing keeps within the limits."""

    from wamctl.analysis.diagnosis.backlash import MIN_BAND_TOLERANCES, MIN_REVERSALS
    from wamctl.analysis.diagnosis.backlash_design import (
        MAX_RUN_S,
        POWER_TARGET,
        OnsetScatter,
        design_crossing,
        onset_scatter,
    )
    from wamctl.analysis.diagnosis.onsets import detection_tolerance

    joints = backlash_suspects(diag) if joints is None else list(joints)
    if not joints:
        return None
    dyn, limits, q0, friction = design_setting(diag, data)
    sig = diag.signals_
    best, why_not = None, []
    leads = _leading_joints(diag)
    for j in joints:
        idx = diag.jd_[j].idx
        idx = idx[:: max(1, int(round(1.0 / (sig.dt_s * 25.0))))]
        noise = float(diag.joints_[j].torque_rms_after_Nm)
        if not np.isfinite(noise) or noise <= 0:
            why_not.append(f"joint {j + 1}: no noise floor (held-out torque RMS) to design against")
            continue
        ons = (getattr(diag, "onsets_", {}) or {}).get(j) or {}
        tol = ons.get("tol_rad") or detection_tolerance(sig, j)[1]
        scatter = (onset_scatter(ons["travel_rad"], ons["reversal"], tol) if len(ons.get("travel_rad", ()))
                   else OnsetScatter())
        f = diag.friction_after(j)
        fc = min(f["fc_pos_Nm"], f["fc_neg_Nm"])
        gap_j = _design_gap_rad(diag, j, leads[j][1]) if j in leads else gap_rad
        share = _link_share(diag, dyn, j, max(float(fc), 0.0), float(tol))
        try:
            cr = design_crossing(dyn, friction, q0, j, gap_j, noise, limits, sig.at("q", idx), sig.at("qd", idx),
                                 tol_rad=float(tol), fc_Nm=max(float(fc), 0.0), run_qdd=sig.at("qdd", idx),
                                 scatter=scatter, threshold=float(diag.threshold_), n_folds=int(diag.n_folds),
                                 share=share["share"])
        except ValueError as exc:
            why_not.append(f"joint {j + 1}: {exc}")
            continue
        rv0, lead_rad = cr.reversals_original, _motor_lead_rad(diag, j)
        if (cr.seen_by == "reversals" and j not in leads and rv0 is not None and rv0[1] >= 2 * MIN_REVERSALS
                and rv0[0] > DESIGN_TARGET_FLOORS and lead_rad is not None and lead_rad < MIN_BAND_TOLERANCES * tol):
            # the run's own reversals were chances enough for a gap to show: the measurement did not lead
            why_not.append(f"joint {j + 1}: at the run's own {rv0[1]} reversals where the link rests on its own "
                           f"friction ({rv0[0]:.2g} noise floors for a {gap_j * 1e3:g} mrad gap) the measurement "
                           f"led by {max(lead_rad, 0.0) * 1e3:.2g} mrad, below the backlash test's resolution")
            continue
        decides = _backlash_decides(cr)
        if best is None or (decides, _backlash_score(cr)) > (_backlash_decides(best[1]), _backlash_score(best[1])):
            best = (j, cr, noise, _one_sign(dyn.gravity_many(sig.at("q", idx))[:, j]), float(tol), float(fc), gap_j,
                    scatter, share)
        if decides:       # the most suspect joint that the design can decide
            break
    base = {"hypotheses": ["backlash", "none"], "gap_rad": gap_rad}
    if best is None:
        return dict(base, spec=None, why="no run designed to show a gap behind the encoder: " + "; ".join(why_not))
    j, cr, noise, one_sign, tol, fc, gap_j, scatter, share = best
    base["gap_rad"] = gap_j
    tr = cr.trajectory
    seen = ("kept one sign over the run, so a gap behind a motor-side encoder was never crossed" if one_sign else
            "changed sign over the run")
    rv, rv0, sz = cr.reversals, cr.reversals_original, cr.size
    cand = diag.joints_[j].candidates.get("backlash") or {}
    t_run = (float(np.sqrt(cand["F"])) if cand.get("encoder_side") == "motor" and cand.get("F") is not None
             and np.isfinite(cand["F"]) else 0.0)
    lead = leads.get(j)
    if lead is None:
        trigger = (f"joint {j + 1}'s residual was left structured and unexplained with nothing named there; a "
                   "gap behind a motor-side encoder is one of what it could be")
    elif lead[2]:
        trigger = (f"joint {j + 1}'s measurement led the link by at least {PARTIAL_LEAD_TOLERANCES:g} detection "
                   f"tolerances at {lead[3]} of its {lead[4]} reversals ({lead[1] * 1e3:.2g} mrad over the larger "
                   f"half; onset test p = {lead[0]:.2g}): a gap crossed partly at a reversal leads by less than "
                   "the gap, and too few reversals to decide")
    else:
        trigger = (f"joint {j + 1}'s measurement led the link by {lead[1] * 1e3:.2g} mrad at reversals, too few "
                   f"to decide (onset test p = {lead[0]:.2g}, not below the threshold {diag.threshold_:.2g})")
    gap_words = f"a {gap_j * 1e3:.2g} mrad gap designed for"
    if lead is not None:
        gap_words += (f": the lead seen, a lower bound of the gap, and at least {ASSUMED_MIN_GAP_TOLERANCES:g} "
                      f"detection tolerances ({ASSUMED_MIN_GAP_TOLERANCES * tol * 1e3:.2g} mrad) assumed")
    if cr.seen_by == "reversals":
        cr.original = t_run
        run_part = (f"the run's {rv0[2]} reversals, {rv0[1]} of them where the link rests on its own friction; its "
                    f"test statistic {t_run:.2g}" if rv0 else f"its test statistic {t_run:.2g}")
        qj = tr.evaluate(np.linspace(0.0, tr.period_s, 201))[0][:, j]
        power = (f"the backlash decision's predicted power {sz['power']:.2f} +- {sz['power_se']:.2f} (its median "
                 f"test statistic {sz['t_median']:.2g}; Monte Carlo of the diagnosis' own test at its threshold "
                 f"{diag.threshold_:.2g}, the run's onsets' scatter: log travel sd {scatter.same_log_sd:.2g} from "
                 f"{scatter.n_same} same-direction onsets, {scatter.lead_log_sd:.2g} from {scatter.n_lead} leads, "
                 f"{'measured' if scatter.n_same >= 3 else 'assumed'})")
        if sz["reached"]:
            size = (f"{cr.periods} periods ({sz['duration_s']:g} s), the fewest that reach power {POWER_TARGET:g}: "
                    f"{power}")
        else:
            size = (f"{cr.periods} periods ({sz['duration_s']:g} s, the most within {MAX_RUN_S:g} s) do not reach "
                    f"power {POWER_TARGET:g}: {power}; this run may not decide")
        how = (f"moving joint {j + 1} alone slowly ({tr.period_s:g} s period) between {qj.min():.3f} and "
               f"{qj.max():.3f} rad, the link comes to rest on its own friction at {rv[1]} of its {rv[2]} reversals "
               f"(the torque the rigid link needs there below {share['share']:.2g} of the joint's {fc:.3g} N m "
               f"Coulomb level, {_share_words(share)}) and the motor crosses the gap before it drives "
               f"the link back: the measurement leads the link by the gap; {size}; the gravity step there "
               f"{cr.torque_separation:.2g} noise floors")
        why = f"{trigger} ({run_part}; {gap_words}); {how} (the run starts at that pose: move the arm there first)"
    else:
        why = (f"{trigger + ' (' + gap_words + '); ' if lead is not None else ''}"
               f"joint {j + 1}'s gravity torque {seen} (a {gap_j * 1e3:.2g} mrad gap: separation {cr.original:.2g} "
               f"noise floors of {noise:.3g} N m); moving joint {j + 1} slowly ({tr.period_s:g} s period) about "
               f"{tr.q0_rad[j]:.3f} rad, where its "
               f"gravity torque changes sign ({cr.slope_Nm_rad:.3g} N m/rad), the link falls through the gap at each "
               f"crossing: the residual steps by {gap_j * cr.slope_Nm_rad:.2g} N m, {cr.separation:.2g} noise "
               "floors RMS after friction and an offset are refitted (the run starts at the crossing pose: move the "
               "arm there first)")
        if sz is not None:
            why += (f"; the diagnosis names a gap behind a motor-side encoder from the leads at reversals only, and "
                    f"no reversal run reaches power {POWER_TARGET:g} within {MAX_RUN_S:g} s: this run's predicted "
                    f"power {sz['power']:.2f}, it may not decide")
        if cr.separation <= DESIGN_TARGET_FLOORS:
            why += f"; still below {DESIGN_TARGET_FLOORS:g}: only a larger gap would show on this joint"
    write_next_experiment(data_path, out_dir, tr, tr.q0_rad, [j + 1], cr.periods, 1.0, why, seed)
    rev_run = cr.seen_by == "reversals"
    return dict(base, spec="next_experiment.yaml", joint=j + 1, joints=[j + 1],
                separation_noise_floors=float(cr.separation), original_separation_noise_floors=float(cr.original),
                seen_by=cr.seen_by,
                reversals={"crossing": rv[1], "all": rv[2]} if rv is not None and rev_run else None,
                power=float(sz["power"]) if sz else None,
                power_se=float(sz["power_se"]) if sz else None,
                power_curve=[[int(n), float(p), float(t)] for n, p, t in sz["curve"]] if rev_run and sz else None,
                periods=int(cr.periods), duration_s=float(cr.periods * tr.period_s),
                decisive=_backlash_decides(cr),
                period_s=float(tr.period_s), crossing_pose_rad=[float(x) for x in tr.q0_rad],
                gravity_slope_Nm_rad=float(cr.slope_Nm_rad), noise_floor_Nm=noise, link_friction_share=share,
                why=why)


def _link_share(diag, dyn, j: int, fc_Nm: float, tol_rad: float) -> dict:
    """The link-side share of 0-based joint ``j``'s Coulomb friction its run's reversals bound
    (:func:`~wamctl.analysis.diagnosis.backlash_design.link_share_from_run`: the torque the rigid link needed at
    each measured turning point, and whether the measurement led there), or the assumed share without reversals."""
    from wamctl.analysis.diagnosis.backlash_design import LINK_FRICTION_SHARE, link_share_from_run

    ons = (getattr(diag, "onsets_", {}) or {}).get(j) or {}
    listed = (diag.jd_[j].extra.get("_onsets") or {}).get(ons.get("tol_rad"))
    if not ons or listed is None or len(listed) != len(ons["travel_rad"]) or not ons["reversal"].any():
        return {"low": 0.0, "high": None, "crossed": 0, "held": 0, "share": LINK_FRICTION_SHARE, "estimated": False}
    rev = np.flatnonzero(ons["reversal"])
    turn = np.array([listed[i].turn if listed[i].turn >= 0 else listed[i].start for i in rev], int)
    sig = diag.signals_
    return link_share_from_run(dyn, sig.at("q", turn), sig.at("qd", turn), sig.at("qdd", turn), j,
                               -ons["travel_rad"][rev], fc_Nm, tol_rad)


def _share_words(share: dict) -> str:
    """How the link-side friction share was had, for the why."""
    hi = "" if share["high"] is None else f", at most {share['high']:.2g} where {share['held']} held"
    if share["estimated"]:
        return (f"the link-side share of the friction the run's reversals bound: at least {share['low']:.2g} where "
                f"{share['crossed']} crossed the gap{hi}; the least taken")
    return f"the link-side share assumed (no reversal of the run crossed a gap to bound it from below{hi})"


def _backlash_decides(cr) -> bool:
    """A backlash design decides: a reversal run reaching its power, or a gravity step above the target."""
    if cr.size is not None:       # a motor-side gap is named from the reversals' leads only
        return bool(cr.size["reached"])
    return cr.separation >= DESIGN_TARGET_FLOORS


def _backlash_score(cr) -> float:
    """Between two designs that both decide or both do not: the predicted power of a reversal run, else the
    gravity step's separation over the target (capped at 1)."""
    if cr.size is not None:
        return float(cr.size["power"])
    return min(cr.separation / DESIGN_TARGET_FLOORS, 1.0)


def next_experiment_friction(diag, data, data_path: Path, out_dir: Path, seed: int = 0) -> dict | None:
    """A friction drift against a Stribeck effect (:mod:`wamctl.analysis.diagnosis.friction_design`): for the
    joints whose diagnosis left the two in one ambiguous group, the motion of that joint alone whose two fitted
    models' torques differ most (each refitting its own parameters, friction and an offset), written as
    ``out_dir/next_experiment.yaml``; ``{"spec", "hypotheses", "joint", "joints", "separation_noise_floors",
    "original_separation_noise_floors", "period_s", "periods", "noise_floor_Nm", "fitted", "why", "candidates"}``.
    None when no joint is ambiguous between them; ``spec`` None with ``why`` when no run could be designed."""

    from wamctl.analysis.diagnosis import friction_design as FD

    joints = FD.ambiguous_joints(diag) if diag.joints_ else []
    if not joints:
        return None
    dyn, limits, q0, friction = design_setting(diag, data)
    settle_s = 0.0          # the drift's clock starts with the run: a hold at rest would spend its first seconds
    best, why_not = None, []
    for j in joints:
        res, jd = diag.joints_[j], diag.jd_[j]
        noise = float(res.torque_rms_after_Nm)
        if not np.isfinite(noise) or noise <= 0:
            why_not.append(f"joint {j + 1}: no noise floor (held-out torque RMS) to design against")
            continue
        hyp = FD.fitted_hypotheses(diag.design_, jd, res)
        try:
            nr = FD.design_next_run(dyn, friction, q0, hyp, noise, jd.qd_rad_s, jd.extra["t_rel"], limits,
                                    settle_s=settle_s, seed=seed)
        except ValueError as exc:
            why_not.append(f"joint {j + 1}: {exc} at the run's q0")
            continue
        if best is None or nr.separation["separation"] > best[1].separation["separation"]:
            best = (j, nr, noise, hyp)
    base = {"hypotheses": list(FD.NAMES)}
    if best is None:
        return dict(base, spec=None, why="friction drift or Stribeck: ambiguous; no run designed to tell them: "
                                         + "; ".join(why_not))
    j, nr, noise, hyp = best
    tr = nr.trajectory
    sep, orig_sep = float(nr.separation["separation"]), float(nr.original["separation"])
    t = np.arange(int(tr.period_s * FD.DESIGN_RATE_HZ)) / FD.DESIGN_RATE_HZ
    peak = float(np.abs(tr.evaluate(t)[1][:, j]).max())
    why = (f"joint {j + 1}'s run cannot tell a friction drift (Coulomb x (1 {hyp.c_d[0]:+.2g} (1 - exp(-t / "
           f"{hyp.T_s:.3g} s))), viscous x (1 {hyp.c_d[1]:+.2g} (...))) from a Stribeck effect (friction raised by "
           f"{hyp.c_s[0]:.2g} / {hyp.c_s[1]:.2g} N m per direction below about {hyp.vs_rad_s:.2g} rad/s): "
           f"separation {orig_sep:.2g} noise floors of {noise:.3g} N m; "
           f"moving joint {j + 1} alone through the same slow and fast speeds (up to {peak:.2g} rad/s) "
           f"{nr.periods} times ({tr.period_s:g} s period; a Stribeck effect gives the same torque at the same "
           "speed whenever, a drift one that changes with time at every speed; the drift assumed to start again "
           f"with the run) their predicted torques differ by {sep:.2g} noise floors (RMS per sliding sample, after "
           "each refits its own parameters, friction and an offset)"
           + ("" if sep > DESIGN_TARGET_FLOORS else
              f": still below {DESIGN_TARGET_FLOORS:g}, this run alone cannot decide it"))
    write_next_experiment(data_path, out_dir, tr, tr.q0_rad, [j + 1], int(nr.periods), settle_s, why, seed)
    return dict(base, spec="next_experiment.yaml", joint=j + 1, joints=[j + 1], separation_noise_floors=sep,
                original_separation_noise_floors=orig_sep, period_s=float(tr.period_s), periods=int(nr.periods),
                decisive=sep > DESIGN_TARGET_FLOORS, noise_floor_Nm=noise, why=why,
                fitted={"stribeck": {"excess_Nm": [float(x) for x in hyp.c_s], "vs_rad_s": hyp.vs_rad_s},
                        "friction_drift": {"coefficients": [float(x) for x in hyp.c_d], "T_s": hyp.T_s}},
                candidates=[{"period_s": p, "scale": k, "peak_speed_rad_s": v, "separation_noise_floors": s}
                            for p, k, v, s in nr.scored])


def next_experiment_delay_or_gap(diag, data, data_path: Path, out_dir: Path, seed: int = 0) -> dict | None:
    """A measurement delay against a gap behind a motor-side encoder left ambiguous at a joint's onsets
    (:func:`wamctl.analysis.diagnosis.delay_backlash.settle`): the motion of that joint alone whose reversals come
    at clearly different accelerations (a delay's lag at a reversal grows with them, a gap's lead does not),
    T-optimal among excite's Fourier candidates within its limits (:func:`~wamctl.analysis.diagnosis.
    delay_backlash.design_two_speeds`), written as ``out_dir/next_experiment.yaml``. ``{"spec", "hypotheses",
    "joint", "joints", "delay_s", "gap_rad", "separation_noise_floors", "original_separation_noise_floors",
    "total_noise_floors", "reversals", "period_s", "decisive", "why", "candidates"}``; None when no joint is
    ambiguous between them; ``spec`` None with ``why`` when no run keeps within the limits."""
    from wamctl.analysis.diagnosis import delay_backlash as DB

    joints = DB.ambiguous_joints(diag) if diag.joints_ else []
    if not joints:
        return None
    j = joints[0]
    rec = next((r for r in getattr(diag, "delay_vs_gap_", []) if r.get("joint") == j + 1), {})
    dyn, limits, q0, friction = design_setting(diag, data)
    ons = diag.onsets_.get(j) or {}
    tol = float(ons.get("tol_rad") or 1e-3)
    delay_s = float(rec.get("delay_torque_s") or DB.arm_delay_s(diag) or 0.005)
    gap_rad = max(-float(rec.get("mean_reversal_travel_rad", -BACKLASH_GAP_RAD)), 5 * tol)
    sig = diag.signals_
    idx = diag.jd_[j].idx
    q, qd, qdd = sig.at("q", idx)[:, j], sig.at("qd", idx)[:, j], sig.at("qdd", idx)[:, j]
    orig = DB.separation(DB.reversal_accelerations(q, qd, qdd), delay_s, gap_rad, tol)
    base = {"hypotheses": ["delay", "backlash"], "joint": j + 1, "delay_s": delay_s, "gap_rad": gap_rad}
    try:
        tr, sep, scored = DB.design_two_speeds(dyn, friction, q0, j, limits, delay_s, gap_rad, tol, seed=seed)
    except ValueError as exc:
        return dict(base, spec=None, why=f"delay or backlash at joint {j + 1}: ambiguous; no run designed to tell "
                                         f"them: {exc} at the run's q0")
    s = float(sep["separation"])
    why = (f"joint {j + 1}'s onsets cannot tell a {delay_s * 1e3:.1f} ms measurement delay from a "
           f"{gap_rad * 1e3:.2g} mrad gap behind a motor-side encoder (n log(RSS ratio) "
           f"{rec.get('log_ratio', float('nan')):+.1f}; at the run's reversals they differ by "
           f"{orig['separation']:.2g} detection tolerances of {tol:.2g} rad RMS per reversal); moving joint {j + 1} "
           f"alone ({tr.period_s:g} s period, {tr.harmonics} harmonics, {DB.DESIGN_PERIODS} periods) its "
           f"{sep['reversals']} reversals "
           "come at different accelerations: a delay's lag grows with the acceleration, a gap's lead does not; "
           f"their predicted leads differ by {s:.2g} tolerances RMS per reversal ({sep['total']:.2g} over the run), "
           "after each refits its own width or delay")
    decisive = bool(sep["total"] >= DESIGN_TARGET_FLOORS)
    if not decisive:
        why += f"; still below {DESIGN_TARGET_FLOORS:g} over the run: a longer run is needed to tell them"
    write_next_experiment(data_path, out_dir, tr, q0, [j + 1], DB.DESIGN_PERIODS, 1.0, why, seed)
    return dict(base, spec="next_experiment.yaml", joints=[j + 1], separation_noise_floors=s,
                original_separation_noise_floors=float(orig["separation"]), total_noise_floors=float(sep["total"]),
                reversals=int(sep["reversals"]), period_s=float(tr.period_s), decisive=decisive, why=why,
                candidates=[{"period_s": p, "separation_noise_floors": v} for p, v in scored])


def next_experiment_more(diag, data, data_path: Path, out_dir: Path, seed: int = 0) -> dict | None:
    """The next experiments beyond the payload against link errors, in turn: a delay against a motor-side gap left
    ambiguous at a joint's onsets (:func:`next_experiment_delay_or_gap`), a delay against inertia errors
    (:func:`next_experiment_delay`), a friction drift against a Stribeck effect (:func:`next_experiment_friction`),
    then a gap behind a motor-side encoder (:func:`next_experiment_backlash`)."""
    gap = next_experiment_delay_or_gap(diag, data, data_path, out_dir, seed)
    if gap is not None and gap.get("spec"):
        return gap
    out = next_experiment_delay(diag, data, data_path, out_dir, seed)
    if out is not None and out.get("spec"):
        return out
    fr = next_experiment_friction(diag, data, data_path, out_dir, seed)
    if fr is not None and fr.get("spec"):
        return fr
    more = next_experiment_backlash(diag, data, data_path, out_dir, seed=seed)
    return more if (more is not None and more.get("spec")) else (gap or out or fr or more)
