"""libbarrett's exported CSV: ``systems::PeriodicDataLogger`` + ``log::Reader::exportCSV``.

What libbarrett writes (log/traits.h, log/detail/traits-helper.h, log/detail/reader-inl.h): one line per
record, no header, the logged ``boost::tuple`` flattened in order, values separated by ``,`` and written with
``std::ostream``'s defaults (6 significant digits: ``0.123457``, ``1.5e-05``, ``nan``), each line ended by
``std::endl``. Which values a line holds is the user's program's tuple, given here as ``--layout``:
``t,q_ref[4],qd_ref[4],q[4],qd[4],tau[4]`` (names ``t q qd qdd tau q_ref qd_ref qdd_ref skip``; ``[n]`` a
vector of n values, one per joint logged; ``skip`` or ``skip[n]`` values to leave out, e.g. a tool position).

Time: the logger writes one record every ``PERIOD_MULTIPLIER`` execution cycles (2 ms at 500 Hz), so the rows
are timed by the logger's period (``--rate-hz``). The ``t`` the programs log is a ``systems::Ramp``: it stays
at its start value until ``start()``, advances ``T_s * slope`` per cycle, and after ``smoothStart(d)`` its slope
grows from 0 over ``d`` seconds (so it lags the logger's clock by about d/2); printed with 6 digits it is
coarser than the period past 100 s (1 ms) and 1000 s (10 ms). ``t`` is checked against the rows' clock (its
slope after the start must match ``--rate-hz`` within 5 %; it must never go back; no step of 1.5 periods or
more where it is printed finely enough to tell) and what it showed is said.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pandas as pd

from wamctl.errors import DataFormatError
from wamctl.runs.importers import Imported, ImportOptions, resolve_joints
from wamctl.runs.measured import internal_name

NAMES = ("t", "q", "qd", "qdd", "tau", "q_ref", "qd_ref", "qdd_ref", "skip")
_ITEM = re.compile(r"^([a-z_]+)(?:\[(\d+)\])?$")
# a slope of t more than this far from the rows' clock is an error (a wrong --rate-hz or a Ramp slope != 1)
SLOPE_TOLERANCE = 0.05


def parse_layout(layout: str) -> list[tuple[str, int]]:
    """``"t,q[4],skip[3]"`` -> ``[("t", 1), ("q", 4), ("skip", 3)]``."""
    items = []
    for raw in layout.split(","):
        item = raw.strip()
        m = _ITEM.match(item)
        if not m or m.group(1) not in NAMES:
            raise DataFormatError(f"--layout: {item!r} is not a layout item (names: {', '.join(NAMES)}; [n] a "
                                  "vector of n values, e.g. q[4])")
        name, n = m.group(1), m.group(2)
        if name == "t" and n is not None:
            raise DataFormatError("--layout: t is one value (libbarrett's Ramp), not a vector")
        if name not in ("t", "skip") and n is None:
            raise DataFormatError(f"--layout: {name} is a joint vector: give its size, e.g. {name}[4]")
        if n is not None and int(n) < 1:
            raise DataFormatError(f"--layout: {item}: a vector of at least one value")
        if name != "skip" and any(name == k for k, _ in items):
            raise DataFormatError(f"--layout: {name} appears twice")
        items.append((name, int(n) if n is not None else 1))
    names = [k for k, _ in items]
    for need in ("q", "tau"):
        if need not in names:
            raise DataFormatError(f"--layout: no {need}: a measured run needs the joint positions (q) and torques "
                                  "(tau)")
    sizes = {n for k, n in items if k not in ("t", "skip")}
    if len(sizes) > 1:
        raise DataFormatError(f"--layout: the joint vectors have different sizes ({', '.join(map(str, sorted(sizes)))})"
                              ": every vector holds the same joints")
    return items


def read_text(path: Path, what: str) -> str:
    """A log file's text, or a DataFormatError naming the first byte that is not text, or ``what`` the file
    should have been when it is a directory."""
    try:
        return path.read_text()
    except UnicodeDecodeError as exc:
        raise DataFormatError(f"{path}: not text (byte 0x{exc.object[exc.start]:02x} at {exc.start})") from None
    except IsADirectoryError:
        raise DataFormatError(f"{path}: a directory, not {what}") from None


def _lines(path: Path) -> list[str]:
    lines = read_text(path, "libbarrett's exported CSV").splitlines()
    while lines and not lines[-1].strip():
        lines.pop()
    if not lines:
        raise DataFormatError(f"{path}: empty")
    return lines


def read(path: Path, opts: ImportOptions) -> Imported:
    if opts.layout is None:
        raise DataFormatError("--layout is needed with --format libbarrett-csv: the logged tuple, e.g. "
                              "\"t,q_ref[4],qd_ref[4],q[4],qd[4],tau[4]\"")
    if opts.rate_hz is None:
        raise DataFormatError("--rate-hz is needed with --format libbarrett-csv: the logger's rate (500 Hz "
                              "divided by its PERIOD_MULTIPLIER)")
    items = parse_layout(opts.layout)
    width = sum(n for _, n in items)
    n_joint = next(n for k, n in items if k not in ("t", "skip"))
    joints = resolve_joints(opts, n_joint, f"--layout {opts.layout!r}")
    lines = _lines(path)
    counts = np.array([ln.count(",") + 1 for ln in lines])
    wrong = np.flatnonzero(counts != width)
    if len(wrong):
        k = int(wrong[0])
        what = "every line has" if (counts == counts[k]).all() else f"line {k + 1} has"
        blank = " (an empty line)" if not lines[k].strip() else ""
        raise DataFormatError(f"{path}: {what} {counts[k]} values{blank}; the layout {opts.layout!r} has {width}")
    raw = pd.read_csv(path, header=None, names=range(width), dtype=str, skip_blank_lines=False, nrows=len(lines),
                      na_filter=False, engine="c")
    num = numeric_values(path, raw, items, range(1, len(lines) + 1))
    rate = float(opts.rate_hz)
    t_logged, columns = layout_columns(num, items, joints)
    out = {"t_s": np.arange(len(num)) / rate, **columns}
    notes = [time_note(t_logged, rate, str(path))]
    return Imported(pd.DataFrame(out), joints, rate, "line", notes)


def numeric_values(path: Path, raw: pd.DataFrame, items: list[tuple[str, int]], line_numbers) -> pd.DataFrame:
    """A layout's values (strings, one column per value) as numbers; a value that is neither a number nor nan is
    an error naming the file's line, the value's place and the layout's name for it."""
    num = raw.apply(lambda c: pd.to_numeric(c.str.strip(), errors="coerce"))
    bad = num.isna().to_numpy() & ~raw.apply(lambda c: c.str.strip().str.lower().isin(["nan", "-nan"])).to_numpy()
    if bad.any():
        names = [f"{k}[{i + 1}]" if k not in ("t", "skip") else k for k, n in items for i in range(n)]
        row, col = map(int, np.argwhere(bad)[0])
        raise DataFormatError(f"{path}: line {list(line_numbers)[row]}, value {col + 1} ({names[col]}): "
                              f"{raw.iat[row, col][:40]!r} is not a number")
    return num


def layout_columns(num: pd.DataFrame, items: list[tuple[str, int]],
                   joints: list[int]) -> tuple[np.ndarray | None, dict[str, np.ndarray]]:
    """(the layout's t column or None, the joint vectors under the measured-run format's names)."""
    t, out, col = None, {}, 0
    for k, n in items:
        if k == "t":
            t = num[col].to_numpy(float)
        elif k != "skip":
            for i, j in enumerate(joints):
                out[internal_name(k, j)] = num[col + i].to_numpy(float)
        col += n
    return t, out


def _print_step(t: np.ndarray) -> np.ndarray:
    """The step of a value printed with 6 significant digits (std::ostream's default)."""
    mag = np.floor(np.log10(np.maximum(np.abs(t), 1e-300)))
    return 10.0 ** (mag - 5)


def time_note(t: np.ndarray | None, rate_hz: float, source: str) -> str:
    """Check libbarrett's logged time (a Ramp) against the rows' clock and say what it showed."""
    period = 1.0 / rate_hz
    clock = f"rows timed by the logger's period ({period * 1e3:.3g} ms, --rate-hz {rate_hz:g})"
    if t is None:
        return f"time: no t in the layout; {clock}"
    n = len(t)
    finite = np.isfinite(t)
    if not finite.all():
        k = int(np.argmin(finite))
        raise DataFormatError(f"{source}: line {k + 1}: t is {t[k]}; libbarrett's Ramp is always a number")
    dt = np.diff(t)
    if (dt < 0).any():
        k = int(np.argmax(dt < 0)) + 1
        raise DataFormatError(f"{source}: t goes back at line {k + 1} (t = {t[k - 1]:.6g} then {t[k]:.6g}): a Ramp "
                              "reset (setOutput) or logs joined together; import each part on its own")
    if t[-1] == t[0]:
        return f"time: t stays at {t[0]:.6g} (the Ramp was not started); {clock}"
    # what the 6 printed digits can hide: a lag or a standstill shorter than this is not told from rounding
    tol = 0.5 * period + float(_print_step(t).max())
    started = int(np.argmax(dt > 0))                 # rows before: the Ramp not yet started
    if started * period <= tol:
        started = 0
    half = max(started, n // 2)
    if n - 1 - half < 10:
        raise DataFormatError(f"{source}: t advances only over its last {n - 1 - started} lines; too few to check "
                              "it against --rate-hz")
    per_row = (t[-1] - t[half]) / (n - 1 - half)
    slope = per_row / period
    if abs(slope - 1.0) > SLOPE_TOLERANCE:
        raise DataFormatError(f"{source}: t advances {per_row * 1e3:.4g} ms a line (lines {half + 1}-{n}) but "
                              f"--rate-hz {rate_hz:g} means {period * 1e3:.4g} ms: check --rate-hz (500 Hz divided "
                              "by the logger's PERIOD_MULTIPLIER), or call the column skip if it is not the Ramp")
    lag = np.arange(n) * period - (t - t[0]) / slope      # how far the Ramp is behind the rows' clock
    full = int(np.argmax(lag[-1] - lag < tol))            # first row from which the Ramp keeps the clock's pace
    fine = _print_step(t[1:]) < 0.5 * period
    steps = np.flatnonzero(fine & (dt > 1.5 * period * slope))
    steps = steps[steps >= full]
    if len(steps):
        k = int(steps[0]) + 1
        raise DataFormatError(f"{source}: t jumps by {dt[k - 1] * 1e3:.4g} ms at line {k + 1} "
                              f"({dt[k - 1] / period / slope:.1f} logger periods): records are missing, and the rows "
                              "cannot be timed by the logger's period")
    said = [f"time: t (libbarrett's Ramp) {t[0]:.6g} s at line 1"]
    if started:
        said.append(f"constant for the first {started + 1} lines (the Ramp not yet started)")
    if full > started + 1:
        said.append(f"at full pace from line {full + 1} on (a smooth start: {lag[-1]:.3g} s behind the logger's "
                    "clock)")
    said.append(f"slope {slope:.4f} of the logger's clock")
    coarse = np.flatnonzero(_print_step(t) >= 0.5 * period)
    if len(coarse):
        said.append(f"printed with 6 digits, coarser than half a period from line {int(coarse[0]) + 1} on")
    return ", ".join(said) + f"; {clock}"
