"""The simulated WAM: the embedded default backend.

Integration scheme (documented choice)
--------------------------------------
The torque is held constant over each 2 ms control period (zero-order hold). The physics advances in
``substeps`` equal steps ``h`` per period with semi-implicit (symplectic) Euler on the rigid body,
``qd_free = qd + h B(q0)^-1 (tau + ripple(q) - C(q, qd) qd - g(q))``: the Coriolis, centrifugal and gravity
terms are evaluated at every step, the inverse inertia ``B^-1`` once per control period (it changes by
~1e-4 relative over 2 ms at the arm's speeds; this is half the cost of an ABA per step). Friction is then
applied implicitly at velocity level
(:func:`wamctl.model.friction.implicit_friction_1`: exact stick, implicit viscous damping), solved jointly
for all joints because friction couples them through ``B(q)^-1`` (computed once per control period;
projected Gauss-Seidel, see ``_physics_step``), and finally ``q += h qd``. The implicit friction keeps the
stiff wrist joints (viscous/inertia ratios of thousands per second) stable at ``h = 1 ms`` without chattering
at zero velocity.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from numba import njit

from wamctl.backends.base import ArmBackend, SafetyLimits
from wamctl.model.dynamics import WamDynamics
from wamctl.model.effects import ripple_torque_Nm
from wamctl.model.friction import implicit_friction_1
from wamctl.model.plant import Plant, SensorChain

# Rows of the packed plant parameters the physics kernel reads (one array: numba's dispatch cost grows with the
# number of arguments, and this kernel runs twice per tick): FrictionModel.as_array() rows 0-7, then these.
# The position ripple: row ROW_RIPPLE_K the wavenumbers, then H rows of amplitudes and H rows of phases (harmonics
# 1 .. H; H from the array's height).
ROW_SCALE, ROW_RIPPLE_K, ROW_RIPPLE_A = 8, 9, 10


@njit(cache=True)
def _physics_step(q, qd, tau, nle, minv, h, pp, work, sweeps):
    """One semi-implicit step in place: velocity without friction, coupled implicit friction, position.

    ``qdd = B^-1 (tau + ripple(q) - nle(q, qd))``, with ``B^-1`` evaluated at the start of the control period
    (pinocchio fills its upper triangle only). Friction couples the joints through ``B^-1`` (a friction
    torque on one joint accelerates the others), so the per-joint stick/slip rule is solved jointly by
    projected Gauss-Seidel sweeps warm-started from the previous step's torques ``f = work[1]``: joint i sees
    ``qd_free_i - h sum_{j != i} (B^-1)_ij f_j`` and takes its own implicit friction for that.
    ``pp`` packs the friction parameters (rows 0-7), the drift scale and the position ripple (rows 8 on).
    """
    n = q.shape[0]
    qd_free = work[0]
    f = work[1]
    u = work[2]
    nh = (pp.shape[0] - ROW_RIPPLE_A) // 2
    for j in range(n):
        u[j] = tau[j] - nle[j]
        if pp[ROW_RIPPLE_K, j] != 0.0:
            u[j] += ripple_torque_Nm(q[j], pp[ROW_RIPPLE_A:ROW_RIPPLE_A + nh, j], pp[ROW_RIPPLE_K, j],
                                     pp[ROW_RIPPLE_A + nh:ROW_RIPPLE_A + 2 * nh, j])
    for i in range(n):
        acc = 0.0
        for j in range(n):
            acc += (minv[i, j] if i <= j else minv[j, i]) * u[j]
        qd_free[i] = qd[i] + h * acc
    for _ in range(sweeps):
        for i in range(n):
            w = qd_free[i]
            for j in range(n):
                if j != i:
                    w -= h * (minv[i, j] if i <= j else minv[j, i]) * f[j]
            f[i] = implicit_friction_1(w, qd[i], minv[i, i], h, i, pp, pp[ROW_SCALE, i])
    for i in range(n):
        acc = 0.0
        for j in range(n):
            acc += (minv[i, j] if i <= j else minv[j, i]) * f[j]
        qd[i] = qd_free[i] - h * acc
        q[i] += h * qd[i]


class SimBackend(ArmBackend):
    """Simulated arm driven by the same protocol as the real one.

    Parameters
    ----------
    plant : the arm's truth (its robot, friction, effects, sensors).
    q0_rad : (n,) initial configuration (at rest), n the plant's robot's joints.
    rng : seeded generator for every random draw of the plant.
    substeps : physics steps per control period.
    """

    name = "sim"
    FRICTION_SWEEPS = 8  # projected Gauss-Seidel sweeps of the coupled friction (warm-started)

    def __init__(self, plant: Plant, q0_rad, rng: np.random.Generator, substeps: int = 2,
                 limits: SafetyLimits | None = None):
        robot = getattr(plant, "robot", None)
        super().__init__(limits if limits is not None else SafetyLimits.for_robot(robot))
        n = self.n_joints
        if robot is not None and robot.n_joints != n:
            raise ValueError(f"limits for {n} joints, the plant's {robot.name} has {robot.n_joints}")
        self.plant = plant
        self.dynamics = WamDynamics(plant.payload, plant.links)
        self.substeps = int(substeps)
        self.h_s = self.control_period_s / self.substeps
        self.rng = rng
        self.q0 = np.asarray(q0_rad, float).copy()
        if self.q0.shape != (n,):
            raise ValueError(f"q0_rad: {self.q0.size} values, the arm has {n} joints")
        self._pp = np.vstack([plant.friction.as_array(), np.ones(n), plant.ripple_wavenumber_rad,
                              plant.ripple_amplitudes_Nm, plant.ripple_phases_rad])
        self._t = 0.0
        self._q = self.q0.copy()
        self._qd = np.zeros(n)
        self._tau = np.zeros(n)
        self._work = np.zeros((3, n))  # velocity without friction, friction torque, net torque
        self.sensors = SensorChain(plant, rng, self.q0, self.h_s)
        self._q_meas = self.sensors.measure(self._q)

    @classmethod
    def from_spec(cls, spec, base_dir: Path | None, q0_rad, rng: np.random.Generator) -> SimBackend:
        """The simulated arm a spec describes: its ``robot``'s ``plant`` at rest at ``q0_rad``
        (``backend.physics_substeps``)."""
        return cls(Plant(spec.plant, base_dir, getattr(spec, "robot", None)), q0_rad, rng,
                   spec.backend.physics_substeps)

    # state of the truth, for tests and for logging simulated runs
    @property
    def q_true_rad(self) -> np.ndarray:
        return self._q.copy()

    @property
    def qd_true_rad_s(self) -> np.ndarray:
        return self._qd.copy()

    def truth(self) -> tuple[np.ndarray, np.ndarray]:
        """Views (not copies) of the true position and velocity, updated in place: the loop recorder keeps them."""
        return self._q, self._qd

    @property
    def friction_torque_Nm(self) -> np.ndarray:
        """Friction torque absorbed over the last physics step (n_joints,)."""
        return self._work[1].copy()

    @property
    def time_s(self) -> float:
        return self._t

    def describe(self) -> dict:
        return {"name": self.name, "robot": self.plant.robot.name, "physics_substeps": self.substeps,
                "physics_step_s": self.h_s,
                "integrator": "semi-implicit Euler + implicit stick/slip friction",
                "effects": self.plant.spec.effects.names()}

    def _open(self) -> None:
        pass

    def _close(self) -> None:
        pass

    def _read_positions(self) -> np.ndarray:
        return self._q_meas

    def _send_torques(self, tau_Nm: np.ndarray) -> None:
        self._tau[:] = tau_Nm
        if self.plant.sensors.torque_noise_Nm > 0:
            self._tau += self.rng.normal(0.0, self.plant.sensors.torque_noise_Nm, self.n_joints)

    def _wait_next_cycle(self) -> None:
        self._advance_physics()
        self._t += self.control_period_s
        self._q_meas = self.sensors.measure(self._q)

    def _advance_physics(self) -> None:
        """One control period of physics under the held torque ``_tau``: ``substeps`` steps that update the
        true state ``_q``, ``_qd`` in place, each fed to the sensor chain. The one place a subclass with other
        physics (benchmarks/bench_peer.py's MuJoCo peer) overrides."""
        plant, dyn = self.plant, self.dynamics
        q, qd = self._q, self._qd
        minv = dyn.mass_matrix_inverse_upper_view(q)  # upper triangle only; the kernel reads it so
        if plant.has_drift:
            self._pp[ROW_SCALE] = plant.friction_scale(self._t)
        for _ in range(self.substeps):
            nle = dyn.nonlinear_effects_view(q, qd)
            _physics_step(q, qd, self._tau, nle, minv, self.h_s, self._pp, self._work, self.FRICTION_SWEEPS)
            self.sensors.record_physics_step(q)
