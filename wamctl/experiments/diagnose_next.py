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


def backlash_suspects(diag) -> list[int]:
    """0-based joints where a gap behind a motor-side encoder cannot be excluded and the diagnosis left it open,
    most suspect first:

    * the backlash onset test saw the measurement lead the link at reversals by at least the test's resolution
      (``MIN_BAND_TOLERANCES`` detection tolerances) with a p-value below ``SUSPECT_P`` but not below the
      diagnosis' threshold (issue 28: "an effect is suspected but its parameters are not identified"; a run with
      few reversals cannot decide it, a run with more can), smallest p-value first;
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
        g = dyn.gravity_many(diag.signals_.at("q", jd.idx[:: max(1, len(jd.idx) // 400)]))[:, j]
        if len(g) and (g.min() > 0 or g.max() < 0):
            out.append(j)
    return sorted(leads, key=lambda j: leads[j][0]) + out


def _leading_joints(diag) -> dict[int, tuple[float, float]]:
    """{0-based joint: (p-value, lead rad)} where the backlash onset test, not kept, saw the measurement lead the
    link at reversals (a gap on the motor side) by at least ``MIN_BAND_TOLERANCES`` detection tolerances with a
    p-value below ``SUSPECT_P``."""
    from wamctl.analysis.diagnosis.backlash import MIN_BAND_TOLERANCES

    out = {}
    for j, res in diag.joints_.items():
        c = res.candidates.get("backlash") or {}
        p = c.get("p_value")
        lead = _motor_lead_rad(diag, j)
        if (c.get("kept") or c.get("encoder_side") != "motor" or p is None or not p < SUSPECT_P or lead is None
                or any(t["name"] == "backlash" for t in res.kept)):
            continue
        if lead >= MIN_BAND_TOLERANCES * diag.onsets_[j]["tol_rad"]:
            out[j] = (float(p), float(lead))
    return out


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
    """A gap behind a motor-side encoder against nothing (:mod:`wamctl.analysis.diagnosis.backlash_design`): for
    the suspected ``joints`` (0-based; default :func:`backlash_suspects`, most suspect first) the slow
    back-and-forth of the joint alone that shows a gap of ``gap_rad`` best, about the pose where its gravity
    torque changes sign (the link falls through the gap: a torque step) or where it rests on its own friction at
    the reversals (the measurement leads the link by the gap), written as ``out_dir/next_experiment.yaml``; the
    first suspect whose design reaches ``DESIGN_TARGET_FLOORS`` (else the best). ``{"spec", "hypotheses",
    "joint", "gap_rad", "separation_noise_floors", "original_separation_noise_floors", "seen_by", "reversals",
    "joints", "period_s", "crossing_pose_rad", "gravity_slope_Nm_rad", "noise_floor_Nm", "why"}``. None when no
    joint is suspected; ``spec`` None with ``why`` when no crossing keeps within the limits."""

    from wamctl.analysis.diagnosis.backlash import MIN_BAND_TOLERANCES, MIN_REVERSALS
    from wamctl.analysis.diagnosis.backlash_design import CROSSING_PERIODS, LINK_FRICTION_SHARE, design_crossing
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
        tol = (getattr(diag, "onsets_", {}).get(j) or {}).get("tol_rad") or detection_tolerance(sig, j)[1]
        f = diag.friction_after(j)
        fc = min(f["fc_pos_Nm"], f["fc_neg_Nm"])
        try:
            cr = design_crossing(dyn, friction, q0, j, gap_rad, noise, limits, sig.at("q", idx), sig.at("qd", idx),
                                 tol_rad=float(tol), fc_Nm=max(float(fc), 0.0), run_qdd=sig.at("qdd", idx))
        except ValueError as exc:
            why_not.append(f"joint {j + 1}: {exc}")
            continue
        rv0, lead_rad = cr.reversals_original, _motor_lead_rad(diag, j)
        if (cr.seen_by == "reversals" and j not in leads and rv0 is not None and rv0[1] >= 2 * MIN_REVERSALS
                and rv0[0] > DESIGN_TARGET_FLOORS and lead_rad is not None and lead_rad < MIN_BAND_TOLERANCES * tol):
            # the run's own reversals were chances enough for a gap to show: the measurement did not lead
            why_not.append(f"joint {j + 1}: at the run's own {rv0[1]} reversals where the link rests on its own "
                           f"friction ({rv0[0]:.2g} noise floors for a {gap_rad * 1e3:g} mrad gap) the measurement "
                           f"led by {max(lead_rad, 0.0) * 1e3:.2g} mrad, below the backlash test's resolution")
            continue
        if best is None or cr.separation > best[1].separation:
            g = dyn.gravity_many(sig.at("q", idx))[:, j]
            best = (j, cr, noise, bool(g.min() > 0 or g.max() < 0), float(tol), float(fc))
        if cr.separation >= DESIGN_TARGET_FLOORS:       # the most suspect joint that the design can show
            break
    base = {"hypotheses": ["backlash", "none"], "gap_rad": gap_rad}
    if best is None:
        return dict(base, spec=None, why="no run designed to show a gap behind the encoder: " + "; ".join(why_not))
    j, cr, noise, one_sign, tol, fc = best
    tr = cr.trajectory
    seen = ("kept one sign over the run, so a gap behind a motor-side encoder was never crossed" if one_sign else
            "changed sign over the run")
    rv, rv0 = cr.reversals, cr.reversals_original
    if cr.seen_by == "reversals":
        run_part = (f"the run's {rv0[2]} reversals, {rv0[1]} of them where the link rests on its own friction, "
                    f"{cr.original:.2g} noise floors" if rv0 else "")
        qj = tr.evaluate(np.linspace(0.0, tr.period_s, 201))[0][:, j]
        how = (f"moving joint {j + 1} alone slowly ({tr.period_s:g} s period, {CROSSING_PERIODS} periods) between "
               f"{qj.min():.3f} and {qj.max():.3f} rad, the link comes to rest on its own friction at {rv[1]} of its "
               f"{rv[2]} "
               f"reversals (the torque the rigid link needs there below {LINK_FRICTION_SHARE:g} of the joint's "
               f"{fc:.3g} N m Coulomb level, the share assumed on the link side) and the motor crosses the gap "
               f"before it drives the link back: the measurement leads the link by the gap, {cr.separation:.2g} "
               f"noise floors RMS per reversal (the floor: the backlash test's resolution, {MIN_BAND_TOLERANCES:g} "
               f"detection tolerances of {tol:.2g} rad); the gravity step there {cr.torque_separation:.2g} noise "
               "floors")
        lead = leads.get(j)
        trigger = (f"joint {j + 1}'s measurement led the link by {lead[1] * 1e3:.2g} mrad at reversals, too few to "
                   f"decide (onset test p = {lead[0]:.2g}, not below the threshold {diag.threshold_:.2g})"
                   if lead else f"joint {j + 1}'s residual was left structured and unexplained with nothing named "
                   "there; a gap behind a motor-side encoder is one of what it could be")
        why = (f"{trigger} ({run_part}; a {gap_rad * 1e3:g} mrad gap); {how} (the run starts at that pose: move "
               "the arm there first)")
    else:
        why = (f"joint {j + 1}'s gravity torque {seen} (a {gap_rad * 1e3:g} mrad gap: separation {cr.original:.2g} "
               f"noise floors of {noise:.3g} N m); moving joint {j + 1} slowly ({tr.period_s:g} s period) about "
               f"{tr.q0_rad[j]:.3f} rad, where its "
               f"gravity torque changes sign ({cr.slope_Nm_rad:.3g} N m/rad), the link falls through the gap at each "
               f"crossing: the residual steps by {gap_rad * cr.slope_Nm_rad:.2g} N m, {cr.separation:.2g} noise "
               "floors RMS after friction and an offset are refitted (the run starts at the crossing pose: move the "
               "arm there first)")
    if cr.separation <= DESIGN_TARGET_FLOORS:
        why += f"; still below {DESIGN_TARGET_FLOORS:g}: only a larger gap would show on this joint"
    write_next_experiment(data_path, out_dir, tr, tr.q0_rad, [j + 1],
                          CROSSING_PERIODS if cr.seen_by == "reversals" else 3, 1.0, why, seed)
    return dict(base, spec="next_experiment.yaml", joint=j + 1, joints=[j + 1],
                separation_noise_floors=float(cr.separation), original_separation_noise_floors=float(cr.original),
                seen_by=cr.seen_by,
                reversals={"crossing": rv[1], "all": rv[2]} if rv is not None and cr.seen_by == "reversals" else None,
                period_s=float(tr.period_s), crossing_pose_rad=[float(x) for x in tr.q0_rad],
                gravity_slope_Nm_rad=float(cr.slope_Nm_rad), noise_floor_Nm=noise, why=why)


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


def next_experiment_more(diag, data, data_path: Path, out_dir: Path, seed: int = 0) -> dict | None:
    """The next experiments beyond the payload against link errors, in turn: a delay against inertia errors
    (:func:`next_experiment_delay`), a friction drift against a Stribeck effect (:func:`next_experiment_friction`),
    then a gap behind a motor-side encoder (:func:`next_experiment_backlash`)."""
    out = next_experiment_delay(diag, data, data_path, out_dir, seed)
    if out is not None and out.get("spec"):
        return out
    fr = next_experiment_friction(diag, data, data_path, out_dir, seed)
    if fr is not None and fr.get("spec"):
        return fr
    more = next_experiment_backlash(diag, data, data_path, out_dir, seed=seed)
    return more if (more is not None and more.get("spec")) else (out or fr or more)
