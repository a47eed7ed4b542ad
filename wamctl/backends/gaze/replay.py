"""Recorded gaze files and their replay.

Recorded gaze files are CSV with a header naming at least ``t_s,x_px,y_px`` (extra columns are ignored); see
:func:`read_gaze_csv` and :func:`write_gaze_csv`. :class:`ReplayGazeSource` plays samples back, as fast as they are
read or paced on the wall clock.
"""

from __future__ import annotations

import csv
import math
import os
from collections.abc import Iterable, Sequence
from pathlib import Path

from wamctl.backends.gaze.base import RealtimePacer, SourceBase
from wamctl.errors import DataFormatError
from wamctl.hmi.gaze import GazeSample, classify


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

