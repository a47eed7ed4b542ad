"""The operator's part of a CAN session, between the start (:mod:`.session`) and the run, and after it: the
start pose, Shift-Activate, and Shift-Idle at the end. A mixin of :class:`~.backend.CanBackend`, which owns the
heartbeat (``_beat``: positions at 500 Hz with zero torque), the monitor and the operator.
"""

from __future__ import annotations

import logging
import time

import can
import numpy as np

from wamctl.backends.can.protocol.addressing import GROUP_WAM, SAFETY_PUCK_ID
from wamctl.backends.can.protocol.properties import Mode, Prop, make_set_property
from wamctl.backends.can.protocol.safety import SafetyMode, SafetyProp
from wamctl.backends.can.session import home_deviation_rad
from wamctl.errors import BackendError, SafetyLimitError
from wamctl.model.transmission import joint_rad_per_count

logger = logging.getLogger(__name__)

__all__ = ["COUNTDOWN_EVERY_S", "SessionWaits", "TORQUE_CONFIRM_S"]

TORQUE_CONFIRM_S = 0.5  # after Shift-Activate, every puck must report TORQUE within this
COUNTDOWN_EVERY_S = 0.5


class SessionWaits:
    """The waits for the operator (mixed into :class:`~.backend.CanBackend`)."""

    def _wait_for_start_pose(self) -> None:
        q = self._beat()
        if self.start.zeroed_now:
            home = self.arm.home_q_rad
            dev = home_deviation_rad(q, home)
            tol = 3 * joint_rad_per_count(self._cts, self.arm.j2mp)
            if (dev > tol).any():
                j = int(np.argmax(dev / tol))
                raise BackendError(f"after zeroing, joint {j + 1} reads {q[j]:.4f} rad instead of the home pose's "
                                   f"{home[j]:.4f} rad: the pucks did not take the new positions")
        if self.q0_rad is None:
            return
        t_start = time.monotonic()
        deadline = t_start + self.settings.activation_timeout_s
        said = False
        while True:
            if self.monitor.module_mode == SafetyMode.ESTOP:
                raise SafetyLimitError("E-stop on the pendant while waiting for the start pose: nothing was applied")
            dev = np.abs(q - self.q0_rad)
            if self.monitor.active:  # activated too early: the arm must not hang on zero torque
                self._back_to_idle("Shift-Activate came before the arm was at the run's start pose: back to idle "
                                   "(nothing was applied); put the arm there first")
            elif (dev <= self.settings.start_tolerance_rad).all():
                break
            j = int(np.argmax(dev))
            text = (f"Move the arm by hand to the run's start pose: joint {j + 1} at {q[j]:.3f} rad, to "
                    f"{self.q0_rad[j]:.3f} rad (the run starts within {self.settings.start_tolerance_rad} rad of it "
                    "on every joint; the arm is idle)")
            if not said:
                self.operator.say(text)
                said = True
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise BackendError(
                    f"the arm did not reach the run's start pose within {self.settings.activation_timeout_s:g} s: "
                    f"joint {j + 1} reads {q[j]:.4f} rad, the run starts at {self.q0_rad[j]:.4f} rad. Move the arm "
                    "there (idle); if it is there already, the encoders' zero is wrong: power the WAM off and on, "
                    "zero it at its home pose, and start again")
            if self._tick % int(COUNTDOWN_EVERY_S / self.control_period_s) == 0:
                self.operator.countdown(text, remaining)
            q = self._beat()
        if said:
            self.operator.done()
        self.session_log["start_pose_wait_s"] = round(time.monotonic() - t_start, 3)

    def _wait_for_activation(self) -> None:
        text = "Press Shift-Activate on the pendant"
        timeout = self.settings.activation_timeout_s
        self.operator.say(f"{text} (within {timeout:g} s; the arm gets zero torque until the run starts)")
        t_start = time.monotonic()
        deadline = t_start + timeout
        active_since: float | None = None
        told: set[str] = set()
        every = int(COUNTDOWN_EVERY_S / self.control_period_s)
        while True:
            q = self._beat()
            m, now = self.monitor, time.monotonic()
            if m.silent():
                raise BackendError(m.silent())
            if m.module_mode == SafetyMode.ESTOP:
                raise SafetyLimitError("E-stop on the pendant while waiting for Shift-Activate: nothing was applied")
            off_pose = self.q0_rad is not None and (np.abs(q - self.q0_rad) > self.settings.start_tolerance_rad).any()
            if m.active:
                active_since = active_since or now
                if off_pose:
                    active_since = None
                    self._back_to_idle("the arm was not at the run's start pose when Shift-Activate was pressed: "
                                       "back to idle (nothing was applied); put it back, then Shift-Activate")
                elif m.all_pucks_torque():
                    break
                if now - active_since > TORQUE_CONFIRM_S:
                    missing = [i for i in self.arm.puck_ids if m.puck_modes.get(i) != Mode.TORQUE]
                    self._refuse_activation(f"the safety module is active but pucks {missing} did not report TORQUE "
                                            f"within {TORQUE_CONFIRM_S} s: nothing was applied")
            else:
                active_since = None
                if off_pose and "pose" not in told:
                    told.add("pose")
                    self.operator.say("The arm has left the run's start pose: put it back before Shift-Activate")
                for f in (m.pen.faults() if m.pen is not None else []):
                    if f not in told:
                        told.add(f)
                        self.operator.say(f"The safety module shows a {f} fault: press Shift-Idle to clear it, then "
                                          "Shift-Activate")
            remaining = deadline - now
            if remaining <= 0:
                raise BackendError(f"Shift-Activate was not pressed within {timeout:g} s: nothing was applied (the "
                                   "pucks got zero torque only and stay idle)")
            if self._tick % every == 0:
                self.operator.countdown(text, remaining)
        self.operator.done()
        self.torque_mode_confirmed = True
        self.session_log["activation_wait_s"] = round(time.monotonic() - t_start, 3)
        self.session_log["heartbeat_cycles_before_run"] = self._tick
        self.operator.say("Active: every puck reports TORQUE; the run starts.")
        logger.info("%s in TORQUE mode after Shift-Activate", self.arm.pucks_words())

    def _back_to_idle(self, text: str) -> None:
        """Pucks and safety module asked to go idle (the safe direction), the operator told; the wait goes on."""
        try:
            self._tx(make_set_property(GROUP_WAM, Prop.MODE, Mode.IDLE))
            self._tx(make_set_property(SAFETY_PUCK_ID, SafetyProp.MODE, SafetyMode.IDLE))
        except can.CanError as exc:
            raise BackendError(f"CAN transmit error going back to idle: {exc}") from None
        self.monitor.module_mode = None  # the next poll says where it is
        now = time.monotonic()
        if now - getattr(self, "_idle_told_t", -np.inf) > 2.0:  # not every 10 ms if the module stays active
            self._idle_told_t = now
            self.operator.say(text + " (press Shift-Idle if the pendant still shows active)")

    def _refuse_activation(self, reason: str) -> None:
        """Back to idle (pucks and safety module: the safe direction) and stop."""
        try:
            self._tx_torque_units(self._zero_tau)
            self._tx(make_set_property(GROUP_WAM, Prop.MODE, Mode.IDLE))
            self._tx(make_set_property(SAFETY_PUCK_ID, SafetyProp.MODE, SafetyMode.IDLE))
        except can.CanError as exc:
            logger.error("going back to idle failed: %s", exc)
        raise SafetyLimitError(reason)

    def _finish_session(self) -> None:
        """Zero torque (already sent by the base), pucks IDLE, the operator's Shift-Idle, the report."""
        self.phase = "closing"
        try:
            self._tx_torque_units(self._zero_tau)
        except can.CanError as exc:
            logger.error("sending zero torque at shutdown failed: %s", exc)
        estop = self.monitor.module_mode == SafetyMode.ESTOP
        if not estop:
            self._idle_pucks()
        wait = self.settings.idle_wait_s
        if self.monitor.active and wait > 0 and not estop:
            text = "Press Shift-Idle on the pendant (the pucks are idle; the safety module is still active)"
            self.operator.say(text)
            deadline = time.monotonic() + wait
            every = int(COUNTDOWN_EVERY_S / self.control_period_s)
            try:  # (a safety module that stops answering ends the wait: the link is gone)
                while self.monitor.active and not self.monitor.silent() and time.monotonic() < deadline:
                    self._beat()
                    if self._tick % every == 0:
                        self.operator.countdown(text, deadline - time.monotonic())
            except (can.CanError, BackendError) as exc:
                logger.error("heartbeat while waiting for Shift-Idle failed: %s", exc)
            self.operator.done()
        mode = self.monitor.module_mode
        words = SafetyMode(mode).words if mode in (0, 1, 2) else "unknown"
        left = f"pucks confirmed IDLE: {self.idle_confirmed or 'none'}; safety module: {words}"
        if mode == SafetyMode.ACTIVE:
            left += " (it will report a heartbeat fault when the polling stops: press Shift-Idle)"
        self.session_log["left"] = left
        self.operator.say(f"Session ended: {left}.")

