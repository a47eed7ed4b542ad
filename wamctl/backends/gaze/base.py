"""What the gaze sources share: iteration, context management, idempotent close, real-time pacing; and what the
stream decoders share: their protocol, the record of one decoded frame, and the counts of what they saw."""

from __future__ import annotations

import math
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

from wamctl.hmi.gaze import CORRUPT_SAMPLE, GazeFlag, GazeSample

#: The extra fields of a frame kept beside every decoded sample (NaN when the format has no such field).
RECORD_FIELDS = ("raw_x", "raw_y", "pupil", "status", "counter")

#: How many examples of each kind of error are kept (hex), and how many bytes of each.
MAX_EXAMPLES = 3
EXAMPLE_BYTES = 32


def hex_bytes(data: bytes, limit: int = EXAMPLE_BYTES) -> str:
    """``80 00 28 ...`` (space-separated hex), cut at ``limit`` bytes with ``... (+N bytes)``."""
    text = data[:limit].hex(" ")
    return text + (f" ... (+{len(data) - limit} bytes)" if len(data) > limit else "")


@dataclass(frozen=True, slots=True)
class Decoded:
    """One frame as decoded: the classified sample, the host's arrival time of its last byte and the frame's raw
    fields (``RECORD_FIELDS`` that the format carries; the others are absent)."""

    sample: GazeSample
    arrival_s: float
    fields: dict[str, float] = field(default_factory=dict)

    def record(self) -> list[float]:
        """``arrival_s, t_s, x_px, y_px, flags`` then :data:`RECORD_FIELDS` (NaN when absent)."""
        s = self.sample
        return [self.arrival_s, s.t_s, s.x_px, s.y_px, float(int(s.flags))] + [
            float(self.fields.get(k, math.nan)) for k in RECORD_FIELDS]


#: Columns of :meth:`Decoded.record` (the ``gaze_samples`` table of a run).
RECORD_COLUMNS = ["arrival_s", "t_s", "x_px", "y_px", "flags", *RECORD_FIELDS]


@dataclass
class DecodeStats:
    """What a decoder saw: bytes, frames, samples by class, and the errors with their first examples in hex.

    Error kinds: ``garbage`` (bytes outside any frame), ``cut`` (a frame interrupted by the start of the next:
    bytes were lost), ``bad`` (a frame of the right length whose content breaks the format), ``dropped``
    (frames the tracker's frame counter says never arrived), ``clock`` (the counter's time was re-anchored
    on the arrival times).
    """

    bytes: int = 0
    frames: int = 0
    samples: int = 0
    valid: int = 0
    blink: int = 0
    out_of_range: int = 0
    corrupt: int = 0
    garbage_bytes: int = 0
    cut_frames: int = 0
    bad_frames: int = 0
    dropped_frames: int = 0
    clock_adjusts: int = 0
    examples: dict[str, list[str]] = field(default_factory=dict)
    extra: dict[str, float | str] = field(default_factory=dict)

    def example(self, kind: str, data: bytes, note: str = "") -> None:
        """Keep the first :data:`MAX_EXAMPLES` examples of ``kind``."""
        kept = self.examples.setdefault(kind, [])
        if len(kept) < MAX_EXAMPLES:
            kept.append(hex_bytes(data) + (f" ({note})" if note else ""))

    def count(self, sample: GazeSample) -> None:
        self.samples += 1
        if sample.flags & GazeFlag.CORRUPT:
            self.corrupt += 1
        elif sample.flags & GazeFlag.BLINK:
            self.blink += 1
        elif sample.flags & GazeFlag.OUT_OF_RANGE:
            self.out_of_range += 1
        else:
            self.valid += 1

    @property
    def errors(self) -> int:
        """Framing and decode errors: cut and bad frames, corrupt samples (garbage is counted in bytes). Each error
        is counted once: a frame the framer dropped yields no sample, a line that yields a corrupt sample is not
        also a bad frame."""
        return self.cut_frames + self.bad_frames + self.corrupt

    def as_dict(self) -> dict:
        out = {k: getattr(self, k) for k in ("bytes", "frames", "samples", "valid", "blink", "out_of_range",
                                              "corrupt", "garbage_bytes", "cut_frames", "bad_frames",
                                              "dropped_frames", "clock_adjusts")}
        out["examples"] = {k: list(v) for k, v in self.examples.items()}
        out.update(self.extra)
        return out


#: A stream is usable once it gave this many samples with at most MAX_PROBLEM_SHARE errors and garbage.
MIN_GOOD_SAMPLES = 3
MAX_PROBLEM_SHARE = 0.25


def stream_problem(stats: DecodeStats) -> str | None:
    """Why a stream is not usable yet (too few samples, too many errors or bytes outside frames), or None."""
    good = stats.samples - stats.corrupt
    if good < MIN_GOOD_SAMPLES:
        return f"{good} sample(s) decoded"
    if stats.errors > MAX_PROBLEM_SHARE * (good + stats.errors):
        return f"{stats.errors} framing/decode errors for {good} samples"
    if stats.garbage_bytes > MAX_PROBLEM_SHARE * max(stats.bytes, 1):
        return f"{stats.garbage_bytes} of {stats.bytes} bytes outside frames"
    return None


@runtime_checkable
class GazeStreamDecoder(Protocol):
    """Turns the bytes of a tracker into samples: frames first, then one sample per frame.

    Framing and decoding are two steps so that a source can keep frames and decode them only when they are read;
    the source stamps each frame with the host's monotonic time of the read that completed it (``arrival_s``),
    which is the sample's time for formats without a tracker clock. Implementations:
    :class:`~wamctl.backends.gaze.asl.AslStreamDecoder` (``asl-serial-out``),
    :class:`~wamctl.backends.gaze.ascii_pair.PairStreamDecoder` (``ascii-pair``),
    :class:`~wamctl.backends.gaze.line_format.LineStreamDecoder` (``ascii-timestamped``); the registry of formats
    is :mod:`wamctl.backends.gaze.formats`.
    """

    #: What the decoder has seen so far.
    stats: DecodeStats

    def feed(self, data: bytes) -> list[bytes]:
        """Add bytes; return the frames they complete, in order."""

    def flush(self) -> bool:
        """End of stream: drop an unfinished frame; True when there was one (it may be cut short: corrupt)."""

    def decode(self, frame: bytes, arrival_s: float) -> Decoded | None:
        """One frame as a classified sample; ``None`` for a frame that carries no sample (blank, comment)."""


def cut_tail(arrival_s: float) -> Decoded:
    """The record of an unfinished frame left when the stream ended (the framer counted it as cut)."""
    return Decoded(CORRUPT_SAMPLE, arrival_s)


class SourceBase:
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


class RealtimePacer:
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
