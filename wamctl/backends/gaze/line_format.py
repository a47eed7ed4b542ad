"""The ``ascii-timestamped`` format: ASCII lines ``t_ms,x_px,y_px`` with the tracker's time; parse, format, decode a
stream of lines. (The line framing is shared with the ``ascii-pair`` format of :mod:`.ascii_pair`.)

This is not what an ASL tracker sends by itself (see :mod:`.asl`): it is the format of a relay program between the
tracker and the PC, and the format wamctl used first.

Line format
-----------
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

:class:`LineStreamDecoder` puts :class:`LineFramer` and :class:`GazeLineDecoder` together as the stream decoder
(:class:`~wamctl.backends.gaze.base.GazeStreamDecoder`) of :class:`~wamctl.backends.gaze.serial.SerialGazeSource`.
"""

from __future__ import annotations

import logging
import re

from wamctl.backends.gaze.base import Decoded, DecodeStats
from wamctl.hmi.gaze import BLINK_SENTINEL_PX, CORRUPT_SAMPLE, GazeFlag, GazeSample, classify

logger = logging.getLogger(__name__)

#: Longest accepted line, terminator excluded; a valid line is at most ~30 bytes.
MAX_LINE_BYTES = 128

_NUM = r"[+-]?(?:\d+(?:\.\d*)?|\.\d+)"
_LINE_RE = re.compile(rf"\s*({_NUM})\s*,\s*({_NUM})\s*,\s*({_NUM})\s*")
_TERMINATOR_RE = re.compile(rb"[\r\n]")


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
            return CORRUPT_SAMPLE
        try:
            text = line.decode("ascii")
        except UnicodeDecodeError:
            return CORRUPT_SAMPLE
    else:
        text = line.rstrip("\r\n")
        if len(text) > max_line_bytes:
            return CORRUPT_SAMPLE
    text = text.strip()
    if not text or text.startswith("#"):
        return None
    match = _LINE_RE.fullmatch(text)
    if match is None:
        return CORRUPT_SAMPLE
    t_ms, x_px, y_px = (float(g) for g in match.groups())
    if t_ms < 0.0:
        return CORRUPT_SAMPLE
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

    def __init__(self, *, max_line_bytes: int = MAX_LINE_BYTES, stats: DecodeStats | None = None) -> None:
        self.max_line_bytes = max_line_bytes
        self.stats = stats if stats is not None else DecodeStats()
        self._buf = bytearray()
        self._skipping = False

    def feed(self, data: bytes) -> list[bytes]:
        """Add bytes; return the complete lines (without terminators) now available."""
        self.stats.bytes += len(data)
        self._buf += data
        lines: list[bytes] = []
        while True:
            match = _TERMINATOR_RE.search(self._buf)
            if match is None:
                if len(self._buf) > self.max_line_bytes:
                    if not self._skipping:
                        lines.append(bytes(self._buf[: self.max_line_bytes + 1]))
                        self._overlong(self._buf)
                    self._skipping = True
                    self._buf.clear()
                return lines
            end = match.start()
            if self._skipping:
                self._skipping = False
            elif end:  # an over-long line is cut to max_line_bytes + 1: enough to be flagged
                lines.append(bytes(self._buf[: min(end, self.max_line_bytes + 1)]))
                if end > self.max_line_bytes:
                    self._overlong(self._buf[:end])
            del self._buf[: end + 1]

    def _overlong(self, line: bytes | bytearray) -> None:
        # counted as a corrupt sample by the decoder; the example shows the whole start of the line
        self.stats.example("corrupt", bytes(line), f"no line end within {self.max_line_bytes} bytes")

    def flush(self) -> bool:
        """Drop the unterminated tail; return True when there was one (a line cut short)."""
        cut = bool(self._buf) and not self._skipping
        if cut:
            self.stats.cut_frames += 1
            self.stats.example("cut", bytes(self._buf), "unterminated at the end of the stream")
        self._buf.clear()
        self._skipping = False
        return cut



class LineStreamDecoder:
    """The ``ascii-timestamped`` format as a stream decoder: :class:`LineFramer` splits the bytes,
    :class:`GazeLineDecoder` decodes each line (see :class:`~wamctl.backends.gaze.base.GazeStreamDecoder`).
    The sample's time is the tracker's (``t_ms``); the arrival time is kept beside it.

    Parameters
    ----------
    max_line_bytes : int
        Longer lines are ``CORRUPT``.
    resync_after : int
        See :class:`GazeLineDecoder`.
    """

    format = "ascii-timestamped"

    def __init__(self, *, max_line_bytes: int = MAX_LINE_BYTES, resync_after: int = 3) -> None:
        self.stats = DecodeStats()
        self.framer = LineFramer(max_line_bytes=max_line_bytes, stats=self.stats)
        self.lines = GazeLineDecoder(max_line_bytes=max_line_bytes, resync_after=resync_after)

    def feed(self, data: bytes) -> list[bytes]:
        """Add bytes; return the complete lines (without terminators) now available."""
        lines = self.framer.feed(data)
        self.stats.frames += len(lines)
        return lines

    def flush(self) -> bool:
        """Drop the unterminated tail; True when there was one (a line cut short)."""
        return self.framer.flush()

    def decode(self, frame: bytes, arrival_s: float) -> Decoded | None:
        """Decode one line; ``None`` for blank and comment lines."""
        sample = self.lines.decode(frame)
        if sample is None:
            return None
        self.stats.count(sample)
        if sample.flags & GazeFlag.CORRUPT and len(frame) <= self.framer.max_line_bytes:
            self.stats.example("corrupt", frame, "not t_ms,x_px,y_px, or a time that does not increase")
        fields = {} if not sample.has_time else {"raw_x": sample.x_px, "raw_y": sample.y_px}
        return Decoded(sample, arrival_s, fields)
