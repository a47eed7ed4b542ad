"""Where a gaze stream starts on the arm clock (:class:`~wamctl.experiments.hmi_block.feeds.StreamFeed`).

A block starts its first trial a fixed arm time after the tick at which the stream is said to start, and takes
every later sample at its tracker-time offset from the first one; so a live run and an offline replay of its raw
capture give the same trial times only if both start the stream at the same sample. The start is the tick that
delivers the third timed sample (``MIN_GOOD_SAMPLES``), judged on the decoder's counts when that sample was decoded,
however far ahead the source has been read: here one capture (30 Hz, ``ascii-pair``) fed as a replay (read one
sample ahead, in the block's thread) and as a live source whose reader had every byte before the arm first looked
(a late start of the block, or a tracker that sent a burst). Both must start at the same tick, two sample periods
after the first sample. Before the fix, the replay started one period early (when the third sample had been read
ahead) and the burst at the first sample: trial times a whole sample apart for the same bytes.
"""

from __future__ import annotations

import threading
import time

import pytest

from wamctl.backends.gaze import tracker_sim
from wamctl.backends.gaze.capture import CaptureSection
from wamctl.backends.gaze.formats import make_decoder
from wamctl.backends.gaze.replay import RawReplaySource, ReplayGazeSource
from wamctl.experiments.hmi_block.feeds import StreamFeed

TICK_S = 0.002
PERIOD_S = 1.0 / tracker_sim.RATE_HZ
T0_S = 5000.0  # tracker (arrival) time of the first read


def _capture(garbage_before: tuple[int, ...] = (), n: int = 30) -> list[CaptureSection]:
    """``n`` ascii-pair frames, one read per period, with a garbage line (a corrupt sample) before frames
    ``garbage_before`` in the same read."""
    chunks = []
    for k in range(n):
        data = tracker_sim.frame("ascii-pair", k, (300 + k, 200))
        if k in garbage_before:
            data = tracker_sim.garbage("ascii-pair") + data
        chunks.append((T0_S + k * PERIOD_S, data))
    return [CaptureSection({"format": "ascii-pair"}, chunks)]


def _feed(sections, live: bool) -> StreamFeed:
    source = RawReplaySource(sections, lambda: make_decoder("ascii-pair"))
    feed = StreamFeed(source, live=live)
    if live:  # the reader thread has read the whole capture before the arm first looks (no wall-clock wait after)
        deadline = time.monotonic() + 30.0
        while not source.exhausted and time.monotonic() < deadline:
            time.sleep(0.001)
        assert source.exhausted
    return feed


def _start(feed: StreamFeed, max_ticks: int = 2000) -> tuple[float, list[float]]:
    """Tick the arm clock as the block does; the arm time at which the stream started and the tracker times of the
    timed samples delivered by then."""
    got = []
    try:
        for k in range(1, max_ticks):
            t_s = k * TICK_S
            while (s := feed.next_due(t_s)) is not None:
                if s.has_time:
                    got.append(s.t_s)
            if feed.started:
                return t_s, got
    finally:
        feed.close()
    raise AssertionError("the stream did not start")


@pytest.mark.parametrize("garbage_before, start_sample", [((), 2), ((1, 2), 5)],
                         ids=["clean", "two-garbage-lines-first"])
def test_replay_and_live_start_the_stream_at_the_same_sample(garbage_before, start_sample):
    """Clean: the third timed sample starts the stream, two periods after the first. With a garbage line before
    samples 1 and 2, the counts at the third good sample have 2 errors in 5 (over a quarter): the stream starts at
    the sample whose counts first pass (2 errors for 6 good, sample 5), five periods after the first."""
    sections = _capture(garbage_before)
    t_replay_s, got_replay = _start(_feed(sections, live=False))
    t_live_s, got_live = _start(_feed(sections, live=True))
    first_tick_s = TICK_S  # the first sample is due at the tick that first looks for it
    expected_s = first_tick_s + start_sample * PERIOD_S
    for t_s, got in ((t_replay_s, got_replay), (t_live_s, got_live)):
        assert len(got) == start_sample + 1 and got[-1] == pytest.approx(T0_S + start_sample * PERIOD_S, abs=1e-9)
        assert expected_s <= t_s < expected_s + TICK_S  # the first tick at which that sample is due
    assert t_live_s == t_replay_s


def test_a_recorded_gaze_file_starts_at_the_same_sample():
    """A gaze file (no decoder, no counts) starts like the stream it was recorded from: at its third timed sample
    (before, at its first: two periods off the live run it came from)."""
    decoded = RawReplaySource(_capture((1, 2)), lambda: make_decoder("ascii-pair"))
    samples = []
    while (d := decoded.read_decoded()) is not None:
        samples.append(d.sample)
    t_file_s, got = _start(StreamFeed(ReplayGazeSource(samples), live=False))
    t_raw_s, _ = _start(_feed(_capture(), live=False))
    assert len(got) == 3 and t_file_s == t_raw_s


def test_first_sample_and_offset_are_reported():
    """``first_t_s`` is the first sample's tracker time; ``offset_s`` is tracker minus arm time (the old
    ``stream_start`` event printed the offset as if it were the first sample's tracker time)."""
    feed = _feed(_capture(), live=False)
    t_s, _ = _start(feed)
    assert feed.first_t_s == pytest.approx(T0_S, abs=1e-9)
    assert feed.first_t_s - feed.offset_s == pytest.approx(TICK_S, abs=1e-9)


class _StalledReader:
    """A live source whose reader stops after the first sample until ``gate`` is set (a block whose process lost
    the CPU or the GIL while the bytes kept arriving and being stamped by the port's reader process)."""

    def __init__(self, sections, gate: threading.Event) -> None:
        self._inner = RawReplaySource(sections, lambda: make_decoder("ascii-pair"))
        self._gate = gate
        self._reads = 0

    @property
    def stats(self):
        return self._inner.stats

    @property
    def exhausted(self) -> bool:
        return self._inner.exhausted

    def read_decoded(self, timeout_s=None):
        if self._reads == 1:
            self._gate.wait(30.0)
        self._reads += 1
        return self._inner.read_decoded(timeout_s)

    def close(self) -> None:
        self._inner.close()


def test_a_simulated_arm_waits_for_samples_a_stalled_reader_holds_back():
    """The reader passes the first sample on, then nothing for 0.3 s of wall time while the rest had arrived: the
    simulated arm's clock (``hold_arm_clock``) waits for them, so they are taken at the ticks they are due and the
    stream starts where the replay of the same bytes starts (before, the arm kept to the wall clock past them and
    started the stream 0.3 s late: the trial times of that live run 0.3 s off its replay)."""
    gate = threading.Event()
    feed = StreamFeed(_StalledReader(_capture(), gate), live=True)
    feed.hold_arm_clock = True
    timer = threading.Timer(0.3, gate.set)
    timer.start()
    try:
        t_live_s, got_live = _start(feed, max_ticks=100_000)
    finally:
        gate.set()
        timer.cancel()
    t_replay_s, _ = _start(_feed(_capture(), live=False))
    assert len(got_live) == 3
    t_first_s = feed.first_t_s - feed.offset_s  # the tick the first sample was taken at (after the first look)
    assert t_live_s - t_first_s == pytest.approx(t_replay_s - TICK_S, abs=1e-9)
