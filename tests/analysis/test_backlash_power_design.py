"""Issue 28, motor-side backlash: the reversal run's prediction is the power of the diagnosis' own decision.

The earlier figure (the lead at one reversal over the onset test's resolution) did not grow with the number of
reversals, so it could not say whether a run would decide. The design now predicts, by Monte Carlo of the backlash
decision itself (the nested test on held-out onsets at the diagnosis' threshold, its BIC, the lead's sign and
``MIN_BAND_TOLERANCES``), the power and the median test statistic of a run of N reversals, and sizes the run to a
power of 0.9 within 120 s, or says it cannot.
"""

from __future__ import annotations

import numpy as np
import pytest

from wamctl.analysis.diagnosis.backlash_design import (
    MAX_RUN_S,
    POWER_TARGET,
    OnsetScatter,
    design_crossing,
    link_share_bounds,
    onset_folds,
    onset_pattern,
    onset_scatter,
    reversal_power,
    size_reversal_run,
)
from wamctl.analysis.diagnosis.onset_tests import backlash_decision, backlash_decision_many
from wamctl.analysis.identification.excitation import ExcitationLimits, FourierTrajectory
from wamctl.model.dynamics import WamDynamics
from wamctl.model.friction import FrictionModel
from wamctl.specs.excitation import ExcitationLimitsSpec

TOL = 2e-4                  # a wrist's detection tolerance, rad
THRESHOLD = 0.01 / 42       # alpha / (7 joints x 6 tests)
PER_PERIOD = np.array([True, True, False])      # the two-harmonic series: two reversals, then its dwell


def _limits():
    spec = ExcitationLimitsSpec()
    return ExcitationLimits(*spec.arrays(), 1 - spec.torque_margin, spec.max_cartesian_speed_m_s)


def test_the_vectorised_decision_is_the_diagnosis_rule():
    """The Monte Carlo's decision on many draws at once gives, draw by draw, the same decision and F statistic as
    the rule the diagnosis applies to a run's onsets (over 1200 draws: gaps 0, 1 and 4 mrad, 2 to 8 periods)."""
    rng = np.random.default_rng(1)
    for periods in (2, 3, 5, 8):
        rev = np.tile(PER_PERIOD, periods)[:-1]
        fold = onset_folds(len(rev))
        for gap in (0.0, 0.001, 0.004):
            lv = np.where(rev, -np.log1p(gap / TOL), 0.0) + 0.8 * rng.standard_normal((100, len(rev)))
            D = np.sign(lv) * TOL * np.expm1(np.abs(lv))
            many = backlash_decision_many(D, rev, fold, TOL, 5, THRESHOLD)
            for i in range(len(D)):
                one = backlash_decision(D[i], rev, fold, TOL, 5, THRESHOLD)
                assert bool(one.get("kept")) == bool(many["kept"][i])
                if "F" in one:
                    assert many["F"][i] == pytest.approx(one["F"], rel=1e-6, abs=1e-9)


def test_the_predicted_figure_grows_with_the_number_of_reversals():
    """A 4 mrad gap crossed at every reversal (20 detection tolerances), the onsets' log travel scattered by 0.7:
    the predicted power rises with the periods (0.05 at 3, 0.9 or more by 7) and the median test statistic about as
    the root of the number of reversals (4 to 7 periods: within 15 % of sqrt(7/4)); the old figure, the lead at
    one reversal over 5 tolerances, was 4 whatever the number."""
    lead = np.array([0.004, 0.004, 0.0])
    r = size_reversal_run(PER_PERIOD, lead, 16.0, TOL, OnsetScatter(), THRESHOLD, max_run_s=7 * 16.0)
    curve = {n: (p, t) for n, p, t in r["curve"]}
    powers = [curve[n][0] for n in range(3, 8)]
    assert powers == sorted(powers) and powers[0] < 0.2 and powers[-1] >= POWER_TARGET
    assert curve[7][1] / curve[4][1] == pytest.approx(np.sqrt(7 / 4), rel=0.15)
    assert r["reached"] and r["periods"] == 7 and r["duration_s"] == 112.0


def test_a_run_sized_to_its_power_or_said_it_cannot():
    """Sizing: the fewest periods that reach power 0.9 (an 8 mrad gap: fewer than a 4 mrad one), within 120 s; a
    gap crossed at one reversal in two whose lead the scatter swamps (1 mrad) does not reach it in 120 s, and the
    sizing says so with the longest run's power."""
    big = size_reversal_run(PER_PERIOD, np.array([0.008, 0.008, 0.0]), 16.0, TOL, OnsetScatter(), THRESHOLD)
    mid = size_reversal_run(PER_PERIOD, np.array([0.004, 0.004, 0.0]), 16.0, TOL, OnsetScatter(), THRESHOLD)
    assert big["reached"] and mid["reached"] and big["periods"] < mid["periods"]
    assert big["power"] >= POWER_TARGET and mid["duration_s"] <= MAX_RUN_S
    weak = size_reversal_run(PER_PERIOD, np.array([0.001, 0.0, 0.0]), 16.0, TOL, OnsetScatter(), THRESHOLD)
    assert not weak["reached"] and weak["periods"] == int(MAX_RUN_S // 16.0) and weak["power"] < 0.2


def test_no_gap_no_power():
    """Without a gap the decision names nothing: the predicted power (its false-alarm rate) stays below 1 %."""
    rev = np.tile(PER_PERIOD, 7)[:-1]
    r = reversal_power(rev, np.zeros(len(rev)), TOL, OnsetScatter(), THRESHOLD, draws=2000)
    assert r["power"] < 0.01


def test_the_scatter_and_the_share_come_from_the_run():
    """The onsets' scatter is measured where the run has three or more of a kind (else 0.7 assumed); the link-side
    friction share is bounded by the run's reversals: above the need ratio where the gap was crossed, below it
    where the link held."""
    d = np.array([1e-4, -1e-4, 2e-4, -4e-3, -3.5e-3, 0.0, -5e-3])
    rev = np.array([False, False, False, True, True, True, True])
    sc = onset_scatter(d, rev, TOL)
    assert sc.n_same == 3 and sc.n_lead == 2 and sc.same_log_sd == pytest.approx(
        max(np.std(np.sign(d[:3]) * np.log1p(np.abs(d[:3]) / TOL), ddof=1), 0.3))
    assert onset_scatter(d[3:], rev[3:], TOL).same_log_sd == 0.7
    b = link_share_bounds(np.array([0.01, 0.02, 0.1]), np.array([0.004, 0.004, 0.0]), 0.1, TOL)
    assert b == {"low": pytest.approx(0.2), "high": pytest.approx(1.0), "crossed": 2, "held": 1}


def test_the_wrist_design_is_sized_to_decide():
    """The joint-7 design (8 mrad gap, 0.2 mrad tolerance, the decision's threshold and the assumed scatter): a
    reversal run reaching power 0.9 within 120 s, its figure the decision's median statistic (not the lead over the
    resolution, 8), its periods those of the sizing; the pattern of its onsets: two reversals and a dwell a
    period."""
    dyn = WamDynamics(None)
    pose = np.array([0.2, 0.0, -0.1, 1.5, -0.9, 0.1, 0.4])
    w = 2 * np.pi / 6.0
    a, b = np.zeros((7, 2)), np.zeros((7, 2))
    a[6] = [0.5 * w, -0.5 * w]
    q, qd, qdd = FourierTrajectory(pose, 6.0, a, b).evaluate(np.arange(300) / 25.0)
    cr = design_crossing(dyn, FrictionModel.table_4_1(), pose, 6, 0.008, 0.0065, _limits(), q, qd, tol_rad=TOL,
                         fc_Nm=0.054, run_qdd=qdd, scatter=OnsetScatter(), threshold=THRESHOLD)
    assert cr.seen_by == "reversals" and cr.size["reached"] and cr.size["power"] >= POWER_TARGET
    assert cr.periods * cr.trajectory.period_s <= MAX_RUN_S and cr.periods == cr.size["periods"]
    assert cr.separation == pytest.approx(cr.size["t_median"]) and cr.reversals[2] == cr.size["reversals"]
    t = np.arange(int(3 * cr.trajectory.period_s * 25)) / 25.0
    assert list(onset_pattern(cr.trajectory.evaluate(t)[1][:, 6])) == [True, True, False] * 2 + [True, True]


def test_a_gravity_step_design_states_the_power_of_the_decision_that_names_the_gap():
    """The elbow crossing (joint 4 about its zero-gravity pose: an 8 mrad gap's step 4 noise floors of 5 mN m) is
    still designed, but the diagnosis names a gap behind a motor-side encoder from the leads at reversals only (the
    step is no test of it; dev backlash-024 and -026: such runs named nothing): the design states that decision's
    power over the run's own three periods, short of 0.9 (the elbow link is pressed on one flank at its turns)."""
    dyn = WamDynamics(None)
    q0 = np.array([0.0, 0.0, 0.0, 1.9, 0.0, 0.0, 0.0])
    t = np.arange(0.0, 20.0, 0.04)
    q = np.tile(q0, (len(t), 1))
    qd = np.zeros_like(q)
    q[:, 3] += 0.3 * np.sin(2 * np.pi * t / 10.0)
    qd[:, 3] = 0.3 * 2 * np.pi / 10.0 * np.cos(2 * np.pi * t / 10.0)
    cr = design_crossing(dyn, FrictionModel.table_4_1(), q0, 3, 0.008, 0.005, _limits(), q, qd, tol_rad=TOL,
                         fc_Nm=0.9, run_qdd=np.zeros_like(q), scatter=OnsetScatter(), threshold=THRESHOLD)
    assert cr.seen_by == "torque" and cr.separation > 2 and cr.periods == 3
    assert cr.size is not None and cr.size["periods"] == 3 and not cr.size["reached"]
    assert cr.size["power"] < POWER_TARGET
