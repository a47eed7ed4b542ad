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
    doc = resolve(KINDS[kind].report)(Path(run_path), manifest, spec, out_dir)
    doc.write(Path(out_dir or run_path), "report", formats)
    return doc
