"""Identification report (``wamctl identify``): what the data determine, the identified base parameters with
their intervals and how far each moved from the declared arm, physical consistency per link, and the held-out
validation of the nominal against the identified model (table and measured-vs-predicted figures)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import yaml

from wamctl.model import params as P
from wamctl.report.document import Document
from wamctl.report.figures import joint_grid, save


def validation_table(result: dict) -> pd.DataFrame:
    v = result["validation"]
    rows = []
    for j in range(len(v["nominal"])):
        nom, idf, ins = v["nominal"][j], v["identified"][j], v["in_sample_identified"][j]
        row = {"joint": j + 1, "nominal_rms_Nm": nom, "identified_rms_Nm": idf,
               "identified_over_nominal": (idf / nom) if nom and idf is not None else None,
               "in_sample_rms_Nm": ins}
        if "identified_diagnosis_band" in v:     # the same held-out samples without the fit's second filter
            dn, di = v["nominal_diagnosis_band"][j], v["identified_diagnosis_band"][j]
            row.update(nominal_rms_diagnosis_band_Nm=dn, identified_rms_diagnosis_band_Nm=di)
        rows.append(row)
    return pd.DataFrame(rows).set_index("joint")


def validation_band_text(result: dict) -> str:
    """Which band the held-out RMS is in: the fit's (the diagnosis' filter, then the fit's second filter)."""
    windows = sorted({b["window_s"] for b in result.get("validation_band") or [] if b.get("window_s")})
    if not windows:
        return "the diagnosis' filter (about 10 Hz, as `wamctl diagnose`), the band the model was fitted in"
    return ("the band the model was fitted in: the diagnosis' filter (about 10 Hz), then the fit's second filter "
            f"({', '.join(f'{w:g}' for w in windows)} s window); the diagnosis band columns: the same held-out samples "
            "without the second filter, as `wamctl diagnose` sees them")


def parameter_table(result: dict) -> pd.DataFrame:
    df = pd.DataFrame(result["base"])
    cols = ["parameter", "unit", "declared", "estimate", "ci_low", "ci_high", "moved_se", "data_share", "status"]
    out = df[cols].copy()
    return out


def links_table(model: dict, margins: list) -> pd.DataFrame:
    rows = []
    robot = model.get("robot", "wam7")
    for j in range(1, len(model["links"]) + 1):
        e = model["links"][j] if j in model["links"] else model["links"][str(j)]
        ev = np.linalg.eigvalsh(P.LinkParameters.datasheet(robot).with_overrides({j: e})
                                .inertia_matrix_kg_m2(j - 1))
        rows.append({"link": j, "mass_kg": e["mass_kg"], "com_x_m": e["com_m"][0], "com_y_m": e["com_m"][1],
                     "com_z_m": e["com_m"][2], "I1_kg_m2": ev[0], "I2_kg_m2": ev[1], "I3_kg_m2": ev[2],
                     "armature_kg_m2": e["armature_kg_m2"], "pseudo_inertia_margin": margins[j - 1],
                     "consistent": bool(margins[j - 1] is not None and margins[j - 1] > 0)})
    return pd.DataFrame(rows).set_index("link")


def report(run_path: Path, manifest: dict, spec: dict, out_dir: Path | None = None) -> Document:
    out_dir = Path(out_dir or run_path)
    if (run_path / "payload.json").exists():
        return payload_report(run_path, manifest)
    result = json.loads((run_path / "identification.json").read_text())
    model_name = result.get("model_file", "model.yaml")
    model = yaml.safe_load((run_path / model_name).read_text())
    doc = Document(f"Identification: {manifest.get('name', run_path.name)}")
    check = result.get("held_out_check")
    if check:
        doc.text(check_first_lines(check, model_name))
        doc.data["held_out_check"] = {k: check.get(k) for k in ("verdict", "ratio", "p_worse", "worse_joints",
                                                                "within_noise_joints", "unchecked_joints",
                                                                "not_moving_joints", "model_written")}
    ident = result["identifiability"]
    prov = result["provenance"]
    held = prov["validation"]
    held = held if isinstance(held, str) else ", ".join(Path(p).name for p in held)
    urdf = result.get("urdf") or {"written": True}
    robot = prov.get("robot", "wam7")
    doc.text(f"Arm: {robot} ({result.get('n_joints', 7)} joints). "
             f"From {len(prov['data'])} run(s), {result['n_rows']} rows (sample, sliding joint); declared arm: "
             f"{prov['declared']}; held out: {held}. "
             f"Instruments: {result['instruments']}. Model file: {model_name}"
             + (f", and the same links as a URDF, {Path(model_name).with_suffix('.urdf')}" if urdf["written"]
                else f" (no URDF: {urdf['reason']})")
             + (" (usable as plant:, controller.declared_links:, diagnose --model)." if model_name == "model.yaml"
                else " (not model.yaml: see the held-out check above)."))
    doc.data["instruments"] = result["instruments"]
    doc.data["robot"] = robot
    refused = result.get("joints_refused") or {}
    if refused:
        doc.text("Joints that moved but give no rows: " + "; ".join(f"joint {j}: {why}"
                                                                     for j, why in refused.items()) + ".")
        doc.data["joints_refused"] = refused
    acc = result.get("row_accounting") or []
    if acc:
        tot = {k: sum(a.get(k, 0) for a in acc)
               for k in ("candidates", "near_stop", "slow", "filter_reach", "held_out", "used")}
        doc.text(f"Rows used: {tot['used']} of {tot['candidates']} candidates (sample at the row rate, joint "
                 f"commanded to move); left out: {tot['near_stop']} near a stop or the record's ends (the "
                 f"classic friction model does not hold at stick), {tot['slow']} slower than "
                 f"{acc[0]['min_speed_rad_s']} rad/s, {tot['filter_reach']} within the second filter's reach "
                 f"({max(a['second_filter_reach_s'] for a in acc):.3g} s) of those"
                 + (f", {tot['held_out']} held out (with the filters' reach before the held-out block)."
                    if tot["held_out"] else "."))
        doc.data["row_accounting"] = tot
    doc.heading("What the data determine")
    cond = ident["condition_number"]
    text = (f"Rank {ident['rank']} of {ident['n_base']} base parameters; condition number of the weighted, "
            f"column-equilibrated base regressor {cond:.4g}." if cond != float("inf") and cond is not None else
            f"Rank {ident['rank']} of {ident['n_base']} base parameters (condition number over the determined "
            f"directions {ident['condition_number_identified']:.4g}).")
    if ident["undetermined"]:
        text += (f" Not identified (the data cannot determine them one by one, so no number is printed): "
                 f"{', '.join(ident['undetermined'])}. Every standard parameter no data row sees keeps the declared "
                 "arm's value; the others move only as far as the combinations the data see require (the declared "
                 "arm decides the split).")
    weak = [r["parameter"] for r in result["base"] if r["status"] == "weak"]
    if weak:
        text += (f" Weakly identified (the declared arm weighs more than the data): {', '.join(weak)}.")
    widened = {j + 1: w for j, w in enumerate(result.get("prior_widths") or []) if w is not None and w > 1.5}
    if widened:
        text += (" The data contradict the declared arm at joint(s) " + ", ".join(
            f"{j} (prior widened x{w:.1f})" for j, w in widened.items()) + ": their link, armature and friction "
            "were given a wider prior than the declared 30 % (type-II maximum likelihood); an undeclared tool or "
            "a link off its datasheet looks like this.")
        doc.data["prior_widened"] = {str(j): w for j, w in widened.items()}
    doc.text(text)
    doc.heading("Held-out validation")
    vt = validation_table(result)
    band = validation_band_text(result)
    doc.table("validation", vt, f"RMS of measured - predicted torque on held-out data, in {band}; nominal: "
              "declared links with friction fitted on the same data; in-sample: the identified model on the data "
              "it was fitted on (after the identification's filter).")
    doc.data["validation"] = vt.reset_index().replace({np.nan: None}).to_dict("records")
    _validation_figure(run_path, out_dir, doc)
    _relative_error_section(result, doc)
    doc.heading("Base parameters")
    doc.table("parameters", parameter_table(result), "estimate: the physically consistent estimate; interval: "
              f"{100 * (1 - spec.get('options', {}).get('alpha', 0.05)):.0f} % (posterior: data with HAC "
              "errors + a prior at the declared arm, 30 % of each declared value; Student's t with the "
              "variance's degrees of freedom; they assume the declared arm within that prior: a truth further "
              "off biases the estimate toward it, not included); moved_se: (estimate - declared) "
              "/ standard error; data_share: the data's share of the information. Expressions in parameters.csv.",
              digits=5)
    _moved_figure(result, out_dir, doc)
    doc.heading("Physical consistency")
    doc.table("links", links_table(model, result["pseudo_inertia_margin"]),
              "the identified arm's links (DH frame i; principal moments about the COM); margin: smallest "
              "eigenvalue of the pseudo-inertia over its largest (> 0: a physical body).", digits=5)
    _physical_checks_section(result, doc)
    doc.data.update(consistent=result["consistent"], not_identified=ident["undetermined"],
                    condition_number=cond)
    return doc


def _ci(ci) -> str:
    return "" if not ci or ci[0] is None else f" ({100 * ci[0]:.2f} to {100 * ci[1]:.2f})"


def _relative_error_section(result: dict, doc: Document) -> None:
    """Relative torque error per trajectory, held out and in sample, and the prior moves (issue 29 item 4)."""
    rel = result.get("relative_error")
    if rel:
        rows = [{"trajectory": Path(e["source"]).name, "data": part.replace("_", " "), "samples": e["samples"],
                 "identified_pct": None if e["identified"] is None else 100 * e["identified"],
                 "identified_ci95_pct": _ci(e["identified_ci95"]).strip(" ()") or None,
                 "nominal_pct": None if e["nominal"] is None else 100 * e["nominal"]}
                for part in ("held_out", "in_sample") for e in rel[part]]
        lo, hi = rel["published_held_out_pct"]
        doc.table("relative error", pd.DataFrame(rows),
                  f"||tau - tau_hat|| / ||tau|| per trajectory, all joints, in %, 95 % block-bootstrap interval; "
                  f"nominal: declared links, friction fitted. Published real-WAM figure: {lo}-{hi} % held out "
                  "(the real arm's noise and friction; a simulated arm's depends on its settings).", digits=4)
        doc.data["relative_error"] = rows
    moves = [m for m in result.get("prior_moves") or [] if m["moved_prior_sd"] is not None]
    if moves:
        far = sorted(moves, key=lambda m: -abs(m["moved_prior_sd"]))
        doc.text("Moved from the declared arm, in the prior's standard deviations (the prior: 30 % of each "
                 "declared value, with floors): " + ", ".join(f"{m['parameter']} {m['moved_prior_sd']:+.2f}"
                                                              for m in far[:8])
                 + (f"; {len(far) - 8} more in identification.json (prior_moves)" if len(far) > 8 else "")
                 + f". Largest |move| {abs(far[0]['moved_prior_sd']):.2f} SD.")
        doc.data["largest_prior_move_sd"] = abs(far[0]["moved_prior_sd"])


def _physical_checks_section(result: dict, doc: Document) -> None:
    chk = result.get("physical_checks")
    if not chk:
        return
    tab = pd.DataFrame([{"link": r["link"], "com_x_m": r["com_m"][0], "com_y_m": r["com_m"][1],
                         "com_z_m": r["com_m"][2], "outside_box_m": r["outside_m"], "ok": r["ok"]}
                        for r in chk["com_in_box"]])
    doc.table("com in box", tab, "each link's centre of mass (DH frame i) against a box around the link "
              "(Sousa and Cortesao's condition; the box in identification.json, physical_checks)", digits=4)
    t = chk["total_mass"]
    doc.text(f"Total mass {t['identified_kg']:.4g} kg against the declared {t['declared_kg']:.4g} kg "
             f"({100 * t['relative']:+.1f} %, tolerance {100 * t['tolerance']:.0f} %): "
             f"{'ok' if t['ok'] else 'OUTSIDE'}. {chk['note'][0].upper() + chk['note'][1:].rstrip('.')}.")
    doc.data["physical_checks_ok"] = chk["ok"]


def check_first_lines(check: dict, model_name: str) -> str:
    """The report's first lines: the held-out check's statement and what was written."""
    s = check["statement"][0].upper() + check["statement"][1:] + "."
    if check["verdict"] not in ("better", "no_worse"):
        s += (f" The model is written as {model_name}"
              + (" because --force was given." if model_name == "model.yaml" else
                 ", not model.yaml: it is not an identified arm to use (wamctl identify --force writes it as "
                 "model.yaml)."))
    return s


def _validation_figure(run_path: Path, out_dir: Path, doc: Document) -> None:
    path = run_path / "validation.parquet"
    if not path.is_file():
        return
    df = pd.read_parquet(path)
    first = df[df["run"] == df["run"].min()]
    joints = sorted(first["joint"].unique())
    if not joints:
        return
    fig, axes = joint_grid(len(joints), "Held-out torque: measured and predicted")
    for ax, j in zip(axes, joints):
        d = first[first["joint"] == j]
        ax.plot(d["t_s"], d["measured_Nm"], ".", ms=1.5, color="0.3", label="measured")
        ax.plot(d["t_s"], d["nominal_Nm"], ".", ms=1.2, color="C1", label="nominal")
        ax.plot(d["t_s"], d["identified_Nm"], ".", ms=1.2, color="C0", label="identified")
        ax.set_title(f"joint {j}")
        ax.set_ylabel("tau (N m)")
        ax.set_xlabel("t (s)")
        ax.grid(alpha=0.3)
    axes[0].legend(markerscale=6)
    doc.figure(save(fig, out_dir / "identification_validation.png"),
               "held-out torque (sliding samples of the first held-out run): measured, nominal and identified")
    fig, axes = joint_grid(len(joints), "Held-out residual: measured - predicted")
    for ax, j in zip(axes, joints):
        d = first[first["joint"] == j]
        ax.plot(d["t_s"], d["measured_Nm"] - d["nominal_Nm"], ".", ms=1.2, color="C1", label="nominal")
        ax.plot(d["t_s"], d["measured_Nm"] - d["identified_Nm"], ".", ms=1.2, color="C0", label="identified")
        ax.set_title(f"joint {j}")
        ax.set_ylabel("residual (N m)")
        ax.set_xlabel("t (s)")
        ax.grid(alpha=0.3)
    axes[0].legend(markerscale=6)
    doc.figure(save(fig, out_dir / "identification_residuals.png"),
               "held-out residual of the nominal and the identified model (the same samples)")


def _moved_figure(result: dict, out_dir: Path, doc: Document) -> None:
    import matplotlib.pyplot as plt

    df = pd.DataFrame(result["base"])
    df = df[df["status"] != "not identified"]
    if not len(df):
        return
    scale = np.maximum(np.abs(df["declared"].to_numpy(float)), 1e-12)
    rel = (df["estimate"].to_numpy(float) - df["declared"].to_numpy(float)) / scale
    err = 0.5 * (df["ci_high"].to_numpy(float) - df["ci_low"].to_numpy(float)) / scale
    fig, ax = plt.subplots(figsize=(11, max(4.0, 0.16 * len(df))))
    y = np.arange(len(df))
    ax.errorbar(np.clip(rel, -2, 2), y, xerr=np.minimum(err, 2), fmt="o", ms=3, lw=0.8)
    ax.axvline(0, color="0.5", lw=0.8)
    ax.set_yticks(y)
    ax.set_yticklabels(df["parameter"], fontsize=6)
    ax.set_xlim(-2.1, 2.1)
    ax.set_xlabel("(estimate - declared) / |declared|  (clipped at +-2)")
    ax.set_title("How far each base parameter moved from the declared arm, with its 95 % interval")
    ax.grid(alpha=0.3)
    doc.figure(save(fig, out_dir / "identification_moved.png"), "relative change of each base parameter from "
               "the declared value, with its interval")


def payload_report(run_path: Path, manifest: dict) -> Document:
    """The report of ``wamctl identify --payload`` (``payload.json``): the payload with its 95 % intervals, what
    the runs do not determine, the loaded/bare order, and the fit's residual per joint."""
    r = json.loads((run_path / "payload.json").read_text())
    doc = Document(f"Payload identification: {manifest.get('name', run_path.name)}")
    m, ci = r["mass_kg"], r["mass_ci95_kg"]
    doc.text(("mass not identified" if m is None else f"mass {m:.4g} kg (95 % interval {ci[0]:.4g} to {ci[1]:.4g})")
             + f"; {r['method']} ({'held poses: gravity only' if r['method'] == 'static' else r['order']}); "
             + (f"not identified: {', '.join(r['not_identified'])}" if r["not_identified"]
                else "every quantity identified") + ". Payload file: payload.yaml (plant.effects.payload, "
             "controller.declared_payload, diagnose --payload).")
    timing = r.get("torque_timing") or {}
    if timing.get("offset_s") is not None:
        lo, hi = timing["offset_ci95_s"]
        doc.text(f"Torque timing, estimated with the payload: the motion answers the logged torque "
                 f"{1e3 * timing['offset_s']:.3f} ms (95 % interval {1e3 * lo:.3f} to {1e3 * hi:.3f} ms) later than "
                 "the zero-order hold's half control period (bus latency on a real arm; 0.5 ms on the simulator, "
                 "its half physics step): assumed instead, it biases the inertia (docs/payload.md).")
    elif "beyond one control period" in timing.get("source", ""):
        doc.text(f"Torque timing {timing['source']}.")
    tab = pd.read_csv(run_path / "payload.csv")
    doc.table("payload", tab, caption="mass, centre of mass (link-7 frame) and inertia about the centre of mass "
                                      "(link-7 axes), 95 % intervals (HAC for the dynamic variant: the noise's "
                                      "share; on the simulator each quantity's held the truth in 54-59 of 60 "
                                      "seeds, biases within 0.3 standard errors, docs/payload.md); 'not "
                                      "identified': the runs do not determine it", digits=5)
    sig = pd.DataFrame({"joint": range(1, P.N_JOINTS + 1), "residual_rms_Nm": r["sigma_Nm"]})
    doc.table("payload residual", sig, caption="RMS of the loaded-minus-bare residual per joint", digits=4)
    doc.data["payload"] = {k: r.get(k) for k in ("method", "mass_kg", "mass_ci95_kg", "com_m", "com_ci95_m",
                                                 "not_identified", "order", "torque_timing")}
    return doc
