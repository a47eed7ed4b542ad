"""wamctl sim-arm: serve the simulated WAM (pucks, safety module, pendant) on a CAN bus in this process."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from wamctl.commands.bus import BusOptionOpt, parse_bus_options
from wamctl.commands.common import console, emit_json, err_console


def sim_arm_cmd(
    interface: Annotated[str, typer.Option("--interface", help="python-can interface (udp_multicast to reach other "
                                           "processes, virtual, socketcan on a vcan device, ...).")] = "udp_multicast",
    channel: Annotated[str, typer.Option("--channel", help="Channel (for udp_multicast a multicast group, e.g. "
                                         "239.74.163.2).")] = "239.74.163.2",
    bitrate: Annotated[int, typer.Option("--bitrate", help="Bit rate, bit/s.")] = 1_000_000,
    bus_option: BusOptionOpt = None,
    spec: Annotated[Path | None, typer.Option("--spec", help="Take the plant, seed and start pose from this "
                                              "experiment spec (default: the default plant).")] = None,
    pendant: Annotated[str, typer.Option("--pendant", help="What the operator does on the pendant, seconds after "
                                         "the host starts polling: e.g. 'activate@1.0', 'activate@0.5,estop@3', "
                                         "'move@0.2,activate@1', 'never'; idle@end: Shift-Idle when the host "
                                         "ends.")] = "activate@1.0,idle@end",
    pose: Annotated[str, typer.Option("--pose", help="Where the arm stands: q0 (the spec's start pose) or home (the "
                                      "zeroing pose).")] = "q0",
    zeroed: Annotated[bool, typer.Option("--zeroed/--not-zeroed", help="Encoders already zeroed (not: arbitrary "
                                         "offsets, as after power-up).")] = False,
    awake: Annotated[bool, typer.Option("--awake/--asleep", help="Pucks already awake (asleep: in the monitor, as "
                                        "after power-up).")] = False,
    joint_encoders: Annotated[bool, typer.Option("--joint-encoders", help="Pucks 1-4 with joint encoders (6-byte "
                                                 "position replies).")] = False,
    gimbals: Annotated[bool, typer.Option("--gimbals", help="Puck 7 with POLES 8: a gimbals arm (the session must "
                                          "refuse it).")] = False,
    upper_group: Annotated[int, typer.Option("--upper-group", metavar="<int>", min=0, max=31,
                                             help="GRPC of pucks 5-7 (5 as in "
                                                  "Barrett's 2008 manual: the session must refuse it).")] = 4,
    heartbeat_timeout: Annotated[float, typer.Option("--heartbeat-timeout", metavar="<float>", min=0.01,
                                                     help="Seconds without "
                                                          "position polling before the safety module faults.")] = 0.5,
    realtime: Annotated[bool, typer.Option("--realtime/--no-realtime", help="SCHED_FIFO for the simulator's thread "
                                           "when permitted, no garbage-collection pauses (pucks answer within "
                                           "microseconds).")] = True,
    json: Annotated[bool, typer.Option("--json", help="At exit, print what the arm saw as JSON.")] = False,
):
    """Serve a simulated WAM (motor pucks 1-7, the safety module and a scripted pendant) on a CAN bus until Ctrl-C,
    so that `wamctl run` or `bus-check` in another process talks to it as to the real arm. Refuses if a WAM already
    answers on the bus."""
    from wamctl.backends.can.sim.serve import ArmOptions, serve_simulated_arm

    s = base = None
    if spec is not None:
        from wamctl.specs import load_spec
        s, base = load_spec(spec), spec.resolve().parent
    options = ArmOptions(pose=pose, zeroed=zeroed, awake=awake, pendant=pendant, joint_encoders=joint_encoders,
                         gimbals=gimbals, upper_group=upper_group, heartbeat_timeout_s=heartbeat_timeout,
                         realtime=realtime)

    def ready(text: str) -> None:  # on stderr, one line (stdout is the JSON's with --json)
        err_console.print(f"[green]serving[/] {text} (Ctrl-C to stop)", highlight=False, soft_wrap=True)

    seen = serve_simulated_arm(interface, channel, bitrate, bus_options=parse_bus_options(bus_option), spec=s,
                               base_dir=base, options=options, on_ready=ready)
    if json:
        emit_json(seen)
    else:
        st = seen["stats"]
        console.print(f"stopped: {st['position_requests']} position requests, {st['torque_frames']} torque frames, "
                      f"{st['host_mode_writes_refused']} MODE writes refused, {st['bus_off_events']} bus-off; safety "
                      f"module: {seen['safety_module']['mode']}", highlight=False)


def register(app: typer.Typer) -> None:
    app.command("sim-arm")(sim_arm_cmd)
