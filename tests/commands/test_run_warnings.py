"""Issue 32, item 2, on the terminal: after a run, each stretch of a joint at its torque limit or off its
reference is one warning line (not one per tick), within 80 columns, also with --quiet, in --json and after a
failed run; and validate / run --dry-run refuse a plan that would saturate, in one line."""

from __future__ import annotations

import json
import uuid

import yaml
from cli_runs import Q0, ROOT, run_cli, write_yaml

# Joint 1 with a breakaway of 6 x its Coulomb level (26.8 N m) above its 25 N m limit: it never starts, the PD
# error grows until its torque sits at the limit. The plan check cannot see it (it uses the Coulomb level the
# spec declares): the run must say it. 0.1 rad at 0.2 rad/s: 0.9 s of arm time.
STUCK = {"kind": "rotation", "name": "stuck", "seed": 1, "q0_rad": Q0,
         "plant": {"friction": "table_4_1",
                   "effects": {"stribeck": {"joints": [1], "breakaway_ratio": 6.0, "vs_rad_s": 0.05}}},
         "rotation": {"joints": [1], "mode": "all_together", "amplitude_rad": 0.1, "velocity_rad_s": 0.2,
                      "tc_s": 0.2, "settle_s": 0.0, "hold_s": 0.2}}


def test_a_joint_stuck_at_its_torque_limit_is_one_warning_line_after_the_run(tmp_path):
    spec = write_yaml(tmp_path / "stuck.yaml", STUCK)
    r = run_cli("run", spec, "--out", tmp_path / "runs", "--quiet")
    assert r.exc is None and r.code == 0, r.tb or r.err
    lines = [x for x in r.out.splitlines() if x.startswith("warning: ")]
    assert lines == ["warning: joint 1 at torque limit 0.23-0.90 s (0.7 s), peak +25.0 N m",
                     "warning: joint 1 error > 0.05 rad 0.35-0.90 s (0.6 s), peak +0.100 rad"]
    assert all(len(x) <= 80 for x in lines), lines

    r = run_cli("run", spec, "--out", tmp_path / "runs", "--json")
    assert r.code == 0, r.err
    assert json.loads(r.out)["warnings"] == [x.removeprefix("warning: ") for x in lines]


def test_a_failed_run_on_the_can_arm_says_its_warnings_too(tmp_path):
    # the same stuck joint over CAN (simulated pucks), the E-stop pressed at cycle 400 (0.8 s): the run fails,
    # no report is written, and the loop's warnings are still said before the status line
    spec = dict(STUCK, name="stuck-can", rotation=dict(STUCK["rotation"]),
                backend={"kind": "can", "interface": "virtual", "channel": f"wamctl-test-{uuid.uuid4().hex[:12]}",
                         "simulate_pucks": True, "watchdog_cycles": 25, "reply_timeout_s": 0.05,
                         "simulated_fault": {"kind": "estop", "at_cycle": 400}})
    r = run_cli("run", write_yaml(tmp_path / "stuck_can.yaml", spec), "--out", tmp_path / "runs", "--quiet")
    assert r.exc is None and r.code == 1, r.tb or r.err
    assert "failed: safety limit: E-stop on the pendant" in r.err
    lines = [x for x in r.out.splitlines() if x.startswith("warning: ")]
    assert [x.split(" 0.")[0] for x in lines] == ["warning: joint 1 at torque limit", "warning: joint 1 error >"]
    assert lines[0].endswith("-0.80 s (0.6 s), peak +25.0 N m")      # until the E-stop at 0.8 s


def test_validate_and_dry_run_refuse_the_old_demo_in_one_line(tmp_path):
    # configs/rotation.yaml before issue 32 (+0.5 rad): joint 2's return needs more than its 20 N m
    raw = yaml.safe_load((ROOT / "configs" / "rotation.yaml").read_text())
    raw["rotation"]["amplitude_rad"] = 0.5
    spec = write_yaml(tmp_path / "old_demo.yaml", raw)
    for args in (("validate", spec), ("run", spec, "--dry-run")):
        r = run_cli(*args)
        assert r.exc is None and r.code == 2, (args, r.tb, r.out)
        assert r.err.startswith("error: rotation: move 4 of 14 (return joint 2, 24.07-31.09 s) would saturate joint 2")
        assert len(r.err.strip().splitlines()) == 1 and "nothing moved" not in r.out
