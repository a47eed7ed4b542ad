"""Reading the output (issue 32, item 12): units keep their slash in terminal headers, counts print as
integers, the sweep's result comes first (report) and is printed (terminal), long paths are printed whole."""

from __future__ import annotations

import json
import re

import pandas as pd
import pytest
from cli_runs import run_cli, write_yaml

from wamctl.report.document import Document, column_label


@pytest.mark.parametrize("name,label", [
    ("speed_peak_rad_s", "speed peak (rad/s)"), ("sigma2_pos_Nm_s_rad", "sigma2 pos (N m s/rad)"),
    ("viscous_neg_Nm_s_rad", "viscous neg (N m s/rad)"), ("acceleration_peak_rad_s2", "acceleration peak (rad/s²)"),
    ("fc_pos_Nm", "fc pos (N m)"), ("t_s", "t (s)"), ("hit_pct", "hit (%)"), ("I1_kg_m2", "I1 (kg m²)"),
    ("bytes_per_s", "bytes/s"), ("rpe_pct.3", "rpe.3 (%)"), ("joint", "joint"), ("n_points", "n points")])
def test_column_labels_keep_their_units(name, label):
    assert column_label(name) == label


def test_terminal_headers_read_rad_per_s_and_n_m_s_per_rad(small_runs, tmp_path):
    """friction-id's tables on the terminal (its viscous coefficients in N m s/rad), at 80 columns and, through
    `wamctl report`, at 40: a header wraps between words, never inside its unit."""
    out = small_runs.printed["friction-id"].out
    assert "(N m s/rad)" in out and "(N m)" in out, out
    assert "Nm s rad" not in out
    r = run_cli("report", small_runs.runs["friction_sweep"], "--out", tmp_path, columns=40)
    assert r.code == 0, r.err[-2000:]
    assert "(N m s/rad)" in r.out, r.out


def test_a_count_row_under_means_prints_integers():
    df = pd.DataFrame({"E1": [37.0, 50.0, 49.111, 17.091, 9.0], "E2": [75.0, 87.5, 71.625, 18.554, 8.0]},
                      index=pd.Index(["1", "2", "Mean", "SD", "n"], name="subject"))
    names, rows, _ = Document("t").table("a", df).blocks[0][1].cells()
    assert rows[-1] == ["n", "9", "8"]                      # was 9.000, 8.000
    assert rows[2] == ["Mean", "49.111", "71.625"] and rows[0] == ["1", "37.000", "75.000"]  # one format per column
    md = Document("t").table("a", df).to_markdown()
    assert "| n | 9 | 8 |" in md


@pytest.fixture(scope="module")
def sweep_cli(small_runs):
    """``wamctl sweep`` of two points on an in-process Dask scheduler, into a folder whose path is longer than 80
    characters: what it printed and its sweep directory (one of the small runs, tests/cli_runs.py; this module
    had made the same sweep again)."""
    return small_runs.printed["sweep"], small_runs.runs["sweep"]


def test_the_sweep_command_prints_its_result(sweep_cli):
    r, sweep_dir = sweep_cli
    rep = json.loads((sweep_dir / "report.json").read_text())
    summary = {row["figure"]: row for row in rep["tables"]["summary"]}
    assert set(summary) == {"rpe_pct.1", "rpe_pct.7"} and {row["n"] for row in summary.values()} == {2}
    assert "sweep tiny: Key figures over the 2 completed points" in r.out
    for fig, row in summary.items():     # each figure's line: n, mean, sd, min, max as the report has them
        line = next(ln for ln in r.out.splitlines() if ln.startswith(fig + " "))
        n, mean, sd, lo, hi = map(float, line.split()[1:6])
        assert n == 2
        for got, want in ((mean, row["mean"]), (sd, row["sd"]), (lo, row["min"]), (hi, row["max"])):
            assert got == pytest.approx(want, rel=1e-3, abs=1e-4), (fig, line)
    assert "sweep tiny: Mean key figures by seed" in r.out


def test_the_sweep_report_puts_its_result_before_the_point_tables(sweep_cli):
    _, sweep_dir = sweep_cli
    rep = json.loads((sweep_dir / "report.json").read_text())
    assert list(rep["tables"]) == ["summary", "by_seed", "sd_by_seed", "points", "key_figures"]
    md = (sweep_dir / "report.md").read_text()
    assert md.index("## Key figures over the 2 completed points") < md.index("## Points")


def test_long_paths_are_printed_whole(sweep_cli):
    r, sweep_dir = sweep_cli
    assert len(str(sweep_dir)) > 80
    lines = r.out.splitlines()
    assert f"completed  sweep directory: {sweep_dir}" in lines
    assert f"report: {sweep_dir / 'report.html'}" in lines
    # a status line of `wamctl report` and the files it wrote: whole paths too
    point = json.loads((sweep_dir / "index.json").read_text())["points"][0]
    rep = run_cli("report", sweep_dir / point["run_dir"])
    assert rep.code == 0, rep.err
    wrote = [ln for ln in rep.out.splitlines() if ln.startswith("wrote ")]
    assert len(wrote) == 3 and all(re.fullmatch(r"wrote /\S+/report\.(md|html|json)", ln) for ln in wrote), wrote
    assert all(len(ln) > 80 for ln in wrote)


def test_run_help_names_every_kind_a_spec_can_have():
    from wamctl.specs.registry import SPEC_KINDS

    r = run_cli("run", "--help", columns=200)
    first = " ".join(r.out.split()).split("Run any experiment spec (")[1].split(")")[0]
    assert sorted(first.split(", ")) == sorted(SPEC_KINDS) and "excitation" in SPEC_KINDS


@pytest.mark.parametrize("field,value,said", [
    ("plant.friction", "table_4_2", "'table_4_2' is neither a friction name (table_4_1, none) nor a friction model "
                                    "file; did you mean table_4_1?"),
    ("plant.friction", "Table41", "'Table41' is neither a friction name (table_4_1, none) nor a friction model "
                                  "file; did you mean table_4_1?"),
    ("plant.friction", "datasheet", "'datasheet' is neither a friction name (table_4_1, none) nor a friction "
                                    "model file"),
    ("controller.friction_ff", "tabel_4_1", "'tabel_4_1' is neither a friction name (table_4_1, none) nor a "
                                            "friction model file; did you mean table_4_1?"),
    ("plant.friction", "missing.yaml", "friction model file not found: missing.yaml")])
def test_a_misspelt_friction_name_gets_the_valid_names(tmp_path, field, value, said):
    spec = {"kind": "rotation", "name": "x", "rotation": {"joints": [7]}}
    if field == "plant.friction":
        spec["plant"] = {"friction": value}
    else:
        spec["controller"] = {"kind": "pd_g_ff", "friction_ff": value}
    for cmd in ("validate", "run --dry-run"):
        r = run_cli(*cmd.split(), write_yaml(tmp_path / "s.yaml", spec))
        assert r.code == 2 and r.exc is None
        assert r.err.strip().splitlines() == [f"error: {tmp_path / 's.yaml'}: {field}: {said}"], r.err
