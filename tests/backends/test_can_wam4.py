"""The CAN session against a 4-DOF WAM (issue 27 item 1): libbarrett's ``wam4`` on the bus is pucks 1-4 and the
safety module, no pucks 5-7 (``ProductManager::foundWam4``); its torques go in the packed frame to group 1 only
(``LowLevelWam``: ``ceil(4 / 4)`` torque groups), its positions come from the whole-WAM position request, it is
zeroed at calibration_data/wam4/zerocal.conf's home pose; the safety module and the watchdogs are the wam7's.

Against the simulated wam4 bus (four simulated pucks, the safety module, the wam4's dynamics) on python-can's virtual
bus: start-up, zeroing, gravity compensation and a short move with the positions checked against the simulator's
truth, a rotation run end to end; a wam4 spec on a 7-DOF WAM and a wam7 spec on a 4-DOF WAM refused in one line
naming the pucks before any puck is woken; a torque fault and a silent puck stopping the run as on the wam7.

Tolerances chosen before looking: positions within one encoder count's joint angle of the truth (the pucks
quantise once); zero torque within three cycles of the fault (issue 9's bound); the held arm within 0.01 rad of the
start pose (about 15 counts of joint 2) under the model's own gravity; the move's end within 0.01 rad of the
target under PD + gravity (a 0.05 rad ramp, libbarrett's wam4 gains). No assertion is on wall time.
"""

from __future__ import annotations

import uuid

import can
import numpy as np
import pytest
from can_wire import drain, host_sets, stop_seen_and_zeroed, torque_frames
from cli_runs import run_cli, write_yaml

from wamctl.backends.can.backend import CanBackend
from wamctl.backends.can.bus_check import bus_check, loop_bus_load_pct
from wamctl.backends.can.operator import ScriptedOperator
from wamctl.backends.can.protocol.addressing import GROUP_LOWER_WAM, GROUP_UPPER_WAM, SAFETY_PUCK_ID
from wamctl.backends.can.protocol.configuration import (
    FACTORY_GROUPS,
    WAM7_BUS,
    arm_on_bus,
    bus_arm,
    configuration_problems,
    puck_set_problem,
    zeroing_counts,
)
from wamctl.backends.can.protocol.properties import Mode, Prop, Status
from wamctl.backends.can.protocol.safety import SafetyMode, SafetyProp
from wamctl.backends.can.protocol.torques import (
    joint_torque_to_puck_units,
    make_torque_frames,
    puck_units_to_joint_torque_Nm,
    unpack_torques,
)
from wamctl.backends.can.session import SessionSettings
from wamctl.backends.can.sim.pucks import StaticPlant
from wamctl.backends.can.sim.simulator import PuckSimulator
from wamctl.errors import BackendError, ConfigurationRefused
from wamctl.experiments.runner import run_spec
from wamctl.model.dynamics import WamDynamics
from wamctl.model.robots import WAM4, WAM7
from wamctl.model.transmission import joint_rad_per_count
from wamctl.runs.store import open_run, read_table
from wamctl.specs import parse_spec

pytestmark = pytest.mark.timeout(180)

Q0_WAM4 = np.array([0.0, 0.0, 0.0, 1.57])      # the wam4 spec's default start pose
Q0_WAM7 = np.array([0.0, 0.0, 0.0, 1.57, 0.0, 0.0, 0.0])
SHORT_ROTATION = {"joints": [2, 4], "mode": "all_together", "amplitude_rad": 0.2, "velocity_rad_s": 0.2,
                  "tc_s": 0.3, "settle_s": 0.2, "hold_s": 0.5}
SENSORS = {"encoder_counts_per_rev": 4096, "position_noise_rad": 0.0}
MAX_CYCLES_TO_ZERO_TORQUE = 3  # issue 9


@pytest.fixture
def channel() -> str:
    return f"wamctl-wam4-{uuid.uuid4().hex[:12]}"


def wam4_spec(channel: str, name: str = "wam4_can", friction: str = "table_4_1", **backend) -> dict:
    """A wam4 rotation over CAN against the in-process simulated wam4 (link tolerances for a loaded machine)."""
    return {"kind": "rotation", "name": name, "robot": "wam4", "seed": 3,
            "plant": {"friction": friction, "sensors": dict(SENSORS)}, "rotation": dict(SHORT_ROTATION),
            "backend": {"kind": "can", "interface": "virtual", "channel": channel, "simulate_pucks": True,
                        "watchdog_cycles": 25, "reply_timeout_s": 0.05, "idle_wait_s": 5.0, **backend}}


# ------------------------------------------------------------------------------ the wam4 on the bus, no bus needed

def test_the_wam4_on_the_bus_is_libbarretts():
    arm = bus_arm("wam4")
    assert arm.puck_ids == (1, 2, 3, 4) and arm.absent_puck_ids == (5, 6, 7) and arm.n_joints == 4
    assert arm.torque_groups == {GROUP_LOWER_WAM: (1, 2, 3, 4)}       # group 1 only: no frame to 0x402
    assert arm.default_pidx == {1: 1, 2: 2, 3: 3, 4: 4}
    np.testing.assert_array_equal(arm.home_q_rad, [0.0, -2.0, 0.0, 3.13])   # wam4 zerocal.conf
    np.testing.assert_array_equal(arm.j2mp, [[-42.0, 0, 0, 0], [0, 28.25, -16.8155, 0], [0, -28.25, -16.8155, 0],
                                             [0, 0, 0, -18.0]])                   # wam4.conf j2mp
    assert WAM7_BUS.torque_groups == {GROUP_LOWER_WAM: (1, 2, 3, 4), GROUP_UPPER_WAM: (5, 6, 7)}
    # libbarrett verifyWamPucks: pucks 1..dof present and the rest of 1-7 absent (other nodes do not count)
    assert arm_on_bus({1, 2, 3, 4, SAFETY_PUCK_ID}) == "wam4"
    assert arm_on_bus(set(range(1, 8)) | {SAFETY_PUCK_ID, 11}) == "wam7"
    assert arm_on_bus({1, 2, 3}) is None and arm_on_bus({1, 2, 3, 4, 6}) is None
    # definePosition: floor(CTS / 2 pi * J2MP @ home), by hand: 4096 / 2 pi * (0, -56.5, 56.5, -56.34)
    np.testing.assert_array_equal(zeroing_counts([4096] * 4, arm.home_q_rad, arm.j2mp), [0, -36833, 36832, -36728])


def test_wam4_torques_go_in_one_packed_frame_to_group_1():
    arm = bus_arm("wam4")
    tau = np.array([10.0, -8.0, 5.0, 3.0])
    units = joint_torque_to_puck_units(tau, 2700, arm.j2mp)
    # through the wam4's own J2MP^-T: motor 1 = tau1 / -42, motor 4 = tau4 / -18
    assert units[0] == round(2700 * 10.0 / -42.0) and units[3] == round(2700 * 3.0 / -18.0)
    frames = make_torque_frames(units, arm.default_pidx, arm.torque_groups)
    assert [f.arbitration_id for f in frames] == [GROUP_LOWER_WAM] and len(frames[0].data) == 8
    np.testing.assert_array_equal(unpack_torques(frames[0].data), units)
    # back to joint torques within half a puck unit per motor, through J2MP^T
    back = puck_units_to_joint_torque_Nm(units, 2700, arm.j2mp)
    np.testing.assert_array_less(np.abs(back - tau), np.abs(arm.j2mp.T) @ np.full(4, 0.5 / 2700) + 1e-12)
    with pytest.raises(ValueError, match="expected 7 puck torques, got 4"):
        make_torque_frames(units)       # the wam7's two groups need seven
    # the control loop's bus load: 1 request + 4 replies + 1 torque frame (wam7: 7 + 2) per 2 ms at 1 Mbit/s
    assert loop_bus_load_pct(1_000_000, arm=arm) == pytest.approx((55 + 4 * 71 + 111) * 500 / 1e4)
    assert loop_bus_load_pct(1_000_000) == pytest.approx((55 + 7 * 71 + 2 * 111) * 500 / 1e4)


def test_the_wam4_configuration_checks_pucks_1_to_4_only():
    arm = bus_arm("wam4")
    factory = {p: FACTORY_GROUPS[p] for p in (1, 2, 3, 4)}
    assert configuration_problems(factory, {}, arm) == []           # no puck 7: no POLES to check
    assert configuration_problems(factory, {}) != []                 # the wam7 needs puck 7's POLES and groups
    bad = configuration_problems({**factory, 3: (0, 2, 4)}, {}, arm)
    assert bad == ["puck 3 is in groups 0/2/4 (GRPA/GRPB/GRPC), not in the torque group 1 (pucks 1-4) that its "
                   "packed torques are sent to"]
    assert puck_set_problem(arm, {1, 2, 3, 4, 10}) is None
    text, refused = puck_set_problem(arm, set(range(1, 8)))
    assert refused and "WAM pucks [5, 6, 7] answered: the bus holds a 7-DOF WAM (robot: wam7, pucks 1-7)" in text
    text, refused = puck_set_problem(WAM7_BUS, {1, 2, 3, 4})
    assert refused and "WAM pucks [5, 6, 7] did not answer: the bus holds a 4-DOF WAM (robot: wam4" in text
    text, refused = puck_set_problem(arm, {1, 2, 4})                 # a puck of the arm missing: the link
    assert not refused and text.startswith("WAM pucks [3] did not answer (power, cabling")


# ------------------------------------------------------------------------------ a wam4 session, frame by frame

def test_a_wam4_session_zeroes_at_its_home_and_drives_pucks_1_to_4_only(channel):
    """A wam4 just powered up (pucks in the monitor, encoders at arbitrary offsets, not zeroed) at its home pose:
    pucks 1-4 woken, zeroed at the wam4's home, moved by hand to the start pose, activated, torque sent to group 1
    only, idle at the end."""
    plant = StaticPlant(WAM4.home_q_rad)
    monitor = can.Bus(interface="virtual", channel=channel)
    try:
        with PuckSimulator(plant, channel=channel, robot="wam4", start_awake=False, zeroed=False, seed=5,
                           wake_s=0.05, start_pose_rad=Q0_WAM4, pendant="idle@end") as sim:
            # moved when asked, activated when asked (a scripted activation could come before the request to move)
            op = ScriptedOperator(answers=(True,), on_say={"Move the arm": lambda _t: sim.press("move"),
                                                           "Press Shift-Activate on the pendant":
                                                               lambda _t: sim.press("activate")})
            with CanBackend("virtual", channel, q0_rad=Q0_WAM4, robot="wam4", operator=op, reply_timeout_s=0.05,
                            watchdog_cycles=25, session=SessionSettings(activation_timeout_s=20.0,
                                                                        idle_wait_s=5.0)) as b:
                q = b.read_positions()
                tau = np.array([1.0, -2.0, 1.5, 0.5])
                applied = b.command_torques(tau).copy()
                b.wait_next_cycle()
                described = b.describe()
            modes, held = sim.modes(), sim.puck_torque_units()
        frames = drain(monitor)
    finally:
        monitor.shutdown()
    assert described["robot"] == "wam4" and sorted(described["pucks"]) == ["1", "2", "3", "4"]
    np.testing.assert_array_equal(applied, tau)
    # woken: pucks 1-4, never 5-7
    woken = [t for _, t, v in host_sets(frames, Prop.STAT) if v == Status.READY]
    assert woken == [1, 2, 3, 4]
    # zeroed at the wam4's home through its J2MP, then ZERO=1 on the safety module
    assert [(t, v) for _, t, v in host_sets(frames, Prop.P)] == list(zip(range(1, 5), [0, -36833, 36832, -36728]))
    assert [v for _, _, v in host_sets(frames, SafetyProp.ZERO, SAFETY_PUCK_ID)] == [1]
    assert "(0, -2, 0, 3.13) rad" in op.questions[0]
    # the run's first reading is the start pose within one count; torques in group 1's frame only
    np.testing.assert_array_less(np.abs(q - Q0_WAM4), joint_rad_per_count(4096, WAM4.j2mp) + 1e-12)
    ids = {m.arbitration_id for m in frames if m.arbitration_id in (GROUP_LOWER_WAM, GROUP_UPPER_WAM)}
    assert ids == {GROUP_LOWER_WAM}
    assert any(s.tolist() == joint_torque_to_puck_units(tau, 2700, WAM4.j2mp).tolist() for _, s in
               torque_frames(frames))
    # closed: zero torque, pucks 1-4 confirmed idle
    assert modes == dict.fromkeys((1, 2, 3, 4), int(Mode.IDLE)) and not held.any()
    assert b.idle_confirmed == [1, 2, 3, 4]


def test_wam4_holds_under_gravity_compensation_and_moves_with_positions_at_the_truth(channel):
    """The simulated wam4's dynamics behind the pucks: 0.3 s held by the model's gravity torque plus libbarrett's
    wam4 PD, then joint 2 ramped 0.05 rad at 0.1 rad/s and held 0.3 s; every reading within one encoder count of
    the truth. (A step instead of the ramp swings the elbow near the safety module's 1 m/s: the simulated module
    times its speed by the wall clock, which a loaded machine compresses.)"""
    spec = parse_spec(wam4_spec(channel, friction="none"))
    b = CanBackend.from_spec(spec, None, Q0_WAM4, np.random.default_rng(0))
    b.operator = ScriptedOperator()
    dyn = WamDynamics(robot="wam4")
    kp, kd = WAM4.kp, WAM4.kd
    count_rad = joint_rad_per_count(4096, WAM4.j2mp)
    move = np.array([0.0, 0.05, 0.0, 0.0])
    worst = np.zeros(4)
    with b:
        q_prev = b.read_positions().copy()
        held = None
        for k in range(550):
            q = b.read_positions() if k else q_prev
            q_true, _ = b.simulated_arm.truth()
            worst = np.maximum(worst, np.abs(q - q_true))
            ref = Q0_WAM4 + move * min(1.0, max(0.0, (k - 150) / 250))
            qd = (q - q_prev) * 500.0
            q_prev = q.copy()
            b.command_torques(dyn.gravity(q) + kp * (ref - q) - kd * qd)
            b.wait_next_cycle()
            if k == 149:
                held = q_true.copy()
        q_end, _ = b.simulated_arm.truth()
        assert b.simulator.describe()["robot"] == "wam4"
    assert b.trip_reason is None
    np.testing.assert_array_less(worst, count_rad + 1e-12)
    np.testing.assert_array_less(np.abs(held - Q0_WAM4), 0.01)
    np.testing.assert_array_less(np.abs(q_end - (Q0_WAM4 + move)), 0.01)
    assert abs(q_end[1] - Q0_WAM4[1]) > 0.04          # it did move


def test_a_wam4_rotation_over_can_runs_end_to_end(runs_dir, channel):
    monitor = can.Bus(interface="virtual", channel=channel)
    try:
        outcome = run_spec(parse_spec(wam4_spec(channel)), None, runs_dir, make_report=False)
        frames = drain(monitor)
    finally:
        monitor.shutdown()
    assert outcome.status == "completed", outcome.reason
    manifest, _ = open_run(outcome.path)
    assert manifest["backend"]["robot"] == "wam4" and sorted(manifest["backend"]["pucks"]) == ["1", "2", "3", "4"]
    data = read_table(outcome.path)
    assert {"q_4_rad", "tau_4_Nm"} <= set(data.columns) and "q_5_rad" not in data.columns
    # the rotation reached its amplitude on joints 2 and 4 (PD + gravity, Table 4.1 friction): within 0.02 rad
    q2 = data["q_2_rad"].to_numpy()
    assert abs(q2.max() - q2[0] - 0.2) < 0.02 or abs(q2[0] - q2.min() - 0.2) < 0.02
    assert {m.arbitration_id for m in frames if m.arbitration_id in (GROUP_LOWER_WAM, GROUP_UPPER_WAM)} \
        == {GROUP_LOWER_WAM}
    assert not manifest["backend"]["watchdog"]["tripped"] and manifest["backend"]["link"]["garbage_frames"] == 0
    sim = manifest["backend"]["simulation"]
    assert sim["arm"]["robot"] == "wam4" and len(sim["puck_torque_units"]) == 4
    # one packed-torque frame per cycle (a wam7 sends two): at most one per position request
    assert 0 < sim["stats"]["torque_frames"] <= sim["stats"]["position_requests"]


# ------------------------------------------------------------------------------ the wrong arm is refused

def _refused(tmp_path, runs_dir, channel, spec: dict, robot: str):
    """``wamctl run`` of ``spec`` against a simulated ``robot`` bus (pucks in the monitor): exit code, the error
    line, the frames."""
    path = write_yaml(tmp_path / "spec.yaml", {**spec, "out_dir": str(runs_dir)})
    monitor = can.Bus(interface="virtual", channel=channel)
    try:
        q = WAM4.home_q_rad if robot == "wam4" else WAM7.home_q_rad
        with PuckSimulator(StaticPlant(q), channel=channel, robot=robot, start_awake=False) as sim:
            res = run_cli("run", path, "--quiet")
            modes = sim.modes()
        frames = drain(monitor)
    finally:
        monitor.shutdown()
    return res, frames, modes


@pytest.mark.parametrize("spec_robot,bus_robot,words", [
    ("wam4", "wam7", "robot wam4 expects pucks 1-4 and no WAM puck beyond, but WAM pucks [5, 6, 7] answered: the "
                     "bus holds a 7-DOF WAM (robot: wam7, pucks 1-7); a wam4 session is refused on it"),
    ("wam7", "wam4", "WAM pucks [5, 6, 7] did not answer: the bus holds a 4-DOF WAM (robot: wam4, pucks 1-4), not "
                     "the wam7 the spec names; refused"),
])
def test_a_spec_for_another_arm_is_refused_naming_the_pucks(tmp_path, runs_dir, channel, spec_robot, bus_robot,
                                                            words):
    backend = {"kind": "can", "interface": "virtual", "channel": channel, "reply_timeout_s": 0.05,
               "idle_wait_s": 1.0}
    spec = {"kind": "rotation", "name": "wrong_arm", "robot": spec_robot, "rotation": dict(SHORT_ROTATION),
            "backend": backend}
    res, frames, modes = _refused(tmp_path, runs_dir, channel, spec, bus_robot)
    assert res.code == 2 and res.exc is None, (res.code, res.err, res.tb)
    # the operator was told what the safety module says; the refusal is one line
    failed = [ln for ln in res.err.splitlines() if ln.startswith("failed:")]
    assert len(failed) == 1 and words in failed[0] and "Traceback" not in res.err, res.err
    # refused before anything moved: no puck woken, no zeroing, no torque frame, every puck idle
    assert not [v for _, _, v in host_sets(frames, Prop.STAT) if v == Status.READY]
    assert not host_sets(frames, Prop.P) and not torque_frames(frames)
    assert set(modes.values()) == {int(Mode.IDLE)}


def test_the_backend_refuses_a_wam4_spec_on_a_7_dof_bus_before_waking(channel):
    with PuckSimulator(StaticPlant(Q0_WAM7), channel=channel, start_awake=False) as sim:
        b = CanBackend("virtual", channel, q0_rad=Q0_WAM4, robot="wam4", operator=ScriptedOperator(),
                       reply_timeout_s=0.05, session=SessionSettings(activation_timeout_s=0.3, idle_wait_s=0.0))
        with pytest.raises(ConfigurationRefused, match=r"WAM pucks \[5, 6, 7\] answered"):
            b.open()
        assert b._bus is None and sim.property_value(1, Prop.STAT) == Status.RESET     # never woken
    with pytest.raises(BackendError, match="q0_rad has 7 joints; the wam4 has 4"):
        CanBackend("virtual", channel, q0_rad=Q0_WAM7, robot="wam4")


def test_bus_check_names_the_wam4(channel):
    r = bus_check("virtual", channel, simulate_pucks=True, robot="wam4", window_s=0.05)
    assert r["arm"] == "wam4" and r["problems"] == [] and r["missing_wam_pucks"] == []
    assert sorted(p["puck_id"] for p in r["pucks"] if p["kind"] == "wam motor") == [1, 2, 3, 4]
    r7 = bus_check("virtual", channel + "-7", simulate_pucks=True, robot=None, window_s=0.05, wake=False)
    assert r7["arm"] == "wam7"


def test_bus_check_command_takes_the_wam4(channel):
    """`wamctl bus-check --robot wam4` against the simulated wam4: pucks 1-4 and the safety module, no problem,
    the 500 Hz loop's load of a wam4 (one position request, 4 replies, one packed-torque frame: (55 + 4 x 71 + 111)
    bits x 500 Hz = 22.5 % of 1 Mbit/s, the wam7's 38.7 %), and the ok line names the 4-DOF arm; an arm wamctl does
    not know is refused in one line."""
    res = run_cli("bus-check", "--interface", "virtual", "--channel", channel, "--simulate-pucks", "--robot", "wam4",
                  "--window", "0.05", "--json")
    assert res.code == 0 and res.exc is None, res.err + res.tb
    import json

    r = json.loads(res.out)
    assert r["arm"] == "wam4" and r["problems"] == [] and r["missing_wam_pucks"] == []
    assert sorted(p["puck_id"] for p in r["pucks"] if p["kind"] == "wam motor") == [1, 2, 3, 4]
    assert r["load"]["control_loop_load_pct"] == pytest.approx(100 * (55 + 4 * 71 + 111) * 500 / 1e6)
    assert r["load"]["control_loop_load_pct"] == pytest.approx(loop_bus_load_pct(1_000_000, arm=bus_arm("wam4")))
    text = run_cli("bus-check", "--interface", "virtual", "--channel", channel + "-t", "--simulate-pucks", "--robot",
                   "wam4", "--window", "0.05", columns=200)
    assert text.code == 0, text.err
    assert ("ok safety module and WAM pucks 1-4 found (no pucks 5-7), supported firmware, a 4-DOF WAM (robot: "
            "wam4), groups 1/4") in text.out, text.out
    bad = run_cli("bus-check", "--interface", "virtual", "--channel", channel + "-b", "--simulate-pucks", "--robot",
                  "wam9")
    assert bad.code == 2 and bad.err.strip().splitlines() == ["error: --robot 'wam9': not an arm wamctl knows "
                                                              "(wam7 or wam4)"], bad.err


# ------------------------------------------------------------------------------ faults stop it as on the wam7

FAULTS = {
    # TL2 = 0.05 N m of motor torque (135 puck units): the gravity torque of joint 2 needs more at once
    "torque_fault": ({"torque_limit_Nm": 0.05}, "safety module: torque fault TL2 (a motor command above 135 puck "
                                                "units)"),
    # the safety module measures the elbow of the wam4 (pucks 1-4's positions) faster than 0.03 m/s as joint 2 turns
    "velocity_fault": ({"velocity_limit_m_s": 0.03}, "safety module: velocity fault VL2 (faster than 0.03 m/s"),
    "silent_puck": ({"simulated_fault": {"kind": "silent_puck", "puck": 4, "at_cycle": 150}, "watchdog_cycles": 3},
                    "position replies from pucks [4] missing or late for 4 consecutive cycles"),
}


@pytest.mark.parametrize("fault", list(FAULTS))
def test_a_fault_stops_the_wam4_as_the_wam7(runs_dir, channel, fault):
    extra, words = FAULTS[fault]
    monitor = can.Bus(interface="virtual", channel=channel)
    try:
        outcome = run_spec(parse_spec(wam4_spec(channel, name=f"wam4-{fault}", **extra)), None, runs_dir,
                           make_report=False)
        frames = drain(monitor)
    finally:
        monitor.shutdown()
    manifest, _ = open_run(outcome.path)
    assert outcome.status == manifest["status"] == "failed"
    assert words in manifest["reason"], manifest["reason"]
    w = manifest["backend"]["watchdog"]
    data = read_table(outcome.path)
    assert w["tripped"] and len(data) == w["trip_cycle"]
    assert np.isfinite(data.to_numpy()).all()
    held = manifest["backend"]["simulation"]["puck_torque_units"]
    if fault == "silent_puck":        # a puck off the bus cannot be commanded: it keeps its last torque
        assert w["fault_onset_cycle"] >= 150 and w["cycles_to_zero_torque"] <= MAX_CYCLES_TO_ZERO_TORQUE
        assert not any(held[:3]) and w["idle_confirmed_pucks"] == [1, 2, 3]
    else:
        seen, zeroed, between = stop_seen_and_zeroed(frames)
        assert 0 <= between <= MAX_CYCLES_TO_ZERO_TORQUE, (seen, zeroed)
        assert not any(held)
        assert manifest["backend"]["simulation"]["safety_module"]["mode"] == SafetyMode.IDLE.words
    assert {m.arbitration_id for m in frames if m.arbitration_id in (GROUP_LOWER_WAM, GROUP_UPPER_WAM)} \
        == {GROUP_LOWER_WAM}


def test_a_silent_puck_the_wam4_does_not_have_is_refused_in_the_spec(tmp_path):
    spec = wam4_spec("unused", simulated_fault={"kind": "silent_puck", "puck": 5})
    res = run_cli("validate", write_yaml(tmp_path / "bad.yaml", spec))
    assert res.code == 2 and "joint 5 is not a joint of the wam4" in res.err, res.err
