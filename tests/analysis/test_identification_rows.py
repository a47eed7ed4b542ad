"""The identification's rows answer the torque they are paired with (issue 27; the payload's issue 29 item 1).

The rows' torque is the logged torque through the first filter's smoothing kernel. Their velocity and
acceleration were that filter's Savitzky-Golay derivative kernels, which are not the smoothing kernel
differentiated: the second-derivative kernel attenuates the motion's acceleration more than the smoothing kernel
attenuates the torque, so the inertial torque of the rows was short of the torque's, and an identification made up
for it with inertia (an apparent armature). Now the rows take the derivatives of the smoothed position itself
(:func:`wamctl.analysis.identification.data.smoothed_derivatives`).

The run is made here, noise-free and without friction: a wam4 of the datasheet (links and armature) on a fast sum
of sines (harmonics 0.5-2.5 Hz), its torque by pinocchio's inverse dynamics at the zero-order hold's mid-interval.
The rows of the true arm's standard parameters then leave only what the filters do to the motion.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
import yaml

from wamctl.analysis.identification.base import layout, standard_vector
from wamctl.analysis.identification.data import run_rows, smoothed_derivatives
from wamctl.model.dynamics import WamDynamics
from wamctl.runs.measured import load_run_data

RATE_HZ = 500.0
DURATION_S = 12.0
F0_HZ = 0.5                     # harmonics 1-5 of it: 0.5-2.5 Hz
Q_CENTRE = np.array([0.0, 0.0, 0.0, 1.6])
AMP_RAD = np.array([0.3, 0.25, 0.3, 0.25])


def _sines(t: np.ndarray, seed: int = 3) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    h = np.arange(1, 6)
    w = 2 * np.pi * F0_HZ * h
    amp = AMP_RAD[:, None] / h[None, :]
    arg = w[None, None, :] * t[:, None, None] + rng.uniform(0, 2 * np.pi, (4, 5))[None]
    return (Q_CENTRE + np.sum(amp * np.sin(arg), 2), np.sum(amp * w * np.cos(arg), 2),
            -np.sum(amp * w ** 2 * np.sin(arg), 2))


@pytest.fixture(scope="module")
def fast_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("rows") / "fast"
    out.mkdir()
    t = np.arange(0.0, DURATION_S, 1.0 / RATE_HZ)
    q, _, _ = _sines(t)
    # a sampled controller holds tau[k] over [t_k, t_k+1): the torque logged at t_k acts at the interval's middle
    tau = WamDynamics(robot="wam4").inverse_dynamics_many(*_sines(t + 0.5 / RATE_HZ))
    df = pd.DataFrame({"t": t})
    for j in range(4):
        df[f"q_ref_{j + 1}"], df[f"q_{j + 1}"], df[f"tau_{j + 1}"] = q[:, j], q[:, j], tau[:, j]
    df.to_parquet(out / "data.parquet", index=False)
    meta = {"format": "wamctl-measured/1", "robot": "wam4", "sample_rate_hz": RATE_HZ,
            "gravity_compensation": True, "controller": {"kind": "pd_g", "kp": [1.0] * 4, "kd": [1.0] * 4},
            "experiment": {"kind": "free", "joints": [1, 2, 3, 4]}, "q0": [float(x) for x in q[0]]}
    (out / "meta.yaml").write_text(yaml.safe_dump(meta, sort_keys=False))
    return load_run_data(out, partial_ok=True)


def _apparent_armature(rows, dyn) -> tuple[np.ndarray, float]:
    """Per joint, the armature a fit would add to the true arm to explain the rows' torque (least squares of the
    residual ``tau - Y pi_true`` on the joint's armature column), kg m^2; and the residual's RMS over the torque's."""
    Y, tau, joint, _ = rows.stacked()
    res = tau - Y @ standard_vector(dyn)
    arm = layout(4)[1]
    out = np.empty(4)
    for j in range(4):
        x = Y[joint == j, arm.start + j]
        out[j] = x @ res[joint == j] / (x @ x)
    return out, float(np.sqrt(np.mean(res ** 2)) / np.sqrt(np.mean(tau ** 2)))


def test_rows_of_a_fast_motion_carry_no_apparent_inertia(fast_run):
    """Measured: the rows' apparent armature -1e-5 to +4e-5 kg m^2 (the arm's 0.03-0.16), residual 0.07 % of the
    torque; with the derivative kernels +2.7e-4 to +2.3e-3 kg m^2 (joint 2: 1.6 % of its armature), residual
    0.27 %."""
    dyn = WamDynamics(robot="wam4")
    rows = run_rows(fast_run, dyn, derivatives="smoothed")
    assert rows.window_s is not None and rows.n_rows > 1000       # the second filter on (0.06 s here)
    apparent, rel = _apparent_armature(rows, dyn)
    assert np.all(np.abs(apparent) < 1.5e-4), apparent
    assert rel < 1.5e-3, rel
    kernel, rel_kernel = _apparent_armature(run_rows(fast_run, dyn), dyn)
    assert np.all(kernel > 2e-4) and kernel[1] > 1.5e-3, kernel     # the bias before: inertia made up
    assert rel_kernel > 2 * rel


def test_smoothed_derivatives_of_a_sampled_sine_and_of_a_measured_velocity():
    """At the rows' 100 Hz, a 3 Hz sine's derivatives within 1e-4 (relative) away from the ends; given a
    (smoothed, measured) velocity, it is the velocity and the acceleration is its spline's derivative."""
    t = np.arange(0.0, 4.0, 0.01)
    w = 2 * np.pi * 3.0
    q = np.column_stack([np.sin(w * t), np.cos(w * t)])
    qd, qdd = smoothed_derivatives(t, q)
    inner = slice(20, -20)
    assert np.max(np.abs(qd[inner] - w * np.column_stack([np.cos(w * t), -np.sin(w * t)])[inner])) < 1e-4 * w
    assert np.max(np.abs(qdd[inner] + w ** 2 * q[inner])) < 1e-4 * w ** 2
    v = w * np.column_stack([np.cos(w * t), -np.sin(w * t)])
    qd2, qdd2 = smoothed_derivatives(t, q, v)
    assert np.array_equal(qd2, v)
    assert np.max(np.abs(qdd2[inner] + w ** 2 * q[inner])) < 1e-4 * w ** 2
