"""The ``asl-serial-out`` format: the binary "Serial Out" stream of ASL trackers (Mobile Eye, 5000/6000 series).

What the tracker sends (streaming mode), as two independent public readers decode it (the iCub driver for the ASL
Mobile Eye, ``robotology/icub-main`` ``MobileEyeServer/ASLSerialOutDecode.cpp``, ``SerialThread.cpp``,
``MobileEye.cpp``; the Gold lab's MATLAB reader, ``TheGoldLab/Lab-Matlab-Control`` ``dotsX/.../ASL/asl.c``; the
field list also as OGAMA's ASL module quotes the ASL manual):

* 57600 baud, 8 data bits, no parity, 1 stop bit, no flow control; tracker to host only.
* One fixed-length frame per camera sample: no length byte, checksum, terminator or time. The payload is the
  configured items ("Serial Out Format" in the ASL software), multi-byte values most significant byte first.
  The standard list is ``status:u8, pupil:i16, spare:u8, x:i16, y:i16`` (8 data bytes); some set-ups add a
  16-bit frame counter after the status (10 data bytes).
* The N data bytes go in groups of 7 (the last may be shorter), each group's bytes with bit 7 cleared and then
  one *overflow byte* whose bit i is bit 7 of the group's i-th byte. The frame's first byte then gets bit 7 set:
  the start mark; no other byte of a frame has bit 7 set. Wire length ``N + (N - 1) // 7 + 1`` (10 and 12).
* Pupil diameter 0 means the tracker lost the pupil (ASL manual, as quoted by OGAMA: "Pupil diameter, most
  significant byte (0=loss)"). The thesis' ``(-2000, -2000)`` for a closed eye is not in any public ASL source:
  it is most likely made by a relay program between tracker and PC. :class:`AslStreamDecoder` takes either as a
  blink (``blink="either"``, the default), or only one of them.
* Gaze is in the tracker's configured units: for the Mobile Eye, scene-image pixels (768 x 576 PAL).

Resynchronisation is strict (:class:`AslFramer`): a byte with bit 7 set always starts a frame, a frame interrupted
by one is dropped (``cut``: bytes were lost), bytes with bit 7 clear outside a frame are ``garbage``, and a frame
whose last overflow byte has bits above its group's size is ``bad``. So a frame spliced from two samples is never
decoded, and a frame is decoded as soon as its last byte arrives.

Times: the stream has none. Without a counter, a sample's time is its arrival time on the host's monotonic clock.
With a ``counter`` field, :class:`CounterClock` rebuilds the times from the counter (u16, wrapping) at
``counter_hz`` counts per second, anchored on the arrival times, and counts the frames that never arrived.
"""

from __future__ import annotations

import math
import re
import struct
from collections import deque
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from functools import cached_property
from typing import Literal

from wamctl.backends.gaze.base import Decoded, DecodeStats
from wamctl.hmi.gaze import BLINK_SENTINEL_PX, GazeFlag, GazeSample, classify

#: Field types of the ASL Serial Out items (byte, short, unsigned short, long, unsigned long, float).
FIELD_TYPES = {"u8": "B", "i8": "b", "u16": "H", "i16": "h", "u32": "I", "i32": "i", "f32": "f"}
#: Field names with a meaning to the decoder; any other name is kept in the frame but not used.
ROLES = ("x", "y", "pupil", "status", "counter")
#: The standard Serial Out items (iCub Mobile Eye driver; OGAMA's "Standard Serial Out data field").
STANDARD_FIELDS = ("status:u8", "pupil:i16", "spare:u8", "x:i16", "y:i16")
#: The standard items with a 16-bit frame counter after the status (the Gold lab's set-up).
COUNTER_FIELDS = ("status:u8", "counter:u16", "pupil:i16", "spare:u8", "x:i16", "y:i16")
BAUD_RATE = 57600

BlinkRule = Literal["either", "pupil-zero", "sentinel"]
BLINK_RULES: tuple[str, ...] = ("either", "pupil-zero", "sentinel")

_START = re.compile(rb"[\x80-\xff]")


def wire_length(n_data: int) -> int:
    """Bytes on the wire of a frame of ``n_data`` data bytes: the data, one overflow byte per group of 7."""
    if n_data < 1:
        raise ValueError(f"a frame has at least one data byte, got {n_data}")
    return n_data + (n_data - 1) // 7 + 1


def data_length(n_wire: int) -> int | None:
    """Data bytes of a frame of ``n_wire`` wire bytes, or None if no frame has that length (9, 17, ...)."""
    for n in range(max(1, n_wire - n_wire // 8 - 1), n_wire):
        if wire_length(n) == n_wire:
            return n
    return None


def unpack_7bit(wire: bytes, n_data: int) -> bytes:
    """The ``n_data`` data bytes of one frame (``wire`` holds exactly its ``wire_length(n_data)`` bytes): the start
    mark cleared, each byte's bit 7 restored from its group's overflow byte."""
    out = bytearray()
    pos = 0
    remaining = n_data
    while remaining:
        n = min(7, remaining)
        overflow = wire[pos + n]
        for i in range(n):
            b = wire[pos + i] & 0x7F
            out.append(b | ((overflow >> i) & 1) << 7)
        pos += n + 1
        remaining -= n
    return bytes(out)


def pack_7bit(data: bytes) -> bytes:
    """The wire bytes of one frame of ``data`` (the tracker's side of :func:`unpack_7bit`, for simulated trackers)."""
    out = bytearray()
    for g in range(0, len(data), 7):
        group = data[g:g + 7]
        overflow = 0
        for i, b in enumerate(group):
            out.append(b & 0x7F)
            overflow |= (b >> 7) << i
        out.append(overflow)
    out[0] |= 0x80
    return bytes(out)


@dataclass(frozen=True)
class AslLayout:
    """The items of a frame, in order, as ``(name, type)``, and the byte order of multi-byte items."""

    fields: tuple[tuple[str, str], ...]
    byte_order: Literal["big", "little"] = "big"

    @classmethod
    def parse(cls, fields: Sequence[str] = STANDARD_FIELDS, byte_order: str = "big") -> AslLayout:
        """A layout from ``["status:u8", "pupil:i16", ...]``; ValueError naming the item that is wrong."""
        items: list[tuple[str, str]] = []
        for k, item in enumerate(fields):
            name, sep, kind = str(item).partition(":")
            name, kind = name.strip(), kind.strip()
            if not sep or not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", name) or kind not in FIELD_TYPES:
                raise ValueError(f"fields[{k}]: {item!r} is not NAME:TYPE with TYPE one of {', '.join(FIELD_TYPES)}")
            if name in (n for n, _ in items):
                raise ValueError(f"fields[{k}]: {name!r} appears twice")
            items.append((name, kind))
        names = [n for n, _ in items]
        for role in ("x", "y"):
            if role not in names:
                raise ValueError(f"fields: no {role!r} item (the gaze coordinates are named x and y)")
        if "counter" in names and dict(items)["counter"] not in ("u8", "u16", "u32"):
            raise ValueError("fields: the counter must be unsigned (u8, u16 or u32)")
        if byte_order not in ("big", "little"):
            raise ValueError(f"byte_order: {byte_order!r} is not big or little")
        return cls(tuple(items), byte_order)  # type: ignore[arg-type]

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(n for n, _ in self.fields)

    @cached_property
    def packer(self) -> struct.Struct:
        codes = "".join(FIELD_TYPES[t] for _, t in self.fields)
        return struct.Struct((">" if self.byte_order == "big" else "<") + codes)

    @property
    def n_data(self) -> int:
        return self.packer.size

    @property
    def n_wire(self) -> int:
        return wire_length(self.n_data)

    def counter_modulus(self) -> int | None:
        kind = dict(self.fields).get("counter")
        return None if kind is None else 1 << (8 * struct.calcsize(FIELD_TYPES[kind]))

    def values(self, data: bytes) -> dict[str, float]:
        return dict(zip(self.names, self.packer.unpack(data)))

    def encode(self, values: Mapping[str, float]) -> bytes:
        """The wire bytes of one frame (missing items are 0): the tracker's side, for simulated trackers."""
        return pack_7bit(self.packer.pack(*(values.get(n, 0) for n in self.names)))

    def describe(self) -> str:
        return ", ".join(f"{n}:{t}" for n, t in self.fields)


class AslFramer:
    """Cuts a byte stream into frames of ``n_wire`` bytes by their start marks, strictly (see the module doc).

    Counts into ``stats``: ``garbage_bytes`` (bit 7 clear, no frame open), ``cut_frames`` (a frame interrupted by
    the next start mark), ``bad_frames`` (the last overflow byte has bits for bytes its group does not have, or the
    frames are too short for the stream).

    Too short: a configured item list shorter than the tracker's makes frames that end early, each followed by the
    rest of the tracker's frame (bytes with bit 7 clear) before the next start mark; such frames would decode to
    nonsense. When the last two frames were each followed by the same number of such bytes, frames are withheld
    (``bad``, with the length the stream seems to have) until one is followed directly by a start mark again.
    """

    def __init__(self, n_data: int, stats: DecodeStats | None = None) -> None:
        self.n_data = n_data
        self.n_wire = wire_length(n_data)
        self._last_group = n_data - 7 * ((n_data - 1) // 7)
        self.stats = stats if stats is not None else DecodeStats()
        self._buf = b""  # empty, or an unfinished frame starting with its start mark
        self._trail: int | None = None  # bytes without a start mark since the last frame ended (None: not after one)
        self._trails: list[int] = []  # what followed the last two frames

    @property
    def too_short(self) -> int:
        """Bytes that followed each of the last two frames before a start mark, when the same and > 0 (else 0)."""
        t = self._trails
        return t[0] if len(t) == 2 and t[0] == t[1] > 0 else 0

    def feed(self, data: bytes) -> list[bytes]:
        self.stats.bytes += len(data)
        buf = self._buf + bytes(data)
        self._buf = b""
        frames: list[bytes] = []
        pos, n, size = 0, len(buf), self.n_wire
        while pos < n:
            if not buf[pos] & 0x80:
                m = _START.search(buf, pos)
                end = m.start() if m else n
                self._garbage(buf[pos:end])
                if self._trail is not None:
                    self._trail += end - pos
                pos = end
                continue
            if self._trail is not None:
                self._trails = [*self._trails[-1:], self._trail]
                self._trail = None
            m = _START.search(buf, pos + 1, min(pos + size, n))
            if m is not None:
                self._cut(buf[pos:m.start()])
                pos = m.start()
                continue
            if pos + size > n:
                self._buf = buf[pos:]
                break
            frame = buf[pos:pos + size]
            pos += size
            self._trail = 0
            if extra := self.too_short:
                self.stats.bad_frames += 1
                longer = data_length(size + extra)
                self.stats.example("bad", frame, f"frames are followed by {extra} bytes without a start mark: the "
                                                 f"tracker's frames are {size + extra} bytes"
                                                 + (f" ({longer} data bytes)" if longer else "")
                                                 + f", not {size}; set asl.fields to its items")
                continue
            if frame[-1] >> self._last_group:
                self.stats.bad_frames += 1
                self.stats.example("bad", frame, f"last overflow byte {frame[-1]:#04x} has bits for bytes "
                                                 f"its group of {self._last_group} does not have")
                continue
            frames.append(frame)
        self.stats.frames += len(frames)
        return frames

    def flush(self) -> bool:
        cut = bool(self._buf)
        if cut:
            self._cut(self._buf, "unfinished at the end of the stream")
        self._buf = b""
        return cut

    def _garbage(self, data: bytes) -> None:
        self.stats.garbage_bytes += len(data)
        self.stats.example("garbage", data, "bit 7 clear outside a frame")

    def _cut(self, data: bytes, note: str | None = None) -> None:
        self.stats.cut_frames += 1
        self.stats.example("cut", data, note or f"{len(data)} of {self.n_wire} bytes, then a new start mark")


class CounterClock:
    """Sample times from the tracker's frame counter, anchored on the host's arrival times.

    The counter (modulus ``2**bits``) is unwrapped with the arrival times: of the increments congruent to the
    counter's difference, the one nearest to ``elapsed arrival time * counter_hz`` (so a gap longer than a wrap is
    still counted right). The frames the increment skips are counted as dropped. A counter that goes back, or jumps
    ahead by more than ``max_jump_s`` beyond the arrival times, is a restart or a corrupt value (counted as a
    ``clock`` error): the count goes on by the arrival times.

    Time: ``t = anchor + n / counter_hz`` (n the unwrapped count). Arrivals are late, never early, so the best anchor
    is the earliest ``arrival - n / counter_hz`` over the last ``window_s``: the frames that came with the least
    delay. The anchor starts at the first arrival and slews towards that target by at most ``slew`` sample periods
    per frame, so times always increase, frames read in a burst get their own times, and a tracker clock that is a
    little off ``counter_hz`` is followed.
    """

    def __init__(self, counter_hz: float, modulus: int, stats: DecodeStats, *, window_s: float = 2.0,
                 slew: float = 0.1, max_jump_s: float = 1.0) -> None:
        if counter_hz <= 0:
            raise ValueError(f"counter_hz must be > 0, got {counter_hz}")
        self.counter_hz = counter_hz
        self.modulus = modulus
        self.stats = stats
        self.window_s = window_s
        self.max_slew_s = slew / counter_hz
        self.max_jump_s = max_jump_s
        self._prev: tuple[int, float] | None = None  # (counter, arrival)
        self._first_arrival_s = math.nan
        self._n = 0
        self._anchor_s = math.nan
        self._candidates: deque[tuple[float, float]] = deque()  # (arrival, arrival - n / hz), increasing arrival

    def time(self, counter: int, arrival_s: float, frame: bytes = b"") -> float | None:
        """The sample time of a frame, or None for a repeated counter (the same frame twice); ``frame`` (its wire
        bytes) goes into the examples of errors."""
        counter = int(counter) % self.modulus
        if self._prev is None:
            self._anchor_s = self._first_arrival_s = arrival_s
        else:
            c_prev, a_prev = self._prev
            expected = max(arrival_s - a_prev, 0.0) * self.counter_hz
            d0 = (counter - c_prev) % self.modulus
            d = d0 + round((expected - d0) / self.modulus) * self.modulus
            if d == 0:
                self.stats.bad_frames += 1
                self.stats.example("bad", frame, f"frame counter {counter} twice in a row")
                return None
            if d < 0 or d > expected + self.max_jump_s * self.counter_hz:
                self.stats.clock_adjusts += 1
                self.stats.example("clock", frame, f"counter went from {c_prev} to {counter} in "
                                                   f"{arrival_s - a_prev:.3f} s")
                d = max(1, round(expected))
            else:
                self.stats.dropped_frames += d - 1
            self._n += d
        self._prev = (counter, arrival_s)
        t_s = self._anchor_s + self._n / self.counter_hz
        cands = self._candidates
        while cands and arrival_s - cands[0][0] > self.window_s:
            cands.popleft()
        cands.append((arrival_s, arrival_s - self._n / self.counter_hz))
        target_s = min(a for _, a in cands)
        self._anchor_s += min(max(target_s - self._anchor_s, -self.max_slew_s), self.max_slew_s)
        return t_s

    def measured_hz(self) -> float | None:
        """Counts per second over the arrival times so far (None before 2 s)."""
        if self._prev is None or self._prev[1] - self._first_arrival_s < 2.0:
            return None
        return self._n / (self._prev[1] - self._first_arrival_s)


class AslStreamDecoder:
    """The ``asl-serial-out`` format as a stream decoder (:class:`~wamctl.backends.gaze.base.GazeStreamDecoder`).

    Parameters
    ----------
    fields : sequence of str
        The Serial Out items in order, ``NAME:TYPE`` (types :data:`FIELD_TYPES`); ``x`` and ``y`` are required,
        ``pupil``, ``status`` and ``counter`` have a meaning, other names are skipped. Default
        :data:`STANDARD_FIELDS`.
    byte_order : {"big", "little"}
        Of the multi-byte items (big: most significant byte first, as the tracker sends them).
    blink : {"either", "pupil-zero", "sentinel"}
        What is a blink: pupil diameter 0 (the tracker's own loss code), gaze ``(-2000, -2000)`` (the thesis'
        convention, made by a relay program), or either. A blink sample is ``(-2000, -2000)`` flagged ``BLINK``.
    scale : (float, float)
        Pixels per tracker unit of x and y (1 for a Mobile Eye, whose gaze is in scene-image pixels).
    offset_px : (float, float)
        Added after scaling.
    counter_hz : float
        Counts per second of the ``counter`` field (the tracker's frame rate); unused without a counter.
    """

    format = "asl-serial-out"

    def __init__(self, *, fields: Sequence[str] = STANDARD_FIELDS, byte_order: str = "big",
                 blink: BlinkRule = "either", scale: Sequence[float] = (1.0, 1.0),
                 offset_px: Sequence[float] = (0.0, 0.0), counter_hz: float = 30.0) -> None:
        self.layout = AslLayout.parse(fields, byte_order)
        if blink not in BLINK_RULES:
            raise ValueError(f"blink: {blink!r} is not one of {', '.join(BLINK_RULES)}")
        if blink == "pupil-zero" and "pupil" not in self.layout.names:
            raise ValueError("blink: pupil-zero needs a pupil item in fields")
        self.blink = blink
        self.scale = (float(scale[0]), float(scale[1]))
        self.offset_px = (float(offset_px[0]), float(offset_px[1]))
        self.stats = DecodeStats()
        self.framer = AslFramer(self.layout.n_data, self.stats)
        modulus = self.layout.counter_modulus()
        self.clock = None if modulus is None else CounterClock(counter_hz, modulus, self.stats)
        self._pupil_zero = blink in ("either", "pupil-zero") and "pupil" in self.layout.names
        self._sentinel = blink in ("either", "sentinel")

    def feed(self, data: bytes) -> list[bytes]:
        return self.framer.feed(data)

    def flush(self) -> bool:
        return self.framer.flush()

    def decode(self, frame: bytes, arrival_s: float) -> Decoded | None:
        v = self.layout.values(unpack_7bit(frame, self.layout.n_data))
        fields = {"raw_x": v["x"], "raw_y": v["y"]}
        fields.update({k: v[k] for k in ("pupil", "status", "counter") if k in v})
        t_s = arrival_s
        if self.clock is not None:
            t = self.clock.time(int(v["counter"]), arrival_s, frame)
            if t is None:
                return None
            t_s = t
            hz = self.clock.measured_hz()
            if hz is not None:
                self.stats.extra["counter_hz_measured"] = round(hz, 3)
        if (self._pupil_zero and v["pupil"] == 0) or (
                self._sentinel and v["x"] == BLINK_SENTINEL_PX and v["y"] == BLINK_SENTINEL_PX):
            sample = GazeSample(t_s, BLINK_SENTINEL_PX, BLINK_SENTINEL_PX, GazeFlag.BLINK)
        else:
            x_px = v["x"] * self.scale[0] + self.offset_px[0]
            y_px = v["y"] * self.scale[1] + self.offset_px[1]
            flags = classify(x_px, y_px)
            if flags & GazeFlag.BLINK:  # (-2000, -2000) when the sentinel is not a blink: just off the image
                flags = GazeFlag.OUT_OF_RANGE
            sample = GazeSample(t_s, x_px, y_px, flags)
        self.stats.count(sample)
        return Decoded(sample, arrival_s, fields)
