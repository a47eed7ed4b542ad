"""Reports over one or many run directories (each by its kind), plus a combined index when there are several."""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from wamctl.report import write_report
from wamctl.report.document import Document
from wamctl.runs.store import open_run


def report_runs(run_dirs: list[Path], out: Path | None, formats=("md", "html", "json")):
    docs, written = [], []
    for rd in run_dirs:
        target = (Path(out) / Path(rd).name) if out and len(run_dirs) > 1 else out
        doc = write_report(Path(rd), target, formats)
        docs.append(doc)
        written += [Path(target or rd) / f"report.{f}" for f in formats]
    if len(run_dirs) > 1:
        dest = Path(out or Path(run_dirs[0]).parent)
        combined = combined_document(run_dirs, docs, dest)
        written += combined.write(dest, "combined_report", formats)
        docs.append(combined)
    return docs, written


def combined_document(run_dirs, docs, out_dir: Path) -> Document:
    rows = []
    for rd, _doc in zip(run_dirs, docs):
        m, _ = open_run(rd)
        rows.append({"run": Path(rd).name, "kind": m.get("kind"), "status": m.get("status"),
                     "report": str(Path(rd) / "report.html")})
    combined = Document(f"Combined report over {len(run_dirs)} runs")
    combined.table("runs", pd.DataFrame(rows).set_index("run"))
    # side-by-side RPE when several rotation runs are given
    rpe = {Path(rd).name: d.data["rpe_pct"] for rd, d in zip(run_dirs, docs) if "rpe_pct" in d.data}
    if len(rpe) > 1:
        df = pd.DataFrame(rpe)
        df.index.name = "joint"
        combined.heading("RPE per joint (%)").table("rpe_pct", df)
    from wamctl.report.hmi import study_report  # HMI blocks: per-location/per-subject tables and the ANOVA
    study_report(run_dirs, out_dir, doc=combined)
    return combined
