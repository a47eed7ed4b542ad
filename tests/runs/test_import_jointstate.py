"""``wamctl import FILE --format jointstate-json | rosbag``: ``sensor_msgs/JointState`` logs as wam_node-based
loggers dump them (JSON records of time, name, position, velocity, effort) and as ROS 1 and ROS 2 bags made
here with the ``rosbags`` package's own writers."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest
import yaml
from cli_runs import run_cli
from test_import_libbarrett import one_error_line

RATE_HZ = 500.0
WAM_NODE_NAMES = [f"wam_j{j}" for j in range(1, 8)]          # barrett-ros-pkg's wam_node
T0_S = 1_700_000_000.25


def states(n: int, n_joints: int = 7, jitter_s: float = 2e-5, seed: int = 1):
    rng = np.random.default_rng(seed)
    t = T0_S + np.arange(n) / RATE_HZ + rng.uniform(-jitter_s, jitter_s, n)
    q = np.column_stack([0.2 * np.sin(2 * np.pi * 0.4 * (t - T0_S) + j) for j in range(n_joints)])
    return t, q, 0.5 * q, 3.0 * q


def json_log(path, n: int = 800, names=WAM_NODE_NAMES, stamp="secs") -> tuple:
    t, q, qd, tau = states(n, len(names))
    recs = []
    for k in range(n):
        sec = int(t[k])
        time = {"secs": sec, "nsecs": int(round((t[k] - sec) * 1e9))} if stamp == "secs" else float(t[k])
        recs.append({"time": time, "name": list(names), "position": q[k].tolist(), "velocity": qd[k].tolist(),
                     "effort": tau[k].tolist()})
    path.write_text(json.dumps(recs))
    return recs, (t, q, qd, tau)


def imp(src, tmp_path, fmt, *extra, robot="wam7", torque="total"):
    return run_cli("import", src, "--format", fmt, "--robot", robot, "--torque", torque, "--out", tmp_path / "runs",
                   *extra)


def run_data(r):
    assert r.code == 0, r.err
    run = json.loads(r.out)["run_dir"]
    return pd.read_parquet(f"{run}/data.parquet"), yaml.safe_load(open(f"{run}/spec.yaml"))["measured_meta"], run


def test_a_wam_node_json_dump_becomes_a_run(tmp_path):
    src = tmp_path / "js.json"
    _, (t, q, qd, tau) = json_log(src)
    data, meta, run = run_data(imp(src, tmp_path, "jointstate-json", "--json"))
    assert len(data) == 800
    assert data["t_s"].iloc[0] == 0.0 and data["t_s"].iloc[-1] == pytest.approx(t[-1] - t[0], abs=1e-6)
    assert np.abs(data["q_5_rad"].to_numpy() - q[:, 4]).max() < 1e-12
    assert np.abs(data["qd_7_rad_s"].to_numpy() - qd[:, 6]).max() < 1e-12
    assert np.abs(data["tau_1_Nm"].to_numpy() - tau[:, 0]).max() < 1e-12
    assert not any(c.startswith("q_ref") for c in data)        # a JointState has no reference: none made up
    assert meta["robot"] == "wam7" and meta["torque"] == "total" and meta["sample_rate_hz"] == 500.0
    # the analyses take it, the measured positions standing in for the reference (tests/analysis/
    # test_no_reference.py); a file with a reference the analyses would use is not made up here
    assert "reference" not in meta


def test_a_wam4_with_a_hand_keeps_the_arms_joints(tmp_path):
    src = tmp_path / "js.json"
    names = WAM_NODE_NAMES[:4] + ["bhand_j11_joint", "bhand_j12_joint"]
    _, (_, q, _, _) = json_log(src, 300, names=names, stamp="float")
    r = imp(src, tmp_path, "jointstate-json", "--json", robot="wam4", torque="controller")
    data, meta, _ = run_data(r)
    assert sorted(c for c in data if c.startswith("tau_")) == [f"tau_{j}_Nm" for j in range(1, 5)]
    assert np.abs(data["q_4_rad"].to_numpy() - q[:, 3]).max() < 1e-12
    assert meta["robot"] == "wam4" and meta["joints"] is None and "bhand_j11_joint" in meta["notes"]


@pytest.mark.parametrize("damage,expected", [
    ("no_effort", "record 5: no 'effort'"),
    ("backwards", "t is not strictly increasing at record 40"),
    ("short_position", "record 3: position has 6 values, record 1's position has 7"),
    ("empty_effort", "record 1: effort has an empty list: the log holds no torque"),
    ("not_a_list", "expected a JSON list of records"),
    ("bad_time", "record 2: time is 'soon': expected seconds or {secs, nsecs}"),
    ("unknown_names", "joint names ['a', 'b', 'c', 'd', 'e', 'f', 'g'] are not wam_node's"),
    ("rate", "sample_rate_hz is 250 but t says 499.9 Hz (more than 5 % apart)"),
])
def test_bad_json_logs_are_one_line_exit_2(tmp_path, damage, expected):
    src = tmp_path / "js.json"
    recs, _ = json_log(src, 100)
    extra = []
    if damage == "no_effort":
        del recs[4]["effort"]
    elif damage == "backwards":
        recs[39]["time"] = recs[38]["time"]
    elif damage == "short_position":
        recs[2]["position"] = recs[2]["position"][:6]
    elif damage == "empty_effort":
        for r in recs:
            r["effort"] = []
    elif damage == "not_a_list":
        recs = {"records": recs}
    elif damage == "bad_time":
        recs[1]["time"] = "soon"
    elif damage == "unknown_names":
        for r in recs:
            r["name"] = list("abcdefg")
    elif damage == "rate":
        extra = ["--rate-hz", "250"]
    src.write_text(json.dumps(recs))
    line = one_error_line(imp(src, tmp_path, "jointstate-json", *extra))
    assert expected in line, line


# ------------------------------------------------------------------------------------------------ rosbags
def write_bag(path, ros: int, topics: dict[str, str], n: int = 200):
    """A bag written by rosbags' own writer: ``topics`` maps a topic to its type; JointState topics get wam_node's
    messages, stamped in their headers."""
    from rosbags.rosbag1 import Writer as Writer1
    from rosbags.rosbag2 import Writer as Writer2
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS1_NOETIC if ros == 1 else Stores.ROS2_HUMBLE)
    js, header, time_t = (ts.types[k] for k in ("sensor_msgs/msg/JointState", "std_msgs/msg/Header",
                                                 "builtin_interfaces/msg/Time"))
    string = ts.types["std_msgs/msg/String"]
    t, q, qd, tau = states(n)
    writer = Writer1(path) if ros == 1 else Writer2(path, version=9)
    with writer as w:
        conns = {tp: w.add_connection(tp, ty, typestore=ts) for tp, ty in topics.items()}
        for k in range(n):
            sec = int(t[k])
            stamp = time_t(sec=sec, nanosec=int(round((t[k] - sec) * 1e9)))
            hdr = header(seq=k, stamp=stamp, frame_id="") if ros == 1 else header(stamp=stamp, frame_id="")
            for tp, ty in topics.items():
                if ty.endswith("JointState"):
                    msg = js(header=hdr, name=WAM_NODE_NAMES, position=q[k], velocity=qd[k], effort=tau[k])
                else:
                    msg = string(data="hello")
                raw = ts.serialize_ros1(msg, ty) if ros == 1 else ts.serialize_cdr(msg, ty)
                w.write(conns[tp], int(t[k] * 1e9) + 1000, raw)
    return t, q, qd, tau


@pytest.mark.parametrize("ros", [1, 2])
def test_a_bag_of_joint_states_becomes_a_run(tmp_path, ros):
    bag = tmp_path / ("wam.bag" if ros == 1 else "wam_bag2")
    t, q, _, tau = write_bag(bag, ros, {"/wam/joint_states": "sensor_msgs/msg/JointState",
                                         "/chatter": "std_msgs/msg/String"})
    data, meta, _ = run_data(imp(bag, tmp_path, "rosbag", "--json"))
    assert len(data) == 200
    assert data["t_s"].iloc[-1] == pytest.approx(t[-1] - t[0], abs=2e-9)     # the header stamps, to the ns
    assert np.abs(data["q_3_rad"].to_numpy() - q[:, 2]).max() < 1e-12
    assert np.abs(data["tau_6_Nm"].to_numpy() - tau[:, 5]).max() < 1e-12
    assert meta["robot"] == "wam7" and meta["imported"]["format"] == "rosbag"


@pytest.mark.parametrize("ros", [1, 2])
def test_bag_topics_missing_or_ambiguous_are_one_line_exit_2(tmp_path, ros):
    two = tmp_path / ("two.bag" if ros == 1 else "two")
    write_bag(two, ros, {"/wam/joint_states": "sensor_msgs/msg/JointState",
                         "/bhand/joint_states": "sensor_msgs/msg/JointState"}, n=20)
    line = one_error_line(imp(two, tmp_path, "rosbag"))
    assert "2 JointState topics (/bhand/joint_states, /wam/joint_states): choose one with --topic" in line, line
    line = one_error_line(imp(two, tmp_path, "rosbag", "--topic", "/joint_states"))
    assert "no topic /joint_states; JointState topics: /bhand/joint_states, /wam/joint_states" in line, line
    data, _, _ = run_data(imp(two, tmp_path, "rosbag", "--topic", "/wam/joint_states", "--json"))
    assert len(data) == 20
    none = tmp_path / ("none.bag" if ros == 1 else "none")
    write_bag(none, ros, {"/chatter": "std_msgs/msg/String"}, n=5)
    line = one_error_line(imp(none, tmp_path, "rosbag"))
    assert "no sensor_msgs/msg/JointState topic (topics: /chatter (std_msgs/msg/String))" in line, line
    junk = tmp_path / "junk.bag"
    junk.write_bytes(b"#ROSBAG V2.0\n" + bytes(range(64)))
    line = one_error_line(imp(junk, tmp_path, "rosbag"))
    assert "not a readable ROS 1 or ROS 2 bag" in line, line
