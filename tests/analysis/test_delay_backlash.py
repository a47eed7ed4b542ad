"""A delay against a gap behind a motor-side encoder, told apart at a joint's onsets (issue 28, D8).

The head to head of :mod:`wamctl.analysis.diagnosis.delay_backlash` on signed hidden travels made by each truth:
a delay ``tau`` makes the measurement lag the model's link by about ``tau x speed`` at every onset (positions
measured late), and the onset model run with a delay ``d`` leaves ``(tau - d) x speed``; a gap ``w`` on the motor
side makes it lead by ``w`` at the reversals only, and a delay added to the model makes that lead longer.
"""

import numpy as np
import pytest

from wamctl.analysis.diagnosis import delay_backlash as DB

TOL = 2e-4                              # detection tolerance, rad
GRID = [0.0, *DB.DELAY_GRID_S[:12]]


def _onsets(rng, n=16, same=4):
    rev = np.r_[np.ones(n - same, bool), np.zeros(same, bool)]
    speed = rng.uniform(0.1, 1.0, n)    # reversals at clearly different speeds
    return rev, speed


def _delay_truth(rng, tau_s=0.006, same=4):
    rev, v = _onsets(rng, same=same)
    noise = rng.normal(0, 0.2 * TOL, len(v))
    return {d: (tau_s - d) * v + noise for d in GRID}, rev


def _gap_truth(rng, gap_rad=0.004):
    rev, v = _onsets(rng)
    noise = rng.normal(0, 0.2 * TOL, len(v))
    base = np.where(rev, -gap_rad * rng.uniform(0.7, 1.0, len(v)), 0.0) + noise
    return {d: base - d * v for d in GRID}, rev


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_delay_is_named_delay_not_a_gap(seed):
    travel, rev = _delay_truth(np.random.default_rng(seed))
    r = DB.compare(travel, rev, TOL)
    assert r["outcome"] == "delay"
    assert r["log_ratio"] <= -DB.DECIDED_LOG_RATIO
    assert r["delay_s"] == pytest.approx(0.006, abs=1.01e-3)      # the grid's step is 1 ms
    assert r["rss_delay"] < 0.2 * r["rss_gap"]


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_motor_side_gap_is_named_backlash_not_a_delay(seed):
    travel, rev = _gap_truth(np.random.default_rng(seed))
    r = DB.compare(travel, rev, TOL)
    assert r["outcome"] == "backlash"
    assert r["log_ratio"] >= DB.DECIDED_LOG_RATIO
    assert r["mean_reversal_travel_rad"] == pytest.approx(-0.0034, abs=0.0006)
    assert r["gap_log_coef"] < 0                                  # the measurement leads


def test_a_lag_at_the_reversals_is_not_a_motor_side_gap():
    """A reversal term of the lag's sign is not the gap hypothesis (a gap on the motor side leads): on a sweep's
    reversals (no same-direction onset) lagging by the delay the gap explains nothing."""
    travel, rev = _delay_truth(np.random.default_rng(5), same=0)
    r = DB.compare(travel, rev, TOL)
    assert r["rss_gap"] == pytest.approx(r["rss_neither"])


def test_too_few_reversals_are_untestable():
    travel, rev = _gap_truth(np.random.default_rng(3))
    rev = np.zeros_like(rev)
    rev[:2] = True
    r = DB.compare(travel, rev, TOL)
    assert r["outcome"] == "untestable"
    assert np.isnan(r["log_ratio"])


def _fake_runs(monkeypatch, truths):
    """Runs whose onsets at joint 7 each truth makes (``"gap"``, ``"delay"``), served to the pooled head to head
    in place of the onset model."""
    data = {}
    for r, t in enumerate(truths):
        travel, rev = (_gap_truth if t == "gap" else _delay_truth)(np.random.default_rng(10 + r))
        v = np.random.default_rng(10 + r).uniform(0.1, 1.0, len(rev))
        data[r] = (travel[0.0], rev, v, t)

    def onsets_at(d, j, delay_s):
        base, rev, v, t = data[d.r]
        return {"travel_rad": base - delay_s * v, "reversal": rev, "tol_rad": TOL}

    monkeypatch.setattr(DB, "_onsets_at", onsets_at)

    class Run:
        conclusive_ = True
        joints_ = {6: None}

        def __init__(self, r):
            self.r = r

    return [Run(r) for r in range(len(truths))]


def test_pooled_runs_share_one_width(monkeypatch):
    """Runs pooled: one gap width and one delay for all runs (the arm's). Two runs whose reversals lead by a gap
    decide ``backlash``; a run whose reversals lead stacked with one whose onsets lag by a delay does not: the
    shared width cannot be both."""
    runs = _fake_runs(monkeypatch, ["gap", "gap"])
    r = DB.pooled_head_to_head(runs, ["a", "b"], 6, 0.006)
    assert r["outcome"] == "backlash" and r["log_ratio"] >= DB.DECIDED_LOG_RATIO
    assert set(r["per_run"]) == {"a", "b"}
    runs = _fake_runs(monkeypatch, ["gap", "delay"])
    one = DB.pooled_head_to_head(runs[:1], ["a"], 6, 0.006)
    both = DB.pooled_head_to_head(runs, ["a", "b"], 6, 0.006)
    assert one["outcome"] == "backlash"
    assert both["outcome"] != "backlash" and both["log_ratio"] < one["log_ratio"]


def test_reversals_at_one_rate_cannot_part_them_two_rates_can():
    """The design's criterion: reversals all at one acceleration make a delay's lag one width (separation 0);
    at two clearly different ones the delay's lags differ by more than the onset test's resolution."""
    tol = 2e-4
    one = DB.separation(np.full(12, 4.0), 0.006, 0.004, tol)
    assert one["delay_true"] == pytest.approx(0.0, abs=1e-9) and one["separation"] == pytest.approx(0.0, abs=1e-9)
    two = DB.separation(np.r_[np.full(6, 0.5), np.full(6, 20.0)], 0.006, 0.004, tol)
    # the delay's lag: a t0 d + a d^2 / 2, t0 = sqrt(2 tol / a): 0.469 and 4.483 tolerances at 0.5 and 20 rad/s^2
    lag = DB.predicted_leads(np.array([0.5, 20.0]), 0.006, tol) / tol
    assert lag == pytest.approx([0.4693, 4.4833], rel=1e-3)
    assert two["delay_true"] == pytest.approx((lag[1] - lag[0]) / 2, rel=1e-6)
    assert two["separation"] > 0.5
    assert two["total"] == pytest.approx(two["separation"] * np.sqrt(12))


def test_the_design_finds_reversals_that_part_them():
    """A designed run of joint 4 alone within excite's limits: its reversals part a 6 ms delay from a 4 mrad gap
    by at least 2 tolerances over the run, more than a run whose reversals all come at one rate."""
    from wamctl.analysis.identification.excitation import ExcitationLimits
    from wamctl.model.dynamics import WamDynamics
    from wamctl.model.friction import FrictionModel
    from wamctl.specs.excitation import ExcitationLimitsSpec

    lim = ExcitationLimitsSpec()
    limits = ExcitationLimits(*lim.arrays(), 1 - lim.torque_margin, lim.max_cartesian_speed_m_s)
    q0 = np.array([0.0, 0.0, 0.0, 1.5, 0.0, 0.0, 0.0])
    tr, sep, scored = DB.design_two_speeds(WamDynamics(), FrictionModel.table_4_1(), q0, 3, limits, 0.006, 0.004,
                                           2e-4, per_period=2)
    assert tr.moving == [3]
    assert sep["reversals"] >= 2 * 10
    assert sep["total"] >= 2.0
    assert sep["separation"] == pytest.approx(max(s for _, s in scored), rel=0.2)


@pytest.fixture(scope="module")
def gap_run(tmp_path_factory):
    """The independent generator's dev case ``backlash-000`` (a motor-side gap at joint 5), diagnosed."""
    from gen_independent import cases, generate

    from wamctl.analysis.diagnosis.estimator import ModelDiagnosis
    from wamctl.runs.measured import load_run_data

    case = next(c for c in cases(1, 0, 0, 0) if c["id"] == "backlash-000")
    d = tmp_path_factory.mktemp("gap")
    generate(case, d)
    data = load_run_data(d)
    diag = ModelDiagnosis().fit(data)
    diag.run_data, diag.run_dir = data, d
    return diag


def test_a_delay_kept_beside_a_motor_side_gap_gives_way_at_the_gap(gap_run):
    """One run: a motor-side gap kept at joint 5 and a 5 ms delay kept there too (as the torque residual of a
    sweep with a gap once chose, report backlash-004): the onsets, which lead where a delay would make them lag,
    prefer the gap; the joint is diagnosed again without the delay, the gap stays named."""
    diag = gap_run
    j = 4
    assert DB.motor_gap_joints(diag) == [j]
    diag.joints_[j].kept.append({"name": "delay", "h_all": 0.005, "h_fold": [0.005] * diag.n_folds,
                                 "evidence": {"p_value": 1e-6}, "gain": 0.05})
    torque = [c for c in diag.candidates if c not in ("backlash", "link_parameters")]
    recs = DB.settle(diag, torque, torque + ["backlash"])
    assert [(r["joint"], r["outcome"]) for r in recs] == [(5, "backlash")]
    assert recs[0]["log_ratio"] > 3 * DB.DECIDED_LOG_RATIO
    assert recs[0]["mean_reversal_travel_rad"] < -1e-3          # the measurement leads by millimetres of rad
    names = [t["name"] for t in diag.joints_[j].kept]
    assert "delay" not in names and "backlash" in names
    assert "onsets prefer a gap" in diag.rejected_[j]["delay"]


def test_an_ambiguous_pair_gets_a_designed_run(gap_run, tmp_path):
    """Left ambiguous at joint 5 (as :func:`settle` leaves it), the next experiment moves joint 5 alone with
    reversals at different accelerations: written as next_experiment.yaml, at least 2 tolerances over the run
    (decisive), more per reversal than the run's own reversals, with its why."""
    import yaml

    from wamctl.experiments.diagnose_next import next_experiment_delay_or_gap, next_experiment_more

    diag = gap_run
    diag.joints_[4].ambiguous.append({"names": ["backlash", "delay"], "evidence": {}})
    diag.delay_vs_gap_ = [{"joint": 5, "log_ratio": 3.1, "delay_torque_s": 0.005,
                           "mean_reversal_travel_rad": -0.0024}]
    try:
        r = next_experiment_delay_or_gap(diag, diag.run_data, diag.run_dir, tmp_path)
        assert r["spec"] == "next_experiment.yaml" and r["hypotheses"] == ["delay", "backlash"]
        assert r["joints"] == [5] and r["delay_s"] == pytest.approx(0.005) and r["gap_rad"] == pytest.approx(0.0024)
        assert r["total_noise_floors"] >= 2.0 and r["decisive"]
        assert r["separation_noise_floors"] > r["original_separation_noise_floors"]
        assert "a delay's lag grows with the acceleration" in r["why"]
        spec = yaml.safe_load((tmp_path / "next_experiment.yaml").read_text())
        assert spec["excitation"]["joints"] == [5] and spec["excitation"]["periods"] == 10
        assert next_experiment_more(diag, diag.run_data, diag.run_dir, tmp_path)["hypotheses"] == ["delay",
                                                                                                   "backlash"]
    finally:
        diag.joints_[4].ambiguous.pop()
