"""Tests of the Barrett puck CAN protocol layer and the simulated pucks on python-can's virtual bus."""

from __future__ import annotations

import itertools
import math
import time
import uuid

import can
import numpy as np
import pytest
from can_wire import wait_for
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from wamctl.backends.can.protocol.addressing import (
    DEFAULT_PIDX,
    FEEDBACK_OTHER,
    FEEDBACK_POSITION,
    GROUP_FLAG,
    GROUP_WAM,
    HOST_ID,
    WAM_PUCK_IDS,
    BusId,
    PuckFrameError,
    decode_bus_id,
    encode_bus_id,
)
from wamctl.backends.can.protocol.positions import (
    POSITION_MAX_COUNTS,
    POSITION_MIN_COUNTS,
    decode_position_22bit,
    encode_position_22bit,
    make_position_reply,
    make_position_request,
    parse_position_reply,
)
from wamctl.backends.can.protocol.properties import (
    MIN_FIRMWARE_VERSION,
    Mode,
    Prop,
    PropertyReply,
    Status,
    check_firmware_version,
    make_get_property,
    make_property_reply,
    make_set_property,
    parse_host_property_message,
    parse_property_reply,
)
from wamctl.backends.can.protocol.safety import SAFETY_BROADCAST_ID
from wamctl.backends.can.protocol.torques import (
    IPNM_DEFAULT,
    MAX_PUCK_TORQUE,
    joint_torque_to_puck_units,
    make_torque_frames,
    pack_torques,
    puck_units_to_joint_torque_Nm,
    puck_units_to_motor_Nm,
    unpack_torques,
)
from wamctl.backends.can.sim.pucks import PlantAdapter, StaticPlant
from wamctl.backends.can.sim.simulator import PuckSimulator
from wamctl.errors import BackendError
from wamctl.model.transmission import (
    J2MP,
    M2JP,
    counts_to_joint_rad,
    joint_rad_to_counts,
    joint_rad_to_motor_rad,
    joint_torque_to_motor_Nm,
    load_kernels,
    motor_rad_to_joint_rad,
    motor_torque_to_joint_Nm,
)

pytestmark = pytest.mark.timeout(60)

RECV_TIMEOUT_S = 0.25  # per reply; the virtual bus answers in well under a millisecond
JOINT_LIMITS_RAD = np.array(
    [[-2.6, 2.6], [-2.0, 2.0], [-2.8, 2.8], [-0.9, 3.1], [-4.76, 1.24], [-1.6, 1.6], [-3.0, 3.0]]
)

int22 = st.integers(POSITION_MIN_COUNTS, POSITION_MAX_COUNTS)
int14 = st.integers(-MAX_PUCK_TORQUE, MAX_PUCK_TORQUE)

load_kernels()   # numba's first-call set-up before hypothesis' per-example deadline


def q_within_limits() -> st.SearchStrategy[np.ndarray]:
    return st.tuples(*[st.floats(lo, hi, allow_nan=False) for lo, hi in JOINT_LIMITS_RAD]).map(np.array)


# ------------------------------------------------------------------------------------------ ids


@given(sender=st.integers(0, 31), target=st.integers(0, 31), group=st.booleans())
def test_bus_id_round_trip(sender: int, target: int, group: bool) -> None:
    arb = encode_bus_id(sender, (GROUP_FLAG if group else 0) | target)
    assert 0 <= arb <= 0x7FF
    assert decode_bus_id(arb) == BusId(sender, target, group)


def test_bus_id_known_values() -> None:
    assert encode_bus_id(HOST_ID, GROUP_WAM) == 0x404
    assert encode_bus_id(HOST_ID, 5) == 0x005
    assert encode_bus_id(3, FEEDBACK_POSITION) == 0x463  # puck 3's position reply
    assert encode_bus_id(1, FEEDBACK_OTHER) == 0x426  # puck 1's property reply
    assert decode_bus_id(0x4E3) == BusId(7, 3, True)
    with pytest.raises(ValueError):
        encode_bus_id(32, 1)
    with pytest.raises(ValueError):
        decode_bus_id(0x800)


# ------------------------------------------------------------------------------------------ properties


def test_property_message_layout() -> None:
    get = make_get_property(4, Prop.CTS)
    assert (get.arbitration_id, bytes(get.data), get.is_extended_id) == (0x004, bytes([68]), False)
    st_ = make_set_property(GROUP_WAM, Prop.MODE, Mode.TORQUE)
    assert (st_.arbitration_id, bytes(st_.data)) == (0x404, bytes([0x88, 0, 2, 0, 0, 0]))
    assert parse_host_property_message(st_.data) == (True, 8, 2)
    assert parse_host_property_message(get.data) == (False, 68, None)
    assert bytes(make_set_property(1, Prop.P, -2).data) == bytes([0xB0, 0, 0xFE, 0xFF, 0xFF, 0xFF])


@given(puck=st.integers(1, 31), prop=st.integers(0, 127), value=st.integers(-(2**31), 2**31 - 1))
def test_property_reply_round_trip(puck: int, prop: int, value: int) -> None:
    reply = parse_property_reply(make_property_reply(puck, prop, value))
    assert reply == PropertyReply(puck, prop, value)


def test_property_reply_16bit_and_malformed() -> None:
    short = can.Message(arbitration_id=0x426, data=bytes([0x80 | 68, 0, 0x00, 0x10]), is_extended_id=False)
    assert parse_property_reply(short, expected_prop=68).value == 4096
    negative = can.Message(arbitration_id=0x426, data=bytes([0x80 | 42, 0, 0xFF, 0xFF]), is_extended_id=False)
    assert parse_property_reply(negative).value == -1
    bad = [
        can.Message(arbitration_id=0x426, data=bytes([0x80 | 68, 0, 1]), is_extended_id=False),  # length
        can.Message(arbitration_id=0x426, data=bytes([68, 0, 1, 0]), is_extended_id=False),  # no 0x80
        can.Message(arbitration_id=0x426, data=bytes([0x80 | 68, 1, 1, 0]), is_extended_id=False),  # byte 1
        can.Message(arbitration_id=0x423, data=bytes([0x80 | 68, 0, 1, 0]), is_extended_id=False),  # group 3
        can.Message(arbitration_id=0x426, data=bytes([0x80 | 68, 0, 1, 0]), is_extended_id=True),
    ]
    for msg in bad:
        with pytest.raises(PuckFrameError):
            parse_property_reply(msg)
    with pytest.raises(PuckFrameError):
        parse_property_reply(make_property_reply(1, 68, 4096), expected_prop=86)
    assert issubclass(PuckFrameError, BackendError)


def test_firmware_check_names_the_ids_of_older_firmware() -> None:
    # libbarrett property_list.cpp: VERS 65 on names CTS 68, IPNM 86, PIDX 70, POLES 90; VERS 64: 66, 83, 68, 87
    assert MIN_FIRMWARE_VERSION == 65
    check_firmware_version(1, 65)
    assert (Prop.CTS, Prop.IPNM, Prop.PIDX, Prop.POLES, Prop.GRPA, Prop.GRPC) == (68, 86, 70, 90, 26, 28)
    with pytest.raises(BackendError, match=r"puck 3: firmware VERS=64 .*CTS 66, IPNM 83, PIDX 68, POLES 87"):
        check_firmware_version(3, 64)
    with pytest.raises(BackendError, match=r"VERS=62 .*CTS 65, IPNM 83, PIDX 67"):
        check_firmware_version(3, 62)
    with pytest.raises(BackendError, match="below VERS 61 every property id differs"):
        check_firmware_version(3, 50)


# ------------------------------------------------------------------------------------------ 22-bit positions


@given(int22)
def test_position_22bit_round_trip(counts: int) -> None:
    data = encode_position_22bit(counts)
    assert len(data) == 3 and data[0] & 0xC0 == 0
    assert decode_position_22bit(data) == counts


@given(st.binary(min_size=3, max_size=3))
def test_position_22bit_decode_then_encode(data: bytes) -> None:
    counts = decode_position_22bit(data)
    assert POSITION_MIN_COUNTS <= counts <= POSITION_MAX_COUNTS
    assert encode_position_22bit(counts) == bytes([data[0] & 0x3F]) + data[1:]  # top two bits ignored


@given(st.integers(-(2**30), 2**30))
def test_position_22bit_out_of_range(counts: int) -> None:
    in_range = POSITION_MIN_COUNTS <= counts <= POSITION_MAX_COUNTS
    if not in_range:
        with pytest.raises(ValueError):
            encode_position_22bit(counts)
    wrapped = decode_position_22bit(encode_position_22bit(counts, wrap=True))
    assert (wrapped - counts) % (1 << 22) == 0
    assert in_range == (wrapped == counts)


def test_position_22bit_extremes() -> None:
    assert encode_position_22bit(-1) == bytes([0x3F, 0xFF, 0xFF])
    assert encode_position_22bit(POSITION_MIN_COUNTS) == bytes([0x20, 0, 0])
    assert encode_position_22bit(POSITION_MAX_COUNTS) == bytes([0x1F, 0xFF, 0xFF])


@given(puck=st.integers(1, 7), counts=int22)
def test_position_reply_round_trip(puck: int, counts: int) -> None:
    msg = make_position_reply(puck, counts)
    assert msg.arbitration_id == 0x400 | puck << 5 | 3
    assert parse_position_reply(msg) == (puck, counts)
    six = can.Message(
        arbitration_id=msg.arbitration_id, data=bytes(msg.data) + b"\x00\x00\x01", is_extended_id=False
    )
    assert parse_position_reply(six) == (puck, counts)  # secondary encoder ignored


def test_position_reply_malformed() -> None:
    for length in (0, 1, 2, 4, 5, 7, 8):
        msg = can.Message(arbitration_id=0x423, data=bytes(length), is_extended_id=False)
        with pytest.raises(PuckFrameError):
            parse_position_reply(msg)
    with pytest.raises(PuckFrameError):
        parse_position_reply(make_property_reply(1, 48, 0))


# ------------------------------------------------------------------------------------------ packed torques


def _bits_reference(values: list[int]) -> bytes:
    """Independent derivation of the layout: 0xAA then the four 14-bit fields, MSB first."""
    bits = "".join(format(v & 0x3FFF, "014b") for v in values)
    return bytes([0xAA]) + int(bits, 2).to_bytes(7, "big")


def test_packed_torque_golden() -> None:
    data = pack_torques([1, -1, 8191, -8191])
    assert data.hex() == "aa0007fff7ffe001"
    # the bytes libbarrett's sendPackedTorques writes for slot 1 and the top of slot 2
    assert data[1] == (1 >> 6) & 0xFF and data[2] == (((1 << 2) & 0xFC) | ((-1 >> 12) & 0x03))


@given(st.lists(st.integers(-30000, 30000), min_size=1, max_size=4), st.randoms())
def test_packed_torques_round_trip_with_saturation(values: list[int], rnd) -> None:
    pidx = rnd.sample(range(1, 5), len(values))
    data = pack_torques(values, pidx)
    assert len(data) == 8 and data[0] == 0xAA
    slots = unpack_torques(data)
    assert slots.shape == (4,)
    expected = [0, 0, 0, 0]
    for v, p in zip(values, pidx):
        expected[p - 1] = max(-8191, min(8191, v))
    assert slots.tolist() == expected
    assert data == _bits_reference(expected)


@given(st.lists(int14, min_size=4, max_size=4))
def test_packed_torques_whole_range_exact(values: list[int]) -> None:
    assert unpack_torques(pack_torques(values)).tolist() == values


@given(st.binary(min_size=7, max_size=7))
def test_unpack_then_pack_any_payload(payload: bytes) -> None:
    data = bytes([0xAA]) + payload
    slots = unpack_torques(data)
    assert np.all((slots >= -8192) & (slots <= 8191))
    if np.all(slots >= -8191):  # -8192 is representable but saturates to -8191 when packed
        assert pack_torques(slots) == data


@given(st.floats(-1e6, 1e6, allow_nan=False))
def test_pack_rounds_and_saturates_floats(x: float) -> None:
    assert unpack_torques(pack_torques([x]))[0] == max(-8191, min(8191, round(x)))


@pytest.mark.parametrize("n", [1, 2, 3])
def test_unpack_short_libbarrett_frames(n: int) -> None:
    """libbarrett sends 1 + 2n bytes for n < 4 torques (e.g. 7 bytes to 0x402)."""
    values = [1234, -4321, 8191][:n]
    data = pack_torques(values)[: 1 + 2 * n]
    assert unpack_torques(data).tolist() == values


def test_pack_unpack_errors() -> None:
    with pytest.raises(ValueError):
        pack_torques([1, 2, 3, 4, 5])
    with pytest.raises(ValueError):
        pack_torques([1, 2], pidx=[1, 1])
    with pytest.raises(ValueError):
        pack_torques([1], pidx=[5])
    with pytest.raises(ValueError):
        pack_torques([float("nan")])
    for bad in (b"", b"\xaa\x00", bytes([0xA9]) + bytes(7), bytes(9)):
        with pytest.raises(PuckFrameError):
            unpack_torques(bad)


def test_torque_frames_and_pidx_check() -> None:
    frames = make_torque_frames(np.arange(1, 8) * 100)
    assert [f.arbitration_id for f in frames] == [0x401, 0x402]
    assert unpack_torques(frames[0].data).tolist() == [100, 200, 300, 400]
    assert unpack_torques(frames[1].data).tolist() == [500, 600, 700, 0]
    swapped = {**DEFAULT_PIDX, 5: 3, 7: 1}
    upper = make_torque_frames(np.arange(1, 8) * 100, swapped)[1]
    assert unpack_torques(upper.data).tolist() == [700, 600, 500, 0]
    missing_4 = {k: v for k, v in DEFAULT_PIDX.items() if k != 4}
    for bad in ({**DEFAULT_PIDX, 2: 1}, {**DEFAULT_PIDX, 6: 0}, missing_4):
        with pytest.raises(BackendError):
            make_torque_frames(np.zeros(7), bad)


# ------------------------------------------------------------------------------------------ conversions


def test_transmission_constants() -> None:
    np.testing.assert_allclose(J2MP @ M2JP, np.eye(7), atol=1e-12)
    assert J2MP[4, 4] == 9.7 and J2MP[0, 0] == -42.0
    assert not J2MP.flags.writeable


# libbarrett (BarrettTechnology/libbarrett 109faf60) config/wam7w.conf, low_level.j2mp: typed from the file,
# not from our code
LIBBARRETT_WAM7W_J2MP = [
    [-42.0, 0, 0, 0, 0, 0, 0],
    [0, 28.25, -16.8155, 0, 0, 0, 0],
    [0, -28.25, -16.8155, 0, 0, 0, 0],
    [0, 0, 0, -18.0, 0, 0, 0],
    [0, 0, 0, 0, 9.7, -9.7, 0],
    [0, 0, 0, 0, 9.7, 9.7, 0],
    [0, 0, 0, 0, 0, 0, -14.93],
]


def test_j2mp_is_libbarretts_wam7w_matrix() -> None:
    np.testing.assert_array_equal(J2MP, np.array(LIBBARRETT_WAM7W_J2MP))


def test_group_ids_are_libbarretts() -> None:
    """include/barrett/products/puck.h GROUP_MASK 0x400; puck_group.h BGRP_WHOLE_BUS 0, BGRP_LOWER_WAM 1,
    BGRP_UPPER_WAM 2, BGRP_WAM 4, BGRP_HAND 5 (each | GROUP_MASK)."""
    from wamctl.backends.can.protocol.addressing import (
        GROUP_HAND,
        GROUP_LOWER_WAM,
        GROUP_UPPER_WAM,
        GROUP_WHOLE_BUS,
    )
    assert (GROUP_FLAG, GROUP_WHOLE_BUS, GROUP_LOWER_WAM, GROUP_UPPER_WAM, GROUP_WAM, GROUP_HAND) == (
        0x400, 0x400, 0x401, 0x402, 0x404, 0x405)


@given(q=q_within_limits(), cts=st.sampled_from([4096, 40960]))
def test_joint_counts_joint_within_one_count(q: np.ndarray, cts: int) -> None:
    counts = joint_rad_to_counts(q, cts)
    assert counts.dtype == np.int64
    assert np.all((counts >= POSITION_MIN_COUNTS) & (counts <= POSITION_MAX_COUNTS))
    q_back = counts_to_joint_rad(counts, cts)
    motor_error_counts = joint_rad_to_motor_rad(q_back - q) * cts / (2 * math.pi)
    assert np.all(np.abs(motor_error_counts) <= 0.5 + 1e-6)
    # through the wire format too
    decoded = [decode_position_22bit(encode_position_22bit(c)) for c in counts]
    np.testing.assert_array_equal(decoded, counts)


@given(hnp.arrays(np.float64, (5, 7), elements=st.floats(-3, 3)))
def test_conversions_vectorised(q: np.ndarray) -> None:
    batch = joint_rad_to_counts(q)
    assert batch.shape == (5, 7)
    for row, counts in zip(q, batch):
        np.testing.assert_array_equal(joint_rad_to_counts(row), counts)
    np.testing.assert_allclose(motor_rad_to_joint_rad(joint_rad_to_motor_rad(q)), q, atol=1e-12)


@given(
    tau=hnp.arrays(np.float64, 7, elements=st.floats(-30, 30)),
    qdot=hnp.arrays(np.float64, 7, elements=st.floats(-3, 3)),
)
def test_torque_transmission_conserves_power(tau: np.ndarray, qdot: np.ndarray) -> None:
    tau_m = joint_torque_to_motor_Nm(tau)
    mdot = joint_rad_to_motor_rad(qdot)
    assert float(tau @ qdot) == pytest.approx(float(tau_m @ mdot), abs=1e-9)
    np.testing.assert_allclose(motor_torque_to_joint_Nm(tau_m), tau, atol=1e-12)


@given(tau=hnp.arrays(np.float64, 7, elements=st.floats(-5, 5)))
def test_joint_torque_puck_units_round_trip(tau: np.ndarray) -> None:
    units = joint_torque_to_puck_units(tau)
    assert units.dtype == np.int64
    # inside +-5 N m no motor saturates (largest |j2mp^-T| entry ~0.03 -> < 450 units)
    motor_error = (puck_units_to_motor_Nm(units) - joint_torque_to_motor_Nm(tau)) * IPNM_DEFAULT
    assert np.all(np.abs(motor_error) <= 0.5 + 1e-9)
    back = puck_units_to_joint_torque_Nm(units)
    bound = np.abs(J2MP.T) @ np.full(7, 0.5 / IPNM_DEFAULT)
    assert np.all(np.abs(back - tau) <= bound + 1e-12)


def test_joint_torque_saturation() -> None:
    units = joint_torque_to_puck_units(np.array([1e4, 0, 0, -1e4, 0, 0, 0]))
    assert units[0] == -8191 and units[3] == 8191  # j2mp[0,0] and [3,3] are negative
    assert np.all(units[[1, 2, 4, 5, 6]] == 0)


# ------------------------------------------------------------------------------------------ simulator


@pytest.fixture
def channel() -> str:
    return f"wam-test-{uuid.uuid4().hex}"


@pytest.fixture
def host(channel: str):
    bus = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
    yield bus
    bus.shutdown()


def recv_until(bus: can.BusABC, n: int, timeout_s: float = RECV_TIMEOUT_S) -> list[can.Message]:
    """Receive up to ``n`` frames, giving up ``timeout_s`` after the last one arrived; the safety module's
    broadcasts (0x540) are skipped, as libbarrett does."""
    out: list[can.Message] = []
    while len(out) < n:
        msg = bus.recv(timeout=timeout_s)
        if msg is None:
            break
        if msg.arbitration_id != SAFETY_BROADCAST_ID:
            out.append(msg)
    return out


def get_property(bus: can.BusABC, puck: int, prop: int) -> int | None:
    bus.send(make_get_property(puck, prop))
    msgs = recv_until(bus, 1)
    return parse_property_reply(msgs[0], expected_prop=prop).value if msgs else None


def read_positions(bus: can.BusABC, expected: int = 7) -> dict[int, int]:
    bus.send(make_position_request())
    return dict(parse_position_reply(m) for m in recv_until(bus, expected))


Q_TEST = np.array([0.3, -1.2, 0.8, 2.0, -0.5, 0.4, -2.2])


def test_static_plant_is_a_plant_adapter() -> None:
    assert isinstance(StaticPlant(), PlantAdapter)


def test_probe_properties(channel: str, host: can.BusABC) -> None:
    pidx = {1: 1, 2: 2, 3: 3, 4: 4, 5: 1, 6: 2, 7: 3}
    ipnm = [2700, 2700, 2700, 2700, 2600, 2600, 2500]
    with PuckSimulator(StaticPlant(), channel=channel, ipnm=ipnm) as sim:
        for puck in WAM_PUCK_IDS:
            assert get_property(host, puck, Prop.VERS) >= MIN_FIRMWARE_VERSION
            assert get_property(host, puck, Prop.STAT) == Status.READY
            assert get_property(host, puck, Prop.ID) == puck
            assert get_property(host, puck, Prop.CTS) == 4096
            assert get_property(host, puck, Prop.PIDX) == pidx[puck]
            assert get_property(host, puck, Prop.MODE) == Mode.IDLE
        assert get_property(host, 5, Prop.IPNM) == 2600
        assert get_property(host, 7, Prop.IPNM) == 2500
        assert get_property(host, 9, Prop.VERS) is None  # no such puck
        # a group get: every WAM puck answers
        host.send(make_get_property(GROUP_WAM, Prop.IPNM))
        replies = [parse_property_reply(m) for m in recv_until(host, 7)]
        assert sorted(r.puck_id for r in replies) == list(WAM_PUCK_IDS)
        # MODE=TORQUE from the host is ignored (only the safety module sets it), and counted
        host.send(make_set_property(GROUP_WAM, Prop.MODE, Mode.TORQUE))
        assert wait_for(lambda: sim.stats.host_mode_writes_refused == 7)
        assert set(sim.modes().values()) == {Mode.IDLE}
        # Shift-Activate on the pendant: the safety module puts every puck into TORQUE
        sim.press("activate")
        assert set(sim.modes().values()) == {Mode.TORQUE}
        assert get_property(host, 6, Prop.MODE) == Mode.TORQUE


def test_position_request_round_trip(channel: str, host: can.BusABC) -> None:
    plant = StaticPlant(Q_TEST)
    with PuckSimulator(plant, channel=channel) as sim:
        got = read_positions(host)
        assert sorted(got) == list(WAM_PUCK_IDS)
        counts = np.array([got[p] for p in WAM_PUCK_IDS])
        np.testing.assert_array_equal(counts, joint_rad_to_counts(Q_TEST))
        q = counts_to_joint_rad(counts)
        err_counts = joint_rad_to_motor_rad(q - Q_TEST) * 4096 / (2 * math.pi)
        assert np.all(np.abs(err_counts) <= 0.5 + 1e-9)
        assert plant.n_position_reads == 1  # one plant read per whole-WAM request
        assert sim.stats.position_requests == 1 and sim.stats.replies_sent == 7
        # single-puck get of P answers on group 3 too
        host.send(make_position_request(4))
        (msg,) = recv_until(host, 1)
        assert parse_position_reply(msg) == (4, int(counts[3]))


def test_define_position_offsets_counts(channel: str, host: can.BusABC) -> None:
    plant = StaticPlant(Q_TEST)
    with PuckSimulator(plant, channel=channel) as sim:
        host.send(make_set_property(2, Prop.P, 12345))
        assert wait_for(lambda: sim.stats.property_sets == 1)
        got = read_positions(host)
        assert got[2] == 12345
        plant.q_rad = Q_TEST + np.array([0, 0.01, 0, 0, 0, 0, 0])
        moved = read_positions(host)
        assert moved[2] - 12345 == joint_rad_to_counts(plant.q_rad)[1] - joint_rad_to_counts(Q_TEST)[1]


def test_torque_frames_reach_the_right_joints(channel: str, host: can.BusABC) -> None:
    plant = StaticPlant()
    with PuckSimulator(plant, channel=channel) as sim:
        tau = np.array([10.0, -8.0, 5.0, 3.0, 1.5, -1.0, 0.5])
        # idle pucks ignore torque commands
        for frame in make_torque_frames(joint_torque_to_puck_units(tau)):
            host.send(frame)
        assert wait_for(lambda: sim.stats.torque_frames == 2)
        assert np.all(sim.puck_torque_units() == 0) and np.all(plant.tau_Nm == 0)

        sim.press("activate")
        assert set(sim.modes().values()) == {Mode.TORQUE}
        units = joint_torque_to_puck_units(tau)
        for frame in make_torque_frames(units):
            host.send(frame)
        assert wait_for(lambda: sim.stats.torque_frames == 4)
        assert wait_for(lambda: np.array_equal(sim.puck_torque_units(), units))
        bound = np.abs(J2MP.T) @ np.full(7, 0.5 / IPNM_DEFAULT)
        assert wait_for(lambda: np.all(np.abs(plant.tau_Nm - tau) <= bound + 1e-12))

        # one joint at a time: only that joint gets torque
        for j in range(7):
            tau_j = np.zeros(7)
            tau_j[j] = 2.0
            for frame in make_torque_frames(joint_torque_to_puck_units(tau_j)):
                host.send(frame)
            def only_joint(j: int = j) -> bool:
                others = np.delete(plant.tau_Nm, j)
                return abs(plant.tau_Nm[j] - 2.0) < 0.05 and bool(np.all(np.abs(others) < 0.02))

            assert wait_for(only_joint)

        # going idle zeroes the held torques and tells the plant
        host.send(make_set_property(GROUP_WAM, Prop.MODE, Mode.IDLE))
        assert wait_for(lambda: np.all(plant.tau_Nm == 0))
        assert np.all(sim.puck_torque_units() == 0)


def test_torque_slots_follow_pidx(channel: str, host: can.BusABC) -> None:
    pidx = {1: 2, 2: 1, 3: 3, 4: 4, 5: 3, 6: 2, 7: 1}
    with PuckSimulator(StaticPlant(), channel=channel, pidx=pidx) as sim:
        probed = {p: get_property(host, p, Prop.PIDX) for p in WAM_PUCK_IDS}
        assert probed == pidx
        sim.press("activate")
        assert set(sim.modes().values()) == {Mode.TORQUE}
        units = np.array([100, 200, 300, 400, 500, 600, 700])
        for frame in make_torque_frames(units, probed):
            host.send(frame)
        assert wait_for(lambda: np.array_equal(sim.puck_torque_units(), units))
        for frame in make_torque_frames(units):  # default PIDX: pucks 1/2 and 5/7 swapped
            host.send(frame)
        assert wait_for(lambda: np.array_equal(sim.puck_torque_units(), [200, 100, 300, 400, 700, 600, 500]))


def test_wake_from_monitor(channel: str, host: can.BusABC) -> None:
    """Woken as libbarrett does (10 ms apart, then silence longer than the wake window), the pucks answer."""
    with PuckSimulator(StaticPlant(), channel=channel, start_awake=False, wake_s=0.1) as sim:
        assert get_property(host, 1, Prop.STAT) == Status.RESET
        assert get_property(host, 1, Prop.VERS) is not None  # the monitor answers VERS
        assert get_property(host, 1, Prop.MODE) is None  # but not motor properties
        assert read_positions(host) == {}
        for puck in WAM_PUCK_IDS:
            host.send(make_set_property(puck, Prop.STAT, Status.READY))
            time.sleep(0.011)
        time.sleep(0.15)
        assert get_property(host, 7, Prop.STAT) == Status.READY
        assert get_property(host, 1, Prop.MODE) == Mode.IDLE
        assert len(read_positions(host)) == 7
        assert sim.stats.bus_off_events == 0


# ------------------------------------------------------------------------------------------ faults


def test_fault_drop_all_and_resume(channel: str, host: can.BusABC) -> None:
    with PuckSimulator(StaticPlant(Q_TEST), channel=channel) as sim:
        sim.drop_replies(1.0)
        assert read_positions(host) == {}
        assert get_property(host, 1, Prop.CTS) is None
        assert sim.stats.replies_dropped == 8
        sim.clear_faults()
        assert len(read_positions(host)) == 7


def test_fault_drop_with_probability(channel: str, host: can.BusABC) -> None:
    with PuckSimulator(StaticPlant(Q_TEST), channel=channel, seed=1) as sim:
        sim.drop_replies(0.5)
        received = sum(len(read_positions(host)) for _ in range(10))
        stats = sim.stats
        assert stats.replies_sent == received
        assert stats.replies_sent + stats.replies_dropped == 70
        assert 0 < stats.replies_dropped < 70


def test_fault_drop_after_time(channel: str, host: can.BusABC) -> None:
    with PuckSimulator(StaticPlant(Q_TEST), channel=channel) as sim:
        sim.drop_replies(1.0, after_s=sim.elapsed_s() + 0.3)
        assert len(read_positions(host)) == 7
        time.sleep(max(0.0, 0.35 - sim.elapsed_s()))
        assert read_positions(host) == {}
        assert sim.stats.replies_sent == 7 and sim.stats.replies_dropped == 7


def test_fault_silent_puck(channel: str, host: can.BusABC) -> None:
    with PuckSimulator(StaticPlant(Q_TEST), channel=channel) as sim:
        sim.set_silent(4)
        got = read_positions(host)
        assert sorted(got) == [1, 2, 3, 5, 6, 7]
        assert get_property(host, 4, Prop.VERS) is None
        sim.set_silent(4, False)
        assert sorted(read_positions(host)) == list(WAM_PUCK_IDS)


def test_fault_garbage(channel: str, host: can.BusABC) -> None:
    with PuckSimulator(StaticPlant(Q_TEST), channel=channel, seed=3) as sim:
        sim.inject_garbage(1.0)
        host.send(make_position_request())
        msgs = recv_until(host, 7)
        assert len(msgs) == 7
        for msg in msgs:
            with pytest.raises(PuckFrameError):
                parse_position_reply(msg)
        host.send(make_get_property(2, Prop.CTS))
        (msg,) = recv_until(host, 1)
        with pytest.raises(PuckFrameError):
            parse_property_reply(msg)
        assert sim.stats.replies_garbled == 8
        sim.inject_garbage(0.0)
        sim.send_garbage(5)
        extra = recv_until(host, 5)
        assert len(extra) == 5 and sim.stats.garbage_sent == 5
        for msg in extra:
            with pytest.raises(PuckFrameError):
                if decode_bus_id(msg.arbitration_id).target == 3:
                    parse_position_reply(msg)
                else:
                    parse_property_reply(msg)
        # host garbage does not upset the pucks
        host.send(can.Message(arbitration_id=0x404, data=bytes([0xFF, 1, 2]), is_extended_id=False))
        host.send(can.Message(arbitration_id=0x401, data=bytes([0xAA, 1]), is_extended_id=False))
        assert len(read_positions(host)) == 7
        assert sim.stats.ignored_frames >= 2 and sim.stats.handler_errors == 0


def test_fault_stop_answering(channel: str, host: can.BusABC) -> None:
    plant = StaticPlant()
    with PuckSimulator(plant, channel=channel) as sim:
        sim.stop_answering()
        assert read_positions(host) == {}
        # commands are still obeyed while silent on the bus
        sim.press("activate")
        host.send(make_set_property(GROUP_WAM, Prop.MODE, Mode.IDLE))
        assert wait_for(lambda: set(sim.modes().values()) == {Mode.IDLE})
        sim.resume_answering()
        assert len(read_positions(host)) == 7


# ------------------------------------------------------------------------------------------ lifecycle


def test_shutdown_twice_and_context_manager(channel: str) -> None:
    sim = PuckSimulator(StaticPlant(), channel=channel)
    sim.start()
    assert sim.running
    sim.shutdown()
    sim.shutdown()
    assert not sim.running
    with pytest.raises(RuntimeError):
        sim.start()
    with PuckSimulator(StaticPlant(), channel=channel) as sim2:
        assert sim2.running
    assert not sim2.running
    sim2.shutdown()


def test_external_bus_is_left_open(channel: str, host: can.BusABC) -> None:
    own = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
    try:
        with PuckSimulator(StaticPlant(Q_TEST), bus=own):
            assert len(read_positions(host)) == 7
        own.send(make_position_request())  # still usable
        assert host.recv(timeout=RECV_TIMEOUT_S) is not None
    finally:
        own.shutdown()


def test_plant_errors_are_counted_not_fatal(channel: str, host: can.BusABC) -> None:
    class Broken(StaticPlant):
        def joint_positions_rad(self) -> np.ndarray:
            raise RuntimeError("physics exploded")

    with PuckSimulator(Broken(), channel=channel) as sim:
        assert read_positions(host) == {}
        assert wait_for(lambda: sim.stats.handler_errors == 1)
        assert sim.running
        assert get_property(host, 1, Prop.CTS) == 4096


@settings(deadline=None, max_examples=5)
@given(q=q_within_limits())
def test_position_round_trip_over_the_bus_property(q: np.ndarray) -> None:
    channel = f"wam-test-{uuid.uuid4().hex}"
    with can.Bus(interface="virtual", channel=channel, receive_own_messages=False) as bus:
        with PuckSimulator(StaticPlant(q), channel=channel, cts=40960):
            got = read_positions(bus)
    counts = np.array([got[p] for p in WAM_PUCK_IDS])
    err = joint_rad_to_motor_rad(counts_to_joint_rad(counts, 40960) - q) * 40960 / (2 * math.pi)
    assert np.all(np.abs(err) <= 0.5 + 1e-6)


def test_all_pucks_answer_every_cycle(channel: str, host: can.BusABC) -> None:
    """200 cycles of a 500 Hz cycle's traffic (request, 7 replies, 2 torque frames): every reply arrives (the
    time it takes is benchmarks/bench_can_loop.py's business)."""
    with PuckSimulator(StaticPlant(Q_TEST), channel=channel) as sim:
        frames = make_torque_frames(np.zeros(7))
        for _ in itertools.repeat(None, 200):
            assert len(read_positions(host)) == 7
            for frame in frames:
                host.send(frame)
        assert wait_for(lambda: sim.stats.torque_frames == 400)
