"""What is left: when a joint's residual is still structured after every named effect, what it correlates with
(no I/O).

Instead of forcing a name on it, the final held-out residual of each joint is regressed, fold by fold, on small
bases of the joint's signals; a group that predicts the held-out residual (the nested test of the candidates, at
the run's threshold, here against the null hypothesis that it explains at most ``MIN_SHARE`` of the residual) is
reported as something the residual still follows:

============  =====================================================================================
group         basis (at the joint's samples, smoothed like the torque where built from the state)
============  =====================================================================================
velocity      ``qd``, ``qd |qd|``, ``qd^3`` (scaled)
acceleration  ``qdd``, ``qdd |qdd|`` (scaled)
position      ``q``, ``q^2``, ``sin q``, ``cos q``, ``sin 2q``, ``cos 2q`` (centred)
time          ``t``, ``t^2``, ``t^3`` over the run (scaled)
lagged        velocity and acceleration 10 ms earlier and later, less their present values
============  =====================================================================================

A residual that is not white (Ljung-Box at the run's threshold) on a joint where no effect is named, yet follows
none of these groups, is said too (``correlates_with`` empty, its whiteness p given): structure nobody named.

:func:`arm_unnamed`: what the arm-level checks found that no joint kept (a payload, or link errors within the
declared accuracy that explain the residual as well as a payload), each with how much of the held-out residual
it explains and why it is not named, for ``diagnosis.json``'s ``not_named``, the report and the terminal.
"""

from __future__ import annotations

import numpy as np

from wamctl.analysis.diagnosis.stats import finite_ss, lstsq, nested_test

GROUPS = ("velocity", "acceleration", "position", "time", "lagged")
MIN_SHARE = 0.2          # a group must explain this share of the residual left: structure worth a user's look
LAG_S = 0.010


def _scaled(*cols) -> np.ndarray:
    X = np.column_stack(cols)
    s = np.abs(X).max(axis=0)
    s[s == 0] = 1.0
    return X / s


def group_columns(diag, j: int, group: str) -> np.ndarray:
    """(m, k) basis of ``group`` at the samples of 0-based joint ``j``."""
    jd, sig = diag.jd_[j], diag.signals_
    q, qd, qdd = jd.q_rad, jd.qd_rad_s, jd.qdd_rad_s2
    if group == "velocity":
        return _scaled(qd, qd * np.abs(qd), qd ** 3)
    if group == "acceleration":
        return _scaled(qdd, qdd * np.abs(qdd))
    if group == "position":
        c = q - q.mean()
        return _scaled(c, c ** 2, np.sin(q), np.cos(q), np.sin(2 * q), np.cos(2 * q))
    if group == "time":
        u = jd.t_s - jd.t_s[0]
        u = u / max(u.max(), 1e-9) - 0.5
        return _scaled(u, u ** 2, u ** 3)
    if group == "lagged":
        k = LAG_S / sig.dt_s
        cols = []
        for what in ("qd", "qdd"):
            now = sig.at(what, jd.idx, joint=j)
            for s in (-k, k):
                cols.append(sig.at(what, jd.idx, s, j) - now)
        return _scaled(*cols)
    raise ValueError(group)


def unexplained(diag, j: int) -> dict | None:
    """``{"correlates_with": [groups], "torque_rms_Nm": ..., "p_values": {group: p}, "whiteness_p": ...}`` when
    the final held-out residual of joint ``j`` still follows some group of signals, or is not white while the
    joint has no effect named (``correlates_with`` empty), else None."""
    res, jd = diag.joints_[j], diag.jd_[j]
    e0 = np.asarray(res.e_after, float)
    ok = np.isfinite(e0)
    if ok.sum() < 50:
        return None
    found, tests = [], {}
    k_model = len(res.theta_after) if res.theta_after is not None else 4
    for g in GROUPS:
        X = group_columns(diag, j, g)
        e1 = np.full(jd.n, np.nan)
        for f in range(diag.n_folds):
            te, tr = (jd.fold == f) & ok, (jd.fold != f) & ok
            if te.sum() == 0 or tr.sum() < X.shape[1] + 10:
                continue
            e1[te] = e0[te] - X[te] @ lstsq(X[tr], e0[tr])
        t = nested_test(e0, e1, X.shape[1], k_model + X.shape[1], MIN_SHARE, jd.fold)
        tests[g] = float(t["p_value"])
        if t["p_value"] < diag.threshold_ and t["delta_bic"] < 0:
            found.append(g)
    white_p = float(res.whiteness_p_after)
    non_white = bool(np.isfinite(white_p) and white_p < diag.threshold_ and not res.kept)
    if not found and not non_white:
        return None
    e = e0[ok]
    return {"correlates_with": found, "torque_rms_Nm": float(np.sqrt(finite_ss(e) / len(e))),
            "p_values": tests, "whiteness_p": white_p if np.isfinite(white_p) else None}


def arm_unnamed(diag) -> list[dict]:
    """Arm-level findings no joint kept: ``[{"name", "joints", "held_out_ssr_ratio", "why"}]``.

    * the payload-or-links decision said ``link_parameters`` (link errors within the declared accuracy explain
      the held-out torque as well as a wrist payload) but ``link_parameters`` was not named: its refit's share of
      the residual and why (its own test, or not a candidate);
    * it said ``payload`` but the payload was dropped afterwards (not a wrist payload, inconsistent joints...);
    * it said ``ambiguous`` and no joint carries the ambiguity.

    ``held_out_ssr_ratio``: the arm refit's held-out squared residual over the joints' own models' (below 1: it
    explains part of the residual; 1 - ratio is that share)."""
    dec = getattr(diag, "payload_vs_links_", None)
    if not dec:
        return []
    found, amb = set(diag.effects_found_), {tuple(g) for g in getattr(diag, "ambiguous_", [])}
    ratio = dec.get("ssr_ratio", {})
    out = []
    if dec["outcome"] == "link_parameters" and "link_parameters" not in found:
        reasons = {r.candidates["link_parameters"]["reason"] for r in diag.joints_.values()
                   if "link_parameters" in r.candidates and r.candidates["link_parameters"].get("reason")}
        if "link_parameters" not in diag.candidates:
            why = "link_parameters is not among the candidates tested"
        elif reasons:
            why = "; ".join(sorted(reasons))
        else:
            why = "the refit of the arm's links was not made (no joint with the rigid-body regressors)"
        out.append({"name": "link_parameters", "joints": list(dec["joints"]),
                    "held_out_ssr_ratio": ratio.get("links"),
                    "why": ("a wrist payload was tested and does not add to link errors within the declared "
                            f"accuracy, which explain {_share(ratio.get('links'))} of the joints' held-out residual; "
                            f"not named: {why}")})
    elif dec["outcome"] == "payload" and "payload" not in found:
        out.append({"name": "payload", "joints": list(dec["joints"]),
                    "held_out_ssr_ratio": ratio.get("payload+wide_links"),
                    "why": "a wrist payload adds to link errors within twice the declared accuracy, but was dropped: "
                           + str(getattr(diag, "payload_dropped_", None) or "no joint kept it")})
    elif dec["outcome"] == "ambiguous" and ("link_parameters", "payload") not in amb:
        out.append({"name": "payload / link_parameters", "joints": list(dec["joints"]),
                    "held_out_ssr_ratio": ratio.get("payload+links"),
                    "why": "ambiguous at the arm level (a payload or a datasheet worse than declared), and no joint "
                           "carries the ambiguity"})
    return out


def _share(ratio) -> str:
    return "an unknown share" if ratio is None or not np.isfinite(ratio) else f"{max(0.0, 1.0 - ratio):.0%}"
