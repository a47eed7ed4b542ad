"""Run directories: data.parquet and data.csv are written as a pair, whatever moment an interrupt comes."""

from __future__ import annotations

import pandas as pd
import pytest

import wamctl.runs.store as store
from wamctl.runs.store import RunDir, read_table


@pytest.mark.parametrize("stop_in", ["parquet", "csv"])
def test_an_interrupt_while_consolidating_leaves_both_files_or_neither(tmp_path, monkeypatch, stop_in):
    run = RunDir.create(tmp_path, "t", {"kind": "rotation"}, 0, "rotation")
    w = run.table("data", ["t_s", "q_1_rad"], chunk_rows=4)
    for i in range(10):
        w.append([i * 0.002, 0.1 * i])
    real_csv, real_parquet = store.write_csv, pd.DataFrame.to_parquet

    def stop(*a, **k):
        raise KeyboardInterrupt
    if stop_in == "csv":
        monkeypatch.setattr(store, "write_csv", stop)
    else:
        monkeypatch.setattr(pd.DataFrame, "to_parquet", lambda self, path, *a, **k: (
            real_parquet(self, path, *a, **k) if "part-" in str(path) else stop()))
    with pytest.raises(KeyboardInterrupt):
        w.close()
    names = {p.name for p in run.path.iterdir()}
    assert "data.parquet" not in names and "data.csv" not in names and not [n for n in names if n.endswith(".tmp")]
    assert len(read_table(run.path)) == 10          # every sample, from the chunks
    monkeypatch.setattr(store, "write_csv", real_csv)
    monkeypatch.setattr(pd.DataFrame, "to_parquet", real_parquet)
    w.close()
    assert len(pd.read_parquet(run.path / "data.parquet")) == len(pd.read_csv(run.path / "data.csv")) == 10


def test_out_naming_a_file_is_an_error_not_a_traceback(tmp_path):
    from wamctl.errors import WamctlError
    f = tmp_path / "runs"
    f.write_text("not a directory")
    with pytest.raises(WamctlError, match="is a file; the parent directory of the run directory must be a"):
        RunDir.create(f, "t", {}, 0, "rotation")


def test_a_truncated_parquet_table_is_a_data_error_naming_the_file(tmp_path):
    """Found by hand: `wamctl diagnose` on a run whose data.parquet was cut in half printed pyarrow's traceback."""
    from wamctl.errors import DataFormatError
    pd.DataFrame({"t_s": [0.0, 0.002, 0.004], "q1_rad": [0.0, 0.1, 0.2]}).to_parquet(tmp_path / "data.parquet")
    whole = (tmp_path / "data.parquet").read_bytes()
    (tmp_path / "data.parquet").write_bytes(whole[: len(whole) // 2])
    with pytest.raises(DataFormatError, match="data.parquet: not a readable Parquet file"):
        read_table(tmp_path)
