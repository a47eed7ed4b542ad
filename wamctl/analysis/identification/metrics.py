"""Figures of merit of an identification (issue 29 item 4), read off a fitted
:class:`~wamctl.analysis.identification.estimator.InertialIdentification`:

* :func:`relative_errors` -- ``||tau - tau_hat|| / ||tau||`` per trajectory (all joints' samples stacked), held out
  and in sample, of the identified and the nominal model, with a 95 % moving-block bootstrap interval (blocks of
  the Newey-West lag length: the filtered residuals are correlated in time). The published real-WAM figure is
  6.7-8.5 % held out (:data:`PUBLISHED_HELD_OUT_PCT`).
* :func:`prior_moves` -- per base parameter, how far the data moved it from the declared arm, in the prior's
  standard deviations (the prior of the consistent estimate: :func:`.estimator.prior_scale`, weight
  ``PRIOR_WEIGHT``; the table's ``moved_se`` is the same move in posterior standard errors).
* :func:`physical_checks` -- Sousa and Cortesao's physical-plausibility conditions beyond positive definite
  pseudo-inertias ("Physical feasibility of robot base inertial parameter identification: a tutorial", IJRR 2014):
  each link's centre of mass inside a box around the link, and the arm's total mass near the declared one.
  **Checks, not constraints**: the consistent estimate (a semidefinite program in :mod:`.estimator`) enforces
  the pseudo-inertia LMIs only; a centre-of-mass box is linear in (m, m c) and could be added there, but that
  estimator is not this module's, and individual link masses and COMs are mostly not identified on their own
  (the declared arm splits the base combinations), so a check says when the split lands somewhere implausible.

The box of link ``i`` (DH frame ``i``): the bounding box of the link's DH skeleton, the origins of frames ``i-1``
and ``i`` and the point ``d_{i+1}`` along ``z_i`` (the body reaches to the next joint), padded on every side by
the link's capsule radius of :mod:`wamctl.model.collision` plus how far the datasheet's own COM lies outside the
skeleton's box (so the datasheet arm passes with the capsule radius to spare). It is a model of the outline, not
the housing. On an arm whose last link ends at a tool plate (the wam4's forearm: libbarrett's toolplate, 0.36 m
along z4) the skeleton reaches the plate. Total mass: within ``mass_tolerance`` (10 % by default, a chosen
figure: the datasheet gives no tolerance) of the declared arm's.
"""

from __future__ import annotations

import numpy as np

from wamctl.model import params as P
from wamctl.model.collision import RADIUS_M
from wamctl.model.robots import get_robot

PUBLISHED_HELD_OUT_PCT = (6.7, 8.5)      # real WAM, held-out relative torque error (issue 29)
LINK_CAPSULE = ("shoulder", "shoulder", "upper arm", "forearm", "wrist and hand", "wrist and hand",
                "wrist and hand")
N_BOOT = 400


def _rel(y: np.ndarray, p: np.ndarray) -> float:
    den = float(np.sqrt(np.sum(y ** 2)))
    return float(np.sqrt(np.sum((y - p) ** 2)) / den) if den > 0 else float("nan")


def _block_interval(y: np.ndarray, p: np.ndarray, k: np.ndarray, block: int, seed: int) -> list:
    """95 % moving-block bootstrap interval of ``||y - p|| / ||y||`` over the samples ``k`` (blocks of
    ``block`` consecutive samples, every joint of a sample kept together)."""
    samples = np.unique(k)
    n = len(samples)
    if n < 4:
        return [None, None]
    block = int(min(max(block, 1), n))
    idx = np.searchsorted(samples, k)
    e2 = np.bincount(idx, (y - p) ** 2, minlength=n)
    y2 = np.bincount(idx, y ** 2, minlength=n)
    ce, cy = np.concatenate([[0.0], np.cumsum(e2)]), np.concatenate([[0.0], np.cumsum(y2)])
    rng = np.random.default_rng(seed)
    n_blocks = int(np.ceil(n / block))
    starts = rng.integers(0, n - block + 1, (N_BOOT, n_blocks))
    se = (ce[starts + block] - ce[starts]).sum(axis=1)
    sy = (cy[starts + block] - cy[starts]).sum(axis=1)
    ok = sy > 0
    if ok.sum() < N_BOOT // 2:
        return [None, None]
    r = np.sqrt(se[ok] / sy[ok])
    return [float(np.quantile(r, 0.025)), float(np.quantile(r, 0.975))]


def relative_errors(est, held_rows: list, held_masks: list) -> dict:
    """``{"held_out": [...], "in_sample": [...], "published_held_out_pct": [6.7, 8.5], "note": ...}``: one entry
    per trajectory with ``source``, ``samples`` and, for ``identified`` and ``nominal``, the relative error and its
    95 % interval (``_ci95``)."""
    from wamctl.analysis.identification.estimator import hac_lags

    def entries(rows, masks, seed0):
        out = []
        for i, rr in enumerate(rows):
            m = masks[i] if masks is not None else None
            entry = {"source": rr.source}
            for which in ("identified", "nominal"):
                p, y, _, k = est.predict(rr, which, m)
                entry["samples"] = int(len(np.unique(k)))
                if len(y) == 0:
                    entry[which] = entry[which + "_ci95"] = None
                    continue
                block = hac_lags(int(len(np.unique(k))), rr.reach_s / rr.dt_s) + 1
                entry[which] = _rel(y, p)
                entry[which + "_ci95"] = _block_interval(y, p, k, block, seed0 + i)
            out.append(entry)
        return out

    return {"held_out": entries(held_rows, held_masks, 1000), "in_sample": entries(est.rows_, None, 2000),
            "published_held_out_pct": list(PUBLISHED_HELD_OUT_PCT),
            "note": ("||tau - tau_hat|| / ||tau|| over all joints' filtered samples of one trajectory; 95 % interval "
                     "by a moving-block bootstrap (blocks of the Newey-West lag). In sample: the rows fitted. The "
                     "published real-WAM figure, 6.7-8.5 % held out, is for the real arm's noise and friction; a "
                     "simulated arm's figure depends on its noise settings.")}


def prior_sd(est) -> np.ndarray:
    """(nb,) the declared prior's standard deviation of each base parameter (the declared arm's accuracy, before
    the data widen it, :attr:`.estimator.InertialIdentification.prior_widths_`: a move is measured in the
    datasheet's own accuracy; precision ``PRIOR_WEIGHT`` along the standard directions that move a base
    parameter)."""
    from wamctl.analysis.identification.estimator import PRIOR_WEIGHT, prior_scale

    K = est.base_.matrix
    s = prior_scale(est.pi_declared_)
    # prior precision in delta = (pi - pi0) / s units: PRIOR_WEIGHT on the row space of K diag(s), 1 elsewhere;
    # the base parameters see the row space only, so their prior covariance is K diag(s) (K diag(s))^T / w
    Ks = K * s
    return np.sqrt(np.diag(Ks @ Ks.T) / PRIOR_WEIGHT)


def prior_moves(est) -> list[dict]:
    """Per base parameter: ``{parameter, declared, estimate, prior_sd, moved_prior_sd}`` (``None`` where the
    data do not determine it: it stays at the declared value)."""
    beta_decl = est.base_.of(est.pi_declared_)
    sd = prior_sd(est)
    out = []
    for k, name in enumerate(est.base_.names):
        ident = bool(est.identified_[k])
        moved = (est.beta_[k] - beta_decl[k]) / sd[k] if ident and sd[k] > 0 else None
        out.append({"parameter": name, "declared": float(beta_decl[k]),
                    "estimate": float(est.beta_[k]) if ident else None, "prior_sd": float(sd[k]),
                    "moved_prior_sd": None if moved is None else float(moved)})
    return out


def _skeleton_box(i: int, robot=None) -> tuple[np.ndarray, np.ndarray]:
    """(low (3,), high (3,)) of link ``i``'s (0-based) DH skeleton in DH frame ``i`` (``robot``: default the
    wam7)."""
    r = get_robot(robot)
    ca, sa = np.cos(r.dh_alpha_rad[i]), np.sin(r.dh_alpha_rad[i])
    rot = np.array([[1.0, 0.0, 0.0], [0.0, ca, -sa], [0.0, sa, ca]])
    prev = -rot.T @ np.array([r.dh_a_m[i], 0.0, r.dh_d_m[i]])          # frame i-1's origin in frame i
    nxt = np.array([0.0, 0.0, r.dh_d_m[i + 1] if i + 1 < r.n_joints else r.flange_d_m])
    pts = np.vstack([np.zeros(3), prev, nxt])
    return pts.min(axis=0), pts.max(axis=0)


def _outside_m(c: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> float:
    return float(np.linalg.norm(np.maximum(lo - c, 0) + np.maximum(c - hi, 0)))


def com_boxes(robot=None) -> list[tuple[np.ndarray, np.ndarray]]:
    """Per link, (low, high) of its COM box in DH frame i (see the module doc; ``robot`` default the wam7)."""
    r = get_robot(robot)
    ds = P.LinkParameters.datasheet(r.name)
    out = []
    for i in range(r.n_joints):
        lo, hi = _skeleton_box(i, r)
        pad = RADIUS_M[LINK_CAPSULE[i]] + _outside_m(ds.com_m[i], lo, hi)
        out.append((lo - pad, hi + pad))
    return out


def physical_checks(links: P.LinkParameters, declared: P.LinkParameters | None = None,
                    mass_tolerance: float = 0.10, payload=None) -> dict:
    """The COM-in-box and total-mass checks of ``links`` (see the module doc): ``{"com_in_box": [{link, com_m,
    box_low_m, box_high_m, outside_m, ok}], "total_mass": {identified_kg, declared_kg, relative, tolerance, ok},
    "ok", "enforced": False, "note"}``. With a ``payload`` (a :class:`~wamctl.model.dynamics.Payload`, part of
    link 7 in the identification) link 7's COM is not checked (``ok`` None: the box is the link's, not the
    payload's) and the declared total includes the payload's mass."""
    declared = declared if declared is not None else P.LinkParameters.datasheet(links.robot)
    payload_kg = float(payload.mass_kg) if payload is not None else 0.0
    rows = []
    boxes = com_boxes(links.robot)
    for i, (lo, hi) in enumerate(boxes):
        c = links.com_m[i]
        out = _outside_m(c, lo, hi)
        skip = i == len(boxes) - 1 and payload_kg > 0
        rows.append({"link": i + 1, "com_m": [float(x) for x in c], "box_low_m": [float(x) for x in lo],
                     "box_high_m": [float(x) for x in hi], "outside_m": out,
                     "ok": None if skip else bool(out <= 1e-12)})
    m, m0 = float(links.mass_kg.sum()), float(declared.mass_kg.sum()) + payload_kg
    rel = (m - m0) / m0
    total = {"identified_kg": m, "declared_kg": m0, "relative": rel, "tolerance": mass_tolerance,
             "ok": bool(abs(rel) <= mass_tolerance)}
    return {"com_in_box": rows, "total_mass": total,
            "ok": bool(total["ok"] and all(r["ok"] is not False for r in rows)),
            "enforced": False,
            "note": ("checks of the physically consistent estimate, not constraints of it (it enforces positive "
                     "semidefinite pseudo-inertias only); link masses and COMs are mostly split by the declared "
                     "arm, not identified on their own. COM box: the link's DH skeleton padded by its capsule "
                     "radius (model/collision.py) and the datasheet COM's overshoot; total mass within "
                     f"{100 * mass_tolerance:.0f} % of the declared arm's (a chosen tolerance).")}
