"""Period jitter and overruns of the CAN backend's 500 Hz loop on python-can's virtual bus.

The whole CAN path in one process: the engine's loop (PD + gravity, holding the arm at q0 with the joint-2
and joint-4 references swaying 0.05 rad so the torques change every cycle) on a :class:`CanBackend`
against simulated pucks driven by the simulated arm (physics on the puck simulator's thread). Reports the
period between cycle starts (p50, p99, max), the jitter ``|period - 2 ms|``, the wake-up lateness after each
release point, each cycle's busy time (position request to the wait), overruns and skipped periods, missed
or late position replies, and the bus load the loop puts on a 1 Mbit/s bus.

    python benchmarks/bench_can_loop.py [--duration 30] [--reply-timeout 0.005] [--watchdog 50]

The figures depend on the machine's load (this is not a real-time kernel); nothing is asserted.
"""

from __future__ import annotations

import argparse
import os
import time
import uuid

import numpy as np

from wamctl.backends import make_backend
from wamctl.control.trajectory import Reference
from wamctl.experiments.common import make_joint_controller
from wamctl.experiments.engine import LoopRecorder, run_loop
from wamctl.model import params as P
from wamctl.specs import parse_spec

Q0 = [0.0, 0.0, 0.0, 1.57, 0.0, 0.0, 0.0]


def sway_reference(duration_s: float) -> Reference:
    """q0 with joints 2 and 4 swaying +-0.05 rad at 0.5 Hz (the torque changes every cycle)."""
    dt = 1.0 / P.CONTROL_RATE_HZ
    t = np.arange(int(round(duration_s / dt))) * dt
    w = 2 * np.pi * 0.5
    q = np.tile(np.asarray(Q0), (t.size, 1))
    qd = np.zeros_like(q)
    qdd = np.zeros_like(q)
    for j in (1, 3):
        q[:, j] += 0.05 * np.sin(w * t)
        qd[:, j] = 0.05 * w * np.cos(w * t)
        qdd[:, j] = -0.05 * w * w * np.sin(w * t)
    return Reference(t, q, qd, qdd, [(0, "sway")])


def ms(x) -> str:
    return "n/a" if x is None else f"{x * 1e3:7.3f} ms"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=30.0, help="seconds of loop (default 30)")
    ap.add_argument("--reply-timeout", type=float, default=0.005, help="position reply timeout, s")
    ap.add_argument("--watchdog", type=int, default=50, help="missing-reply cycles tolerated")
    args = ap.parse_args()
    spec = parse_spec({
        "kind": "rotation", "name": "bench-can", "seed": 0, "q0_rad": Q0,
        "backend": {"kind": "can", "interface": "virtual", "channel": f"bench-{uuid.uuid4().hex[:8]}",
                    "simulate_pucks": True, "watchdog_cycles": args.watchdog,
                    "reply_timeout_s": args.reply_timeout},
        "plant": {"friction": "table_4_1"}, "controller": {"kind": "pd_g"}})
    ref = sway_reference(args.duration)
    controller = make_joint_controller(spec)
    rec = LoopRecorder(len(ref), with_truth=False)
    backend = make_backend(spec)
    t_wall = time.perf_counter()
    with backend:
        run_loop(backend, controller, ref, rec)
        d = backend.describe()
    t_wall = time.perf_counter() - t_wall
    loop, link = d["loop"], d["link"]
    n = loop["cycles"]
    print(f"CAN loop on the virtual bus, simulated pucks: {n} cycles at {P.CONTROL_RATE_HZ:.0f} Hz "
          f"({n / P.CONTROL_RATE_HZ:.1f} s of arm time, {t_wall:.1f} s of wall time incl. start-up)")
    print(f"period     p50 {ms(loop['period_p50_s'])}   p99 {ms(loop['period_p99_s'])}   "
          f"max {ms(loop['period_max_s'])}")
    print(f"jitter     p50 {ms(loop['jitter_p50_s'])}   p99 {ms(loop['jitter_p99_s'])}   "
          f"max {ms(loop['jitter_max_s'])}   (|period - 2 ms|)")
    print(f"wake late  p50 {ms(loop['wake_late_p50_s'])}   p99 {ms(loop['wake_late_p99_s'])}   "
          f"max {ms(loop['wake_late_max_s'])}   (after each release point)")
    print(f"busy       p50 {ms(loop['busy_p50_s'])}   p99 {ms(loop['busy_p99_s'])}   "
          f"max {ms(loop['busy_max_s'])}   (request -> replies -> control -> torques)")
    print(f"overruns   {loop['overruns']} ({100 * loop['overruns'] / max(n, 1):.2f} % of cycles), "
          f"{loop['skipped_periods']} release points skipped, worst {ms(loop['worst_overrun_s'])} late")
    print(f"link       {link['missed_reply_cycles']} cycles with a missing/late reply "
          f"(timeout {args.reply_timeout * 1e3:.1f} ms), {link['late_replies']} late replies, "
          f"{link['frames_sent']} frames sent, {link['frames_received']} received")
    from wamctl.backends.can.bus_tools import loop_bus_load_pct
    print(f"bus load   {loop_bus_load_pct(1_000_000):.1f} % of 1 Mbit/s "
          f"({loop_bus_load_pct(1_000_000, stuffing=True):.1f} % with worst-case bit stuffing)")
    print(f"machine    load average {' / '.join(f'{x:.2f}' for x in os.getloadavg())} (1/5/15 min) on "
          f"{os.cpu_count()} cores")
    if d["watchdog"]["tripped"]:
        print(f"watchdog TRIPPED: {d['watchdog']['reason']}")


if __name__ == "__main__":
    main()
