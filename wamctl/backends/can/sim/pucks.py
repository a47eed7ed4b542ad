"""Simulated WAM motor pucks: their properties, groups, power and wake-up, encoders and held torque; the plant
interface they read positions from and hand torques to.

A puck powers up in the monitor (STAT 0, the bootloader: it answers VERS, ROLE, SN, ID, ERROR and STAT only)
with its position counter at an arbitrary value (the simulation draws one), until the host sets P (the
zeroing). A set of STAT=READY wakes it: its transceiver goes off the bus and comes back ``wake_s`` later
(libbarrett waits 1 s); in between (the *wake window*) it hears nothing, and a frame on the bus while its
transceiver goes off (the first 10 ms) or comes back puts the host bus-off (libbarrett ``Puck::wake``).
It listens to the groups in GRPA/GRPB/GRPC (factory 0/1/4 for pucks 1-4, 0/2/4 for 5-7) and takes its
packed torque from slot PIDX; its MODE is what the safety module broadcasts (a host may only set IDLE).
"""

from __future__ import annotations

import dataclasses
import threading
from typing import Protocol, runtime_checkable

import numpy as np

from wamctl.backends.can.protocol.addressing import N_JOINTS
from wamctl.backends.can.protocol.configuration import FACTORY_GROUPS, FACTORY_POLES, groups_of
from wamctl.backends.can.protocol.properties import ROLE_OPTICAL_ENC_ON_ENC, ROLE_TATER, Mode, Prop, Status

__all__ = ["JOINT_ENCODER_COUNTS", "MotorPuck", "PlantAdapter", "SIM_FIRMWARE_VERSION", "StaticPlant",
           "TURN_OFF_S", "motor_puck"]

# Firmware version the simulated pucks report: at or above the newest property table in libbarrett (motor pucks
# VERS >= 175), so every id in properties.Prop applies.
SIM_FIRMWARE_VERSION = 200
TURN_OFF_S = 0.01  # a waking puck's transceiver goes off the bus within this (libbarrett TURN_OFF_TIME)
# Joint encoder counts per joint revolution (libbarrett config/wam7w.conf joint_encoder_counts; 0: none).
JOINT_ENCODER_COUNTS = (1578399, 655360, 655360, 327680, 0, 0, 0)


@runtime_checkable
class PlantAdapter(Protocol):
    """What the simulated pucks need from the simulated arm (both called from the simulator's thread)."""

    def joint_positions_rad(self) -> np.ndarray:
        """Return the current joint angles, shape (7,), rad. Called once per position request."""
        ...

    def apply_joint_torques_Nm(self, tau: np.ndarray) -> None:
        """Receive the joint torques (7,), N m, that the pucks now apply (held until the next call)."""
        ...


class StaticPlant:
    """A plant that does not move (unless placed): fixed joint angles, records the torques it receives.

    Parameters
    ----------
    q_rad : array_like, shape (n,), optional
        Joint angles reported to the pucks (n the arm's joints: 4 for a wam4); default seven zeros. May be
        reassigned (or :meth:`place`) at any time.
    """

    def __init__(self, q_rad: np.ndarray | None = None) -> None:
        self.q_rad = np.zeros(N_JOINTS) if q_rad is None else np.asarray(q_rad, dtype=float).copy()
        self.tau_Nm = np.zeros(len(self.q_rad))
        self.n_position_reads = 0
        self.n_torque_updates = 0
        self._lock = threading.Lock()

    def joint_positions_rad(self) -> np.ndarray:
        """Return the fixed joint angles (rad)."""
        with self._lock:
            self.n_position_reads += 1
            return np.array(self.q_rad, dtype=float)

    def apply_joint_torques_Nm(self, tau: np.ndarray) -> None:
        """Record the applied joint torques (N m)."""
        with self._lock:
            self.tau_Nm = np.array(tau, dtype=float)
            self.n_torque_updates += 1

    def place(self, q_rad) -> None:
        """Put the arm at ``q_rad`` (an operator moving the idle arm by hand)."""
        with self._lock:
            self.q_rad = np.asarray(q_rad, dtype=float).copy()


@dataclasses.dataclass
class MotorPuck:
    """One simulated motor puck (state only; the simulator's thread changes it under its lock)."""

    puck_id: int
    props: dict[int, int]
    powered: bool = True
    wake_set_t: float | None = None  # wall time of the STAT=READY set that woke it (None: not waking)
    wake_at: float | None = None  # wall time it is READY (None: in the monitor)
    offset_counts: int = 0  # reported P = true counts + offset (set P redefines it)
    torque_units: int = 0  # held torque command
    joint_encoder_counts: int = 0  # per joint revolution; 0 = no joint encoder (3-byte position replies)

    def listens_to(self, group: int) -> bool:
        """Whether the puck is in broadcast group ``group`` (0..31)."""
        return group in groups_of((self.props[Prop.GRPA], self.props[Prop.GRPB], self.props[Prop.GRPC]))

    def awake(self, now_wall: float) -> bool:
        """READY (main firmware running); a puck whose wake-up time has come becomes READY here."""
        if not self.powered or self.wake_at is None or now_wall < self.wake_at:
            return False
        if self.props[Prop.STAT] != Status.READY:
            self.props[Prop.STAT] = int(Status.READY)
            self.wake_set_t = None
        return True

    def in_wake_window(self, t_wall: float) -> str | None:
        """``"turning off"`` or ``"coming back"`` when ``t_wall`` falls inside this puck's wake window."""
        if self.wake_set_t is None or self.wake_at is None or not self.wake_set_t <= t_wall < self.wake_at:
            return None
        return "turning off" if t_wall < self.wake_set_t + TURN_OFF_S else "coming back"

    def power_off(self) -> None:
        self.powered = False
        self.wake_set_t = self.wake_at = None
        self.torque_units = 0
        self.props[Prop.STAT] = int(Status.RESET)
        self.props[Prop.MODE] = int(Mode.IDLE)
        self.props[Prop.T] = 0

    def power_on(self, offset_counts: int) -> None:
        """Power-up: the monitor, a new position counter."""
        self.powered = True
        self.offset_counts = int(offset_counts)
        self.props[Prop.STAT] = int(Status.RESET)


def motor_puck(puck_id: int, *, vers: int, cts: int, ipnm: int, pidx: int, awake: bool, offset_counts: int,
               groups: tuple[int, int, int] | None = None, poles: int | None = None,
               joint_encoder_counts: int = 0) -> MotorPuck:
    """A motor puck as Barrett configures it (factory groups and POLES unless given)."""
    groups = FACTORY_GROUPS[puck_id] if groups is None else groups
    role = ROLE_TATER | (ROLE_OPTICAL_ENC_ON_ENC if joint_encoder_counts else 0)
    props = {Prop.VERS: vers, Prop.ROLE: role, Prop.SN: 1000 + puck_id, Prop.ID: puck_id, Prop.ERROR: 0,
             Prop.STAT: Status.READY if awake else Status.RESET, Prop.MODE: Mode.IDLE, Prop.CTS: cts,
             Prop.IPNM: ipnm, Prop.PIDX: pidx, Prop.T: 0, Prop.GRPA: groups[0], Prop.GRPB: groups[1],
             Prop.GRPC: groups[2], Prop.POLES: FACTORY_POLES[puck_id] if poles is None else poles,
             Prop.P: 0}
    return MotorPuck(puck_id, {int(k): int(v) for k, v in props.items()}, wake_at=0.0 if awake else None,
                     offset_counts=offset_counts, joint_encoder_counts=joint_encoder_counts)
