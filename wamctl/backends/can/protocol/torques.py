"""Torque commands on the bus: packed 14-bit torque frames and puck torque units.

The host sends the WAM pucks their torques in packed frames, one per torque group (a wam7: 0x401 pucks 1-4,
0x402 pucks 5-7; a wam4: 0x401 pucks 1-4 only, libbarrett ``LowLevelWam``'s ``ceil(dof / 4)`` groups), each
puck in the slot its PIDX names; a puck's command is in puck units, ``IPNM``
per N m of motor torque. Sources: libbarrett ``src/products/motor_puck.cpp`` (``sendPackedTorques``),
``include/barrett/products/motor_puck.h`` and ``puck.h`` (``DEFAULT_IPNM``). Joint <-> motor torques:
:mod:`wamctl.model.transmission`.
"""

from __future__ import annotations

from collections.abc import Sequence

import can
import numpy as np
from numpy.typing import ArrayLike

from wamctl.backends.can.protocol.addressing import (
    DEFAULT_PIDX,
    HOST_ID,
    PUCKS_PER_TORQUE_GROUP,
    TORQUE_GROUPS,
    PuckFrameError,
    data_frame,
    encode_bus_id,
)
from wamctl.backends.can.protocol.properties import SET_MASK, Prop
from wamctl.errors import BackendError
from wamctl.model.transmission import J2MP, as_joint_vectors, joint_torque_to_motor_Nm, motor_torque_to_joint_Nm

__all__ = [
    "IPNM_DEFAULT",
    "MAX_PUCK_TORQUE",
    "PACKED_TORQUE_HEADER",
    "joint_torque_to_puck_units",
    "make_torque_frames",
    "motor_Nm_to_puck_units",
    "pack_torques",
    "puck_units_to_joint_torque_Nm",
    "puck_units_to_motor_Nm",
    "saturate_puck_units",
    "torque_slot_of_puck",
    "unpack_torques",
]

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


def torque_slot_of_puck(pidx: dict[int, int] | None = None,
                        groups: dict[int, tuple[int, ...]] | None = None) -> dict[int, tuple[int, int]]:
    """Map each of the arm's pucks to its packed-torque group and slot, checking the PIDX values read at start-up.

    Parameters
    ----------
    pidx : dict of int to int, optional
        PIDX per puck id. Default :data:`DEFAULT_PIDX` (the wam7's).
    groups : dict of int to tuple of int, optional
        The arm's torque groups (group id -> pucks; :attr:`~.configuration.BusArm.torque_groups`). Default
        :data:`TORQUE_GROUPS` (the wam7's two).

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
    for group, members in (TORQUE_GROUPS if groups is None else groups).items():
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


def make_torque_frames(puck_units: ArrayLike, pidx: dict[int, int] | None = None,
                       groups: dict[int, tuple[int, ...]] | None = None) -> list[can.Message]:
    """Build the packed-torque frames for the arm's pucks (one per torque group).

    Parameters
    ----------
    puck_units : array_like, shape (n,)
        Commands for pucks 1..n in puck units (rounded, saturated at +-8191).
    pidx : dict of int to int, optional
        PIDX per puck id; default :data:`DEFAULT_PIDX`.
    groups : dict of int to tuple of int, optional
        The arm's torque groups; default :data:`TORQUE_GROUPS` (the wam7: n = 7).

    Returns
    -------
    list of can.Message
        8-byte frames, one per group in order: the wam7's to 0x401 (pucks 1-4) and 0x402 (pucks 5-7), the wam4's
        to 0x401 only.
    """
    groups = TORQUE_GROUPS if groups is None else groups
    n = sum(len(m) for m in groups.values())
    values = np.asarray(puck_units, dtype=float).reshape(-1)
    if values.size != n:
        raise ValueError(f"expected {n} puck torques, got {values.size}")
    slots = torque_slot_of_puck(pidx, groups)
    frames = []
    for group, members in groups.items():
        payload = pack_torques([values[p - 1] for p in members], [slots[p][1] for p in members])
        frames.append(data_frame(encode_bus_id(HOST_ID, group), payload))
    return frames


IPNM_DEFAULT = 2700  # puck.h DEFAULT_IPNM; read IPNM from each puck at start-up


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
    tau_Nm : array_like, shape (..., n)
        Joint torques (N m), n = the arm's joints (7 for the default ``j2mp``, 4 with the wam4's).
    ipnm : float or array_like, default 2700
        Puck units per N m, per puck.
    j2mp : numpy.ndarray, default :data:`J2MP`

    Returns
    -------
    numpy.ndarray, shape (..., n)
        ``int64`` puck units for pucks 1..n. Saturated entries equal +-:data:`MAX_PUCK_TORQUE`.
    """
    return motor_Nm_to_puck_units(joint_torque_to_motor_Nm(tau_Nm, j2mp), ipnm)


def puck_units_to_joint_torque_Nm(
    puck_units: ArrayLike, ipnm: ArrayLike = IPNM_DEFAULT, j2mp: np.ndarray = J2MP
) -> np.ndarray:
    """Joint torques produced by puck torque commands (``j2mp^T @ (units / IPNM)``).

    Parameters
    ----------
    puck_units : array_like, shape (..., n)
        Commands of pucks 1..n (n = the size of ``j2mp``).
    ipnm : float or array_like, default 2700
        Puck units per N m, per puck.
    j2mp : numpy.ndarray, default :data:`J2MP`

    Returns
    -------
    numpy.ndarray, shape (..., n)
        Joint torques (N m).
    """
    units = as_joint_vectors(puck_units, "puck_units", np.shape(j2mp)[0])
    return motor_torque_to_joint_Nm(puck_units_to_motor_Nm(units, ipnm), j2mp)

