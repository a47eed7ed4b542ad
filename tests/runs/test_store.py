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


# ------------------------------------------------------------------------------ issue 32: interrupts, storage
def test_a_chunk_write_cut_by_an_exception_is_retried_without_losing_or_repeating_a_row(tmp_path, monkeypatch):
    """The demo's crash: Ctrl-C inside a chunk's to_parquet left the buffer full, and the retry in close() hit
    `IndexError: index 2500 is out of bounds`; re-appending the recorder's rows would also repeat them."""
    import numpy as np

    run = RunDir.create(tmp_path, "t", {"kind": "rotation"}, 0, "rotation")
    w = run.table("data", ["t_s", "q_1_rad"], chunk_rows=4)
    rows = np.column_stack([0.002 * np.arange(11), 0.1 * np.arange(11)])
    real = pd.DataFrame.to_parquet
    calls = {"n": 0}

    def cut_second(self, path, *a, **k):
        calls["n"] += 1
        if calls["n"] == 2:
            raise KeyboardInterrupt
        return real(self, path, *a, **k)
    monkeypatch.setattr(pd.DataFrame, "to_parquet", cut_second)
    with pytest.raises(KeyboardInterrupt):
        w.sync(rows, 9)                     # the second chunk (rows 4-7) is cut
    monkeypatch.setattr(pd.DataFrame, "to_parquet", real)
    w.sync(rows, 9)                         # the recorder's retry with the same rows: nothing repeated
    w.append(rows[9])                       # and appending goes on (was IndexError)
    w.sync(rows, 11)
    df = w.close()
    np.testing.assert_array_equal(df.to_numpy(), rows)
    assert w.close().shape == (11, 2)       # idempotent
    assert not (run.path / "data").exists() and not list(run.path.glob(".*.tmp"))


def test_the_chunks_go_once_data_parquet_holds_their_rows_and_stay_otherwise(tmp_path):
    import numpy as np

    from wamctl.runs.store import remove_chunks
    run = RunDir.create(tmp_path, "t", {"kind": "rotation"}, 0, "rotation")
    w = run.table("data", ["t_s"], chunk_rows=3)
    for i in range(7):
        w.append([i * 0.002])
    w.flush()
    assert len(list((run.path / "data").glob("part-*.parquet"))) == 3
    pd.DataFrame({"t_s": np.zeros(6)}).to_parquet(run.path / "data.parquet")     # one row short: kept
    assert not remove_chunks(run.path, "data", 7) and len(list((run.path / "data").iterdir())) == 3
    (run.path / "data.parquet").write_bytes(b"PAR1 cut")                          # unreadable: kept
    assert not remove_chunks(run.path, "data", 7)
    (run.path / "data.parquet").unlink()
    assert len(read_table(run.path)) == 7                                         # read from the chunks
    assert len(w.close()) == 7 and not (run.path / "data").exists()
    assert len(read_table(run.path)) == 7


def test_data_csv_keeps_9_significant_digits_of_each_column_in_fewer_bytes(tmp_path):
    import io

    import numpy as np

    from wamctl.runs.store import CSV_SIGNIFICANT_DIGITS, write_csv
    rng = np.random.default_rng(0)
    n = 5000
    df = pd.DataFrame({"t_s": 0.002 * np.arange(n), "q_1_rad": 0.5 * np.sin(np.arange(n) / 700) + 1e-5 *
                       rng.standard_normal(n), "tau_1_Nm": 17.0 * rng.standard_normal(n),
                       "qd_true_7_rad_s": 1e-18 * rng.standard_normal(n), "flag": np.arange(n) % 3})
    df.loc[10, "q_1_rad"] = np.nan
    run = RunDir.create(tmp_path, "t", {"kind": "rotation"}, 0, "rotation")
    run.write_table("data", df)
    back = pd.read_csv(run.path / "data.csv")
    pd.testing.assert_frame_equal(pd.read_parquet(run.path / "data.parquet"), df)      # every bit
    for c in df.columns:
        err = np.nanmax(np.abs(back[c].to_numpy() - df[c].to_numpy()))
        assert err <= 0.5 * 10.0 ** -CSV_SIGNIFICANT_DIGITS * np.nanmax(np.abs(df[c])) * 10, c
    assert np.isnan(back.loc[10, "q_1_rad"]) and (back["flag"] == df["flag"]).all()
    # a column below 1e-13 (numerically zero in SI units) would need more than 22 decimals: written exactly
    np.testing.assert_array_equal(back["qd_true_7_rad_s"], df["qd_true_7_rad_s"])
    text = (run.path / "data.csv").read_text()
    assert "\n0.084,0.0" in text                               # times as written: 0.084, not 0.08400000000000001
    usual = df.drop(columns="qd_true_7_rad_s")
    compact, full = io.BytesIO(), io.BytesIO()
    write_csv(usual, compact, CSV_SIGNIFICANT_DIGITS)
    write_csv(usual, full)                                     # shortest round-trip form of every bit
    assert len(compact.getvalue()) < 0.65 * len(full.getvalue())   # 0.64 here (short times and flags in both)


def test_events_csv_times_to_the_microsecond(tmp_path):
    run = RunDir.create(tmp_path, "t", {"kind": "rotation"}, 0, "rotation")
    t = 4262 * 0.002
    assert repr(t) == "8.524000000000001"
    run.event(t, "segment", 2, "move joint 2")
    run.event(1 / 3, "note")
    run.finish("completed")
    lines = (run.path / "events.csv").read_text().splitlines()
    assert lines[1] == "8.524,segment,2,move joint 2" and lines[2] == "0.333333,note,,"


def test_signals_are_held_back_inside_the_block_and_delivered_after(tmp_path):
    import os
    import signal

    from wamctl.runs.store import signals_deferred
    seen = []
    with pytest.raises(KeyboardInterrupt):
        with signals_deferred():
            with signals_deferred():
                os.kill(os.getpid(), signal.SIGINT)
                for _ in range(1000):         # Python would have run the handler by now
                    seen.append(1)
            seen.append("inner block ended")
        seen.append("not reached")
    assert seen[-1] == "inner block ended" and len(seen) == 1001
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
