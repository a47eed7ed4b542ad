"""``wamctl import FILE --format csv --columns MAP``, and ``wamctl import DIR`` of measured runs that name a wam4
or a subset of joints."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest
import yaml
from cli_runs import run_cli
from test_import_libbarrett import one_error_line

from wamctl.errors import DataFormatError
from wamctl.runs.measured import load_run_data

MAP = "t=time,q=pos{j},tau=torque{j},q_ref=cmd{j}"


def lab_csv(path, joints, n=400, rate_hz=250.0):
    t = 12.5 + np.arange(n) / rate_hz
    cols = {"time": t}
    for j in joints:
        q = 0.1 * j * np.sin(2 * np.pi * 0.3 * (t - 12.5))
        cols.update({f"pos{j}": q, f"torque{j}": 4.0 * q, f"cmd{j}": q + 2e-3, f"other{j}": 1.0})
    df = pd.DataFrame(cols)
    df.to_csv(path, index=False)
    return df


def test_a_csv_with_a_column_map(tmp_path):
    src = tmp_path / "lab.csv"
    df = lab_csv(src, [2, 4])
    r = run_cli("import", src, "--format", "csv", "--columns", MAP, "--robot", "wam7", "--joints", "2,4",
                "--torque", "total", "--out", tmp_path / "runs", "--json")
    assert r.code == 0, r.err
    run = json.loads(r.out)["run_dir"]
    data = pd.read_parquet(f"{run}/data.parquet")
    assert sorted(data.columns) == sorted(["t_s", "q_2_rad", "q_4_rad", "tau_2_Nm", "tau_4_Nm", "q_ref_2_rad",
                                           "q_ref_4_rad"])
    assert data["t_s"].iloc[0] == 0.0 and data["t_s"].iloc[-1] == pytest.approx(399 / 250.0, abs=1e-9)
    assert np.array_equal(data["tau_4_Nm"].to_numpy(), df["torque4"].to_numpy())
    meta = yaml.safe_load(open(f"{run}/spec.yaml"))["measured_meta"]
    assert meta["sample_rate_hz"] == 250.0 and meta["joints"] == [2, 4] and meta["torque"] == "total"


@pytest.mark.parametrize("args,expected", [
    (("--columns", "t=time,q=pos{j},tau=torque{j}", "--joints", "2,3"),
     "no column 'pos3' (q of joint 3 in --columns)"),
    (("--columns", "t=time,q=pos,tau=torque{j}", "--joints", "2,4"),
     "--columns: q=pos: a joint quantity's column names {j} (the joint number)"),
    (("--columns", "t=time,q=pos{j}", "--joints", "2,4"), "--columns: no tau"),
    (("--columns", MAP, "--joints", "4,2"), "--joints: expected joint numbers in increasing order"),
    (("--columns", MAP, "--joints", "2,9"), "--joints: joint numbers of wam7 are 1..7, got [9]"),
    (("--layout", "q[2]", "--columns", MAP), "--layout applies to --format libbarrett-csv / table only"),
])
def test_bad_column_maps_are_one_line_exit_2(tmp_path, args, expected):
    src = tmp_path / "lab.csv"
    lab_csv(src, [2, 4])
    r = run_cli("import", src, "--format", "csv", "--robot", "wam7", "--torque", "total", "--out", tmp_path / "runs",
                *args)
    line = one_error_line(r)
    assert expected in line, line


@pytest.mark.parametrize("column, cell, expected", [
    ("pos4", "n/a?", "data row 42, column pos4: 'n/a?' is not a number"),
    ("time", "12:00", "data row 42, column time: '12:00' is not a number"),
])
def test_a_cell_that_is_not_a_number_is_named_by_the_files_column(tmp_path, column, cell, expected):
    """The user's file has ``pos4``, not the run's ``q_4`` (which the message named before)."""
    src = tmp_path / "lab.csv"
    df = lab_csv(src, [2, 4]).astype({column: object})
    df.loc[41, column] = cell
    df.to_csv(src, index=False)
    r = run_cli("import", src, "--format", "csv", "--columns", MAP, "--robot", "wam7", "--joints", "2,4",
                "--torque", "total", "--out", tmp_path / "runs")
    line = one_error_line(r)
    assert line.endswith(expected), line


def test_a_file_without_format_is_told_the_formats(tmp_path):
    src = tmp_path / "lab.csv"
    lab_csv(src, [1])
    line = one_error_line(run_cli("import", src, "--out", tmp_path / "runs"))
    assert "not a measured-run directory (no meta.yaml); a log needs --format libbarrett-csv | jointstate-json | " \
           "rosbag | csv" in line


def measured_wam4(tmp_path, **meta_over):
    d = tmp_path / "m4"
    d.mkdir()
    t = np.arange(500) / 500.0
    cols = {"t": t}
    for j in range(1, 5):
        q = 0.2 * np.sin(2 * np.pi * t + j)
        cols.update({f"q_ref_{j}": q, f"q_{j}": q - 1e-3, f"tau_{j}": 3.0 * q})
    pd.DataFrame(cols).to_csv(d / "data.csv", index=False)
    meta = {"format": "wamctl-measured/1", "robot": "wam4", "sample_rate_hz": 500, "gravity_compensation": True,
            "controller": {"kind": "pd_g", "kp": [900, 2500, 600, 500]}, "experiment": {"kind": "free",
                                                                                        "joints": [1, 2, 3, 4]},
            "q0": [0.0, 0.0, 0.0, 1.57], "torque": "total", **meta_over}
    (d / "meta.yaml").write_text(yaml.safe_dump(meta))
    return d


def test_a_measured_run_of_a_wam4_imports_and_reports(tmp_path):
    d = measured_wam4(tmp_path)
    r = run_cli("import", d, "--out", tmp_path / "runs", "--json")
    assert r.code == 0, r.err
    run = json.loads(r.out)["run_dir"]
    assert json.loads(open(f"{run}/manifest.json").read())["kind"] == "measured"
    with pytest.raises(DataFormatError, match="robot wam4: not supported by this analysis yet"):
        load_run_data(run)
    rd = load_run_data(run, partial_ok=True)
    assert rd.col("q").shape == (500, 7) and np.isnan(rd.col("q")[:, 4:]).all()
    assert not np.isnan(rd.col("q")[:, :4]).any()
    assert run_cli("report", run, "--out", tmp_path / "rep").code == 0


@pytest.mark.parametrize("over,expected", [
    ({"q0": [0.0] * 7}, "meta.yaml: q0: List should have at most 4 items"),
    ({"controller": {"kind": "pd_g", "kp": [1.0] * 7}}, "meta.yaml: controller.kp: List should have at most 4 items"),
    ({"experiment": {"kind": "free", "joints": [5]}}, "experiment.joints: joint numbers of wam4 are 1..4, got [5]"),
    ({"joints": [1, 2]}, "column q_ref_3 is present but joint 3 is not logged (the joints logged: 1, 2)"),
    ({"torque": "estimated"}, "meta.yaml: torque: Input should be 'total', 'controller' or 'measured'"),
])
def test_bad_wam4_measured_runs_are_one_line_exit_2(tmp_path, over, expected):
    d = measured_wam4(tmp_path, **over)
    if "joints" in over:
        (d / "meta.yaml").write_text(yaml.safe_dump({**yaml.safe_load((d / "meta.yaml").read_text()),
                                                     "q0": [0.0, 0.0, None, None]}))
    line = one_error_line(run_cli("import", d, "--out", tmp_path / "runs"))
    assert expected in line, line


def test_a_full_wam7_log_with_reference_and_total_torque_reaches_the_analyses(tmp_path):
    src = tmp_path / "lab.csv"
    lab_csv(src, list(range(1, 8)), n=300)
    r = run_cli("import", src, "--format", "csv", "--columns", MAP, "--robot", "wam7", "--torque", "total",
                "--out", tmp_path / "runs", "--json")
    assert r.code == 0, r.err
    rd = load_run_data(json.loads(r.out)["run_dir"])          # no refusal: the analyses take it
    assert rd.col("tau").shape == (300, 7) and not np.isnan(rd.col("tau")).any()
    r = run_cli("import", src, "--format", "csv", "--columns", MAP, "--robot", "wam7", "--torque", "controller",
                "--out", tmp_path / "runs", "--json")
    with pytest.raises(DataFormatError, match=r"torque controller \(the controller's output, gravity compensation "
                                              r"added downstream and not logged\): not supported by this analysis"):
        load_run_data(json.loads(r.out)["run_dir"])


def test_an_imported_subset_exports_and_imports_again_as_it_was_logged(tmp_path):
    src = tmp_path / "lab.csv"
    df = lab_csv(src, [2, 4])
    r = run_cli("import", src, "--format", "csv", "--columns", MAP, "--robot", "wam7", "--joints", "2,4",
                "--torque", "controller", "--out", tmp_path / "runs", "--json")
    run = json.loads(r.out)["run_dir"]
    assert run_cli("export", run, "--to", tmp_path / "m", "--csv").code == 0
    meta = yaml.safe_load((tmp_path / "m" / "meta.yaml").read_text())
    assert meta["joints"] == [2, 4] and meta["torque"] == "controller" and meta["q0"][0] is None
    ext = pd.read_csv(tmp_path / "m" / "data.csv")
    assert sorted(ext.columns) == ["q_2", "q_4", "q_ref_2", "q_ref_4", "t", "tau_2", "tau_4"]
    r = run_cli("import", tmp_path / "m", "--out", tmp_path / "again", "--json")
    assert r.code == 0, r.err
    again = pd.read_parquet(json.loads(r.out)["run_dir"] + "/data.parquet")
    assert np.array_equal(again["q_4_rad"].to_numpy(), df["pos4"].to_numpy())


def test_a_header_without_rows_names_the_file(tmp_path):
    """A CSV of its header only said 'error: the time stamps never advance', naming no file."""
    src = tmp_path / "lab.csv"
    lab_csv(src, [2, 4]).iloc[:0].to_csv(src, index=False)
    r = run_cli("import", src, "--format", "csv", "--columns", MAP, "--robot", "wam7", "--joints", "2,4",
                "--torque", "total", "--out", tmp_path / "runs")
    assert one_error_line(r).endswith(f"{src}: the time stamps never advance (0 of them): no sample rate")


def test_a_folder_that_is_no_run_says_what_a_run_is(tmp_path):
    """`diagnose configs` said 'not a wamctl run directory (no manifest.json)', though a measured-run directory
    (meta.yaml) is taken too; a path that is not there said 'not a directory'."""
    (tmp_path / "configs").mkdir()
    for path, expected in ((tmp_path / "configs", "configs: neither a measured run (meta.yaml + data) nor a wamctl "
                                                  "run directory (manifest.json)"),
                           (tmp_path / "nowhere", "nowhere: no such directory")):
        with pytest.raises(DataFormatError) as exc:
            load_run_data(path)
        assert str(exc.value).endswith(expected), exc.value
