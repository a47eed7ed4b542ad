"""A simulated gaze tracker on a pseudo-terminal: writes a scripted stream in any of the formats, one frame per
period on an absolute schedule (with one pause), and records when each frame was written (for end-to-end tests and
benchmarks).

Run it as its own process, so that its schedule does not share a GIL with the reader under test::

    python -m wamctl.backends.gaze.tracker_sim --fd N --slave /dev/pts/K --format asl-serial-out --out sent.json

with the pty's master fd passed (``pass_fds``). Once started it says so on stdout (:data:`READY`: a reader
that gives up when no byte arrives within a few seconds of opening the port should open it after that line). It
starts streaming once the reader has opened the port: it polls the slave's
line speed until it reads ``--baud`` (pyserial sets the speed, then flushes the input, when it opens a port), waits
0.2 s, then streams. It writes its JSON (the speed it saw; per frame the planned time and the start and return of
the write of its last bytes, on ``time.monotonic``, the clock of the reader's arrival stamps) when done.

The frames come from the library's encoders (:meth:`~wamctl.backends.gaze.asl.AslLayout.encode`,
:func:`~wamctl.backends.gaze.ascii_pair.format_pair`, :func:`~wamctl.backends.gaze.line_format.format_line`), which
tests/backends/test_gaze_formats.py checks against byte fixtures written by hand from the public description.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import termios
import time
from collections.abc import Sequence

from wamctl.backends.gaze.ascii_pair import format_pair
from wamctl.backends.gaze.asl import STANDARD_FIELDS, AslLayout
from wamctl.backends.gaze.line_format import format_line

RATE_HZ = 30.0
#: (count, (x, y) or None for a blink): 3 s at the centre while the arm moves to the start pose, 1 s looking left,
#: a 0.9 s voluntary blink (21 samples make one at 30 Hz), then the centre while the hand closes.
TRIAL_SCRIPT: tuple[tuple[int, tuple[int, int] | None], ...] = (
    (90, (384, 288)), (30, (200, 300)), (10, (384, 288)), (27, None), (30, (384, 288)))
#: Garbage goes before frame k when k % GARBAGE_EVERY == GARBAGE_EVERY // 2; frame k is split across two writes
#: 2 ms apart when k % SPLIT_EVERY == 7.
GARBAGE_EVERY = 40
SPLIT_EVERY = 25
#: After frame PAUSE_AT the tracker skips PAUSE_FRAMES periods (a hiccup): frame times are not k / rate.
PAUSE_AT = 60
PAUSE_FRAMES = 6
_BAUDS = {9600: termios.B9600, 19200: termios.B19200, 38400: termios.B38400, 57600: termios.B57600,
          115200: termios.B115200}


def expand(script: Sequence[tuple[int, tuple[int, int] | None]]) -> list[tuple[int, int] | None]:
    return [xy for n, xy in script for _ in range(n)]


def schedule_s(k: int, rate_hz: float = RATE_HZ) -> float:
    """Time of frame ``k`` from the first one, s: ``k / rate_hz``, plus the pause after frame ``PAUSE_AT``."""
    return (k + (PAUSE_FRAMES if k > PAUSE_AT else 0)) / rate_hz


def frame(fmt: str, k: int, xy: tuple[int, int] | None, rate_hz: float = RATE_HZ) -> bytes:
    """Frame ``k`` of a stream; ``None`` is a blink in the format's own encoding (ASL: pupil 0, gaze 0, 0)."""
    if fmt == "asl-serial-out":
        x, y = xy if xy is not None else (0, 0)
        return AslLayout.parse(STANDARD_FIELDS).encode({"status": 0, "pupil": 0 if xy is None else 40, "x": x, "y": y})
    x, y = xy if xy is not None else (-2000, -2000)
    if fmt == "ascii-pair":
        return format_pair(float(x), float(y))
    if fmt == "ascii-timestamped":
        return format_line(schedule_s(k, rate_hz), float(x), float(y))
    raise ValueError(f"unknown format {fmt!r}")


def garbage(fmt: str) -> bytes:
    """Line noise: bytes with bit 7 clear between ASL frames, a broken line between ASCII lines."""
    return b"\x13\x55\x07" if fmt == "asl-serial-out" else b"\xfe\x00garbage,,\n"


READY = "tracker_sim: waiting for the reader"   # the line on stdout once the process has started


def wait_for_reader(slave: str, baud: int, timeout_s: float = 60.0) -> int:
    """Poll the slave's output speed until the reader set it to ``baud``; return the speed code seen."""
    fd = os.open(slave, os.O_RDWR | os.O_NOCTTY)
    try:
        deadline = time.monotonic() + timeout_s
        while (speed := termios.tcgetattr(fd)[5]) != _BAUDS[baud]:
            if time.monotonic() > deadline:
                raise TimeoutError(f"the reader never opened {slave} at {baud} Bd")
            time.sleep(0.01)
        return speed
    finally:
        os.close(fd)


def stream(fd: int, fmt: str, samples: Sequence[tuple[int, int] | None], rate_hz: float = RATE_HZ) -> dict:
    """Write the frames on their schedule; return the planned times and the start and return of each write."""
    planned, start, written = [], [], []
    t0 = time.monotonic()
    for k, xy in enumerate(samples):
        data = frame(fmt, k, xy, rate_hz)
        if k % GARBAGE_EVERY == GARBAGE_EVERY // 2:
            data = garbage(fmt) + data
        due = t0 + schedule_s(k, rate_hz)
        time.sleep(max(0.0, due - time.monotonic()))
        try:
            if k % SPLIT_EVERY == 7:
                os.write(fd, data[:5])
                time.sleep(0.002)
                data = data[5:]
            t_start = time.monotonic()
            view = memoryview(data)
            while view:
                view = view[os.write(fd, view):]
        except OSError:  # the reader closed the port
            break
        written.append(time.monotonic())
        start.append(t_start)
        planned.append(due)
    return {"planned_s": planned, "write_start_s": start, "written_s": written}


def main(argv: Sequence[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--fd", type=int, required=True, help="pty master file descriptor (inherited)")
    p.add_argument("--slave", required=True, help="pty slave path (to watch its speed)")
    p.add_argument("--format", required=True)
    p.add_argument("--out", required=True, help="JSON written when done")
    p.add_argument("--baud", type=int, default=57600)
    p.add_argument("--rate", type=float, default=RATE_HZ)
    p.add_argument("--seconds", type=float, default=None,
                   help="look at the centre this long, no blink (default: the trial script)")
    args = p.parse_args(argv)
    sys.stdout.write(READY + "\n")     # a caller may open the port now (its first-byte timeout runs from there)
    sys.stdout.flush()
    try:
        speed = wait_for_reader(args.slave, args.baud)
    except TimeoutError as exc:
        sys.exit(str(exc))
    time.sleep(0.2)
    samples = (expand(TRIAL_SCRIPT) if args.seconds is None
               else [(384, 288)] * round(args.seconds * args.rate))
    result = {"ospeed": speed, **stream(args.fd, args.format, samples, args.rate)}
    time.sleep(0.5)
    with open(args.out, "w") as fh:
        json.dump(result, fh)


if __name__ == "__main__":
    main()
