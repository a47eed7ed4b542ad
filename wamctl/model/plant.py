"""The simulated arm's truth: rigid body + friction + effects + sensors, built from a plant spec
(:class:`wamctl.specs.PlantSpec`).

Effects (each switchable in ``plant.effects``; see :mod:`wamctl.specs` for the parameters):

* ``stribeck``        breakaway friction ``breakaway_ratio * Fc`` decaying with speed (eq. 2.8), in the
                      plant's friction model.
* ``position_ripple`` a torque ``A sin(2 pi q / period + phase)`` and its harmonics (``harmonics``: the
                      2nd, 3rd, ... ``A_h sin(2 pi h q / period + phase_h)``) added at every physics step.
* ``links``           (not an effect: the rigid body itself) the plant's link masses, COMs, inertias and
                      armature in place of the datasheet's, e.g. an arm identified by ``wamctl identify``.
* ``payload``         a point mass added to link 7 of the plant's rigid body (the controller does not know it
                      unless ``controller.declared_payload`` says so).
* ``delay``           measured positions are the true ones ``delay_s`` earlier (linear interpolation over the
                      physics steps).
* ``friction_drift``  every friction parameter of the chosen joints scaled by
                      ``1 + fraction (1 - exp(-t / time_constant))``.
* ``backlash``        a play operator of width ``w`` between link and motor encoder: the encoder position
                      follows the link only once the link has crossed the dead band, so at each direction
                      reversal the measurement stands still over ``w`` of link travel.

Sensors: motor encoders with ``counts`` per revolution read through the transmission (motor angle =
J2MP @ q, rounded to counts, mapped back with J2MP^-1: :func:`wamctl.model.transmission.quantise_joint_rad`,
the formula the CAN backend uses too), optional Gaussian position noise, and optional actuation (torque)
noise. All randomness comes from one seeded generator.
"""

from __future__ import annotations

from collections import deque
from pathlib import Path

import numpy as np

from wamctl.errors import SpecError
from wamctl.io import resolve_path
from wamctl.model import params as P
from wamctl.model.dynamics import Payload
from wamctl.model.effects import friction_drift_scale, ripple_series, ripple_torque_Nm
from wamctl.model.friction import FrictionModel
from wamctl.model.robots import get_robot
from wamctl.model.transmission import counts_per_rad, joint_rad_per_count, quantise_joint_rad, transmission_inverse


def resolve_friction(value, base_dir: Path | None = None, n_joints: int = P.N_JOINTS) -> FrictionModel:
    """A friction model from a spec value: ``table_4_1``, ``none``, a file path, or an inline ``joints:`` table
    (a mapping, or the spec's validated model of one), for an arm of ``n_joints`` (the spec's robot; Table 4.1:
    its first joints, :meth:`FrictionModel.table_4_1`)."""
    if value is None or value == "none":
        return FrictionModel.zero(n_joints)
    if value == "table_4_1":
        return FrictionModel.table_4_1(n_joints)
    if hasattr(value, "model_dump"):
        value = value.model_dump()
    if isinstance(value, dict):
        return FrictionModel.from_dict(value, "plant.friction", n_joints)
    path = resolve_path(value, base_dir)
    if not path.is_file():
        raise SpecError(_not_found(str(value)))
    return FrictionModel.load(path, n_joints)


FRICTION_NAMES = ("table_4_1", "none")    # the friction a spec can name instead of giving a file


def _not_found(value: str) -> str:
    """The error for a friction value that is no file: a value that reads as a misspelt name (no folder, no
    file suffix) gets the valid names, the closest first."""
    import difflib

    if "/" in value or "." in value:
        return f"friction model file not found: {value}"
    close = difflib.get_close_matches(value.lower(), FRICTION_NAMES, n=1, cutoff=0.5)
    return (f"{value!r} is neither a friction name ({', '.join(FRICTION_NAMES)}) nor a friction model file"
            + (f"; did you mean {close[0]}?" if close else ""))


def joint_mask(joints, n_joints: int = P.N_JOINTS) -> np.ndarray:
    m = np.zeros(n_joints, bool)
    bad = [j for j in joints if not 1 <= j <= n_joints]
    if bad:
        raise SpecError(f"joint numbers are 1..{n_joints}, got {bad}")
    m[[j - 1 for j in joints]] = True
    return m


class Plant:
    """Runtime description of the simulated arm (no state)."""

    def __init__(self, spec, base_dir: Path | None = None, robot=None):
        """``spec``: a plant description (:class:`wamctl.specs.PlantSpec`: friction, effects, sensors);
        ``robot``: the arm (:mod:`wamctl.model.robots`, a spec's ``robot``; default the wam7): its joint count,
        datasheet links, transmission and encoders."""
        self.spec = spec
        self.robot = get_robot(robot)
        n = self.n_joints = self.robot.n_joints
        fx = spec.effects
        friction = resolve_friction(spec.friction, base_dir, n)
        if fx.stribeck is not None:
            m = joint_mask(fx.stribeck.joints, n)
            r = fx.stribeck.breakaway_ratio
            friction = friction.with_stribeck(
                np.where(m, friction.fc_pos_Nm * r, np.nan), np.where(m, friction.fc_neg_Nm * r, np.nan),
                np.where(m, fx.stribeck.vs_rad_s, np.nan), fx.stribeck.delta)
        self.friction = friction
        self.payload = Payload(fx.payload.mass_kg, tuple(fx.payload.com_m)) if fx.payload else None
        # the rigid body: the datasheet's links unless the plant gives its own (`links:`, e.g. an identified arm)
        self.links = P.LinkParameters.datasheet(self.robot.name).with_overrides(getattr(spec, "links", None))
        # the position ripple: (H, n) amplitudes and phases of harmonics 1 .. H, (n,) wavenumbers 2 pi / period
        self.ripple_amplitudes_Nm = np.zeros((1, n))
        self.ripple_phases_rad = np.zeros((1, n))
        self.ripple_wavenumber_rad = np.zeros(n)
        if fx.position_ripple is not None:
            r = fx.position_ripple
            m = joint_mask(r.joints, n)
            amps, phases = ripple_series(r.amplitude_Nm, r.phase_rad, r.harmonics)
            self.ripple_amplitudes_Nm = np.where(m, amps[:, None], 0.0)
            self.ripple_phases_rad = np.where(m, phases[:, None], 0.0)
            self.ripple_wavenumber_rad[m] = 2 * np.pi / r.period_rad
        self.has_ripple = bool(self.ripple_amplitudes_Nm.any())
        self.drift_fraction = np.zeros(n)
        self.drift_time_constant_s = 1.0
        if fx.friction_drift is not None:
            self.drift_fraction[joint_mask(fx.friction_drift.joints, n)] = fx.friction_drift.fraction
            self.drift_time_constant_s = fx.friction_drift.time_constant_s
        self.has_drift = bool(self.drift_fraction.any())
        self.delay_s = fx.delay.delay_s if fx.delay else 0.0
        self.backlash_width_rad = np.zeros(n)
        if fx.backlash is not None:
            self.backlash_width_rad[joint_mask(fx.backlash.joints, n)] = fx.backlash.width_rad
        self.sensors = spec.sensors

    def ripple_torque_Nm(self, q: np.ndarray) -> np.ndarray:
        """Position ripple torque applied to the joints (n_joints,) or (k, n_joints)."""
        q = np.asarray(q, float)
        return np.stack([ripple_torque_Nm(q[..., j], self.ripple_amplitudes_Nm[:, j], self.ripple_wavenumber_rad[j],
                                          self.ripple_phases_rad[:, j]) for j in range(self.n_joints)], axis=-1)

    def friction_scale(self, t_s: float) -> np.ndarray:
        """(n_joints,) friction multiplier at time t (1 without drift)."""
        return friction_drift_scale(t_s, self.drift_fraction, self.drift_time_constant_s)


class SensorChain:
    """Turns true link positions into what the encoders report: delay -> backlash -> quantisation -> noise."""

    def __init__(self, plant: Plant, rng: np.random.Generator, q0: np.ndarray, dt_physics_s: float):
        self.plant = plant
        self.rng = rng
        cts = plant.sensors.encoder_counts_per_rev
        self._cts = cts
        # per motor, as the transmission's kernel takes them; None: ideal sensor, no quantisation
        n = plant.n_joints
        self._n = n
        self._counts_per_rad = np.full(n, counts_per_rad(cts)) if cts > 0 else None
        j2mp = plant.robot.j2mp                  # the arm's transmission (the wam7's: transmission.J2MP)
        self._j2mp, self._m2jp = np.array(j2mp), np.array(transmission_inverse(j2mp))  # writable: numba is faster
        self._play = np.asarray(q0, float).copy()
        self._half_band = plant.backlash_width_rad / 2
        self._has_backlash = bool(self._half_band.any())
        n_hist = int(np.ceil(plant.delay_s / dt_physics_s)) + 2 if plant.delay_s > 0 else 0
        self._dt = dt_physics_s
        self._hist: deque | None = deque([np.asarray(q0, float).copy()] * n_hist, maxlen=n_hist) if n_hist else None

    def record_physics_step(self, q_true: np.ndarray) -> None:
        """Called after each physics step (feeds the delay line)."""
        if self._hist is not None:
            self._hist.append(q_true.copy())

    def measure(self, q_true: np.ndarray) -> np.ndarray:
        q = q_true
        if self._hist is not None:
            lag = self.plant.delay_s / self._dt          # physics steps back from the newest sample
            k = int(np.floor(lag))
            frac = lag - k
            newer = self._hist[-1 - k]
            older = self._hist[-2 - k]
            q = (1 - frac) * newer + frac * older
        if self._has_backlash:
            self._play = np.clip(self._play, q - self._half_band, q + self._half_band)
            q = np.where(self._half_band > 0, self._play, q)
        if self._counts_per_rad is not None:
            q = quantise_joint_rad(q, self._j2mp, self._m2jp, self._counts_per_rad)
        if self.plant.sensors.position_noise_rad > 0:
            q = q + self.rng.normal(0.0, self.plant.sensors.position_noise_rad, self._n)
        return q

    def quantisation_step_rad(self) -> np.ndarray:
        """(n_joints,) joint-angle size of one encoder count (the largest over the coupled joints)."""
        if self._counts_per_rad is None:
            return np.zeros(self._n)
        return joint_rad_per_count(self._cts, self._j2mp)
