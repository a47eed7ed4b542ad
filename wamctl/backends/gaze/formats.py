"""The registry of gaze stream formats: ``gaze.format`` in a spec -> the decoder that reads it.

Each entry names its decoder as ``"module:class"`` (resolved at first use, as the registry of run kinds does), the
options the decoder takes, and whether its samples carry the tracker's time. A new format is one module next to
:mod:`.asl` with a class following :class:`~wamctl.backends.gaze.base.GazeStreamDecoder`, and one entry here.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass

from wamctl.backends.gaze.base import GazeStreamDecoder


@dataclass(frozen=True)
class StreamFormat:
    name: str
    decoder: str
    tracker_time: bool
    description: str

    def make(self, **options) -> GazeStreamDecoder:
        """A fresh decoder (they keep state); ``options`` are the decoder's keyword arguments."""
        module, _, attr = self.decoder.partition(":")
        return getattr(importlib.import_module(module), attr)(**options)


FORMATS: dict[str, StreamFormat] = {f.name: f for f in (
    StreamFormat("asl-serial-out", "wamctl.backends.gaze.asl:AslStreamDecoder", False,
                 "ASL Serial Out binary frames (7-bit groups + overflow bytes, start mark in bit 7); the tracker's own "
                 "output, 57600 Bd 8N1"),
    StreamFormat("ascii-pair", "wamctl.backends.gaze.ascii_pair:PairStreamDecoder", False,
                 "ASCII lines 'x,y' or 'x y' (the thesis' ordered pair), stamped on arrival"),
    StreamFormat("ascii-timestamped", "wamctl.backends.gaze.line_format:LineStreamDecoder", True,
                 "ASCII lines 't_ms,x_px,y_px' with the tracker's time"),
)}
FORMAT_NAMES: tuple[str, ...] = tuple(FORMATS)
DEFAULT_FORMAT = "asl-serial-out"


def make_decoder(name: str, **options) -> GazeStreamDecoder:
    """The decoder of format ``name``; ValueError naming the known formats otherwise."""
    try:
        fmt = FORMATS[name]
    except KeyError:
        raise ValueError(f"unknown gaze stream format {name!r} (known: {', '.join(FORMATS)})") from None
    return fmt.make(**options)
