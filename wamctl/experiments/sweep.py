"""Sweeps: one spec, many runs. A ``vary:`` section in any spec names the fields to vary; each point becomes
an ordinary run directory, executed on a Dask cluster, and one sweep directory indexes them.

The ``vary:`` section
---------------------
(Not ``sweep:``: the friction_sweep kind already has a ``sweep:`` field, its schedule, and a friction sweep
must be sweepable too, e.g. ``vary: {grid: {sweep.joints: [[1], [7]], seed: [0, 1]}}``.)
Fields are named by dotted paths into the spec (``plant.effects.stribeck.breakaway_ratio``, ``seed``,
``q0_rad.3`` for a list element, ``subject.id`` for an hmi block's subject)::

    vary:
      grid:                       # every combination (cartesian product, last key varies fastest)
        plant.effects.stribeck.breakaway_ratio: [1.2, 2.0]
        seed: {range: [0, 50]}    # 0..49; also {range: [stop]}, {range: [start, stop, step]}
      zip:                        # varied together (equal lengths)
        rotation.amplitude_rad: [0.1, 0.2]
        rotation.velocity_rad_s: {linspace: [0.1, 0.3, 2]}
      points:                     # an explicit list of points, each a mapping of path -> value
        - {plant.friction: table_4_1}
        - {plant.friction: none}
      retries: 2                  # re-runs of a point after an unexpected error (not after a spec error)
      reports: true               # write each run's own report (figures: ~1 s per point)
      name: my-sweep              # sweep directory name (default: the spec's name)

The points are ``points x zip x grid`` (each factor absent counts as one empty point). The section is
taken out before the spec's own validation; every expanded point is then validated with
:func:`wamctl.specs.parse_spec`, and an invalid point stops the sweep before anything runs, with an error
naming the point, its values and the field.

The sweep directory
-------------------
``<out>/<UTC time>-<name>-sweep/``::

    sweep.yaml        the spec as given, with its vary section
    sweep.json        manifest: format wamctl-sweep/1, source, base_dir, points, status, cluster, timing
    index.json/.csv   one row per point: point, parameter values, status, attempts, run_dir, error,
                      worker, start/end, and the run's key figures (numbers of its report's data)
    runs/<point>/     the point's run directories (one per attempt; a lost attempt is marked failed)
    report.md/.html/.json   the combined report: index, key figures, key figures per parameter value

Point status: ``completed`` (its run completed), ``failed`` (the run failed, its spec or plan was refused,
or it kept erroring; ``error`` says why), ``interrupted`` (running when the sweep was stopped),
``pending`` (not started). ``resume`` runs every point that is not ``completed``.

Execution is on Dask only (:mod:`dask.distributed`): a ``LocalCluster`` of one single-threaded process per
core by default, or any running scheduler by address (the sweep directory must then be on a file system the
workers share, at the same path). Results are streamed back with ``as_completed``; a worker lost mid-point
makes the scheduler run the point again elsewhere (up to ``distributed.scheduler.allowed-failures``, then it
is recorded failed with ``KilledWorker``); an exception is retried ``retries`` times by Dask.
"""

from __future__ import annotations

import copy
import datetime as _dt
import itertools
import json
import logging
import math
import os
import socket
import time
import uuid
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import yaml
from pydantic import Field, ValidationError, model_validator

from wamctl.errors import BackendError, SpecError, WamctlError
from wamctl.io import load_yaml
from wamctl.report.document import Document
from wamctl.runs.store import atomic_write_text, git_revision, json_default, new_stamped_dir, package_versions, utc_now
from wamctl.specs import Strict, load_model_file, parse_spec

log = logging.getLogger(__name__)

SWEEP_FORMAT = "wamctl-sweep/1"
INDEX_FORMAT = "wamctl-sweep-index/1"
MAX_POINTS = 100_000
SECTION = "vary"  # the key of the section in a spec
FORBIDDEN_PATHS = ("kind", "out_dir", SECTION)
STATUSES = ("completed", "failed", "interrupted", "pending")
_ABANDONED = "abandoned: the process running this attempt stopped (worker lost or sweep interrupted)"


class SweepInterrupted(WamctlError):
    """The sweep was stopped (Ctrl-C, SIGTERM); its index is on disk and ``--resume`` finishes it."""

    exit_code = 130


# ---------------------------------------------------------------------------------------------- the section
class SweepSection(Strict):
    """The ``vary:`` section of a spec (see the module docstring)."""

    grid: dict[str, Any] = Field(default_factory=dict, description="path -> values; every combination")
    zip: dict[str, Any] = Field(default_factory=dict, description="path -> values; varied together")
    points: list[dict[str, Any]] = Field(default_factory=list, description="explicit points, path -> value")
    retries: int = Field(2, ge=0, le=20, description="Dask retries of a point after an unexpected error")
    reports: bool = Field(True, description="write each run's own report (with figures)")
    name: str | None = Field(None, pattern=r"^[A-Za-z0-9_.-]+$", description="default: the spec's name")

    @model_validator(mode="after")
    def _not_empty(self):
        if not (self.grid or self.zip or self.points):
            raise ValueError("needs at least one of grid, zip or points")
        return self


def expand_values(value: Any, where: str) -> list:
    """The values of one swept field: a list, ``{range: [start, ]stop[, step]}``, ``{linspace: [a, b, n]}``
    or a single scalar. Raises :class:`SpecError` naming ``where``."""
    if isinstance(value, list):
        if not value:
            raise SpecError(f"{where}: an empty list of values")
        return list(value)
    if isinstance(value, dict):
        if set(value) == {"range"}:
            args = value["range"] if isinstance(value["range"], list) else [value["range"]]
            if not (1 <= len(args) <= 3) or not all(isinstance(a, int) and not isinstance(a, bool) for a in args):
                raise SpecError(f"{where}: range takes 1 to 3 integers: [stop], [start, stop] or "
                                f"[start, stop, step]")
            if len(args) == 3 and args[2] == 0:
                raise SpecError(f"{where}: range step must not be 0")
            out = list(range(*args))
            if not out:
                raise SpecError(f"{where}: range {args} is empty")
            return out
        if set(value) == {"linspace"}:
            args = value["linspace"]
            if (not isinstance(args, list) or len(args) != 3 or not isinstance(args[2], int)
                    or isinstance(args[2], bool) or args[2] < 1):
                raise SpecError(f"{where}: linspace takes [start, stop, n] with an integer n >= 1")
            try:
                return [float(v) for v in np.linspace(float(args[0]), float(args[1]), args[2])]
            except (TypeError, ValueError):
                raise SpecError(f"{where}: linspace start and stop must be numbers") from None
        raise SpecError(f"{where}: give a list of values, {{range: [start, stop, step]}} or "
                        f"{{linspace: [start, stop, n]}}, not a mapping with keys {sorted(value)}")
    return [value]


def _check_path(path: Any, where: str) -> str:
    if not isinstance(path, str) or not path or any(not c for c in path.split(".")):
        raise SpecError(f"{where}: {path!r} is not a dotted path (e.g. plant.effects.stribeck.breakaway_ratio)")
    if path.split(".")[0] in FORBIDDEN_PATHS:
        raise SpecError(f"{where}: {path}: `{path.split('.')[0]}` cannot be swept")
    return path


def expand_section(section: SweepSection) -> list[dict[str, Any]]:
    """Every point of a section as a mapping ``path -> value``, in order (points x zip x grid)."""
    seen: dict[str, str] = {}

    def claim(path, part):
        if path in seen and seen[path] != part:
            raise SpecError(f"{SECTION}: {path} is varied in both {seen[path]} and {part}")
        seen[path] = part

    listed = []
    for i, p in enumerate(section.points):
        point = {}
        for path, v in p.items():
            claim(_check_path(path, f"{SECTION}.points[{i}]"), "points")
            point[path] = v
        listed.append(point)
    listed = listed or [{}]

    zipped = [{}]
    if section.zip:
        cols = {}
        for path, v in section.zip.items():
            claim(_check_path(path, f"{SECTION}.zip"), "zip")
            cols[path] = expand_values(v, f"{SECTION}.zip.{path}")
        lengths = {p: len(v) for p, v in cols.items()}
        if len(set(lengths.values())) > 1:
            raise SpecError(f"{SECTION}.zip: the lists must have equal lengths: "
                            + ", ".join(f"{p} has {n}" for p, n in lengths.items()))
        zipped = [dict(zip(cols, vals)) for vals in zip(*cols.values())]

    grid = [{}]
    if section.grid:
        cols = {}
        for path, v in section.grid.items():
            claim(_check_path(path, f"{SECTION}.grid"), "grid")
            cols[path] = expand_values(v, f"{SECTION}.grid.{path}")
        n = math.prod(len(v) for v in cols.values())
        if n * len(listed) * len(zipped) > MAX_POINTS:
            raise SpecError(f"{SECTION}: {n * len(listed) * len(zipped)} points, more than {MAX_POINTS}")
        grid = [dict(zip(cols, vals)) for vals in itertools.product(*cols.values())]

    n = len(listed) * len(zipped) * len(grid)
    if n > MAX_POINTS:
        raise SpecError(f"{SECTION}: {n} points, more than {MAX_POINTS}")
    return [{**a, **b, **c} for a in listed for b in zipped for c in grid]


def set_path(data: dict, path: str, value: Any, where: str = SECTION) -> None:
    """Set ``path`` (dotted; integer components index lists, or match integer mapping keys) in place,
    creating missing mappings. Raises :class:`SpecError` naming ``where`` and the path."""
    parts = path.split(".")
    node: Any = data
    for depth, part in enumerate(parts):
        last = depth == len(parts) - 1
        here = ".".join(parts[: depth + 1])
        if isinstance(node, list):
            try:
                i = int(part)
            except ValueError:
                raise SpecError(f"{where}: {path}: {'.'.join(parts[:depth]) or 'the spec'} is a list; "
                                f"{part!r} is not an index") from None
            if not -len(node) <= i < len(node):
                raise SpecError(f"{where}: {path}: index {i} outside the list of {len(node)}")
            if last:
                node[i] = copy.deepcopy(value)
            else:
                if node[i] is None:
                    node[i] = {}
                node = node[i]
        elif isinstance(node, dict):
            key: Any = part
            if part not in node and part.lstrip("-").isdigit() and int(part) in node:
                key = int(part)  # YAML mappings keyed by joint number: {1: {...}}
            if last:
                node[key] = copy.deepcopy(value)
            else:
                if node.get(key) is None:
                    node[key] = {}
                node = node[key]
        else:
            raise SpecError(f"{where}: {path}: cannot go into {'.'.join(parts[:depth])} = {node!r} "
                            f"(not a mapping or list) to set {here}")


def apply_values(base: dict, values: dict[str, Any], where: str = SECTION) -> dict:
    """A deep copy of ``base`` with every ``path -> value`` of ``values`` set."""
    data = copy.deepcopy(base)
    for path, value in values.items():
        set_path(data, path, value, where)
    return data


def describe_values(values: dict[str, Any], width: int = 100) -> str:
    s = ", ".join(f"{p}={_short(v)}" for p, v in values.items())
    return s if len(s) <= width else s[: width - 3] + "..."


def _short(v: Any) -> str:
    return json.dumps(v, default=str) if isinstance(v, (list, dict)) else str(v)


# ---------------------------------------------------------------------------------------------- the sweep
@dataclass
class SweepPoint:
    """One point: its id (``p0000``...), the swept values (path -> value) and its full spec mapping."""

    point_id: str
    values: dict[str, Any]
    spec: dict


@dataclass
class Sweep:
    """A parsed sweep: the spec as given (``raw``, with its vary section), the section, the points."""

    source: str
    raw: dict
    section: SweepSection
    points: list[SweepPoint]
    base_dir: Path | None
    kind: str
    name: str

    @property
    def parameters(self) -> list[str]:
        out: list[str] = []
        for p in self.points:
            out += [k for k in p.values if k not in out]
        return out

    def point(self, point_id: str) -> SweepPoint:
        for p in self.points:
            if p.point_id == point_id:
                return p
        raise KeyError(point_id)


def point_ids(n: int) -> list[str]:
    width = max(4, len(str(n - 1)))
    return [f"p{i:0{width}d}" for i in range(n)]


def sweep_from_mapping(raw: Any, source: str = "spec", base_dir: Path | None = None) -> Sweep:
    """Parse a spec mapping with a ``vary:`` section: expand and validate every point.

    Raises :class:`SpecError` (every invalid point, one line per problem, at most 20 points reported).
    """
    if not isinstance(raw, dict):
        raise SpecError(f"{source}: expected a mapping at the top level")
    if SECTION not in raw:
        raise SpecError(f"{source}: {SECTION}: missing (a sweep spec has a `{SECTION}:` section with grid, zip "
                        f"or points; `wamctl run` runs a single spec)")
    body = {k: v for k, v in raw.items() if k != SECTION}
    try:
        section = SweepSection.model_validate(raw[SECTION] if raw[SECTION] is not None else {})
    except ValidationError as exc:
        lines = []
        for err in exc.errors():
            loc = ".".join(str(x) for x in err["loc"])
            msg = "unknown key" if err["type"] == "extra_forbidden" else err["msg"].removeprefix("Value error, ")
            lines.append(f"{source}: {SECTION}{'.' + loc if loc else ''}: {msg}")
        raise SpecError("\n".join(lines)) from None
    if isinstance(body.get("plant"), str):
        body["plant"] = load_model_file(_resolve(body["plant"], base_dir))
    values = expand_section(section)
    ids = point_ids(len(values))
    points, problems, first = [], [], None
    for pid, vals in zip(ids, values):
        where = f"{source}: point {pid} ({describe_values(vals, 80)})"
        try:
            data = apply_values(body, vals, where)
            if isinstance(data.get("plant"), str):
                data["plant"] = load_model_file(_resolve(data["plant"], base_dir))
            spec = parse_spec(data, where)
        except SpecError as exc:
            problems.append(str(exc))
            continue
        points.append(SweepPoint(pid, vals, data))
        first = first or spec
    if problems:
        more = f"\n... and {len(problems) - 20} more invalid points" if len(problems) > 20 else ""
        raise SpecError(f"{len(problems)} of {len(values)} sweep points are invalid (nothing was run):\n"
                        + "\n".join(problems[:20]) + more)
    return Sweep(source, raw, section, points, base_dir, first.kind, section.name or first.name)


def _resolve(path: str, base_dir: Path | None) -> Path:
    p = Path(path)
    if not p.is_absolute() and not p.exists() and base_dir is not None:
        p = Path(base_dir) / p
    return p


def load_sweep(path: str | Path) -> Sweep:
    """Read a spec file with a ``vary:`` section (paths in it are relative to its folder)."""
    path = Path(path)
    return sweep_from_mapping(load_yaml(path), str(path), path.resolve().parent)


def check_plans(sweep: Sweep) -> list[str]:
    """Plan every point and check its setpoints against the limits (what ``wamctl validate`` does for one
    spec); nothing moves. Returns the checks of the first point; raises :class:`SpecError` naming every
    point whose plan is refused (at most 20)."""
    from wamctl.experiments.runner import plan_only
    problems, first = [], None
    for p in sweep.points:
        try:
            _, checks = plan_only(parse_spec(p.spec, p.point_id), sweep.base_dir)
        except SpecError as exc:
            problems.append(f"{sweep.source}: point {p.point_id} ({describe_values(p.values, 80)}): {exc}")
            continue
        first = first if first is not None else checks
    if problems:
        more = f"\n... and {len(problems) - 20} more" if len(problems) > 20 else ""
        raise SpecError(f"{len(problems)} of {len(sweep.points)} sweep points break a limit:\n"
                        + "\n".join(problems[:20]) + more)
    return first or []


# ---------------------------------------------------------------------------------------------- on a worker
def _run_dirs(point_dir: Path) -> list[Path]:
    if not point_dir.is_dir():
        return []
    return sorted(d for d in point_dir.iterdir() if d.is_dir() and (d / "manifest.json").is_file())


def _manifest(run_dir: Path) -> dict:
    try:
        return json.loads((Path(run_dir) / "manifest.json").read_text())
    except (OSError, json.JSONDecodeError):
        return {}


def mark_abandoned(point_dir: Path) -> list[Path]:
    """Mark the point's run directories still ``running`` as failed (their process is gone); returns them."""
    from wamctl.runs.store import RunDir
    out = []
    for d in _run_dirs(point_dir):
        if _manifest(d).get("status") == "running":
            RunDir(d).update_manifest(status="failed", reason=_ABANDONED, end_utc=utc_now())
            out.append(d)
    return out


def key_figures(report_data: dict, limit: int = 32) -> dict[str, float]:
    """The numbers of a report's ``data``: scalars, and one level of mappings (``rpe_pct.1``...)."""
    out: dict[str, float] = {}
    for k, v in report_data.items():
        if k in ("title", "tables"):
            continue
        if isinstance(v, (int, float, np.floating, np.integer)) and not isinstance(v, bool):
            out[k] = float(v)
        elif isinstance(v, dict):
            for kk, vv in v.items():
                if isinstance(vv, (int, float, np.floating, np.integer)) and not isinstance(vv, bool):
                    out[f"{k}.{kk}"] = float(vv)
        if len(out) >= limit:
            break
    return dict(itertools.islice(out.items(), limit))


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
    from wamctl.experiments.runner import RunInterrupted, run_spec
    from wamctl.report import write_report
    from wamctl.runs.store import RunDir

    t0 = time.time()
    pdir = Path(point_dir)
    pdir.mkdir(parents=True, exist_ok=True)
    mark_abandoned(pdir)
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
        dirs = _run_dirs(pdir)  # a run that started and then failed leaves its directory
        if dirs and _manifest(dirs[-1]).get("status") in ("failed", "interrupted"):
            rec["run_dir"] = str(dirs[-1])
    rec["end_unix_s"] = time.time()
    rec["attempts"] = len(_run_dirs(pdir))
    return rec


# ---------------------------------------------------------------------------------------------- the index
INDEX_COLUMNS = ["point", "status", "attempts", "run_dir", "error", "worker", "start_unix_s", "end_unix_s",
                 "duration_s"]


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


def read_index(sweep_dir: str | Path) -> pd.DataFrame:
    """The index of a sweep directory as a table (one row per point)."""
    p = Path(sweep_dir) / "index.csv"
    if not p.is_file():
        from wamctl.errors import DataFormatError
        raise DataFormatError(f"{sweep_dir}: not a sweep directory (no index.csv)")
    return pd.read_csv(p)


# ---------------------------------------------------------------------------------------------- the client
@dataclass
class SweepResult:
    sweep_dir: Path
    counts: dict[str, int]
    wall_s: float
    n_workers: int
    ran: int                      # points executed by this call
    skipped: int                  # points already completed
    efficiency: float | None      # sum of point times / (wall time x workers), this call
    max_concurrent: int
    report: list[Path] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return self.counts.get("completed", 0) == sum(self.counts.values())


def default_n_workers() -> int:
    """Cores this process may use (CPU affinity), at least 1."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:
        return max(1, os.cpu_count() or 1)


def _import_distributed():
    try:
        import distributed
    except ImportError:
        raise BackendError("wamctl sweep needs dask.distributed: pip install 'dask[distributed]'") from None
    return distributed


def start_local_cluster(n_workers: int | None = None):
    """A ``LocalCluster`` of ``n_workers`` single-threaded worker processes (default: one per core) and
    its client. Returns ``(cluster, client)``.

    The workers ignore SIGINT (a plugin, so restarted workers do too): Ctrl-C in a terminal reaches the
    whole process group, and only the client should act on it (write the index, then close the cluster).
    """
    distributed = _import_distributed()
    n = n_workers or default_n_workers()
    cluster = distributed.LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                                       dashboard_address=":0", silence_logs=logging.ERROR)
    client = distributed.Client(cluster)
    client.register_plugin(_ignore_sigint_plugin(), name="wamctl-ignore-sigint")
    return cluster, client


def _ignore_sigint_plugin():
    from distributed.diagnostics.plugin import WorkerPlugin

    class IgnoreSigint(WorkerPlugin):
        def setup(self, worker):
            import signal
            import threading
            if threading.current_thread() is threading.main_thread():
                signal.signal(signal.SIGINT, signal.SIG_IGN)

    return IgnoreSigint()


def create_sweep_dir(sweep: Sweep, out_dir: str | Path) -> Path:
    path = new_stamped_dir(out_dir, f"{sweep.name}-sweep")
    (path / "sweep.yaml").write_text(yaml.safe_dump(sweep.raw, sort_keys=False))
    manifest = {"format": SWEEP_FORMAT, "kind": sweep.kind, "name": sweep.name, "source": sweep.source,
                "base_dir": str(sweep.base_dir) if sweep.base_dir else None,
                "n_points": len(sweep.points), "parameters": sweep.parameters, "status": "created",
                "start_utc": utc_now(), "end_utc": None, "sessions": [], "host": socket.gethostname(),
                "versions": {**package_versions(), **_dask_versions()}, "git_revision": git_revision()}
    atomic_write_text(path / "sweep.json", json.dumps(manifest, indent=2, default=json_default))
    return path


def _dask_versions() -> dict:
    from importlib import metadata
    out = {}
    for n in ("dask", "distributed"):
        try:
            out[n] = metadata.version(n)
        except metadata.PackageNotFoundError:
            out[n] = None
    return out


def open_sweep_dir(sweep_dir: str | Path) -> tuple[Sweep, dict]:
    """(sweep, manifest) of an existing sweep directory, for ``--resume``."""
    d = Path(sweep_dir)
    if not (d / "sweep.json").is_file() or not (d / "sweep.yaml").is_file():
        raise SpecError(f"{d}: not a sweep directory (no sweep.json / sweep.yaml)")
    manifest = json.loads((d / "sweep.json").read_text())
    raw = yaml.safe_load((d / "sweep.yaml").read_text())
    base = Path(manifest["base_dir"]) if manifest.get("base_dir") else None
    return sweep_from_mapping(raw, manifest.get("source", str(d / "sweep.yaml")), base), manifest


def _update_manifest(sweep_dir: Path, **fields) -> dict:
    p = sweep_dir / "sweep.json"
    m = json.loads(p.read_text())
    m.update(fields)
    atomic_write_text(p, json.dumps(m, indent=2, default=json_default))
    return m


def _completed_run(point: SweepPoint, point_dir: Path, base_dir: Path | None) -> Path | None:
    """A completed run directory of this point whose resolved spec is the point's (an attempt that
    finished after the sweep was stopped), or None."""
    dirs = [d for d in _run_dirs(point_dir) if _manifest(d).get("status") == "completed"]
    if not dirs:
        return None
    want = parse_spec(point.spec, point.point_id).model_dump(mode="json")
    for d in reversed(dirs):
        try:
            if yaml.safe_load((d / "spec.yaml").read_text()) == want:
                return d
        except (OSError, yaml.YAMLError):
            continue
    return None


def _adopt(point: SweepPoint, run_dir: Path, reports: bool) -> dict:
    rec = {"point": point.point_id, "status": "completed", "run_dir": str(run_dir), "error": None,
           "attempts": len(_run_dirs(run_dir.parent)), "figures": {}}
    m = _manifest(run_dir)
    for k, src in (("start_unix_s", "start_utc"), ("end_unix_s", "end_utc")):
        try:
            rec[k] = _dt.datetime.fromisoformat(m[src]).timestamp()
        except (KeyError, TypeError, ValueError):
            rec[k] = None
    rj = run_dir / "report.json"
    if reports and not rj.is_file():
        from wamctl.report import write_report
        write_report(run_dir)
    if rj.is_file():
        rec["figures"] = key_figures(json.loads(rj.read_text()))
    return rec


def _max_concurrency(intervals: list[tuple[float, float]]) -> int:
    ev = sorted([(a, 1) for a, _ in intervals] + [(b, -1) for _, b in intervals])
    n = best = 0
    for _, d in ev:
        n += d
        best = max(best, n)
    return best


def run_sweep(sweep: Sweep, out_dir: str | Path | None = None, *, resume_dir: str | Path | None = None,
              client=None, scheduler: str | None = None, n_workers: int | None = None,
              progress: Callable[[int, int, str | None], None] | None = None,
              on_point: Callable[[dict], None] | None = None) -> SweepResult:
    """Run every point of ``sweep`` that is not completed yet, on Dask, into a sweep directory.

    Parameters
    ----------
    sweep : the parsed sweep (:func:`load_sweep`, :func:`open_sweep_dir`).
    out_dir : parent of a new sweep directory (default: the spec's ``out_dir``). Ignored with ``resume_dir``.
    resume_dir : an existing sweep directory: its completed points are skipped.
    client : a ``distributed.Client`` to use (not closed here); else ``scheduler`` (an address) or a new
        ``LocalCluster`` of ``n_workers`` processes (default one per core), closed at the end.
    progress : ``progress(done, total, label)`` after every point.
    on_point : called with each point's index row as it finishes.

    Raises
    ------
    SweepInterrupted on Ctrl-C / SIGTERM (the index is written first); BackendError if the cluster cannot
    be reached.
    """
    from wamctl.experiments.runner import signals_as_interrupt

    if resume_dir is not None:
        sweep_dir = Path(resume_dir)
        index = SweepIndex.load(sweep_dir, sweep)
    else:
        sweep_dir = create_sweep_dir(sweep, out_dir or sweep.raw.get("out_dir", "runs"))
        index = SweepIndex(sweep_dir, sweep)
    sweep_dir = sweep_dir.resolve()
    index.dir = sweep_dir
    runs_root = sweep_dir / "runs"

    # what is left: completed points whose run directory is still there are skipped; a point whose
    # attempt completed after the sweep was stopped is adopted
    todo, skipped = [], 0
    for p in sweep.points:
        row = index.rows[p.point_id]
        if row["status"] == "completed" and row["run_dir"] and \
                _manifest(sweep_dir / row["run_dir"]).get("status") == "completed":
            skipped += 1
            continue
        found = _completed_run(p, runs_root / p.point_id, sweep.base_dir) if resume_dir else None
        if found is not None:
            index.update(_adopt(p, found, sweep.section.reports))
            skipped += 1
            continue
        if row["status"] == "completed":  # its run directory was deleted
            row.update(status="pending", run_dir=None, figures={})
        todo.append(p)
    index.write()
    total = len(sweep.points)

    session = {"start_utc": utc_now(), "todo": len(todo), "skipped": skipped}
    own_cluster = cluster = None
    t_start = time.time()
    intervals: list[tuple[float, float]] = []
    ran = 0
    interrupted = False
    futures = {}
    try:
        with signals_as_interrupt():
            try:
                if todo and client is None:
                    distributed = _import_distributed()
                    try:
                        if scheduler:
                            client = own_cluster = distributed.Client(scheduler, timeout="20s")
                        else:
                            cluster, client = start_local_cluster(n_workers)
                            own_cluster = client
                    except (OSError, TimeoutError) as exc:
                        raise BackendError(f"cannot reach the Dask scheduler {scheduler or '(local)'}: "
                                           f"{exc}") from None
                workers = client.scheduler_info()["workers"] if client is not None else {}
                session.update(scheduler=scheduler or ("local" if cluster is not None else "given client"),
                               n_workers=len(workers),
                               threads=sum(w.get("nthreads", 1) for w in workers.values()))
                _update_manifest(sweep_dir, status="running", sessions=_sessions(sweep_dir) + [session])
                done = total - len(todo)
                if progress:
                    progress(done, total, _label(sweep, index))
                if todo:
                    from distributed import as_completed
                    token = uuid.uuid4().hex[:8]
                    for p in todo:
                        fut = client.submit(run_point, p.spec, p.point_id, str(runs_root / p.point_id),
                                            str(sweep.base_dir) if sweep.base_dir else None, p.values,
                                            str(sweep_dir), sweep.section.reports,
                                            key=f"wamctl-sweep-{token}-{p.point_id}", pure=False,
                                            retries=sweep.section.retries)
                        futures[fut.key] = (fut, p)
                    for fut in as_completed([f for f, _ in futures.values()]):
                        p = futures.pop(fut.key)[1]  # first: an interrupt from here on leaves its row alone
                        rec = _record_of(fut, p, runs_root / p.point_id)
                        index.update(rec)
                        index.write()
                        if rec.get("start_unix_s") and rec.get("end_unix_s"):
                            intervals.append((rec["start_unix_s"], rec["end_unix_s"]))
                        ran += 1
                        done += 1
                        if on_point:
                            on_point(dict(index.rows[p.point_id]))
                        if progress:
                            progress(done, total, _label(sweep, index))
            except KeyboardInterrupt:
                interrupted = True
                try:  # first stop the scheduler from starting more points
                    client.cancel([f for f, _ in futures.values()])
                except Exception:  # noqa: BLE001 - best effort; the cluster may be gone already
                    pass
                for _fut, p in futures.values():
                    started = any(_manifest(d).get("status") == "running" for d in _run_dirs(runs_root / p.point_id))
                    index.rows[p.point_id]["status"] = "interrupted" if started else "pending"
                index.write()
    finally:
        wall = time.time() - t_start
        busy = sum(b - a for a, b in intervals)
        n_w = session.get("n_workers") or 0
        session.update(end_utc=utc_now(), wall_s=wall, ran=ran,
                       efficiency=(busy / (wall * n_w)) if ran and n_w and wall > 0 else None,
                       max_concurrent=_max_concurrency(intervals), interrupted=interrupted)
        counts = index.counts()
        finished = counts["pending"] == 0 and counts["interrupted"] == 0
        sessions = _sessions(sweep_dir)
        sessions[-1:] = [session] if sessions and sessions[-1].get("start_utc") == session["start_utc"] \
            else sessions[-1:] + [session]
        _update_manifest(sweep_dir, sessions=sessions, counts=counts,
                         status="completed" if finished else ("interrupted" if interrupted else "incomplete"),
                         end_utc=utc_now())
        if own_cluster is not None:
            _close_quietly(own_cluster, cluster)
    written = write_sweep_report(sweep_dir)
    result = SweepResult(sweep_dir, counts, wall, n_w, ran, skipped, session["efficiency"],
                         session["max_concurrent"], written)
    if interrupted:
        missing = counts["pending"] + counts["interrupted"]
        raise SweepInterrupted(f"{sweep_dir}: sweep interrupted, {counts['completed']} of {total} points "
                               f"completed; `wamctl sweep --resume {sweep_dir}` runs the {missing} missing "
                               f"points" + (f" and the {counts['failed']} failed ones" if counts["failed"] else ""))
    return result


def _sessions(sweep_dir: Path) -> list:
    return json.loads((sweep_dir / "sweep.json").read_text()).get("sessions", [])


def _label(sweep: Sweep, index: SweepIndex) -> str:
    c = index.counts()
    return f"sweep {sweep.name}: {c['completed']} completed, {c['failed']} failed"


def _record_of(fut, point: SweepPoint, point_dir: Path) -> dict:
    """The index record of a finished future: its result, or its error (after Dask's retries)."""
    if fut.status == "finished":
        return fut.result()
    rec = {"point": point.point_id, "status": "failed", "run_dir": None, "attempts": len(_run_dirs(point_dir)),
           "end_unix_s": time.time(), "start_unix_s": None}
    if fut.status == "cancelled":
        rec["status"] = "pending"
        return rec
    try:
        exc = fut.exception()
    except Exception as err:  # noqa: BLE001 - e.g. a lost future
        exc = err
    name = type(exc).__name__
    if name == "KilledWorker":
        rec["error"] = (f"KilledWorker: the workers running this point died "
                        f"{rec['attempts'] or 'repeatedly'} times; the point was given up")
    else:
        rec["error"] = f"{name}: {exc}"
    mark_abandoned(point_dir)
    dirs = _run_dirs(point_dir)
    if dirs:
        rec["run_dir"] = str(dirs[-1])
    return rec


def _close_quietly(client, cluster) -> None:
    for obj in (client, cluster):
        if obj is None:
            continue
        try:
            obj.close(timeout=10) if obj is client else obj.close(timeout=20)
        except Exception:  # noqa: BLE001 - shutting down after Ctrl-C or a lost cluster
            log.debug("closing %s failed", obj, exc_info=True)


# ---------------------------------------------------------------------------------------------- report
def sweep_report(sweep_dir: str | Path) -> Document:
    """The combined report of a sweep directory: the index, the key figures of every point, and their means
    per value of each swept parameter (parameters with 2..20 distinct values)."""
    d = Path(sweep_dir)
    m = json.loads((d / "sweep.json").read_text())
    idx = read_index(d)
    params = [p for p in m.get("parameters", []) if p in idx.columns]
    counts = idx["status"].value_counts().to_dict()
    doc = Document(f"Sweep {m.get('name')}: {len(idx)} points of {m.get('kind')}")
    doc.text(f"Spec {m.get('source')}; swept: {', '.join(params) or 'nothing'}. Status: "
             + ", ".join(f"{counts.get(s, 0)} {s}" for s in STATUSES if counts.get(s, 0)) + ".")
    for i, s in enumerate(m.get("sessions", [])):
        if s.get("wall_s") is None:
            continue
        eff = s.get("efficiency")
        doc.text(f"Session {i + 1} ({s.get('start_utc')}): {s.get('ran', 0)} points run, {s.get('skipped', 0)} "
                 f"skipped as completed, {s.get('wall_s', 0):.1f} s on {s.get('n_workers')} workers "
                 f"({s.get('scheduler')}); at most {s.get('max_concurrent')} points at once"
                 + (f", workers busy {100 * eff:.0f} % of the time" if eff is not None else "")
                 + (" - interrupted" if s.get("interrupted") else "") + ".")
    base = ["point"] + params + ["status", "attempts", "duration_s", "run_dir", "error"]
    doc.heading("Points")
    doc.table("points", idx[[c for c in base if c in idx.columns]].set_index("point"),
              "run_dir is relative to the sweep directory; each run has its own report there.", digits=3)
    figs = [c for c in idx.columns if c not in set(INDEX_COLUMNS) | set(params) | {"pid"}]
    figs = [c for c in figs if pd.api.types.is_numeric_dtype(idx[c])]
    ok = idx[idx["status"] == "completed"]
    doc.data["counts"] = {str(k): int(v) for k, v in counts.items()}
    if figs and len(ok):
        doc.heading("Key figures per point")
        doc.table("key_figures", ok[["point"] + params + figs].set_index("point"),
                  "numbers from each run's report (e.g. rpe_pct.j: RPE of joint j, %)")
        for p in params:
            nvals = ok[p].nunique()
            if 2 <= nvals <= 20:
                g = ok.groupby(p)[figs].mean()
                g.insert(0, "n_points", ok.groupby(p).size())
                doc.heading(f"Mean key figures by {p}")
                doc.table(f"by_{p}", g, f"means over the completed points with each value of {p}")
                doc.data.setdefault("by_parameter", {})[p] = json.loads(g.to_json(orient="index"))
    return doc


def write_sweep_report(sweep_dir: str | Path, formats=("md", "html", "json")) -> list[Path]:
    return sweep_report(sweep_dir).write(Path(sweep_dir), "report", formats)
