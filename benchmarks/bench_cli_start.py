"""Start-up time of the command line (issue 16: `wamctl --help` and `--version` under 0.3 s).

Runs the installed ``wamctl`` entry point (the one a user types) N times per command line, each a fresh
process, and prints p50 / max wall time, with the machine's load average at the start.

    python benchmarks/bench_cli_start.py [--repeat 15]
"""

from __future__ import annotations

import argparse
import os
import shutil
import statistics
import subprocess
import sys
import time
from pathlib import Path

COMMANDS = (["--help"], ["--version"], ["run", "--help"], ["diagnose", "--help"])


def entry_point() -> str:
    here = Path(sys.executable).with_name("wamctl")
    return str(here) if here.exists() else (shutil.which("wamctl") or sys.exit("wamctl is not installed"))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=15, help="processes per command line (default 15)")
    args = ap.parse_args()
    exe = entry_point()
    print(f"{exe}; load average {os.getloadavg()[0]:.1f}")
    subprocess.run([exe, "--version"], capture_output=True, check=True)  # warm the file cache
    for cmd in COMMANDS:
        times = []
        for _ in range(args.repeat):
            t0 = time.perf_counter()
            subprocess.run([exe, *cmd], capture_output=True, check=True)
            times.append(time.perf_counter() - t0)
        print(f"wamctl {' '.join(cmd):<18} p50 {statistics.median(times):.3f} s  max {max(times):.3f} s "
              f"({args.repeat} runs)")


if __name__ == "__main__":
    main()
