"""``wamctl import FILE --format F``: what labs log, into the measured-run format (docs/measured-run.md).

Each format has a reader (``read(path, options) -> Imported``): libbarrett's exported CSV (``libbarrett.py``),
a JSON dump of ``sensor_msgs/JointState`` records and ROS 1 / ROS 2 bags (``jointstate.py``), a CSV with a
column map (``csv_map.py``), a headerless table of numbers with a layout (``table.py``). What they read is
checked like any measured run (:func:`validate_samples`: row numbers the file's own), described (robot, joints
logged, what the torque is, how the time was read) and stored as a run directory by
:func:`wamctl.runs.measured.store_measured`. Joints not logged have no columns: never zeros.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from wamctl.errors import DataFormatError
from wamctl.runs.measured import (
    FORMAT,
    ROBOT_JOINTS,
    TORQUE_KINDS,
    MeasuredMeta,
    RunData,
    import_measured,
    internal_name,
    store_measured,
    validate_samples,
)

# --format -> the module that reads it ("measured": the measured-run directory, wamctl.runs.measured)
READERS = {"libbarrett-csv": "libbarrett", "jointstate-json": "jointstate", "rosbag": "jointstate",
           "csv": "csv_map", "table": "table"}
FORMATS = ("measured", *READERS)
# a joint "moved" (experiment.joints) when its position spans more than this
MOVED_RAD = 0.01
TORQUE_HELP = ("total (the command including gravity compensation: libbarrett's jtSum, wam_node's effort), "
               "controller (the user's controller output; gravity compensation added downstream, not logged) "
               "or measured (a torque sensor)")


@dataclass
class ImportOptions:
    """What the user said about a log (the command line's options)."""

    format: str
    robot: str | None = None
    torque: str | None = None
    joints: list[int] | None = None      # which joints the log's joint vectors hold, in order
    rate_hz: float | None = None         # the logger's rate (libbarrett: 500 Hz / PERIOD_MULTIPLIER)
    layout: str | None = None            # libbarrett-csv
    columns: str | None = None           # csv
    topic: str | None = None             # rosbag
    # options given on the command line, to refuse those that do not apply to the format
    given: dict = field(default_factory=dict)


@dataclass
class Imported:
    """What a reader made of a log: internal-named columns of the logged joints."""

    data: pd.DataFrame
    joints: list[int]
    rate_hz: float
    row_name: str                        # what the file's row numbers count: "line", "record", "message", ...
    notes: list[str] = field(default_factory=list)   # what was found and done (time conventions), said and kept
    source: str = ""


APPLIES = {"layout": ("libbarrett-csv", "table"), "columns": ("csv",), "topic": ("rosbag",)}


def _check_options(opts: ImportOptions) -> None:
    if opts.format not in FORMATS:
        raise DataFormatError(f"--format: {opts.format!r} is not one of {', '.join(FORMATS)}")
    for key, fmts in APPLIES.items():
        if getattr(opts, key) is not None and opts.format not in fmts:
            raise DataFormatError(f"--{key} applies to --format {' / '.join(fmts)} only")
    if opts.format == "measured":
        given = [k for k in ("robot", "torque", "joints", "rate_hz") if getattr(opts, k) is not None]
        if given:
            raise DataFormatError(f"--{given[0].replace('_', '-')}: a measured-run directory says it in its meta.yaml")
        return
    if opts.robot is None:
        raise DataFormatError(f"--robot is needed with --format {opts.format}: {' or '.join(ROBOT_JOINTS)}")
    if opts.robot not in ROBOT_JOINTS:
        raise DataFormatError(f"--robot: {opts.robot!r} is not one of {', '.join(ROBOT_JOINTS)}")
    if opts.torque is None:
        raise DataFormatError(f"--torque is needed with --format {opts.format}: {TORQUE_HELP}")
    if opts.torque not in TORQUE_KINDS:
        raise DataFormatError(f"--torque: {opts.torque!r} is not one of {', '.join(TORQUE_KINDS)}")
    if opts.rate_hz is not None and not opts.rate_hz > 0:
        raise DataFormatError(f"--rate-hz: {opts.rate_hz:g} is not a rate (Hz > 0)")
    n = ROBOT_JOINTS[opts.robot]
    if opts.joints is not None:
        bad = [j for j in opts.joints if not 1 <= j <= n]
        if bad:
            raise DataFormatError(f"--joints: joint numbers of {opts.robot} are 1..{n}, got {bad}")
        if sorted(set(opts.joints)) != list(opts.joints):
            raise DataFormatError(f"--joints: expected joint numbers in increasing order, once each, got "
                                  f"{','.join(map(str, opts.joints))}")


def parse_joints(text: str | None) -> list[int] | None:
    """``--joints 2,4`` -> [2, 4]."""
    if text is None or text == "":
        return None
    try:
        return [int(x) for x in text.split(",")]
    except ValueError:
        raise DataFormatError(f"--joints: expected joint numbers separated by commas (e.g. 2,4), got {text!r}") \
            from None


def resolve_joints(opts: ImportOptions, n_values: int, where: str) -> list[int]:
    """The joints a log's joint vectors of ``n_values`` entries hold: ``--joints``, or all of the robot's."""
    n = ROBOT_JOINTS[opts.robot]
    if opts.joints is not None:
        if len(opts.joints) != n_values:
            raise DataFormatError(f"{where} holds {n_values} joint(s) but --joints names {len(opts.joints)} "
                                  f"({','.join(map(str, opts.joints))})")
        return list(opts.joints)
    if n_values != n:
        raise DataFormatError(f"{where} holds {n_values} joint(s) but --robot {opts.robot} has {n}: say which with "
                              f"--joints (e.g. --joints {','.join(map(str, range(1, n_values + 1)))})"
                              + (", or --robot wam4" if opts.robot == "wam7" and n_values == 4 else ""))
    return list(range(1, n + 1))


def median_rate_hz(t_s: np.ndarray, source) -> float:
    """The sample rate from the median interval of the stamps ``t_s`` (s), or DataFormatError naming ``source`` when
    they never advance (a file of one row or none, or one stamp repeated)."""
    dt = np.diff(t_s)
    dt = dt[dt > 0]
    if not len(dt):
        raise DataFormatError(f"{source}: the time stamps never advance ({len(t_s)} of them): no sample rate")
    return float(f"{1.0 / np.median(dt):.3g}")    # 3 digits: a logger's nominal rate under jittered stamps


def _meta(imp: Imported, opts: ImportOptions) -> MeasuredMeta:
    n = ROBOT_JOINTS[opts.robot]
    df = imp.data
    ref = "q_ref" if internal_name("q_ref", imp.joints[0]) in df else "q"
    moved = [j for j in imp.joints if np.ptp(df[internal_name(ref, j)].to_numpy()) > MOVED_RAD]
    q0 = [float(df[internal_name("q", j)].iloc[0]) if j in imp.joints else None for j in range(1, n + 1)]
    notes = f"imported by wamctl from {imp.source} (--format {opts.format})" + "".join(f"; {x}" for x in imp.notes)
    return MeasuredMeta(
        format=FORMAT, robot=opts.robot, sample_rate_hz=imp.rate_hz,
        gravity_compensation=opts.torque == "total", controller={"kind": "unknown"},
        experiment={"kind": "free", "joints": moved}, q0=q0, notes=notes,
        joints=None if imp.joints == list(range(1, n + 1)) else imp.joints, torque=opts.torque,
        imported={"format": opts.format, "layout": opts.layout, "columns": opts.columns, "topic": opts.topic,
                  "time": imp.notes[0] if imp.notes else None})


def import_log(path: str | Path, opts: ImportOptions, out_dir: str | Path = "runs",
               name: str | None = None) -> tuple[Path, list[str]]:
    """Read a log in ``opts.format``, check it, store it as a run directory. Returns (run dir, notes)."""
    _check_options(opts)
    path = Path(path)
    if opts.format == "measured":
        return import_measured(path, out_dir, name), []
    if not path.exists():
        raise DataFormatError(f"{path}: no such file")
    reader = importlib.import_module(f"wamctl.runs.importers.{READERS[opts.format]}")
    imp = reader.read(path, opts)
    imp.source = imp.source or str(path)
    imp.data = validate_samples(imp.data, opts.rate_hz, imp.source, imp.joints, imp.row_name)
    rd = RunData(_meta(imp, opts), imp.data, path)
    return store_measured(rd, out_dir, name or path.stem, str(path.resolve())), imp.notes
