"""--resume of a run whose process died (issue 30): `tune-ift --resume` and `hmi-session --resume` take a run that
`wamctl runs` shows `abandoned` (a real process killed with SIGKILL mid-run), record it as `--mark-abandoned` does
and finish it, every sample of before the kill kept; a run whose process is alive, or of another host, is refused
in one line. (The sweep's --resume of a killed sweep: tests/experiments/test_sweep_killed.py.)"""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd
import pytest
import yaml
from cli_runs import HMI, IFT, run_cli

from wamctl.runs import catalog
from wamctl.runs.store import open_run

ROOT = Path(__file__).resolve().parents[2]
REASON = "process ended without closing the run"


def killed_run(tmp_path: Path, command: str, spec: dict, written: str) -> tuple[Path, Path]:
    """(spec file, run directory) of a real `wamctl COMMAND` killed with SIGKILL once ``written`` (a glob in its
    run directory) exists."""
    p = tmp_path / "s.yaml"
    p.write_text(yaml.safe_dump(spec))
    out = tmp_path / "out"
    proc = subprocess.Popen([sys.executable, "-m", "wamctl", command, str(p), "--out", str(out), "--quiet"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, cwd=ROOT)
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and proc.poll() is None and not list(out.glob(f"*/{written}")):
            time.sleep(0.02)
        assert proc.poll() is None and list(out.glob(f"*/{written}")), f"{command} ended before {written}"
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
    [run] = [d for d in out.iterdir() if d.is_dir()]
    [e] = catalog.list_runs([out])
    assert e.status == "abandoned" and e.manifest_status == "running"
    return p, run


def test_tune_ift_resumes_an_abandoned_run(tmp_path):
    spec = dict(IFT, ift=dict(IFT["ift"], max_iterations=3))
    p, run = killed_run(tmp_path, "tune-ift", spec, "iter-001-exp1.parquet")
    before = {f.name: len(pd.read_parquet(f)) for f in run.glob("iter-*.parquet")}
    r = run_cli("tune-ift", p, "--resume", run, "--quiet", "--json")
    assert r.code == 0, r.err
    m, _ = open_run(run)
    assert m["status"] == "completed" and m["abandoned"]["known_by"] == "its pid (gone)" and len(m["resumed"]) == 1
    events = pd.read_csv(run / "events.csv")
    [note] = events.loc[events["kind"] == "ift_resumed", "detail"]
    assert "previous status interrupted" in note      # recorded as abandoned before it went on
    for name, n in before.items():                    # the iterations run before the kill are kept, not re-run
        assert len(pd.read_parquet(run / name)) == n, name
    assert len(pd.read_csv(run / "iterations.csv")) == 4    # iterations 0-3 (J before, 3 tuning steps)


@pytest.mark.parametrize("command", ["hmi-session", "run"])
def test_hmi_session_resumes_an_abandoned_block_keeping_its_trajectory(tmp_path, command):
    spec = dict(HMI, hmi=dict(HMI["hmi"], locations=["P1", "P2", "P3"]))
    _, run = killed_run(tmp_path, "hmi-session", spec, "trajectory/part-*.parquet")
    first = {int(f.stem.split("-")[1]): len(pd.read_parquet(f)) for f in (run / "trajectory").glob("part-*.parquet")}
    r = run_cli(command, "--resume", run, "--quiet", "--json")
    assert r.code == 0, r.err
    m, _ = open_run(run)
    assert m["status"] == "completed" and m["abandoned"]["rows"] == {"trajectory": sum(first.values())}
    trials = pd.read_csv(run / "trials.csv")
    assert list(trials["trial"]) == [1, 2, 3]
    per_trial = pd.read_parquet(run / "trajectory.parquet").groupby("trial").size()
    assert sorted(per_trial.index.astype(int)) == [1, 2, 3]
    for trial, n in first.items():                    # the trial recorded before the kill: every sample
        assert per_trial[float(trial)] == n


def _running_manifest(d: Path, pid: int, host: str) -> None:
    m, _ = open_run(d)
    m.update(status="running", pid=pid, host=host, end_utc=None)
    (d / "manifest.json").write_text(json.dumps(m))


@pytest.mark.parametrize("where", ["this host, alive", "another host"])
def test_a_live_run_or_another_hosts_is_not_resumed(tmp_path, where):
    p = tmp_path / "s.yaml"
    p.write_text(yaml.safe_dump(IFT))
    r = run_cli("tune-ift", p, "--out", tmp_path / "out", "--quiet", "--json")
    assert r.code == 0, r.err
    run = Path(json.loads(r.out)["run_dir"])
    alive = where.startswith("this")
    _running_manifest(run, os.getpid() if alive else 4242, socket.gethostname() if alive else "lab-pc-2")
    r = run_cli("tune-ift", p, "--resume", run, "--quiet")
    assert r.code == 2 and len(r.err.strip().splitlines()) == 1 and "Traceback" not in r.err, r.err
    assert ("still running" if alive else "host lab-pc-2") in r.err
    assert open_run(run)[0]["status"] == "running"    # left as it was
