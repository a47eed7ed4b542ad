"""What the gaze sources share: iteration, context management, idempotent close, real-time pacing, and the
protocol of the stream decoders a :class:`~wamctl.backends.gaze.serial.SerialGazeSource` reads with."""

from __future__ import annotations

import time
from collections.abc import Iterator
from typing import Protocol, runtime_checkable

from wamctl.hmi.gaze import GazeSample


@runtime_checkable
class GazeStreamDecoder(Protocol):
    """Turns the bytes of a tracker into samples: frames first, then one sample per frame.

    Framing and decoding are two steps so that a source can keep frames and decode them only when they are read
    (the decoder may hold state, e.g. the last time seen). :class:`~wamctl.backends.gaze.line_format.LineStreamDecoder`
    is the ASCII line format; a binary format of the tracker is another class with these three methods.
    """

    def feed(self, data: bytes) -> list[bytes]:
        """Add bytes; return the frames they complete, in order."""

    def flush(self) -> bool:
        """End of stream: drop an unfinished frame; True when there was one (it may be cut short: corrupt)."""

    def decode(self, frame: bytes) -> GazeSample | None:
        """One frame as a classified sample; ``None`` for a frame that carries no sample (blank, comment)."""


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

