"""The sweep directory: its manifest (``sweep.json``, with one record per session), its spec (``sweep.yaml``)
and its index of points (``index.json`` / ``index.csv``, read back by :func:`wamctl.report.sweep.read_index`)."""

from __future__ import annotations

import json
import socket
from pathlib import Path

import pandas as pd
import yaml

from wamctl.errors import SpecError
from wamctl.experiments.sweep.cluster import dask_versions
from wamctl.report.sweep import INDEX_COLUMNS, STATUSES
from wamctl.runs.store import atomic_write_text, git_revision, json_default, new_stamped_dir, package_versions, utc_now
from wamctl.specs.sweep import Sweep, load_sweep, sweep_from_mapping

SWEEP_FORMAT = "wamctl-sweep/1"
INDEX_FORMAT = "wamctl-sweep-index/1"


class SweepIndex:
    """The sweep directory's table of points, written atomically (JSON + CSV) after every change."""

    def __init__(self, sweep_dir: Path, sweep: Sweep):
        self.dir = Path(sweep_dir)
        self.parameters = sweep.parameters
        self.rows: dict[str, dict] = {}
        for p in sweep.points:
            self.rows[p.point_id] = {"point": p.point_id, "values": p.values, "status": "pending",
                                     "attempts": 0, "run_dir": None, "error": None, "worker": None,
                                     "start_unix_s": None, "end_unix_s": None, "figures": {}}

    @classmethod
    def load(cls, sweep_dir: Path, sweep: Sweep) -> SweepIndex:
        idx = cls(sweep_dir, sweep)
        p = Path(sweep_dir) / "index.json"
        if p.is_file():
            stored = json.loads(p.read_text())
            for row in stored.get("points", []):
                pid = row.get("point")
                if pid in idx.rows:
                    if row.get("values") != idx.rows[pid]["values"]:
                        raise SpecError(f"{sweep_dir}: point {pid} of the index has values {row.get('values')}, "
                                        f"the spec gives {idx.rows[pid]['values']}: not the same sweep")
                    idx.rows[pid].update({k: v for k, v in row.items() if k in idx.rows[pid]})
        return idx

    def update(self, rec: dict) -> None:
        row = self.rows[rec["point"]]
        for k in ("status", "attempts", "run_dir", "error", "worker", "start_unix_s", "end_unix_s", "figures"):
            if k in rec:
                row[k] = rec[k]
        if row["run_dir"]:
            try:
                row["run_dir"] = str(Path(row["run_dir"]).resolve().relative_to(self.dir.resolve()))
            except ValueError:
                pass

    def counts(self) -> dict[str, int]:
        c = dict.fromkeys(STATUSES, 0)
        for r in self.rows.values():
            c[r["status"]] = c.get(r["status"], 0) + 1
        return c

    def frame(self) -> pd.DataFrame:
        """One row per point: point, parameter values, status, attempts, run_dir, error, worker, timing,
        key figures."""
        recs = []
        for r in self.rows.values():
            rec = {"point": r["point"]}
            for p in self.parameters:
                v = r["values"].get(p)
                rec[p] = json.dumps(v) if isinstance(v, (list, dict)) else v
            rec.update({k: r[k] for k in INDEX_COLUMNS[1:-1]})
            rec["duration_s"] = (r["end_unix_s"] - r["start_unix_s"]) if r["end_unix_s"] and r["start_unix_s"] \
                else None
            rec.update(r.get("figures") or {})
            recs.append(rec)
        return pd.DataFrame(recs)

    def write(self) -> None:
        doc = {"format": INDEX_FORMAT, "parameters": self.parameters, "counts": self.counts(),
               "points": list(self.rows.values())}
        atomic_write_text(self.dir / "index.json", json.dumps(doc, indent=1, default=json_default))
        atomic_write_text(self.dir / "index.csv", self.frame().to_csv(index=False))


def create_sweep_dir(sweep: Sweep, out_dir: str | Path) -> Path:
    """A new sweep directory under ``out_dir`` with the spec as given and a fresh manifest."""
    path = new_stamped_dir(out_dir, f"{sweep.name}-sweep")
    (path / "sweep.yaml").write_text(yaml.safe_dump(sweep.raw, sort_keys=False))
    manifest = {"format": SWEEP_FORMAT, "kind": sweep.kind, "name": sweep.name, "source": sweep.source,
                "base_dir": str(sweep.base_dir) if sweep.base_dir else None,
                "n_points": len(sweep.points), "parameters": sweep.parameters, "status": "created",
                "start_utc": utc_now(), "end_utc": None, "sessions": [], "host": socket.gethostname(),
                "versions": {**package_versions(), **dask_versions()}, "git_revision": git_revision()}
    atomic_write_text(path / "sweep.json", json.dumps(manifest, indent=2, default=json_default))
    return path


def open_sweep_dir(sweep_dir: str | Path) -> tuple[Sweep, dict]:
    """(sweep, manifest) of an existing sweep directory, for ``--resume``."""
    d = Path(sweep_dir)
    if not (d / "sweep.json").is_file() or not (d / "sweep.yaml").is_file():
        raise SpecError(f"{d}: not a sweep directory (no sweep.json / sweep.yaml)")
    manifest = json.loads((d / "sweep.json").read_text())
    raw = yaml.safe_load((d / "sweep.yaml").read_text())
    base = Path(manifest["base_dir"]) if manifest.get("base_dir") else None
    return sweep_from_mapping(raw, manifest.get("source", str(d / "sweep.yaml")), base), manifest


def sweep_to_run(spec_path: str | Path | None, resume_dir: str | Path | None) -> Sweep:
    """The sweep a ``wamctl sweep`` call means: the spec's, or with ``resume_dir`` the sweep directory's own
    (a spec given as well must have the same points, or SpecError)."""
    if spec_path is None and resume_dir is None:
        raise SpecError("give a spec with a `vary:` section, or --resume SWEEP_DIR")
    if resume_dir is None:
        return load_sweep(spec_path)
    sw, _ = open_sweep_dir(resume_dir)
    if spec_path is not None:
        given = load_sweep(spec_path)
        if [(p.point_id, p.spec) for p in given.points] != [(p.point_id, p.spec) for p in sw.points]:
            raise SpecError(f"{spec_path}: not the spec of the sweep in {resume_dir} (its points differ); resume "
                            f"without the spec, or start a new sweep")
    return sw


def update_manifest(sweep_dir: Path, **fields) -> dict:
    """Set ``fields`` in the sweep manifest (atomically); returns the manifest."""
    p = sweep_dir / "sweep.json"
    m = json.loads(p.read_text())
    m.update(fields)
    atomic_write_text(p, json.dumps(m, indent=2, default=json_default))
    return m


def read_sessions(sweep_dir: Path) -> list:
    """The session records of the sweep manifest (one per call of ``run_sweep``)."""
    return json.loads((sweep_dir / "sweep.json").read_text()).get("sessions", [])
