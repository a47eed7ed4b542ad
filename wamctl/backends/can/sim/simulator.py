"""Simulated WAM on a python-can bus: the arm's motor pucks (1-7 for a wam7, 1-4 for a wam4), the safety module
and its pendant, driven by a plant.

:class:`PuckSimulator` listens on a bus (python-can's ``virtual`` interface in-process, or any interface,
e.g. ``udp_multicast``, when served by ``wamctl sim-arm`` in its own process) in a background thread and
behaves as strictly as the real arm does for what wamctl relies on:

- the arm is a robot of :mod:`wamctl.model.robots` (``robot``, default the wam7): only its motor pucks are on
  the bus (a wam4: pucks 1-4, no 5-7, libbarrett's ``foundWam4``), its plant takes and reports its joints;
- the pucks (:mod:`.pucks`) answer property gets (only VERS..STAT in the monitor), wake on STAT=READY with
  a wake window in which any frame but the next STAT=READY puts the host bus-off (for ``BUS_OFF_S`` the
  simulated bus drops the host's frames and nothing answers), answer the position request of the groups
  they are in (3-byte replies, or 6 with a joint encoder), take packed torques from the slot their PIDX names
  and apply them only in TORQUE mode;
- the safety module (:mod:`.safety_module`) alone puts them into TORQUE (on the pendant's Shift-Activate) and
  back to IDLE (Shift-Idle, faults, E-stop), broadcasting on 0x540; a host's MODE=TORQUE write is ignored
  and counted; stopping the position polling while active is a heartbeat fault;
- the pendant follows a script (:mod:`.pendant`) or :meth:`PuckSimulator.press`;
- encoders start at arbitrary offsets after power-up until the host sets P (the zeroing).

The physics stays outside: a :class:`~.pucks.PlantAdapter` supplies joint angles and receives joint torques.
Frames not sent by the host (node 0) are ignored, as a puck's acceptance filter would (on ``udp_multicast``
every node also receives its own frames).

Fault injection for the link watchdog tests: dropped replies, silent pucks, malformed ("garbage") frames,
pucks that stop answering; counters in :class:`SimStats`.
"""

from __future__ import annotations

import dataclasses
import logging
import random
import threading
import time
from collections.abc import Iterable

import can
import numpy as np

from wamctl.backends.can.protocol.addressing import (
    FEEDBACK_POSITION_TARGET,
    HOST_ID,
    SAFETY_PUCK_ID,
    TORQUE_GROUPS,
    PuckFrameError,
    decode_bus_id,
)
from wamctl.backends.can.protocol.configuration import FACTORY_GROUPS, bus_arm, groups_of
from wamctl.backends.can.protocol.positions import POSITION_MAX_COUNTS, POSITION_MIN_COUNTS, make_position_reply
from wamctl.backends.can.protocol.properties import (
    CTS_DEFAULT,
    MONITOR_PROPS,
    Mode,
    Prop,
    Status,
    make_property_reply,
    parse_host_property_message,
)
from wamctl.backends.can.protocol.safety import SafetyMode, SafetyProp, make_safety_broadcast
from wamctl.backends.can.protocol.torques import (
    IPNM_DEFAULT,
    PACKED_TORQUE_HEADER,
    puck_units_to_joint_torque_Nm,
    saturate_puck_units,
    unpack_torques,
)
from wamctl.backends.can.sim.faults import FaultInjection
from wamctl.backends.can.sim.pendant import Pendant
from wamctl.backends.can.sim.pucks import JOINT_ENCODER_COUNTS, SIM_FIRMWARE_VERSION, MotorPuck, motor_puck
from wamctl.backends.can.sim.safety_module import SIM_SAFETY_FIRMWARE_VERSION, SimulatedSafetyModule
from wamctl.backends.can.timing import RealtimeSection
from wamctl.model.transmission import counts_to_joint_rad, joint_rad_to_counts, load_kernels

logger = logging.getLogger(__name__)

__all__ = ["BUS_OFF_S", "PuckSimulator", "SimStats", "WAKE_S"]

WAKE_S = 0.8  # a woken puck's transceiver is back on the bus after this (libbarrett waits 1 s before talking)
BUS_OFF_S = 0.5  # the host's controller is off the bus this long after a frame in a wake window
_BUS_OFF_ERROR_ID = 0x40  # SocketCAN's CAN_ERR_BUSOFF class in an error frame's id
_CLOCK_TOLERANCE_S = 5e-4  # frame timestamps and sleeps come from different clocks


@dataclasses.dataclass
class SimStats:
    """Counters of what the simulated arm saw and did (a snapshot; see :attr:`PuckSimulator.stats`)."""

    frames_received: int = 0
    frames_handled: int = 0  # frames whose handling has finished (lets a host wait until it caught up)
    position_requests: int = 0
    property_gets: int = 0
    property_sets: int = 0
    torque_frames: int = 0
    replies_sent: int = 0
    replies_dropped: int = 0
    replies_garbled: int = 0
    garbage_sent: int = 0
    ignored_frames: int = 0
    send_errors: int = 0
    handler_errors: int = 0
    broadcasts_sent: int = 0  # the safety module's 0x540 frames
    host_mode_writes_refused: int = 0  # MODE other than IDLE set by the host: ignored, as on the real arm
    nonzero_torque_not_in_torque_mode: int = 0  # a torque slot other than zero for an awake puck not in TORQUE
    wake_window_frames: int = 0  # host frames inside a puck's wake window (each puts the host bus-off)
    bus_off_events: int = 0
    frames_dropped_bus_off: int = 0


class PuckSimulator(FaultInjection):
    """A simulated WAM (the arm's pucks 1..n and, unless ``safety_module=False``, the safety module) on a python-can
    bus.

    Parameters
    ----------
    plant : PlantAdapter
        Supplies joint angles, receives joint torques (optionally ``place(q)``: the operator moves the arm), n
        joints each.
    robot : str or Robot, optional
        The arm (:mod:`wamctl.model.robots`): ``wam7`` (default, pucks 1-7) or ``wam4`` (pucks 1-4).
    bus : can.BusABC, optional
        Bus to listen on. If None, one is opened with ``interface``, ``channel`` and ``bus_options`` and
        closed by :meth:`shutdown`; a bus passed in is left open.
    channel, interface : str
        For the bus opened when ``bus`` is None (default: the in-process ``virtual`` bus).
    bus_options : dict, optional
        Further :class:`can.Bus` arguments (e.g. ``port`` for ``udp_multicast``).
    cts, ipnm : int or sequence of int
        Per puck.
    pidx : dict of int to int, optional
        PIDX per puck (default: the arm's, 1-4 then 1-3).
    groups : dict of int to (int, int, int), optional
        GRPA/GRPB/GRPC per puck, overriding Barrett's factory values (e.g. ``{5: (0, 2, 5), ...}``).
    poles : dict of int to int, optional
        POLES per puck, overriding the factory values (puck 7: 6 wrist, 8 gimbals).
    firmware_version, safety_firmware_version : int
        VERS of the motor pucks and of the safety module.
    start_awake : bool
        Pucks READY at start (a previous session woke them) or in the monitor (power-up).
    zeroed : bool
        Positions already defined (offset 0, ZERO=1) or arbitrary encoder offsets and ZERO=0 (power-up).
    wake_s : float
        Time from STAT=READY to the puck being back on the bus, READY.
    joint_encoders : bool
        Pucks with a joint encoder (libbarrett's wam7w counts: pucks 1-4) send 6-byte position replies.
    safety_module : bool
        Simulate node 10. Without it nothing puts the pucks into TORQUE (only a test of the refusal needs this).
    safety_mode : str
        Module MODE at start: ``idle``, ``active`` or ``estop``.
    heartbeat_timeout_s : float
        See :mod:`.safety_module`.
    pendant : str
        Pendant script (:mod:`.pendant`), e.g. ``"activate@0.5"``; ``never`` by default.
    start_pose_rad : array_like, optional
        Where the pendant's ``move`` action puts the arm.
    j2mp : numpy.ndarray, optional
        The transmission (default the arm's).
    seed : int, optional
        Encoder offsets and fault draws.
    poll_timeout_s : float
        Receive timeout of the thread (bounds the pendant's and the heartbeat's time resolution).
    realtime : bool
        Give the thread what a Python real-time thread can have (pucks answer within microseconds; a simulated
        arm in a process of its own, ``wamctl sim-arm``, should come close): the garbage collector off and
        SCHED_FIFO when permitted (:class:`~wamctl.backends.can.timing.RealtimeSection`).
    """

    def __init__(self, plant, *, bus: can.BusABC | None = None, channel: str = "wam-test",
                 interface: str = "virtual", bus_options: dict | None = None,
                 cts: int | Iterable[int] = CTS_DEFAULT, ipnm: int | Iterable[int] = IPNM_DEFAULT,
                 pidx: dict[int, int] | None = None, groups: dict[int, tuple[int, int, int]] | None = None,
                 poles: dict[int, int] | None = None, firmware_version: int = SIM_FIRMWARE_VERSION,
                 safety_firmware_version: int = SIM_SAFETY_FIRMWARE_VERSION, start_awake: bool = True,
                 zeroed: bool = True, wake_s: float = WAKE_S, joint_encoders: bool = False,
                 safety_module: bool = True, safety_mode: str = "idle", heartbeat_timeout_s: float = 0.5,
                 pendant: str = "never", start_pose_rad=None, j2mp: np.ndarray | None = None,
                 seed: int | None = None, poll_timeout_s: float = 0.005, realtime: bool = False,
                 robot=None) -> None:
        self._plant = plant
        self.arm = bus_arm(robot)
        n = self._n = self.arm.n_joints
        self._j2mp = np.asarray(self.arm.j2mp if j2mp is None else j2mp, dtype=float)
        if self._j2mp.shape != (n, n):
            raise ValueError(f"j2mp of shape {self._j2mp.shape}; the {self.arm.name} has {n} joints")
        self._cts = np.broadcast_to(np.asarray(cts, dtype=np.int64), (n,)).copy()
        self._ipnm = np.broadcast_to(np.asarray(ipnm, dtype=np.int64), (n,)).copy()
        if np.any(self._cts <= 0) or np.any(self._ipnm <= 0):
            raise ValueError("CTS and IPNM must be positive")
        load_kernels()  # the transmission's kernels now, not within the first reply's deadline
        joint_rad_to_counts(np.zeros(n), self._cts, self._j2mp)
        self._rng = random.Random(seed)
        self._wake_s = float(wake_s)
        self._zeroed = bool(zeroed)
        pidx_map = dict(self.arm.default_pidx if pidx is None else pidx)
        groups, poles = dict(groups or {}), dict(poles or {})
        self._pucks: dict[int, MotorPuck] = {
            pid: motor_puck(pid, vers=int(firmware_version), cts=int(self._cts[i]), ipnm=int(self._ipnm[i]),
                            pidx=int(pidx_map.get(pid, 0)), awake=start_awake,
                            offset_counts=0 if zeroed else self._random_offset(i), groups=groups.get(pid),
                            poles=poles.get(pid), joint_encoder_counts=JOINT_ENCODER_COUNTS[i] if joint_encoders else 0)
            for i, pid in enumerate(self.arm.puck_ids)}
        self.safety = None if not safety_module else SimulatedSafetyModule(
            firmware_version=safety_firmware_version, mode=SafetyMode[safety_mode.upper()], zeroed=zeroed,
            heartbeat_timeout_s=heartbeat_timeout_s, groups=groups.get(SAFETY_PUCK_ID, FACTORY_GROUPS[10]))
        if self.safety is not None and self.safety.mode == SafetyMode.ESTOP:
            for p in self._pucks.values():
                p.power_off()
        self.pendant = Pendant(pendant)
        self._start_pose = None if start_pose_rad is None else np.asarray(start_pose_rad, float).copy()
        self._owns_bus = bus is None
        if bus is None:
            bus = can.Bus(interface=interface, channel=channel, **{"receive_own_messages": False,
                                                                   **(bus_options or {})})
        self._bus = bus
        self._poll_timeout_s = float(poll_timeout_s)
        self._realtime = realtime
        self.realtime_granted: dict | None = None
        self._lock = threading.RLock()
        self._stats = SimStats()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._closed = False
        self._t0 = time.monotonic()
        self._bus_off_until = -np.inf
        self.bus_off_reasons: list[str] = []
        # fault switches
        self._drop_probability = 0.0
        self._drop_after_s: float | None = None
        self._garbage_probability = 0.0
        self._silent: set[int] = set()
        self._answering = True

    def _random_offset(self, i: int) -> int:
        span = 5 * int(self._cts[i])  # up to five motor turns: a reading that means nothing until zeroed
        return self._rng.randint(-span, span)

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> PuckSimulator:
        """Start the listening thread (no-op if running). Fault times count from here."""
        if self._closed:
            raise RuntimeError("PuckSimulator was shut down; create a new one")
        if self._thread is None:
            self._t0 = time.monotonic()
            self._thread = threading.Thread(target=self._run, name="puck-sim", daemon=True)
            self._thread.start()
            logger.debug("puck simulator started on %s", self._bus.channel_info)
        return self

    def shutdown(self) -> None:
        """Stop the thread and close the bus if this simulator opened it. Safe to call more than once."""
        if self._closed:
            return
        self._closed = True
        self._stop.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=max(1.0, 20 * self._poll_timeout_s))
            if self._thread.is_alive():
                logger.warning("puck simulator thread did not stop within the timeout")
        if self._owns_bus:
            try:
                self._bus.shutdown()
            except Exception:  # noqa: BLE001 - closing must not raise
                logger.exception("closing the simulator's bus failed")

    def __enter__(self) -> PuckSimulator:
        return self.start()

    def __exit__(self, *exc_info: object) -> None:
        self.shutdown()

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def elapsed_s(self) -> float:
        """Seconds since :meth:`start` (or construction if not started)."""
        return time.monotonic() - self._t0

    # ------------------------------------------------------------------ the operator
    def press(self, button: str) -> None:
        """The operator presses ``activate``, ``idle`` or ``estop`` on the pendant now (or ``move``s the arm)."""
        with self._lock:
            self._operator(button, time.monotonic())

    def _operator(self, action: str, now: float) -> None:
        if action == "move":
            if hasattr(self._plant, "place") and self._start_pose is not None \
                    and not any(p.props[Prop.MODE] == Mode.TORQUE for p in self._pucks.values()):
                self._plant.place(self._start_pose)
            return
        if self.safety is None:
            return
        self._apply(self.safety.press(action, now, self._pucks_ready))

    def safety_fault(self, param: str) -> None:
        """The safety module sees a ``param`` fault now (``velocity``, ``torque``, ``heartbeat``, ``voltage``)."""
        with self._lock:
            self._apply(self.safety.inject_fault(param, time.monotonic()))

    def _pucks_ready(self) -> bool:
        now = time.time()
        return all(p.awake(now) for p in self._pucks.values())

    # ------------------------------------------------------------------ inspection
    @property
    def stats(self) -> SimStats:
        with self._lock:
            return dataclasses.replace(self._stats)

    def property_value(self, puck_id: int, prop: int) -> int | None:
        """A property as the simulator holds it (puck 10: the safety module), None if it has none."""
        with self._lock:
            if puck_id == SAFETY_PUCK_ID and self.safety is not None:
                return self.safety.get(prop, time.monotonic())
            return self._pucks[puck_id].props.get(int(prop))

    def modes(self) -> dict[int, int]:
        """MODE of every motor puck, by puck id."""
        with self._lock:
            return {pid: p.props[Prop.MODE] for pid, p in self._pucks.items()}

    def puck_torque_units(self) -> np.ndarray:
        """Torque commands the pucks hold, puck units, shape (n,) (zero for pucks not in TORQUE mode)."""
        with self._lock:
            return np.array([self._pucks[p].torque_units for p in self.arm.puck_ids], dtype=np.int64)

    def joint_torques_Nm(self) -> np.ndarray:
        """Joint torques the held puck commands produce, N m, shape (n,)."""
        return puck_units_to_joint_torque_Nm(self.puck_torque_units(), self._ipnm, self._j2mp)

    def describe(self) -> dict:
        with self._lock:
            return {"robot": self.arm.name, "pucks": list(self.arm.puck_ids),
                    "stats": dataclasses.asdict(self._stats), "pendant": str(self.pendant),
                    "realtime": self.realtime_granted,
                    "safety_module": None if self.safety is None else self.safety.describe(),
                    "bus_off": list(self.bus_off_reasons[-10:])}

    # ------------------------------------------------------------------ thread
    def _run(self) -> None:
        rt = RealtimeSection(fifo=True).enter() if self._realtime else None
        self.realtime_granted = None if rt is None else dict(rt.granted)
        try:
            self._serve()
        finally:
            if rt is not None:
                rt.exit()

    def _serve(self) -> None:
        while not self._stop.is_set():
            try:
                msg = self._bus.recv(timeout=self._poll_timeout_s)
            except Exception:  # noqa: BLE001 - keep the thread alive, but do not spin
                if self._stop.is_set():
                    break
                logger.exception("puck simulator: receive failed")
                self._count("handler_errors")
                self._stop.wait(self._poll_timeout_s)
                continue
            try:
                with self._lock:
                    self._tick(time.monotonic())
                    if msg is not None:
                        self._handle(msg)
            except Exception:  # noqa: BLE001 - a plant or protocol bug must not kill the pucks silently
                logger.exception("puck simulator: handling %s failed", msg)
                self._count("handler_errors")
            finally:
                if msg is not None:
                    self._count("frames_handled")

    def _count(self, name: str, n: int = 1) -> None:
        with self._lock:  # (re-entrant: the thread holds it while it handles a frame)
            self._stats.__dict__[name] += n

    def _tick(self, now: float) -> None:
        for action in self.pendant.due(now):
            if action == "activate" and self.safety is not None and self.safety.latched \
                    and self.safety.mode == SafetyMode.IDLE:
                self._operator("idle", now)  # the scripted operator does as the host says: Shift-Idle first
            self._operator(action, now)
        if self.safety is not None:
            self._apply(self.safety.tick(now))

    def _apply(self, action: str | None) -> None:
        """Make the pucks follow the safety module."""
        if action is None:
            return
        if action == "torque":
            self.pendant.activated()
        if action in ("torque", "idle"):
            mode = Mode.TORQUE if action == "torque" else Mode.IDLE
            now = time.time()
            for p in self._pucks.values():
                if p.awake(now) and p.puck_id not in self._silent:  # a puck off the bus misses the broadcast
                    p.props[Prop.MODE] = int(mode)
                    p.torque_units = p.props[Prop.T] = 0
            self._send(make_safety_broadcast(mode), counter="broadcasts_sent")
        elif action == "power_off":
            for p in self._pucks.values():
                p.power_off()
        elif action == "power_on":
            for i, p in enumerate(self._pucks.values()):
                p.power_on(self._random_offset(i))
        self._apply_torques()

    def _module_hears(self, group: int) -> bool:
        s = self.safety
        return s is not None and group in groups_of((s.props[SafetyProp.GRPA], s.props[SafetyProp.GRPB],
                                                     s.props[SafetyProp.GRPC]))

    def _addressed(self, bid) -> tuple[list[MotorPuck], bool]:
        """The motor pucks a host frame reaches, and whether the safety module is addressed too."""
        if bid.is_group:
            pucks = [p for p in self._pucks.values() if p.listens_to(bid.target)]
            module = self._module_hears(bid.target)
        else:
            pucks = [self._pucks[bid.target]] if bid.target in self._pucks else []
            module = self.safety is not None and bid.target == SAFETY_PUCK_ID
        return [p for p in pucks if p.powered and p.puck_id not in self._silent], module

    def _wake_window_violation(self, bid, data: bytes, t_wall: float) -> str | None:
        is_wake = (not bid.is_group and bid.target in self._pucks and len(data) in (4, 6)
                   and data[0] == (0x80 | Prop.STAT) and data[2] == Status.READY)
        for p in self._pucks.values():
            where = p.in_wake_window(t_wall + _CLOCK_TOLERANCE_S)
            if where == "turning off" or (where == "coming back" and not is_wake):
                return (f"frame {bid} {data.hex()} {t_wall - p.wake_set_t:.3f} s after puck {p.puck_id} was woken "
                        f"(its transceiver {where})")
        return None

    def _handle(self, msg: can.Message) -> None:
        self._count("frames_received")
        if msg.is_error_frame or msg.is_remote_frame or msg.is_extended_id:
            self._count("ignored_frames")
            return
        bid = decode_bus_id(msg.arbitration_id)
        if bid.sender != HOST_ID:  # our own replies (udp_multicast loops them back), other nodes
            self._count("ignored_frames")
            return
        t_wall = msg.timestamp or time.time()
        data = bytes(msg.data)
        if t_wall < self._bus_off_until:
            self._count("frames_dropped_bus_off")
            return
        violation = self._wake_window_violation(bid, data, t_wall)
        if violation is not None:
            self._count("wake_window_frames")
            self._count("bus_off_events")
            self._bus_off_until = t_wall + BUS_OFF_S
            self.bus_off_reasons.append(violation)
            logger.warning("simulated bus: host bus-off: %s", violation)
            self._send(can.Message(arbitration_id=_BUS_OFF_ERROR_ID, is_error_frame=True, is_extended_id=False,
                                   data=bytes(8)), counter="replies_sent")
            return
        pucks, module = self._addressed(bid)
        if not pucks and not module:
            self._count("ignored_frames")
            return
        if bid.is_group and bid.target in {g & 0x1F for g in TORQUE_GROUPS} \
                and data[:1] == bytes([PACKED_TORQUE_HEADER]):
            self._on_packed_torques(pucks, module, data)
            return
        try:
            is_set, prop, value = parse_host_property_message(data)
        except PuckFrameError as exc:
            logger.debug("puck simulator: ignoring %s (%s)", msg, exc)
            self._count("ignored_frames")
            return
        if module and not bid.is_group:
            self._on_safety(is_set, prop, value)
        elif is_set:
            self._on_set(pucks, prop, value, t_wall)
        elif prop == Prop.P:
            self._on_position_request(pucks, bid.is_group)
        else:
            self._on_get(pucks, prop)

    # ------------------------------------------------------------------ the safety module's frames
    def _on_safety(self, is_set: bool, prop: int, value: int | None) -> None:
        now = time.monotonic()
        if is_set:
            self._count("property_sets")
            self._apply(self.safety.set(prop, value, now))
            return
        self._count("property_gets")
        v = self.safety.get(prop, now)
        if v is not None:
            self._reply(make_property_reply(SAFETY_PUCK_ID, prop, v))

    # ------------------------------------------------------------------ the motor pucks' frames
    def _on_get(self, pucks: list[MotorPuck], prop: int) -> None:
        self._count("property_gets")
        now = time.time()
        for puck in pucks:
            awake = puck.awake(now)  # first: a puck whose wake-up time has come answers STAT=READY
            value = puck.props.get(prop)
            if value is None or (not awake and prop not in MONITOR_PROPS):
                continue
            if puck.wake_set_t is not None:  # waking: off the bus
                continue
            self._reply(make_property_reply(puck.puck_id, prop, value))

    def _raw_counts(self) -> tuple[np.ndarray, np.ndarray]:
        q_rad = np.asarray(self._plant.joint_positions_rad(), dtype=float).reshape(self._n)
        return joint_rad_to_counts(q_rad, self._cts, self._j2mp), q_rad

    def _on_position_request(self, pucks: list[MotorPuck], group: bool) -> None:
        self._count("position_requests")
        now = time.monotonic()
        if group:
            self.pendant.position_request(now)
        now_wall = time.time()
        awake = [p for p in pucks if p.awake(now_wall)]
        if not awake:
            return
        counts, q_rad = self._raw_counts()
        reported = counts.astype(np.int64).copy()
        for puck in awake:
            i = puck.puck_id - 1
            c = int(counts[i]) + puck.offset_counts
            reported[i] = c
            if not POSITION_MIN_COUNTS <= c <= POSITION_MAX_COUNTS:
                logger.warning("puck %d: %d counts overflow 22 bits; the reply wraps", puck.puck_id, c)
            je = None
            if puck.joint_encoder_counts:
                je = int(round(q_rad[i] * puck.joint_encoder_counts / (2 * np.pi)))
            self._reply(make_position_reply(puck.puck_id, c, wrap=True, secondary_counts=je))
        if self._module_hears(FEEDBACK_POSITION_TARGET):
            q_meas = counts_to_joint_rad(reported.astype(float), self._cts, self._j2mp)
            self._apply(self.safety.position_sample(q_meas, now))

    def _on_set(self, pucks: list[MotorPuck], prop: int, value: int, t_wall: float) -> None:
        self._count("property_sets")
        torque_changed = False
        counts = self._raw_counts()[0] if prop == Prop.P else None
        now = time.time()
        for puck in pucks:
            if prop == Prop.STAT:
                if value == Status.READY and puck.wake_at is None:
                    puck.wake_set_t, puck.wake_at = t_wall, t_wall + self._wake_s
                elif value == Status.RESET:
                    puck.wake_set_t = puck.wake_at = None
                    puck.props[Prop.STAT] = int(Status.RESET)
                continue
            if not puck.awake(now):
                continue
            if prop == Prop.MODE:
                if value != Mode.IDLE:  # only the safety module puts a puck into another mode
                    if not self._stats.host_mode_writes_refused:
                        logger.warning("pucks ignore MODE=%d from the host (the safety module sets MODE)", value)
                    self._count("host_mode_writes_refused")
                    continue
                if puck.props[prop] == Mode.TORQUE:
                    self.pendant.host_idled(time.monotonic())
                puck.props[prop] = int(Mode.IDLE)
                if puck.torque_units:
                    puck.torque_units = 0
                    torque_changed = True
            elif prop == Prop.T:
                torque_changed |= self._hold_torque(puck, value)
            elif prop == Prop.P:
                puck.offset_counts = value - int(counts[puck.puck_id - 1])
                puck.props[prop] = value
            elif prop not in (Prop.VERS, Prop.ROLE, Prop.ID):
                puck.props[prop] = value
        if torque_changed:
            self._apply_torques()

    def _hold_torque(self, puck: MotorPuck, units: int) -> bool:
        new = int(saturate_puck_units(units)) if puck.props[Prop.MODE] == Mode.TORQUE else 0
        puck.props[Prop.T] = new
        changed = new != puck.torque_units
        puck.torque_units = new
        return changed

    def _on_packed_torques(self, pucks: list[MotorPuck], module: bool, data: bytes) -> None:
        try:
            values = unpack_torques(data)
        except PuckFrameError as exc:
            logger.debug("puck simulator: bad packed-torque frame (%s)", exc)
            self._count("ignored_frames")
            return
        self._count("torque_frames")
        now = time.time()
        for puck in pucks:
            slot = puck.props.get(Prop.PIDX, 0)
            if puck.awake(now) and 1 <= slot <= values.size:
                if values[slot - 1] != 0 and puck.props[Prop.MODE] != Mode.TORQUE:
                    self._count("nonzero_torque_not_in_torque_mode")      # the host's contract broken (tests)
                self._hold_torque(puck, int(values[slot - 1]))
        self._apply_torques()
        if module:
            self._apply(self.safety.torques(values, time.monotonic()))

    def _apply_torques(self) -> None:
        self._plant.apply_joint_torques_Nm(self.joint_torques_Nm())

    # ------------------------------------------------------------------ sending
    def _send(self, msg: can.Message, counter: str) -> None:
        if not self._answering:
            return
        try:
            self._bus.send(msg)
        except can.CanError:
            logger.warning("puck simulator: sending %s failed", msg, exc_info=True)
            self._count("send_errors")
            return
        self._count(counter)
