"""Issue 28 item 2: diagnose writes the run that can tell a payload from link errors (next_experiment.yaml).

A simulated sweep of the elbow (joint 4, the run's own spec.yaml naming the sim backend and plant) with a
1 kg payload. Whatever the run's decision, the design is asked for as it would be for an ambiguous one (the
decision set to ``ambiguous`` on the fitted diagnosis): next_experiment.yaml is a valid excitation spec for the
same backend and plant, passes excite's plan and limit checks, moves joints other than the elbow, and its
predicted separation is larger than the run's; the summary lines carry it. Then the loop is closed: the
designed spec is run on the simulated arm and diagnosed, and the payload is named first, its mass within 5 %;
the two runs pooled (``wamctl diagnose RUN NEXT``) decide the payload with the designed run among those that
decided it, its mass within 5 % and each centre-of-mass coordinate within 2 cm, each 95 % interval holding the
truth, and raise no delay-or-inertia question. (Measured when written: 0.528 kg for 0.529 kg; the design's
separation 1.8 noise floors, the run's 1.1; pooled 0.5275 [0.517, 0.538] kg, centre of mass within 0.3 mm,
intervals +-5 mm, decided by both runs.)
"""

from __future__ import annotations

import logging

import numpy as np
import yaml

from wamctl.analysis.diagnosis.estimator import ModelDiagnosis
from wamctl.experiments.diagnose import next_experiment
from wamctl.report.diagnosis import next_experiment_line
from wamctl.runs.measured import load_run_data


def test_next_experiment_is_a_runnable_spec_that_separates_more(tmp_path):
    from diagnosis_gen import generate_run

    from wamctl.experiments.excitation import plan
    from wamctl.specs import load_spec

    r = generate_run(tmp_path, "payload", seed=5, joint=4, duration_s=12.0)
    (r.path / "spec.yaml").write_text(yaml.safe_dump(
        {"kind": "free", "backend": {"kind": "sim"},
         "plant": yaml.safe_load((r.path / "truth.yaml").read_text())["plant"]}))
    data = load_run_data(r.path)
    logging.disable(logging.WARNING)
    try:
        diag = ModelDiagnosis(candidates=("payload", "link_parameters")).fit(data)
    finally:
        logging.disable(logging.NOTSET)
    assert diag.payload_vs_links_ is not None and diag.payload_cone_fit_ is not None
    outcome_alone = diag.payload_vs_links_["outcome"]
    diag.payload_vs_links_ = dict(diag.payload_vs_links_, outcome="ambiguous")
    out = next_experiment(diag, data, r.path, tmp_path)
    assert out is not None
    spec = load_spec(tmp_path / "next_experiment.yaml")
    assert spec.kind == "excitation" and spec.backend.kind == "sim"
    assert spec.plant.effects.payload is not None
    plan(spec, tmp_path).check_limits()            # excite's own checks: raises when a limit is crossed
    assert set(out["joints"]) - {4}
    assert out["separation_noise_floors"] > out["original_separation_noise_floors"]
    assert np.isfinite(out["noise_floor_Nm"]) and out["noise_floor_Nm"] > 0
    line = next_experiment_line({"next_experiment": out})
    assert line.startswith("next experiment: next_experiment.yaml (excitation of joints")

    # closing the loop: the designed spec run on the simulated arm (the same plant), then diagnosed
    from typer.testing import CliRunner

    from wamctl.cli import _register, app

    _register()
    res = CliRunner().invoke(app, ["run", str(tmp_path / "next_experiment.yaml"), "--out", str(tmp_path / "runs")])
    assert res.exit_code == 0, res.output
    run = next(p for p in (tmp_path / "runs").iterdir() if p.is_dir())
    data2 = load_run_data(run)
    logging.disable(logging.WARNING)
    try:
        diag2 = ModelDiagnosis(candidates=("payload", "link_parameters")).fit(data2)
    finally:
        logging.disable(logging.NOTSET)
    again = diag2.to_dict()
    assert again["effects_found"][:1] == ["payload"], (again["effects_found"], again.get("payload_or_links"))
    truth = yaml.safe_load((r.path / "truth.yaml").read_text())["plant"]["effects"]["payload"]
    got = next(e for e in again["joints"]["4"]["effects"] if e["name"] == "payload")["params"]
    assert abs(got["mass_kg"] - truth["mass_kg"]) <= 0.05 * truth["mass_kg"]       # 5 %, set before the run

    # and pooled, as `wamctl diagnose RUN NEXT` does: the payload decided, by the designed run
    from wamctl.analysis.diagnosis.pooled import PooledDiagnosis

    diag.payload_vs_links_ = dict(diag.payload_vs_links_, outcome=outcome_alone)
    pooled = PooledDiagnosis([diag, diag2], ["sweep", "next"], [data, data2]).fit().to_dict([str(r.path), str(run)])
    f = next(f for f in pooled["findings"] if f["joint"] is None and f["name"] in ("payload", "link_parameters",
                                                                                   "payload_or_links"))
    assert pooled["payload_or_links"]["pooled"]["outcome"] == "payload", pooled["payload_or_links"]["pooled"]
    assert "next" in f["decided_by"], f
    est, ci = pooled["payload"]["params"], pooled["payload"]["params_ci"]
    lo, hi = ci["mass_kg"]
    assert abs(est["mass_kg"] - truth["mass_kg"]) <= 0.05 * truth["mass_kg"] and lo <= truth["mass_kg"] <= hi, ci
    for k, c in zip("xyz", truth["com_m"]):             # the 2 cm where the proposed run excites it
        lo, hi = ci[f"com_{k}_m"]
        assert abs(est[f"com_{k}_m"] - c) <= 0.02 and lo <= c <= hi, (k, est, ci)
    # a payload the runs name is no delay-or-inertia question (the check's friction-only model would take the
    # payload's torque at the elbow for an inertia error)
    assert not any(f.get("delay_or_inertia") for f in pooled["findings"]), pooled["findings"]


def test_an_elbow_sweep_named_link_parameters_gets_a_run_that_separates(tmp_path):
    """Issue 28 item 2 (a) on the independent generator: a sweep of the elbow alone with a medium wrist payload
    (seed fixed before the run was looked at) is named link_parameters (a sweep of one joint cannot tell a payload
    from link errors); next_experiment moves joints beyond the elbow and predicts a separation above 2 noise
    floors where the run's is below 1. (Measured when written: 4.1 against 3.5e-08, all seven joints.)"""
    from gen_independent import generate

    case = {"id": "payload-sweep-medium", "seed": 9402, "links": "nominal", "rate_hz": 500, "noise": "quiet",
            "jitter": "stamp", "excitation": "sweep", "joint": 4, "effects": [{"name": "payload", "size": "medium"}]}
    r = generate(case, tmp_path / case["id"])
    data = load_run_data(r.path)
    logging.disable(logging.WARNING)
    try:
        diag = ModelDiagnosis(candidates=("payload", "link_parameters")).fit(data)
    finally:
        logging.disable(logging.NOTSET)
    assert diag.payload_vs_links_["outcome"] == "link_parameters", diag.payload_vs_links_
    out = next_experiment(diag, data, r.path, tmp_path)
    assert out is not None and out["spec"] == "next_experiment.yaml"
    assert set(out["joints"]) - {4}
    assert out["original_separation_noise_floors"] < 1
    assert out["separation_noise_floors"] > 2
    # a payload no WAM carries (a 370 kg fit, seen on a wrist sweep with a delay) gets no run: nothing written
    diag.payload_cone_fit_ = dict(diag.payload_cone_fit_, mass_kg=370.0)
    (tmp_path / "implausible").mkdir()
    out = next_experiment(diag, data, r.path, tmp_path / "implausible")
    assert out["spec"] is None and "370 kg, not a wrist payload (0.01 to 10 kg)" in out["why"]
    assert not (tmp_path / "implausible" / "next_experiment.yaml").exists()
