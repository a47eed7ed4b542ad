"""A run that ended before its first sample was recorded (a sweep point killed while its backend was built, before
its data table existed) gets a report that says so, not "no data table" and exit 2.

Seen in the full suite on a fresh clone (test_sweep_killed, 2026-11-27): one of the points the sweep's kill left
behind had a manifest and no table yet; `wamctl report` on it failed. A run with its data folder and no chunk
yet was already reported (an empty table).
"""

from __future__ import annotations

import json

from cli_runs import run_cli

from wamctl.runs.store import RunDir


def _killed_before_recording(tmp_path):
    spec = {"kind": "rotation", "name": "tiny"}
    run = RunDir.create(tmp_path, "tiny", spec, 0, "rotation", {"backend": {"name": "sim"}})
    run.update_manifest(status="interrupted", reason="abandoned: its process is gone")
    return run.path


def test_a_run_with_no_table_is_reported_as_nothing_recorded(tmp_path):
    path = _killed_before_recording(tmp_path)
    r = run_cli("report", str(path), "--out", str(tmp_path / "rep"), "--json")
    assert r.code == 0, r.err
    md = (tmp_path / "rep" / "report.md").read_text()
    assert "nothing recorded" in md and "before its first sample was recorded" in md
    assert "abandoned: its process is gone" in md
    assert json.loads((tmp_path / "rep" / "report.json").read_text())["samples"] == 0


def test_a_completed_run_without_its_table_is_still_an_error(tmp_path):
    path = _killed_before_recording(tmp_path)
    m = json.loads((path / "manifest.json").read_text())
    (path / "manifest.json").write_text(json.dumps(dict(m, status="completed", reason=None)))
    r = run_cli("report", str(path), "--out", str(tmp_path / "rep"))
    assert r.code != 0 and "no data table" in r.err
