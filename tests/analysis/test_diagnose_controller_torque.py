"""``wamctl diagnose`` on a log whose torque is the controller's output (``torque: controller``, issue 27 item 2):
libbarrett's gravity compensation was added downstream and not logged, so only the joints whose gravity torque is
constant over the run (:mod:`wamctl.model.controller_torque`) are diagnosed, the declared gravity added back; every
other joint is named, with why, on the terminal, in diagnosis.json and in the report; no joint left is a one-line
error (exit 2).

The runs are the diagnosis' generator (tests/analysis/diagnosis_gen.py: the simulator under libbarrett's PD +
gravity law): a position ripple at joint 1 (the wam7's vertical axis, gravity torque zero), logged as the total
command and, minus the controller's gravity term, as the controller's output. Tolerances were set before the first
run: the ripple's period within 1 % and its amplitude within 5 % of the truth; joint 1's ripple found alike (1 %)
in both logs, its torque being the same.
"""

from __future__ import annotations

import json
import shutil

import numpy as np
import pandas as pd
import pytest
import yaml
from cli_runs import run_cli
from diagnosis_gen import DT_S, Q0_BASE, generate_run, simulate, write_measured

from wamctl.analysis.diagnosis.estimator import ModelDiagnosis
from wamctl.control.trajectory import ReferenceBuilder
from wamctl.model import params as P
from wamctl.model.dynamics import WamDynamics
from wamctl.runs.measured import load_run_data

REASON = "torque controller: gravity compensation not logged and joint {j}'s gravity torque varies by"


def as_controller_torque(run, to):
    """A copy of the measured run ``run`` whose torque is the controller's output: the total command minus the
    gravity term libbarrett's controller added (the datasheet arm at the measured positions), ``torque: controller``
    in meta.yaml."""
    shutil.copytree(run, to)
    df = pd.read_parquet(to / "data.parquet")
    q = df[[f"q_{j}" for j in range(1, P.N_JOINTS + 1)]].to_numpy()
    g = WamDynamics().gravity_many(q)
    for j in range(P.N_JOINTS):
        df[f"tau_{j + 1}"] = df[f"tau_{j + 1}"] - g[:, j]
    df.to_parquet(to / "data.parquet", index=False)
    meta = yaml.safe_load((to / "meta.yaml").read_text())
    meta["torque"] = "controller"
    (to / "meta.yaml").write_text(yaml.safe_dump(meta, sort_keys=False))
    return to


@pytest.fixture(scope="module")
def ripple(tmp_path_factory):
    """(the generated run, logged as the total command; its controller-torque copy; the total command's
    diagnosis.json mapping)."""
    root = tmp_path_factory.mktemp("ctrl_ripple")
    g = generate_run(root, "position_ripple", 12, joint=1, duration_s=15.0)
    return g, as_controller_torque(g.path, root / "ctrl"), ModelDiagnosis().fit(load_run_data(g.path)).to_dict()


def _ripple_params(joint: dict) -> dict:
    e = next(x for x in joint["effects"] if x["name"] == "position_ripple")
    return e["params"]


def test_a_controller_torque_log_is_diagnosed_at_joint_1_and_the_others_are_named_with_why(ripple, tmp_path):
    g, ctrl, total = ripple
    r = run_cli("diagnose", ctrl, "--out", tmp_path / "out", columns=400)
    assert r.exc is None and r.code == 0, (r.err, r.tb)
    out = r.out.splitlines()
    assert "effects found: position_ripple" in out, r.out
    for j in range(2, 8):           # one line each, with the reason
        assert sum(ln.startswith(f"joint {j} not diagnosed: " + REASON.format(j=j)) for ln in out) == 1, r.out
    run = next((tmp_path / "out").iterdir())
    d = json.loads((run / "diagnosis.json").read_text())
    assert d["torque"] == "controller" and d["conclusive"]
    assert list(d["joints"]) == ["1"] and d["effects_found"] == ["position_ripple"]
    p = _ripple_params(d["joints"]["1"])
    assert p["period_rad"] == pytest.approx(g.effect_spec["period_rad"], rel=0.01)
    assert p["amplitude_Nm"] == pytest.approx(g.effect_spec["amplitude_Nm"], rel=0.05)
    assert sorted(d["skipped_joints"], key=int) == [str(j) for j in range(2, 8)] and d["idle_joints"] == []
    for j, why in d["skipped_joints"].items():
        assert why.startswith(REASON.format(j=j)), why
    report = (run / "report.md").read_text()
    assert "Torque: the controller's output" in report
    for j in range(2, 8):
        assert f"Joint {j} not diagnosed: " + REASON.format(j=j) in report
    # joint 1's torque is the same in both logs (its gravity torque is zero): its ripple found alike
    p_total = _ripple_params(total["joints"]["1"])
    for k in ("period_rad", "amplitude_Nm"):
        assert p[k] == pytest.approx(p_total[k], rel=0.01), k


def test_the_same_run_logged_as_the_total_command_is_diagnosed_at_every_joint(ripple):
    """No regression: the total command's run is diagnosed at all seven joints as before, nothing skipped, no
    torque kind said; the ripple named at joint 1 and nowhere else."""
    g, _, d = ripple
    assert d["conclusive"] and "torque" not in d
    assert list(d["joints"]) == [str(j) for j in range(1, 8)] and d["skipped_joints"] == {}
    assert d["effects_found"] == ["position_ripple"]
    assert [j for j, v in d["joints"].items() if v["effects"]] == ["1"]
    p = _ripple_params(d["joints"]["1"])
    assert p["period_rad"] == pytest.approx(g.effect_spec["period_rad"], rel=0.01)
    assert p["amplitude_Nm"] == pytest.approx(g.effect_spec["amplitude_Nm"], rel=0.05)


def test_no_joint_of_constant_gravity_torque_is_one_line_and_exit_2(tmp_path):
    """Only joints 2 and 4 move (their gravity torque varies): nothing is left to diagnose; one line naming each
    joint and why, exit 2, no run directory."""
    q0 = Q0_BASE.copy()
    ref = (ReferenceBuilder(q0, DT_S).hold(0.3, "settle").move({1: 0.3, 3: -0.4}, 0.5, 0.2, "out")
           .hold(0.2, "hold").move({1: -0.3, 3: 0.4}, 0.5, 0.2, "back").build())
    plant = {"friction": "table_4_1", "effects": {},
             "sensors": {"encoder_counts_per_rev": P.ENCODER_COUNTS_PER_REV}}
    run = write_measured(tmp_path / "total", simulate(plant, ref, q0), q0)
    ctrl = as_controller_torque(run, tmp_path / "ctrl")
    r = run_cli("diagnose", ctrl, "--out", tmp_path / "out", columns=400)
    assert r.exc is None, r.tb
    lines = [ln for ln in r.err.splitlines() if ln.strip()]
    assert r.code == 2 and len(lines) == 1, (r.code, r.err)
    assert lines[0].startswith("error: ") and "no joint left to diagnose (joint 2: " + REASON.format(j=2) in lines[0]
    assert "; joint 4: " + REASON.format(j=4) in lines[0], lines[0]
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").iterdir())
    assert np.ptp(pd.read_parquet(ctrl / "data.parquet")["q_1"]) < 0.01      # joint 1 held indeed


def test_pooling_controller_torque_runs_is_refused_in_one_line(ripple, tmp_path):
    """The pooled diagnosis knows the total command only so far: two controller-torque runs, one line, exit 2."""
    _, ctrl, _ = ripple
    other = shutil.copytree(ctrl, tmp_path / "ctrl2")
    r = run_cli("diagnose", ctrl, other, "--out", tmp_path / "out", columns=400)
    assert r.exc is None, r.tb
    assert r.code == 2 and r.err.strip().splitlines() == [
        f"error: {ctrl}: torque controller (the controller's output, gravity compensation added downstream and not "
        "logged): not supported by diagnose of several runs yet"], r.err
