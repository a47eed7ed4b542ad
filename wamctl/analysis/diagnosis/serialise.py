"""``diagnosis.json`` of a fitted diagnosis (format ``wamctl-diagnosis/1``, see docs/diagnosis-report.md).

Builds the mapping only; writing it is the caller's (no I/O).
"""

from __future__ import annotations

import numpy as np

from wamctl.analysis.diagnosis.parameters import friction_levels_after, friction_levels_before

FORMAT = "wamctl-diagnosis/1"
DECLARED_MODEL = "wam7 rigid body + armature + classic friction (Coulomb + viscous, per direction)"


def _num(x):
    """A JSON number: None for a missing or non-finite value."""
    if x is None:
        return None
    x = float(x)
    return None if not np.isfinite(x) else x


def _candidate(c: str, d: dict) -> dict:
    out = {"name": c, "p_value": _num(d.get("p_value")), "delta_bic": _num(d.get("delta_bic")),
           "kept": bool(d.get("kept")), "reason": d.get("reason", "")}
    if d.get("head_to_head"):
        out["head_to_head"] = [{"vs": r["vs"], "outcome": r["outcome"], "p_this_beyond": _num(r["p_this_beyond"]),
                                "p_other_beyond": _num(r["p_other_beyond"])} for r in d["head_to_head"]]
    if d.get("onset_test"):           # Stribeck tested again at the breakaways under the joint's final model
        ot = d["onset_test"]
        out["at_breakaways"] = {"p_value": _num(ot.get("p_value")), "delta_bic": _num(ot.get("delta_bic")),
                                "reason": ot.get("reason", "")}
    return out


def _joint_dict(diag, j: int, res) -> dict:
    out = {
        "effects": res.effects,
        "candidates": [_candidate(c, d) for c, d in res.candidates.items()],
        "torque_rms_before_Nm": _num(res.torque_rms_before_Nm),
        "torque_rms_after_Nm": _num(res.torque_rms_after_Nm),
        "position_rms_before_rad": _num(res.position_rms_before_rad),
        "position_rms_after_rad": _num(res.position_rms_after_rad),
        "residual_whiteness_p_before": _num(res.whiteness_p_before),
        "residual_whiteness_p_after": _num(res.whiteness_p_after),
        "friction_before": friction_levels_before(diag, j),
        "friction_after": friction_levels_after(diag, j),
    }
    if res.position_not_checked:       # position_rms_* are then null: not a zero that reads as a perfect fit
        out["position_not_checked"] = res.position_not_checked
    if res.ambiguous:
        out["ambiguous"] = [g["names"] for g in res.ambiguous]
    if res.unexplained:
        out["unexplained"] = res.unexplained
    return out


def diagnosis_dict(diag, data_path: str = "") -> dict:
    """The ``diagnosis.json`` mapping of a fitted ``ModelDiagnosis`` (``data_path``: the data it was fitted on)."""
    joints = {str(j + 1): _joint_dict(diag, j, res) for j, res in sorted(diag.joints_.items())}
    model = DECLARED_MODEL
    dyn = getattr(diag, "dynamics_", None)
    if dyn is not None and dyn.robot.name != "wam7":      # the run's arm
        model = DECLARED_MODEL.replace("wam7", dyn.robot.name, 1)
    declared = model if diag.declared_.fitted else f"{model}, parameters from {diag.declared_.source}"
    out = {"format": FORMAT, "data": data_path, "declared_model": declared,
           "effects_found": list(diag.effects_found_), "joints": joints,
           "ambiguous": [list(g) for g in getattr(diag, "ambiguous_", [])],
           "not_named": list(getattr(diag, "arm_unnamed_", None) or []),
           "conclusive": bool(diag.conclusive_), "reason": diag.reason_}
    if dyn is not None and dyn.robot.name != "wam7":
        out["robot"] = dyn.robot.name
    torque = getattr(getattr(diag, "meta_", None), "torque_kind", "total")
    if torque != "total":       # the controller's output: only the joints of constant gravity torque diagnosed
        out["torque"] = torque
    if getattr(diag, "warnings_", None):
        out["warnings"] = list(diag.warnings_)
    check = getattr(diag, "against_declared_", None) if diag.conclusive_ else None
    if check is not None:       # the model written against the declared one, held-out torque RMS per joint
        from wamctl.analysis.diagnosis.honesty import worse_warnings

        out["held_out_vs_declared"] = {
            str(j + 1): {"torque_rms_declared_Nm": _num(c["torque_rms_declared_Nm"]),
                         "torque_rms_final_Nm": _num(c["torque_rms_final_Nm"]), "ratio": _num(c["ratio"]),
                         "worse": c["worse"], "note": c["note"],
                         "warning": (worse_warnings({j: c}) or [None])[0]}
            for j, c in sorted(check.items())}
        out["worse_than_declared"] = [j + 1 for j, c in sorted(check.items()) if c["worse"]]
    if getattr(diag, "payload_vs_links_", None):
        out["payload_or_links"] = diag.payload_vs_links_
    gains = getattr(diag, "gains_", None)
    if gains is not None or getattr(diag, "position_skipped_", None):
        out["position_check"] = {"controller_gains": gains,
                                 "skipped": getattr(diag, "position_skipped_", None)}
        pc = getattr(diag, "positions_", None)
        if pc is not None:          # which stretches of the run the check simulated and scored
            out["position_check"].update(
                spans_s=pc["spans_s"], samples_checked=int(pc["samples"]), samples_run=int(pc["samples_run"]),
                whole_run=bool(pc["samples"] == pc["samples_run"]))
    sig = getattr(diag, "signals_", None)
    if sig is not None:
        out["skipped_joints"] = {str(j + 1): r for j, r in sig.skipped.items()}
        # neither commanded nor moved: not diagnosed either (named, so that every joint is accounted for)
        out["idle_joints"] = [j + 1 for j in range(sig.q_raw_rad.shape[1])
                              if j not in sig.joints and j not in sig.skipped]
        out["method"] = {"test_threshold_p": _num(getattr(diag, "threshold_", float("nan"))),
                         "alpha_per_run": diag.alpha, "folds": diag.n_folds, "blocks": diag.n_blocks,
                         "savgol_window_samples": sig.window, "gauss_sigma_samples": sig.gauss,
                         "sample_rate_hz": 1.0 / sig.dt_s,
                         "samples": sig.n, "resampled": sig.resampled, "time_base": sig.time_base,
                         "velocities": "measured (qd columns)" if sig.qd_raw_rad_s is not None else
                         "differentiated positions",
                         "decimation": getattr(diag, "decimation_", 1)}
    return out
