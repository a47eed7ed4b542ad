"""Bus tools shared by the CAN backend and ``wamctl bus-check``: open a bus, read a property from several
nodes, find the pucks, wake them as libbarrett does, and read what the session needs from the motor pucks
(:class:`PuckInfo`) and the safety module (:class:`SafetyInfo`).

Everything here is synchronous: it sends, then receives until the replies are in or a timeout passes.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from collections.abc import Callable, Iterable
from typing import Any

import can

from wamctl.backends.can.protocol.addressing import (
    FEEDBACK_OTHER_TARGET,
    FORCE_TORQUE_PUCK_ID,
    HAND_PUCK_IDS,
    MAX_CAN_ID,
    N_JOINTS,
    SAFETY_PUCK_ID,
    WAM_PUCK_IDS,
    PuckFrameError,
    decode_bus_id,
)
from wamctl.backends.can.protocol.configuration import WAM7_BUS, BusArm, configuration_problems
from wamctl.backends.can.protocol.properties import (
    MIN_FIRMWARE_VERSION,
    ROLE_MASK,
    ROLE_OPTICAL_ENC_ON_ENC,
    ROLE_SAFETY,
    ROLE_TATER,
    Mode,
    Prop,
    PropertyReply,
    Status,
    check_firmware_version,
    make_get_property,
    make_set_property,
    parse_property_reply,
)
from wamctl.backends.can.protocol.safety import (
    SAFETY_MIN_FIRMWARE_VERSION,
    SafetyMode,
    SafetyProp,
    decode_pen,
    velocity_limit_m_s,
)
from wamctl.errors import BackendError, ConfigurationRefused

logger = logging.getLogger(__name__)

__all__ = [
    "ALL_WAM_PUCKS",
    "PROBE_TIMEOUT_S",
    "PuckInfo",
    "SafetyInfo",
    "TX_TIMEOUT_S",
    "TURN_OFF_TIME_S",
    "WAKE_CHECK_S",
    "WAKE_UP_TIME_S",
    "check_motor_pucks",
    "open_bus",
    "probe_pucks",
    "read_property",
    "read_safety_module",
    "recv_until",
    "wake_pucks",
]

PROBE_TIMEOUT_S = 0.05  # wait for property replies at start-up (a puck answers in well under 1 ms)
TX_TIMEOUT_S = 0.005  # a send blocked longer (transmit queue full: bus-off, no ACK) is a transmit error
# libbarrett Puck::wake (puck.h, puck.cpp): STAT=READY to one puck at a time, TURN_OFF_TIME apart ("talking on
# the CANbus when a transceiver goes offline can also cause bus-off"), then WAKE_UP_TIME of silence, then a get
# of STAT per puck with a 50 ms wait ("pucks can take longer to respond when in the process of waking up").
TURN_OFF_TIME_S = 0.01
WAKE_UP_TIME_S = 1.0
WAKE_CHECK_S = 0.05
ALL_WAM_PUCKS = (1 << N_JOINTS) - 1  # bit i - 1 set: puck i answered
_NODE_KINDS = {**dict.fromkeys(WAM_PUCK_IDS, "wam motor"), FORCE_TORQUE_PUCK_ID: "force-torque sensor",
               SAFETY_PUCK_ID: "safety module", **dict.fromkeys(HAND_PUCK_IDS, "hand")}

Send = Callable[[can.Message], None]


def open_bus(interface: str, channel: str, bitrate: int, **kwargs: Any) -> can.BusABC:
    """Open a python-can bus; an unavailable interface or channel becomes a :class:`BackendError`.

    Parameters
    ----------
    interface, channel : str
        python-can interface (``socketcan``, ``pcan``, ``virtual``, ``udp_multicast``, ...) and channel.
    bitrate : int
        Bit/s (ignored by interfaces configured outside the process, e.g. SocketCAN, and by ``virtual``).
    **kwargs
        Passed to :class:`can.Bus` (e.g. ``can_filters``, ``port``).
    """
    try:
        return can.Bus(interface=interface, channel=channel, bitrate=bitrate, **kwargs)
    except (can.CanError, OSError, ImportError, ValueError, NotImplementedError, TypeError) as exc:
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


def _default_send(bus: can.BusABC) -> Send:
    return lambda msg: bus.send(msg, timeout=TX_TIMEOUT_S)


def read_property(bus: can.BusABC, ids: Iterable[int], prop: int, timeout_s: float = PROBE_TIMEOUT_S,
                  retries: int = 1, send: Send | None = None) -> dict[int, int]:
    """Get one property from several nodes (one get each), collecting the replies.

    Frames already waiting when it is called are discarded first (replies to earlier requests must not pass
    for answers).

    Returns
    -------
    dict of int to int
        Value per node that answered (nodes that did not are absent).
    """
    wanted = list(dict.fromkeys(int(i) for i in ids))
    send = send or _default_send(bus)
    out: dict[int, int] = {}
    while bus.recv(timeout=0.0) is not None:
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


def set_and_confirm(bus: can.BusABC, node: int, prop: int, value: int, send: Send | None = None,
                    timeout_s: float = PROBE_TIMEOUT_S) -> None:
    """A set followed by a get of STAT that must be answered (libbarrett's blocking ``setProperty``: "so we
    don't overflow the Puck's receive buffer"); raises :class:`BackendError` if the node does not answer."""
    send = send or _default_send(bus)
    send(make_set_property(node, prop, value))
    if node not in read_property(bus, [node], Prop.STAT, timeout_s, retries=1, send=send):
        raise BackendError(f"node {node} did not answer after a set of property {prop}")


# ------------------------------------------------------------------------------------------- motor pucks

@dataclasses.dataclass
class PuckInfo:
    """What start-up (and ``bus-check``) learns about one node.

    Attributes
    ----------
    puck_id : int
    stat : int
        STAT (0 monitor, 2 ready).
    vers, role, sn : int or None
        Firmware version, role, serial number.
    cts, ipnm, pidx, poles, mode : int or None
        Motor pucks (1..7) awake with supported firmware only.
    groups : (int, int, int) or None
        GRPA, GRPB, GRPC (motor pucks awake with supported firmware).
    """

    puck_id: int
    stat: int
    vers: int | None = None
    role: int | None = None
    sn: int | None = None
    cts: int | None = None
    ipnm: int | None = None
    pidx: int | None = None
    poles: int | None = None
    mode: int | None = None
    groups: tuple[int, int, int] | None = None

    @property
    def kind(self) -> str:
        return _NODE_KINDS.get(self.puck_id, "unknown node")

    @property
    def firmware_ok(self) -> bool:
        """Whether a motor puck's firmware uses the property ids of :class:`~.protocol.properties.Prop`."""
        return self.vers is not None and self.vers >= MIN_FIRMWARE_VERSION

    @property
    def joint_encoder(self) -> bool:
        """The puck reports a joint encoder (6-byte position replies)."""
        return self.role is not None and bool(self.role & ROLE_OPTICAL_ENC_ON_ENC)

    def to_dict(self) -> dict:
        d = dataclasses.asdict(self)
        d.update(kind=self.kind, stat_name=_enum_name(Status, self.stat),
                 mode_name=None if self.mode is None else _enum_name(Mode, self.mode))
        if self.puck_id in WAM_PUCK_IDS:
            d.update(firmware_ok=self.firmware_ok, joint_encoder=self.joint_encoder)
        return d


def _enum_name(enum_cls, value: int | None) -> str | None:
    try:
        return enum_cls(value).name
    except ValueError:
        return str(value)


def check_motor_pucks(found: dict[int, PuckInfo], arm: BusArm = WAM7_BUS) -> None:
    """Refuse the arm's pucks (default the wam7's, 1-7) the backend cannot drive or the model does not describe.

    Raises
    ------
    BackendError
        If a puck did not wake, has firmware older than :data:`~.properties.MIN_FIRMWARE_VERSION` (naming the
        ids it uses), is not a motor puck, did not report CTS, IPNM or PIDX, reports a CTS or IPNM that is not
        positive, or the arm is not the one expected in its groups (a wam7 with wrist in groups 1/2/4, not gimbals
        or pucks 5-7 in group 5; a wam4 in groups 1/4).
    """
    for i, info in found.items():
        if info.stat != Status.READY:
            raise BackendError(f"puck {i} did not wake up (STAT={info.stat})")
        check_firmware_version(i, info.vers if info.vers is not None else -1)
        if info.role is not None and (info.role & ROLE_MASK) != ROLE_TATER:
            raise ConfigurationRefused(f"puck {i}: ROLE={info.role} is not a WAM motor puck (low five bits 0)")
        for name in ("cts", "ipnm", "pidx"):
            if getattr(info, name) is None:
                raise BackendError(f"puck {i} did not report {name.upper()}")
        if info.cts <= 0 or info.ipnm <= 0:
            raise BackendError(f"puck {i}: CTS={info.cts}, IPNM={info.ipnm} must be positive")
    problems = configuration_problems({i: p.groups for i, p in found.items() if p.groups is not None},
                                      {i: p.poles for i, p in found.items() if p.poles is not None}, arm)
    if problems:
        raise ConfigurationRefused("the arm is not the one wamctl's model describes: " + "; ".join(problems))


def wake_pucks(bus: can.BusABC, ids: Iterable[int], send: Send | None = None,
               sleep: Callable[[float], None] = time.sleep) -> None:
    """Wake pucks in the monitor as libbarrett's ``Puck::wake`` does.

    STAT=READY to each puck, one at a time, :data:`TURN_OFF_TIME_S` apart; then :data:`WAKE_UP_TIME_S` during
    which nothing at all is sent (a frame while a transceiver comes back can put the host bus-off); then per
    puck a get of STAT answered within :data:`WAKE_CHECK_S` with READY.

    Raises
    ------
    BackendError
        Naming the puck that did not wake (libbarrett's "Failed to wake Puck").
    """
    ids = list(ids)
    if not ids:
        return
    send = send or _default_send(bus)
    logger.info("waking pucks %s (%.0f ms apart, then %.1f s of silence)", ids, TURN_OFF_TIME_S * 1e3,
                WAKE_UP_TIME_S)
    for i in ids:
        send(make_set_property(i, Prop.STAT, Status.READY))
        sleep(TURN_OFF_TIME_S)
    sleep(WAKE_UP_TIME_S)
    for i in ids:
        stat = read_property(bus, [i], Prop.STAT, WAKE_CHECK_S, retries=0, send=send).get(i)
        if stat is None:
            raise BackendError(f"puck {i} did not answer after waking ({WAKE_UP_TIME_S:.2f} s): is the bus quiet "
                               "(talking while pucks wake can put the host bus-off) and the puck powered?")
        if stat != Status.READY:
            raise BackendError(f"puck {i} failed to wake: STAT={stat}")


def probe_pucks(bus: can.BusABC, ids: Iterable[int] = WAM_PUCK_IDS, *, wake: bool = True,
                timeout_s: float = PROBE_TIMEOUT_S, send: Send | None = None,
                sleep: Callable[[float], None] = time.sleep) -> dict[int, PuckInfo]:
    """Find the nodes answering on the bus, wake WAM pucks left in the monitor, read their properties.

    Parameters
    ----------
    bus : can.BusABC
    ids : iterable of int
        Node ids to probe (a get of STAT each; the monitor answers it too).
    wake : bool
        Wake WAM pucks found in the monitor (:func:`wake_pucks`: needed to read CTS, IPNM, PIDX, POLES, the
        groups and MODE); a woken puck is left idle.
    timeout_s : float
        Reply timeout per request.
    send, sleep : callable, optional
        Transmit (default ``bus.send``) and wait (default ``time.sleep``).

    Returns
    -------
    dict of int to PuckInfo
        The nodes that answered, by id. Motor pucks (1..7) awake with firmware >= 65 carry CTS, IPNM, PIDX,
        POLES, groups and MODE.
    """
    send = send or _default_send(bus)
    stat = read_property(bus, ids, Prop.STAT, timeout_s, send=send)
    found = {i: PuckInfo(i, s) for i, s in sorted(stat.items())}
    asleep = [i for i, info in found.items() if info.stat != Status.READY and i in WAM_PUCK_IDS]
    if wake and asleep:
        wake_pucks(bus, asleep, send, sleep)
        for i in asleep:
            found[i].stat = int(Status.READY)
    ids_found = list(found)
    for field, prop in (("vers", Prop.VERS), ("role", Prop.ROLE), ("sn", Prop.SN)):
        for i, v in read_property(bus, ids_found, prop, timeout_s, send=send).items():
            setattr(found[i], field, v)
    motors = [i for i in ids_found if i in WAM_PUCK_IDS and found[i].stat == Status.READY
              and found[i].firmware_ok]
    for field, prop in (("cts", Prop.CTS), ("ipnm", Prop.IPNM), ("pidx", Prop.PIDX), ("poles", Prop.POLES),
                        ("mode", Prop.MODE)):
        for i, v in read_property(bus, motors, prop, timeout_s, send=send).items():
            setattr(found[i], field, v)
    grp = {p: read_property(bus, motors, p, timeout_s, send=send) for p in (Prop.GRPA, Prop.GRPB, Prop.GRPC)}
    for i in motors:
        if all(i in grp[p] for p in grp):
            found[i].groups = tuple(grp[p][i] for p in (Prop.GRPA, Prop.GRPB, Prop.GRPC))
    return found


# -------------------------------------------------------------------------------------- the safety module

@dataclasses.dataclass
class SafetyInfo:
    """What the session and ``bus-check`` read from the safety module (node 10).

    Attributes
    ----------
    vers, role : int or None
    mode : int or None
        :class:`~.protocol.safety.SafetyMode` (0 E-stop, 1 idle, 2 active).
    zero : int or None
        1 when the arm has been zeroed since power-up.
    pen : int or None
        Raw pendant state (:func:`~.protocol.safety.decode_pen`).
    limits : dict of str to int
        VL1, VL2, TL1, TL2 as read.
    groups : (int, int, int) or None
    """

    vers: int | None = None
    role: int | None = None
    mode: int | None = None
    zero: int | None = None
    pen: int | None = None
    limits: dict = dataclasses.field(default_factory=dict)
    groups: tuple[int, int, int] | None = None

    @property
    def firmware_ok(self) -> bool:
        return self.vers is not None and self.vers >= SAFETY_MIN_FIRMWARE_VERSION

    @property
    def is_safety_module(self) -> bool:
        return self.role is not None and (self.role & ROLE_MASK) == ROLE_SAFETY

    @property
    def zeroed(self) -> bool:
        return self.zero == 1

    def mode_words(self) -> str:
        try:
            return SafetyMode(self.mode).words
        except (TypeError, ValueError):
            return "unknown" if self.mode is None else f"MODE {self.mode}"

    def to_dict(self) -> dict:
        d = dataclasses.asdict(self)
        d.update(firmware_ok=self.firmware_ok, mode_name=self.mode_words(), zeroed=self.zeroed)
        try:
            pen = decode_pen(self.pen) if self.pen is not None else None
        except PuckFrameError as exc:
            d["pendant"] = str(exc)
        else:
            d["pendant"] = None if pen is None else {"summary": pen.summary(), "faults": pen.faults(),
                                                     "warnings": pen.warnings()}
        if "VL1" in self.limits and "VL2" in self.limits:
            d["velocity_limits_m_s"] = {k: velocity_limit_m_s(self.limits[k]) for k in ("VL1", "VL2")}
        return d


def read_safety_module(bus: can.BusABC, send: Send | None = None,
                       timeout_s: float = PROBE_TIMEOUT_S) -> SafetyInfo | None:
    """Read node 10 (None if it does not answer): VERS, ROLE, then, with firmware >= 61, MODE, ZERO, PEN, the
    limits and the groups."""
    send = send or _default_send(bus)

    def get(prop: int) -> int | None:
        return read_property(bus, [SAFETY_PUCK_ID], prop, timeout_s, send=send).get(SAFETY_PUCK_ID)

    vers = get(SafetyProp.VERS)
    if vers is None:
        return None
    info = SafetyInfo(vers=vers, role=get(SafetyProp.ROLE))
    if not (info.firmware_ok and info.is_safety_module):
        return info
    info.mode, info.zero, info.pen = get(SafetyProp.MODE), get(SafetyProp.ZERO), get(SafetyProp.PEN)
    for name in ("VL1", "VL2", "TL1", "TL2"):
        v = get(SafetyProp[name])
        if v is not None:
            info.limits[name] = v
    grp = [get(p) for p in (SafetyProp.GRPA, SafetyProp.GRPB, SafetyProp.GRPC)]
    info.groups = None if None in grp else tuple(grp)
    return info
