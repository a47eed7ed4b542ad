"""Timing of `wamctl runs` over 1000 run directories (issue 30: under 1 s; it reads manifests and report JSONs,
never data). The run directories are small copies of one of each kind's manifest and report JSON (a friction
sweep's report.json is ~31 kB), made in a temporary folder.

    python benchmarks/bench_runs_listing.py [--runs 1000] [--repeat 5]

Reported: the library's listing (``wamctl.runs.catalog.list_runs``) and the whole command in a fresh process
(interpreter start and imports included), best of ``--repeat``. Nothing is asserted.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from wamctl.runs import catalog

_REPORTS = {
    "rotation": {"rpe_pct": {str(j): 1.0 + j for j in range(1, 8)},
                 "tables": {"rotation": [{"joint": j, "rpe_pct": 1.0 + j} for j in range(1, 8)]}},
    "friction_sweep": {"chosen_model": {"1": "classic", "7": "classic"},
                       "friction_map": [{"joint": 1, "v": 0.01 * i, "f": 0.1 * i} for i in range(400)]},
    "ift": {"J": {str(j): {"initial": 1e-3, "tuned": 5e-4} for j in range(1, 8)}},
    "hmi_block": {"hmi": {"trials": 8, "hits": 7, "hit_pct": 87.5, "mean_time_s": 12.0}},
}


def make(folder: Path, n: int) -> None:
    kinds = list(_REPORTS)
    for i in range(n):
        kind = kinds[i % len(kinds)]
        d = folder / f"20260101T{i // 60 % 24:02d}{i % 60:02d}00.000Z-run-{i}"
        d.mkdir()
        (d / "manifest.json").write_text(json.dumps({
            "format": "wamctl-run/1", "kind": kind, "name": f"run-{i}", "status": "completed",
            "start_utc": f"2026-01-01T{i // 60 % 24:02d}:{i % 60:02d}:00.000+00:00",
            "end_utc": f"2026-01-01T{i // 60 % 24:02d}:{i % 60:02d}:30.000+00:00", "host": "bench", "pid": 1,
            "backend": {"name": "sim"}}, indent=2))
        (d / "report.json").write_text(json.dumps(_REPORTS[kind], indent=2))


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--runs", type=int, default=1000)
    ap.add_argument("--repeat", type=int, default=5)
    a = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        make(folder, a.runs)
        lib, cli = [], []
        for _ in range(a.repeat):
            t = time.perf_counter()
            n = len(catalog.list_runs([folder]))
            lib.append(time.perf_counter() - t)
            t = time.perf_counter()
            subprocess.run([sys.executable, "-m", "wamctl", "runs", str(folder), "--json"], check=True,
                           capture_output=True)
            cli.append(time.perf_counter() - t)
        print(f"{n} runs: list_runs {min(lib):.3f} s, `wamctl runs --json` {min(cli):.3f} s (best of {a.repeat})")


if __name__ == "__main__":
    main()
