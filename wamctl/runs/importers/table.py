"""A headerless table of numbers, one row per sample (``--format table --layout "t,q[4],tau[4]"``).

What many lab recorders write: Python's ``" ".join(map(str, row))`` or ``numpy.savetxt`` (e.g. the ``rbtlog_*.dat``
files of the WAM identification recorders: ``time q1..qn tau1..tau7``), MATLAB's ``dlmwrite``. Values are
separated by white space (spaces or tabs, any number) or, in a file with commas, by commas; lines starting with
``#`` are comments (numpy's header), blank lines are skipped. The columns are given as ``--layout``, with the
names of libbarrett's layout (``t q qd qdd tau q_ref qd_ref qdd_ref skip``, ``[n]`` a joint vector).

Time: ``t`` is required and is a time stamp in seconds (a wall clock such as ROS's ``header.stamp``, or time from
the start); rows are timed by it (from its first value), and it must increase from row to row. The sample rate
is ``--rate-hz`` (checked against the stamps) or the stamps' median interval. Row numbers in messages are the
file's line numbers.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from wamctl.errors import DataFormatError
from wamctl.runs.importers import Imported, ImportOptions, median_rate_hz, resolve_joints
from wamctl.runs.importers.libbarrett import layout_columns, numeric_values, parse_layout, read_text


def _rows(path: Path) -> tuple[list[int], list[list[str]], str]:
    """The file's data lines as (1-based line numbers, their values as text, the separator's name)."""
    text = read_text(path, "a table of numbers")
    numbered = [(k + 1, ln) for k, ln in enumerate(text.splitlines()) if ln.strip() and not ln.lstrip().startswith("#")]
    if not numbered:
        raise DataFormatError(f"{path}: no data lines")
    commas = any("," in ln for _, ln in numbered)
    split = (lambda s: [v.strip() for v in s.split(",")]) if commas else str.split
    return [k for k, _ in numbered], [split(ln) for _, ln in numbered], "commas" if commas else "white space"


def read(path: Path, opts: ImportOptions) -> Imported:
    if opts.layout is None:
        raise DataFormatError("--layout is needed with --format table: the columns in order, e.g. "
                              "\"t,q[4],tau[4]\"")
    items = parse_layout(opts.layout)
    if not any(k == "t" for k, _ in items):
        raise DataFormatError("--layout: no t: --format table times its rows by their stamps (a column t in "
                              "seconds)")
    width = sum(n for _, n in items)
    n_joint = next(n for k, n in items if k not in ("t", "skip"))
    joints = resolve_joints(opts, n_joint, f"--layout {opts.layout!r}")
    lines, values, sep = _rows(path)
    counts = np.array([len(v) for v in values])
    wrong = np.flatnonzero(counts != width)
    if len(wrong):
        k = int(wrong[0])
        what = "every line has" if (counts == counts[k]).all() else f"line {lines[k]} has"
        raise DataFormatError(f"{path}: {what} {counts[k]} values (separated by {sep}); the layout "
                              f"{opts.layout!r} has {width}")
    num = numeric_values(path, pd.DataFrame(values), items, lines)
    t, out = layout_columns(num, items, joints)
    if not np.isfinite(t).all():
        k = int(np.argmin(np.isfinite(t)))
        raise DataFormatError(f"{path}: line {lines[k]}: t is {t[k]}; every row needs its time stamp")
    dt = np.diff(t)
    if (dt <= 0).any():
        k = int(np.argmax(dt <= 0)) + 1
        raise DataFormatError(f"{path}: t does not increase at line {lines[k]} (t = {t[k - 1]:.10g} then "
                              f"{t[k]:.10g}): rows out of order, or logs joined together; import each part on its own")
    gaps = ""
    if len(t) > 2:
        period = float(np.median(dt))
        big = np.flatnonzero(dt > 1.5 * period)
        if len(big):
            gaps = (f"; {len(big)} interval(s) longer than 1.5 median intervals (the longest {dt.max() * 1e3:.3g} ms,"
                    f" before line {lines[int(np.argmax(dt)) + 1]}): samples the recorder missed, the rows stay timed"
                    " by their stamps")
    data = pd.DataFrame({"t_s": t - t[0], **out})
    if opts.rate_hz is None:
        rate = median_rate_hz(t, path)
        note = (f"time: column t (stamps), from {t[0]:.10g} s, {t[-1] - t[0]:.4g} s long; sample rate {rate:g} Hz "
                f"from their median interval{gaps}")
    else:
        rate = float(opts.rate_hz)
        note = (f"time: column t (stamps), from {t[0]:.10g} s, {t[-1] - t[0]:.4g} s long; sample rate {rate:g} Hz "
                f"(--rate-hz), checked against them{gaps}")
    return Imported(data, joints, rate, "line", [note, f"values separated by {sep}"])
