"""Reports over one or many run directories (each by its kind), plus a combined report when there are several:
the runs (with links to their own reports, wherever they were written), the RPE side by side for rotation
runs, the spread (mean, SD, min-max) of every key figure over runs that repeat one spec with other seeds, and
the HMI study over ``hmi_block`` runs."""

from __future__ import annotations

import json
import os
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from wamctl.report import write_report
from wamctl.report.document import Document, Link, key_figures
from wamctl.runs.store import open_run

# spec keys that do not make two runs different experiments
_NOT_THE_EXPERIMENT = ("seed", "name", "description", "out_dir")


COMBINED_DIR = "combined-report"   # beside the runs when no --out is given: a folder that is not a run


@dataclass
class Reported:
    """What ``report_runs`` did: the documents (each run's, then the combined one), the files written, the
    runs reported (path, manifest) and the paths skipped with why (not a run directory)."""

    docs: list = field(default_factory=list)
    written: list[Path] = field(default_factory=list)
    runs: list[tuple[Path, dict]] = field(default_factory=list)
    skipped: list[tuple[Path, str]] = field(default_factory=list)


def not_a_run(path: Path) -> str | None:
    """Why ``path`` is not a run directory wamctl can report (None when it is one). A combined report's folder,
    a sweep directory or a stray file among ``runs/*`` is named, not read."""
    path = Path(path)
    if not path.exists():
        return "no such file or directory"
    if not path.is_dir():
        return "a file, not a run directory"
    if (path / "manifest.json").is_file():
        return None
    if (path / "sweep.json").is_file():
        return "a sweep directory (its report is written by `wamctl sweep`: report.html there)"
    if any(path.glob("combined_report.*")):
        return "a combined report's folder"
    return "not a wamctl run directory (no manifest.json)"


def report_runs(run_dirs: list[Path], out: Path | None, formats=("md", "html", "json")) -> Reported:
    """Write the report of each run (into ``out/<run name>`` when ``out`` is given for several runs, ``out``
    for one, else into the run itself) and, for several runs, ``combined_report.*``: into ``out``, else into
    :data:`COMBINED_DIR` beside the first run (never among the runs, so that ``wamctl report runs/*`` can be
    run again). Paths that are not run directories are skipped with why (:func:`not_a_run`); DataFormatError
    when none is left."""
    from wamctl.errors import DataFormatError

    done = Reported()
    runs = []
    for rd in map(Path, run_dirs):
        why = not_a_run(rd)
        if why is None:
            runs.append(rd)
        else:
            done.skipped.append((rd, why))
    if not runs:
        raise DataFormatError("nothing to report: " + "; ".join(f"{p}: {why}" for p, why in done.skipped))
    targets = []
    for rd in runs:
        target = (Path(out) / rd.name) if out and len(runs) > 1 else out
        doc = write_report(rd, target, formats)
        done.docs.append(doc)
        done.runs.append((rd, open_run(rd)[0]))
        targets.append(Path(target or rd))
        done.written += [Path(target or rd) / f"report.{f}" for f in formats]
    if len(runs) > 1:
        dest = Path(out) if out else runs[0].parent / COMBINED_DIR
        combined = combined_document(runs, list(done.docs), dest, targets)
        done.written += combined.write(dest, "combined_report", formats)
        done.docs.append(combined)
    return done


def _title(manifests: list[dict]) -> str:
    kinds = Counter(m.get("kind") or "unknown" for m in manifests)
    names = sorted({str(m.get("name")) for m in manifests})
    what = ", ".join(f"{n} {k}" for k, n in kinds.items())
    if len(names) == 1:
        return f"{names[0]}: {len(manifests)} runs compared ({what})"
    return f"{len(manifests)} runs compared ({what})"


def _experiment_key(manifest: dict, spec: dict) -> str:
    """Runs with the same key repeat one experiment (same kind and spec but for the seed and name)."""
    return json.dumps([manifest.get("kind"), {k: v for k, v in (spec or {}).items() if k not in _NOT_THE_EXPERIMENT}],
                      sort_keys=True, default=str)


def spread_table(figures: list[dict[str, float]]) -> pd.DataFrame:
    """Per key figure over repeated runs: n, mean, SD (ddof 1), min and max (index: figure)."""
    frame = pd.DataFrame(figures)
    rows = []
    for col in frame.columns:
        v = frame[col].dropna().to_numpy(float)
        if len(v) < 2:
            continue
        rows.append({"figure": col, "n": len(v), "mean": float(v.mean()), "sd": float(v.std(ddof=1)),
                     "min": float(v.min()), "max": float(v.max())})
    return pd.DataFrame(rows).set_index("figure") if rows else pd.DataFrame()


def combined_document(run_dirs, docs, out_dir: Path, targets: list[Path] | None = None) -> Document:
    """The combined report of several runs whose reports are ``docs`` (written into ``targets``)."""
    targets = targets or [Path(rd) for rd in run_dirs]
    opened = [open_run(rd) for rd in run_dirs]
    manifests = [m for m, _ in opened]
    labels = [f"r{i + 1}" for i in range(len(run_dirs))]
    rows = []
    for label, rd, (m, _), target in zip(labels, run_dirs, opened, targets):
        href = os.path.relpath(Path(target) / "report.html", Path(out_dir)).replace(os.sep, "/")
        rows.append({"run": label, "name": m.get("name"), "kind": m.get("kind"), "seed": m.get("seed"),
                     "status": m.get("status"), "directory": Path(rd).name, "report": Link("report", href)})
    combined = Document(_title(manifests))
    combined.text("Each run's own report is linked in the last column; r1, r2, ... label the runs in the tables "
                  "below.")
    combined.table("runs", pd.DataFrame(rows).set_index("run"))
    rpe = {label: d.data["rpe_pct"] for label, d in zip(labels, docs) if isinstance(d.data.get("rpe_pct"), dict)
           and all(isinstance(v, (int, float)) for v in d.data["rpe_pct"].values())}
    if len(rpe) > 1:
        df = pd.DataFrame(rpe)
        df.index = df.index.astype(int)
        df.index.name = "joint"
        combined.heading("RPE per joint (%)")
        combined.table("rpe_pct", df.sort_index(), "RPE = |final error / amplitude| x 100 % of each rotation run; "
                       "empty where a run did not move the joint.")
    _add_spreads(combined, run_dirs, opened, docs, labels)
    from wamctl.report.hmi import study_report  # HMI blocks: per-location/per-subject tables and the ANOVA
    study_report(run_dirs, out_dir, doc=combined)
    return combined


def _add_spreads(doc: Document, run_dirs, opened, docs, labels) -> None:
    """For every group of runs repeating one spec with other seeds: the spread of each key figure."""
    groups: dict[str, list[int]] = {}
    for i, (m, spec) in enumerate(opened):
        if m.get("status") == "completed":
            groups.setdefault(_experiment_key(m, spec), []).append(i)
    for members in groups.values():
        if len(members) < 2:
            continue
        seeds = [opened[i][0].get("seed") for i in members]
        figs = [key_figures(docs[i].data) for i in members]
        table = spread_table(figs)
        if table.empty:
            continue
        name = opened[members[0]][0].get("name")
        doc.heading(f"Spread over {len(members)} repeats of {name}")
        doc.text(f"Runs {', '.join(labels[i] for i in members)} repeat one spec with seeds "
                 f"{', '.join(str(s) for s in seeds)}: mean, standard deviation (n - 1) and range of each key "
                 "figure of their reports.")
        doc.table(f"spread_{name}", table, "figure: a number of each run's report (e.g. rpe_pct.3: RPE of joint 3, "
                  "%); sd over the runs with the figure.")
        doc.data.setdefault("spread", {})[str(name)] = {
            "runs": [str(Path(run_dirs[i]).name) for i in members], "seeds": seeds,
            "figures": {f: {k: (None if not np.isfinite(v) else float(v)) for k, v in r.items()}
                        for f, r in table.iterrows()}}
