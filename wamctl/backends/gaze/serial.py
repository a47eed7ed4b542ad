"""The gaze tracker on a serial port (pyserial): bytes in, classified samples out, through a stream decoder.

The decoder is a plug-in chosen by format name (:mod:`wamctl.backends.gaze.formats`: ``asl-serial-out``, the
tracker's own binary output and the default; ``ascii-pair``; ``ascii-timestamped``) or passed as ``decoder=``.

Arrival stamps: each read returns as soon as a byte is there (``read(1)`` with a short timeout, then what else is
waiting), and the frames it completes are stamped with ``time.monotonic()`` taken when the read returned. For the
formats without a tracker clock that stamp is the sample's time. What delays it: the transport (a USB serial
adapter holds bytes up to its latency timer, 16 ms by default on FTDI chips; see the README), the operating system's
scheduling, and in a busy Python process the GIL. Several frames completed by one read share its stamp.

With ``reader="process"`` the port is read, and the reads stamped, in a child process of its own (sent to this
one over a pipe): the stamps then do not wait for this process' GIL, which a busy main loop (an ``hmi_block``
writing its tables between trials) can hold for tens of milliseconds. The ``hmi_block`` reads its tracker that way.

Every read can go to a capture file (:class:`~wamctl.backends.gaze.capture.CaptureWriter`) as it arrives; the first
:data:`HEAD_BYTES` bytes are also kept in memory, to say what arrived when nothing decoded.
"""

from __future__ import annotations

import datetime as _dt
import logging
import multiprocessing
import time
from collections import deque

from wamctl.backends.gaze.base import Decoded, GazeStreamDecoder, SourceBase, cut_tail
from wamctl.backends.gaze.capture import CaptureWriter
from wamctl.backends.gaze.formats import DEFAULT_FORMAT, make_decoder
from wamctl.errors import BackendError
from wamctl.hmi.gaze import GazeSample

logger = logging.getLogger(__name__)

#: Bytes kept in memory from the start of the stream (for diagnosis when nothing decodes).
HEAD_BYTES = 8192
PARITIES = {"none": "N", "even": "E", "odd": "O", "mark": "M", "space": "S"}
FLOW_CONTROLS = ("none", "rtscts", "xonxoff", "dsrdtr")


class SerialGazeSource(SourceBase):
    """Gaze tracker on a serial port or any pyserial URL (``loop://``, ``socket://host:port``, a pty path).

    Parameters
    ----------
    url : str
        Device path or pyserial URL, passed to ``serial.serial_for_url``.
    baudrate : int
        Line speed (ignored by ``loop://`` and ``socket://``); 57600, the ASL Serial Out rate, by default.
    bytesize, parity, stopbits : int, str, float
        Character format: 8, ``"none"`` (or ``even``, ``odd``, ``mark``, ``space``), 1 (or 1.5, 2).
    flow_control : str
        ``none`` (the tracker streams without handshake), ``rtscts``, ``xonxoff`` or ``dsrdtr``.
    format : str
        Stream format (:data:`wamctl.backends.gaze.formats.FORMATS`), unless ``decoder`` is given.
    decoder : GazeStreamDecoder or None
        How the bytes become samples (overrides ``format``).
    timeout_s : float
        Default wait of :meth:`read`.
    poll_s : float
        Longest single blocking read on the port; bounds how late a ``read`` returns after its timeout.
    eof_idle_s : float or None
        If set, the source is exhausted after this long without a byte (useful for files and ptys whose
        writer never hangs up). A closed connection exhausts it in any case.
    capture : CaptureWriter or str or path or None
        Where every read goes as it arrives (a path opens a :class:`CaptureWriter`, closed with the source).
    reader : {"thread", "process"}
        Read the port in the calling thread, or in a child process that stamps the reads (see the module doc).

    Raises
    ------
    BackendError
        When the port cannot be opened.
    """

    def __init__(self, url: str, *, baudrate: int = 57600, bytesize: int = 8, parity: str = "none",
                 stopbits: float = 1, flow_control: str = "none", format: str = DEFAULT_FORMAT,
                 decoder: GazeStreamDecoder | None = None, timeout_s: float = 0.1, poll_s: float = 0.01,
                 eof_idle_s: float | None = None, capture=None, reader: str = "thread") -> None:
        import serial  # pyserial is only needed here

        if reader not in ("thread", "process"):
            raise ValueError(f"reader must be thread or process, got {reader!r}")
        if parity not in PARITIES or flow_control not in FLOW_CONTROLS:
            raise ValueError(f"parity {parity!r} / flow_control {flow_control!r}: expected one of "
                             f"{', '.join(PARITIES)} / {', '.join(FLOW_CONTROLS)}")
        self.url = url
        self.timeout_s = timeout_s
        self.eof_idle_s = eof_idle_s
        self.decoder = decoder if decoder is not None else make_decoder(format)
        self.format = getattr(self.decoder, "format", format)
        self.settings = {"url": url, "baudrate": baudrate, "bytesize": bytesize, "parity": PARITIES[parity],
                         "stopbits": stopbits, "flow_control": flow_control, "format": self.format}
        self._serial_error = serial.SerialException
        self._frames: deque[tuple[bytes | None, float]] = deque()  # None: a frame cut short by the end of the stream
        self._exhausted = False
        self.reads = 0
        self.head: list[tuple[float, bytes]] = []  # the first HEAD_BYTES bytes, as read
        self._head_bytes = 0
        options = {"baudrate": baudrate, "bytesize": bytesize, "parity": PARITIES[parity], "stopbits": stopbits,
                   "rtscts": flow_control == "rtscts", "xonxoff": flow_control == "xonxoff",
                   "dsrdtr": flow_control == "dsrdtr", "timeout": poll_s}
        self._poll_s = poll_s
        self._port = None
        self._child: _ChildReader | None = None
        if reader == "process":
            self._child = _ChildReader(url, options)
        else:
            try:
                self._port = serial.serial_for_url(url, **options)
            except (serial.SerialException, ValueError, OSError) as exc:
                raise BackendError(f"gaze tracker: cannot open serial port {url!r}: {exc}") from exc
        self.opened_s = self._last_rx_s = time.monotonic()
        self.first_rx_s: float | None = None
        if capture is not None and not isinstance(capture, CaptureWriter):
            capture = CaptureWriter(capture, {**self.settings, "opened_utc": _dt.datetime.now(
                _dt.timezone.utc).isoformat(timespec="milliseconds"), "opened_monotonic_s": self.opened_s})
        self.capture: CaptureWriter | None = capture
        logger.info("gaze tracker serial port %s open at %d Bd, format %s", url, baudrate, self.format)

    @property
    def port(self):
        """The underlying pyserial object (tests write to ``loop://`` through it)."""
        return self._port

    @property
    def stats(self):
        """What the decoder has seen (:class:`~wamctl.backends.gaze.base.DecodeStats`)."""
        return self.decoder.stats

    @property
    def exhausted(self) -> bool:
        return self._exhausted and not self._frames

    def read(self, timeout_s: float | None = None) -> GazeSample | None:
        d = self.read_decoded(timeout_s)
        return None if d is None else d.sample

    def read_decoded(self, timeout_s: float | None = None) -> Decoded | None:
        """Next decoded frame (sample, arrival time, raw fields), or None as :meth:`read`."""
        self._check_open()
        deadline = time.monotonic() + (self.timeout_s if timeout_s is None else timeout_s)
        while True:
            while self._frames:
                frame, arrival_s = self._frames.popleft()
                decoded = cut_tail(arrival_s) if frame is None else self.decoder.decode(frame, arrival_s)
                if decoded is not None:
                    return decoded
            if self._exhausted:
                return None
            self._receive()
            if not self._frames and time.monotonic() >= deadline:
                return None

    def _receive(self) -> None:
        if self._child is not None:
            chunks, ended = self._child.receive(self._poll_s)
            for now, data in chunks:
                self._got(data, now)
            now = chunks[-1][0] if chunks else time.monotonic()
            data = bool(chunks)
        else:
            data, ended = read_port(self._port, self._serial_error)
            now = time.monotonic()
            if data:
                self._got(bytes(data), now)
        if ended is not None:
            logger.warning("gaze tracker %s: connection ended (%s)", self.url, ended)
            self._end_of_stream(now)
        elif not data and self._idle_ended(now):
            logger.info("gaze tracker %s: no data for %.2f s, end of stream", self.url, self.eof_idle_s)
            self._end_of_stream(now)

    def _idle_ended(self, now: float) -> bool:
        """True when the port has been silent for longer than ``eof_idle_s`` (the stream's end, where one is set)."""
        return self.eof_idle_s is not None and now - self._last_rx_s > self.eof_idle_s

    def _got(self, data: bytes, now: float) -> None:
        self._last_rx_s = now
        if self.first_rx_s is None:
            self.first_rx_s = now
        self.reads += 1
        if self._head_bytes < HEAD_BYTES:
            self.head.append((now, data))
            self._head_bytes += len(data)
        if self.capture is not None:
            self.capture.write(now, data)
        self._frames.extend((f, now) for f in self.decoder.feed(data))

    def _end_of_stream(self, now: float) -> None:
        self._exhausted = True
        if self.decoder.flush():
            self._frames.append((None, now))  # an unterminated tail may be cut short, whatever it holds

    def _close(self) -> None:
        self._exhausted = True
        if self._child is not None:
            self._child.close()
        else:
            self._port.close()
        if self.capture is not None:
            self.capture.close()
        logger.info("gaze tracker serial port %s closed", self.url)


def read_port(port, serial_error) -> tuple[bytearray, Exception | None]:
    """One read: wait up to the port's timeout for a byte, then take what else is waiting (bounded); the error
    that ended the connection, if any (what came before it is kept)."""
    data = bytearray()
    try:
        data += port.read(1)
        # in_waiting is exact for ttys and loop://, 0/1 for socket://: drain what is there, bounded.
        while data and len(data) < 65536 and (n := port.in_waiting):
            data += port.read(n)
    except serial_error as exc:
        return data, exc
    return data, None


def _child_main(url: str, options: dict, conn, stop) -> None:
    """The child process of ``reader="process"``: open the port, then send ``("data", t, bytes)`` for every read
    (``t`` taken when the read returned) until told to stop or the connection ends (``("end", t, why)``)."""
    import serial

    try:
        port = serial.serial_for_url(url, **options)
    except (serial.SerialException, ValueError, OSError) as exc:
        conn.send(("error", 0.0, str(exc)))
        conn.close()
        return
    conn.send(("open", time.monotonic(), b""))
    try:
        while not stop.is_set():
            data, ended = read_port(port, serial.SerialException)
            now = time.monotonic()
            if data:
                conn.send(("data", now, bytes(data)))
            if ended is not None:
                conn.send(("end", now, str(ended)))
                break
    except (BrokenPipeError, EOFError, OSError):  # the parent went away
        pass
    finally:
        port.close()
        conn.close()


class _ChildReader:
    """A child process reading a serial port and stamping its reads (``reader="process"``)."""

    START_TIMEOUT_S = 20.0

    def __init__(self, url: str, options: dict) -> None:
        ctx = multiprocessing.get_context("spawn")  # no fork of a process that runs threads
        self._conn, child_conn = ctx.Pipe(duplex=False)
        self._stop = ctx.Event()
        self._proc = ctx.Process(target=_child_main, args=(url, options, child_conn, self._stop),
                                 name="gaze-port-reader", daemon=True)
        self._proc.start()
        child_conn.close()
        if not self._conn.poll(self.START_TIMEOUT_S):
            self.close()
            raise BackendError(f"gaze tracker: the reader process for {url!r} did not start")
        kind, _, payload = self._conn.recv()
        if kind == "error":
            self.close()
            raise BackendError(f"gaze tracker: cannot open serial port {url!r}: {payload}")

    def receive(self, timeout_s: float) -> tuple[list[tuple[float, bytes]], Exception | None]:
        """The reads that came within ``timeout_s`` (all that are waiting), and the end of the connection, if any."""
        chunks: list[tuple[float, bytes]] = []
        try:
            wait = timeout_s
            while self._conn.poll(wait):
                kind, t_s, payload = self._conn.recv()
                if kind == "end":
                    return chunks, ConnectionError(payload)
                chunks.append((t_s, payload))
                wait = 0.0
        except (EOFError, OSError) as exc:
            return chunks, ConnectionError(f"the reader process ended ({exc or 'no more data'})")
        return chunks, None

    def close(self) -> None:
        self._stop.set()
        self._proc.join(2.0)
        if self._proc.is_alive():
            self._proc.terminate()
            self._proc.join(1.0)
        self._conn.close()
