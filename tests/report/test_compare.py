"""wamctl compare (issue 30): spec differences, tables side by side with differences, figures overlaid, a Welch
test with its interval on repeated measures, runs of different kinds refused in one line."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml
from cli_runs import run_cli
from conftest import rotation_spec

from wamctl.report.compare import compare, side_by_side, spec_differences, welch


def test_spec_differences_and_tables_side_by_side():
    d = spec_differences([{"seed": 1, "controller": {"kind": "pd_g", "kp": None}},
                          {"seed": 1, "controller": {"kind": "pd_g", "kp": [1, 2]}}], ["A", "B"])
    assert list(d.index) == ["controller.kp"] and d.loc["controller.kp", "B"] == "[1, 2]"
    s = side_by_side([pd.DataFrame({"joint": [1, 2], "rpe_pct": [2.0, 5.0]}),
                      pd.DataFrame({"joint": [1, 2], "rpe_pct": [1.5, 7.0]})], ["A", "B"])
    assert s["rpe_pct.ΔB"].tolist() == [-0.5, 2.0]


def test_welch_interval_matches_scipy_by_hand():
    rng = np.random.default_rng(0)
    a, b = rng.normal(10, 1, 20), rng.normal(11, 2, 25)
    r = welch(a, b)
    assert r["difference"] == pytest.approx(b.mean() - a.mean(), abs=1e-12)
    assert r["ci95_low"] < r["difference"] < r["ci95_high"]
    va, vb = a.var(ddof=1) / 20, b.var(ddof=1) / 25
    dof = (va + vb) ** 2 / (va ** 2 / 19 + vb ** 2 / 24)
    from scipy import stats
    half = stats.t.ppf(0.975, dof) * np.sqrt(va + vb)
    assert r["ci95_high"] - r["difference"] == pytest.approx(half, rel=1e-9)


def _hmi(tmp: Path, name: str, times: list[float]) -> Path:
    d = tmp / name
    d.mkdir()
    (d / "manifest.json").write_text(json.dumps({"kind": "hmi_block", "name": name, "status": "completed"}))
    (d / "spec.yaml").write_text(yaml.safe_dump({"kind": "hmi_block", "name": name}))
    pd.DataFrame({"trial": range(len(times)), "hit": 1, "time_s": times}).to_csv(d / "trials.csv", index=False)
    (d / "report.json").write_text(json.dumps({"title": name, "tables": {}}))
    return d


def test_repeated_measures_get_a_test_and_kinds_are_not_mixed(tmp_path):
    a = _hmi(tmp_path, "a", [10.0, 12.0, 11.0, 13.0])
    b = _hmi(tmp_path, "b", [8.0, 9.0, 8.5, 9.5])
    doc = compare([a, b], tmp_path / "out")
    t = doc.data["tests"]["time_s B - A"]
    assert t["difference"] == pytest.approx(-2.75) and t["ci95_high"] < 0
    c = tmp_path / "c"
    c.mkdir()
    (c / "manifest.json").write_text(json.dumps({"kind": "rotation", "name": "c", "status": "completed"}))
    r = run_cli("compare", str(a), str(c))
    assert r.code == 2 and r.err.count("\n") == 1 and "different kinds" in r.err


def test_rotation_runs_compared_with_overlaid_errors(tmp_path):
    runs = tmp_path / "runs"
    for name, kp4 in (("soft", 300.0), ("stiff", 1200.0)):
        rot = {"joints": [4], "amplitude_rad": -0.1, "velocity_rad_s": 0.05}
        kp = [900.0, 2500.0, 600.0, kp4, 50.0, 50.0, 8.0]
        spec = rotation_spec(name=name, rotation=rot, controller={"kind": "pd_g", "kp": kp})
        (tmp_path / f"{name}.yaml").write_text(yaml.safe_dump(spec))
        assert run_cli("run", str(tmp_path / f"{name}.yaml"), "--out", str(runs), "-q").code == 0
    soft, stiff = sorted(runs.glob("*-soft"))[0], sorted(runs.glob("*-stiff"))[0]
    r = run_cli("compare", str(soft), str(stiff), "--out", str(tmp_path / "cmp"), "--json")
    assert r.code == 0, r.err
    out = json.loads(r.out)["report"]
    assert out["tables"]["spec differences"][0]["key"] == "controller.kp"
    row = out["tables"]["rotation"][0]
    assert row["rpe_pct.ΔB"] == pytest.approx(row["rpe_pct.B"] - row["rpe_pct.A"], abs=1e-12)
    assert row["rpe_pct.ΔB"] < 0                       # the stiffer joint ends nearer its target
    assert (tmp_path / "cmp" / "compare_rotation_errors.png").stat().st_size > 10_000
    assert (tmp_path / "cmp" / "compare.html").is_file()


def test_tables_with_flags_and_repeated_keys_side_by_side():
    """A friction map's table: several rows per joint and a boolean column (subtracting it raised)."""
    a = pd.DataFrame({"joint": [1, 1, 7], "friction_Nm": [4.5, -4.4, 0.2], "accepted": [True, True, False]})
    b = a.assign(friction_Nm=[4.0, -4.0, 0.25])
    s = side_by_side([a, b], ["A", "B"])
    assert s["friction_Nm.ΔB"].round(12).tolist() == [-0.5, 0.4, 0.05] and "accepted.A" not in s


@pytest.mark.parametrize("kind", ["ift", "hmi_block"])
def test_ift_j_and_hmi_paths_are_overlaid(tmp_path, kind):
    """Two real runs of one kind: J per iteration (IFT) or every trial's hand path (HMI) of both
    runs drawn in one figure, each run its own line."""
    from cli_runs import HMI, IFT
    command, spec, png = (("tune-ift", IFT, "compare_ift_J.png") if kind == "ift"
                          else ("hmi-session", HMI, "compare_hmi_paths.png"))
    runs = []
    for i in (1, 2):         # the runs differ: one more IFT iteration, another virtual subject's seed
        changed = (dict(spec, ift=dict(spec["ift"], max_iterations=i)) if kind == "ift"
                   else dict(spec, hmi=dict(spec["hmi"], subject=dict(spec["hmi"]["subject"], seed=10 + i))))
        p = tmp_path / f"s{i}.yaml"
        p.write_text(yaml.safe_dump(changed))
        r = run_cli(command, p, "--out", tmp_path / "runs", "--quiet", "--json")
        assert r.code == 0, r.err
        runs.append(Path(json.loads(r.out)["run_dir"]))
    doc = compare(runs, tmp_path / "cmp")
    figure = tmp_path / "cmp" / png
    assert figure.stat().st_size > 10_000
    assert any(k == "fig" and b[0] == figure for k, b in doc.blocks)     # in the report
    assert (doc.tables()["thesis_table_5_1"] if kind == "ift" else doc.tables()["trials"]).shape[0] >= 1


def test_compare_of_a_runs_glob_skips_the_index_page_and_earlier_comparisons(tmp_path):
    """``wamctl compare runs/*`` as a user types it: the folder holds the index page and, after a first comparison,
    its ``compare/`` folder; neither is a run: skipped with why, as ``wamctl report runs/*`` skips them."""
    runs = tmp_path / "runs"
    runs.mkdir()
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
    runs.mkdir()
    a = _hmi(runs, "a", [10.0, 12.0])
    (runs / "index.html").write_text("<html></html>")
    r = run_cli("compare", a, runs / "index.html")
    assert r.code == 2 and r.err.count("\n") == 1
    assert "two or more run directories; skipped" in r.err and "index.html (a file, not a run directory)" in r.err
