"""What went wrong in a closed loop, read from its recorded rows: a joint held at its torque limit, a joint that
does not follow its reference. One event per stretch of time (a long saturation is one event, not one per tick),
each with its start, duration and peak, so that ``events.csv``, the terminal and the report can say it in a line.

Thresholds:

* torque saturation: ``|tau| >= tau_max`` (the applied torque, after the backend's saturation) for longer than
  :data:`MIN_DURATION_S`;
* tracking error: ``|q_ref - q| > TRACKING_ERROR_RAD`` (measured position) for longer than
  :data:`MIN_DURATION_S`; 0.05 rad is the largest error the IFT safeguards accept (``max_error_rad``), twice the
  largest error of the demo's rotation test under libbarrett's gains (joint 7, 0.025 rad).

Stretches of one joint less than :data:`MERGE_GAP_S` apart are one event (a joint that chatters at its limit).
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

from wamctl.model import params as P

MIN_DURATION_S = 0.1
"""A joint at its torque limit, or off its reference, for longer than this is an event."""
MERGE_GAP_S = 0.2
"""Stretches of one joint closer than this are one event."""
TRACKING_ERROR_RAD = 0.05
"""Tracking errors beyond this are events (the IFT safeguards' max_error_rad)."""
SATURATION_TOL = 1e-9
"""Relative tolerance of 'at the limit' (the backend clips to the limit exactly)."""

TORQUE_SATURATION = "torque_saturation"
TRACKING_ERROR = "tracking_error"
KINDS = (TORQUE_SATURATION, TRACKING_ERROR)
"""The kinds of event this module writes (``events.csv`` kind column)."""

_NUM = r"[-+0-9.eEinfa]+"
_DETAIL = re.compile(rf"start (?P<start>{_NUM}) s, duration (?P<duration>{_NUM}) s, peak (?P<peak>{_NUM}) "
                     rf"(?:N m|rad) \((?:torque limit|threshold) (?P<limit>{_NUM}) (?:N m|rad)\)")


@dataclass(frozen=True)
class LoopEvent:
    """One stretch of trouble of one joint."""

    kind: str
    joint: int          # 1-based
    start_s: float
    duration_s: float
    peak: float         # signed: N m for a saturation, rad for a tracking error
    limit: float        # the torque limit (N m) or the error threshold (rad)

    @property
    def detail(self) -> str:
        """The ``events.csv`` detail: start, duration, peak (and the limit)."""
        if self.kind == TORQUE_SATURATION:
            peak, limit = f"{self.peak:+.2f} N m", f"torque limit {self.limit:g} N m"
        else:
            peak, limit = f"{self.peak:+.4f} rad", f"threshold {self.limit:g} rad"
        return f"start {self.start_s:.3f} s, duration {self.duration_s:.3f} s, peak {peak} ({limit})"

    @property
    def line(self) -> str:
        """One line for the terminal and the report (fits 80 columns after ``warning: ``)."""
        end = self.start_s + self.duration_s
        what = "at torque limit" if self.kind == TORQUE_SATURATION else f"error > {self.limit:g} rad"
        peak = f"{self.peak:+.1f} N m" if self.kind == TORQUE_SATURATION else f"{self.peak:+.3f} rad"
        return (f"joint {self.joint} {what} {self.start_s:.2f}-{end:.2f} s ({self.duration_s:.1f} s), "
                f"peak {peak}")

    @classmethod
    def from_row(cls, kind: str, joint, detail: str) -> LoopEvent | None:
        """The event of an ``events.csv`` row written from :attr:`detail`; None if it is not one."""
        m = _DETAIL.fullmatch(str(detail).strip())
        if m is None or kind not in KINDS:
            return None
        try:
            return cls(kind, int(joint), float(m["start"]), float(m["duration"]), float(m["peak"]),
                       float(m["limit"]))
        except (TypeError, ValueError):
            return None


def stretches(mask: np.ndarray, t_s: np.ndarray, min_duration_s: float = MIN_DURATION_S,
              merge_gap_s: float = MERGE_GAP_S) -> list[tuple[int, int]]:
    """``(first, last)`` sample indices of the runs of True in ``mask`` (n,), runs closer than ``merge_gap_s``
    joined, kept when they last longer than ``min_duration_s`` (``t_s[last] - t_s[first]``)."""
    m = np.asarray(mask, bool)
    if not m.any():
        return []
    edges = np.diff(np.concatenate(([0], m.astype(np.int8), [0])))
    starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1) - 1
    merged = [[int(starts[0]), int(ends[0])]]
    for s, e in zip(starts[1:], ends[1:]):
        if t_s[s] - t_s[merged[-1][1]] < merge_gap_s:
            merged[-1][1] = int(e)
        else:
            merged.append([int(s), int(e)])
    return [(s, e) for s, e in merged if t_s[e] - t_s[s] > min_duration_s]


def _events(kind: str, t_s: np.ndarray, values: np.ndarray, mask: np.ndarray,
            limits: np.ndarray) -> list[LoopEvent]:
    out = []
    for j in range(values.shape[1]):
        for s, e in stretches(mask[:, j], t_s):
            seg = values[s: e + 1, j]
            k = int(np.nanargmax(np.abs(seg)))
            out.append(LoopEvent(kind, j + 1, float(t_s[s]), float(t_s[e] - t_s[s]), float(seg[k]),
                                 float(limits[j])))
    return out


def loop_events(t_s: np.ndarray, q_ref_rad: np.ndarray, q_rad: np.ndarray, tau_Nm: np.ndarray,
                tau_max_Nm: np.ndarray = P.TAU_MAX_NM,
                tracking_error_rad: float = TRACKING_ERROR_RAD) -> list[LoopEvent]:
    """Torque saturations and tracking errors of a loop's rows ((n,) times, (n, 7) arrays), by start time."""
    t_s = np.asarray(t_s, float)
    tau = np.asarray(tau_Nm, float)
    tau_max = np.asarray(tau_max_Nm, float)
    err = np.asarray(q_ref_rad, float) - np.asarray(q_rad, float)
    with np.errstate(invalid="ignore"):
        saturated = np.abs(tau) >= tau_max * (1.0 - SATURATION_TOL)
        off = np.abs(err) > tracking_error_rad
    events = (_events(TORQUE_SATURATION, t_s, tau, saturated, tau_max)
              + _events(TRACKING_ERROR, t_s, err, off, np.full(err.shape[1], tracking_error_rad)))
    return sorted(events, key=lambda e: (e.start_s, e.joint, e.kind))


def loop_events_of_table(data, tau_max_Nm: np.ndarray = P.TAU_MAX_NM) -> list[LoopEvent]:
    """:func:`loop_events` of a run table with the run columns (``t_s``, ``q_ref_{j}_rad``, ``q_{j}_rad``,
    ``tau_{j}_Nm``) of the arm whose torque limits are ``tau_max_Nm`` (one per joint)."""
    J = range(1, len(tau_max_Nm) + 1)
    return loop_events(data["t_s"].to_numpy(), data[[f"q_ref_{j}_rad" for j in J]].to_numpy(),
                       data[[f"q_{j}_rad" for j in J]].to_numpy(), data[[f"tau_{j}_Nm" for j in J]].to_numpy(),
                       tau_max_Nm)
