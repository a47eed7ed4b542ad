"""Issue 28 item 2: ``wamctl diagnose RUN1 RUN2 ...`` pools runs of one arm.

Three runs of the same plant made by the independent generator (seed 9150: a large wrist payload of 1.498 kg at
(25.9, 20.1, 26.4) mm from the flange, the links as declared, the same friction), each a sweep of one joint: the
elbow (4), the shoulder (2), the wrist (6). Alone, no run identifies the payload: each sweep names it with its mass
and centre of mass not identified; the shoulder sweep only on the declared link accuracy (it leaves 4.86 noise
floors that link errors within it cannot reproduce, but link errors within twice it could: the caveat is said).
Pooled, the mass is identified (elbow + shoulder), then the centre of mass too (all three).
"""

from __future__ import annotations

import logging
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml

from wamctl.analysis.diagnosis.estimator import ModelDiagnosis
from wamctl.analysis.diagnosis.pooled import PooledDiagnosis, PoolingError, different_arm
from wamctl.runs.measured import load_run_data

CASE = {"effects": [{"name": "payload", "size": "large"}], "links": "nominal", "rate_hz": 500, "noise": "quiet",
        "jitter": "stamp", "seed": 9150, "excitation": "sweep"}
SWEPT = {"elbow": 4, "shoulder": 2, "wrist": 6}


pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """{name: (path, RunData, ModelDiagnosis fitted alone)} and the truth of the plant."""
    from gen_independent import generate

    root = tmp_path_factory.mktemp("pooled")
    out, truth = {}, None
    logging.disable(logging.WARNING)
    try:
        for name, j in SWEPT.items():
            r = generate(dict(CASE, joint=j, id=name), root / name)
            truth = r.truth["effects"][0]["params"]
            data = load_run_data(r.path)
            out[name] = (r.path, data, ModelDiagnosis().fit(data))
    finally:
        logging.disable(logging.NOTSET)
    return out, truth


def _pool(runs, names):
    return PooledDiagnosis([runs[n][2] for n in names], list(names), [runs[n][1] for n in names]).fit() \
        .to_dict([str(runs[n][0]) for n in names])


def test_no_run_alone_identifies_the_payload(runs):
    """The single-run path as it is: each sweep names the payload without mass or centre of mass. The shoulder
    sweep's payload adds to link errors within the declared accuracy by at least a noise floor at joint 2 (the
    generator's own figure for what those link errors leave of it: 4.9 floors, identifiable) but not to link errors
    within twice it: named, with that caveat as a warning (it was ``ambiguous`` while the wide test alone
    decided)."""
    runs, _ = runs
    for name in ("elbow", "wrist", "shoulder"):
        d = runs[name][2]
        assert d.effects_found_[:1] == ["payload"]
        assert "mass_kg" in d.payload_ci_[1] and {"com_x_m", "com_y_m", "com_z_m"} <= set(d.payload_ci_[1])
    dec = runs["shoulder"][2].payload_vs_links_
    assert dec["outcome"] == "payload" and dec["excess_noise_floors"]["2"] >= 2.0
    assert dec["tests"]["beyond_wide_links"]["p_value"] > runs["shoulder"][2].threshold_
    assert dec["grey_zone"] in runs["shoulder"][2].warnings_ and "2 times" in dec["grey_zone"]
    assert runs["elbow"][2].payload_vs_links_["grey_zone"] is None


def test_one_run_pooled_alone_repeats_its_own_decision(runs):
    """The pooled machinery on one run gives that run's own payload-or-links tests (same p-values, same held-out
    SSR ratios to 1e-9)."""
    runs, _ = runs
    out = _pool(runs, ["wrist"])
    own = runs["wrist"][2].payload_vs_links_["tests"]
    mine = out["payload_or_links"]["pooled"]["tests"]
    assert out["payload_or_links"]["pooled"]["outcome"] == "payload"
    for k in ("beyond_links", "beyond_wide_links"):
        assert mine[k]["p_value"] == pytest.approx(own[k]["p_value"], rel=1e-6, abs=1e-300)
        assert mine[k]["ssr_ratio"] == pytest.approx(own[k]["ssr_ratio"], rel=1e-9)


def test_elbow_and_shoulder_pooled_identify_the_mass(runs):
    """Pooled, payload is named first and its mass is identified within 10 % of the truth with a 95 % interval
    that holds it and is at most 25 % of it wide (alone: no number, no interval); the pooled decision is recorded
    with each run's own statistic, and both runs decided it (neither alone identifies the mass).
    (Measured when written: 1.437 kg [1.312, 1.584] against 1.498.)"""
    runs, truth = runs
    out = _pool(runs, ["elbow", "shoulder"])
    assert out["effects_found"][:1] == ["payload"]
    pay = out["payload"]
    m, (lo, hi) = pay["params"]["mass_kg"], pay["params_ci"]["mass_kg"]
    assert "mass_kg" not in pay["not_identified"]
    assert m == pytest.approx(truth["mass_kg"], rel=0.10)
    assert lo <= truth["mass_kg"] <= hi and hi - lo <= 0.25 * truth["mass_kg"]
    stacks = out["payload_or_links"]
    for name in ("elbow", "shoulder"):
        alone = stacks[f"{name} alone"]["payload"]
        assert "mass_kg" in alone["not_identified"] and alone["params_ci"]["mass_kg"] == [None, None]
    f = next(f for f in out["findings"] if f["name"] == "payload")
    assert f["pooled"]["named"] and f["per_stack"]["elbow alone"]["named"]
    assert f["per_stack"]["shoulder alone"]["outcome"] == "payload"
    assert sorted(f["decided_by"]) == ["elbow", "shoulder"] and f["added_nothing"] == []


def test_three_sweeps_pooled_identify_the_centre_of_mass_and_say_which_run_added_nothing(runs):
    """All three pooled: mass within 3 % and each centre-of-mass coordinate within 5 mm of the truth, inside 95 %
    intervals at most 2 cm wide; the elbow and wrist decided it, the shoulder added nothing (without it the same
    parameters are identified). (Measured when written: 1.496 kg [1.462, 1.525]; 27.2, 20.1, 27.4 mm.)"""
    runs, truth = runs
    out = _pool(runs, ["elbow", "shoulder", "wrist"])
    pay = out["payload"]
    assert pay["not_identified"] == []
    assert pay["params"]["mass_kg"] == pytest.approx(truth["mass_kg"], rel=0.03)
    for i, ax in enumerate("xyz"):
        c, (lo, hi) = pay["params"][f"com_{ax}_m"], pay["params_ci"][f"com_{ax}_m"]
        assert abs(c - truth["com_m"][i]) <= 0.005, (ax, c, truth["com_m"])
        assert lo <= truth["com_m"][i] <= hi and hi - lo <= 0.02
    f = next(f for f in out["findings"] if f["name"] == "payload")
    assert sorted(f["decided_by"]) == ["elbow", "wrist"] and f["added_nothing"] == ["shoulder"]
    assert "without shoulder" in f["per_stack"]


def test_runs_of_different_arms_are_refused(runs, tmp_path):
    """Two runs naming different arms in meta.yaml (``arm``), or different robots: refused in one line naming what
    differs, exit code 2, no traceback, nothing fitted."""
    from cli_runs import run_cli

    runs, _ = runs
    paths = []
    for name, arm in (("elbow", "wam-17"), ("shoulder", "wam-23")):
        p = shutil.copytree(runs[name][0], tmp_path / name)
        meta = yaml.safe_load((p / "meta.yaml").read_text())
        meta["arm"] = arm
        (p / "meta.yaml").write_text(yaml.safe_dump(meta))
        paths.append(p)
    r = run_cli("diagnose", *paths, "--out", tmp_path / "out")
    assert r.code == 2 and r.exc is None
    lines = [x for x in (r.out + r.err).splitlines() if x.strip()]
    assert len(lines) == 1 and "different arms" in lines[0] and "arm differs" in lines[0], lines
    assert not (tmp_path / "out").exists()
    meta4 = runs["elbow"][1].meta.model_copy(update={"robot": "wam4"})
    why = different_arm([runs["shoulder"][1].meta, meta4], [None, None], ["a", "b"])
    assert why is not None and "robot differs" in why
    with pytest.raises(PoolingError, match="robot differs"):
        PooledDiagnosis([runs["shoulder"][2], runs["elbow"][2]], ["a", "b"],
                        [runs["shoulder"][1], type(runs["elbow"][1])(meta4, runs["elbow"][1].data,
                                                                     runs["elbow"][1].source)]).fit()


def test_pooled_run_directory_and_report(runs, tmp_path):
    """The pooled run directory (:func:`write_pooled`, the runs as fitted above): diagnosis.json (pooled), each
    run's own diagnosis, a report saying which run decided what; the same run given twice is refused before
    anything is fitted."""
    from wamctl.experiments.diagnose import diagnose_runs_to_run_dir, write_pooled

    runs, _ = runs
    names = ["elbow", "shoulder"]
    paths = [runs[n][0] for n in names]
    path, result, doc = write_pooled(paths, names, [runs[n][1] for n in names], [runs[n][2] for n in names],
                                     out=tmp_path, formats=("md",))
    assert result["pooled"] and result["effects_found"][:1] == ["payload"]
    assert [r["label"] for r in result["runs"]] == names
    assert (Path(path) / "alone-1.json").is_file() and (Path(path) / "alone-2.json").is_file()
    md = (Path(path) / "report.md").read_text()
    assert "decided by elbow, shoulder" in md and "not identified" in md
    assert np.isfinite(result["payload"]["params"]["mass_kg"])
    with pytest.raises(PoolingError, match="more than once"):
        diagnose_runs_to_run_dir([paths[0], paths[0]], out=tmp_path)


def test_friction_that_changed_between_runs_is_each_run_own(runs, tmp_path):
    """The elbow sweep again with 0.3 N m more Coulomb friction at joint 4 in both directions (the logged torque
    plus 0.3 sign of its true velocity where it slides): pooled, the second run's friction torque at its median
    sliding speed of each direction is 0.3 N m above the first run's within 0.05 N m, with a 95 % interval that
    excludes zero (the Coulomb and viscous levels themselves trade against each other on a sweep at nearly one
    speed per direction); the payload is still named (the shared effect does not take up the drift)."""
    import pandas as pd

    runs, _ = runs
    src = runs["elbow"][0]
    p = shutil.copytree(src, tmp_path / "elbow-later")
    df = pd.read_parquet(p / "data.parquet")
    truth = pd.read_parquet(p / "truth_states.parquet")        # the generator's true link velocity
    assert len(truth) == len(df)
    df["tau_4"] = df["tau_4"] + 0.3 * np.sign(truth["qd_true_4"].to_numpy()) * ~truth["stuck_4"].to_numpy(bool)
    df.to_parquet(p / "data.parquet", index=False)
    logging.disable(logging.WARNING)
    try:
        data = load_run_data(p)
        later = ModelDiagnosis().fit(data)
    finally:
        logging.disable(logging.NOTSET)
    out = PooledDiagnosis([runs["elbow"][2], later], ["elbow", "elbow-later"], [runs["elbow"][1], data]).fit() \
        .to_dict([str(src), str(p)])
    assert out["effects_found"][:1] == ["payload"]
    at = out["friction_per_run"]["4"]["elbow-later"]["torque_change_at_median_speed"]
    assert set(at) == {"pos", "neg"}
    for d in ("pos", "neg"):
        assert at[d]["change_Nm"] == pytest.approx(0.3, abs=0.05), at
        assert at[d]["change_ci_Nm"][0] > 0, at


def test_a_finding_named_without_a_pooled_test_is_ordered_not_a_crash():
    """An effect seen at the onsets only is named from the runs that named it, with no pooled p-value (None):
    the effects are ordered by p with those after the tested ones (sorting crashed with a TypeError on the
    independent generator's pair-stribeck+payload-007 and its designed run, `wamctl diagnose RUN NEXT`)."""
    from wamctl.analysis.diagnosis.pooled import effects_in_order

    findings = [{"name": "backlash", "pooled": {"named": True, "p_value": None}},
                {"name": "stribeck", "pooled": {"named": True, "p_value": 1e-5}},
                {"name": "ripple", "pooled": {"named": False, "p_value": 0.5}},
                {"name": "payload", "pooled": {"named": True, "p_value": 1e-40}}]
    assert effects_in_order(findings) == ["payload", "stribeck", "backlash"]


def _di_part(label, y_kind, size, named, seed):
    """One run's share of the pooled delay-or-inertia check, made by hand: joint 1 only, a rigid body that is an
    inertia of 0.5 kg m^2 (``R(t + d) = 0.5 qdd(t + d)``), a two-speed motion, friction 0.3 N m Coulomb; the
    residual a delay of ``size`` s (``y_kind`` "delay") or an inertia error of ``size`` kg m^2 ("inertia") makes,
    plus white noise of 0.01 N m."""
    from wamctl.analysis.diagnosis import delay_inertia as DI

    rng = np.random.default_rng(seed)
    t = np.arange(0, 40, 0.02)

    def qd_at(s):
        return 0.4 * np.sin(2 * np.pi * (t + s) / 4.0) + 0.2 * np.sin(2 * np.pi * (t + s) / 1.0)

    def qdd_at(s):
        return (0.4 * 2 * np.pi / 4.0 * np.cos(2 * np.pi * (t + s) / 4.0)
                + 0.2 * 2 * np.pi * np.cos(2 * np.pi * (t + s) / 1.0))

    mask = np.abs(qd_at(0.0)) > DI.MIN_SPEED_RAD_S
    R = [{0: 0.5 * qdd_at(float(d))[mask]} for d in DI.DELAY_GRID_S]
    QD = [{0: qd_at(float(d))[mask]} for d in DI.DELAY_GRID_S]
    rows = DI.Rows(R, QD, {0: qdd_at(0.0)[mask]}, [0], {0: mask})
    lev = {0: np.array([0.3, 0.3, 0.0, 0.0])}
    if y_kind == "delay":
        y = DI.delay_torque(rows, DI.nearest_k(size), lev)
    else:
        y = DI.inertia_torque(rows, {0: size}, lev)
    y = {0: y[0] + rng.normal(scale=0.01, size=mask.sum())}
    return DI.RunPart(label, rows, y, DI.decide(rows, y), named=named)


def test_a_delay_a_run_named_is_kept_pooled_unless_a_run_contradicts_it():
    """Two runs whose delay (1 ms) is too small to part from an inertia error on either (each run's excess below one
    noise floor): pooled as before, ``ambiguous``; when the first run's own diagnosis named the delay, the pooled
    result keeps it (named by that run, no run preferring inertia by a noise floor). A third run whose residual
    is an inertia error that a delay cannot reproduce contradicts it: ambiguous again."""
    from wamctl.analysis.diagnosis import delay_inertia as DI

    a = _di_part("run", "delay", 1e-3, None, 1)
    b = _di_part("next", "delay", 1e-3, None, 2)
    assert a.decision["excess_noise_floors"] < 1 and b.decision["excess_noise_floors"] < 1
    plain = DI.decide_pooled([a, b], n_boot=20)
    assert plain["winner"] == "delay" and plain["outcome"] == "ambiguous"
    a.named = "delay"
    kept = DI.decide_pooled([a, b], n_boot=20)
    assert kept["outcome"] == "delay" and kept["named_by"] == ["run"] and "run" in kept["decided_by"]
    c = _di_part("third", "inertia", 0.05, None, 3)
    assert c.decision["outcome"] == "inertia"
    against = DI.decide_pooled([a, b, c], n_boot=20)
    assert against["outcome"] == "ambiguous" and against["contradicted_by"]
