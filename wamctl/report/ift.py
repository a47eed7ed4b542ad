"""IFT report: the iteration table in the layout of thesis Table 5.1, the gains, the rejected proposals,
convergence plots, the error of the first experiment per iteration (Fig. 5.1) and the strategy comparison of
section 5.4 (RPE per joint beside the thesis' figures, error plots side by side as Fig. 5.3)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd

from wamctl.analysis.rotation import rotation_metrics, thesis_test_differences
from wamctl.model import params as P
from wamctl.report.document import Document
from wamctl.report.figures import joint_grid, save
from wamctl.report.rotation import THESIS_TEST
from wamctl.runs.store import read_events
from wamctl.specs.ift import GAIN_UNITS

# The IFT run directory's tables (written by wamctl.experiments.ift, read here)
ITERATIONS_TABLE = "iterations"         # .parquet and .csv: one row per joint and iteration
STATE_FILE = "ift_state.json"           # each joint's tuning state after the last completed iteration


def iteration_file(k: int, part: str) -> str:
    """``iter-NNN-{exp1,exp2,check}.parquet``: the experiments of iteration ``k``."""
    return f"iter-{int(k):03d}-{part}.parquet"


def comparison_file(strategy: str) -> str:
    """``compare-{pd_g,pd_g_ff,pid}.parquet``: the task under one strategy of the comparison (section 5.4)."""
    return f"compare-{strategy}.parquet"


# Thesis Table 5.1: J(rho) per joint; columns initial PID, iterations 1 (BFGS) and 2-5 (Newton-Gauss); blank
# cells are NaN. Copied from the thesis (chapter 5, Table 5.1); its J is in the thesis' own units.
THESIS_TABLE_5_1 = pd.DataFrame(
    [[0.0715, 0.0321, 0.0296, np.nan, np.nan, np.nan],
     [0.5837, np.nan, 0.6142, 0.5933, np.nan, np.nan],
     [0.2343, 0.0105, 0.0132, np.nan, 0.4753, 0.4585],
     [1.5818, 0.6169, 0.5765, 0.5235, np.nan, np.nan],
     [0.3137, 0.1705, np.nan, np.nan, np.nan, np.nan],
     [0.3511, 0.1352, np.nan, np.nan, np.nan, np.nan],
     [2.0517, 0.9095, 0.8613, np.nan, np.nan, np.nan]],
    index=pd.Index(range(1, 8), name="joint"), columns=["initial", "1", "2", "3", "4", "5"])

# Thesis section 5.4: RPE (%) of the final position under the tuned PID (joint 1..7). The PD + gravity and
# PD + gravity + feed-forward figures are the same as chapters 3 and 4 (wamctl.model.params.THESIS_RPE_PCT).
THESIS_RPE_PID_PCT = np.array([0.0003, 0.0, 0.0004, 0.0003, 0.0003, 0.0003, 0.0007])
THESIS_RPE = {"pd_g": P.THESIS_RPE_PCT["pd_g"], "pd_g_ff": P.THESIS_RPE_PCT["pd_g_ff"], "pid": THESIS_RPE_PID_PCT}
STRATEGY_LABELS = {"pd_g": "PD + gravity", "pd_g_ff": "PD + gravity + ff friction", "pid": "tuned PID"}


def read_iterations(run_path: Path) -> pd.DataFrame:
    p = Path(run_path) / f"{ITERATIONS_TABLE}.parquet"
    if p.is_file():
        return pd.read_parquet(p)
    p = Path(run_path) / f"{ITERATIONS_TABLE}.csv"
    return pd.read_csv(p) if p.is_file() else pd.DataFrame()


def plant_rows(it: pd.DataFrame) -> pd.DataFrame:
    """Rows evaluated on the plant (initial, accepted, rejected by the plant)."""
    return it[it["status"].isin(["initial", "accepted", "plant_rejected"])]


def table_5_1(it: pd.DataFrame) -> pd.DataFrame:
    """J on the plant per joint (rows) and iteration (columns ``initial``, ``1``, ``2``, ...), as Table 5.1.
    A proposal the plant rejected (J did not decrease) is shown too; :func:`method_table` marks which."""
    pr = plant_rows(it)
    if pr.empty:
        return pd.DataFrame()
    wide = pr.pivot_table(index="joint", columns="iteration", values="J", aggfunc="first")
    wide.columns = ["initial" if c == 0 else str(int(c)) for c in wide.columns]
    return wide


def method_table(it: pd.DataFrame) -> pd.DataFrame:
    """Method and gamma behind each cell of :func:`table_5_1` ("bfgs 0.5", "gauss_newton 0.1 (rejected)")."""
    pr = plant_rows(it)
    if pr.empty:
        return pd.DataFrame()
    lab = pr.assign(label=[("PID" if r.status == "initial" else f"{r.method} {r.gamma:g}")
                           + (" (J rose: kept previous)" if r.status == "plant_rejected" else "")
                           for r in pr.itertuples()])
    wide = lab.pivot_table(index="joint", columns="iteration", values="label", aggfunc="first").fillna("")
    wide.columns = ["initial" if c == 0 else str(int(c)) for c in wide.columns]
    return wide


def gains_table(it: pd.DataFrame) -> pd.DataFrame:
    """Per joint: initial and tuned gains, J initial and final (accepted), their ratio, plant experiments."""
    rows = []
    for j, g in it.groupby("joint"):
        ini = g[g["status"] == "initial"].iloc[0]
        acc = g[g["status"].isin(["initial", "accepted"])].sort_values("iteration").iloc[-1]
        rows.append({"joint": int(j), "kp_initial": ini.kp, "kd_initial": ini.kd, "ki_initial": ini.ki,
                     "kp_tuned": acc.kp, "kd_tuned": acc.kd, "ki_tuned": acc.ki, "J_initial": ini.J,
                     "J_tuned": acc.J, "J_ratio": acc.J / ini.J if ini.J else np.nan,
                     "accepted": int((g["status"] == "accepted").sum()),
                     "plant_experiments": int(g["status"].isin(["initial", "accepted", "plant_rejected"]).sum()),
                     "model_rejections": int((g["status"] == "model_rejected").sum())})
    return pd.DataFrame(rows).set_index("joint") if rows else pd.DataFrame()


GAINS = ("kp", "kd", "ki")


def gains_long(gt: pd.DataFrame) -> pd.DataFrame:
    """:func:`gains_table`'s gains one row per joint and gain, with the gain's unit: initial, tuned, tuned /
    initial (the table fits 80 columns and each value stands beside its unit)."""
    rows = [{"joint": int(j), "gain": g, "unit": GAIN_UNITS[g], "initial": float(r[f"{g}_initial"]),
             "tuned": float(r[f"{g}_tuned"]),
             "x_initial": float(r[f"{g}_tuned"]) / float(r[f"{g}_initial"]) if r[f"{g}_initial"] else np.nan}
            for j, r in gt.iterrows() for g in GAINS]
    return pd.DataFrame(rows).set_index(["joint", "gain"]) if rows else pd.DataFrame()


def read_state(run_path: Path) -> dict:
    """The run's ``ift_state.json`` (each joint's gains, J and gradient after the last completed iteration), or
    {} when there is none or it cannot be read."""
    try:
        return json.loads((Path(run_path) / STATE_FILE).read_text())
    except (OSError, ValueError):
        return {}


def bounds_table(it: pd.DataFrame, spec: dict, state: dict | None = None) -> pd.DataFrame:
    """The tuned gains that ended at a bound of ``ift.bounds`` (within 0.1 %): joint, gain, tuned value, which
    bound and its value, the tuned value over the initial one, and ``J_falls_beyond``: whether the gradient of J
    at the tuned gains (from ``state``, the run's ift_state.json) points beyond the bound, i.e. J would still fall
    there (None when unknown). Empty when none did (or the spec's bounds cannot be rebuilt)."""
    from wamctl.errors import WamctlError
    from wamctl.specs import parse_spec
    from wamctl.specs.ift import gain_bounds

    try:
        lo, hi = gain_bounds(parse_spec(spec, "spec.yaml"))
    except (WamctlError, ValueError, TypeError):
        return pd.DataFrame()
    joints = (state or {}).get("joints") or {}
    rows = []
    for joint, r in gains_table(it).iterrows():
        st = joints.get(str(joint)) or {}
        grad, rho = st.get("gradient"), st.get("rho")
        for i, g in enumerate(GAINS):
            v, v0 = float(r[f"{g}_tuned"]), float(r[f"{g}_initial"])
            for side, b in (("upper", hi[joint - 1, i]), ("lower", lo[joint - 1, i])):
                if abs(v - b) <= 1e-3 * max(abs(b), 1e-12) or v == b:
                    known = grad is not None and rho is not None and np.isclose(rho[i], v, rtol=1e-9, atol=0)
                    falls = (grad[i] < 0 if side == "upper" else grad[i] > 0) if known else None
                    rows.append({"joint": int(joint), "gain": g, "unit": GAIN_UNITS[g], "tuned": v, "bound": side,
                                 "bound_value": float(b), "x_initial": v / v0 if v0 else np.nan,
                                 "J_falls_beyond": None if falls is None else bool(falls)})
                    break
    return pd.DataFrame(rows).set_index("joint") if rows else pd.DataFrame()


def joint_list(joints) -> str:
    """Joints as a short list with ranges: ``[1, 2, 3, 4, 7]`` -> ``"1-4, 7"``."""
    js = sorted({int(j) for j in joints})
    parts: list[list[int]] = []
    for j in js:
        if parts and j == parts[-1][-1] + 1:
            parts[-1].append(j)
        else:
            parts.append([j])
    return ", ".join(f"{p[0]}-{p[-1]}" if len(p) > 2 else ", ".join(map(str, p)) for p in parts)


def bounds_message(bt: pd.DataFrame) -> str:
    """:func:`bounds_table` in one sentence (two lines at 80 columns): the gains at a bound with J still falling
    beyond it, which the bound chose rather than J. The gains at a bound beyond which J rises are left to the
    table; those whose gradient is unknown (no ift_state.json) are named as at the bound. '' when there are
    none."""
    if bt.empty:
        return ""
    flat = bt.reset_index()
    falls = flat["J_falls_beyond"]
    still, unknown = flat[falls.eq(True)], flat[falls.isna()]

    def listing(rows: pd.DataFrame) -> str:
        out = []
        for side, at_side in rows.groupby("bound", sort=False):
            parts = []
            for g in GAINS:
                js = at_side.loc[at_side["gain"] == g, "joint"]
                if len(js):
                    label = "" if out or parts else ("joint " if len(js) == 1 else "joints ")
                    parts.append(f"{g} ({label}{joint_list(js)})")
            out.append(f"the {side} bound of " + ", ".join(parts))
        return "; ".join(out)
    if len(still):
        return f"J still fell at {listing(still)}: the bound, not J, chose these gains (see ift.bounds)."
    if len(unknown):
        return f"gains at {listing(unknown)}: J may still fall beyond; check ift.bounds."
    return ""


def _stopped_text(manifest: dict) -> str:
    """For a run that did not complete: ``interrupted after iteration N`` (or ``failed ...``), '' otherwise."""
    status = manifest.get("status")
    if status in (None, "completed"):
        return ""
    last = (manifest.get("ift") or {}).get("last_completed_iteration")
    if last is None or int(last) < 0:
        return f"{status} before iteration 0 completed"
    return f"{status} after iteration {int(last)}"


def schedule_table(it: pd.DataFrame, spec: dict) -> pd.DataFrame:
    """Per stage of ``ift.schedule``: method, gamma, and per tuned joint the iterations it gave that the plant
    accepted (rows: stages, 1-based)."""
    stages = ((spec.get("ift") or {}).get("schedule")) or []
    tuned = it[it["status"] != "initial"]
    joints = sorted(int(j) for j in it["joint"].unique())
    rows = []
    for k, st in enumerate(stages):
        row = {"stage": k + 1, "method": st.get("method"), "gamma": st.get("gamma")}
        at = tuned[tuned["stage"] == k]
        for j in joints:
            row[f"joint_{j}"] = int(((at["joint"] == j) & (at["status"] == "accepted")).sum())
        row["tried"] = int(len(at))
        rows.append(row)
    return pd.DataFrame(rows).set_index("stage") if rows else pd.DataFrame()


def _flag_gains_and_stages(doc: Document, it: pd.DataFrame, spec: dict, manifest: dict, state: dict) -> None:
    """Say how the tuning ended: interrupted or failed after which iteration, or which gains ended at a bound and
    whether J still fell beyond it; and which stages of the schedule were never used."""
    bt = bounds_table(it, spec, state)
    doc.data["gains_at_bounds"] = [{"joint": int(j), **r} for j, r in bt.reset_index().set_index("joint").iterrows()
                                   ] if len(bt) else []
    stopped = _stopped_text(manifest)
    if stopped:
        doc.warning(f"{stopped}: the gains are those accepted so far, not tuned ones; continue with "
                    f"wamctl tune-ift SPEC --resume RUN_DIR.")
    if len(bt):
        doc.table("ift_gains_at_bounds", bt, "Gains within 0.1 % of a bound of ift.bounds"
                  + (" so far" if stopped else "") + " (defaults: kp and kd in [0.5, 4] x their start, ki in "
                  "[0, ki_max_per_s x the starting kp]); x_initial = tuned / initial; J_falls_beyond: the gradient of "
                  "J at these gains points beyond the bound (J would still fall there).")
        msg = bounds_message(bt)
        if msg and not stopped:
            doc.warning(msg)
    done = {int(j): st.get("done_reason", "") for j, st in (state.get("joints") or {}).items() if st.get("done")}
    capped = [j for j, why in done.items() if why.startswith("max_iterations")]
    if capped and not stopped:
        doc.text(f"Stopped by max_iterations ({spec.get('ift', {}).get('max_iterations')}), not because J stopped "
                 f"falling: "
                 f"{'joint' if len(capped) == 1 else 'joints'} {joint_list(capped)}.")
    st = schedule_table(it, spec)
    if len(st):
        doc.table("ift_schedule", st, "Iterations accepted on the plant per joint for each stage of ift.schedule; "
                  "tried: proposals made in the stage (accepted or rejected).")
        unused = [f"{k} ({r['method']} gamma={r['gamma']:g})" for k, r in st.iterrows() if r["tried"] == 0]
        idle = [f"{k} ({r['method']} gamma={r['gamma']:g})" for k, r in st.iterrows()
                if r["tried"] > 0 and not any(r[c] for c in st.columns if c.startswith("joint_"))]
        if unused:
            doc.text(f"Stage{'s' if len(unused) > 1 else ''} {', '.join(unused)} of the schedule "
                     f"{'were' if len(unused) > 1 else 'was'} never used: every joint stopped before reaching it.")
        if idle:
            doc.text(f"Stage{'s' if len(idle) > 1 else ''} {', '.join(idle)} gave no accepted iteration.")
        doc.data["unused_stages"] = [int(k) for k, r in st.iterrows() if r["tried"] == 0]


def comparison_table(run_path: Path) -> tuple[pd.DataFrame, list[str]]:
    """RPE (%) of the final position per joint under each strategy, with the thesis' figures when the task is
    the thesis' (0.5 rad at 0.083 rad/s); and how the task differs from it (empty: the same)."""
    out = {}
    differs: list[str] = []
    for s in THESIS_RPE:
        p = Path(run_path) / comparison_file(s)
        if not p.is_file():
            continue
        df = pd.read_parquet(p)
        for joint, part in df.groupby("joint"):
            part = part.drop(columns="joint").reset_index(drop=True)
            differs += thesis_test_differences(part)
            m = rotation_metrics(part)
            if int(joint) in m.index:
                out.setdefault(int(joint), {})[f"rpe_{s}_pct"] = float(m.loc[int(joint), "rpe_pct"])
                out[int(joint)][f"max_abs_error_{s}_rad"] = float(m.loc[int(joint), "max_abs_error_rad"])
    if not out:
        return pd.DataFrame(), []
    t = pd.DataFrame.from_dict(out, orient="index").sort_index()
    t.index.name = "joint"
    differs = list(dict.fromkeys(differs))
    for s, v in THESIS_RPE.items():
        if f"rpe_{s}_pct" in t and not differs:
            t[f"thesis_rpe_{s}_pct"] = [v[j - 1] for j in t.index]
    order = [c for s in THESIS_RPE for c in (f"rpe_{s}_pct", f"thesis_rpe_{s}_pct") if c in t]
    return t[order + [c for c in t.columns if c not in order]], differs


# ------------------------------------------------------------------------------------------------ figures
def _convergence_figure(it: pd.DataFrame, path: Path) -> Path:
    joints = sorted(it["joint"].unique())
    fig, axes = joint_grid(len(joints), "IFT convergence: J on the plant per iteration")
    for ax, j in zip(axes, joints):
        g = it[it["joint"] == j]
        ok = g[g["status"].isin(["initial", "accepted"])].sort_values("iteration")
        bad = g[g["status"] == "plant_rejected"]
        ax.semilogy(ok["iteration"], ok["J"], "o-", label="accepted")
        if len(bad):
            ax.semilogy(bad["iteration"], bad["J"], "x", color="C3", ms=8, label="J rose (kept previous)")
        mod = g[g["status"] == "model_rejected"]
        if len(mod):
            ax.semilogy(mod["iteration"], np.clip(mod["J_model"].replace(np.inf, np.nan), 1e-300, None), "|",
                        color="C7", ms=10, label="rejected on the model")
        ax.set_title(f"joint {j}")
        ax.set_xlabel("iteration")
        ax.set_ylabel("J (rad^2)")
        ax.grid(alpha=0.3, which="both")
    axes[0].legend(fontsize=7)
    return save(fig, path)


def _gains_figure(it: pd.DataFrame, path: Path) -> Path:
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(1, 3, figsize=(12, 3.5))
    acc = it[it["status"].isin(["initial", "accepted"])].sort_values("iteration")
    for name, ax in zip(("kp", "kd", "ki"), axes):
        for j, g in acc.groupby("joint"):
            ax.semilogy(g["iteration"], np.clip(g[name].to_numpy(), 1e-6, None), "o-", label=f"joint {j}")
        ax.set_title(f"{name} (accepted)")
        ax.set_xlabel("iteration")
        ax.grid(alpha=0.3, which="both")
    axes[0].legend(fontsize=7)
    return save(fig, path)


def _errors_figure(run_path: Path, it: pd.DataFrame, path: Path) -> Path | None:
    """Fig. 5.1: the first experiment's position error at the initial, an intermediate and the final accepted
    iteration of each joint."""
    joints = sorted(it["joint"].unique())
    fig, axes = joint_grid(len(joints), "Position error q_ref - q of the first experiment (Fig. 5.1)")
    cache: dict[int, pd.DataFrame] = {}
    drew = False
    for ax, j in zip(axes, joints):
        acc = it[(it["joint"] == j) & it["status"].isin(["initial", "accepted"])].sort_values("iteration")
        its = list(acc["iteration"])
        pick = sorted({its[0], its[len(its) // 2], its[-1]}) if its else []
        for k in pick:
            if k not in cache:
                p = Path(run_path) / iteration_file(k, "exp1")
                cache[k] = pd.read_parquet(p) if p.is_file() else pd.DataFrame()
            d = cache[k]
            if d.empty:
                continue
            d = d[d["joint"] == j]
            e = (d[f"q_ref_{j}_rad"] - d[f"q_{j}_rad"]).to_numpy()
            ax.plot(d["t_s"].to_numpy(), e * 1e3, lw=0.8, label="initial" if k == 0 else f"iteration {int(k)}")
            drew = True
        ax.set_title(f"joint {j}")
        ax.set_ylabel("error (mrad)")
        ax.set_xlabel("t (s)")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    if not drew:
        import matplotlib.pyplot as plt
        plt.close(fig)
        return None
    return save(fig, path)


def _comparison_figure(run_path: Path, path: Path) -> Path | None:
    """Fig. 5.3: per joint (rows) the error under each strategy (columns), same y scale per row."""
    import matplotlib.pyplot as plt
    data = {s: pd.read_parquet(Path(run_path) / comparison_file(s)) for s in THESIS_RPE
            if (Path(run_path) / comparison_file(s)).is_file()}
    if not data:
        return None
    joints = sorted(next(iter(data.values()))["joint"].unique())
    fig, axes = plt.subplots(len(joints), len(data), figsize=(12, 1.9 * len(joints) + 0.8), squeeze=False,
                             sharey="row")
    fig.suptitle("Position error q_ref - q under the three strategies (Fig. 5.3)")
    for r, j in enumerate(joints):
        for c, (s, df) in enumerate(data.items()):
            d = df[df["joint"] == j]
            ax = axes[r, c]
            ax.plot(d["t_s"].to_numpy(), (d[f"q_ref_{j}_rad"] - d[f"q_{j}_rad"]).to_numpy() * 1e3, lw=0.8)
            ax.grid(alpha=0.3)
            if r == 0:
                ax.set_title(STRATEGY_LABELS[s])
            if c == 0:
                ax.set_ylabel(f"joint {j}\nerror (mrad)")
            if r == len(joints) - 1:
                ax.set_xlabel("t (s)")
    return save(fig, path)


# ------------------------------------------------------------------------------------------------ report
def report(run_path: Path, manifest: dict, spec: dict, out_dir: Path | None = None) -> Document:
    run_path = Path(run_path)
    out_dir = Path(out_dir or run_path)
    out_dir.mkdir(parents=True, exist_ok=True)
    s = spec.get("ift") or {}
    it = read_iterations(run_path)
    info = manifest.get("ift") or {}
    doc = Document(f"Iterative feedback tuning: {manifest.get('name', run_path.name)}")
    plant = s.get("plant") or {}
    fx = ", ".join(k for k, v in ((spec.get("plant") or {}).get("effects") or {}).items() if v) or "none"
    doc.text(f"Run {run_path.name}: status {manifest.get('status')}"
             + (f" ({manifest.get('reason')})" if manifest.get("reason") else "")
             + f"; joints {s.get('joints')}; first experiment on "
             + (f"the {spec.get('backend', {}).get('kind')} backend (plant effects: {fx})"
                if plant.get("source", "backend") == "backend" else f"{len(plant.get('runs') or [])} measured runs")
             + f"; second experiment ({s.get('second_experiment')}) on the model; J on "
             f"{s.get('objective_signal')} positions, compared at {s.get('stop_digits')} digits. "
             f"{info.get('plant_experiments', '?')} plant experiments, {info.get('model_experiments', '?')} model "
             f"simulations, {info.get('last_completed_iteration', '?')} as the last completed iteration "
             f"(phase {info.get('phase', '?')}).")
    sched = ", ".join(f"{st['method']} gamma={st['gamma']}" + (f" x{st['iterations']}" if st.get("iterations") else "")
                      for st in s.get("schedule") or [])
    doc.text(f"Schedule: {sched}. Each proposal was simulated on the model first; rejected proposals are listed "
             f"below and never ran on the plant.")
    if it.empty:
        doc.text("No iteration completed.")
        return doc
    doc.heading("Objective function J per iteration (layout of thesis Table 5.1)")
    t51 = table_5_1(it)
    doc.table("ift_J", t51, "J = 1/(2N) sum (y - r)^2 on the plant, rad^2, per joint and iteration; an iteration "
              "whose J did not decrease kept the previous gains (see the method table).", digits=4)
    doc.heading("Method and step per iteration")
    doc.table("ift_methods", method_table(it), "Hessian method and step gamma that produced each iteration's gains.")
    doc.heading("Thesis Table 5.1 (for comparison)")
    doc.table("thesis_table_5_1", THESIS_TABLE_5_1, "The thesis' Table 5.1 (real WAM, its own units) for "
              "comparison: initial PID, BFGS iteration 1, Newton-Gauss iterations 2-5.", digits=4)
    gt = gains_table(it)
    doc.heading("Gains")
    doc.table("ift_gains", gains_long(gt), "Initial (the PD gains, ki = kd/10) and tuned gains; x_initial = tuned / "
              "initial.", digits=4)
    doc.table("ift_J_change", gt[["J_initial", "J_tuned", "J_ratio", "accepted", "plant_experiments",
                                  "model_rejections"]].rename(columns={"J_initial": "J_initial_rad2",
                                                                       "J_tuned": "J_tuned_rad2"}),
              "J on the plant (rad^2) at the initial and the tuned gains; J_ratio = J_tuned / J_initial; accepted "
              "iterations, experiments on the plant, proposals rejected on the model.", digits=4)
    _flag_gains_and_stages(doc, it, spec, manifest, read_state(run_path))
    doc.data["J"] = {str(j): {"initial": float(r.J_initial), "tuned": float(r.J_tuned)} for j, r in gt.iterrows()}
    doc.data["gain_units"] = dict(GAIN_UNITS)
    doc.data["tuned_gains"] = {str(j): {"kp": float(r.kp_tuned), "kd": float(r.kd_tuned), "ki": float(r.ki_tuned)}
                               for j, r in gt.iterrows()}
    ev = read_events(run_path)
    rej = ev[ev["kind"] == "ift_rejected"] if len(ev) else ev
    doc.heading("Proposals rejected on the model")
    if len(rej):
        rej = rej.assign(joint=rej["joint"].astype("Int64"))
        doc.table("ift_rejected", rej[["joint", "detail"]].reset_index(drop=True),
                  "Simulated on the model and rejected before reaching the plant (unstable, diverging error, "
                  "torque limit, or J not decreasing); gamma was then reduced.")
    else:
        doc.text("None.")
    doc.data["rejected_on_model"] = int(len(rej))
    doc.figure(_convergence_figure(it, out_dir / "ift_convergence.png"), "J per iteration (log scale)")
    doc.figure(_gains_figure(it, out_dir / "ift_gains.png"), "accepted gains per iteration")
    f = _errors_figure(run_path, it, out_dir / "ift_errors.png")
    if f is not None:
        doc.figure(f, "position error of the first experiment at the initial, an intermediate and the final "
                      "accepted gains (Fig. 5.1)")
    ct, differs = comparison_table(run_path)
    doc.heading("Strategy comparison (thesis section 5.4)")
    if ct.empty:
        doc.text("Not run (comparison disabled, measured first experiments, or the tuning did not finish).")
    else:
        doc.table("comparison_rpe", ct, "RPE = |final error / amplitude| x 100 % (eq. 3.2) at the end of the hold, "
                  "on the plant; " + ("thesis_*: the thesis' figures (chapters 3-5) for the same task on the real arm."
                                      if not differs else
                                      f"no thesis columns: {THESIS_TEST}; this task: {'; '.join(differs)}."),
                  digits=4)
        doc.data["rpe_pct"] = {s: {str(j): float(v) for j, v in ct[f"rpe_{s}_pct"].items()}
                               for s in THESIS_RPE if f"rpe_{s}_pct" in ct}
        f = _comparison_figure(run_path, out_dir / "ift_comparison_errors.png")
        if f is not None:
            doc.figure(f, "position error per joint under PD + gravity, PD + gravity + feed-forward friction and "
                          "the tuned PID (Fig. 5.3)")
    return doc
