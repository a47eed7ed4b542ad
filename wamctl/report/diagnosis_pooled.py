"""Report of a pooled diagnosis (``wamctl diagnose RUN1 RUN2 ...``): the runs, what each decided alone, every
decision made on the runs pooled with its statistic per run, which run decided what, the arm's payload, and each
run's friction. Everything comes from diagnosis.json (``pooled: true``)."""

from __future__ import annotations

import pandas as pd

from wamctl.report.document import Document


def _p(x) -> str:
    return "n/a" if x is None else f"{x:.2g}"


def _ci(v, lo_hi, scale: float = 1.0, fmt: str = "{:.4g}") -> str:
    if v is None:
        return "not identified"
    lo, hi = lo_hi or [None, None]
    s = fmt.format(v * scale)
    return s + ("" if lo is None else f" [{fmt.format(lo * scale)}, {fmt.format(hi * scale)}]")


def runs_table(result: dict) -> pd.DataFrame:
    """One row per run: its joints and what it decided alone (the terminal's table)."""
    rows = []
    for r in result.get("runs") or []:
        a = r["alone"]
        rows.append({"run": r["label"], "joints": ", ".join(map(str, r["joints_diagnosed"])) or "-",
                     "alone: effects found": ", ".join(a["effects_found"]) or ("none" if a["conclusive"] else
                                                                             "nothing concluded"),
                     "alone: ambiguous": "; ".join(" / ".join(g) for g in a["ambiguous"]) or "-",
                     "alone: payload or links": a["payload_or_links"] or "-"})
    return pd.DataFrame(rows)


def run_states_table(result: dict) -> pd.DataFrame:
    """One row per run: samples, start state, controller gains (each run's own)."""
    rows = []
    for r in result.get("runs") or []:
        c = r["controller"]
        rows.append({"run": r["label"], "samples": r["samples"],
                     "q0_rad": ", ".join("-" if v is None else f"{v:.3g}" for v in r["q0_rad"]),
                     "controller": c["kind"], "gains": c["source"]})
    return pd.DataFrame(rows)


def findings_table(result: dict) -> pd.DataFrame:
    """One row per decision and stack (pooled, each run alone, without each run): outcome, p-value, BIC change."""
    rows = []
    for f in result.get("findings") or []:
        for stack, st in [("pooled", f["pooled"])] + list(f["per_stack"].items()):
            rows.append({"finding": f["name"] + ("" if f["joint"] is None else f" (joint {f['joint']})"),
                         "stack": stack, "outcome": st.get("outcome") or ("named" if st["named"] else "not named"),
                         "p_value": _p(st["p_value"]), "delta_bic": st["delta_bic"],
                         "held_out_ssr_ratio": st["ssr_ratio"],
                         "not_identified": ", ".join(st.get("not_identified") or []) or "-"})
    return pd.DataFrame(rows)


def decided_lines(result: dict) -> list[str]:
    """Which run decided each finding and which added nothing, one line each (also on the terminal)."""
    lines = []
    for f in result.get("findings") or []:
        if f.get("delay_or_inertia"):
            lines += delay_lines(f["delay_or_inertia"])
            continue
        what = f["name"] + ("" if f["joint"] is None else f" at joint {f['joint']}")
        pooled = f["pooled"]
        verdict = pooled.get("outcome") if f["joint"] is None else ("named" if pooled["named"] else "not named")
        alone = [r["label"] for r in result.get("runs") or []
                 if (f["per_stack"].get(f"{r['label']} alone") or {}).get("named")]
        line = (f"{what}: pooled {verdict} (p {_p(pooled['p_value'])}); named alone by "
                f"{', '.join(alone) or 'no run'}; decided by {', '.join(f['decided_by']) or 'no single run'}")
        if f["added_nothing"]:
            line += f"; added nothing: {', '.join(f['added_nothing'])}"
        lines.append(line)
    return lines


def _g(x: float) -> str:
    return f"{x:.3g}"


def delay_lines(dec: dict) -> list[str]:
    """A delay against inertia errors decided on the runs pooled (``findings[].delay_or_inertia``), in two lines:
    the decision, which run decided it and the estimate with its 95 % interval; the held-out torque RMS of each
    run before (friction only) and after (with the winner), and with the loser instead."""
    win, out = dec["winner"], dec["outcome"]
    lose = "inertia" if win == "delay" else "delay"
    lose_words = {"inertia": "inertia errors", "delay": "a delay"}[lose]
    excess = f"what {lose_words} leave{'s' if lose == 'delay' else ''} beyond the {win}, noise floors RMS"
    runs = "; ".join(f"{p['label']} {p['excess_noise_floors']:.2g} (alone: {p['alone']['outcome']}"
                     + ("" if p["alone"]["outcome"] == "ambiguous" else
                        f", {p['alone']['excess_noise_floors']:.2g}") + ")" for p in dec["per_run"])
    if win == "delay":
        lo, hi = dec["delay_ci_s"]
        est = (f"delay {dec['delay_s'] * 1e3:.1f} ms" + ("" if lo is None else
                                                          f" [{lo * 1e3:.1f}, {hi * 1e3:.1f}] ms (95 %)"))
    else:
        est = "inertia errors " + ", ".join(
            f"joint {j} {v:+.2g}" + ("" if dec["inertia_error_ci_kg_m2"][j][0] is None else
                                    " [{:.2g}, {:.2g}]".format(*dec["inertia_error_ci_kg_m2"][j]))
            for j, v in dec["inertia_error_kg_m2"].items()) + " kg m^2 (95 %)"
    if out == "ambiguous":
        contra = dec["contradicted_by"]
        head = (f"delay or inertia (runs pooled): ambiguous ({excess}, "
                + (f"per run: {runs}; the runs disagree: {', '.join(contra)} prefer{'s' if len(contra) == 1 else ''}"
                   f" the {lose}" if contra else f"below 1 in every run: {runs}") + ")")
    else:
        head = (f"delay or inertia (runs pooled): {out}, decided by {', '.join(dec['decided_by'])} ({excess}, per "
                f"run: {runs}); {est}")
    held = ", ".join(f"{p['label']} {_g(p['held_out_rms_Nm']['neither'])} -> {_g(p['held_out_rms_Nm'][win])} N m "
                     f"(joint{'s' if len(p['joints']) > 1 else ''} {', '.join(map(str, p['joints']))}; "
                     f"{lose_words} instead {_g(p['held_out_rms_Nm'][lose])})" for p in dec["per_run"])
    return [head, f"held-out torque RMS, friction only -> with the {win}: {held}"]


def delay_table(result: dict) -> pd.DataFrame:
    """Per run and joint: the held-out torque RMS with friction only, with a delay, with inertia errors; the run's
    excess of the loser over the winner (pooled fits) and what the run decided alone."""
    rows = []
    for f in result.get("findings") or []:
        dec = f.get("delay_or_inertia")
        if not dec:
            continue
        for p in dec["per_run"]:
            for j, h in p["held_out_rms_per_joint_Nm"].items():
                rows.append({"run": p["label"], "joint": int(j), "friction_only_Nm": h["neither"],
                             "with_delay_Nm": h["delay"], "with_inertia_errors_Nm": h["inertia"],
                             "run_excess_noise_floors": p["excess_noise_floors"],
                             "alone": p["alone"]["outcome"]})
    return pd.DataFrame(rows)


def payload_table(result: dict) -> pd.DataFrame:
    """The arm's payload per stack: estimate and 95 % interval, or not identified."""
    rows = []
    for stack, st in (result.get("payload_or_links") or {}).items():
        p = st.get("payload")
        if not p:
            continue
        pr, ci = p["params"], p["params_ci"]
        rows.append({"stack": stack, "outcome": st["outcome"], "mass_kg": _ci(pr["mass_kg"], ci["mass_kg"]),
                     **{f"com_{a}_mm": _ci(pr[f"com_{a}_m"], ci[f"com_{a}_m"], 1e3, "{:.1f}") for a in "xyz"}})
    return pd.DataFrame(rows)


def friction_table(result: dict) -> pd.DataFrame:
    """Each run's classic friction per joint (fitted in the pooled stack) and its change from the first run."""
    rows = []
    for j, runs in (result.get("friction_per_run") or {}).items():
        for label, row in runs.items():
            lv, ci = row["levels"], row["levels_ci"]
            out = {"joint": int(j), "run": label,
                   "fc_pos_Nm": _ci(lv["fc_pos_Nm"], ci["fc_pos_Nm"], fmt="{:.3g}"),
                   "fc_neg_Nm": _ci(lv["fc_neg_Nm"], ci["fc_neg_Nm"], fmt="{:.3g}"),
                   "viscous_pos_Nm_s_rad": _ci(lv["viscous_pos_Nm_s_rad"], ci["viscous_pos_Nm_s_rad"], fmt="{:.3g}"),
                   "viscous_neg_Nm_s_rad": _ci(lv["viscous_neg_Nm_s_rad"], ci["viscous_neg_Nm_s_rad"], fmt="{:.3g}")}
            at = row.get("torque_change_at_median_speed")
            for d in ("pos", "neg"):
                c = (at or {}).get(d)
                out[f"change_{d}_Nm"] = "-" if c is None else (
                    _ci(c["change_Nm"], c["change_ci_Nm"], fmt="{:.3g}") + f" at {c['speed_rad_s']:.2g} rad/s")
            rows.append(out)
    return pd.DataFrame(rows)


def report_pooled(result: dict, manifest: dict, doc: Document) -> Document:
    """The pooled diagnosis into ``doc``."""
    runs = result.get("runs") or []
    method = result.get("method") or ""
    doc.text("Runs pooled: " + ", ".join(r["label"] for r in runs) + ". " + method[:1].upper() + method[1:]
             + ("." if method else ""))
    if not result.get("conclusive"):
        doc.heading("Nothing could be concluded")
        doc.text(str(result.get("reason")))
        doc.table("summary", runs_table(result), "each run on its own")
        return doc
    found = result.get("effects_found") or []
    amb = result.get("ambiguous") or []
    doc.heading("Effects found (runs pooled)")
    doc.text((", ".join(found) + " (strongest evidence first)." if found else "None named.")
             + (" Ambiguous: " + "; ".join(" / ".join(g) for g in amb) + "." if amb else ""))
    for line in decided_lines(result):
        doc.text(line[0].upper() + line[1:] + ".")
    doc.table("summary", runs_table(result), "each run on its own: the joints it diagnosed and what its own "
              "diagnosis decided")
    doc.table("runs", run_states_table(result), "each run's start state and controller gains (as its log or "
              "meta.yaml give them), its own in the pooled fit")
    doc.heading("Every decision per stack")
    thr = _p(result.get("test_threshold_p"))
    doc.table("effects", findings_table(result), f"nested held-out tests (threshold p < {thr} and a BIC drop); "
              "payload: does a wrist payload add to link errors within (twice) the declared "
              "accuracy; a joint's effect: does it add to each run's own model with coefficients shared by the runs")
    dt = delay_table(result)
    if len(dt):
        doc.heading("A delay or inertia errors")
        doc.table("delay_or_inertia", dt, "held-out torque RMS per run and joint (each run's own friction and "
                  "offset; the delay one for all runs, the inertia errors shared); the run's excess: how many noise "
                  "floors RMS the losing hypothesis leaves beyond the winner in that run, both fitted on all runs "
                  "(1 decides)")
    pt = payload_table(result)
    if len(pt):
        doc.heading("The arm's payload")
        doc.table("payload", pt, "estimate [95 % interval] per stack; not identified: these runs' motion does not "
                  "determine it (no number)")
    ft = friction_table(result)
    if len(ft):
        doc.heading("Friction per run")
        doc.table("friction", ft, "classic friction of each run fitted in the pooled stack (its own levels: a "
                  "friction that drifted between runs), 95 % intervals; the change of the friction torque from the "
                  "first run at this run's median sliding speed of each direction (what the data determine where a "
                  "direction ran at one speed: Coulomb and viscous levels then trade against each other)")
    doc.text("Each run's own diagnosis is in alone-<k>.json; no model file is written for the pooled runs.")
    return doc
