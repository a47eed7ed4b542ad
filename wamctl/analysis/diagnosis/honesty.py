"""The diagnosis' final model against the declared one on held-out torque (issue 27: a model that predicts
held-out torque worse than the declared arm is never written quietly). No I/O.

What the selection already guarantees, and what it does not: every effect kept passed a held-out nested F-test
on the joint's sliding samples against the model without it, and a joint's own effect (Stribeck, a ripple, a
drift, a dead band behind the encoder) must take at least 1 - ``NET_GAIN`` off the joint's held-out torque RMS,
sliding samples and stalls together, against the same model without it (``ModelDiagnosis._check_net_gain``).
That is a comparison with the model one effect smaller, not with the declared model, and the arm's payload,
delay and link errors are judged over the arm: a joint's final model can still predict its held-out torque
(sliding samples and stalls) worse than the declared model, and the model file hangs the arm's one payload on
every joint, also on a joint whose own model did not keep it (``arm.payload_inconsistency`` allows up to twice
the residual power there). So it is checked here, per joint, on the model as written.
"""

from __future__ import annotations

import numpy as np

from wamctl.analysis.diagnosis.arm import held_out_with_fixed


def _rms(*parts) -> float:
    e = np.concatenate([p[np.isfinite(p)] for p in parts if p is not None and len(p)])
    return float(np.sqrt(np.mean(e ** 2))) if len(e) else float("nan")


def rms_with_arm_payload(diag, j: int) -> float:
    """Held-out torque RMS (sliding samples and the joint's own stall residual) of 0-based joint ``j``'s final
    model with the arm's payload added as the model file writes it (fitted without each fold, fixed), the joint's
    other coefficients refitted without the fold."""
    jd, res = diag.jd_[j], diag.joints_[j]
    e = held_out_with_fixed(diag.design_, jd, res.kept, lambda f: jd.extra["payload"] @ diag.payload_pi_[f])
    e[~np.isfinite(res.e_after)] = np.nan
    return _rms(e, res.stall_after)


def against_declared(diag) -> dict:
    """{0-based joint: {"torque_rms_declared_Nm", "torque_rms_final_Nm", "ratio", "worse", "note"}} for every
    diagnosed joint: the held-out torque RMS of the declared model (classic friction fitted on the same data, or
    the given model file's) and of the final model as the model file writes it; ``worse`` when the final one is
    larger. Where the two differ, ``note`` says how the figure relates to model.yaml (the arm's payload added;
    the arm's delay not counted at a joint whose own model left it out; a link refit that the file does not
    carry)."""
    out = {}
    payload = getattr(diag, "payload_", None) is not None and getattr(diag, "payload_pi_", None)
    for j, res in diag.joints_.items():
        before, after, note = res.torque_rms_before_Nm, res.torque_rms_after_Nm, None
        own = any(t["name"] == "payload" for t in res.kept)
        if payload and not own and "payload" in diag.jd_[j].extra:
            after = rms_with_arm_payload(diag, j)
            note = "with the arm's payload, which the model file carries and this joint's own model did not keep"
        if "delay" in diag.effects_found_ and not any(t["name"] == "delay" for t in res.kept):
            note = "; ".join(x for x in (note, "without the arm's delay, which model.yaml writes for every joint "
                                               "and this joint's own model left out (not counted here)") if x)
        if any(t["name"] == "link_parameters" for t in res.kept):
            note = "; ".join(x for x in (note, "with the arm's link refit, which model.yaml does not carry (it "
                                               "writes effects and the declared links)") if x)
        ok = np.isfinite(before) and np.isfinite(after)
        out[j] = {"torque_rms_declared_Nm": float(before), "torque_rms_final_Nm": float(after),
                  "ratio": float(after / before) if ok and before > 0 else float("nan"),
                  "worse": bool(ok and after > before), "note": note}
    return out


def worse_warnings(check: dict) -> list[str]:
    """One warning per joint whose final model predicts held-out torque worse than the declared model."""
    return [f"joint {j + 1}: the model written (model.yaml) predicts the held-out torque worse than the declared "
            f"model: RMS {c['torque_rms_final_Nm']:.3g} N m against {c['torque_rms_declared_Nm']:.3g} N m "
            f"(+{100 * (c['ratio'] - 1):.0f} %)" + (f", {c['note']}" if c["note"] else "")
            for j, c in sorted(check.items()) if c["worse"]]
