"""The arm's own parameters: ``link_parameters``, a refit of the rigid-body parameters the data can determine,
against ``payload`` (no I/O).

Every real arm's links differ somewhat from their datasheet; a payload is the special case of an extra body on
link 7. The refit uses the base parameters of the identification (:mod:`wamctl.analysis.identification.base`:
the combinations of link parameters and armature any data could determine), restricted to those these data
determine (:func:`~wamctl.analysis.identification.base.identifiability`), shared by every diagnosed joint (one
arm), on top of each joint's own model (its friction and the other effects it kept). Held-out residuals: each
joint's folds, the shared parameters fitted without the fold.

The decision, on the held-out residuals of all diagnosed joints together (each joint weighted by its residual, as
the payload's fit): does the link refit add to the current model (the arm's payload, if one was kept)? With a
payload kept: no -> the payload stands (it explains the data as well as a refit of the links would, with ten
parameters); yes -> ``link_parameters`` is named instead (the payload was the part of the links' errors a wrist
mass can mimic). Without one: yes -> ``link_parameters``. The refit is one for the arm: it is tested when two
joints or more are diagnosed and named only when it passes the nested test of two of them or more on their own
(a refit that helps one joint only is just another function of that joint's angles, and takes up what another
effect's model left there).
"""

from __future__ import annotations

import numpy as np

from wamctl.analysis.diagnosis.design import N_FRICTION, Design, ncols, target_and_design
from wamctl.analysis.diagnosis.stats import MIN_EFFECT, finite_ss, lstsq, nested_test

RANK_RTOL = 1e-3
SHARE_TOL = 0.01
MIN_JOINTS = 2          # the arm's one refit must help two joints or more (each passing its own test)


def _own_terms(res) -> list[dict]:
    return [t for t in res.kept if t["name"] not in ("payload", "link_parameters")]


def identified_columns(jds: dict, joints: list[int]) -> tuple[np.ndarray, list[str]]:
    """(k,) indices of the rigid-body base columns these data determine, and the names of those they do not."""
    from wamctl.analysis.identification.base import N7, N_INERTIAL, base_parameters, identifiability

    base = base_parameters()
    cols = base.independent < N_INERTIAL + N7
    names = [n for n, c in zip(base.names, cols) if c]
    W = np.vstack([jds[j].extra["links_base"][:: max(1, jds[j].n // 3000)] for j in joints])
    # its columns: the rigid-body part of the base; a direction excited less than RANK_RTOL of the best (column
    # equilibrated) is not determined well enough to be refitted, a parameter with more than SHARE_TOL of it in
    # such directions neither
    ok = np.asarray(identifiability(W, rank_tol=RANK_RTOL, share_tol=SHARE_TOL).identified)
    return np.flatnonzero(ok), [n for n, k in zip(names, ok) if not k]


def base_names(cols: np.ndarray) -> list[str]:
    """Names of the rigid-body base columns ``cols``."""
    from wamctl.analysis.identification.base import N7, N_INERTIAL, base_parameters

    base = base_parameters()
    names = [n for n, i in zip(base.names, base.independent) if i < N_INERTIAL + N7]
    return [names[k] for k in cols]


def links_uncertainty(des: Design, joints: dict, jds: dict, test: dict) -> tuple[dict, dict]:
    """The refit's change of each determined base parameter (``d_<name>``, estimate) and its 95 % interval (a
    bootstrap over every joint's time blocks)."""
    from wamctl.analysis.diagnosis.uncertainty import group_bootstrap, percentile_ci

    js, cols = test["joints"], test["cols"]
    sub = {j: joints[j] for j in js}
    w = {j: 1.0 / max(sub[j].torque_rms_after_Nm, 1e-9) for j in js}
    own = {j: target_and_design(des, jds[j], _own_terms(sub[j]), None) for j in js}
    Z = {j: jds[j].extra["links_base"][:, cols] for j in js}
    X, y = _stack(js, own, Z, {j: np.ones(jds[j].n, bool) for j in js}, w)
    groups = np.vstack([np.column_stack([np.full(jds[j].n, j), jds[j].extra["block"]]) for j in js])
    reps = group_bootstrap(X, y, groups, rng=np.random.default_rng(5000))[:, -len(cols):]
    beta = test["betas"][None]
    names = [f"d_{n}" for n in base_names(cols)]
    ng = len({tuple(g) for g in groups})
    params = {n: float(b) for n, b in zip(names, beta)}
    ci = {n: percentile_ci(reps[:, k], center=beta[k], n_groups=ng) for k, n in enumerate(names)}
    return params, ci


def arm_links_cv(des: Design, joints: dict, jds: dict, cols: np.ndarray) -> tuple[dict, dict, np.ndarray]:
    """Held-out residuals {joint: (m,)} of each joint's own model plus the shared link refit (columns ``cols``),
    the refit per fold {fold: (k,)} and on all data (under key None), and the joints' weights (1 / residual)."""
    js = list(joints)
    w = {j: 1.0 / max(joints[j].torque_rms_after_Nm, 1e-9) for j in js}
    own = {j: target_and_design(des, jds[j], _own_terms(joints[j]), None) for j in js}
    Z = {j: jds[j].extra["links_base"][:, cols] for j in js}
    e = {j: np.full(jds[j].n, np.nan) for j in js}
    betas = {}
    for f in [None] + list(range(des.n_folds)):
        rows = {j: (np.ones(jds[j].n, bool) if f is None else jds[j].fold != f) for j in js}
        X, y = _stack(js, own, Z, rows, w)
        th = lstsq(X, y)
        beta = th[-len(cols):]
        betas[f] = beta
        if f is None:
            continue
        c0 = 0
        for j in js:
            y_j, X_j = own[j]
            p = X_j.shape[1]
            te = jds[j].fold == f
            e[j][te] = y_j[te] - X_j[te] @ th[c0:c0 + p] - Z[j][te] @ beta
            c0 += p
    return e, betas, np.array([w[j] for j in js])


def _stack(js, own, Z, rows, w) -> tuple[np.ndarray, np.ndarray]:
    """Each joint's own columns block-diagonal, the shared link columns stacked last; rows weighted."""
    n_own = sum(own[j][1].shape[1] for j in js)
    k = Z[js[0]].shape[1]
    m = sum(int(rows[j].sum()) for j in js)
    X = np.zeros((m, n_own + k))
    y = np.zeros(m)
    r0, c0 = 0, 0
    for j in js:
        y_j, X_j = own[j]
        sel = rows[j]
        nr, p = int(sel.sum()), X_j.shape[1]
        X[r0:r0 + nr, c0:c0 + p] = X_j[sel] * w[j]
        X[r0:r0 + nr, n_own:] = Z[j][sel] * w[j]
        y[r0:r0 + nr] = y_j[sel] * w[j]
        r0 += nr
        c0 += p
    return X, y


def links_test(des: Design, joints: dict, jds: dict, threshold: float) -> dict | None:
    """Does a refit of the arm's parameters add to the current model of the diagnosed joints? None when the data
    carry no link regressor (no payload candidate) or too few joints moved.

    Returns the nested test (``p_value``, ``delta_bic``, ...) with ``passes``, ``cols`` (the base columns fitted),
    ``not_identified`` (base parameters these data cannot determine), ``e`` {joint: held-out residual} and
    ``betas``."""
    js = [j for j in joints if "links_base" in jds[j].extra]
    if len(js) < MIN_JOINTS:       # one joint alone: a refit is just another function of its angle
        return None
    cols, undetermined = identified_columns(jds, js)
    if len(cols) == 0:
        return None
    sub = {j: joints[j] for j in js}
    e_l, betas, wts = arm_links_cv(des, sub, jds, cols)
    e0 = np.concatenate([sub[j].e_after * wt for j, wt in zip(js, wts)])
    e1 = np.concatenate([e_l[j] * wt for j, wt in zip(js, wts)])
    groups = np.concatenate([jds[j].fold + 10 * j for j in js])
    base_ss = sum(finite_ss(sub[j].e_base) * wt ** 2 for j, wt in zip(js, wts))
    share = base_ss / max(finite_ss(e0), 1e-300)
    has_payload = any(t["name"] == "payload" for j in js for t in sub[j].kept)
    p_extra = max(len(cols) - (10 if has_payload else 0), 1)
    k1 = sum(N_FRICTION + sum(ncols(t) for t in _own_terms(sub[j])) for j in js) + len(cols)
    t = nested_test(e0, e1, p_extra, k1, min(MIN_EFFECT * share, 0.9), groups)
    helped = []
    for j in js:           # each joint on its own: the refit must pass the joint's own nested test
        share_j = finite_ss(sub[j].e_base) / max(finite_ss(sub[j].e_after), 1e-300)
        k_j = N_FRICTION + sum(ncols(x) for x in _own_terms(sub[j])) + len(cols)
        tj = nested_test(sub[j].e_after, e_l[j], p_extra, k_j, min(MIN_EFFECT * share_j, 0.9), jds[j].fold)
        if tj["p_value"] < threshold and tj["delta_bic"] < 0:
            helped.append(j)
    t.update(passes=bool(t["p_value"] < threshold and t["delta_bic"] < 0 and len(helped) >= MIN_JOINTS),
             cols=cols, not_identified=undetermined, e=e_l, betas=betas, joints=js, has_payload=has_payload,
             helped=helped)
    return t


WIDE_PRIOR = 2.0       # the grey zone: link errors up to twice the declared accuracy may still be the arm's own


def payload_or_links(des: Design, joints: dict, jds: dict, threshold: float, link_map: np.ndarray) -> dict | None:
    """A wrist payload, or the arm's own links within their declared accuracy? On the held-out residuals of every
    diagnosed joint together (each joint's own model, the payload and link terms left out; joints weighted by
    the RMS of their residual), nested tests:

    * ``beyond_links``: does a payload (ten free inertial parameters of link 7) add to link errors within the
      declared accuracy (``link_map``, :func:`~wamctl.analysis.diagnosis.rigid.plausible_link_map`, each
      physical parameter within its bound)?
    * ``beyond_wide_links``: does it add to link errors within ``WIDE_PRIOR`` times the declared accuracy?

    ``outcome``: ``"payload"`` when both pass (a wrist mass explains what plausible link errors cannot),
    ``"ambiguous"`` when only the first does (beyond the declared accuracy, within twice it: the data cannot tell
    a payload from a datasheet worse than assumed), ``"link_parameters"`` when a payload does not add to plausible
    link errors (they explain the data as well). None without link regressors."""
    from wamctl.analysis.diagnosis.rigid import arm_cv, arm_system, payload_map

    js = [j for j in joints if "links_base" in jds[j].extra]
    if not js:
        return None
    own = {j: target_and_design(des, jds[j], _own_terms(joints[j]), None) for j in js}
    sys_ = arm_system(des, jds, own, dict.fromkeys(js, 1.0))
    e_own, _ = arm_cv(sys_, jds, None)
    sys_.w = {j: 1.0 / max(float(np.sqrt(np.nanmean(e_own[j] ** 2))), 1e-9) for j in js}
    P = payload_map()
    free = np.full(P.shape[1], np.inf)
    nl = link_map.shape[1]
    fits = {}
    for name, scale in (("links", 1.0), ("wide_links", WIDE_PRIOR)):
        fits[name] = arm_cv(sys_, jds, link_map, np.full(nl, scale))
        fits["payload+" + name] = arm_cv(sys_, jds, np.hstack([P, link_map]), np.r_[free, np.full(nl, scale)])
    w = sys_.w
    pool = lambda e: np.concatenate([e[j] * w[j] for j in js])             # noqa: E731
    groups = np.concatenate([jds[j].fold + 10 * j for j in js])
    base_ss = sum(finite_ss(joints[j].e_base) * w[j] ** 2 for j in js)
    k_own = sum(own[j][1].shape[1] for j in js)
    p_pay = max(_payload_rank(des, jds, js, P), 1)
    tests = {}
    for name in ("links", "wide_links"):
        e0, e1 = pool(fits[name][0]), pool(fits["payload+" + name][0])
        share = base_ss / max(finite_ss(e0), 1e-300)
        tests["beyond_" + name] = nested_test(e0, e1, p_pay, k_own + p_pay + nl, min(MIN_EFFECT * share, 0.9),
                                              groups)
    ok = {k: bool(t["p_value"] < threshold and t["delta_bic"] < 0) for k, t in tests.items()}
    outcome = ("payload" if ok["beyond_wide_links"] and ok["beyond_links"] else
               "ambiguous" if ok["beyond_links"] else "link_parameters")
    return {"outcome": outcome, "tests": tests, "passes": ok, "joints": js, "payload_params_seen": p_pay,
            "ssr_ratio": {k: finite_ss(pool(v[0])) / max(finite_ss(pool(e_own)), 1e-300) for k, v in fits.items()}}


def _payload_rank(des: Design, jds: dict, js: list[int], P: np.ndarray) -> int:
    """How many payload parameters (combinations) the diagnosed joints' motion excites."""
    from wamctl.analysis.diagnosis.uncertainty import RANK_RTOL as RTOL

    Z = np.vstack([jds[j].extra["links_base"][:: max(1, jds[j].n // 3000)] @ P for j in js])
    scale = np.sqrt((Z ** 2).sum(axis=0))
    live = scale > 1e-12 * max(scale.max(), 1e-300)
    if not live.any():
        return 0
    sv = np.linalg.svd(Z[:, live] / scale[live], compute_uv=False)
    return int(np.sum(sv > sv[0] * RTOL))
