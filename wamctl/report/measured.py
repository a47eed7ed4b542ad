"""Report of an imported measured run of no particular experiment (``experiment.kind: free``): what was
recorded, per-joint tracking error statistics, and the traces of the joints that moved."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from wamctl.report.document import Document
from wamctl.report.figures import joint_grid, save
from wamctl.runs.measured import load_run_data


def report(run_path: Path, manifest: dict, spec: dict, out_dir: Path | None = None) -> Document:
    out_dir = Path(out_dir or run_path)
    rd = load_run_data(run_path, partial_ok=True)    # whatever was logged, NaN where nothing was
    t = rd.t_s
    err = rd.col("q_ref") - rd.col("q")
    moved = [j for j in range(1, 8) if np.ptp(rd.col("q_ref")[:, j - 1]) > 1e-6]
    doc = Document(f"Measured run: {manifest.get('name', Path(run_path).name)}")
    doc.text(f"Imported from {manifest.get('imported_from', '?')}: {len(t)} samples over {t[-1] - t[0]:.2f} s "
             f"at {rd.meta.sample_rate_hz:g} Hz, controller {rd.meta.controller.kind}, "
             f"gravity compensation in the logged torque: {rd.meta.gravity_compensation}.")
    table = pd.DataFrame({
        "joint": range(1, 8),
        "moved": [j in moved for j in range(1, 8)],
        "range_rad": np.ptp(rd.col("q"), axis=0),
        "rms_error_rad": np.sqrt((err ** 2).mean(axis=0)),
        "max_abs_error_rad": np.abs(err).max(axis=0),
        "max_abs_tau_Nm": np.abs(rd.col("tau")).max(axis=0),
    }).set_index("joint")
    doc.heading("Tracking error per joint").table("tracking", table, "error = q_ref - q")
    if moved:
        fig, axes = joint_grid(len(moved), "Position error q_ref - q")
        for ax, j in zip(axes, moved):
            ax.plot(t, err[:, j - 1] * 1e3)
            ax.set_title(f"joint {j}")
            ax.set_ylabel("error (mrad)")
            ax.grid(alpha=0.3)
        doc.figure(save(fig, out_dir / "measured_errors.png"), "position error of the joints that moved")
    return doc
