"""Watching the safety module and the pucks' MODE during a session, at a low rate between the position polls.

Every few cycles the backend sends :meth:`SafetyMonitor.requests` (a get of PEN and of MODE to node 10 and,
when asked, of MODE to the whole WAM) right after its torque frames; the replies are read with the next
cycle's frames (:meth:`SafetyMonitor.on_reply`). :meth:`SafetyMonitor.run_stop` then says whether the run must
end, and why, in words:

- the safety module E-stopped: ``E-stop on the pendant`` (failed);
- it dropped to idle with a fault on the pendant: ``velocity fault VL2 ...``, ``torque fault TL2 ...``,
  ``heartbeat fault ...`` (failed);
- it dropped to idle without a fault: ``stopped on the pendant (Shift-Idle)`` (the run is *interrupted*, as by
  Ctrl-C: :class:`PendantStop`);
- a puck left TORQUE mode while the module is active, or the module stopped answering (failed).
"""

from __future__ import annotations

from collections.abc import Sequence

import can

from wamctl.backends.can.protocol.addressing import GROUP_WAM, SAFETY_PUCK_ID, WAM_PUCK_IDS, PuckFrameError
from wamctl.backends.can.protocol.properties import Mode, Prop, PropertyReply, make_get_property
from wamctl.backends.can.protocol.safety import PendantState, SafetyMode, SafetyProp, decode_pen, velocity_limit_m_s
from wamctl.errors import BackendError, SafetyLimitError

__all__ = ["PendantStop", "SILENT_POLLS", "SafetyMonitor", "stop_reason"]

SILENT_POLLS = 4  # polls of the safety module left unanswered before the run stops


class PendantStop(KeyboardInterrupt):
    """The operator stopped the run on the pendant (Shift-Idle): the arm's Ctrl-C. The runner marks the run
    ``interrupted``, every sample kept; the reason reads "stopped by the operator on the pendant (Shift-Idle)"."""


def stop_reason(mode: int | None, pen: PendantState | None, limits: dict[str, int]) -> tuple[str, type]:
    """Why the safety module left ACTIVE, in words, and the exception that ends the run."""
    faults = pen.faults() if pen is not None else []
    if mode == SafetyMode.ESTOP:
        return "E-stop on the pendant: the arm is unpowered (release it, press Shift-Idle)", SafetyLimitError
    words = []
    for f in faults:
        if f == "velocity":
            vl2 = limits.get("VL2")
            words.append("velocity fault VL2" + (f" (faster than {velocity_limit_m_s(vl2):.2f} m/s at the elbow or "
                                                 "the 4-DOF end point)" if vl2 is not None else ""))
        elif f == "torque":
            tl2 = limits.get("TL2")
            words.append("torque fault TL2" + (f" (a motor command above {tl2} puck units)" if tl2 else ""))
        elif f == "heartbeat":
            words.append("heartbeat fault (the safety module missed the position polling)")
        elif f == "voltage":
            words.append("voltage fault")
        else:
            words.append(f"{f} fault")
    if words:
        return "safety module: " + "; ".join(words) + " (the pucks are idle)", SafetyLimitError
    return "the operator on the pendant (Shift-Idle)", PendantStop


class SafetyMonitor:
    """What the latest replies of the safety module and the arm's pucks (``puck_ids``, default the wam7's 1-7) say
    (see the module docstring)."""

    def __init__(self, puck_ids: Sequence[int] = WAM_PUCK_IDS) -> None:
        self.puck_ids = tuple(puck_ids)
        self.module_mode: int | None = None
        self.pen: PendantState | None = None
        self.pen_error: str | None = None
        self.puck_modes: dict[int, int] = {}
        self.unanswered_polls = 0
        self.polls = 0

    def requests(self, pucks: bool) -> list[can.Message]:
        """The frames of one poll (PEN first: its reply is in when MODE's is)."""
        self.unanswered_polls += 1
        self.polls += 1
        out = [make_get_property(SAFETY_PUCK_ID, SafetyProp.PEN), make_get_property(SAFETY_PUCK_ID, SafetyProp.MODE)]
        if pucks:
            self.puck_modes.clear()
            out.append(make_get_property(GROUP_WAM, Prop.MODE))
        return out

    def on_reply(self, reply: PropertyReply) -> None:
        if reply.puck_id == SAFETY_PUCK_ID:
            if reply.prop == SafetyProp.MODE:
                self.module_mode = reply.value
                self.unanswered_polls = 0
            elif reply.prop == SafetyProp.PEN:
                try:
                    self.pen = decode_pen(reply.value)
                    self.pen_error = None
                except PuckFrameError as exc:
                    self.pen_error = str(exc)
        elif reply.puck_id in self.puck_ids and reply.prop == Prop.MODE:
            self.puck_modes[reply.puck_id] = reply.value

    @property
    def active(self) -> bool:
        return self.module_mode == SafetyMode.ACTIVE

    def all_pucks_torque(self) -> bool:
        return len(self.puck_modes) == len(self.puck_ids) and all(m == Mode.TORQUE for m in self.puck_modes.values())

    def silent(self) -> str | None:
        if self.unanswered_polls > SILENT_POLLS:
            return f"the safety module did not answer {self.unanswered_polls - 1} polls of its MODE"
        return None

    def run_stop(self, limits: dict[str, int]) -> tuple[str, type] | None:
        """During the run (module was active): why to stop now, or None."""
        silent = self.silent()
        if silent:
            return silent, BackendError
        if self.module_mode is not None and self.module_mode != SafetyMode.ACTIVE:
            return stop_reason(self.module_mode, self.pen, limits)
        wrong = {i: m for i, m in self.puck_modes.items() if m != Mode.TORQUE}
        if wrong:
            return (f"pucks {sorted(wrong)} left TORQUE mode (MODE {sorted(set(wrong.values()))}) while the safety "
                    "module is active", BackendError)
        return None

    def describe(self) -> dict:
        return {"mode": self.module_mode, "mode_name": _words(self.module_mode),
                "pendant": None if self.pen is None else self.pen.summary(), "polls": self.polls,
                "puck_modes": {str(k): v for k, v in sorted(self.puck_modes.items())}}


def _words(mode: int | None) -> str | None:
    try:
        return SafetyMode(mode).words
    except (TypeError, ValueError):
        return None if mode is None else str(mode)
