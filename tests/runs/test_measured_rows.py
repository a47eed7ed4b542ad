"""Row numbers in measured-run errors are the file's own, and long blocks of NaN rows are refused
(issue 32, item 7)."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
import yaml

from wamctl.errors import DataFormatError
from wamctl.runs.measured import read_measured

RATE_HZ = 500.0


def measured_dir(tmp_path, n_rows: int, name: str = "m"):
    """A small valid measured run (wam7, every joint) of ``n_rows`` rows at 500 Hz, as data.parquet."""
    t = np.arange(n_rows) / RATE_HZ
    cols = {"t": t}
    for j in range(1, 8):
        q = 0.1 * j * np.sin(2 * np.pi * 0.2 * t)
        cols.update({f"q_ref_{j}": q, f"q_{j}": q - 1e-3, f"tau_{j}": 2.0 * q})
    d = tmp_path / name
    d.mkdir()
    meta = {"format": "wamctl-measured/1", "robot": "wam7", "sample_rate_hz": RATE_HZ, "gravity_compensation": True,
            "controller": {"kind": "pd_g"}, "experiment": {"kind": "free", "joints": [1, 2, 3, 4, 5, 6, 7]},
            "q0": [0.0] * 7}
    (d / "meta.yaml").write_text(yaml.safe_dump(meta))
    return d, pd.DataFrame(cols)


def test_row_numbers_do_not_shift_by_the_nan_rows_dropped_before_them(tmp_path):
    d, df = measured_dir(tmp_path, 10_000)
    df.loc[[9, 4000], "q_2"] = np.nan            # data rows 10 and 4001: isolated, dropped
    df.loc[8001, "t"] = df.loc[8000, "t"]        # data row 8002 repeats the time of data row 8001
    df.to_parquet(d / "data.parquet", index=False)
    with pytest.raises(DataFormatError) as err:
        read_measured(d)
    assert "t is not strictly increasing at data row 8002 " in str(err.value)   # was 8000 (two rows dropped)


def test_a_block_of_nan_rows_is_an_error_naming_its_first_and_last_row(tmp_path):
    d, df = measured_dir(tmp_path, 30_000)
    df.loc[3000:3199, "tau_5"] = np.nan          # data rows 3001-3200: 200 rows, 0.67 % of the file
    df.to_parquet(d / "data.parquet", index=False)
    with pytest.raises(DataFormatError) as err:
        read_measured(d)
    msg = str(err.value)
    assert "data rows 3001-3200: 200 consecutive rows with NaN" in msg, msg
    assert len(msg.splitlines()) == 1


def test_blocks_of_up_to_four_nan_rows_are_dropped_with_a_count(tmp_path):
    d, df = measured_dir(tmp_path, 2_000)
    df.loc[100:103, "q_ref_3"] = np.nan          # 4 in a row: still isolated
    df.loc[[500, 1500], "tau_1"] = np.nan
    df.to_parquet(d / "data.parquet", index=False)
    rd = read_measured(d)
    assert len(rd.data) == 2_000 - 6
    df.loc[100:104, "q_ref_3"] = np.nan          # 5 in a row: refused
    df.to_parquet(d / "data.parquet", index=False)
    with pytest.raises(DataFormatError, match="data rows 101-105: 5 consecutive rows with NaN"):
        read_measured(d)


def test_csv_row_numbers_count_data_rows_after_the_header(tmp_path):
    d, df = measured_dir(tmp_path, 1_000)
    df.loc[5, "q_1"] = np.nan                    # dropped; data row 6
    df = df.astype(object)
    df.loc[700, "tau_3"] = "x"                   # data row 701 = line 702 of data.csv
    df.to_csv(d / "data.csv", index=False)
    with pytest.raises(DataFormatError, match=r"data row 701, column tau_3: 'x' is not a number"):
        read_measured(d)


def test_an_error_after_dropped_nan_rows_is_the_only_line(tmp_path):
    from cli_runs import wamctl_completed

    d, df = measured_dir(tmp_path, 3_000)
    df.loc[[9, 400], "q_2"] = np.nan
    df.loc[2000, "t"] = df.loc[1999, "t"]
    df.to_csv(d / "data.csv", index=False)
    # the warnings logged on stderr, as in a process of its own (logging is set up once per process)
    r = wamctl_completed("import", d, "--out", tmp_path / "runs", log_to_err=True)
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert r.returncode == 2 and len(lines) == 1, r.stderr   # was a 'dropped 2 rows' warning, then the error
    assert "t is not strictly increasing at data row 2001 " in lines[0]
