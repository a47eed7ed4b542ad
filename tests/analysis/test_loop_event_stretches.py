"""Loop events from recorded rows (issue 32, item 2): a stretch at the torque limit or off the reference is one
event with its start, duration and peak; short blips are not events; the events.csv detail reads back."""

from __future__ import annotations

import numpy as np
import pytest

from wamctl.analysis.loop_events import (
    TORQUE_SATURATION,
    TRACKING_ERROR,
    LoopEvent,
    loop_events,
    stretches,
)
from wamctl.model import params as P

DT = 1.0 / P.CONTROL_RATE_HZ


def rows(seconds: float):
    t = np.arange(int(round(seconds / DT))) * DT
    z = np.zeros((len(t), P.N_JOINTS))
    return t, z.copy(), z.copy(), z.copy()


def test_the_demos_stuck_joint_is_one_saturation_and_one_tracking_event():
    # the demo before issue 32: joint 2 pinned at -20 N m from 24.288 s for 29.6 s (leaving the limit for a few
    # ticks now and then), 0.499 rad off its reference meanwhile
    t, q_ref, q, tau = rows(60.0)
    pinned = (t >= 24.288) & (t <= 53.906)
    tau[pinned, 1] = -20.0
    tau[(t > 30.0) & (t < 30.02), 1] = -19.5          # 10 ticks off the limit: the same stretch
    q_ref[pinned, 1] = np.linspace(0.0, 0.499, pinned.sum())
    tau[(t > 5.0) & (t < 5.05), 0] = 25.0              # 0.05 s at joint 1's limit: shorter than 0.1 s, no event
    ev = loop_events(t, q_ref, q, tau)
    assert [(e.kind, e.joint) for e in ev] == [(TORQUE_SATURATION, 2), (TRACKING_ERROR, 2)]
    sat, track = ev
    assert sat.start_s == pytest.approx(24.288, abs=DT) and sat.duration_s == pytest.approx(29.618, abs=2 * DT)
    assert sat.peak == -20.0 and sat.limit == 20.0
    assert track.peak == pytest.approx(0.499) and track.limit == 0.05
    assert track.start_s == pytest.approx(24.288 + 0.05 / 0.499 * 29.618, abs=0.01)


def test_stretches_apart_by_more_than_the_gap_are_two_events():
    t = np.arange(0, 10, DT)
    mask = ((t >= 1.0) & (t < 2.0)) | ((t >= 2.5) & (t < 3.0)) | ((t >= 3.1) & (t < 3.15))
    # 1-2 s; 2.5-3.15 s (the 0.1 s gap joins the blip at 3.1 s); a gap of 0.5 s splits
    got = [(round(t[a], 3), round(t[b], 3)) for a, b in stretches(mask, t)]
    assert got == [(1.0, 1.998), (2.5, 3.148)]


def test_the_detail_written_to_events_csv_reads_back_and_says_it_in_one_short_line():
    e = LoopEvent(TORQUE_SATURATION, 2, 24.288, 29.618, -20.0, 20.0)
    assert e.detail == "start 24.288 s, duration 29.618 s, peak -20.00 N m (torque limit 20 N m)"
    assert LoopEvent.from_row(TORQUE_SATURATION, 2, e.detail) == e
    assert e.line == "joint 2 at torque limit 24.29-53.91 s (29.6 s), peak -20.0 N m"
    t = LoopEvent(TRACKING_ERROR, 4, 104.652, 4.18, 0.4990, 0.05)
    assert LoopEvent.from_row(TRACKING_ERROR, 4, t.detail) == t
    assert t.line == "joint 4 error > 0.05 rad 104.65-108.83 s (4.2 s), peak +0.499 rad"
    assert max(len("warning: " + x.line) for x in (e, t)) <= 80
    assert LoopEvent.from_row("segment", None, "move joint 2") is None
