"""A run's joints diagnosed side by side in worker processes, when it pays (no I/O).

Each joint's forward selection (:meth:`~wamctl.analysis.diagnosis.estimator.ModelDiagnosis._diagnose_joint`)
reads the run's prepared signals and design and writes nothing another joint reads: its result, its declared
friction (``jd.extra["theta_before"]``, also ``result.theta_before``), its friction-map test (``map_tests_``) and
caches (design columns and shifted targets in ``jd.extra``, windows and statistics in ``Signals.memo``) that are
rebuilt, the same numbers, on first use. The one cache shared by the joints, the friction map of every joint, is
made before the workers start. So the joints can be diagnosed in any order, in any process, and give the same
diagnosis bit for bit.

Workers are forked (they inherit the prepared arrays copy-on-write) from the process that holds them, and only
compute and return: their standard streams go nowhere, their log records and warnings are sent back with the
result and given to this process's logging and warnings, joint by joint in order. Where fork is not available,
inside a daemonic process, or on a short run (:data:`MIN_PARALLEL_WORK`) the joints are diagnosed here, one after
the other.
"""

from __future__ import annotations

import logging
import multiprocessing
import os
import signal
import sys
import warnings
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool

log = logging.getLogger(__name__)

LEFT_IN_WORKER = ("_cache", "_shift")     # a joint's design columns and shifted targets (design.py): not sent back

# samples x joints below which the joints stay in this process. Two workers on 2 CPUs, the second one mostly free
# (the first generator's seven-joint runs, no position check, three passes each): 20 s (72 000) 1.56 -> 1.19 s,
# 30 s (105 000) 1.85 -> 1.40 s, 120 s (426 000) 3.1 -> 2.35 s, 900 s (3.2 M) 5.8 -> 4.7 s, the hour (12.6 M)
# 7.6 -> 6.5 s; with another process taking 0.7 CPU meanwhile, nothing gained on the hour (and up to 10 % lost).
# Starting the workers is repaid from short runs on; the threshold keeps runs of a few seconds (the tests' many)
# in one process, where a second is the most there is to gain.
MIN_PARALLEL_WORK = 200_000


def joint_workers(n_joints: int, n_samples: int, jobs: int | None = None,
                  min_work: int = MIN_PARALLEL_WORK) -> int:
    """Worker processes for the joints of a run of ``n_samples`` samples (1: none, the joints one after the other).

    ``jobs``: None chooses (the CPUs this process may run on, at most one per joint, on a run of at least
    ``min_work`` samples x joints); a number asks for that many (1: none), at most one per joint. Without fork or
    inside a daemonic process (which may not have children): 1."""
    if "fork" not in multiprocessing.get_all_start_methods() or multiprocessing.current_process().daemon:
        return 1
    if jobs is None:
        if n_samples * n_joints < min_work:
            return 1
        jobs = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1
    return max(1, min(int(jobs), n_joints))


def cache_keys(sig, jd) -> tuple[set, dict]:
    """What the caches of the signals ``sig`` and of one joint's ``jd`` hold now (see :func:`caches_since`)."""
    return set(sig.statistics()), dict(jd.extra)


def caches_since(sig, jd, before: tuple[set, dict]) -> tuple[dict, dict]:
    """``(memo, extra)``: what a joint's diagnosis added to the signals' statistics (``Signals.memo``: the encoder
    step, the distinct values, the inertia at the onsets) and set in ``jd.extra`` (the declared friction, the
    onsets found) since ``before`` (:func:`cache_keys`), for the process that goes on with the run: rebuilt there,
    they cost about 0.7 s on an hour's run. Left out: the gathered windows and their counters (keyed by the ids of
    this process's objects) and the design columns and shifted targets (7-26 MB a joint, rebuilt in 0.05 s)."""
    memo_before, extra_before = before
    memo = {k: v for k, v in sig.statistics().items() if k not in memo_before}
    extra = {k: v for k, v in jd.extra.items() if k not in LEFT_IN_WORKER and extra_before.get(k) is not v}
    return memo, extra


def adopt_caches(sig, jd, caches: tuple[dict, dict]) -> None:
    """The caches of :func:`caches_since` put back (a statistic already there is kept: the same numbers)."""
    memo, extra = caches
    sig.adopt_statistics(memo)
    jd.extra.update(extra)


def map_in_order(task, n: int, workers: int, done=None) -> list:
    """``[task(0), ..., task(n - 1)]``: here one after the other (``workers`` <= 1), or in ``workers`` forked
    processes. ``done(k)`` is called in this process as each ``task(k)`` completes; the tasks' log records and
    warnings are given out here task by task in order, as one after the other would.

    A task's exception reaches the caller unchanged (the earliest task's, as one after the other would); the tasks
    not started are cancelled and the workers finish the one they are on (one joint: seconds). They are not
    terminated: a worker killed while it writes its result leaves a partial message in the pool's result pipe, and
    the pool's reader then waits for the rest forever (seen: the suite's worker-error test hung 600 s; 30 tries of
    3 MB results with an early error hung the terminating version within 30 s, 3 of 3). A worker that dies (killed,
    out of memory) leaves its tasks and the ones not started to this process, with a warning: the results are the
    same, only later. Ctrl-C or SIGTERM (the workers ignore SIGINT, so that a terminal's Ctrl-C reaches this process
    alone) terminates the workers before it is raised here: waiting for them instead was seen to hang at exit (the
    workers never got the pool's stop sentinels after the interrupt); that a worker cut off while sending could
    still leave the pool's reader waiting is not excluded there."""
    done = done or (lambda k: None)
    if workers <= 1 or n <= 1:
        out = []
        for k in range(n):
            out.append(task(k))
            done(k)
        return out
    sent: dict = {}             # task -> (result, log records, warnings) from a worker
    results: dict = {}          # task -> result, once its records and warnings were given out

    def receive(k: int, package: tuple) -> None:
        sent[k] = package
        done(k)
        while len(results) in sent:
            results[len(results)] = _give_out(sent[len(results)])

    pool = ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("fork"),
                               initializer=_worker_init, initargs=(task,))
    try:
        futures = {pool.submit(_worker_call, k): k for k in range(n)}
        pending = set(futures)
        while pending:
            finished, pending = wait(pending, return_when=FIRST_COMPLETED)
            for f in sorted(finished, key=futures.get):
                if f.exception() is None:
                    receive(futures[f], f.result())
                elif isinstance(f.exception(), BrokenProcessPool):
                    raise f.exception()
                else:      # an earlier task's error comes first, as one after the other
                    for g in sorted(futures, key=futures.get)[:futures[f]]:
                        if futures[g] not in sent:
                            receive(futures[g], g.result())
                    raise f.exception()
    except BrokenProcessPool as exc:        # the pool has stopped its other workers itself
        log.warning("a worker process of the joint diagnosis died (%s): %d of %d tasks done here instead",
                    exc, n - len(sent), n)
        for k in range(len(results), n):
            if k in sent:
                results[k] = _give_out(sent[k])
            else:
                results[k] = task(k)
                done(k)
    except Exception:
        raise           # the finally: the tasks not started cancelled, the ones running finished (not terminated)
    except BaseException:
        _stop(pool)     # Ctrl-C, SIGTERM: now (waiting for the sentinels after an interrupt was seen to hang)
        raise
    finally:
        pool.shutdown(wait=True, cancel_futures=True)
    return [results[k] for k in range(n)]


def _stop(pool: ProcessPoolExecutor) -> None:
    """Every worker of ``pool`` terminated (SIGTERM), without waiting for its task: on Ctrl-C or SIGTERM only (a
    worker cut off while it sends a result can leave the pool's reader waiting; see :func:`map_in_order`)."""
    for p in list((getattr(pool, "_processes", None) or {}).values()):
        if p.is_alive():
            p.terminate()


def _give_out(package: tuple):
    """A worker's ``(result, log records, warnings)`` of one task: the records and warnings given to this process's
    logging and warnings (filtered here as if raised here), the result returned."""
    value, records, caught = package
    for rec in records:
        logger = logging.getLogger(rec.name)
        if not logger.disabled:
            logger.handle(rec)
    for w in caught:
        module = next((m for m in list(sys.modules.values()) if getattr(m, "__file__", None) == w.filename), None)
        warnings.warn_explicit(w.message, w.category, w.filename, w.lineno,
                               registry=None if module is None else vars(module).setdefault("__warningregistry__", {}))
    return value


# ---------------------------------------------------------------------------------------------- in the workers
_TASK = None             # set in each worker by _worker_init (a forked child's own copy), never in the parent


class _Kept(logging.Handler):
    """Every log record a worker emits, kept to be sent back (once, whichever loggers it passed)."""

    def __init__(self):
        super().__init__(logging.NOTSET)
        self.records = []

    def emit(self, record):
        if not self.records or self.records[-1] is not record:
            self.records.append(record)


_KEPT = None


def _worker_init(task) -> None:
    """A forked worker: the task kept, Ctrl-C left to the parent, the standard streams to nowhere (a lock another
    thread of the parent held at the fork, a progress bar's say, is never waited for) and every logger's handlers
    replaced by one that keeps the records."""
    global _TASK, _KEPT
    _TASK = task
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    sys.stdout = sys.stderr = open(os.devnull, "w")
    _KEPT = _Kept()
    loggers = [logging.getLogger()] + [lg for lg in logging.Logger.manager.loggerDict.values()
                                       if isinstance(lg, logging.Logger)]
    for lg in loggers:
        if lg.handlers or lg is loggers[0]:
            lg.handlers = [_KEPT]


def _worker_call(k: int) -> tuple:
    """``(task(k), its log records, its warnings)``, the records' messages formatted (their arguments need not
    pickle)."""
    _KEPT.records = []
    with warnings.catch_warnings(record=True) as caught:
        value = _TASK(k)
    records = []
    for rec in _KEPT.records:
        rec.msg, rec.args = rec.getMessage(), None
        if rec.exc_info:
            rec.exc_text = rec.exc_text or logging.Formatter().formatException(rec.exc_info)
            rec.exc_info = None
        records.append(rec)
    return value, records, [warnings.WarningMessage(w.message, w.category, w.filename, w.lineno) for w in caught]
