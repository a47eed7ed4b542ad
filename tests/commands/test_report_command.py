"""`wamctl report` over run directories (issue 32): a run that did not complete says so on the first line, and
`wamctl report runs/*` can be run again (the combined report goes into a folder that is not a run; paths that
are not runs are skipped with a note)."""

from __future__ import annotations

import json
import shutil

import pytest
from cli_runs import ROTATION, run_cli, write_yaml


@pytest.fixture(scope="module")
def one_run(tmp_path_factory):
    """One small rotation run (a few seconds of arm time), made once for this module."""
    root = tmp_path_factory.mktemp("report_cmd")
    spec = dict(ROTATION, rotation=dict(ROTATION["rotation"], joints=[7]))
    r = run_cli("run", write_yaml(root / "rot.yaml", spec), "--out", root / "made", "--quiet")
    assert r.code == 0, r.err
    (run,) = (root / "made").iterdir()
    return run


def _copy(run, dest, **manifest):
    """A copy of ``run`` at ``dest`` with ``manifest`` fields changed."""
    shutil.copytree(run, dest)
    m = json.loads((dest / "manifest.json").read_text())
    m.update(manifest)
    (dest / "manifest.json").write_text(json.dumps(m))
    return dest


@pytest.mark.parametrize("status,reason", [("interrupted", "Ctrl-C (SIGINT) at t = 1.234 s"),
                                           ("failed", "joint 4 torque 31.2 N m over its limit 30 N m")])
def test_report_of_a_run_that_did_not_complete_says_so_on_its_first_line(one_run, tmp_path, status, reason):
    run = _copy(one_run, tmp_path / "r", status=status, reason=reason)
    for args in ((), ("--quiet",)):
        r = run_cli("report", run, *args)
        assert r.code == 0, r.err
        first = r.out.splitlines()[0]
        assert first == f"{status}: {reason}  run directory: {run}", first
    data = json.loads(run_cli("report", run, "--json").out)
    assert data["runs"] == [{"run_dir": str(run), "status": status, "reason": reason}]


def test_a_completed_run_gets_no_status_line(one_run, tmp_path):
    run = _copy(one_run, tmp_path / "r")
    r = run_cli("report", run)
    assert r.code == 0
    assert "run directory:" not in r.out
    assert r.out.splitlines()[0].startswith(json.loads((run / "report.json").read_text())["title"][:20])


def test_report_runs_star_can_be_run_twice(one_run, tmp_path):
    runs = tmp_path / "runs"
    a = _copy(one_run, runs / "a")
    b = _copy(one_run, runs / "b", seed=4)
    (runs / "notes.txt").write_text("a stray file among the runs\n")
    for attempt in (1, 2, 3):
        everything = sorted(runs.iterdir())                       # what the shell's runs/* gives
        r = run_cli("report", *everything)
        assert r.code == 0, (attempt, r.out[-500:], r.err)
        assert (runs / "combined-report" / "combined_report.html").is_file()
        assert not list(runs.glob("combined_report.*"))           # never among the runs
        assert f"skipped (a file, not a run directory): {runs / 'notes.txt'}" in r.out.splitlines()
        if attempt > 1:
            assert f"skipped (a combined report's folder): {runs / 'combined-report'}" in r.out.splitlines()
        combined = json.loads((runs / "combined-report" / "combined_report.json").read_text())
        assert [row["directory"] for row in combined["tables"]["runs"]] == [a.name, b.name]
        # its links reach each run's own report
        assert [row["report"] for row in combined["tables"]["runs"]] == ["../a/report.html", "../b/report.html"]


def test_report_of_nothing_but_non_runs_is_one_line_exit_2(tmp_path):
    (tmp_path / "x.txt").write_text("x")
    r = run_cli("report", tmp_path / "x.txt", tmp_path / "missing")
    assert r.code == 2 and r.exc is None
    assert r.err.strip().count("\n") == 0, r.err
    assert "x.txt: a file, not a run directory" in r.err and "missing: no such file or directory" in r.err


def test_export_prints_its_paths_whole(one_run, tmp_path):
    to = tmp_path / ("a-folder-name-long-enough-that-the-line-passes-eighty-columns-" + "y" * 30)
    r = run_cli("export", one_run, "--to", to)
    assert r.code == 0, r.err
    lines = [ln for ln in r.out.splitlines() if ln.startswith("exported ")]
    assert len(lines) == 1 and lines[0].endswith(f" -> {to}") and len(lines[0]) > 80, r.out


def test_diagnose_prints_its_run_directory_whole(one_run, tmp_path):
    """The path alone on its line, unwrapped: rich broke a path longer than the terminal mid-word."""
    long = tmp_path / ("a-folder-name-long-enough-that-the-path-passes-eighty-columns-" + "z" * 30)
    assert run_cli("export", one_run, "--to", tmp_path / "m").code == 0
    r = run_cli("diagnose", tmp_path / "m", "--out", long, "--quiet")
    assert r.code == 0, r.err
    (made,) = long.iterdir()
    assert f"run directory: {made}" in r.out.splitlines(), r.out
