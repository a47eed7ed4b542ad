"""The start of a session on the WAM, as libbarrett does it, up to the moment the position polling starts.

1. The safety module (node 10) must answer, be a safety module with firmware >= 61 (else refused).
2. Its limits are reloaded from EEPROM (SET DEF, SET LOAD, each confirmed, as libbarrett's
   ``setDefaultSafetyLimits``) or set from the spec (``setVelocityLimit`` / ``setTorqueLimit``), read back and
   reported.
3. It must be idle (libbarrett ``waitForMode(IDLE)``): after an E-stop, or while active, the operator is asked
   to press Shift-Idle (countdown, timeout).
4. The WAM pucks that answer must be the arm's (:class:`~.protocol.configuration.BusArm`: pucks 1-7 for a
   wam7; pucks 1-4 and none of 5-7 for a wam4, libbarrett's ``foundWam4``): another arm on the bus (a wam4
   spec on a 7-DOF WAM, a wam7 spec on a 4-DOF WAM) is refused naming the pucks, before any puck is woken.
   The arm's pucks in the monitor are woken with libbarrett's pacing; firmware, ROLE, CTS, IPNM, PIDX, POLES
   and groups are read and a configuration the model does not describe is refused.
5. MODE=IDLE to the whole WAM (libbarrett's only MODE write: "make sure the Pucks are IDLE").
6. If the safety module's ZERO is not 1: the operator confirms the arm is at its home pose (the arm's: wam7w's
   or wam4's zerocal.conf), then IFAULT=5, P of every puck from the home pose through the arm's J2MP, ZERO=1
   (libbarrett ``LowLevelWam``); the positions are read back and must be the home pose.
7. IFAULT=5 (libbarrett: "prevent velocity faults on startup due to WAM motion while no program was running").

The 500 Hz polling, the wait for the start pose and for Shift-Activate follow in the backend
(:mod:`.backend`), which owns the loop.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from collections.abc import Callable

import can
import numpy as np

from wamctl.backends.can.bus_tools import (
    PROBE_TIMEOUT_S,
    PuckInfo,
    SafetyInfo,
    check_motor_pucks,
    probe_pucks,
    read_property,
    read_safety_module,
    set_and_confirm,
)
from wamctl.backends.can.operator import Operator
from wamctl.backends.can.protocol.addressing import GROUP_WAM, SAFETY_PUCK_ID, WAM_PUCK_IDS
from wamctl.backends.can.protocol.configuration import HOME_Q_RAD, WAM7_BUS, BusArm, puck_set_problem, zeroing_counts
from wamctl.backends.can.protocol.properties import Mode, Prop, make_set_property
from wamctl.backends.can.protocol.safety import (
    IGNORE_VELOCITY_FAULTS,
    WARNING_FRACTION,
    SafetyMode,
    SafetyProp,
    check_safety_firmware,
    torque_limit_Nm,
    torque_limit_units,
    velocity_limit_m_s,
    velocity_limit_units,
)
from wamctl.backends.can.protocol.torques import IPNM_DEFAULT
from wamctl.errors import BackendError, ConfigurationRefused

logger = logging.getLogger(__name__)

__all__ = ["SessionSettings", "StartState", "format_limits", "start_session"]

MODE_WAIT_POLL_S = 0.25  # libbarrett waitForMode's default polling period
CONFIG_GAP_S = 0.01  # Barrett: "leave at least 10ms between each configuration message" to the safety module


@dataclasses.dataclass
class SessionSettings:
    """How a session waits and what it may do without asking (from the spec's CAN backend section).

    Attributes
    ----------
    activation_timeout_s : float
        Longest wait for the operator: Shift-Idle at start, the start pose, Shift-Activate.
    idle_wait_s : float
        After the run, how long the heartbeat goes on while the operator is asked to press Shift-Idle.
    zeroing_confirmed : bool
        The operator has confirmed in advance that the arm is at its home pose (``--yes``, scripted use).
    velocity_limit_m_s, torque_limit_Nm : float or None
        Safety module limits (fault; the warning is 0.9 of it); None reloads the EEPROM's.
    start_tolerance_rad : float
        Largest ``|q - q0|`` per joint at which the run may start.
    """

    activation_timeout_s: float = 60.0
    idle_wait_s: float = 10.0
    zeroing_confirmed: bool = False
    velocity_limit_m_s: float | None = None
    torque_limit_Nm: float | None = None
    start_tolerance_rad: float = 0.05


@dataclasses.dataclass
class StartState:
    """What the start of the session found and did."""

    safety: SafetyInfo
    pucks: dict[int, PuckInfo]
    limits: dict[str, int]
    zeroed_now: bool = False
    zero_counts: list[int] | None = None


def format_limits(limits: dict[str, int]) -> str:
    """The safety module's limits in words."""
    parts = []
    if "VL1" in limits and "VL2" in limits:
        parts.append(f"velocity warning {velocity_limit_m_s(limits['VL1']):.2f} m/s, fault "
                     f"{velocity_limit_m_s(limits['VL2']):.2f} m/s (elbow and 4-DOF end point)")
    if "TL1" in limits and "TL2" in limits:
        parts.append(f"torque warning {limits['TL1']}, fault {limits['TL2']} puck units "
                     f"({torque_limit_Nm(limits['TL1'], IPNM_DEFAULT):.2f} / "
                     f"{torque_limit_Nm(limits['TL2'], IPNM_DEFAULT):.2f} N m of motor torque at IPNM "
                     f"{IPNM_DEFAULT})")
    return "; ".join(parts) or "not read"


class _Start:
    def __init__(self, bus: can.BusABC, send: Callable[[can.Message], None], operator: Operator,
                 settings: SessionSettings, sleep: Callable[[float], None], arm: BusArm = WAM7_BUS) -> None:
        self.bus, self.send, self.op, self.settings, self.sleep = bus, send, operator, settings, sleep
        self.arm = arm

    def get(self, node: int, prop: int) -> int | None:
        return read_property(self.bus, [node], prop, PROBE_TIMEOUT_S, retries=1, send=self.send).get(node)

    def set_module(self, prop: int, value: int) -> None:
        set_and_confirm(self.bus, SAFETY_PUCK_ID, prop, value, self.send)
        self.sleep(CONFIG_GAP_S)

    # 1
    def safety_module(self) -> SafetyInfo:
        info = read_safety_module(self.bus, self.send)
        if info is None:
            raise BackendError("no safety module (node 10) answered: wamctl drives the WAM only through its safety "
                               "system (is the WAM powered and the CAN cable plugged in?)")
        if not info.is_safety_module:
            raise ConfigurationRefused(f"node 10 has ROLE={info.role}: not a safety module (low five bits 2)")
        check_safety_firmware(info.vers)
        return info

    # 2
    def limits(self) -> dict[str, int]:
        s = self.settings
        if s.velocity_limit_m_s is None:
            for name in ("VL1", "VL2"):
                self.set_module(SafetyProp.DEF, SafetyProp[name])
                self.set_module(SafetyProp.LOAD, SafetyProp[name])
        else:
            self.set_module(SafetyProp.VL2, velocity_limit_units(s.velocity_limit_m_s))
            self.set_module(SafetyProp.VL1, velocity_limit_units(WARNING_FRACTION * s.velocity_limit_m_s))
        if s.torque_limit_Nm is None:
            for name in ("TL1", "TL2"):
                self.set_module(SafetyProp.DEF, SafetyProp[name])
                self.set_module(SafetyProp.LOAD, SafetyProp[name])
        else:
            self.set_module(SafetyProp.TL2, torque_limit_units(s.torque_limit_Nm, IPNM_DEFAULT))
            self.set_module(SafetyProp.TL1, torque_limit_units(WARNING_FRACTION * s.torque_limit_Nm, IPNM_DEFAULT))
        out = {}
        for name in ("VL1", "VL2", "TL1", "TL2"):
            v = self.get(SAFETY_PUCK_ID, SafetyProp[name])
            if v is None:
                raise BackendError(f"the safety module did not report {name}")
            out[name] = v
        return out

    # 3
    def wait_until_idle(self, info: SafetyInfo) -> None:
        mode = info.mode
        if mode == SafetyMode.IDLE:
            return
        text = ("Release the E-stop (twist it) and press Shift-Idle on the pendant" if mode == SafetyMode.ESTOP
                else "The WAM is active: press Shift-Idle on the pendant")
        self.op.say(text)
        deadline = time.monotonic() + self.settings.activation_timeout_s
        while mode != SafetyMode.IDLE:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise BackendError(f"the safety module stayed {SafetyMode(mode).words if mode in (0, 1, 2) else mode} "
                                   f"for {self.settings.activation_timeout_s:g} s: nothing was done "
                                   "(press Shift-Idle on the pendant, then start again)")
            self.op.countdown(text, remaining)
            self.sleep(MODE_WAIT_POLL_S)
            mode = self.get(SAFETY_PUCK_ID, SafetyProp.MODE)
        self.op.done()
        info.mode = int(mode)

    # 4
    def pucks(self) -> dict[int, PuckInfo]:
        arm = self.arm
        # which WAM pucks are there (the monitor answers STAT too): the arm's, and none other, before waking any
        present = read_property(self.bus, WAM_PUCK_IDS, Prop.STAT, PROBE_TIMEOUT_S, send=self.send)
        problem = puck_set_problem(arm, present)
        if problem is not None:
            text, refused = problem
            raise (ConfigurationRefused if refused else BackendError)(text)
        found = probe_pucks(self.bus, arm.puck_ids, wake=True, send=self.send, sleep=self.sleep)
        problem = puck_set_problem(arm, found)
        if problem is not None:  # a puck of the arm gone silent since (while waking)
            raise BackendError(problem[0])
        check_motor_pucks(found, arm)
        return found

    # 6
    def zero(self, pucks: dict[int, PuckInfo]) -> list[int]:
        s, arm = self.settings, self.arm
        home = ", ".join(f"{x:g}" for x in arm.home_q_rad)
        question = (f"The WAM needs to be zeroed. Put the arm at its home pose ({home}) rad: folded, every joint "
                    "against its stop as in Barrett's manual. Is the arm at its home pose?")
        if s.zeroing_confirmed:
            self.op.say(question.replace("Is the arm at its home pose?", "Confirmed in advance (--yes / "
                                         "zeroing_confirmed): zeroing now."))
        elif not self.op.confirm(question):
            raise BackendError("the WAM is not zeroed and zeroing was not confirmed: nothing was done (put the "
                               "arm at its home pose and confirm, or answer with --yes)")
        cts = [pucks[i].cts for i in arm.puck_ids]
        counts = zeroing_counts(cts, arm.home_q_rad, arm.j2mp)
        self.set_module(SafetyProp.IFAULT, IGNORE_VELOCITY_FAULTS)
        for i, c in zip(arm.puck_ids, counts.tolist()):
            self.send(make_set_property(i, Prop.P, c))
        got = read_property(self.bus, arm.puck_ids, Prop.STAT, PROBE_TIMEOUT_S, send=self.send)
        if len(got) < len(arm.puck_ids):
            raise BackendError(f"pucks {[i for i in arm.puck_ids if i not in got]} did not answer after zeroing")
        self.set_module(SafetyProp.ZERO, 1)
        if self.get(SAFETY_PUCK_ID, SafetyProp.ZERO) != 1:
            raise BackendError("the safety module did not record the zeroing (ZERO is not 1)")
        self.op.say(f"Zeroed at the home pose: P = {counts.tolist()} counts on {arm.pucks_words()}.")
        return counts.tolist()


def start_session(bus: can.BusABC, send: Callable[[can.Message], None], operator: Operator,
                  settings: SessionSettings, sleep: Callable[[float], None] = time.sleep,
                  arm: BusArm = WAM7_BUS) -> StartState:
    """Steps 1-7 of the module docstring for ``arm`` (default the wam7); raises :class:`BackendError` naming what is
    wrong (nothing moves)."""
    st = _Start(bus, send, operator, settings, sleep, arm)
    safety = st.safety_module()
    limits = st.limits()
    operator.say(f"Safety module: {safety.mode_words()}, {'zeroed' if safety.zeroed else 'not zeroed'}; limits: "
                 f"{format_limits(limits)}.")
    st.wait_until_idle(safety)
    pucks = st.pucks()
    send(make_set_property(GROUP_WAM, Prop.MODE, Mode.IDLE))
    state = StartState(safety, pucks, limits)
    if not safety.zeroed:
        state.zero_counts = st.zero(pucks)
        state.zeroed_now = True
        safety.zero = 1
    st.set_module(SafetyProp.IFAULT, IGNORE_VELOCITY_FAULTS)
    logger.info("session started (%s): pucks %s, VERS %s", arm.name, list(pucks), [pucks[i].vers for i in arm.puck_ids])
    return state


def home_deviation_rad(q_rad: np.ndarray, home_q_rad: np.ndarray = HOME_Q_RAD) -> np.ndarray:
    """``|q - home|`` per joint (after a zeroing the measured pose must be the home pose; the wam7's by default)."""
    return np.abs(np.asarray(q_rad, float) - np.asarray(home_q_rad, float))
