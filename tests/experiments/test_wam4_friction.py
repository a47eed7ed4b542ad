"""The friction sweep and `wamctl friction-id` on the simulated 4-DOF WAM (issue 27 item 1): a ``robot: wam4``
friction_sweep spec sweeps the four joints of a plant whose friction is declared inline (not Table 4.1), and both the
run's own identification and `friction-id --data` on the run recover it within the wam7 test's tolerances
(tests/analysis/test_friction_id.py: every level within 1 %, within 3.5 standard errors)."""

from __future__ import annotations

import json

import numpy as np
import pytest
import yaml
from cli_runs import run_cli, write_yaml

from wamctl.model.friction import FrictionModel

pytestmark = pytest.mark.xdist_group("wam4_sweep")

# the declared (true) friction of the simulated wam4: per joint Fc+, Fc-, sigma2+, sigma2- (N m, N m s/rad)
TRUE = {1: (3.9, 4.2, 1.1, 0.9), 2: (2.9, 2.4, 1.6, 2.0), 3: (1.2, 1.5, 0.6, 0.45), 4: (1.1, 0.8, 0.5, 0.7)}
NAMES = ("fc_pos_Nm", "fc_neg_Nm", "viscous_pos_Nm_s_rad", "viscous_neg_Nm_s_rad")
STD_KEYS = ("fc_pos", "fc_neg", "sigma2_pos", "sigma2_neg")


def sweep_spec() -> dict:
    return {"kind": "friction_sweep", "name": "wam4_sweep", "robot": "wam4", "seed": 5,
            "plant": {"friction": {"joints": {j: dict(zip(NAMES, v)) for j, v in TRUE.items()}},
                      "sensors": {"encoder_counts_per_rev": 4096, "position_noise_rad": 2e-5}},
            "sweep": {"joints": [1, 2, 3, 4], "velocities_rad_s": [0.02, 0.1, 0.5], "cruise_s": 1.0,
                      "settle_s": 0.3, "tc_s": 0.2, "travel_rad": 0.5}}


@pytest.fixture(scope="module")
def sweep_run(tmp_path_factory):
    root = tmp_path_factory.mktemp("wam4_sweep")
    res = run_cli("run", write_yaml(root / "sweep.yaml", sweep_spec()), "--out", root / "runs")
    assert res.code == 0 and res.exc is None, res.err + res.tb
    return next((root / "runs").glob("*-wam4_sweep"))


def check_recovered(model_file):
    raw = yaml.safe_load(model_file.read_text())
    assert set(raw["joints"]) == {1, 2, 3, 4} and "not_identified" not in raw
    model = FrictionModel.load(model_file, n_joints=4)
    z = []
    for j, values in TRUE.items():
        std = raw["identification"]["joints"][j]["std"]
        for name, key, want in zip(NAMES, STD_KEYS, values):
            got = getattr(model, name)[j - 1]
            assert got == pytest.approx(want, rel=0.01), (j, name, got, want)
            z.append((got - want) / std[key])
    assert np.abs(z).max() <= 3.5, np.round(z, 1)
    return model


def test_the_wam4_sweep_recovers_the_declared_friction(sweep_run):
    check_recovered(sweep_run / "friction_model.yaml")
    report = json.loads((sweep_run / "report.json").read_text())
    rows = report["tables"]["recovered_vs_true"]
    assert {r["joint"] for r in rows} == {1, 2, 3, 4}
    assert max(abs(r["error_pct"]) for r in rows) < 1.0
    fmap = yaml.safe_load((sweep_run / "spec.yaml").read_text())
    assert fmap["robot"] == "wam4"


def test_friction_id_on_the_wam4_run(sweep_run, tmp_path):
    res = run_cli("friction-id", "--data", sweep_run, "--out", tmp_path, "--json")
    assert res.code == 0 and res.exc is None, res.err + res.tb
    out = json.loads(res.out)
    model = check_recovered(tmp_path / out["run_dir"].split("/")[-1] / "friction_model.yaml")
    # the same data, the same identification: friction-id reproduces the run's own model
    same = FrictionModel.load(sweep_run / "friction_model.yaml", n_joints=4)
    for name in NAMES:
        assert np.array_equal(getattr(model, name), getattr(same, name))


def test_a_wam4_sweep_of_a_joint_it_lacks_is_refused(tmp_path):
    spec = sweep_spec()
    spec["sweep"]["joints"] = [2, 6]
    res = run_cli("validate", write_yaml(tmp_path / "bad.yaml", spec))
    assert res.code == 2 and res.exc is None
    assert res.err.strip() == f"error: {tmp_path / 'bad.yaml'}: sweep.joints: joint 6 is not a joint of the wam4 " \
                              "(joints 1..4)", res.err
