"""Issue 28, motor-side backlash at the wrist: the designed run shows the gap at its reversals, not as a torque step.

On a wrist joint gravity is too small for the gap's torque step at a gravity crossing to show (``2 b |dg/dq|``:
below a thousandth of a noise floor at joint 7); what shows there is lost motion: at each reversal where the link
comes to rest on its own friction (the torque the rigid link needs at the turning point below the link's share of
the joint's Coulomb friction) the motor turns round and crosses the gap alone, and the measurement leads the link
by the gap, which the backlash onset test resolves against ``MIN_BAND_TOLERANCES`` detection tolerances. The
design scores both ways and the next experiment says which.
"""

from __future__ import annotations

import numpy as np
import pytest

from wamctl.analysis.diagnosis.backlash import MIN_BAND_TOLERANCES
from wamctl.analysis.diagnosis.backlash_design import (
    LINK_FRICTION_SHARE,
    design_crossing,
    level_poses,
    reversal_leads,
    reversal_separation,
)
from wamctl.analysis.identification.excitation import ExcitationLimits, FourierTrajectory
from wamctl.model.dynamics import WamDynamics
from wamctl.model.friction import FrictionModel
from wamctl.specs.excitation import ExcitationLimitsSpec

Q0 = np.array([0.0, 0.0, 0.0, 1.9, 0.0, 0.0, 0.0])
GAP_RAD = 0.008


def _limits():
    spec = ExcitationLimitsSpec()
    return ExcitationLimits(*spec.arrays(), 1 - spec.torque_margin, spec.max_cartesian_speed_m_s)


def _two_harmonic(j, pose, amplitude_rad=0.25, period_s=16.0, periods=2):
    """The design's motion of joint ``j`` alone about ``pose``, sampled at 25 Hz over ``periods`` periods."""
    w = 2 * np.pi / period_s
    a, b = np.zeros((7, 2)), np.zeros((7, 2))
    a[j] = [amplitude_rad * w, -amplitude_rad * w]
    tr = FourierTrajectory(np.asarray(pose, float), period_s, a, b)
    return tr.evaluate(np.arange(int(periods * period_s * 25)) / 25.0)


def test_the_wrist_link_rests_on_its_friction_at_every_reversal_the_elbow_link_at_none():
    """Joint 7 (gravity under a milli-newton-metre): every reversal of the slow two-harmonic motion is one where
    the link rests on its own friction (0.2 of Table 4.1's 0.054 N m), the lead is the gap; the elbow about
    1.9 rad (gravity about -5 N m) keeps the link pressed on one flank at each reversal: no lead. Two
    reversals per period; the dwell at the series' start (at rest, same direction) is none."""
    dyn = WamDynamics(None)
    fc7, fc4 = 0.054, 0.9
    q, qd, qdd = _two_harmonic(6, Q0)
    lead = reversal_leads(dyn, q, qd, qdd, 6, GAP_RAD, fc7)
    assert len(lead) == 4 and np.all(lead == GAP_RAD)          # 2 periods: 4 reversals
    q, qd, qdd = _two_harmonic(3, Q0)
    assert len(reversal_leads(dyn, q, qd, qdd, 3, GAP_RAD, fc4)) == 4
    assert not reversal_leads(dyn, q, qd, qdd, 3, GAP_RAD, fc4).any()
    # the separation: the gap over the test's resolution, RMS over the reversals
    tol = 2e-4
    sep, crossing, n = reversal_separation(dyn, *_two_harmonic(6, Q0), 6, GAP_RAD, fc7, tol)
    assert (crossing, n) == (4, 4) and sep == pytest.approx(GAP_RAD / (MIN_BAND_TOLERANCES * tol))
    # without friction on the link side nothing holds the link at rest against gravity: no crossing predicted
    assert not reversal_leads(dyn, *_two_harmonic(6, Q0), 6, GAP_RAD, 0.0).any()
    assert LINK_FRICTION_SHARE <= 0.3


def test_level_poses_find_where_the_upper_arm_rotation_carries_no_gravity():
    """Joint 3 (upper arm rotation): its gravity torque vanishes where the upper arm is vertical (joint 2 at 0)
    or the forearm is folded along it; the best pose keeps |g_3| at the stroke's ends below 0.05 N m, where the
    run's own pose (joint 2 at 1 rad, elbow at 1.5) needs several N m."""
    dyn = WamDynamics(None)
    lim = _limits()
    run_pose = np.array([0.0, 1.0, 0.0, 1.5, 0.0, 0.0, 0.0])
    poses = level_poses(dyn, run_pose, 2, lim.q_min_rad, lim.q_max_rad)
    ends = 1.3 * 0.25 * np.array([-1.0, 1.0])
    worst = []
    for p in (poses[0], run_pose):
        Q = np.tile(p, (2, 1))
        Q[:, 2] = p[2] + ends
        worst.append(np.abs(dyn.gravity_many(Q)[:, 2]).max())
    assert worst[0] < 0.05 < 1.0 < worst[1], worst


def test_the_wrist_design_predicts_the_gap_at_its_reversals():
    """The design for joint 7 (a run's pose, an 8 mrad gap, a detection tolerance of 0.2 mrad, the floor of a
    250 Hz wrist log): the gravity step stays below a hundredth of a noise floor (what the crossing design
    predicted alone: 7e-5 on the dev split's wrist sweeps), the reversals separate it by more than 2 noise floors
    (the gap against 5 tolerances: 8), with sixteen reversals over the designed run's eight periods, all crossing; the
    design keeps within excite's limits. Without a tolerance the design is the gravity crossing's alone, as before."""
    dyn = WamDynamics(None)
    lim = _limits()
    pose = np.array([0.2, 0.0, -0.1, 1.5, -0.9, 0.1, 0.4])
    q, qd, qdd = _two_harmonic(6, pose, amplitude_rad=0.5, period_s=6.0)
    old = design_crossing(dyn, FrictionModel.table_4_1(), pose, 6, GAP_RAD, 0.0065, lim, q, qd)
    assert old.separation < 0.01 and old.seen_by == "torque"
    cr = design_crossing(dyn, FrictionModel.table_4_1(), pose, 6, GAP_RAD, 0.0065, lim, q, qd,
                         tol_rad=2e-4, fc_Nm=0.054, run_qdd=qdd)
    assert cr.seen_by == "reversals" and cr.torque_separation < 0.01
    assert cr.separation == pytest.approx(GAP_RAD / (MIN_BAND_TOLERANCES * 2e-4)) and cr.separation > 2
    assert cr.reversals[1:] == (16, 16)
    assert cr.original == pytest.approx(cr.reversals_original[0]) and cr.reversals_original[1] >= 1
    assert cr.trajectory.moving == [6] and cr.limit_use.worst[2] <= 0.95 + 1e-9


def test_a_wrist_sweep_whose_gap_the_run_cannot_decide_gets_a_reversal_run_that_decides_it(tmp_path):
    """The independent generator's joint-7 sweep with a medium motor-side gap (250 Hz, seed fixed before the run
    was looked at; observable: the link changed flank 4 times): the run names nothing (the onset test saw the
    measurement lead by 5.1 mrad at reversals, p = 0.0044, not below the threshold); the joint is a suspect for
    that lead, the design moves joint 7 alone and predicts the gap at its reversals above 2 noise floors (the
    crossing design alone predicted 1e-5 on such runs), and the designed run, made by the generator with the same
    truth, names backlash alone and pooled with the run (``wamctl diagnose RUN NEXT``). (Measured when written:
    7.8 noise floors, 16 of 16 reversals crossing; backlash named in both.)"""
    import logging

    from gen_independent import follow_up, generate

    from wamctl.analysis.diagnosis.estimator import ModelDiagnosis
    from wamctl.analysis.diagnosis.pooled import PooledDiagnosis
    from wamctl.experiments.diagnose_next import backlash_suspects, next_experiment_backlash
    from wamctl.runs.measured import load_run_data

    case = {"id": "bkl-wrist-11", "seed": 11, "links": "nominal", "rate_hz": 250, "noise": "quiet",
            "jitter": "stamp", "excitation": "sweep", "joint": 7, "effects": [{"name": "backlash", "size": "medium"}]}
    logging.disable(logging.WARNING)
    try:
        r = generate(case, tmp_path / case["id"])
        assert r.truth["effects"][0]["observable"]
        data = load_run_data(r.path)
        diag = ModelDiagnosis().fit(data)
        assert "backlash" not in diag.effects_found_
        c = diag.joints_[6].candidates["backlash"]
        assert c["encoder_side"] == "motor" and diag.threshold_ < c["p_value"] < 0.05
        assert backlash_suspects(diag)[:1] == [6]
        out = next_experiment_backlash(diag, data, r.path, tmp_path)
        assert out["spec"] == "next_experiment.yaml" and out["joints"] == [7] and out["seen_by"] == "reversals"
        assert out["separation_noise_floors"] > 2 and out["reversals"]["crossing"] >= 8
        assert "led the link" in out["why"]
        follow_up(r.path, tmp_path / out["spec"], tmp_path / "next")
        data2 = load_run_data(tmp_path / "next")
        diag2 = ModelDiagnosis().fit(data2)
        pooled = PooledDiagnosis([diag, diag2], ["run", "next"], [data, data2]).fit().to_dict(
            [str(r.path), str(tmp_path / "next")])
    finally:
        logging.disable(logging.NOTSET)
    assert diag2.effects_found_[:1] == ["backlash"]
    assert pooled["effects_found"][:1] == ["backlash"]
    # the design's figure is the predicted power of that decision, sized to 0.9 within 120 s; the statistic the
    # designed run's test then gave is at least the predicted median (the prediction takes the first run's onset
    # scatter, and a run that repeats one motion scatters less; measured when written: predicted 8.1 with power
    # 0.97 over 6 periods of 16 s, seen 92)
    assert out["power"] >= 0.9 and out["decisive"] and out["duration_s"] <= 120.0
    seen = diag2.joints_[6].candidates["backlash"]
    assert seen["encoder_side"] == "motor" and np.sqrt(seen["F"]) >= out["separation_noise_floors"]


def test_no_reversal_run_for_a_joint_whose_own_reversals_showed_no_lead(tmp_path):
    """The independent generator's clean joint-1 sweep (no gap; seed fixed before the run was looked at): joint 1
    carries no gravity, so the crossing design has nothing to cross, and the reversal design would move it back
    and forth; but the run's own reversals (6, each where the link rests on its own friction) were chances enough
    for a gap to show, and the measurement did not lead the model: no run is designed, and the why says so. (The
    dev split's clean-heavier_3_4-001 got such a needless design, pooled to link_parameters.)"""
    import logging

    from gen_independent import generate

    from wamctl.analysis.diagnosis.estimator import ModelDiagnosis
    from wamctl.experiments.diagnose_next import next_experiment_backlash
    from wamctl.runs.measured import load_run_data

    case = {"id": "clean-j1", "seed": 5, "links": "nominal", "rate_hz": 250, "noise": "quiet", "jitter": "stamp",
            "excitation": "sweep", "joint": 1, "effects": []}
    logging.disable(logging.WARNING)
    try:
        r = generate(case, tmp_path / case["id"])
        data = load_run_data(r.path)
        diag = ModelDiagnosis().fit(data)
    finally:
        logging.disable(logging.NOTSET)
    assert diag.effects_found_ == []
    out = next_experiment_backlash(diag, data, r.path, tmp_path, joints=[0])
    assert out["spec"] is None and not (tmp_path / "next_experiment.yaml").exists()
    assert "reversals where the link rests on its own friction" in out["why"]
    assert "below the backlash test's resolution" in out["why"]
