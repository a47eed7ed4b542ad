"""Timing of the CAN backend's 500 Hz loop, with the simulated WAM in its own process (``wamctl sim-arm`` over
python-can's ``udp_multicast``, as on the lab bus) and in this one (the ``virtual`` bus), for comparison.

The engine's loop (PD + gravity, holding the arm at q0 with the joint-2 and joint-4 references swaying 0.05 rad so
the torques change every cycle) runs for ``--duration`` seconds of arm time after a full session start (safety
module, pucks, Shift-Activate by the simulated pendant). Reported per bus: the period between cycle starts and the
jitter ``|period - 2 ms|`` (p50, p99, max), the wake-up lateness after each release point, each cycle's busy time,
the reply latency (position request to the seventh reply), overruns and skipped release points, cycles with a
missing reply, whether the link watchdog tripped (with the arm's defaults: 3 cycles, 1.5 ms, unless changed), what
the loop was given (garbage collector frozen, SCHED_FIFO, affinity) and the machine's load average.

    python benchmarks/bench_can_loop.py [--duration 60] [--bus udp|virtual|both] [--reply-timeout 0.0015]
        [--watchdog 3] [--cpu N] [--no-realtime] [--bare 15] [--json results.json]

First, for reference, the bare 500 Hz wait (nothing in the cycle) for ``--bare`` seconds: what the machine alone
allows a (SCHED_FIFO) Python thread.

The figures depend on the machine and its load (this is not a real-time kernel); nothing is asserted. Goal (issue
14): p99 jitter < 0.5 ms and no watchdog trip in 60 s.
"""

from __future__ import annotations

import argparse
import json
import os
import random
import signal
import subprocess
import sys
import tempfile
import time
import uuid
from pathlib import Path

import numpy as np
import yaml

from wamctl.backends import make_backend
from wamctl.backends.can.backend import CanBackend
from wamctl.backends.can.session import SessionSettings
from wamctl.control.trajectory import Reference
from wamctl.errors import WamctlError
from wamctl.experiments.common import make_joint_controller
from wamctl.experiments.engine import LoopRecorder, run_loop
from wamctl.model import params as P
from wamctl.specs import parse_spec

Q0 = [0.0, 0.0, 0.0, 1.57, 0.0, 0.0, 0.0]
GOAL_JITTER_P99_S = 0.5e-3


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


def spec_for(bus: str, args, group: str, port: int) -> dict:
    backend = {"kind": "can", "watchdog_cycles": args.watchdog, "reply_timeout_s": args.reply_timeout,
               "idle_wait_s": 5.0}
    if bus == "virtual":
        backend.update(interface="virtual", channel=f"bench-{uuid.uuid4().hex[:8]}", simulate_pucks=True,
                       simulated_pendant="activate@0.1,idle@end")
    else:
        backend.update(interface="udp_multicast", channel=group, bus_options={"port": port})
    return {"kind": "rotation", "name": f"bench-can-{bus}", "seed": 0, "q0_rad": Q0, "backend": backend,
            "plant": {"friction": "table_4_1", "sensors": {"encoder_counts_per_rev": 4096}},
            "controller": {"kind": "pd_g"}}


def start_sim_arm(spec: dict, group: str, port: int, tmp: Path) -> subprocess.Popen:
    path = tmp / "bench-spec.yaml"
    path.write_text(yaml.safe_dump(spec))
    cmd = [sys.executable, "-m", "wamctl.cli", "sim-arm", "--interface", "udp_multicast", "--channel", group,
           "--bus-option", f"port={port}", "--spec", str(path), "--zeroed", "--awake", "--json",
           "--pendant", "activate@0.2,idle@end", "--heartbeat-timeout", "1.0"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "COLUMNS": "300"})
    line = proc.stderr.readline()
    if "serving" not in line:
        proc.kill()
        raise SystemExit(f"sim-arm did not start: {line}{proc.stderr.read()}")
    return proc


def run_one(bus: str, args) -> dict:
    group = f"239.{random.randint(1, 254)}.{random.randint(1, 254)}.{random.randint(1, 254)}"
    port = random.randint(42000, 60000)
    raw = spec_for(bus, args, group, port)
    spec = parse_spec(raw)
    with tempfile.TemporaryDirectory() as tmp:
        proc = start_sim_arm(raw, group, port, Path(tmp)) if bus == "udp" else None
        load_before = os.getloadavg()
        ref = sway_reference(args.duration)
        rec = LoopRecorder(len(ref), with_truth=False)
        if bus == "udp":
            backend = CanBackend("udp_multicast", group, q0_rad=Q0, watchdog_cycles=args.watchdog,
                                 reply_timeout_s=args.reply_timeout, session=SessionSettings(idle_wait_s=5.0),
                                 bus_options={"port": port}, realtime=args.realtime, cpu=args.cpu)
        else:
            backend = make_backend(spec)
        tripped = None
        t_wall = time.perf_counter()
        try:
            with backend:
                run_loop(backend, make_joint_controller(spec), ref, rec)
        except WamctlError as exc:
            tripped = str(exc)
        t_wall = time.perf_counter() - t_wall
        d = backend.describe()
        load_after = os.getloadavg()
        arm = None
        if proc is not None:
            proc.send_signal(signal.SIGTERM)  # (SIGINT may be ignored in a background job)
            out, _ = proc.communicate(timeout=60)
            seen = json.loads(out) if out.strip() else {}
            arm = {"stats": seen.get("stats"), "realtime": seen.get("realtime")}
    return {"bus": bus, "cycles": d["loop"]["cycles"], "wall_s": t_wall, "loop": d["loop"], "link": d["link"],
            "tripped": tripped, "realtime": d["session"].get("realtime"), "load_before": load_before,
            "load_after": load_after, "reply_timeout_s": args.reply_timeout, "watchdog_cycles": args.watchdog,
            "arm": arm}


def bare_loop(duration_s: float, realtime: bool) -> dict:
    """The same 500 Hz wait with nothing else in the cycle (no bus, no control): what the machine alone allows."""
    from wamctl.backends.can.timing import RealtimeSection, sleep_until
    rt = RealtimeSection(fifo=realtime).enter()
    try:
        t0 = time.perf_counter()
        late = np.array([sleep_until(t0 + k * 0.002) - (t0 + k * 0.002)
                         for k in range(1, int(duration_s / 0.002) + 1)])
    finally:
        rt.exit()
    return {"wake_late_p50_s": float(np.percentile(late, 50)), "wake_late_p99_s": float(np.percentile(late, 99)),
            "wake_late_p999_s": float(np.percentile(late, 99.9)), "wake_late_max_s": float(late.max()),
            "over_1ms": int((late > 1e-3).sum()), "n": int(late.size), "given": rt.granted,
            "load": os.getloadavg()}


def ms(x) -> str:
    return "   n/a   " if x is None else f"{x * 1e3:7.3f} ms"


def show(r: dict) -> None:
    loop, link, n = r["loop"], r["link"], r["cycles"]
    where = "simulated arm in its own process, udp_multicast" if r["bus"] == "udp" else \
        "simulated arm in this process, virtual bus"
    print(f"\n== {where}: {n} cycles ({n / P.CONTROL_RATE_HZ:.1f} s of arm time, {r['wall_s']:.1f} s wall incl. "
          "start-up)")
    for name, label in (("period", ""), ("jitter", "(|period - 2 ms|)"), ("wake_late", "(after each release point)"),
                        ("busy", "(request -> replies -> control -> torques)"),
                        ("reply", "(request -> 7th reply)")):
        print(f"{name:10s} p50 {ms(loop.get(name + '_p50_s'))}   p99 {ms(loop.get(name + '_p99_s'))}   "
              f"max {ms(loop.get(name + '_max_s'))}   {label}")
    print(f"overruns   {loop['overruns']} ({100 * loop['overruns'] / max(n, 1):.2f} % of cycles), "
          f"{loop['skipped_periods']} release points skipped, worst {ms(loop['worst_overrun_s'])} late")
    print(f"link       {link['missed_reply_cycles']} cycles with a missing/late reply (timeout "
          f"{r['reply_timeout_s'] * 1e3:.1f} ms, watchdog {r['watchdog_cycles']} cycles), {link['late_replies']} "
          f"late replies")
    print(f"watchdog   {'TRIPPED: ' + r['tripped'] if r['tripped'] else 'no trip'}")
    print(f"loop given {r['realtime']}")
    if r["arm"]:
        print(f"arm given  {r['arm']['realtime']} (the simulated arm's thread, in its process)")
    print("machine    load average " + " / ".join(f"{x:.2f}" for x in r["load_before"]) + " before, "
          + " / ".join(f"{x:.2f}" for x in r["load_after"]) + f" after (1/5/15 min) on {os.cpu_count()} cores")
    jit = loop.get("jitter_p99_s")
    ok = jit is not None and jit < GOAL_JITTER_P99_S and not r["tripped"]
    print(f"goal       p99 jitter < 0.5 ms and no trip: {'reached' if ok else 'NOT reached'}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=60.0, help="seconds of arm time (default 60)")
    ap.add_argument("--bus", choices=("udp", "virtual", "both"), default="both")
    ap.add_argument("--reply-timeout", type=float, default=0.0015, help="position reply timeout, s (arm default)")
    ap.add_argument("--watchdog", type=int, default=3, help="missing-reply cycles tolerated (arm default 3)")
    ap.add_argument("--cpu", type=int, default=None, help="pin the loop's thread to this CPU")
    ap.add_argument("--no-realtime", dest="realtime", action="store_false", help="no SCHED_FIFO (udp)")
    ap.add_argument("--json", type=Path, default=None, help="also write the results here")
    ap.add_argument("--bare", type=float, default=15.0, help="seconds of the bare 500 Hz wait first (0: none)")
    args = ap.parse_args()
    bare = bare_loop(args.bare, args.realtime) if args.bare > 0 else None
    results = [run_one(b, args) for b in (("udp", "virtual") if args.bus == "both" else (args.bus,))]
    if bare is not None:
        print(f"\n== the bare 500 Hz wait, {bare['n']} cycles, {bare['given']}: wake-up late p50 "
              f"{ms(bare['wake_late_p50_s'])}, p99 {ms(bare['wake_late_p99_s'])}, "
              f"p99.9 {ms(bare['wake_late_p999_s'])}, "
              f"max {ms(bare['wake_late_max_s'])}; {bare['over_1ms']} wake-ups more than 1 ms late (load "
              + " / ".join(f"{x:.2f}" for x in bare["load"]) + ")")
    for r in results:
        show(r)
    if args.json:
        args.json.write_text(json.dumps({"bare": bare, "runs": results}, indent=2, default=str))


if __name__ == "__main__":
    main()
