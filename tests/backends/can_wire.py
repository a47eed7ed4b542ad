"""Reading a CAN session off the wire (shared by the session tests on the virtual bus and across processes).

A monitor bus on the same channel sees every frame in order; these helpers answer the questions of issue 14's
acceptance criteria from those frames only.
"""

from __future__ import annotations

import time

import can
import numpy as np

from wamctl.backends.can.protocol.addressing import (
    FEEDBACK_OTHER_TARGET,
    GROUP_WAM,
    HOST_ID,
    SAFETY_PUCK_ID,
    TORQUE_GROUPS,
    WAM_PUCK_IDS,
    decode_bus_id,
)
from wamctl.backends.can.protocol.positions import make_position_request
from wamctl.backends.can.protocol.properties import SET_MASK, Mode, Prop, Status
from wamctl.backends.can.protocol.safety import SafetyMode, SafetyProp
from wamctl.backends.can.protocol.torques import PACKED_TORQUE_HEADER, unpack_torques

REQUEST = bytes(make_position_request().data)


def drain(bus: can.BusABC) -> list[can.Message]:
    out = []
    while (msg := bus.recv(timeout=0.0)) is not None:
        out.append(msg)
    return out


def _host_set(m: can.Message) -> tuple[int, int, int] | None:
    """(target id, property, value) of a host's set, else None."""
    if m.is_error_frame or m.arbitration_id > 0x7FF:
        return None
    bid = decode_bus_id(m.arbitration_id)
    d = bytes(m.data)
    if bid.sender != HOST_ID or len(d) not in (4, 6) or not d[0] & SET_MASK or m.arbitration_id in TORQUE_GROUPS:
        return None
    return m.arbitration_id, d[0] & 0x7F, int.from_bytes(d[2:], "little", signed=True)


def host_mode_writes(frames: list[can.Message]) -> list[tuple[int, int]]:
    """(target id, value) of every MODE set the host sent (to pucks, groups or the safety module)."""
    out = []
    for m in frames:
        s = _host_set(m)
        if s is not None and s[1] == Prop.MODE:
            out.append((s[0], s[2]))
    return out


def host_sets(frames: list[can.Message], prop: int, target: int | None = None) -> list[tuple[int, int, int]]:
    """(frame index, target id, value) of the host's sets of ``prop`` (to ``target`` if given)."""
    out = []
    for i, m in enumerate(frames):
        s = _host_set(m)
        if s is not None and s[1] == prop and (target is None or s[0] == target):
            out.append((i, s[0], s[2]))
    return out


def _reply(m: can.Message) -> tuple[int, int, int] | None:
    """(sender, property, value) of a property reply."""
    if m.is_error_frame or m.arbitration_id > 0x7FF:
        return None
    bid = decode_bus_id(m.arbitration_id)
    d = bytes(m.data)
    if not (bid.is_group and bid.target == FEEDBACK_OTHER_TARGET and len(d) in (4, 6) and d[0] & SET_MASK):
        return None
    return bid.sender, d[0] & 0x7F, int.from_bytes(d[2:], "little", signed=True)


def all_pucks_torque_index(frames: list[can.Message]) -> int | None:
    """Index of the frame with which the last of pucks 1-7 has reported MODE=TORQUE (None: never)."""
    seen: set[int] = set()
    for i, m in enumerate(frames):
        r = _reply(m)
        if r is not None and r[0] in WAM_PUCK_IDS and r[1] == Prop.MODE:
            if r[2] == Mode.TORQUE:
                seen.add(r[0])
                if len(seen) == len(WAM_PUCK_IDS):
                    return i
            else:
                seen.discard(r[0])
    return None


def torque_frames(frames: list[can.Message]) -> list[tuple[int, np.ndarray]]:
    """(frame index, slots) of every packed-torque frame."""
    return [(i, unpack_torques(m.data)) for i, m in enumerate(frames)
            if m.arbitration_id in TORQUE_GROUPS and bytes(m.data)[:1] == bytes([PACKED_TORQUE_HEADER])]


def requests(frames: list[can.Message]) -> list[int]:
    """Frame index of every position request to the whole WAM."""
    return [i for i, m in enumerate(frames) if m.arbitration_id == GROUP_WAM and bytes(m.data) == REQUEST]


def safety_mode_replies(frames: list[can.Message]) -> list[tuple[int, int]]:
    """(frame index, MODE) of the safety module's replies to gets of its MODE."""
    out = []
    for i, m in enumerate(frames):
        r = _reply(m)
        if r is not None and r[0] == SAFETY_PUCK_ID and r[1] == SafetyProp.MODE:
            out.append((i, r[2]))
    return out


def stop_seen_and_zeroed(frames: list[can.Message]) -> tuple[int, int, int]:
    """For a run ended by the safety module: (the cycle that saw the module leave ACTIVE, the cycle whose torque
    frames are zero from then on, the number of cycles between), cycles counted by position requests.

    "Saw" is taken as the cycle whose request precedes the module's reply: the earliest that can have read it
    (if the reply came after that cycle's reply window, the next cycle read it), so the count is an upper bound.
    """
    active = [i for i, mode in safety_mode_replies(frames) if mode == SafetyMode.ACTIVE]
    left = next(i for i, mode in safety_mode_replies(frames) if mode != SafetyMode.ACTIVE and active and i > active[0])
    req = requests(frames)
    seen_cycle = max(k for k, i in enumerate(req) if i < left)
    tq = torque_frames(frames)
    last_nonzero = max((i for i, s in tq if s.any()), default=-1)
    zero_from = next(i for i, s in tq if i > last_nonzero)
    zero_cycle = max(k for k, i in enumerate(req) if i < zero_from)
    return seen_cycle, zero_cycle, zero_cycle - seen_cycle


def wake_pacing(frames: list[can.Message]) -> dict:
    """The wake-up as the wire shows it: the STAT=READY sets' timestamps, the gaps between them, and the silence
    after the last one (time to the host's next frame)."""
    wakes = [(i, m.timestamp) for i, m in enumerate(frames)
             if (s := _host_set(m)) is not None and s[1] == Prop.STAT and s[2] == Status.READY]
    if not wakes:
        return {"n": 0}
    last_i, last_t = wakes[-1]
    nxt = next((m.timestamp for m in frames[last_i + 1:] if decode_bus_id(m.arbitration_id).sender == HOST_ID
                and not m.is_error_frame), None)
    return {"n": len(wakes), "gaps_s": np.diff([t for _, t in wakes]).tolist(),
            "silence_s": None if nxt is None else nxt - last_t}


def wait_for(predicate, timeout_s: float = 5.0) -> bool:
    """Poll ``predicate`` until it holds (True) or ``timeout_s`` passed (its last value): a deadline for an
    event, generous so that a loaded machine only makes the wait longer."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(0.002)
    return predicate()
