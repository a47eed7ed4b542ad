"""Raw byte captures of a gaze tracker: every read of the port, with the host's time, as text.

A capture file (``gaze_capture.txt`` in a run directory, ``--capture FILE`` of ``wamctl gaze-check``)::

    # wamctl gaze capture 1
    # section {"url": "/dev/ttyUSB0", "baudrate": 57600, "bytesize": 8, "parity": "N", "stopbits": 1, ...}
    1234.567890123 80002800010001202000
    1234.601223456 800028000100012020...

One line per read: the host's monotonic clock (s, written so that it reads back bit for bit) when the read
returned, then the bytes in hex. A ``# section``
line starts the bytes of one opening of the port (its settings as JSON); a resumed session or another baud rate
tried by ``gaze-check`` adds a section. Each line is written and flushed as it comes, so a crash loses at most the
line being written; :func:`read_capture` skips such a torn last line. Replaying the chunks through the same decoder
at their recorded times gives the same samples as the live session
(:class:`~wamctl.backends.gaze.replay.RawReplaySource`).
"""

from __future__ import annotations

import json
import logging
import os
from dataclasses import dataclass, field
from pathlib import Path

from wamctl.errors import DataFormatError

log = logging.getLogger(__name__)

MAGIC = "# wamctl gaze capture 1"


@dataclass
class CaptureSection:
    """The reads of one opening of a port: its settings and ``(t_s, bytes)`` chunks in time order."""

    info: dict
    chunks: list[tuple[float, bytes]] = field(default_factory=list)

    @property
    def data(self) -> bytes:
        return b"".join(c for _, c in self.chunks)

    @property
    def duration_s(self) -> float:
        return self.chunks[-1][0] - self.chunks[0][0] if self.chunks else 0.0


class CaptureWriter:
    """Appends reads to a capture file, one flushed line each.

    Parameters
    ----------
    path : path
        The file; created with its header, or appended to (a new section) if it exists.
    info : dict
        The port's settings, written as the section's JSON.
    """

    def __init__(self, path: str | os.PathLike, info: dict) -> None:
        self.path = Path(path)
        new = not self.path.is_file() or self.path.stat().st_size == 0
        self._fh = self.path.open("a", encoding="ascii", buffering=1)  # line-buffered: flushed at each line end
        if new:
            self._fh.write(MAGIC + "\n")
        self._fh.write(f"# section {json.dumps(info, sort_keys=True)}\n")
        self.bytes_written = 0

    def write(self, t_s: float, data: bytes) -> None:
        if data and not self._fh.closed:
            self._fh.write(f"{t_s!r} {data.hex()}\n")  # repr: the stamp reads back bit for bit
            self.bytes_written += len(data)

    def close(self) -> None:
        if not self._fh.closed:
            self._fh.close()


def read_capture(path: str | os.PathLike) -> list[CaptureSection]:
    """The sections of a capture file.

    Raises
    ------
    DataFormatError
        Not a capture file, or a line (named) that is not ``TIME HEX`` or a ``# section`` with JSON; a torn last line
        (a crash while writing) is skipped with a warning.
    """
    path = Path(path)
    try:
        lines = path.read_text(encoding="ascii").splitlines(keepends=True)
    except (OSError, UnicodeDecodeError) as exc:
        raise DataFormatError(f"{path}: cannot read the capture: {exc}") from None
    if not lines or lines[0].rstrip("\r\n") != MAGIC:
        raise DataFormatError(f"{path}, line 1: not a gaze capture (expected {MAGIC!r})")
    sections: list[CaptureSection] = []
    for number, raw in enumerate(lines[1:], start=2):
        line = raw.strip()
        if not line:
            continue
        if number == len(lines) and not raw.endswith("\n"):  # every line is written with its end: torn
            log.warning("%s, line %d: torn last line skipped", path, number)
            break
        if line.startswith("# section "):
            try:
                sections.append(CaptureSection(json.loads(line[len("# section "):])))
            except json.JSONDecodeError as exc:
                raise DataFormatError(f"{path}, line {number}: section settings are not JSON ({exc})") from None
            continue
        if line.startswith("#"):
            continue
        try:
            stamp, hex_text = line.split()
            chunk = (float(stamp), bytes.fromhex(hex_text))
            if not sections:
                raise ValueError("bytes before the first '# section' line")
        except ValueError as exc:
            raise DataFormatError(f"{path}, line {number}: not 'TIME HEX' ({exc})") from None
        sections[-1].chunks.append(chunk)
    return sections


class MemoryCapture:
    """Keeps the reads of a port in memory as a :class:`CaptureSection` (and also writes them to ``also``, a
    :class:`CaptureWriter`, if given): the capture of ``wamctl gaze-check``."""

    def __init__(self, info: dict, also: CaptureWriter | None = None) -> None:
        self.section = CaptureSection(dict(info))
        self.also = also

    def write(self, t_s: float, data: bytes) -> None:
        if data:
            self.section.chunks.append((t_s, bytes(data)))
            if self.also is not None:
                self.also.write(t_s, data)

    def close(self) -> None:
        if self.also is not None:
            self.also.close()
