"""The simulated WAM in its own process (``wamctl sim-arm``) over python-can's ``udp_multicast`` interface, a run in
this one: the lab's situation (issue 14). A whole first session of the day, from power-up (pucks in the monitor,
encoders not zeroed, the arm at its home pose) through zeroing, the operator moving the arm to the start pose,
Shift-Activate and the rotation test, must match the direct simulation as the in-process virtual bus does; the
wire (recorded by python-can's logger in a third process) shows libbarrett's pacing, no MODE=TORQUE from wamctl and zero
torque until every puck reports TORQUE. A gimbals arm is refused on the command line in one line.

Each test uses its own multicast group and port, so that runs of other test sessions on this machine do not mix
(tests/sim_arm.py, the setup tests/commands/test_hmi_yes.py shares).
"""

from __future__ import annotations

import signal
import subprocess
import sys

import can
import numpy as np
import pytest
import yaml
from can_wire import all_pucks_torque_index, host_mode_writes, host_sets, torque_frames, wake_pacing
from conftest import Q0, rotation_spec
from sim_arm import PENDANT_AFTER_ZEROING, SimArm, can_backend
from typer.testing import CliRunner

from wamctl.analysis.rotation import rotation_metrics
from wamctl.backends.can.protocol.configuration import zeroing_counts
from wamctl.backends.can.protocol.properties import Mode, Prop
from wamctl.experiments.runner import run_spec
from wamctl.model.transmission import joint_rad_per_count
from wamctl.runs.store import open_run, read_table
from wamctl.specs import parse_spec

pytestmark = pytest.mark.timeout(300)

SHORT_ROTATION = {"joints": [2, 4], "mode": "all_together", "amplitude_rad": 0.2, "velocity_rad_s": 0.2,
                  "tc_s": 0.3, "settle_s": 0.2, "hold_s": 0.5}


class WireLog:
    """``python -m can.logger`` on the multicast group, in its own process, into ``path`` (candump format); on
    leaving, stopped with SIGINT (it closes the file) and its frames read back in the order received."""

    def __init__(self, group: str, port: int, path):
        self.path, self.frames = path, []
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "can.logger", "-i", "udp_multicast", "-c", group, "--bus-kwargs", f"port={port}",
             "-f", str(path)], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))   # a background shell ignores it

    def __enter__(self):
        line = self.proc.stdout.readline()          # "Connected to UdpMulticastBus..." once it listens
        assert "Connected" in line, line + self.proc.stdout.read()
        return self

    def __exit__(self, *exc):
        self.proc.send_signal(signal.SIGINT)
        self.proc.wait(timeout=30)
        self.frames = list(can.LogReader(self.path))


def test_first_session_of_the_day_over_udp_matches_the_direct_simulation(runs_dir, udp, tmp_path):
    group, port = udp
    can_spec = rotation_spec(name="xproc", rotation=SHORT_ROTATION,
                             backend=can_backend(group, port, zeroing_confirmed=True))
    spec_file = tmp_path / "xproc.yaml"
    spec_file.write_text(yaml.safe_dump(can_spec))
    # the wire is recorded by python-can's logger in a process of its own: a reader thread in this process (which
    # runs the 500 Hz session) could be starved of the GIL on a loaded machine, its socket overflow and a frame be
    # missing from the record (a puck's MODE=TORQUE reply lost put the confirmation later than the torques)
    with WireLog(group, port, tmp_path / "wire.log") as wire:
        arm = SimArm(group, port, "--spec", str(spec_file), "--pose", "home", "--not-zeroed", "--asleep",
                     "--pendant", PENDANT_AFTER_ZEROING)
        try:
            out_can = run_spec(parse_spec(can_spec), tmp_path, runs_dir, make_report=False)
        finally:
            seen = arm.stop()
    frames = wire.frames
    out_direct = run_spec(parse_spec(rotation_spec(name="direct", rotation=SHORT_ROTATION)), None, runs_dir,
                          make_report=False)
    assert out_can.status == "completed", out_can.reason
    data_can, data_direct = read_table(out_can.path), read_table(out_direct.path)
    q_cols = [f"q_{j}_rad" for j in range(1, 8)]
    # zeroed at home, moved to the start pose by the operator: the run starts at the spec's q0
    np.testing.assert_array_less(np.abs(data_can[q_cols].to_numpy()[0] - Q0), joint_rad_per_count(4096) + 1e-12)
    # as on the virtual bus (tests/backends/test_can_backend.py): RPE within 5 %, trajectory within 5e-4 rad
    m_can, m_direct = rotation_metrics(data_can), rotation_metrics(data_direct)
    assert (m_direct["rpe_pct"] > 0.1).all()
    np.testing.assert_allclose(m_can["rpe_pct"], m_direct["rpe_pct"], rtol=0.05)
    assert np.abs(data_can[q_cols].to_numpy() - data_direct[q_cols].to_numpy()).max() < 5e-4

    # the wire: libbarrett's pacing, the zeroing, no MODE=TORQUE, zero torque until every puck reports TORQUE
    w = wake_pacing(frames)
    assert w["n"] == 7 and min(w["gaps_s"]) >= 0.010 - 5e-4 and w["silence_s"] >= 1.0 - 5e-4
    assert [v for _, _, v in host_sets(frames, Prop.P)] == zeroing_counts([4096] * 7).tolist()
    assert {v for _, v in host_mode_writes(frames)} == {int(Mode.IDLE)}
    i_torque = all_pucks_torque_index(frames)
    tq = torque_frames(frames)
    st = seen["stats"]
    # what the arm saw: no torque other than zero to a puck before it was in TORQUE (counted by the arm itself)
    assert st["nonzero_torque_not_in_torque_mode"] == 0 and any(s.any() for i, s in tq if i > i_torque)
    # and on the wire, when the record holds every torque frame the arm got (on a loaded machine the recorder's
    # socket can overflow: a hole in its kernel time stamps, a TORQUE reply missing, the check inconclusive)
    if len(tq) == st["torque_frames"]:
        assert not any(s.any() for i, s in tq if i < i_torque)
    assert st["host_mode_writes_refused"] == 0 and st["bus_off_events"] == 0
    assert seen["safety_module"]["zero"] == 1 and seen["safety_module"]["mode"] == "Shift-idle"
    manifest, _ = open_run(out_can.path)
    assert manifest["backend"]["session"]["zeroed_now"] is True


def test_gimbals_arm_is_refused_in_one_line(runs_dir, udp, tmp_path):
    group, port = udp
    spec_file = tmp_path / "gimbals.yaml"
    spec_file.write_text(yaml.safe_dump({**rotation_spec(name="gimbals", rotation=SHORT_ROTATION,
                                                         backend=can_backend(group, port)), "out_dir": str(runs_dir)}))
    arm = SimArm(group, port, "--gimbals", "--zeroed", "--awake")
    try:
        from wamctl.cli import _register, app
        _register()
        res = CliRunner().invoke(app, ["run", str(spec_file), "--quiet"])
    finally:
        seen = arm.stop()
    assert res.exit_code != 0
    text = " ".join(res.output.split())
    assert "puck 7 reports POLES=8: a WAM with gimbals" in text and "Traceback" not in res.output
    assert seen["stats"]["torque_frames"] == 0 and seen["stats"]["position_requests"] == 0
