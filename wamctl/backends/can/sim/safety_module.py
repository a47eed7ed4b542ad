"""The simulated safety module (node 10): modes, pendant, limits, zeroing flag and the faults it watches for.

What it does, as far as Barrett's documents and libbarrett say (:mod:`wamctl.backends.can.protocol.safety`):

- MODE 0 E-stop, 1 idle, 2 active. Only the pendant moves it up: Shift-Activate (from idle, no fault latched,
  every motor puck awake) puts the pucks into TORQUE; Shift-Idle, a fault or an E-stop puts them back to
  IDLE (the E-stop also cuts their power). A host's request to go from idle to active (or from E-stop to
  idle) is ignored, as libbarrett's ``SafetyModule::setMode`` documents; requests towards idle are obeyed.
- Limits VL1/VL2 (m/s, Q4.12, at the elbow and the 4-DOF end point) and TL1/TL2 (puck units, any motor):
  above ``*1`` the pendant shows a warning, above ``*2`` a fault, the module drops to idle; if the speed
  stays above VL2 for 0.5 s after that, a full E-stop follows. DEF/LOAD/SAVE act on a simulated EEPROM whose
  defaults are Barrett's (VL 0.5/1.0 m/s, TL 4731/5204).
- IFAULT=n ignores the next n velocity faults (the zeroing makes the positions jump); ZERO records the zeroing.
- The heartbeat is the position traffic it hears (it listens to group 3): no position reply for
  ``heartbeat_timeout_s`` while active is a heartbeat fault.

Choices of the simulation where Barrett's documents are silent (said so, not measured): the heartbeat timeout
(0.5 s by default), the speed estimated over the last five position samples the module heard (its
"velocity fault history buffer" of five, samples more than 0.1 s old dropped) and checked only while active,
faults latched until the next Shift-Idle, and after an E-stop the pucks power up again in the monitor with new
encoder offsets and ZERO back to 0 (re-zeroing needed, as Barrett's zerocal says "after certain types of
safety faults").
"""

from __future__ import annotations

import collections
import logging

import numpy as np

from wamctl.backends.can.protocol.properties import ROLE_SAFETY, Mode, Status
from wamctl.backends.can.protocol.safety import (
    DEFAULT_LIMITS,
    PEN_PARAMETERS,
    Level,
    PendantState,
    SafetyMode,
    SafetyProp,
    encode_pen,
    velocity_limit_m_s,
)
from wamctl.model.mjcf import dh_fixed

logger = logging.getLogger(__name__)

__all__ = ["SIM_SAFETY_FIRMWARE_VERSION", "SimulatedSafetyModule", "elbow_and_end_point_m"]

SIM_SAFETY_FIRMWARE_VERSION = 200  # at or above every safety table of libbarrett (>= 61)
HEARTBEAT_TIMEOUT_S = 0.5
VELOCITY_SAMPLES = 5
STALE_SAMPLE_S = 0.1
ESTOP_AFTER_VELOCITY_FAULT_S = 0.5
BUTTON_SHOWN_S = 0.2

_FIXED = []
for _i in range(5):
    _rot, _trans = dh_fixed(_i)
    _m = np.eye(4)
    _m[:3, :3], _m[:3, 3] = _rot, _trans
    _FIXED.append(_m)


def elbow_and_end_point_m(q_rad: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Positions (m, base frame) of the elbow (DH frame 3) and the 4-DOF end point (DH frame 5, the wrist
    centre) where the safety module measures speed.

    Only joints 1-4 move these points (frame 5's origin lies on joint 5's axis), so the angles of a wam4 (four
    joints) give them too: the module hears the positions of pucks 1-4 on either arm. Where a real module measures
    on a wam4 (the wam7's wrist centre, 0.30 m along the forearm, or wam4.conf's tool plate at 0.36 m) is not
    documented; the simulation takes the wam7's wrist centre on both arms (the same firmware)."""
    q = np.zeros(5)
    k = min(5, len(q_rad))
    q[:k] = np.asarray(q_rad, float)[:k]
    q_rad = q
    t = np.eye(4)
    out = []
    for i in range(5):
        c, s = np.cos(q_rad[i]), np.sin(q_rad[i])
        rz = np.array([[c, -s, 0, 0], [s, c, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1.0]])
        t = t @ rz @ _FIXED[i]
        if i in (2, 4):
            out.append(t[:3, 3].copy())
    return out[0], out[1]


class SimulatedSafetyModule:
    """The safety module's state machine (called by the puck simulator's thread only).

    Parameters
    ----------
    firmware_version : int
    mode : SafetyMode
        At power-up.
    zeroed : bool
        ZERO at start (a module that was zeroed earlier in the day).
    heartbeat_timeout_s : float
    groups : (int, int, int)
        GRPA/GRPB/GRPC: 1, 2 (hears the torque frames) and 3 (hears the position replies) by default.

    Each change the pucks must follow is returned by the methods as an action: ``"torque"`` (pucks into
    TORQUE), ``"idle"`` (pucks IDLE), ``"power_off"`` (E-stop) or ``"power_on"`` (E-stop released), else None.
    """

    def __init__(self, *, firmware_version: int = SIM_SAFETY_FIRMWARE_VERSION,
                 mode: SafetyMode = SafetyMode.IDLE, zeroed: bool = False,
                 heartbeat_timeout_s: float = HEARTBEAT_TIMEOUT_S, groups: tuple[int, int, int] = (1, 2, 3)) -> None:
        self.heartbeat_timeout_s = float(heartbeat_timeout_s)
        self.eeprom = {int(SafetyProp[k]): v for k, v in DEFAULT_LIMITS.items()}
        self.props: dict[int, int] = {
            SafetyProp.VERS: int(firmware_version), SafetyProp.ROLE: ROLE_SAFETY, SafetyProp.SN: 1010,
            SafetyProp.ID: 10, SafetyProp.ERROR: 0, SafetyProp.STAT: int(Status.READY),
            SafetyProp.MODE: int(mode), SafetyProp.GRPA: groups[0], SafetyProp.GRPB: groups[1],
            SafetyProp.GRPC: groups[2], SafetyProp.ZERO: int(zeroed), SafetyProp.SAFE: 0,
            SafetyProp.IFAULT: 0, **self.eeprom,
        }
        self.props = {int(k): int(v) for k, v in self.props.items()}
        self.latched: dict[str, Level] = {}  # faults, until the next Shift-Idle
        self.warnings: dict[str, Level] = {}
        self._button, self._button_until = "none", 0.0
        self._samples: collections.deque = collections.deque(maxlen=VELOCITY_SAMPLES)
        self._last_reply_t: float | None = None
        self._active_since: float | None = None
        self._velocity_idle_t: float | None = None
        self.last_speed_m_s = 0.0
        self.log: list[tuple[float, str]] = []  # (monotonic time, what happened)
        self.refused_requests = 0
        self.ignored_velocity_faults = 0

    # ------------------------------------------------------------------ state
    @property
    def mode(self) -> SafetyMode:
        return SafetyMode(self.props[SafetyProp.MODE])

    def _set_mode(self, mode: SafetyMode, now: float, why: str) -> None:
        self.props[SafetyProp.MODE] = int(mode)
        self._active_since = now if mode == SafetyMode.ACTIVE else None
        self.log.append((now, f"{mode.words}: {why}"))
        logger.info("simulated safety module: %s (%s)", mode.words, why)

    def pendant_state(self, now: float) -> PendantState:
        levels = dict.fromkeys(PEN_PARAMETERS, Level.SAFE)
        levels.update(self.warnings)
        levels.update(self.latched)
        mode = self.mode
        button = "estop" if mode == SafetyMode.ESTOP else (self._button if now < self._button_until else "none")
        return PendantState(button, mode == SafetyMode.ACTIVE, mode == SafetyMode.IDLE, 0, levels)

    def get(self, prop: int, now: float) -> int | None:
        """A property's value as the module answers a get (PEN computed now); None: no such property."""
        if prop == SafetyProp.PEN:
            return encode_pen(self.pendant_state(now))
        return self.props.get(int(prop))

    # ------------------------------------------------------------------ host
    def set(self, prop: int, value: int, now: float) -> str | None:
        """A set from the host."""
        prop = int(prop)
        if prop == SafetyProp.MODE:
            if value == SafetyMode.ESTOP:
                return self.press("estop", now, lambda: True)
            if value == SafetyMode.IDLE and self.mode == SafetyMode.ACTIVE:
                self._set_mode(SafetyMode.IDLE, now, "set to idle by the host")
                return "idle"
            self.refused_requests += 1
            self.log.append((now, f"ignored the host's request for MODE {value}"))
            return None
        if prop == SafetyProp.DEF:
            if value in self.eeprom:
                self.props[value] = DEFAULT_LIMITS[SafetyProp(value).name]
        elif prop == SafetyProp.LOAD:
            if value in self.eeprom:
                self.props[value] = self.eeprom[value]
        elif prop == SafetyProp.SAVE:
            if value in self.eeprom:
                self.eeprom[value] = self.props[value]
        elif prop in (SafetyProp.VERS, SafetyProp.ROLE, SafetyProp.ID, SafetyProp.PEN):
            return None
        else:
            self.props[prop] = int(value)
            if prop == SafetyProp.ZERO:
                self.log.append((now, f"ZERO={value}"))
        return None

    # ------------------------------------------------------------------ pendant
    def press(self, button: str, now: float, pucks_ready) -> str | None:
        """The operator presses ``activate`` (Shift-Activate), ``idle`` (Shift-Idle) or ``estop``;
        ``pucks_ready()`` says whether every motor puck is awake (activation needs them)."""
        self._button, self._button_until = button, now + BUTTON_SHOWN_S
        mode = self.mode
        if button == "estop":
            self.latched["other"] = Level.FAULT
            if mode != SafetyMode.ESTOP:
                self._set_mode(SafetyMode.ESTOP, now, "E-stop pressed")
                self.props[SafetyProp.ZERO] = 0
                return "power_off"
            return None
        if button == "idle":
            self.latched.clear()
            self._velocity_idle_t = None
            if mode == SafetyMode.ESTOP:
                self._set_mode(SafetyMode.IDLE, now, "E-stop released, Shift-Idle")
                return "power_on"
            if mode == SafetyMode.ACTIVE:
                self._set_mode(SafetyMode.IDLE, now, "Shift-Idle")
                return "idle"
            return None
        if button == "activate":
            if mode != SafetyMode.IDLE:
                self.log.append((now, f"Shift-Activate ignored: the module is {mode.words}, not idle"))
            elif self.latched:
                self.log.append((now, f"Shift-Activate refused: {', '.join(self.latched)} fault (Shift-Idle first)"))
            elif not pucks_ready():
                self.log.append((now, "Shift-Activate refused: motor pucks not awake"))
            else:
                self._set_mode(SafetyMode.ACTIVE, now, "Shift-Activate")
                self._samples.clear()
                return "torque"
            return None
        raise ValueError(f"unknown pendant button {button!r}")

    # ------------------------------------------------------------------ watching the bus
    def _fault(self, param: str, now: float, detail: str) -> str | None:
        self.latched[param] = Level.FAULT
        self.log.append((now, f"{param} fault: {detail}"))
        logger.info("simulated safety module: %s fault (%s)", param, detail)
        if self.mode == SafetyMode.ACTIVE:
            self._set_mode(SafetyMode.IDLE, now, f"{param} fault")
            if param == "velocity":
                self._velocity_idle_t = now
            return "idle"
        return None

    def inject_fault(self, param: str, now: float) -> str | None:
        """A fault of ``param`` as if the module had measured one (tests and demos)."""
        if param not in PEN_PARAMETERS:
            raise ValueError(f"unknown safety parameter {param!r}")
        return self._fault(param, now, "injected")

    def position_sample(self, q_rad: np.ndarray, now: float) -> str | None:
        """The module heard the position replies of one request (joint angles from the reported counts); the
        speed is watched while active."""
        self._last_reply_t = now
        if self.mode != SafetyMode.ACTIVE and self._velocity_idle_t is None:
            return None
        while self._samples and now - self._samples[0][0] > STALE_SAMPLE_S:
            self._samples.popleft()
        elbow, end = elbow_and_end_point_m(q_rad)
        self._samples.append((now, elbow, end))
        t0, e0, p0 = self._samples[0]
        if len(self._samples) < 2 or now - t0 < 1e-3:
            return None
        speed = max(np.linalg.norm(elbow - e0), np.linalg.norm(end - p0)) / (now - t0)
        self.last_speed_m_s = float(speed)
        if self.mode != SafetyMode.ACTIVE:  # after a velocity fault: watched for the E-stop that may follow
            return None
        vl1, vl2 = self.props[SafetyProp.VL1], self.props[SafetyProp.VL2]
        if vl2 > 0 and speed > velocity_limit_m_s(vl2):
            if self.props[SafetyProp.IFAULT] > 0:
                self.props[SafetyProp.IFAULT] -= 1
                self.ignored_velocity_faults += 1
                return None
            return self._fault("velocity", now, f"{speed:.2f} m/s above VL2 = {velocity_limit_m_s(vl2):.2f} m/s")
        if vl1 > 0 and speed > velocity_limit_m_s(vl1):
            self.warnings["velocity"] = Level.WARNING
        else:
            self.warnings.pop("velocity", None)
        return None

    def torques(self, puck_units: np.ndarray, now: float) -> str | None:
        """The module heard a packed-torque frame."""
        if self.mode != SafetyMode.ACTIVE or not len(puck_units):
            return None
        peak = int(np.abs(puck_units).max())
        if peak > self.props[SafetyProp.TL2]:
            return self._fault("torque", now, f"{peak} puck units above TL2 = {self.props[SafetyProp.TL2]}")
        if peak > self.props[SafetyProp.TL1]:
            self.warnings["torque"] = Level.WARNING
        else:
            self.warnings.pop("torque", None)
        return None

    def tick(self, now: float) -> str | None:
        """Time passes: the heartbeat while active, the E-stop after a velocity fault that does not end."""
        if self.mode == SafetyMode.ACTIVE:
            last = max(self._last_reply_t or -np.inf, self._active_since or -np.inf)
            if now - last > self.heartbeat_timeout_s:
                return self._fault("heartbeat", now, f"no position reply for {now - last:.2f} s")
        if self._velocity_idle_t is not None and now - self._velocity_idle_t >= ESTOP_AFTER_VELOCITY_FAULT_S:
            self._velocity_idle_t = None
            if self.last_speed_m_s > velocity_limit_m_s(self.props[SafetyProp.VL2]) > 0:
                return self.press("estop", now, lambda: True)
        return None

    def puck_mode(self) -> int:
        """The MODE the module holds the motor pucks in."""
        return int(Mode.TORQUE) if self.mode == SafetyMode.ACTIVE else int(Mode.IDLE)

    def describe(self) -> dict:
        return {"mode": self.mode.words, "zero": self.props[SafetyProp.ZERO],
                "limits": {k: self.props[SafetyProp[k]] for k in ("VL1", "VL2", "TL1", "TL2")},
                "faults": sorted(self.latched), "refused_host_requests": self.refused_requests,
                "ignored_velocity_faults": self.ignored_velocity_faults,
                "log": [msg for _, msg in self.log[-50:]]}
