"""The demo (`make demo`: configs/rotation.yaml, the thesis' rotation test under PD + gravity on the simulated
arm): the RPE per joint the README prints, at its printed precision; no joint reaches its torque limit; and the
plan check (`validate`, `--dry-run`, `run`) refuses a rotation that would hold a joint at its torque limit."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from wamctl.errors import SpecError
from wamctl.experiments.runner import plan_only, run_spec
from wamctl.model import params as P
from wamctl.report import write_report
from wamctl.runs.store import read_events, read_table
from wamctl.specs import load_spec, parse_spec

ROOT = Path(__file__).resolve().parents[2]
# README, "What it reproduces": RPE per joint of the demo, %, two decimals
README_RPE_PCT = [0.96, 0.27, 0.78, 0.28, 0.47, 1.75, 3.42]


def test_demo_rpe_per_joint_is_what_the_readme_prints(tmp_path):
    spec_path = ROOT / "configs" / "rotation.yaml"
    outcome = run_spec(load_spec(spec_path), spec_path.parent, tmp_path, make_report=False)
    assert outcome.status == "completed", outcome.reason
    rpe = write_report(outcome.path, tmp_path / "report", ("json",)).data["rpe_pct"]
    got = [rpe[str(j)] for j in range(1, 8)]
    assert got == pytest.approx(README_RPE_PCT, abs=0.005), got
    # issue 32: no joint at its torque limit, no joint off its reference (joint 2 sat at -20 N m for 29.6 s)
    data = read_table(outcome.path)
    tau_used = np.abs(data[[f"tau_{j}_Nm" for j in range(1, 8)]].to_numpy()).max(axis=0) / P.TAU_MAX_NM
    assert tau_used.max() < 0.75, tau_used
    ev = read_events(outcome.path)
    assert not ev["kind"].isin(["torque_saturation", "tracking_error"]).any()


def the_demo(**rotation) -> dict:
    raw = yaml.safe_load((ROOT / "configs" / "rotation.yaml").read_text())
    raw["rotation"].update(rotation)
    return raw


def test_the_plan_check_names_the_move_that_would_saturate():
    # the demo before issue 32 (+0.5 rad): joint 2's return lifts the tilted arm against gravity (-17.2 N m) and
    # Coulomb friction (-3.56 N m), over its 20 N m limit
    with pytest.raises(SpecError) as err:
        plan_only(parse_spec(the_demo(amplitude_rad=0.5)), ROOT / "configs")
    msg = str(err.value)
    assert msg.startswith("rotation: move 4 of 14 (return joint 2, 24.07-31.09 s) would saturate joint 2: it needs "
                          "-20.91 N m at 24.20 s (gravity -17.18, friction -3.59, acceleration -0.14) against its "
                          "20 N m torque limit"), msg
    assert "\n" not in msg


def test_the_demo_plan_is_within_the_torque_limits():
    summary, checks = plan_only(load_spec(ROOT / "configs" / "rotation.yaml"), ROOT / "configs")
    assert "torque needed at most 51% of a limit (joint 2: -10.1 of 20 N m at 16.15 s)" in checks


def test_a_pose_held_beyond_the_limit_is_refused_with_the_payload_the_plant_carries():
    # 3 kg at the wrist (the plant's, undeclared to the controller): the start pose alone takes 17.2 N m at joint 4
    raw = the_demo(joints=[2], mode="all_together")
    raw["plant"]["effects"] = {"payload": {"mass_kg": 3.0, "com_m": [0.0, 0.0, 0.05]}}
    with pytest.raises(SpecError) as err:
        plan_only(parse_spec(raw), ROOT / "configs")
    assert str(err.value).startswith(
        "rotation: hold (settle, 0.00-0.50 s) would saturate joint 4: it needs -17.15 N m at 0.00 s (gravity -17.15, "
        "friction +0.00, acceleration +0.00) against its 15 N m torque limit; 1 more segment too"), str(err.value)
