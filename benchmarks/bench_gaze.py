"""The gaze chain: per-sample cost (framing -> decode -> filters -> strategy) and the timing of arrival stamps.

Three parts, each can run alone (``--only chain|decode|pty``):

* ``chain``: a virtual subject's stream (fixations, saccades, blinks, artefacts) in the ``ascii-timestamped`` line
  format, each line timed on its own through a fresh controller per configuration (strategy / filter / profile).
* ``decode``: framing + decoding cost per frame of each stream format (``asl-serial-out``, ``ascii-pair``,
  ``ascii-timestamped``), frames fed one read at a time as they come from a port.
* ``pty``: the arrival stamps of each format through a pseudo-terminal at 57600 Bd. A simulated tracker
  (:mod:`wamctl.backends.gaze.tracker_sim`, its own process) writes a frame every 1/30 s on an absolute schedule and
  records the start and return of each write; the reader's latency is ``max(0, arrival - write returned)`` (the
  bytes became readable during the write). Measured three ways: the serial source alone, reading the port in this
  process (``thread``) or in a child process (``process``), and the whole ``hmi_block`` on the simulated arm
  (``block``, which reads its port in a child process; the samples of ``gaze_samples.csv``). The tracker's own
  lateness against its schedule (``sender late``) shows the machine's wake-up noise in the same window.
  ``--hogs N`` runs N busy processes meanwhile (a loaded machine).

Usage: ``.venv/bin/python benchmarks/bench_gaze.py [--seconds 300] [--pty-seconds 20] [--hogs 0] [--only ...]``

The pty figures depend on the machine's load (this is not a real-time kernel); nothing is asserted here.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import os
import platform
import subprocess
import sys
import tempfile
import threading
import time
import tty
from pathlib import Path

import numpy as np
import pandas as pd

from wamctl.backends.gaze import tracker_sim
from wamctl.backends.gaze.formats import FORMAT_NAMES, make_decoder
from wamctl.backends.gaze.line_format import GazeLineDecoder, LineFramer, format_line
from wamctl.backends.gaze.serial import SerialGazeSource
from wamctl.backends.gaze.virtual import VirtualSubject
from wamctl.hmi.strategy import make_gaze_controller

FRAME_PERIOD_S = 1.0 / 30.0
ROOT = Path(__file__).resolve().parents[1]

CONFIGS = {
    "four / none / single": {"strategy": "four", "profile": "single"},
    "four / MA 300 ms / single": {"strategy": "four", "profile": "single", "point_filter": "ma", "window_s": 0.3},
    "four / MA 500 ms / dual": {"strategy": "four", "profile": "dual", "point_filter": "ma", "window_s": 0.5},
    "four / WMA 300 ms / cubic": {"strategy": "four", "profile": "cubic", "point_filter": "wma", "window_s": 0.3},
    "vector / Kalman Q=0.001 / dual": {"strategy": "vector", "profile": "dual", "kalman_q": 0.001},
    "vector / Kalman Q=0.0001 / cubic": {"strategy": "vector", "profile": "cubic", "kalman_q": 0.0001},
}


def stream_lines(seconds: float, seed: int) -> list[bytes]:
    """Serial lines of a virtual subject looking around the scene, with a voluntary blink every 4 s."""
    targets = [(650.0, 120.0), (120.0, 460.0), (384.0, 40.0), (700.0, 500.0), (384.0, 288.0)]
    subject = VirtualSubject(lambda t: targets[int(t / 6.0) % len(targets)], seed=seed, duration_s=seconds,
                             artifact_prob=0.01)
    for k in range(int(seconds / 4.0)):
        subject.request_voluntary_blink(at_s=2.0 + 4.0 * k)
    lines = [format_line(s.t_s, s.x_px, s.y_px) for s in subject]
    for i in range(7, len(lines), 97):  # some line noise
        lines[i] = b"\xfe\x00" + lines[i][3:]
    return lines


def time_chain(lines: list[bytes], config: dict) -> np.ndarray:
    """Seconds spent on each line, framing to command."""
    framer, decoder, controller = LineFramer(), GazeLineDecoder(), make_gaze_controller(**config)
    clock = time.perf_counter_ns
    out = np.empty(len(lines))
    for i, line in enumerate(lines):
        start = clock()
        for chunk in framer.feed(line):
            sample = decoder.decode(chunk)
            if sample is not None:
                controller.update(sample)
        out[i] = clock() - start
    return out * 1e-9


def run_chain(args) -> None:
    lines = stream_lines(args.seconds, args.seed)
    print(f"gaze chain latency per sample: {len(lines)} samples ({args.seconds:.0f} s at 30 Hz)")
    print(f"{'configuration (strategy / filter / profile)':<44}{'p50 us':>9}{'p99 us':>9}{'max us':>9}"
          f"{'p99 / frame':>13}")
    for name, config in CONFIGS.items():
        time_chain(lines[:300], config)  # warm-up
        t = time_chain(lines, config)
        p50, p99 = np.percentile(t, [50, 99])
        print(f"{name:<44}{p50 * 1e6:9.1f}{p99 * 1e6:9.1f}{t.max() * 1e6:9.1f}{p99 / FRAME_PERIOD_S:12.3%}")


def run_decode(args) -> None:
    n = round(args.seconds * 30)
    rng = np.random.default_rng(args.seed)
    xy = [(int(x), int(y)) for x, y in zip(rng.integers(0, 768, n), rng.integers(0, 576, n))]
    print(f"\nframing + decoding per frame, {n} frames fed one read each")
    print(f"{'format':<22}{'p50 us':>9}{'p99 us':>9}{'frames/s (1 core)':>20}")
    for fmt in FORMAT_NAMES:
        frames = [tracker_sim.frame(fmt, k, p) for k, p in enumerate(xy)]
        decoder = make_decoder(fmt)
        clock = time.perf_counter_ns
        out = np.empty(n)
        for k, data in enumerate(frames):
            start = clock()
            for f in decoder.feed(data):
                decoder.decode(f, 0.0)
            out[k] = clock() - start
        t = out[n // 10:] * 1e-9
        p50, p99 = np.percentile(t, [50, 99])
        print(f"{fmt:<22}{p50 * 1e6:9.1f}{p99 * 1e6:9.1f}{1.0 / t.mean():20.0f}")


def _hog(stop) -> None:
    x = 0
    while not stop.is_set():
        x += 1


def _sender(fmt: str, seconds: float, out: Path, master_fd: int, slave: str) -> subprocess.Popen:
    env = {**os.environ, "PYTHONPATH": str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    return subprocess.Popen([sys.executable, "-m", "wamctl.backends.gaze.tracker_sim", "--fd", str(master_fd),
                             "--slave", slave, "--format", fmt, "--out", str(out), "--seconds", str(seconds)],
                            pass_fds=(master_fd,), env=env)


def _reader_alone(fmt: str, slave: str, seconds: float, reader: str) -> list:
    records = []
    with SerialGazeSource(slave, format=fmt, timeout_s=0.1, reader=reader) as source:
        stop = threading.Event()

        def read():
            while not stop.is_set():
                d = source.read_decoded(0.1)
                if d is not None and d.sample.has_time:
                    records.append(d.arrival_s)

        thread = threading.Thread(target=read, daemon=True)
        thread.start()
        time.sleep(seconds + 1.5)
        stop.set()
        thread.join(2.0)
    return records


def _block(fmt: str, slave: str, seconds: float, tmp: Path) -> list:
    from wamctl.experiments.runner import run_spec
    from wamctl.specs import parse_spec

    spec = parse_spec({"kind": "hmi_block", "seed": 1, "name": f"bench-{fmt}", "hmi": {
        "subject": {"id": "B"}, "locations": ["P4"], "start": "auto", "timeout_s": max(seconds - 4.0, 1.0),
        "source": {"kind": "serial", "url": slave, "format": fmt, "eof_idle_s": 2.0}}})
    outcome = run_spec(spec, tmp, tmp / "runs", make_report=False)
    got = pd.read_csv(outcome.path / "gaze_samples.csv")
    return list(got.loc[got["flags"] != 4, "arrival_s"])


def run_pty(args) -> None:
    stop = multiprocessing.Event()
    hogs = [multiprocessing.Process(target=_hog, args=(stop,), daemon=True) for _ in range(args.hogs)]
    for h in hogs:
        h.start()
    print(f"\narrival stamps through a pty at 57600 Bd, {args.pty_seconds:g} s at 30 Hz per run, {args.hogs} busy "
          f"process(es), load average {os.getloadavg()[0]:.1f} at start")
    print(f"{'format':<20}{'where':<8}{'n':>6}{'p50 ms':>9}{'p99 ms':>9}{'max ms':>9}{'sender late p99 ms':>21}")
    try:
        for fmt in FORMAT_NAMES:
            for where in ("thread", "process", "block"):
                with tempfile.TemporaryDirectory() as d:
                    tmp = Path(d)
                    master_fd, slave_fd = os.openpty()
                    tty.setraw(slave_fd)
                    slave = os.ttyname(slave_fd)
                    sender = _sender(fmt, args.pty_seconds, tmp / "sent.json", master_fd, slave)
                    try:
                        arrivals = (_block(fmt, slave, args.pty_seconds, tmp) if where == "block"
                                    else _reader_alone(fmt, slave, args.pty_seconds, where))
                        sender.wait(timeout=60)
                        sent = json.loads((tmp / "sent.json").read_text())
                    finally:
                        if sender.poll() is None:
                            sender.kill()
                        os.close(master_fd)
                        os.close(slave_fd)
                n = min(len(arrivals), len(sent["written_s"]))
                latency = np.maximum(np.array(arrivals[:n]) - np.array(sent["written_s"][:n]), 0.0) * 1e3
                late = (np.array(sent["written_s"]) - np.array(sent["planned_s"])) * 1e3
                p50, p99 = np.percentile(latency, [50, 99])
                print(f"{fmt:<20}{where:<8}{n:6d}{p50:9.2f}{p99:9.2f}{latency.max():9.2f}"
                      f"{np.percentile(late, 99):21.2f}", flush=True)
    finally:
        stop.set()
        for h in hogs:
            h.join(2.0)
    print(f"load average at the end {os.getloadavg()[0]:.1f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=300.0, help="simulated stream length (chain, decode), s")
    parser.add_argument("--pty-seconds", type=float, default=20.0, help="stream length of each pty run, s")
    parser.add_argument("--hogs", type=int, default=0, help="busy processes during the pty runs")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--only", choices=["chain", "decode", "pty"], default=None)
    args = parser.parse_args()
    print(f"Python {platform.python_version()} on {platform.machine()}, {os.cpu_count()} cores; frame period "
          f"{FRAME_PERIOD_S * 1e3:.1f} ms")
    if args.only in (None, "chain"):
        run_chain(args)
    if args.only in (None, "decode"):
        run_decode(args)
    if args.only in (None, "pty"):
        run_pty(args)


if __name__ == "__main__":
    main()
