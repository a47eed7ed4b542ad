"""``sensor_msgs/JointState`` logs: a JSON dump of records (``--format jointstate-json``) and ROS 1 / ROS 2 bags
(``--format rosbag``, read with the pure-Python ``rosbags`` package).

A record has ``time`` (seconds, or ``{secs, nsecs}`` / ``{sec, nanosec}`` as ROS stamps are dumped),
``position``, ``velocity`` and ``effort`` (one value per joint) and may have ``name``. wam_node (Barrett's ROS
driver) publishes ``wam/joint_states`` with the names ``wam_j1`` .. ``wam_j7`` (``wam/YawJoint`` ..
``wam/LowerWristYawJoint`` in later versions, ``wam_j1_joint`` .. in the URDFs) and as effort the torque it
commands, gravity compensation included (``--torque total``). Names of other joints (a BarrettHand's) are left
out; a log without names needs ``--joints`` if it does not hold all of the robot's joints. A JointState has no
reference: the run has no ``q_ref``.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd

from wamctl.errors import DataFormatError
from wamctl.runs.importers import Imported, ImportOptions, median_rate_hz, resolve_joints
from wamctl.runs.measured import ROBOT_JOINTS, internal_name

JOINTSTATE = "sensor_msgs/msg/JointState"
# wam_node's joint names, in joint order, as the versions of the driver and the URDFs spell them
WAM_NAMES = (
    ("wam_j1", "wam_j2", "wam_j3", "wam_j4", "wam_j5", "wam_j6", "wam_j7"),
    ("wam/YawJoint", "wam/ShoulderPitchJoint", "wam/ShoulderYawJoint", "wam/ElbowJoint", "wam/UpperWristYawJoint",
     "wam/UpperWristPitchJoint", "wam/LowerWristYawJoint"),
    tuple(f"wam_j{j}_joint" for j in range(1, 8)),
)
JOINT_OF_NAME = {name: j + 1 for names in WAM_NAMES for j, name in enumerate(names)}
FIELDS = {"position": "q", "velocity": "qd", "effort": "tau"}


def _stamp_s(v, where: str) -> float:
    if isinstance(v, bool):
        raise DataFormatError(f"{where}: time is {v!r}, not seconds")
    if isinstance(v, (int, float)):
        return float(v)
    if isinstance(v, dict):
        for s, ns in (("secs", "nsecs"), ("sec", "nanosec"), ("sec", "nsec")):
            if s in v and ns in v:
                return float(v[s]) + 1e-9 * float(v[ns])
    raise DataFormatError(f"{where}: time is {str(v)[:40]!r}: expected seconds or {{secs, nsecs}}")


def _len(v) -> int:
    return len(v) if isinstance(v, (list, tuple, np.ndarray)) else 0


def _table(records: list[dict], opts: ImportOptions, source: str, unit: str) -> Imported:
    """Records of time, name, position, velocity, effort -> the run's columns."""
    if not records:
        raise DataFormatError(f"{source}: no {unit}s")
    first = records[0]
    names = list(first.get("name") or [])
    width = _len(first.get("position"))
    if names:
        keep = [i for i, nm in enumerate(names) if nm in JOINT_OF_NAME]
        if not keep and opts.joints is None:
            raise DataFormatError(f"{source}: joint names {names[:8]} are not wam_node's (wam_j1 .., wam/YawJoint .., "
                                  "wam_j1_joint ..): say which joints the values are with --joints")
        if keep:
            named = [JOINT_OF_NAME[names[i]] for i in keep]
            if named != sorted(set(named)):
                raise DataFormatError(f"{source}: {unit} 1: joint names {names} are not in joint order")
            if opts.joints is not None and opts.joints != named:
                raise DataFormatError(f"{source}: the names say joints {named}, --joints says {opts.joints}")
            n = ROBOT_JOINTS[opts.robot]
            if max(named) > n:
                raise DataFormatError(f"{source}: {unit} 1 names joint {max(named)}; --robot {opts.robot} has {n}")
            joints = named
        else:
            keep = list(range(width))
            joints = resolve_joints(opts, width, f"{source}: {unit} 1")
    else:
        keep = list(range(width))
        joints = resolve_joints(opts, width, f"{source}: {unit} 1")
    fields = [f for f in FIELDS if f != "velocity" or _len(first.get("velocity"))]
    t = np.empty(len(records))
    values = {f: np.empty((len(records), len(keep))) for f in fields}
    for k, rec in enumerate(records):
        where = f"{source}: {unit} {k + 1}"
        if not isinstance(rec, dict):
            raise DataFormatError(f"{where}: expected a record (time, position, velocity, effort)")
        if "time" not in rec:
            raise DataFormatError(f"{where}: no 'time'")
        t[k] = _stamp_s(rec["time"], where)
        if names and list(rec.get("name") or []) != names:
            raise DataFormatError(f"{where}: joint names {list(rec.get('name') or [])[:8]} differ from {unit} 1's")
        for f in fields:
            if f not in rec:
                raise DataFormatError(f"{where}: no {f!r}")
            v = rec[f]
            if not isinstance(v, (list, tuple, np.ndarray)) or len(v) != width:
                n = len(v) if isinstance(v, (list, tuple, np.ndarray)) else "no list of"
                what = "an empty list: the log holds no torque" if f == "effort" and n == 0 else \
                    f"{n} values, {unit} 1's position has {width}"
                raise DataFormatError(f"{where}: {f} has {what}")
            try:
                values[f][k] = np.asarray(v, dtype=float)[keep]
            except (TypeError, ValueError):
                raise DataFormatError(f"{where}: {f} holds {str(v)[:40]!r}, not numbers") from None
    out = {"t_s": t - t[0]}
    for f in fields:
        for i, j in enumerate(joints):
            out[internal_name(FIELDS[f], j)] = values[f][:, i]
    notes = []
    if opts.rate_hz is None:
        rate = median_rate_hz(t, source)
        notes.append(f"time: the stamps, from {t[0]:.6f} s; sample rate {rate:g} Hz from their median interval")
    else:
        rate = float(opts.rate_hz)
        notes.append(f"time: the stamps, from {t[0]:.6f} s; sample rate {rate:g} Hz (--rate-hz), checked against "
                     "them")
    if len(keep) < len(names):
        others = [nm for i, nm in enumerate(names) if i not in keep]
        notes.append(f"left out joints that are not the arm's: {', '.join(others)}")
    if "velocity" not in fields:
        notes.append("no velocities logged")
    return Imported(pd.DataFrame(out), joints, rate, unit, notes)


def read_json(path: Path, opts: ImportOptions) -> Imported:
    try:
        records = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise DataFormatError(f"{path}: not JSON ({str(exc).splitlines()[0]})") from None
    except IsADirectoryError:
        raise DataFormatError(f"{path}: a directory, not a JSON file") from None
    if not isinstance(records, list):
        raise DataFormatError(f"{path}: expected a JSON list of records (time, position, velocity, effort)")
    return _table(records, opts, str(path), "record")


def read_bag(path: Path, opts: ImportOptions) -> Imported:
    from rosbags.highlevel import AnyReader
    from rosbags.rosbag1 import ReaderError as Ros1Error
    from rosbags.rosbag2 import ReaderError as Ros2Error
    from rosbags.typesys import Stores, get_typestore

    try:
        reader = AnyReader([path], default_typestore=get_typestore(Stores.ROS2_HUMBLE))
        reader.open()
    except (Ros1Error, Ros2Error, Exception) as exc:  # noqa: BLE001 - rosbags raises several types for bad bags
        msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise DataFormatError(f"{path}: not a readable ROS 1 or ROS 2 bag ({msg})") from None
    try:
        topics = {c.topic: c.msgtype for c in reader.connections}
        joint_topics = sorted(tp for tp, ty in topics.items() if ty == JOINTSTATE)
        if opts.topic is not None:
            if opts.topic not in topics:
                raise DataFormatError(f"{path}: no topic {opts.topic}; JointState topics: "
                                      f"{', '.join(joint_topics) or 'none'}")
            if topics[opts.topic] != JOINTSTATE:
                raise DataFormatError(f"{path}: topic {opts.topic} is {topics[opts.topic]}, not {JOINTSTATE}")
            topic = opts.topic
        elif len(joint_topics) == 1:
            topic = joint_topics[0]
        elif not joint_topics:
            shown = ", ".join(f"{tp} ({ty})" for tp, ty in sorted(topics.items())[:6]) or "none"
            raise DataFormatError(f"{path}: no {JOINTSTATE} topic (topics: {shown})")
        else:
            raise DataFormatError(f"{path}: {len(joint_topics)} JointState topics ({', '.join(joint_topics)}): "
                                  "choose one with --topic")
        records = []
        conns = [c for c in reader.connections if c.topic == topic]
        for conn, bag_ns, raw in reader.messages(connections=conns):
            m = reader.deserialize(raw, conn.msgtype)
            stamp = m.header.stamp
            records.append({"time": stamp.sec + 1e-9 * stamp.nanosec, "bag_time": bag_ns * 1e-9,
                            "name": list(m.name), "position": m.position, "velocity": m.velocity,
                            "effort": m.effort})
    finally:
        reader.close()
    note = None
    if records and all(r["time"] == 0 for r in records):     # header stamps not filled: the recording's time
        for r in records:
            r["time"] = r["bag_time"]
        note = "header stamps all zero: timed by the bag's receive times"
    imp = _table(records, opts, f"{path} {topic}", "message")
    if note:
        imp.notes.insert(1, note)
    imp.source = str(path)
    return imp


def read(path: Path, opts: ImportOptions) -> Imported:
    return read_bag(path, opts) if opts.format == "rosbag" else read_json(path, opts)
