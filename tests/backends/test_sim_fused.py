"""The compiled closed loop (wamctl.backends.sim_fused) against the Python path of run_loop: same rows, same
faults, same generator state."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import Q0

from wamctl.backends.base import SafetyLimits
from wamctl.backends.sim import SimBackend
from wamctl.backends.sim_fused import fused_supported
from wamctl.control.controllers import JointController
from wamctl.control.trajectory import ReferenceBuilder
from wamctl.errors import SafetyLimitError
from wamctl.experiments.engine import LoopRecorder, run_loop
from wamctl.model import params as P
from wamctl.model.dynamics import Payload, WamDynamics
from wamctl.model.plant import Plant
from wamctl.specs import PlantSpec

DT = 1.0 / P.CONTROL_RATE_HZ

EVERYTHING = {
    "friction": "table_4_1",
    "effects": {"stribeck": {"joints": [1, 2, 4], "breakaway_ratio": 1.8, "vs_rad_s": 0.03},
                "position_ripple": {"joints": [1, 3], "amplitude_Nm": 0.6, "period_rad": 0.2},
                "payload": {"mass_kg": 1.5, "com_m": [0.0, 0.01, 0.05]},
                "delay": {"delay_s": 0.0035},
                "friction_drift": {"joints": [1, 2], "fraction": -0.3, "time_constant_s": 1.0},
                "backlash": {"joints": [1, 4], "width_rad": 0.002}},
    "sensors": {"position_noise_rad": 2e-5, "torque_noise_Nm": 0.05},
    "links": {3: {"mass_kg": 2.2}, 6: {"armature_kg_m2": 0.05}},
}


def _reference(seconds=1.2):
    return (ReferenceBuilder(Q0, dt_s=DT).hold(0.1).move({0: 0.3, 1: -0.2, 3: 0.25}, 0.4, tc_s=0.3)
            .move({0: -0.1, 4: 0.3}, 0.5, tc_s=0.3).hold(0.1).build())


def _run(plant_spec, fused, reference, seed=3, ff=True, limits=None, ki=None, payload=(0.5, (0, 0, 0.02))):
    backend = SimBackend(Plant(PlantSpec.model_validate(plant_spec)), Q0, np.random.default_rng(seed), 2, limits)
    feedforward = np.random.default_rng(9).normal(0, 0.05, (len(reference) // 2, 7)) if ff else None
    ctl = JointController(P.KP, P.KD, np.full(7, 5.0) if ki is None else ki, DT,
                          gravity=WamDynamics(Payload(*payload)).gravity_view, feedforward_Nm=feedforward)
    assert fused_supported(backend, ctl)
    rec = LoopRecorder(len(reference), True)
    progress = []
    err = None
    with backend:
        try:
            run_loop(backend, ctl, reference, rec, lambda k, n: progress.append(k), fused=fused)
        except SafetyLimitError as e:
            err = str(e)
    return rec, backend, ctl, progress, err


@pytest.mark.parametrize("spec", [EVERYTHING, {"friction": "none", "sensors": {"encoder_counts_per_rev": 0}},
                                  {"friction": "table_4_1"}])
def test_fused_loop_matches_python_path(spec):
    ref = _reference()
    a = _run(spec, False, ref)
    b = _run(spec, True, ref)
    assert a[4] is None and b[4] is None, (a[4], b[4])
    ra, rb = a[0].result(), b[0].result()
    assert ra.shape == rb.shape == (len(ref), a[0].rows.shape[1])
    assert np.ptp(ra[:, 1 + 7 + 0]) > 0.25                 # the arm moved
    np.testing.assert_allclose(rb, ra, rtol=0, atol=1e-9)
    np.testing.assert_allclose(b[1].q_true_rad, a[1].q_true_rad, rtol=0, atol=1e-9)
    np.testing.assert_allclose(b[1].qd_true_rad_s, a[1].qd_true_rad_s, rtol=0, atol=1e-8)
    np.testing.assert_allclose(b[2].integral_Nm, a[2].integral_Nm, rtol=0, atol=1e-9)
    assert b[1].time_s == pytest.approx(a[1].time_s, abs=1e-12)
    assert b[3] == a[3]                                     # progress reported at the same ticks
    assert b[1].rng.normal() == a[1].rng.normal()           # the generator where the Python path left it


def test_fused_loop_faults_at_the_same_tick_with_the_same_message():
    ref = _reference()
    lim = SafetyLimits()
    lim.q_max_rad = lim.q_max_rad.copy()
    lim.q_max_rad[0] = Q0[0] + 0.15                          # the first move crosses it
    a = _run(EVERYTHING, False, ref, limits=lim)
    lim2 = SafetyLimits()
    lim2.q_max_rad = lim.q_max_rad.copy()
    b = _run(EVERYTHING, True, ref, limits=lim2)
    assert a[4] is not None and a[4].startswith("joint 1 position")
    assert b[4] == a[4]
    assert b[0].n == a[0].n and 0 < a[0].n < len(ref)
    np.testing.assert_allclose(b[0].result(), a[0].result(), rtol=0, atol=1e-9)
    assert b[1].rng.normal() == a[1].rng.normal()


def test_fused_only_where_it_reproduces_the_python_path():
    be = SimBackend(Plant(PlantSpec()), Q0, np.random.default_rng(0))

    class Other(SimBackend):
        def _advance_physics(self):
            super()._advance_physics()

    other = Other(Plant(PlantSpec()), Q0, np.random.default_rng(0))
    plain = JointController(P.KP, P.KD, np.zeros(7), DT, gravity=WamDynamics().gravity_view)
    assert fused_supported(be, plain)
    assert fused_supported(be, JointController(P.KP, P.KD, np.zeros(7), DT))
    assert not fused_supported(other, plain)
    assert not fused_supported(be, JointController(P.KP, P.KD, np.zeros(7), DT, gravity=lambda q: np.zeros(7)))


def test_an_interrupt_from_the_progress_callback_stops_both_paths_at_the_same_row():
    """Ctrl-C reaches the compiled loop between its chunks, which end where the Python path reports progress:
    stopped at the same tick, with the same rows and the same state."""
    ref = _reference()
    out = []
    for fused in (False, True):
        backend = SimBackend(Plant(PlantSpec.model_validate(EVERYTHING)), Q0, np.random.default_rng(1), 2)
        ctl = JointController(P.KP, P.KD, np.zeros(7), DT, gravity=WamDynamics().gravity_view)
        rec = LoopRecorder(len(ref), True)

        def progress(k, n):
            if k >= 300:
                raise KeyboardInterrupt

        with backend, pytest.raises(KeyboardInterrupt):
            run_loop(backend, ctl, ref, rec, progress, fused=fused)
        out.append((rec, backend))
    (ra, ba), (rb, bb) = out
    assert ra.n == rb.n == 301
    np.testing.assert_allclose(rb.result(), ra.result(), rtol=0, atol=1e-9)
    np.testing.assert_allclose(bb.q_true_rad, ba.q_true_rad, rtol=0, atol=1e-9)
