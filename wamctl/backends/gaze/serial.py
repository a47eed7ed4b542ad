"""The gaze tracker on a serial port (pyserial): bytes in, classified samples out, through a stream decoder.

The decoder is a plug-in (:class:`~wamctl.backends.gaze.base.GazeStreamDecoder`): the ASCII line format of
:mod:`wamctl.backends.gaze.line_format` by default; a binary format of the tracker is a module next to it whose
decoder is passed as ``decoder=``.
"""

from __future__ import annotations

import logging
import time
from collections import deque

from wamctl.backends.gaze.base import GazeStreamDecoder, SourceBase
from wamctl.backends.gaze.line_format import MAX_LINE_BYTES, LineStreamDecoder
from wamctl.errors import BackendError
from wamctl.hmi.gaze import CORRUPT_SAMPLE, GazeSample

logger = logging.getLogger(__name__)


class SerialGazeSource(SourceBase):
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
        Longer lines are ``CORRUPT`` (for the default line decoder).
    eof_idle_s : float or None
        If set, the source is exhausted after this long without a byte (useful for files and ptys whose
        writer never hangs up). A closed connection exhausts it in any case.
    decoder : GazeStreamDecoder or None
        How the bytes become samples; the line format (:class:`LineStreamDecoder`) if None.

    Raises
    ------
    BackendError
        When the port cannot be opened.
    """

    def __init__(self, url: str, *, baudrate: int = 115200, timeout_s: float = 0.1, poll_s: float = 0.01,
                 max_line_bytes: int = MAX_LINE_BYTES, eof_idle_s: float | None = None,
                 decoder: GazeStreamDecoder | None = None) -> None:
        import serial  # pyserial is only needed here

        self.url = url
        self.timeout_s = timeout_s
        self.eof_idle_s = eof_idle_s
        self._serial_error = serial.SerialException
        self._decoder = decoder if decoder is not None else LineStreamDecoder(max_line_bytes=max_line_bytes)
        self._frames: deque[bytes | None] = deque()  # None: a frame cut short by the end of the stream
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
        return self._exhausted and not self._frames

    def read(self, timeout_s: float | None = None) -> GazeSample | None:
        self._check_open()
        deadline = time.monotonic() + (self.timeout_s if timeout_s is None else timeout_s)
        while True:
            while self._frames:
                frame = self._frames.popleft()
                sample = CORRUPT_SAMPLE if frame is None else self._decoder.decode(frame)
                if sample is not None:
                    return sample
            if self._exhausted:
                return None
            self._receive()
            if not self._frames and time.monotonic() >= deadline:
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
            self._frames.extend(self._decoder.feed(bytes(data)))
        if ended is not None:
            logger.warning("gaze tracker %s: connection ended (%s)", self.url, ended)
            self._end_of_stream()
        elif not data and self.eof_idle_s is not None and now - self._last_rx_s > self.eof_idle_s:
            logger.info("gaze tracker %s: no data for %.2f s, end of stream", self.url, self.eof_idle_s)
            self._end_of_stream()

    def _end_of_stream(self) -> None:
        self._exhausted = True
        if self._decoder.flush():
            self._frames.append(None)  # an unterminated tail may be cut short, whatever it holds

    def _close(self) -> None:
        self._exhausted = True
        self._port.close()
        logger.info("gaze tracker serial port %s closed", self.url)

