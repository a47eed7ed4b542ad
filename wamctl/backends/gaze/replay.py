"""Recorded gaze and its replay: decoded samples, and raw byte captures played back through a decoder.

Recorded gaze files are CSV with a header naming at least ``t_s,x_px,y_px`` (extra columns are ignored); see
:func:`read_gaze_csv` and :func:`write_gaze_csv`. :class:`ReplayGazeSource` plays samples back, as fast as they are
read or paced on the wall clock.

Raw captures (:mod:`.capture`) are replayed two ways (the ``replay-raw`` source of an ``hmi_block``):
:class:`RawReplaySource` feeds the recorded reads to a fresh decoder in-process, stamped with their recorded
arrival times, so it gives exactly the samples of the live session; :class:`PtyReplaySource` writes them at their
recorded pace into a pseudo-terminal read by a :class:`~wamctl.backends.gaze.serial.SerialGazeSource`, the whole
live path with new arrival stamps.
"""

from __future__ import annotations

import csv
import logging
import math
import os
import threading
import time
from collections import deque
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path

from wamctl.backends.gaze.base import Decoded, DecodeStats, GazeStreamDecoder, RealtimePacer, SourceBase, cut_tail
from wamctl.backends.gaze.capture import CaptureSection, read_capture
from wamctl.backends.gaze.serial import SerialGazeSource
from wamctl.errors import DataFormatError
from wamctl.hmi.gaze import GazeSample, classify

log = logging.getLogger(__name__)


def read_gaze_csv(path: str | os.PathLike) -> list[GazeSample]:
    """Read a recorded gaze file (CSV with columns ``t_s,x_px,y_px``), classifying every row.

    Raises
    ------
    DataFormatError
        When the file cannot be read, a column is missing, a value is not a finite number, or ``t_s``
        does not increase; the message names the row and the column.
    """
    path = Path(path)
    try:
        with path.open(newline="", encoding="utf-8") as fh:
            rows = list(csv.reader(fh))
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise DataFormatError(f"{path}: cannot read gaze log: {exc}") from exc
    if not rows:
        raise DataFormatError(f"{path}: empty gaze log, expected a header 't_s,x_px,y_px'")
    header = [h.strip() for h in rows[0]]
    columns = ("t_s", "x_px", "y_px")
    missing = [c for c in columns if c not in header]
    if missing:
        raise DataFormatError(f"{path}: missing column(s) {', '.join(missing)} (header: {','.join(header)})")
    index = [header.index(c) for c in columns]
    samples: list[GazeSample] = []
    last_t_s = -math.inf
    for row_number, row in enumerate(rows[1:], start=2):
        if not row or all(not cell.strip() for cell in row):
            continue
        if len(row) != len(header):
            raise DataFormatError(f"{path}, row {row_number}: {len(row)} fields, header has {len(header)}")
        values = []
        for name, i in zip(columns, index):
            try:
                value = float(row[i])
            except ValueError:
                raise DataFormatError(f"{path}, row {row_number}, column {name}: not a number: {row[i]!r}") from None
            if not math.isfinite(value):
                raise DataFormatError(f"{path}, row {row_number}, column {name}: not finite: {row[i]!r}")
            values.append(value)
        t_s, x_px, y_px = values
        if t_s <= last_t_s:
            raise DataFormatError(f"{path}, row {row_number}, column t_s: {t_s} does not increase")
        last_t_s = t_s
        samples.append(GazeSample(t_s, x_px, y_px, classify(x_px, y_px)))
    return samples


def write_gaze_csv(path: str | os.PathLike, samples: Iterable[GazeSample]) -> int:
    """Write samples as a gaze file readable by :func:`read_gaze_csv`; corrupt samples are left out.

    Values are written with ``repr`` so they read back bit for bit. Returns the number of rows written.
    """
    n = 0
    with Path(path).open("w", newline="", encoding="utf-8") as fh:
        fh.write("t_s,x_px,y_px\n")
        for s in samples:
            if s.has_time:
                fh.write(f"{s.t_s!r},{s.x_px!r},{s.y_px!r}\n")
                n += 1
    return n


class ReplayGazeSource(SourceBase):
    """Replay of recorded samples, by default as fast as they are read.

    Parameters
    ----------
    samples : sequence of GazeSample
        Samples in time order.
    realtime : bool
        If True, :meth:`read` holds each sample back until its time has come on the wall clock.
    timeout_s : float
        Default wait of :meth:`read` (only matters when ``realtime``).
    """

    def __init__(self, samples: Sequence[GazeSample], *, realtime: bool = False, timeout_s: float = 0.1) -> None:
        self._samples = list(samples)
        self.realtime = realtime
        self.timeout_s = timeout_s
        self._i = 0
        self._pacer = RealtimePacer()

    @classmethod
    def from_csv(cls, path: str | os.PathLike, *, realtime: bool = False) -> ReplayGazeSource:
        """Replay a gaze file written by :func:`write_gaze_csv` (raises ``DataFormatError`` if malformed)."""
        return cls(read_gaze_csv(path), realtime=realtime)

    def __len__(self) -> int:
        return len(self._samples)

    @property
    def exhausted(self) -> bool:
        return self._i >= len(self._samples)

    def read(self, timeout_s: float | None = None) -> GazeSample | None:
        self._check_open()
        if self.exhausted:
            return None
        sample = self._samples[self._i]
        if self.realtime and not self._pacer.wait(sample.t_s, self.timeout_s if timeout_s is None else timeout_s):
            return None
        self._i += 1
        return sample



def merge_stats(stats: Sequence[DecodeStats]) -> DecodeStats:
    """The counts of several decoders (one per section of a capture) added up; the first examples kept."""
    out = DecodeStats()
    for st in stats:
        for k in ("bytes", "frames", "samples", "valid", "blink", "out_of_range", "corrupt", "garbage_bytes",
                  "cut_frames", "bad_frames", "dropped_frames", "clock_adjusts"):
            setattr(out, k, getattr(out, k) + getattr(st, k))
        for kind, examples in st.examples.items():
            kept = out.examples.setdefault(kind, [])
            kept.extend(examples[: max(0, 3 - len(kept))])
        out.extra.update(st.extra)
    return out


class RawReplaySource(SourceBase):
    """A raw capture played back through a decoder in-process: each section (one opening of the port) through a
    fresh decoder, each read stamped with its recorded arrival time, so the samples are those of the live session.

    Parameters
    ----------
    sections : sequence of CaptureSection
        From :func:`~wamctl.backends.gaze.capture.read_capture`.
    make_decoder : callable
        ``make_decoder() -> GazeStreamDecoder``, called once per section.
    realtime : bool
        If True, reads are held back until their recorded time has come on the wall clock.
    timeout_s : float
        Default wait of :meth:`read` (only matters when ``realtime``).
    """

    def __init__(self, sections: Sequence[CaptureSection], make_decoder: Callable[[], GazeStreamDecoder], *,
                 realtime: bool = False, timeout_s: float = 0.1) -> None:
        self._sections = list(sections)
        self._make_decoder = make_decoder
        self.realtime = realtime
        self.timeout_s = timeout_s
        self._pacer = RealtimePacer()
        self._section = -1
        self._chunk = 0
        self._frames: deque[tuple[bytes | None, float]] = deque()
        self.decoders: list[GazeStreamDecoder] = []
        self._next_section()

    @classmethod
    def from_capture(cls, path: str | os.PathLike, make_decoder: Callable[[], GazeStreamDecoder], *,
                     realtime: bool = False) -> RawReplaySource:
        """Replay a capture file (``DataFormatError`` if it is malformed or holds no bytes)."""
        sections = read_capture(path)
        if not any(s.chunks for s in sections):
            raise DataFormatError(f"{path}: the capture holds no bytes")
        return cls(sections, make_decoder, realtime=realtime)

    @property
    def stats(self) -> DecodeStats:
        return merge_stats([d.stats for d in self.decoders])

    @property
    def exhausted(self) -> bool:
        return self._section >= len(self._sections) and not self._frames

    def _next_section(self) -> None:
        self._section += 1
        self._chunk = 0
        if self._section < len(self._sections):
            self.decoders.append(self._make_decoder())

    def read(self, timeout_s: float | None = None) -> GazeSample | None:
        d = self.read_decoded(timeout_s)
        return None if d is None else d.sample

    def read_decoded(self, timeout_s: float | None = None) -> Decoded | None:
        self._check_open()
        while True:
            while self._frames:
                frame, arrival_s = self._frames.popleft()
                decoder = self.decoders[-1] if frame is not None else None
                decoded = cut_tail(arrival_s) if decoder is None else decoder.decode(frame, arrival_s)
                if decoded is not None:
                    return decoded
            if self._section >= len(self._sections):
                return None
            section = self._sections[self._section]
            decoder = self.decoders[-1]
            if self._chunk >= len(section.chunks):
                if decoder.flush():
                    last_s = section.chunks[-1][0] if section.chunks else math.nan
                    self._frames.append((None, last_s))
                self._next_section()
                continue
            t_s, data = section.chunks[self._chunk]
            if self.realtime and not self._pacer.wait(t_s, self.timeout_s if timeout_s is None else timeout_s):
                return None
            self._chunk += 1
            self._frames.extend((f, t_s) for f in decoder.feed(data))


class _PtyPlayer:
    """Writes recorded reads into the master side of a pseudo-terminal at their recorded pace (a thread)."""

    def __init__(self, sections: Sequence[CaptureSection], *, speed: float = 1.0) -> None:
        import pty
        import tty

        self._chunks = [c for s in sections for c in s.chunks]
        self.speed = speed
        self.master_fd, self.slave_fd = pty.openpty()
        tty.setraw(self.slave_fd)  # no echo or line editing before the reader configures the port
        self.path = os.ttyname(self.slave_fd)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._play, name="gaze-pty-replay", daemon=True)
        #: ``time.monotonic()`` when the last recorded read had been written (None until then).
        self.finished_s: float | None = None

    def start(self) -> None:
        self._thread.start()

    def _play(self) -> None:
        if self._chunks:
            t0_rec, t0 = self._chunks[0][0], time.monotonic()
            for t_s, data in self._chunks:
                due = t0 + (t_s - t0_rec) / self.speed
                if self._stop.wait(max(0.0, due - time.monotonic())):
                    return
                view = memoryview(data)
                while view:
                    view = view[os.write(self.master_fd, view):]
        self.finished_s = time.monotonic()

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2.0)
        for fd in (self.master_fd, self.slave_fd):
            try:
                os.close(fd)
            except OSError:
                pass


class PtyReplaySource(SerialGazeSource):
    """A raw capture written at its recorded pace into a pseudo-terminal and read back by the serial source (the
    whole live path: port settings, reads, arrival stamps). Exhausted ``eof_idle_s`` after the last byte, once the
    whole capture has been written: a silence while the player still has bytes to write (its process lost the CPU
    or the GIL, or the capture has a pause) is not the end of the stream.

    Parameters
    ----------
    sections : sequence of CaptureSection
        What to play.
    speed : float
        Playback speed (1: as recorded).
    **serial_options
        For :class:`~wamctl.backends.gaze.serial.SerialGazeSource` (``format``/``decoder``, ``baudrate``, ...).
    """

    def __init__(self, sections: Sequence[CaptureSection], *, speed: float = 1.0, eof_idle_s: float = 1.0,
                 **serial_options) -> None:
        self._player = _PtyPlayer(sections, speed=speed)
        try:
            super().__init__(self._player.path, eof_idle_s=eof_idle_s, **serial_options)
        except BaseException:
            self._player.close()
            raise
        self._player.start()  # after the open: pyserial flushes the input when it opens a port

    def _idle_ended(self, now: float) -> bool:
        """The serial source's idle end, once the player has written the whole capture ``eof_idle_s`` ago: a
        silence while it still plays (or has just finished) is not the end."""
        finished = self._player.finished_s
        return super()._idle_ended(now) and finished is not None and now - finished > self.eof_idle_s

    def _close(self) -> None:
        super()._close()
        self._player.close()
