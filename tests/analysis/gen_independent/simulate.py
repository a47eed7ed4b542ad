"""Generation of one case: the closed loop (controller, sensors, physics at 4 kHz) and the files of a run."""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pinocchio as pin
import yaml

from .arm import (
    ARMATURE,
    CART_SPEED_FAULT,
    ENCODER_CPR,
    H_PHYS,
    J2MP,
    J2MP_INV,
    JITTER_S,
    JOINT_EFFECTS,
    KD,
    KP,
    LOOP_JITTER_S,
    NOISE_PROFILES,
    Q_MAX,
    Q_MIN,
    STICK_BAND,
    T_CTRL,
    TAU_MAX,
    N,
    build_model,
)
from .effects import _friction_truth, draw_effect, perturb_links
from .excitation import _Checker, design_free, design_sweep, designed_reference
from .physics import _limits_code, _measure, phys_step
from .truth import _plain, _truth, _truth_states


class Encoders:
    def __init__(self, rng):
        self.res = 2 * np.pi / ENCODER_CPR
        self.phase = rng.uniform(0, 1, N)

    def read(self, q_drive):
        m = J2MP @ q_drive
        c = np.floor(m / self.res + self.phase)
        return J2MP_INV @ ((c - self.phase + 0.5) * self.res)

    @property
    def joint_resolution(self):
        return np.abs(J2MP_INV) @ np.full(N, self.res)



# ----------------------------------------------------------------------------------------------------------------
# Generation.

@dataclasses.dataclass
class GeneratedRun:
    path: Path
    case_id: str
    status: str              # ok | safety_trip | diverged
    reason: str | None
    effects: list
    expected_effects: list
    rows: int
    arm_time_s: float
    wall_time_s: float
    truth: dict


def _case_id(case):
    return case.get("id") or hashlib.sha1(json.dumps(_plain(case), sort_keys=True).encode()).hexdigest()[:10]


def generate(case: dict, out_dir: Path) -> GeneratedRun:
    """Simulate one case and write meta.yaml, data.parquet and truth.yaml into ``out_dir``.

    case keys: seed (int), effects (list of {name, joint (1-based, for joint effects), size, params (optional
    override)}), links (nominal | heavier_3_4 | random_10pct), excitation (sweep | free), joint (1-based: swept
    joint, or one joint that must move in a free run), rate_hz (500 | 250), noise (quiet | noisy),
    jitter (loop | stamp), free_joints (optional, 1-based), id (optional).
    """
    wall0 = time.perf_counter()
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    seed = int(case["seed"])
    ss = np.random.SeedSequence(seed)
    r_design, r_effect, r_noise, r_fric, r_links, r_time = [np.random.default_rng(s) for s in ss.spawn(6)]
    if case.get("noise_seed") is not None:   # a further run of the same arm: the same truth, other noise and jitter
        r_noise, r_time = [np.random.default_rng(s) for s in np.random.SeedSequence(int(case["noise_seed"])).spawn(2)]
    noise = case.get("noise", "quiet")
    rate = int(case.get("rate_hz", 500))
    jitter_mode = case.get("jitter", "loop")
    excitation = case.get("excitation", "sweep")
    joint = int(case.get("joint", 1)) - 1

    fric = _friction_truth(r_fric)
    mass, com, inertia, link_rec = perturb_links(case.get("links", "nominal"), r_links)

    # -- effects
    eff_list = []
    for e in case.get("effects", []):
        name = e["name"]
        ej = (int(e["joint"]) - 1) if (name in JOINT_EFFECTS and e.get("joint") is not None) else (
            joint if name in JOINT_EFFECTS else None)
        p = draw_effect(name, ej, e.get("size", "medium"), r_effect, fric, noise)
        p.update(e.get("params", {}) or {})
        eff_list.append(dict(name=name, joint=None if ej is None else ej + 1, size=e.get("size", "medium"),
                             params=p, **({"params_given": dict(e["params"])} if e.get("params") else {})))
    by_name = {e["name"]: e for e in eff_list}

    # -- friction table per DOF (7 joints + rotor)
    fr = np.zeros((8, 9))
    for i in range(N):
        fr[i] = [fric["Fc_pos"][i], fric["Fc_neg"][i], fric["B_pos"][i], fric["B_neg"][i],
                 fric["Fc_pos"][i], fric["Fc_neg"][i], 1.0, 0, 1.0]
    if "stribeck" in by_name:
        e = by_name["stribeck"]
        j, p = e["joint"] - 1, e["params"]
        code, delta = {"exp_delta1": (1, 1.0), "exp_delta1.5": (1, 1.5), "lorentz": (2, 2.0)}[p["shape"]]
        fr[j, 4] = fr[j, 0] * p["ratio_pos"]
        fr[j, 5] = fr[j, 1] * p["ratio_neg"]
        fr[j, 6], fr[j, 7], fr[j, 8] = p["vs_rad_s"], code, delta
        p.update(Fs_pos_Nm=float(fr[j, 4]), Fs_neg_Nm=float(fr[j, 5]))
    rip = np.full(9, 0.0)
    rip[0] = -1
    if "position_ripple" in by_name:
        e = by_name["position_ripple"]
        p = e["params"]
        rip[:] = [e["joint"] - 1, p["amplitude_Nm"], p["period_rad"], *p["harmonic_weights"], *p["phases_rad"]]
    bkl = np.array([-1.0, 0, 0, 0, 1.0])
    armature = ARMATURE.copy()
    payload = None
    if "payload" in by_name:
        p = by_name["payload"]["params"]
        payload = dict(mass=p["mass_kg"], com=p["com_m"], inertia=np.array(p["inertia_kg_m2"]))

    # -- excitation (designed on the nominal model)
    model_nom = build_model()
    checker = _Checker(model_nom)
    fric_mean = 0.5 * (fric["Fc_pos"] + fric["Fc_neg"])
    if excitation == "sweep":
        ref, ex_info = design_sweep(r_design, joint, checker, fric_mean)
        moving = [joint]
        kind = "sweep"
    elif excitation == "free":
        if case.get("free_joints"):
            fj = [int(x) - 1 for x in case["free_joints"]]
        else:
            must = {joint} | {e["joint"] - 1 for e in eff_list if e["joint"] is not None}
            others = [k for k in range(N) if k not in must]
            n_more = max(0, int(r_design.integers(3, 6)) - len(must))
            fj = sorted(must | set(r_design.choice(others, size=min(n_more, len(others)), replace=False).tolist()))
        ref, ex_info = design_free(r_design, fj, checker, fric_mean)
        moving = fj
        kind = "free"
    elif excitation == "designed":      # the reference of an excitation spec (next_experiment.yaml)
        ref = designed_reference(case["reference"])
        ev = checker.evaluate(ref, ref.duration, fric=fric_mean)
        ex_info = dict(q0=ref.q0, duration=ref.duration, period_s=ref.period, periods=ref.periods,
                       settle_s=ref.settle, harmonics=int(ref.a.shape[1]),
                       design=dict(check_failed=ev["fail"], tau_ratio=ev["tau_ratio"], vcart=ev["vcart"],
                                   zmin=ev["zmin"]))
        moving = list(ref.joints)
        kind = "designed"
    else:
        raise ValueError(excitation)
    q0 = ex_info["q0"]
    T_run = float(ex_info["duration"])

    # drift needs the run length
    dri = np.array([-1.0, 0, 0, 1.0, 1.0])
    if "friction_drift" in by_name:
        e = by_name["friction_drift"]
        p = e["params"]
        dri[:] = [e["joint"] - 1, p["f"], 0 if p["shape"] == "linear" else 1, p["tau_w_frac"] * T_run, T_run]
        p["tau_w_s"] = p["tau_w_frac"] * T_run

    # -- true plant
    if "backlash" in by_name:
        armature[by_name["backlash"]["joint"] - 1] = 0.0
    model_true = build_model(mass, com, inertia, armature, payload)
    data_true = model_true.createData()
    data_nom = model_nom.createData()
    if "backlash" in by_name:
        e = by_name["backlash"]
        j, p = e["joint"] - 1, e["params"]
        Jr = ARMATURE[j]                      # the rotor, now a body of its own
        pin.crba(model_true, data_true, q0)
        Jl = float(data_true.M[j, j])         # link-side inertia at q0
        Jeff = Jr * Jl / (Jr + Jl)
        k = Jeff * (2 * np.pi * p["resonance_hz"]) ** 2
        c = 2 * p["zeta"] * math.sqrt(k * Jeff)
        given = e.get("params_given") or {}
        if "stiffness_Nm_rad" in given:  # a further run of the same drive: its contact as in the first run
            k, c, Jl = float(given["stiffness_Nm_rad"]), float(given["damping_Nms_rad"]), given["link_inertia_at_q0"]
        bkl[:] = [j, 0.5 * p["gap_rad"], k, c, Jr]
        rho = p["link_friction_share"]
        fr[7] = fr[j]
        fr[7, 0:6] *= (1 - rho)
        fr[j, 0:6] *= rho
        p.update(stiffness_Nm_rad=k, damping_Nms_rad=c, rotor_inertia_kg_m2=Jr, link_inertia_at_q0=Jl)
    delay = by_name["delay"]["params"]["delay_ms"] * 1e-3 if "delay" in by_name else 0.0

    sim = _simulate(model_true, data_true, model_nom, data_nom, ref, q0, T_run, fr, rip, dri, bkl, delay,
                    NOISE_PROFILES[noise], jitter_mode, r_noise, r_time)

    # -- log
    step = 1 if rate == 500 else 2
    K_ok = sim["n_ticks_done"]
    sel = np.arange(0, K_ok, step)
    t_log = sim["t_stamp"][sel]
    df = pd.DataFrame({"t": t_log})
    for i in range(N):
        df[f"q_ref_{i + 1}"] = sim["q_ref"][sel, i]
    for i in range(N):
        df[f"q_{i + 1}"] = sim["q_meas"][sel, i]
    for i in range(N):
        df[f"tau_{i + 1}"] = sim["tau_cmd"][sel, i]
    df.to_parquet(out_dir / "data.parquet", index=False)
    _truth_states(sim, sel, int(bkl[0])).to_parquet(out_dir / "truth_states.parquet", index=False)
    run_name = "run-" + hashlib.sha1(f"{seed}-{_case_id(case)}".encode()).hexdigest()[:8]
    meta = {
        "format": "wamctl-measured/1",
        "robot": "wam7",
        "sample_rate_hz": rate,
        "gravity_compensation": True,
        "controller": {"kind": "pd_g", "kp": KP.tolist(), "kd": KD.tolist()},
        "experiment": {"kind": "free" if kind == "designed" else kind, "joints": [m + 1 for m in moving]},
        "q0": [round(float(x), 6) for x in q0],
        "payload": None,
        "notes": f"{run_name}; simulated WAM run (independent generator)",
    }
    with open(out_dir / "meta.yaml", "w") as fh:
        yaml.safe_dump(_plain(meta), fh, sort_keys=False)

    # -- truth
    for e in eff_list:
        e.pop("params_given", None)
    truth = _truth(case, eff_list, link_rec, fric, ex_info, kind, moving, sim, model_true, model_nom, mass, com,
                   inertia, armature, payload, noise, rate, jitter_mode, T_run, rip, dri, fr, bkl)
    with open(out_dir / "truth.yaml", "w") as fh:
        yaml.safe_dump(_plain(truth), fh, sort_keys=False)
    wall = time.perf_counter() - wall0
    return GeneratedRun(path=out_dir, case_id=_case_id(case), status=sim["status"], reason=sim["reason"],
                        effects=[e["name"] for e in eff_list], expected_effects=truth["expected_effects"],
                        rows=len(df), arm_time_s=float(t_log[-1]) if len(t_log) else 0.0, wall_time_s=wall,
                        truth=truth)


def _simulate(mt, dt, mn, dn, ref, q0, T_run, fr, rip, dri, bkl, delay, noise, jitter_mode, r_noise, r_time):
    h = H_PHYS
    K = int(round(T_run / T_CTRL))
    n_steps = int(round(T_run / h)) + 8
    t_nom = np.arange(K) * T_CTRL
    if jitter_mode == "loop":
        jit = r_time.uniform(-LOOP_JITTER_S, LOOP_JITTER_S, K)
        jit[0] = 0.0
        t_tick = t_nom + jit
        t_stamp = t_tick.copy()
    else:
        jit = r_time.uniform(-JITTER_S, JITTER_S, K)
        jit[0] = 0.0
        t_tick = t_nom.copy()
        t_stamp = t_nom + jit
    q_ref_all, _, _ = ref(t_nom)
    enc = Encoders(r_noise)
    pos_sigma, tau_sigma = noise["pos_sigma"], noise["tau_sigma"]
    jb = int(bkl[0])

    x = np.zeros(16)
    x[:7] = q0
    if jb >= 0:
        x[14] = q0[jb]
    X_h = np.empty((n_steps + 1, 16))     # full physics history (link q, v, rotor qr, vr)
    stuck_h = np.zeros((n_steps, 8), np.int8)
    W = np.zeros((8, 40))
    ecol_q = np.arange(7)                  # encoder (drive) coordinates: the rotor for a backlash joint
    ecol_v = np.arange(7, 14)
    if jb >= 0:
        ecol_q[jb], ecol_v[jb] = 14, 15

    X_h[0] = x
    qv, vv = x[:7], x[7:14]  # views on the state
    qm = np.zeros(N)
    noisy_pos = bool(pos_sigma.any())
    noisy_tau = bool(tau_sigma.any())
    q_meas = np.zeros((K, N))
    tau_app_log = np.zeros((K, N))
    tau_cmd = np.zeros((K, N))
    tau_applied = np.zeros(N)
    e_prev = None
    stuck = np.zeros(8, np.int64)
    tick_step = np.zeros(K, np.int64)
    fw, ff = mt.getFrameId("dh5"), mt.getFrameId("dh7")
    status, reason = "ok", None
    k = 0
    n = 0
    t_trip = None
    while n < n_steps and k <= K:
        tn = n * h
        while k < K and t_tick[k] <= tn + 1e-12:
            # safety on the true state at the tick
            code = _limits_code(x, Q_MIN, Q_MAX)
            if code:
                status, reason = [None, ("diverged", "non-finite state"),
                                  ("safety_trip", "joint beyond its hard stop"),
                                  ("safety_trip", "joint velocity above 5 rad/s")][code]
            elif k % 4 == 0:
                pin.forwardKinematics(mt, dt, qv, vv)
                vc = max(np.linalg.norm(pin.getFrameVelocity(mt, dt, fw, pin.LOCAL_WORLD_ALIGNED).linear),
                         np.linalg.norm(pin.getFrameVelocity(mt, dt, ff, pin.LOCAL_WORLD_ALIGNED).linear))
                if vc > CART_SPEED_FAULT:
                    status, reason = "safety_trip", f"Cartesian speed {vc:.2f} m/s above the 1.0 m/s fault"
            if status != "ok":
                t_trip = t_tick[k]
                break
            _measure(X_h, ecol_q, ecol_v, n, t_tick[k] - delay, h, q0, J2MP, J2MP_INV, enc.res, enc.phase, qm)
            if noisy_pos:
                qm += pos_sigma * r_noise.standard_normal(N)
            e = q_ref_all[k] - qm
            if e_prev is None:
                e_prev = e
            u = KP * e + KD * (e - e_prev) / T_CTRL + pin.computeGeneralizedGravity(mn, dn, qm)
            e_prev = e
            u = np.clip(u, -TAU_MAX, TAU_MAX)
            q_meas[k] = qm
            tau_cmd[k] = u
            tau_applied = u + tau_sigma * r_noise.standard_normal(N) if noisy_tau else u
            tau_app_log[k] = tau_applied
            tick_step[k] = n
            k += 1
        if status != "ok" or (k >= K and n * h > t_tick[K - 1] + T_CTRL):
            break
        Minv = pin.computeMinverse(mt, dt, qv)
        nle = pin.nonLinearEffects(mt, dt, qv, vv)
        phys_step(x, tau_applied, Minv, nle, tn, fr, rip, dri, bkl, h, STICK_BAND, stuck, W)
        stuck_h[n] = stuck
        n += 1
        X_h[n] = x
    n_done = n
    return dict(status=status, reason=reason, t_trip=t_trip, n_ticks_done=k, t_tick=t_tick, t_stamp=t_stamp,
                tau_applied=tau_app_log, X_h=X_h[:n_done + 1],
                q_ref=q_ref_all, q_meas=q_meas, tau_cmd=tau_cmd, ql_h=X_h[:n_done + 1, 0:7],
                vl_h=X_h[:n_done + 1, 7:14], qe_h=X_h[:n_done + 1][:, ecol_q], ve_h=X_h[:n_done + 1][:, ecol_v],
                stuck_h=stuck_h[:n_done], tick_step=tick_step,
                n_steps=n_done, enc_res=enc.joint_resolution)


