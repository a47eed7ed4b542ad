"""Reports: tables and figures built from a run directory, written as Markdown, HTML and JSON.

What lives here: one module per run kind (``report(run_path, manifest, spec, out_dir) -> Document``, named in
:data:`wamctl.specs.registry.KINDS`), the document model (:mod:`.document`), shared figure helpers
(:mod:`.figures`), and the combined report over many runs (:mod:`.combined`).

May import: analysis, specs, runs, model, control, hmi, io, errors. Never experiments, backends or the CLI:
the runner calls the report, never the other way round.
"""

from __future__ import annotations

from pathlib import Path


def write_report(run_path: str | Path, out_dir: Path | None = None, formats=("md", "html", "json")):
    """Build and write the report of one run directory (by its kind); returns the Document."""
    from wamctl.errors import WamctlError
    from wamctl.runs.store import open_run
    from wamctl.specs.registry import KINDS, resolve

    manifest, spec = open_run(run_path)
    kind = manifest.get("kind")
    if kind not in KINDS:
        raise WamctlError(f"{run_path}: no report for run kind {kind!r}")
    if out_dir is not None:
        Path(out_dir).mkdir(parents=True, exist_ok=True)
    if manifest.get("status") != "completed" and not _recorded_anything(Path(run_path)):
        doc = _nothing_recorded(Path(run_path), manifest)
    else:
        doc = resolve(KINDS[kind].report)(Path(run_path), manifest, spec, out_dir)
    doc.write(Path(out_dir or run_path), "report", formats)
    return doc


def _recorded_anything(run_path: Path) -> bool:
    """Whether the run directory holds a table: a consolidated Parquet file, its data folder (chunks, or none yet:
    an empty table the run's report reads) or another table's chunks."""
    if any(run_path.glob("*.parquet")) or (run_path / "data").is_dir():
        return True
    return any(d.is_dir() and any(d.glob("part-*.parquet")) for d in run_path.iterdir())


def _nothing_recorded(run_path: Path, manifest: dict):
    """The report of a run that ended before its recording began (a sweep's point killed while its backend was
    being built): what the manifest says, and that there is no sample to report on."""
    from wamctl.report.document import Document

    doc = Document(f"Run {manifest.get('name', run_path.name)}: nothing recorded")
    reason = f": {manifest['reason']}" if manifest.get("reason") else ""
    doc.warning(f"The run ended {manifest.get('status', 'unknown')}{reason}, before its first sample was recorded: "
                "no table, no figure.")
    doc.data["samples"] = 0
    return doc
