"""The simulated arm: friction, controllers, effects, sensors and safety, checked with numbers."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import Q0

from wamctl.backends.base import SafetyLimits
from wamctl.backends.sim import SimBackend
from wamctl.control.controllers import JointController
from wamctl.control.trajectory import ReferenceBuilder, lspb, lspb_final_time_s
from wamctl.errors import SafetyLimitError
from wamctl.experiments.common import closed_loop_stage
from wamctl.model import params as P
from wamctl.model.dynamics import WamDynamics
from wamctl.model.friction import FrictionModel
from wamctl.model.plant import Plant
from wamctl.specs import PlantSpec

DT = 1.0 / P.CONTROL_RATE_HZ


def simulate(plant_spec: dict, reference, kp=P.KP, kd=P.KD, ki=np.zeros(7), seed=0, substeps=2, q0=Q0,
             payload=None):
    plant = Plant(PlantSpec.model_validate(plant_spec))
    backend = SimBackend(plant, q0, np.random.default_rng(seed), substeps)
    ctl = JointController(kp, kd, ki, DT, gravity=WamDynamics(payload).gravity_view)
    with backend:
        rows = closed_loop_stage(backend, ctl, reference, None)
    return rows, backend


def cols(rows, first):
    return rows[:, first:first + 7]


# ------------------------------------------------------------------------------------ trajectory
def test_lspb_matches_thesis_equations():
    t_f = lspb_final_time_s(0.5, 0.083, 1.0)
    assert t_f == pytest.approx(1 + 0.5 / 0.083)
    t = np.linspace(0, t_f, 20001)
    q, qd, qdd = lspb(t, -0.55, -0.05, t_f, 1.0)
    assert q[0] == pytest.approx(-0.55) and q[-1] == pytest.approx(-0.05)
    assert qd.max() == pytest.approx(0.083, rel=1e-9)            # eq. 3.4 cruise velocity
    assert qdd.max() == pytest.approx(0.083, rel=1e-9)           # eq. 3.5 with t_c = 1 s
    np.testing.assert_allclose(np.gradient(q, t)[1:-1], qd[1:-1], atol=1e-4)  # continuous and consistent
    # the published example of Fig. 3.7: q_i=-0.55, q_f=-0.05, t_f=7 s -> qd_c = 0.5 / (1 * 6) rad/s
    q7, qd7, _ = lspb(np.array([3.0]), -0.55, -0.05, 7.0, 1.0)
    assert qd7[0] == pytest.approx(0.5 / 6.0)


@pytest.mark.parametrize("tc", [0.3, 0.5, 1.0, 2.0])
def test_lspb_continuous_for_any_blend_time(tc):
    t_f = lspb_final_time_s(0.2, 0.05, tc)
    t = np.linspace(0, t_f, 40001)
    q, qd, _ = lspb(t, 0.1, 0.3, t_f, tc)
    assert np.abs(np.diff(q)).max() < 0.05 * t_f / 40000 * 1.01 + 1e-12   # no jump: steps bounded by v dt
    assert qd.max() == pytest.approx(0.05)
    assert q[-1] == pytest.approx(0.3)


# ------------------------------------------------------------------------------------ friction
def test_friction_table_4_1_layout_and_absolute_viscous():
    f = FrictionModel.table_4_1()
    assert f.viscous_pos_Nm_s_rad[3] == pytest.approx(2.7045)     # printed -2.7045: absolute value used
    tau = f.friction_torque(np.array([[0.1, -0.1, 0.0, 0.2, -0.2, 0.0, 0.0]]))[0]
    assert tau[0] == pytest.approx(4.4748 + 1.3348 * 0.1)
    assert tau[1] == pytest.approx(-(3.5643 + 2.3951 * 0.1))
    assert tau[2] == 0.0


def test_stiction_holds_below_breakaway_and_slides_above():
    # joint 1 at rest; an open-loop torque just below Fc+ must not move it, just above must
    plant = Plant(PlantSpec.model_validate({"friction": "table_4_1", "sensors": {"encoder_counts_per_rev": 0}}))
    for tau1, moves in ((4.3, False), (4.7, True)):
        be = SimBackend(plant, Q0, np.random.default_rng(0))
        g = WamDynamics().gravity(Q0)
        with be:
            for _ in range(500):
                tau = g.copy()
                tau[0] += tau1
                be.command_torques(tau)
                be.wait_next_cycle()
        moved = abs(be.q_true_rad[0] - Q0[0])
        assert (moved > 1e-3) == moves, (tau1, moved)


def test_no_chatter_at_zero_velocity_crossing():
    # a slow sinusoidal reference makes joint 6 reverse; velocity must never oscillate in sign between ticks
    ref = ReferenceBuilder(Q0, DT).move({5: 0.02}, 0.02, 0.5).move({5: -0.02}, 0.02, 0.5).hold(0.5).build()
    rows, be = simulate({"friction": "table_4_1", "sensors": {"encoder_counts_per_rev": 0}}, ref)
    qd6 = rows[:, 29 + 5]
    sign = np.sign(np.where(np.abs(qd6) > 1e-6, qd6, 0.0))
    moving = sign[sign != 0]
    assert np.count_nonzero(np.diff(moving)) <= 2      # one reversal (and at most one settling flip), no chatter
    assert (np.abs(qd6[-100:]) < 1e-12).all()          # at rest, the joint sticks (to rounding)
    assert np.isfinite(rows).all()


# ------------------------------------------------------------------------------------ the thesis task
@pytest.fixture(scope="module")
def pd_rotation():
    ref = ReferenceBuilder(Q0, DT).move(dict.fromkeys(range(7), 0.5), 0.083).hold(0.3).build()
    rows, be = simulate({"friction": "table_4_1"}, ref)
    return rows, be


def test_pd_final_error_bounded_by_static_estimate(pd_rotation):
    rows, be = pd_rotation
    err_meas = np.abs(cols(rows, 1)[-1] - cols(rows, 8)[-1])
    step = be.sensors.quantisation_step_rad()
    f = FrictionModel.table_4_1()
    bound = np.maximum(f.fc_pos_Nm, f.fc_neg_Nm) / P.KP           # static estimate Fc / Kp
    assert (err_meas <= bound + step).all(), (err_meas, bound)
    # a sizeable fraction of it on joints 1-4 (the move ends in the positive direction: Fc+ applies)
    frac = err_meas[:4] / (f.fc_pos_Nm[:4] / P.KP[:4])
    assert (frac > 0.3).all(), frac


def test_pid_removes_the_final_error():
    # gains chosen so that the integral acts within a second (kp / ki = 50 ms, 20 ms on joint 7); the wrist's
    # stiffer kp lets its integral cross the stick band (2 Fc) within the hold. Ideal sensors: one encoder count
    # of the wrist (~1e-4 rad) is larger than the 5e-5 rad asked for.
    kp = P.KP * np.array([1, 1, 1, 2, 6, 6, 10.0])
    ki = kp * np.array([20, 20, 20, 20, 20, 20, 50.0])
    ref = ReferenceBuilder(Q0, DT).move(dict.fromkeys(range(7), 0.5), 0.083).hold(2.0).build()
    rows, be = simulate({"friction": "table_4_1", "sensors": {"encoder_counts_per_rev": 0}}, ref, kp=kp, ki=ki,
                        kd=P.KD * 3)
    err = np.abs(cols(rows, 1)[-1] - cols(rows, 22)[-1])
    assert (err < 1e-4 * 0.5).all(), err                           # below 0.01 % of the move on every joint


# ------------------------------------------------------------------------------------ effects
def constant_velocity_move(joint0, velocity=0.2, travel=0.6):
    return ReferenceBuilder(Q0, DT).move({joint0: travel}, velocity, 0.5).build()


def test_position_ripple_visible_at_its_period():
    period = 0.1
    ref = constant_velocity_move(2, 0.2, 0.8)
    spec = {"friction": "table_4_1", "sensors": {"encoder_counts_per_rev": 0},
            "effects": {"position_ripple": {"joints": [3], "amplitude_Nm": 0.8, "period_rad": period}}}
    rows, _ = simulate(spec, ref)
    q = cols(rows, 8)[:, 2]
    tau = cols(rows, 15)[:, 2]
    qd = np.gradient(q, DT)
    cruise = np.abs(qd - 0.2) < 0.02
    phase = 2 * np.pi * q[cruise] / period
    X = np.column_stack([np.sin(phase), np.cos(phase), np.ones(cruise.sum())])
    coef, *_ = np.linalg.lstsq(X, tau[cruise], rcond=None)
    amp = np.hypot(*coef[:2])
    assert 0.5 < amp < 1.1, amp                           # the controller answers the ripple torque
    clean, _ = simulate({"friction": "table_4_1", "sensors": {"encoder_counts_per_rev": 0}}, ref)
    coef0, *_ = np.linalg.lstsq(X, cols(clean, 15)[:, 2][cruise], rcond=None)
    assert np.hypot(*coef0[:2]) < 0.1


def test_payload_changes_held_torque_by_m_g_lever():
    q0 = np.array([0.0, 0.0, 0.0, np.pi / 2, 0.0, 0.0, 0.0])
    ref = ReferenceBuilder(q0, DT).hold(3.0).build()      # long enough for the frictionless sag to settle
    spec = {"friction": "none", "sensors": {"encoder_counts_per_rev": 0},
            "effects": {"payload": {"mass_kg": 1.5, "com_m": [0.0, 0.0, 0.0]}}}
    loaded, _ = simulate(spec, ref, q0=q0)
    # the controller does not know the payload: the arm sags until the PD supplies it; at rest (no friction) the
    # logged torque is the plant's gravity, i.e. the bare arm's plus m g times the flange's horizontal lever
    q_end = cols(loaded, 22)[-1]
    lever = abs(WamDynamics().link7_pose(q_end)[0, 3])       # J2 axis passes through the origin, along y0
    assert lever == pytest.approx(0.045 + 0.3609, abs=0.01)
    extra = cols(loaded, 15)[-1, 1] - WamDynamics().gravity(q_end)[1]
    assert abs(extra) == pytest.approx(1.5 * P.GRAVITY_M_S2 * lever, rel=0.01)


def test_delay_shifts_measurement():
    ref = constant_velocity_move(0, 0.3, 0.6)
    spec = {"friction": "table_4_1", "sensors": {"encoder_counts_per_rev": 0},
            "effects": {"delay": {"delay_s": 0.007}}}
    rows, _ = simulate(spec, ref)
    q_meas, q_true = cols(rows, 8)[:, 0], cols(rows, 22)[:, 0]
    lag = np.median((q_true - q_meas)[np.abs(np.gradient(q_true, DT) - 0.3) < 0.01]) / 0.3
    assert lag == pytest.approx(0.007, abs=0.0005)


def test_backlash_dead_band_at_reversal():
    w = 0.004
    ref = ReferenceBuilder(Q0, DT).move({0: 0.1}, 0.1, 0.3).move({0: -0.1}, 0.1, 0.3).build()
    spec = {"friction": "none", "sensors": {"encoder_counts_per_rev": 0},
            "effects": {"backlash": {"joints": [1], "width_rad": w}}}
    rows, _ = simulate(spec, ref)
    gap = cols(rows, 22)[:, 0] - cols(rows, 8)[:, 0]
    # measured lags the link by w/2 going up and by -w/2 coming back
    assert gap.max() == pytest.approx(w / 2, abs=2e-4)
    assert gap.min() == pytest.approx(-w / 2, abs=2e-4)


def test_friction_drift_changes_torque_over_time():
    ref = ReferenceBuilder(Q0, DT).move({0: 1.2}, 0.1, 0.5).build()
    spec = {"friction": "table_4_1", "sensors": {"encoder_counts_per_rev": 0},
            "effects": {"friction_drift": {"joints": [1], "fraction": -0.5, "time_constant_s": 4.0}}}
    rows, _ = simulate(spec, ref)
    tau = cols(rows, 15)[:, 0] - WamDynamics().gravity(Q0)[0]
    t = rows[:, 0]
    early = tau[(t > 1.0) & (t < 2.0)].mean()
    late = tau[(t > 9.0) & (t < 11.0)].mean()
    assert late < 0.8 * early


def test_stribeck_raises_breakaway():
    ref = ReferenceBuilder(Q0, DT).hold(0.2).move({1: 0.05}, 0.01, 0.5).build()
    base = {"friction": "table_4_1", "sensors": {"encoder_counts_per_rev": 0}}
    strib = dict(base, effects={"stribeck": {"joints": [2], "breakaway_ratio": 2.0, "vs_rad_s": 0.02}})
    r0, _ = simulate(base, ref)
    r1, _ = simulate(strib, ref)
    g2 = WamDynamics().gravity(Q0)[1]
    peak0 = np.abs(cols(r0, 15)[:, 1] - g2).max()
    peak1 = np.abs(cols(r1, 15)[:, 1] - g2).max()
    assert peak1 > 1.6 * peak0 > 0


# ------------------------------------------------------------------------------------ sensors, seeds
def test_encoder_quantisation_through_the_transmission():
    plant = Plant(PlantSpec())
    be = SimBackend(plant, Q0, np.random.default_rng(0))
    step = be.sensors.quantisation_step_rad()
    assert step[0] == pytest.approx(2 * np.pi / (4096 * 42.0))
    assert step[6] == pytest.approx(2 * np.pi / (4096 * 14.93))
    q = Q0 + np.random.default_rng(1).normal(0, 0.1, 7)
    meas = be.sensors.measure(q)
    counts = P.J2MP @ meas * 4096 / (2 * np.pi)
    np.testing.assert_allclose(counts, np.round(counts), atol=1e-6)          # whole motor counts
    assert np.abs(meas - q).max() <= step.max()


def test_noise_is_seeded():
    spec = {"friction": "table_4_1", "sensors": {"position_noise_rad": 1e-4, "torque_noise_Nm": 0.01}}
    ref = ReferenceBuilder(Q0, DT).move({0: 0.05}, 0.1, 0.2).build()
    a, _ = simulate(spec, ref, seed=5)
    b, _ = simulate(spec, ref, seed=5)
    c, _ = simulate(spec, ref, seed=6)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)


def test_substeps_converge():
    ref = ReferenceBuilder(Q0, DT).move(dict.fromkeys(range(7), 0.2), 0.1).build()
    spec = {"friction": "table_4_1", "sensors": {"encoder_counts_per_rev": 0}}
    coarse, _ = simulate(spec, ref, substeps=2)
    fine, _ = simulate(spec, ref, substeps=8)
    err_c = cols(coarse, 1) - cols(coarse, 22)
    err_f = cols(fine, 1) - cols(fine, 22)
    assert np.abs(err_c - err_f).max() < 5e-4


# ------------------------------------------------------------------------------------ safety
def test_torque_saturation_and_nonfinite_command():
    be = SimBackend(Plant(PlantSpec()), Q0, np.random.default_rng(0))
    with be:
        applied = be.command_torques(np.array([100.0, -100, 1, 1, 1, 1, 1]))
        np.testing.assert_array_equal(applied[:2], [25.0, -20.0])
        with pytest.raises(SafetyLimitError, match="joint 3"):
            be.command_torques(np.array([0, 0, np.nan, 0, 0, 0, 0]))
        np.testing.assert_array_equal(be._tau, 0.0)


def test_position_limit_stops_the_loop():
    q0 = Q0.copy()
    q0[0] = 2.55
    ref = ReferenceBuilder(q0, DT).hold(2.0).build()
    ref.q_rad[:, 0] = 2.7          # a reference beyond the limit, as a runaway would produce
    plant = Plant(PlantSpec.model_validate({"friction": "none"}))
    be = SimBackend(plant, q0, np.random.default_rng(0))
    ctl = JointController(P.KP, P.KD, np.zeros(7), DT, gravity=WamDynamics().gravity_view)
    with pytest.raises(SafetyLimitError, match="joint 1 position"):
        with be:
            closed_loop_stage(be, ctl, ref, None)
    assert be.is_open is False
    np.testing.assert_array_equal(be._tau, 0.0)       # zero torque on exit
    be.shutdown()                                     # safe twice


def test_velocity_fault_limit():
    limits = SafetyLimits(qd_max_rad_s=np.full(7, 0.05))
    plant = Plant(PlantSpec.model_validate({"friction": "none"}))
    be = SimBackend(plant, Q0, np.random.default_rng(0), limits=limits)
    ref = ReferenceBuilder(Q0, DT).move({6: 0.3}, 0.2, 0.3).build()
    ctl = JointController(P.KP, P.KD, np.zeros(7), DT, gravity=WamDynamics().gravity_view)
    with pytest.raises(SafetyLimitError, match="joint 7 velocity"):
        with be:
            closed_loop_stage(be, ctl, ref, None)
