"""Rotation report: per-joint RPE (eq. 3.2) and errors, error traces and reference-vs-measured plots, with the
thesis' own RPE figures beside ours when the test is one the thesis ran (controller, mode, 0.5 rad at 0.083 rad/s,
libbarrett's gains); otherwise the caption says what differs."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from wamctl.analysis.rotation import find_rotations, rotation_metrics, thesis_test_differences
from wamctl.model import params as P
from wamctl.report.document import Document
from wamctl.report.figures import joint_grid, save
from wamctl.runs.store import read_table

THESIS_TEST = ("the thesis rotated each joint 0.5 rad at 0.083 rad/s under libbarrett's gains (PD + gravity one at a "
               "time and all together, friction feed-forward one at a time)")


def thesis_column(data: pd.DataFrame, spec: dict) -> tuple[np.ndarray | None, str]:
    """The thesis RPE figures comparable with this run, ``(figures, caption)``: ``figures`` None when the
    thesis ran no such test, and the caption says what differs."""
    ctl = spec.get("controller") or {}
    kind = ctl.get("kind", "pd_g")
    mode = (spec.get("rotation") or {}).get("mode", "one_at_a_time")
    key = {("pd_g", "one_at_a_time"): "pd_g", ("pd_g", "all_together"): "pd_g_all",
           ("pd_g_ff", "one_at_a_time"): "pd_g_ff"}.get((kind, mode))
    differs = ([] if key else [f"controller {kind}, {mode.replace('_', ' ')}"]) + thesis_test_differences(data, ctl)
    if differs:
        return None, f"No thesis column: {THESIS_TEST}; this run: {'; '.join(differs)}."
    return P.THESIS_RPE_PCT[key], "thesis_rpe_pct: the thesis' figures for the same test."


def rotation_table(data: pd.DataFrame, spec: dict) -> pd.DataFrame:
    m = rotation_metrics(data)
    figures, _ = thesis_column(data, spec)
    if figures is not None and len(m):
        m["thesis_rpe_pct"] = [figures[j - 1] for j in m.index]
    return m


def report(run_path: Path, manifest: dict, spec: dict, out_dir: Path | None = None) -> Document:
    out_dir = Path(out_dir or run_path)
    data = read_table(run_path)
    table = rotation_table(data, spec)
    ctl = (spec.get("controller") or {}).get("kind", "?")
    doc = Document(f"Rotation test: {manifest.get('name', run_path.name)}")
    doc.text(f"Run {run_path.name}: status {manifest.get('status')}, controller {ctl}, backend "
             f"{(manifest.get('backend') or {}).get('name', manifest.get('source', '?'))}, "
             f"{len(data)} samples.")
    if manifest.get("status") != "completed" and manifest.get("reason"):
        doc.text(f"The run ended {manifest['status']}: {manifest['reason']}.")
    doc.heading("Relative position error at the end of each move (eq. 3.2)")
    doc.table("rotation", table, "RPE = |final error / amplitude| x 100 %; errors are q_ref - q, rad."
              + " " + thesis_column(data, spec)[1])
    doc.data["rpe_pct"] = {str(j): float(v) for j, v in table["rpe_pct"].items()}
    rots = find_rotations(data)
    if rots:
        t = data["t_s"].to_numpy()
        fig, axes = joint_grid(len(rots), "Position error q_ref - q")
        for ax, r in zip(axes, rots):
            sl = slice(r.i_start, r.i_final + 1)
            ax.plot(t[sl], (data[f"q_ref_{r.joint}_rad"] - data[f"q_{r.joint}_rad"]).to_numpy()[sl] * 1e3)
            ax.set_title(f"joint {r.joint}")
            ax.set_ylabel("error (mrad)")
            ax.set_xlabel("t (s)")
            ax.grid(alpha=0.3)
        doc.figure(save(fig, out_dir / "rotation_errors.png"), "position error during each joint's move")
        fig, axes = joint_grid(len(rots), "Reference and measured position")
        for ax, r in zip(axes, rots):
            sl = slice(r.i_start, r.i_final + 1)
            ax.plot(t[sl], data[f"q_ref_{r.joint}_rad"].to_numpy()[sl], label="reference")
            ax.plot(t[sl], data[f"q_{r.joint}_rad"].to_numpy()[sl], "--", label="measured")
            ax.set_title(f"joint {r.joint}")
            ax.set_ylabel("q (rad)")
            ax.grid(alpha=0.3)
        axes[0].legend()
        doc.figure(save(fig, out_dir / "rotation_positions.png"), "reference vs measured position")
    return doc
