"""Addressing on the WAM's CAN bus: 11-bit identifiers, node ids, broadcast and feedback groups.

Also the packed-torque groups and their slots, the one helper that builds a standard data frame, and
:class:`PuckFrameError` (a frame from the bus that does not follow the protocol). Sources: libbarrett
``include/barrett/products/puck.h``, ``puck_group.h`` and ``low_level_wam-inl.h``.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import can

from wamctl.errors import BackendError

__all__ = [
    "BusId",
    "DEFAULT_PIDX",
    "FEEDBACK_OTHER",
    "FEEDBACK_OTHER_TARGET",
    "FEEDBACK_POSITION",
    "FEEDBACK_POSITION_TARGET",
    "FEEDBACK_SECONDARY_POSITION",
    "GROUP_FLAG",
    "GROUP_HAND",
    "GROUP_LOWER_WAM",
    "GROUP_UPPER_WAM",
    "GROUP_WAM",
    "GROUP_WHOLE_BUS",
    "HOST_ID",
    "MAX_CAN_ID",
    "N_JOINTS",
    "NODE_ID_MASK",
    "PuckFrameError",
    "TORQUE_GROUPS",
    "TO_MASK",
    "WAM_PUCK_IDS",
    "data_frame",
    "decode_bus_id",
    "decode_reply_id",
    "encode_bus_id",
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
# Low five bits of the id of a frame to a feedback group (what a reply's BusId.target holds).
FEEDBACK_POSITION_TARGET = FEEDBACK_POSITION & NODE_ID_MASK
FEEDBACK_OTHER_TARGET = FEEDBACK_OTHER & NODE_ID_MASK

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



def decode_reply_id(msg: can.Message) -> BusId:
    """The id of a standard data frame received from the bus.

    Raises
    ------
    PuckFrameError
        If the frame is an extended, error or remote frame, or its id does not fit in 11 bits.
    """
    if msg.is_extended_id or msg.is_error_frame or msg.is_remote_frame:
        raise PuckFrameError(f"not a puck data frame: id {msg.arbitration_id:#x}")
    try:
        return decode_bus_id(msg.arbitration_id)
    except ValueError as exc:
        raise PuckFrameError(str(exc)) from exc


def data_frame(arbitration_id: int, data: bytes | bytearray | Sequence[int]) -> can.Message:
    """A standard (11-bit id) data frame."""
    return can.Message(arbitration_id=arbitration_id, data=bytes(data), is_extended_id=False)
