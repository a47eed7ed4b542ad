"""The warnings of a run's closed loop (a joint held at its torque limit, a joint off its reference), read from
its ``events.csv`` (written by the loop, :mod:`wamctl.analysis.loop_events`): one line per event, for the
terminal after a run and the warnings block at the top of a report."""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from wamctl.analysis.loop_events import LoopEvent
from wamctl.runs.store import read_events


def loop_events_of_run(run_path: str | Path) -> list[LoopEvent]:
    """The loop events of a run, by start time; empty when there is none or no readable events file."""
    try:
        ev = read_events(run_path)
    except (OSError, ValueError, pd.errors.ParserError):
        return []
    if not {"kind", "joint", "detail"} <= set(ev.columns):
        return []
    out = [LoopEvent.from_row(k, j, d) for k, j, d in zip(ev["kind"], ev["joint"], ev["detail"])
           if not pd.isna(j)]
    return sorted((e for e in out if e is not None), key=lambda e: (e.start_s, e.joint, e.kind))


def run_warnings(run_path: str | Path) -> list[str]:
    """One line per loop event of the run (by start time); empty when there is none."""
    return [e.line for e in loop_events_of_run(run_path)]
