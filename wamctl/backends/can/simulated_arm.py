"""The simulated arm behind the simulated pucks, and the faults they can be made to show.

Simulated pucks (``backend: {kind: can, simulate_pucks: true}``, virtual bus only): a
:class:`~wamctl.backends.can.puck_sim.PuckSimulator` answers on the same in-process channel, its plant a
:class:`~wamctl.backends.sim.SimBackend` of the spec's plant wrapped in :class:`SimulatedArm`. The CAN
frames are the only coupling: the physics runs on the simulator's thread, one control period per position
request while any puck is in TORQUE mode (the arm is held at rest while the pucks are idle, as an operator
holds the WAM while activating it). The simulated arm therefore advances at the loop's real-time rate,
and a run over the virtual bus reproduces the direct simulation up to the protocol's quantisation.

Fault injection for tests and demos (``backend.simulated_fault``, simulated pucks only): the fault starts
at a given control cycle (dropped replies, a silent puck, garbled replies, garbage frames, pucks that stop
answering, or host transmit errors); :func:`inject_fault` starts it.
"""

from __future__ import annotations

import threading
from pathlib import Path

import numpy as np

from wamctl.backends.base import SafetyLimits
from wamctl.backends.can.protocol.properties import Mode
from wamctl.model import params as P

__all__ = ["SIM_CTS_IDEAL_SENSOR", "SimulatedArm", "build_simulated_arm", "inject_fault", "open_limits"]

SIM_CTS_IDEAL_SENSOR = 40960  # simulated pucks' CTS when the plant's sensor is ideal (magnetic encoders)


class SimulatedArm:
    """A :class:`~wamctl.backends.can.puck_sim.PlantAdapter` over a :class:`~wamctl.backends.sim.SimBackend`.

    Runs on the puck simulator's thread only. Each position request (but the very first) made while a
    puck is in TORQUE mode advances the physics by one control period under the torques the pucks hold
    (zero-order hold, like the direct simulation), then returns the encoders' reading. While the pucks
    are idle the arm is held at rest. With the host switching to TORQUE mode at its first torque command
    (cycle 0), the arm's cycle count matches the host's.

    Parameters
    ----------
    sim : SimBackend
        The arm (opened here); build it with open safety limits: the host's backend enforces the real ones.

    Attributes
    ----------
    cycle : int
        Control periods simulated: the index of the current cycle.
    zero_torque_since_cycle : numpy.ndarray, shape (7,)
        Per joint, the cycle since which the applied torque has been exactly zero (-1: since before the
        loop; NaN: not zero now).
    """

    def __init__(self, sim) -> None:
        self.sim = sim
        sim.open()
        self._lock = threading.Lock()
        self._tau_Nm = np.zeros(P.N_JOINTS)
        self._requested = False
        self._simulator = None
        self.cycle = 0
        self.zero_torque_since_cycle = np.full(P.N_JOINTS, -1.0)

    def attach(self, simulator) -> None:
        """The :class:`PuckSimulator` whose pucks' MODE gates the physics."""
        self._simulator = simulator

    def _torque_mode(self) -> bool:
        if self._simulator is None:
            return True
        return any(m == Mode.TORQUE for m in self._simulator.modes().values())

    def joint_positions_rad(self) -> np.ndarray:
        """Advance one control period if a puck is in TORQUE mode; the encoders' reading."""
        torque_mode = self._torque_mode()
        with self._lock:
            if torque_mode and self._requested:
                self.sim.command_torques(self._tau_Nm)
                self.sim.wait_next_cycle()
                self.cycle += 1
            self._requested = True
            return self.sim.read_positions().copy()

    def apply_joint_torques_Nm(self, tau: np.ndarray) -> None:
        """Hold the joint torques the pucks now apply, until the next step."""
        with self._lock:
            tau = np.asarray(tau, float)
            zero = tau == 0.0
            since = self.zero_torque_since_cycle
            since[~zero] = np.nan
            since[zero & np.isnan(since)] = self.cycle
            self._tau_Nm[:] = tau

    def truth(self) -> tuple[np.ndarray, np.ndarray]:
        """Copies of the true position and velocity (for tests)."""
        with self._lock:
            q, qd = self.sim.truth()
            return q.copy(), qd.copy()

    def describe(self) -> dict:
        with self._lock:
            return {"cycles_simulated": self.cycle, **self.sim.describe(),
                    "zero_torque_since_cycle": [None if np.isnan(c) else int(c)
                                                for c in self.zero_torque_since_cycle]}


def open_limits() -> SafetyLimits:
    inf = np.full(P.N_JOINTS, np.inf)
    return SafetyLimits(tau_max_Nm=inf.copy(), q_min_rad=-inf, q_max_rad=inf.copy(), qd_max_rad_s=inf.copy())



def build_simulated_arm(plant_spec, base_dir: Path | None, q0_rad, rng: np.random.Generator,
                        physics_substeps: int) -> tuple[SimulatedArm, int]:
    """The simulated arm a spec's plant describes, at rest at ``q0_rad``, and the CTS its pucks report.

    Parameters
    ----------
    plant_spec : wamctl.specs.PlantSpec
        Friction, effects and sensors of the simulated arm.
    base_dir : Path or None
        Directory relative paths in the plant spec are resolved against.
    q0_rad : array_like, shape (7,)
        Start configuration.
    rng : numpy.random.Generator
        The arm's random draws.
    physics_substeps : int
        Physics steps per control period.

    Returns
    -------
    tuple of (SimulatedArm, int)
        The arm (open, safety limits open: the host's backend enforces the real ones) and the pucks' CTS
        (the plant's encoder resolution, :data:`SIM_CTS_IDEAL_SENSOR` for an ideal sensor).
    """
    from wamctl.backends.sim import SimBackend
    from wamctl.model.plant import Plant

    plant = Plant(plant_spec, base_dir)
    arm = SimulatedArm(SimBackend(plant, q0_rad, rng, physics_substeps, limits=open_limits()))
    return arm, plant.sensors.encoder_counts_per_rev or SIM_CTS_IDEAL_SENSOR


def inject_fault(simulator, fault) -> int:
    """Start a simulated fault on the simulated pucks.

    Parameters
    ----------
    simulator : PuckSimulator
        The pucks.
    fault : wamctl.specs.SimulatedFault
        What goes wrong.

    Returns
    -------
    int
        How many of the host's next transmits must fail (``bus_error``: the host's side of the link); 0 for
        the faults the pucks show.
    """
    if fault.kind == "drop_replies":
        simulator.drop_replies(fault.probability)
    elif fault.kind == "silent_puck":
        simulator.set_silent(fault.puck)
    elif fault.kind == "garbage_replies":
        simulator.inject_garbage(fault.probability)
    elif fault.kind == "garbage_frames":
        simulator.send_garbage(fault.count)
    elif fault.kind == "stop_answering":
        simulator.stop_answering()
    elif fault.kind == "bus_error":
        return fault.count
    else:  # pragma: no cover - the spec's Literal lists every kind
        raise ValueError(f"unknown simulated fault {fault.kind!r}")
    return 0
