"""Puck properties: their ids, the MODE and STAT values, the firmware check, and property messages.

A property is read with a get (one byte, the id) and answered by a reply to feedback group 6; it is written
with a set (``[id | 0x80, 0, value int32 LE]``). Sources: libbarrett ``src/products/property_list.cpp``
(motor-puck tables for firmware >= 65), ``include/barrett/products/puck.h``, ``motor_puck.h`` and
``detail/puck-inl.h``.
"""

from __future__ import annotations

import enum
from typing import NamedTuple

import can

from wamctl.backends.can.protocol.addressing import (
    FEEDBACK_OTHER,
    FEEDBACK_OTHER_TARGET,
    HOST_ID,
    PuckFrameError,
    data_frame,
    decode_reply_id,
    encode_bus_id,
)
from wamctl.errors import ConfigurationRefused
from wamctl.model import params as P

__all__ = [
    "CTS_DEFAULT",
    "MIN_FIRMWARE_VERSION",
    "MONITOR_PROPS",
    "OLD_MOTOR_IDS",
    "Mode",
    "PROPERTY_MASK",
    "Prop",
    "PropertyReply",
    "SET_MASK",
    "Status",
    "check_firmware_version",
    "make_get_property",
    "make_property_reply",
    "make_set_property",
    "parse_host_property_message",
    "parse_property_reply",
]

SET_MASK = 0x80  # puck.h SET_MASK: first data byte of a SET (and of a property reply)
PROPERTY_MASK = 0x7F  # puck.h PROPERTY_MASK

# --------------------------------------------------------------------------------------------------
# Properties (libbarrett src/products/property_list.cpp, motor-puck tables for firmware >= 65)
# --------------------------------------------------------------------------------------------------


class Prop(enum.IntEnum):
    """Property ids of a WAM motor puck with firmware VERS >= 65 (libbarrett ``property_list.cpp``, motor tables
    from VERS 65 on; the ids below do not move again up to the newest table, VERS >= 175).

    VERS..STAT also exist in the monitor (the bootloader a puck starts in), where 8 is LOCK, not MODE. Older
    firmware uses other ids for CTS, IPNM, PIDX and POLES (:data:`OLD_MOTOR_IDS`); it is refused by
    :func:`check_firmware_version`.
    """

    VERS = 0  # firmware version
    ROLE = 1  # puck role and options (low 5 bits: 0 = motor "tater"; see ROLE_* below)
    SN = 2  # serial number
    ID = 3  # node id
    ERROR = 4
    STAT = 5  # 0 reset (monitor), 2 ready; set STAT=2 to wake a puck
    MODE = 8  # motor mode, see :class:`Mode` (set by the safety module, never by wamctl: only IDLE)
    GRPA = 26  # the three broadcast groups a puck listens to (EEPROM; libbarrett never writes them)
    GRPB = 27
    GRPC = 28
    SAVE = 30  # SAVE / LOAD / DEF: write a property to EEPROM / reload it / load its factory default
    LOAD = 31
    DEF = 32
    T = 42  # torque command (puck units); packed-torque frames start with 0x80|42 = 0xAA
    P = 48  # motor encoder position (counts, 22-bit replies to feedback group 3); a set defines the position
    MECH = 66  # absolute mechanical angle (counts, firmware >= 118 with absolute encoders)
    CTS = 68  # encoder counts per motor revolution
    PIDX = 70  # 1-based slot of this puck in its packed-torque frame
    IPNM = 86  # puck torque units per N m of motor torque
    POLES = 90  # motor poles: 12 (pucks 1-4), 8 (wrist pucks 5-6), 6 (wrist puck 7) or 8 (gimbals puck 7)


# Property ids above are valid from this motor-puck firmware version on (property_list.cpp PL_Motor).
MIN_FIRMWARE_VERSION = 65
# What older motor firmware calls CTS, IPNM, PIDX and POLES (libbarrett property_list.cpp): the reason it is
# refused. Below 61, every id differs (motor pucks and the safety module shared one list).
OLD_MOTOR_IDS: dict[tuple[int, int], dict[str, int]] = {
    (61, 63): {"CTS": 65, "IPNM": 83, "PIDX": 67, "POLES": 87},
    (64, 64): {"CTS": 66, "IPNM": 83, "PIDX": 68, "POLES": 87},
}

# ROLE (libbarrett puck.h): the puck type in the low five bits, options above.
ROLE_MASK = 0x1F
ROLE_TATER = 0  # a WAM motor puck
ROLE_GIMBALS = 1
ROLE_SAFETY = 2  # the safety module
ROLE_OPTICAL_ENC_ON_ENC = 0x4000  # RO_OpticalEncOnEnc: a joint (secondary) encoder: 6-byte position replies
ROLE_MAG_ENC_ON_SERIAL = 0x0100  # RO_MagEncOnSerial: absolute motor encoder (MECH)
# Properties a puck answers in the monitor (libbarrett PL_Monitor: VERS, ROLE, SN, ID, ERROR, STAT, ...).
MONITOR_PROPS = frozenset({0, 1, 2, 3, 4, 5})

# CTS assumed until each puck's is read: the model's encoder resolution (4096 on older arms, 40960 with
# magnetic encoders); IPNM's default is with the torques (torques.IPNM_DEFAULT).
CTS_DEFAULT = P.ENCODER_COUNTS_PER_REV


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
    """Refuse a motor puck whose firmware uses other property ids than :class:`Prop`.

    Parameters
    ----------
    puck_id : int
        Node id, for the message.
    vers : int
        Value of the puck's VERS property.

    Raises
    ------
    BackendError
        If ``vers`` is below :data:`MIN_FIRMWARE_VERSION`; the message names the ids that firmware uses.
    """
    if vers >= MIN_FIRMWARE_VERSION:
        return
    ids = next((d for (lo, hi), d in OLD_MOTOR_IDS.items() if lo <= vers <= hi), None)
    why = ("it names " + ", ".join(f"{k} {v}" for k, v in ids.items()) + " where VERS >= 65 uses "
           + ", ".join(f"{k} {int(Prop[k])}" for k in ids)) if ids else \
        "below VERS 61 every property id differs (motor pucks and the safety module shared one list)"
    raise ConfigurationRefused(f"puck {puck_id}: firmware VERS={vers} is older than {MIN_FIRMWARE_VERSION}: {why} "
                       f"(libbarrett property_list.cpp); update the puck firmware")


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
    return data_frame(encode_bus_id(HOST_ID, target), [_check_prop(prop)])


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
    return data_frame(encode_bus_id(HOST_ID, target), payload)


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
    return data_frame(encode_bus_id(puck_id, FEEDBACK_OTHER), payload)


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
    bid = decode_reply_id(msg)
    if not (bid.is_group and bid.target == FEEDBACK_OTHER_TARGET):
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

