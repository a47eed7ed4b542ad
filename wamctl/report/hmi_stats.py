"""HMI statistics as a report: the thesis-style per-unit tables, the one-way ANOVA table, and for per-subject
results the repeated-measures ANOVA with sphericity test, Greenhouse-Geisser/Huynh-Feldt corrections and
Holm-corrected pairwise comparisons, with mean and median bar charts (thesis Figs. 6.28-6.29).

Used for imported results files (``wamctl report --hmi-results FILE.csv``) and for HMI trial blocks."""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from wamctl.analysis.hmi_results import HmiResults
from wamctl.errors import DataFormatError
from wamctl.report.document import Document
from wamctl.report.hmi_figures import save_bar_chart

_LABELS = {"hit_pct": "Hits (%)", "hit_rate": "Hit rate", "mean_time_s": "Execution time (s)"}


def add_hmi_analysis(doc: Document, results: HmiResults, out_dir: Path | None, stem: str = "hmi",
                     unit_tables: bool = True) -> Document:
    """Append the tables, statistics and figures of ``results`` to ``doc``.

    Figures are written to ``out_dir`` (none when it is None); ``unit_tables=False`` leaves out the per-unit
    tables when the caller already shows them in its own layout."""
    unit = results.unit_kind
    for m in [m for m in results.measures if m != "hit_rate"] if unit_tables else []:
        doc.heading(f"{_LABELS.get(m, m)} per {unit}")
        doc.table(f"{stem}_table_{m}", results.table(m), "Mean, SD (sample) and SEM over the available units.")
    try:
        analysis = results.analyse()
    except DataFormatError as exc:
        doc.text(f"No statistics: {exc}")
        return doc
    doc.data[f"{stem}_analysis"] = analysis.to_dict()
    if analysis.exclusions:
        doc.heading("Excluded units")
        doc.text("; ".join(f"{unit} {e.unit}: {e.reason}" for e in analysis.exclusions))
    for m, a in analysis.one_way.items():
        doc.heading(f"One-way ANOVA of {_LABELS.get(m, m)}: {a.apa()}")
        doc.table(f"{stem}_anova_{m}", a.to_pandas(), f"{len(analysis.complete.units)} complete {unit}s.")
    for m, a in analysis.rm.items():
        doc.heading(f"Repeated-measures ANOVA of {_LABELS.get(m, m)}")
        sph = a.sphericity
        doc.text(f"Mauchly's test of sphericity: W = {sph.w:.3f}, p = {sph.p:.3f} "
                 f"({'assumed' if sph.assumed() else 'violated'}); Greenhouse-Geisser epsilon = {sph.eps_gg:.3f} "
                 f"(corrected p = {sph.p_gg:.4f}), Huynh-Feldt epsilon = {sph.eps_hf:.3f} "
                 f"(corrected p = {sph.p_hf:.4f}).")
        doc.table(f"{stem}_rm_anova_{m}", a.to_pandas(),
                  "Sphericity: Mauchly's test; p_gg / p_hf: Greenhouse-Geisser / Huynh-Feldt corrected p.")
        pw = analysis.pairwise.get(m)
        if pw is not None:
            doc.table(f"{stem}_pairwise_{m}", pw.to_pandas(), "Paired t-tests, Holm-corrected p.")
    if out_dir is None:
        return doc
    Path(out_dir).mkdir(parents=True, exist_ok=True)
    panels = {_LABELS.get(m, m): results.wide(m) for m in results.measures if m != "hit_rate"}
    for statistic in ("mean", "median"):
        p = save_bar_chart(panels, Path(out_dir) / f"{stem}_{statistic}.png", statistic=statistic)
        doc.figure(p, f"{statistic} per condition with error bars ({'SEM' if statistic == 'mean' else 'IQR'})")
    return doc


def hmi_results_report(path: Path, out_dir: Path) -> Document:
    """A report of one HMI results file (raw trials or per-unit summaries)."""
    from wamctl.analysis.hmi_csv import read_hmi_csv
    results = read_hmi_csv(path)
    doc = Document(f"HMI results: {Path(path).name}")
    doc.text(f"{len(results.units)} {results.unit_kind}s x {len(results.conditions)} conditions "
             f"({', '.join(results.conditions)}) from {path}.")
    add_hmi_analysis(doc, results, out_dir, Path(path).stem)
    return doc


def tables_of(doc: Document) -> dict[str, pd.DataFrame]:
    return {obj[0]: obj[1] for kind, obj in doc.blocks if kind == "table"}
