"""wamctl diagnose, second round (issue 15): honest about what it cannot tell, right on data it was not tuned to.

* a real-style recording (noise, no gains in meta.yaml) where a payload is moved by two joints only: the mass with
  an interval, the centre-of-mass component the motion cannot feel reported as not identified;
* the controller's gains estimated from the log when missing or wrong; torques beyond the limits kept as data;
  measured velocities used;
* a delay measured at 100 Hz to 1 kHz, with jittered time stamps;
* the head-to-head decision table, the block bootstrap's coverage, the profile interval, the rank test;
* a small fixed subset of the independent generator's study (the full study is benchmarks/bench_diagnose.py).

Tolerances were fixed before the runs were looked at (each is stated where it is used); the seeds are not the
benchmark's.
"""

from __future__ import annotations

import json
import logging

import numpy as np
import pandas as pd
import pytest
import yaml
from diagnosis_gen import DT_S, generate_run, simulate, write_measured
from once import independent_run, make_once

from wamctl.analysis.diagnosis import headtohead
from wamctl.analysis.diagnosis.estimator import ModelDiagnosis
from wamctl.analysis.diagnosis.uncertainty import estimable, group_bootstrap, percentile_ci, profile_ci
from wamctl.control.trajectory import ReferenceBuilder
from wamctl.experiments.diagnose import simulate_positions
from wamctl.model import params as P
from wamctl.model.dynamics import WamDynamics
from wamctl.runs.measured import load_run_data

PAYLOAD = {"mass_kg": 1.0, "com_m": [0.03, -0.02, 0.08]}
Q0_PLANAR = np.array([0.0, -0.1, 0.0, 1.9, 0.0, 0.0, 0.0])   # joint 3 at zero: the axes of joints 2 and 4 parallel


def _two_joint_run(root, seed: int):
    """A recording where only joints 2 and 4 move (LSPB back and forth), with a payload the model does not
    declare, position and torque noise, and meta.yaml without the controller's gains."""
    rng = np.random.default_rng(seed)
    b = ReferenceBuilder(Q0_PLANAR, DT_S).hold(0.3)
    for k in range(24):
        sgn = 1 if k % 2 else -1
        b.move({1: sgn * float(rng.uniform(0.2, 0.35)), 3: sgn * float(rng.uniform(0.3, 0.6))},
               float(rng.uniform(0.1, 0.3)), 0.25)
    plant = {"friction": "table_4_1", "effects": {"payload": PAYLOAD},
             "sensors": {"encoder_counts_per_rev": 4096, "position_noise_rad": 2e-5, "torque_noise_Nm": 0.02}}
    rows = simulate(plant, b.build(), Q0_PLANAR, seed)
    path = write_measured(root / f"two-joints-{seed}", rows, Q0_PLANAR)
    meta = yaml.safe_load((path / "meta.yaml").read_text())
    meta["controller"] = {"kind": "pd_g"}                      # the gains are not known
    (path / "meta.yaml").write_text(yaml.safe_dump(meta))
    return path


@pytest.fixture(scope="module")
def two_joints(tmp_path_factory):
    path = _two_joint_run(tmp_path_factory.mktemp("two"), 8)
    diag = ModelDiagnosis(simulator=simulate_positions).fit(load_run_data(path))
    return path, diag, json.loads(json.dumps(diag.to_dict(str(path))))


def test_payload_moved_by_two_joints_reports_what_it_cannot_determine(two_joints):
    """Mass: named, its interval contains the truth and is narrower than 10 % of it. Centre of mass: the component
    along the common axis of joints 2 and 4 (the frame-7 axis parallel to it, at q0) is reported as not
    identified (None, listed, no interval); every component reported is within 1 cm of the truth. The payload
    was weighed against the arm's own link errors and won."""
    _, diag, out = two_joints
    assert out["effects_found"] == ["payload"], out["effects_found"]
    e = next(e for e in out["joints"]["2"]["effects"] if e["name"] == "payload")
    lo, hi = e["params_ci"]["mass_kg"]
    assert lo <= PAYLOAD["mass_kg"] <= hi and hi - lo < 0.1 * PAYLOAD["mass_kg"]
    assert lo <= e["params"]["mass_kg"] <= hi
    R = WamDynamics().link7_pose(Q0_PLANAR)[:3, :3]
    axis_in_7 = R.T @ np.array([0.0, 1.0, 0.0])     # joint 2's axis (world y at q1 = 0) in frame-7 axes
    blind = "xyz"[int(np.argmax(np.abs(axis_in_7)))]
    assert np.abs(axis_in_7).max() > 0.99
    assert f"com_{blind}_m" in e["not_identified"] and e["params"][f"com_{blind}_m"] is None
    assert e["params_ci"][f"com_{blind}_m"] == [None, None]          # no interval for what is not determined
    assert out["payload_or_links"]["outcome"] == "payload"           # beyond what the links' errors can make
    for i, ax in enumerate("xyz"):
        v = e["params"][f"com_{ax}_m"]
        if v is not None:
            assert abs(v - PAYLOAD["com_m"][i]) < 0.01, (ax, v)
            assert e["params_ci"][f"com_{ax}_m"][0] <= v <= e["params_ci"][f"com_{ax}_m"][1]


def test_model_file_lists_what_the_data_did_not_determine(two_joints):
    """model.yaml must hold a whole centre of mass to run, but the component the two joints cannot feel is listed
    under ``diagnosis.not_identified`` with the note that its value is not an estimate (a real 4-DOF log showed a
    model file with the full centre of mass and no word of it), and the components that were determined are not."""
    from wamctl.analysis.diagnosis.augmented import NOT_IDENTIFIED_NOTE, model_file

    path, diag, out = two_joints
    e = next(e for e in out["joints"]["2"]["effects"] if e["name"] == "payload")
    mf = model_file(diag, str(path))
    assert len(mf["effects"]["payload"]["com_m"]) == 3
    assert mf["diagnosis"]["not_identified"] == {"payload": sorted(e["not_identified"])}
    assert [k for k in ("com_x_m", "com_y_m", "com_z_m") if k not in e["not_identified"]]   # some determined
    assert mf["diagnosis"]["note"] == NOT_IDENTIFIED_NOTE


def test_missing_gains_are_estimated_from_the_log(two_joints):
    """Gains absent from meta.yaml: estimated from the log within 2 % at the moving joints, said so, and the
    closed-loop check runs with them (the position error drops with the payload found)."""
    _, diag, out = two_joints
    pc = out["position_check"]
    g = pc["controller_gains"]
    assert pc["skipped"] is None and "estimated from the log" in g["source"]
    for j in (1, 3):
        assert g["kp"][j] == pytest.approx(P.KP[j], rel=0.02)
        assert g["kd"][j] == pytest.approx(P.KD[j], rel=0.02)
    for j in ("2", "4"):
        d = out["joints"][j]
        assert d["position_rms_after_rad"] < d["position_rms_before_rad"]


def test_wrong_gains_are_replaced_and_said(two_joints, tmp_path):
    path, _, _ = two_joints
    meta = yaml.safe_load((path / "meta.yaml").read_text())
    meta["controller"] = {"kind": "pd_g", "kp": (2 * P.KP).tolist(), "kd": P.KD.tolist()}
    d = tmp_path / "wrong"
    d.mkdir()
    (d / "meta.yaml").write_text(yaml.safe_dump(meta))
    (d / "data.parquet").write_bytes((path / "data.parquet").read_bytes())
    diag = ModelDiagnosis(simulator=simulate_positions).fit(load_run_data(d))
    g = diag.gains_
    assert "do not fit the log" in g["source"]
    assert g["kp"][1] == pytest.approx(P.KP[1], rel=0.02)


@pytest.fixture(scope="module")
def short_delay(tmp_path_factory):
    """A 6 ms delay (first generator), 20 s at 500 Hz."""
    root = tmp_path_factory.mktemp("delay")
    g = generate_run(root, "delay", 61, duration_s=20.0)
    return g, pd.read_parquet(g.path / "data.parquet"), yaml.safe_load((g.path / "meta.yaml").read_text())


def _resampled(df: pd.DataFrame, rate: int, rng) -> pd.DataFrame:
    """The 500 Hz log as a logger at ``rate`` would have written it: every k-th row (100, 250 Hz), or at 1 kHz the
    positions interpolated and the held torque repeated; time stamps with a jitter of 2 % of the period."""
    if rate <= 500:
        out = df.iloc[:: 500 // rate].reset_index(drop=True)
    else:
        t = np.arange(0, df["t"].iloc[-1], 1.0 / rate)
        out = pd.DataFrame({"t": t})
        k = np.minimum(np.searchsorted(df["t"].to_numpy(), t, side="right") - 1, len(df) - 1)
        for c in df.columns[1:]:
            out[c] = np.interp(t, df["t"], df[c]) if not c.startswith("tau") else df[c].to_numpy()[k]
    out["t"] = out["t"] + rng.uniform(-0.02, 0.02, len(out)) / rate
    return out


@pytest.mark.parametrize("rate", [100, 250, 1000])
def test_delay_is_measured_at_any_rate_with_jittered_stamps(short_delay, tmp_path, rate):
    """The delay named, within 1.5 ms of the truth, from the same run logged at 100, 250 and 1000 Hz."""
    g, df, meta = short_delay
    d = tmp_path / f"r{rate}"
    d.mkdir()
    _resampled(df, rate, np.random.default_rng(rate)).to_parquet(d / "data.parquet", index=False)
    (d / "meta.yaml").write_text(yaml.safe_dump(dict(meta, sample_rate_hz=rate)))
    diag = ModelDiagnosis().fit(load_run_data(d))
    assert "delay" in diag.effects_found_, diag.to_dict()["effects_found"]
    found = [diag.effect_params(j, "delay")["delay_s"] for j, r in diag.joints_.items()
             if any(t["name"] == "delay" for t in r.kept)]
    assert np.median(found) == pytest.approx(g.effect_spec["delay_s"], abs=1.5e-3)


def test_torque_beyond_the_limits_is_data_and_velocities_are_used(tmp_path):
    g = generate_run(tmp_path, None, 62, duration_s=10.0)
    df = pd.read_parquet(g.path / "data.parquet")
    df.loc[100:120, "tau_2"] = 1.5 * P.TAU_MAX_NM[1]
    q = df[[f"q_{j}" for j in range(1, 8)]].to_numpy()
    qd = np.gradient(q, df["t"].to_numpy(), axis=0)
    for j in range(7):
        df[f"qd_{j + 1}"] = qd[:, j]
    df.to_parquet(g.path / "data.parquet", index=False)
    with caplog_off():
        diag = ModelDiagnosis().fit(load_run_data(g.path))
    out = diag.to_dict()
    assert diag.conclusive_
    assert any("joint 2" in w and "limit" in w for w in out["warnings"])
    assert out["method"]["velocities"] == "measured (qd columns)"


class caplog_off:
    def __enter__(self):
        logging.disable(logging.WARNING)

    def __exit__(self, *a):
        logging.disable(logging.NOTSET)


# ------------------------------------------------------------------------------------- statistics
def test_head_to_head_decision_table(monkeypatch):
    """a | b and b | a decide: wins, loses, both (the stronger now), neither (ambiguous)."""
    def test(p):
        return {"p_value": p, "delta_bic": -10.0 if p < 0.01 else 5.0}

    table = {("a", "b"): (test(1e-9), test(0.5)), ("a", "c"): (test(0.5), test(0.5)),
             ("a", "d"): (test(0.5), test(1e-9)), ("d", "c"): (test(1e-9), test(0.5)),
             ("a", "e"): (test(1e-9), test(1e-9))}
    monkeypatch.setattr(headtohead, "beyond_tests",
                        lambda des, jd, terms, a, b, e_base, rc=None: table[(a["name"], b["name"])])
    ent = {n: {"name": n} for n in "abcde"}
    winner, group, _ = headtohead.tournament(None, None, [], [ent["a"], ent["b"]], None, 0.01)
    assert winner["name"] == "a" and not group
    winner, group, _ = headtohead.tournament(None, None, [], [ent["a"], ent["c"]], None, 0.01)
    assert winner is None and [g["name"] for g in group] == ["a", "c"]
    winner, group, _ = headtohead.tournament(None, None, [], [ent["a"], ent["d"]], None, 0.01)
    assert winner["name"] == "d"
    # a and c tie, then d beats a and c: the new champion meets the ambiguous one again
    winner, group, _ = headtohead.tournament(None, None, [], [ent["a"], ent["c"], ent["d"]], None, 0.01)
    assert winner["name"] == "d" and not group
    winner, group, _ = headtohead.tournament(None, None, [], [ent["a"], ent["e"]], None, 0.01)
    assert winner["name"] == "a" and not group


def test_block_bootstrap_covers_the_truth():
    """Linear regression with AR(1) noise in 10 contiguous blocks: the t-widened percentile interval of the slope
    covers the truth in at least 85 % of 100 data sets (nominal 95 %; a bootstrap over 10 blocks is rough)."""
    rng = np.random.default_rng(4)
    hits = 0
    for _ in range(100):
        n = 2000
        x = np.sin(np.arange(n) / 37.0) + rng.normal(size=n)
        e = np.zeros(n)
        w = rng.normal(size=n)
        for i in range(1, n):
            e[i] = 0.9 * e[i - 1] + w[i]
        y = 2.0 * x + e
        X = np.column_stack([np.ones(n), x])
        blocks = np.arange(n) * 10 // n
        reps = group_bootstrap(X, y, blocks, 200, rng)
        est = np.linalg.lstsq(X, y, rcond=None)[0][1]
        lo, hi = percentile_ci(reps[:, 1], center=est, n_groups=10)
        hits += lo <= 2.0 <= hi
    assert hits >= 85


def test_profile_interval_and_rank():
    h = np.linspace(0.0, 2.0, 201)
    ssr = 100.0 * (1 + 0.01 * (h - 1.0) ** 2)          # n_eff 1000: chi2 3.84 -> |h - 1| < 0.62
    lo, hi = profile_ci(h, ssr, 1000.0)
    assert lo == pytest.approx(1 - 0.62, abs=0.02) and hi == pytest.approx(1 + 0.62, abs=0.02)
    lo, hi = profile_ci(h, 100.0 * (1 + 1e-6 * (h - 1.0) ** 2), 1000.0)
    assert lo is None and hi is None                     # flat: open at both ends
    rng = np.random.default_rng(5)
    a = rng.normal(size=200)
    X = np.column_stack([a, 2 * a, rng.normal(size=200)])  # the first two cannot be told apart
    assert estimable(X, [0, 1, 2]) == [False, False, True]


# ------------------------------------------------------------------------------------- independent data
INDEPENDENT_SUBSET = ("stribeck-001", "position_ripple-000", "payload-002", "delay-001", "friction_drift-000",
                      "clean-heavier_3_4-001", "clean-random_10pct-002")


@pytest.fixture(scope="module")
def independent(tmp_path_factory):
    """A fixed subset of the independent generator's plan (seed 7, neither the benchmark's dev nor its report
    split), each run diagnosed once; made once per session for every xdist worker (tests/once.py: each worker that
    got one of its tests had made them)."""
    return make_once(tmp_path_factory, "diagnose_v2_independent",
                     lambda root: _diagnose_the_independent_subset(tmp_path_factory))


def _diagnose_the_independent_subset(tmp_path_factory) -> dict:
    out = {}
    for cid in INDEPENDENT_SUBSET:       # the clean runs are test_friction_id's too (once.independent_run)
        r = independent_run(tmp_path_factory, cid)
        with caplog_off():
            out[cid] = (r.truth, ModelDiagnosis().fit(load_run_data(r.path)).to_dict())
    return out


def test_independent_subset_names_nothing_that_is_not_there(independent):
    """On data from the independent generator: no effect that is not there is named (first or at all), clean runs
    with perturbed links name nothing but possibly link_parameters, and at least 4 of the 5 effect runs name
    their effect first. A payload is a change of link 7's parameters (docs/diagnosis-report.md), so on a payload
    run link_parameters is not an effect that is not there (it is not the right name either)."""
    right = 0
    for cid, (truth, out) in independent.items():
        ok = set(truth["expected_effects"]) | set(truth["acceptable_extra"])
        if "payload" in ok:
            ok.add("link_parameters")
        assert set(out["effects_found"]) <= ok, (cid, out["effects_found"])
        if truth["expected_effects"]:
            right += bool(out["effects_found"]) and out["effects_found"][0] in truth["expected_effects"]
    assert right >= 4


def test_every_effect_carries_intervals(independent):
    for cid, (_, out) in independent.items():
        for d in out["joints"].values():
            for e in d["effects"]:
                assert set(e["params_ci"]) <= set(e["params"]) | {"com_x_m", "com_y_m", "com_z_m"}
                for k, (lo, hi) in e["params_ci"].items():
                    v = e["params"].get(k)
                    if v is not None and lo is not None and hi is not None:
                        assert lo <= v <= hi, (cid, e["name"], k)
                assert "not_identified" in e


def test_a_candidate_an_arm_wide_check_ruled_out_stays_out(two_joints, monkeypatch):
    """A joint diagnosed again by a later arm-wide check (the breakaways, say) keeps out what an earlier one ruled
    out there (a payload the links explain, a delay the other joints contradict), keeps the ambiguity that check
    left, and keeps the arm's one payload term where the arm has a payload."""
    _, diag, _ = two_joints
    j = 3                                              # joint 4 (0-based 3): it carries the arm's payload
    assert diag.payload_ is not None and j + 1 in diag.payload_["joints_fitted"]
    seen = []
    real = diag._diagnose_joint
    monkeypatch.setattr(diag, "_diagnose_joint", lambda jd, tests, rejected=None: seen.append(dict(rejected))
                        or real(jd, tests, rejected))
    group = {"names": ["payload", "link_parameters"], "step": "arm", "evidence": {}}
    diag.rejected_[j] = {"delay": "the other joints contradict it"}
    diag.arm_ambiguous_[j] = [group]
    tests = ["stribeck", "position_ripple", "payload", "friction_drift"]
    diag._rediagnose(j, tests, "stribeck", "the breakaways show none")
    assert seen == [{"delay": "the other joints contradict it", "stribeck": "the breakaways show none"}]
    res = diag.joints_[j]
    assert group in res.ambiguous
    kept = {t["name"]: t for t in res.kept}
    assert "stribeck" not in kept and "delay" not in kept
    assert kept["payload"]["h_all"] == ("global", None)      # the arm's one payload, not the joint's own fit


def test_a_delay_the_joints_disagree_on_is_explained_joint_by_joint():
    """The reason names each joint that kept a delay with its own figure, and how many agree (a user once read
    "seen at 2 of 7 joints (delays 3.2, 9.5, 7.5 ms)": three delays for two joints, none named)."""
    from types import SimpleNamespace

    from wamctl.analysis.diagnosis.arm import delay_disagreements

    def joint(delay_s=None):
        return SimpleNamespace(kept=[] if delay_s is None else [{"name": "delay", "h_all": delay_s}])
    joints = {j: joint() for j in range(7)}
    joints[1], joints[3], joints[5] = joint(2.0e-3), joint(6.0e-3), joint(12.0e-3)    # one within 2 ms of 6
    why = delay_disagreements(joints, 2e-3)
    assert set(why) == {1, 3, 5} and len(set(why.values())) == 1
    text = why[1]
    assert "joints 2 (2.0 ms), 4 (6.0 ms), 6 (12.0 ms)" in text and "1 of the 7 joints diagnosed agree" in text


# ------------------------------------------------------------------------------------- breakaways
def test_a_breakaway_beside_another_effect_must_add_to_it(tmp_path):
    """Independent generator, case ``pair-position_ripple+friction_drift-001`` of ``cases(10, 20, seed=0)`` (a
    ripple at joint 2, a friction drift at joint 7, no Stribeck anywhere; the benchmark's dev split, never its
    report split). Once the drift is in joint 7's model, its breakaways read 1.2 times the Coulomb level (held-out
    onset test p ~ 1e-4), and Stribeck was named third, an effect that is not there, though the model with it
    predicts the held-out torque no better than the model with the drift alone (the joint's RMS from 0.0103 N m
    before to 0.00058 N m is the drift's). Not named now, and the candidate says why."""
    from gen_independent import cases, generate

    plan = {c["id"]: c for c in cases(10, 20, seed=0)}
    r = generate(plan["pair-position_ripple+friction_drift-001"], tmp_path / "run")
    with caplog_off():
        out = ModelDiagnosis().fit(load_run_data(r.path)).to_dict()
    assert sorted(out["effects_found"]) == ["friction_drift", "position_ripple"], out["effects_found"]
    cand = next(c for c in out["joints"]["7"]["candidates"] if c["name"] == "stribeck")
    assert "no better than without it" in cand["reason"], cand
    assert out["joints"]["7"]["torque_rms_after_Nm"] < 0.1 * out["joints"]["7"]["torque_rms_before_Nm"]


def test_an_effect_seen_at_onsets_must_take_something_off_the_held_out_torque(tmp_path):
    """Independent generator, ``cases(21, 0, seed=4242)`` (neither the benchmark's dev nor its report split).

    ``backlash-000``: a small gap on the motor side of joint 7 (the light wrist, free motion). Its breakaways read
    1.2-1.3 times the Coulomb level, and Stribeck seen there was named first, an effect that is not there, though
    the joint's model with it predicted the held-out torque worse than without it (RMS 0.00672 against 0.00661
    N m). Now nothing is named there, and the candidate says why.

    ``backlash-014``: a large gap on the motor side of joint 7, seen at the reversals (the measurement leads the
    link). Its model has no torque term (the link follows the measurement at a constant offset), so the held-out
    torque cannot show it: still named."""
    from gen_independent import cases, generate

    plan = {c["id"]: c for c in cases(21, 0, seed=4242)}
    out = {}
    for cid in ("backlash-000", "backlash-014"):
        r = generate(plan[cid], tmp_path / cid)
        with caplog_off():
            out[cid] = ModelDiagnosis().fit(load_run_data(r.path)).to_dict()
    assert out["backlash-000"]["effects_found"] == []
    cand = next(c for c in out["backlash-000"]["joints"]["7"]["candidates"] if c["name"] == "stribeck")
    assert "no better than without it" in cand["reason"], cand
    assert out["backlash-014"]["effects_found"] == ["backlash"]
    eff = out["backlash-014"]["joints"]["7"]["effects"][0]
    assert eff["params"]["encoder_side"] == "motor"


# ------------------------------------------------------------------------------------- friction drift
def test_a_linear_friction_drift_is_measured_by_its_change_over_the_run(tmp_path):
    """Independent generator, ``friction_drift-004`` of ``cases(10, 20, seed=0)`` (dev split): joint 1's friction
    falls linearly by 36.8 % over an 18 s run of free motion. The drift's time constant once had to lie within 4
    run lengths and its end level (t -> infinity) had to stay non-negative, so a fall of more than 22 % over the
    run could not be represented (held-out torque ratio 0.44; the same drift on a sweep was not named at all). Now
    the levels at the start of the run are the ones kept non-negative and the time constant may reach 30 run
    lengths: the change over the run is measured (it read -0.3684 against the truth's -0.3684; the test allows 2
    points), the fraction it would drift to is reported not identified (the time constant's interval is open
    above), and the held-out torque falls below a third."""
    import yaml
    from gen_independent import cases, generate

    plan = {c["id"]: c for c in cases(10, 20, seed=0)}
    r = generate(plan["friction_drift-004"], tmp_path / "run")
    truth = yaml.safe_load((r.path / "truth.yaml").read_text())["effects"][0]
    assert truth["params"]["shape"] == "linear" and truth["joint"] == 1
    with caplog_off():
        diag = ModelDiagnosis().fit(load_run_data(r.path))
    out = diag.to_dict()
    assert out["effects_found"] == ["friction_drift"]
    d = out["joints"]["1"]
    e = d["effects"][0]
    assert e["params"]["change_over_run"] == pytest.approx(truth["params"]["f"], abs=0.02)
    lo, hi = e["params_ci"]["change_over_run"]
    assert lo <= e["params"]["change_over_run"] <= hi
    assert e["params"]["fraction"] is None and "fraction" in e["not_identified"]
    assert e["params_ci"]["time_constant_s"][1] is None
    assert d["torque_rms_after_Nm"] < d["torque_rms_before_Nm"] / 3
    # the model file keeps the plant's range: the same change over the run
    from wamctl.analysis.diagnosis.augmented import plant_dict

    pd_ = plant_dict(diag)["effects"]["friction_drift"]
    T, f = pd_["time_constant_s"], pd_["fraction"]
    assert -0.9 <= f <= 3.0
    assert f * -np.expm1(-diag.signals_.duration_s / T) == pytest.approx(e["params"]["change_over_run"], rel=1e-6)


def test_a_drift_within_the_friction_models_accuracy_is_not_named(tmp_path):
    """First generator, backlash run seed 55002 (the benchmark's dev split): joint 6, which has no effect, showed a
    'friction drift' of 0.2 % of its friction torque over the run (Coulomb +0.2 %, viscous -1 %, p ~ 1e-4 on a
    residual of 0.35 mN m), once time constants far beyond the run were allowed. A drift must change the friction
    torque by the minimum effect (5 %)."""
    g = generate_run(tmp_path, "backlash", 55002)
    with caplog_off():
        out = ModelDiagnosis().fit(load_run_data(g.path)).to_dict()
    assert out["effects_found"] == ["backlash"]
    cand = next(c for c in out["joints"]["6"]["candidates"] if c["name"] == "friction_drift")
    assert not cand["kept"] and "less than the 5%" in cand["reason"], cand


def test_a_drift_beyond_the_plants_range_keeps_its_change_over_the_run():
    from wamctl.analysis.diagnosis.augmented import plant_drift

    assert plant_drift(-0.4, 20.0, 30.0) == (-0.4, 20.0)                # in range: as it is
    f, T = plant_drift(-11.2, 540.0, 18.0)
    assert f == -0.9 and f * -np.expm1(-18.0 / T) == pytest.approx(-11.2 * -np.expm1(-18.0 / 540.0))
    assert plant_drift(-50.0, 10.0, 30.0)[0] == -0.9                    # unreachable: the end of the range


def test_an_effect_seen_in_the_sliding_samples_must_not_worsen_the_stalls(tmp_path):
    """First generator, backlash run seed 85006 (neither the benchmark's dev nor its report seeds): the dead band is
    at joint 2; at joint 6 a Stribeck term passed on the sliding samples (held-out RMS 0.51 -> 0.44 mN m there), but
    its breakaway levels made the stalls' residual so much worse that the joint's held-out torque doubled
    (0.56 -> 1.25 mN m, sliding samples and stalls together): it was named beside the dead band, an effect that is
    not there. Now the joint's own effects must improve the whole held-out torque."""
    g = generate_run(tmp_path, "backlash", 85006)
    with caplog_off():
        out = ModelDiagnosis().fit(load_run_data(g.path)).to_dict()
    assert out["effects_found"] == ["backlash"]
    assert out["joints"]["2"]["effects"][0]["name"] == "backlash"
    cand = next(c for c in out["joints"]["6"]["candidates"] if c["name"] == "stribeck")
    assert not cand["kept"] and "no better than without it" in cand["reason"], cand
