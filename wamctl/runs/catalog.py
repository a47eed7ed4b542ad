"""The lab's runs at a glance: the run directories under one or more folders, each with its status as it
stands (a ``running`` manifest whose process is gone is ``abandoned``), its duration and the figure that matters
for its kind, read from what the run already wrote (its report's JSON, its result files), never its data.

Liveness (:func:`liveness`): a manifest records the host and pid of the process that wrote it and its start
time. On the same host, the run is alive when that pid exists, is a Python or wamctl process, and started no
later than the run did (a pid reused by a later process is not the run's); otherwise it is dead. A run of
another host cannot be checked from here: it is shown ``running? (host X)`` and never marked.

:func:`mark_abandoned` records a dead run as ``interrupted`` (reason :data:`ABANDONED_REASON`), after
consolidating the chunks of its tables with the store's reader and writer (every sample kept).
"""

from __future__ import annotations

import datetime as _dt
import json
import os
import socket
from dataclasses import asdict, dataclass, field
from pathlib import Path

from wamctl.errors import DataFormatError

ABANDONED_REASON = "process ended without closing the run"
ABANDONED = "abandoned"
"""The status shown for a run whose manifest says ``running`` while its process is gone."""
_MAX_DEPTH = 4          # runs/<sweep>/points/<point>/<run>: how deep a folder is searched for run directories
_PARTS_RESUMED_FROM = {"hmi_block": ("trajectory",)}
"""Tables whose parts a kind's ``--resume`` reads back (an HMI block's trajectory: one part per trial, all of
them consolidated again at the block's end): marking keeps them beside the consolidated file."""
_START_SLACK_S = 2.0    # a process started this much after the manifest's start time is not the run's


@dataclass
class RunEntry:
    """One run directory as listed by ``wamctl runs``."""

    path: str
    kind: str
    name: str
    status: str               # as shown: completed, failed, interrupted, running, abandoned, running? (host X)
    manifest_status: str      # as written in the manifest
    start_utc: str | None
    end_utc: str | None
    duration_s: float | None
    backend: str
    headline: str             # the kind's figure, in words ("RPE max 3.2 % (joint 4)")
    figures: dict = field(default_factory=dict)   # the same as numbers, for scripts
    reason: str | None = None
    host: str | None = None
    report: str | None = None  # report.html, when written

    def to_json(self) -> dict:
        return asdict(self)


# ----------------------------------------------------------------------------------------------- finding runs
def find_run_dirs(folders: list[Path]) -> list[Path]:
    """Every run directory (a folder with ``manifest.json``) given or under ``folders``, searched
    :data:`_MAX_DEPTH` levels deep (sweeps hold their points' runs), not inside a run directory."""
    found: list[Path] = []

    def walk(d: Path, depth: int) -> None:
        if (d / "manifest.json").is_file():
            found.append(d)
            return
        if depth >= _MAX_DEPTH:
            return
        try:
            children = sorted(e.path for e in os.scandir(d) if e.is_dir() and not e.name.startswith("."))
        except OSError:
            return
        for c in children:
            walk(Path(c), depth + 1)

    for f in folders:
        walk(Path(f), 0)
    return list(dict.fromkeys(found))


def read_json(path: Path) -> dict:
    """A JSON object from a file, empty when it is missing or unreadable (a listing never fails on one run)."""
    try:
        obj = json.loads(Path(path).read_text())
    except (OSError, ValueError):
        return {}
    return obj if isinstance(obj, dict) else {}


# ----------------------------------------------------------------------------------------------- liveness
def parse_utc(text: str | None) -> _dt.datetime | None:
    if not text:
        return None
    try:
        t = _dt.datetime.fromisoformat(str(text).replace("Z", "+00:00"))
    except ValueError:
        return None
    return t if t.tzinfo else t.replace(tzinfo=_dt.timezone.utc)


def _boot_time_s() -> float | None:
    try:
        for line in Path("/proc/stat").read_text().splitlines():
            if line.startswith("btime "):
                return float(line.split()[1])
    except OSError:
        pass
    return None


def process_start_unix_s(pid: int) -> float | None:
    """When process ``pid`` started (Unix time, to the clock tick) from /proc, or None where /proc has no
    answer."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    boot = _boot_time_s()
    if boot is None:
        return None
    fields = stat[stat.rfind(")") + 2:].split()     # after "pid (comm) ": state is field 3, starttime field 22
    try:
        return boot + int(fields[19]) / os.sysconf("SC_CLK_TCK")
    except (IndexError, ValueError, OSError):
        return None


def _process_cmdline(pid: int) -> str | None:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
    except OSError:
        return None


def pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:         # exists, another user's
        return True
    except OSError:
        return False
    return True


def liveness(manifest: dict, this_host: str | None = None) -> str:
    """``alive``, ``dead`` or ``other_host`` for a manifest that says ``running``."""
    host = manifest.get("host")
    if host and host != (this_host or socket.gethostname()):
        return "other_host"
    try:
        pid = int(manifest.get("pid"))
    except (TypeError, ValueError):
        return "dead"
    if pid <= 0 or not pid_alive(pid):
        return "dead"
    started = process_start_unix_s(pid)
    run_start = parse_utc(manifest.get("start_utc"))
    if started is not None and run_start is not None and started > run_start.timestamp() + _START_SLACK_S:
        return "dead"               # the pid was reused by a process that started after the run
    cmd = _process_cmdline(pid)
    if cmd is not None and cmd.strip() and not any(w in cmd.lower() for w in ("python", "wamctl", "pytest")):
        return "dead"               # not a process that runs wamctl
    return "alive"


def shown_status(manifest: dict, this_host: str | None = None) -> str:
    """The status as it stands: the manifest's, but ``abandoned`` for a ``running`` run whose process is gone
    and ``running? (host X)`` for a ``running`` run of another host."""
    status = str(manifest.get("status") or "unknown")
    if status != "running":
        return status
    live = liveness(manifest, this_host)
    if live == "dead":
        return ABANDONED
    if live == "other_host":
        return f"running? (host {manifest.get('host')})"
    return "running"


# ----------------------------------------------------------------------------------------------- headlines
def _g(x: float) -> str:
    return f"{x:.3g}"


def _rotation(path: Path, rep: dict) -> tuple[str, dict]:
    rpe = {k: float(v) for k, v in (rep.get("rpe_pct") or {}).items() if v is not None}
    if not rpe:
        return "", {}
    j = max(rpe, key=lambda k: abs(rpe[k]))
    return f"RPE {_g(rpe[j])} % j{j}", {"rpe_max_pct": rpe[j], "rpe_max_joint": int(j)}


def _ift(path: Path, rep: dict) -> tuple[str, dict]:
    per = rep.get("J") or {}
    try:
        j0 = sum(float(v["initial"]) for v in per.values())
        j1 = sum(float(v["tuned"]) for v in per.values())
    except (KeyError, TypeError, ValueError):
        return "", {}
    if not per:
        return "", {}
    return f"J {_g(j0)} -> {_g(j1)}", {"J_initial": j0, "J_tuned": j1, "joints": len(per)}


def _hmi(path: Path, rep: dict) -> tuple[str, dict]:
    h = rep.get("hmi") or {}
    if not h:
        try:                        # no report yet: the trials table the block writes
            import pandas as pd
            t = pd.read_csv(path / "trials.csv")
            times = t["time_s"].dropna()
            h = {"trials": len(t), "hits": int(t["hit"].sum()), "hit_pct": 100.0 * t["hit"].mean() if len(t) else 0,
                 "mean_time_s": float(times.mean()) if len(times) else None}
        except (OSError, KeyError, ValueError, ImportError):
            return "", {}
    if not h.get("trials"):
        return "no trial", {"trials": 0}
    mean = h.get("mean_time_s")
    text = f"hit {h['hits']}/{h['trials']}" + (f" {mean:.1f}s" if mean is not None else "")
    return text, {k: h.get(k) for k in ("trials", "hits", "hit_pct", "mean_time_s")}


def _diagnosis(path: Path, rep: dict) -> tuple[str, dict]:
    d = read_json(path / "diagnosis.json")
    found = d.get("effects_found")
    if found is None:
        found = (rep.get("diagnosis") or {}).get("effects_found")
    if found is None:
        return "", {}
    text = f"{len(found)} effect{'s' if len(found) != 1 else ''}" + (f": {', '.join(found)}" if found else "")
    return text, {"effects_found": list(found)}


def _friction(path: Path, rep: dict) -> tuple[str, dict]:
    chosen = rep.get("chosen_model")
    if chosen is None:
        chosen = {j: (v or {}).get("chosen") if isinstance(v, dict) else v
                  for j, v in (read_json(path / "identification.json").get("joints") or {}).items()}
    if not chosen:
        return "", {}
    joints = sorted(chosen, key=lambda j: int(j) if str(j).isdigit() else 0)
    return (f"{len(joints)} joint{'s' if len(joints) != 1 else ''} ({','.join(map(str, joints))})",
            {"joints_identified": [int(j) for j in joints if str(j).isdigit()]})


def _identification(path: Path, rep: dict) -> tuple[str, dict]:
    check = read_json(path / "identification.json").get("held_out_check") or rep.get("held_out_check") or {}
    verdict = check.get("verdict")
    if not verdict:
        return "", {}
    return f"held-out {verdict}", {"held_out_verdict": verdict}


_HEADLINES = {"rotation": _rotation, "ift": _ift, "hmi_block": _hmi, "diagnosis": _diagnosis,
              "friction_sweep": _friction, "identification": _identification}


def headline(path: Path, kind: str) -> tuple[str, dict]:
    """The figure that matters for a run of ``kind``, as words and as numbers (empty when the run wrote none),
    followed by the count of its report's warnings (a joint at its torque limit, a tracking error: the figure
    alone would read as a clean run)."""
    fn = _HEADLINES.get(kind)
    if fn is None:
        return "", {}
    rep = read_json(Path(path) / "report.json")
    words, numbers = fn(Path(path), rep)
    n = len(rep.get("warnings") or [])        # read_json gives a dict, empty when there is no report
    if n:
        count = f"{n} warning{'s' if n > 1 else ''}"
        words, numbers = (f"{words}; {count}" if words else count), dict(numbers, warnings=n)
    return words, numbers


# ----------------------------------------------------------------------------------------------- the listing
def _last_write_unix_s(path: Path) -> float | None:
    """The latest modification time of the run directory's entries and of its tables' chunk folders (one level
    down), a dead run's last sign of life."""
    best = None
    try:
        for e in os.scandir(path):
            t = e.stat().st_mtime
            best = t if best is None or t > best else best
    except OSError:
        pass
    return best


def entry(path: Path, this_host: str | None = None) -> RunEntry:
    """The listing's entry of one run directory (DataFormatError when its manifest cannot be read)."""
    path = Path(path)
    m = read_json(path / "manifest.json")
    if not m:
        raise DataFormatError(f"{path}: manifest.json missing or not a JSON object")
    status = shown_status(m, this_host)
    start, end = parse_utc(m.get("start_utc")), parse_utc(m.get("end_utc"))
    duration = None
    if start is not None:
        if end is not None:
            duration = (end - start).total_seconds()
        elif status == "running":
            duration = _dt.datetime.now(_dt.timezone.utc).timestamp() - start.timestamp()
        elif status == ABANDONED:
            last = _last_write_unix_s(path)
            duration = None if last is None else max(0.0, last - start.timestamp())
    backend = m.get("backend")
    backend = (backend.get("name") or backend.get("kind")) if isinstance(backend, dict) else backend
    kind = str(m.get("kind") or "unknown")
    text, figures = headline(path, kind)
    report = path / "report.html"
    return RunEntry(path=str(path), kind=kind, name=str(m.get("name") or path.name), status=status,
                    manifest_status=str(m.get("status")), start_utc=m.get("start_utc"), end_utc=m.get("end_utc"),
                    duration_s=duration, backend=str(backend or "-"), headline=text, figures=figures,
                    reason=m.get("reason"), host=m.get("host"), report=str(report) if report.is_file() else None)


def parse_since(text: str) -> _dt.datetime:
    """``--since``: a date (2026-11-26) or a date and time (2026-11-26T14:00, UTC unless it says otherwise)."""
    t = parse_utc(text)
    if t is None:
        raise DataFormatError(f"--since: {text!r} is not a date (2026-11-26) or a date and time (2026-11-26T14:00)")
    return t


def list_runs(folders: list[Path], kind: str | None = None, status: str | None = None,
              since: _dt.datetime | None = None) -> list[RunEntry]:
    """Every run directory under ``folders``, newest first, filtered by kind, shown status (``running``
    matches ``running? (host X)`` too) and start time. A folder that does not exist is a DataFormatError."""
    for f in folders:
        if not Path(f).exists():
            raise DataFormatError(f"{f}: no such directory")
    host = socket.gethostname()
    out = []
    for d in find_run_dirs(folders):
        try:
            e = entry(d, host)
        except DataFormatError:
            continue
        if kind and e.kind != kind:
            continue
        if status and e.status != status and not (status == "running" and e.status.startswith("running")):
            continue
        if since is not None:
            t = parse_utc(e.start_utc)
            if t is None or t < since:
                continue
        out.append(e)
    out.sort(key=lambda e: (parse_utc(e.start_utc) or _dt.datetime.min.replace(tzinfo=_dt.timezone.utc)).timestamp(),
             reverse=True)
    return out


def format_duration(seconds: float | None) -> str:
    if seconds is None:
        return "-"
    s = int(round(seconds))
    if seconds < 60:
        return f"{seconds:.1f}s" if seconds < 10 else f"{s}s"
    if s < 3600:
        return f"{s // 60}m{s % 60:02d}s"
    if s < 86400:
        return f"{s // 3600}h{s % 3600 // 60:02d}m"
    return f"{s // 86400}d{s % 86400 // 3600:02d}h"


KIND_LABELS = {"friction_sweep": "friction", "hmi_block": "hmi", "identification": "identify"}
"""Kinds shortened for an 80-column terminal."""


def format_start(start_utc: str | None, short: bool = False) -> str:
    """``2026-11-26 19:40``; ``short``: ``11-26 19:40`` in the current year."""
    t = parse_utc(start_utc)
    if t is None:
        return "-"
    if short and t.year == _dt.datetime.now(_dt.timezone.utc).year:
        return t.strftime("%m-%d %H:%M")
    return t.strftime("%Y-%m-%d %H:%M")


# ----------------------------------------------------------------------------------------------- marking
def mark_abandoned(path: Path, known_dead: str | None = None) -> bool:
    """Record a dead run (shown ``abandoned``) as ``interrupted`` with :data:`ABANDONED_REASON`: each table's
    chunks consolidated into ``<table>.parquet``/``.csv`` by the store (every sample kept; the chunks stay if
    anything fails), then the manifest. Returns False (nothing written) for a run that is not abandoned.

    ``known_dead``: the caller knows the run's process is gone though its pid cannot tell (a sweep whose own
    cluster is closed, a point that Dask gave to another worker); said in the manifest (``abandoned.known_by``).
    The run must still say ``running``."""
    from wamctl.runs.store import RunDir, read_chunks, remove_chunks, signals_deferred, utc_now, write_table_pair

    path = Path(path)
    m = read_json(path / "manifest.json")
    if (m.get("status") != "running") if known_dead else (shown_status(m) != ABANDONED):
        return False
    consolidated = {}
    for d in sorted(p for p in path.iterdir() if p.is_dir()):
        if not any(d.glob("part-*.parquet")):
            continue
        df = read_chunks(d)
        write_table_pair(df, path, d.name)
        if d.name not in _PARTS_RESUMED_FROM.get(m.get("kind"), ()):
            remove_chunks(path, d.name, len(df))
        consolidated[d.name] = len(df)
    last = _last_write_unix_s(path)
    last_utc = (_dt.datetime.fromtimestamp(last, _dt.timezone.utc).isoformat(timespec="milliseconds")
                if last else utc_now())
    with signals_deferred():       # the end is the run's last write; when it was marked is said beside it
        RunDir(path).update_manifest(status="interrupted", reason=ABANDONED_REASON, end_utc=last_utc,
                                     abandoned={"marked_utc": utc_now(), "rows": consolidated,
                                                "known_by": known_dead or "its pid (gone)"})
    return True


def ready_to_resume(path: Path) -> str:
    """Before ``--resume``: a run whose process is still alive here, or that says ``running`` on another host
    (which cannot be checked from here), is refused in one line; an abandoned one is first recorded as
    ``--mark-abandoned`` does (its chunks consolidated: the resumed run's own chunks, numbered from 0, must not
    overwrite them). Returns the status as it was shown."""
    from wamctl.errors import SpecError

    path = Path(path)
    m = read_json(path / "manifest.json")
    if not m:
        raise SpecError(f"{path}: --resume needs a run directory (no readable manifest.json there)")
    status = shown_status(m)
    if status == "running":
        raise SpecError(f"{path}: the run is still running (pid {m.get('pid')} on this host); stop it (Ctrl-C) "
                        f"or wait for it before --resume")
    if status.startswith("running?"):
        raise SpecError(f"{path}: the run says running on host {m.get('host')}, which cannot be checked from "
                        f"here; resume it there, or mark it with `wamctl runs --mark-abandoned` on that host")
    if status == ABANDONED:
        mark_abandoned(path)
    return status
