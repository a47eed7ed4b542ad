"""``wamctl compare runs/*`` as a user types it (issue 30): the folder holds the index page (`wamctl runs --html`,
rewritten when a run ends) and, after a first comparison, its ``compare/`` folder; neither is a run. They are
skipped with why, as ``wamctl report runs/*`` skips them, so the same command works every time."""

from __future__ import annotations

import json
from pathlib import Path

import pandas as pd
import yaml
from cli_runs import run_cli


def _hmi(runs: Path, name: str, times: list[float]) -> Path:
    d = runs / name
    d.mkdir(parents=True)
    (d / "manifest.json").write_text(json.dumps({"kind": "hmi_block", "name": name, "status": "completed"}))
    (d / "spec.yaml").write_text(yaml.safe_dump({"kind": "hmi_block", "name": name}))
    pd.DataFrame({"trial": range(len(times)), "hit": 1, "time_s": times}).to_csv(d / "trials.csv", index=False)
    (d / "report.json").write_text(json.dumps({"title": name, "tables": {}}))
    return d


def test_compare_of_a_runs_glob_skips_the_index_page_and_earlier_comparisons(tmp_path):
    runs = tmp_path / "runs"
    _hmi(runs, "20261127T000000Z-a", [10.0, 12.0, 11.0, 13.0])
    _hmi(runs, "20261127T000100Z-b", [8.0, 9.0, 8.5, 9.5])
    (runs / "index.html").write_text("<html></html>")
    for attempt in (1, 2):                         # the second sees runs/compare from the first
        r = run_cli("compare", *sorted(runs.iterdir()), "--quiet")
        assert r.code == 0, r.err
        assert f"skipped (a file, not a run directory): {runs / 'index.html'}" in r.out
        assert (f"skipped (not a wamctl run directory (no manifest.json)): {runs / 'compare'}" in r.out) == \
            (attempt == 2)
        assert (runs / "compare" / "compare.html").is_file()
    r = run_cli("compare", *sorted(runs.iterdir()), "--json")
    doc = json.loads(r.out)["report"]
    assert doc["runs"] == [str(runs / "20261127T000000Z-a"), str(runs / "20261127T000100Z-b")]
    assert {s["path"] for s in doc["skipped"]} == {str(runs / "index.html"), str(runs / "compare")}
    assert doc["tests"]["time_s B - A"]["difference"] == -2.75


def test_one_run_left_after_skipping_is_one_line(tmp_path):
    runs = tmp_path / "runs"
    a = _hmi(runs, "a", [10.0, 12.0])
    (runs / "index.html").write_text("<html></html>")
    r = run_cli("compare", a, runs / "index.html")
    assert r.code == 2 and r.err.count("\n") == 1
    assert "two or more run directories; skipped" in r.err and "index.html (a file, not a run directory)" in r.err
