"""The gaze on the arm clock: the current trial's virtual subject (:class:`VirtualFeed`) or a recorded or live
tracker stream (:class:`StreamFeed`), chosen by the spec's ``hmi.source`` (:func:`open_feed`)."""

from __future__ import annotations

import logging
import queue
import threading
import time
from collections.abc import Callable
from pathlib import Path

from wamctl.backends.gaze.virtual import VirtualSubject
from wamctl.hmi.gaze import GazeSample
from wamctl.io import resolve_path
from wamctl.specs.hmi_block import HmiTask

log = logging.getLogger(__name__)

#: Longest wait for the first sample of a serial or replayed stream, s.
STREAM_START_TIMEOUT_S = 30.0


class VirtualFeed:
    """Samples of the current trial's virtual subject (none between trials), on the arm clock."""

    exhausted = False
    started = True
    offset_s = 0.0

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
    """

    def __init__(self, source, *, live: bool, clock: Callable[[], float] = time.monotonic) -> None:
        self.source = source
        self.live = live
        self.clock = clock
        self._ahead: GazeSample | None = None
        self._offset_s: float | None = None
        self._last_t_s: float | None = None
        self._last_wall_s = clock()
        self._ended = False
        self._queue: queue.Queue | None = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        if live:
            self._queue = queue.Queue()
            self._thread = threading.Thread(target=self._reader, name="gaze-reader", daemon=True)
            self._thread.start()

    def _reader(self) -> None:
        try:
            while not self._stop.is_set():
                s = self.source.read(0.05)
                if s is not None:
                    self._queue.put(s)
                elif self.source.exhausted:
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
        """True once the first timed sample has been seen (it sets the stream's time offset)."""
        return self._offset_s is not None

    @property
    def offset_s(self) -> float:
        """Tracker time minus arm time, s (0 before the first sample)."""
        return self._offset_s or 0.0

    def _read(self, t_s: float) -> GazeSample | None:
        if self._ended:
            return None
        if not self.live:
            s = self.source.read(0.0)
            if s is None and self.source.exhausted:
                self._ended = True
            return s
        try:
            item = self._queue.get_nowait()
        except queue.Empty:
            if self._last_t_s is None:
                wait = 0.02
            else:
                wait = t_s - (self._last_t_s + self.clock() - self._last_wall_s)
            if wait <= 0.0:
                return None
            try:
                item = self._queue.get(timeout=min(wait, 0.5))
            except queue.Empty:
                return None
        if item is _END:
            self._ended = True
            return None
        return item

    def next_due(self, t_s: float) -> GazeSample | None:
        if self._ahead is None:
            self._ahead = self._read(t_s)
            if self._ahead is None:
                return None
        s = self._ahead
        if not s.has_time:
            self._ahead = None
            return s
        if self._offset_s is None:
            self._offset_s = s.t_s - t_s
        if s.t_s - self._offset_s <= t_s:
            self._ahead = None
            self._last_t_s = s.t_s - self._offset_s
            self._last_wall_s = self.clock()
            return s
        return None

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(2.0)
        self.source.close()


def open_feed(h: HmiTask, base_dir: Path | None) -> VirtualFeed | StreamFeed:
    """The feed of ``h.source``: a virtual subject, a replayed gaze file (relative to ``base_dir`` unless it exists
    as given), or a serial tracker read in a thread."""
    src = h.source
    if src.kind == "virtual":
        return VirtualFeed()
    if src.kind == "replay":
        from wamctl.backends.gaze.replay import ReplayGazeSource
        return StreamFeed(ReplayGazeSource.from_csv(resolve_path(src.path, base_dir)), live=False)
    from wamctl.backends.gaze.serial import SerialGazeSource
    return StreamFeed(SerialGazeSource(src.url, baudrate=src.baudrate, eof_idle_s=src.eof_idle_s), live=True)
