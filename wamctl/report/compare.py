"""``wamctl compare``: runs of one kind side by side (issue 30): the spec differences, each report table with the
runs' values and the difference to the first run, figures overlaid (rotation error traces, friction maps, J per
iteration, HMI hand paths), and where the runs have repeated measures (an HMI block's trials) a test of the
difference with its 95 % interval."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd

from wamctl.errors import WamctlError
from wamctl.report import write_report
from wamctl.report.combined import not_a_run
from wamctl.report.document import Document
from wamctl.report.figures import joint_grid, save
from wamctl.runs.store import open_run, read_table


def _flatten(d, prefix="") -> dict:
    out = {}
    if isinstance(d, dict):
        for k, v in d.items():
            out.update(_flatten(v, f"{prefix}{k}."))
    else:
        out[prefix[:-1]] = d
    return out


def spec_differences(specs: list[dict], labels: list[str]) -> pd.DataFrame:
    """The spec keys (dotted) whose values differ between the runs, one column per run."""
    flat = [_flatten(s) for s in specs]
    keys = sorted(set().union(*flat))
    rows = [{"key": k, **{lab: json.dumps(f.get(k), default=str) for lab, f in zip(labels, flat)}}
            for k in keys if len({json.dumps(f.get(k), sort_keys=True, default=str) for f in flat}) > 1]
    return pd.DataFrame(rows, columns=["key", *labels]).set_index("key")


def side_by_side(tables: list[pd.DataFrame], labels: list[str]) -> pd.DataFrame:
    """One report table of each run, keyed by its first column: each numeric column per run (``<column>.<label>``),
    and for every run after the first its difference to the first (``<column>.Δ<label>``: label minus A)."""
    key = tables[0].columns[0]
    idx = [t.set_index(key) for t in tables if key in t.columns]
    if len(idx) != len(tables):
        return pd.DataFrame()
    numeric = [c for c in idx[0].columns if all(c in t.columns and pd.api.types.is_numeric_dtype(t[c])
                                                and not pd.api.types.is_bool_dtype(t[c]) for t in idx)]
    if any(not t.index.is_unique for t in idx):        # not keyed by its first column: rows side by side
        idx = [t.reset_index(drop=True) for t in idx]
    out = {}
    for c in numeric:
        for lab, t in zip(labels, idx):
            out[f"{c}.{lab}"] = t[c]
        for lab, t in zip(labels[1:], idx[1:]):
            out[f"{c}.Δ{lab}"] = t[c] - idx[0][c]
    return pd.DataFrame(out)


def welch(a: np.ndarray, b: np.ndarray) -> dict:
    """Welch's t-test of mean(b) - mean(a) with its 95 % interval."""
    from scipy import stats
    r = stats.ttest_ind(b, a, equal_var=False)
    ci = r.confidence_interval(0.95)
    return {"n_a": len(a), "n_b": len(b), "mean_a": float(np.mean(a)), "mean_b": float(np.mean(b)),
            "difference": float(np.mean(b) - np.mean(a)), "ci95_low": float(ci.low), "ci95_high": float(ci.high),
            "t": float(r.statistic), "p": float(r.pvalue)}


def _run_tables(runs: list[Path], name: str) -> list[pd.DataFrame] | None:
    """Each run's ``name`` (CSV), or None when a run has none."""
    paths = [r / name for r in runs]
    return [pd.read_csv(p) for p in paths] if all(p.is_file() for p in paths) else None


def _joint_overlay(tables: list[pd.DataFrame], labels: list[str], joints: list[int], title: str, curve, xlabel: str,
                   ylabel: str, path: Path, style: dict, scale=None) -> Path | None:
    """One panel per joint, one line per run: ``curve(table, j) -> (x, y)``; ``scale(ax)`` sets the axes' scales."""
    if not joints:
        return None
    fig, axes = joint_grid(len(joints), title)
    for ax, j in zip(axes, joints):
        for lab, t in zip(labels, tables):
            ax.plot(*curve(t, j), **style, label=lab)
        if scale is not None:
            scale(ax)
        ax.set_title(f"joint {j}")
        ax.set_xlabel(xlabel)
        ax.set_ylabel(ylabel)
        ax.legend(fontsize=7)
    return save(fig, path)


_POINTS = {"marker": "o", "ms": 3, "lw": 0.8}


def _rotation_overlay(runs: list[Path], labels: list[str], out_dir: Path) -> Path | None:
    datas = [read_table(r) for r in runs]
    joints = [j for j in range(1, 8) if all(f"q_{j}_rad" in d and np.ptp(d[f"q_ref_{j}_rad"]) > 0 for d in datas)]
    return _joint_overlay(datas, labels, joints, "Tracking error q_ref - q, runs overlaid",
                          lambda d, j: (d["t_s"], 1e3 * (d[f"q_ref_{j}_rad"] - d[f"q_{j}_rad"])), "t (s)",
                          "error (mrad)", out_dir / "compare_rotation_errors.png", {"lw": 0.8})


def _friction_overlay(runs: list[Path], labels: list[str], out_dir: Path) -> Path | None:
    maps = _run_tables(runs, "friction_map.csv")
    if maps is None:
        return None

    def curve(m, j):
        mj = m[(m["joint"] == j) & m["accepted"].astype(bool)].sort_values("velocity_rad_s")
        return mj["velocity_rad_s"], mj["friction_Nm"]
    return _joint_overlay(maps, labels, sorted(set.intersection(*[set(m["joint"]) for m in maps])),
                          "Friction-velocity maps, runs overlaid", curve, "velocity (rad/s)", "friction (N m)",
                          out_dir / "compare_friction_maps.png", _POINTS,
                          lambda ax: ax.set_xscale("symlog", linthresh=1e-2))


def _ift_overlay(runs: list[Path], labels: list[str], out_dir: Path) -> Path | None:
    """J per iteration of each tuned joint, one line per run (the plant's J, log scale)."""
    its = _run_tables(runs, "iterations.csv")
    if its is None:
        return None

    def curve(t, j):
        tj = t[(t["joint"] == j) & t["J"].notna()].sort_values("iteration")
        return tj["iteration"], tj["J"]
    return _joint_overlay(its, labels, sorted(set.intersection(*[set(t["joint"].dropna().astype(int)) for t in its])),
                          "J per iteration, runs overlaid", curve, "iteration", "J (rad²)",
                          out_dir / "compare_ift_J.png", _POINTS, lambda ax: ax.set_yscale("log"))


def _hmi_overlay(runs: list[Path], labels: list[str], out_dir: Path) -> Path | None:
    """The hand's path of every trial seen from above, one colour per run."""
    import matplotlib.pyplot as plt
    paths = []
    for r in runs:
        p = r / "trajectory.parquet"
        if not p.is_file():
            return None
        paths.append(pd.read_parquet(p, columns=["trial", "hand_x_m", "hand_y_m"]))
    fig, ax = plt.subplots(figsize=(7.0, 6.0))
    for i, (lab, d) in enumerate(zip(labels, paths)):
        for k, (_, g) in enumerate(d.groupby("trial")):
            ax.plot(g["hand_y_m"], g["hand_x_m"], lw=0.9, alpha=0.8, color=f"C{i}", label=lab if k == 0 else None)
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("y (m)")
    ax.set_ylabel("x (m)")
    ax.set_title("Hand paths of every trial, runs overlaid (seen from above)")
    ax.legend(fontsize=8)
    return save(fig, out_dir / "compare_hmi_paths.png")


# the figure each kind's runs are overlaid in
_OVERLAYS = {"rotation": _rotation_overlay, "friction_sweep": _friction_overlay, "ift": _ift_overlay,
             "hmi_block": _hmi_overlay}


def compare(run_dirs: list[Path], out_dir: Path) -> Document:
    """The comparison document of ``run_dirs`` (figures written into ``out_dir``). Paths that are not run
    directories (``runs/index.html``, an earlier comparison's folder, a combined report's, among ``runs/*``) are
    skipped with why, in ``doc.data["skipped"]``, as ``wamctl report`` skips them. WamctlError (one line, exit
    2) for fewer than two runs left or runs of different kinds."""
    runs, skipped = [], []
    for r in map(Path, run_dirs):
        why = not_a_run(r)
        if why is None:
            runs.append(r)
        else:
            skipped.append((r, why))
    if len(runs) < 2:
        raise WamctlError("compare: give two or more run directories"
                          + "".join(f"; skipped {p} ({why})" for p, why in skipped))
    opened = [open_run(r) for r in runs]
    kinds = [m.get("kind") for m, _ in opened]
    if len(set(kinds)) > 1:
        raise WamctlError("compare: runs of different kinds (" + ", ".join(f"{r.name}: {k}" for r, k in
                                                                          zip(runs, kinds)) + "); compare one kind")
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    labels = [chr(ord("A") + i) if i < 26 else str(i) for i in range(len(runs))]
    doc = Document(f"{kinds[0]}: {len(runs)} runs compared")
    doc.table("runs", pd.DataFrame({"run": labels, "name": [m.get("name") for m, _ in opened],
                                    "status": [m.get("status") for m, _ in opened],
                                    "directory": [r.name for r in runs]}))
    diffs = spec_differences([s for _, s in opened], labels)
    doc.heading("Spec differences")
    if len(diffs):
        doc.table("spec differences", diffs)
    else:
        doc.text("The specs are the same.")
    reports = []
    for r in runs:
        p = r / "report.json"
        reports.append(json.loads(p.read_text()) if p.is_file() else write_report(r).to_json())
    doc.data["runs"] = [str(r) for r in runs]
    doc.data["skipped"] = [{"path": str(p), "why": why} for p, why in skipped]
    for name in reports[0].get("tables", {}):
        if not all(name in rep.get("tables", {}) for rep in reports):
            continue
        frames = [pd.DataFrame(rep["tables"][name]) for rep in reports]
        if not all(len(f) and len(f.columns) for f in frames):
            continue
        sbs = side_by_side(frames, labels)
        if len(sbs.columns):
            doc.heading(name)
            doc.table(name, sbs, "each run's value (.A, .B, ...) and its difference to run A (.ΔB = B - A)")
    tests = {}
    if kinds[0] == "hmi_block" and all((r / "trials.csv").is_file() for r in runs):
        trials = [pd.read_csv(r / "trials.csv") for r in runs]
        for lab, t in zip(labels[1:], trials[1:]):
            a, b = trials[0]["time_s"].dropna().to_numpy(float), t["time_s"].dropna().to_numpy(float)
            if len(a) > 1 and len(b) > 1:
                tests[f"time_s {lab} - A"] = welch(a, b)
        if tests:
            doc.heading("Execution time: the difference tested")
            doc.table("time difference (Welch t-test)", pd.DataFrame(tests).T,
                      "mean of the later run minus the first run's, with its 95 % interval")
    doc.data["tests"] = tests
    overlay = _OVERLAYS.get(kinds[0])
    fig = overlay(runs, labels, out_dir) if overlay is not None else None
    if fig is not None:
        doc.figure(fig, fig.stem.replace("_", " "))
    return doc
