"""Excitation reports: the design (``wamctl excite``: condition number, limits reached, one period) and the run
(limits reached by the arm itself, the condition number of the data it recorded)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from wamctl.model import params as P
from wamctl.report.document import Document
from wamctl.report.figures import joint_grid, save
from wamctl.runs.store import read_table

# the limits' names in reports, summaries and refusals; the end point is the wrist's centre on a wam7 and the tool
# plate on a wam4 (wamctl.model.collision)
LABELS = {"position": "joint range (with margin)", "speed": "speed", "acceleration": "acceleration",
          "torque": "torque (declared model, with margin)", "cartesian_speed": "end-point speed"}
END_POINT = {"wam7": "the wrist", "wam4": "the tool plate"}
PEAK_COLUMNS = {"position": "position_peak_rad", "speed": "speed_peak_rad_s",
                "acceleration": "acceleration_peak_rad_s2", "torque": "torque_peak_Nm"}


def limits_table(use) -> pd.DataFrame:
    """Per joint: the peak of each quantity and the share of its limit used (a LimitUse and its limits)."""
    rows = []
    for j in range(len(use.used["position"])):
        row = {"joint": j + 1}
        for kind, col in PEAK_COLUMNS.items():
            row[col] = float(use.peak[kind][j])
            row[f"{kind}_used_pct"] = 100 * float(use.used[kind][j])
        rows.append(row)
    return pd.DataFrame(rows).set_index("joint")


def design_document(spec, design, use, limits, out_dir: Path, outlook: dict | None = None) -> Document:
    """The report of a design (written into ``out_dir`` as report.md/html/json + a figure of one period);
    ``outlook``: :func:`wamctl.experiments.excitation.instruments_outlook`."""
    ex = spec.excitation
    doc = Document(f"Excitation design: {spec.name}")
    doc.text(f"Fourier series of {ex.harmonics} harmonics, period {ex.period_s:g} s, joints {ex.joints}, q0 = "
             f"{[round(v, 3) for v in spec.q0_rad]}. Criterion {design.criterion} over the {design.n_target} base "
             f"parameters these joints can determine; condition number of the column-equilibrated base regressor "
             f"over one period: {design.condition_number:.4g}.")
    worst = use.worst
    doc.text(f"Closest limit: {LABELS[worst[0]]}" + (f" of joint {worst[1]}" if worst[1] else "")
             + f", {worst[2]:.0%} used; end-point speed ({END_POINT.get(spec.robot, 'the last link')}) peak "
               f"{use.peak['cartesian_speed']:.3f} m/s of "
               f"{limits.cartesian_speed_m_s:g} m/s. All limits checked at {P.CONTROL_RATE_HZ:.0f} Hz over the "
               "whole period.")
    if outlook:
        doc.text(outlook["statement"][0].upper() + outlook["statement"][1:] + ". Predicted tracking error over "
                 "the motion per joint (PD + gravity, the spec's gains, the declared model): "
                 + ", ".join(f"joint {j} {100 * v:.1f} %" for j, v in outlook["tracking_share_predicted"].items())
                 + ".")
        doc.data["instruments_outlook"] = outlook
    if design.clearance is not None:
        world_section(doc, design.clearance, spec, getattr(design, "scaled_back", 1.0))
    doc.heading("Limits reached")
    doc.table("limits", limits_table(use), "peak of each quantity over one period and the share of its "
              "limit used (position: distance from the middle of the range with margin, as a share of its half).")
    doc.heading("Starts")
    doc.table("starts", pd.DataFrame(design.starts), "each random feasible start and where SLSQP ended")
    doc.data.update(condition_number=design.condition_number, criterion=design.criterion,
                    limits_used={k: np.asarray(v).tolist() for k, v in use.used.items()})
    t = np.linspace(0, design.trajectory.period_s, 600)
    q, qd, _ = design.trajectory.evaluate(t)
    moving = design.trajectory.moving
    fig, axes = joint_grid(len(moving), "One period of the designed excitation")
    for ax, j in zip(axes, moving):
        ax.plot(t, q[:, j], label="q (rad)")
        ax.plot(t, qd[:, j], "--", label="qd (rad/s)")
        ax.axhline(limits.q_min_rad[j], color="0.6", lw=0.8)
        ax.axhline(limits.q_max_rad[j], color="0.6", lw=0.8)
        ax.set_title(f"joint {j + 1}")
        ax.set_xlabel("t (s)")
        ax.grid(alpha=0.3)
    axes[0].legend()
    doc.figure(save(fig, Path(out_dir) / "excitation_design.png"), "one period; grey: joint range with margin")
    doc.write(Path(out_dir), "report")
    return doc


WORLD_KINDS = {"self": "self-collision (non-adjacent links)", "table": "table plane", "box": "workspace box"}


def world_table(clearance) -> pd.DataFrame:
    """Per kind: the smallest distance sampled, between what, when, and the distance the whole period keeps at
    least (the sampling's bound subtracted)."""
    rows = [{"kind": WORLD_KINDS[k], "between": c.between, "smallest_sampled_m": c.distance_m,
             "at_t_s": c.index * clearance.dt_s, "at_least_m": clearance.guaranteed_m(k),
             "clearance_m": clearance.clearance_m, "kept": clearance.guaranteed_m(k) >= clearance.clearance_m - 1e-12}
            for k, c in clearance.smallest.items()]
    return pd.DataFrame(rows).set_index("kind")


def world_section(doc: Document, clearance, spec, scaled_back: float = 1.0) -> None:
    """The smallest distances to the world reached over one period (``excitation.world``)."""
    w = spec.excitation.world
    doc.heading("The world around the arm")
    said = [f"self-collision {'checked' if w.self_collision else 'not checked'}",
            f"table plane at z = {w.table_z_m:g} m" if w.table_z_m is not None else "no table",
            f"workspace box {w.box.min_m} to {w.box.max_m} m" if w.box is not None else "no workspace box"]
    capsules = ("shoulder, upper arm, forearm to the tool plate" if spec.robot == "wam4"
                else "shoulder, upper arm, forearm, wrist and hand")
    doc.text(f"Capsules along the arm ({capsules}"
             + (f" with a tool of {w.tool_length_m:g} m" if w.tool_length_m else "") + "); " + ", ".join(said)
             + f"; clearance {clearance.clearance_m:g} m. Sampled every {1e3 * clearance.dt_s:.1f} ms over the whole "
             f"period; between samples no distance can shrink by more than {1e3 * clearance.sampling_bound_m:.1f} mm "
             "(joint speeds x lever arms), so each distance is given as at least the smallest sampled minus that."
             + (f" SLSQP's design crossed a limit or the clearance between its grid points: scaled back toward "
                f"q0 to {scaled_back:.4f} of its amplitude." if scaled_back < 1.0 else ""))
    doc.table("world", world_table(clearance), "smallest distance (surface to surface; box: inside the box) of "
              "each kind over one period, the links it is between and its time in the period")
    doc.data["world"] = clearance.to_dict()


def report(run_path: Path, manifest: dict, spec: dict, out_dir: Path | None = None) -> Document:
    """The run of an excitation: limits the arm reached (measured), and what the data determine."""
    from wamctl.analysis.identification.base import base_parameters, identifiability
    from wamctl.analysis.identification.data import run_rows
    from wamctl.errors import DataFormatError
    from wamctl.model.dynamics import WamDynamics
    from wamctl.model.robots import get_robot
    from wamctl.runs.measured import load_run_data

    out_dir = Path(out_dir or run_path)
    robot = get_robot((spec or {}).get("robot"))
    n = robot.n_joints
    data = read_table(run_path)
    doc = Document(f"Excitation run: {manifest.get('name', run_path.name)}")
    doc.text(f"Run {run_path.name}: status {manifest.get('status')}, backend "
             f"{(manifest.get('backend') or {}).get('name', '?')}, {len(data)} samples.")
    if manifest.get("status") != "completed" and manifest.get("reason"):
        doc.text(f"The run ended {manifest['status']}: {manifest['reason']}.")
    if len(data) < 10:
        return doc
    q = data[[f"q_{j}_rad" for j in range(1, n + 1)]].to_numpy()
    tau = data[[f"tau_{j}_Nm" for j in range(1, n + 1)]].to_numpy()
    t = data["t_s"].to_numpy()
    qd = np.gradient(q, t, axis=0)
    rows = []
    for j in range(n):
        lo, hi = q[:, j].min(), q[:, j].max()
        rows.append({"joint": j + 1, "q_min_rad": lo, "q_max_rad": hi,
                     "range_margin_rad": float(min(lo - robot.q_min_rad[j], robot.q_max_rad[j] - hi)),
                     "speed_peak_rad_s": float(np.abs(qd[:, j]).max()),
                     "torque_peak_Nm": float(np.abs(tau[:, j]).max()),
                     "torque_used_pct": 100 * float(np.abs(tau[:, j]).max() / robot.tau_max_Nm[j])})
    measured = pd.DataFrame(rows).set_index("joint")
    doc.heading("Limits reached by the arm (measured)")
    doc.table("measured_limits", measured, "positions as measured; speed: finite difference of the measured "
              f"positions (with encoder noise); torque: the commanded torque against the {robot.name}'s limits")
    doc.data["measured_limits"] = measured.reset_index().to_dict("records")
    try:
        # a run of any robot (identify takes them all)
        rd = load_run_data(run_path, reader="report", any_robot=True, stand_in=True)
        rr = run_rows(rd, WamDynamics(robot=robot.name))
        Y, _, _, _ = rr.stacked()
        base = base_parameters(robot.name)
        ident = identifiability(base.regressor(Y), base)
        doc.heading("What these data determine")
        doc.text(ident.statement() + ".")
        doc.data["identifiability"] = ident.to_dict()
    except DataFormatError as exc:
        doc.text(f"No identification rows: {exc}")
    moving = [j for j in range(n) if np.ptp(data[f"q_ref_{j + 1}_rad"]) > 1e-9]
    if moving:
        fig, axes = joint_grid(len(moving), "Reference, measured position and torque")
        for ax, j in zip(axes, moving):
            ax.plot(t, data[f"q_ref_{j + 1}_rad"], label="q_ref (rad)")
            ax.plot(t, q[:, j], "--", label="q (rad)")
            ax2 = ax.twinx()
            ax2.plot(t, tau[:, j], color="C3", lw=0.6, alpha=0.7)
            ax2.set_ylabel("tau (N m)", color="C3")
            ax.set_title(f"joint {j + 1}")
            ax.set_xlabel("t (s)")
            ax.grid(alpha=0.3)
        axes[0].legend(loc="upper left")
        doc.figure(save(fig, out_dir / "excitation_run.png"), "reference and measured position; torque in red")
    return doc
