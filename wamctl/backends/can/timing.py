"""Timing of a periodic loop (the CAN backend's 500 Hz cycle): waiting for a release point, the statistics of
periods, jitter, lateness, overruns and reply latency, and what a Python loop can be given to keep time
(:class:`RealtimeSection`: the garbage collector frozen and off, SCHED_FIFO and CPU affinity when permitted)."""

from __future__ import annotations

import gc
import logging
import os
import time
from typing import Any

import numpy as np

logger = logging.getLogger(__name__)

__all__ = ["FIFO_PRIORITY", "LoopTiming", "RealtimeSection", "SPIN_S", "sleep_until"]

FIFO_PRIORITY = 50  # libbarrett's real-time thread priority (product_manager.h)

SPIN_S = 2e-4  # the last part of each wait yields (sleep(0)) instead of sleeping: time.sleep overshoots


def sleep_until(deadline: float) -> float:
    """Wait until ``time.perf_counter()`` reaches ``deadline``: sleep to just before it, then yield.

    Returns
    -------
    float
        The ``perf_counter`` time on waking (at or just after ``deadline``).
    """
    while True:
        remaining = deadline - time.perf_counter()
        if remaining <= 0.0:
            break
        time.sleep(remaining - SPIN_S if remaining > SPIN_S else 0.0)
    return time.perf_counter()


class LoopTiming:
    """Cycle start times of a periodic loop: periods, lateness and overruns.

    Parameters
    ----------
    period_s : float
        Nominal period.
    """

    def __init__(self, period_s: float) -> None:
        self.period_s = float(period_s)
        self._starts = np.empty(4096)
        self._late = np.empty(4096)
        self._busy = np.full(4096, np.nan)
        self._reply = np.empty(4096)
        self.n_replies = 0
        self.n = 0
        self.overruns = 0
        self.skipped_periods = 0
        self.worst_overrun_s = 0.0

    def cycle_started(self, t_s: float, late_s: float) -> None:
        """Record a cycle start (perf_counter time) and how late after its release point it came."""
        if self.n == self._starts.size:
            self._starts = np.concatenate([self._starts, np.empty_like(self._starts)])
            self._late = np.concatenate([self._late, np.empty_like(self._late)])
        self._starts[self.n] = t_s
        self._late[self.n] = late_s
        self.n += 1

    def cycle_ended(self, t_s: float) -> None:
        """Record the end of the current cycle's work (perf_counter time): its busy time."""
        if self.n:
            i = self.n - 1
            if i >= self._busy.size:
                self._busy = np.concatenate([self._busy, np.full_like(self._busy, np.nan)])
            self._busy[i] = t_s - self._starts[i]

    def reply(self, latency_s: float) -> None:
        """Record the time from a position request to its last reply."""
        if self.n_replies == self._reply.size:
            self._reply = np.concatenate([self._reply, np.empty_like(self._reply)])
        self._reply[self.n_replies] = latency_s
        self.n_replies += 1

    def overrun(self, late_s: float, skipped: int) -> None:
        self.overruns += 1
        self.skipped_periods += skipped
        self.worst_overrun_s = max(self.worst_overrun_s, late_s)

    @property
    def periods_s(self) -> np.ndarray:
        """Time between consecutive cycle starts, s, shape (n - 1,)."""
        return np.diff(self._starts[: self.n])

    def summary(self) -> dict:
        """``cycle_starts, overruns, skipped_periods, worst_overrun_s``, and percentiles (p50, p99, max) of the
        period, of the jitter ``|period - T|``, of the wake-up lateness after each release point, of each
        cycle's busy time (start to the wait) and of the reply latency (request to the seventh reply), s."""
        per = self.periods_s
        out: dict[str, Any] = {"cycle_starts": self.n, "period_nominal_s": self.period_s,
                               "overruns": self.overruns, "skipped_periods": self.skipped_periods,
                               "worst_overrun_s": self.worst_overrun_s}
        if per.size:
            jit = np.abs(per - self.period_s)
            late = self._late[1: self.n]
            busy = self._busy[: self.n]
            busy = busy[np.isfinite(busy)]
            reply = self._reply[: self.n_replies]
            for name, x in (("period", per), ("jitter", jit), ("wake_late", late), ("busy", busy),
                            ("reply", reply)):
                if not x.size:
                    continue
                out[f"{name}_p50_s"] = float(np.percentile(x, 50))
                out[f"{name}_p99_s"] = float(np.percentile(x, 99))
                out[f"{name}_max_s"] = float(x.max())
        return out


class RealtimeSection:
    """What a Python real-time loop can have, for the thread that enters it.

    :meth:`enter`: a full collection, then the garbage collector frozen (the objects alive now are never
    scanned again) and disabled, so no collection pauses a cycle; SCHED_FIFO at ``priority`` (libbarrett's 50)
    if the process may (root, CAP_SYS_NICE or an rtprio limit), and the thread pinned to ``cpu`` if given.
    :meth:`exit` undoes all of it. :attr:`granted` says what was obtained, and why not.

    Parameters
    ----------
    fifo : bool
        Ask for SCHED_FIFO.
    priority : int
    cpu : int, optional
        Pin the thread to this CPU.
    """

    def __init__(self, fifo: bool = True, priority: int = FIFO_PRIORITY, cpu: int | None = None) -> None:
        self.fifo, self.priority, self.cpu = fifo, int(priority), cpu
        self.granted: dict[str, Any] = {}
        self._gc_was_enabled = True
        self._old_policy: tuple[int, int] | None = None
        self._old_affinity: set[int] | None = None

    def enter(self) -> RealtimeSection:
        self._gc_was_enabled = gc.isenabled()
        gc.collect()
        gc.freeze()
        gc.disable()
        self.granted = {"gc": "frozen and disabled", "sched_fifo": None, "affinity": None}
        if self.fifo:
            try:
                self._old_policy = (os.sched_getscheduler(0), os.sched_getparam(0).sched_priority)
                os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(self.priority))
                self.granted["sched_fifo"] = self.priority
            except (AttributeError, OSError) as exc:  # not Linux, or not permitted
                self._old_policy = None
                self.granted["sched_fifo"] = f"not permitted: {exc}"
        if self.cpu is not None:
            try:
                self._old_affinity = os.sched_getaffinity(0)
                os.sched_setaffinity(0, {int(self.cpu)})
                self.granted["affinity"] = int(self.cpu)
            except (AttributeError, OSError) as exc:
                self._old_affinity = None
                self.granted["affinity"] = f"not permitted: {exc}"
        logger.info("real-time loop: %s", self.granted)
        return self

    def exit(self) -> None:
        if self._old_affinity is not None:
            try:
                os.sched_setaffinity(0, self._old_affinity)
            except OSError:
                logger.warning("restoring the CPU affinity failed")
            self._old_affinity = None
        if self._old_policy is not None:
            try:
                os.sched_setscheduler(0, self._old_policy[0], os.sched_param(self._old_policy[1]))
            except OSError:
                logger.warning("restoring the scheduling policy failed")
            self._old_policy = None
        gc.unfreeze()
        if self._gc_was_enabled:
            gc.enable()
