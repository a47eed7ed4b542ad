"""The 4-DOF WAM (libbarrett's wam4.conf) on the simulated arm, end to end (issue 27 item 1): a ``robot: wam4``
rotation spec runs through `wamctl run` on a four-joint plant with the wam4's gains and limits, writes four-joint
tables, and its report scores the moves; joint numbers and joint vectors a wam4 does not have are refused in one
line naming the field. (The wam7 path is checked bit for bit by test_rotation.py, tests/backends/test_sim*.py.)"""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest
from cli_runs import run_cli, write_yaml

from wamctl.backends import make_backend
from wamctl.backends.sim_fused import fused_supported
from wamctl.experiments import rotation
from wamctl.experiments.common import make_joint_controller
from wamctl.experiments.engine import LoopRecorder, run_loop
from wamctl.model.robots import WAM4
from wamctl.runs.store import read_table
from wamctl.specs import parse_spec

# short moves of every joint (0.1 rad at 0.1 rad/s): ~2.8 s of arm time per joint
ROTATION = {"joints": [1, 2, 3, 4], "amplitude_rad": 0.1, "velocity_rad_s": 0.1, "tc_s": 0.3, "settle_s": 0.2,
            "hold_s": 0.4}
SENSORS = {"encoder_counts_per_rev": 4096, "position_noise_rad": 0.0}


def wam4_rotation(**overrides) -> dict:
    spec = {"kind": "rotation", "name": "wam4_rotation", "robot": "wam4", "seed": 3,
            "plant": {"friction": "table_4_1", "sensors": dict(SENSORS)}, "rotation": dict(ROTATION)}
    spec.update(overrides)
    return spec


def test_a_wam4_rotation_runs_end_to_end_through_the_cli(tmp_path):
    spec_path = write_yaml(tmp_path / "wam4_rotation.yaml", wam4_rotation())
    res = run_cli("run", spec_path, "--out", tmp_path / "runs", "--json")
    assert res.code == 0 and res.exc is None, res.err + res.tb
    run_dir = next((tmp_path / "runs").glob("*-wam4_rotation"))
    data = read_table(run_dir)
    # four joints everywhere: the reference, the measurement, the torque, the simulator's truth
    joints = sorted({int(c.split("_")[-2]) for c in data.columns if c.startswith("q_ref_")})
    assert joints == [1, 2, 3, 4]
    assert {"q_true_4_rad", "qd_true_4_rad_s", "tau_4_Nm"} <= set(data.columns)
    assert not any(c.endswith(("_5_rad", "_5_Nm")) for c in data.columns)
    manifest = json.loads((run_dir / "manifest.json").read_text())
    assert manifest["status"] == "completed" and manifest["backend"]["robot"] == "wam4"
    # the wam4's torque limits (wam4.conf control_signal_limit) hold, and no joint was near them
    tau = np.abs(data[[f"tau_{j}_Nm" for j in joints]].to_numpy()).max(axis=0)
    assert (tau < 0.75 * WAM4.tau_max_Nm).all(), tau
    # every move scored; the final error of a joint held by Coulomb friction under PD is at most the larger
    # Coulomb level over kp (Table 4.1, joints 1-4; wam4.conf kp) plus one encoder count through the
    # transmission, and each joint ended within it
    rpe = json.loads((run_dir / "report.json").read_text())["rpe_pct"]
    assert sorted(map(int, rpe)) == [1, 2, 3, 4]
    fc = np.maximum([4.4748, 2.6385, 1.7399, 1.5414], [4.3609, 3.5643, 2.3529, 0.7342])
    count_rad = 2 * np.pi / 4096 * np.abs(np.linalg.inv(WAM4.j2mp)).max(axis=1)
    bound_pct = (fc / WAM4.kp + count_rad) / ROTATION["amplitude_rad"] * 100
    got = np.array([rpe[str(j)] for j in joints])
    assert (got <= bound_pct).all() and (got > 0).all(), (got, bound_pct)
    # the report says the thesis' figures are of another arm instead of printing them beside these
    md = (run_dir / "report.md").read_text()
    assert "this run's arm is the wam4" in md and "thesis_rpe_pct" not in md


def test_the_wam4_spec_takes_the_robots_defaults():
    spec = parse_spec({"kind": "rotation", "robot": "wam4"})
    assert spec.q0_rad == [0.0, 0.0, 0.0, 1.57] and spec.rotation.joints == [1, 2, 3, 4]
    kp, kd, ki = parse_spec({"kind": "rotation", "robot": "wam4", "controller": {"kind": "pid"}}).controller.gains()
    # libbarrett config/wam4.conf joint_position_control: kp 900 2500 600 500, kd 10 20 10 2.5, ki 2.5 5 2.5 .5
    assert kp.tolist() == [900.0, 2500.0, 600.0, 500.0]
    assert kd.tolist() == [10.0, 20.0, 10.0, 2.5] and ki.tolist() == [2.5, 5.0, 2.5, 0.5]
    # the wam7's defaults are unchanged
    wam7 = parse_spec({"kind": "rotation"})
    assert wam7.robot == "wam7" and len(wam7.q0_rad) == 7 and wam7.rotation.joints == list(range(1, 8))
    assert wam7.controller.gains()[1].tolist() == [10.0, 20.0, 5.0, 2.0, 0.5, 0.5, 0.05]


@pytest.mark.parametrize("change, message", [
    ({"rotation": {**ROTATION, "joints": [2, 5]}},
     "rotation.joints: joint 5 is not a joint of the wam4 (joints 1..4)"),
    ({"q0_rad": [0.0, 0.0, 0.0, 1.57, 0.0, 0.0, 0.0]},
     "q0_rad: List should have at most 4 items (one per joint of the wam4), not 7"),
    ({"plant": {"friction": "table_4_1", "effects": {"stribeck": {"joints": [1, 6]}}}},
     "plant.effects.stribeck.joints: joint 6 is not a joint of the wam4 (joints 1..4)"),
    ({"plant": {"friction": {"joints": {7: {"fc_pos_Nm": 0.1}}}}},
     "plant.friction.joints: joint 7 is not a joint of the wam4 (joints 1..4)"),
    ({"controller": {"kp": [900, 2500, 600]}},
     "controller.kp: List should have at least 4 items (one per joint of the wam4), not 3"),
    ({"q0_rad": [0.0, 0.0, 0.0, 3.2]},
     "q0_rad: joint 4 would reach 3.2000 rad, outside its limits [-0.9, 3.1] rad"),
])
def test_what_a_wam4_does_not_have_is_refused_naming_the_field(tmp_path, change, message):
    spec_path = write_yaml(tmp_path / "bad.yaml", wam4_rotation(**change))
    for command in (("validate", spec_path), ("run", spec_path, "--out", tmp_path / "runs")):
        res = run_cli(*command)
        assert res.code == 2 and res.exc is None, res.out + res.err + res.tb
        lines = res.err.strip().splitlines()
        assert len(lines) == 1 and message in lines[0], res.err
        assert "Traceback" not in res.err
    assert not (tmp_path / "runs").exists() or not any((tmp_path / "runs").iterdir())


def test_the_compiled_loop_says_no_for_the_wam4_and_the_python_loop_runs():
    spec = parse_spec(wam4_rotation(rotation={**ROTATION, "joints": [2]}))
    plan = rotation.plan(spec)
    out = {}
    for fused in (False, True):
        controller = make_joint_controller(spec, plan.feedforward_Nm)
        with make_backend(spec) as backend:
            assert backend.n_joints == 4
            assert not fused_supported(backend, controller)
            rec = LoopRecorder(len(plan.reference), True, n_joints=4)
            run_loop(backend, controller, plan.reference, rec, fused=fused)
            out[fused] = pd.DataFrame(rec.result(), columns=rec.columns)
    assert out[True].equals(out[False])
    err = (out[False]["q_ref_2_rad"] - out[False]["q_2_rad"]).to_numpy()
    assert np.abs(err).max() < 0.01 and np.abs(err[-1]) <= 3.5643 / 2500 + 2 * np.pi / 4096 / 16


def test_a_kind_that_does_not_take_the_wam4_yet_says_so(tmp_path):
    res = run_cli("validate", write_yaml(tmp_path / "ift.yaml", {"kind": "ift", "robot": "wam4"}))
    assert res.code == 2 and res.exc is None
    assert res.err.strip().endswith("robot: ift runs on the wam7 only so far, not the wam4"), res.err


def test_the_wam4_plant_takes_the_first_four_joints_of_table_4_1_and_refuses_a_wam7_friction_file(tmp_path):
    from wamctl.errors import WamctlError
    from wamctl.model.friction import FrictionModel
    from wamctl.model.plant import Plant

    spec = parse_spec(wam4_rotation())
    plant = Plant(spec.plant, None, spec.robot)
    assert plant.n_joints == 4 and plant.links.n_joints == 4
    assert plant.friction.fc_neg_Nm.tolist() == [4.3609, 3.5643, 2.3529, 0.7342]
    assert plant.friction.viscous_pos_Nm_s_rad.tolist() == [1.3348, 3.5572, 0.3944, 2.7045]
    # a friction model of the wam7 (joints 5-7 given) is not the wam4's: refused naming the joint
    FrictionModel.table_4_1().save(tmp_path / "wam7.yaml")
    bad = parse_spec(wam4_rotation(plant={"friction": str(tmp_path / "wam7.yaml")}))
    with pytest.raises(WamctlError, match=r"joints\.5: joint numbers are 1\.\.4"):
        Plant(bad.plant, None, bad.robot)
    res = run_cli("validate", write_yaml(tmp_path / "bad.yaml", wam4_rotation(plant={"friction": str(tmp_path /
                                                                                                   "wam7.yaml")})))
    assert res.code == 2 and res.err.strip().endswith("plant.friction: " + str(tmp_path / "wam7.yaml")
                                                      + ": joints.5: joint numbers are 1..4"), res.err
