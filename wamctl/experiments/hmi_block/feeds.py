"""The gaze on the arm clock: the current trial's virtual subject (:class:`VirtualFeed`) or a recorded or live
tracker stream (:class:`StreamFeed`), chosen by the spec's ``hmi.source`` (:func:`open_feed`).

What a stream leaves in the run directory (:class:`StreamRecord`): for a serial tracker, ``gaze_capture.txt``, the
raw bytes of every read with its arrival time (:mod:`wamctl.backends.gaze.capture`); for every decoded stream,
``gaze_samples.csv``, one row per decoded frame (:data:`wamctl.backends.gaze.base.RECORD_COLUMNS`: arrival time,
sample time, gaze, flags, and the frame's raw x/y, pupil, status and counter when it has them), both appended and
flushed as they come; and when the stream closes, ``gaze_stream.json``, the decoder's counts (samples, blinks,
framing and decode errors with their first examples in hex) that the report shows.
"""

from __future__ import annotations

import json
import logging
import math
import queue
import shutil
import threading
import time
from collections.abc import Callable
from pathlib import Path

from wamctl.backends.gaze.base import MIN_GOOD_SAMPLES, RECORD_COLUMNS, Decoded, stream_problem
from wamctl.backends.gaze.virtual import VirtualSubject
from wamctl.hmi.gaze import GazeSample
from wamctl.io import resolve_path
from wamctl.runs.store import atomic_write_text, json_default
from wamctl.specs.hmi_block import HmiTask

log = logging.getLogger(__name__)

#: Longest wait for the first sample of a stream, s (the default of the spec's ``source.start_timeout_s``).
STREAM_START_TIMEOUT_S = 30.0
CAPTURE_FILE = "gaze_capture.txt"
SAMPLES_FILE = "gaze_samples.csv"
STREAM_FILE = "gaze_stream.json"


class StreamRecord:
    """``gaze_samples.csv`` (appended, one flushed line per decoded frame) and, at :meth:`close`,
    ``gaze_stream.json`` in a run directory. A resumed session appends to the same files."""

    def __init__(self, run_path: Path, source_spec: dict) -> None:
        self.run_path = Path(run_path)
        self.source_spec = source_spec
        path = self.run_path / SAMPLES_FILE
        new = not path.is_file() or path.stat().st_size == 0
        self._fh = path.open("a", encoding="ascii", buffering=1)
        if new:
            self._fh.write(",".join(RECORD_COLUMNS) + "\n")
        self.rows = 0

    def write(self, d: Decoded) -> None:
        if not self._fh.closed:
            self._fh.write(",".join("" if math.isnan(v) else repr(v) for v in d.record()) + "\n")
            self.rows += 1

    def close_file(self) -> None:
        self._fh.close()

    def close(self, source) -> dict:
        """Close the samples file; write and return the stream's summary (the source's counts)."""
        self.close_file()
        summary = stream_summary(source, self.source_spec)
        summary["samples_file"] = SAMPLES_FILE
        if (self.run_path / CAPTURE_FILE).is_file():
            summary["capture_file"] = CAPTURE_FILE
        previous = self.run_path / STREAM_FILE
        if previous.is_file():  # a resumed session: keep the earlier sessions' summaries
            try:
                old = json.loads(previous.read_text())
                summary["earlier_sessions"] = old.pop("earlier_sessions", []) + [old]
            except json.JSONDecodeError:
                pass
        atomic_write_text(previous, json.dumps(summary, indent=2, default=json_default))
        return summary


def stream_summary(source, source_spec: dict) -> dict:
    """What a stream source saw: its format and settings, the decoder's counts and first error examples."""
    stats = getattr(source, "stats", None)
    out = {"source": source_spec.get("kind"), "format": source_spec.get("format"),
           "settings": getattr(source, "settings", None)}
    if stats is not None:
        out["stats"] = stats.as_dict()
        out["errors"] = stats.errors
    first, last = getattr(source, "first_rx_s", None), getattr(source, "_last_rx_s", None)
    if first is not None and last is not None and last > first and stats is not None:
        out["bytes_per_s"] = round(stats.bytes / (last - first), 1)
    return out


class VirtualFeed:
    """Samples of the current trial's virtual subject (none between trials), on the arm clock."""

    exhausted = False
    started = True
    offset_s = 0.0
    start_timeout_s = STREAM_START_TIMEOUT_S

    def __init__(self) -> None:
        self._subject: VirtualSubject | None = None
        self._ahead: GazeSample | None = None

    @property
    def subject(self) -> VirtualSubject | None:
        return self._subject

    @subject.setter
    def subject(self, subject: VirtualSubject | None) -> None:
        self._subject = subject
        self._ahead = None

    def next_due(self, t_s: float) -> GazeSample | None:
        if self._subject is None:
            return None
        if self._ahead is None:
            self._ahead = self._subject.read()
        s = self._ahead
        if s is not None and s.t_s <= t_s:
            self._ahead = None
            return s
        return None

    def close(self) -> None:
        pass


_END = object()


class StreamFeed:
    """A recorded or live gaze stream on the arm clock.

    The first timed sample is due when it is first looked for; later ones at their tracker-time offset from it.
    A live source is read in a thread; when its next sample has not arrived yet, :meth:`next_due` waits for it as
    long as the arm clock is ahead of the last sample's time plus the wall time since it arrived (so the
    simulation follows the tracker and a silent tracker stalls in real time).

    With :attr:`hold_arm_clock` (a simulated arm, whose clock may wait), it waits instead until the reader has
    passed on every frame that arrived up to the arm's time (on the frames' arrival clock, from the last sample's
    arrival): a sample that had arrived is then taken at the tick it is due, however late the reader thread ran
    (a process that lost the CPU or the GIL for half a second let the arm catch up with the wall clock past
    samples still in the pipe, and took them that much late), as a replay of the capture takes it.

    The stream is said to start (:attr:`started`) at the arm tick that delivers its ``MIN_GOOD_SAMPLES``-th timed
    sample (for a decoded stream, judged on the decoder's counts as they were when that sample was decoded): a
    function of the samples alone, so a live run and an offline replay of its capture start at the same sample, and
    their trials, which begin a fixed arm time after the start, agree but for how late the live run took its
    samples. (Judged on the counts of whatever had been read at the time, the start followed how far ahead the
    source had been read: in a live run, the third sample's arrival; in a replay, which reads one sample ahead, a
    sample period earlier; a burst of bytes, at the first sample. That shifted a replay's trial times by up to a
    sample against its live run.)
    """

    def __init__(self, source, *, live: bool, clock: Callable[[], float] = time.monotonic,
                 record: StreamRecord | None = None, start_timeout_s: float = STREAM_START_TIMEOUT_S) -> None:
        self.source = source
        self.live = live
        self.clock = clock
        self.record = record
        self.start_timeout_s = start_timeout_s
        self.summary: dict | None = None
        # the sample read ahead, with its decoder's problem and its arrival time (:meth:`_next`'s item)
        self._ahead: tuple[GazeSample, str | None, float] | None = None
        self._offset_s: float | None = None
        self._last_t_s: float | None = None
        self._last_wall_s = clock()
        self._first_look: tuple[float, float] | None = None  # (arm time, wall time) when first looked for a sample
        self._first_t_s: float | None = None  # tracker time of the first timed sample
        self._timed = 0  # timed samples delivered
        self._problem: str | None = None  # stream_problem of the decoder's counts when the last delivered one decoded
        self._last_arrival_s = math.nan  # arrival time of the last timed sample delivered
        #: The arm clock may wait for the stream (a simulated arm): see the class's docstring.
        self.hold_arm_clock = False
        # Arrival time up to which (exclusive) the reader has passed on every frame, and (arrival time, clock) of
        # the newest frame it read: written by the reader thread only.
        self._heard_s = -math.inf
        self._newest: tuple[float, float] | None = None
        self._ended = False
        self._queue: queue.Queue | None = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        if live:
            self._queue = queue.Queue()
            self._thread = threading.Thread(target=self._reader, name="gaze-reader", daemon=True)
            self._thread.start()

    def _next(self, timeout_s: float) -> tuple[GazeSample, str | None, float] | None:
        """The source's next sample, its decoded frame recorded (sources with ``read_decoded``),
        :func:`~wamctl.backends.gaze.base.stream_problem` of the decoder's counts right after it was decoded
        (None for a source without counts), and its arrival time (the sample's time for a source without)."""
        read_decoded = getattr(self.source, "read_decoded", None)
        if read_decoded is None:
            s = self.source.read(timeout_s)
            return None if s is None else (s, None, s.t_s)
        d = read_decoded(timeout_s)
        if d is None:
            return None
        if self.record is not None:
            self.record.write(d)
        stats = getattr(self.source, "stats", None)
        return d.sample, None if stats is None else stream_problem(stats), d.arrival_s

    def _reader(self) -> None:
        try:
            while not self._stop.is_set():
                before = self.clock()
                item = self._next(0.05)
                if item is not None:
                    self._queue.put(item)
                    if math.isfinite(item[2]):  # frames come in arrival order: all before this one are passed on
                        self._newest = (item[2], self.clock())
                        self._heard_s = max(self._heard_s, item[2])
                else:
                    if self._newest is not None:  # nothing was waiting when the read began
                        arrival, read = self._newest
                        self._heard_s = max(self._heard_s, arrival + max(0.0, before - read))
                    if self.source.exhausted:
                        break
        except Exception as exc:  # noqa: BLE001 - reported through the queue's end
            log.error("gaze reader stopped: %s", exc)
        finally:
            self._queue.put(_END)

    @property
    def exhausted(self) -> bool:
        return self._ended and self._ahead is None

    @property
    def started(self) -> bool:
        """True once ``MIN_GOOD_SAMPLES`` timed samples have been delivered (the first sets the stream's time
        offset) and, for a decoded stream, the stream is usable (:func:`~wamctl.backends.gaze.base.stream_problem`
        of the decoder's counts as they were when the last delivered sample was decoded: few errors and bytes
        outside frames): a misconfigured decoder that makes a sample or two of nonsense does not start a session.

        Judged on what :meth:`next_due` has delivered, not on what has been read ahead, and the same for every
        source (a recorded gaze file too): so it turns True at the tick that delivers the same sample, live or
        replayed."""
        return self._timed >= MIN_GOOD_SAMPLES and self._problem is None

    @property
    def first_t_s(self) -> float | None:
        """Tracker time of the stream's first timed sample, s (None before it)."""
        return self._first_t_s

    @property
    def offset_s(self) -> float:
        """Tracker time minus arm time, s (0 before the first sample)."""
        return self._offset_s or 0.0

    def _read(self, t_s: float) -> tuple[GazeSample, str | None, float] | None:
        if self._ended:
            return None
        if not self.live:
            item = self._next(0.0)
            if item is None:
                if self.source.exhausted:
                    self._ended = True
                return None
            return item
        try:
            item = self._queue.get_nowait()
        except queue.Empty:
            item = self._wait(t_s)
            if item is None:
                return None
        if item is _END:
            self._ended = True
            return None
        return item

    def _wait(self, t_s: float):
        """The reader's next item if it is worth waiting for at arm time ``t_s``, else None."""
        if self._last_t_s is None:  # before the first sample: the arm clock keeps to the wall clock
            if self._first_look is None:
                self._first_look = (t_s, self.clock())
            wait = (t_s - self._first_look[0]) - (self.clock() - self._first_look[1])
        elif self.hold_arm_clock and math.isfinite(self._last_arrival_s):
            return self._hold(self._last_arrival_s + (t_s - self._last_t_s))
        else:
            wait = t_s - (self._last_t_s + self.clock() - self._last_wall_s)
        if wait <= 0.0:
            return None
        try:
            return self._queue.get(timeout=min(wait, 0.5))
        except queue.Empty:
            return None

    #: Longest wait of :meth:`_hold` for a reader that passes nothing on, s (it reports every 0.05 s).
    HOLD_LIMIT_S = 2.0

    def _hold(self, arrival_s: float):
        """Wait until the reader passed on a sample (returned) or every frame that arrived up to ``arrival_s``
        (None: nothing is due up to there). A reader that reports nothing for :attr:`HOLD_LIMIT_S` is not waited
        for longer."""
        deadline = self.clock() + self.HOLD_LIMIT_S
        while self._heard_s <= arrival_s and self.clock() < deadline:
            try:
                return self._queue.get(timeout=0.01)
            except queue.Empty:
                continue
        try:
            return self._queue.get_nowait()
        except queue.Empty:
            return None

    def _deliver(self, s: GazeSample, problem: str | None) -> GazeSample:
        self._ahead = None
        self._problem = problem
        return s

    def next_due(self, t_s: float) -> GazeSample | None:
        if self._ahead is None:
            self._ahead = self._read(t_s)
            if self._ahead is None:
                return None
        s, problem, arrival_s = self._ahead
        if not s.has_time:
            return self._deliver(s, problem)
        if self._offset_s is None:
            self._offset_s = s.t_s - t_s
            self._first_t_s = s.t_s
        if s.t_s - self._offset_s <= t_s:
            self._last_t_s = s.t_s - self._offset_s
            self._last_wall_s = self.clock()
            self._last_arrival_s = arrival_s
            self._timed += 1
            return self._deliver(s, problem)
        return None

    def no_sample_message(self, waited_s: float, ended: bool = False) -> str:
        """Why no usable sample came in ``waited_s`` (or before the stream ``ended``): what arrived and what to try
        (serial sources), else the basics."""
        waited_s = round(waited_s, 1)
        if getattr(self.source, "settings", None) is not None:
            from wamctl.backends.gaze.check import describe_silence
            text = describe_silence(self.source, waited_s)
        else:
            stats = getattr(self.source, "stats", None)
            seen = (f": {stats.bytes} bytes, {stats.samples} samples, {stats.errors} errors"
                    if stats is not None else "")
            text = f"no gaze sample from the {type(self.source).__name__} within {waited_s:g} s{seen}"
        return text + (" (the stream ended)" if ended else "")

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(2.0)
        self.source.close()
        if self.record is not None and self.summary is None:
            self.summary = self.record.close(self.source)
            errors = self.summary.get("errors") or 0
            if errors or (self.summary.get("stats") or {}).get("garbage_bytes"):
                st = self.summary["stats"]
                first = next((f"{k}: {v[0]}" for k, v in st["examples"].items() if v), "")
                log.warning("gaze stream: %d samples, %d framing/decode errors, %d bytes outside frames%s",
                            st["samples"], errors, st["garbage_bytes"], f"; first {first}" if first else "")


def open_feed(h: HmiTask, base_dir: Path | None, run_path: Path | None = None) -> VirtualFeed | StreamFeed:
    """The feed of ``h.source``: a virtual subject, a replayed gaze file or raw capture (relative to ``base_dir``
    unless it exists as given), or a serial tracker (its port read and stamped in a child process, its samples
    decoded in a thread). With ``run_path``, a stream is recorded there (:class:`StreamRecord`, and the raw
    capture of a serial port)."""
    src = h.source
    if src.kind == "virtual":
        return VirtualFeed()
    if src.kind == "replay":
        from wamctl.backends.gaze.replay import ReplayGazeSource
        return StreamFeed(ReplayGazeSource.from_csv(resolve_path(src.path, base_dir)), live=False)
    from wamctl.backends.gaze.formats import make_decoder

    def decoder():
        return make_decoder(src.format, **src.decoder_options())

    record = StreamRecord(run_path, src.model_dump(mode="json")) if run_path is not None else None
    capture = Path(run_path) / CAPTURE_FILE if run_path is not None else None
    try:
        if src.kind == "replay-raw":
            from wamctl.backends.gaze.capture import read_capture
            from wamctl.backends.gaze.replay import PtyReplaySource, RawReplaySource
            path = resolve_path(src.path, base_dir)
            if src.via == "direct":
                source = RawReplaySource.from_capture(path, decoder, realtime=src.realtime)
                if capture is not None and not capture.exists():  # the run keeps the bytes it decoded
                    shutil.copyfile(path, capture)
                return StreamFeed(source, live=src.realtime, record=record, start_timeout_s=src.start_timeout_s)
            source = PtyReplaySource(read_capture(path), decoder=decoder(), capture=capture, reader="process")
            return StreamFeed(source, live=True, record=record, start_timeout_s=src.start_timeout_s)
        from wamctl.backends.gaze.serial import SerialGazeSource
        source = SerialGazeSource(src.url, baudrate=src.baudrate, bytesize=src.bytesize, parity=src.parity,
                                  stopbits=src.stopbits, flow_control=src.flow_control, decoder=decoder(),
                                  eof_idle_s=src.eof_idle_s, capture=capture, reader="process")
        return StreamFeed(source, live=True, record=record, start_timeout_s=src.start_timeout_s)
    except BaseException:
        if record is not None:
            record.close_file()
        raise
