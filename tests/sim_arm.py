"""The simulated WAM in a process of its own (``wamctl sim-arm``) on a ``udp_multicast`` CAN bus of the test's own:
the setup shared by the cross-process tests (tests/backends/test_can_cross_process.py: a rotation run,
tests/commands/test_hmi_yes.py: an HMI session answered by --yes)."""

from __future__ import annotations

import json
import os
import random
import signal
import subprocess
import sys

import can
import pytest


@pytest.fixture
def udp() -> tuple[str, int]:
    """A multicast group and port of this test's own (runs of other test sessions on this machine do not mix);
    skipped, with the reason, where multicast is unavailable."""
    group = f"239.{random.randint(1, 254)}.{random.randint(1, 254)}.{random.randint(1, 254)}"
    port = random.randint(42000, 60000)
    try:
        can.Bus(interface="udp_multicast", channel=group, port=port).shutdown()
    except Exception as exc:  # noqa: BLE001 - any failure to join a multicast group
        pytest.skip(f"udp_multicast unavailable here: {exc}")
    return group, port


# what the simulated operator does on a just-powered arm (times from the first position request): moves the arm to
# the start pose only after wamctl has checked the zeroing. That check reads the positions at the first heartbeat,
# right after the first read (which waits up to 1 s for the pucks); a move scripted at 0.3 s came first on a loaded
# machine, and the check read the start pose ("after zeroing, joint 2 reads -0.0000 rad instead of the home pose's
# -2.0000 rad", test_can_cross_process and test_hmi_yes, 2 in 3 full runs of the suite on 2026-11-27)
PENDANT_AFTER_ZEROING = "move@2.0,activate@2.5,idle@end"


def can_backend(group: str, port: int, **kw) -> dict:
    """A spec's ``backend`` on that bus, with the timeouts the cross-process tests use."""
    return {"kind": "can", "interface": "udp_multicast", "channel": group, "bus_options": {"port": port},
            "watchdog_cycles": 25, "reply_timeout_s": 0.05, "idle_wait_s": 5.0, **kw}


class SimArm:
    """``wamctl sim-arm`` in a subprocess: started, waited for ("serving"), stopped with SIGTERM (SIGINT is ignored
    by processes started from a background job)."""

    def __init__(self, group: str, port: int, *args: str) -> None:
        cmd = [sys.executable, "-m", "wamctl.cli", "sim-arm", "--interface", "udp_multicast", "--channel", group,
               "--bus-option", f"port={port}", "--json", *map(str, args)]
        self.proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                     env={**os.environ, "COLUMNS": "300"})
        self.seen: dict | None = None
        # ready when it logs that it serves (event-driven: the first line on stderr, no sleep)
        line = self.proc.stderr.readline()
        if "serving" not in line:
            self.proc.kill()
            raise RuntimeError(f"sim-arm did not start: {line}{self.proc.stderr.read()}")

    def stop(self) -> dict:
        """SIGTERM; what the arm saw (its --json summary). It must have exited cleanly."""
        self.proc.send_signal(signal.SIGTERM)
        out, err = self.proc.communicate(timeout=60)
        assert self.proc.returncode == 0, err
        self.seen = json.loads(out)
        return self.seen
