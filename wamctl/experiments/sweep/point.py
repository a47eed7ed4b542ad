"""One point of a sweep on a Dask worker: its run into the point's directory, its index record (status, error,
run directory, key figures), and the attempts a lost process left behind."""

from __future__ import annotations

import json
import logging
import os
import socket
import time
from pathlib import Path

from wamctl.errors import WamctlError
from wamctl.experiments.runner import RunInterrupted, run_spec
from wamctl.report import write_report
from wamctl.report.document import key_figures
from wamctl.runs import catalog
from wamctl.runs.store import RunDir
from wamctl.specs import parse_spec

log = logging.getLogger(__name__)



def run_dirs(point_dir: Path) -> list[Path]:
    """The run directories (attempts) of a point, oldest first."""
    if not point_dir.is_dir():
        return []
    return sorted(d for d in point_dir.iterdir() if d.is_dir() and (d / "manifest.json").is_file())


def read_manifest(run_dir: Path) -> dict:
    """The manifest of a run directory, empty when it cannot be read."""
    try:
        return json.loads((Path(run_dir) / "manifest.json").read_text())
    except (OSError, json.JSONDecodeError):
        return {}


def mark_abandoned(point_dir: Path, known_by: str) -> list[Path]:
    """Record the point's run directories still ``running`` (their process is gone, ``known_by`` says how) as
    ``wamctl runs --mark-abandoned`` does: ``interrupted``, reason ``process ended without closing the run``,
    their chunks consolidated (every sample kept). Returns them."""
    return [d for d in run_dirs(point_dir) if catalog.mark_abandoned(d, known_dead=known_by)]


def _worker_name() -> str:
    try:
        from distributed import get_worker
        return get_worker().address
    except (ImportError, ValueError):
        return f"{socket.gethostname()}:{os.getpid()}"


def run_point(spec: dict, point_id: str, point_dir: str, base_dir: str | None, values: dict,
              sweep_dir: str, reports: bool = True) -> dict:
    """Run one point into ``point_dir`` (executed on a Dask worker). Returns its index record.

    User-caused errors (a refused spec or plan, a safety fault) are results: ``status`` failed with the
    error. Anything else raises, so that Dask retries it.
    """
    t0 = time.time()
    pdir = Path(point_dir)
    pdir.mkdir(parents=True, exist_ok=True)
    mark_abandoned(pdir, "sweep: the point given to another worker (the one running it was lost)")
    rec = {"point": point_id, "status": "failed", "run_status": None, "run_dir": None, "error": None,
           "worker": _worker_name(), "pid": os.getpid(), "start_unix_s": t0, "figures": {}}
    base = Path(base_dir) if base_dir else None
    try:
        parsed = parse_spec(spec, f"point {point_id}")
        outcome = run_spec(parsed, base, pdir, None, make_report=False)
    except RunInterrupted as exc:
        rec.update(status="interrupted", error=str(exc))
    except WamctlError as exc:  # refused before the run started: deterministic, not retried
        rec["error"] = str(exc)
    else:
        rec.update(run_dir=str(outcome.path), run_status=outcome.status, error=outcome.reason,
                   status="completed" if outcome.status == "completed" else "failed")
        RunDir(outcome.path).update_manifest(sweep={"dir": str(sweep_dir), "point": point_id,
                                                    "values": values})
        if outcome.status == "completed" and reports:
            try:
                rec["figures"] = key_figures(write_report(outcome.path).data)
            except Exception as exc:  # noqa: BLE001 - a report failure must not lose the run
                log.exception("report of %s failed", outcome.path)
                rec["error"] = f"report failed: {type(exc).__name__}: {exc}"
    if rec["run_dir"] is None:
        dirs = run_dirs(pdir)  # a run that started and then failed leaves its directory
        if dirs and read_manifest(dirs[-1]).get("status") in ("failed", "interrupted"):
            rec["run_dir"] = str(dirs[-1])
    rec["end_unix_s"] = time.time()
    rec["attempts"] = len(run_dirs(pdir))
    return rec
