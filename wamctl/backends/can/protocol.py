"""Barrett puck CAN protocol: identifiers, message builders/parsers and joint <-> puck conversions.

Pure functions and constants only: nothing here opens a bus, sleeps or keeps state. The backend loop and
the simulated pucks (:mod:`wamctl.backends.can.puck_sim`) are built on top of it.

Conventions
-----------
- Joints and pucks are numbered 1..7 on the bus and in user-facing text, 0..6 in arrays; WAM puck ``n``
  drives motor ``n``.
- SI units everywhere except on the wire; names carry units: ``q_rad`` (joint angle), ``m_rad`` (motor
  angle), ``counts`` (encoder counts), ``tau_Nm`` (joint torque), ``tau_m_Nm`` (motor torque),
  ``puck_units`` (puck torque command, ``IPNM`` units per N m of motor torque).
- Vectorised functions accept one vector of shape ``(7,)`` or a batch ``(..., 7)``; per-puck constants
  (``cts``, ``ipnm``) may be scalars or ``(7,)`` arrays.
- CAN identifiers are 11-bit: ``[G FFFFF TTTTT]`` = group flag ``0x400``, sender bits ``0x3e0``, target
  bits ``0x01f``; the host is node 0.
- A malformed frame received from the bus raises :class:`PuckFrameError` (a
  :class:`~wamctl.errors.BackendError`: the device misbehaved); bad arguments from calling code raise
  ``ValueError``.

Sources: libbarrett (github.com/BarrettTechnology/libbarrett) ``include/barrett/products/puck.h``,
``puck_group.h``, ``motor_puck.h``, ``detail/puck-inl.h``, ``detail/motor_puck-inl.h``,
``src/products/motor_puck.cpp``, ``src/products/puck.cpp``, ``src/products/property_list.cpp`` and
``config/wam7w.conf``; summarised in the project's WAM parameter notes (CAN bus, motors and transmission).
"""

from __future__ import annotations

import enum
import logging
import math
from collections.abc import Sequence
from typing import NamedTuple

import can
import numpy as np
from numpy.typing import ArrayLike

from wamctl.errors import BackendError
from wamctl.model import params as _params

logger = logging.getLogger(__name__)

__all__ = [
    "BusId",
    "CTS_DEFAULT",
    "DEFAULT_PIDX",
    "FEEDBACK_OTHER",
    "FEEDBACK_POSITION",
    "FEEDBACK_SECONDARY_POSITION",
    "GROUP_FLAG",
    "GROUP_HAND",
    "GROUP_LOWER_WAM",
    "GROUP_UPPER_WAM",
    "GROUP_WAM",
    "GROUP_WHOLE_BUS",
    "HOST_ID",
    "IPNM_DEFAULT",
    "J2MP",
    "M2JP",
    "MAX_PUCK_TORQUE",
    "MIN_FIRMWARE_VERSION",
    "Mode",
    "N_JOINTS",
    "POSITION_MAX_COUNTS",
    "POSITION_MIN_COUNTS",
    "Prop",
    "PropertyReply",
    "PuckFrameError",
    "Status",
    "TORQUE_GROUPS",
    "WAM_PUCK_IDS",
    "check_firmware_version",
    "counts_to_joint_rad",
    "counts_to_motor_rad",
    "decode_bus_id",
    "decode_position_22bit",
    "encode_bus_id",
    "encode_position_22bit",
    "joint_rad_to_counts",
    "joint_rad_to_motor_rad",
    "joint_torque_to_motor_Nm",
    "joint_torque_to_puck_units",
    "make_get_property",
    "make_position_reply",
    "make_position_request",
    "make_property_reply",
    "make_set_property",
    "make_torque_frames",
    "motor_Nm_to_puck_units",
    "motor_rad_to_counts",
    "motor_rad_to_joint_rad",
    "motor_torque_to_joint_Nm",
    "pack_torques",
    "parse_host_property_message",
    "parse_position_reply",
    "parse_property_reply",
    "puck_units_to_joint_torque_Nm",
    "puck_units_to_motor_Nm",
    "saturate_puck_units",
    "torque_slot_of_puck",
    "unpack_torques",
]


class PuckFrameError(BackendError):
    """A frame received from the bus does not follow the puck protocol (wrong id, length or header)."""


# --------------------------------------------------------------------------------------------------
# Bus identifiers (libbarrett include/barrett/products/puck.h, puck_group.h)
# --------------------------------------------------------------------------------------------------

N_JOINTS = 7
HOST_ID = 0  # node id of the control PC (puck.h HOST_ID)
NODE_ID_WIDTH = 5  # puck.h NODE_ID_WIDTH
NODE_ID_MASK = 0x1F  # puck.h NODE_ID_MASK
GROUP_FLAG = 0x400  # puck.h GROUP_MASK
FROM_MASK = 0x3E0  # puck.h FROM_MASK (sender bits)
TO_MASK = 0x41F  # puck.h TO_MASK (target bits, group flag included)
SET_MASK = 0x80  # puck.h SET_MASK: first data byte of a SET (and of a property reply)
PROPERTY_MASK = 0x7F  # puck.h PROPERTY_MASK
MAX_CAN_ID = 0x7FF  # 11-bit identifiers

# Broadcast groups the host sends to (puck_group.h BroadcastGroup).
GROUP_WHOLE_BUS = GROUP_FLAG | 0  # every puck but the safety module
GROUP_LOWER_WAM = GROUP_FLAG | 1  # packed-torque group, pucks 1-4
GROUP_UPPER_WAM = GROUP_FLAG | 2  # packed-torque group, pucks 5-7
GROUP_WAM = GROUP_FLAG | 4  # the whole WAM, pucks 1-7
GROUP_HAND = GROUP_FLAG | 5  # BarrettHand, pucks 11-14
# Feedback groups pucks reply to (puck_group.h FeedbackGroup).
FEEDBACK_POSITION = GROUP_FLAG | 3  # replies to a get of P (motor encoder position, 22-bit)
FEEDBACK_OTHER = GROUP_FLAG | 6  # replies to a get of any other property
FEEDBACK_SECONDARY_POSITION = GROUP_FLAG | 7  # joint / break-away encoder (not used by wamctl)

WAM_PUCK_IDS: tuple[int, ...] = (1, 2, 3, 4, 5, 6, 7)  # WAM pucks; F/T sensor 8, safety 10, hand 11-14
SAFETY_PUCK_ID = 10
FORCE_TORQUE_PUCK_ID = 8
HAND_PUCK_IDS: tuple[int, ...] = (11, 12, 13, 14)

# Packed-torque groups and their members (libbarrett low_level_wam-inl.h: four pucks per group, in order).
PUCKS_PER_TORQUE_GROUP = 4  # motor_puck.h PUCKS_PER_TORQUE_GROUP
TORQUE_GROUPS: dict[int, tuple[int, ...]] = {
    GROUP_LOWER_WAM: (1, 2, 3, 4),
    GROUP_UPPER_WAM: (5, 6, 7),
}
# PIDX is each puck's 1-based slot in its packed-torque frame. The default WAM configuration numbers the
# pucks of each group in order (libbarrett packs the i-th puck of a group into slot i and never reads PIDX).
DEFAULT_PIDX: dict[int, int] = {1: 1, 2: 2, 3: 3, 4: 4, 5: 1, 6: 2, 7: 3}


class BusId(NamedTuple):
    """A decoded 11-bit CAN identifier.

    Attributes
    ----------
    sender : int
        Node id of the sender (0 = host).
    target : int
        Node id, or group number when ``is_group`` (the low five bits).
    is_group : bool
        Whether the group flag 0x400 is set.
    """

    sender: int
    target: int
    is_group: bool


def encode_bus_id(sender: int, target: int) -> int:
    """Compose an 11-bit CAN id from a sender node and a target node or group.

    Parameters
    ----------
    sender : int
        Sender node id, 0..31 (0 = host).
    target : int
        Target node id 0..31, or a group id with the flag set (``0x400 | g``, e.g. :data:`GROUP_WAM`).

    Returns
    -------
    int
        ``(target & 0x41f) | (sender << 5)``.

    Raises
    ------
    ValueError
        If the sender or target is out of range.
    """
    if not 0 <= sender <= NODE_ID_MASK:
        raise ValueError(f"sender node id must be 0..31, got {sender}")
    if target & ~TO_MASK or target < 0:
        raise ValueError(f"target must be a node id 0..31 or 0x400|group, got {target:#x}")
    return (target & TO_MASK) | ((sender & NODE_ID_MASK) << NODE_ID_WIDTH)


def decode_bus_id(arbitration_id: int) -> BusId:
    """Split an 11-bit CAN id into sender, target and group flag.

    Parameters
    ----------
    arbitration_id : int
        The frame's 11-bit identifier.

    Returns
    -------
    BusId
        ``(sender, target, is_group)``; ``target`` is the low five bits (node id or group number).

    Raises
    ------
    ValueError
        If the id does not fit in 11 bits.
    """
    if not 0 <= arbitration_id <= MAX_CAN_ID:
        raise ValueError(f"CAN id must be 11-bit (0..0x7ff), got {arbitration_id:#x}")
    return BusId(
        sender=(arbitration_id & FROM_MASK) >> NODE_ID_WIDTH,
        target=arbitration_id & NODE_ID_MASK,
        is_group=bool(arbitration_id & GROUP_FLAG),
    )


# --------------------------------------------------------------------------------------------------
# Properties (libbarrett src/products/property_list.cpp, motor-puck tables for firmware >= 68)
# --------------------------------------------------------------------------------------------------


class Prop(enum.IntEnum):
    """Property ids of a WAM motor puck.

    VERS, ROLE, SN, ID, ERROR, STAT, MODE, T and P have these ids from firmware 61 on (VERS..STAT also
    in the bootloader/monitor). CTS, IPNM and PIDX moved: 65/83/67 (firmware 61-64), 66/83/68 (65-67),
    68/86/70 from firmware 68 on; see :func:`check_firmware_version`.
    """

    VERS = 0  # firmware version
    ROLE = 1  # puck role and options (low 5 bits: 0 = motor "tater")
    SN = 2  # serial number
    ID = 3  # node id
    ERROR = 4
    STAT = 5  # 0 reset (monitor), 2 ready; set STAT=2 to wake a puck
    MODE = 8  # motor mode, see :class:`Mode`
    T = 42  # torque command (puck units); packed-torque frames start with 0x80|42 = 0xAA
    P = 48  # motor encoder position (counts, 22-bit replies to feedback group 3)
    MECH = 66  # absolute mechanical angle (counts, firmware >= 118 with absolute encoders)
    CTS = 68  # encoder counts per motor revolution
    PIDX = 70  # 1-based slot of this puck in its packed-torque frame
    IPNM = 86  # puck torque units per N m of motor torque


# Property ids above are valid from this motor-puck firmware version on (property_list.cpp PL_Motor).
MIN_FIRMWARE_VERSION = 68


class Mode(enum.IntEnum):
    """Values of the MODE property (libbarrett motor_puck.h ``MotorMode``)."""

    IDLE = 0
    DUTY = 1
    TORQUE = 2
    PID = 3
    VELOCITY = 4
    TRAPEZOIDAL = 5


class Status(enum.IntEnum):
    """Values of the STAT property (libbarrett puck.h, from the puck2 firmware PARSE.H)."""

    RESET = 0  # in the bootloader ("monitor"); must be woken with STAT=READY
    ERR = 1
    READY = 2


def check_firmware_version(puck_id: int, vers: int) -> None:
    """Refuse a motor puck whose firmware uses other ids for CTS, IPNM and PIDX.

    Parameters
    ----------
    puck_id : int
        Node id, for the message.
    vers : int
        Value of the puck's VERS property.

    Raises
    ------
    BackendError
        If ``vers`` is below :data:`MIN_FIRMWARE_VERSION`.
    """
    if vers < MIN_FIRMWARE_VERSION:
        raise BackendError(
            f"puck {puck_id}: firmware VERS={vers} is older than {MIN_FIRMWARE_VERSION}; its CTS/IPNM/PIDX "
            "property ids differ and are not supported"
        )


class PropertyReply(NamedTuple):
    """A decoded reply to a property get.

    Attributes
    ----------
    puck_id : int
        Node id of the replying puck.
    prop : int
        Property id.
    value : int
        Signed value.
    """

    puck_id: int
    prop: int
    value: int


def _message(arbitration_id: int, data: bytes | bytearray | Sequence[int]) -> can.Message:
    return can.Message(arbitration_id=arbitration_id, data=bytes(data), is_extended_id=False)


def _check_prop(prop: int) -> int:
    prop = int(prop)
    if not 0 <= prop <= PROPERTY_MASK:
        raise ValueError(f"property id must be 0..127, got {prop}")
    return prop


def _int32_le(value: int) -> bytes:
    value = int(value)
    if not -(2**31) <= value < 2**32:
        raise ValueError(f"property value {value} does not fit in 32 bits")
    return (value & 0xFFFFFFFF).to_bytes(4, "little")


def make_get_property(target: int, prop: int) -> can.Message:
    """Build a property get from the host: one data byte, the property id.

    Parameters
    ----------
    target : int
        Puck node id or group id (``0x400 | g``).
    prop : int
        Property id (:class:`Prop`).

    Returns
    -------
    can.Message
        Addressed ``host -> target``. Each addressed puck answers with :func:`make_property_reply`
        (or :func:`make_position_reply` for ``Prop.P``).
    """
    return _message(encode_bus_id(HOST_ID, target), [_check_prop(prop)])


def make_set_property(target: int, prop: int, value: int) -> can.Message:
    """Build a property set from the host: ``[prop | 0x80, 0, value int32 LE]``.

    Parameters
    ----------
    target : int
        Puck node id or group id (``0x400 | g``).
    prop : int
        Property id (:class:`Prop`).
    value : int
        Value; must fit in 32 bits (signed or unsigned).

    Returns
    -------
    can.Message
        A six-byte frame addressed ``host -> target``.
    """
    payload = bytes([_check_prop(prop) | SET_MASK, 0]) + _int32_le(value)
    return _message(encode_bus_id(HOST_ID, target), payload)


def make_property_reply(puck_id: int, prop: int, value: int) -> can.Message:
    """Build a puck's reply to a property get (what a puck sends; used by the simulator).

    Parameters
    ----------
    puck_id : int
        Replying puck's node id.
    prop : int
        Property id.
    value : int
        Value, sent as int32 LE.

    Returns
    -------
    can.Message
        ``[0x80 | prop, 0, value LE]`` to feedback group 6 (id ``0x400 | puck_id << 5 | 6``).
    """
    payload = bytes([_check_prop(prop) | SET_MASK, 0]) + _int32_le(value)
    return _message(encode_bus_id(puck_id, FEEDBACK_OTHER), payload)


def parse_property_reply(msg: can.Message, expected_prop: int | None = None) -> PropertyReply:
    """Decode a puck's reply to a property get.

    Parameters
    ----------
    msg : can.Message
        A frame to feedback group 6. Two value bytes (16-bit) or four (32-bit) are accepted, as in
        libbarrett's ``Puck::StandardParser``; the value is sign-extended.
    expected_prop : int, optional
        If given, the reply must carry this property id.

    Returns
    -------
    PropertyReply

    Raises
    ------
    PuckFrameError
        If the id, length, header or property does not match.
    """
    bid = _decode_rx_id(msg)
    if not (bid.is_group and bid.target == (FEEDBACK_OTHER & NODE_ID_MASK)):
        raise PuckFrameError(f"not a property reply: id {msg.arbitration_id:#05x}")
    data = bytes(msg.data)
    if len(data) not in (4, 6):
        raise PuckFrameError(f"property reply from puck {bid.sender}: expected 4 or 6 bytes, got {len(data)}")
    if not data[0] & SET_MASK:
        raise PuckFrameError(
            f"property reply from puck {bid.sender}: header {data[0]:#04x} lacks the 0x80 flag"
        )
    if data[1] != 0:
        raise PuckFrameError(f"property reply from puck {bid.sender}: second byte is {data[1]}, expected 0")
    prop = data[0] & PROPERTY_MASK
    if expected_prop is not None and prop != expected_prop:
        raise PuckFrameError(
            f"property reply from puck {bid.sender}: property {prop}, expected {expected_prop}"
        )
    return PropertyReply(bid.sender, prop, int.from_bytes(data[2:], "little", signed=True))


def parse_host_property_message(data: bytes | bytearray) -> tuple[bool, int, int | None]:
    """Decode a get or set sent by the host (what a puck parses; used by the simulator).

    Parameters
    ----------
    data : bytes
        Frame payload: ``[prop]`` (get) or ``[prop | 0x80, 0, value LE]`` with 2 or 4 value bytes (set).

    Returns
    -------
    tuple of (bool, int, int or None)
        ``(is_set, prop, value)``; ``value`` is None for a get.

    Raises
    ------
    PuckFrameError
        If the payload is neither a get nor a set.
    """
    data = bytes(data)
    if not data:
        raise PuckFrameError("empty property message")
    prop = data[0] & PROPERTY_MASK
    if not data[0] & SET_MASK:
        if len(data) != 1:
            raise PuckFrameError(f"property get of {prop}: expected 1 byte, got {len(data)}")
        return False, prop, None
    if len(data) not in (4, 6) or data[1] != 0:
        raise PuckFrameError(f"property set of {prop}: malformed payload {data.hex()}")
    return True, prop, int.from_bytes(data[2:], "little", signed=True)


def _decode_rx_id(msg: can.Message) -> BusId:
    if msg.is_extended_id or msg.is_error_frame or msg.is_remote_frame:
        raise PuckFrameError(f"not a puck data frame: id {msg.arbitration_id:#x}")
    try:
        return decode_bus_id(msg.arbitration_id)
    except ValueError as exc:
        raise PuckFrameError(str(exc)) from exc


# --------------------------------------------------------------------------------------------------
# Positions: 22-bit two's-complement counts (libbarrett motor_puck-inl.h twentyTwoBit2,
# src/products/motor_puck.cpp PositionParser)
# --------------------------------------------------------------------------------------------------

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


def make_position_reply(puck_id: int, counts: int, *, wrap: bool = False) -> can.Message:
    """Build a puck's position reply (used by the simulator).

    Parameters
    ----------
    puck_id : int
        Replying puck.
    counts : int
        Motor encoder counts.
    wrap : bool, default False
        See :func:`encode_position_22bit`.

    Returns
    -------
    can.Message
        Three bytes to feedback group 3: id ``0x400 | puck_id << 5 | 3``.
    """
    return _message(encode_bus_id(puck_id, FEEDBACK_POSITION), encode_position_22bit(counts, wrap=wrap))


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
    bid = _decode_rx_id(msg)
    if not (bid.is_group and bid.target == (FEEDBACK_POSITION & NODE_ID_MASK)):
        raise PuckFrameError(f"not a position reply: id {msg.arbitration_id:#05x}")
    data = bytes(msg.data)
    if len(data) not in (3, 6):
        raise PuckFrameError(f"position reply from puck {bid.sender}: expected 3 or 6 bytes, got {len(data)}")
    return bid.sender, decode_position_22bit(data)


# --------------------------------------------------------------------------------------------------
# Packed torques (libbarrett src/products/motor_puck.cpp sendPackedTorques, motor_puck.h)
# --------------------------------------------------------------------------------------------------

MAX_PUCK_TORQUE = 8191  # motor_puck.h MAX_PUCK_TORQUE: saturation of a 14-bit torque command
TORQUE_BITS = 14
_TORQUE_MASK = (1 << TORQUE_BITS) - 1
PACKED_TORQUE_HEADER = SET_MASK | Prop.T  # 0xAA


def saturate_puck_units(puck_units: ArrayLike) -> np.ndarray:
    """Round to the nearest integer and saturate at +-:data:`MAX_PUCK_TORQUE`.

    libbarrett floors instead (``floor(saturate(x, 8191))``); rounding is unbiased and differs by at most
    one unit.

    Parameters
    ----------
    puck_units : array_like
        Torque commands in puck units.

    Returns
    -------
    numpy.ndarray
        ``int64`` array of the same shape.
    """
    x = np.asarray(puck_units, dtype=float)
    if not np.all(np.isfinite(x)):
        raise ValueError("puck torques must be finite")
    return np.clip(np.rint(x), -MAX_PUCK_TORQUE, MAX_PUCK_TORQUE).astype(np.int64)


def pack_torques(puck_units: ArrayLike, pidx: Sequence[int] | None = None) -> bytes:
    """Pack up to four torque commands into the 8-byte payload of a packed-torque frame.

    Layout (bytes 0..7, most significant bit first)::

        10101010 AAAAAAAA AAAAAABB BBBBBBBB BBBBCCCC CCCCCCCC CCDDDDDD DDDDDDDD

    byte 0 is ``0x80 | T`` = 0xAA; A..D are slots 1..4, each a 14-bit two's-complement value; slots
    without a puck are 0.

    Parameters
    ----------
    puck_units : sequence of float
        One to four commands in puck units; rounded and saturated at +-8191.
    pidx : sequence of int, optional
        Each command's slot, the PIDX (1..4, distinct) of the puck it is for. Default ``1, 2, ...``.

    Returns
    -------
    bytes
        Eight bytes.

    Raises
    ------
    ValueError
        If there are more than four commands or the slots are invalid.
    """
    values = saturate_puck_units(puck_units).reshape(-1)
    n = values.size
    if not 1 <= n <= PUCKS_PER_TORQUE_GROUP:
        raise ValueError(f"a packed-torque frame carries 1..4 torques, got {n}")
    slots = list(range(1, n + 1)) if pidx is None else [int(p) for p in pidx]
    if len(slots) != n or len(set(slots)) != n or not all(1 <= p <= PUCKS_PER_TORQUE_GROUP for p in slots):
        raise ValueError(f"PIDX must be {n} distinct values in 1..4, got {list(pidx or [])}")
    bits = 0
    for value, slot in zip(values.tolist(), slots):
        bits |= (value & _TORQUE_MASK) << (TORQUE_BITS * (PUCKS_PER_TORQUE_GROUP - slot))
    return bytes([PACKED_TORQUE_HEADER]) + bits.to_bytes(7, "big")


def unpack_torques(data: bytes | bytearray | Sequence[int]) -> np.ndarray:
    """Decode the payload of a packed-torque frame (what a puck does; used by the simulator).

    Parameters
    ----------
    data : bytes
        ``0xAA`` then packed 14-bit values. Eight bytes carry four slots; libbarrett sends ``1 + 2 n``
        bytes when it packs ``n < 4`` torques, so shorter frames yield the slots they fully contain.

    Returns
    -------
    numpy.ndarray
        ``int64`` values of slots 1..k (index = PIDX - 1), k = ``min(4, (len - 1) * 8 // 14)``.

    Raises
    ------
    PuckFrameError
        If the header is not 0xAA or the frame holds no complete slot.
    """
    data = bytes(data)
    if len(data) < 3 or len(data) > 8:
        raise PuckFrameError(f"packed-torque frame: expected 3..8 bytes, got {len(data)}")
    if data[0] != PACKED_TORQUE_HEADER:
        raise PuckFrameError(
            f"packed-torque frame: header {data[0]:#04x}, expected {PACKED_TORQUE_HEADER:#04x}"
        )
    n_slots = min(PUCKS_PER_TORQUE_GROUP, (len(data) - 1) * 8 // TORQUE_BITS)
    bits = int.from_bytes(data[1:].ljust(7, b"\0"), "big")
    out = np.empty(n_slots, dtype=np.int64)
    for i in range(n_slots):
        v = (bits >> (TORQUE_BITS * (PUCKS_PER_TORQUE_GROUP - 1 - i))) & _TORQUE_MASK
        out[i] = v - (1 << TORQUE_BITS) if v & (1 << (TORQUE_BITS - 1)) else v
    return out


def torque_slot_of_puck(pidx: dict[int, int] | None = None) -> dict[int, tuple[int, int]]:
    """Map each WAM puck to its packed-torque group and slot, checking the PIDX values read at start-up.

    Parameters
    ----------
    pidx : dict of int to int, optional
        PIDX per puck id (1..7). Default :data:`DEFAULT_PIDX`.

    Returns
    -------
    dict of int to (int, int)
        ``puck_id -> (group_id, pidx)``.

    Raises
    ------
    BackendError
        If a puck's PIDX is missing, out of 1..4, or shared with another puck of its group.
    """
    pidx = dict(DEFAULT_PIDX if pidx is None else pidx)
    out: dict[int, tuple[int, int]] = {}
    for group, members in TORQUE_GROUPS.items():
        seen: dict[int, int] = {}
        for puck in members:
            if puck not in pidx:
                raise BackendError(f"puck {puck}: PIDX unknown")
            p = int(pidx[puck])
            if not 1 <= p <= PUCKS_PER_TORQUE_GROUP:
                raise BackendError(f"puck {puck}: PIDX={p} outside 1..4")
            if p in seen:
                raise BackendError(
                    f"pucks {seen[p]} and {puck} both have PIDX={p} in torque group {group:#05x}"
                )
            seen[p] = puck
            out[puck] = (group, p)
    return out


def make_torque_frames(puck_units: ArrayLike, pidx: dict[int, int] | None = None) -> list[can.Message]:
    """Build the two packed-torque frames for the seven WAM pucks.

    Parameters
    ----------
    puck_units : array_like, shape (7,)
        Commands for pucks 1..7 in puck units (rounded, saturated at +-8191).
    pidx : dict of int to int, optional
        PIDX per puck id; default :data:`DEFAULT_PIDX`.

    Returns
    -------
    list of can.Message
        8-byte frames to 0x401 (pucks 1-4) and 0x402 (pucks 5-7), in that order.
    """
    values = np.asarray(puck_units, dtype=float).reshape(-1)
    if values.size != N_JOINTS:
        raise ValueError(f"expected 7 puck torques, got {values.size}")
    slots = torque_slot_of_puck(pidx)
    frames = []
    for group, members in TORQUE_GROUPS.items():
        payload = pack_torques([values[p - 1] for p in members], [slots[p][1] for p in members])
        frames.append(_message(encode_bus_id(HOST_ID, group), payload))
    return frames


# --------------------------------------------------------------------------------------------------
# Joint <-> motor <-> puck conversions (libbarrett config/wam7w.conf j2mp; low_level_wam-inl.h;
# motor_puck.cpp update(): rad per count = 2 pi / CTS)
# --------------------------------------------------------------------------------------------------

# Motor angle = J2MP @ joint angle: the one copy lives in wamctl.model.params (libbarrett config/wam7w.conf,
# 9.7 for the J5/J6 differential). Here a read-only view of it, so protocol code cannot alter the model's.
J2MP = _params.J2MP.view()
J2MP.setflags(write=False)
M2JP = np.linalg.inv(J2MP)  # joint angle = M2JP @ motor angle; motor torque = M2JP.T @ joint torque
M2JP.setflags(write=False)

CTS_DEFAULT = 4096  # encoder counts per motor revolution, older arms (40960 on magnetic encoders); read CTS
IPNM_DEFAULT = 2700  # puck.h DEFAULT_IPNM; read IPNM from each puck at start-up


def _inverse(j2mp: np.ndarray) -> np.ndarray:
    if j2mp is J2MP or j2mp is _params.J2MP:
        return M2JP
    j2mp = np.asarray(j2mp, dtype=float)
    if j2mp.shape != (N_JOINTS, N_JOINTS):
        raise ValueError(f"j2mp must be 7x7, got {j2mp.shape}")
    return np.linalg.inv(j2mp)


def _vec7(x: ArrayLike, name: str) -> np.ndarray:
    a = np.asarray(x, dtype=float)
    if a.shape[-1:] != (N_JOINTS,):
        raise ValueError(f"{name} must have shape (..., 7), got {a.shape}")
    return a


def joint_rad_to_motor_rad(q_rad: ArrayLike, j2mp: np.ndarray = J2MP) -> np.ndarray:
    """Motor angles from joint angles: ``m = j2mp @ q``.

    Parameters
    ----------
    q_rad : array_like, shape (..., 7)
        Joint angles (rad).
    j2mp : numpy.ndarray, shape (7, 7), default :data:`J2MP`

    Returns
    -------
    numpy.ndarray, shape (..., 7)
        Motor angles (rad).
    """
    return _vec7(q_rad, "q_rad") @ np.asarray(j2mp, dtype=float).T


def motor_rad_to_joint_rad(m_rad: ArrayLike, j2mp: np.ndarray = J2MP) -> np.ndarray:
    """Joint angles from motor angles: ``q = j2mp^-1 @ m``.

    Parameters
    ----------
    m_rad : array_like, shape (..., 7)
        Motor angles (rad).
    j2mp : numpy.ndarray, shape (7, 7), default :data:`J2MP`

    Returns
    -------
    numpy.ndarray, shape (..., 7)
        Joint angles (rad).
    """
    return _vec7(m_rad, "m_rad") @ _inverse(j2mp).T


def motor_rad_to_counts(m_rad: ArrayLike, cts: ArrayLike = CTS_DEFAULT) -> np.ndarray:
    """Encoder counts from motor angles: ``round(m * CTS / (2 pi))``.

    Rounded to the nearest count (libbarrett floors); the error is at most half a count.

    Parameters
    ----------
    m_rad : array_like
        Motor angles (rad).
    cts : float or array_like, default 4096
        Counts per motor revolution, per puck.

    Returns
    -------
    numpy.ndarray
        ``int64`` counts.
    """
    counts_per_rad = np.asarray(cts, dtype=float) / (2.0 * math.pi)
    return np.rint(np.asarray(m_rad, dtype=float) * counts_per_rad).astype(np.int64)


def counts_to_motor_rad(counts: ArrayLike, cts: ArrayLike = CTS_DEFAULT) -> np.ndarray:
    """Motor angles from encoder counts: ``counts * 2 pi / CTS``.

    Parameters
    ----------
    counts : array_like
        Encoder counts.
    cts : float or array_like, default 4096
        Counts per motor revolution, per puck.

    Returns
    -------
    numpy.ndarray
        Motor angles (rad).
    """
    return np.asarray(counts, dtype=float) * (2.0 * math.pi / np.asarray(cts, dtype=float))


def joint_rad_to_counts(
    q_rad: ArrayLike, cts: ArrayLike = CTS_DEFAULT, j2mp: np.ndarray = J2MP
) -> np.ndarray:
    """Encoder counts of the seven motors for joint angles.

    Parameters
    ----------
    q_rad : array_like, shape (..., 7)
        Joint angles (rad).
    cts : float or array_like, default 4096
        Counts per motor revolution, per puck.
    j2mp : numpy.ndarray, default :data:`J2MP`

    Returns
    -------
    numpy.ndarray, shape (..., 7)
        ``int64`` counts.
    """
    return motor_rad_to_counts(joint_rad_to_motor_rad(q_rad, j2mp), cts)


def counts_to_joint_rad(
    counts: ArrayLike, cts: ArrayLike = CTS_DEFAULT, j2mp: np.ndarray = J2MP
) -> np.ndarray:
    """Joint angles from the seven motors' encoder counts.

    Parameters
    ----------
    counts : array_like, shape (..., 7)
        Encoder counts of pucks 1..7.
    cts : float or array_like, default 4096
        Counts per motor revolution, per puck.
    j2mp : numpy.ndarray, default :data:`J2MP`

    Returns
    -------
    numpy.ndarray, shape (..., 7)
        Joint angles (rad).
    """
    return motor_rad_to_joint_rad(counts_to_motor_rad(_vec7(counts, "counts"), cts), j2mp)


def joint_torque_to_motor_Nm(tau_Nm: ArrayLike, j2mp: np.ndarray = J2MP) -> np.ndarray:
    """Motor torques from joint torques: ``tau_m = j2mp^-T @ tau`` (power-conserving transmission).

    Parameters
    ----------
    tau_Nm : array_like, shape (..., 7)
        Joint torques (N m).
    j2mp : numpy.ndarray, default :data:`J2MP`

    Returns
    -------
    numpy.ndarray, shape (..., 7)
        Motor torques (N m).
    """
    # row-vector form of j2mp^-T @ tau
    return _vec7(tau_Nm, "tau_Nm") @ _inverse(j2mp)


def motor_torque_to_joint_Nm(tau_m_Nm: ArrayLike, j2mp: np.ndarray = J2MP) -> np.ndarray:
    """Joint torques from motor torques: ``tau = j2mp^T @ tau_m``.

    Parameters
    ----------
    tau_m_Nm : array_like, shape (..., 7)
        Motor torques (N m).
    j2mp : numpy.ndarray, default :data:`J2MP`

    Returns
    -------
    numpy.ndarray, shape (..., 7)
        Joint torques (N m).
    """
    return _vec7(tau_m_Nm, "tau_m_Nm") @ np.asarray(j2mp, dtype=float)


def motor_Nm_to_puck_units(tau_m_Nm: ArrayLike, ipnm: ArrayLike = IPNM_DEFAULT) -> np.ndarray:
    """Puck torque commands from motor torques: ``round(IPNM * tau_m)``, saturated at +-8191.

    Parameters
    ----------
    tau_m_Nm : array_like
        Motor torques (N m).
    ipnm : float or array_like, default 2700
        Puck units per N m, per puck.

    Returns
    -------
    numpy.ndarray
        ``int64`` puck units.
    """
    return saturate_puck_units(np.asarray(tau_m_Nm, dtype=float) * np.asarray(ipnm, dtype=float))


def puck_units_to_motor_Nm(puck_units: ArrayLike, ipnm: ArrayLike = IPNM_DEFAULT) -> np.ndarray:
    """Motor torques from puck torque commands: ``units / IPNM``.

    Parameters
    ----------
    puck_units : array_like
        Puck torque commands.
    ipnm : float or array_like, default 2700
        Puck units per N m, per puck.

    Returns
    -------
    numpy.ndarray
        Motor torques (N m).
    """
    return np.asarray(puck_units, dtype=float) / np.asarray(ipnm, dtype=float)


def joint_torque_to_puck_units(
    tau_Nm: ArrayLike, ipnm: ArrayLike = IPNM_DEFAULT, j2mp: np.ndarray = J2MP
) -> np.ndarray:
    """Puck torque commands for joint torques (``round(IPNM * j2mp^-T @ tau)``, saturated at +-8191).

    Parameters
    ----------
    tau_Nm : array_like, shape (..., 7)
        Joint torques (N m).
    ipnm : float or array_like, default 2700
        Puck units per N m, per puck.
    j2mp : numpy.ndarray, default :data:`J2MP`

    Returns
    -------
    numpy.ndarray, shape (..., 7)
        ``int64`` puck units for pucks 1..7. Saturated entries equal +-:data:`MAX_PUCK_TORQUE`.
    """
    return motor_Nm_to_puck_units(joint_torque_to_motor_Nm(tau_Nm, j2mp), ipnm)


def puck_units_to_joint_torque_Nm(
    puck_units: ArrayLike, ipnm: ArrayLike = IPNM_DEFAULT, j2mp: np.ndarray = J2MP
) -> np.ndarray:
    """Joint torques produced by puck torque commands (``j2mp^T @ (units / IPNM)``).

    Parameters
    ----------
    puck_units : array_like, shape (..., 7)
        Commands of pucks 1..7.
    ipnm : float or array_like, default 2700
        Puck units per N m, per puck.
    j2mp : numpy.ndarray, default :data:`J2MP`

    Returns
    -------
    numpy.ndarray, shape (..., 7)
        Joint torques (N m).
    """
    return motor_torque_to_joint_Nm(puck_units_to_motor_Nm(_vec7(puck_units, "puck_units"), ipnm), j2mp)
