"""A sweep whose process dies (issue 30): killed with SIGKILL mid-point, the point's run is listed `abandoned`,
`wamctl runs --mark-abandoned` records it with every sample, `wamctl report` reads it and `wamctl sweep --resume`
finishes the sweep; stopped with SIGTERM to its process group, no point's run is left `running`."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd
import pytest
import yaml
from cli_runs import run_cli
from test_sweep import tiny

from wamctl.runs import catalog
from wamctl.runs.store import open_run, read_table

pytest.importorskip("distributed")

ROOT = Path(__file__).resolve().parents[2]
REASON = "process ended without closing the run"


def _start(tmp_path: Path, n_points: int) -> tuple[subprocess.Popen, Path]:
    spec = tmp_path / "s.yaml"
    # long points (120 s of arm time, 24 chunks each): on the compiled loop a 4 s point (2200 ticks, less than a
    # chunk) wrote its one chunk just before it consolidated and ended, and the kill could land after that
    spec.write_text(yaml.safe_dump(tiny({"grid": {"seed": {"range": [n_points]}}, "reports": False}, hold_s=120.0)))
    out = tmp_path / "out"
    proc = subprocess.Popen([sys.executable, "-m", "wamctl", "sweep", str(spec), "--out", str(out), "--workers", "2",
                             "--quiet"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True, cwd=ROOT)
    return proc, out


def _wait_for_a_chunk(proc: subprocess.Popen, out: Path) -> None:
    """Until a point's run has flushed a chunk of samples (it is mid-point)."""
    deadline = time.monotonic() + 180
    while time.monotonic() < deadline and proc.poll() is None:
        if list(out.glob("*-sweep/runs/*/*/data/part-*.parquet")):
            return
        time.sleep(0.01)
    raise AssertionError(f"no point wrote a chunk (exit {proc.poll()})")


def _group_gone(pgid: int, timeout_s: float = 60) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        try:
            os.killpg(pgid, 0)
        except ProcessLookupError:
            return True
        time.sleep(0.1)
    return False


def _kill_group(proc: subprocess.Popen) -> None:
    """Whatever is left of the sweep's process group (nothing, when the test passes)."""
    try:
        os.killpg(proc.pid, signal.SIGKILL)
    except ProcessLookupError:
        pass
    if proc.poll() is None:
        proc.wait(timeout=30)


def test_a_sweep_killed_mid_point_is_abandoned_marked_reported_and_resumed(tmp_path):
    proc, out = _start(tmp_path, 4)
    try:
        _wait_for_a_chunk(proc, out)
        os.kill(proc.pid, signal.SIGKILL)            # the sweep's own process only, as `kill -9 PID` does
        proc.communicate(timeout=60)
        assert _group_gone(proc.pid), "the sweep's workers outlived it"
    finally:
        _kill_group(proc)
    sweep_dir = next(out.glob("*-sweep"))
    listed = catalog.list_runs([out])
    dead = [e for e in listed if e.status == "abandoned"]
    assert dead and all(e.manifest_status == "running" for e in dead)
    assert all(e.status in ("completed", "abandoned") for e in listed)
    run = Path(next(e.path for e in dead if list(Path(e.path).glob("data/part-*.parquet"))))
    rows = len(read_table(run))                       # the chunks, as the store reads them
    assert rows >= 1000

    r = run_cli("runs", str(out), "--mark-abandoned", "--json")
    assert r.code == 0, r.err
    assert sorted(json.loads(r.out)["marked_abandoned"]) == sorted(e.path for e in dead)
    m, _ = open_run(run)
    assert (m["status"], m["reason"]) == ("interrupted", REASON)
    assert m["abandoned"]["rows"] == {"data": rows}
    assert len(pd.read_parquet(run / "data.parquet")) == rows
    for e in dead:                                     # a point killed before its first sample too
        r = run_cli("report", e.path, "--out", str(tmp_path / "reports" / Path(e.path).parent.name), "--json")
        assert r.code == 0, r.err
        assert json.loads(r.out)["runs"][0]["status"] == "interrupted"

    r = subprocess.run([sys.executable, "-m", "wamctl", "sweep", "--resume", str(sweep_dir), "--workers", "2",
                        "--quiet", "--json"], capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert r.returncode == 0, r.stderr[-2000:]
    index = json.loads((sweep_dir / "index.json").read_text())
    assert index["counts"]["completed"] == 4
    assert json.loads((sweep_dir / "sweep.json").read_text())["status"] == "completed"
    m, _ = open_run(run)                               # the dead attempt stays as it was recorded
    assert m["status"] == "interrupted" and len(pd.read_parquet(run / "data.parquet")) == rows
    assert not [e for e in catalog.list_runs([out]) if e.status in ("running", "abandoned")]


def test_sigterm_to_a_sweeps_process_group_leaves_no_point_running(tmp_path):
    proc, out = _start(tmp_path, 6)
    try:
        _wait_for_a_chunk(proc, out)
        os.killpg(proc.pid, signal.SIGTERM)
        _, err = proc.communicate(timeout=120)
    finally:
        _kill_group(proc)
    assert proc.returncode == 130 and "sweep interrupted" in err and "Traceback" not in err, err
    sweep_dir = next(out.glob("*-sweep"))
    attempts = list(sweep_dir.glob("runs/*/*/manifest.json"))
    assert attempts
    stopped = 0
    for p in attempts:
        m = json.loads(p.read_text())
        assert m["status"] in ("completed", "interrupted"), (p, m["status"], m.get("reason"))
        if m["status"] == "interrupted":
            assert m["reason"] in (REASON, "stopped by SIGTERM"), m["reason"]
            stopped += 1
    assert stopped >= 1
    assert json.loads((sweep_dir / "sweep.json").read_text())["status"] == "interrupted"
    assert not [e for e in catalog.list_runs([out]) if e.status in ("running", "abandoned")]
