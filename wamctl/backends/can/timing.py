"""Timing of a periodic loop (the CAN backend's 500 Hz cycle): waiting for a release point, and the statistics
of periods, jitter, lateness and overruns."""

from __future__ import annotations

import time
from typing import Any

import numpy as np

__all__ = ["LoopTiming", "SPIN_S", "sleep_until"]

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
        period, of the jitter ``|period - T|``, of the wake-up lateness after each release point and of
        each cycle's busy time (start to the wait), s."""
        per = self.periods_s
        out: dict[str, Any] = {"cycle_starts": self.n, "period_nominal_s": self.period_s,
                               "overruns": self.overruns, "skipped_periods": self.skipped_periods,
                               "worst_overrun_s": self.worst_overrun_s}
        if per.size:
            jit = np.abs(per - self.period_s)
            late = self._late[1: self.n]
            busy = self._busy[: self.n]
            busy = busy[np.isfinite(busy)]
            for name, x in (("period", per), ("jitter", jit), ("wake_late", late), ("busy", busy)):
                if not x.size:
                    continue
                out[f"{name}_p50_s"] = float(np.percentile(x, 50))
                out[f"{name}_p99_s"] = float(np.percentile(x, 99))
                out[f"{name}_max_s"] = float(x.max())
        return out
