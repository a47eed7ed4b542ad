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
    """``{"correlates_with": [groups], "torque_rms_Nm": ..., "tests": {group: p}}`` when the final held-out
    residual of joint ``j`` still follows some group of signals, else None."""
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
    if not found:
        return None
    e = e0[ok]
    return {"correlates_with": found, "torque_rms_Nm": float(np.sqrt(finite_ss(e) / len(e))),
            "p_values": tests}
