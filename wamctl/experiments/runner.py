"""Runs any experiment kind: plan -> (dry run | run directory + execute) -> status -> report.

A termination signal (SIGTERM, SIGHUP) is turned into the same path as Ctrl-C: every sample recorded so far
is flushed and the run is marked ``interrupted``. A safety fault marks it ``failed`` with the reason. The caller
may be told of an interrupt as soon as the rows to save are known (``on_interrupt``): consolidating a long run's
table takes seconds (1.3 million rows: about 7 s).
"""

from __future__ import annotations

import logging
import signal
import threading
from collections.abc import Callable
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

from wamctl.errors import ConfigurationRefused, SafetyLimitError, WamctlError
from wamctl.report import write_report
from wamctl.runs.store import RunDir
from wamctl.specs import Common
from wamctl.specs.registry import KINDS, resolve

log = logging.getLogger(__name__)

def experiment_module(kind: str):
    """The module running ``kind`` (``plan``, ``execute``, optionally ``resume``), from the registry."""
    return resolve(KINDS[kind].experiment)


class RunInterrupted(WamctlError):
    """The run was stopped by Ctrl-C or a termination signal; its data so far are on disk."""

    exit_code = 130


@dataclass
class RunOutcome:
    path: Path
    status: str
    reason: str | None
    exit_code: int = 0
    """0 completed; 2 refused before anything moved (a configuration the model does not describe, like a bad
    spec); 1 any other failure."""


@contextmanager
def _handled(handler, signals):
    """``handler`` for each of ``signals`` that is not ignored (a run started with ``nohup`` keeps ignoring
    SIGHUP) inside the block, the previous handlers restored after it. Nothing outside the main thread."""
    old = {}
    if threading.current_thread() is threading.main_thread():
        old = {s: signal.signal(s, handler) for s in signals if signal.getsignal(s) is not signal.SIG_IGN}
    try:
        yield
    finally:
        for s, h in old.items():
            signal.signal(s, h)


@contextmanager
def signals_as_interrupt():
    """SIGTERM/SIGHUP raise KeyboardInterrupt inside the block (main thread only; an ignored signal stays
    ignored)."""
    def handler(signum, frame):
        raise KeyboardInterrupt(signal.Signals(signum).name)
    with _handled(handler, (signal.SIGTERM, signal.SIGHUP)):
        yield


@contextmanager
def signals_as_event():
    """Ctrl-C (SIGINT), SIGTERM and SIGHUP set the yielded :class:`threading.Event` instead of raising (main
    thread only, elsewhere the event is never set by a signal; an ignored signal stays ignored).

    For code that waits inside a library which a KeyboardInterrupt at an arbitrary point leaves in a broken
    state (a Dask client's synchronous calls log a NameError traceback when interrupted before their coroutine
    has started): the caller polls the event between library calls and stops cleanly."""
    stop = threading.Event()
    with _handled(lambda signum, frame: stop.set(), (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)):
        yield stop


class _FirstSignalRaises:
    """A signal handler: the first Ctrl-C (SIGINT), SIGTERM or SIGHUP raises KeyboardInterrupt, any later one
    is only noted (``caught``), so that the bookkeeping after an interrupt (closing the tables, the status)
    cannot itself be interrupted. ``armed = False`` notes without raising from then on. ``on_first(name)`` is
    called before the first one raises (inside the handler: it must only take note)."""

    def __init__(self, on_first: Callable[[str], None] | None = None):
        self.armed = True
        self.caught: list[str] = []
        self.on_first = on_first

    def __call__(self, signum, frame):
        name = "Ctrl-C" if signum == signal.SIGINT else signal.Signals(signum).name
        self.caught.append(name)
        if self.armed:
            self.armed = False
            if self.on_first is not None:
                self.on_first(name)
            raise KeyboardInterrupt(*(() if signum == signal.SIGINT else (name,)))


class _SavingNotice:
    """Tells ``say(by, rows)`` once that ``run`` was interrupted by ``by`` (Ctrl-C, SIGTERM, SIGHUP), with the
    rows recorded, just before the first of its tables is consolidated after the interrupt
    (:attr:`RunDir.on_saving`): in ``body`` (a stage closing its table) or in the runner's bookkeeping. Nothing
    is said when nothing is left to consolidate (an interrupt that was not a signal, e.g. the pendant's stop,
    reaches the runner after the stage saved its table)."""

    def __init__(self, run: RunDir, say: Callable[[str, int], None] | None):
        self.run, self.say, self.armed = run, say, False

    def arm(self, by: str) -> None:
        if self.say is not None and not self.armed:
            self.armed = True
            self.run.on_saving = lambda rows: self.say(by, rows)


def record_outcome(run: RunDir, body, resume_hint: bool = False,
                   on_interrupt: Callable[[str, int], None] | None = None) -> RunOutcome:
    """Run ``body()`` into ``run``: termination signals act as Ctrl-C, and the outcome becomes the run's status
    (``completed``, ``failed`` with the reason, ``interrupted``), written however ``body`` ends.

    After ``body`` (however it ends) further signals are noted, not raised, until every table of the run is
    consolidated and its status written. Raises RunInterrupted when interrupted (the data so far are on disk),
    also when a signal came after ``body`` completed (the run is ``completed``, its report not written);
    programming errors propagate after the run is marked failed. ``on_interrupt(by, rows)`` is called once
    before the tables of an interrupted run are consolidated: ``by`` Ctrl-C, SIGTERM or SIGHUP, ``rows`` the
    rows of its tables."""
    status, reason, exit_code, error = "completed", None, 0, None
    notice = _SavingNotice(run, on_interrupt)
    stop = _FirstSignalRaises(notice.arm)
    by = None
    with _handled(stop, (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)):
        try:
            try:
                body()
            finally:
                stop.armed = False
        except KeyboardInterrupt as exc:
            by = exc.args[0] if exc.args else "Ctrl-C"
            status, reason = "interrupted", f"stopped by {by}"
            notice.arm(by)      # said by close_tables below, unless a table's consolidation in ``body`` said it
        except SafetyLimitError as exc:
            status, reason, exit_code = "failed", f"safety limit: {exc}", 1
        except WamctlError as exc:
            status, reason, exit_code = "failed", str(exc), 2 if isinstance(exc, ConfigurationRefused) else 1
        except BaseException as exc:  # noqa: BLE001 - recorded as failed, then raised again below
            status, reason, exit_code, error = "failed", f"{type(exc).__name__}: {exc}", 1, exc
        run.close_tables()
        run.finish(status, reason)
    if error is not None:
        raise error
    if status == "interrupted":
        hint = f"; continue with --resume {run.path}" if resume_hint else ""
        raise RunInterrupted(f"{run.path}: interrupted by {by}; the data recorded so far are readable{hint}")
    if status == "completed" and stop.caught:
        raise RunInterrupted(f"{run.path}: completed, then stopped by {stop.caught[0]} before its report; "
                             f"`wamctl report {run.path}` writes it")
    return RunOutcome(run.path, status, reason, exit_code)


def plan_only(spec: Common, base_dir: Path | None = None) -> tuple[list[str], list[str]]:
    """The dry run: the plan's summary and the limit checks made (raises SpecError on a violation)."""
    mod = experiment_module(spec.kind)
    p = mod.plan(spec, base_dir)
    return p.summary, p.check_limits()


def run_spec(spec: Common, base_dir: Path | None = None, out_dir: str | Path | None = None,
             progress=None, make_report: bool = True,
             on_interrupt: Callable[[str, int], None] | None = None) -> RunOutcome:
    """Execute a validated spec into a new run directory and (on success) write its report. ``on_interrupt``:
    as :func:`record_outcome`'s."""
    mod = experiment_module(spec.kind)
    p = mod.plan(spec, base_dir)
    p.check_limits()
    run = RunDir.create(out_dir or spec.out_dir, spec.name, spec.model_dump(mode="json"), spec.seed, spec.kind,
                        {"backend": {"name": spec.backend.kind}, "planned_duration_s": p.duration_s})
    log.info("run directory %s", run.path)
    outcome = record_outcome(run, lambda: mod.execute(spec, p, run, progress, base_dir),
                             resume_hint=hasattr(mod, "resume"), on_interrupt=on_interrupt)
    _rewrite_index(run.path.parent)
    if make_report:
        try:
            with signals_as_interrupt():
                write_report(run.path)
        except KeyboardInterrupt:
            raise RunInterrupted(f"{run.path}: the run {outcome.status}; its report was interrupted, "
                                 f"`wamctl report {run.path}` writes it") from None
    return outcome


def _rewrite_index(folder: Path) -> None:
    """``index.html`` of the folder of runs (issue 30), where one is kept (made by ``wamctl runs --html``; a
    folder without one gets none: sweep points, scratch folders): reads manifests and report JSONs only; a
    failure is logged, never the run's."""
    if not (folder / "index.html").exists():
        return
    try:
        from wamctl.report.index_page import write_index
        write_index(folder)
    except Exception:  # noqa: BLE001 - the index is a convenience; the run's outcome is what matters
        log.warning("could not rewrite %s/index.html", folder, exc_info=True)
