"""The controller's gains as the log shows them, for the closed-loop position check (no I/O).

A recording may come without its controller's gains, or with wrong ones. With gravity compensation, libbarrett's
PD + g law is linear in its gains: ``tau - g(q) = kp e + kd (e[k] - e[k-1]) / T``, ``e = q_ref - q``; the gains are
estimated per joint by least squares on the log (saturated samples left out) and judged by the share of the
torque they explain (``R^2``). The declared gains are used when they explain the log as well (``MIN_R2``); else the
estimated ones, said so; when neither does (a feed-forward, another control law), the closed-loop check is skipped
with the reason.
"""

from __future__ import annotations

import numpy as np

MIN_R2 = 0.9                 # share of the torque beyond gravity the PD law must explain
MAX_ROWS = 20000             # samples the gains are estimated on (spread over the run)


def _pd_system(sig, gravity, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(u, e, de) (m, 7) at ``rows``: the torque beyond the controller's gravity model (``gravity``: positions
    (m, 7) -> torques (m, 7), or None), the error and its backward difference over one sample."""
    def error(r):
        return sig.q_ref_rad[r] - sig.q_raw_rad[r]

    e = error(rows)
    de = np.zeros_like(e)
    ok = rows > 0
    de[ok] = (e[ok] - error(rows[ok] - 1)) / sig.dt_s
    g = gravity(sig.q_raw_rad[rows]) if gravity is not None else 0.0
    return sig.tau_raw_Nm[rows] - g, e, de


def _r2(u: np.ndarray, pred: np.ndarray) -> float:
    ss = float(np.sum((u - u.mean()) ** 2))
    return 1.0 - float(np.sum((u - pred) ** 2)) / ss if ss > 0 else float("nan")


def controller_gains(sig, meta, gravity) -> dict:
    """The gains the closed-loop check uses and where they come from (``gravity``: the controller's gravity
    model, positions (m, 7) -> torques (m, 7)).

    Returns ``{"kp", "kd"}`` (7,) lists or None (check skipped), ``source``, ``reason`` (why skipped, or None),
    ``kp_log``, ``kd_log``, ``r2_log`` (estimated), ``r2_declared`` (of the declared gains) per joint."""
    c = meta.controller
    n = sig.n
    rows = np.unique(np.linspace(1, n - 1, min(n - 1, MAX_ROWS)).astype(int))
    rows = rows[sig.usable(rows) & sig.usable(rows - 1)]        # not across a gap of the log
    u, e, de = _pd_system(sig, gravity if meta.gravity_compensation else None, rows)
    from wamctl.model.robots import get_robot

    robot = get_robot(getattr(meta, "robot", None))          # the run's arm: its joints, limits, default gains
    nj = robot.n_joints
    sat = np.abs(sig.tau_raw_Nm[rows]) >= 0.98 * robot.tau_max_Nm
    kp_log, kd_log, r2_log, r2_decl = (np.full(nj, np.nan) for _ in range(4))
    for j in range(nj):
        m = ~sat[:, j]
        if m.sum() < 50 or np.std(e[m, j]) <= 0:
            continue
        X = np.column_stack([e[m, j], de[m, j]])
        th = np.linalg.lstsq(X, u[m, j], rcond=None)[0]
        kp_log[j], kd_log[j] = th
        r2_log[j] = _r2(u[m, j], X @ th)
        if c.kp is not None and c.kd is not None:
            r2_decl[j] = _r2(u[m, j], X @ np.array([c.kp[j], c.kd[j]]))
    out = {"kp_log": _list(kp_log), "kd_log": _list(kd_log), "r2_log": _list(r2_log),
           "r2_declared": _list(r2_decl), "reason": None}
    js = sig.joints
    declared = c.kp is not None and c.kd is not None
    if c.kind == "pd_g_ff":
        if declared:
            return dict(out, kp=list(c.kp), kd=list(c.kd), source="meta.yaml (a feed-forward run: not checked)")
        return dict(out, kp=None, kd=None, source=None,
                    reason="a pd_g_ff run without its gains: the feed-forward hides the PD law in the log")
    if declared and all(np.nan_to_num(r2_decl[j]) >= MIN_R2 for j in js):
        return dict(out, kp=list(c.kp), kd=list(c.kd), source="meta.yaml, consistent with the log")
    if all(np.nan_to_num(r2_log[j]) >= MIN_R2 and kp_log[j] > 0 for j in js):
        fallback_kp = list(c.kp) if declared else list(robot.kp)
        fallback_kd = list(c.kd) if declared else list(robot.kd)
        ok = np.nan_to_num(r2_log) >= MIN_R2
        kp = [float(kp_log[j]) if ok[j] else fallback_kp[j] for j in range(nj)]
        kd = [float(kd_log[j]) if ok[j] else fallback_kd[j] for j in range(nj)]
        if declared:
            bad = [j + 1 for j in js if np.nan_to_num(r2_decl[j]) < MIN_R2]
            why = f"meta.yaml's gains do not fit the log at joints {bad} (R^2 below {MIN_R2})"
        else:
            why = "meta.yaml gives no gains"
        return dict(out, kp=kp, kd=kd, source=f"estimated from the log ({why})")
    worst = min(js, key=lambda j: np.nan_to_num(r2_log[j], nan=-1.0))
    return dict(out, kp=None, kd=None, source=None,
                reason=(f"the log does not follow a PD + gravity law with constant gains (joint {worst + 1}: "
                        f"R^2 {np.nan_to_num(r2_log[worst], nan=0.0):.2f}, at least {MIN_R2} needed)"
                        + ("" if declared else "; meta.yaml gives no gains")))


def _list(x: np.ndarray) -> list:
    return [None if not np.isfinite(v) else float(v) for v in x]
