"""The truth of a run (truth.yaml, truth_states.parquet): what the diagnosis should find, each effect's torque
signature and observability, stick-slip, saturation, what made the run hard. Never read by the diagnosis."""

from __future__ import annotations

import math
from functools import lru_cache
from pathlib import Path

import numpy as np
import pandas as pd
import pinocchio as pin

from .arm import (
    ARMATURE,
    ENCODER_CPR,
    GENERATOR_VERSION,
    H_PHYS,
    JITTER_S,
    LOOP_JITTER_S,
    NOISE_FLOOR,
    NOISE_PROFILES,
    TAU_MAX,
    N,
    build_model,
)


def _plain(o):
    if isinstance(o, dict):
        return {str(k) if not isinstance(k, (int, str)) else k: _plain(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [_plain(v) for v in o]
    if isinstance(o, np.ndarray):
        return _plain(o.tolist())
    if isinstance(o, (np.floating,)):
        return float(o)
    if isinstance(o, (np.integer,)):
        return int(o)
    if isinstance(o, (np.bool_,)):
        return bool(o)
    if isinstance(o, Path):
        return str(o)
    return o


def _hermite_many(X, cols_q, cols_v, tau, h):
    """Vectorised cubic Hermite of the physics history at times tau (post hoc, for the truth file)."""
    s = np.clip(tau / h, 0.0, len(X) - 1 - 1e-9)
    i = np.minimum(s.astype(np.int64), len(X) - 2)
    u = (s - i)[:, None]
    p0, p1 = X[i][:, cols_q], X[i + 1][:, cols_q]
    m0, m1 = X[i][:, cols_v] * h, X[i + 1][:, cols_v] * h
    u2, u3 = u * u, u * u * u
    q = (2 * u3 - 3 * u2 + 1) * p0 + (u3 - 2 * u2 + u) * m0 + (-2 * u3 + 3 * u2) * p1 + (u3 - u2) * m1
    v = ((6 * u2 - 6 * u) * p0 + (3 * u2 - 4 * u + 1) * m0 + (-6 * u2 + 6 * u) * p1 + (3 * u2 - 2 * u) * m1) / h
    return q, v


def _truth_states(sim, sel, jb):
    """truth_states.parquet: the true link state at each logged row's sampling instant, the torque really applied
    (command + actuator noise) and the stick flags; for a backlash joint also the rotor angle (what the encoder saw).
    Never read by the diagnosis; for checking the generator and for tests."""
    h = H_PHYS
    X = sim["X_h"]
    ts = sim["t_tick"][sel]
    q, v = _hermite_many(X, np.arange(7), np.arange(7, 14), ts, h)
    out = {"t": sim["t_stamp"][sel], "t_sample": ts}
    for i in range(N):
        out[f"q_true_{i + 1}"] = q[:, i]
    for i in range(N):
        out[f"qd_true_{i + 1}"] = v[:, i]
    for i in range(N):
        out[f"tau_applied_{i + 1}"] = sim["tau_applied"][sel, i]
    st = sim["stuck_h"]
    steps = np.minimum(sim["tick_step"][sel], len(st) - 1)
    for i in range(N):
        out[f"stuck_{i + 1}"] = st[steps, i].astype(np.int8)
    if jb >= 0:
        qr, _ = _hermite_many(X, np.array([14]), np.array([15]), ts, h)
        out[f"q_rotor_{jb + 1}"] = qr[:, 0]
    return pd.DataFrame(out)


# The diagnosis' declared accuracy of the arm (its documented assumptions, diagnosis.json `assumptions`): each
# link's mass and inertia entries within 10 % (inertia: of its largest diagonal entry), its centre of mass within
# 10 % of its distance from the frame's origin plus 5 mm, each joint's armature within 10 %.
ACCURACY_SHARE = 0.10
ACCURACY_COM_M = 0.005


def _on_joint(x, j):
    """(len(x), N): ``x`` on joint ``j`` (0-based), zero on the others."""
    out = np.zeros((len(x), N))
    out[:, j] = x
    return out


@lru_cache(maxsize=1)
def _accuracy_generators():
    """(70, 70): column k is the change of pinocchio's dynamic parameters (per joint: m, m c, inertia about the
    joint's origin in its axes) when physical quantity k of one link (its mass, a coordinate of its centre of mass,
    an entry of its inertia about the centre) moves to the bound of the declared accuracy above. To first order
    the declared arms are ``p0 + G u`` with ``|u_k| <= 1``."""
    def params(mass, com, inertia):
        m = build_model(mass, com, inertia, ARMATURE, None)
        return np.concatenate([m.inertias[i + 1].toDynamicParameters() for i in range(N)])
    from .arm import LINK_COM, LINK_INERTIA, LINK_MASS
    p0 = params(LINK_MASS, LINK_COM, LINK_INERTIA)
    cols = []
    for i in range(N):
        steps = [("m", (i,), ACCURACY_SHARE * LINK_MASS[i])]
        steps += [("c", (i, k), ACCURACY_SHARE * np.linalg.norm(LINK_COM[i]) + ACCURACY_COM_M) for k in range(3)]
        steps += [("I", (i, k), ACCURACY_SHARE * LINK_INERTIA[i, :3].max()) for k in range(6)]
        for what, where, bound in steps:
            arrays = {"m": LINK_MASS.copy(), "c": LINK_COM.copy(), "I": LINK_INERTIA.copy()}
            arrays[what][where] += bound
            cols.append(params(arrays["m"], arrays["c"], arrays["I"]) - p0)
    return np.column_stack(cols)


def _beyond_declared_model(effect_Nm, model_nom, q, v, a, moving, floor):
    """Per moving joint (1-based), the RMS of an effect's torque left after the best fit that the declared model's
    own freedom allows, over the noise floor: the links within their declared accuracy (``|u| <= 1`` in
    :func:`_accuracy_generators`) and the armatures within 10 %, with each moving joint's Coulomb and viscous
    friction (per direction) free (the diagnosis refits them on every run). Fitted jointly over the moving joints
    on the samples where each slides (|qd| > 0.005 rad/s: friction is not a function of the state while a joint
    sticks) and the effect's torque is defined (not NaN), rows weighted by 1 / floor."""
    from scipy.optimize import lsq_linear

    data = model_nom.createData()
    YG = np.array([pin.computeJointTorqueRegressor(model_nom, data, q[i], v[i], a[i]) for i in range(len(q))]) \
        @ _accuracy_generators()
    rows, target, owner = [], [], []
    nm = len(moving)
    for r, j in enumerate(moving):
        slide = (np.abs(v[:, j]) > 0.005) & np.isfinite(effect_Nm[:, j])
        fric = np.zeros((len(q), 4 * nm))
        pos, neg = v[:, j] > 0, v[:, j] < 0
        fric[:, 4 * r] = pos
        fric[:, 4 * r + 1] = -neg.astype(float)
        fric[:, 4 * r + 2] = v[:, j] * pos
        fric[:, 4 * r + 3] = v[:, j] * neg
        arm = np.zeros((len(q), N))
        arm[:, j] = a[:, j] * ACCURACY_SHARE * ARMATURE[j]
        rows.append((np.hstack([YG[:, j, :], arm, fric]) / floor[j])[slide])
        target.append((effect_Nm[:, j] / floor[j])[slide])
        owner.append(np.full(slide.sum(), j))
    A, b, owner = np.vstack(rows), np.concatenate(target), np.concatenate(owner)
    n_bounded = YG.shape[2] + N
    lo = np.concatenate([-np.ones(n_bounded), np.full(4 * nm, -np.inf)])
    fit = lsq_linear(A, b, bounds=(lo, -lo), method="bvls")
    left = b - A @ fit.x
    return {j + 1: float(np.sqrt(np.mean(left[owner == j] ** 2))) if (owner == j).any() else 0.0 for j in moving}


def _truth(case, eff_list, link_rec, fric, ex_info, kind, moving, sim, model_true, model_nom, mass, com, inertia,
           armature, payload, noise, rate, jitter_mode, T_run, rip, dri, fr, bkl):
    h = H_PHYS
    floor = NOISE_FLOOR[noise]
    K = sim["n_ticks_done"]
    steps = sim["tick_step"][:K]
    ql = sim["ql_h"][steps]
    vl = sim["vl_h"][steps]
    nxt = np.minimum(steps + 8, len(sim["vl_h"]) - 1)
    al = (sim["vl_h"][nxt] - vl) / np.maximum((nxt - steps) * h, h)[:, None]
    t = steps * h
    slipping = np.abs(vl) > 0.02

    def rms_on(x, mask):
        return float(np.sqrt(np.mean(x[mask] ** 2))) if mask.any() else 0.0

    idx = np.arange(0, K, 5)           # the samples the rigid-body fits use (as the payload's signature)
    series = {}                         # id(effect) -> (K or len(idx), N) torque of the effect, N m
    for e in eff_list:
        s = {}
        if e["name"] in ("stribeck", "friction_drift", "position_ripple") and e["joint"]:
            j = e["joint"] - 1
            if e["name"] == "stribeck":
                code, delta = int(fr[j, 7]), fr[j, 8]
                x = np.abs(vl[:, j]) / fr[j, 6]
                S = np.exp(-(x ** delta)) if code == 1 else 1.0 / (1.0 + x * x)
                exc = np.where(vl[:, j] > 0, (fr[j, 4] - fr[j, 0]) * S, -(fr[j, 5] - fr[j, 1]) * S)
                s[j + 1] = rms_on(exc, np.abs(vl[:, j]) > 0.005)
                series[id(e)] = _on_joint(np.where(np.abs(vl[:, j]) > 0.005, exc, np.nan)[idx], j)
            elif e["name"] == "friction_drift":
                g = np.array([1.0 + dri[1] * (min(tt / dri[4], 1.0) if dri[2] == 0 else math.tanh(tt / dri[3]))
                              for tt in t])
                base = np.where(vl[:, j] > 0, fr[j, 0] + fr[j, 2] * vl[:, j], -(fr[j, 1] - fr[j, 3] * vl[:, j]))
                m = slipping[:, j]
                gbar = g[m].mean() if m.any() else 1.0
                s[j + 1] = rms_on((g - gbar) * base, m)  # what a constant friction fit cannot absorb
                series[id(e)] = _on_joint(np.where(m, g * base, np.nan)[idx], j)
            else:
                r = np.array([math.fsum([rip[3 + kk] * math.sin(2 * math.pi * (kk + 1) * qq / rip[2] + rip[6 + kk])
                                         for kk in range(3)]) for qq in ql[:, j]]) * rip[1]
                s[j + 1] = rms_on(r, slipping[:, j])
                series[id(e)] = _on_joint(np.where(slipping[:, j], r, np.nan)[idx], j)
        elif e["name"] == "payload":
            m_nopl = build_model(mass, com, inertia, armature, None)
            d1, d2 = model_true.createData(), m_nopl.createData()
            diff = np.array([pin.rnea(model_true, d1, ql[i], vl[i], al[i]) - pin.rnea(m_nopl, d2, ql[i], vl[i], al[i])
                             for i in range(0, K, 5)])
            for j in moving:
                s[j + 1] = float(np.sqrt(np.mean((diff[:, j] - diff[:, j].mean()) ** 2)))
            s["static_gravity_change_Nm"] = np.abs(diff).max(axis=0).tolist()
            series[id(e)] = diff
        elif e["name"] == "delay":
            d = e["params"]["delay_ms"] * 1e-3
            lag = d * vl
            for j in moving:
                s[j + 1] = float(np.sqrt(np.mean(lag[:, j] ** 2)))  # rad, position lag RMS
        elif e["name"] == "backlash":
            j = e["joint"] - 1
            qe = sim["qe_h"][steps][:, j]
            lost = qe - ql[:, j]
            half = float(bkl[1])
            side = np.where(lost > 0.9 * half, 1, np.where(lost < -0.9 * half, -1, 0))
            side = side[side != 0]
            switches = int(np.sum(side[1:] != side[:-1])) if len(side) > 1 else 0
            s = {j + 1: float(np.std(lost)), "contact_side_switches": switches,
                 "lost_motion_p2p_rad": float(np.ptp(lost)),
                 "time_in_dead_band_fraction": float(np.mean(np.abs(lost) < 0.9 * half))}
        e["signature"] = s
        e["signature_unit"] = {"delay": "rad (position lag RMS)", "backlash": "rad (rotor-link std)"}.get(
            e["name"], "N m (RMS of the effect's torque on moving samples)")
        if e["name"] in ("stribeck", "friction_drift", "position_ripple", "payload"):
            snrs = {jj: v / floor[jj - 1] for jj, v in s.items() if isinstance(jj, int)}
            e["snr_vs_noise_floor"] = snrs
            e["observable"] = bool(max(snrs.values(), default=0.0) >= 2.0)
        elif e["name"] == "delay":
            res = sim["enc_res"]
            snrs = {jj: v / res[jj - 1] for jj, v in s.items() if isinstance(jj, int)}
            e["lag_in_encoder_counts"] = snrs
            e["observable"] = bool(max(snrs.values(), default=0.0) >= 2.0)
        else:  # backlash: seen only if the load actually crosses the dead band (gravity may press one flank)
            e["observable"] = bool(s.get("contact_side_switches", 0) >= 2)
        if id(e) in series:
            left = _beyond_declared_model(series[id(e)], model_nom, ql[idx], vl[idx], al[idx], moving, floor)
            joints = [e["joint"]] if e["joint"] else [j + 1 for j in moving]
            e["snr_beyond_declared_accuracy"] = {jj: left[jj] for jj in joints if jj in left}
            e["identifiable"] = bool(e["observable"] and max(e["snr_beyond_declared_accuracy"].values(),
                                                             default=0.0) >= 2.0)
        else:  # a position lag or lost motion: no change of the links' masses or of friction produces one
            e["identifiable"] = e["observable"]

    # link perturbation signature (gravity/inertia torque change along the run)
    link_sig = None
    if link_rec:
        d1, d2 = model_true.createData(), model_nom.createData()
        m_nopl = build_model(mass, com, inertia, ARMATURE, None)
        d3 = m_nopl.createData()
        diff = np.array([pin.rnea(m_nopl, d3, ql[i], vl[i], al[i]) - pin.rnea(model_nom, d2, ql[i], vl[i], al[i])
                         for i in range(0, K, 5)])
        link_sig = {j + 1: float(np.sqrt(np.mean(diff[:, j] ** 2))) for j in moving}

    # stick-slip (true state)
    st = sim["stuck_h"]
    stick = {}
    if kind == "sweep":
        j = moving[0]
        per_speed = {}
        for (a, b, v) in ex_info["cruise"]:
            ia, ib = int(a / h), min(int(b / h), len(st))
            if ib - ia < 10:
                continue
            seg = st[ia:ib, j] if not (int(bkl[0]) == j) else st[ia:ib, 7]
            key = round(abs(v), 4)
            d = per_speed.setdefault(key, {"stuck_fraction": [], "breakaways": 0, "windows": 0})
            d["stuck_fraction"].append(float(seg.mean()))
            d["breakaways"] += int(np.sum(np.diff(seg.astype(int)) == -1))
            d["windows"] += 1
        for d in per_speed.values():
            d["stuck_fraction"] = float(np.mean(d["stuck_fraction"]))
        slow = [d for v, d in per_speed.items() if v <= 0.012]
        frac_slow = float(np.mean([d["stuck_fraction"] for d in slow])) if slow else 0.0
        # stick-slip at a speed: the joint sticks again after sliding (more than the one breakaway that starts a
        # window) and sticks a noticeable part of the time
        ss_speeds = sorted(v for v, d in per_speed.items()
                           if d["breakaways"] >= 2 * d["windows"] and d["stuck_fraction"] >= 0.1)
        held = sorted(v for v, d in per_speed.items() if d["stuck_fraction"] >= 0.97)
        stick = dict(joint=j + 1, per_speed=dict(sorted(per_speed.items())), slow_stuck_fraction=frac_slow,
                     slow_breakaways=sum(d["breakaways"] for d in slow), slow_windows=sum(d["windows"] for d in slow),
                     stick_slip_speeds=ss_speeds, stick_slipped=bool(ss_speeds), held_by_static_friction_at=held)
    else:
        stick = dict(stuck_fraction={j + 1: float(st[:, j].mean()) for j in moving})

    sat = (np.abs(sim["tau_cmd"][:K]) >= TAU_MAX - 1e-9).mean(axis=0)
    expected = []
    for e in eff_list:
        if e["name"] not in expected:
            expected.append(e["name"])
    acceptable, forbidden = [], []
    if link_rec:
        acceptable.append("link_parameters")
        forbidden.append("payload") if "payload" not in expected else None
    hard = []
    if stick.get("stick_slipped"):
        hard.append("stick-slip during sweeps at " + ", ".join(f"{v:g}" for v in stick["stick_slip_speeds"])
                    + " rad/s")
    if stick.get("held_by_static_friction_at"):
        hard.append("joint held by static friction through whole windows at "
                    + ", ".join(f"{v:g}" for v in stick["held_by_static_friction_at"]) + " rad/s")
    if sim["status"] != "ok":
        hard.append(f"loop not held: {sim['reason']}")
    if any(not e.get("observable", True) for e in eff_list):
        hard.append("effect below twice the noise floor on the moving joints (see signature)")
    if (sat > 0.01).any():
        hard.append("torque saturation on joints " + ", ".join(str(i + 1) for i in np.where(sat > 0.01)[0]))
    if link_rec:
        hard.append("link parameters differ from the declared model (not a payload)")
    return {
        "format": "gen2-truth/1",
        "generator": GENERATOR_VERSION,
        "case": _plain(case),
        "status": sim["status"],
        "trip": None if sim["status"] == "ok" else {"reason": sim["reason"], "t_s": float(sim["t_trip"] or 0.0)},
        "label": "+".join(expected) if expected else "none",
        "expected_effects": expected,
        "acceptable_extra": acceptable,
        "forbidden": forbidden,
        "effects": eff_list,
        "link_perturbation": {"mode": case.get("links", "nominal"), "links": link_rec, "signature_Nm": link_sig},
        "friction_truth_classic": {k: np.round(v, 5).tolist() for k, v in fric.items()},
        "excitation": {"kind": kind, "moving_joints": [m + 1 for m in moving],
                       **{k: v for k, v in ex_info.items() if k != "q0"}},
        "stick": stick,
        "saturation_fraction": sat.tolist(),
        "noise": {"profile": noise, "pos_sigma_rad": NOISE_PROFILES[noise]["pos_sigma"].tolist(),
                  "actuator_tau_sigma_Nm": NOISE_PROFILES[noise]["tau_sigma"].tolist(),
                  "encoder_cpr": ENCODER_CPR, "joint_resolution_rad": sim["enc_res"].tolist(),
                  "noise_floor_Nm": floor.tolist()},
        "timing": {"log_rate_hz": rate, "control_rate_hz": 500, "physics_rate_hz": int(round(1 / H_PHYS)),
                   "jitter_mode": jitter_mode, "jitter_s": JITTER_S if jitter_mode == "stamp" else LOOP_JITTER_S,
                   "stamps_truthful": jitter_mode == "loop"},
        "integration": "semi-implicit Euler 4 kHz, Karnopp band 2e-4 rad/s + zero-crossing capture",
        "hard": hard,
    }


