"""Test-data generator for ``wamctl diagnose``: simulated measured runs with one undeclared effect, or none.

Each run is the real simulator (:class:`wamctl.backends.sim.SimBackend` with a :class:`wamctl.model.plant.Plant`
holding Table 4.1 friction and 4096-count encoders) driven by libbarrett's PD + gravity controller along a
varied excitation: a chain of LSPB moves, each moving a random subset of joints by a random amount, mostly
turning back, at a random cruise speed, with short holds between some of them. The declared model (rigid body +
armature + classic friction) never knows the injected effect. The run is written in the measured-run format
(``meta.yaml`` + ``data.parquet``); the truth goes to a separate ``truth.yaml`` that the diagnosis never reads.

Effect magnitudes are drawn from ranges a WAM could plausibly show (they are not the diagnosis' thresholds):

========================  =====================================================================
stribeck                  breakaway ratio 1.4-2.2 x Fc, vs 0.02-0.08 rad/s, delta 2
position_ripple           amplitude 0.3-0.6 x the joint's mean Coulomb level, period 0.04-0.4 rad
payload                   0.4-1.5 kg at 3-10 cm from the flange
delay                     2-8 ms on every measured position (libbarrett gains go unstable near 11 ms)
friction_drift            friction x (1 + f (1 - exp(-t / T))), f in +-[0.3, 0.6], T 0.2-0.6 x run length
backlash                  dead band 0.004-0.012 rad on one joint's encoder
========================  =====================================================================
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd
import yaml

from wamctl.backends.sim import SimBackend
from wamctl.control.controllers import JointController
from wamctl.control.trajectory import ReferenceBuilder
from wamctl.errors import SafetyLimitError
from wamctl.experiments.common import closed_loop_stage
from wamctl.model import params as P
from wamctl.model.dynamics import WamDynamics
from wamctl.model.plant import Plant
from wamctl.specs import PlantSpec

EFFECTS = ("stribeck", "position_ripple", "payload", "delay", "friction_drift", "backlash")
DT_S = 1.0 / P.CONTROL_RATE_HZ
Q0_BASE = np.array([0.0, 0.0, 0.0, 1.9, 0.0, 0.0, 0.0])     # elbow folded: joint 2 stays within its torque
# Half-width of the box around q0 each joint explores (rad), inside the joint limits.
EXCURSION_RAD = np.array([0.7, 0.35, 0.7, 0.6, 0.8, 0.7, 0.9])
FC_MEAN_NM = (P.TABLE_4_1_FC_POS_NM + P.TABLE_4_1_FC_NEG_NM) / 2


@dataclass
class GeneratedRun:
    """A generated measured run: its directory and the truth the diagnosis should find."""

    path: Path
    effect: str | None
    joint: int | None            # 1-based joint carrying the effect (None for payload/delay/clean)
    effect_spec: dict = field(default_factory=dict)
    seed: int = 0
    n_samples: int = 0


def make_reference(rng: np.random.Generator, q0: np.ndarray, duration_s: float = 30.0):
    """A varied excitation: LSPB moves of random joint subsets, both directions, several speeds.

    Each move takes every joint with probability one half; a joint mostly turns back (two moves in three),
    so that every joint reverses several times; positions stay within ``q0 +- EXCURSION_RAD``.
    """
    lo = np.maximum(q0 - EXCURSION_RAD, P.Q_MIN_RAD + 0.1)
    hi = np.minimum(q0 + EXCURSION_RAD, P.Q_MAX_RAD - 0.1)
    b = ReferenceBuilder(q0, DT_S).hold(0.3, "settle")
    q = q0.copy()
    last = rng.choice([-1.0, 1.0], P.N_JOINTS)
    t = 0.3
    k = 0
    while t < duration_s:
        joints = np.flatnonzero(rng.random(P.N_JOINTS) < 0.5)
        if len(joints) == 0:
            joints = rng.integers(0, P.N_JOINTS, 1)
        deltas = {}
        for j in joints:
            amp = rng.uniform(0.1, 0.5) * (hi[j] - lo[j]) / 2
            sign = -last[j] if rng.random() < 2 / 3 else last[j]
            if not lo[j] <= q[j] + sign * amp <= hi[j]:
                sign = -sign
            target = float(np.clip(q[j] + sign * amp, lo[j], hi[j]))
            if abs(target - q[j]) > 0.02:
                deltas[int(j)] = target - q[j]
                last[j] = np.sign(target - q[j])
        if not deltas:
            continue
        amp = max(abs(d) for d in deltas.values())
        v = float(np.exp(rng.uniform(np.log(0.08), np.log(0.8))))
        v = min(v, amp / 0.3)                                      # keep t_f >= 2 t_c + a little
        tc = float(rng.uniform(0.15, 0.4))
        tc = min(tc, 0.45 * amp / v)                               # 2 t_c < t_f (LSPB)
        b.move(deltas, v, tc, f"move {k}")
        for j, d in deltas.items():
            q[j] += d
        t += tc + amp / v
        if rng.random() < 0.3:
            hold = float(rng.uniform(0.05, 0.3))
            b.hold(hold, "hold")
            t += hold
        k += 1
    return b.build()


def effect_spec(effect: str, rng: np.random.Generator, joint: int, duration_s: float) -> dict:
    """The ``plant.effects`` entry injecting ``effect`` (joint is 1-based; ignored by payload and delay)."""
    j = joint - 1
    if effect == "stribeck":
        return {"joints": [joint], "breakaway_ratio": float(rng.uniform(1.4, 2.2)),
                "vs_rad_s": float(np.exp(rng.uniform(np.log(0.02), np.log(0.08)))), "delta": 2.0}
    if effect == "position_ripple":
        return {"joints": [joint], "amplitude_Nm": float(rng.uniform(0.3, 0.6) * FC_MEAN_NM[j]),
                "period_rad": float(np.exp(rng.uniform(np.log(0.04), np.log(0.4)))),
                "phase_rad": float(rng.uniform(0, 2 * np.pi))}
    if effect == "payload":
        direction = rng.normal(size=3)
        direction[2] = abs(direction[2]) + 1.0
        com = direction / np.linalg.norm(direction) * rng.uniform(0.03, 0.10)
        return {"mass_kg": float(rng.uniform(0.4, 1.5)), "com_m": [float(c) for c in com]}
    if effect == "delay":
        return {"delay_s": float(rng.uniform(0.002, 0.008))}
    if effect == "friction_drift":
        return {"joints": [joint], "fraction": float(rng.choice([-1, 1]) * rng.uniform(0.3, 0.6)),
                "time_constant_s": float(rng.uniform(0.2, 0.6) * duration_s)}
    if effect == "backlash":
        return {"joints": [joint], "width_rad": float(rng.uniform(0.004, 0.012))}
    raise ValueError(f"unknown effect {effect!r}")


def simulate(plant_spec: dict, reference, q0: np.ndarray, seed: int = 0, kind: str = "pd_g") -> np.ndarray:
    """Closed-loop rows (see :func:`wamctl.experiments.engine.data_columns`, with truth)."""
    plant = Plant(PlantSpec.model_validate(plant_spec))
    backend = SimBackend(plant, q0, np.random.default_rng(seed), 2)
    ki = P.KI if kind == "pid" else np.zeros(P.N_JOINTS)
    ctl = JointController(P.KP, P.KD, ki, DT_S, gravity=WamDynamics().gravity_view)
    with backend:
        return closed_loop_stage(backend, ctl, reference, None)


def write_measured(path: Path, rows: np.ndarray, q0: np.ndarray, kind: str = "pd_g",
                   notes: str = "generated by tests/diagnosis_gen.py") -> Path:
    """Write closed-loop rows as a measured run (``wamctl-measured/1``)."""
    path = Path(path)
    path.mkdir(parents=True, exist_ok=True)
    n7 = P.N_JOINTS
    cols = {"t": rows[:, 0]}
    for j in range(n7):
        cols[f"q_ref_{j + 1}"] = rows[:, 1 + j]
    for j in range(n7):
        cols[f"q_{j + 1}"] = rows[:, 8 + j]
    for j in range(n7):
        cols[f"tau_{j + 1}"] = rows[:, 15 + j]
    pd.DataFrame(cols).to_parquet(path / "data.parquet", index=False)
    moved = [j + 1 for j in range(n7) if np.ptp(rows[:, 1 + j]) > 1e-9]
    meta = {"format": "wamctl-measured/1", "robot": "wam7", "sample_rate_hz": P.CONTROL_RATE_HZ,
            "gravity_compensation": True,
            "controller": {"kind": kind, "kp": P.KP.tolist(), "kd": P.KD.tolist(),
                           "ki": (P.KI if kind == "pid" else np.zeros(n7)).tolist()},
            "experiment": {"kind": "free", "joints": moved}, "q0": [float(x) for x in q0],
            "payload": None, "notes": notes}
    (path / "meta.yaml").write_text(yaml.safe_dump(meta, sort_keys=False))
    return path


def generate_run(out_dir: str | Path, effect: str | None = None, seed: int = 0, joint: int | None = None,
                 duration_s: float = 30.0, position_noise_rad: float = 0.0, torque_noise_Nm: float = 0.0,
                 kind: str = "pd_g") -> GeneratedRun:
    """Simulate one measured run with ``effect`` (one of :data:`EFFECTS`) or none, into ``out_dir``.

    The effect's joint (when it has one) and magnitude are drawn from ``seed`` unless ``joint`` is given.
    """
    # an experiment that trips a safety limit (a payload too heavy for the pose, a delay that destabilises
    # the loop) would not be a measured run, and one that runs into the torque limits does not track its
    # reference: draw again (at most five times) from a derived seed
    for attempt in range(5):
        rng = np.random.default_rng(seed if attempt == 0 else [seed, attempt])
        q0 = Q0_BASE + rng.uniform(-0.4, 0.4, P.N_JOINTS) * np.array([1, 0.25, 1, 0.5, 1, 0.5, 1])
        ref = make_reference(rng, q0, duration_s)
        j_eff = joint if joint is not None else int(rng.integers(1, P.N_JOINTS + 1))
        effects = {}
        if effect is not None:
            effects[effect] = effect_spec(effect, rng, j_eff, len(ref) * DT_S)
        plant = {"friction": "table_4_1", "effects": effects,
                 "sensors": {"encoder_counts_per_rev": P.ENCODER_COUNTS_PER_REV,
                             "position_noise_rad": position_noise_rad, "torque_noise_Nm": torque_noise_Nm}}
        try:
            rows = simulate(plant, ref, q0, seed, kind)
        except SafetyLimitError:
            if attempt == 4:
                raise
            continue
        saturated = np.abs(rows[:, 15:22]) >= P.TAU_MAX_NM * (1 - 1e-9)
        if saturated.mean(axis=0).max() <= 0.002 or attempt == 4:
            break
    joint = j_eff
    name = f"{effect or 'clean'}-s{seed}"
    path = write_measured(Path(out_dir) / name, rows, q0, kind)
    has_joint = effect in ("stribeck", "position_ripple", "friction_drift", "backlash")
    truth = {"effect": effect, "joint": joint if has_joint else None, "plant": plant, "seed": seed}
    (path / "truth.yaml").write_text(yaml.safe_dump(truth, sort_keys=False))
    return GeneratedRun(path, effect, joint if has_joint else None, effects.get(effect, {}) if effect else {},
                        seed, len(rows))


def diagnose_quietly(path):
    """``(ModelDiagnosis().fit(data), data)`` of the run at ``path`` (read by ``load_run_data``), the analyses'
    warnings silenced."""
    import logging

    from wamctl.analysis.diagnosis.estimator import ModelDiagnosis
    from wamctl.runs.measured import load_run_data

    logging.disable(logging.WARNING)
    try:
        data = load_run_data(path)
        return ModelDiagnosis().fit(data), data
    finally:
        logging.disable(logging.NOTSET)
