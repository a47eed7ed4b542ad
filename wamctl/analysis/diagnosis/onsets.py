"""A joint's onsets under a model of it: torque available, hidden travel, breakaway levels, stall residual (no I/O).

An onset is a measured stall followed by motion (:func:`wamctl.analysis.diagnosis.backlash.find_onsets`).
Through each stall the joint's own dynamics are integrated with the torque available to it,
``u = tau - rnea_j(q, qd, qdd with the joint's own velocity and acceleration zeroed)``, and the model's
friction (:func:`wamctl.analysis.diagnosis.backlash.hidden_travel`): the travel the model predicts before the
measurement moved, and the breakaway level the joint withstood.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from wamctl.analysis.diagnosis.backlash import (
    MIN_BAND_TOLERANCES,
    breakaway_ratio,
    find_onsets,
    hidden_travel,
    resolution_rad,
    signed_travel,
)
from wamctl.analysis.diagnosis.candidates import MAX_BREAKAWAY_RATIO, STRIBECK_VS_GRID_RAD_S, ripple_harmonics
from wamctl.analysis.diagnosis.design import Design, block_of, levels, levels_dict
from wamctl.analysis.diagnosis.prepare import link_base_rows
from wamctl.analysis.diagnosis.signals import Signals, delayed
from wamctl.model.dynamics import Payload, WamDynamics
from wamctl.model.effects import friction_drift_scale, ripple_torque_Nm

EXTEND_SAMPLES = 100        # samples of the slip kept after each stall (the slip velocity is fitted on them)
# where the model's link has not moved within them (a slow reversal through a gap: the measurement leads by more
# than the window), the window is extended up to this long, never into the next onset, before the onset is given up
EXTEND_MAX_S = 1.0
MAX_ONSETS = 250            # onsets analysed per joint at most


@dataclass
class OnsetModel:
    """A joint's model as it acts at onsets.

    Attributes
    ----------
    friction : classic friction levels by name (absolute; at t = 0 when friction drifts).
    fs_ratio : (positive, negative) breakaway / Coulomb of a kept Stribeck effect, else None.
    drift, ripple : parameters of a kept friction drift / position ripple, else None.
    dynamics : the rigid body with a kept payload (else the declared one).
    delay_s : the delay of the measurement (declared plus kept).
    delay_declared_s : its declared part.
    links : (base columns, coefficients) of a kept ``link_parameters`` refit (the torque it adds), else None.
    """

    friction: dict
    fs_ratio: tuple[float, float] | None
    drift: dict | None
    ripple: dict | None
    dynamics: WamDynamics
    delay_s: float
    delay_declared_s: float
    links: tuple[np.ndarray, np.ndarray] | None = None


def stribeck_ratio(p: dict) -> tuple[float, float]:
    """(positive, negative) breakaway / reference Coulomb level (:func:`breakaway_reference_Nm`) of Stribeck
    parameters ``p`` (see ``effect_params``)."""
    ref = breakaway_reference_Nm(p["Fc_pos_Nm"], p["Fc_neg_Nm"])
    return p["Fs_pos_Nm"] / ref[0], p["Fs_neg_Nm"] / ref[1]


def payload_dynamics(declared: Payload | None, found: dict, robot=None) -> WamDynamics:
    """The rigid body of ``robot`` (default the wam7) carrying the declared payload and the one found
    (``mass_kg``, ``com_m``) together."""
    if declared is None:
        return WamDynamics(Payload(found["mass_kg"], tuple(found["com_m"])), robot=robot)
    m = declared.mass_kg + found["mass_kg"]
    com = (declared.mass_kg * np.asarray(declared.com_m) + found["mass_kg"] * np.asarray(found["com_m"])) / m
    return WamDynamics(Payload(m, tuple(com)), robot=robot)


def onset_model(diag, j: int, declared: bool = False, exclude: tuple[str, ...] = ()) -> OnsetModel:
    """The model of 0-based joint ``j`` of a fitted ``ModelDiagnosis`` at onsets: the final one (its kept
    effects but ``exclude``), or with ``declared`` the declared model fitted."""
    if declared:
        fr = levels_dict(levels(diag.declared_.friction, j, diag.jd_[j].extra["theta_before"]))
        kept = {}
    else:
        fr = diag.friction_after(j)
        kept = {t["name"]: t for t in diag.joints_[j].kept if t["name"] not in exclude}

    def params(name):
        return diag.effect_params(j, name) if name in kept else None

    stri = params("stribeck")
    dyn = diag.dynamics_
    if "payload" in kept and diag.payload_ is not None:
        dyn = payload_dynamics(diag.payload_declared_, diag.payload_, diag.dynamics_.robot)
    delay_decl = diag.declared_.delay_s
    delay = delay_decl + (params("delay")["delay_s"] if "delay" in kept else 0.0)
    des = diag.design_
    links = (des.links_cols, des.links_beta[None]) if "link_parameters" in kept and None in des.links_beta else None
    return OnsetModel(fr, stribeck_ratio(stri) if stri else None, params("friction_drift"),
                      params("position_ripple"), dyn, delay, delay_decl, links)


def detection_tolerance(sig: Signals, j: int) -> tuple[float, float]:
    """(encoder step, tolerance) rad: the measurement has moved once it left the stall value by two encoder
    steps (or four noise sigmas)."""
    # measured samples only: a gap's interpolated stretch would add steps finer than a count
    quantum = sig.memo(("resolution_rad", j), lambda: resolution_rad(sig.q_raw_rad[sig.usable(), j]))
    return quantum, max(2.0 * quantum, 4.0 * float(sig.q_noise_rad[j]), 1e-6)


def joint_onsets(des: Design, dyn0: WamDynamics, jd, model: OnsetModel, extend: int = EXTEND_SAMPLES) -> dict:
    """Hidden travel and breakaway ratio at every onset of the joint of ``jd`` under ``model``.

    ``dyn0`` is the declared rigid body (``des.rnea_Nm``'s). The torque available uses the model with its
    kept effects (payload in the rigid body, ripple added), and the friction levels are scaled by a kept
    drift at the onset's time. Onsets are dealt into the folds of the joint's blocks they fall in.

    Returns
    -------
    dict of (k,) arrays over the k onsets: ``travel_rad`` (the signed hidden travel,
    :func:`~wamctl.analysis.diagnosis.backlash.signed_travel`), ``reversal``, ``t_s``, ``fold``,
    ``breakaway_ratio`` (against :func:`breakaway_reference_Nm`), ``breakaway_Nm`` (the level the joint withstood
    in its new direction), ``sign``; and ``resolution_rad``, ``tol_rad``, ``windows`` (per onset: the torques,
    inertia, friction, measured travel of its window, the turning point ``q_turn`` and the sample ``moved`` where
    the model's link has moved by the tolerance).
    """
    sig, j = des.sig, jd.j
    q_raw = sig.q_raw_rad[:, j]
    quantum, tol = detection_tolerance(sig, j)
    cache = jd.extra.setdefault("_onsets", {})
    if tol not in cache:     # the measured onsets depend on the signals only
        ons = find_onsets(sig.t_s, q_raw, sig.qd_rad_s[:, j], float(sig.v_stick_rad_s[j]), tol, 2 * sig.reach)
        if sig.valid is not None:          # an onset whose window reaches into a gap of the log is left out
            ons = [o for o in ons if sig.valid[max(min(o.start, o.turn if o.turn >= 0 else o.start)
                                                   - 2 * sig.reach, 0):o.end + extend].all()]
        if len(ons) > MAX_ONSETS:          # a long run: evenly spread over it, plenty for the tests
            ons = [ons[i] for i in np.unique(np.linspace(0, len(ons) - 1, MAX_ONSETS).round().astype(int))]
        cache[tol] = ons
    ons = cache[tol]
    tau_c = sig.tau_centred_Nm[:, j]           # aligned to the zero-order hold, as for the sliding residual
    tau_c_decl = delayed(sig.t_s, tau_c, model.delay_declared_s) if model.delay_declared_s > 0 else tau_c
    if model.delay_s > 0:   # positions measured d late: the torque that moved the link to q_meas(t) acted at t - d
        tau_c = delayed(sig.t_s, tau_c, model.delay_s)
    travel, ratio, level, windows = [], [], [], []
    # the smoothed state the windows need, evaluated at once (a long run has no full-rate arrays)
    spans = [np.arange(o.start, min(o.end + extend, sig.n)) for o in ons]
    cut = np.cumsum([0] + [len(ii) for ii in spans])
    qdd_all = sig.smooth_at(sig.q_raw_rad[:, j], np.concatenate(spans), 0.0, 2) if ons else np.zeros(0)
    q_ends = sig.at("q", np.array([o.end for o in ons], int)) if ons else np.zeros((0, 7))
    long_n = max(int(EXTEND_MAX_S / sig.dt_s), extend)
    for k, o in enumerate(ons):
        state = {"ii": spans[k], "qdd_j": qdd_all[cut[k]:cut[k + 1]], "q_end": q_ends[k]}
        w = _onset_window(des, dyn0, j, o, model, tau_c, tau_c_decl, state)
        stall = o.end - o.start
        f = w["friction"]
        ref = breakaway_reference_Nm(f["fc_pos_Nm"], f["fc_neg_Nm"])
        fsp = ref[0] * model.fs_ratio[0] if model.fs_ratio else None
        fsn = ref[1] * model.fs_ratio[1] if model.fs_ratio else None
        x = travel_with(w["u"], sig.dt_s, w["inertia"], f, fsp, fsn)
        moved = np.flatnonzero(o.sign_new * x >= tol)
        stop = min(o.end + long_n, sig.n, ons[k + 1].start if k + 1 < len(ons) else sig.n)
        if sig.valid is not None:              # nor into a gap of the log
            bad = np.flatnonzero(~sig.valid[o.end:stop])
            stop = o.end + int(bad[0]) if len(bad) else stop
        if not len(moved) and stop > spans[k][-1] + 1:
            # the model's link still at rest at the window's end: the same onset over a longer window
            ii = np.arange(o.start, stop)
            state = {"ii": ii, "qdd_j": sig.smooth_at(sig.q_raw_rad[:, j], ii, 0.0, 2), "q_end": q_ends[k]}
            w = _onset_window(des, dyn0, j, o, model, tau_c, tau_c_decl, state)
            x = travel_with(w["u"], sig.dt_s, w["inertia"], f, fsp, fsn)
            moved = np.flatnonzero(o.sign_new * x >= tol)
        w["moved"] = int(moved[0]) if len(moved) else len(x)
        travel.append(signed_travel(x, w["q"], stall, w["q_turn"], o.sign_new, tol))
        # a direction whose level was floored (no sliding samples that way) holds the joint at the new direction's
        # reference in the other direction's stalls: its own breakaway is not what they measure
        kern = list(ref)
        d = 0 if o.sign_new > 0 else 1
        if ref[1 - d] > max(f["fc_pos_Nm" if d == 1 else "fc_neg_Nm"], 1e-6):
            kern[1 - d] = max(ref[1 - d], ref[d])
        rho = breakaway_ratio(w["u"][:stall], sig.dt_s, w["inertia"], kern[0], kern[1], f["viscous_pos_Nm_s_rad"],
                              f["viscous_neg_Nm_s_rad"], tol)
        ratio.append(rho)
        level.append(rho * ref[0 if o.sign_new > 0 else 1])
        windows.append(w)
    t_on = np.asarray([o.t_s for o in ons])
    return {"travel_rad": np.asarray(travel), "reversal": np.asarray([o.reversal for o in ons], bool),
            "t_s": t_on, "fold": block_of(jd, t_on) % des.n_folds, "breakaway_ratio": np.asarray(ratio),
            "breakaway_Nm": np.asarray(level, float),
            "sign": np.asarray([o.sign_new for o in ons]), "resolution_rad": quantum, "tol_rad": tol,
            "windows": windows}


def _onset_window(des: Design, dyn0: WamDynamics, j: int, o, model: OnsetModel, tau_c: np.ndarray,
                  tau_c_decl: np.ndarray, state: dict) -> dict:
    """Torque available (final and declared model), inertia, friction and measured travel through onset
    ``o`` (a :class:`wamctl.analysis.diagnosis.backlash.Onset`) and the samples after it: ``state`` holds the
    window's samples ``ii``, the joint's smoothed acceleration there ``qdd_j`` and the position ``q_end``."""
    sig = des.sig
    q_raw = sig.q_raw_rad[:, j]
    ii, q_end = state["ii"], state["q_end"]
    # the declared inertia at the onset's end: the same for every model tested at this onset (kept per onset)
    kept = sig.memo(("onset_b_jj", id(dyn0), j), lambda: (dyn0, {}))[1]     # dyn0 held: its id stays its own
    if o.end not in kept:
        kept[o.end] = float(dyn0.mass_matrix(q_end)[j, j])
    b_jj = kept[o.end]
    # the rigid body without the joint's own acceleration (its velocity is ~0 in a stall)
    rigid = des.rnea_Nm[ii, j] - b_jj * state["qdd_j"] + des.known_other_Nm[ii, j]
    u_decl = tau_c_decl[ii] - rigid
    u = tau_c[ii] - rigid
    dyn = model.dynamics
    if dyn is not dyn0:
        u = u - _payload_torque(dyn, dyn0, sig, ii, j)
    if model.links is not None:
        u = u - _links_torque(model.links, dyn0, sig, ii, j)
    if model.ripple:
        amps, phases = ripple_harmonics(model.ripple)
        u += ripple_torque_Nm(q_raw[ii], amps, 2 * np.pi / model.ripple["period_rad"], phases)
    scale = 1.0
    if model.drift:
        scale = float(friction_drift_scale(o.t_s - sig.t_s[0], model.drift["fraction"],
                                           model.drift["time_constant_s"]))
    f = {k: max(v, 0.0) * scale for k, v in model.friction.items()}
    inertia = b_jj if dyn is dyn0 else float(dyn.mass_matrix(q_end)[j, j])
    turn = o.turn if o.turn >= 0 else o.start
    return {"u": u, "u_declared": u_decl, "inertia": inertia, "friction": f, "start": o.start,
            "end": o.end, "sign": o.sign_new, "q": q_raw[ii] - q_raw[o.start], "reversal": o.reversal,
            "t_s": o.t_s, "q_turn": float(q_raw[turn] - q_raw[o.start])}


def _payload_torque(dyn: WamDynamics, dyn0: WamDynamics, sig: Signals, ii: np.ndarray, j: int) -> np.ndarray:
    """(len(ii),) torque a kept payload adds at joint ``j`` along samples ``ii`` (the joint's own velocity and
    acceleration zeroed), computed every fifth sample (10 ms at 500 Hz) and interpolated."""
    pts = np.unique(np.r_[ii[::5], ii[-1]])
    Q, QD, QDD = sig.at("q", pts), sig.at("qd", pts).copy(), sig.at("qdd", pts).copy()
    QD[:, j] = QDD[:, j] = 0.0
    extra_t = [dyn.inverse_dynamics(Q[k], QD[k], QDD[k])[j] - dyn0.inverse_dynamics(Q[k], QD[k], QDD[k])[j]
               for k in range(len(pts))]
    return np.interp(ii, pts, extra_t)


def _links_torque(links: tuple[np.ndarray, np.ndarray], dyn0: WamDynamics, sig: Signals, ii: np.ndarray,
                  j: int) -> np.ndarray:
    """(len(ii),) torque a kept link refit (base columns, coefficients) adds at joint ``j`` along samples ``ii``
    (the joint's own velocity and acceleration zeroed), computed every fifth sample (10 ms at 500 Hz) and
    interpolated."""
    cols, beta = links
    pts = np.unique(np.r_[ii[::5], ii[-1]])
    Q, QD, QDD = sig.at("q", pts), sig.at("qd", pts).copy(), sig.at("qdd", pts).copy()
    QD[:, j] = QDD[:, j] = 0.0
    rows = np.array([dyn0.regressor_basis(Q[k], QD[k], QDD[k])[j] for k in range(len(pts))])
    extra_t = link_base_rows(rows, np.zeros(len(pts)), j)[:, cols] @ beta
    return np.interp(ii, pts, extra_t)


def travel_with(u_Nm: np.ndarray, dt_s: float, inertia: float, f: dict, fs_pos: float | None = None,
                fs_neg: float | None = None, vs_rad_s: float = 0.0) -> np.ndarray:
    """:func:`hidden_travel` (m,) with the classic friction levels ``f`` by name."""
    return hidden_travel(u_Nm, dt_s, inertia, f["fc_pos_Nm"], f["fc_neg_Nm"], f["viscous_pos_Nm_s_rad"],
                         f["viscous_neg_Nm_s_rad"], fs_pos, fs_neg, vs_rad_s=vs_rad_s)


# ---------------------------------------------------------------------------------------------- levels
# a direction's reference Coulomb level is at least this share of the other direction's: below the asymmetry of
# real drives (Table 4.1's most uneven joint, 7: 0.054 against 0.137 N m, 0.39), so a level the sliding samples
# determine is its own reference
REFERENCE_SHARE = 0.2


def breakaway_reference_Nm(fc_pos_Nm: float, fc_neg_Nm: float) -> tuple[float, float]:
    """(positive, negative) Coulomb levels the breakaway ratios are measured against: the model's, each at least
    ``REFERENCE_SHARE`` of the other direction's (and 1 uN m).

    A joint that only sticks and slips one way leaves few or no sliding samples in that direction, and the
    fitted level there is anything down to its bound, zero (seed 11's joint 3: 2.87 N m from 21 samples, 0 once
    one encoder count moved them below the stick speed). A ratio against such a level is unbounded (it was cut
    at ``hi`` = 10), while the torque the joint withstood, ratio times reference, hardly depends on the
    reference (3.84 to 3.95 N m for references from 2.9 to 0.5 N m there): the breakaway levels in N m
    (``breakaway_Nm``) are the estimate, the ratios the test's scale."""
    lo = 1e-6
    return (max(float(fc_pos_Nm), REFERENCE_SHARE * float(fc_neg_Nm), lo),
            max(float(fc_neg_Nm), REFERENCE_SHARE * float(fc_pos_Nm), lo))


def direction_levels_Nm(ons: dict, sign: float, use: np.ndarray) -> np.ndarray:
    """Breakaway levels (m,) N m of direction ``sign`` the joint withstood at the onsets ``use`` (k,) bool: its
    estimate is their geometric mean (with two or more), its interval :func:`level_bootstrap`'s.

    The detection adds a bias the interval does not hold: the measurement is seen to move a sample or two after
    the joint broke away, when the torque has risen further (+9 % and +13 % on test_diagnose's seed 11)."""
    lv = np.asarray(ons["breakaway_Nm"], float)
    m = np.asarray(use, bool) & (ons["sign"] == sign) & np.isfinite(lv) & (lv > 0)
    return lv[m]


def level_bootstrap(levels: dict, n_boot: int, rng: np.random.Generator) -> dict:
    """{direction: (n_boot,) geometric means of its breakaway levels ``levels[direction]`` (m,) resampled with
    replacement}, for the directions with two levels or more."""
    out = {}
    for key, lv in levels.items():
        lg = np.log(np.asarray(lv, float))
        if len(lg) >= 2:
            out[key] = np.exp(lg[rng.integers(0, len(lg), size=(n_boot, len(lg)))].mean(axis=1))
    return out


def geometric_mean(x: np.ndarray) -> float:
    """Geometric mean of positive values (k,) (breakaway ratios: a ratio and its inverse weigh alike)."""
    return float(np.exp(np.mean(np.log(x))))


def direction_breakaway_ratio(ons: dict, sign: float, fold: int | None = None) -> float | None:
    """Breakaway ratio (geometric mean) of direction ``sign`` at the onsets usable for it
    (``ons["use_breakaway"]``), outside fold ``fold`` when given; None when fewer than two."""
    use = ons.get("use_breakaway")
    if use is None:
        return None
    m = use & (ons["sign"] == sign)
    if fold is not None:
        m &= ons["fold"] != fold
    if m.sum() < 2:
        return None
    return float(np.clip(geometric_mean(ons["breakaway_ratio"][m]), 1.0, MAX_BREAKAWAY_RATIO))


def slip_vs(windows: list[dict], dt_s: float, ratio: float) -> float | None:
    """Stribeck velocity that best reproduces the measured slips after each same-direction breakaway
    (``windows`` of :func:`joint_onsets`; the joint integrated open-loop from rest with the logged torque,
    ``Fs = ratio Fc``); None without same-direction onsets."""
    wins = [w for w in windows if not w["reversal"]]
    if not wins:
        return None
    best, arg = np.inf, None
    for vs in STRIBECK_VS_GRID_RAD_S:
        ssr = 0.0
        for w in wins:
            f = w["friction"]
            x = travel_with(w["u"], dt_s, w["inertia"], f, ratio * f["fc_pos_Nm"], ratio * f["fc_neg_Nm"], vs)
            err = x - w["q"]
            ssr += float(err @ err)
        if ssr < best:
            best, arg = ssr, float(vs)
    return arg


# ---------------------------------------------------------------------------------------------- stalls
def stall_residual(diag, j: int, ons: dict, after: bool) -> np.ndarray:
    """Torque residual (m,) at the samples where the measured joint stood still at an onset.

    At rest, friction is set-valued: anything up to the breakaway level. The model is wrong at a stall
    sample when its link, integrated from rest through the stall with the applied torque, has already
    moved further than the measurement allows (two encoder steps; plus the dead band for a model with
    backlash behind the encoder): the residual there is the torque beyond the level the model holds a joint
    with. The declared model uses its Coulomb levels; the augmented one its breakaway levels, dead band, and
    the torque of its other effects. Breakaway ratio and dead band come from the onsets of the other folds.
    On a joint where a gap on the motor side was found (the measurement leads the link), the windows run on
    while the model's link is at rest, and a sample also counts where the measurement has moved further from
    its turning point than the model's link, by more than the backlash test resolves (plus the gap, for the
    augmented model): the residual there is the torque short of the breakaway level. Elsewhere a model whose
    link starts late is not counted (a breakaway level fitted too high is the Stribeck tests' to judge).
    Sets the stall samples' times on the joint's result (``stall_t``).
    """
    sig, res = diag.signals_, diag.joints_[j]
    if not ons["windows"]:
        return np.zeros(0)
    kept = {t["name"]: t for t in res.kept} if after else {}
    p_ratio = stribeck_ratio(diag.effect_params(j, "stribeck")) if "stribeck" in kept else None
    fb = diag.friction_before(j)
    leads = any(t["name"] == "backlash" and t.get("encoder_side") == "motor" for t in res.kept)
    out = []
    stops = [stall_stop(w, leads) for w in ons["windows"]]
    res.stall_t = np.concatenate([sig.t_s[w["start"]:w["start"] + m] for w, m in zip(ons["windows"], stops)])
    for w, f_on, m in zip(ons["windows"], ons["fold"], stops):
        if after:       # a Stribeck effect's ratios against the reference levels the onsets measured them with
            u, f = w["u"][:m], w["friction"]
            ratio, band = _held_out_levels(ons, w, int(f_on), kept, p_ratio)
            ref = breakaway_reference_Nm(f["fc_pos_Nm"], f["fc_neg_Nm"]) if "stribeck" in kept \
                else (f["fc_pos_Nm"], f["fc_neg_Nm"])
        else:
            u, f = w["u_declared"][:m], {k: max(v, 0.0) for k, v in fb.items()}
            ratio, band = (1.0, 1.0), 0.0
            ref = (f["fc_pos_Nm"], f["fc_neg_Nm"])
        fsp, fsn = ratio[0] * ref[0], ratio[1] * ref[1]
        x = travel_with(u, sig.dt_s, w["inertia"], f, fsp, fsn)
        turn = (w["q_turn"], w["end"] - w["start"] if leads else -1)
        out.append(stall_gap_residual(u, x, w["q"][:m], w["sign"], ons["tol_rad"], band, fsp, fsn, turn))
    return np.concatenate(out) if out else np.zeros(0)


def stall_stop(w: dict, leads: bool = True) -> int:
    """Samples of an onset window ``w`` the stall residual covers: until the measurement moved (``end``), and
    with ``leads`` on while the model's link has not moved by the tolerance (before ``moved``)."""
    stall = w["end"] - w["start"]
    return int(min(max(stall, w.get("moved", 0)), len(w["u"]))) if leads else stall


def _held_out_levels(ons: dict, w: dict, fold: int, kept: dict,
                     p_ratio: tuple[float, float] | None) -> tuple[tuple[float, float], float]:
    """(breakaway ratio per direction, signed dead band) of the final model at onset window ``w`` of ``fold``:
    from the onsets of the other folds where they give them, else from the fit on all data (``p_ratio``). The
    band is positive behind the encoder (the measurement lags), negative for a gap on the motor side."""
    fold_coef = ons.get("fold_coef", {})
    ratio = (1.0, 1.0)
    if "stribeck" in kept:
        r = fold_coef.get("stribeck", {}).get(fold)
        ratio = p_ratio if r is None else (float(np.exp(r)),) * 2
        held_out = [direction_breakaway_ratio(ons, sgn, fold) for sgn in (1.0, -1.0)]
        ratio = tuple(rr if h is None else h for h, rr in zip(held_out, ratio))
    band = 0.0
    if "backlash" in kept and w["reversal"]:
        t = kept["backlash"]
        side = -1.0 if t.get("encoder_side") == "motor" else 1.0
        wf = fold_coef.get("backlash", {}).get(fold)
        # a fold whose training onsets hold no reversal has no band of its own: the fit on all onsets
        band = side * max(side * wf if wf is not None and np.isfinite(wf) else t["width_rad"], 0.0)
    return ratio, band


def stall_gap_residual(u: np.ndarray, x: np.ndarray, q: np.ndarray, sign: float, tol: float, band: float,
                       fs_pos: float, fs_neg: float, turn: tuple[float, int] = (0.0, -1)) -> np.ndarray:
    """Torque residual (m,) of one stall: ``u`` (m,) torque available, ``x`` (m,) the model's travel, ``q`` (m,)
    the measured one, ``sign`` the new direction, ``band`` a dead band (positive: behind the encoder; negative:
    a gap on the motor side), ``fs_*`` the breakaway levels, ``turn`` the measured turning point (relative to the
    window's start) and the first sample where the measurement has left the stall (-1: none in the window).

    Model ahead: both travels are counted from the sample before the model moved by half the tolerance (the
    window opens while the joint may still settle by a count or two); travel toward the new direction may use
    a dead band behind the encoder, back along the old one may not; the residual is the torque beyond the
    breakaway level. Measurement ahead (once it has left the stall, within which it is still by a count or two,
    and while the model's link is at rest): its travel from the turning point beyond the model's, less the
    resolution of the backlash test (``MIN_BAND_TOLERANCES`` tolerances: a light joint's measurement may lead the
    model by a sample or two), may use a gap on the motor side; the residual is the torque short of the breakaway
    level of the new direction. Else zero."""
    away = np.flatnonzero(np.abs(x) > 0.5 * tol)
    k0 = max(away[0] - 1, 0) if len(away) else 0
    gap = (x - x[k0]) - (q - q[k0])
    gap[:k0] = 0.0
    along = sign * gap
    allowed = tol + np.where(along > 0, max(band, 0.0), 0.0)
    wrong = np.abs(gap) > allowed
    level = np.where(u > 0, fs_pos, fs_neg)
    out = np.where(wrong, np.sign(u) * np.maximum(np.abs(u) - level, 0.0), 0.0)
    q_turn, left = turn
    lead = sign * (q - q_turn) - sign * x
    short = np.maximum((fs_pos if sign > 0 else fs_neg) - sign * u, 0.0)
    at_rest = (sign * x < tol) & (np.arange(len(u)) >= left) & (left >= 0)
    ahead = (lead > MIN_BAND_TOLERANCES * tol + max(-band, 0.0)) & (out == 0.0) & at_rest
    return np.where(ahead, -sign * short, out)
