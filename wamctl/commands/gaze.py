"""wamctl gaze-check: what is the gaze tracker sending? Capture, try every format and baud rate, suggest a spec."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table

from wamctl.commands.common import console, emit_json, err_console, progress_bar


def gaze_check_cmd(
    port: Annotated[str | None, typer.Option("--port", help="Serial device or pyserial URL (/dev/ttyUSB0, "
                                             "socket://host:port).", show_default=False)] = None,
    seconds: Annotated[float, typer.Option("--seconds", metavar="<float>", min=0.5, max=600.0,
                                           help="Seconds of capture per baud "
                                                "rate.")] = 5.0,
    capture: Annotated[Path | None, typer.Option("--capture", help="Also write the raw bytes to this capture file "
                                                 "(hex, one line per read; replay it with a replay-raw source).",
                                                 show_default=False)] = None,
    baud: Annotated[list[int] | None, typer.Option("--baud", metavar="<int>",
                                                   help="Baud rate to try (repeat for several; default "
                                                        "57600, the ASL Serial Out rate).", show_default=False)] = None,
    parity: Annotated[str, typer.Option("--parity", help="none, even, odd, mark or space.")] = "none",
    stopbits: Annotated[float, typer.Option("--stopbits", help="1, 1.5 or 2.")] = 1,
    flow_control: Annotated[str, typer.Option("--flow-control", help="none, rtscts, xonxoff or dsrdtr.")] = "none",
    from_capture: Annotated[Path | None, typer.Option("--from-capture", help="Check a capture file instead of a "
                                                      "port.", show_default=False)] = None,
    json: Annotated[bool, typer.Option("--json", help="Print the result as JSON on stdout.")] = False,
):
    """Capture the bytes a gaze tracker sends (per baud rate asked for), try every known stream format on them
    (ASL Serial Out with the standard items or with a frame counter, 'x,y' lines, 't_ms,x,y' lines) and report which
    decodes: sample rate, value ranges, how blinks showed, framing errors with examples in hex, and the spec section
    to use. Exits 1 when nothing decodes ("no known format", with the bytes in hex)."""
    from wamctl.backends.gaze.capture import read_capture
    from wamctl.backends.gaze.check import best_of, check_port, identify
    from wamctl.errors import SpecError

    if (port is None) == (from_capture is None):
        raise SpecError("give --port URL or --from-capture FILE")
    for name, value, allowed in (("--parity", parity, ("none", "even", "odd", "mark", "space")),
                                 ("--flow-control", flow_control, ("none", "rtscts", "xonxoff", "dsrdtr")),
                                 ("--stopbits", stopbits, (1, 1.5, 2))):
        if value not in allowed:
            raise SpecError(f"{name}: {value!r} is not one of {', '.join(map(str, allowed))}")
    if from_capture is not None:
        results = [identify(section) for section in read_capture(from_capture) if section.chunks]
        if not results:
            raise SpecError(f"{from_capture}: the capture holds no bytes")
    else:
        with progress_bar("gaze-check", enabled=not json) as progress:
            results = check_port(port, seconds=seconds, bauds=baud or [57600], capture_path=capture,
                                 progress=progress, parity=parity, stopbits=stopbits, flow_control=flow_control)
    best = best_of(results)
    if json:
        from wamctl.backends.gaze.check import suggested_spec
        emit_json({"results": [r.as_dict() for r in results], "verdict": best.verdict if best else "no known format",
                   "suggested_spec": suggested_spec(best) if best else None})
    else:
        for r in results:
            _print(r)
        _print_verdict(best, results)
    if best is None:
        raise typer.Exit(1)


def _where(info: dict) -> str:
    return (f"{info.get('url', '?')} at {info.get('baudrate', '?')} Bd {info.get('bytesize', 8)}"
            f"{info.get('parity', 'N')}{info.get('stopbits', 1):g}")


def _print(r) -> None:
    rate = r.n_bytes / r.duration_s if r.duration_s > 0 else float("nan")
    console.print(f"[bold]{_where(r.info)}[/]: {r.n_bytes} bytes in {r.duration_s:.2f} s ({rate:.0f} B/s), "
                  f"{r.reads} reads; {r.looks_like}", highlight=False)
    t = Table()
    for c in ("format", "samples", "blinks", "errors", "garbage", "Hz", "decodes"):
        t.add_column(c, justify="left" if c in ("format", "decodes") else "right")
    for trial in r.trials:
        s = trial.stats
        good = trial.timed
        hz = "-"
        if len(good) >= 2 and good[-1].sample.t_s > good[0].sample.t_s:
            hz = f"{(len(good) - 1) / (good[-1].sample.t_s - good[0].sample.t_s):.1f}"
        t.add_row(trial.candidate.short or trial.candidate.label, str(len(good)), str(s["blink"]),
                  str(s["cut_frames"] + s["bad_frames"] + s["corrupt"]), str(s["garbage_bytes"]), hz,
                  "[green]yes[/]" if trial.decodes else f"no ({trial.why_not})")
    console.print(t)


def _print_verdict(best, results) -> None:
    from wamctl.backends.gaze.check import suggested_spec

    if best is None:
        r = max(results, key=lambda r: r.n_bytes)
        err_console.print(f"[bold red]no known format[/] in {r.n_bytes} bytes; first bytes: {r.head_hex or '-'}",
                          highlight=False)
        err_console.print(f"they look like: {r.looks_like}", highlight=False)
        for note in r.notes:
            err_console.print(f"try: {note}", highlight=False)
        return
    s = best.summary
    console.print(f"[green bold]{best.verdict}[/] at {best.info.get('baudrate', '?')} Bd: {s['samples']} samples at "
                  f"{s.get('rate_hz', '?')} Hz (period p50 {s.get('period_p50_ms', '?')} ms)", highlight=False)
    if "x_px" in s:
        console.print(f"x {s['x_px'][0]:g}..{s['x_px'][1]:g} px, y {s['y_px'][0]:g}..{s['y_px'][1]:g} px"
                      + (f", pupil {s['pupil'][0]:g}..{s['pupil'][1]:g}" if "pupil" in s else "")
                      + (f", status {s['status']}" if "status" in s else "")
                      + f"; {s['out_of_range']} outside the 768 x 576 image", highlight=False)
    b = s["blinks"]
    console.print(f"blinks: {b['samples']} samples ({b['pupil_zero']} with pupil 0, the tracker's loss code; "
                  f"{b['sentinel_-2000']} at (-2000, -2000), the thesis' convention)", highlight=False)
    console.print(f"framing: {s['garbage_bytes']} bytes outside frames, {s['cut_frames']} cut, {s['bad_frames']} "
                  f"bad, {s['corrupt']} corrupt, {s['dropped_frames']} dropped by the counter", highlight=False)
    for kind, examples in s["examples"].items():
        for e in examples:
            console.print(f"  {kind}: {e}", highlight=False)
    for note in best.notes:
        console.print(f"note: {note}", highlight=False)
    console.print("suggested spec section (hmi: source:):", highlight=False)
    console.print(suggested_spec(best), highlight=False, markup=False)


def register(app: typer.Typer) -> None:
    app.command("gaze-check")(gaze_check_cmd)
