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

Simulated pucks (``simulate_pucks: true``, virtual bus only) and injected faults (``backend.simulated_fault``):
see :mod:`wamctl.backends.can.simulated_arm`.

Limits: torque frames get no reply, so a torque frame lost on the way (SocketCAN can drop transmit frames
silently) is noticed only through the position replies; and a puck that neither answers nor listens cannot
be commanded at all: the host sends zero torque and IDLE, the other pucks obey, that puck keeps its last
command (the WAM's safety module is the backstop).

Conventions: pucks 1..7 on the bus, arrays 0..6; SI units in names; the host is node 0.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from pathlib import Path
from typing import Any

import can
import numpy as np

from wamctl.backends.base import ArmBackend, SafetyLimits
from wamctl.backends.can.bus_tools import (
    ALL_WAM_PUCKS,
    PROBE_TIMEOUT_S,
    TX_TIMEOUT_S,
    PuckInfo,
    check_motor_pucks,
    open_bus,
    probe_pucks,
    read_property,
    recv_until,
)
from wamctl.backends.can.protocol.addressing import (
    FEEDBACK_OTHER,
    FEEDBACK_OTHER_TARGET,
    FEEDBACK_POSITION,
    FEEDBACK_POSITION_TARGET,
    GROUP_WAM,
    MAX_CAN_ID,
    N_JOINTS,
    TO_MASK,
    TORQUE_GROUPS,
    WAM_PUCK_IDS,
    BusId,
    PuckFrameError,
    decode_bus_id,
)
from wamctl.backends.can.protocol.positions import make_position_request, parse_position_reply
from wamctl.backends.can.protocol.properties import (
    CTS_DEFAULT,
    Mode,
    Prop,
    make_get_property,
    make_set_property,
    parse_property_reply,
)
from wamctl.backends.can.protocol.torques import (
    IPNM_DEFAULT,
    joint_torque_to_puck_units,
    pack_torques,
    torque_slot_of_puck,
)
from wamctl.backends.can.simulated_arm import SimulatedArm, build_simulated_arm, inject_fault
from wamctl.backends.can.timing import LoopTiming, sleep_until
from wamctl.errors import BackendError, SafetyLimitError
from wamctl.model import params as P
from wamctl.model.transmission import J2MP, counts_to_joint_rad, load_kernels

logger = logging.getLogger(__name__)

__all__ = ["CanBackend"]

MAX_OVERRUN_EVENTS = 20  # overruns recorded one by one as events; the rest only counted


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
                 sim_cts: int = CTS_DEFAULT, simulated_fault=None, seed: int | None = None) -> None:
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
        self._cts = np.full(P.N_JOINTS, float(CTS_DEFAULT))
        self._ipnm = np.full(P.N_JOINTS, float(IPNM_DEFAULT))
        self._slots: list[tuple[int, list[int], list[int]]] = []  # (group id, puck indices 0..6, PIDX)
        self._request = make_position_request(GROUP_WAM)
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
        arm, cts = None, CTS_DEFAULT
        if b.simulate_pucks:
            arm, cts = build_simulated_arm(spec.plant, base_dir, q0_rad, rng, b.physics_substeps)
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
        load_kernels()   # the loop converts counts every cycle: compile/load before the first deadline
        try:
            if self.simulated_arm is not None:
                from wamctl.backends.can.puck_sim import PuckSimulator
                self.simulator = PuckSimulator(self.simulated_arm, channel=self.channel, interface=self.interface,
                                               cts=self._sim_cts, seed=self._seed)
                self.simulated_arm.attach(self.simulator)
                self.simulator.start()
            filters = [{"can_id": FEEDBACK_POSITION, "can_mask": TO_MASK, "extended": False},
                       {"can_id": FEEDBACK_OTHER, "can_mask": TO_MASK, "extended": False}]
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
        found = probe_pucks(bus, WAM_PUCK_IDS, wake=True, send=self._tx)
        missing = [i for i in WAM_PUCK_IDS if i not in found]
        if missing:
            raise BackendError(f"WAM pucks {missing} did not answer on {self.interface} channel "
                               f"{self.channel!r} (power, cabling, termination?)")
        check_motor_pucks(found)
        self.pucks = found
        self._cts = np.array([found[i].cts for i in WAM_PUCK_IDS], float)
        self._ipnm = np.array([found[i].ipnm for i in WAM_PUCK_IDS], float)
        slots = torque_slot_of_puck({i: found[i].pidx for i in WAM_PUCK_IDS})
        self._slots = [(g, [p - 1 for p in members], [slots[p][1] for p in members])
                       for g, members in TORQUE_GROUPS.items()]
        logger.info("pucks 1-7: VERS %s, CTS %s, IPNM %s", [found[i].vers for i in WAM_PUCK_IDS],
                    self._cts.astype(int).tolist(), self._ipnm.astype(int).tolist())
        # where is the arm? (pucks still idle: nothing moves)
        counts = self._poll_positions_once(PROBE_TIMEOUT_S)
        if counts is None:
            raise BackendError("no complete set of position replies at start-up")
        self._counts[:] = counts
        q = counts_to_joint_rad(self._counts, self._cts, J2MP)
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
            if bid is not None and bid.target == FEEDBACK_POSITION_TARGET:
                puck, c = parse_position_reply(msg)
                counts[puck - 1] = c
                got |= 1 << (puck - 1)
            return got == ALL_WAM_PUCKS

        recv_until(self._bus, time.perf_counter() + timeout_s, handle)
        return counts if got == ALL_WAM_PUCKS else None

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
                self._tx(make_set_property(GROUP_WAM, Prop.MODE, Mode.IDLE), count_errors=False)
                break
            except can.CanError as exc:
                logger.error("setting the pucks IDLE failed (attempt %d): %s", attempt + 1, exc)
        try:
            modes = read_property(self._bus, WAM_PUCK_IDS, Prop.MODE, PROBE_TIMEOUT_S, retries=0,
                                  send=self._tx)
        except can.CanError as exc:
            logger.error("reading MODE back failed: %s", exc)
            modes = {}
        self.idle_confirmed = sorted(i for i, m in modes.items() if m == Mode.IDLE)
        if len(self.idle_confirmed) < N_JOINTS:
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
        units = joint_torque_to_puck_units(tau_Nm, self._ipnm, J2MP)
        for group, idx, pidx in self._slots:
            payload = pack_torques(units[idx], pidx)
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
                self._tx(make_set_property(GROUP_WAM, Prop.MODE, Mode.TORQUE))
                self._mode_sent_cycle = self._cycle
                self._tx_torque_units(tau_Nm)
                self._tx(make_get_property(GROUP_WAM, Prop.MODE))
            else:
                self._tx_torque_units(tau_Nm)
        except can.CanError as exc:
            self._trip(f"CAN transmit error: {exc}", BackendError)

    def _check_torque_mode(self) -> None:
        """Trip if a puck reported another MODE than TORQUE, or not all did in time."""
        if self._mode_sent_cycle is None or self.torque_mode_confirmed:
            return
        wrong = {i: m for i, m in self._mode_replies.items() if m != Mode.TORQUE}
        if wrong:
            self._trip(f"pucks {sorted(wrong)} report MODE {sorted(set(wrong.values()))} instead of TORQUE "
                       f"({int(Mode.TORQUE)}): is the WAM activated (Shift+Activate on the pendant)?",
                       BackendError)
        if len(self._mode_replies) == N_JOINTS:
            self.torque_mode_confirmed = True
            self._event("torque_mode", f"pucks 1-7 confirmed in TORQUE mode (cycle {self._cycle})")
            logger.info("pucks 1-7 in TORQUE mode")
        elif self._cycle - self._mode_sent_cycle > self.watchdog_cycles + 1:
            missing = [i for i in WAM_PUCK_IDS if i not in self._mode_replies]
            self._trip(f"pucks {missing} did not confirm TORQUE mode within {self._cycle - self._mode_sent_cycle} "
                       "cycles", BackendError)

    # ---------------------------------------------------------------- receive
    def _decode(self, msg: can.Message) -> BusId | None:
        """The id of a frame from a WAM puck to a feedback group, or None (counted) for anything else."""
        self._stats["frames_received"] += 1
        if msg.is_error_frame:
            self._stats["error_frames"] += 1
            return None
        if msg.is_extended_id or msg.is_remote_frame or msg.arbitration_id > MAX_CAN_ID:
            self._stats["foreign_frames"] += 1
            return None
        bid = decode_bus_id(msg.arbitration_id)
        if not (bid.is_group and bid.sender in WAM_PUCK_IDS
                and bid.target in (FEEDBACK_POSITION_TARGET, FEEDBACK_OTHER_TARGET)):
            self._stats["foreign_frames"] += 1
            return None
        return bid

    def _check_frame(self, msg: can.Message, bid: BusId) -> tuple[int, int] | None:
        """A position reply's (puck, counts); None for a property reply; PuckFrameError if malformed."""
        if bid.target == FEEDBACK_POSITION_TARGET:
            return parse_position_reply(msg)
        reply = parse_property_reply(msg)
        if reply.prop == Prop.MODE and self._mode_sent_cycle is not None and not self.torque_mode_confirmed:
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
            except PuckFrameError as exc:
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
            except PuckFrameError as exc:
                garbage = str(exc)
                return True
            if reply is not None:
                puck, counts = reply
                self._counts[puck - 1] = counts
                got |= 1 << (puck - 1)
            return got == ALL_WAM_PUCKS

        recv_until(bus, deadline, handle)
        if garbage is not None:
            self._garbage(garbage)
        if got != ALL_WAM_PUCKS:
            missing = [i for i in WAM_PUCK_IDS if not got & (1 << (i - 1))]
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
        self._q[:] = counts_to_joint_rad(self._counts, self._cts, J2MP)
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
        self._tx_failures_pending = inject_fault(sim, f)

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
        now = sleep_until(deadline)
        self.timing.cycle_started(now, now - deadline)
