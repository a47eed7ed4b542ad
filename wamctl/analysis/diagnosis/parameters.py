"""Parameters of a diagnosis' models in physical units: friction before and after, each kept effect's (no I/O).

The fitted coefficients of a joint are ``[friction (4), term 1, term 2, ...]`` (:mod:`.design`); here they
become the quantities a model file and the report name (levels in N m, a ripple's amplitude and phase, a
payload's mass and centre of mass, ...).
"""

from __future__ import annotations

import numpy as np

from wamctl.analysis.diagnosis.candidates import payload_from_pi, ripple_key
from wamctl.analysis.diagnosis.design import (
    columns,
    declared_levels,
    drift_offset,
    levels,
    levels_dict,
    split_coefs,
)
from wamctl.model.effects import friction_drift_scale

TEST_NAME = "nested F-test on held-out folds"
ONSET_TEST_NAME = "nested F-test on held-out folds (hidden travel at onsets)"


def friction_levels_before(diag, j: int, theta: np.ndarray | None = None) -> dict:
    """Classic friction of 0-based joint ``j`` in the declared model of a fitted ``ModelDiagnosis`` (``theta``:
    its four coefficients, default fitted on all data)."""
    return levels_dict(levels(diag.declared_.friction, j, diag.joints_[j].theta_before if theta is None else theta))


def friction_levels_after(diag, j: int, theta: np.ndarray | None = None) -> dict:
    """Classic friction of 0-based joint ``j`` in the final model (at t = 0 when friction drifts)."""
    res = diag.joints_[j]
    c = split_coefs(res.kept, res.theta_after if theta is None else theta)
    return levels_dict(levels(diag.declared_.friction, j, np.array(c["friction"], float)))


def kept_effect_params(diag, j: int, name: str, theta: np.ndarray | None = None) -> dict:
    """Parameters of kept effect ``name`` at 0-based joint ``j`` (units in the key names); ``theta`` overrides
    the coefficients fitted on all data (see ``ModelDiagnosis.refit``)."""
    res = diag.joints_[j]
    c = split_coefs(res.kept, res.theta_after if theta is None else theta)
    t = next(t for t in res.kept if t["name"] == name)
    h = t.get("h_all")
    fr = levels(diag.declared_.friction, j, c["friction"])     # absolute levels
    coef = c[name]
    if name == "stribeck":
        return stribeck_params(fr, coef, h, t)
    if name == "position_ripple":
        return ripple_params(coef, h)
    if name == "payload":
        if diag.payload_ is not None and (theta is None or len(coef) == 1):
            return dict(diag.payload_)
        basis = diag.jd_[j].extra.get("payload_basis")        # the joint's candidate: coefficients in its basis
        return payload_from_pi(coef if basis is None else basis @ coef, getattr(diag.design_, "robot", "wam7"))
    if name == "delay":
        return {"delay_s": float(h)}
    if name == "friction_drift":
        jd = diag.jd_[j]
        return drift_params(columns(diag.design_, "friction", jd, None), fr, coef,
                            declared_levels(diag.design_, jd), h, diag.signals_.duration_s)
    if name == "backlash":
        return backlash_params(t, coef, diag.onsets_.get(j, {}))
    if name == "link_parameters":
        rep = getattr(diag, "links_report_", None) or {"params": {}}
        return dict(rep["params"], joints_fitted=[jj + 1 for jj, r in diag.joints_.items()
                                                  if any(k["name"] == "link_parameters" for k in r.kept)])
    raise ValueError(name)


def stribeck_params(fr: np.ndarray, coef: np.ndarray, vs_rad_s: float, term: dict) -> dict:
    """Breakaway and Coulomb levels per direction and the Stribeck velocity, from the absolute classic levels
    ``fr`` (4,) and the breakaway excess ``coef`` (2,); a term found at the breakaways takes the levels the
    joint withstood there."""
    shape = term.get("fixed_h")
    if isinstance(shape, tuple):        # measured at the breakaways or on the friction map
        rp, rn, vs, delta = shape
        lv = term.get("breakaway_Nm") or {}     # the levels in N m the onsets measured (onset_tests)
        return {"Fs_pos_Nm": float(lv.get("pos", rp * fr[0])), "Fs_neg_Nm": float(lv.get("neg", rn * fr[1])),
                "Fc_pos_Nm": float(fr[0]), "Fc_neg_Nm": float(fr[1]), "vs_rad_s": float(vs),
                "stribeck_delta": float(delta), "Fs_from": term.get("seen", "breakaways")}
    out = {"Fs_pos_Nm": float(fr[0] + coef[0]), "Fs_neg_Nm": float(fr[1] + coef[1]),
           "Fc_pos_Nm": float(fr[0]), "Fc_neg_Nm": float(fr[1]), "vs_rad_s": float(vs_rad_s),
           "stribeck_delta": 2.0}
    if term.get("onset_ratio"):
        rho = term.get("onset_ratio_dir", {})
        out["Fs_pos_Nm"] = rho.get("pos", term["onset_ratio"]) * out["Fc_pos_Nm"]
        out["Fs_neg_Nm"] = rho.get("neg", term["onset_ratio"]) * out["Fc_neg_Nm"]
        if term.get("onset_vs"):
            out["vs_rad_s"] = term["onset_vs"]
        out["Fs_from"] = "breakaways"
    return out


def ripple_params(coef: np.ndarray, shape: tuple[float, int]) -> dict:
    """Period, amplitude and phase of each harmonic of the ripple ``sum_h A_h sin(2 pi h q / P + phase_h)`` from
    its sin/cos coefficients (2 H,) and its shape ``(P, H)`` (keys: :func:`...candidates.ripple_key`), the number
    of harmonics and the ripple's RMS ``sqrt(sum A_h^2 / 2)``."""
    period_rad, nh = float(shape[0]), int(shape[1])
    out = {"period_rad": period_rad, "n_harmonics": nh}
    for h in range(1, nh + 1):
        a, b = -coef[2 * h - 2], -coef[2 * h - 1]   # y = friction - ripple: the plant's ripple is minus the fit
        out[ripple_key(h, "amplitude")] = float(np.hypot(a, b))
        out[ripple_key(h, "phase")] = float(np.arctan2(b, a) % (2 * np.pi))
    out["rms_Nm"] = float(np.sqrt(0.5 * np.sum(np.asarray(coef[:2 * nh], float) ** 2)))
    return out


def drift_params(X: np.ndarray, fr: np.ndarray, coef: np.ndarray, tb: np.ndarray, T_s: float,
                 duration_s: float) -> dict:
    """Fraction and time constant of a friction drift, its change over the run, and the friction at t = 0.

    ``X`` (m, 4) classic friction columns at the joint's samples, ``fr`` (4,) the levels at the start of the run,
    ``coef`` (2,) the drift's coefficients, ``tb`` (4,) the declared levels they scale, ``duration_s`` the run's
    length. The fraction is the least-squares ratio of the friction torque's change (t -> infinity) to the torque
    at t = 0: friction x ``1 + fraction (1 - exp(-t / T))``; ``change_over_run`` is that factor less one at the end
    of the run (what the data see, even where a time constant far beyond the run leaves fraction and time constant
    undetermined on their own)."""
    dec = drift_offset(coef, tb)
    f0 = X @ fr                          # friction at t = 0
    f1 = X @ dec                         # its change
    frac = float(f1 @ f0 / max(f0 @ f0, 1e-300))
    return {"fraction": frac, "time_constant_s": float(T_s),
            "change_over_run": float(friction_drift_scale(duration_s, frac, T_s)) - 1.0,
            "friction_t0": levels_dict(fr)}


def backlash_params(term: dict, coef: np.ndarray, ons: dict) -> dict:
    """Dead band (from the onsets), the side of the gap the encoder is on, the onsets it was measured at, and
    for a dead band behind the encoder its gravity offset coefficient (1,; a gap on the motor side has none)."""
    rev = np.asarray(ons.get("reversal", []), bool)
    used = np.isfinite(ons.get("travel_rad", np.zeros(len(rev))))
    out = {"width_rad": float(term["width_rad"]), "encoder_side": term.get("encoder_side", "link"),
           "reversals": int(np.sum(rev & used)), "same_direction_onsets": int(np.sum(~rev & used))}
    if len(coef):
        out["gravity_offset_rad"] = float(coef[0])
    return out


def report_effects(diag) -> None:
    """Set every joint's report-ready ``effects`` (name, parameters, their 95 % intervals and what the data
    cannot determine, evidence, held-out RMS before and after the effect) of a fitted ``ModelDiagnosis``."""
    from wamctl.analysis.diagnosis.intervals import joint_intervals

    for j, res in diag.joints_.items():
        res.effects = []
        intervals = joint_intervals(diag, j)
        for t in res.kept:
            ev = t["evidence"]
            test = TEST_NAME if t["name"] != "backlash" else ONSET_TEST_NAME
            params = kept_effect_params(diag, j, t["name"])
            if t["name"] == "payload":
                ci, ni = getattr(diag, "payload_ci_", ({}, []))
                params = payload_params(params, ni)
            elif t["name"] == "link_parameters":
                rep = diag.links_report_
                ci, ni = rep["params_ci"], rep["not_identified"]
            else:
                ci, ni = intervals[t["name"]]["params_ci"], intervals[t["name"]]["not_identified"]
                params = {k: (None if k in ni else v) for k, v in params.items()}
            entry = {"name": t["name"], "params": params, "params_ci": ci, "not_identified": list(ni),
                     "evidence": {"test": test, "p_value": float(ev["p_value"]), "delta_bic": float(ev["delta_bic"])}}
            if t["name"] == "link_parameters":
                # params are the free refit's changes (what these data say); with this flag the held-out figures
                # and the model file use the refit held within the declared accuracy
                entry["within_declared_accuracy"] = bool(diag.links_report_.get("within_declared_accuracy"))
            if t.get("onset_test") and t["name"] == "stribeck":
                entry["evidence"]["test"] = ONSET_TEST_NAME
            for k in ("rms_before_Nm", "rms_after_Nm"):
                if k in t:
                    entry[f"torque_{k}"] = float(t[k])
            res.effects.append(entry)


def payload_params(p: dict, not_identified: list[str]) -> dict:
    """A payload's parameters with the centre of mass also by component (``com_x_m`` ...), the ones the data
    cannot determine set to None (also in ``com_m``)."""
    out = dict(p)
    com = list(p["com_m"])
    for i, ax in enumerate("xyz"):
        key = f"com_{ax}_m"
        out[key] = None if key in not_identified else float(com[i])
        if key in not_identified:
            com[i] = None
    out["com_m"] = com
    if "mass_kg" in not_identified:
        out["mass_kg"] = None
    return out
