"""Serve the simulated WAM on any python-can bus, in its own process (``wamctl sim-arm``), so that a run in another
process talks to it as it will to the arm on the lab bus (e.g. over ``udp_multicast``).

The arm is the simulated plant of a spec (its ``robot``: the wam7's pucks 1-7 or the wam4's 1-4, its ``plant``,
``seed``, ``q0_rad`` and CAN ``physics_substeps``; the default plant without one) behind
:class:`~.simulator.PuckSimulator`: by default as just powered up (pucks in the monitor, encoders at arbitrary
offsets, not zeroed, the safety module idle), standing at the spec's start pose.
Before serving, the bus is probed: if a WAM (or another simulated one) already answers, nothing is served.
"""

from __future__ import annotations

import dataclasses
import logging
import signal
import threading
from pathlib import Path

import numpy as np

from wamctl.backends.can.bus_tools import open_bus, read_property
from wamctl.backends.can.protocol.addressing import SAFETY_PUCK_ID, WAM_PUCK_IDS
from wamctl.backends.can.protocol.configuration import FACTORY_GROUPS, GIMBALS_PUCK7_POLES, bus_arm
from wamctl.backends.can.protocol.properties import Prop
from wamctl.backends.can.sim.pendant import parse_pendant_script
from wamctl.errors import BackendError, SpecError

logger = logging.getLogger(__name__)

__all__ = ["ArmOptions", "serve_simulated_arm"]


@dataclasses.dataclass
class ArmOptions:
    """How the served arm is built (``wamctl sim-arm``'s options).

    Attributes
    ----------
    pose : str
        Where it stands: ``q0`` (the spec's start pose) or ``home`` (the zeroing pose).
    zeroed, awake : bool
        Already zeroed / pucks already awake (a second session of the day) instead of just powered up.
    pendant : str
        The pendant's script.
    joint_encoders, gimbals : bool
        6-byte position replies; puck 7 with POLES 8 (a gimbals arm, which the session must refuse).
    upper_group : int
        GRPC of pucks 5-7 (4 as Barrett and libbarrett; 5 as Barrett's 2008 manual, which must be refused).
    firmware : int or None
        VERS of the motor pucks (None: the simulator's).
    heartbeat_timeout_s : float
    realtime : bool
        The simulator's thread gets SCHED_FIFO (when permitted) and no garbage collection pauses.
    seed : int or None
        Encoder offsets (default: the spec's seed).
    """

    pose: str = "q0"
    zeroed: bool = False
    awake: bool = False
    pendant: str = "activate@1.0,idle@end"
    joint_encoders: bool = False
    gimbals: bool = False
    upper_group: int = 4
    firmware: int | None = None
    heartbeat_timeout_s: float = 0.5
    seed: int | None = None
    realtime: bool = True


def _check_bus_is_free(bus) -> None:
    found = read_property(bus, [*WAM_PUCK_IDS, SAFETY_PUCK_ID], Prop.STAT, 0.05, retries=1)
    if found:
        raise BackendError(f"nodes {sorted(found)} already answer on this bus (a real WAM or another simulated "
                           "one): a simulated arm must never answer next to them")


def serve_simulated_arm(interface: str, channel: str, bitrate: int = 1_000_000, *, bus_options: dict | None = None,
                        spec=None, base_dir: Path | None = None, options: ArmOptions | None = None,
                        stop: threading.Event | None = None, on_ready=None) -> dict:
    """Serve until ``stop`` is set (or Ctrl-C); return what the simulated arm saw (:meth:`PuckSimulator.describe`).

    Parameters
    ----------
    interface, channel, bitrate, bus_options
        The bus.
    spec : wamctl.specs.Common, optional
        Plant, seed, start pose and physics substeps of the simulated arm.
    base_dir : Path, optional
        Relative paths in the spec.
    options : ArmOptions
    stop : threading.Event, optional
    on_ready : callable, optional
        ``on_ready(text)`` once serving (one line saying what is served).
    """
    from wamctl.backends.can.sim.simulator import PuckSimulator
    from wamctl.backends.can.simulated_arm import build_simulated_arm
    from wamctl.specs.common import CanBackendSpec, Common

    o = options or ArmOptions()
    try:
        parse_pendant_script(o.pendant)
    except ValueError as exc:
        raise SpecError(f"--pendant: {exc}") from None
    if o.pose not in ("q0", "home"):
        raise SpecError(f"--pose: expected q0 or home, not {o.pose!r}")
    spec = spec or Common()
    robot = bus_arm(getattr(spec, "robot", None))
    if 7 not in robot.puck_ids and (o.gimbals or o.upper_group != 4):
        raise SpecError(f"--gimbals / --upper-group: pucks 5-7 are not on a {robot.name} bus")
    q0 = np.asarray(spec.q0_rad, float)
    substeps = spec.backend.physics_substeps if isinstance(spec.backend, CanBackendSpec) else 2
    arm, cts = build_simulated_arm(spec.plant, base_dir, robot.home_q_rad if o.pose == "home" else q0,
                                   np.random.default_rng(spec.seed), substeps, robot.name)
    bus = open_bus(interface, channel, bitrate, receive_own_messages=False, **(bus_options or {}))
    try:
        _check_bus_is_free(bus)
        sim = PuckSimulator(
            arm, bus=bus, cts=cts, start_awake=o.awake, zeroed=o.zeroed, joint_encoders=o.joint_encoders,
            pendant=o.pendant, start_pose_rad=q0, heartbeat_timeout_s=o.heartbeat_timeout_s, realtime=o.realtime,
            seed=spec.seed if o.seed is None else o.seed,
            groups=None if o.upper_group == 4 else {p: (FACTORY_GROUPS[p][0], FACTORY_GROUPS[p][1], o.upper_group)
                                                    for p in (5, 6, 7)},
            poles={7: GIMBALS_PUCK7_POLES} if o.gimbals else None,
            robot=robot.name, **({} if o.firmware is None else {"firmware_version": o.firmware}))
        arm.attach(sim)
        stop = stop or threading.Event()
        old = None
        if threading.current_thread() is threading.main_thread():  # SIGTERM stops the server as Ctrl-C does
            old = signal.signal(signal.SIGTERM, lambda *_: stop.set())
        with sim:
            if on_ready is not None:
                on_ready(f"simulated {robot.name} on {interface} {channel}: {robot.pucks_words()} "
                         f"{'awake' if o.awake else 'in the monitor'}, {'zeroed' if o.zeroed else 'not zeroed'}, at "
                         f"its {o.pose} pose, CTS {cts}, pendant {sim.pendant}")
            try:
                stop.wait()  # (interrupted by Ctrl-C; SIGTERM sets it)
            except KeyboardInterrupt:
                pass
            finally:
                if old is not None:
                    signal.signal(signal.SIGTERM, old)
            return sim.describe()
    finally:
        bus.shutdown()
