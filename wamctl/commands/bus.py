"""wamctl bus-check: which pucks answer on the CAN bus, their firmware and constants, and the bus load."""

from __future__ import annotations

from typing import Annotated

import typer

from wamctl.commands.common import console, emit_json, err_console, print_frame


def bus_check_cmd(
    interface: Annotated[str, typer.Option("--interface", help="python-can interface: socketcan, pcan, virtual, "
                                           "...")] = "socketcan",
    channel: Annotated[str, typer.Option("--channel", help="CAN channel (can0, PCAN_USBBUS1, a virtual channel "
                                         "name).")] = "can0",
    bitrate: Annotated[int, typer.Option("--bitrate", help="Bit rate, bit/s (the WAM runs at 1 Mbit/s).")]
    = 1_000_000,
    simulate_pucks: Annotated[bool, typer.Option("--simulate-pucks", help="Answer as a simulated WAM's pucks "
                                                 "(virtual interface only).")] = False,
    window: Annotated[float, typer.Option("--window", min=0.05, max=60.0, help="Seconds of listening for the "
                                          "bus load.")] = 1.0,
    poll: Annotated[bool, typer.Option("--poll", help="During the window, request positions at 500 Hz as the "
                                       "control loop would, and time the replies.")] = False,
    wake: Annotated[bool, typer.Option("--wake/--no-wake", help="Wake motor pucks found in the monitor to read "
                                       "CTS, IPNM and PIDX (they stay idle).")] = True,
    json: Annotated[bool, typer.Option("--json", help="Print the result as JSON on stdout.")] = False,
):
    """List the pucks found on the bus (firmware VERS, CTS, IPNM, PIDX, state) and measure the bus load
    (frames/s and % of the bit rate over a short window). Exits 1 if a WAM puck is missing or unusable."""
    from wamctl.backends.can.bus_tools import bus_check
    from wamctl.model import params as P

    result = bus_check(interface, channel, bitrate, simulate_pucks=simulate_pucks, window_s=window,
                       poll_hz=P.CONTROL_RATE_HZ if poll else 0.0, wake=wake)
    if json:
        emit_json(result)
    else:
        _print(result)
    if result["problems"]:
        raise typer.Exit(1)


def _fmt(v) -> str:
    return "-" if v is None else str(v)


def _print(r: dict) -> None:
    import pandas as pd

    sim = " (simulated pucks)" if r["simulated"] else ""
    rows = [{"id": p["puck_id"], "node": p["kind"], "state": p["stat_name"],
             "VERS": _fmt(p["vers"]) + ("" if p.get("firmware_ok", True) else " (too old)"), "CTS": p["cts"],
             "IPNM": p["ipnm"], "PIDX": p["pidx"], "MODE": p["mode_name"], "SN": p["sn"]} for p in r["pucks"]]
    print_frame(f"Pucks on {r['interface']} {r['channel']} at {r['bitrate'] / 1e6:g} Mbit/s{sim}",
                pd.DataFrame(rows, columns=["id", "node", "state", "VERS", "CTS", "IPNM", "PIDX", "MODE", "SN"]),
                key="id")
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
        console.print("[green]ok[/] WAM pucks 1-7 found, awake, supported firmware, PIDX consistent")


def register(app: typer.Typer) -> None:
    app.command("bus-check")(bus_check_cmd)
