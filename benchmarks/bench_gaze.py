"""Per-sample latency of the gaze chain (framing -> parse -> filters -> strategy -> blink commands).

The tracker sends a sample every 33.3 ms (30 Hz, thesis 6.1.2); the chain must take a small part of that.
A virtual subject's stream (fixations, saccades, blinks, artefacts) is serialised in the line format, then
each line is timed on its own through a fresh controller per configuration.

Usage: ``.venv/bin/python benchmarks/bench_gaze.py [--seconds 300] [--seed 0]``
"""

from __future__ import annotations

import argparse
import platform
import time

import numpy as np

from wamctl.backends.gaze.line_format import GazeLineDecoder, LineFramer, format_line
from wamctl.backends.gaze.virtual import VirtualSubject
from wamctl.hmi.strategy import make_gaze_controller

FRAME_PERIOD_S = 1.0 / 30.0

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


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=300.0, help="simulated stream length, s")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()

    lines = stream_lines(args.seconds, args.seed)
    print(f"gaze chain latency per sample: {len(lines)} samples ({args.seconds:.0f} s at 30 Hz), "
          f"Python {platform.python_version()} on {platform.machine()}")
    print(f"frame period {FRAME_PERIOD_S * 1e3:.1f} ms")
    print(f"{'configuration (strategy / filter / profile)':<44}{'p50 us':>9}{'p99 us':>9}{'max us':>9}"
          f"{'p99 / frame':>13}")
    for name, config in CONFIGS.items():
        time_chain(lines[:300], config)  # warm-up
        t = time_chain(lines, config)
        p50, p99 = np.percentile(t, [50, 99])
        print(f"{name:<44}{p50 * 1e6:9.1f}{p99 * 1e6:9.1f}{t.max() * 1e6:9.1f}{p99 / FRAME_PERIOD_S:12.3%}")


if __name__ == "__main__":
    main()
