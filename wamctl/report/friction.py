"""Friction identification report (thesis chapter 4): the Table 4.1-style parameters with standard errors, one
friction-velocity map per joint with the measured points and the fitted curves (Fig. 4.6), the model selection,
the segments left out and why, the true parameters beside the identified ones when the run is simulated, and
the rotation test under PD + gravity with and without the identified feed-forward (section 4.4) when the run
holds it (or when two rotation runs are compared, :func:`comparison_document`).
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pandas as pd

from wamctl.analysis.friction_id.identify import FrictionIdentification, identify, identify_from_map
from wamctl.analysis.friction_id.models import MODEL_NAMES
from wamctl.model import params as P
from wamctl.model.friction import FrictionModel
from wamctl.report.document import Document
from wamctl.report.figures import joint_grid, save

log = logging.getLogger(__name__)

PARAMS = [("fc_pos", "fc_pos_Nm", "Fc+"), ("fc_neg", "fc_neg_Nm", "Fc-"),
          ("sigma2_pos", "viscous_pos_Nm_s_rad", "sigma2+"), ("sigma2_neg", "viscous_neg_Nm_s_rad", "sigma2-")]
STRIBECK_PARAMS = [("fs_pos", "fs_pos_Nm", "Fs+"), ("fs_neg", "fs_neg_Nm", "Fs-"), ("vs", "vs_rad_s", "vs"),
                   ("delta", "stribeck_delta", "delta")]
CURVE_STYLE = {"classic": ("C0", "-"), "classic_symmetric": ("C2", ":"), "stribeck": ("C3", "--")}


# ------------------------------------------------------------------------------------------------ truth
def true_friction(truth: dict | None, base_dir: Path | None = None, robot: str | None = None
                  ) -> FrictionModel | None:
    """The simulated plant's friction (with its Stribeck effect) from the run's plant spec of ``robot`` (the
    run's arm; default the wam7), or None."""
    if not truth:
        return None
    try:
        from wamctl.model.plant import Plant
        from wamctl.specs import PlantSpec
        return Plant(PlantSpec.model_validate(truth), base_dir, robot).friction
    except Exception as exc:  # a plant spec we cannot rebuild (file moved): no truth column
        log.warning("true friction not available: %s", exc)
        return None


def recovered_table(ident: FrictionIdentification, truth: FrictionModel) -> pd.DataFrame:
    """Per joint and parameter: true value, identified value (chosen model), its standard error, error %."""
    rows = []
    for j, ji in sorted(ident.joints.items()):
        est = ji.fits[ji.chosen]
        pairs = list(PARAMS)
        if ji.chosen == "stribeck" or truth.has_stribeck[j - 1]:
            pairs += STRIBECK_PARAMS[:2]
        for attr, field, label in pairs:
            tv = float(getattr(truth, field)[j - 1])
            fv = getattr(est, f"{attr}_", np.nan)
            sd = getattr(est, f"{attr}_std_", np.nan)
            if attr.startswith("fs") and not np.isfinite(tv):
                tv = float(getattr(truth, "fc" + field[2:])[j - 1])  # no Stribeck term: breakaway = Coulomb
            err = (fv - tv) / abs(tv) * 100 if np.isfinite(fv) and tv else np.nan
            rows.append({"joint": j, "parameter": label, "model": ji.chosen, "true": tv, "identified": fv,
                         "std": sd, "error_pct": err})
    return pd.DataFrame(rows).set_index("joint") if rows else pd.DataFrame()


# ------------------------------------------------------------------------------------------------ sections
def parameter_table(ident: FrictionIdentification) -> pd.DataFrame:
    """Table 4.1 layout of the chosen model per joint, with standard errors."""
    t = ident.table_4_1()
    return t


def map_figure(ident: FrictionIdentification, truth: FrictionModel | None, path: Path) -> Path:
    """One friction-velocity map per joint: segments with 95 % CI bars, fitted curves, the truth if known."""
    joints = sorted(ident.joints) or sorted(ident.map["joint"].unique())
    fig, axes = joint_grid(len(joints), "Friction-velocity maps (thesis Fig. 4.6)", height_per_row=2.8)
    for ax, j in zip(axes, joints):
        m = ident.map[ident.map["joint"] == j]
        acc = m[m["accepted"] & m["friction_Nm"].notna()]
        rej = m[~m["accepted"] & m["friction_Nm"].notna()]
        ax.errorbar(acc["velocity_rad_s"], acc["friction_Nm"], yerr=acc["friction_ci95_Nm"].fillna(0),
                    fmt="o", ms=3.5, color="k", ecolor="0.4", capsize=2, label="measured (95 % CI)", zorder=3)
        if len(rej):
            ax.plot(rej["velocity_rad_s"], rej["friction_Nm"], "x", color="0.6", ms=4, label="rejected")
        vmax = float(np.nanmax(np.abs(m["velocity_rad_s"]))) if m["velocity_rad_s"].notna().any() else 1.0
        vv = np.concatenate([-np.geomspace(vmax * 1.05, 1e-4, 200), np.geomspace(1e-4, vmax * 1.05, 200)])
        ji = ident.joints.get(j)
        if ji is not None:
            for name, est in ji.fits.items():
                c, ls = CURVE_STYLE.get(name, ("C4", "-"))
                lw = 2.0 if name == ji.chosen else 0.9
                for side in (vv < 0, vv > 0):
                    ax.plot(vv[side], est.predict(vv[side]), ls, color=c, lw=lw,
                            label=(name + (" (chosen)" if name == ji.chosen else "")) if side[-1] else None)
        if truth is not None:
            qd = np.zeros((len(vv), truth.n_joints))
            qd[:, j - 1] = vv
            ft = truth.friction_torque(qd)[:, j - 1]
            for side in (vv < 0, vv > 0):
                ax.plot(vv[side], ft[side], "-", color="0.5", lw=0.8, alpha=0.7,
                        label="true (simulated plant)" if side[-1] else None)
        ax.axhline(0, color="0.8", lw=0.5)
        ax.axvline(0, color="0.8", lw=0.5)
        ax.set_title(f"joint {j}")
        ax.set_xlabel("velocity (rad/s)")
        ax.set_ylabel("friction torque (N m)")
        ax.grid(alpha=0.3)
    if len(axes):
        axes[0].legend(fontsize=7, loc="upper left")
    return save(fig, path)


def segments_figure(t_s: np.ndarray, q: np.ndarray, ident: FrictionIdentification, path: Path) -> Path:
    """Measured position of each swept joint with the constant-velocity stages used (thesis Fig. 4.1)."""
    joints = sorted(ident.map["joint"].unique())
    fig, axes = joint_grid(len(joints), "Segment detection: measured position, constant-velocity stages used")
    for ax, j in zip(axes, joints):
        m = ident.map[ident.map["joint"] == j]
        acc = m[m["accepted"]]
        if len(acc):
            t0, t1 = float(acc["t_start_s"].min()), float(acc["t_end_s"].max())
            pad = 0.02 * (t1 - t0 + 1)
            sel = (t_s >= t0 - 5 - pad) & (t_s <= t1 + 5 + pad)
        else:
            sel = np.ones(len(t_s), bool)
        ax.plot(t_s[sel], q[sel, j - 1], lw=0.7, color="C0")
        for _, r in acc.iterrows():
            ax.axvspan(r["t_start_s"], r["t_end_s"], color="C1", alpha=0.25, lw=0)
        ax.set_title(f"joint {j}")
        ax.set_xlabel("t (s)")
        ax.set_ylabel("q (rad)")
        ax.grid(alpha=0.3)
    return save(fig, path)


def comparison_table(pd_data: pd.DataFrame, ff_data: pd.DataFrame, thesis: bool = True) -> pd.DataFrame:
    """Rotation metrics under pd_g and pd_g_ff side by side, per joint (thesis section 4.4), with the thesis' RPE
    when ``thesis`` (the same test as the thesis')."""
    from wamctl.analysis.rotation import rotation_metrics
    a, b = rotation_metrics(pd_data), rotation_metrics(ff_data)
    joints = sorted(set(a.index) & set(b.index))
    rows = []
    for j in joints:
        ea, eb = a.loc[j, "mean_abs_error_rad"], b.loc[j, "mean_abs_error_rad"]
        rows.append({"joint": j, "mean_abs_error_pd_g_mrad": ea * 1e3, "mean_abs_error_pd_g_ff_mrad": eb * 1e3,
                     "change_pct": (eb - ea) / ea * 100 if ea else np.nan,
                     "max_abs_error_pd_g_mrad": a.loc[j, "max_abs_error_rad"] * 1e3,
                     "max_abs_error_pd_g_ff_mrad": b.loc[j, "max_abs_error_rad"] * 1e3,
                     "rpe_pd_g_pct": a.loc[j, "rpe_pct"], "rpe_pd_g_ff_pct": b.loc[j, "rpe_pct"]}
                    | ({"thesis_rpe_pd_g_pct": P.THESIS_RPE_PCT["pd_g"][j - 1],
                        "thesis_rpe_pd_g_ff_pct": P.THESIS_RPE_PCT["pd_g_ff"][j - 1]} if thesis else {}))
    return pd.DataFrame(rows).set_index("joint") if rows else pd.DataFrame()


def add_comparison(doc: Document, pd_data: pd.DataFrame, ff_data: pd.DataFrame, out_dir: Path,
                   source: str = "", controller: dict | None = None) -> pd.DataFrame:
    """Append the pd_g vs pd_g_ff section (table + error traces) to ``doc``; returns the table. ``controller``:
    the pd_g run's controller section, when known (its own gains make it another test than the thesis')."""
    from wamctl.analysis.rotation import find_rotations, thesis_test_differences
    from wamctl.report.rotation import THESIS_TEST
    differs = thesis_test_differences(pd_data, controller) + thesis_test_differences(ff_data)
    table = comparison_table(pd_data, ff_data, thesis=not differs)
    thesis_note = ("thesis_*: the thesis' RPE for the same test." if not differs else
                   f"No thesis columns: {THESIS_TEST}; these runs: {'; '.join(dict.fromkeys(differs))}.")
    doc.heading("Rotation test: PD + gravity vs PD + gravity + feed-forward friction (thesis 4.4)")
    doc.text("Each joint rotated one at a time; errors are q_ref - q over the move and the hold at the target. "
             "The feed-forward is eq. 4.3 with the identified friction model." + (f" {source}" if source else ""))
    doc.table("ff_comparison", table, "mean/max absolute position error (mrad) and RPE (%) under both "
              "controllers; change_pct < 0: the feed-forward lowers the mean error. " + thesis_note)
    if len(table):
        better = [int(j) for j in table.index if table.loc[j, "change_pct"] < 0]
        doc.text(f"The feed-forward lowers the mean absolute error on joints {better or 'none'} "
                 f"of {[int(j) for j in table.index]}.")
        doc.data["ff_comparison"] = {str(j): {"pd_g_mrad": float(table.loc[j, "mean_abs_error_pd_g_mrad"]),
                                              "pd_g_ff_mrad": float(table.loc[j, "mean_abs_error_pd_g_ff_mrad"])}
                                     for j in table.index}
        ra, rb = find_rotations(pd_data), {r.joint: r for r in find_rotations(ff_data)}
        ra = [r for r in ra if r.joint in rb]
        fig, axes = joint_grid(len(ra), "Position error q_ref - q: pd_g vs pd_g_ff")
        for ax, r in zip(axes, ra):
            for data, rr, lab in ((pd_data, r, "pd_g"), (ff_data, rb[r.joint], "pd_g_ff")):
                sl = slice(rr.i_start, rr.i_final + 1)
                t = data["t_s"].to_numpy()[sl]
                e = (data[f"q_ref_{r.joint}_rad"] - data[f"q_{r.joint}_rad"]).to_numpy()[sl] * 1e3
                ax.plot(t - t[0], e, lw=0.8, label=lab)
            ax.set_title(f"joint {r.joint}")
            ax.set_xlabel("t from move start (s)")
            ax.set_ylabel("error (mrad)")
            ax.grid(alpha=0.3)
        if len(ra):
            axes[0].legend()
        doc.figure(save(fig, Path(out_dir) / "ff_comparison_errors.png"), "position error under both controllers")
    return table


# ------------------------------------------------------------------------------------------------ documents
def friction_document(rd, ident: FrictionIdentification, out_dir: Path, title: str,
                      header: str = "", validation: tuple[pd.DataFrame, pd.DataFrame] | None = None) -> Document:
    """The identification report of one recorded sweep (``rd``: :class:`~wamctl.runs.measured.RunData`)."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    doc = Document(title)
    m = ident.map
    n_acc = int(m["accepted"].sum())
    doc.text((header + " " if header else "") +
             f"{len(rd.data)} samples; joints {sorted(int(j) for j in m['joint'].unique())}; {len(m)} moves found, "
             f"{n_acc} constant-velocity stages used, {len(m) - n_acc} left out. Friction = logged torque minus the "
             "declared rigid-body model (inverse dynamics); fits weighted by each segment's standard error "
             f"({ident.options.get('weighting', 'se')}), loss {ident.options.get('loss')}, selection by "
             f"{ident.options.get('criterion', 'bic').upper()} on {ident.options.get('folds')}-fold held-out "
             "segments.")
    doc.heading("Friction model parameters (Table 4.1 layout)")
    t41 = parameter_table(ident)
    doc.table("friction_parameters", t41, "chosen model per joint; Fc (N m) as magnitudes, sigma2 (N m s/rad); "
              "*_std: standard errors (classic models: the largest of the fit's, the jackknife's over the segments, "
              "which a single stage off by more than its scatter widens, and the segments' own standard errors "
              "carried through the fit; Stribeck: the fit's or the segments'; both with the rigid body's timing "
              "within the held torque's period, half a period, which a constant-velocity sweep cannot tell from "
              "viscous friction). Written to friction_model.yaml.")
    missing = ident.not_identified()
    if missing:
        doc.text("Not identified, so friction_model.yaml gives no friction for them (whatever reads it treats them "
                 "as frictionless): " + "; ".join(f"joint {j} ({why})" for j, why in missing.items()) + ".")
    doc.data["friction_model"] = ident.model_file()[0]
    doc.data["chosen_model"] = {str(j): ji.chosen for j, ji in ident.joints.items()}
    truth = true_friction(rd.truth, robot=rd.meta.robot)
    if truth is not None:
        rec = recovered_table(ident, truth)
        doc.heading("Identified vs true parameters (simulated plant)")
        doc.table("recovered_vs_true", rec, "true: the simulated plant's friction (run spec plant); error_pct "
                  "relative to the true value.")
        doc.data["recovered_vs_true"] = {f"{j}/{r['parameter']}": {"true": float(r["true"]),
                                                                   "identified": float(r["identified"]),
                                                                   "error_pct": float(r["error_pct"])}
                                         for j, r in rec.iterrows()}
    doc.heading("Friction-velocity maps")
    doc.figure(map_figure(ident, truth, out_dir / "friction_maps.png"),
               "friction-velocity map per joint: segment means with 95 % confidence bars, fitted models (chosen "
               "bold)" + (", true friction in grey" if truth is not None else ""))
    doc.heading("Model selection")
    sel = ident.selection_table()
    if len(sel):
        doc.data["model_selection_in_sample"] = json_map(sel.reset_index()[["joint", "model", "aic", "bic"]])
        sel = sel.reset_index().set_index("joint")[["model", "k", "n", "rmse_Nm", "cv_rmse_Nm", "aic_cv", "bic_cv",
                                                     "chosen"]]
    doc.table("model_selection", sel, "k parameters, n segments; rmse: in-sample; cv_*: k-fold held-out "
              "segments, residuals over each segment's sigma, scored as chi2 + 2k (AIC) or chi2 + k ln n (BIC). "
              f"The smallest {ident.options.get('criterion', 'bic').upper()} wins; a simpler model within 2 of "
              "it is preferred.")
    fits = {}
    for j, ji in ident.joints.items():
        fits[str(j)] = {name: est.to_dict() for name, est in ji.fits.items()}
    doc.data["fits"] = fits
    doc.heading("Segments")
    doc.figure(segments_figure(rd.t_s, rd.col("q"), ident, out_dir / "friction_segments.png"),
               "measured position; shaded: the constant-velocity stages averaged into the map")
    rej = m[~m["accepted"]][["joint", "direction", "v_cmd_rad_s", "velocity_rad_s", "reason"]]
    if len(rej):
        doc.table("rejected_segments", rej.set_index("joint"),
                  "moves without a usable constant-velocity stage and why (stick-slip, transients, too short)")
    else:
        doc.text("Every move gave a constant-velocity stage.")
    doc.data["friction_map"] = json_map(m)
    if validation is not None:
        add_comparison(doc, validation[0], validation[1], out_dir,
                       "Both runs after the sweep, on the same plant (tables validation_pd_g, validation_pd_g_ff).",
                       rd.meta.controller.model_dump())
    return doc


def json_map(m: pd.DataFrame) -> list[dict]:
    from wamctl.analysis.friction_id.identify import json_records
    return json_records(m)


def report(run_path: Path, manifest: dict, spec: dict, out_dir: Path | None = None) -> Document:
    """Report of a friction_sweep run directory (simulated, or an imported measured sweep)."""
    from wamctl.runs.measured import load_run_data
    from wamctl.runs.store import read_table

    run_path = Path(run_path)
    rd = load_run_data(run_path, reader="report", any_robot=True, controller_ok=True, stand_in=True)
    opts = dict(spec.get("identification") or {})
    ident = None
    map_file = run_path / "friction_map.csv"
    if map_file.is_file():  # the map the run's identification made from these data: refit, do not re-detect
        try:
            fmap = pd.read_csv(map_file, keep_default_na=True)
            fmap["accepted"] = fmap["accepted"].astype(bool)
            fmap["reason"] = fmap["reason"].astype(object).where(fmap["reason"].notna(), "")
            o = {"models": list(MODEL_NAMES), "folds": 5, "criterion": "bic", "loss": "linear", "weighting": "se"}
            o.update(opts)
            ident = identify_from_map(fmap, o["models"], o["folds"], o["criterion"], o["loss"], o["weighting"])
        except (KeyError, ValueError) as exc:
            log.warning("%s: not usable (%s); detecting the segments again", map_file, exc)
            ident = None
    if ident is None or not ident.joints:
        ident = identify(rd, opts)
    validation = None
    if (run_path / "validation_pd_g.parquet").is_file() and (run_path / "validation_pd_g_ff.parquet").is_file():
        validation = (read_table(run_path, "validation_pd_g"), read_table(run_path, "validation_pd_g_ff"))
    backend = (manifest.get("backend") or {}).get("name", "?")
    header = (f"Run {run_path.name}: status {manifest.get('status')}, controller "
              f"{(spec.get('controller') or {}).get('kind', rd.meta.controller.kind)}, backend {backend}.")
    if manifest.get("status") not in (None, "completed") and manifest.get("reason"):
        header += f" The run ended {manifest['status']}: {manifest['reason']}."
    return friction_document(rd, ident, Path(out_dir or run_path), f"Friction identification: "
                             f"{manifest.get('name', run_path.name)}", header, validation)


def comparison_document(pd_run: Path, ff_run: Path, out_dir: Path) -> Document:
    """pd_g vs pd_g_ff from two rotation run directories (or measured rotation runs)."""
    from wamctl.errors import DataFormatError
    from wamctl.runs.measured import load_run_data

    a, b = (load_run_data(p, reader="report", any_robot=True, controller_ok=True, stand_in=True)
            for p in (pd_run, ff_run))
    for rd, want in ((a, "pd_g"), (b, "pd_g_ff")):
        if rd.meta.controller.kind != want:
            raise DataFormatError(f"{rd.source}: controller is {rd.meta.controller.kind}, expected {want} "
                                  "(give the pd_g run first, then the pd_g_ff run)")
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    doc = Document("Feed-forward friction compensation: rotation test comparison")
    add_comparison(doc, a.data, b.data, out_dir, f"pd_g: {Path(pd_run).name}; pd_g_ff: {Path(ff_run).name}.",
                   a.meta.controller.model_dump())
    return doc
