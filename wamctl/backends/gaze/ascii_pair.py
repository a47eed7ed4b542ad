"""The ``ascii-pair`` format: one gaze point per ASCII line, ``x,y`` or ``x y``, no time.

This is the format the thesis describes (6.1.2: the tracker's laptop sends "the gaze point as an ordered pair through
the serial port at a rate of 30 Hz", scene-image pixels, ``-2000,-2000`` while the eye is closed). The line carries
no time: each sample is stamped with the host's monotonic clock when its line end arrived (``t_s = arrival_s``), so
its times are as good as the read loop (see :class:`~wamctl.backends.gaze.serial.SerialGazeSource`).

Line: two decimals separated by a comma or by spaces/tabs (``412.5,300``, ``412 300``, ``412.5, 300``), ended by
LF, CR or CRLF; blank lines and lines starting with ``#`` are ignored. Anything else (one or three numbers,
exponents, ``nan``, non-ASCII bytes, a line longer than ``max_line_bytes``) is ``CORRUPT``. ``-2000,-2000`` is a
blink (:func:`~wamctl.hmi.gaze.classify`).
"""

from __future__ import annotations

import re

from wamctl.backends.gaze.base import Decoded, DecodeStats
from wamctl.backends.gaze.line_format import MAX_LINE_BYTES, LineFramer
from wamctl.hmi.gaze import CORRUPT_SAMPLE, GazeFlag, GazeSample, classify

_NUM = r"[+-]?(?:\d+(?:\.\d*)?|\.\d+)"
_PAIR_RE = re.compile(rf"\s*({_NUM})(?:\s*,\s*|\s+)({_NUM})\s*")


def parse_pair(line: bytes, t_s: float, *, max_line_bytes: int = MAX_LINE_BYTES) -> GazeSample | None:
    """One ``x,y`` line (terminator optional) as a sample at ``t_s``; ``None`` for blank and comment lines."""
    line = line.rstrip(b"\r\n")
    if len(line) > max_line_bytes:
        return CORRUPT_SAMPLE
    try:
        text = line.decode("ascii").strip()
    except UnicodeDecodeError:
        return CORRUPT_SAMPLE
    if not text or text.startswith("#"):
        return None
    match = _PAIR_RE.fullmatch(text)
    if match is None:
        return CORRUPT_SAMPLE
    x_px, y_px = float(match.group(1)), float(match.group(2))
    return GazeSample(t_s, x_px, y_px, classify(x_px, y_px))


def format_pair(x_px: float, y_px: float) -> bytes:
    """One line of the format: pixels with one decimal (``-2000,-2000`` for a blink), LF-terminated."""
    if x_px == -2000.0 and y_px == -2000.0:
        return b"-2000,-2000\n"
    return b"%.1f,%.1f\n" % (x_px, y_px)


class PairStreamDecoder:
    """The ``ascii-pair`` format as a stream decoder (:class:`~wamctl.backends.gaze.base.GazeStreamDecoder`): lines
    from :class:`~wamctl.backends.gaze.line_format.LineFramer`, each stamped with its arrival time.

    Parameters
    ----------
    max_line_bytes : int
        Longer lines are ``CORRUPT``.
    """

    format = "ascii-pair"

    def __init__(self, *, max_line_bytes: int = MAX_LINE_BYTES) -> None:
        self.stats = DecodeStats()
        self.framer = LineFramer(max_line_bytes=max_line_bytes, stats=self.stats)

    def feed(self, data: bytes) -> list[bytes]:
        lines = self.framer.feed(data)
        self.stats.frames += len(lines)
        return lines

    def flush(self) -> bool:
        return self.framer.flush()

    def decode(self, frame: bytes, arrival_s: float) -> Decoded | None:
        sample = parse_pair(frame, arrival_s, max_line_bytes=self.framer.max_line_bytes)
        if sample is None:
            return None
        self.stats.count(sample)
        if sample.flags & GazeFlag.CORRUPT:
            if len(frame) <= self.framer.max_line_bytes:
                self.stats.example("corrupt", frame, "not x,y or x y")
            return Decoded(sample, arrival_s)
        return Decoded(sample, arrival_s, {"raw_x": sample.x_px, "raw_y": sample.y_px})
