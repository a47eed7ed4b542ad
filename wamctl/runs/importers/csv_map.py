"""Any CSV with a header row, through a column map (``--format csv --columns MAP``).

``MAP`` names the file's column for each quantity, ``{j}`` standing for the joint number:
``"t=time,q=pos{j},tau=torque{j},q_ref=cmd{j},qd=vel{j}"`` (quantities ``t q qd qdd tau q_ref qd_ref qdd_ref``;
``t``, ``q`` and ``tau`` required). Units: seconds, radians, N m. The joints are ``--joints`` or all of the
robot's. Time is the file's ``t`` (from its first value); the sample rate ``--rate-hz`` or its median interval.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from wamctl.errors import DataFormatError
from wamctl.runs.importers import Imported, ImportOptions, median_rate_hz
from wamctl.runs.measured import QUANTITIES, ROBOT_JOINTS, as_numbers, internal_name


def parse_columns(text: str) -> dict[str, str]:
    out = {}
    for raw in text.split(","):
        key, sep, col = raw.partition("=")
        key, col = key.strip(), col.strip()
        if not sep or not col:
            raise DataFormatError(f"--columns: {raw.strip()!r} is not QUANTITY=COLUMN (e.g. q=pos{{j}})")
        if key != "t" and key not in QUANTITIES:
            raise DataFormatError(f"--columns: {key!r} is not one of t, {', '.join(QUANTITIES)}")
        if key in out:
            raise DataFormatError(f"--columns: {key} appears twice")
        if key != "t" and "{j}" not in col:
            raise DataFormatError(f"--columns: {key}={col}: a joint quantity's column names {{j}} (the joint number)")
        out[key] = col
    for need in ("t", "q", "tau"):
        if need not in out:
            raise DataFormatError(f"--columns: no {need} (e.g. \"t=time,q=pos{{j}},tau=torque{{j}}\", {{j}} the "
                                  "joint number)")
    return out


def read(path: Path, opts: ImportOptions) -> Imported:
    if opts.columns is None:
        raise DataFormatError("--columns is needed with --format csv: e.g. \"t=time,q=pos{j},tau=torque{j}\"")
    cmap = parse_columns(opts.columns)
    joints = opts.joints or list(range(1, ROBOT_JOINTS[opts.robot] + 1))
    try:
        df = pd.read_csv(path, low_memory=False)
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError, ValueError, IsADirectoryError) as exc:
        msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise DataFormatError(f"{path}: unreadable CSV ({msg})") from None
    out, file_column = {}, {}
    for key, pattern in cmap.items():
        for j in ([None] if key == "t" else joints):
            col = pattern if j is None else pattern.replace("{j}", str(j))
            if col not in df.columns:
                what = "t" if j is None else f"{key} of joint {j}"
                raise DataFormatError(f"{path}: no column {col!r} ({what} in --columns); the header has "
                                      f"{', '.join(map(str, df.columns[:8]))}{' ...' if len(df.columns) > 8 else ''}")
            name = "t_s" if j is None else internal_name(key, j)
            out[name], file_column[name] = df[col], col
    # a cell that is not a number named by the file's own column (the run's name for it, q_3, is not in the file)
    data = as_numbers(pd.DataFrame(out), path, "data row", file_column.get)
    t = data["t_s"].to_numpy(float)
    if np.isfinite(t).any():
        data["t_s"] = t - t[np.isfinite(t)][0]
    if opts.rate_hz is None:
        rate = median_rate_hz(t[np.isfinite(t)], path)
        note = f"time: column {cmap['t']}, from {t[0]:.6g} s; sample rate {rate:g} Hz from its median interval"
    else:
        rate = float(opts.rate_hz)
        note = f"time: column {cmap['t']}, from {t[0]:.6g} s; sample rate {rate:g} Hz (--rate-hz), checked against it"
    return Imported(data, joints, rate, "data row", [note])
