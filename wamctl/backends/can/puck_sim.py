"""Simulated WAM motor pucks answering on a python-can bus, driven by a plant through callbacks.

:class:`PuckSimulator` listens on a bus (by default python-can's ``virtual`` interface) in a background
thread and behaves like pucks 1..7 of a WAM as far as wamctl's CAN backend needs: it answers property
gets (VERS, ROLE, SN, ID, ERROR, STAT, MODE, CTS, IPNM, PIDX, P, T and anything set before), accepts
sets (MODE, STAT to wake, P to define the position, T, ...), answers the whole-WAM position request
(``[48]`` to group 0x404) with one 22-bit reply per puck, and turns the two packed-torque frames (0x401,
0x402) into a joint torque vector handed to the plant.

The physics stays outside: a :class:`PlantAdapter` supplies joint angles and receives joint torques.
:class:`StaticPlant` is a minimal adapter for tests and demos.

Fault injection (for the link watchdog tests): drop replies (with a probability, optionally only after
a time), silent pucks, malformed ("garbage") frames and stop answering altogether; see
:meth:`PuckSimulator.drop_replies` and the methods after it. Counters in :class:`SimStats` make the
faults observable.

Conventions: as in :mod:`wamctl.backends.can.protocol` (pucks 1..7 on the bus, arrays indexed 0..6, SI
units in names). The callbacks run on the simulator's thread: ``joint_positions_rad()`` once per
position request (so a plant may advance its integration there), ``apply_joint_torques_Nm(tau)`` after
every torque update (packed-torque frame, T set, or MODE change), with the torques every puck holds.
Pucks out of TORQUE mode hold zero torque, as real pucks ignore torque commands when idle.
"""

from __future__ import annotations

import dataclasses
import logging
import random
import threading
import time
from collections.abc import Iterable
from typing import Protocol, runtime_checkable

import can
import numpy as np

from wamctl.backends.can.protocol.addressing import (
    DEFAULT_PIDX,
    FEEDBACK_OTHER,
    FEEDBACK_POSITION,
    FEEDBACK_POSITION_TARGET,
    GROUP_FLAG,
    GROUP_WAM,
    GROUP_WHOLE_BUS,
    N_JOINTS,
    TORQUE_GROUPS,
    WAM_PUCK_IDS,
    BusId,
    PuckFrameError,
    decode_bus_id,
    encode_bus_id,
)
from wamctl.backends.can.protocol.positions import POSITION_MAX_COUNTS, POSITION_MIN_COUNTS, make_position_reply
from wamctl.backends.can.protocol.properties import (
    CTS_DEFAULT,
    Mode,
    Prop,
    Status,
    make_property_reply,
    parse_host_property_message,
)
from wamctl.backends.can.protocol.torques import (
    IPNM_DEFAULT,
    PACKED_TORQUE_HEADER,
    puck_units_to_joint_torque_Nm,
    saturate_puck_units,
    unpack_torques,
)
from wamctl.model.transmission import J2MP, joint_rad_to_counts, load_kernels

logger = logging.getLogger(__name__)

__all__ = ["PlantAdapter", "PuckSimulator", "SimStats", "StaticPlant", "SIM_FIRMWARE_VERSION"]

# Firmware version the simulated pucks report: arbitrary, at or above the newest property table in
# libbarrett (motor pucks VERS >= 145) so every id in properties.Prop applies.
SIM_FIRMWARE_VERSION = 200
_ROLE_MOTOR = 0  # puck.h ROLE_TATER in the low five bits, no options (optical encoder)
_MODE_VALUES = frozenset(int(m) for m in Mode)
_MONITOR_PROPS = frozenset({Prop.VERS, Prop.ROLE, Prop.SN, Prop.ID, Prop.ERROR, Prop.STAT})


@runtime_checkable
class PlantAdapter(Protocol):
    """What the simulated pucks need from the simulated arm.

    Both methods are called from the simulator's thread.
    """

    def joint_positions_rad(self) -> np.ndarray:
        """Return the current joint angles, shape (7,), rad. Called once per position request."""
        ...

    def apply_joint_torques_Nm(self, tau: np.ndarray) -> None:
        """Receive the joint torques (7,), N m, that the pucks now apply (held until the next call)."""
        ...


class StaticPlant:
    """A plant that does not move: fixed joint angles, records the torques it receives.

    Parameters
    ----------
    q_rad : array_like, shape (7,), optional
        Joint angles reported to the pucks; default zeros. May be reassigned at any time.
    """

    def __init__(self, q_rad: np.ndarray | None = None) -> None:
        self.q_rad = np.zeros(N_JOINTS) if q_rad is None else np.asarray(q_rad, dtype=float).copy()
        self.tau_Nm = np.zeros(N_JOINTS)
        self.n_position_reads = 0
        self.n_torque_updates = 0
        self._lock = threading.Lock()

    def joint_positions_rad(self) -> np.ndarray:
        """Return the fixed joint angles (rad)."""
        with self._lock:
            self.n_position_reads += 1
            return np.array(self.q_rad, dtype=float)

    def apply_joint_torques_Nm(self, tau: np.ndarray) -> None:
        """Record the applied joint torques (N m)."""
        with self._lock:
            self.tau_Nm = np.array(tau, dtype=float)
            self.n_torque_updates += 1


@dataclasses.dataclass
class SimStats:
    """Counters of what the simulated pucks saw and did (a snapshot; see :attr:`PuckSimulator.stats`)."""

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


@dataclasses.dataclass
class _Puck:
    puck_id: int
    props: dict[int, int]
    torque_group: int
    wake_at: float | None  # monotonic time the puck becomes READY; None = asleep (monitor)
    offset_counts: int = 0  # set by "define position" (a set of P)
    torque_units: int = 0  # held torque command


class PuckSimulator:
    """Simulated pucks 1..7 of a WAM on a python-can bus.

    Parameters
    ----------
    plant : PlantAdapter
        Supplies joint angles, receives joint torques.
    bus : can.BusABC, optional
        Bus to listen on. If None, one is opened with ``interface`` and ``channel`` and closed by
        :meth:`shutdown`; a bus passed in is left open.
    channel : str, default "wam-test"
        Channel for the bus opened when ``bus`` is None.
    interface : str, default "virtual"
        python-can interface for that bus.
    cts : int or sequence of int, default 4096
        CTS per puck.
    ipnm : int or sequence of int, default 2700
        IPNM per puck.
    pidx : dict of int to int, optional
        PIDX per puck id; default :data:`~wamctl.backends.can.protocol.addressing.DEFAULT_PIDX`.
    firmware_version : int, default :data:`SIM_FIRMWARE_VERSION`
        VERS reported by every puck.
    start_awake : bool, default True
        If False the pucks start in the monitor (STAT=0) and must be woken by a set of STAT=2.
    wake_delay_s : float, default 0.0
        Time between the STAT=2 set and the puck answering as READY.
    j2mp : numpy.ndarray, default :data:`~wamctl.model.transmission.J2MP`
        Transmission used to turn joint angles into counts and puck torques into joint torques.
    seed : int, optional
        Seed of the fault-injection random generator.
    poll_timeout_s : float, default 0.01
        Receive timeout of the listening thread (bounds the shutdown latency).

    Examples
    --------
    >>> plant = StaticPlant()
    >>> with PuckSimulator(plant, channel="demo") as sim:  # doctest: +SKIP
    ...     ...  # talk to the pucks from another bus on channel "demo"
    """

    def __init__(
        self,
        plant: PlantAdapter,
        *,
        bus: can.BusABC | None = None,
        channel: str = "wam-test",
        interface: str = "virtual",
        cts: int | Iterable[int] = CTS_DEFAULT,
        ipnm: int | Iterable[int] = IPNM_DEFAULT,
        pidx: dict[int, int] | None = None,
        firmware_version: int = SIM_FIRMWARE_VERSION,
        start_awake: bool = True,
        wake_delay_s: float = 0.0,
        j2mp: np.ndarray = J2MP,
        seed: int | None = None,
        poll_timeout_s: float = 0.01,
    ) -> None:
        self._plant = plant
        self._j2mp = np.asarray(j2mp, dtype=float)
        self._cts = np.broadcast_to(np.asarray(cts, dtype=np.int64), (N_JOINTS,)).copy()
        self._ipnm = np.broadcast_to(np.asarray(ipnm, dtype=np.int64), (N_JOINTS,)).copy()
        if np.any(self._cts <= 0) or np.any(self._ipnm <= 0):
            raise ValueError("CTS and IPNM must be positive")
        # load (or compile) the transmission's numba kernels now, not within the first position request's
        # reply deadline
        load_kernels()
        joint_rad_to_counts(np.zeros(N_JOINTS), self._cts, self._j2mp)
        pidx_map = dict(DEFAULT_PIDX if pidx is None else pidx)
        self._wake_delay_s = float(wake_delay_s)
        now = time.monotonic()
        self._pucks: dict[int, _Puck] = {}
        for i, puck_id in enumerate(WAM_PUCK_IDS):
            group = next(g for g, members in TORQUE_GROUPS.items() if puck_id in members)
            props = {
                Prop.VERS: int(firmware_version),
                Prop.ROLE: _ROLE_MOTOR,
                Prop.SN: 1000 + puck_id,
                Prop.ID: puck_id,
                Prop.ERROR: 0,
                Prop.STAT: Status.READY if start_awake else Status.RESET,
                Prop.MODE: Mode.IDLE,
                Prop.CTS: int(self._cts[i]),
                Prop.IPNM: int(self._ipnm[i]),
                Prop.PIDX: int(pidx_map.get(puck_id, 0)),
                Prop.T: 0,
            }
            self._pucks[puck_id] = _Puck(puck_id, {int(k): int(v) for k, v in props.items()}, group,
                                         now if start_awake else None)

        self._owns_bus = bus is None
        if bus is None:
            bus = can.Bus(interface=interface, channel=channel, receive_own_messages=False)
        self._bus = bus
        self._poll_timeout_s = float(poll_timeout_s)
        self._rng = random.Random(seed)
        self._lock = threading.Lock()
        self._stats = SimStats()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._closed = False
        self._t0 = time.monotonic()
        # fault switches
        self._drop_probability = 0.0
        self._drop_after_s: float | None = None
        self._garbage_probability = 0.0
        self._silent: set[int] = set()
        self._answering = True

    # ------------------------------------------------------------------ lifecycle

    def start(self) -> PuckSimulator:
        """Start the listening thread (no-op if running). Fault times count from here.

        Returns
        -------
        PuckSimulator
            ``self``.
        """
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
        logger.debug("puck simulator shut down")

    def __enter__(self) -> PuckSimulator:
        return self.start()

    def __exit__(self, *exc_info: object) -> None:
        self.shutdown()

    @property
    def running(self) -> bool:
        """Whether the listening thread is alive."""
        return self._thread is not None and self._thread.is_alive()

    def elapsed_s(self) -> float:
        """Seconds since :meth:`start` (or construction if not started)."""
        return time.monotonic() - self._t0

    # ------------------------------------------------------------------ fault injection

    def drop_replies(self, probability: float = 1.0, *, after_s: float | None = None) -> None:
        """Drop replies (position and property) at random.

        Parameters
        ----------
        probability : float, default 1.0
            Chance of dropping each reply; 0 turns dropping off.
        after_s : float, optional
            Only drop once :meth:`elapsed_s` has reached this time.
        """
        if not 0.0 <= probability <= 1.0:
            raise ValueError(f"probability must be in [0, 1], got {probability}")
        self._drop_probability = float(probability)
        self._drop_after_s = None if after_s is None else float(after_s)

    def set_silent(self, puck_id: int, silent: bool = True) -> None:
        """Make a puck silent (it neither answers nor obeys, like a puck off the bus) or bring it back.

        Parameters
        ----------
        puck_id : int
            Puck 1..7.
        silent : bool, default True
        """
        if puck_id not in self._pucks:
            raise ValueError(f"no simulated puck {puck_id}")
        if silent:
            self._silent.add(puck_id)
        else:
            self._silent.discard(puck_id)

    def inject_garbage(self, probability: float) -> None:
        """Replace each reply, with this probability, by a malformed frame (same id, wrong length).

        Parameters
        ----------
        probability : float
            0 turns it off.
        """
        if not 0.0 <= probability <= 1.0:
            raise ValueError(f"probability must be in [0, 1], got {probability}")
        self._garbage_probability = float(probability)

    def send_garbage(self, count: int = 1) -> None:
        """Send ``count`` malformed frames now: puck -> feedback group frames of the wrong length.

        Parameters
        ----------
        count : int, default 1
        """
        for _ in range(count):
            puck_id = self._rng.choice(WAM_PUCK_IDS)
            group = self._rng.choice((FEEDBACK_POSITION, FEEDBACK_OTHER))
            self._send(self._garble(encode_bus_id(puck_id, group)), counter="garbage_sent")

    def stop_answering(self) -> None:
        """Stop sending anything (commands are still obeyed)."""
        self._answering = False

    def resume_answering(self) -> None:
        """Undo :meth:`stop_answering`."""
        self._answering = True

    def clear_faults(self) -> None:
        """Turn every fault off."""
        self._drop_probability = 0.0
        self._drop_after_s = None
        self._garbage_probability = 0.0
        self._silent.clear()
        self._answering = True

    # ------------------------------------------------------------------ inspection

    @property
    def stats(self) -> SimStats:
        """A copy of the counters."""
        with self._lock:
            return dataclasses.replace(self._stats)

    def property_value(self, puck_id: int, prop: int) -> int | None:
        """Value of a puck's property as the simulator holds it (None if never set)."""
        with self._lock:
            return self._pucks[puck_id].props.get(int(prop))

    def modes(self) -> dict[int, int]:
        """MODE of every puck, by puck id."""
        with self._lock:
            return {pid: p.props[Prop.MODE] for pid, p in self._pucks.items()}

    def puck_torque_units(self) -> np.ndarray:
        """Torque commands the pucks hold, puck units, shape (7,) (zero for pucks not in TORQUE mode)."""
        with self._lock:
            return np.array([self._pucks[p].torque_units for p in WAM_PUCK_IDS], dtype=np.int64)

    def joint_torques_Nm(self) -> np.ndarray:
        """Joint torques the held puck commands produce, N m, shape (7,)."""
        return puck_units_to_joint_torque_Nm(self.puck_torque_units(), self._ipnm, self._j2mp)

    # ------------------------------------------------------------------ thread

    def _run(self) -> None:
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
            if msg is None:
                continue
            try:
                self._handle(msg)
            except Exception:  # noqa: BLE001 - a plant or protocol bug must not kill the pucks silently
                logger.exception("puck simulator: handling %s failed", msg)
                self._count("handler_errors")
            finally:
                self._count("frames_handled")

    def _count(self, name: str, n: int = 1) -> None:
        with self._lock:
            setattr(self._stats, name, getattr(self._stats, name) + n)

    def _awake(self, puck: _Puck) -> bool:
        if puck.wake_at is None or time.monotonic() < puck.wake_at:
            return False
        if puck.props[Prop.STAT] != Status.READY:
            puck.props[Prop.STAT] = int(Status.READY)
        return True

    def _addressed(self, bid: BusId) -> list[_Puck]:
        if bid.is_group:
            group = GROUP_FLAG | bid.target
            if group in (GROUP_WHOLE_BUS, GROUP_WAM):
                ids: Iterable[int] = WAM_PUCK_IDS
            elif group in TORQUE_GROUPS:
                ids = TORQUE_GROUPS[group]
            else:
                ids = ()  # feedback groups and groups without WAM pucks
        else:
            ids = (bid.target,) if bid.target in self._pucks else ()
        return [self._pucks[i] for i in ids if i not in self._silent]

    def _handle(self, msg: can.Message) -> None:
        self._count("frames_received")
        if msg.is_error_frame or msg.is_remote_frame or msg.is_extended_id:
            self._count("ignored_frames")
            return
        bid = decode_bus_id(msg.arbitration_id)
        pucks = self._addressed(bid)
        if not pucks:
            self._count("ignored_frames")
            return
        data = bytes(msg.data)
        group = GROUP_FLAG | bid.target if bid.is_group else None
        if group in TORQUE_GROUPS and data[:1] == bytes([PACKED_TORQUE_HEADER]):
            self._on_packed_torques(pucks, data)
            return
        try:
            is_set, prop, value = parse_host_property_message(data)
        except PuckFrameError as exc:
            logger.debug("puck simulator: ignoring %s (%s)", msg, exc)
            self._count("ignored_frames")
            return
        if is_set:
            assert value is not None
            self._on_set(pucks, prop, value)
        elif prop == Prop.P:
            self._on_position_request(pucks)
        else:
            self._on_get(pucks, prop)

    def _on_get(self, pucks: list[_Puck], prop: int) -> None:
        self._count("property_gets")
        for puck in pucks:
            with self._lock:
                awake = self._awake(puck)
                value = puck.props.get(prop)
            if value is None or (not awake and prop not in _MONITOR_PROPS):
                logger.debug("puck %d: no answer to a get of property %d", puck.puck_id, prop)
                continue
            self._reply(make_property_reply(puck.puck_id, prop, value))

    def _raw_counts(self) -> np.ndarray:
        q_rad = np.asarray(self._plant.joint_positions_rad(), dtype=float).reshape(N_JOINTS)
        return joint_rad_to_counts(q_rad, self._cts, self._j2mp)

    def _on_position_request(self, pucks: list[_Puck]) -> None:
        self._count("position_requests")
        with self._lock:
            awake = [p for p in pucks if self._awake(p)]
        if not awake:
            return
        counts = self._raw_counts()
        for puck in awake:
            c = int(counts[puck.puck_id - 1]) + puck.offset_counts
            if not POSITION_MIN_COUNTS <= c <= POSITION_MAX_COUNTS:
                logger.warning("puck %d: %d counts overflow 22 bits; the reply wraps", puck.puck_id, c)
            self._reply(make_position_reply(puck.puck_id, c, wrap=True))

    def _on_set(self, pucks: list[_Puck], prop: int, value: int) -> None:
        self._count("property_sets")
        torque_changed = False
        raw_counts = self._raw_counts() if prop == Prop.P else None
        with self._lock:
            for puck in pucks:
                if prop == Prop.STAT:
                    if value == Status.READY and puck.wake_at is None:
                        puck.wake_at = time.monotonic() + self._wake_delay_s
                    elif value == Status.RESET:
                        puck.wake_at = None
                        puck.props[Prop.STAT] = int(Status.RESET)
                    continue
                if not self._awake(puck):
                    continue
                if prop == Prop.MODE:
                    if value not in _MODE_VALUES:
                        logger.debug("puck %d: ignoring MODE=%d", puck.puck_id, value)
                        continue
                    puck.props[prop] = value
                    if value != Mode.TORQUE and puck.torque_units != 0:
                        puck.torque_units = 0
                        torque_changed = True
                elif prop == Prop.T:
                    torque_changed |= self._hold_torque(puck, value)
                elif prop == Prop.P:
                    assert raw_counts is not None
                    puck.offset_counts = value - int(raw_counts[puck.puck_id - 1])
                    puck.props[prop] = value
                else:
                    puck.props[prop] = value
        if torque_changed:
            self._apply_torques()

    def _hold_torque(self, puck: _Puck, units: int) -> bool:
        """Set a puck's held torque (lock held); return whether it changed."""
        new = int(saturate_puck_units(units)) if puck.props[Prop.MODE] == Mode.TORQUE else 0
        puck.props[Prop.T] = new
        changed = new != puck.torque_units
        puck.torque_units = new
        return changed

    def _on_packed_torques(self, pucks: list[_Puck], data: bytes) -> None:
        try:
            values = unpack_torques(data)
        except PuckFrameError as exc:
            logger.debug("puck simulator: bad packed-torque frame (%s)", exc)
            self._count("ignored_frames")
            return
        self._count("torque_frames")
        with self._lock:
            for puck in pucks:
                slot = puck.props.get(Prop.PIDX, 0)
                if self._awake(puck) and 1 <= slot <= values.size:
                    self._hold_torque(puck, int(values[slot - 1]))
        # apply after every frame: the plant sees the torques every puck holds now
        self._apply_torques()

    def _apply_torques(self) -> None:
        self._plant.apply_joint_torques_Nm(self.joint_torques_Nm())

    # ------------------------------------------------------------------ sending

    def _garble(self, arbitration_id: int) -> can.Message:
        bid = decode_bus_id(arbitration_id)
        valid = (3, 6) if bid.target == FEEDBACK_POSITION_TARGET else (4, 6)
        length = self._rng.choice([n for n in range(9) if n not in valid])
        data = bytes(self._rng.getrandbits(8) for _ in range(length))
        return can.Message(arbitration_id=arbitration_id, data=data, is_extended_id=False)

    def _reply(self, msg: can.Message) -> None:
        if not self._answering:
            self._count("replies_dropped")
            return
        dropping = self._drop_probability > 0.0 and (
            self._drop_after_s is None or self.elapsed_s() >= self._drop_after_s
        )
        if dropping:
            if self._drop_probability >= 1.0 or self._rng.random() < self._drop_probability:
                self._count("replies_dropped")
                return
        if self._garbage_probability > 0.0 and self._rng.random() < self._garbage_probability:
            self._send(self._garble(msg.arbitration_id), counter="replies_garbled")
            return
        self._send(msg, counter="replies_sent")

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
