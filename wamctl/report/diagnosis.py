"""Report of a diagnosis run directory (``wamctl diagnose``): what the declared model lacked, the evidence for
each candidate effect, the held-out torque residual before and after, and the measured positions against the
closed-loop re-simulation of both models. Everything comes from the run directory (diagnosis.json,
residuals.parquet, positions.parquet)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd

from wamctl.io import load_yaml
from wamctl.report.document import Document
from wamctl.report.figures import joint_grid, save

CAP = 20      # -log10 p shown up to here: beyond, every effect is overwhelming


def _fmt_params(params: dict) -> str:
    """An effect's parameters in one cell; those the data do not determine (None, or a list of None) are left to
    the table's "not identified" column, which names them."""
    out = []
    for k, v in params.items():
        if v is None or isinstance(v, dict) or (isinstance(v, list) and v and all(x is None for x in v)):
            continue
        if isinstance(v, float):
            out.append(f"{k}={v:.4g}")
        elif isinstance(v, list) and all(isinstance(x, (int, float)) or x is None for x in v):
            out.append(f"{k}=[{', '.join('not identified' if x is None else f'{x:.3g}' for x in v)}]")
        else:
            out.append(f"{k}={v}")
    return ", ".join(out) or "-"


NOT_CHECKED = "not checked: did not move in the span checked"


def summary_table(result: dict) -> pd.DataFrame:
    """Per diagnosed joint, the held-out figures before and after; a joint the position check did not score has
    no position figure (never a zero) and says so in ``position_check``."""
    rows = []
    for j, d in result.get("joints", {}).items():
        row = {"joint": int(j), "effects": ", ".join(e["name"] for e in d["effects"]) or "-",
               "torque_rms_before_Nm": d["torque_rms_before_Nm"],
               "torque_rms_after_Nm": d["torque_rms_after_Nm"],
               "position_rms_before_rad": d["position_rms_before_rad"],
               "position_rms_after_rad": d["position_rms_after_rad"],
               "whiteness_p_before": d["residual_whiteness_p_before"],
               "whiteness_p_after": d["residual_whiteness_p_after"]}
        if any(dd.get("position_not_checked") for dd in result["joints"].values()):
            row["position_check"] = NOT_CHECKED if d.get("position_not_checked") else "checked"
        rows.append(row)
    df = pd.DataFrame(rows)
    return df.set_index("joint") if len(df) else df


def position_span(result: dict) -> str | None:
    """Which part of the run the closed-loop position check simulated, or why it was skipped, in one line (None:
    nothing was checked, as when nothing was concluded)."""
    pc = result.get("position_check") or {}
    spans = pc.get("spans_s")
    if pc.get("skipped"):
        return f"position check: skipped ({pc['skipped']})"
    if not spans:
        return None
    if pc.get("whole_run"):
        where = (f"the whole run ({spans[0][0]:.0f}-{spans[-1][1]:.0f} s"
                 + (f", in {len(spans)} windows each started from the measured state" if len(spans) > 1 else "")
                 + ")")
    else:
        where = (f"{pc['samples_checked']} of {pc['samples_run']} samples, in {len(spans)} window"
                 f"{'s' if len(spans) > 1 else ''} each started from the measured state: "
                 + ", ".join(f"{a:.0f}-{b:.0f} s" for a, b in spans))
    return f"position check: {where}"


def _fmt_ci(params: dict, ci: dict) -> str:
    """Each estimate with its 95 % interval, e.g. ``mass_kg=1.28 [1.25, 1.31]`` (open ends as ``..``)."""
    out = []
    for k, (lo, hi) in (ci or {}).items():
        v = params.get(k)
        if v is None or isinstance(v, (dict, list)):
            continue
        out.append(f"{k}={v:.4g} [{'..' if lo is None else f'{lo:.4g}'}, {'..' if hi is None else f'{hi:.4g}'}]")
    return ", ".join(out)


def effects_table(result: dict) -> pd.DataFrame:
    rows = []
    for j, d in result.get("joints", {}).items():
        for e in d["effects"]:
            rows.append({"joint": int(j), "effect": e["name"], "params": _fmt_params(e["params"]),
                         "95 % intervals": _fmt_ci(e["params"], e.get("params_ci")),
                         "not identified": ", ".join(e.get("not_identified") or []) or "-",
                         "torque_rms_before_Nm": e.get("torque_rms_before_Nm"),
                         "torque_rms_after_Nm": e.get("torque_rms_after_Nm"),
                         "p_value": _p(e["evidence"]["p_value"]), "delta_bic": e["evidence"]["delta_bic"],
                         "test": e["evidence"]["test"]})
    return pd.DataFrame(rows)


def ambiguous_table(result: dict) -> pd.DataFrame:
    rows = []
    for j, d in result.get("joints", {}).items():
        for g in d.get("ambiguous") or []:
            cands = {c["name"]: c for c in d["candidates"]}
            rows.append({"joint": int(j), "candidates": " / ".join(g),
                         "p_values": ", ".join(f"{n}: {_p(cands.get(n, {}).get('p_value'))}" for n in g)})
    return pd.DataFrame(rows)


def unexplained_table(result: dict) -> pd.DataFrame:
    rows = []
    for j, d in result.get("joints", {}).items():
        u = d.get("unexplained")
        if u:
            rows.append({"joint": int(j), "correlates_with": ", ".join(u["correlates_with"]) or
                         f"no group tested (not white: p {_p(u.get('whiteness_p'))})",
                         "torque_rms_Nm": u["torque_rms_Nm"]})
    return pd.DataFrame(rows)


def not_named_lines(result: dict) -> list[str]:
    """What the diagnosis saw and did not name: arm-level findings no joint kept (``not_named``) and the joints
    whose residual is still structured (``unexplained``), one line each."""
    lines = [f"not named: {u['name']} (joints {', '.join(str(j) for j in u['joints'])}): {u['why']}"
             for u in result.get("not_named") or []]
    for j, d in sorted(result.get("joints", {}).items(), key=lambda kv: int(kv[0])):
        u = d.get("unexplained")
        if u:
            what = ("follows " + ", ".join(u["correlates_with"]) if u["correlates_with"] else
                    f"is not white (Ljung-Box p {_p(u.get('whiteness_p'))}) and follows no signal tested")
            lines.append(f"unexplained residual at joint {j}: {_g(u['torque_rms_Nm'])} N m RMS held out, {what}")
    return lines


def next_experiment_line(result: dict) -> str | None:
    """The run designed to tell what this one could not (``next_experiment``), in one line, or None."""
    n = result.get("next_experiment")
    if not n:
        return None
    if not n.get("spec"):
        return f"next experiment: {n['why']}"
    return (f"next experiment: {n['spec']} (excitation of joints {', '.join(map(str, n['joints']))}, predicted "
            f"separation {n['separation_noise_floors']:.2g} noise floors, this run's "
            f"{n['original_separation_noise_floors']:.2g}): {n['why']}")


def found_line(result: dict) -> str:
    """The diagnosis in one line: the effects found, the ambiguous groups, and how many findings and structured
    residuals are not named (each said by :func:`not_named_lines`)."""
    if not result.get("conclusive"):
        return f"nothing concluded: {result.get('reason')}"
    found = ", ".join(result.get("effects_found") or []) or "none"
    amb = "; ".join(" / ".join(g) for g in result.get("ambiguous") or [])
    nn = [u["name"] for u in result.get("not_named") or []]
    unx = [j for j, d in sorted(result.get("joints", {}).items(), key=lambda kv: int(kv[0])) if d.get("unexplained")]
    return (f"effects found: {found}" + (f" (ambiguous: {amb})" if amb else "")
            + (f"; seen, not named: {', '.join(nn)}" if nn else "")
            + (f"; unexplained residual at joint{'s' if len(unx) > 1 else ''} {', '.join(unx)}" if unx else ""))


def candidates_table(result: dict) -> pd.DataFrame:
    rows = []
    for j, d in result.get("joints", {}).items():
        for c in d["candidates"]:
            rows.append({"joint": int(j), "candidate": c["name"], "p_value": _p(c["p_value"]),
                         "delta_bic": c["delta_bic"], "kept": "yes" if c["kept"] else "no",
                         "reason": c.get("reason", "")})
    return pd.DataFrame(rows)


def _figures(run_path: Path, out_dir: Path, result: dict, doc: Document) -> None:
    joints = sorted(int(j) for j in result.get("joints", {}))
    if not joints:
        return
    res_path = run_path / "residuals.parquet"
    if res_path.is_file():
        res = pd.read_parquet(res_path)
        fig, axes = joint_grid(len(joints), "Held-out torque residual, declared model vs with the effects found")
        for ax, j in zip(axes, joints):
            r = res[res["joint"] == j]
            slide = r[r["at"] == "sliding"] if "at" in r else r
            stall = r[r["at"] == "stall"] if "at" in r else r.iloc[:0]
            ax.plot(slide["t_s"], slide["residual_before_Nm"], ".", ms=1.5, alpha=0.5, color="tab:blue",
                    label="declared")
            ax.plot(slide["t_s"], slide["residual_after_Nm"], ".", ms=1.5, alpha=0.5, color="tab:orange",
                    label="with effects")
            if len(stall):
                ax.plot(stall["t_s"], stall["residual_before_Nm"], "x", ms=2.5, alpha=0.6, color="tab:blue",
                        label="declared, at stalls")
                ax.plot(stall["t_s"], stall["residual_after_Nm"], "x", ms=2.5, alpha=0.6, color="tab:orange",
                        label="with effects, at stalls")
            d = result["joints"][str(j)]
            ax.set_title(f"joint {j}: RMS {d['torque_rms_before_Nm']:.3g} -> {d['torque_rms_after_Nm']:.3g} N m")
            ax.set_ylabel("residual (N m)")
            ax.set_xlabel("t (s)")
            ax.grid(alpha=0.3)
        axes[0].legend(markerscale=6)
        doc.figure(save(fig, out_dir / "diagnosis_residuals.png"),
                   "held-out torque residual (tau - model) per joint, before and after adding the effects; dots: "
                   "sliding samples, crosses: samples where the joint stood still before moving (the torque "
                   "beyond what the model's friction holds a joint at rest with)")
    # evidence: -log10 p of every candidate, with the threshold
    thr = (result.get("method") or {}).get("test_threshold_p")
    fig, axes = joint_grid(len(joints), "Evidence per candidate effect (held-out nested F-test)")
    for ax, j in zip(axes, joints):
        cands = result["joints"][str(j)]["candidates"]
        names = [c["name"] for c in cands]
        vals = [min(-np.log10(max(c["p_value"], 1e-300)), CAP) if c["p_value"] is not None else 0.0
                for c in cands]
        colours = ["tab:green" if c["kept"] else "tab:gray" for c in cands]
        ax.barh(names, vals, color=colours)
        if thr:
            ax.axvline(-np.log10(thr), color="tab:red", lw=1, label="threshold")
        ax.set_xlim(0, CAP)
        ax.set_title(f"joint {j}")
        ax.set_xlabel(f"-log10 p, capped at {CAP} (green: kept)")
    doc.figure(save(fig, out_dir / "diagnosis_evidence.png"),
               "evidence for each candidate effect: -log10 of the held-out F-test p-value; the red line is the "
               "run's threshold (alpha / number of tests)")
    pos_path = run_path / "positions.parquet"
    if pos_path.is_file():
        pos = pd.read_parquet(pos_path)
        t = pos["t_s"].to_numpy()
        if len(t) > 2:      # windows spread over a long run: no line drawn across the stretch not simulated
            dt = np.diff(t)
            pos = pos.mask(pd.Series(np.r_[False, dt > 1.5 * np.median(dt)], index=pos.index), axis=0)
        fig, axes = joint_grid(len(joints), "Measured positions and closed-loop re-simulation (held-out)",
                               height_per_row=2.4)
        for ax, j in zip(axes, joints):
            qm = pos[f"q_{j}_rad"].to_numpy()
            ax.plot(t, (pos[f"q_before_{j}_rad"] - qm) * 1e3, lw=0.8, label="declared model - measured")
            ax.plot(t, (pos[f"q_after_{j}_rad"] - qm) * 1e3, lw=0.8, label="with effects - measured")
            d = result["joints"][str(j)]
            ax.set_title(f"joint {j}: {NOT_CHECKED}" if d.get("position_not_checked") else
                         f"joint {j}: RMS {_g(_milli(d['position_rms_before_rad']))} -> "
                         f"{_g(_milli(d['position_rms_after_rad']))} mrad")   # the axis' unit
            ax.set_ylabel("mrad")
            ax.set_xlabel("t (s)")
            ax.grid(alpha=0.3)
        axes[0].legend()
        doc.figure(save(fig, out_dir / "diagnosis_positions.png"),
                   "re-simulated minus measured joint positions, declared model vs with the effects found")
        fig, axes = joint_grid(len(joints), "Measured and re-simulated positions", height_per_row=2.4)
        for ax, j in zip(axes, joints):
            ax.plot(t, pos[f"q_{j}_rad"], "k", lw=1.2, label="measured")
            ax.plot(t, pos[f"q_before_{j}_rad"], "--", lw=0.8, label="declared model")
            ax.plot(t, pos[f"q_after_{j}_rad"], ":", lw=1.0, label="with effects")
            ax.set_title(f"joint {j}")
            ax.set_ylabel("q (rad)")
            ax.grid(alpha=0.3)
        axes[0].legend()
        doc.figure(save(fig, out_dir / "diagnosis_traces.png"),
                   "measured positions and the closed-loop re-simulation of both models")


def not_diagnosed(result: dict) -> list[str]:
    """One line per joint that was not diagnosed, with why (``skipped_joints``), and one line for the joints that
    were neither commanded nor moved (``idle_joints``): every joint of the arm is either in ``joints`` or named
    here."""
    lines = [f"joint {j} not diagnosed: {why}" for j, why in (result.get("skipped_joints") or {}).items()]
    idle = result.get("idle_joints") or []
    if idle:
        lines.append(f"joint{'s' if len(idle) > 1 else ''} {', '.join(str(j) for j in idle)} not diagnosed: not "
                     "commanded to move, and did not move")
    return lines


def _p(x) -> str:
    """A p-value as text (tables print floats with fixed decimals, which would show 0.0000)."""
    return "n/a" if x is None else f"{x:.2g}"


def _milli(x):
    return None if x is None else 1e3 * x


def _g(x) -> str:
    return "n/a" if x is None else f"{x:.3g}"


def report(run_path: Path, manifest: dict, spec: dict, out_dir: Path | None = None) -> Document:
    """Build the report of a diagnosis run directory."""
    run_path = Path(run_path)
    out_dir = Path(out_dir or run_path)
    out_dir.mkdir(parents=True, exist_ok=True)
    result = json.loads((run_path / "diagnosis.json").read_text())
    doc = Document(f"Model diagnosis: {manifest.get('name', run_path.name)}")
    if result.get("pooled"):          # several runs of one arm (wamctl diagnose RUN1 RUN2 ...)
        from wamctl.report.diagnosis_pooled import report_pooled

        doc.data["diagnosis"] = result
        return report_pooled(result, manifest, doc)
    worse = [d["warning"] for d in (result.get("held_out_vs_declared") or {}).values() if d.get("warning")]
    for w in worse:     # first: a model written that predicts worse than the declared one is never quiet
        doc.warning(w)
    doc.text(f"Data: {result.get('data') or spec.get('data')}. Declared model: {result.get('declared_model')}.")
    if result.get("torque") == "controller":
        doc.text("Torque: the controller's output, libbarrett's gravity compensation added downstream and not logged; "
                 "only the joints whose gravity torque is constant over the run are diagnosed (the declared gravity "
                 "added back), the others are named below with why.")
    m = result.get("method") or {}
    if m:
        doc.text(f"{m.get('samples')} samples at {m.get('sample_rate_hz', 0):.0f} Hz; derivatives by a Gaussian "
                 f"pre-filter (sigma {m.get('gauss_sigma_samples', 0):.1f} samples) and a Savitzky-Golay window of "
                 f"{m.get('savgol_window_samples')} samples; {m.get('blocks')} time blocks in {m.get('folds')} "
                 f"folds for held-out figures; an effect is kept when its held-out nested F-test gives "
                 f"p < {_g(m.get('test_threshold_p'))} (alpha {m.get('alpha_per_run')} per run over every test) "
                 "and the BIC drops.")
    if not result.get("conclusive", True):
        doc.heading("Nothing could be concluded")
        doc.text(str(result.get("reason")))
    else:
        found = result.get("effects_found") or []
        amb = result.get("ambiguous") or []
        doc.heading("Effects found")
        if found:
            doc.text(", ".join(found) + " (strongest evidence first).")
        elif amb:
            doc.text("None named: the data show something the declared model lacks, but the candidates below "
                     "explain it equally well (ambiguous).")
        else:
            doc.text("None: the data show nothing the declared model lacks.")
        if amb:
            doc.text("Ambiguous (neither candidate explains the held-out data clearly better than the other, so "
                     "neither is named): " + "; ".join(" / ".join(g) for g in amb) + ".")
        for line in not_named_lines(result):       # seen and not named: said with why, never dropped
            doc.text(line[0].upper() + line[1:] + ".")
        nxt = next_experiment_line(result)
        if nxt:
            doc.text(nxt[0].upper() + nxt[1:] + ".")
    for w in result.get("warnings") or []:
        if w not in worse:          # already at the top
            doc.text(f"Warning: {w}.")
    pc = result.get("position_check") or {}
    if pc.get("skipped"):
        doc.text(f"The closed-loop position check was skipped: {pc['skipped']}.")
    elif (pc.get("controller_gains") or {}).get("source"):
        doc.text(f"Closed-loop check: controller gains {pc['controller_gains']['source']}.")
    span = position_span(result)
    if span and not pc.get("skipped"):         # a skipped check is said above
        doc.text(span[0].upper() + span[1:] + ".")
    for line in not_diagnosed(result):
        doc.text(line[0].upper() + line[1:] + ".")
    doc.data["diagnosis"] = result
    if not result.get("joints"):
        return doc
    doc.heading("Before and after (held-out data)")
    doc.table("summary", summary_table(result),
              "torque: inverse-dynamics residual; position: closed-loop re-simulation minus measurement; "
              "whiteness: Ljung-Box p of the residual taken once per filter window")
    eff = effects_table(result)
    if len(eff):
        doc.heading("Effects and their evidence")
        doc.table("effects", eff, "torque rms before / after: held out, over the sliding samples, at the step the "
                  "effect was added (the model with the effects found before it, without and with this one); the "
                  "table above is the declared model against the final one, and counts the stalls too")
    amb = ambiguous_table(result)
    if len(amb):
        doc.heading("Ambiguous candidates")
        doc.table("ambiguous", amb, "candidates that passed but neither explained the held-out residual clearly "
                  "better than the other")
    unx = unexplained_table(result)
    if len(unx):
        doc.heading("What is left")
        doc.table("unexplained", unx, "joints whose held-out residual, after every named effect, still follows "
                  "these signals (not named as an effect)")
    doc.heading("Candidates")
    doc.table("candidates", candidates_table(result), "every candidate tested per joint, with the reason it was "
              "kept or rejected")
    _figures(run_path, out_dir, result, doc)
    if (run_path / "model.yaml").is_file():
        undetermined = ((load_yaml(run_path / "model.yaml") or {}).get("diagnosis") or {}).get("not_identified") or {}
        doc.text("The augmented model is in model.yaml (format wamctl-model/1); use it as `plant: model.yaml` in a "
                 "spec to re-simulate an experiment with it."
                 + "".join(f" Its {name} holds values for {', '.join(ps)} that the data did not determine (listed "
                           "under diagnosis.not_identified): they let the model run and are not estimates."
                           for name, ps in undetermined.items()))
    return doc
