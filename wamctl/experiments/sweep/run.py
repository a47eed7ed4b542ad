"""Running a sweep: every point not completed yet, on Dask, into a sweep directory (new, or resumed), and the
plan check of every point that ``wamctl validate`` and ``wamctl sweep --dry-run`` do."""

from __future__ import annotations

import json
import threading
import time
import uuid
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import yaml

from wamctl.errors import SpecError, WamctlError
from wamctl.experiments.runner import plan_only, signals_as_event
from wamctl.experiments.sweep.cluster import close_quietly, connect
from wamctl.experiments.sweep.index import SweepIndex, create_sweep_dir, read_sessions, update_manifest
from wamctl.experiments.sweep.point import key_figures, mark_abandoned, read_manifest, run_dirs, run_point
from wamctl.report import write_report
from wamctl.report.sweep import write_sweep_report
from wamctl.runs.store import utc_now
from wamctl.specs import parse_spec
from wamctl.specs.sweep import Sweep, SweepPoint, point_problems


class SweepInterrupted(WamctlError):
    """The sweep was stopped (Ctrl-C, SIGTERM); its index is on disk and ``--resume`` finishes it."""

    exit_code = 130


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


def refuse_the_arm(sweep: Sweep) -> None:
    """A sweep drives the simulated arm only: its points run in parallel on Dask workers, with no terminal to
    answer a CAN session's questions (zeroing, Shift-Activate), and one arm takes one run at a time."""
    on_arm = [p.point_id for p in sweep.points if isinstance(p.spec.get("backend"), dict)
              and p.spec["backend"].get("kind") == "can"]
    if on_arm:
        raise SpecError(f"{sweep.source}: backend: kind can in {len(on_arm)} of {len(sweep.points)} points: a sweep "
                        f"runs its points in parallel on Dask workers, with nobody to answer the arm's questions; "
                        f"run each point on the arm with `wamctl run SPEC`, one at a time")


def check_plans(sweep: Sweep) -> list[str]:
    """Plan every point and check its setpoints against the limits (what ``wamctl validate`` does for one
    spec); nothing moves. Returns the checks of the first point; raises :class:`SpecError` naming every
    point whose plan is refused (at most 20), or for a sweep on the CAN arm (:func:`refuse_the_arm`)."""
    refuse_the_arm(sweep)
    problems, first = [], None
    for p in sweep.points:
        try:
            _, checks = plan_only(parse_spec(p.spec, p.point_id), sweep.base_dir)
        except SpecError as exc:
            problems.append((p.point_id, p.values, str(exc)))
            continue
        first = first if first is not None else checks
    if problems:
        raise SpecError(point_problems(str(sweep.source), problems, len(sweep.points), "break a limit"))
    return first or []


def run_sweep(sweep: Sweep, out_dir: str | Path | None = None, *, resume_dir: str | Path | None = None,
              client=None, scheduler: str | None = None, n_workers: int | None = None, security=None,
              progress: Callable[[int, int, str | None], None] | None = None,
              on_point: Callable[[dict], None] | None = None) -> SweepResult:
    """Run every point of ``sweep`` that is not completed yet, on Dask, into a sweep directory.

    Parameters
    ----------
    sweep : the parsed sweep (:func:`wamctl.specs.sweep.load_sweep`,
        :func:`wamctl.experiments.sweep.index.open_sweep_dir`).
    out_dir : parent of a new sweep directory (default: the spec's ``out_dir``). Ignored with ``resume_dir``.
    resume_dir : an existing sweep directory: its completed points are skipped.
    client : a ``distributed.Client`` to use (not closed here); else ``scheduler`` (an address) or a new
        ``LocalCluster`` of ``n_workers`` processes (default one per core), closed at the end.
    security : Dask's TLS settings for a ``tls://`` scheduler (:func:`.cluster.tls_security`).
    progress : ``progress(done, total, label)`` after every point.
    on_point : called with each point's index row as it finishes.

    Raises
    ------
    SweepInterrupted on Ctrl-C / SIGTERM (the index is written first); BackendError if the cluster cannot
    be reached.
    """
    refuse_the_arm(sweep)
    sweep_dir, index = _open_index(sweep, out_dir, resume_dir)
    todo, skipped = _points_to_run(sweep, index, resume_dir is not None)
    index.write()
    session = _Session(sweep, index, todo, skipped)
    # Ctrl-C and termination signals set `stop` rather than raise: a KeyboardInterrupt inside a Dask client call
    # leaves the client's event loop with a failing callback (a traceback after "sweep interrupted"); the loop
    # below looks at `stop` between calls. Shutdown runs under the same handler, so a second Ctrl-C cannot break
    # it either (closing the cluster has its own time limits).
    with signals_as_event() as stop:
        try:
            session.connect(client, scheduler, n_workers, security)
            if not stop.is_set():
                session.run(progress, on_point, stop)
            if stop.is_set():
                session.interrupt()
        finally:
            session.finish()
    written = write_sweep_report(sweep_dir)
    rec, counts = session.record, session.counts
    result = SweepResult(sweep_dir, counts, rec["wall_s"], rec.get("n_workers") or 0, session.ran, skipped,
                         rec["efficiency"], rec["max_concurrent"], written)
    if session.interrupted:
        missing = counts["pending"] + counts["interrupted"]
        raise SweepInterrupted(f"{sweep_dir}: sweep interrupted, {counts['completed']} of {len(sweep.points)} "
                               f"points completed; `wamctl sweep --resume {sweep_dir}` runs the {missing} missing "
                               f"points" + (f" and the {counts['failed']} failed ones" if counts["failed"] else ""))
    return result


def _open_index(sweep: Sweep, out_dir: str | Path | None, resume_dir: str | Path | None) -> tuple[Path, SweepIndex]:
    """The (resolved) sweep directory and its index: an existing one to resume, or a new one."""
    if resume_dir is not None:
        sweep_dir = Path(resume_dir)
        index = SweepIndex.load(sweep_dir, sweep)
    else:
        sweep_dir = create_sweep_dir(sweep, out_dir or sweep.raw.get("out_dir", "runs"))
        index = SweepIndex(sweep_dir, sweep)
    sweep_dir = sweep_dir.resolve()
    index.dir = sweep_dir
    return sweep_dir, index


def _points_to_run(sweep: Sweep, index: SweepIndex, resume: bool) -> tuple[list[SweepPoint], int]:
    """The points left to run, and how many are skipped: completed points whose run directory is still there
    are skipped; on resume, a point whose attempt completed after the sweep was stopped is adopted."""
    runs_root = index.dir / "runs"
    todo, skipped = [], 0
    for p in sweep.points:
        row = index.rows[p.point_id]
        if row["status"] == "completed" and row["run_dir"] and \
                read_manifest(index.dir / row["run_dir"]).get("status") == "completed":
            skipped += 1
            continue
        found = _completed_run(p, runs_root / p.point_id) if resume else None
        if found is not None:
            index.update(_adopt(p, found, sweep.section.reports))
            skipped += 1
            continue
        if row["status"] == "completed":  # its run directory was deleted
            row.update(status="pending", run_dir=None, figures={})
        todo.append(p)
    return todo, skipped


def _completed_run(point: SweepPoint, point_dir: Path) -> Path | None:
    """A completed run directory of this point whose resolved spec is the point's (an attempt that
    finished after the sweep was stopped), or None."""
    dirs = [d for d in run_dirs(point_dir) if read_manifest(d).get("status") == "completed"]
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
    """The index record of a completed run found on resume (its report written if it has none). Its start and
    end times (and so its duration) stay empty: the worker's time on the point (run, report, start-up) is what
    the index records, and nobody saw it for a point that finished after the sweep was stopped."""
    rec = {"point": point.point_id, "status": "completed", "run_dir": str(run_dir), "error": None,
           "attempts": len(run_dirs(run_dir.parent)), "figures": {}, "start_unix_s": None, "end_unix_s": None}
    rj = run_dir / "report.json"
    if reports and not rj.is_file():
        write_report(run_dir)
    if rj.is_file():
        rec["figures"] = key_figures(json.loads(rj.read_text()))
    return rec


class _Session:
    """One call of :func:`run_sweep`: the cluster it uses, the points in flight, and its ``record`` in the
    manifest's ``sessions`` (scheduler, workers, wall time, points run, busy fraction, interrupted)."""

    def __init__(self, sweep: Sweep, index: SweepIndex, todo: list[SweepPoint], skipped: int):
        self.sweep, self.index, self.todo = sweep, index, todo
        self.dir = index.dir
        self.runs_root = index.dir / "runs"
        self.record = {"start_utc": utc_now(), "todo": len(todo), "skipped": skipped}
        self.client = self.own_client = self.cluster = None
        self.t_start = time.time()
        self.intervals: list[tuple[float, float]] = []
        self.ran = 0
        self.interrupted = False
        self.futures: dict = {}
        self.counts: dict[str, int] = {}

    def connect(self, client, scheduler: str | None, n_workers: int | None, security=None) -> None:
        """Use ``client``, or (when there is something to run) connect to ``scheduler`` or start a local
        cluster, closed by :meth:`finish`."""
        self.client = client
        if self.todo and client is None:
            self.client, self.cluster = connect(scheduler, n_workers, security)
            self.own_client = self.client
        workers = self.client.scheduler_info()["workers"] if self.client is not None else {}
        self.record.update(scheduler=scheduler or ("local" if self.cluster is not None else "given client"),
                           n_workers=len(workers), threads=sum(w.get("nthreads", 1) for w in workers.values()))

    def run(self, progress, on_point, stop: threading.Event) -> None:
        """Submit the points left and record each as it finishes (index, progress, ``on_point``), until all
        have finished or ``stop`` is set (looked at every 0.1 s)."""
        update_manifest(self.dir, status="running", sessions=read_sessions(self.dir) + [self.record])
        total = len(self.sweep.points)
        done = total - len(self.todo)
        if progress:
            progress(done, total, self._label())
        if not self.todo:
            return
        self._submit()
        while self.futures and not stop.is_set():
            finished = [f for f, _ in self.futures.values() if f.done()]   # local state, no call to the cluster
            if not finished:
                stop.wait(0.1)
                continue
            for fut in finished:
                p = self.futures.pop(fut.key)[1]  # first: an interrupt from here on leaves its row alone
                rec = _record_of(fut, p, self.runs_root / p.point_id)
                self.index.update(rec)
                self.index.write()
                if rec.get("start_unix_s") and rec.get("end_unix_s"):
                    self.intervals.append((rec["start_unix_s"], rec["end_unix_s"]))
                self.ran += 1
                done += 1
                if on_point:
                    on_point(dict(self.index.rows[p.point_id]))
                if progress:
                    progress(done, total, self._label())
        if stop.is_set() and progress:    # closing a cluster takes seconds: say what is happening
            progress(done, total, f"sweep {self.sweep.name}: stopping, closing the cluster")

    def _submit(self) -> None:
        sw, token = self.sweep, uuid.uuid4().hex[:8]
        for p in self.todo:
            fut = self.client.submit(run_point, p.spec, p.point_id, str(self.runs_root / p.point_id),
                                     str(sw.base_dir) if sw.base_dir else None, p.values,
                                     str(self.dir), sw.section.reports,
                                     key=f"wamctl-sweep-{token}-{p.point_id}", pure=False,
                                     retries=sw.section.retries)
            self.futures[fut.key] = (fut, p)

    def _label(self) -> str:
        c = self.index.counts()
        return f"sweep {self.sweep.name}: {c['completed']} completed, {c['failed']} failed"

    def interrupt(self) -> None:
        """Ctrl-C: cancel the points in flight and mark them interrupted (started) or pending; write the index."""
        self.interrupted = True
        try:  # first stop the scheduler from starting more points
            self.client.cancel([f for f, _ in self.futures.values()])
        except Exception:  # noqa: BLE001 - best effort; the cluster may be gone already
            pass
        for _fut, p in self.futures.values():
            started = any(read_manifest(d).get("status") == "running" for d in run_dirs(self.runs_root / p.point_id))
            self.index.rows[p.point_id]["status"] = "interrupted" if started else "pending"
        self.index.write()

    def finish(self) -> None:
        """Close a cluster of our own; after an interrupt, bring the index in line with the run directories;
        complete the session's record and the manifest's status and counts."""
        wall = time.time() - self.t_start
        owned = self.own_client is not None
        if owned:   # first: no point runs on after this
            close_quietly(self.own_client, self.cluster)
            self.own_client = None
        if self.interrupted:
            _reconcile(self.sweep, self.index, abandon=owned)
        busy = sum(b - a for a, b in self.intervals)
        n_w = self.record.get("n_workers") or 0
        self.record.update(end_utc=utc_now(), wall_s=wall, ran=self.ran,
                           efficiency=(busy / (wall * n_w)) if self.ran and n_w and wall > 0 else None,
                           max_concurrent=_max_concurrency(self.intervals), interrupted=self.interrupted)
        self.counts = counts = self.index.counts()
        finished = counts["pending"] == 0 and counts["interrupted"] == 0
        sessions = read_sessions(self.dir)
        sessions[-1:] = [self.record] if sessions and sessions[-1].get("start_utc") == self.record["start_utc"] \
            else sessions[-1:] + [self.record]
        update_manifest(self.dir, sessions=sessions, counts=counts,
                        status="completed" if finished else ("interrupted" if self.interrupted else "incomplete"),
                        end_utc=utc_now())


def _reconcile(sweep: Sweep, index: SweepIndex, abandon: bool) -> None:
    """After an interrupt: a point whose run completed (in flight when Ctrl-C came, its result never collected)
    is completed in the index; with ``abandon`` (our own cluster is closed), attempts left ``running`` by a
    process that is gone are marked as abandoned. The index, the counts and the message then say what the run
    directories hold."""
    for p in sweep.points:
        row = index.rows[p.point_id]
        if row["status"] == "completed":
            continue
        pdir = index.dir / "runs" / p.point_id
        if abandon:
            mark_abandoned(pdir, "sweep: its own cluster closed after the sweep was stopped")
        found = _completed_run(p, pdir)
        if found is not None:
            index.update(_adopt(p, found, False))
        elif row["status"] == "interrupted" and not run_dirs(pdir):
            row["status"] = "pending"       # it never started: nothing to say it was interrupted
    index.write()


def _max_concurrency(intervals: list[tuple[float, float]]) -> int:
    ev = sorted([(a, 1) for a, _ in intervals] + [(b, -1) for _, b in intervals])
    n = best = 0
    for _, d in ev:
        n += d
        best = max(best, n)
    return best


def _record_of(fut, point: SweepPoint, point_dir: Path) -> dict:
    """The index record of a finished future: its result, or its error (after Dask's retries)."""
    if fut.status == "finished":
        return fut.result()
    rec = {"point": point.point_id, "status": "failed", "run_dir": None, "attempts": len(run_dirs(point_dir)),
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
    mark_abandoned(point_dir, f"sweep: Dask gave the point up ({name})")
    dirs = run_dirs(point_dir)
    if dirs:
        rec["run_dir"] = str(dirs[-1])
    return rec
