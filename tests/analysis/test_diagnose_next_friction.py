"""Issue 28, the friction pair: a friction drift against a Stribeck effect, the run that tells them apart, and the
runs pooled deciding.

Cases: a drift and a Stribeck model built by hand (the criterion's two directions, no fit: a run whose slow speeds
fall early cannot tell them, the same speeds repeated over the run can); and the loop on the independent
generator's dev case ``pair-delay+stribeck-009`` (``cases(10, 0, seed=0, 20)``: a 6.2 ms delay and a large Stribeck
effect at joint 7 on a joint-7 sweep, 250 Hz), whose diagnosis leaves friction_drift and stribeck ambiguous at
joint 7 and names the delay: the designed run is made by the generator with the same truth and both runs pooled.
"""

from __future__ import annotations

import logging

import numpy as np
import pytest
import yaml

from wamctl.analysis.diagnosis import friction_design as FD


def _hyp(**kw):
    base = dict(j=6, lev_s=np.array([0.3, 0.3, 0.5, 0.5]), c_s=np.array([0.25, 0.25]), vs_rad_s=0.04,
                lev_d=np.array([0.3, 0.3, 0.5, 0.5]), c_d=np.array([-0.3, -0.3]), T_s=20.0,
                tb=np.array([0.3, 0.3, 0.5, 0.5]), duration_s=100.0)
    base.update(kw)
    return FD.Hypotheses(**base)


def test_the_same_speeds_repeated_over_the_run_part_a_drift_from_a_stribeck_effect():
    """A Stribeck effect of 0.25 N m below 0.04 rad/s against a 30 % warm-up drift (T 20 s), floor 0.01 N m: on a
    run that is slow only in its first 20 s (0.03 rad/s, then 0.8) a drift reproduces the Stribeck torque exactly
    (the criterion's smaller direction is 0); a back-and-forth motion through the same slow and fast speeds repeated
    over 100 s parts them in both directions. (When written: 1e-13; 5.5 and 3.8 noise floors.)"""
    hyp = _hyp()
    t = np.arange(0, 100, 0.1)
    early_slow = np.where(t < 20, 0.03, 0.8) * np.sign(np.sin(2 * np.pi * t / 4.0) + 1e-9)
    repeated = 0.8 * np.sin(2 * np.pi * t / 8.0) ** 3
    sep_run = FD.separation(hyp, early_slow, t, 0.01)
    sep_new = FD.separation(hyp, repeated, t, 0.01)
    assert sep_run["separation"] < 1e-6 and sep_run["drift_true"] > 1
    assert sep_new["stribeck_true"] > 5 and sep_new["drift_true"] > 3
    # each hypothesis reproduces itself: a Stribeck torque refitted by a Stribeck model leaves nothing
    X = np.column_stack([FD.classic_friction_columns(repeated), np.ones(len(t))])
    y = FD.stribeck_torque(hyp, repeated)
    assert FD._best_refit(y, X, [FD.stribeck_columns(repeated, hyp.vs_rad_s)]) < 1e-9


def test_a_joint_that_hardly_moves_has_no_separation():
    hyp = _hyp()
    t = np.arange(0, 10, 0.1)
    assert FD.separation(hyp, np.full(len(t), 0.001), t, 0.01)["separation"] == 0.0


def _diagnose(path):
    from wamctl.analysis.diagnosis.estimator import ModelDiagnosis
    from wamctl.runs.measured import load_run_data

    logging.disable(logging.WARNING)
    try:
        data = load_run_data(path)
        return ModelDiagnosis().fit(data), data
    finally:
        logging.disable(logging.NOTSET)


@pytest.fixture(scope="module")
def loop(tmp_path_factory):
    """The dev case diagnosed, its designed run made by the generator with the same truth, both pooled."""
    from gen_independent import cases, follow_up, generate

    from wamctl.analysis.diagnosis.pooled import PooledDiagnosis
    from wamctl.experiments.diagnose_next import next_experiment_friction

    root = tmp_path_factory.mktemp("friction_loop")
    case = next(c for c in cases(10, 0, 0, 20) if c["id"] == "pair-delay+stribeck-009")
    first = generate(case, root / "run").path
    diag, data = _diagnose(first)
    out = next_experiment_friction(diag, data, first, root)
    nxt = follow_up(first, root / "next_experiment.yaml", root / "next")
    diag2, data2 = _diagnose(nxt.path)
    pooled = PooledDiagnosis([diag, diag2], ["run", "next"], [data, data2]).fit()
    return {"diag": diag, "out": out, "status": nxt.status, "pooled": pooled, "root": root}


def test_the_ambiguous_friction_pair_gets_a_run_designed_to_part_it(loop):
    """The run leaves friction_drift and stribeck ambiguous at joint 7; the design moves joint 7 alone, within
    excite's limits, and predicts a separation above the target of 2 noise floors where the run's is below it.
    (When written: 1.3 -> 8.2 noise floors, an 8 s period 8 times.)"""
    from wamctl.experiments.excitation import plan
    from wamctl.specs import load_spec

    assert ("friction_drift", "stribeck") in loop["diag"].ambiguous_
    out = loop["out"]
    assert out["spec"] == "next_experiment.yaml" and out["joints"] == [7]
    assert out["original_separation_noise_floors"] < 2 < out["separation_noise_floors"]
    assert out["decisive"] and out["periods"] >= 3
    spec = load_spec(loop["root"] / "next_experiment.yaml")
    plan(spec, loop["root"]).check_limits()
    assert "drift" in out["why"] and "Stribeck" in out["why"]
    text = (loop["root"] / "next_experiment.yaml").read_text()
    assert text.startswith("# designed by wamctl diagnose:") and yaml.safe_load(text)["excitation"]["joints"] == [7]


def test_the_two_runs_pooled_decide_stribeck_and_keep_the_delay(loop):
    """The generator runs the spec (status ok); pooled, Stribeck beats the drift head to head on the runs stacked
    (the drift adds nothing beyond it), the pair is no longer ambiguous, and the delay the first run named is kept
    (no run's delay-or-inertia evidence contradicts it). Before: pooled named stribeck and link_parameters, with
    delay or inertia ambiguous and the friction pair dropped silently."""
    assert loop["status"] == "ok"
    p = loop["pooled"]
    assert p.effects_found_[:2] in (["stribeck", "delay"], ["delay", "stribeck"])
    assert p.ambiguous_ == []
    f = next(f for f in p.findings_ if f["name"] == "stribeck")
    h2h = f["head_to_head"]
    assert h2h["outcome"] == "stribeck" and h2h["left_ambiguous_by"] == ["run"]
    assert h2h["stribeck_beyond_friction_drift"]["named"] and not h2h["friction_drift_beyond_stribeck"]["named"]
    d = next(f for f in p.findings_ if f["name"] == "delay")
    assert d["delay_or_inertia"]["named_by"] == ["run"] and d["delay_or_inertia"]["contradicted_by"] == []
