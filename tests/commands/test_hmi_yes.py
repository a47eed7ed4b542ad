"""`wamctl hmi-session --yes` answers a CAN session's questions as `wamctl run --yes` does (issue 30): against the
simulated WAM in its own process, just powered up (encoders not zeroed, at its home pose), with no terminal to
answer, the block zeroes the arm (`yes (--yes)`) and completes."""

from __future__ import annotations

import json
import os
import random
import signal
import subprocess
import sys

import can
import pytest
import yaml

pytestmark = pytest.mark.timeout(300)


def test_hmi_session_yes_zeroes_a_just_powered_arm(tmp_path):
    group = f"239.{random.randint(1, 254)}.{random.randint(1, 254)}.{random.randint(1, 254)}"
    port = random.randint(42000, 60000)
    try:
        can.Bus(interface="udp_multicast", channel=group, port=port).shutdown()
    except Exception as exc:  # noqa: BLE001 - any failure to join a multicast group
        pytest.skip(f"udp_multicast unavailable here: {exc}")
    spec = {"kind": "hmi_block", "name": "hmi-yes", "seed": 1,
            "backend": {"kind": "can", "interface": "udp_multicast", "channel": group, "bus_options": {"port": port},
                        "watchdog_cycles": 25, "reply_timeout_s": 0.05, "idle_wait_s": 5.0},
            "plant": {"friction": "table_4_1"}, "controller": {"kind": "pd_g"},
            "hmi": {"subject": {"id": "S1", "seed": 11, "skill": 0.8}, "source": {"kind": "virtual"},
                    "strategy": "four", "filter": {"kind": "ma", "window_s": 0.3},
                    "profile": {"kind": "dual", "speed_m_s": 0.03}, "attempts": 1, "timeout_s": 3,
                    "targets_m": {"P1": [0.35, 0.10]}}}
    p = tmp_path / "hmi.yaml"
    p.write_text(yaml.safe_dump(spec))
    arm = subprocess.Popen([sys.executable, "-m", "wamctl.cli", "sim-arm", "--interface", "udp_multicast",
                            "--channel", group, "--bus-option", f"port={port}", "--json", "--spec", str(p),
                            "--pose", "home", "--not-zeroed", "--asleep",
                            "--pendant", "move@0.3,activate@0.8,idle@end"],
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                           env={**os.environ, "COLUMNS": "300"})
    try:
        assert "serving" in arm.stderr.readline()
        r = subprocess.run([sys.executable, "-m", "wamctl", "hmi-session", str(p), "--out", str(tmp_path / "runs"),
                            "--yes", "--json"], capture_output=True, text=True, stdin=subprocess.DEVNULL,
                           timeout=240)
    finally:
        arm.send_signal(signal.SIGTERM)
        arm.communicate(timeout=60)
    assert r.returncode == 0, r.stderr[-2000:]
    assert "yes (--yes)" in r.stderr
    out = json.loads(r.stdout)
    assert out["status"] == "completed" and out["report"]["hmi"]["trials"] == 1
