"""The simulated arm behind the simulated pucks, and the faults they can be made to show.

Simulated pucks (``backend: {kind: can, simulate_pucks: true}``, virtual bus only, or ``wamctl sim-arm`` in
its own process): a :class:`~wamctl.backends.can.sim.simulator.PuckSimulator` answers on the bus, its plant a
:class:`~wamctl.backends.sim.SimBackend` of the spec's plant and robot (the wam7, or the wam4: four pucks, its
own dynamics) wrapped in :class:`SimulatedArm`. The CAN
frames are the only coupling: the physics runs on the simulator's thread, one control period per position
request once the pucks apply torque. The arm is held at rest while no puck is in TORQUE mode (idle pucks
brake) and, after Shift-Activate, until the first non-zero torque command arrives: an operator holds the WAM
while activating it, until the controller takes it. The simulated arm therefore advances at the loop's
real-time rate, and a run over the bus reproduces the direct simulation up to the protocol's quantisation.

Fault injection for tests and demos (``backend.simulated_fault``, simulated pucks only): the fault starts
at a given control cycle (dropped replies, a silent puck, garbled replies, garbage frames, pucks that stop
answering, host transmit errors, or the pendant: Shift-Idle, E-stop, a velocity fault of the safety
module); :func:`inject_fault` starts it.
"""

from __future__ import annotations

import threading
from pathlib import Path

import numpy as np

from wamctl.backends.base import SafetyLimits
from wamctl.backends.can.protocol.properties import Mode

__all__ = ["SIM_CTS_IDEAL_SENSOR", "SimulatedArm", "build_simulated_arm", "inject_fault", "open_limits"]

SIM_CTS_IDEAL_SENSOR = 40960  # simulated pucks' CTS when the plant's sensor is ideal (magnetic encoders)


class SimulatedArm:
    """A :class:`~wamctl.backends.can.puck_sim.PlantAdapter` over a :class:`~wamctl.backends.sim.SimBackend`.

    Runs on the puck simulator's thread only. Once released (the first non-zero torque while a puck is in
    TORQUE mode), each position request made while a puck is in TORQUE mode advances the physics by one control
    period under the torques the pucks hold (zero-order hold, like the direct simulation), then returns the
    encoders' reading; otherwise the arm is held at rest. The host's first command (cycle 0) releases it, so
    the arm's cycle count matches the host's.

    Parameters
    ----------
    sim : SimBackend
        The arm (opened here); build it with open safety limits: the host's backend enforces the real ones.
    rebuild : callable, optional
        ``rebuild(q_rad) -> SimBackend`` at rest at ``q_rad``: lets :meth:`place` move the held arm.

    Attributes
    ----------
    cycle : int
        Control periods simulated: the index of the current cycle.
    zero_torque_since_cycle : numpy.ndarray, shape (n,)
        Per joint, the cycle since which the applied torque has been exactly zero (-1: since before the
        loop; NaN: not zero now).
    """

    def __init__(self, sim, rebuild=None) -> None:
        self.sim = sim
        sim.open()
        self._rebuild = rebuild
        self._lock = threading.Lock()
        self.n_joints = int(sim.n_joints)
        self._tau_Nm = np.zeros(self.n_joints)
        self._released = False
        self._simulator = None
        self.cycle = 0
        self.zero_torque_since_cycle = np.full(self.n_joints, -1.0)

    def attach(self, simulator) -> None:
        """The :class:`PuckSimulator` whose pucks' MODE gates the physics."""
        self._simulator = simulator

    def _torque_mode(self) -> bool:
        if self._simulator is None:
            return True
        return any(m == Mode.TORQUE for m in self._simulator.modes().values())

    def joint_positions_rad(self) -> np.ndarray:
        """Advance one control period if released and a puck is in TORQUE mode; the encoders' reading."""
        torque_mode = self._torque_mode()
        with self._lock:
            if torque_mode and self._released:
                self.sim.command_torques(self._tau_Nm)
                self.sim.wait_next_cycle()
                self.cycle += 1
            return self.sim.read_positions().copy()

    def apply_joint_torques_Nm(self, tau: np.ndarray) -> None:
        """Hold the joint torques the pucks now apply, until the next step."""
        torque_mode = self._torque_mode()
        with self._lock:
            tau = np.asarray(tau, float)
            zero = tau == 0.0
            if torque_mode and not zero.all():
                self._released = True
            since = self.zero_torque_since_cycle
            since[~zero] = np.nan
            since[zero & np.isnan(since)] = self.cycle
            self._tau_Nm[:] = tau

    def place(self, q_rad) -> None:
        """An operator moves the held arm to ``q_rad`` (ignored once the controller has it)."""
        with self._lock:
            if self._released or self._rebuild is None:
                return
            self.sim = self._rebuild(np.asarray(q_rad, float))
            self.sim.open()

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


def open_limits(n_joints: int = 7) -> SafetyLimits:
    inf = np.full(n_joints, np.inf)
    return SafetyLimits(tau_max_Nm=inf.copy(), q_min_rad=-inf, q_max_rad=inf.copy(), qd_max_rad_s=inf.copy())



def build_simulated_arm(plant_spec, base_dir: Path | None, q0_rad, rng: np.random.Generator,
                        physics_substeps: int, robot=None) -> tuple[SimulatedArm, int]:
    """The simulated arm a spec's plant describes, at rest at ``q0_rad``, and the CTS its pucks report.

    Parameters
    ----------
    plant_spec : wamctl.specs.PlantSpec
        Friction, effects and sensors of the simulated arm.
    base_dir : Path or None
        Directory relative paths in the plant spec are resolved against.
    q0_rad : array_like, shape (n,)
        Start configuration.
    rng : numpy.random.Generator
        The arm's random draws.
    physics_substeps : int
        Physics steps per control period.
    robot : str or Robot, optional
        The arm (default the wam7): its joints, dynamics and transmission.

    Returns
    -------
    tuple of (SimulatedArm, int)
        The arm (open, safety limits open: the host's backend enforces the real ones) and the pucks' CTS
        (the plant's encoder resolution, :data:`SIM_CTS_IDEAL_SENSOR` for an ideal sensor).
    """
    from wamctl.backends.sim import SimBackend
    from wamctl.model.plant import Plant

    plant = Plant(plant_spec, base_dir, robot)
    n = plant.n_joints
    # one physics step of a throwaway copy now (its own plant: effects keep state), not at the run's first cycle
    warm = SimBackend(Plant(plant_spec, base_dir, robot), q0_rad, np.random.default_rng(0), physics_substeps,
                      limits=open_limits(n))
    warm.open()
    warm.command_torques(np.zeros(n))
    warm.wait_next_cycle()

    def rebuild(q_rad):
        return SimBackend(plant, q_rad, rng, physics_substeps, limits=open_limits(n))

    arm = SimulatedArm(rebuild(q0_rad), rebuild)
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
    elif fault.kind in ("shift_idle", "estop"):
        simulator.press({"shift_idle": "idle", "estop": "estop"}[fault.kind])
    elif fault.kind == "velocity_fault":
        simulator.safety_fault("velocity")
    else:  # pragma: no cover - the spec's Literal lists every kind
        raise ValueError(f"unknown simulated fault {fault.kind!r}")
    return 0
