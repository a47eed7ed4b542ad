"""The safety module (node 10): its property ids, modes, pendant state, limits and broadcast.

The WAM's safety module watches the arm (velocity at the elbow and the 4-DOF end point, torque commands, the
position traffic as heartbeat, voltages, the pendants' buttons) and alone puts the motor pucks into TORQUE mode
(on Shift-Activate) and back to IDLE (on Shift-Idle or a fault). The host only reads its MODE, sets its
limits, and records the zeroing (ZERO, IFAULT). Sources: libbarrett ``include/barrett/products/
safety_module.h``, ``src/products/safety_module.cpp``, ``src/products/property_list.cpp`` (safety table for
VERS >= 61), ``src/products/bus/bus_manager.cpp`` (the 0x540 broadcast it discards); Barrett's support wiki
"WAM/SafetyFeaturesPrecautions" (limit units and defaults).
"""

from __future__ import annotations

import dataclasses
import enum

import can

from wamctl.backends.can.protocol.addressing import (
    GROUP_WHOLE_BUS,
    SAFETY_PUCK_ID,
    PuckFrameError,
    data_frame,
    encode_bus_id,
)
from wamctl.backends.can.protocol.properties import SET_MASK, Prop
from wamctl.errors import ConfigurationRefused

__all__ = [
    "DEFAULT_LIMITS",
    "IGNORE_VELOCITY_FAULTS",
    "PendantState",
    "SAFETY_BROADCAST_ID",
    "SAFETY_MIN_FIRMWARE_VERSION",
    "SafetyMode",
    "SafetyProp",
    "Level",
    "check_safety_firmware",
    "decode_pen",
    "encode_pen",
    "make_safety_broadcast",
    "torque_limit_Nm",
    "torque_limit_units",
    "velocity_limit_m_s",
    "velocity_limit_units",
]

SAFETY_MIN_FIRMWARE_VERSION = 61  # below, the module shares the old combined property list (ZERO 55, ...)


class SafetyProp(enum.IntEnum):
    """Property ids of the safety module with firmware VERS >= 61 (libbarrett ``property_list.cpp``)."""

    VERS = 0
    ROLE = 1  # low five bits 2 (ROLE_SAFETY)
    SN = 2
    ID = 3
    ERROR = 4
    STAT = 5
    MODE = 8  # :class:`SafetyMode`
    GRPA = 26
    GRPB = 27
    GRPC = 28
    SAVE = 30
    LOAD = 31  # SET LOAD=id reloads property id from EEPROM
    DEF = 32  # SET DEF=id loads property id's factory default
    ZERO = 42  # 1 once the host has defined the positions at the home pose (libbarrett wamIsZeroed)
    PEN = 43  # pendant state, :func:`decode_pen`
    SAFE = 44
    VL1 = 45  # velocity warning, m/s in Q4.12 (0x1000 = 1 m/s), at the elbow and the 4-DOF end point
    VL2 = 46  # velocity fault
    TL1 = 47  # torque warning, puck units of any motor
    TL2 = 48  # torque fault
    IFAULT = 55  # ignore the next n velocity faults


class SafetyMode(enum.IntEnum):
    """MODE of the safety module (libbarrett ``SafetyModule::SafetyMode``)."""

    ESTOP = 0
    IDLE = 1
    ACTIVE = 2

    @property
    def words(self) -> str:
        """libbarrett's names: E-stop, Shift-idle, Shift-activate."""
        return {0: "E-stop", 1: "Shift-idle", 2: "Shift-activate"}[int(self)]


def check_safety_firmware(vers: int) -> None:
    """Refuse a safety module whose firmware uses the old property list (ZERO, PEN, VL*, TL*, IFAULT move)."""
    if vers < SAFETY_MIN_FIRMWARE_VERSION:
        raise ConfigurationRefused(
            f"safety module: firmware VERS={vers} is older than {SAFETY_MIN_FIRMWARE_VERSION}: its "
            "ZERO, PEN, VL1/VL2, TL1/TL2 and IFAULT have other ids (libbarrett property_list.cpp, "
            "e.g. ZERO 55, IFAULT 100 instead of 42, 55); update the safety module firmware")


# IFAULT written before and after zeroing (libbarrett VELOCITY_FAULT_HISTORY_BUFFER_SIZE): "ignore the next
# velocity fault (the position will appear to change rapidly)".
IGNORE_VELOCITY_FAULTS = 5

# The limits a safety module loads at power-up (Barrett's wiki, "Setting Safety Limits"): velocity warning
# 0.5 m/s, fault 1.0 m/s (Q4.12), torque warning 4731 and fault 5204 puck units. libbarrett reloads them from
# EEPROM at start-up (SET DEF, SET LOAD); a spec may set lower ones.
DEFAULT_LIMITS: dict[str, int] = {"VL1": 2048, "VL2": 4096, "TL1": 4731, "TL2": 5204}
VELOCITY_Q = 0x1000  # Q4.12: units per m/s
WARNING_FRACTION = 0.9  # libbarrett setVelocityLimit / setTorqueLimit: warning = 0.9 fault


def velocity_limit_units(v_m_s: float) -> int:
    """VL1/VL2 value for a speed in m/s (libbarrett ``setVelocityLimit``: ``(int)(v * 0x1000)``)."""
    if v_m_s < 0:
        raise ValueError(f"velocity limit must be >= 0 m/s (0 = never fault), got {v_m_s}")
    return int(v_m_s * VELOCITY_Q)


def velocity_limit_m_s(units: int) -> float:
    """Speed in m/s of a VL1/VL2 value."""
    return units / VELOCITY_Q


def torque_limit_units(tau_m_Nm: float, ipnm: float) -> int:
    """TL1/TL2 value for a motor torque (libbarrett ``setTorqueLimit``: ``(int)(tau * ipnm)``)."""
    if tau_m_Nm <= 0:
        raise ValueError(f"torque limit must be > 0 N m, got {tau_m_Nm}")
    return int(tau_m_Nm * ipnm)


def torque_limit_Nm(units: int, ipnm: float) -> float:
    """Motor torque in N m of a TL1/TL2 value at a puck's IPNM."""
    return units / ipnm


# --------------------------------------------------------------------------------------------------- pendant

class Level(enum.IntEnum):
    """State of one safety parameter on the pendant (one-hot in PEN: bit 0 safe, 1 warning, 2 fault)."""

    SAFE = 0
    WARNING = 1
    FAULT = 2


PEN_PARAMETERS = ("velocity", "torque", "voltage", "heartbeat", "other")  # bits 3i..3i+2, i = 0..4
PEN_BUTTONS = {0b11: "none", 0b10: "idle", 0b01: "activate", 0b00: "estop"}  # bits 27, 26


@dataclasses.dataclass(frozen=True)
class PendantState:
    """The pendant as the safety module reports it in PEN (libbarrett ``SafetyModule::PendantState``).

    Attributes
    ----------
    button : str
        Button pressed: ``none``, ``idle`` (Shift-Idle), ``activate`` (Shift-Activate) or ``estop`` (latched).
    activate_light, idle_light : bool
    display : int
        Raw 7-segment bits (their meaning is not documented).
    levels : dict of str to Level
        Per parameter (velocity, torque, voltage, heartbeat, other; "other" shows an E-stop).
    """

    button: str = "none"
    activate_light: bool = False
    idle_light: bool = True
    display: int = 0
    levels: dict = dataclasses.field(default_factory=lambda: dict.fromkeys(PEN_PARAMETERS, Level.SAFE))

    def faults(self) -> list[str]:
        """Parameters at FAULT."""
        return [p for p in PEN_PARAMETERS if self.levels.get(p) == Level.FAULT]

    def warnings(self) -> list[str]:
        """Parameters at WARNING."""
        return [p for p in PEN_PARAMETERS if self.levels.get(p) == Level.WARNING]

    def summary(self) -> str:
        """libbarrett's one-line form, in words: button, lights, parameters."""
        lv = " ".join(f"{p} {self.levels[p].name.lower()}" for p in PEN_PARAMETERS)
        lights = ", ".join(n for n, on in (("activate", self.activate_light), ("idle", self.idle_light)) if on)
        return f"button {self.button}; lights: {lights or 'none'}; {lv}"


def decode_pen(value: int) -> PendantState:
    """Decode a PEN value (libbarrett ``SafetyModule::getPendantState``).

    Raises
    ------
    PuckFrameError
        If a parameter's three bits are not one-hot ("Bad PEN value").
    """
    value = int(value) & 0xFFFFFFFF
    button = PEN_BUTTONS[(value >> 26) & 0b11]
    levels = {}
    for i, name in enumerate(PEN_PARAMETERS):
        bits = (value >> (3 * i)) & 0b111
        if bits not in (1, 2, 4):
            raise PuckFrameError(f"safety module: bad PEN value {value:#010x} for the {name} parameter")
        levels[name] = Level(bits.bit_length() - 1)
    return PendantState(button, bool(value >> 25 & 1), bool(value >> 24 & 1), (value >> 16) & 0xFF, levels)


def encode_pen(state: PendantState) -> int:
    """The PEN value of a pendant state (what the simulated safety module reports)."""
    button = {v: k for k, v in PEN_BUTTONS.items()}[state.button]
    value = button << 26 | int(state.activate_light) << 25 | int(state.idle_light) << 24 | (state.display & 0xFF) << 16
    for i, name in enumerate(PEN_PARAMETERS):
        value |= (1 << int(state.levels.get(name, Level.SAFE))) << (3 * i)
    return value


# ------------------------------------------------------------------------------------------------ broadcast

# The safety module's frames to group 0 (id 0x540): libbarrett discards them ("disregard safetyboard broadcast
# message", bus_manager.cpp). Their content is not documented; the simulated module uses them to put the pucks
# into TORQUE or IDLE (a set of MODE), which is one reading of how the real one does it.
SAFETY_BROADCAST_ID = encode_bus_id(SAFETY_PUCK_ID, GROUP_WHOLE_BUS)


def make_safety_broadcast(puck_mode: int) -> can.Message:
    """The simulated safety module's broadcast putting every motor puck into ``puck_mode``."""
    payload = bytes([Prop.MODE | SET_MASK, 0]) + int(puck_mode).to_bytes(4, "little", signed=True)
    return data_frame(SAFETY_BROADCAST_ID, payload)
