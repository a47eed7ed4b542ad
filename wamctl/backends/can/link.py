"""The link to the pucks: one position request per cycle, the replies collected within ``reply_timeout_s`` (and
the safety monitor's replies on the way), and the link watchdog (missing or late replies, malformed frames).
A mixin of :class:`~.backend.CanBackend`, which owns the bus, the counters and the trip.
"""

from __future__ import annotations

import time

import can
import numpy as np

from wamctl.backends.can.bus_tools import recv_until
from wamctl.backends.can.monitor import stop_reason
from wamctl.backends.can.protocol.addressing import (
    FEEDBACK_OTHER_TARGET,
    FEEDBACK_POSITION_TARGET,
    GROUP_WHOLE_BUS,
    MAX_CAN_ID,
    SAFETY_PUCK_ID,
    BusId,
    PuckFrameError,
    decode_bus_id,
)
from wamctl.backends.can.protocol.positions import parse_position_reply
from wamctl.backends.can.protocol.properties import parse_property_reply
from wamctl.backends.can.protocol.safety import SafetyMode
from wamctl.errors import BackendError, SafetyLimitError
from wamctl.model.transmission import counts_to_joint_rad

__all__ = ["Link"]


class Link:
    """Polling the positions and watching the replies (mixed into :class:`~.backend.CanBackend`)."""

    def _decode(self, msg: can.Message) -> BusId | None:
        """The id of a reply from one of the arm's pucks or the safety module, or None (counted) for anything else
        (a WAM puck the arm does not have is foreign: the session refused a bus where one answers)."""
        self._stats["frames_received"] += 1
        if msg.is_error_frame:
            self._stats["error_frames"] += 1
            return None
        if msg.is_extended_id or msg.is_remote_frame or msg.arbitration_id > MAX_CAN_ID:
            self._stats["foreign_frames"] += 1
            return None
        bid = decode_bus_id(msg.arbitration_id)
        if bid.sender == SAFETY_PUCK_ID and bid.is_group and bid.target == GROUP_WHOLE_BUS & 0x1F:
            self._stats["safety_broadcasts"] += 1  # 0x540: libbarrett discards them too
            return None
        pucks = self.arm.puck_ids
        if bid.is_group and bid.target == FEEDBACK_OTHER_TARGET and (bid.sender in pucks
                                                                     or bid.sender == SAFETY_PUCK_ID):
            return bid
        if bid.is_group and bid.target == FEEDBACK_POSITION_TARGET and bid.sender in pucks:
            return bid
        self._stats["foreign_frames"] += 1
        return None

    def _check_frame(self, msg: can.Message, bid: BusId) -> tuple[int, int] | None:
        """A position reply's (puck, counts); None for a property reply (handed to the monitor)."""
        if bid.target == FEEDBACK_POSITION_TARGET:
            return parse_position_reply(msg)
        self.monitor.on_reply(parse_property_reply(msg))
        return None

    def _poll(self) -> np.ndarray:
        """Request the positions and collect the replies (and the monitor's), with the link watchdog."""
        bus = self._bus
        garbage: str | None = None
        while (msg := bus.recv(timeout=0.0)) is not None:  # replies that came after the last timeout
            bid = self._decode(msg)
            if bid is None:
                continue
            try:
                if self._check_frame(msg, bid) is not None:
                    self._stats["late_replies"] += 1
            except PuckFrameError as exc:
                garbage = garbage or str(exc)
        if garbage is not None:
            self._garbage(garbage)
        try:
            self._tx(self._request)
        except can.CanError as exc:
            self._trip(f"CAN transmit error: {exc}", BackendError)
        t_sent = time.perf_counter()
        self._got, self._garbage_seen = 0, None
        recv_until(bus, t_sent + self.reply_timeout_s, self._on_frame)
        # a host descheduled past the deadline still reads what arrived meanwhile: only replies that are not there
        # count as missing (a stall of the host is an overrun, not a link fault)
        all_in = self.arm.all_replied_mask
        while self._got != all_in and self._garbage_seen is None \
                and (msg := bus.recv(timeout=0.0)) is not None:
            self._on_frame(msg)
        if self._garbage_seen is not None:
            self._garbage(self._garbage_seen)
        if self._got != all_in:
            self._missing_replies([i for i in self.arm.puck_ids if not self._got & (1 << (i - 1))])
        else:
            (self.timing if self.phase == "run" else self.heartbeat_timing).reply(time.perf_counter() - t_sent)
            if self._bad_run_start is not None:
                self._event("link", f"cycle {self._cycle}: replies back after {self._bad_cycles} bad cycles")
            self._bad_cycles = 0
            self._bad_run_start = None
        self._q[:] = counts_to_joint_rad(self._counts, self._cts, self.arm.j2mp)
        return self._q

    def _on_frame(self, msg: can.Message) -> bool:
        """One frame within a cycle's reply window; True once all the arm's positions are in (or garbage came)."""
        bid = self._decode(msg)
        if bid is None:
            return False
        try:
            reply = self._check_frame(msg, bid)
        except PuckFrameError as exc:
            self._garbage_seen = str(exc)
            return True
        if reply is not None:
            puck, counts = reply
            self._counts[puck - 1] = counts
            self._got |= 1 << (puck - 1)
        return self._got == self.arm.all_replied_mask

    def _missing_replies(self, missing: list[int]) -> None:
        self._stats["missed_reply_cycles"] += 1
        self._bad_cycles += 1
        if self._bad_run_start is None:
            self._bad_run_start = self._cycle
            self._event("link", f"cycle {self._cycle}: no position reply from pucks {missing} within "
                                f"{self.reply_timeout_s * 1e3:.1f} ms")
            if self.phase != "closing":  # an E-stop silences the pucks: ask the safety module at once
                try:
                    for m in self.monitor.requests(pucks=False):
                        self._tx(m)
                except can.CanError:
                    pass
        if self._bad_cycles > self.watchdog_cycles and self.phase != "closing":
            if self.monitor.module_mode == SafetyMode.ESTOP:
                self._trip(stop_reason(SafetyMode.ESTOP, None, {})[0], SafetyLimitError)
            self._trip(f"CAN link watchdog: position replies from pucks {missing} missing or late for "
                       f"{self._bad_cycles} consecutive cycles (more than watchdog_cycles = "
                       f"{self.watchdog_cycles})", SafetyLimitError)

    def _garbage(self, detail: str) -> None:
        self._stats["garbage_frames"] += 1
        if self.phase == "closing":
            return
        if self._bad_run_start is None:
            self._bad_run_start = self._cycle
        self._trip(f"CAN link watchdog: malformed frame from a puck ({detail})", SafetyLimitError)

