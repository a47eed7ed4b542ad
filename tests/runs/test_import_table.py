"""``wamctl import FILE --format table``: headerless tables of numbers, written the way lab recorders write them.

The fixtures are made here as the WAM identification recorders make them (``amir-noohian/barrett-ros-pkg-wam``,
``datadynamics_4dof_4_rowley_feasible.py``: ``" ".join(map(str, [time, *position, *effort]))`` per JointState
message, wall-clock stamps ``header.stamp.secs + nsecs * 1e-9`` at a jittered 250 Hz; and the ``_4dof`` files
its companion ``process_data.py`` writes with ``numpy.savetxt(fmt="%.10f")``); no header.
"""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest
import yaml
from cli_runs import run_cli

T0_S = 1762997429.9554934502           # a ROS wall-clock stamp, as the recordings have
N = 600


def signals(n: int = N, seed: int = 3) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    t = T0_S + np.cumsum(np.r_[0.0, 0.004 + rng.uniform(-2e-4, 2e-4, n - 1)])   # jittered 250 Hz stamps
    s = t - T0_S
    q = np.column_stack([0.4 * np.sin(2 * np.pi * 0.3 * s + j) for j in range(4)])
    tau = np.column_stack([3.0 * np.cos(2 * np.pi * 0.3 * s + j) - 7.0 * (j == 1) for j in range(4)])
    return t, q, tau


def write_str_join(path, t, q, tau) -> None:
    """The recorder's write_data: ``f.write(" ".join(map(str, line)) + "\\n")``."""
    path.write_text("".join(" ".join(map(str, [float(t[k]), *map(float, q[k]), *map(float, tau[k])])) + "\n"
                            for k in range(len(t))))


def imp(src, tmp_path, *extra, layout="t,q[4],tau[4]"):
    return run_cli("import", src, "--format", "table", "--layout", layout, "--robot", "wam4", "--torque", "total",
                   "--out", tmp_path / "runs", *extra)


def one_error_line(r) -> str:
    assert r.exc is None, r.tb
    lines = [ln for ln in r.err.splitlines() if ln.strip()]
    assert r.code == 2 and len(lines) == 1 and lines[0].startswith("error: "), (r.code, r.err)
    return lines[0]


def test_a_recorders_space_separated_log_becomes_a_wam4_run_timed_by_its_stamps(tmp_path):
    t, q, tau = signals()
    src = tmp_path / "rbtlog_0.dat"
    write_str_join(src, t, q, tau)
    r = imp(src, tmp_path, "--json")
    assert r.code == 0, r.err
    run = json.loads(r.out)["run_dir"]
    data = pd.read_parquet(f"{run}/data.parquet")
    assert len(data) == N
    # timed by the stamps, from the first (a 1.76e9 s wall clock keeps its 0.1 us digits through the subtraction)
    assert np.abs(data["t_s"].to_numpy() - (t - t[0])).max() < 1e-6
    assert np.abs(data["q_3_rad"].to_numpy() - q[:, 2]).max() < 1e-12
    assert np.abs(data["tau_2_Nm"].to_numpy() - tau[:, 1]).max() < 1e-12
    assert not any(c.startswith(("qd_", "q_ref_")) for c in data)        # not logged: absent, never zeros
    meta = yaml.safe_load(open(f"{run}/spec.yaml"))["measured_meta"]
    assert meta["robot"] == "wam4" and meta["torque"] == "total" and meta["gravity_compensation"] is True
    assert meta["sample_rate_hz"] == 250.0 and meta["experiment"]["joints"] == [1, 2, 3, 4]
    assert "from their median interval" in meta["imported"]["time"]


def test_numpy_savetxt_with_a_comment_header_and_a_reference_column(tmp_path):
    t, q, tau = signals()
    src = tmp_path / "rbtlog_0_4dof.dat"
    np.savetxt(src, np.column_stack([t, q, tau, q + 0.01]), fmt="%.10f", header="time q1..q4 tau1..tau4 qref1..4")
    r = imp(src, tmp_path, "--json", "--rate-hz", 250, layout="t,q[4],tau[4],q_ref[4]")
    assert r.code == 0, r.err
    data = pd.read_parquet(f"{json.loads(r.out)['run_dir']}/data.parquet")
    assert np.abs(data["q_ref_4_rad"].to_numpy() - (q[:, 3] + 0.01)).max() < 1e-9     # %.10f
    assert np.abs(data["tau_1_Nm"].to_numpy() - tau[:, 0]).max() < 1e-9


def test_a_gap_in_the_stamps_is_said_and_the_rows_stay_timed_by_them(tmp_path):
    t, q, tau = signals()
    keep = np.r_[0:300, 303:N]                   # three messages the recorder never got
    src = tmp_path / "gap.dat"
    write_str_join(src, t[keep], q[keep], tau[keep])
    r = imp(src, tmp_path, "--json")
    assert r.code == 0, r.err
    run = json.loads(r.out)["run_dir"]
    note = yaml.safe_load(open(f"{run}/spec.yaml"))["measured_meta"]["imported"]["time"]
    assert "1 interval(s) longer than 1.5 median intervals" in note and "before line 301" in note, note
    data = pd.read_parquet(f"{run}/data.parquet")
    assert data["t_s"].iloc[300] - data["t_s"].iloc[299] == pytest.approx(t[303] - t[299], abs=1e-6)


@pytest.mark.parametrize(("damage", "expected"), [
    ("short_line", "line 7 has 8 values (separated by white space); the layout 't,q[4],tau[4]' has 9"),
    ("wrong_layout", "every line has 9 values (separated by white space); the layout 't,q[4],qd[4],tau[4]' has 13"),
    ("time_back", "t does not increase at line 401"),
    ("text", "line 12, value 3 (q[2]): 'abc' is not a number"),
    ("no_t", "--layout: no t: --format table times its rows by their stamps"),
    ("no_layout", "--layout is needed with --format table"),
    ("wam7_for_4", "--layout 't,q[4],tau[4]' holds 4 joint(s) but --robot wam7 has 7"),
])
def test_bad_tables_are_one_line_exit_2(tmp_path, damage, expected):
    t, q, tau = signals()
    src = tmp_path / "bad.dat"
    if damage == "time_back":
        t = t.copy()
        t[400:] -= 0.5                           # two recordings joined
    write_str_join(src, t, q, tau)
    lines = src.read_text().splitlines()
    if damage == "short_line":
        lines[6] = lines[6].rsplit(" ", 1)[0]
    elif damage == "text":
        vals = lines[11].split(" ")
        vals[2] = "abc"
        lines[11] = " ".join(vals)
    src.write_text("\n".join(lines) + "\n")
    layout = {"wrong_layout": "t,q[4],qd[4],tau[4]", "no_t": "skip,q[4],tau[4]"}.get(damage, "t,q[4],tau[4]")
    args = ["import", src, "--format", "table", "--robot", "wam7" if damage == "wam7_for_4" else "wam4",
            "--torque", "total", "--out", tmp_path / "runs"]
    if damage != "no_layout":
        args += ["--layout", layout]
    line = one_error_line(run_cli(*args))
    assert expected in line, line
