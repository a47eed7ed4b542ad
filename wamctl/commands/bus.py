"""wamctl bus-check: the safety module (mode, zeroing, limits, pendant), the pucks on the CAN bus (firmware,
constants, groups, POLES, state), what the model does not describe, and the bus load."""

from __future__ import annotations

from typing import Annotated

import typer

from wamctl.commands.common import console, emit_json, err_console, print_frame

BusOptionOpt = Annotated[list[str] | None, typer.Option(
    "--bus-option", metavar="<key=value>", help="Further python-can Bus argument KEY=VALUE (repeatable), e.g. "
    "port=43113 for "
    "udp_multicast.")]


def parse_bus_options(items: list[str] | None) -> dict:
    """``["port=43113", "fd=false"]`` -> ``{"port": 43113, "fd": False}`` (python-can's own casting)."""
    from can.util import cast_from_string

    from wamctl.errors import SpecError

    out = {}
    for item in items or []:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise SpecError(f"--bus-option {item!r}: expected KEY=VALUE")
        out[key.strip()] = cast_from_string(value.strip())
    return out


def bus_check_cmd(
    interface: Annotated[str, typer.Option("--interface", help="python-can interface: socketcan, pcan, virtual, "
                                           "udp_multicast, ...")] = "socketcan",
    channel: Annotated[str, typer.Option("--channel", help="CAN channel (can0, PCAN_USBBUS1, a virtual channel "
                                         "name, a multicast group).")] = "can0",
    bitrate: Annotated[int, typer.Option("--bitrate", help="Bit rate, bit/s (the WAM runs at 1 Mbit/s).")]
    = 1_000_000,
    bus_option: BusOptionOpt = None,
    simulate_pucks: Annotated[bool, typer.Option("--simulate-pucks", help="Answer as a simulated WAM just powered "
                                                 "up (virtual interface only).")] = False,
    window: Annotated[float, typer.Option("--window", metavar="<float>", min=0.05, max=60.0,
                                          help="Seconds of listening for the "
                                               "bus load.")] = 1.0,
    poll: Annotated[bool, typer.Option("--poll", help="During the window, request positions at 500 Hz as the "
                                       "control loop would, and time the replies.")] = False,
    wake: Annotated[bool, typer.Option("--wake/--no-wake", help="Wake motor pucks found in the monitor (10 ms "
                                       "apart, then 1 s of silence, as libbarrett) to read their constants, groups "
                                       "and POLES; they stay idle.")] = True,
    robot: Annotated[str | None, typer.Option("--robot", help="wam7 | wam4: the arm expected on the bus (pucks 1-7; "
                                              "pucks 1-4 and no 5-7); another arm is a problem. Default: the "
                                              "arm the pucks found make. With --simulate-pucks: the arm "
                                              "simulated.", show_default=False)] = None,
    json: Annotated[bool, typer.Option("--json", help="Print the result as JSON on stdout.")] = False,
):
    """Show the safety module (mode, zeroed or not, limits, pendant) and the pucks found on the bus (firmware VERS,
    CTS, IPNM, PIDX, groups GRPA/GRPB/GRPC, POLES, state), say what the model does not describe (gimbals, pucks
    in the wrong group, old firmware), and measure the bus load. Exits 1 if anything is wrong."""
    from wamctl.backends.can.bus_check import bus_check
    from wamctl.errors import SpecError
    from wamctl.model import params as P
    from wamctl.model.robots import ROBOTS

    if robot is not None and robot not in ROBOTS:
        raise SpecError(f"--robot {robot!r}: not an arm wamctl knows ({' or '.join(ROBOTS)})")
    result = bus_check(interface, channel, bitrate, simulate_pucks=simulate_pucks, window_s=window,
                       poll_hz=P.CONTROL_RATE_HZ if poll else 0.0, wake=wake,
                       bus_options=parse_bus_options(bus_option), robot=robot)
    if json:
        emit_json(result)
    else:
        _print(result)
    if result["problems"]:
        raise typer.Exit(1)


def _fmt(v) -> str:
    return "-" if v is None else str(v)


def _print_safety(s: dict | None) -> None:
    if s is None:
        console.print("[bold red]no safety module (node 10)[/]")
        return
    if not s["firmware_ok"]:
        console.print(f"safety module (node 10): VERS {s['vers']} (too old to read)", highlight=False)
        return
    zero = "[green]zeroed[/]" if s["zeroed"] else "[yellow]not zeroed[/] (the session will ask to zero it at home)"
    console.print(f"safety module (node 10): VERS {s['vers']}, [bold]{s['mode_name']}[/], {zero}, groups "
                  f"{'/'.join(map(str, s['groups'] or []))}", highlight=False)
    lim, v = s["limits"], s.get("velocity_limits_m_s") or {}
    if lim:
        console.print(f"  limits: velocity warning {v.get('VL1', 0):.2f} m/s, fault {v.get('VL2', 0):.2f} m/s "
                      f"(VL1 {lim.get('VL1')}, VL2 {lim.get('VL2')}); torque warning TL1 {lim.get('TL1')}, fault "
                      f"TL2 {lim.get('TL2')} puck units", highlight=False)
    pen = s.get("pendant")
    if isinstance(pen, dict):
        console.print(f"  pendant: {pen['summary']}", highlight=False)


def _print(r: dict) -> None:
    import pandas as pd

    sim = " (simulated WAM)" if r["simulated"] else ""
    console.print(f"CAN bus {r['interface']} {r['channel']} at {r['bitrate'] / 1e6:g} Mbit/s{sim}", highlight=False)
    _print_safety(r.get("safety_module"))
    cols = ["id", "node", "state", "VERS", "CTS", "IPNM", "PIDX", "groups", "POLES", "MODE", "SN"]
    # "motor" for "wam motor": the table fits 80 columns
    rows = [{"id": p["puck_id"], "node": p["kind"].removeprefix("wam ") + (" +JE" if p.get("joint_encoder") else ""),
             "state": _fmt(p["stat_name"]),
             "VERS": _fmt(p["vers"]) + ("" if p.get("firmware_ok", True) else " (too old)"), "CTS": _fmt(p["cts"]),
             "IPNM": _fmt(p["ipnm"]), "PIDX": _fmt(p["pidx"]),
             "groups": "/".join(map(str, p["groups"])) if p.get("groups") else "-", "POLES": _fmt(p.get("poles")),
             "MODE": _fmt(p["mode_name"]), "SN": _fmt(p["sn"])} for p in r["pucks"]]
    print_frame("Pucks", pd.DataFrame(rows, columns=cols), key="id")
    ld = r["load"]
    console.print(f"bus load over {ld['window_s']:.2f} s: {ld['frames_per_s']:.0f} frames/s, "
                  f"{ld['bits_per_s'] / 1e3:.1f} kbit/s = {ld['load_pct']:.1f} % of the bit rate "
                  f"({ld['load_pct_worst']:.1f} % with worst-case bit stuffing)", highlight=False)
    console.print(f"the 500 Hz control loop adds about {ld['control_loop_load_pct']:.1f} % "
                  f"({ld['control_loop_load_pct_worst']:.1f} % worst case)", highlight=False)
    if ld.get("polls"):
        lat = ld["reply_latency_p50_s"]
        console.print(f"polled positions {ld['polls']} times, {ld['complete_polls']} complete; reply latency "
                      + (f"p50 {lat * 1e3:.2f} ms, p99 {ld['reply_latency_p99_s'] * 1e3:.2f} ms, max "
                         f"{ld['reply_latency_max_s'] * 1e3:.2f} ms" if lat is not None else "n/a"),
                      highlight=False)
    for problem in r["problems"]:
        err_console.print(f"[bold red]problem:[/] {problem}", highlight=False)
    if not r["problems"]:
        console.print("[green]ok[/] " + _ok_words(r), highlight=False)


def _ok_words(r: dict) -> str:
    """What a bus without problems holds, for the arm found (libbarrett's ``verifyWamPucks``)."""
    from wamctl.model.robots import get_robot

    arm = r["arm"]
    if arm is None or arm == "wam7":
        return ("safety module and WAM pucks 1-7 found, supported firmware, a 7-DOF WAM with wrist (puck 7 POLES "
                "6), groups 1/2/4 as the torque and position frames need, PIDX consistent")
    n = get_robot(arm).n_joints
    groups = "/".join(map(str, sorted({g for p in r["pucks"] if p["kind"] == "wam motor"
                                       for g in p.get("groups") or [] if g != 0})))
    return (f"safety module and WAM pucks 1-{n} found (no pucks {n + 1}-7), supported firmware, a {n}-DOF WAM "
            f"(robot: {arm}), groups {groups} as the torque and position frames need, PIDX consistent")


def register(app: typer.Typer) -> None:
    app.command("bus-check")(bus_check_cmd)
