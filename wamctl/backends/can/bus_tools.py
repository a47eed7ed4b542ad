"""Bus tools shared by the CAN backend and ``wamctl bus-check``: open a bus, read a property from several
pucks, find and wake the pucks, and measure the bus load.

:func:`bus_check` is what ``wamctl bus-check`` reports: the nodes that answer (:class:`PuckInfo`), what is
wrong with them, and the load on the bus (:func:`measure_bus_load`; :func:`loop_bus_load_pct` is the
500 Hz control loop's estimate). Everything here is synchronous: it sends, then receives until the replies
are in or a timeout passes.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import time
from collections.abc import Iterable
from typing import Any

import can
import numpy as np

from wamctl.backends.can.protocol.addressing import (
    FEEDBACK_OTHER_TARGET,
    FEEDBACK_POSITION_TARGET,
    FORCE_TORQUE_PUCK_ID,
    GROUP_WAM,
    HAND_PUCK_IDS,
    MAX_CAN_ID,
    N_JOINTS,
    SAFETY_PUCK_ID,
    WAM_PUCK_IDS,
    PuckFrameError,
    decode_bus_id,
)
from wamctl.backends.can.protocol.positions import make_position_request
from wamctl.backends.can.protocol.properties import (
    MIN_FIRMWARE_VERSION,
    Mode,
    Prop,
    PropertyReply,
    Status,
    check_firmware_version,
    make_get_property,
    make_set_property,
    parse_property_reply,
)
from wamctl.backends.can.protocol.torques import torque_slot_of_puck
from wamctl.errors import BackendError
from wamctl.model import params as P

logger = logging.getLogger(__name__)

__all__ = [
    "ALL_WAM_PUCKS",
    "PROBE_TIMEOUT_S",
    "PuckInfo",
    "TX_TIMEOUT_S",
    "WAKE_TIMEOUT_S",
    "bus_check",
    "check_motor_pucks",
    "frame_bits",
    "loop_bus_load_pct",
    "measure_bus_load",
    "open_bus",
    "probe_pucks",
    "read_property",
    "recv_until",
]

PROBE_TIMEOUT_S = 0.05  # wait for property replies at start-up (a puck answers in well under 1 ms)
WAKE_TIMEOUT_S = 3.0  # a puck leaving the monitor takes a few hundred ms (libbarrett waits ~1 s)
TX_TIMEOUT_S = 0.005  # a send blocked longer (transmit queue full: bus-off, no ACK) is a transmit error
ALL_WAM_PUCKS = (1 << N_JOINTS) - 1  # bit i - 1 set: puck i answered
_NODE_KINDS = {**dict.fromkeys(WAM_PUCK_IDS, "wam motor"), FORCE_TORQUE_PUCK_ID: "force-torque sensor",
               SAFETY_PUCK_ID: "safety module", **dict.fromkeys(HAND_PUCK_IDS, "hand")}


def open_bus(interface: str, channel: str, bitrate: int, **kwargs: Any) -> can.BusABC:
    """Open a python-can bus; an unavailable interface or channel becomes a :class:`BackendError`.

    Parameters
    ----------
    interface, channel : str
        python-can interface (``socketcan``, ``pcan``, ``virtual``, ...) and channel.
    bitrate : int
        Bit/s (ignored by interfaces configured outside the process, e.g. SocketCAN, and by ``virtual``).
    **kwargs
        Passed to :class:`can.Bus` (e.g. ``can_filters``).

    Returns
    -------
    can.BusABC
    """
    try:
        return can.Bus(interface=interface, channel=channel, bitrate=bitrate, **kwargs)
    except (can.CanError, OSError, ImportError, ValueError, NotImplementedError) as exc:
        raise BackendError(f"cannot open CAN interface {interface!r} channel {channel!r}: {exc}") from None


def recv_until(bus: can.BusABC, deadline: float, handle) -> None:
    """Receive frames until ``handle(msg)`` returns True or ``deadline`` (perf_counter) passes."""
    while True:
        remaining = deadline - time.perf_counter()
        if remaining <= 0.0:
            return
        msg = bus.recv(timeout=remaining)
        if msg is None:
            return
        if handle(msg):
            return


def _as_property_reply(msg: can.Message) -> PropertyReply | None:
    """The property reply in ``msg``, or None for any other frame (malformed ones included)."""
    if msg.is_error_frame or msg.is_remote_frame or msg.is_extended_id or msg.arbitration_id > MAX_CAN_ID:
        return None
    bid = decode_bus_id(msg.arbitration_id)
    if not (bid.is_group and bid.target == FEEDBACK_OTHER_TARGET):
        return None
    try:
        return parse_property_reply(msg)
    except PuckFrameError:
        return None


def read_property(bus: can.BusABC, ids: Iterable[int], prop: int, timeout_s: float = PROBE_TIMEOUT_S,
                  retries: int = 1, send=None) -> dict[int, int]:
    """Get one property from several pucks (one get each), collecting the replies.

    Parameters
    ----------
    bus : can.BusABC
    ids : iterable of int
        Node ids to ask.
    prop : int
        Property id (:class:`~wamctl.backends.can.protocol.properties.Prop`).
    timeout_s : float
        Wait for the replies, per attempt.
    retries : int
        Further attempts for the pucks that did not answer.
    send : callable, optional
        ``send(msg)`` used to transmit (default ``bus.send`` with a short timeout).

    Returns
    -------
    dict of int to int
        Value per puck that answered (pucks that did not are absent). Frames already waiting when it is
        called are discarded first.
    """
    wanted = list(dict.fromkeys(int(i) for i in ids))
    send = send or (lambda msg: bus.send(msg, timeout=TX_TIMEOUT_S))
    out: dict[int, int] = {}
    while bus.recv(timeout=0.0) is not None:  # replies to earlier requests must not pass for answers
        pass
    for _ in range(1 + max(0, retries)):
        todo = [i for i in wanted if i not in out]
        if not todo:
            break
        for i in todo:
            send(make_get_property(i, prop))

        def handle(msg: can.Message, todo=todo) -> bool:
            reply = _as_property_reply(msg)
            if reply is not None and reply.prop == prop and reply.puck_id in todo:
                out[reply.puck_id] = reply.value
            return all(i in out for i in todo)

        recv_until(bus, time.perf_counter() + timeout_s, handle)
    return out


@dataclasses.dataclass
class PuckInfo:
    """What start-up (and ``bus-check``) learns about one node.

    Attributes
    ----------
    puck_id : int
    stat : int
        STAT when found (0 monitor, 2 ready).
    vers, role, sn : int or None
        Firmware version, role, serial number.
    cts, ipnm, pidx, mode : int or None
        Motor pucks (1..7) with supported firmware only.
    """

    puck_id: int
    stat: int
    vers: int | None = None
    role: int | None = None
    sn: int | None = None
    cts: int | None = None
    ipnm: int | None = None
    pidx: int | None = None
    mode: int | None = None

    @property
    def kind(self) -> str:
        return _NODE_KINDS.get(self.puck_id, "unknown node")

    @property
    def firmware_ok(self) -> bool:
        """Whether a motor puck's firmware uses the property ids of :class:`~.protocol.properties.Prop`."""
        return self.vers is not None and self.vers >= MIN_FIRMWARE_VERSION

    def to_dict(self) -> dict:
        d = dataclasses.asdict(self)
        d.update(kind=self.kind, stat_name=_enum_name(Status, self.stat),
                 mode_name=None if self.mode is None else _enum_name(Mode, self.mode))
        if self.puck_id in WAM_PUCK_IDS:
            d["firmware_ok"] = self.firmware_ok
        return d


def _enum_name(enum_cls, value: int | None) -> str | None:
    try:
        return enum_cls(value).name
    except ValueError:
        return str(value)


def check_motor_pucks(found: dict[int, PuckInfo]) -> None:
    """Refuse pucks the backend cannot drive.

    Parameters
    ----------
    found : dict of int to PuckInfo
        What :func:`probe_pucks` found.

    Raises
    ------
    BackendError
        If a puck did not wake, has firmware older than :data:`~.properties.MIN_FIRMWARE_VERSION`, is not a
        motor puck, did not report CTS, IPNM or PIDX, or reports a CTS or IPNM that is not positive.
    """
    for i, info in found.items():
        if info.stat != Status.READY:
            raise BackendError(f"puck {i} did not wake up (STAT={info.stat})")
        check_firmware_version(i, info.vers if info.vers is not None else -1)
        if info.role is not None and (info.role & 0x1F) != 0:
            raise BackendError(f"puck {i}: ROLE={info.role} is not a motor puck")
        for name in ("cts", "ipnm", "pidx"):
            if getattr(info, name) is None:
                raise BackendError(f"puck {i} did not report {name.upper()}")
        if info.cts <= 0 or info.ipnm <= 0:
            raise BackendError(f"puck {i}: CTS={info.cts}, IPNM={info.ipnm} must be positive")


def probe_pucks(bus: can.BusABC, ids: Iterable[int] = WAM_PUCK_IDS, *, wake: bool = True,
                timeout_s: float = PROBE_TIMEOUT_S, wake_timeout_s: float = WAKE_TIMEOUT_S,
                send=None) -> dict[int, PuckInfo]:
    """Find the pucks answering on the bus, wake motor pucks left in the monitor, read their properties.

    Parameters
    ----------
    bus : can.BusABC
    ids : iterable of int
        Node ids to probe (a get of STAT each).
    wake : bool
        Set STAT=READY on WAM pucks found in the monitor and wait for them (needed to read CTS, IPNM,
        PIDX and MODE); a woken puck is left idle.
    timeout_s, wake_timeout_s : float
        Reply timeout per request; the longest wait for pucks to wake.
    send : callable, optional
        ``send(msg)`` used to transmit (default ``bus.send``).

    Returns
    -------
    dict of int to PuckInfo
        The nodes that answered, by id. Motor pucks (1..7) that are awake and have firmware >= 68 carry
        CTS, IPNM, PIDX and MODE.
    """
    send = send or (lambda msg: bus.send(msg, timeout=TX_TIMEOUT_S))
    stat = read_property(bus, ids, Prop.STAT, timeout_s, send=send)
    found = {i: PuckInfo(i, s) for i, s in sorted(stat.items())}
    asleep = [i for i, info in found.items() if info.stat != Status.READY and i in WAM_PUCK_IDS]
    if wake and asleep:
        logger.info("waking pucks %s", asleep)
        for i in asleep:
            send(make_set_property(i, Prop.STAT, Status.READY))
        t_end = time.perf_counter() + wake_timeout_s
        while asleep and time.perf_counter() < t_end:
            time.sleep(0.02)
            for i, s in read_property(bus, asleep, Prop.STAT, timeout_s, retries=0, send=send).items():
                found[i].stat = s
            asleep = [i for i in asleep if found[i].stat != Status.READY]
    ids_found = list(found)
    for field, prop in (("vers", Prop.VERS), ("role", Prop.ROLE), ("sn", Prop.SN)):
        for i, v in read_property(bus, ids_found, prop, timeout_s, send=send).items():
            setattr(found[i], field, v)
    motors = [i for i in ids_found if i in WAM_PUCK_IDS and found[i].stat == Status.READY
              and found[i].firmware_ok]
    for field, prop in (("cts", Prop.CTS), ("ipnm", Prop.IPNM), ("pidx", Prop.PIDX),
                        ("mode", Prop.MODE)):
        for i, v in read_property(bus, motors, prop, timeout_s, send=send).items():
            setattr(found[i], field, v)
    return found


# ---------------------------------------------------------------------------------------------- bus load

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


def loop_bus_load_pct(bitrate: int, rate_hz: float = P.CONTROL_RATE_HZ, stuffing: bool = False) -> float:
    """Bus load of the control loop: per cycle one position request (1 byte), seven replies (3 bytes) and
    two packed-torque frames (8 bytes), in % of ``bitrate``."""
    bits = frame_bits(1, stuffing) + 7 * frame_bits(3, stuffing) + 2 * frame_bits(8, stuffing)
    return 100.0 * bits * rate_hz / bitrate


def measure_bus_load(bus: can.BusABC, bitrate: int, window_s: float = 1.0, poll_hz: float = 0.0) -> dict:
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
        count(len(msg.data))
        if t_sent is not None and not msg.is_extended_id and msg.arbitration_id <= MAX_CAN_ID:
            bid = decode_bus_id(msg.arbitration_id)
            if bid.is_group and bid.target == FEEDBACK_POSITION_TARGET and bid.sender in WAM_PUCK_IDS:
                got |= 1 << (bid.sender - 1)
                if got == ALL_WAM_PUCKS:
                    latencies.append(time.perf_counter() - t_sent)
                    complete += 1
                    t_sent = None
    elapsed = time.perf_counter() - t_start
    out = {"window_s": elapsed, "frames": n_frames, "frames_per_s": n_frames / elapsed,
           "bits_per_s": bits / elapsed, "load_pct": 100.0 * bits / elapsed / bitrate,
           "load_pct_worst": 100.0 * bits_worst / elapsed / bitrate,
           "control_loop_load_pct": loop_bus_load_pct(bitrate),
           "control_loop_load_pct_worst": loop_bus_load_pct(bitrate, stuffing=True)}
    if poll_hz > 0:
        lat = np.asarray(latencies)
        out.update(polls=polls, complete_polls=complete, poll_hz=poll_hz,
                   reply_latency_p50_s=float(np.percentile(lat, 50)) if lat.size else None,
                   reply_latency_p99_s=float(np.percentile(lat, 99)) if lat.size else None,
                   reply_latency_max_s=float(lat.max()) if lat.size else None)
    return out


def bus_check(interface: str, channel: str, bitrate: int = 1_000_000, *, simulate_pucks: bool = False,
              window_s: float = 1.0, poll_hz: float = 0.0, wake: bool = True,
              ids: Iterable[int] = range(1, 32)) -> dict:
    """What ``wamctl bus-check`` reports: the pucks found and the bus load.

    Parameters
    ----------
    interface, channel, bitrate
        The bus.
    simulate_pucks : bool
        Answer as simulated pucks (a WAM at rest at ``HOME_Q_RAD``) on the in-process virtual bus.
    window_s, poll_hz
        See :func:`measure_bus_load`.
    wake : bool
        Wake motor pucks found in the monitor to read CTS, IPNM and PIDX.
    ids : iterable of int
        Node ids probed.

    Returns
    -------
    dict
        ``interface, channel, bitrate, simulated, pucks`` (list of :meth:`PuckInfo.to_dict`),
        ``missing_wam_pucks``, ``problems`` (list of str) and ``load`` (:func:`measure_bus_load`).

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
        from wamctl.backends.can.puck_sim import PuckSimulator, StaticPlant
        sim = PuckSimulator(StaticPlant(P.HOME_Q_RAD), channel=channel, interface="virtual").start()
    try:
        bus = open_bus(interface, channel, bitrate)
        try:
            found = probe_pucks(bus, ids, wake=wake)
            if not found:
                raise BackendError(f"no puck answered on {interface} channel {channel!r} "
                                   f"(is the WAM powered and the bus terminated?)")
            problems = []
            missing = [i for i in WAM_PUCK_IDS if i not in found]
            if missing:
                problems.append(f"WAM pucks not found: {missing}")
            for i in WAM_PUCK_IDS:
                info = found.get(i)
                if info is None:
                    continue
                if info.stat != Status.READY:
                    problems.append(f"puck {i} is not awake (STAT={info.stat})")
                elif not info.firmware_ok:
                    problems.append(f"puck {i}: firmware VERS={info.vers} older than {MIN_FIRMWARE_VERSION}")
            present = {i: found[i].pidx for i in WAM_PUCK_IDS if i in found and found[i].pidx is not None}
            if len(present) == N_JOINTS:
                try:
                    torque_slot_of_puck(present)
                except BackendError as exc:
                    problems.append(str(exc))
            load = measure_bus_load(bus, bitrate, window_s, poll_hz)
        finally:
            bus.shutdown()
    finally:
        if sim is not None:
            sim.shutdown()
    return {"interface": interface, "channel": channel, "bitrate": bitrate, "simulated": simulate_pucks,
            "pucks": [info.to_dict() for info in found.values()], "missing_wam_pucks": missing,
            "problems": problems, "load": load}

