"""`wamctl identify` on a log like the public real-WAM recording of issue 27 (item 3) and issue 32 (item 3).

The recording: a 7-DOF WAM, joints 2 and 4 on a Fourier trajectory, 10 s at 250 Hz, the torque libbarrett's total
command (gravity compensation included), an undeclared ~1 kg tool at the wrist, jittered stamps; `identify` on the
first 60 % validated on the rest wrote a model whose held-out RMS on joint 2 was 31.6 N m (datasheet 6.25, datasheet
+ payload 1.23), solver objective 3e21. Made here by the independent generator (tests/analysis/gen_independent:
its own 4 kHz Karnopp physics and controller, sharing no code with wamctl): joints 2 and 4 on a free Fourier
excitation, a 1 kg payload not declared in meta.yaml, 250 Hz, stamp jitter, position and actuation noise, the first
10 s cut into 60 % / 40 %. Seed 1 is the first seed tried on which the code of 22a114c broke (objective 7.5e14, held-out
RMS 21058 / 11446 N m on joints 2 / 4 against 0.74 / 0.74 for the datasheet arm); with the reference not logged
(q_ref = q, as a hand conversion without it) seeds 1-3 broke (objective 1e21-1e24, 9-11 N m).

Cause: the consistent estimate weighed the data by the inverse of the HAC covariance of the base parameters,
computed from (X^T X)^-1: on two joints over 6 s the determined directions span a condition number of 1e7, so
that inverse (1e14) and its whitening lost every direction the data see poorly (eigenvalues below 1e-14 of the
largest, floored), and the SDP matched those instead of the torque. Now the data term is formed from the QR factors
(precision R^T S_Q^-1 R), never from an inverted covariance. Second cause (q_ref = q): the held joints' speed and
acceleration noise made 48 of 76 base parameters look determined; joints that never slide are at rest in the
regressor.
"""

from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml
from cli_runs import wamctl_completed

from wamctl.analysis.identification.base import ARMATURE_SLICE, FRICTION_SLICE
from wamctl.experiments.identify import identify, identify_to_run_dir

PAYLOAD = {"mass_kg": 1.0}


def _cut(src: Path, out: Path, share: float = 0.6, t_end_s: float = 10.0, no_reference: bool = False,
         payload: dict | None = None) -> tuple[Path, Path]:
    """The first ``t_end_s`` of a generated run, split at ``share`` into two measured runs (fit, held out)."""
    df = pd.read_parquet(src / "data.parquet")
    meta = yaml.safe_load((src / "meta.yaml").read_text())
    if payload is not None:
        meta["payload"] = payload
    df = df[df["t"] < t_end_s].reset_index(drop=True)
    if no_reference:
        for j in range(1, 8):
            df[f"q_ref_{j}"] = df[f"q_{j}"]
    k = int(share * len(df))
    paths = []
    for name, part in (("fit", df.iloc[:k]), ("held", df.iloc[k:])):
        d = out / name
        d.mkdir(parents=True)
        part = part.copy()
        part["t"] -= part["t"].iloc[0]
        part.to_parquet(d / "data.parquet", index=False)
        (d / "meta.yaml").write_text(yaml.safe_dump(meta, sort_keys=False))
        paths.append(d)
    return paths[0], paths[1]


@pytest.fixture(scope="module")
def real_like(tmp_path_factory):
    from gen_independent import generate

    out = tmp_path_factory.mktemp("real_like")
    case = dict(id="real-like", seed=1, effects=[{"name": "payload", "size": "large", "params": PAYLOAD}],
                links="nominal", excitation="free", free_joints=[2, 4], joint=2, rate_hz=250, noise="noisy",
                jitter="stamp")
    r = generate(case, out / "full")
    assert r.status == "ok" and r.arm_time_s > 10.0
    return r


def _fit(fit, held):
    logging.disable(logging.WARNING)
    try:
        return identify([fit], [held])
    finally:
        logging.disable(logging.NOTSET)


@pytest.mark.parametrize("no_reference", [False, True])
def test_two_joint_real_like_log_is_at_least_as_good_as_the_datasheet_arm_with_its_payload(real_like, tmp_path,
                                                                                           no_reference):
    """Held-out RMS on joints 2 and 4: the identified model at most the datasheet arm's with friction fitted
    (0.73 / 0.66 N m here in the fit's band, 0.1x and 0.02x of it; without the reference, no second filter:
    0.80 / 0.79) and, in the diagnosis' band, within 2 % of the
    datasheet arm plus the true payload, declared, with friction fitted (the truth: the noise floor). In the fit's
    band (issue H10: the held-out check's rows), where the noise is smaller, 0.97x / 1.14x that floor measured
    (0.075 / 0.0125 against 0.077 / 0.011 N m): the fit's own estimation error shows; at most 1.25x asserted;
    the solver's objective is of the order of the rows (it was 7.5e14 and 1e21); the held joints' parameters are
    not identified."""
    fit, held = _cut(real_like.path, tmp_path / "undeclared", no_reference=no_reference)
    est, validation, _ = _fit(fit, held)
    rms = validation["rms"]
    payload = {"mass_kg": 1.0, "com_m": real_like.truth["effects"][0]["params"]["com_m"]}
    fit_p, held_p = _cut(real_like.path, tmp_path / "declared", no_reference=no_reference, payload=payload)
    _, validation_p, _ = _fit(fit_p, held_p)
    with_payload = validation_p["rms"]["nominal"]
    print("identified", np.round(rms["identified"][[1, 3]], 3), "datasheet", np.round(rms["nominal"][[1, 3]], 3),
          "datasheet + payload", np.round(with_payload[[1, 3]], 3), "objective", est.opt_["objective"],
          "in-sample", np.round(rms["in_sample_identified"][[1, 3]], 3))
    with_payload_diag = validation_p["rms"]["nominal_diagnosis_band"]
    print("diagnosis band: identified", np.round(rms["identified_diagnosis_band"][[1, 3]], 4), "datasheet + payload",
          np.round(with_payload_diag[[1, 3]], 4))
    for j in (1, 3):
        assert rms["identified"][j] <= rms["nominal"][j], j
        # the datasheet arm with the true payload is this arm's model (the links are the datasheet's): its
        # held-out RMS is the noise floor, which the identified model reaches within 2 % in the diagnosis' band
        # (0.4 % measured before H10) and within 25 % in the fit's band
        assert rms["identified_diagnosis_band"][j] <= 1.02 * with_payload_diag[j], j
        assert rms["identified"][j] <= 1.25 * with_payload[j], j
        assert rms["in_sample_identified"][j] <= rms["identified"][j], j
    assert est.opt_["objective"] < 1e4
    # what no row sees stays exactly the declared arm's: the friction and armature of the joints that did not move
    # (the weak prior on them was below the solver's tolerance: joint 7's Coulomb level drifted 0.054 -> 0.44 N m)
    held = [0, 2, 4, 5, 6]
    fr, fr0 = est.pi_[FRICTION_SLICE].reshape(7, 4), est.pi_declared_[FRICTION_SLICE].reshape(7, 4)
    assert np.array_equal(fr[held], fr0[held]), (fr[held] - fr0[held]).round(3)
    assert np.array_equal(est.pi_[ARMATURE_SLICE][[2, 4, 5, 6]], est.pi_declared_[ARMATURE_SLICE][[2, 4, 5, 6]])
    und = set(est.identifiability_.undetermined)
    assert {"fc_pos1", "fc_pos3", "Ia5", "fc_neg6", "Izz7"} <= und, sorted(und)
    assert est.identifiability_.rank <= 30


def test_held_out_check_is_said_in_json_report_and_model_file(real_like, tmp_path):
    """Without --validate (a held-out quarter of its own data): the JSON carries the verdict and the per-joint
    ratios, the report's first line says it, the joints that did not move are named, model.yaml is written.

    The quarter is 2.5 s: in the fit's band (issue H10) its loss difference rests on few independent stretches
    (fixed-b degrees of freedom 2.6 / 2.3 on joints 2 / 4), so the identified model, 0.052x / 0.013x the declared
    arm's RMS, is below it on both joints but not significantly (one-sided p 0.11 / 0.13): `no_worse`, written,
    and said so. (Before H10, in the diagnosis' band with normal critical values: `better`; those values rejected
    12-20 % of equally good models on rows this few, tests/analysis/test_identification_heldout_band.py.)"""
    fit, _ = _cut(real_like.path, tmp_path / "runs", share=1.0 - 1e-9)
    logging.disable(logging.WARNING)
    try:
        run, result, _ = identify_to_run_dir([fit], out=tmp_path)
    finally:
        logging.disable(logging.NOTSET)
    check = result["held_out_check"]
    print(check["statement"])
    assert check["verdict"] == "no_worse" and check["within_noise_joints"] == [], check
    assert set(check["ratio"]) == {2, 4} and max(check["ratio"].values()) <= 0.1
    assert all(p > 0.5 for p in check["p_worse"].values())
    assert check["not_moving_joints"] == [1, 3, 5, 6, 7]
    saved = json.loads((run / "identification.json").read_text())["held_out_check"]
    assert saved["verdict"] == "no_worse" and saved["model_written"] is True
    assert (run / "model.yaml").is_file() and not (run / "model_rejected.yaml").exists()
    first = (run / "report.md").read_text().split("\n\n")[1]
    assert first.startswith("Held-out check: the identified model is below the declared arm") and "joint 2" in first
    assert "but on no joint significantly" in first
    assert "joint(s) 1, 3, 5, 6, 7 did not move: not identified" in first
    mf = yaml.safe_load((run / "model.yaml").read_text())
    assert mf["identification"]["held_out_check"]["verdict"] == "no_worse"
    # where the rows went (the real log used 395 of its candidates, unsaid): every candidate accounted for once,
    # the fitted rows are the used ones, and the report says it
    (acc,) = result["row_accounting"]
    assert acc["used"] + acc["near_stop"] + acc["slow"] + acc["filter_reach"] + acc["held_out"] == acc["candidates"]
    assert acc["used"] == result["n_rows"] and acc["candidates"] >= 2 * acc["used"] > 0 and acc["held_out"] > 0
    assert f"Rows used: {acc['used']} of {acc['candidates']} candidates" in (run / "report.md").read_text()


def test_a_model_worse_than_the_declared_arm_is_not_written_and_exits_3(real_like, tmp_path):
    """Validated on the same trajectory of the arm without its tool (the datasheet arm itself): the identified
    model, which learnt the 1 kg tool, predicts it worse than the datasheet arm: verdict `worse`,
    model_rejected.yaml instead of model.yaml, exit code 3, said on the terminal, in the JSON and the report's first
    line; --force writes model.yaml, exit 0, the verdict still `worse`.

    The bad model is the same as before issue H10 (fitted on the tool-carrying run's first 6 s); it is validated
    on the bare arm's first 14 s instead of its 4 s tail. On the tail, judged in the fit's band, joint 4 is 1.105x
    the declared arm but with 3.2 fixed-b degrees of freedom p = 0.057: the check cannot see it there (before H10,
    in the diagnosis' band with normal critical values, 1.11x, p 0.014). On 14 s: joint 4 1.36x, p 0.0014."""
    from gen_independent import generate

    fit, _ = _cut(real_like.path, tmp_path / "runs")
    bare = generate(dict(id="bare", seed=1, effects=[], links="nominal", excitation="free", free_joints=[2, 4],
                         joint=2, rate_hz=250, noise="noisy", jitter="stamp"), tmp_path / "bare")
    held, _ = _cut(bare.path, tmp_path / "bare_runs", share=1.0 - 1e-9, t_end_s=14.0)
    cmd = ["identify", fit, "--validate", held, "--out", tmp_path]
    r = wamctl_completed(*cmd, "--quiet")
    assert r.returncode == 3, r.stderr[-2000:]
    assert "held-out check FAILED" in r.stdout and "NOT written as model.yaml" in r.stdout
    (run,) = tmp_path.glob("*-identify-fit")
    saved = json.loads((run / "identification.json").read_text())
    check = saved["held_out_check"]
    # joint 4 1.36x, significantly (Diebold-Mariano p 0.0014); joint 2 1.17x, within what the held-out data tell
    # (p 0.097)
    assert check["verdict"] == "worse" and check["worse_joints"] == [4] and check["model_written"] is False
    assert check["ratio"]["4"] > 1.05 and check["p_worse"]["4"] < 0.05 and check["within_noise_joints"] == [2]
    assert saved["model_file"] == "model_rejected.yaml"
    assert not (run / "model.yaml").exists() and (run / "model_rejected.yaml").is_file()
    assert (run / "report.md").read_text().split("\n\n")[1].startswith("Held-out check FAILED")
    r = wamctl_completed(*cmd, "--force", "--json")
    assert r.returncode == 0, r.stderr[-2000:]
    out = json.loads(r.stdout)
    assert out["held_out_check"]["verdict"] == "worse" and out["held_out_check"]["forced"] is True
    assert Path(out["model"]).is_file() and Path(out["model"]).name == "model.yaml"


def test_joints_named_moving_that_only_drift_are_held(real_like, tmp_path):
    """The public log's import names joints 2-6 as moving although 3, 5 and 6 stay within 0.02 rad of their start
    (drift at encoder level). Here: joints 3, 5 and 6 drift by 0.015 rad (0.13 Hz) with 0.3 mrad of noise, their
    reference is their measurement, and meta.yaml names joints 2-6. They yield no sliding rows and span less than
    0.05 rad, so they are held (at rest in the regressor): rank 19 as without the drift (39 before: their noisy
    speed made parameters look determined), and joint 2's held-out RMS stays that of the clean log (0.18 N m; 0.25
    before)."""
    fit, held = _cut(real_like.path, tmp_path / "drift")
    rng = np.random.default_rng(0)
    for d in (fit, held):
        df = pd.read_parquet(d / "data.parquet")
        meta = yaml.safe_load((d / "meta.yaml").read_text())
        for j in (3, 5, 6):
            df[f"q_{j}"] += 0.015 * np.sin(2 * np.pi * 0.13 * df["t"] + j) + 3e-4 * rng.standard_normal(len(df))
            df[f"q_ref_{j}"] = df[f"q_{j}"]
        meta["experiment"]["joints"] = [2, 3, 4, 5, 6]
        df.to_parquet(d / "data.parquet", index=False)
        (d / "meta.yaml").write_text(yaml.safe_dump(meta, sort_keys=False))
    est, validation, _ = _fit(fit, held)
    rms = validation["rms"]
    print("rank", est.identifiability_.rank, "held-out", np.round(rms["identified"][[1, 3]], 3))
    assert est.identifiability_.rank <= 25
    assert {"fc_pos3", "Ia5", "fc_neg6"} <= set(est.identifiability_.undetermined)
    assert rms["identified"][1] <= 0.21 and rms["identified"][3] <= 0.06
