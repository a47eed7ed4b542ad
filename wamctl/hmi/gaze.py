"""Gaze samples, the serial line format, and the gaze sources (serial, replay, virtual subject).

Conventions
-----------
* Pixels of the ASL Mobile Eye scene image, 768 x 576, origin at the upper-left corner, x to the right,
  y downward (thesis section 6.1.2 and 6.3). Names carry ``_px``.
* Times in seconds on the tracker's clock (``t_s``). The tracker streams at about 30 Hz (thesis 6.1.2).
* An eye closed (pupil or corneal reflections lost) is the pair (-2000, -2000) (thesis 6.1.2 and 6.2.1).
* Every sample is classified, never rejected with an exception: ``GazeSample.flags`` is empty for a
  valid gaze point, ``BLINK`` for (-2000, -2000), ``OUT_OF_RANGE`` for a parsed point outside the image,
  ``CORRUPT`` for anything that cannot be trusted at all (t_s, x_px, y_px are then NaN).
* The *command frame* used by the strategies (:mod:`wamctl.hmi.strategy`) has its origin at the image
  centre (384, 288) px, x to the right and y **up**; see :func:`gaze_vector_px`.

Serial line format
------------------
One sample per line, ASCII, three comma-separated decimal fields::

    t_ms,x_px,y_px<LF>

* ``t_ms``: tracker time in milliseconds, a non-negative decimal, strictly increasing;
* ``x_px``, ``y_px``: the gaze point in scene-image pixels (decimals, e.g. ``412.5``), or ``-2000,-2000``
  while the eye is closed.

Example: ``1033,412.5,300.0`` then ``1067,-2000,-2000``. A line ends with LF, CR or CRLF; spaces around
fields are allowed; blank lines and lines starting with ``#`` are ignored. Exponents, ``nan``, ``inf``,
a wrong field count, a negative time, non-ASCII bytes and lines longer than :data:`MAX_LINE_BYTES` are
``CORRUPT``. A time that does not increase is ``CORRUPT`` too, until :attr:`GazeLineDecoder.resync_after`
such lines in a row show the tracker clock really restarted. An unterminated tail left when the stream
ends is ``CORRUPT`` (it may be cut short). :func:`format_line` writes this format.

Recorded gaze files (replay) are CSV with a header naming at least ``t_s,x_px,y_px`` (extra columns are
ignored); see :func:`read_gaze_csv` and :func:`write_gaze_csv`.

Sources
-------
Every source follows :class:`GazeSource`: ``read(timeout_s) -> GazeSample | None`` (``None`` when nothing
arrived in time, or when the source is ``exhausted``), iteration (blocking, until exhausted), context
manager, ``close()`` safe to call twice.
"""

from __future__ import annotations

import csv
import enum
import logging
import math
import os
import re
import time
from collections import deque
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol, runtime_checkable

import numpy as np

from wamctl.errors import BackendError, DataFormatError

logger = logging.getLogger(__name__)

# Thesis 6.1.2: scene image of the Mobile Eye, 768 x 576 px, streamed at 30 Hz; (-2000, -2000) = eye closed.
IMAGE_WIDTH_PX = 768
IMAGE_HEIGHT_PX = 576
NOMINAL_RATE_HZ = 30.0
BLINK_SENTINEL_PX = -2000.0
# Thesis 6.3, Figure 6.10: the control space is centred on (384, 288) px.
CENTER_X_PX = IMAGE_WIDTH_PX / 2
CENTER_Y_PX = IMAGE_HEIGHT_PX / 2

#: Longest accepted line, terminator excluded; a valid line is at most ~30 bytes.
MAX_LINE_BYTES = 128

_TWO_PI = 2.0 * math.pi
_NUM = r"[+-]?(?:\d+(?:\.\d*)?|\.\d+)"
_LINE_RE = re.compile(rf"\s*({_NUM})\s*,\s*({_NUM})\s*,\s*({_NUM})\s*")
_TERMINATOR_RE = re.compile(rb"[\r\n]")


class GazeFlag(enum.IntFlag):
    """Classification of a gaze sample; no flag set means a valid gaze point."""

    BLINK = 1
    """(-2000, -2000): the eye is closed or the tracker lost the pupil."""
    OUT_OF_RANGE = 2
    """Parsed, but outside the 768 x 576 image (thesis 6.1.2: corrupted data)."""
    CORRUPT = 4
    """Unparseable, non-finite, or a time that does not increase."""


VALID = GazeFlag(0)


@dataclass(frozen=True, slots=True)
class GazeSample:
    """One gaze sample.

    Attributes
    ----------
    t_s : float
        Tracker time, s (NaN for a corrupt line).
    x_px, y_px : float
        Gaze point in scene-image pixels, origin upper-left, y downward (NaN for a corrupt line).
    flags : GazeFlag
        Empty for a valid point; see :class:`GazeFlag`.
    """

    t_s: float
    x_px: float
    y_px: float
    flags: GazeFlag = VALID

    @property
    def is_valid(self) -> bool:
        """True for a gaze point inside the image."""
        return not self.flags

    @property
    def is_blink(self) -> bool:
        """True for an eye-closed sample."""
        return bool(self.flags & GazeFlag.BLINK)

    @property
    def has_time(self) -> bool:
        """True when ``t_s`` can be trusted (every flag but ``CORRUPT``)."""
        return not self.flags & GazeFlag.CORRUPT


_CORRUPT_SAMPLE = GazeSample(math.nan, math.nan, math.nan, GazeFlag.CORRUPT)


@dataclass(frozen=True, slots=True)
class BlinkTruth:
    """Ground truth of one blink produced by :class:`VirtualSubject`.

    Samples with ``t_start_s <= t_s < t_end_s`` are (-2000, -2000).
    """

    t_start_s: float
    t_end_s: float
    voluntary: bool

    @property
    def duration_s(self) -> float:
        return self.t_end_s - self.t_start_s


# --------------------------------------------------------------------------------------------------
# Geometry of the image (thesis 6.3, Figure 6.10)


def classify(x_px: float, y_px: float) -> GazeFlag:
    """Classify a gaze point: blink sentinel, inside the image, outside it, or not finite."""
    if x_px == BLINK_SENTINEL_PX and y_px == BLINK_SENTINEL_PX:
        return GazeFlag.BLINK
    if not (math.isfinite(x_px) and math.isfinite(y_px)):
        return GazeFlag.CORRUPT
    if 0.0 <= x_px <= IMAGE_WIDTH_PX and 0.0 <= y_px <= IMAGE_HEIGHT_PX:
        return VALID
    return GazeFlag.OUT_OF_RANGE


def gaze_vector_px(x_px: float, y_px: float) -> tuple[float, float]:
    """Gaze point in the command frame: origin at the image centre, x right, y up, px.

    The thesis (6.3, Figure 6.10) prints ``y = y_gt - 288`` with the image origin at the upper-left
    corner; with image rows growing downward that would put "Up" (``y_ratio > 0``, Table 6.1) in the lower
    half of the image. We take the Cartesian reading of Figure 6.10 (y up), so looking at the upper part
    of the image commands "Up".
    """
    return x_px - CENTER_X_PX, CENTER_Y_PX - y_px


def gaze_ratios(x_px: float, y_px: float) -> tuple[float, float]:
    """``(x_ratio, y_ratio)`` of thesis 6.3: the centred point over the half-width 384 and half-height 288."""
    x, y = gaze_vector_px(x_px, y_px)
    return x / CENTER_X_PX, y / CENTER_Y_PX


def gaze_angle_rad(x_px: float, y_px: float) -> float:
    """Direction of the gaze vector in the command frame, rad in [0, 2 pi), 0 = right, pi/2 = up."""
    x, y = gaze_vector_px(x_px, y_px)
    return math.atan2(y, x) % _TWO_PI


# --------------------------------------------------------------------------------------------------
# Line format


def parse_line(line: bytes | str, *, max_line_bytes: int = MAX_LINE_BYTES) -> GazeSample | None:
    """Parse one line of the serial format (terminator optional), never raising.

    Parameters
    ----------
    line : bytes or str
        One line, with or without its terminator.
    max_line_bytes : int
        Longer lines are ``CORRUPT``.

    Returns
    -------
    GazeSample or None
        ``None`` for a blank or comment line; otherwise a classified sample.
    """
    if isinstance(line, (bytes, bytearray)):
        line = line.rstrip(b"\r\n")
        if len(line) > max_line_bytes:
            return _CORRUPT_SAMPLE
        try:
            text = line.decode("ascii")
        except UnicodeDecodeError:
            return _CORRUPT_SAMPLE
    else:
        text = line.rstrip("\r\n")
        if len(text) > max_line_bytes:
            return _CORRUPT_SAMPLE
    text = text.strip()
    if not text or text.startswith("#"):
        return None
    match = _LINE_RE.fullmatch(text)
    if match is None:
        return _CORRUPT_SAMPLE
    t_ms, x_px, y_px = (float(g) for g in match.groups())
    if t_ms < 0.0:
        return _CORRUPT_SAMPLE
    return GazeSample(t_ms / 1000.0, x_px, y_px, classify(x_px, y_px))


def format_line(t_s: float, x_px: float, y_px: float) -> bytes:
    """One line of the serial format: integer milliseconds, pixels with one decimal, LF-terminated."""
    if x_px == BLINK_SENTINEL_PX and y_px == BLINK_SENTINEL_PX:
        return b"%d,-2000,-2000\n" % round(t_s * 1000.0)
    return b"%d,%.1f,%.1f\n" % (round(t_s * 1000.0), x_px, y_px)


class GazeLineDecoder:
    """Stateful line decoder: :func:`parse_line` plus the check that time increases.

    Parameters
    ----------
    max_line_bytes : int
        Longer lines are ``CORRUPT``.
    resync_after : int
        After this many non-increasing times in a row, the latest one is accepted as a new time base
        (the tracker restarted, or one garbled time ran ahead and would otherwise block every later line).
    """

    def __init__(self, *, max_line_bytes: int = MAX_LINE_BYTES, resync_after: int = 3) -> None:
        if resync_after < 1:
            raise ValueError("resync_after must be >= 1")
        self.max_line_bytes = max_line_bytes
        self.resync_after = resync_after
        self.reset()

    def reset(self) -> None:
        """Forget the last time seen."""
        self._last_t_s: float | None = None
        self._n_backward = 0

    def decode(self, line: bytes | str) -> GazeSample | None:
        """Decode one line; ``None`` for blank and comment lines."""
        sample = parse_line(line, max_line_bytes=self.max_line_bytes)
        if sample is None or not sample.has_time:
            if sample is not None:
                logger.debug("corrupt gaze line %r", line[:40])
            return sample
        if self._last_t_s is not None and sample.t_s <= self._last_t_s:
            self._n_backward += 1
            if self._n_backward < self.resync_after:
                logger.debug("gaze time %.3f s does not increase (last %.3f s)", sample.t_s, self._last_t_s)
                return GazeSample(sample.t_s, sample.x_px, sample.y_px, sample.flags | GazeFlag.CORRUPT)
            logger.warning("gaze tracker clock jumped from %.3f s to %.3f s; resynchronising",
                           self._last_t_s, sample.t_s)
        self._n_backward = 0
        self._last_t_s = sample.t_s
        return sample


class LineFramer:
    """Split a byte stream into lines; an over-long line yields one chunk of ``max_line_bytes + 1`` (corrupt).

    Parameters
    ----------
    max_line_bytes : int
        Once the pending bytes exceed this without a terminator, they are emitted as one chunk longer than
        ``max_line_bytes`` and the rest of that line is skipped up to its terminator.
    """

    def __init__(self, *, max_line_bytes: int = MAX_LINE_BYTES) -> None:
        self.max_line_bytes = max_line_bytes
        self._buf = bytearray()
        self._skipping = False

    def feed(self, data: bytes) -> list[bytes]:
        """Add bytes; return the complete lines (without terminators) now available."""
        self._buf += data
        lines: list[bytes] = []
        while True:
            match = _TERMINATOR_RE.search(self._buf)
            if match is None:
                if len(self._buf) > self.max_line_bytes:
                    if not self._skipping:
                        lines.append(bytes(self._buf[: self.max_line_bytes + 1]))
                    self._skipping = True
                    self._buf.clear()
                return lines
            end = match.start()
            if self._skipping:
                self._skipping = False
            elif end:  # an over-long line is cut to max_line_bytes + 1: enough to be flagged
                lines.append(bytes(self._buf[: min(end, self.max_line_bytes + 1)]))
            del self._buf[: end + 1]

    def flush(self) -> bool:
        """Drop the unterminated tail; return True when there was one (a line cut short)."""
        cut = bool(self._buf) and not self._skipping
        self._buf.clear()
        self._skipping = False
        return cut


# --------------------------------------------------------------------------------------------------
# Recorded gaze files


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


# --------------------------------------------------------------------------------------------------
# Sources


@runtime_checkable
class GazeSource(Protocol):
    """What every gaze source offers."""

    @property
    def exhausted(self) -> bool:
        """True once the source will never produce another sample."""

    def read(self, timeout_s: float | None = None) -> GazeSample | None:
        """Next sample, or ``None`` if none came within ``timeout_s`` or the source is exhausted."""

    def close(self) -> None:
        """Release the source; safe to call twice."""

    def __iter__(self) -> Iterator[GazeSample]: ...

    def __enter__(self) -> GazeSource: ...

    def __exit__(self, *exc_info: object) -> None: ...


class _SourceBase:
    """Iteration, context management and idempotent close shared by the sources."""

    _closed = False

    @property
    def closed(self) -> bool:
        return self._closed

    @property
    def exhausted(self) -> bool:
        raise NotImplementedError

    def read(self, timeout_s: float | None = None) -> GazeSample | None:
        raise NotImplementedError

    def _check_open(self) -> None:
        if self._closed:
            raise ValueError(f"read from a closed {type(self).__name__}")

    def __iter__(self) -> Iterator[GazeSample]:
        while True:
            sample = self.read()
            if sample is not None:
                yield sample
            elif self.exhausted:
                return

    def __enter__(self):
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            self._close()

    def _close(self) -> None:
        pass


class _RealtimePacer:
    """Holds samples back until their time has come on the wall clock (for demos and live replays)."""

    def __init__(self) -> None:
        self._offset_s: float | None = None

    def wait(self, t_s: float, timeout_s: float) -> bool:
        """Sleep until ``t_s`` is due; False if that is more than ``timeout_s`` away (slept ``timeout_s``)."""
        now = time.monotonic()
        if self._offset_s is None:
            self._offset_s = now - t_s
        wait_s = t_s + self._offset_s - now
        if wait_s > timeout_s:
            time.sleep(timeout_s)
            return False
        if wait_s > 0:
            time.sleep(wait_s)
        return True


class SerialGazeSource(_SourceBase):
    """Gaze tracker on a serial port or any pyserial URL (``loop://``, ``socket://host:port``, a pty path).

    Parameters
    ----------
    url : str
        Device path or pyserial URL, passed to ``serial.serial_for_url``.
    baudrate : int
        Line speed (ignored by ``loop://`` and ``socket://``).
    timeout_s : float
        Default wait of :meth:`read`.
    poll_s : float
        Longest single blocking read on the port; bounds how late a ``read`` returns after its timeout.
    max_line_bytes : int
        Longer lines are ``CORRUPT``.
    eof_idle_s : float or None
        If set, the source is exhausted after this long without a byte (useful for files and ptys whose
        writer never hangs up). A closed connection exhausts it in any case.

    Raises
    ------
    BackendError
        When the port cannot be opened.
    """

    def __init__(self, url: str, *, baudrate: int = 115200, timeout_s: float = 0.1, poll_s: float = 0.01,
                 max_line_bytes: int = MAX_LINE_BYTES, eof_idle_s: float | None = None) -> None:
        import serial  # pyserial is only needed here

        self.url = url
        self.timeout_s = timeout_s
        self.eof_idle_s = eof_idle_s
        self._serial_error = serial.SerialException
        self._framer = LineFramer(max_line_bytes=max_line_bytes)
        self._decoder = GazeLineDecoder(max_line_bytes=max_line_bytes)
        self._lines: deque[bytes | None] = deque()  # None: a line cut short by the end of the stream
        self._exhausted = False
        try:
            self._port = serial.serial_for_url(url, baudrate=baudrate, timeout=poll_s)
        except (serial.SerialException, ValueError, OSError) as exc:
            raise BackendError(f"gaze tracker: cannot open serial port {url!r}: {exc}") from exc
        self._last_rx_s = time.monotonic()
        logger.info("gaze tracker serial port %s open at %d Bd", url, baudrate)

    @property
    def port(self):
        """The underlying pyserial object (tests write to ``loop://`` through it)."""
        return self._port

    @property
    def exhausted(self) -> bool:
        return self._exhausted and not self._lines

    def read(self, timeout_s: float | None = None) -> GazeSample | None:
        self._check_open()
        deadline = time.monotonic() + (self.timeout_s if timeout_s is None else timeout_s)
        while True:
            while self._lines:
                line = self._lines.popleft()
                sample = _CORRUPT_SAMPLE if line is None else self._decoder.decode(line)
                if sample is not None:
                    return sample
            if self._exhausted:
                return None
            self._receive()
            if not self._lines and time.monotonic() >= deadline:
                return None

    def _receive(self) -> None:
        data = bytearray()
        ended = None
        try:
            data += self._port.read(1)
            # in_waiting is exact for ttys and loop://, 0/1 for socket://: drain what is there, bounded.
            while data and len(data) < 65536 and (n := self._port.in_waiting):
                data += self._port.read(n)
        except self._serial_error as exc:  # keep what came before the hang-up
            ended = exc
        now = time.monotonic()
        if data:
            self._last_rx_s = now
            self._lines.extend(self._framer.feed(bytes(data)))
        if ended is not None:
            logger.warning("gaze tracker %s: connection ended (%s)", self.url, ended)
            self._end_of_stream()
        elif not data and self.eof_idle_s is not None and now - self._last_rx_s > self.eof_idle_s:
            logger.info("gaze tracker %s: no data for %.2f s, end of stream", self.url, self.eof_idle_s)
            self._end_of_stream()

    def _end_of_stream(self) -> None:
        self._exhausted = True
        if self._framer.flush():
            self._lines.append(None)  # an unterminated tail may be cut short, whatever it holds

    def _close(self) -> None:
        self._exhausted = True
        self._port.close()
        logger.info("gaze tracker serial port %s closed", self.url)


class ReplayGazeSource(_SourceBase):
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
        self._pacer = _RealtimePacer()

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


# --------------------------------------------------------------------------------------------------
# Virtual subject

#: Scene-camera resolution assumed for saccade durations (not from the thesis: ~64 deg over 768 px).
SCENE_PX_PER_DEG = 12.0


def _min_jerk(tau: float) -> float:
    return tau * tau * tau * (10.0 - 15.0 * tau + 6.0 * tau * tau)


class VirtualSubject(_SourceBase):
    """A simulated wearer of the gaze tracker, looking where it wants the hand to go.

    The gaze follows ``target_px`` with a reaction time, by saccades (main-sequence duration, minimum-jerk
    shape, undershoot and landing error, corrective saccades), and fixates with drift, square-wave
    intrusions (the "involuntary saccades" of thesis 6.2.1), occasional glances elsewhere in the scene and
    tremor/measurement noise. It blinks involuntarily (Poisson onsets, 0.1-0.4 s) and voluntarily on
    :meth:`request_voluntary_blink` (at least ``voluntary_min_s``). The tracker adds out-of-range samples,
    notably just after a blink. Fatigue scales noise, drift, intrusions, blink rate and reaction times up
    by ``1 + fatigue_per_min * minutes``; ``skill`` in [0, 1] (1 = expert) lowers landing error,
    intrusions, glances, noise and reaction time. Everything is drawn from ``numpy.random.default_rng(seed)``.

    Parameters
    ----------
    target_px : callable
        ``target_px(t_s) -> (x_px, y_px)`` the point the subject wants to look at now, or ``None`` to keep
        looking where it looks. May be replaced between reads (attribute ``target_px``).
    seed : int
        Seed of the random generator.
    skill : float
        0 (naive) to 1 (expert).
    fatigue_per_min : float
        Relative growth of the noise terms and reaction time per minute of session.
    rate_hz : float
        Sample rate of the tracker.
    jitter_s : float
        Standard deviation of the timestamp jitter; times are rounded to whole milliseconds.
    blink_rate_hz : float
        Rate of involuntary blinks when rested (people blink about 15 times a minute).
    voluntary_min_s, voluntary_max_s : float
        Range of the durations of voluntary blinks.
    artifact_prob : float
        Probability that a sample is an out-of-range artefact.
    edge_artifact_prob : float
        Probability that the first sample after a blink is an out-of-range artefact (half-open eye).
    duration_s : float or None
        The source is exhausted after this much simulated time (None: never).
    realtime : bool
        If True, :meth:`read` paces samples on the wall clock.
    t0_s : float
        Time of the first sample.
    timeout_s : float
        Default wait of :meth:`read` (only matters when ``realtime``).
    session_start_s : float or None
        Start of the session for the fatigue clock (``t0_s`` if None): a subject simulated trial by trial
        keeps tiring over the session.
    """

    def __init__(self, target_px: Callable[[float], tuple[float, float] | None], *, seed: int = 0,
                 skill: float = 0.8, fatigue_per_min: float = 0.02, rate_hz: float = NOMINAL_RATE_HZ,
                 jitter_s: float = 0.001, blink_rate_hz: float = 0.25, voluntary_min_s: float = 0.75,
                 voluntary_max_s: float = 1.4, artifact_prob: float = 0.002, edge_artifact_prob: float = 0.15,
                 duration_s: float | None = None, realtime: bool = False, t0_s: float = 0.0,
                 timeout_s: float = 0.1, session_start_s: float | None = None) -> None:
        if not 0.0 <= skill <= 1.0:
            raise ValueError(f"skill must be in [0, 1], got {skill}")
        if rate_hz <= 0 or not 0 < voluntary_min_s <= voluntary_max_s:
            raise ValueError("rate_hz must be > 0 and 0 < voluntary_min_s <= voluntary_max_s")
        self.target_px = target_px
        self.seed = seed
        self.skill = skill
        self.fatigue_per_min = fatigue_per_min
        self.rate_hz = rate_hz
        self.jitter_s = jitter_s
        self.blink_rate_hz = blink_rate_hz
        self.voluntary_min_s = voluntary_min_s
        self.voluntary_max_s = voluntary_max_s
        self.artifact_prob = artifact_prob
        self.edge_artifact_prob = edge_artifact_prob
        self.duration_s = duration_s
        self.realtime = realtime
        self.t0_s = t0_s
        self.timeout_s = timeout_s
        self.session_start_s = t0_s if session_start_s is None else session_start_s
        #: Ground truth of every blink so far, in order.
        self.blinks: list[BlinkTruth] = []
        self._rng = np.random.default_rng(seed)
        self._pacer = _RealtimePacer()
        self._k = 0
        self._last_t_s = -math.inf
        self._requests: deque[tuple[float, float]] = deque()  # (due time, duration)
        self._blink: BlinkTruth | None = None
        self._refractory_until_s = -math.inf
        self._edge_pending = False
        self._next_blink_s = t0_s + self._exp(self.blink_rate_hz)
        start = target_px(t0_s) or (CENTER_X_PX, CENTER_Y_PX)
        self._goal = (float(start[0]), float(start[1]))
        self._fix = self._goal
        self._last_pos = self._goal
        self._saccade: tuple[float, float, tuple[float, float], tuple[float, float]] | None = None
        self._saccade_due_s: float | None = None
        self._offset: tuple[float, float] = (0.0, 0.0)
        self._offset_until_s = -math.inf
        self._prev_t_s = t0_s

    # -- public ------------------------------------------------------------------------------------

    @property
    def t_s(self) -> float:
        """Time of the last sample produced (``t0_s`` before the first)."""
        return self._prev_t_s

    @property
    def exhausted(self) -> bool:
        return self.duration_s is not None and self._k / self.rate_hz >= self.duration_s

    def request_voluntary_blink(self, *, duration_s: float | None = None, at_s: float | None = None) -> None:
        """Ask the subject for a voluntary blink (to open or close the hand).

        Parameters
        ----------
        duration_s : float or None
            Eyes-closed time; drawn in [voluntary_min_s, voluntary_max_s] if None.
        at_s : float or None
            When the eyes close (at the first sample from then on, once any blink in progress has ended);
            if None, after a reaction time from now.
        """
        if duration_s is None:
            duration_s = float(self._rng.uniform(self.voluntary_min_s, self.voluntary_max_s))
        if at_s is None:
            at_s = self._prev_t_s + self._reaction_s(0.25 + 0.25 * (1.0 - self.skill))
        self._requests.append((at_s, duration_s))

    def read(self, timeout_s: float | None = None) -> GazeSample | None:
        self._check_open()
        if self.exhausted:
            return None
        if self.realtime:
            due_s = self.t0_s + self._k / self.rate_hz
            if not self._pacer.wait(due_s, self.timeout_s if timeout_s is None else timeout_s):
                return None
        return self._step()

    # -- model -------------------------------------------------------------------------------------

    def _exp(self, rate_hz: float) -> float:
        return math.inf if rate_hz <= 0 else float(self._rng.exponential(1.0 / rate_hz))

    def _fatigue(self, t_s: float) -> float:
        return 1.0 + self.fatigue_per_min * (t_s - self.session_start_s) / 60.0

    def _reaction_s(self, mean_s: float) -> float:
        return mean_s * self._fatigue(self._prev_t_s) * math.exp(0.25 * float(self._rng.standard_normal()))

    def _step(self) -> GazeSample:
        rng = self._rng
        k = self._k
        self._k += 1
        t_s = round((self.t0_s + k / self.rate_hz + self.jitter_s * float(rng.standard_normal())) * 1000.0) / 1000.0
        t_s = max(t_s, self._last_t_s + 0.001)
        self._last_t_s = t_s
        dt_s = max(t_s - self._prev_t_s, 0.0)
        self._prev_t_s = t_s
        fatigue = self._fatigue(t_s)
        lack = 1.0 - self.skill

        x_px, y_px = self._eye(t_s, dt_s, fatigue, lack)
        if self._blinking(t_s, fatigue):
            return GazeSample(t_s, BLINK_SENTINEL_PX, BLINK_SENTINEL_PX, GazeFlag.BLINK)
        noise_px = (1.5 + 3.0 * lack) * fatigue
        x_px += noise_px * float(rng.standard_normal())
        y_px += noise_px * float(rng.standard_normal())
        edge = self._edge_pending and rng.random() < self.edge_artifact_prob
        self._edge_pending = False
        if edge:  # the eye half open: the tracker has one coordinate only
            y_px = BLINK_SENTINEL_PX
        elif rng.random() < self.artifact_prob * fatigue:
            x_px = float(rng.choice([-1.0, 1.0])) * float(rng.uniform(800.0, 3000.0))
        x_px, y_px = round(x_px, 1), round(y_px, 1)
        return GazeSample(t_s, x_px, y_px, classify(x_px, y_px))

    def _blinking(self, t_s: float, fatigue: float) -> bool:
        blink = self._blink
        if blink is not None:
            if t_s < blink.t_end_s:
                return True
            self._blink = None
            self._edge_pending = True
            self._refractory_until_s = blink.t_end_s + 0.3
        if t_s < self._refractory_until_s:
            return False
        if self._requests and t_s >= self._requests[0][0]:
            _, duration_s = self._requests.popleft()
            self._start_blink(t_s, duration_s, voluntary=True)
            return True
        if t_s >= self._next_blink_s:
            # Keep involuntary blinks apart from an imminent voluntary one: the truth stays unambiguous.
            if self._requests and self._requests[0][0] - t_s < 0.8:
                self._next_blink_s = t_s + self._exp(self.blink_rate_hz * fatigue)
                return False
            duration_s = min(max(0.2 * math.exp(0.3 * float(self._rng.standard_normal())), 0.1), 0.4)
            self._start_blink(t_s, duration_s, voluntary=False)
            self._next_blink_s = t_s + duration_s + self._exp(self.blink_rate_hz * fatigue)
            return True
        return False

    def _start_blink(self, t_s: float, duration_s: float, *, voluntary: bool) -> None:
        self._blink = BlinkTruth(t_s, t_s + duration_s, voluntary)
        self.blinks.append(self._blink)

    def _eye(self, t_s: float, dt_s: float, fatigue: float, lack: float) -> tuple[float, float]:
        """Advance the oculomotor state to ``t_s``; return the true eye position, px."""
        rng = self._rng
        goal = self.target_px(t_s)
        if goal is not None:
            self._goal = (float(goal[0]), float(goal[1]))
        gx, gy = self._goal

        if self._saccade is not None:
            t0_s, dur_s, (x0, y0), (x1, y1) = self._saccade
            tau = (t_s - t0_s) / dur_s
            if tau < 1.0:
                s = _min_jerk(tau)
                self._last_pos = (x0 + (x1 - x0) * s, y0 + (y1 - y0) * s)
                return self._last_pos
            self._saccade = None
            self._fix = (x1, y1)

        # Fixation: the centre drifts as a random walk.
        drift_px = (6.0 + 10.0 * lack) * fatigue * math.sqrt(dt_s)
        fx = self._fix[0] + drift_px * float(rng.standard_normal())
        fy = self._fix[1] + drift_px * float(rng.standard_normal())
        self._fix = (fx, fy)

        error_px = math.hypot(gx - fx, gy - fy)
        if self._saccade_due_s is None and error_px > 12.0 + 15.0 * lack:
            mean_s = 0.15 if error_px < 60.0 else 0.2 + 0.15 * lack
            self._saccade_due_s = t_s + self._reaction_s(mean_s)
        if self._saccade_due_s is not None and t_s >= self._saccade_due_s:
            self._saccade_due_s = None
            self._offset_until_s = -math.inf
            self._launch_saccade(t_s, self._last_pos, (gx, gy), fatigue, lack)
            return self._last_pos

        # Square-wave intrusions and glances elsewhere in the scene, then back to the fixation.
        if t_s >= self._offset_until_s:
            self._offset = (0.0, 0.0)
            if rng.random() < (0.3 + 1.2 * lack) * fatigue * dt_s:
                amp_px = abs(float(rng.standard_normal())) * (15.0 + 25.0 * lack) * fatigue
                angle = float(rng.uniform(0.0, 2.0 * math.pi))
                self._offset = (amp_px * math.cos(angle), amp_px * math.sin(angle))
                self._offset_until_s = t_s + float(rng.uniform(0.1, 0.6))
            elif rng.random() < (0.02 + 0.08 * lack) * dt_s:
                px = (float(rng.uniform(0, IMAGE_WIDTH_PX)), float(rng.uniform(0, IMAGE_HEIGHT_PX)))
                self._offset = (px[0] - fx, px[1] - fy)
                self._offset_until_s = t_s + float(rng.uniform(0.25, 0.7))
        self._last_pos = (fx + self._offset[0], fy + self._offset[1])
        return self._last_pos

    def _launch_saccade(self, t_s: float, start: tuple[float, float], goal: tuple[float, float],
                        fatigue: float, lack: float) -> None:
        rng = self._rng
        dx, dy = goal[0] - start[0], goal[1] - start[1]
        amp_px = math.hypot(dx, dy)
        # Large saccades undershoot by a few percent; a corrective saccade follows.
        gain = float(rng.normal(0.95, 0.03 + 0.05 * lack)) if amp_px > 40.0 else float(rng.normal(1.0, 0.05))
        land_px = (2.0 + 8.0 * lack) * fatigue
        end = (start[0] + gain * dx + land_px * float(rng.standard_normal()),
               start[1] + gain * dy + land_px * float(rng.standard_normal()))
        # Main sequence: about 21 ms + 2.2 ms per degree.
        dur_s = 0.021 + 0.0022 * math.hypot(end[0] - start[0], end[1] - start[1]) / SCENE_PX_PER_DEG
        self._saccade = (t_s, dur_s, start, end)
        self._last_pos = start
