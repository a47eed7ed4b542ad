"""Motor positions on the bus: the host's request (a get of P) and the pucks' 22-bit replies.

Each puck answers the position request to feedback group 3 with its motor encoder's counts as a 22-bit
two's-complement number (libbarrett ``detail/motor_puck-inl.h`` ``twentyTwoBit2``,
``src/products/motor_puck.cpp`` ``PositionParser``). Counts <-> joint angles:
:mod:`wamctl.model.transmission`.
"""

from __future__ import annotations

from collections.abc import Sequence

import can

from wamctl.backends.can.protocol.addressing import (
    FEEDBACK_POSITION,
    FEEDBACK_POSITION_TARGET,
    GROUP_WAM,
    PuckFrameError,
    data_frame,
    decode_reply_id,
    encode_bus_id,
)
from wamctl.backends.can.protocol.properties import Prop, make_get_property

__all__ = [
    "POSITION_MAX_COUNTS",
    "POSITION_MIN_COUNTS",
    "decode_position_22bit",
    "encode_position_22bit",
    "make_position_reply",
    "make_position_request",
    "parse_combined_position_reply",
    "parse_position_reply",
]

POSITION_BITS = 22
POSITION_MIN_COUNTS = -(2 ** (POSITION_BITS - 1))  # -2097152
POSITION_MAX_COUNTS = 2 ** (POSITION_BITS - 1) - 1  # 2097151
_POSITION_MASK = (1 << POSITION_BITS) - 1


def encode_position_22bit(counts: int, *, wrap: bool = False) -> bytes:
    """Encode a motor position as the three bytes of a puck's position reply.

    Parameters
    ----------
    counts : int
        Encoder counts, ``-2**21 .. 2**21 - 1``.
    wrap : bool, default False
        Wrap out-of-range counts modulo ``2**22`` like a puck's counter instead of raising.

    Returns
    -------
    bytes
        ``[bits 21..16 (top two bits 0), bits 15..8, bits 7..0]``.

    Raises
    ------
    ValueError
        If ``counts`` is out of range and ``wrap`` is False.
    """
    counts = int(counts)
    if not wrap and not POSITION_MIN_COUNTS <= counts <= POSITION_MAX_COUNTS:
        raise ValueError(f"{counts} counts do not fit in 22-bit two's complement")
    v = counts & _POSITION_MASK
    return bytes([(v >> 16) & 0x3F, (v >> 8) & 0xFF, v & 0xFF])


def decode_position_22bit(data: bytes | bytearray | Sequence[int]) -> int:
    """Decode the first three bytes of a position reply into signed counts.

    Parameters
    ----------
    data : bytes
        At least three bytes; the top two bits of the first byte are ignored (as libbarrett does).

    Returns
    -------
    int
        Counts in ``-2**21 .. 2**21 - 1``.
    """
    if len(data) < 3:
        raise ValueError(f"a 22-bit position needs 3 bytes, got {len(data)}")
    v = ((data[0] & 0x3F) << 16) | ((data[1] & 0xFF) << 8) | (data[2] & 0xFF)
    return v - (1 << POSITION_BITS) if v & (1 << (POSITION_BITS - 1)) else v


def make_position_request(target: int = GROUP_WAM) -> can.Message:
    """Build the host's position request ``[48]`` (a get of P), by default to the whole WAM (0x404).

    Parameters
    ----------
    target : int, default :data:`GROUP_WAM`
        Group or puck to ask.

    Returns
    -------
    can.Message
    """
    return make_get_property(target, Prop.P)


def make_position_reply(puck_id: int, counts: int, *, wrap: bool = False,
                        secondary_counts: int | None = None) -> can.Message:
    """Build a puck's position reply (used by the simulator).

    Parameters
    ----------
    puck_id : int
        Replying puck.
    counts : int
        Motor encoder counts.
    wrap : bool, default False
        See :func:`encode_position_22bit`.
    secondary_counts : int, optional
        A joint (secondary) encoder's counts: the reply then has six bytes, motor encoder first (pucks whose
        ROLE has the joint-encoder option, libbarrett ``CombinedPositionParser``).

    Returns
    -------
    can.Message
        Three (or six) bytes to feedback group 3: id ``0x400 | puck_id << 5 | 3``.
    """
    payload = encode_position_22bit(counts, wrap=wrap)
    if secondary_counts is not None:
        payload += encode_position_22bit(secondary_counts, wrap=wrap)
    return data_frame(encode_bus_id(puck_id, FEEDBACK_POSITION), payload)


def parse_position_reply(msg: can.Message) -> tuple[int, int]:
    """Decode a puck's position reply.

    Parameters
    ----------
    msg : can.Message
        A frame to feedback group 3 with 3 bytes (or 6: primary then secondary encoder; the secondary
        is ignored), as libbarrett's ``MotorPuck::PositionParser`` accepts.

    Returns
    -------
    tuple of (int, int)
        ``(puck_id, counts)``.

    Raises
    ------
    PuckFrameError
        If the id or length does not match.
    """
    bid = decode_reply_id(msg)
    if not (bid.is_group and bid.target == FEEDBACK_POSITION_TARGET):
        raise PuckFrameError(f"not a position reply: id {msg.arbitration_id:#05x}")
    data = bytes(msg.data)
    if len(data) not in (3, 6):
        raise PuckFrameError(f"position reply from puck {bid.sender}: expected 3 or 6 bytes, got {len(data)}")
    return bid.sender, decode_position_22bit(data)


def parse_combined_position_reply(msg: can.Message) -> tuple[int, int, int | None]:
    """Decode a position reply with its joint encoder: ``(puck_id, motor counts, joint counts or None)``; a
    3-byte reply has no joint encoder (libbarrett ``CombinedPositionParser``).

    Raises
    ------
    PuckFrameError
        As :func:`parse_position_reply`.
    """
    puck, counts = parse_position_reply(msg)
    data = bytes(msg.data)
    return puck, counts, decode_position_22bit(data[3:]) if len(data) == 6 else None

