"""The arm's own parameters: ``link_parameters``, a refit of the rigid-body parameters the data can determine,
against ``payload`` (no I/O).

Every real arm's links differ somewhat from their datasheet; a payload is the special case of an extra body on
link 7. The refits (:mod:`wamctl.analysis.diagnosis.rigid`) change the base parameters of the identification
(:mod:`wamctl.analysis.identification.base`) shared by every diagnosed joint (one arm), on top of each joint's own
model (its friction and the other effects it kept); held-out residuals: each joint's folds, the shared change
fitted without the fold; the joints are pooled, each weighted by the inverse of the RMS of its own held-out
residual.

**Payload or links** (:func:`payload_or_links`). On a sweep of one joint, a payload and an error of the distal
links change the same two gravity coefficients and one inertia; on free motion of several joints a payload moves
every joint's torque in its own way, but link errors can still mimic part of it. What tells them apart is size:
the declared arm's parameters are known to a declared accuracy (:data:`~wamctl.analysis.diagnosis.rigid.
LINK_PRIOR_SHARE`), so the change plausible link errors can make is bounded. A payload (a positive mass within
``PAYLOAD_COM_BOX_M`` of the flange) is named when it adds to the link errors within that accuracy and either
to those within ``WIDE_PRIOR`` times it too, or by itself leaves at least ``DECIDED_FLOORS`` noise floor at a
joint that no link error within the declared accuracy reproduces (issue 28's "identifiable": outside what the
declared link accuracy can produce; the same line the delay-or-inertia decision draws); a payload that adds to
the declared accuracy's link errors by less, and not to the wide ones, the data cannot tell from a datasheet
worse than declared (``ambiguous``); when it does not add to plausible link errors, they explain the data as well
(``link_parameters``). :func:`payload_outcome` is the rule, for one run and pooled runs alike.

**Links** (:func:`links_test`): does a refit of the arm's parameters add to the current model (the arm's payload,
if one was kept)? The free refit (the base parameters these data determine) is tested when two joints or more are
diagnosed and named only when it passes the nested test of two of them or more on their own (a refit that helps
one joint only is just another function of that joint's angles, and takes up what another effect's model left
there); the refit within the declared accuracy, after a payload candidate was found to be the links', needs one.
"""

from __future__ import annotations

import numpy as np

from wamctl.analysis.diagnosis.candidates import robot_of
from wamctl.analysis.diagnosis.design import Design, target_and_design
from wamctl.analysis.diagnosis.stats import DECIDED_FLOORS, MIN_EFFECT, excess_floors, finite_ss, lstsq, nested_test

SHARE_TOL = 0.01        # a base parameter with more than this share outside the determined directions
MIN_JOINTS = 2          # the arm's one refit must help two joints or more (each passing its own test)
WIDE_PRIOR = 2.0       # up to twice the declared accuracy a datasheet may still be the arm's own (the grey zone)


def _own_terms(res, with_payload: bool = False) -> list[dict]:
    """The joint's kept terms but the rigid-body ones (the arm's payload kept when ``with_payload``)."""
    drop = ("link_parameters",) if with_payload else ("payload", "link_parameters")
    return [t for t in res.kept if t["name"] not in drop]


def base_names(cols: np.ndarray, robot: str = "wam7") -> list[str]:
    """Names of the rigid-body base columns ``cols`` (of ``robot``'s base parameters)."""
    from wamctl.analysis.identification.base import base_parameters

    base = base_parameters(robot)
    names = [n for n, i in zip(base.names, base.independent) if i < 11 * base.n_joints]
    return [names[k] for k in cols]


def links_uncertainty(des: Design, joints: dict, jds: dict, test: dict) -> tuple[dict, dict]:
    """The change of each base parameter these data determine (``d_<name>``: the free refit's estimate, on top of
    the payload when one is kept) and its 95 % interval (a bootstrap over every joint's time blocks)."""
    from wamctl.analysis.diagnosis.uncertainty import group_bootstrap, percentile_ci

    js, cols = test["joints"], test["cols"]
    sub = {j: joints[j] for j in js}
    w = {j: 1.0 / max(sub[j].torque_rms_after_Nm, 1e-9) for j in js}
    own = {j: target_and_design(des, jds[j], _own_terms(sub[j], test["has_payload"]), None) for j in js}
    Z = {j: jds[j].extra["links_base"][:, cols] for j in js}
    X, y = _stack(js, own, Z, {j: np.ones(jds[j].n, bool) for j in js}, w)
    groups = np.vstack([np.column_stack([np.full(jds[j].n, j), jds[j].extra["block"]]) for j in js])
    reps = group_bootstrap(X, y, groups, rng=np.random.default_rng(5000))[:, -len(cols):]
    beta = lstsq(X, y)[-len(cols):]
    names = [f"d_{n}" for n in base_names(cols, robot_of(des))]
    ng = len({tuple(g) for g in groups})
    params = {n: float(b) for n, b in zip(names, beta)}
    ci = {n: percentile_ci(reps[:, k], center=beta[k], n_groups=ng) for k, n in enumerate(names)}
    return params, ci


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


def arm_links(des: Design, joints: dict, jds: dict, js: list[int], with_payload: bool = False):
    """The arm's normal equations (:func:`~wamctl.analysis.diagnosis.rigid.arm_system`) of joints ``js`` with
    their own models (the payload kept when ``with_payload``), each weighted by the RMS of its held-out residual;
    and that residual {j: (m,)}."""
    from wamctl.analysis.diagnosis.rigid import arm_cv, arm_system

    own = {j: target_and_design(des, jds[j], _own_terms(joints[j], with_payload), None) for j in js}
    sys_ = arm_system(des, jds, own, dict.fromkeys(js, 1.0))
    e_own, _, _ = arm_cv(sys_, jds, None)
    sys_.w = {j: 1.0 / max(float(np.sqrt(np.nanmean(e_own[j] ** 2))), 1e-9) for j in js}
    return sys_, e_own


def _pooled_test(sys_, joints: dict, jds: dict, e0: dict, e1: dict, p_extra: int, of_declared: bool = True) -> dict:
    """Nested test of ``e1`` against ``e0`` ({j: held-out residual}) over the joints of ``sys_`` pooled (rows
    weighted as fitted); the minimum effect is a share of the declared models' residual (``of_declared``) or of
    ``e0``'s."""
    js, w = sys_.js, sys_.w
    pool = lambda e: np.concatenate([e[j] * w[j] for j in js])             # noqa: E731
    a, b = pool(e0), pool(e1)
    share = sum(finite_ss(joints[j].e_base) * w[j] ** 2 for j in js) / max(finite_ss(a), 1e-300) \
        if of_declared else 1.0
    k1 = sum(sys_.own[j][1].shape[1] for j in js) + p_extra
    return nested_test(a, b, p_extra, k1, min(MIN_EFFECT * share, 0.9),
                       np.concatenate([jds[j].fold + 10 * j for j in js]))


def links_test(des: Design, joints: dict, jds: dict, threshold: float, link_map: np.ndarray | None = None,
               min_joints: int = MIN_JOINTS) -> dict | None:
    """Does a refit of the arm's parameters add to the current model of the diagnosed joints (the arm's payload
    kept, if any)? ``link_map`` None: the free refit of the base parameters these data determine; else the refit
    within the declared accuracy (``link_map``, coefficients in [-1, 1]). None when the data carry no link
    regressor or fewer than ``min_joints`` joints moved.

    Returns the nested test (``p_value``, ``delta_bic``, ...) with ``passes``, ``cols`` (the base columns the
    free refit changes), ``not_identified`` (base parameters these data cannot determine), ``e`` {joint: held-out
    residual with the refit}, ``e0`` (without it), ``betas`` {fold: the change of the base parameters},
    ``helped`` (the joints whose own test it passes)."""
    from wamctl.analysis.diagnosis.rigid import arm_cv, determined_parameters, payload_map

    js = [j for j in joints if "links_base" in jds[j].extra]
    if len(js) < min_joints:       # one joint alone: a refit is just another function of its angle
        return None
    has_payload = any(t["name"] == "payload" for j in js for t in joints[j].kept)
    sys_, e0 = arm_links(des, joints, jds, js, has_payload)
    ok, rank = determined_parameters(sys_, SHARE_TOL)
    cols, undetermined = np.flatnonzero(ok), [n for n, k in zip(base_names(np.arange(len(ok)), robot_of(des)), ok)
                                              if not k]
    if rank == 0:
        return None
    if link_map is None:
        A, bounds = np.eye(sys_.n_base), None
        p_extra = max(rank - (_excited_rank(jds, js, payload_map(robot_of(des))) if has_payload else 0), 1)
    else:
        A, bounds = link_map, (-np.ones(link_map.shape[1]), np.ones(link_map.shape[1]))
        p_extra = rank
    e_l, betas, _ = arm_cv(sys_, jds, A, bounds)
    t = _pooled_test(sys_, joints, jds, e0, e_l, p_extra)
    helped = []
    for j in js:           # each joint on its own: the refit must pass the joint's own nested test
        share_j = finite_ss(joints[j].e_base) / max(finite_ss(e0[j]), 1e-300)
        k_j = sys_.own[j][1].shape[1] + p_extra
        tj = nested_test(e0[j], e_l[j], p_extra, k_j, min(MIN_EFFECT * share_j, 0.9), jds[j].fold)
        if tj["p_value"] < threshold and tj["delta_bic"] < 0:
            helped.append(j)
    t.update(passes=bool(t["p_value"] < threshold and t["delta_bic"] < 0 and len(helped) >= min_joints),
             cols=cols, not_identified=undetermined, e=e_l, e0=e0, betas=betas, joints=js, has_payload=has_payload,
             helped=helped, bounded=link_map is not None)
    return t


def payload_or_links(des: Design, joints: dict, jds: dict, threshold: float, link_map: np.ndarray,
                     com_box_m: float) -> dict | None:
    """A wrist payload, or the arm's own links within their declared accuracy? Nested tests on the held-out
    residuals of every diagnosed joint together (each joint's own model, the rigid-body terms left out):

    * ``beyond_links``: does a wrist payload (a positive mass within ``com_box_m`` of the flange in each
      coordinate, :func:`~wamctl.analysis.diagnosis.rigid.payload_cone`) add to link errors within the declared
      accuracy (``link_map``, :func:`~wamctl.analysis.diagnosis.rigid.plausible_link_map`)?
    * ``beyond_wide_links``: does it add to link errors within ``WIDE_PRIOR`` times that accuracy?

    ``outcome`` (:func:`payload_outcome`): ``"payload"`` when both pass, or the first does and the payload leaves
    at least ``DECIDED_FLOORS`` noise floor beyond the declared accuracy's link errors at a joint
    (``excess_noise_floors`` {0-based joint: floors}), ``"ambiguous"`` when only the first passes and the excess is
    smaller, ``"link_parameters"`` when a payload does not add to plausible link errors (the second test is then
    not made). Also ``payload_seen`` (the mass and first-moment combinations the motion excites), ``cone_fit``
    (a wrist payload that explains the data on its own, all data: ``mass_kg``, ``com_m``) and ``ssr_ratio``
    {model: held-out SSR / the own models'}. None without link regressors."""
    from wamctl.analysis.diagnosis.candidates import payload_from_pi
    from wamctl.analysis.diagnosis.rigid import arm_cv, payload_cone, payload_map

    js = [j for j in joints if "links_base" in jds[j].extra]
    if not js:
        return None
    sys_, e_own = arm_links(des, joints, jds, js)
    robot = robot_of(des)
    cone, rays = payload_cone(com_box_m, robot)
    nl, nc = link_map.shape[1], cone.shape[1]
    pos = (np.zeros(nc), np.full(nc, np.inf))
    p_pay = max(_excited_rank(jds, js, payload_map(robot)[:, :4]), 1)
    fits, tests, ok = {}, {}, {}
    for name, scale in (("links", 1.0), ("wide_links", WIDE_PRIOR)):
        lim = np.full(nl, scale)
        fits[name] = arm_cv(sys_, jds, link_map, (-lim, lim))
        fits["payload+" + name] = arm_cv(sys_, jds, np.hstack([cone, link_map]),
                                         (np.r_[pos[0], -lim], np.r_[pos[1], lim]))
        t = _pooled_test(sys_, joints, jds, fits[name][0], fits["payload+" + name][0], p_pay, False)
        tests["beyond_" + name], ok["beyond_" + name] = t, bool(t["p_value"] < threshold and t["delta_bic"] < 0)
        if not ok["beyond_" + name]:
            break                   # within the declared accuracy already
    excess = payload_excess_floors(fits["links"][0], fits["payload+links"][0])
    outcome = payload_outcome(ok, excess)
    ss0 = sum(finite_ss(e_own[j]) * sys_.w[j] ** 2 for j in js)
    mh = rays @ arm_cv(sys_, jds, cone, pos, folds=False)[2][None]
    return {"outcome": outcome, "tests": tests, "passes": ok, "joints": js, "payload_seen": p_pay,
            "excess_noise_floors": excess,
            "cone_fit": payload_from_pi(mh, robot) if mh[0] > 0 else None,
            "ssr_ratio": {k: sum(finite_ss(v[0][j]) * sys_.w[j] ** 2 for j in js) / max(ss0, 1e-300)
                          for k, v in fits.items()}}


def payload_excess_floors(e_links: dict, e_payload: dict) -> dict:
    """{joint key: what the wrist payload adds to link errors within the declared accuracy, in noise floors}: the
    excess (:func:`~wamctl.analysis.diagnosis.stats.excess_floors`) of the links-only model's held-out residual RMS
    ``e_links`` over the payload model's ``e_payload`` (the joint's noise floor), on the samples where both are
    finite."""
    out = {}
    for k, a in e_links.items():
        b = e_payload[k]
        ok = np.isfinite(a) & np.isfinite(b)
        if ok.any():
            out[k] = excess_floors(float(np.sqrt(np.mean(a[ok] ** 2))), float(np.sqrt(np.mean(b[ok] ** 2))))
    return out


def payload_outcome(passes: dict, excess: dict) -> str:
    """The payload-or-links decision from its tests' ``passes`` (``beyond_links``, ``beyond_wide_links``) and the
    payload's excess over link errors within the declared accuracy per joint (:func:`payload_excess_floors`):
    ``"link_parameters"`` when the payload does not add to them; ``"payload"`` when it adds to the wide ones too,
    or leaves at least ``DECIDED_FLOORS`` noise floor at a joint that they cannot reproduce; else
    ``"ambiguous"``."""
    if not passes.get("beyond_links"):
        return "link_parameters"
    if passes.get("beyond_wide_links") or max(excess.values(), default=0.0) >= DECIDED_FLOORS:
        return "payload"
    return "ambiguous"


def _excited_rank(jds: dict, js: list[int], P: np.ndarray) -> int:
    """How many combinations of the payload parameters ``P`` (base map columns) the joints' motion excites."""
    from wamctl.analysis.diagnosis.uncertainty import RANK_RTOL as RTOL

    Z = np.vstack([jds[j].extra["links_base"][:: max(1, jds[j].n // 3000)] @ P for j in js])
    scale = np.sqrt((Z ** 2).sum(axis=0))
    live = scale > 1e-12 * max(scale.max(), 1e-300)
    if not live.any():
        return 0
    sv = np.linalg.svd(Z[:, live] / scale[live], compute_uv=False)
    return int(np.sum(sv > sv[0] * RTOL))


def rigid_body_r2(des: Design, jds: dict, js: list[int], link_map: np.ndarray, com_box_m: float) -> float:
    """Share of the torque variance of joints ``js`` the declared model explains (held-out, friction fitted) once
    the arm may carry a wrist payload (any positive mass within ``com_box_m`` of the flange) and its links may be
    off by up to ``WIDE_PRIOR`` times their declared accuracy: a large payload is still this arm."""
    from wamctl.analysis.diagnosis.rigid import arm_cv, arm_system, payload_cone

    js = [j for j in js if "links_base" in jds[j].extra]
    if not js:
        return float("-inf")
    sys_ = arm_system(des, jds, {j: target_and_design(des, jds[j], [], None) for j in js}, dict.fromkeys(js, 1.0))
    cone, _ = payload_cone(com_box_m, robot_of(des))
    nc, lim = cone.shape[1], np.full(link_map.shape[1], WIDE_PRIOR)
    bounds = (np.r_[np.zeros(nc), -lim], np.r_[np.full(nc, np.inf), lim])
    e, _, _ = arm_cv(sys_, jds, np.hstack([cone, link_map]), bounds)
    ss_res = sum(finite_ss(e[j]) for j in js)
    ss_tot = sum(float(np.sum((jds[j].extra["tau"] - jds[j].extra["tau"].mean()) ** 2)) for j in js)
    return 1.0 - ss_res / ss_tot if ss_tot > 0 else 0.0
