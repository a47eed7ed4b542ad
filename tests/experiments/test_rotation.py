"""The demo (`make demo`: configs/rotation.yaml, the thesis' rotation test under PD + gravity on the simulated
arm): the RPE per joint the README prints, at its printed precision."""

from __future__ import annotations

from pathlib import Path

import pytest

from wamctl.experiments.runner import run_spec
from wamctl.report import write_report
from wamctl.specs import load_spec

ROOT = Path(__file__).resolve().parents[2]
# README, "What it reproduces": RPE per joint of the demo, %, two decimals
README_RPE_PCT = [0.99, 0.20, 0.57, 0.52, 1.10, 1.92, 1.34]


def test_demo_rpe_per_joint_is_what_the_readme_prints(tmp_path):
    spec_path = ROOT / "configs" / "rotation.yaml"
    outcome = run_spec(load_spec(spec_path), spec_path.parent, tmp_path, make_report=False)
    assert outcome.status == "completed", outcome.reason
    rpe = write_report(outcome.path, tmp_path / "report", ("json",)).data["rpe_pct"]
    got = [rpe[str(j)] for j in range(1, 8)]
    assert got == pytest.approx(README_RPE_PCT, abs=0.005), got
