"""Run directories: one self-describing folder per run.

Layout of ``<out>/<UTC timestamp>-<name>/``::

    spec.yaml          the resolved spec (every default filled in)
    manifest.json      seed, versions, git revision, backend, host, start/end, status and its reason
    data/part-*.parquet  sampled data, written in chunks while the run goes (each chunk a complete file)
    data.parquet       the same rows consolidated when the run ends (completed, failed or interrupted), every
                       bit; the chunks are removed once it is written and holds all their rows
    data.csv           a readable copy, floats to CSV_SIGNIFICANT_DIGITS of each column's largest value
    events.csv         t_s (to the microsecond), kind, joint, detail: segment starts, faults, notes; a run that
                       ended ``interrupted`` or ``failed`` drops the planned events after its last sample
                       (what happened is kept) and ends with one row of that kind, its detail the reason
    report.md/.html, *.png   the report

Status is ``running`` until the run ends, then ``completed``, ``failed`` (with the reason) or
``interrupted`` (Ctrl-C or a termination signal). Chunk writes, the run directory's creation, the final
status and file renames hold Ctrl-C, SIGTERM and SIGHUP back (:func:`signals_deferred`): an interrupt lands
before or after them, never inside. A run killed outright (SIGKILL, power) stays ``running`` with its chunks
readable; :func:`read_table` reads chunks when the consolidated file is missing.
"""

from __future__ import annotations

import datetime as _dt
import json
import logging
import os
import platform
import signal
import socket
import subprocess
import threading
from collections.abc import Callable
from contextlib import contextmanager
from functools import lru_cache
from importlib import metadata
from pathlib import Path

import numpy as np
import pandas as pd
import yaml

from wamctl.errors import DataFormatError
from wamctl.io import ensure_dir, parse_yaml, read_text

log = logging.getLogger(__name__)

MANIFEST_FORMAT = "wamctl-run/1"
_DEPENDENCIES = ("numpy", "scipy", "pandas", "pyarrow", "pin", "numba", "python-can", "pyserial",
                 "statsmodels", "pydantic", "typer", "matplotlib")


def utc_now() -> str:
    return _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="milliseconds")


@lru_cache(maxsize=1)
def _versions() -> tuple:
    out = []
    for name in ("wamctl",) + _DEPENDENCIES:
        try:
            out.append((name, metadata.version(name)))
        except metadata.PackageNotFoundError:
            out.append((name, None))
    return tuple(out)


def package_versions() -> dict[str, str | None]:
    """The versions of wamctl and its dependencies in this process (looked up once)."""
    return dict(_versions())


@lru_cache(maxsize=1)
def git_revision() -> str | None:
    """The source checkout's revision (with ``+dirty`` when it has changes), or None; looked up once per
    process (the code running is the code loaded at its start)."""
    here = Path(__file__).resolve().parent
    try:
        rev = subprocess.run(["git", "rev-parse", "HEAD"], cwd=here, capture_output=True, text=True, timeout=5)
        if rev.returncode != 0:
            return None
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=here,
                               capture_output=True, text=True, timeout=5)
        return rev.stdout.strip() + ("+dirty" if dirty.stdout.strip() else "")
    except (OSError, subprocess.SubprocessError):
        return None


class TableWriter:
    """Appends rows to a chunked Parquet table; ``close()`` consolidates Parquet + CSV and removes the chunks.

    Rows are buffered in a preallocated array and flushed every ``chunk_rows`` rows, so a crash loses at
    most one chunk and a termination signal loses nothing. A chunk is written with Ctrl-C, SIGTERM and SIGHUP
    held back (:func:`signals_deferred`), so an interrupt never tears it; every method leaves the writer
    consistent whatever moment an exception lands, and ``flush``/``close`` may be called again after one.
    """

    def __init__(self, run_dir: Path, name: str, columns: list[str], chunk_rows: int = 2500,
                 before_consolidating: Callable[[], None] | None = None):
        self.run_dir = Path(run_dir)
        self.name = name
        self.columns = list(columns)
        self.chunk_rows = int(chunk_rows)
        self._dir = self.run_dir / name
        self._dir.mkdir(parents=True, exist_ok=True)
        self._buf = np.empty((self.chunk_rows, len(self.columns)))
        self._n = 0
        self._parts = 0
        self.rows_written = 0
        self.closed = False
        self.before_consolidating = before_consolidating
        """Called by :meth:`close` before it consolidates (the seconds a long run's table takes)."""
        self._t_col = self.columns.index("t_s") if "t_s" in self.columns else None
        self.last_t_s: float | None = None
        """``t_s`` of the last row handed to the writer (None: no row yet, or no ``t_s`` column)."""

    @property
    def rows_total(self) -> int:
        """Rows handed to the writer so far (on disk or buffered)."""
        return self.rows_written + self._n

    def append(self, row: np.ndarray) -> None:
        """One row (len(columns),)."""
        if self._n == self.chunk_rows:      # a flush that raised (disk full) is retried before the buffer overflows
            self.flush()
        self._buf[self._n] = row
        self._n += 1
        if self._t_col is not None:
            self.last_t_s = float(row[self._t_col])
        if self._n == self.chunk_rows:
            self.flush()

    def sync(self, rows: np.ndarray, n: int) -> None:
        """Make the table hold the first ``n`` rows of ``rows`` (all rows so far of a recorder): the ones it does
        not have yet are appended, with signals held back. Idempotent: calling it again after an interrupt or
        an error anywhere neither loses nor repeats a row."""
        with signals_deferred():
            while self.rows_total < n:
                if self._n == self.chunk_rows:
                    self.flush()
                k = min(n - self.rows_total, self.chunk_rows - self._n)
                self._buf[self._n: self._n + k] = rows[self.rows_total: self.rows_total + k]
                self._n += k
                if self._n == self.chunk_rows:
                    self.flush()
            if n and self._t_col is not None:
                self.last_t_s = float(rows[n - 1, self._t_col])

    def flush(self) -> None:
        """Write the buffered rows as the next chunk (a complete file or none; signals held back meanwhile)."""
        if self._n == 0:
            return
        with signals_deferred():
            df = pd.DataFrame(self._buf[: self._n].copy(), columns=self.columns)
            part = self._dir / f"part-{self._parts:05d}.parquet"
            atomic_write(part, lambda tmp: df.to_parquet(tmp, index=False))   # appears complete or not at all
            self._parts += 1
            self.rows_written += self._n
            self._n = 0

    def close(self) -> pd.DataFrame:
        """Flush, consolidate ``<name>.parquet`` and ``<name>.csv``, then remove the chunks (kept if anything
        fails; :func:`read_table` reads them). Idempotent; may be called again after an interrupt."""
        self.flush()
        if self.closed:
            return read_table(self.run_dir, self.name)
        if self.before_consolidating is not None:
            self.before_consolidating()
        df = read_chunks(self._dir, self.columns)
        write_table_pair(df, self.run_dir, self.name)
        remove_chunks(self.run_dir, self.name, len(df))
        self.closed = True
        return df


def remove_chunks(run_dir: Path, name: str, rows: int) -> bool:
    """Remove the chunk directory ``<name>/`` once ``<name>.parquet`` is readable and holds ``rows`` rows (the
    rows of the chunks); keep it otherwise. Returns whether it was removed."""
    run_dir = Path(run_dir)
    try:
        import pyarrow.parquet as pq
        ok = pq.ParquetFile(run_dir / f"{name}.parquet").metadata.num_rows == rows
    except (OSError, ValueError):
        ok = False
    if not ok:
        log.warning("%s: %s.parquet does not hold the %d rows of its chunks; the chunks stay", run_dir, name, rows)
        return False
    with signals_deferred():
        for p in sorted((run_dir / name).glob("*part-*")):
            p.unlink(missing_ok=True)
        try:
            (run_dir / name).rmdir()
        except OSError:           # something else in it: leave it
            pass
    return True


def write_table_pair(df: pd.DataFrame, run_dir: Path, name: str) -> None:
    """``<name>.parquet`` and ``<name>.csv`` in ``run_dir``: both or neither. Both are written to temporary
    files first, then renamed in place with termination signals held back, so that an interrupt (Ctrl-C,
    SIGTERM) at any moment leaves the previous pair (or none, and the chunks) rather than one without the
    other."""
    run_dir = Path(run_dir)
    final = [run_dir / f"{name}.parquet", run_dir / f"{name}.csv"]
    tmp = [p.with_name(f".{p.name}.tmp") for p in final]
    try:
        df.to_parquet(tmp[0], index=False)
        write_csv(df, tmp[1], CSV_SIGNIFICANT_DIGITS)
        with signals_deferred():
            for t, f in zip(tmp, final):
                os.replace(t, f)
    finally:
        for t in tmp:
            t.unlink(missing_ok=True)


_DEFERRABLE = tuple(s for s in (getattr(signal, n, None) for n in ("SIGINT", "SIGTERM", "SIGHUP")) if s)


@contextmanager
def signals_deferred():
    """Hold back Ctrl-C (SIGINT), SIGTERM and SIGHUP inside the block; each one that came is delivered to the
    handler in force before the block as soon as it ends.

    The Python handlers are swapped (in the main thread, where Python runs them; elsewhere nothing changes),
    not the thread's signal mask: a mask does not stop another thread (pyarrow's pool) from taking a
    process-directed signal and Python from then running its handler here. Blocks nest; an ignored signal
    stays ignored."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    caught: list[int] = []
    old = {}
    try:
        for s in _DEFERRABLE:
            h = signal.getsignal(s)
            if h is signal.SIG_IGN or h is None:
                continue
            old[s] = h
            signal.signal(s, lambda signum, frame: caught.append(signum))
        yield
    finally:
        for s, h in old.items():
            signal.signal(s, h)
        for s in dict.fromkeys(caught):
            signal.raise_signal(s)


CSV_SIGNIFICANT_DIGITS = 9
"""Digits a run directory's ``<table>.csv`` keeps of each float column, counted from the column's largest
magnitude: positions up to 3.1 rad to 1e-8 rad, torques up to 20 N m to 1e-7 N m, times to the microsecond for
runs up to 1000 s; three orders of magnitude finer than the encoders (3.6e-5 rad on joint 1) or the torque
commands. ``<table>.parquet`` keeps every bit and is what wamctl reads."""


def write_csv(df: pd.DataFrame, path: Path, significant_digits: int | None = None) -> None:
    """CSV with a header row, no index (pyarrow's writer: ~10x faster than pandas'). Floats in their shortest
    round-trip form; with ``significant_digits``, each float column rounded first to that many digits of its
    largest magnitude (``8.524`` rather than ``8.524000000000001``: the CSV is 2.5x smaller)."""
    import pyarrow as pa
    import pyarrow.csv as pcsv
    if significant_digits is not None:
        df = round_columns(df, significant_digits)
    pcsv.write_csv(pa.Table.from_pandas(df, preserve_index=False), path,
                   pcsv.WriteOptions(quoting_style="needed"))


def round_columns(df: pd.DataFrame, significant_digits: int) -> pd.DataFrame:
    """Each float column rounded to ``significant_digits`` of its largest finite magnitude (a fixed number of
    decimals per column, so that the rounded value's shortest form has at most that many digits)."""
    out = {}
    for c in df.columns:
        x = df[c]
        if x.dtype.kind == "f" and len(x):
            v = x.to_numpy()
            finite = np.abs(v[np.isfinite(v)])
            top = finite.max() if finite.size else 0.0
            if top > 0:
                decimals = significant_digits - int(np.ceil(np.log10(top)))
                if decimals <= 22:        # 10**decimals exact: each value becomes the double nearest its decimal
                    x = pd.Series(np.round(v, decimals), index=x.index, name=c)
        out[c] = x
    return pd.DataFrame(out, index=df.index)


def read_chunks(chunk_dir: Path, columns: list[str] | None = None) -> pd.DataFrame:
    parts = sorted(Path(chunk_dir).glob("part-*.parquet"))
    if not parts:                # no row yet: an empty table of float columns (what the rows would be)
        return pd.DataFrame(np.empty((0, len(columns or []))), columns=columns or [])
    return pd.concat([read_parquet(p) for p in parts], ignore_index=True)


def read_parquet(path: Path) -> pd.DataFrame:
    """A Parquet file, or a DataFormatError naming it (a truncated or foreign file is bad data, not a crash)."""
    try:
        return pd.read_parquet(path)
    except (OSError, ValueError) as exc:      # pyarrow's ArrowInvalid is a ValueError
        raise DataFormatError(f"{path}: not a readable Parquet file ({exc})") from None


def new_stamped_dir(out_dir: str | Path, name: str) -> Path:
    """Create and return ``<out_dir>/<UTC timestamp>-<name>`` (``-2``, ``-3``... if it already exists)."""
    ensure_dir(out_dir, "parent directory of the run directory")
    stamp = _dt.datetime.now(_dt.timezone.utc).strftime("%Y%m%dT%H%M%S.%fZ")[:-4] + "Z"
    path = Path(out_dir) / f"{stamp}-{name}"
    n = 1
    while path.exists():
        n += 1
        path = Path(out_dir) / f"{stamp}-{name}-{n}"
    path.mkdir(parents=True)
    return path


class RunDir:
    """A run directory being written. Create with :meth:`create`, end with :meth:`finish`."""

    def __init__(self, path: Path):
        self.path = Path(path)
        self._events: list[dict] = []
        self._tables: list[TableWriter] = []
        self.on_saving: Callable[[int], None] | None = None
        """Called once, with :attr:`rows_recorded`, before the next table is consolidated (set by the runner
        after an interrupt, to say so before the seconds a long run's table takes to write), then cleared."""

    @classmethod
    def create(cls, out_dir: str | Path, name: str, spec: dict, seed: int | None,
               kind: str, extra: dict | None = None) -> RunDir:
        """A new run directory with its spec and a ``running`` manifest (all made with signals held back: an
        interrupt leaves a complete run directory or none)."""
        with signals_deferred():
            return cls._create(out_dir, name, spec, seed, kind, extra)

    @classmethod
    def _create(cls, out_dir, name, spec, seed, kind, extra) -> RunDir:
        path = new_stamped_dir(out_dir, name)
        run = cls(path)
        (path / "spec.yaml").write_text(yaml.safe_dump(spec, sort_keys=False))
        manifest = {
            "format": MANIFEST_FORMAT, "kind": kind, "name": name, "seed": seed,
            "status": "running", "reason": None, "start_utc": utc_now(), "end_utc": None,
            "wamctl_version": package_versions()["wamctl"], "versions": package_versions(),
            "git_revision": git_revision(), "host": socket.gethostname(),
            "platform": platform.platform(), "python": platform.python_version(), "pid": os.getpid(),
        }
        manifest.update(extra or {})
        run.write_manifest(manifest)
        _OPEN_RUNS[run.path] = run
        return run

    # ------------------------------------------------------------------ manifest
    def manifest(self) -> dict:
        return json.loads((self.path / "manifest.json").read_text())

    def write_manifest(self, manifest: dict) -> None:
        atomic_write_text(self.path / "manifest.json", json.dumps(manifest, indent=2, default=json_default))

    def update_manifest(self, **fields) -> None:
        m = self.manifest()
        m.update(fields)
        self.write_manifest(m)

    def finish(self, status: str, reason: str | None = None, **fields) -> None:
        """Write the events and the final status (with signals held back: the status is written whole). A run
        ``interrupted`` or ``failed`` keeps only the events that happened (:meth:`end_events`)."""
        with signals_deferred():
            if status in ("interrupted", "failed"):
                self.end_events(status, reason)
            self.flush_events()
            self.update_manifest(status=status, reason=reason, end_utc=utc_now(), **fields)
            _OPEN_RUNS.pop(self.path, None)
            FINISHED_RUNS.append((self.path, status))

    @property
    def last_sample_t_s(self) -> float | None:
        """``t_s`` of the last sample of this run's tables (the latest of them; None: no sample recorded)."""
        return max((w.last_t_s for w in self._tables if w.last_t_s is not None), default=None)

    @property
    def rows_recorded(self) -> int:
        """Rows handed to this run's tables so far."""
        return sum(w.rows_total for w in self._tables)

    def _before_consolidating(self) -> None:
        """:attr:`on_saving`, once; each table of the run calls this before it consolidates."""
        hook, self.on_saving = self.on_saving, None
        if hook is not None:
            try:
                hook(self.rows_recorded)
            except Exception as exc:  # noqa: BLE001 - a notice (a closed terminal) must never stop the saving
                log.warning("%s: the interrupt notice failed (%s: %s)", self.path, type(exc).__name__, exc)

    def end_events(self, status: str, reason: str | None) -> None:
        """The events of a run that stopped early: the planned ones after its last sample are dropped (the
        segments it never reached; all planned ones when it recorded no sample), what happened is kept (a
        watchdog or fault seen after the last sample is the reason the run stopped), and one row of kind
        ``status`` is added last, with ``reason`` as its detail, at the last sample's time or the latest event
        kept if later (with neither, 0)."""
        t_last = self.last_sample_t_s
        self._events = [e for e in self._events
                        if not e.get("planned") or (t_last is not None and e["t_s"] <= t_last)]
        t_stop = max([e["t_s"] for e in self._events] + ([t_last] if t_last is not None else []), default=0.0)
        self.event(t_stop, status, None, reason or "")

    def close_tables(self) -> None:
        """Consolidate every table of this run not closed yet (a stage that was interrupted while closing its
        table); a table that cannot be consolidated keeps its chunks (logged, not raised)."""
        for w in self._tables:
            if not w.closed:
                try:
                    w.close()
                except Exception as exc:  # noqa: BLE001 - the chunks stay readable; the run's outcome matters
                    log.warning("%s: consolidating %s failed (%s: %s); its chunks stay readable", self.path,
                                w.name, type(exc).__name__, exc)

    # ------------------------------------------------------------------ tables
    def table(self, name: str, columns: list[str], chunk_rows: int = 2500) -> TableWriter:
        w = TableWriter(self.path, name, columns, chunk_rows, before_consolidating=self._before_consolidating)
        self._tables.append(w)
        return w

    def write_table(self, name: str, df: pd.DataFrame) -> None:
        """A whole table at once (imported or analysed data): ``<name>.parquet`` and ``<name>.csv``."""
        write_table_pair(df, self.path, name)

    def event(self, t_s: float, kind: str, joint: int | None = None, detail: str = "",
              planned: bool = False) -> None:
        """One row of ``events.csv``. ``planned``: written before it happens (a segment of the reference), so
        dropped if the run stops before it (:meth:`end_events`)."""
        self._events.append({"t_s": float(t_s), "kind": kind, "joint": joint, "detail": detail,
                             "planned": planned})

    def flush_events(self) -> None:
        """``events.csv``: times to the microsecond (``8.524``, not ``8.524000000000001``), written atomically."""
        df = pd.DataFrame(self._events, columns=["t_s", "kind", "joint", "detail"])
        df["t_s"] = df["t_s"].astype(float).round(EVENT_TIME_DECIMALS)
        df["joint"] = df["joint"].astype("Int64")
        atomic_write(self.path / "events.csv", lambda tmp: df.to_csv(tmp, index=False))

    def write_json(self, name: str, obj) -> Path:
        p = self.path / name
        p.write_text(json.dumps(obj, indent=2, default=json_default))
        return p


_OPEN_RUNS: dict[Path, RunDir] = {}
"""Run directories created in this process and not finished yet (what an interrupt must mark)."""
FINISHED_RUNS: list[tuple[Path, str]] = []
"""(path, status) of every run directory finished in this process, in order."""
EVENT_TIME_DECIMALS = 6
"""``events.csv`` times are written to the microsecond (the loop's clock is 2 ms)."""


def end_open_runs(reason: str) -> list[Path]:
    """Mark every run directory of this process still ``running`` as ``interrupted`` with ``reason``, after
    consolidating its tables; returns their paths. For the command line when an interrupt reaches it outside
    the runner (an analysis writing its run directory)."""
    ended = []
    for run in list(_OPEN_RUNS.values()):
        _OPEN_RUNS.pop(run.path, None)
        if not (run.path / "manifest.json").is_file():      # removed meanwhile: nothing to mark
            continue
        try:
            run.close_tables()
            run.finish("interrupted", reason)
            ended.append(run.path)
        except (OSError, ValueError, DataFormatError) as exc:
            log.warning("%s: marking it interrupted failed (%s)", run.path, exc)
    return ended


def json_default(o):
    """``json.dumps(..., default=json_default)``: numpy scalars and arrays as numbers, anything else as text."""
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, (np.floating, np.integer, np.bool_)):
        return o.item()
    return str(o)


def atomic_write(path: Path, write) -> None:
    """Write a file so that readers see the old or the new content, never a half-written one: ``write(tmp)``
    writes a temporary file beside ``path``, which then replaces it (or is removed if anything fails)."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp")
    try:
        write(tmp)
        os.replace(tmp, path)
    finally:                   # an interrupt or error on the way leaves no temporary file behind
        tmp.unlink(missing_ok=True)


def atomic_write_text(path: Path, text: str) -> None:
    """:func:`atomic_write` of a text."""
    atomic_write(path, lambda tmp: tmp.write_text(text))


# ---------------------------------------------------------------------- reading runs back
def open_run(path: str | Path) -> tuple[dict, dict]:
    """(manifest, spec) of a run directory, or DataFormatError naming what is missing."""
    path = Path(path)
    if not path.is_dir():
        raise DataFormatError(f"{path}: {'not a directory' if path.exists() else 'no such directory'}")
    mpath = path / "manifest.json"
    if not mpath.is_file():
        raise DataFormatError(f"{path}: not a wamctl run directory (no manifest.json)")
    try:
        manifest = json.loads(read_text(mpath, DataFormatError, what="a JSON file"))
    except json.JSONDecodeError as exc:
        raise DataFormatError(f"{mpath}: not valid JSON ({exc})") from None
    if not isinstance(manifest, dict):
        raise DataFormatError(f"{mpath}: expected a JSON object")
    spath = path / "spec.yaml"
    spec = parse_yaml(read_text(spath, DataFormatError, what="a YAML file"), str(spath), DataFormatError) \
        if spath.is_file() else {}
    if not isinstance(spec, dict):
        raise DataFormatError(f"{spath}: expected a mapping")
    return manifest, spec


def read_table(path: str | Path, name: str = "data") -> pd.DataFrame:
    """A run's table: the consolidated Parquet if present, else its chunks (a run killed mid-way)."""
    path = Path(path)
    if (path / f"{name}.parquet").is_file():
        return read_parquet(path / f"{name}.parquet")
    if (path / name).is_dir():
        return read_chunks(path / name)
    raise DataFormatError(f"{path}: no {name} table")


def read_events(path: str | Path) -> pd.DataFrame:
    p = Path(path) / "events.csv"
    if not p.is_file():
        return pd.DataFrame(columns=["t_s", "kind", "joint", "detail"])
    return pd.read_csv(p)
