"""`wamctl diagnose` on a 4-DOF WAM (libbarrett's wam4; issue 27 item 1): the joints count from the run's robot.

The runs are made by wamctl itself: one excitation designed for the wam4 (`excite`, a quick design), run twice on a
simulated wam4 (Table 4.1's joints 1-4, 4096-count encoders, a little torque noise) that carries an effect the
declared model lacks: a position ripple of 1.0 N m, period 0.2 rad, at joint 2; a 0.5 kg payload 5 cm beyond the
tool plate (the wam4's flange, 0.36 m along z4 from frame 4: its last link carries it). The diagnosis must name
each and nothing else, with the truth inside its 95 % intervals, and write a wam4 model; a declared model of
another arm is refused in one line.
"""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest
import yaml
from cli_runs import run_cli, write_yaml

from wamctl.errors import SpecError
from wamctl.experiments.excitation import excite
from wamctl.experiments.runner import run_spec
from wamctl.specs import load_spec

RIPPLE = {"joints": [2], "amplitude_Nm": 1.0, "period_rad": 0.2}
PAYLOAD = {"mass_kg": 0.5, "com_m": [0.0, 0.0, 0.05]}


def wam4_spec() -> dict:
    return {"kind": "excitation", "name": "wam4_diagnose", "robot": "wam4", "seed": 2,
            "q0_rad": [0.0, 0.3, 0.0, 1.6],
            "plant": {"friction": "table_4_1", "sensors": {"encoder_counts_per_rev": 4096, "torque_noise_Nm": 0.02}},
            "excitation": {"period_s": 4.0, "harmonics": 3, "periods": 3, "settle_s": 0.5,
                           "limits": {"max_speed_rad_s": 1.0, "max_acceleration_rad_s2": 3.0, "torque_margin": 0.4},
                           "design": {"starts": 1, "max_iterations": 10, "grid_points": 40}}}


@pytest.fixture(scope="module")
def designed(tmp_path_factory):
    d = tmp_path_factory.mktemp("wam4_design")
    out, _, _ = excite(write_yaml(d / "wam4.yaml", wam4_spec()), d / "design")
    return yaml.safe_load((out / "excitation.yaml").read_text())


def run_with(designed: dict, effect: str, value: dict, runs) -> object:
    """The designed excitation run on the wam4 carrying ``effect`` (``plant.effects``)."""
    raw = json.loads(json.dumps(designed))
    raw["name"] = f"wam4_{effect}"
    raw["plant"]["effects"] = {effect: dict(value)}
    outcome = run_spec(load_spec(write_yaml(runs / f"{effect}.yaml", raw)), runs, runs, make_report=False)
    assert outcome.status == "completed", outcome.reason
    return outcome.path


def diagnose_cli(run_dir, out) -> tuple[dict, object]:
    res = run_cli("diagnose", run_dir, "--out", out, "--json")
    assert res.code == 0 and res.exc is None, res.err + res.tb
    return json.loads(res.out), next(out.glob("*-diagnose-*"))


@pytest.fixture(scope="module")
def ripple_run(designed, tmp_path_factory):
    return run_with(designed, "position_ripple", RIPPLE, tmp_path_factory.mktemp("wam4_ripple"))


@pytest.fixture(scope="module")
def diagnosed(ripple_run, tmp_path_factory):
    return diagnose_cli(ripple_run, tmp_path_factory.mktemp("wam4_diagnosis"))


def test_the_ripple_of_a_wam4_is_named_at_its_joint_and_nowhere_else(diagnosed):
    result, _ = diagnosed
    assert result["conclusive"] and result["robot"] == "wam4"
    assert result["declared_model"].startswith("wam4 rigid body")
    assert sorted(result["joints"]) == ["1", "2", "3", "4"]          # four joints, not seven
    assert result["effects_found"] == ["position_ripple"]
    named = {j: [e["name"] for e in d["effects"]] for j, d in result["joints"].items()}
    assert named == {"1": [], "2": ["position_ripple"], "3": [], "4": []}, named
    ripple = result["joints"]["2"]["effects"][0]
    lo, hi = ripple["params_ci"]["amplitude_Nm"]
    assert lo <= RIPPLE["amplitude_Nm"] <= hi and hi - lo < 0.1, (lo, hi)
    assert ripple["params"]["period_rad"] == pytest.approx(RIPPLE["period_rad"], rel=0.01)
    # the held-out torque residual at joint 2 falls to the noise: the ripple's RMS is 1.0 / sqrt 2 = 0.71 N m
    j2 = result["joints"]["2"]
    assert j2["torque_rms_before_Nm"] > 0.5 and j2["torque_rms_after_Nm"] < 0.15 * j2["torque_rms_before_Nm"]
    # and the closed-loop position check of the wam4 agrees (the ripple model re-simulates joint 2's positions)
    assert j2["position_rms_after_rad"] < 0.5 * j2["position_rms_before_rad"]


def test_a_payload_on_the_wam4s_last_link_is_named_with_its_mass_and_centre(designed, tmp_path):
    """The payload of the wam4 (on link 4, its centre given in the flange frame at the tool plate): named for the
    whole arm, beyond what link errors within the declared accuracy make (the payload-or-links decision), its mass
    and centre of mass within their 95 % intervals, and in the model written."""
    (tmp_path / "runs").mkdir()
    result, run_dir = diagnose_cli(run_with(designed, "payload", PAYLOAD, tmp_path / "runs"), tmp_path / "out")
    assert result["conclusive"] and result["effects_found"] == ["payload"], result["effects_found"]
    assert result["payload_or_links"]["outcome"] == "payload"
    found = [e for d in result["joints"].values() for e in d["effects"]]
    assert found and {e["name"] for e in found} == {"payload"}
    p = found[0]
    print("payload", p["params"]["mass_kg"], p["params"]["com_m"], p["params_ci"])
    lo, hi = p["params_ci"]["mass_kg"]
    assert lo <= PAYLOAD["mass_kg"] <= hi and hi - lo < 0.1, (lo, hi)
    for k, axis in enumerate("xyz"):
        lo, hi = p["params_ci"][f"com_{axis}_m"]
        assert lo <= PAYLOAD["com_m"][k] <= hi and hi - lo < 0.03, (axis, lo, hi)
    model = yaml.safe_load((run_dir / "model.yaml").read_text())
    assert model["robot"] == "wam4" and model["effects"]["payload"]["mass_kg"] == pytest.approx(0.5, abs=0.05)


def test_the_wam4_flange_frame_is_read_from_the_model():
    """A payload's centre is given in the flange frame (the tool plate on the wam4); its inertial parameters live in
    the last link's frame: the diagnosis reads one from the other through the model, on any arm."""
    from wamctl.analysis.diagnosis.candidates import flange_frame, payload_from_pi
    from wamctl.model.dynamics import Payload, WamDynamics

    origin, rot = flange_frame("wam4")
    np.testing.assert_allclose(origin, [-0.045, -0.36, 0.0], atol=1e-12)      # a4 along x4, the tool plate
    np.testing.assert_allclose(rot, [[1, 0, 0], [0, 0, -1], [0, 1, 0]], atol=1e-12)   # alpha4 = pi/2
    for robot in ("wam7", "wam4"):
        pi = (WamDynamics(Payload(0.8, (0.01, -0.02, 0.05)), robot=robot).standard_parameters()
              - WamDynamics(robot=robot).standard_parameters())[-10:]
        got = payload_from_pi(pi, robot)
        assert got["mass_kg"] == pytest.approx(0.8) and np.allclose(got["com_m"], [0.01, -0.02, 0.05], atol=1e-12)


def test_the_wam4_diagnosis_writes_a_wam4_model_and_four_joint_tables(diagnosed):
    _, run_dir = diagnosed
    model = yaml.safe_load((run_dir / "model.yaml").read_text())
    assert model["robot"] == "wam4" and sorted(model["friction"]["joints"]) == [1, 2, 3, 4]
    assert model["effects"]["position_ripple"]["joints"] == [2]
    assert model["effects"]["position_ripple"]["amplitude_Nm"] == pytest.approx(1.0, abs=0.05)
    pos = pd.read_parquet(run_dir / "positions.parquet")
    assert {f"q_after_{j}_rad" for j in range(1, 5)} <= set(pos.columns) and "q_5_rad" not in pos.columns
    md = (run_dir / "report.md").read_text()
    assert "wam4 rigid body" in md


def test_a_declared_model_of_another_arm_is_refused_in_one_line(ripple_run, tmp_path):
    from wamctl.experiments.diagnose import declared_model
    from wamctl.model.friction import FrictionModel

    wam7_model = write_yaml(tmp_path / "wam7_model.yaml", {"format": "wamctl-model/1", "friction": "table_4_1"})
    FrictionModel.table_4_1().save(tmp_path / "wam7_friction.yaml")
    for model, message in ((wam7_model, f"{wam7_model}: robot: wam7; the run is of a wam4"),
                           (tmp_path / "wam7_friction.yaml", "joints.5: joint numbers are 1..4; the run is of a "
                                                             "wam4 (joints 1..4)")):
        res = run_cli("diagnose", ripple_run, "--model", model, "--out", tmp_path / "out")
        assert res.code == 2 and res.exc is None, res.out + res.err + res.tb
        lines = res.err.strip().splitlines()
        assert len(lines) == 1 and message in lines[0], res.err
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").iterdir())
    # a wam4 model for a wam7 run, the other way round
    wam4_model = write_yaml(tmp_path / "wam4_model.yaml", {"format": "wamctl-model/1", "robot": "wam4"})
    with pytest.raises(SpecError, match="robot: wam4; the run is of a wam7"):
        declared_model(wam4_model, "wam7")
    # the wam4's own Table 4.1 rows are taken for its run
    own = declared_model(write_yaml(tmp_path / "wam4_own.yaml", {"format": "wamctl-model/1", "robot": "wam4",
                                                                   "friction": "table_4_1"}), "wam4")
    np.testing.assert_allclose(own.friction.fc_neg_Nm, [4.3609, 3.5643, 2.3529, 0.7342])


def test_pooling_wam4_runs_is_refused_in_one_line(ripple_run, tmp_path):
    import shutil

    other = shutil.copytree(ripple_run, tmp_path / "copy" / ripple_run.name)
    res = run_cli("diagnose", ripple_run, other, "--out", tmp_path / "out")
    assert res.code == 2 and res.exc is None, res.err + res.tb
    assert res.err.strip().splitlines() == [f"error: {ripple_run}: robot wam4: not supported by diagnose of several "
                                            "runs yet"], res.err
