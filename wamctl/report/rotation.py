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
from wamctl.report.loop_warnings import loop_events_of_run
from wamctl.runs.store import read_table

THESIS_TEST = ("the thesis rotated each joint 0.5 rad at 0.083 rad/s under libbarrett's gains (PD + gravity one at a "
               "time and all together, friction feed-forward one at a time)")


def thesis_column(data: pd.DataFrame, spec: dict) -> tuple[np.ndarray | None, str]:
    """The thesis RPE figures comparable with this run, ``(figures, caption)``: ``figures`` None when the
    thesis ran no such test, and the caption says what differs."""
    ctl = spec.get("controller") or {}
    robot = spec.get("robot") or "wam7"
    if robot != "wam7":
        return None, f"No thesis column: {THESIS_TEST} on the 7-DOF WAM; this run's arm is the {robot}."
    kind = ctl.get("kind", "pd_g")
    mode = (spec.get("rotation") or {}).get("mode", "one_at_a_time")
    key = {("pd_g", "one_at_a_time"): "pd_g", ("pd_g", "all_together"): "pd_g_all",
           ("pd_g_ff", "one_at_a_time"): "pd_g_ff"}.get((kind, mode))
    differs = ([] if key else [f"controller {kind}, {mode.replace('_', ' ')}"]) + thesis_test_differences(data, ctl)
    if differs:
        return None, f"No thesis column: {THESIS_TEST}; this run: {'; '.join(differs)}."
    return P.THESIS_RPE_PCT[key], "thesis_rpe_pct: the thesis' figures for the same test."


def planned_move(spec: dict) -> tuple[float | None, float]:
    """``(amplitude_rad, hold_s)`` of the spec's rotation section (None, 0 when it does not say)."""
    r = spec.get("rotation") or {}
    amp = r.get("amplitude_rad")
    return (float(amp) if amp is not None else None), float(r.get("hold_s") or 0.0)


def rotation_table(data: pd.DataFrame, spec: dict) -> pd.DataFrame:
    """Per joint: RPE and errors of each finished move (:func:`rotation_metrics` with the spec's planned move),
    the thesis' figures when comparable; a ``move`` column (``finished`` / ``not finished``) when a move did not
    finish."""
    m = rotation_metrics(data, *planned_move(spec))
    figures, _ = thesis_column(data, spec)
    if figures is not None and len(m):
        m["thesis_rpe_pct"] = [figures[j - 1] for j in m.index]
    finished = m.pop("finished").astype(bool) if "finished" in m else pd.Series(dtype=bool)
    if len(m) and not finished.all():
        m["move"] = np.where(finished, "finished", "not finished")
    return m


def _whole_run_figures(doc: Document, data: pd.DataFrame, rots, events, out_dir: Path) -> None:
    """Error and position of every joint that moves or has a warning, over the whole run: the joint's scored
    move and hold in grey, its warnings in red (a joint that sags while another moves shows where it does)."""
    rot = {r.joint: r for r in rots}
    stretches: dict[int, list[tuple[float, float]]] = {}
    for e in events:
        stretches.setdefault(e.joint, []).append((e.start_s, e.duration_s))
    joints = sorted(set(rot) | set(stretches))
    if not joints:
        return
    t = data["t_s"].to_numpy()

    def shade(ax, j):
        if j in rot:
            ax.axvspan(t[rot[j].i_start], t[rot[j].i_final], color="0.85", lw=0, zorder=0)
        for start_s, duration_s in stretches.get(j, []):
            ax.axvspan(start_s, start_s + max(duration_s, 0.01), color="tab:red", alpha=0.25, lw=0, zorder=0)
        ax.set_title(f"joint {j}" + ("" if j in rot else " (not moved)"))
        ax.set_xlabel("t (s)")
        ax.grid(alpha=0.3)

    shaded = "grey: the joint's move and hold (scored), red: a warning"
    fig, axes = joint_grid(len(joints), "Position error q_ref - q over the whole run")
    for ax, j in zip(axes, joints):
        shade(ax, j)
        ax.plot(t, (data[f"q_ref_{j}_rad"] - data[f"q_{j}_rad"]).to_numpy() * 1e3, lw=0.8)
        ax.set_ylabel("error (mrad)")
    doc.figure(save(fig, out_dir / "rotation_errors.png"), f"position error over the whole run; {shaded}")
    fig, axes = joint_grid(len(joints), "Reference and measured position over the whole run")
    for ax, j in zip(axes, joints):
        shade(ax, j)
        ax.plot(t, data[f"q_ref_{j}_rad"].to_numpy(), label="reference")
        ax.plot(t, data[f"q_{j}_rad"].to_numpy(), "--", label="measured")
        ax.set_ylabel("q (rad)")
    axes[0].legend()
    doc.figure(save(fig, out_dir / "rotation_positions.png"),
               f"reference vs measured position over the whole run; {shaded}")


def report(run_path: Path, manifest: dict, spec: dict, out_dir: Path | None = None) -> Document:
    out_dir = Path(out_dir or run_path)
    data = read_table(run_path)
    table = rotation_table(data, spec)
    events = loop_events_of_run(run_path)
    ctl = (spec.get("controller") or {}).get("kind", "?")
    doc = Document(f"Rotation test: {manifest.get('name', run_path.name)}")
    for e in events:          # the warnings block, first: what went wrong in the loop
        doc.warning(e.line)
    robot = "" if (spec.get("robot") or "wam7") == "wam7" else f"robot {spec['robot']}, "
    doc.text(f"Run {run_path.name}: status {manifest.get('status')}, {robot}controller {ctl}, backend "
             f"{(manifest.get('backend') or {}).get('name', manifest.get('source', '?'))}, "
             f"{len(data)} samples.")
    if manifest.get("status") != "completed" and manifest.get("reason"):
        doc.text(f"The run ended {manifest['status']}: {manifest['reason']}.")
    unfinished = [int(j) for j in table.index[table["move"] == "not finished"]] if "move" in table else []
    if unfinished:
        doc.text(f"Not finished: the move of joint{'s' if len(unfinished) > 1 else ''} "
                 f"{', '.join(map(str, unfinished))} (the run ended before its reference reached its end and "
                 "held it): no final error and no RPE.")
    doc.heading("Relative position error at the end of each move (eq. 3.2)")
    doc.table("rotation", table, "RPE = |final error / amplitude| x 100 %; errors are q_ref - q, rad."
              + " " + thesis_column(data, spec)[1])
    doc.data["rpe_pct"] = {str(j): float(v) for j, v in table["rpe_pct"].items() if np.isfinite(v)}
    doc.data["not_finished"] = unfinished
    _whole_run_figures(doc, data, find_rotations(data, *planned_move(spec)), events, out_dir)
    return doc
