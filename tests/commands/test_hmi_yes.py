"""`wamctl hmi-session --yes` answers a CAN session's questions as `wamctl run --yes` does (issue 30): against the
simulated WAM in its own process, just powered up (encoders not zeroed, at its home pose), with no terminal to
answer, the block zeroes the arm (`yes (--yes)`) and completes.

The arm is a process of its own (tests/sim_arm.py, as in tests/backends/test_can_cross_process.py); the command
runs in this one (tests/cli_runs.py), its stdin empty and not a terminal."""

from __future__ import annotations

import io
import json

import pytest
import yaml
from cli_runs import run_cli
from sim_arm import PENDANT_AFTER_ZEROING, SimArm, can_backend

pytestmark = pytest.mark.timeout(300)


def test_hmi_session_yes_zeroes_a_just_powered_arm(tmp_path, udp, monkeypatch):
    group, port = udp
    spec = {"kind": "hmi_block", "name": "hmi-yes", "seed": 1, "backend": can_backend(group, port),
            "plant": {"friction": "table_4_1"}, "controller": {"kind": "pd_g"},
            "hmi": {"subject": {"id": "S1", "seed": 11, "skill": 0.8}, "source": {"kind": "virtual"},
                    "strategy": "four", "filter": {"kind": "ma", "window_s": 0.3},
                    "profile": {"kind": "dual", "speed_m_s": 0.03}, "attempts": 1, "timeout_s": 3,
                    "targets_m": {"P1": [0.35, 0.10]}}}
    p = tmp_path / "hmi.yaml"
    p.write_text(yaml.safe_dump(spec))
    monkeypatch.setattr("sys.stdin", io.StringIO(""))          # no terminal to answer (was stdin=DEVNULL)
    arm = SimArm(group, port, "--spec", p, "--pose", "home", "--not-zeroed", "--asleep",
                 "--pendant", PENDANT_AFTER_ZEROING)
    try:
        r = run_cli("hmi-session", p, "--out", tmp_path / "runs", "--yes", "--json")
    finally:
        arm.stop()
    assert r.exc is None, r.tb
    assert r.code == 0, r.err[-2000:]
    assert "yes (--yes)" in r.err
    out = json.loads(r.out)
    assert out["status"] == "completed" and out["report"]["hmi"]["trials"] == 1
