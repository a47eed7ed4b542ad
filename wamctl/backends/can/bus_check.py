"""What ``wamctl bus-check`` reports: the nodes that answer, the arm they make (libbarrett's ``verifyWamPucks``:
pucks 1-7 a 7-DOF WAM, pucks 1-4 and no 5-7 a 4-DOF WAM), the safety module (mode, zeroing, limits, pendant),
every motor puck's firmware, constants, groups and POLES, what the model does not describe, and the load on the
bus (:func:`measure_bus_load`; :func:`loop_bus_load_pct` is the 500 Hz control loop's estimate).
"""

from __future__ import annotations

import math
import time
from collections.abc import Iterable

import can
import numpy as np

from wamctl.backends.can.bus_tools import (
    TX_TIMEOUT_S,
    open_bus,
    probe_pucks,
    read_safety_module,
)
from wamctl.backends.can.protocol.addressing import (
    FEEDBACK_POSITION_TARGET,
    GROUP_WAM,
    HOST_ID,
    MAX_CAN_ID,
    SAFETY_PUCK_ID,
    WAM_PUCK_IDS,
    decode_bus_id,
)
from wamctl.backends.can.protocol.configuration import (
    FACTORY_GROUPS,
    WAM7_BUS,
    BusArm,
    arm_on_bus,
    bus_arm,
    configuration_problems,
    puck_set_problem,
)
from wamctl.backends.can.protocol.positions import make_position_request
from wamctl.backends.can.protocol.properties import MIN_FIRMWARE_VERSION, Status
from wamctl.backends.can.protocol.safety import SAFETY_MIN_FIRMWARE_VERSION
from wamctl.backends.can.protocol.torques import torque_slot_of_puck
from wamctl.errors import BackendError
from wamctl.model import params as P

__all__ = ["bus_check", "frame_bits", "loop_bus_load_pct", "measure_bus_load"]


def frame_bits(dlc: int | np.ndarray, stuffing: bool = False) -> int | np.ndarray:
    """Bits a standard (11-bit id) data frame occupies on the bus, interframe space included.

    Parameters
    ----------
    dlc : int or array of int
        Data bytes, 0..8.
    stuffing : bool
        Add the worst-case stuff bits ``floor((34 + 8 dlc - 1) / 4)``.

    Returns
    -------
    int or numpy.ndarray
        ``47 + 8 dlc`` (SOF, id, control, CRC, ACK, EOF and the 3-bit interframe space), plus stuffing.
    """
    dlc = np.asarray(dlc)
    bits = 47 + 8 * dlc
    if stuffing:
        bits = bits + (34 + 8 * dlc - 1) // 4
    return bits if bits.ndim else int(bits)


def loop_bus_load_pct(bitrate: int, rate_hz: float = P.CONTROL_RATE_HZ, stuffing: bool = False,
                      arm: BusArm = WAM7_BUS) -> float:
    """Bus load of the control loop: per cycle one position request (1 byte), one reply (3 bytes) per puck of the
    arm and one packed-torque frame (8 bytes) per torque group (the wam7: 7 replies, 2 frames; the wam4: 4, 1), in
    % of ``bitrate``."""
    bits = (frame_bits(1, stuffing) + arm.n_joints * frame_bits(3, stuffing)
            + len(arm.torque_groups) * frame_bits(8, stuffing))
    return 100.0 * bits * rate_hz / bitrate


def measure_bus_load(bus: can.BusABC, bitrate: int, window_s: float = 1.0, poll_hz: float = 0.0,
                     arm: BusArm = WAM7_BUS) -> dict:
    """Count the frames on the bus over a window and estimate the load.

    Parameters
    ----------
    bus : can.BusABC
    bitrate : int
        Bit/s, for the percentage.
    window_s : float
        Listening time.
    poll_hz : float
        If > 0, request the WAM's positions at this rate during the window (deadline-scheduled), and
        time the replies; the frames sent count in the load.
    arm : BusArm
        Whose pucks' replies complete a poll, and whose loop the estimate is (default the wam7).

    Returns
    -------
    dict
        ``window_s, frames, frames_per_s, bits_per_s, load_pct, load_pct_worst`` (with worst-case bit
        stuffing), ``control_loop_load_pct`` (the 500 Hz loop's estimate), and with polling
        ``polls, complete_polls, reply_latency_p50_s, reply_latency_p99_s, reply_latency_max_s``.
    """
    n_frames = 0
    bits = bits_worst = 0
    latencies: list[float] = []
    polls = complete = 0
    t_start = time.perf_counter()
    t_end = t_start + window_s
    period = 1.0 / poll_hz if poll_hz > 0 else math.inf
    next_poll = t_start if poll_hz > 0 else math.inf
    request = make_position_request(GROUP_WAM)
    got = 0
    t_sent = None

    def count(dlc: int) -> None:
        nonlocal n_frames, bits, bits_worst
        n_frames += 1
        bits += frame_bits(dlc)
        bits_worst += frame_bits(dlc, stuffing=True)

    while True:
        now = time.perf_counter()
        if now >= t_end:
            break
        if now >= next_poll:
            bus.send(request, timeout=TX_TIMEOUT_S)
            count(1)
            polls += 1
            got, t_sent = 0, now
            next_poll += period * max(1, math.floor((now - next_poll) / period) + 1)
        msg = bus.recv(timeout=max(0.0, min(t_end, next_poll) - time.perf_counter()))
        if msg is None or msg.is_error_frame:
            continue
        if not msg.is_extended_id and msg.arbitration_id <= MAX_CAN_ID \
                and decode_bus_id(msg.arbitration_id).sender == HOST_ID:
            continue  # our own frame looped back (udp_multicast): counted when sent
        count(len(msg.data))
        if t_sent is not None and not msg.is_extended_id and msg.arbitration_id <= MAX_CAN_ID:
            bid = decode_bus_id(msg.arbitration_id)
            if bid.is_group and bid.target == FEEDBACK_POSITION_TARGET and bid.sender in arm.puck_ids:
                got |= 1 << (bid.sender - 1)
                if got == arm.all_replied_mask:
                    latencies.append(time.perf_counter() - t_sent)
                    complete += 1
                    t_sent = None
    elapsed = time.perf_counter() - t_start
    out = {"window_s": elapsed, "frames": n_frames, "frames_per_s": n_frames / elapsed,
           "bits_per_s": bits / elapsed, "load_pct": 100.0 * bits / elapsed / bitrate,
           "load_pct_worst": 100.0 * bits_worst / elapsed / bitrate,
           "control_loop_load_pct": loop_bus_load_pct(bitrate, arm=arm),
           "control_loop_load_pct_worst": loop_bus_load_pct(bitrate, stuffing=True, arm=arm)}
    if poll_hz > 0:
        lat = np.asarray(latencies)
        out.update(polls=polls, complete_polls=complete, poll_hz=poll_hz,
                   reply_latency_p50_s=float(np.percentile(lat, 50)) if lat.size else None,
                   reply_latency_p99_s=float(np.percentile(lat, 99)) if lat.size else None,
                   reply_latency_max_s=float(lat.max()) if lat.size else None)
    return out




def bus_check(interface: str, channel: str, bitrate: int = 1_000_000, *, simulate_pucks: bool = False,
              window_s: float = 1.0, poll_hz: float = 0.0, wake: bool = True,
              ids: Iterable[int] = range(1, 32), bus_options: dict | None = None, robot: str | None = None) -> dict:
    """What ``wamctl bus-check`` reports: the nodes found, the safety module, the problems, and the bus load.

    Parameters
    ----------
    interface, channel, bitrate
        The bus.
    simulate_pucks : bool
        Answer as a simulated WAM just powered up (pucks in the monitor, not zeroed, at its home pose) on the
        in-process virtual bus (the ``robot``'s, default the wam7).
    window_s, poll_hz
        See :func:`measure_bus_load`.
    wake : bool
        Wake motor pucks found in the monitor (libbarrett's pacing) to read CTS, IPNM, PIDX, POLES, groups.
    ids : iterable of int
        Node ids probed.
    bus_options : dict, optional
        Further :class:`can.Bus` arguments.
    robot : str, optional
        The arm expected (``wam7``, ``wam4``): another arm on the bus is a problem. None: the arm the WAM pucks
        found make (libbarrett's ``verifyWamPucks``), a problem if they make none.

    Returns
    -------
    dict
        ``interface, channel, bitrate, simulated, arm`` (the robot the WAM pucks found make, or None), ``pucks``
        (list of :meth:`PuckInfo.to_dict`, the safety module excluded), ``safety_module``
        (:meth:`SafetyInfo.to_dict` or None), ``missing_wam_pucks`` (of the arm expected, or of pucks 1-7),
        ``problems`` (list of str) and ``load`` (:func:`measure_bus_load`).

    Raises
    ------
    BackendError
        If the bus cannot be opened or no node answers.
    """
    sim = None
    if simulate_pucks:
        if interface != "virtual":
            raise BackendError("--simulate-pucks needs --interface virtual: simulated pucks must never answer "
                               "on a bus with a real arm")
        from wamctl.backends.can.sim.pucks import StaticPlant
        from wamctl.backends.can.sim.simulator import PuckSimulator
        sim_arm = bus_arm(robot)
        sim = PuckSimulator(StaticPlant(sim_arm.home_q_rad), channel=channel, interface="virtual",
                            start_awake=False, zeroed=False, seed=0, robot=sim_arm.name).start()
    try:
        bus = open_bus(interface, channel, bitrate, **(bus_options or {}))
        try:
            safety = read_safety_module(bus)
            found = probe_pucks(bus, [i for i in ids if i != SAFETY_PUCK_ID], wake=wake)
            if not found and safety is None:
                raise BackendError(f"no puck answered on {interface} channel {channel!r} "
                                   f"(is the WAM powered and the bus terminated?)")
            on_bus = arm_on_bus(found)
            expected = bus_arm(robot if robot is not None else on_bus)  # (None: the wam7's pucks, for the report)
            problems = _problems(found, safety, expected, robot is None and on_bus is None)
            load = measure_bus_load(bus, bitrate, window_s, poll_hz, expected)
        finally:
            bus.shutdown()
    finally:
        if sim is not None:
            sim.shutdown()
    return {"interface": interface, "channel": channel, "bitrate": bitrate, "simulated": simulate_pucks,
            "arm": on_bus, "pucks": [info.to_dict() for info in found.values()],
            "safety_module": None if safety is None else safety.to_dict(),
            "missing_wam_pucks": [i for i in expected.puck_ids if i not in found], "problems": problems,
            "load": load}


def _problems(found: dict, safety, arm: BusArm = WAM7_BUS, unknown_arm: bool = False) -> list[str]:
    """What is wrong on the bus for ``arm``; ``unknown_arm``: no robot was named and the WAM pucks found make
    none (then the puck set is reported against pucks 1-7 as before)."""
    problems = []
    if safety is None:
        problems.append("no safety module (node 10) answered: wamctl drives the WAM only through it")
    elif not safety.firmware_ok:
        problems.append(f"safety module: firmware VERS={safety.vers} older than {SAFETY_MIN_FIRMWARE_VERSION}")
    elif not safety.is_safety_module:
        problems.append(f"node 10 has ROLE={safety.role}: not a safety module")
    else:
        if safety.mode == 0:
            problems.append("the safety module reports E-stop: release the E-stop and press Shift-Idle")
        if safety.groups is not None and set(safety.groups) != set(FACTORY_GROUPS[SAFETY_PUCK_ID]):
            problems.append(f"the safety module is in groups {'/'.join(map(str, safety.groups))}, not 1/2/3 (it "
                            "would not hear the torque frames or the position replies it watches)")
    if unknown_arm:
        missing = [i for i in WAM_PUCK_IDS if i not in found]
        if missing:
            problems.append(f"WAM pucks not found: {missing}")
    else:
        wrong = puck_set_problem(arm, found)
        if wrong is not None:
            problems.append(wrong[0])
    for i in WAM_PUCK_IDS:
        info = found.get(i)
        if info is None:
            continue
        if info.stat != Status.READY:
            problems.append(f"puck {i} is not awake (STAT={info.stat})")
        elif not info.firmware_ok:
            problems.append(f"puck {i}: firmware VERS={info.vers} older than {MIN_FIRMWARE_VERSION}")
    motors = {i: found[i] for i in arm.puck_ids if i in found and found[i].firmware_ok}
    if len(motors) == arm.n_joints:
        problems += configuration_problems({i: p.groups for i, p in motors.items() if p.groups is not None},
                                           {i: p.poles for i, p in motors.items() if p.poles is not None}, arm)
        present = {i: p.pidx for i, p in motors.items() if p.pidx is not None}
        if len(present) == arm.n_joints:
            try:
                torque_slot_of_puck(present, arm.torque_groups)
            except BackendError as exc:
                problems.append(str(exc))
    return problems
