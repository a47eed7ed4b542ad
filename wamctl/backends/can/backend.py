"""The real arm over CAN: a backend speaking the Barrett puck protocol through python-can, in a session the way
Barrett's safety system expects it (libbarrett's order; see :mod:`.session` for the start).

:class:`CanBackend` implements the backend protocol of :class:`~wamctl.backends.base.ArmBackend`:

- ``_open``: open the bus; the start of the session (:func:`~.session.start_session`: safety module, limits,
  Shift-Idle, wake with libbarrett's pacing, the arm's configuration, zeroing after confirmation); then the
  heartbeat: positions polled at 500 Hz with zero torque (the polling is what the safety module watches);
  the operator is asked to put the arm at the spec's start pose, then to press Shift-Activate (countdowns,
  timeouts). wamctl never sets MODE=TORQUE: it waits until the safety module reports active and every puck
  reports TORQUE, then hands over to the run. A timeout ends the session with nothing applied.
- ``_read_positions``: one get of P to the whole-WAM group (0x404), the replies decoded to motor counts (3 or
  6 bytes), turned into joint angles through the arm's ``J2MP`` and each puck's CTS; replies of the safety
  monitor (:mod:`.monitor`) read on the way.
- ``_send_torques``: joint torques -> motor torques (``J2MP^-T``) -> puck units (IPNM) -> the packed 14-bit
  frames of the arm's torque groups (a wam7: 0x401 pucks 1-4, 0x402 pucks 5-7; a wam4: 0x401 only; slots by
  PIDX).

The arm is the spec's ``robot`` (:class:`~.protocol.configuration.BusArm`): ``wam7`` (pucks 1-7) by default,
``wam4`` (pucks 1-4, pucks 5-7 absent: libbarrett's ``foundWam4``); its joint count sets every vector, its home
pose the zeroing, its transmission the conversions. The safety module's limits and every watchdog are the same
for both arms.
- ``_wait_next_cycle``: every 25 cycles (50 ms) the safety module's PEN and MODE and the pucks' MODE are asked
  for; then the wait for the next release point ``t0 + k T`` (:mod:`.timing`).
- ``_close``: zero torque (the base), MODE=IDLE to the WAM (read back), the heartbeat goes on while the
  operator is asked to press Shift-Idle, then the report of the state the arm is left in.

Stops: the safety module leaving active (Shift-Idle: the run is *interrupted*; E-stop, velocity, torque or
heartbeat fault: *failed*, the reason in words), a puck leaving TORQUE, the module falling silent, position
replies missing or late for more than ``watchdog_cycles`` cycles, a malformed frame from a puck, or a transmit
error: zero torque at once, pucks IDLE, the reason raised (:class:`~wamctl.errors.SafetyLimitError`,
:class:`~wamctl.errors.BackendError` or :class:`~.monitor.PendantStop`); the runner keeps every sample.

Defaults for a lab PC without a real-time kernel (see the README): ``reply_timeout_s`` 1.5 ms = the bus time
of the request and seven replies (75 us each, Barrett's CAN timing: 0.6 ms) plus 0.9 ms for the host's
scheduling jitter; ``watchdog_cycles`` 3 (6 ms without a complete set of replies).

Simulated pucks (``simulate_pucks: true``, virtual bus only), injected faults: :mod:`.simulated_arm`.
Conventions: pucks 1..n on the bus, arrays 0..n-1; SI units in names; the host is node 0.
"""

from __future__ import annotations

import logging
import time
from pathlib import Path
from typing import Any

import can
import numpy as np

from wamctl.backends.base import ArmBackend, SafetyLimits
from wamctl.backends.can.bus_tools import (
    PROBE_TIMEOUT_S,
    TX_TIMEOUT_S,
    open_bus,
    read_property,
)
from wamctl.backends.can.link import Link
from wamctl.backends.can.monitor import SafetyMonitor, stop_reason
from wamctl.backends.can.operator import Operator, current_operator
from wamctl.backends.can.protocol.addressing import (
    FEEDBACK_OTHER,
    FEEDBACK_POSITION,
    GROUP_WAM,
    SAFETY_PUCK_ID,
    TO_MASK,
    PuckFrameError,
)
from wamctl.backends.can.protocol.configuration import bus_arm
from wamctl.backends.can.protocol.positions import make_position_request
from wamctl.backends.can.protocol.properties import CTS_DEFAULT, Mode, Prop, make_set_property
from wamctl.backends.can.protocol.safety import SafetyMode, SafetyProp, decode_pen
from wamctl.backends.can.protocol.torques import (
    IPNM_DEFAULT,
    joint_torque_to_puck_units,
    pack_torques,
    torque_slot_of_puck,
)
from wamctl.backends.can.session import SessionSettings, StartState, start_session
from wamctl.backends.can.simulated_arm import SimulatedArm, build_simulated_arm, inject_fault
from wamctl.backends.can.timing import LoopTiming, RealtimeSection, sleep_until
from wamctl.backends.can.waits import SessionWaits
from wamctl.errors import BackendError
from wamctl.model.transmission import load_kernels

logger = logging.getLogger(__name__)

__all__ = ["CanBackend"]

MAX_OVERRUN_EVENTS = 20  # overruns recorded one by one as events; the rest only counted
POLL_RUN_CYCLES = 25  # the safety module and the pucks' MODE every 50 ms during the run
POLL_WAIT_CYCLES = 5  # the safety module every 10 ms while waiting for Shift-Activate / Shift-Idle
DEFAULT_PENDANT = "activate@0.2,idle@end"  # in-process simulated operator
FIRST_READ_TIMEOUT_S = 1.0  # libbarrett CommunicationsBus::TIMEOUT


class CanBackend(SessionWaits, Link, ArmBackend):
    """The WAM over CAN (see the module docstring).

    Parameters
    ----------
    interface, channel : str
        python-can interface and channel.
    bitrate : int
        Bit/s.
    robot : str or Robot, optional
        The arm (:mod:`wamctl.model.robots`): ``wam7`` (default) or ``wam4``; the pucks, torque groups, home pose
        and transmission the session expects (:func:`~.protocol.configuration.bus_arm`).
    q0_rad : array_like, shape (n,), optional
        The run's start pose: the operator is asked to put the arm there (within the session's
        ``start_tolerance_rad``) before Shift-Activate. None: no start pose (tools, hardware checks).
    watchdog_cycles : int
        Consecutive cycles with missing or late position replies tolerated; one more trips the watchdog.
    reply_timeout_s : float
        Wait for the seven position replies of a cycle.
    limits : SafetyLimits, optional
        Default: the robot's.
    session : SessionSettings, optional
        Timeouts, zeroing confirmation, the safety module's limits, the start tolerance.
    operator : Operator, optional
        Who is told and asked (default: :func:`~.operator.current_operator`).
    bus_options : dict, optional
        Further :class:`can.Bus` arguments (e.g. ``port`` of ``udp_multicast``).
    simulated_arm : SimulatedArm, optional
        Run simulated pucks driven by this arm on the (virtual) channel.
    sim_cts : int
        CTS of the simulated pucks.
    simulated_fault : wamctl.specs.SimulatedFault, optional
        A fault to inject at a given cycle (simulated pucks only).
    simulated_pendant : str
        The simulated pendant's script (:mod:`.sim.pendant`).
    seed : int, optional
        Seed of the simulated pucks' draws.
    realtime : bool
        From the heartbeat on: the garbage collector frozen and off, SCHED_FIFO (priority 50) if permitted
        (:class:`~.timing.RealtimeSection`). Off for simulated pucks in this process (they need the CPU).
    cpu : int, optional
        Pin the loop's thread to this CPU.
    """

    name = "can"

    def __init__(self, interface: str, channel: str, bitrate: int = 1_000_000, *, q0_rad=None,
                 watchdog_cycles: int = 3, reply_timeout_s: float = 0.0015, limits: SafetyLimits | None = None,
                 session: SessionSettings | None = None, operator: Operator | None = None,
                 bus_options: dict | None = None, simulated_arm: SimulatedArm | None = None,
                 sim_cts: int = CTS_DEFAULT, simulated_fault=None, simulated_pendant: str = DEFAULT_PENDANT,
                 seed: int | None = None, realtime: bool = True, cpu: int | None = None, robot=None) -> None:
        try:
            self.arm = bus_arm(robot)
        except ValueError as exc:
            raise BackendError(str(exc)) from None
        n = self.arm.n_joints
        super().__init__(limits if limits is not None else SafetyLimits.for_robot(self.arm.name))
        if self.limits.n_joints != n:
            raise BackendError(f"safety limits for {self.limits.n_joints} joints; the {self.arm.name} has {n}")
        self.interface, self.channel, self.bitrate = interface, channel, int(bitrate)
        self.bus_options = dict(bus_options or {})
        self.q0_rad = None if q0_rad is None else np.asarray(q0_rad, float).copy()
        if self.q0_rad is not None and self.q0_rad.shape != (n,):
            raise BackendError(f"q0_rad has {self.q0_rad.size} joints; the {self.arm.name} has {n}")
        self.watchdog_cycles = int(watchdog_cycles)
        self.reply_timeout_s = float(reply_timeout_s)
        self.settings = session or SessionSettings()
        self.operator = operator if operator is not None else current_operator(self.settings.zeroing_confirmed)
        self.simulated_arm = simulated_arm
        self.simulated_fault = simulated_fault
        self.simulated_pendant = simulated_pendant
        if simulated_fault is not None and simulated_arm is None:
            raise BackendError("a simulated fault needs the simulated pucks")
        if simulated_fault is not None and simulated_fault.kind == "silent_puck" \
                and simulated_fault.puck not in self.arm.puck_ids:
            raise BackendError(f"simulated_fault.puck: puck {simulated_fault.puck} is not one of the "
                               f"{self.arm.name}'s ({self.arm.pucks_words()})")
        self._sim_cts = int(sim_cts)
        self._seed = seed
        self._realtime = RealtimeSection(fifo=realtime and simulated_arm is None, cpu=cpu)
        self._rt_entered = False
        self.simulator = None
        self._bus: can.BusABC | None = None
        self.pucks: dict = {}
        self.start: StartState | None = None
        self.monitor = SafetyMonitor(self.arm.puck_ids)
        self.phase = "closed"  # start -> waiting -> run -> closing
        self._cts = np.full(n, float(CTS_DEFAULT))
        self._ipnm = np.full(n, float(IPNM_DEFAULT))
        self._slots: list[tuple[int, list[int], list[int]]] = []  # (group id, puck indices 0..n-1, PIDX)
        self._request = make_position_request(GROUP_WAM)
        self._counts = np.zeros(n)
        self._q = np.zeros(n)
        self._zero_tau = np.zeros(n)
        self._torque_msgs: list[can.Message] = []  # one per torque group, their data rewritten every cycle
        self._got = 0
        self._garbage_seen: str | None = None
        # loop state: _tick counts every 2 ms cycle of the session, _cycle those of the run
        self._tick = 0
        self._cycle = 0
        self._t0: float | None = None  # the schedule: release point k is t0 + (k + skipped) T
        self._k = 0
        self._skipped = 0
        self.timing = LoopTiming(self.control_period_s)
        self.heartbeat_timing = LoopTiming(self.control_period_s)
        self._bad_cycles = 0
        self._bad_run_start: int | None = None
        self._events: list[tuple[float, str, int | None, str]] = []
        self._stats = {"frames_sent": 0, "frames_received": 0, "late_replies": 0, "missed_reply_cycles": 0,
                       "foreign_frames": 0, "error_frames": 0, "garbage_frames": 0, "tx_errors": 0,
                       "safety_broadcasts": 0}
        self.session_log: dict[str, Any] = {}
        # watchdog
        self.trip_reason: str | None = None
        self.trip_cycle: int | None = None
        self.fault_onset_cycle: int | None = None
        self.zero_torque_cycle: int | None = None
        self.idle_confirmed: list[int] = []
        self._tx_failures_pending = 0
        self._fault_injected_cycle: int | None = None
        self.torque_mode_confirmed = False

    # ---------------------------------------------------------------- construction
    @classmethod
    def from_spec(cls, spec, base_dir: Path | None, q0_rad, rng: np.random.Generator) -> CanBackend:
        """The backend a spec's ``backend: {kind: can, ...}`` describes (with simulated pucks if asked)."""
        b = spec.backend
        arm, cts = None, CTS_DEFAULT
        robot = getattr(spec, "robot", None)
        if b.simulate_pucks:
            arm, cts = build_simulated_arm(spec.plant, base_dir, q0_rad, rng, b.physics_substeps, robot)
        settings = SessionSettings(
            activation_timeout_s=b.activation_timeout_s, idle_wait_s=b.idle_wait_s,
            zeroing_confirmed=b.zeroing_confirmed, velocity_limit_m_s=b.velocity_limit_m_s,
            torque_limit_Nm=b.torque_limit_Nm, start_tolerance_rad=b.start_tolerance_rad)
        return cls(b.interface, b.channel, b.bitrate, q0_rad=q0_rad, watchdog_cycles=b.watchdog_cycles,
                   reply_timeout_s=b.reply_timeout_s, session=settings, bus_options=dict(b.bus_options),
                   simulated_arm=arm, sim_cts=cts, simulated_fault=b.simulated_fault,
                   simulated_pendant=b.simulated_pendant, seed=spec.seed, robot=robot)

    # ---------------------------------------------------------------- properties
    @property
    def time_s(self) -> float:
        """Nominal loop time: cycles of the run times the control period."""
        return self._cycle * self.control_period_s

    @property
    def cycle(self) -> int:
        """Index of the current control cycle of the run (0 = the first position read after activation)."""
        return self._cycle

    def describe(self) -> dict:
        """Interface, pucks, safety module, session, loop statistics, link counters and the watchdog's verdict.

        With simulated pucks, first waits (up to a second) until they have handled every frame sent."""
        self._sync_simulator()
        w = {"tripped": self.trip_reason is not None, "reason": self.trip_reason,
             "fault_onset_cycle": self.fault_onset_cycle, "trip_cycle": self.trip_cycle,
             "zero_torque_cycle": self.zero_torque_cycle,
             "cycles_to_zero_torque": (None if self.zero_torque_cycle is None or self.fault_onset_cycle is None
                                       else self.zero_torque_cycle - self.fault_onset_cycle),
             "idle_confirmed_pucks": list(self.idle_confirmed)}
        d: dict[str, Any] = {
            "name": self.name, "robot": self.arm.name, "interface": self.interface, "channel": self.channel,
            "bitrate": self.bitrate,
            "simulated_pucks": self.simulated_arm is not None, "watchdog_cycles": self.watchdog_cycles,
            "reply_timeout_s": self.reply_timeout_s, "torque_mode_confirmed": self.torque_mode_confirmed,
            "phase": self.phase,
            "pucks": {str(i): {k: info.to_dict()[k] for k in ("vers", "cts", "ipnm", "pidx", "poles", "groups",
                                                               "sn", "joint_encoder")}
                      for i, info in self.pucks.items()},
            "safety_module": None if self.start is None else {**self.start.safety.to_dict(),
                                                               "limits": self.start.limits},
            "session": {**self.session_log, "zeroed_now": bool(self.start and self.start.zeroed_now),
                        "zero_counts": None if self.start is None else self.start.zero_counts,
                        "heartbeat": self.heartbeat_timing.summary(), "monitor": self.monitor.describe()},
            "loop": {**self.timing.summary(), "cycles": self._cycle}, "link": dict(self._stats), "watchdog": w,
        }
        if self.simulated_arm is not None:
            sim: dict[str, Any] = {"arm": self.simulated_arm.describe()}
            if self.simulator is not None:
                sd = self.simulator.describe()
                sim["stats"] = sd["stats"]
                sim["safety_module"] = sd["safety_module"]
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
        """Events since the last call, ``(t_s, kind, joint, detail)`` with loop time ``t_s``."""
        out, self._events = self._events, []
        if self.timing.overruns > MAX_OVERRUN_EVENTS:
            out.append((self.time_s, "overrun", None, f"{self.timing.overruns} overruns in total "
                        f"({self.timing.skipped_periods} periods skipped), first {MAX_OVERRUN_EVENTS} listed"))
        return out

    def _event(self, kind: str, detail: str, joint: int | None = None, cycle: int | None = None) -> None:
        c = self._cycle if cycle is None else cycle
        self._events.append((c * self.control_period_s, kind, joint, detail))

    # ---------------------------------------------------------------- open
    def _open(self) -> None:
        load_kernels()   # the loop converts counts every cycle: compile/load before the first deadline
        try:
            if self.simulated_arm is not None:
                from wamctl.backends.can.sim.simulator import PuckSimulator
                self.simulator = PuckSimulator(self.simulated_arm, channel=self.channel, interface=self.interface,
                                               cts=self._sim_cts, seed=self._seed, pendant=self.simulated_pendant,
                                               start_pose_rad=self.q0_rad, robot=self.arm.name)
                self.simulated_arm.attach(self.simulator)
                self.simulator.start()
            filters = [{"can_id": FEEDBACK_POSITION, "can_mask": TO_MASK, "extended": False},
                       {"can_id": FEEDBACK_OTHER, "can_mask": TO_MASK, "extended": False}]
            self._bus = open_bus(self.interface, self.channel, self.bitrate, can_filters=filters,
                                 **self.bus_options)
            self.phase = "start"
            try:
                self.start = start_session(self._bus, self._tx, self.operator, self.settings, arm=self.arm)
                self._configure()
                self._realtime.enter()
                self._rt_entered = True
                self.session_log["realtime"] = dict(self._realtime.granted)
                self._first_read()
                self.phase = "waiting"
                self._wait_for_start_pose()
                self._wait_for_activation()
            except can.CanError as exc:
                raise BackendError(f"CAN error during start-up: {exc}") from None
        except BaseException:
            self._close()
            raise
        self.phase = "run"
        self._t0 = None  # the run's schedule starts at its first read
        self._cycle = 0
        self._bad_cycles, self._bad_run_start = 0, None

    def _configure(self) -> None:
        found, arm = self.start.pucks, self.arm
        self.pucks = found
        self._cts = np.array([found[i].cts for i in arm.puck_ids], float)
        self._ipnm = np.array([found[i].ipnm for i in arm.puck_ids], float)
        slots = torque_slot_of_puck({i: found[i].pidx for i in arm.puck_ids}, arm.torque_groups)
        self._slots = [(g, [p - 1 for p in members], [slots[p][1] for p in members])
                       for g, members in arm.torque_groups.items()]
        self._torque_msgs = [can.Message(arbitration_id=g, data=bytearray(8), is_extended_id=False)
                             for g in arm.torque_groups]

    def _first_read(self) -> None:
        """One position request answered by all the arm's pucks within 1 s before the 500 Hz polling starts
        (libbarrett's first read, with its blocking receive's 1 s timeout)."""
        saved = self.reply_timeout_s
        self.reply_timeout_s = FIRST_READ_TIMEOUT_S
        try:
            self._poll()
        finally:
            self.reply_timeout_s = saved
        if self._bad_cycles:
            raise BackendError(f"pucks did not answer the first position request within {FIRST_READ_TIMEOUT_S} s")

    def _beat(self) -> np.ndarray:
        """One heartbeat cycle outside the run: positions, zero torque, the monitor's poll, the wait."""
        q = self._poll()
        self._tx_torque_units(self._zero_tau)
        self._end_cycle(POLL_WAIT_CYCLES, pucks=self.monitor.active)
        return q

    # ---------------------------------------------------------------- close
    def _close(self) -> None:
        try:
            if self._bus is not None and self.phase in ("waiting", "run"):
                self._finish_session()
        finally:
            self.phase = "closed"
            if self._rt_entered:
                self._realtime.exit()
                self._rt_entered = False
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
                self._tx(make_set_property(GROUP_WAM, Prop.MODE, Mode.IDLE), count_errors=False)
                break
            except can.CanError as exc:
                logger.error("setting the pucks IDLE failed (attempt %d): %s", attempt + 1, exc)
        try:
            modes = read_property(self._bus, self.arm.puck_ids, Prop.MODE, PROBE_TIMEOUT_S, retries=1, send=self._tx)
        except can.CanError as exc:
            logger.error("reading MODE back failed: %s", exc)
            modes = {}
        self.idle_confirmed = sorted(i for i, m in modes.items() if m == Mode.IDLE)
        if len(self.idle_confirmed) < self.arm.n_joints:
            logger.error("pucks confirmed IDLE: %s of %s", self.idle_confirmed, self.arm.pucks_words())

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
        units = joint_torque_to_puck_units(tau_Nm, self._ipnm, self.arm.j2mp)
        for msg, (_group, idx, pidx) in zip(self._torque_msgs, self._slots):
            msg.data[:] = pack_torques(units[idx], pidx)  # the interfaces copy or serialise what they send
            self._tx(msg)

    def _send_torques(self, tau_Nm: np.ndarray) -> None:
        if self._bus is None:
            return
        if self._closed or self.trip_reason is not None or self.phase != "run":  # best effort, never raise
            try:
                self._tx_torque_units(self._zero_tau)
            except can.CanError as exc:
                logger.error("sending zero torque failed: %s", exc)
            return
        try:
            self._tx_torque_units(tau_Nm)
        except can.CanError as exc:
            self._trip(f"CAN transmit error: {exc}", BackendError)

    # ---------------------------------------------------------------- receive
    def _read_positions(self) -> np.ndarray:
        if self._bus is None:
            raise BackendError("CAN backend is not open")
        if self._t0 is None:
            now = time.perf_counter()
            self._t0, self._k, self._skipped = now, 0, 0
            self.timing.cycle_started(now, 0.0)
        if self.simulated_fault is not None and self._fault_injected_cycle is None \
                and self._cycle >= self.simulated_fault.at_cycle:
            self._inject_fault()
        q = self._poll()
        stop = self.monitor.run_stop(self.start.limits if self.start else {})
        if stop is not None:
            reason, exc_type = stop
            if exc_type is not BackendError and self.monitor.module_mode != SafetyMode.ESTOP:
                reason, exc_type = self._confirmed_stop_reason()
            self._trip(reason, exc_type)
        return q

    def _confirmed_stop_reason(self) -> tuple[str, type]:
        """The pendant read once more: a fault shows there a moment after the mode changes."""
        try:
            pen = read_property(self._bus, [SAFETY_PUCK_ID], SafetyProp.PEN, PROBE_TIMEOUT_S, retries=0,
                                send=self._tx).get(SAFETY_PUCK_ID)
            pen_state = decode_pen(pen) if pen is not None else self.monitor.pen
        except (can.CanError, PuckFrameError):
            pen_state = self.monitor.pen
        return stop_reason(self.monitor.module_mode, pen_state, self.start.limits if self.start else {})

    # ---------------------------------------------------------------- watchdog
    def _trip(self, reason: str, exc_type: type[BaseException]) -> None:
        """Zero torque, pucks to IDLE, remember why, raise ``exc_type(reason)``."""
        if self.trip_reason is None:
            self.trip_reason = reason
            self.trip_cycle = self._cycle
            self.fault_onset_cycle = self._bad_run_start if self._bad_run_start is not None else self._cycle
            logger.error("%s: zero torque, pucks to IDLE", reason)
            self._tau_applied[:] = 0.0
            for attempt in range(3):
                try:
                    self._tx_torque_units(self._zero_tau)
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
        self._tx_failures_pending = inject_fault(sim, f)

    # ---------------------------------------------------------------- timing
    def _wait_next_cycle(self) -> None:
        self._end_cycle(POLL_RUN_CYCLES, pucks=True)

    def _end_cycle(self, poll_every: int, pucks: bool) -> None:
        """The monitor's poll when due, then the wait for the next release point (absolute deadlines)."""
        if self._tick % poll_every == 0:
            try:
                for m in self.monitor.requests(pucks=pucks):
                    self._tx(m)
            except can.CanError as exc:
                if self.phase == "run":
                    self._trip(f"CAN transmit error: {exc}", BackendError)
                if self.phase != "closing":
                    raise BackendError(f"CAN transmit error: {exc}") from None
        timing = self.timing if self.phase == "run" else self.heartbeat_timing
        T = self.control_period_s
        now = time.perf_counter()
        if self._t0 is None:
            self._t0, self._k, self._skipped = now, 0, 0
            timing.cycle_started(now, 0.0)
        timing.cycle_ended(now)
        self._tick += 1
        self._k += 1
        if self.phase == "run":
            self._cycle += 1
        deadline = self._t0 + (self._k + self._skipped) * T
        if now > deadline:
            late = now - deadline
            skipped = int(late // T)
            self._skipped += skipped
            timing.overrun(late, skipped)
            if self.phase == "run" and timing.overruns <= MAX_OVERRUN_EVENTS:
                self._event("overrun", f"cycle {self._cycle - 1} ended {late * 1e3:.2f} ms after its deadline"
                            + (f"; {skipped} release points skipped" if skipped else ""), cycle=self._cycle - 1)
            timing.cycle_started(now, late - skipped * T)
            return
        now = sleep_until(deadline)
        timing.cycle_started(now, now - deadline)
