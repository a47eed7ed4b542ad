"""The combined report of a sweep directory (points, key figures, their means per swept value), and the reader
of its index.

The index (``index.csv``) is written by :mod:`wamctl.experiments.sweep`; its fixed columns
(:data:`INDEX_COLUMNS`) and the point statuses (:data:`STATUSES`) are defined here, where the report reads
them, so that the report never imports the experiments.
"""

from __future__ import annotations

import json
from pathlib import Path

import pandas as pd

from wamctl.errors import DataFormatError
from wamctl.report.document import Document

STATUSES = ("completed", "failed", "interrupted", "pending")
INDEX_COLUMNS = ["point", "status", "attempts", "run_dir", "error", "worker", "start_unix_s", "end_unix_s",
                 "duration_s"]


def read_index(sweep_dir: str | Path) -> pd.DataFrame:
    """The index of a sweep directory as a table (one row per point)."""
    p = Path(sweep_dir) / "index.csv"
    if not p.is_file():
        raise DataFormatError(f"{sweep_dir}: not a sweep directory (no index.csv)")
    return pd.read_csv(p)


def summary_tables(idx: pd.DataFrame, params: list[str]) -> list[tuple[str, str, pd.DataFrame, str]]:
    """The result of a sweep, in a few short tables: (name, heading, table, caption) of the key figures over
    the completed points (n, mean, SD, min, max: one row per figure), then their means per value of each swept
    parameter with 2..20 distinct values. What the report shows first and ``wamctl sweep`` prints."""
    from wamctl.report.combined import spread_table

    figs = key_figure_columns(idx, params)
    ok = idx[idx["status"] == "completed"]
    out: list[tuple[str, str, pd.DataFrame, str]] = []
    if not figs or not len(ok):
        return out
    overall = spread_table(ok[figs].to_dict("records"))
    if not overall.empty:
        out.append(("summary", f"Key figures over the {len(ok)} completed points", overall,
                    "n: points with the figure; sd with n - 1; e.g. rpe_pct.j: RPE of joint j (%)"))
    for p in params:
        if 2 <= ok[p].nunique() <= 20:
            g = ok.groupby(p)[figs].mean()
            g.insert(0, "n_points", ok.groupby(p).size())
            out.append((f"by_{p}", f"Mean key figures by {p}", g,
                        f"means over the completed points with each value of {p}"))
    return out


def key_figure_columns(idx: pd.DataFrame, params: list[str]) -> list[str]:
    """The index's numeric columns that are key figures of the runs (not bookkeeping, not parameters)."""
    figs = [c for c in idx.columns if c not in set(INDEX_COLUMNS) | set(params) | {"pid"}]
    return [c for c in figs if pd.api.types.is_numeric_dtype(idx[c])]


def sweep_parameters(sweep_dir: str | Path, idx: pd.DataFrame) -> tuple[dict, list[str]]:
    """(sweep manifest, swept parameters found in the index)."""
    m = json.loads((Path(sweep_dir) / "sweep.json").read_text())
    return m, [p for p in m.get("parameters", []) if p in idx.columns]


def sweep_report(sweep_dir: str | Path) -> Document:
    """The combined report of a sweep directory: first the result (the key figures over the completed points,
    their means and SDs per value of each swept parameter with 2..20 distinct values, a figure per parameter),
    then the index and the key figures of every point."""
    d = Path(sweep_dir)
    idx = read_index(d)
    m, params = sweep_parameters(d, idx)
    counts = idx["status"].value_counts().to_dict()
    doc = Document(f"Sweep {m.get('name')}: {len(idx)} points of {m.get('kind')}")
    doc.text(f"Spec {m.get('source')}; swept: {', '.join(params) or 'nothing'}. Status: "
             + ", ".join(f"{counts.get(s, 0)} {s}" for s in STATUSES if counts.get(s, 0)) + ".")
    for i, s in enumerate(m.get("sessions", [])):
        if s.get("wall_s") is None:
            continue
        eff = s.get("efficiency")
        doc.text(f"Session {i + 1} ({s.get('start_utc')}): {s.get('ran', 0)} points run, {s.get('skipped', 0)} "
                 f"skipped as completed, {s.get('wall_s', 0):.1f} s on {s.get('n_workers')} workers "
                 f"({s.get('scheduler')}); at most {s.get('max_concurrent')} points at once"
                 + (f", workers busy {100 * eff:.0f} % of the time" if eff is not None else "")
                 + (" - interrupted" if s.get("interrupted") else "") + ".")
    doc.data["counts"] = {str(k): int(v) for k, v in counts.items()}
    figs = key_figure_columns(idx, params)
    ok = idx[idx["status"] == "completed"]
    for name, heading, table, caption in summary_tables(idx, params):     # the result first
        doc.heading(heading)
        doc.table(name, table, caption)
        if not name.startswith("by_"):
            continue
        p = name[3:]
        doc.data.setdefault("by_parameter", {})[p] = json.loads(table.to_json(orient="index"))
        sd = ok.groupby(p)[figs].std(ddof=1)
        sd.insert(0, "n_points", ok.groupby(p).size())
        doc.table(f"sd_by_{p}", sd, f"standard deviation over the completed points with each value of {p} "
                  "(empty with one point); the figure shows every point, where a mean hides groups")
        doc.data.setdefault("sd_by_parameter", {})[p] = json.loads(sd.to_json(orient="index"))
        doc.figure(_points_by_value(ok, p, figs, d / f"by_{_file_safe(p)}.png"),
                   f"each completed point's key figures against {p} (dots, spread sideways so that equal "
                   "values stay visible); bars: the mean")
    base = ["point"] + params + ["status", "attempts", "duration_s", "run_dir", "error"]
    doc.heading("Points")
    doc.table("points", idx[[c for c in base if c in idx.columns]].set_index("point"),
              "run_dir is relative to the sweep directory; each run has its own report there.", digits=3)
    if figs and len(ok):
        doc.heading("Key figures per point")
        doc.table("key_figures", ok[["point"] + params + figs].set_index("point"),
                  "numbers from each run's report (e.g. rpe_pct.j: RPE of joint j, %)")
    return doc


def _file_safe(name: str) -> str:
    return "".join(c if c.isalnum() or c in "-_" else "_" for c in name)


def _points_by_value(ok: pd.DataFrame, p: str, figs: list[str], path: Path) -> Path:
    """One panel per key figure: every point at its value of ``p`` (categories in sorted order), and the mean."""
    import numpy as np

    from wamctl.report.figures import joint_grid, save
    values = sorted(ok[p].unique(), key=lambda v: (isinstance(v, str), v))
    pos = {v: i for i, v in enumerate(values)}
    x0 = ok[p].map(pos).to_numpy(float)
    spread = (np.arange(len(ok)) % 7 - 3) * 0.04
    fig, axes = joint_grid(len(figs), f"Key figures per point against {p}")
    for ax, f in zip(axes, figs):
        y = ok[f].to_numpy(float)
        ax.plot(x0 + spread, y, "o", ms=3, alpha=0.6)
        means = ok.groupby(p)[f].mean()
        ax.hlines([means[v] for v in values], np.arange(len(values)) - 0.3, np.arange(len(values)) + 0.3,
                  colors="k", lw=1.5)
        ax.set_xticks(range(len(values)), [f"{v:g}" if isinstance(v, float) else str(v) for v in values])
        ax.set_xlabel(p)
        ax.set_ylabel(f)
        ax.grid(alpha=0.3)
    return save(fig, path)


def write_sweep_report(sweep_dir: str | Path, formats=("md", "html", "json")) -> list[Path]:
    return sweep_report(sweep_dir).write(Path(sweep_dir), "report", formats)
