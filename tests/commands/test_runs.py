"""wamctl runs (issue 30): the listing at 80 columns, filters, JSON, dead runs shown `abandoned` and marked, the
index page."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml
from cli_runs import run_cli
from conftest import rotation_spec

from wamctl.runs import catalog
from wamctl.runs.store import RunDir, open_run, read_table, utc_now

ROOT = Path(__file__).resolve().parents[2]


def fake_run(root: Path, name: str, kind: str, start: str, end: str | None, status: str, report: dict | None = None,
             pid: int | None = None, host: str | None = None, files: dict | None = None) -> Path:
    d = root / f"{start.replace(':', '')}-{name}"
    d.mkdir(parents=True)
    m = {"format": "wamctl-run/1", "kind": kind, "name": name, "status": status, "reason": None, "start_utc": start,
         "end_utc": end, "host": host or socket.gethostname(), "pid": pid or os.getpid(), "backend": {"name": "sim"}}
    (d / "manifest.json").write_text(json.dumps(m))
    (d / "spec.yaml").write_text(yaml.safe_dump({"kind": kind, "name": name}))
    if report is not None:
        (d / "report.json").write_text(json.dumps(report))
    for fname, obj in (files or {}).items():
        (d / fname).write_text(json.dumps(obj))
    return d


def dead_pid() -> int:
    p = subprocess.Popen([sys.executable, "-c", "pass"])
    p.wait()
    return p.pid


@pytest.fixture()
def lab(tmp_path):
    runs = tmp_path / "runs"
    fake_run(runs, "rot-before-repair", "rotation", "2026-03-01T09:00:00.000+00:00", "2026-03-01T09:01:23.500+00:00",
             "completed", {"rpe_pct": {"1": 2.5, "4": -7.25, "7": 3.0}})
    fake_run(runs, "ift-7dof", "ift", "2026-03-02T10:00:00.000+00:00", "2026-03-02T11:02:00.000+00:00", "completed",
             {"J": {"1": {"initial": 2e-3, "tuned": 5e-4}, "2": {"initial": 1e-3, "tuned": 5e-4}}})
    fake_run(runs, "hmi-s1", "hmi_block", "2026-03-03T10:00:00.000+00:00", "2026-03-03T10:10:00.000+00:00",
             "completed", {"hmi": {"trials": 8, "hits": 7, "hit_pct": 87.5, "mean_time_s": 12.25}})
    fake_run(runs, "diag", "diagnosis", "2026-03-04T10:00:00.000+00:00", "2026-03-04T10:00:30.000+00:00",
             "completed", files={"diagnosis.json": {"effects_found": ["position_ripple", "payload"]}})
    fake_run(runs, "fric", "friction_sweep", "2026-03-05T10:00:00.000+00:00", "2026-03-05T10:00:20.000+00:00",
             "completed", {"chosen_model": {"1": "classic", "7": "stribeck"}})
    fake_run(runs, "ident", "identification", "2026-03-06T10:00:00.000+00:00", "2026-03-06T10:00:40.000+00:00",
             "completed", files={"identification.json": {"held_out_check": {"verdict": "worse"}}})
    fake_run(runs, "a-very-long-name-of-a-friction-sweep-on-a-cold-morning", "friction_sweep",
             "2026-03-07T08:00:00.000+00:00", None, "running", pid=dead_pid())
    fake_run(runs, "elsewhere", "rotation", "2026-03-08T08:00:00.000+00:00", None, "running", host="lab-pc-2",
             pid=1)
    fake_run(runs, "here-alive", "rotation", utc_now(), None, "running")     # this process: alive
    return runs


def test_list_newest_first_with_each_kinds_figure(lab):
    e = catalog.list_runs([lab])
    assert [x.name for x in e][:3] == ["here-alive", "elsewhere",
                                       "a-very-long-name-of-a-friction-sweep-on-a-cold-morning"]
    by = {x.name: x for x in e}
    assert by["rot-before-repair"].figures == {"rpe_max_pct": -7.25, "rpe_max_joint": 4}
    assert by["rot-before-repair"].duration_s == pytest.approx(83.5, abs=1e-9)
    assert by["ift-7dof"].figures["J_initial"] == pytest.approx(3e-3) and \
        by["ift-7dof"].figures["J_tuned"] == pytest.approx(1e-3)
    assert by["hmi-s1"].headline == "hit 7/8 12.2s"
    assert by["diag"].figures["effects_found"] == ["position_ripple", "payload"]
    assert by["fric"].figures["joints_identified"] == [1, 7]
    assert by["ident"].figures["held_out_verdict"] == "worse"
    assert by["a-very-long-name-of-a-friction-sweep-on-a-cold-morning"].status == "abandoned"
    assert by["elsewhere"].status == "running? (host lab-pc-2)"
    assert by["here-alive"].status == "running"


def test_a_runs_warnings_are_counted_beside_its_figure(tmp_path):
    """A rotation that held a joint at its torque limit read 'RPE 1.81 % j2' like a clean run (a new user's walk);
    its report's warnings are counted beside the figure, and in the figures."""
    sat = {"rpe_pct": {"2": 1.815}, "warnings": ["joint 2 at torque limit 4.85-7.50 s (2.6 s), peak -20.0 N m",
                                                 "joint 2 error > 0.05 rad 5.54-7.50 s (2.0 s), peak -0.196 rad"]}
    fake_run(tmp_path, "sat", "rotation", "2026-03-01T09:00:00.000+00:00", "2026-03-01T09:00:09.000+00:00",
             "completed", sat)
    fake_run(tmp_path, "one", "rotation", "2026-03-02T09:00:00.000+00:00", "2026-03-02T09:00:09.000+00:00",
             "completed", {"rpe_pct": {"7": 3.4}, "warnings": ["joint 7 error > 0.05 rad"]})
    by = {x.name: x for x in catalog.list_runs([tmp_path])}
    assert by["sat"].headline == "RPE 1.81 % j2; 2 warnings" and by["sat"].figures["warnings"] == 2
    assert by["one"].headline == "RPE 3.4 % j7; 1 warning"


def test_filters_and_json(lab):
    r = run_cli("runs", str(lab), "--json", "--kind", "rotation")
    assert r.code == 0, r.err
    assert [x["name"] for x in json.loads(r.out)["runs"]] == ["here-alive", "elsewhere", "rot-before-repair"]
    r = run_cli("runs", str(lab), "--json", "--status", "running")
    assert [x["name"] for x in json.loads(r.out)["runs"]] == ["here-alive", "elsewhere"]
    r = run_cli("runs", str(lab), "--json", "--status", "abandoned")
    assert len(json.loads(r.out)["runs"]) == 1
    r = run_cli("runs", str(lab), "--json", "--since", "2026-03-06")
    assert len(json.loads(r.out)["runs"]) == 4
    r = run_cli("runs", str(lab), "--json", "--since", "2026-03-07T09:00")
    assert len(json.loads(r.out)["runs"]) == 2
    r = run_cli("runs", str(lab), "--since", "yesterday-ish")
    assert r.code == 2 and r.err.count("\n") == 1 and "--since" in r.err
    r = run_cli("runs", str(lab / "nowhere"))
    assert r.code == 2 and "no such directory" in r.err


def test_one_line_per_run_at_80_columns(lab):
    r = run_cli("runs", str(lab), columns=80)
    assert r.code == 0, r.err
    lines = r.out.rstrip("\n").splitlines()
    assert len(lines) == 1 + 9 + 1                      # head, nine runs, the count
    assert max(len(x) for x in lines) <= 80
    assert lines[-1] == "9 runs"
    assert any("RPE -7.25 % j4" in x for x in lines), lines
    assert any("abandoned" in x and x.split()[2] == "friction" for x in lines), lines
    assert any("hit 7/8 12.2s" in x for x in lines) and any("1m24s" in x for x in lines)
    assert any("running?" in x and "(host lab-pc-2)" in x for x in lines)


def test_mark_abandoned_skips_live_and_other_hosts(lab):
    r = run_cli("runs", str(lab), "--mark-abandoned", "--json")
    out = json.loads(r.out)
    assert len(out["marked_abandoned"]) == 1
    m, _ = open_run(out["marked_abandoned"][0])
    assert (m["status"], m["reason"]) == ("interrupted", "process ended without closing the run")
    status = {x["name"]: x["manifest_status"] for x in out["runs"]}
    assert status["elsewhere"] == "running" and status["here-alive"] == "running"


def test_reused_pid_is_not_the_run(tmp_path):
    """A pid alive but started after the run (here: this test's process, for a run 'started' in 2020)."""
    d = fake_run(tmp_path, "old", "rotation", "2020-01-01T00:00:00.000+00:00", None, "running")
    assert catalog.shown_status(open_run(d)[0]) == "abandoned"
    d2 = fake_run(tmp_path, "init", "rotation", "2099-01-01T00:00:00.000+00:00", None, "running", pid=1)
    assert catalog.liveness(open_run(d2)[0]) == "dead"      # pid 1 is not a python/wamctl process


def test_index_page_links_every_report(lab):
    (Path(catalog.list_runs([lab], kind="ift")[0].path) / "report.html").write_text("<html></html>")
    r = run_cli("runs", str(lab), "--html", "--json")
    assert r.code == 0, r.err
    page = (lab / "index.html").read_text()
    assert page.count("<tr>") == 1 + 9 and "abandoned" in page and "href=\"2026-03-02T100000" in page
    assert "http" not in page          # no CDN, nothing fetched


def test_killed_run_is_abandoned_then_marked_and_reported(tmp_path):
    """A real `wamctl run` killed with SIGKILL once it has written chunks: listed `abandoned`, marked interrupted
    with every chunked sample in data.parquet, and `wamctl report` says abandoned before marking."""
    spec = rotation_spec(name="killed", rotation={"joints": [1, 2, 3, 4, 5, 6, 7], "mode": "one_at_a_time",
                                                  "amplitude_rad": -0.5, "velocity_rad_s": 0.083})
    p = tmp_path / "spec.yaml"
    p.write_text(yaml.safe_dump(spec))
    runs = tmp_path / "runs"
    proc = subprocess.Popen([sys.executable, "-m", "wamctl", "run", str(p), "--out", str(runs), "-q"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, cwd=ROOT)
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and len(list(runs.glob("*/data/part-*.parquet"))) < 2:
            time.sleep(0.05)
        assert len(list(runs.glob("*/data/part-*.parquet"))) >= 2
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
    run = next(runs.iterdir())
    rows = len(read_table(run))                  # the chunks, as the store reads them
    assert rows >= 5000
    [e] = catalog.list_runs([runs])
    assert e.status == "abandoned" and e.manifest_status == "running"
    r = run_cli("report", str(run), "--json")
    assert r.code == 0, r.err
    assert json.loads(r.out)["runs"][0]["status"] == "abandoned"
    r = run_cli("runs", str(runs), "--mark-abandoned", "--json")
    assert json.loads(r.out)["marked_abandoned"] == [str(run)]
    m, _ = open_run(run)
    assert (m["status"], m["reason"]) == ("interrupted", "process ended without closing the run")
    assert m["abandoned"]["rows"] == {"data": rows}
    data = pd.read_parquet(run / "data.parquet")
    assert len(data) == rows and not (run / "data").exists()
    assert np.all(np.diff(data["t_s"].to_numpy()) > 0)
    r = run_cli("report", str(run), "--json")
    assert r.code == 0 and json.loads(r.out)["runs"][0]["status"] == "interrupted"
    assert catalog.mark_abandoned(run) is False              # once only
    RunDir  # noqa: B018 - the store's writer is what marked it


def test_a_run_ending_rewrites_the_index(tmp_path):
    """`wamctl run` (the runner) rewrites <out>/index.html when a run ends, once `wamctl runs --html` made one,
    with a row linking its report; an index that cannot be written (a folder in its place) leaves the run
    completed; a folder without an index gets none."""
    p = tmp_path / "spec.yaml"
    rot = {"joints": [4], "amplitude_rad": -0.1, "velocity_rad_s": 0.05}
    p.write_text(yaml.safe_dump(rotation_spec(name="indexed", rotation=rot)))
    (tmp_path / "runs").mkdir()
    assert run_cli("runs", str(tmp_path / "runs"), "--html").code == 0
    assert (tmp_path / "runs" / "index.html").read_text().count("<tr>") == 1
    r = run_cli("run", str(p), "--out", str(tmp_path / "runs"), "-q", "--json")
    assert r.code == 0, r.err
    run = Path(json.loads(r.out)["run_dir"])
    page = (tmp_path / "runs" / "index.html").read_text()
    assert page.count("<tr>") == 2 and f'href="{run.name}/report.html"' in page
    (tmp_path / "runs2" / "index.html").mkdir(parents=True)
    r = run_cli("run", str(p), "--out", str(tmp_path / "runs2"), "-q", "--json")
    assert r.code == 0 and json.loads(r.out)["status"] == "completed"
    r = run_cli("run", str(p), "--out", str(tmp_path / "runs3"), "-q", "--json")
    assert r.code == 0 and [x.name for x in (tmp_path / "runs3").iterdir() if not x.is_dir()] == []
