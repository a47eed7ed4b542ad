"""Head-to-head before naming: when several candidates pass at a joint, each against the others on held-out data
(no I/O).

Two candidates ``a`` and ``b`` that both explain the residual may explain the same part of it (a measurement delay
and a Stribeck hump both add torque where the joint turns; a payload and a link's wrong mass both change the
gravity torques). The model with both is fitted without each fold, and two nested tests are made on its held-out
residual, at the run's threshold and minimum effect:

* does ``a`` add to the model with ``b`` (``a | b``)? does ``b`` add to the model with ``a`` (``b | a``)?

=========  =========  =============================================================
``a | b``  ``b | a``  outcome
=========  =========  =============================================================
yes        no         ``a`` wins clearly (``b`` only explained part of ``a``'s residual)
no         yes        ``b`` wins clearly
yes        yes        both are there: ``a`` now, ``b`` at a later step
no         no         neither wins: **ambiguous** ``[a, b]``, neither is named
=========  =========  =============================================================

A wrong name is worse than "inconclusive": an ambiguous group is reported with its evidence and left out of the
model the diagnosis writes (the selection goes on with the group in the model, so that a further effect is still
seen beyond it).
"""

from __future__ import annotations

import numpy as np

from wamctl.analysis.diagnosis.crossval import cv_residual
from wamctl.analysis.diagnosis.design import N_FRICTION, Design, JointData, ncols
from wamctl.analysis.diagnosis.stats import MIN_EFFECT, finite_ss, nested_test

HAS_GRID = {"stribeck": True, "position_ripple": True, "payload": False, "delay": True,
            "friction_drift": True, "backlash": False, "link_parameters": False}


def p_extra(name: str, term: dict | None = None) -> int:
    """Parameters a candidate adds: its columns plus one per shape parameter chosen on a grid (a ripple's columns,
    2 per harmonic, are counted from its ``term``)."""
    from wamctl.analysis.diagnosis.design import N_COLUMNS

    n = ncols(term) if name == "position_ripple" and term is not None else N_COLUMNS[name]
    return n + (1 if HAS_GRID.get(name) else 0)


def passes(t: dict, threshold: float) -> bool:
    return t["p_value"] < threshold and t["delta_bic"] < 0


def beyond_tests(des: Design, jd: JointData, terms: list[dict], a: dict, b: dict, e_base: np.ndarray,
                 onset_recheck=None) -> tuple[dict, dict]:
    """(``a | b``, ``b | a``): does candidate entry ``a`` add to ``friction + terms + b``, and ``b`` to ``+ a``.

    Entries are ``{"name", "term", "e"}`` (``term``: the term dict, ``e``: the held-out residual of ``terms`` plus
    it). ``onset_recheck(name, other_term) -> test or None``: for a candidate seen at the breakaways (where the
    sliding residual cannot show it), its onset test redone under the model with the other candidate."""
    fixed = a["term"].get("fixed_h")
    e_ab, _ = cv_residual(des, jd, terms + [b["term"]], a["name"], fixed)
    k1 = N_FRICTION + sum(ncols(t) for t in terms) + ncols(a["term"]) + ncols(b["term"])
    out = []
    for x, y in ((a, b), (b, a)):
        share = finite_ss(e_base) / max(finite_ss(y["e"]), 1e-300)
        t = nested_test(y["e"], e_ab, p_extra(x["name"], x["term"]), k1, min(MIN_EFFECT * share, 0.9), jd.fold)
        if x["term"].get("onset_test") and onset_recheck is not None:
            t2 = onset_recheck(x["name"], y["term"])
            if t2 is not None:
                t = dict(t2, seen="at the breakaways")
        out.append(t)
    return out[0], out[1]


def tournament(des: Design, jd: JointData, terms: list[dict], entries: list[dict], e_base: np.ndarray,
               threshold: float, onset_recheck=None) -> tuple[dict | None, list[dict], dict]:
    """The candidate to keep among ``entries`` (all passing, strongest first), or an ambiguous group.

    Returns ``(winner entry or None, ambiguous group of entries ([] when there is a winner), {name: [records]})``:
    each record is ``{"vs", "p_this_beyond", "p_other_beyond", "outcome"}``."""
    records: dict[str, list] = {e["name"]: [] for e in entries}
    champion = entries[0]
    group: list[dict] = []
    beaten: set[str] = set()
    queue = list(entries[1:])
    while queue:
        challenger = queue.pop(0)
        if challenger["name"] in beaten:
            continue
        t_cb, t_bc = beyond_tests(des, jd, terms, champion, challenger, e_base, onset_recheck)
        c_adds, b_adds = passes(t_cb, threshold), passes(t_bc, threshold)
        outcome = {(True, False): "wins", (False, True): "loses", (True, True): "both",
                   (False, False): "ambiguous"}[(c_adds, b_adds)]
        records[champion["name"]].append({"vs": challenger["name"], "p_this_beyond": t_cb["p_value"],
                                          "p_other_beyond": t_bc["p_value"], "outcome": outcome})
        flip = {"wins": "loses", "loses": "wins"}.get(outcome, outcome)
        records[challenger["name"]].append({"vs": champion["name"], "p_this_beyond": t_bc["p_value"],
                                            "p_other_beyond": t_cb["p_value"], "outcome": flip})
        if outcome == "wins":
            beaten.add(challenger["name"])
        elif outcome == "loses":
            beaten.add(champion["name"])
            champion = challenger
            queue = group + queue          # the ambiguous ones meet the new champion
            group = []
        elif outcome == "ambiguous":
            group.append(challenger)
    if group:
        return None, [champion] + group, records
    return champion, [], records
