"""The simulated WAM is as strict as the real one where wamctl relies on it (issue 14): the safety module alone puts
the pucks into TORQUE, stopping the polling is a heartbeat fault, talking while pucks wake puts the host
bus-off, encoders read arbitrary offsets until zeroed, the pendant follows a script, position replies of 3 or 6
bytes, groups decide who answers; and the protocol pieces the session relies on (safety module ids, PEN, limits,
the arm's configuration, the zeroing counts)."""

from __future__ import annotations

import time
import uuid

import can
import numpy as np
import pytest
from can_wire import wait_for
from conftest import Q0

from wamctl.backends.can.bus_tools import read_property, wake_pucks
from wamctl.backends.can.protocol.addressing import GROUP_WAM, SAFETY_PUCK_ID, WAM_PUCK_IDS, PuckFrameError
from wamctl.backends.can.protocol.configuration import FACTORY_GROUPS, configuration_problems, zeroing_counts
from wamctl.backends.can.protocol.positions import (
    make_position_request,
    parse_combined_position_reply,
    parse_position_reply,
)
from wamctl.backends.can.protocol.properties import (
    ROLE_OPTICAL_ENC_ON_ENC,
    Mode,
    Prop,
    Status,
    make_get_property,
    make_set_property,
)
from wamctl.backends.can.protocol.safety import (
    SAFETY_BROADCAST_ID,
    Level,
    PendantState,
    SafetyMode,
    SafetyProp,
    check_safety_firmware,
    decode_pen,
    encode_pen,
    velocity_limit_units,
)
from wamctl.backends.can.protocol.torques import make_torque_frames
from wamctl.backends.can.sim.pendant import parse_pendant_script
from wamctl.backends.can.sim.pucks import JOINT_ENCODER_COUNTS, StaticPlant
from wamctl.backends.can.sim.safety_module import elbow_and_end_point_m
from wamctl.backends.can.sim.simulator import PuckSimulator
from wamctl.errors import BackendError
from wamctl.model.transmission import joint_rad_to_counts

pytestmark = pytest.mark.timeout(60)
Q = np.array([0.3, -1.2, 0.8, 2.0, -0.5, 0.4, -2.2])


@pytest.fixture
def channel() -> str:
    return f"wam-sim-{uuid.uuid4().hex[:12]}"


@pytest.fixture
def host(channel):
    bus = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
    yield bus
    bus.shutdown()


def positions(bus: can.BusABC, n: int = 7, timeout_s: float = 0.25) -> dict[int, can.Message]:
    bus.send(make_position_request())
    out = {}
    while len(out) < n and (m := bus.recv(timeout=timeout_s)) is not None:
        if m.arbitration_id != SAFETY_BROADCAST_ID:
            out[parse_position_reply(m)[0]] = m
    return out


def module(bus, prop):
    return read_property(bus, [SAFETY_PUCK_ID], prop, 0.2).get(SAFETY_PUCK_ID)


# --------------------------------------------------------------------------------------------- protocol pieces

def test_safety_module_ids_and_pen_layout():
    # libbarrett property_list.cpp, safety module VERS >= 61
    assert (SafetyProp.MODE, SafetyProp.ZERO, SafetyProp.PEN, SafetyProp.VL1, SafetyProp.VL2, SafetyProp.TL1,
            SafetyProp.TL2, SafetyProp.IFAULT) == (8, 42, 43, 45, 46, 47, 48, 55)
    with pytest.raises(BackendError, match="VERS=60 is older than 61"):
        check_safety_firmware(60)
    # libbarrett getPendantState: bits 27/26 button (11 none), 25/24 lights, 3 bits per parameter, one-hot
    idle = PendantState()
    assert encode_pen(idle) == (0b11 << 26) | (1 << 24) | sum(1 << (3 * i) for i in range(5))
    fault = PendantState("idle", False, True, 0x79, {**idle.levels, "heartbeat": Level.FAULT,
                                                     "velocity": Level.WARNING})
    assert decode_pen(encode_pen(fault)) == fault
    assert decode_pen(encode_pen(fault)).faults() == ["heartbeat"]
    with pytest.raises(PuckFrameError, match="bad PEN value"):
        decode_pen(0b011)  # two bits set in the velocity parameter
    # Q4.12 m/s (libbarrett setVelocityLimit), Barrett's defaults 2048 / 4096
    assert velocity_limit_units(0.5) == 2048 and velocity_limit_units(1.0) == 4096


def test_zeroing_counts_and_configuration():
    # libbarrett definePosition at the wam7w home with CTS 4096: floor(CTS/2pi J2MP home)
    assert zeroing_counts([4096] * 7).tolist() == [0, -36833, 36832, -36728, 0, 0, 0]
    groups = {p: FACTORY_GROUPS[p] for p in WAM_PUCK_IDS}
    poles = {7: 6}
    assert configuration_problems(groups, poles) == []
    assert "gimbals" in configuration_problems(groups, {7: 8})[0]
    manual = {**groups, 5: (0, 2, 5), 6: (0, 2, 5), 7: (0, 2, 5)}
    assert [p.split(" is")[0] for p in configuration_problems(manual, poles)] == ["puck 5", "puck 6", "puck 7"]
    wrong_torque = {**groups, 2: (0, 2, 4)}
    assert "torque group 1" in configuration_problems(wrong_torque, poles)[0]


def test_pendant_script_grammar():
    assert [str(e) for e in parse_pendant_script("idle@end,activate@1,estop@2.5")] == \
        ["activate@1", "estop@2.5", "idle@end"]
    assert parse_pendant_script("never") == ()
    for bad in ("activate", "jump@1", "activate@-1", "activate@end"):
        with pytest.raises(ValueError, match="pendant script item"):
            parse_pendant_script(bad)


def test_elbow_and_end_point_kinematics():
    elbow, end = elbow_and_end_point_m(np.zeros(7))  # WAM DH: shoulder-elbow 0.55 m, elbow offset 0.045 m
    np.testing.assert_allclose(elbow, [0.045, 0, 0.55], atol=1e-12)
    np.testing.assert_allclose(end, [0, 0, 0.85], atol=1e-12)
    # a pure rotation of joint 1 keeps both at their distance from the base axis
    e2, p2 = elbow_and_end_point_m(np.array([0.7, 0, 0, 0, 0, 0, 0]))
    assert np.hypot(*e2[:2]) == pytest.approx(0.045) and p2[2] == pytest.approx(0.85)


# --------------------------------------------------------------------------------------------- strictness

def test_only_the_safety_module_puts_pucks_into_torque(channel, host):
    with PuckSimulator(StaticPlant(Q0), channel=channel, start_awake=False) as sim:
        sim.press("activate")  # pucks asleep: refused
        assert module(host, SafetyProp.MODE) == SafetyMode.IDLE
        assert "motor pucks not awake" in sim.safety.log[-1][1]
        wake_pucks(host, WAM_PUCK_IDS, sleep=lambda s: time.sleep(min(s, sim._wake_s + 0.05)))
        host.send(make_set_property(GROUP_WAM, Prop.MODE, Mode.TORQUE))
        host.send(make_set_property(SAFETY_PUCK_ID, SafetyProp.MODE, SafetyMode.ACTIVE))  # ignored, as documented
        assert wait_for(lambda: sim.stats.host_mode_writes_refused == 7 and sim.safety.refused_requests == 1)
        assert set(sim.modes().values()) == {Mode.IDLE}
        sim.press("activate")
        assert set(sim.modes().values()) == {Mode.TORQUE}
        assert wait_for(lambda: sim.stats.broadcasts_sent == 1)
        # a host's request towards idle is obeyed (the safe direction)
        host.send(make_set_property(SAFETY_PUCK_ID, SafetyProp.MODE, SafetyMode.IDLE))
        assert wait_for(lambda: set(sim.modes().values()) == {Mode.IDLE})


def test_stopping_the_polling_is_a_heartbeat_fault(channel, host):
    with PuckSimulator(StaticPlant(Q0), channel=channel, heartbeat_timeout_s=0.1) as sim:
        sim.press("activate")
        for _ in range(20):
            assert len(positions(host)) == 7
            time.sleep(0.002)
        assert module(host, SafetyProp.MODE) == SafetyMode.ACTIVE
        assert wait_for(lambda: sim.safety.mode == SafetyMode.IDLE)  # no polling: the module faults
        assert set(sim.modes().values()) == {Mode.IDLE}
        assert decode_pen(module(host, SafetyProp.PEN)).faults() == ["heartbeat"]
        sim.press("activate")  # refused while the fault is latched
        assert sim.safety.mode == SafetyMode.IDLE
        sim.press("idle")  # Shift-Idle clears it
        assert decode_pen(module(host, SafetyProp.PEN)).faults() == []


def test_talking_while_pucks_wake_puts_the_host_bus_off(channel, host):
    with PuckSimulator(StaticPlant(Q0), channel=channel, start_awake=False, wake_s=0.3) as sim:
        for p in WAM_PUCK_IDS:  # back to back: the next frame comes while the previous puck turns off
            host.send(make_set_property(p, Prop.STAT, Status.READY))
        host.send(make_get_property(1, Prop.STAT))  # and a question inside the wake window
        assert wait_for(lambda: sim.stats.frames_handled == 8)
        assert sim.stats.bus_off_events == 1 and "turning off" in sim.bus_off_reasons[0]
        assert sim.stats.frames_dropped_bus_off == 6  # the host is off the bus: its next frames are lost
        assert any(m.is_error_frame for m in iter(lambda: host.recv(timeout=0.05), None))
    with PuckSimulator(StaticPlant(Q0), channel=channel + "-paced", start_awake=False, wake_s=0.3) as sim, \
            can.Bus(interface="virtual", channel=channel + "-paced") as paced:
        wake_pucks(paced, WAM_PUCK_IDS)  # libbarrett's pacing: fine
        assert sim.stats.bus_off_events == 0


def test_encoders_read_arbitrary_offsets_until_zeroed(channel, host):
    with PuckSimulator(StaticPlant(Q), channel=channel, zeroed=False, seed=11) as sim:
        truth = joint_rad_to_counts(Q)
        got = {p: parse_position_reply(m)[1] for p, m in positions(host).items()}
        assert sum(got[p] != truth[p - 1] for p in WAM_PUCK_IDS) >= 6  # (an offset of 0 is possible, not likely)
        assert module(host, SafetyProp.ZERO) == 0
        for p in WAM_PUCK_IDS:
            host.send(make_set_property(p, Prop.P, int(truth[p - 1])))
        assert wait_for(lambda: sim.stats.property_sets == 7)
        got = {p: parse_position_reply(m)[1] for p, m in positions(host).items()}
        assert [got[p] for p in WAM_PUCK_IDS] == truth.tolist()


def test_pendant_script_and_estop(channel, host):
    with PuckSimulator(StaticPlant(Q0), channel=channel, pendant="activate@0.05,estop@0.2") as sim:
        t_end = time.monotonic() + 5.0
        while sim.safety.mode != SafetyMode.ESTOP and time.monotonic() < t_end:
            positions(host, timeout_s=0.02)  # the host polls: the script's clock runs
        assert [m for _, m in sim.safety.log][-2:] == ["Shift-activate: Shift-Activate", "E-stop: E-stop pressed"]
        assert positions(host, timeout_s=0.05) == {}  # the pucks are unpowered
        assert decode_pen(module(host, SafetyProp.PEN)).button == "estop"
        sim.press("idle")  # released, Shift-Idle: the pucks power up in the monitor, to be zeroed again
        assert read_property(host, [1], Prop.STAT, 0.2) == {1: Status.RESET}
        assert module(host, SafetyProp.ZERO) == 0


def test_six_byte_replies_and_groups(channel, host):
    groups = dict.fromkeys((5, 6, 7), (0, 2, 5))
    with PuckSimulator(StaticPlant(Q), channel=channel, joint_encoders=True, groups=groups):
        got = positions(host, timeout_s=0.1)
        assert sorted(got) == [1, 2, 3, 4]  # pucks 5-7 are in group 5, not the whole-WAM group 4
        for p, m in got.items():
            puck, motor, joint = parse_combined_position_reply(m)
            assert len(m.data) == 6 and motor == joint_rad_to_counts(Q)[p - 1]
            assert joint == round(Q[p - 1] * JOINT_ENCODER_COUNTS[p - 1] / (2 * np.pi))
        assert read_property(host, [1, 5], Prop.ROLE, 0.2) == {1: ROLE_OPTICAL_ENC_ON_ENC, 5: 0}
        host.send(make_get_property(0x405, Prop.P))
        assert len([m for m in iter(lambda: host.recv(timeout=0.1), None) if len(m.data) == 3]) == 3


def test_limits_torque_fault_and_eeprom(channel, host):
    with PuckSimulator(StaticPlant(Q0), channel=channel) as sim:
        host.send(make_set_property(SAFETY_PUCK_ID, SafetyProp.TL2, 1000))
        host.send(make_set_property(SAFETY_PUCK_ID, SafetyProp.TL1, 900))
        assert wait_for(lambda: module(host, SafetyProp.TL2) == 1000)
        sim.press("activate")
        for frame in make_torque_frames(np.array([0, 1200, 0, 0, 0, 0, 0])):
            host.send(frame)
        assert wait_for(lambda: sim.safety.mode == SafetyMode.IDLE)
        assert decode_pen(module(host, SafetyProp.PEN)).faults() == ["torque"]
        for prop in (SafetyProp.TL1, SafetyProp.TL2):  # libbarrett's reset: DEF then LOAD
            host.send(make_set_property(SAFETY_PUCK_ID, SafetyProp.DEF, prop))
            host.send(make_set_property(SAFETY_PUCK_ID, SafetyProp.LOAD, prop))
        assert wait_for(lambda: module(host, SafetyProp.TL2) == 5204 and module(host, SafetyProp.TL1) == 4731)
