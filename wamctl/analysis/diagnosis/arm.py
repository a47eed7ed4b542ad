"""Effects that are one for the whole arm: a payload and a measurement delay (no I/O).

Each joint's forward selection may keep a payload or a delay on its own; the arm has one of each. A payload
is fitted over every joint that kept it (shared mass and first moment) and must be a wrist payload; a delay
must be seen alike at half the diagnosed joints or more. Joints that disagree are diagnosed again without it.
"""

from __future__ import annotations

import numpy as np

from wamctl.analysis.diagnosis.candidates import payload_from_pi, robot_of
from wamctl.analysis.diagnosis.design import Design, target_and_design
from wamctl.analysis.diagnosis.stats import finite_ss, lstsq

# a wrist payload the WAM can carry (its rated payload is about 4 kg; PayloadEffect allows up to 5 kg), held
# within half a metre of the flange
PAYLOAD_MASS_RANGE_KG = (0.01, 10.0)
PAYLOAD_MAX_COM_M = 0.5
# the payloads weighed against the arm's own link errors (links.payload_or_links): a hand, a tool and what it holds,
# its centre within this distance of the flange in each coordinate of the flange frame. A sweep of one joint feels
# the payload's first moment about that joint's axis only; a mass at the flange can make the sinusoid only at the
# phase the flange's place allows, which is what tells it from the other joints' errors
PAYLOAD_COM_BOX_M = 0.15
N_PAYLOAD = 10                    # inertial parameters of the payload (m, m c, inertia)
# a payload parameter whose 95 % interval is wider than this is reported as not identified: a centre of mass
# known to 5 cm says little about a wrist payload (a few centimetres from the flange), a mass known to half
# its value little more
COM_CI_MAX_WIDTH_M = 0.05
MASS_CI_MAX_SHARE = 0.5
# The bootstrap interval is statistical: it takes the declared rigid body as exact. The arm's own link parameters
# are known to a few per cent (datasheet against identification), which moves a payload's estimate more than the
# noise does; the intervals are therefore at least this wide on either side of the estimate.
MASS_SYSTEMATIC_SHARE = 0.02
COM_SYSTEMATIC_M = 0.005


def payload_fit(des: Design, joints: dict, jds: dict, rows_of=None) -> dict | None:
    """One payload for the whole arm, fitted over every joint that kept it (shared mass and first moment,
    each joint's other terms free, joints weighted by their residual); ``rows_of`` (``JointData -> (m,)
    bool``) restricts the samples. None when no joint kept a payload.

    Returns ``mass_kg``, ``com_m``, ``joints_fitted`` (1-based) and ``pi`` (10,) the inertial parameters."""
    system = payload_system(des, joints, jds, rows_of)
    if system is None:
        return None
    X, y, w, _, with_p = system
    theta = lstsq(X * w[:, None], y * w)
    n_own = X.shape[1] - N_PAYLOAD
    pi = theta[n_own:n_own + N_PAYLOAD]    # mass, first moment, inertia of the last link's addition
    return {**payload_from_pi(pi, robot_of(des)), "joints_fitted": [j + 1 for j in with_p], "pi": pi}


def payload_system(des: Design, joints: dict, jds: dict, rows_of=None):
    """The stacked least-squares problem of :func:`payload_fit`: ``(X, y, w, groups, joints)`` with ``groups``
    (m, 2) the (joint, time block) of each row; None when no joint kept a payload. The payload's ten columns are
    the last ones of ``X``."""
    with_p = [j for j, r in joints.items() if any(t["name"] == "payload" for t in r.kept)]
    if not with_p:
        return None
    blocks, ys, shared, wts, groups = [], [], [], [], []
    for j in with_p:
        res, jd = joints[j], jds[j]
        mask = np.ones(jd.n, bool) if rows_of is None else rows_of(jd)
        sub = np.flatnonzero(mask)
        sub = sub[:: max(1, len(sub) // 5000)]
        others = [t for t in res.kept if t["name"] != "payload"]
        y_o, X_o = target_and_design(des, jd, others, None)
        blocks.append(X_o[sub])
        shared.append(jd.extra["payload"][sub])
        ys.append(y_o[sub])
        wts.append(np.full(len(sub), 1.0 / max(res.torque_rms_after_Nm, 1e-9)))
        groups.append(np.column_stack([np.full(len(sub), j), jd.extra["block"][sub]]))
    return _shared_design(blocks, shared), np.concatenate(ys), np.concatenate(wts), np.vstack(groups), with_p


def payload_uncertainty(des: Design, joints: dict, jds: dict) -> tuple[dict, list[str]]:
    """95 % intervals of the arm's payload (``mass_kg``, ``com_x_m``, ``com_y_m``, ``com_z_m``; a bootstrap over the
    time blocks of each joint that fitted it) and the keys the motion cannot determine: the mass when its column
    is not in the row space of the regressor, or its interval reaches zero or is wider than ``MASS_CI_MAX_SHARE``
    of it; a centre-of-mass component when the mass or its first moment is not determined, or when its interval
    is wider than ``COM_CI_MAX_WIDTH_M``. What is not determined has no interval either (``[None, None]``)."""
    from wamctl.analysis.diagnosis.uncertainty import estimable, group_bootstrap

    system = payload_system(des, joints, jds)
    if system is None:
        return {}, []
    X, y, w, groups, _ = system
    n_own = X.shape[1] - N_PAYLOAD
    ok = estimable(X * w[:, None], [n_own + k for k in range(4)])
    reps = group_bootstrap(X, y, groups, rng=np.random.default_rng(4000), w=w)
    pis = reps[:, n_own:n_own + N_PAYLOAD]
    ests = [payload_from_pi(pi, robot_of(des)) for pi in pis]
    est = payload_from_pi(lstsq(X * w[:, None], y * w)[n_own:n_own + N_PAYLOAD], robot_of(des))
    return payload_intervals(est, ests, len({tuple(g) for g in groups}), ok)


def payload_intervals(est: dict, ests: list[dict], n_groups: int, ok) -> tuple[dict, list[str]]:
    """The payload's 95 % intervals from bootstrap replicates ``ests`` of the estimate ``est`` (percentile, over
    ``n_groups`` resampled blocks, widened by the declared links' systematic share) and the keys not determined
    (``ok``: mass, then first-moment columns estimable; the rules of :func:`payload_uncertainty`), whose interval
    is ``[None, None]``."""
    from wamctl.analysis.diagnosis.uncertainty import percentile_ci

    ci = {"mass_kg": _at_least(percentile_ci([e["mass_kg"] for e in ests], center=est["mass_kg"], n_groups=n_groups),
                               est["mass_kg"], MASS_SYSTEMATIC_SHARE * abs(est["mass_kg"]))}
    for i, ax in enumerate("xyz"):
        ci[f"com_{ax}_m"] = _at_least(percentile_ci([e["com_m"][i] if e["mass_kg"] > 0 else None for e in ests],
                                                    center=est["com_m"][i], n_groups=n_groups),
                                      est["com_m"][i], COM_SYSTEMATIC_M)
    m_lo, m_hi = ci["mass_kg"]
    mass_ok = bool(ok[0] and m_lo is not None and m_lo > 0 and m_hi - m_lo <= MASS_CI_MAX_SHARE * est["mass_kg"])
    ni = [] if mass_ok else ["mass_kg"]
    for i, ax in enumerate("xyz"):
        lo, hi = ci[f"com_{ax}_m"]
        wide = lo is None or hi - lo > COM_CI_MAX_WIDTH_M
        if not (mass_ok and ok[1 + i]) or wide:
            ni.append(f"com_{ax}_m")
    for k in ni:                  # what the data cannot determine has no interval either
        ci[k] = [None, None]
    return ci, ni


def _shared_design(blocks: list[np.ndarray], shared: list[np.ndarray]) -> np.ndarray:
    """Design of joints fitted together: each joint's own columns ``blocks[i]`` (m_i, p_i) block-diagonal,
    the shared columns ``shared[i]`` (m_i, s) stacked in the last ``s`` columns: (sum m_i, sum p_i + s)."""
    n_own = sum(b.shape[1] for b in blocks)
    X = np.zeros((sum(len(b) for b in blocks), n_own + shared[0].shape[1]))
    r0, c0 = 0, 0
    for b, z in zip(blocks, shared):
        X[r0:r0 + len(b), c0:c0 + b.shape[1]] = b
        X[r0:r0 + len(b), n_own:] = z
        r0 += len(b)
        c0 += b.shape[1]
    return X


def payload_rejection(fit: dict, not_identified: list[str] = ()) -> str | None:
    """Why a payload fitted over the arm (:func:`payload_fit`) is not a wrist payload, or None. Only what the
    data determine is judged: with the mass ``not_identified`` (a sweep of one joint), that a wrist payload
    explains the data was shown against the link errors (:func:`~wamctl.analysis.diagnosis.links.
    payload_or_links`)."""
    if "mass_kg" in not_identified:
        return None
    com = [c for c, ax in zip(fit["com_m"], "xyz") if f"com_{ax}_m" not in not_identified]
    far = float(np.linalg.norm(com))
    if not (PAYLOAD_MASS_RANGE_KG[0] <= fit["mass_kg"] <= PAYLOAD_MASS_RANGE_KG[1]) or far > PAYLOAD_MAX_COM_M:
        return (f"the payload fitted over joints {fit['joints_fitted']} is {fit['mass_kg']:.3g} kg at "
                f"{far:.3g} m from the flange: not a wrist payload (mass {PAYLOAD_MASS_RANGE_KG[0]} to "
                f"{PAYLOAD_MASS_RANGE_KG[1]} kg within {PAYLOAD_MAX_COM_M} m)")
    return None


def payload_links_reason(dec: dict | None) -> str | None:
    """Why the payload candidate is not named, from the payload-or-links decision (None: it stands)."""
    from wamctl.analysis.diagnosis.links import WIDE_PRIOR
    from wamctl.analysis.diagnosis.rigid import LINK_PRIOR_COM_M, LINK_PRIOR_SHARE

    if dec is None or dec["outcome"] == "payload":
        return None
    t1 = dec["tests"]["beyond_links"]
    acc = (f"+-{LINK_PRIOR_SHARE:.0%} of each link's mass, inertia and armature, +-({LINK_PRIOR_SHARE:.0%} of its "
           f"distance + {1e3 * LINK_PRIOR_COM_M:g} mm) in each coordinate of its centre of mass")
    if dec["outcome"] == "link_parameters":
        return (f"link errors within the declared accuracy ({acc}) explain the held-out torques as well: a wrist "
                f"payload does not add to them (p = {t1['p_value']:.3g})")
    t2 = dec["tests"]["beyond_wide_links"]
    return (f"ambiguous: a wrist payload adds to link errors within the declared accuracy ({acc}; p = "
            f"{t1['p_value']:.3g}), by {_most_excess(dec)}, and not to link errors within {WIDE_PRIOR:g} times it "
            f"(p = {t2['p_value']:.3g}): the data cannot tell a payload from a datasheet worse than declared")


def _most_excess(dec: dict) -> str:
    """The payload's largest excess over the declared accuracy's link errors, said with the line that decides."""
    from wamctl.analysis.diagnosis.stats import DECIDED_FLOORS

    ex = dec.get("excess_noise_floors") or {}
    if not ex:
        return "nothing measurable"
    j = max(ex, key=ex.get)
    return f"at most {ex[j]:.2g} noise floors (joint {j + 1}; {DECIDED_FLOORS:g} decides)"


def payload_grey_zone(dec: dict | None) -> str | None:
    """The caveat of a payload named beyond the declared accuracy's link errors but not beyond ``WIDE_PRIOR`` times
    them (None otherwise): what a datasheet worse than declared would mean."""
    from wamctl.analysis.diagnosis.links import WIDE_PRIOR

    if dec is None or dec["outcome"] != "payload" or dec["passes"].get("beyond_wide_links"):
        return None
    t2 = dec["tests"]["beyond_wide_links"]
    return (f"payload named on the declared link accuracy: it leaves {_most_excess(dec)} that no link error "
            f"within that accuracy reproduces, but link errors up to {WIDE_PRIOR:g} times it would explain the data "
            f"too (p = {t2['p_value']:.3g}); if the datasheet may be worse than declared, the next experiment tells "
            "them apart")


def payload_links_summary(dec: dict | None) -> dict | None:
    """The payload-or-links decision as ``diagnosis.json`` reports it: the outcome, both tests, the held-out
    SSR of each model against the joints' own models, and the assumptions (the declared accuracy)."""
    from wamctl.analysis.diagnosis.links import WIDE_PRIOR
    from wamctl.analysis.diagnosis.rigid import LINK_PRIOR_COM_M, LINK_PRIOR_SHARE

    if dec is None:
        return None
    keys = ("p_value", "delta_bic", "ssr_ratio")
    return {"outcome": dec["outcome"], "joints": [j + 1 for j in dec["joints"]],
            "tests": {k: {x: float(t[x]) for x in keys} for k, t in dec["tests"].items()},
            "excess_noise_floors": {str(j + 1): float(v) for j, v in dec["excess_noise_floors"].items()},
            "grey_zone": payload_grey_zone(dec),
            "ssr_ratio": {k: float(v) for k, v in dec["ssr_ratio"].items()},
            "payload_combinations_seen": int(dec["payload_seen"]),
            "assumptions": {"link_accuracy_share": LINK_PRIOR_SHARE, "link_com_allowance_m": LINK_PRIOR_COM_M,
                            "wide_factor": WIDE_PRIOR, "payload_com_box_m": PAYLOAD_COM_BOX_M}}


def held_out_with_fixed(des: Design, jd, kept: list, fixed) -> np.ndarray:
    """(n,) held-out torque residual of a joint's model ``kept`` with a torque held fixed: for each fold, the
    joint's other coefficients refitted without the fold on the torque less ``fixed(fold)`` ((n,) N m, e.g. a
    payload's), and the fold scored; NaN where a fold has no samples or too few are left to fit."""
    e = np.full(jd.n, np.nan)
    for f in range(des.n_folds):
        te = jd.fold == f
        tr = ~te
        if not te.any() or tr.sum() < 20:
            continue
        y, X = target_and_design(des, jd, kept, f)
        y = y - fixed(f)
        e[te] = y[te] - X[te] @ lstsq(X[tr], y[tr])
    return e


def payload_inconsistency(des: Design, joints: dict, jds: dict, fit: dict, factor: float = 2.0) -> str | None:
    """Why the payload fitted at some joints is not one for the arm, or None: a payload changes the torque of
    every joint it hangs from, so at each diagnosed joint that did not keep it and where its torque would be
    larger than that joint's held-out residual, adding it (fixed, as fitted) must not make that residual more
    than ``factor`` times larger in power (a payload found through one joint's inertial coupling, say, would
    load the others' gravity torques with what they do not show)."""
    for j, res in joints.items():
        jd = jds[j]
        if j + 1 in fit["joints_fitted"] or "payload" not in jd.extra:
            continue
        pt = jd.extra["payload"] @ fit["pi"]
        e_after = res.e_after
        ss0 = finite_ss(e_after)
        if ss0 <= 0 or np.sum(pt ** 2) < ss0:
            continue
        e_with = held_out_with_fixed(des, jd, res.kept, lambda f, pt=pt: pt)
        e_with[~np.isfinite(e_after)] = np.nan
        if finite_ss(e_with) > factor * ss0:
            return (f"the payload fitted at joints {fit['joints_fitted']} ({fit['mass_kg']:.3g} kg) would make the "
                    f"held-out torque residual of joint {j + 1}, which shows no payload, "
                    f"{np.sqrt(finite_ss(e_with) / ss0):.2g} times larger: not a payload of the arm")
    return None


def _at_least(ci: list, center: float, half: float) -> list:
    """``ci`` widened to at least ``center +- half``."""
    lo, hi = ci
    if lo is None or hi is None:
        return ci
    return [min(lo, center - half), max(hi, center + half)]


def fold_payloads(des: Design, joints: dict, jds: dict, fit: dict) -> dict:
    """{fold: (10,) the arm's payload fitted without that fold, None: ``fit``'s on all data}."""
    pis = {None: fit["pi"]}
    for f in range(des.n_folds):
        ff = payload_fit(des, joints, jds, lambda jd, f=f: jd.fold != f)
        pis[f] = ff["pi"] if ff is not None else fit["pi"]
    return pis


def global_payload_terms(kept: list[dict], n_folds: int) -> list[dict]:
    """The joint's kept terms with its payload replaced by the arm's one (one column, fitted per fold)."""
    terms = []
    for t in kept:
        if t["name"] == "payload":
            t = dict(t, h_fold=[("global", f) for f in range(n_folds)], h_all=("global", None),
                     fixed_h=("global", None))
        terms.append(t)
    return terms


def delay_disagreements(joints: dict, dt_s: float, des: Design | None = None, jds: dict | None = None) -> dict:
    """{0-based joint: why} of the joints whose kept delay is not the arm's.

    A late measurement delays every joint's positions by the same time. A delay stands where the joints that
    show it agree (within ``max(min(dt_s, 2 ms), 25 %)`` of their median; position noise fed back by the
    controller can mimic a lag, but not the same one at several joints): at least half of the diagnosed
    ``joints``, or at least two (the only one when a single joint is diagnosed) when none of the others
    contradicts it: the arm's delay put into a joint that did not keep one must not make its held-out residual
    worse by more than the minimum effect (a joint whose motion is too slow or too quiet to show a few
    milliseconds of lag does not contradict it; one that moves and tracks without lag does)."""
    with_d = {j: next(t["h_all"] for t in r.kept if t["name"] == "delay")
              for j, r in joints.items() if any(t["name"] == "delay" for t in r.kept)}
    if not with_d:
        return {}
    med = float(np.median(list(with_d.values())))
    agree = {j for j, d in with_d.items() if abs(d - med) <= max(min(dt_s, 2e-3), 0.25 * med)}
    half = int(np.ceil(len(joints) / 2))
    against = [] if des is None else _contradicting(des, joints, jds, set(with_d), med)
    if len(agree) >= half or (len(agree) >= min(2, len(joints)) and not against):
        return {j: (f"delay {with_d[j] * 1e3:.1f} ms disagrees with the {med * 1e3:.1f} ms of the other "
                    "joints (a late measurement is one delay for the arm)") for j in with_d if j not in agree}
    seen = ", ".join(f"{j + 1} ({d * 1e3:.1f} ms)" for j, d in sorted(with_d.items()))
    why = (f"delays kept at joint{'s' if len(with_d) > 1 else ''} {seen}: {len(agree)} of the {len(joints)} "
           f"joints diagnosed agree on one delay")
    if against:
        why += f", and joints {[j + 1 for j in against]} move without it"
    why += (f"; a late measurement delays every joint alike (at least {half} joints, or two that no other joint "
            "contradicts, needed)")
    return dict.fromkeys(with_d, why)


def _contradicting(des: Design, joints: dict, jds: dict, with_d: set, d: float) -> list[int]:
    """The joints without a kept delay whose held-out residual the delay ``d`` makes worse by more than the
    minimum effect."""
    from wamctl.analysis.diagnosis.crossval import cv_terms
    from wamctl.analysis.diagnosis.stats import MIN_EFFECT

    out = []
    for j, res in joints.items():
        if j in with_d:
            continue
        terms = list(res.kept) + [{"name": "delay", "h_fold": [d] * des.n_folds, "h_all": d, "fixed_h": d}]
        e_d = cv_terms(des, jds[j], terms)
        ok = np.isfinite(e_d) & np.isfinite(res.e_after)
        if finite_ss(e_d[ok]) > (1 + MIN_EFFECT) * finite_ss(res.e_after[ok]):
            out.append(j)
    return out
