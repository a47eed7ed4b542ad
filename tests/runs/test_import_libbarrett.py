"""``wamctl import FILE --format libbarrett-csv``: logs written the way libbarrett writes them.

The fixtures are made here as libbarrett makes them: a ``systems::Ramp`` clock advanced once per 2 ms cycle
(``y += T_s * curGain``, ``smoothStart(d)`` growing ``curGain`` from 0 by ``T_s / d`` per cycle, as in
libbarrett's ramp.cpp), ``PeriodicDataLogger`` writing one record per cycle, ``log::Reader::exportCSV`` writing
each record as the tuple's values with ``std::ostream``'s defaults (``%g``: 6 significant digits), joined by
``,``, each line ended by ``std::endl``; no header.
"""

from __future__ import annotations

import json
import re

import numpy as np
import pandas as pd
import pytest
import yaml
from cli_runs import run_cli

RATE_HZ = 500.0
LAYOUT4 = "t,q_ref[4],qd_ref[4],q[4],qd[4],tau[4]"


def ramp(n: int, start_row: int = 10, smooth_s: float | None = 0.5, period_s: float = 1 / RATE_HZ) -> np.ndarray:
    """libbarrett's Ramp as the logger sees it, one value per cycle (slope 1)."""
    y, gain, out = 0.0, 0.0, np.empty(n)
    for k in range(n):
        if k >= start_row:
            gain = min(1.0, gain + period_s / smooth_s) if smooth_s else 1.0
            y += period_s * gain
        out[k] = y
    return out


def signals(n: int, n_joints: int) -> dict[str, np.ndarray]:
    t = np.arange(n) / RATE_HZ
    q_ref = np.column_stack([0.3 * np.sin(2 * np.pi * 0.5 * t + j) for j in range(n_joints)])
    return {"q_ref": q_ref, "qd_ref": np.gradient(q_ref, t, axis=0), "q": q_ref - 1e-3,
            "qd": np.gradient(q_ref, t, axis=0) * 0.99, "tau": 5.0 * q_ref}


def export_csv(path, rows: list[list[float]]) -> None:
    """log::Reader::exportCSV: ostream << double (6 significant digits), ',' between values, std::endl."""
    path.write_text("".join(",".join(f"{v:g}" for v in row) + "\n" for row in rows))


def wam4_log(path, n: int = 1500, t: np.ndarray | None = None) -> dict:
    s = signals(n, 4)
    t = ramp(n) if t is None else t
    rows = [[t[k], *s["q_ref"][k], *s["qd_ref"][k], *s["q"][k], *s["qd"][k], *s["tau"][k]] for k in range(n)]
    export_csv(path, rows)
    return s


def imp(src, tmp_path, *extra, layout=LAYOUT4, robot="wam4", torque="controller"):
    return run_cli("import", src, "--format", "libbarrett-csv", "--layout", layout, "--robot", robot,
                   "--rate-hz", 500, "--torque", torque, "--out", tmp_path / "runs", *extra)


def one_error_line(r) -> str:
    assert r.exc is None, r.tb
    lines = [ln for ln in r.err.splitlines() if ln.strip()]
    assert r.code == 2 and len(lines) == 1 and lines[0].startswith("error: "), (r.code, r.err)
    return lines[0]


def test_a_wam4_log_becomes_a_run_of_four_joints_timed_by_the_logger(tmp_path):
    src = tmp_path / "wam4.csv"
    s = wam4_log(src)
    r = imp(src, tmp_path, "--json")
    assert r.code == 0, r.err
    run = json.loads(r.out)["run_dir"]
    data = pd.read_parquet(f"{run}/data.parquet")
    assert len(data) == 1500
    # rows timed by the logger's period: exactly 2 ms apart from 0 (the Ramp lags 0.27 s after its slow start)
    assert data["t_s"].iloc[-1] == pytest.approx(1499 / RATE_HZ, abs=1e-12)
    assert np.diff(data["t_s"]).max() == pytest.approx(0.002, abs=1e-12)
    # four joints, nothing made up for 5-7
    assert sorted(c for c in data if c.startswith("q_")) == sorted(
        [f"q_{j}_rad" for j in range(1, 5)] + [f"q_ref_{j}_rad" for j in range(1, 5)])
    assert not any(c.endswith(("_5_rad", "_6_rad", "_7_rad", "_5_Nm")) for c in data)
    # the values as printed with 6 significant digits
    assert np.abs(data["q_3_rad"].to_numpy() - s["q"][:, 2]).max() < 5e-6
    assert np.abs(data["tau_4_Nm"].to_numpy() - s["tau"][:, 3]).max() < 5e-5
    assert np.abs(data["qd_ref_2_rad_s"].to_numpy() - s["qd_ref"][:, 1]).max() < 5e-5
    meta = yaml.safe_load(open(f"{run}/spec.yaml"))["measured_meta"]
    assert meta["robot"] == "wam4" and meta["torque"] == "controller" and meta["joints"] is None
    assert meta["sample_rate_hz"] == 500.0 and len(meta["q0"]) == 4 and meta["gravity_compensation"] is False
    assert meta["experiment"]["joints"] == [1, 2, 3, 4]


def test_libbarretts_time_conventions_are_said(tmp_path):
    src = tmp_path / "wam4.csv"
    wam4_log(src)
    r = imp(src, tmp_path)
    assert r.code == 0, r.err
    out = " ".join(r.out.split())
    assert "constant for the first 10 lines (the Ramp not yet started)" in out
    # smoothStart(0.5 s) from row 10: full pace about 250 rows later, 10 rows + 0.25 s behind the rows' clock
    full = int(re.search(r"at full pace from line (\d+)", out).group(1))
    assert 240 <= full <= 262, out
    lag = float(re.search(r"a smooth start: ([0-9.]+) s behind", out).group(1))
    assert lag == pytest.approx(0.27, abs=0.005)
    assert "slope 1.0000" in out and "rows timed by the logger's period (2 ms" in out


@pytest.mark.parametrize("t0_s", [120.0, 999.5, 5000.0])
def test_six_printed_digits_are_said_and_not_taken_for_a_slow_start(tmp_path, t0_s):
    """A Ramp running since long before the log: printed as 120.002, 1000, 1000.01, 5000, 5000 (1 ms and 10 ms
    steps at 2 ms a row): no standstill and no smooth start are made up from the rounding."""
    src = tmp_path / "late.csv"
    wam4_log(src, 2000, t=t0_s + np.arange(2000) / RATE_HZ)
    r = imp(src, tmp_path)
    assert r.code == 0, r.err
    out = " ".join(r.out.split())
    assert "printed with 6 digits, coarser than half a period from line 1 on" in out
    assert "not yet started" not in out and "smooth start" not in out, out
    slope = float(re.search(r"slope ([0-9.]+) of the logger's clock", out).group(1))
    assert abs(slope - 1.0) <= 0.002


def test_a_ramp_never_started_and_a_missing_t_are_said(tmp_path):
    src = tmp_path / "flat.csv"
    wam4_log(src, 200, t=np.zeros(200))
    r = imp(src, tmp_path)
    assert r.code == 0 and "t stays at 0 (the Ramp was not started)" in " ".join(r.out.split()), r.err
    r = imp(src, tmp_path, layout="skip,q_ref[4],qd_ref[4],q[4],qd[4],tau[4]")
    assert r.code == 0 and "no t in the layout" in " ".join(r.out.split()), r.err


def test_the_analyses_on_a_wam4_controller_log_and_the_report_reads_it(tmp_path):
    src = tmp_path / "wam4.csv"
    wam4_log(src)
    run = json.loads(imp(src, tmp_path, "--json").out)["run_dir"]
    # diagnose takes a wam4 (tests/analysis/test_diagnose_wam4.py) and, of the controller's torque, the joints whose
    # gravity torque is constant (tests/analysis/test_diagnose_controller_torque.py): joints 2-4 named with why
    r = run_cli("diagnose", run, "--out", tmp_path / "diagnose", columns=400)
    assert r.code == 0, r.err
    for j in (2, 3, 4):
        assert f"joint {j} not diagnosed: torque controller: gravity compensation not logged" in r.out, r.out
    # identify takes a wam4 (tests/analysis/test_identification_wam4.py) and, of the controller's torque, the joints
    # whose gravity torque is constant: joint 1 here; joints 2-4 moved and are refused with the reason
    r = run_cli("identify", run, "--out", tmp_path / "identify", "--json")
    assert r.code == 0, r.err
    check = json.loads(r.out)["held_out_check"]
    assert check["improved_joints"] == [1] and sorted(check["refused_joints"]) == ["2", "3", "4"]
    assert "gravity compensation not logged" in check["refused_joints"]["2"]
    # friction-id takes a wam4 (tests/runs/test_wam4_friction_id.py) and, of the controller's torque, the joints
    # without gravity: here joint 1 (a sine, no constant-velocity stage); joints 2-4 refused with the reason
    line = one_error_line(run_cli("friction-id", "--data", run, "--out", tmp_path / "fid"))
    assert "no joint could be identified (joint 1: too few usable constant-velocity segments" in line, line
    assert "joint 2: torque controller: gravity compensation not logged" in line, line
    r = run_cli("report", run, "--out", tmp_path / "rep", "--format", "json")
    assert r.code == 0, r.err
    table = json.loads((tmp_path / "rep" / "report.json").read_text())["tables"]["tracking"]
    rows = {row["joint"]: row for row in table}
    assert rows[3]["range_rad"] == pytest.approx(0.6, abs=1e-3)
    assert rows[6]["range_rad"] is None          # not logged: empty, never 0


def test_a_subset_of_a_wam7s_joints_with_joints(tmp_path):
    n = 600
    s = signals(n, 2)
    src = tmp_path / "two.csv"
    t = ramp(n, start_row=0, smooth_s=None)
    export_csv(src, [[t[k], *s["q"][k], *s["tau"][k], *s["q_ref"][k]] for k in range(n)])
    r = imp(src, tmp_path, layout="t,q[2],tau[2],q_ref[2]", robot="wam7", torque="total")
    line = one_error_line(r)
    assert "holds 2 joint(s) but --robot wam7 has 7: say which with --joints" in line
    r = imp(src, tmp_path, "--joints", "2,4", "--json", layout="t,q[2],tau[2],q_ref[2]", robot="wam7",
            torque="total")
    assert r.code == 0, r.err
    run = json.loads(r.out)["run_dir"]
    data = pd.read_parquet(f"{run}/data.parquet")
    assert sorted(c for c in data if c.startswith("tau_")) == ["tau_2_Nm", "tau_4_Nm"]
    assert np.abs(data["q_4_rad"].to_numpy() - s["q"][:, 1]).max() < 5e-6
    meta = yaml.safe_load(open(f"{run}/spec.yaml"))["measured_meta"]
    assert meta["joints"] == [2, 4] and meta["q0"][0] is None and meta["q0"][3] == pytest.approx(s["q"][0, 1],
                                                                                                 abs=5e-6)
    line = one_error_line(run_cli("diagnose", run, "--out", tmp_path / "d"))
    assert line.endswith("joint(s) 1, 3, 5, 6, 7 not logged (the analyses need all 7 joints of the wam7): "
                         "not supported by diagnose yet"), line


@pytest.mark.parametrize("damage,expected", [
    ("short_line", "line 7 has 20 values; the layout 't,q_ref[4],qd_ref[4],q[4],qd[4],tau[4]' has 21"),
    ("wrong_layout", "every line has 21 values; the layout 't,q_ref[4],qd_ref[4],q[4],qd[4],qdd[4],tau[4]' has 25"),
    ("ramp_reset", "t goes back at line 1001 ("),
    ("lost_records", "t jumps by 8 ms at line 801 (4.0 logger periods): records are missing"),
    ("wrong_rate", "t advances 2 ms a line (lines 751-1500) but --rate-hz 250 means 4 ms"),
    ("text", "line 12, value 3 (q_ref[2]): 'abc' is not a number"),
    ("no_torque", "--torque is needed with --format libbarrett-csv"),
    ("no_layout_q", "--layout: no q: a measured run needs the joint positions (q) and torques (tau)"),
    ("nan_block", "lines 301-310: 10 consecutive rows with NaN"),
])
def test_bad_libbarrett_logs_are_one_line_exit_2(tmp_path, damage, expected):
    src = tmp_path / "wam4.csv"
    t = ramp(1500)
    if damage == "ramp_reset":
        t[1000:] -= t[1000]                      # setOutput(0.0) between two moves
    wam4_log(src, t=t)
    lines = src.read_text().splitlines()
    layout, rate, extra = LAYOUT4, 500, ()
    if damage == "short_line":
        lines[6] = lines[6].rsplit(",", 1)[0]
    elif damage == "wrong_layout":
        layout = "t,q_ref[4],qd_ref[4],q[4],qd[4],qdd[4],tau[4]"
    elif damage == "lost_records":
        del lines[800:803]                       # three records the writer never wrote
    elif damage == "wrong_rate":
        rate = 250
    elif damage == "text":
        vals = lines[11].split(",")
        vals[2] = "abc"
        lines[11] = ",".join(vals)
    elif damage == "nan_block":
        for k in range(300, 310):                # a computed signal gone NaN (glibc prints -nan); t stays a number
            lines[k] = ",".join([lines[k].split(",")[0]] + ["-nan"] * 20)
    src.write_text("\n".join(lines) + "\n")
    args = ["import", src, "--format", "libbarrett-csv", "--layout", layout, "--robot", "wam4", "--rate-hz", rate,
            "--out", tmp_path / "runs", *extra]
    if damage != "no_torque":
        args += ["--torque", "controller"]
    if damage == "no_layout_q":
        args[args.index(layout)] = "t,skip[8],qd[4],skip[4],tau[4]"
    line = one_error_line(run_cli(*args))
    assert expected in line, line


def test_isolated_nan_records_are_dropped_and_counted_as_lines(tmp_path):
    src = tmp_path / "wam4.csv"
    wam4_log(src)
    lines = src.read_text().splitlines()
    lines[99] = ",".join([lines[99].split(",")[0]] + ["-nan"] * 20)
    vals = lines[1200].split(",")
    vals[5] = "nan"
    lines[1200] = ",".join(vals)
    src.write_text("\n".join(lines) + "\n")
    r = imp(src, tmp_path, "--json")
    assert r.code == 0, r.err
    data = pd.read_parquet(json.loads(r.out)["run_dir"] + "/data.parquet")
    assert len(data) == 1498
    assert data["t_s"].iloc[99] == pytest.approx(100 / RATE_HZ)      # line 101's time: line 100 left out
