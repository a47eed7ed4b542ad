"""The real arm over CAN: a backend speaking the Barrett puck protocol through python-can.

:class:`CanBackend` implements the backend protocol of :class:`~wamctl.backends.base.ArmBackend` (the same
as the simulator's), so the same specs, run directories and reports work on the arm:

- ``_open``: open ``can.Bus(interface=..., channel=..., bitrate=...)`` (python-can imports the vendor driver
  of the chosen interface only), probe pucks 1..7 (a get of STAT each), wake those in the monitor
  (STAT=READY), read VERS (firmware check), ROLE, CTS, IPNM and PIDX, read the positions and check them
  against the spec's start configuration. The pucks stay idle until the first torque command, which is
  preceded by MODE=TORQUE (so there is no moment of zero torque in TORQUE mode while the caller gets ready)
  and followed by a get of MODE, whose replies the next cycles check (a puck not in TORQUE mode trips).
- ``_read_positions``: one get of P to the whole-WAM group (0x404), the seven 22-bit replies decoded to motor
  counts, turned into joint angles through ``J2MP`` and each puck's CTS.
- ``_send_torques``: joint torques -> motor torques (``J2MP^-T``) -> puck units (IPNM) -> the two packed
  14-bit frames (0x401 pucks 1-4, 0x402 pucks 5-7, slots by PIDX).
- ``_wait_next_cycle``: 500 Hz on absolute deadlines ``t0 + k T`` (``time.perf_counter``, monotonic): sleep
  to just before the deadline, then yield until it; a cycle that ends after its deadline is an *overrun*
  (counted; release points already in the past are skipped, so the loop neither drifts nor bursts).
- ``_close``: zero torque (by the base), pucks to IDLE (read back), bus shut down.

Link watchdog (on top of the base's saturation, position limits and velocity fault): position replies
missing or later than ``reply_timeout_s`` for more than ``watchdog_cycles`` consecutive cycles, a malformed
("garbage") frame from a WAM puck, or a transmit error (``can.CanError``) zero the torques, put the pucks
in IDLE and raise :class:`~wamctl.errors.SafetyLimitError` (link faults) or
:class:`~wamctl.errors.BackendError` (transmit errors): the runner ends the run as failed with the reason,
keeping every sample recorded so far. While replies are missing (up to the tolerance) the last positions
received are held. Loop statistics (overruns, period jitter, late replies) and the watchdog's verdict are
in :meth:`CanBackend.describe`; events (overruns, faults) in :meth:`CanBackend.drain_events`.

Simulated pucks (``simulate_pucks: true``, virtual bus only): a
:class:`~wamctl.backends.can.puck_sim.PuckSimulator` answers on the same in-process channel, its plant a
:class:`~wamctl.backends.sim.SimBackend` of the spec's plant wrapped in :class:`SimulatedArm`. The CAN
frames are the only coupling: the physics runs on the simulator's thread, one control period per position
request while any puck is in TORQUE mode (the arm is held at rest while the pucks are idle, as an operator
holds the WAM while activating it). The simulated arm therefore advances at the loop's real-time rate,
and a run over the virtual bus reproduces the direct simulation up to the protocol's quantisation.

Fault injection for tests and demos (``backend.simulated_fault``, simulated pucks only): the fault starts
at a given control cycle (dropped replies, a silent puck, garbled replies, garbage frames, pucks that stop
answering, or host transmit errors).

Limits: torque frames get no reply, so a torque frame lost on the way (SocketCAN can drop transmit frames
silently) is noticed only through the position replies; and a puck that neither answers nor listens cannot
be commanded at all: the host sends zero torque and IDLE, the other pucks obey, that puck keeps its last
command (the WAM's safety module is the backstop).

Conventions: pucks 1..7 on the bus, arrays 0..6; SI units in names; the host is node 0.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import threading
import time
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import can
import numpy as np

from wamctl.backends.base import ArmBackend, SafetyLimits
from wamctl.backends.can import protocol as pp
from wamctl.errors import BackendError, SafetyLimitError
from wamctl.model import params as P

logger = logging.getLogger(__name__)

__all__ = [
    "CanBackend",
    "LoopTiming",
    "PuckInfo",
    "SimulatedArm",
    "bus_check",
    "frame_bits",
    "loop_bus_load_pct",
    "measure_bus_load",
    "open_bus",
    "probe_pucks",
    "read_property",
]

PROBE_TIMEOUT_S = 0.05  # wait for property replies at start-up (a puck answers in well under 1 ms)
WAKE_TIMEOUT_S = 3.0  # a puck leaving the monitor takes a few hundred ms (libbarrett waits ~1 s)
TX_TIMEOUT_S = 0.005  # a send blocked longer (transmit queue full: bus-off, no ACK) is a transmit error
SPIN_S = 2e-4  # the last part of each wait yields (sleep(0)) instead of sleeping: time.sleep overshoots
MAX_OVERRUN_EVENTS = 20  # overruns recorded one by one as events; the rest only counted
SIM_CTS_IDEAL_SENSOR = 40960  # simulated pucks' CTS when the plant's sensor is ideal (magnetic encoders)
_ALL_WAM = (1 << pp.N_JOINTS) - 1
_FEEDBACK_POSITION_TARGET = pp.FEEDBACK_POSITION & pp.NODE_ID_MASK
_FEEDBACK_OTHER_TARGET = pp.FEEDBACK_OTHER & pp.NODE_ID_MASK
_NODE_KINDS = {**dict.fromkeys(pp.WAM_PUCK_IDS, "wam motor"), pp.FORCE_TORQUE_PUCK_ID: "force-torque sensor",
               pp.SAFETY_PUCK_ID: "safety module", **dict.fromkeys(pp.HAND_PUCK_IDS, "hand")}


# --------------------------------------------------------------------------------------------------
# Bus helpers shared by the backend and `wamctl bus-check`
# --------------------------------------------------------------------------------------------------


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


def _recv_until(bus: can.BusABC, deadline: float, handle) -> None:
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


def _as_property_reply(msg: can.Message) -> pp.PropertyReply | None:
    """The property reply in ``msg``, or None for any other frame (malformed ones included)."""
    if msg.is_error_frame or msg.is_remote_frame or msg.is_extended_id or msg.arbitration_id > pp.MAX_CAN_ID:
        return None
    bid = pp.decode_bus_id(msg.arbitration_id)
    if not (bid.is_group and bid.target == _FEEDBACK_OTHER_TARGET):
        return None
    try:
        return pp.parse_property_reply(msg)
    except pp.PuckFrameError:
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
        Property id (:class:`~wamctl.backends.can.protocol.Prop`).
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
            send(pp.make_get_property(i, prop))

        def handle(msg: can.Message, todo=todo) -> bool:
            reply = _as_property_reply(msg)
            if reply is not None and reply.prop == prop and reply.puck_id in todo:
                out[reply.puck_id] = reply.value
            return all(i in out for i in todo)

        _recv_until(bus, time.perf_counter() + timeout_s, handle)
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
        """Whether a motor puck's firmware uses the property ids of :class:`protocol.Prop`."""
        return self.vers is not None and self.vers >= pp.MIN_FIRMWARE_VERSION

    def to_dict(self) -> dict:
        d = dataclasses.asdict(self)
        d.update(kind=self.kind, stat_name=_enum_name(pp.Status, self.stat),
                 mode_name=None if self.mode is None else _enum_name(pp.Mode, self.mode))
        if self.puck_id in pp.WAM_PUCK_IDS:
            d["firmware_ok"] = self.firmware_ok
        return d


def _enum_name(enum_cls, value: int | None) -> str | None:
    try:
        return enum_cls(value).name
    except ValueError:
        return str(value)


def probe_pucks(bus: can.BusABC, ids: Iterable[int] = pp.WAM_PUCK_IDS, *, wake: bool = True,
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
    stat = read_property(bus, ids, pp.Prop.STAT, timeout_s, send=send)
    found = {i: PuckInfo(i, s) for i, s in sorted(stat.items())}
    asleep = [i for i, info in found.items() if info.stat != pp.Status.READY and i in pp.WAM_PUCK_IDS]
    if wake and asleep:
        logger.info("waking pucks %s", asleep)
        for i in asleep:
            send(pp.make_set_property(i, pp.Prop.STAT, pp.Status.READY))
        t_end = time.perf_counter() + wake_timeout_s
        while asleep and time.perf_counter() < t_end:
            time.sleep(0.02)
            for i, s in read_property(bus, asleep, pp.Prop.STAT, timeout_s, retries=0, send=send).items():
                found[i].stat = s
            asleep = [i for i in asleep if found[i].stat != pp.Status.READY]
    ids_found = list(found)
    for field, prop in (("vers", pp.Prop.VERS), ("role", pp.Prop.ROLE), ("sn", pp.Prop.SN)):
        for i, v in read_property(bus, ids_found, prop, timeout_s, send=send).items():
            setattr(found[i], field, v)
    motors = [i for i in ids_found if i in pp.WAM_PUCK_IDS and found[i].stat == pp.Status.READY
              and found[i].firmware_ok]
    for field, prop in (("cts", pp.Prop.CTS), ("ipnm", pp.Prop.IPNM), ("pidx", pp.Prop.PIDX),
                        ("mode", pp.Prop.MODE)):
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
    request = pp.make_position_request(pp.GROUP_WAM)
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
        if t_sent is not None and not msg.is_extended_id and msg.arbitration_id <= pp.MAX_CAN_ID:
            bid = pp.decode_bus_id(msg.arbitration_id)
            if bid.is_group and bid.target == _FEEDBACK_POSITION_TARGET and bid.sender in pp.WAM_PUCK_IDS:
                got |= 1 << (bid.sender - 1)
                if got == _ALL_WAM:
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
            missing = [i for i in pp.WAM_PUCK_IDS if i not in found]
            if missing:
                problems.append(f"WAM pucks not found: {missing}")
            for i in pp.WAM_PUCK_IDS:
                info = found.get(i)
                if info is None:
                    continue
                if info.stat != pp.Status.READY:
                    problems.append(f"puck {i} is not awake (STAT={info.stat})")
                elif not info.firmware_ok:
                    problems.append(f"puck {i}: firmware VERS={info.vers} older than {pp.MIN_FIRMWARE_VERSION}")
            present = {i: found[i].pidx for i in pp.WAM_PUCK_IDS if i in found and found[i].pidx is not None}
            if len(present) == pp.N_JOINTS:
                try:
                    pp.torque_slot_of_puck(present)
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


# --------------------------------------------------------------------------------------------------
# The simulated arm behind the simulated pucks
# --------------------------------------------------------------------------------------------------


class SimulatedArm:
    """A :class:`~wamctl.backends.can.puck_sim.PlantAdapter` over a :class:`~wamctl.backends.sim.SimBackend`.

    Runs on the puck simulator's thread only. Each position request (but the very first) made while a
    puck is in TORQUE mode advances the physics by one control period under the torques the pucks hold
    (zero-order hold, like the direct simulation), then returns the encoders' reading. While the pucks
    are idle the arm is held at rest. With the host switching to TORQUE mode at its first torque command
    (cycle 0), the arm's cycle count matches the host's.

    Parameters
    ----------
    sim : SimBackend
        The arm (opened here); build it with open safety limits: the host's backend enforces the real ones.

    Attributes
    ----------
    cycle : int
        Control periods simulated: the index of the current cycle.
    zero_torque_since_cycle : numpy.ndarray, shape (7,)
        Per joint, the cycle since which the applied torque has been exactly zero (-1: since before the
        loop; NaN: not zero now).
    """

    def __init__(self, sim) -> None:
        self.sim = sim
        sim.open()
        self._lock = threading.Lock()
        self._tau_Nm = np.zeros(P.N_JOINTS)
        self._requested = False
        self._simulator = None
        self.cycle = 0
        self.zero_torque_since_cycle = np.full(P.N_JOINTS, -1.0)

    def attach(self, simulator) -> None:
        """The :class:`PuckSimulator` whose pucks' MODE gates the physics."""
        self._simulator = simulator

    def _torque_mode(self) -> bool:
        if self._simulator is None:
            return True
        return any(m == pp.Mode.TORQUE for m in self._simulator.modes().values())

    def joint_positions_rad(self) -> np.ndarray:
        """Advance one control period if a puck is in TORQUE mode; the encoders' reading."""
        torque_mode = self._torque_mode()
        with self._lock:
            if torque_mode and self._requested:
                self.sim.command_torques(self._tau_Nm)
                self.sim.wait_next_cycle()
                self.cycle += 1
            self._requested = True
            return self.sim.read_positions().copy()

    def apply_joint_torques_Nm(self, tau: np.ndarray) -> None:
        """Hold the joint torques the pucks now apply, until the next step."""
        with self._lock:
            tau = np.asarray(tau, float)
            zero = tau == 0.0
            since = self.zero_torque_since_cycle
            since[~zero] = np.nan
            since[zero & np.isnan(since)] = self.cycle
            self._tau_Nm[:] = tau

    def truth(self) -> tuple[np.ndarray, np.ndarray]:
        """Copies of the true position and velocity (for tests)."""
        with self._lock:
            q, qd = self.sim.truth()
            return q.copy(), qd.copy()

    def describe(self) -> dict:
        with self._lock:
            return {"cycles_simulated": self.cycle, **self.sim.describe(),
                    "zero_torque_since_cycle": [None if np.isnan(c) else int(c)
                                                for c in self.zero_torque_since_cycle]}


def _open_limits() -> SafetyLimits:
    inf = np.full(P.N_JOINTS, np.inf)
    return SafetyLimits(tau_max_Nm=inf.copy(), q_min_rad=-inf, q_max_rad=inf.copy(), qd_max_rad_s=inf.copy())


# --------------------------------------------------------------------------------------------------
# Loop timing
# --------------------------------------------------------------------------------------------------


class LoopTiming:
    """Cycle start times of a periodic loop: periods, lateness and overruns.

    Parameters
    ----------
    period_s : float
        Nominal period.
    """

    def __init__(self, period_s: float) -> None:
        self.period_s = float(period_s)
        self._starts = np.empty(4096)
        self._late = np.empty(4096)
        self._busy = np.full(4096, np.nan)
        self.n = 0
        self.overruns = 0
        self.skipped_periods = 0
        self.worst_overrun_s = 0.0

    def cycle_started(self, t_s: float, late_s: float) -> None:
        """Record a cycle start (perf_counter time) and how late after its release point it came."""
        if self.n == self._starts.size:
            self._starts = np.concatenate([self._starts, np.empty_like(self._starts)])
            self._late = np.concatenate([self._late, np.empty_like(self._late)])
        self._starts[self.n] = t_s
        self._late[self.n] = late_s
        self.n += 1

    def cycle_ended(self, t_s: float) -> None:
        """Record the end of the current cycle's work (perf_counter time): its busy time."""
        if self.n:
            i = self.n - 1
            if i >= self._busy.size:
                self._busy = np.concatenate([self._busy, np.full_like(self._busy, np.nan)])
            self._busy[i] = t_s - self._starts[i]

    def overrun(self, late_s: float, skipped: int) -> None:
        self.overruns += 1
        self.skipped_periods += skipped
        self.worst_overrun_s = max(self.worst_overrun_s, late_s)

    @property
    def periods_s(self) -> np.ndarray:
        """Time between consecutive cycle starts, s, shape (n - 1,)."""
        return np.diff(self._starts[: self.n])

    def summary(self) -> dict:
        """``cycle_starts, overruns, skipped_periods, worst_overrun_s``, and percentiles (p50, p99, max) of the
        period, of the jitter ``|period - T|``, of the wake-up lateness after each release point and of
        each cycle's busy time (start to the wait), s."""
        per = self.periods_s
        out: dict[str, Any] = {"cycle_starts": self.n, "period_nominal_s": self.period_s,
                               "overruns": self.overruns, "skipped_periods": self.skipped_periods,
                               "worst_overrun_s": self.worst_overrun_s}
        if per.size:
            jit = np.abs(per - self.period_s)
            late = self._late[1: self.n]
            busy = self._busy[: self.n]
            busy = busy[np.isfinite(busy)]
            for name, x in (("period", per), ("jitter", jit), ("wake_late", late), ("busy", busy)):
                if not x.size:
                    continue
                out[f"{name}_p50_s"] = float(np.percentile(x, 50))
                out[f"{name}_p99_s"] = float(np.percentile(x, 99))
                out[f"{name}_max_s"] = float(x.max())
        return out


# --------------------------------------------------------------------------------------------------
# The backend
# --------------------------------------------------------------------------------------------------


class CanBackend(ArmBackend):
    """The WAM over CAN (see the module docstring).

    Parameters
    ----------
    interface, channel : str
        python-can interface and channel.
    bitrate : int
        Bit/s.
    q0_rad : array_like, shape (7,)
        Where the arm must be at start-up (within ``start_tolerance_rad`` per joint).
    watchdog_cycles : int
        Consecutive cycles with missing or late position replies tolerated; one more trips the watchdog.
    reply_timeout_s : float
        Wait for the seven position replies of a cycle.
    start_tolerance_rad : float
        Largest accepted ``|q - q0|`` at start-up.
    limits : SafetyLimits, optional
    simulated_arm : SimulatedArm, optional
        Run simulated pucks driven by this arm on the (virtual) channel.
    sim_cts : int
        CTS of the simulated pucks.
    simulated_fault : wamctl.specs.SimulatedFault, optional
        A fault to inject at a given cycle (simulated pucks only).
    seed : int, optional
        Seed of the simulated pucks' fault draws.
    """

    name = "can"

    def __init__(self, interface: str, channel: str, bitrate: int = 1_000_000, *, q0_rad=None,
                 watchdog_cycles: int = 3, reply_timeout_s: float = 0.0015, start_tolerance_rad: float = 0.05,
                 limits: SafetyLimits | None = None, simulated_arm: SimulatedArm | None = None,
                 sim_cts: int = pp.CTS_DEFAULT, simulated_fault=None, seed: int | None = None) -> None:
        super().__init__(limits)
        self.interface, self.channel, self.bitrate = interface, channel, int(bitrate)
        self.q0_rad = None if q0_rad is None else np.asarray(q0_rad, float).copy()
        self.watchdog_cycles = int(watchdog_cycles)
        self.reply_timeout_s = float(reply_timeout_s)
        self.start_tolerance_rad = float(start_tolerance_rad)
        self.simulated_arm = simulated_arm
        self.simulated_fault = simulated_fault
        if simulated_fault is not None and simulated_arm is None:
            raise BackendError("a simulated fault needs the simulated pucks")
        self._sim_cts = int(sim_cts)
        self._seed = seed
        self.simulator = None
        self._bus: can.BusABC | None = None
        self.pucks: dict[int, PuckInfo] = {}
        self._cts = np.full(P.N_JOINTS, float(pp.CTS_DEFAULT))
        self._ipnm = np.full(P.N_JOINTS, float(pp.IPNM_DEFAULT))
        self._slots: list[tuple[int, list[int], list[int]]] = []  # (group id, puck indices 0..6, PIDX)
        self._request = pp.make_position_request(pp.GROUP_WAM)
        self._counts = np.zeros(P.N_JOINTS)
        self._q = np.zeros(P.N_JOINTS)
        # loop state
        self._cycle = 0
        self._t0: float | None = None
        self.timing = LoopTiming(self.control_period_s)
        self._bad_cycles = 0
        self._bad_run_start: int | None = None
        self._events: list[tuple[float, str, int | None, str]] = []
        self._stats = {"frames_sent": 0, "frames_received": 0, "late_replies": 0, "missed_reply_cycles": 0,
                       "foreign_frames": 0, "error_frames": 0, "garbage_frames": 0, "tx_errors": 0}
        # watchdog
        self.trip_reason: str | None = None
        self.trip_cycle: int | None = None
        self.fault_onset_cycle: int | None = None
        self.zero_torque_cycle: int | None = None
        self.idle_confirmed: list[int] = []
        self._tx_failures_pending = 0
        self._fault_injected_cycle: int | None = None
        # TORQUE mode: set with the first torque command, confirmed by the pucks' MODE replies
        self._mode_sent_cycle: int | None = None
        self._mode_replies: dict[int, int] = {}
        self.torque_mode_confirmed = False

    # ---------------------------------------------------------------- construction
    @classmethod
    def from_spec(cls, spec, base_dir: Path | None, q0_rad, rng: np.random.Generator) -> CanBackend:
        """The backend a spec's ``backend: {kind: can, ...}`` describes (with simulated pucks if asked).

        Parameters
        ----------
        spec : wamctl.specs.Common
            Its ``backend`` is a :class:`~wamctl.specs.CanBackendSpec`; ``plant`` is used only with
            ``simulate_pucks``.
        base_dir : Path or None
            Directory relative paths in the spec are resolved against.
        q0_rad : array_like, shape (7,)
            Start configuration.
        rng : numpy.random.Generator
            The simulated arm's random draws.
        """
        b = spec.backend
        arm, cts = None, pp.CTS_DEFAULT
        if b.simulate_pucks:
            from wamctl.backends.sim import SimBackend
            from wamctl.model.plant import Plant
            plant = Plant(spec.plant, base_dir)
            arm = SimulatedArm(SimBackend(plant, q0_rad, rng, b.physics_substeps, limits=_open_limits()))
            cts = plant.sensors.encoder_counts_per_rev or SIM_CTS_IDEAL_SENSOR
        return cls(b.interface, b.channel, b.bitrate, q0_rad=q0_rad, watchdog_cycles=b.watchdog_cycles,
                   reply_timeout_s=b.reply_timeout_s, start_tolerance_rad=b.start_tolerance_rad,
                   simulated_arm=arm, sim_cts=cts, simulated_fault=b.simulated_fault, seed=spec.seed)

    # ---------------------------------------------------------------- properties
    @property
    def time_s(self) -> float:
        """Nominal loop time: cycles since the first position read times the control period."""
        return self._cycle * self.control_period_s

    @property
    def cycle(self) -> int:
        """Index of the current control cycle (0 = the first position read)."""
        return self._cycle

    def describe(self) -> dict:
        """Interface, pucks, loop statistics (overruns, jitter), link counters and the watchdog's verdict.

        With simulated pucks, first waits (up to a second) until they have handled every frame sent, so
        their state (modes, torques) is the consequence of everything the host did."""
        self._sync_simulator()
        d: dict[str, Any] = {
            "name": self.name, "interface": self.interface, "channel": self.channel, "bitrate": self.bitrate,
            "simulated_pucks": self.simulated_arm is not None, "watchdog_cycles": self.watchdog_cycles,
            "reply_timeout_s": self.reply_timeout_s, "torque_mode_confirmed": self.torque_mode_confirmed,
            "pucks": {str(i): {"vers": info.vers, "cts": info.cts, "ipnm": info.ipnm, "pidx": info.pidx,
                               "sn": info.sn} for i, info in self.pucks.items()},
            "loop": {**self.timing.summary(), "cycles": self._cycle}, "link": dict(self._stats),
            "watchdog": {"tripped": self.trip_reason is not None, "reason": self.trip_reason,
                         "fault_onset_cycle": self.fault_onset_cycle, "trip_cycle": self.trip_cycle,
                         "zero_torque_cycle": self.zero_torque_cycle,
                         "cycles_to_zero_torque": (None if self.zero_torque_cycle is None
                                                   or self.fault_onset_cycle is None
                                                   else self.zero_torque_cycle - self.fault_onset_cycle),
                         "idle_confirmed_pucks": list(self.idle_confirmed)},
        }
        if self.simulated_arm is not None:
            sim: dict[str, Any] = {"arm": self.simulated_arm.describe()}
            if self.simulator is not None:
                sim["stats"] = dataclasses.asdict(self.simulator.stats)
                sim["puck_torque_units"] = self.simulator.puck_torque_units().tolist()
                sim["modes"] = {str(k): int(v) for k, v in self.simulator.modes().items()}
            if self.simulated_fault is not None:
                sim["fault"] = {**self.simulated_fault.model_dump(), "injected_cycle": self._fault_injected_cycle}
            d["simulation"] = sim
        return d

    def _sync_simulator(self, timeout_s: float = 1.0) -> None:
        sim = self.simulator
        if sim is None or not sim.running:
            return
        t_end = time.monotonic() + timeout_s
        while sim.stats.frames_handled < self._stats["frames_sent"] and time.monotonic() < t_end:
            time.sleep(0.001)

    def drain_events(self) -> list[tuple[float, str, int | None, str]]:
        """Events since the last call, ``(t_s, kind, joint, detail)`` with loop time ``t_s``; an overrun
        summary is appended when overruns were not all recorded one by one."""
        out, self._events = self._events, []
        if self.timing.overruns > MAX_OVERRUN_EVENTS:
            out.append((self.time_s, "overrun", None, f"{self.timing.overruns} overruns in total "
                        f"({self.timing.skipped_periods} periods skipped), first {MAX_OVERRUN_EVENTS} listed"))
        return out

    def _event(self, kind: str, detail: str, joint: int | None = None, cycle: int | None = None) -> None:
        c = self._cycle if cycle is None else cycle
        self._events.append((c * self.control_period_s, kind, joint, detail))

    # ---------------------------------------------------------------- open / close
    def _open(self) -> None:
        try:
            if self.simulated_arm is not None:
                from wamctl.backends.can.puck_sim import PuckSimulator
                self.simulator = PuckSimulator(self.simulated_arm, channel=self.channel, interface=self.interface,
                                               cts=self._sim_cts, seed=self._seed)
                self.simulated_arm.attach(self.simulator)
                self.simulator.start()
            filters = [{"can_id": pp.FEEDBACK_POSITION, "can_mask": pp.TO_MASK, "extended": False},
                       {"can_id": pp.FEEDBACK_OTHER, "can_mask": pp.TO_MASK, "extended": False}]
            self._bus = open_bus(self.interface, self.channel, self.bitrate, can_filters=filters)
            try:
                self._start_pucks()
            except can.CanError as exc:
                raise BackendError(f"CAN error during start-up: {exc}") from None
        except BaseException:
            self._release(idle=self._bus is not None)
            raise

    def _start_pucks(self) -> None:
        bus = self._bus
        assert bus is not None
        found = probe_pucks(bus, pp.WAM_PUCK_IDS, wake=True, send=self._tx)
        missing = [i for i in pp.WAM_PUCK_IDS if i not in found]
        if missing:
            raise BackendError(f"WAM pucks {missing} did not answer on {self.interface} channel "
                               f"{self.channel!r} (power, cabling, termination?)")
        for i, info in found.items():
            if info.stat != pp.Status.READY:
                raise BackendError(f"puck {i} did not wake up (STAT={info.stat})")
            pp.check_firmware_version(i, info.vers if info.vers is not None else -1)
            if info.role is not None and (info.role & 0x1F) != 0:
                raise BackendError(f"puck {i}: ROLE={info.role} is not a motor puck")
            for name in ("cts", "ipnm", "pidx"):
                if getattr(info, name) is None:
                    raise BackendError(f"puck {i} did not report {name.upper()}")
            if info.cts <= 0 or info.ipnm <= 0:
                raise BackendError(f"puck {i}: CTS={info.cts}, IPNM={info.ipnm} must be positive")
        self.pucks = found
        self._cts = np.array([found[i].cts for i in pp.WAM_PUCK_IDS], float)
        self._ipnm = np.array([found[i].ipnm for i in pp.WAM_PUCK_IDS], float)
        slots = pp.torque_slot_of_puck({i: found[i].pidx for i in pp.WAM_PUCK_IDS})
        self._slots = [(g, [p - 1 for p in members], [slots[p][1] for p in members])
                       for g, members in pp.TORQUE_GROUPS.items()]
        logger.info("pucks 1-7: VERS %s, CTS %s, IPNM %s", [found[i].vers for i in pp.WAM_PUCK_IDS],
                    self._cts.astype(int).tolist(), self._ipnm.astype(int).tolist())
        # where is the arm? (pucks still idle: nothing moves)
        counts = self._poll_positions_once(PROBE_TIMEOUT_S)
        if counts is None:
            raise BackendError("no complete set of position replies at start-up")
        self._counts[:] = counts
        q = pp.counts_to_joint_rad(self._counts, self._cts, pp.J2MP)
        if self.q0_rad is not None:
            dev = np.abs(q - self.q0_rad)
            if (dev > self.start_tolerance_rad).any():
                j = int(np.argmax(dev))
                raise SafetyLimitError(f"the arm is at joint {j + 1} = {q[j]:.4f} rad but the spec starts at "
                                       f"{self.q0_rad[j]:.4f} rad (tolerance {self.start_tolerance_rad} rad): "
                                       f"move the arm to q0_rad or change q0_rad")
        self._q[:] = q
        logger.info("pucks found and idle; TORQUE mode comes with the first torque command")

    def _poll_positions_once(self, timeout_s: float) -> np.ndarray | None:
        counts = np.zeros(P.N_JOINTS)
        got = 0
        self._tx(self._request)

        def handle(msg: can.Message) -> bool:
            nonlocal got
            bid = self._decode(msg)
            if bid is not None and bid.target == _FEEDBACK_POSITION_TARGET:
                puck, c = pp.parse_position_reply(msg)
                counts[puck - 1] = c
                got |= 1 << (puck - 1)
            return got == _ALL_WAM

        _recv_until(self._bus, time.perf_counter() + timeout_s, handle)
        return counts if got == _ALL_WAM else None

    def _close(self) -> None:
        self._release(idle=True)

    def _release(self, idle: bool) -> None:
        """Pucks to IDLE (best effort, read back), then the bus and the simulated pucks shut down."""
        try:
            if idle and self._bus is not None:
                self._idle_pucks()
        finally:
            if self._bus is not None:
                try:
                    self._bus.shutdown()
                except Exception:  # noqa: BLE001 - closing must not raise
                    logger.exception("closing the CAN bus failed")
                self._bus = None
            if self.simulator is not None:
                self.simulator.shutdown()

    def _idle_pucks(self) -> None:
        """MODE=IDLE to the whole WAM (up to three attempts), then read MODE back into ``idle_confirmed``."""
        for attempt in range(3):
            try:
                self._tx(pp.make_set_property(pp.GROUP_WAM, pp.Prop.MODE, pp.Mode.IDLE), count_errors=False)
                break
            except can.CanError as exc:
                logger.error("setting the pucks IDLE failed (attempt %d): %s", attempt + 1, exc)
        try:
            modes = read_property(self._bus, pp.WAM_PUCK_IDS, pp.Prop.MODE, PROBE_TIMEOUT_S, retries=0,
                                  send=self._tx)
        except can.CanError as exc:
            logger.error("reading MODE back failed: %s", exc)
            modes = {}
        self.idle_confirmed = sorted(i for i, m in modes.items() if m == pp.Mode.IDLE)
        if len(self.idle_confirmed) < pp.N_JOINTS:
            logger.error("pucks confirmed IDLE: %s of 1-7", self.idle_confirmed)

    # ---------------------------------------------------------------- transmit
    def _tx(self, msg: can.Message, count_errors: bool = True) -> None:
        if self._tx_failures_pending > 0:
            self._tx_failures_pending -= 1
            if count_errors:
                self._stats["tx_errors"] += 1
            raise can.CanOperationError("simulated transmit error (backend.simulated_fault: bus_error)")
        try:
            self._bus.send(msg, timeout=TX_TIMEOUT_S)
        except can.CanError:
            if count_errors:
                self._stats["tx_errors"] += 1
            raise
        self._stats["frames_sent"] += 1

    def _tx_torque_units(self, tau_Nm: np.ndarray) -> None:
        units = pp.joint_torque_to_puck_units(tau_Nm, self._ipnm, pp.J2MP)
        for group, idx, pidx in self._slots:
            payload = pp.pack_torques(units[idx], pidx)
            self._tx(can.Message(arbitration_id=group, data=payload, is_extended_id=False))

    def _send_torques(self, tau_Nm: np.ndarray) -> None:
        if self._bus is None:
            return
        if self._closed or self.trip_reason is not None:  # shutting down: best effort, never raise
            try:
                self._tx_torque_units(np.zeros(P.N_JOINTS))
            except can.CanError as exc:
                logger.error("sending zero torque at shutdown failed: %s", exc)
            return
        try:
            if self._mode_sent_cycle is None:
                # TORQUE mode right before the first command (no moment of zero torque in TORQUE mode), read
                # back asynchronously: the replies are checked by the next cycles' reads
                self._tx(pp.make_set_property(pp.GROUP_WAM, pp.Prop.MODE, pp.Mode.TORQUE))
                self._mode_sent_cycle = self._cycle
                self._tx_torque_units(tau_Nm)
                self._tx(pp.make_get_property(pp.GROUP_WAM, pp.Prop.MODE))
            else:
                self._tx_torque_units(tau_Nm)
        except can.CanError as exc:
            self._trip(f"CAN transmit error: {exc}", BackendError)

    def _check_torque_mode(self) -> None:
        """Trip if a puck reported another MODE than TORQUE, or not all did in time."""
        if self._mode_sent_cycle is None or self.torque_mode_confirmed:
            return
        wrong = {i: m for i, m in self._mode_replies.items() if m != pp.Mode.TORQUE}
        if wrong:
            self._trip(f"pucks {sorted(wrong)} report MODE {sorted(set(wrong.values()))} instead of TORQUE "
                       f"({int(pp.Mode.TORQUE)}): is the WAM activated (Shift+Activate on the pendant)?",
                       BackendError)
        if len(self._mode_replies) == pp.N_JOINTS:
            self.torque_mode_confirmed = True
            self._event("torque_mode", f"pucks 1-7 confirmed in TORQUE mode (cycle {self._cycle})")
            logger.info("pucks 1-7 in TORQUE mode")
        elif self._cycle - self._mode_sent_cycle > self.watchdog_cycles + 1:
            missing = [i for i in pp.WAM_PUCK_IDS if i not in self._mode_replies]
            self._trip(f"pucks {missing} did not confirm TORQUE mode within {self._cycle - self._mode_sent_cycle} "
                       "cycles", BackendError)

    # ---------------------------------------------------------------- receive
    def _decode(self, msg: can.Message) -> pp.BusId | None:
        """The id of a frame from a WAM puck to a feedback group, or None (counted) for anything else."""
        self._stats["frames_received"] += 1
        if msg.is_error_frame:
            self._stats["error_frames"] += 1
            return None
        if msg.is_extended_id or msg.is_remote_frame or msg.arbitration_id > pp.MAX_CAN_ID:
            self._stats["foreign_frames"] += 1
            return None
        bid = pp.decode_bus_id(msg.arbitration_id)
        if not (bid.is_group and bid.sender in pp.WAM_PUCK_IDS
                and bid.target in (_FEEDBACK_POSITION_TARGET, _FEEDBACK_OTHER_TARGET)):
            self._stats["foreign_frames"] += 1
            return None
        return bid

    def _check_frame(self, msg: can.Message, bid: pp.BusId) -> tuple[int, int] | None:
        """A position reply's (puck, counts); None for a property reply; PuckFrameError if malformed."""
        if bid.target == _FEEDBACK_POSITION_TARGET:
            return pp.parse_position_reply(msg)
        reply = pp.parse_property_reply(msg)
        if reply.prop == pp.Prop.MODE and self._mode_sent_cycle is not None and not self.torque_mode_confirmed:
            self._mode_replies[reply.puck_id] = reply.value
        return None

    def _read_positions(self) -> np.ndarray:
        bus = self._bus
        if bus is None:
            raise BackendError("CAN backend is not open")
        if self._t0 is None:
            now = time.perf_counter()
            self._t0 = now
            self.timing.cycle_started(now, 0.0)
        if self.simulated_fault is not None and self._fault_injected_cycle is None \
                and self._cycle >= self.simulated_fault.at_cycle:
            self._inject_fault()
        garbage: str | None = None
        # stale frames: replies that came after the previous cycle's timeout
        while True:
            msg = bus.recv(timeout=0.0)
            if msg is None:
                break
            bid = self._decode(msg)
            if bid is None:
                continue
            try:
                if self._check_frame(msg, bid) is not None:
                    self._stats["late_replies"] += 1
            except pp.PuckFrameError as exc:
                garbage = garbage or str(exc)
        if garbage is not None:
            self._garbage(garbage)
        try:
            self._tx(self._request)
        except can.CanError as exc:
            self._trip(f"CAN transmit error: {exc}", BackendError)
        got = 0
        deadline = time.perf_counter() + self.reply_timeout_s

        def handle(msg: can.Message) -> bool:
            nonlocal got, garbage
            bid = self._decode(msg)
            if bid is None:
                return False
            try:
                reply = self._check_frame(msg, bid)
            except pp.PuckFrameError as exc:
                garbage = str(exc)
                return True
            if reply is not None:
                puck, counts = reply
                self._counts[puck - 1] = counts
                got |= 1 << (puck - 1)
            return got == _ALL_WAM

        _recv_until(bus, deadline, handle)
        if garbage is not None:
            self._garbage(garbage)
        if got != _ALL_WAM:
            missing = [i for i in pp.WAM_PUCK_IDS if not got & (1 << (i - 1))]
            self._stats["missed_reply_cycles"] += 1
            self._bad_cycles += 1
            if self._bad_run_start is None:
                self._bad_run_start = self._cycle
                self._event("link", f"cycle {self._cycle}: no position reply from pucks {missing} within "
                                    f"{self.reply_timeout_s * 1e3:.1f} ms")
            if self._bad_cycles > self.watchdog_cycles:
                self._trip(f"CAN link watchdog: position replies from pucks {missing} missing or late for "
                           f"{self._bad_cycles} consecutive cycles (more than watchdog_cycles = "
                           f"{self.watchdog_cycles})", SafetyLimitError)
        else:
            if self._bad_run_start is not None:
                self._event("link", f"cycle {self._cycle}: replies back after {self._bad_cycles} bad cycles")
            self._bad_cycles = 0
            self._bad_run_start = None
        self._check_torque_mode()
        self._q[:] = pp.counts_to_joint_rad(self._counts, self._cts, pp.J2MP)
        return self._q

    def _garbage(self, detail: str) -> None:
        self._stats["garbage_frames"] += 1
        if self._bad_run_start is None:
            self._bad_run_start = self._cycle
        self._trip(f"CAN link watchdog: malformed frame from a puck ({detail})", SafetyLimitError)

    # ---------------------------------------------------------------- watchdog
    def _trip(self, reason: str, exc_type: type[Exception]) -> None:
        """Zero torque, pucks to IDLE, remember why, raise ``exc_type(reason)``."""
        if self.trip_reason is None:
            self.trip_reason = reason
            self.trip_cycle = self._cycle
            self.fault_onset_cycle = self._bad_run_start if self._bad_run_start is not None else self._cycle
            logger.error("%s: zero torque, pucks to IDLE", reason)
            self._tau_applied[:] = 0.0
            for attempt in range(3):
                try:
                    self._tx_torque_units(np.zeros(P.N_JOINTS))
                    self.zero_torque_cycle = self._cycle
                    break
                except can.CanError as exc:
                    logger.error("sending zero torque failed (attempt %d): %s", attempt + 1, exc)
            self._idle_pucks()
            self._event("watchdog", f"{reason}; zero torque "
                        + (f"sent in cycle {self.zero_torque_cycle}" if self.zero_torque_cycle is not None
                           else "could NOT be sent") + f", pucks confirmed IDLE: {self.idle_confirmed}")
        raise exc_type(reason)

    def _inject_fault(self) -> None:
        f, sim = self.simulated_fault, self.simulator
        self._fault_injected_cycle = self._cycle
        self._event("fault_injected", f"simulated fault {f.kind} at cycle {self._cycle}",
                    f.puck if f.kind == "silent_puck" else None)
        logger.warning("injecting simulated fault %s at cycle %d", f.kind, self._cycle)
        if f.kind == "drop_replies":
            sim.drop_replies(f.probability)
        elif f.kind == "silent_puck":
            sim.set_silent(f.puck)
        elif f.kind == "garbage_replies":
            sim.inject_garbage(f.probability)
        elif f.kind == "garbage_frames":
            sim.send_garbage(f.count)
        elif f.kind == "stop_answering":
            sim.stop_answering()
        elif f.kind == "bus_error":
            self._tx_failures_pending = f.count
        else:  # pragma: no cover - the spec's Literal lists every kind
            raise ValueError(f"unknown simulated fault {f.kind!r}")

    # ---------------------------------------------------------------- timing
    def _wait_next_cycle(self) -> None:
        T = self.control_period_s
        now = time.perf_counter()
        if self._t0 is None:
            self._t0 = now
            self.timing.cycle_started(now, 0.0)
        self.timing.cycle_ended(now)
        self._cycle += 1
        k = self._cycle + self.timing.skipped_periods
        deadline = self._t0 + k * T
        if now > deadline:
            late = now - deadline
            skipped = int(late // T)
            self.timing.overrun(late, skipped)
            if self.timing.overruns <= MAX_OVERRUN_EVENTS:
                self._event("overrun", f"cycle {self._cycle - 1} ended {late * 1e3:.2f} ms after its deadline"
                            + (f"; {skipped} release points skipped" if skipped else ""), cycle=self._cycle - 1)
            self.timing.cycle_started(now, late - skipped * T)
            return
        while True:
            remaining = deadline - time.perf_counter()
            if remaining <= 0.0:
                break
            time.sleep(remaining - SPIN_S if remaining > SPIN_S else 0.0)
        now = time.perf_counter()
        self.timing.cycle_started(now, now - deadline)
