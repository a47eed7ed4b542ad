"""Rotation-test metrics (thesis chapter 3), computed from the data alone (no events needed).

For each joint whose reference moves: the *target* is the reference value farthest from its start; the
*final sample* is the last sample of the first hold at the target (before any return move). Then

    RPE = |q_ref_final - q_final| / |target - start| * 100 %          (thesis eq. 3.2)

with the move amplitude as the "desired joint position" (the rotation asked for). Errors are
``e = q_ref - q`` (measured position). Input tables use the run columns ``q_ref_{j}_rad`` and ``q_{j}_rad``.

A move is *finished* when its reference reached its end and stayed there for the hold that follows it; a run
that ended before (interrupted, failed) has moves that are not, and those get no final error and no RPE: the
last sample of a move cut off mid-ramp is not where the move ends. Given the planned amplitude and hold
(``amplitude_rad``, ``hold_s``, from the spec), both are checked; from the data alone, only that the reference
was not still moving at the last sample.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np
import pandas as pd

from wamctl.model import params as P

MOVE_TOL_RAD = 1e-9
END_TOL = 1e-3
"""A move reached its planned end when its reference came within this fraction of the amplitude of it (the
first sample of a run without a settle is already one step into the move: 5e-6 rad of a 0.05 rad move)."""


@dataclass
class JointRotation:
    joint: int
    start_rad: float
    target_rad: float
    i_start: int        # first sample where the reference leaves its start
    i_final: int        # last sample of the hold at the target (or of the data, for a move not finished)
    finished: bool = True   # the reference reached its end and held it (see the module doc)

    @property
    def amplitude_rad(self) -> float:
        return self.target_rad - self.start_rad


def reference_joints(data: pd.DataFrame) -> list[int]:
    """The joints whose reference the table holds (``q_ref_{j}_rad``), ascending: 1..7 on the wam7, 1..4 on the
    wam4, the logged ones of a measured run."""
    return sorted(int(m.group(1)) for m in (re.fullmatch(r"q_ref_(\d+)_rad", str(c)) for c in data.columns) if m)


def find_rotations(data: pd.DataFrame, amplitude_rad: float | None = None,
                   hold_s: float = 0.0) -> list[JointRotation]:
    """The move of each joint whose reference changes; ``amplitude_rad`` and ``hold_s``: the planned move and
    the hold after it, when known (a move that did not reach ``start + amplitude_rad`` or was held less than
    ``hold_s`` is not finished)."""
    out = []
    t = data["t_s"].to_numpy() if "t_s" in data else np.empty(0)   # a dead run's empty table has no columns
    if len(t) == 0:          # a run interrupted before its first sample: no move to find
        return out
    dt = float(np.median(np.diff(t))) if len(t) > 1 else 0.0
    for j in reference_joints(data):
        ref = data[f"q_ref_{j}_rad"].to_numpy()
        dev = np.abs(ref - ref[0])
        if dev.max() < 1e-6:
            continue
        i_peak = int(np.argmax(dev))
        target = ref[i_peak]
        at_target = np.abs(ref - target) <= MOVE_TOL_RAD + 1e-12 * abs(target)
        i_final = i_peak
        while i_final + 1 < len(ref) and at_target[i_final + 1]:
            i_final += 1
        i_start = int(np.argmax(dev > MOVE_TOL_RAD))
        moving_at_end = i_final == len(ref) - 1 and abs(ref[-1] - ref[-2]) > MOVE_TOL_RAD
        finished = not moving_at_end
        if amplitude_rad is not None:
            reached = abs(target - (ref[0] + amplitude_rad)) <= END_TOL * abs(amplitude_rad)
            held = t[i_final] - t[i_peak] >= hold_s - 1.5 * dt
            finished = finished and reached and held
        out.append(JointRotation(j, float(ref[0]), float(target), i_start, i_final, finished))
    return out


def rotation_metrics(data: pd.DataFrame, amplitude_rad: float | None = None, hold_s: float = 0.0) -> pd.DataFrame:
    """Per moved joint: amplitude, final error, RPE, max and mean absolute error during the move, and whether
    the move finished (:func:`find_rotations`; a move not finished has no final error and no RPE: NaN).

    Returns
    -------
    DataFrame indexed by joint with columns ``amplitude_rad, final_error_rad, rpe_pct, max_abs_error_rad,
    mean_abs_error_rad, finished``.
    """
    rows = []
    for r in find_rotations(data, amplitude_rad, hold_s):
        e = (data[f"q_ref_{r.joint}_rad"] - data[f"q_{r.joint}_rad"]).to_numpy()
        window = e[r.i_start: r.i_final + 1]
        final = e[r.i_final] if r.finished else np.nan
        # the rotation made (the reference's own, as recorded); of a move cut off, the rotation asked for
        asked = amplitude_rad if amplitude_rad is not None and not r.finished else r.amplitude_rad
        rows.append({"joint": r.joint, "amplitude_rad": asked, "final_error_rad": final,
                     "rpe_pct": abs(final / asked) * 100.0,
                     "max_abs_error_rad": float(np.abs(window).max()),
                     "mean_abs_error_rad": float(np.abs(window).mean()), "finished": r.finished})
    cols = ["amplitude_rad", "final_error_rad", "rpe_pct", "max_abs_error_rad", "mean_abs_error_rad", "finished"]
    if not rows:
        return pd.DataFrame(columns=cols, index=pd.Index([], name="joint"))
    return pd.DataFrame(rows).set_index("joint")[cols]


def move_speed_rad_s(data: pd.DataFrame, r: JointRotation) -> float:
    """Speed of the reference over the middle half of a move, rad/s (the constant-velocity stretch of an LSPB
    move; a slope over many samples, so jittered time stamps do not matter)."""
    ref = data[f"q_ref_{r.joint}_rad"].to_numpy()[r.i_start: r.i_final + 1]
    t = data["t_s"].to_numpy()[r.i_start: r.i_final + 1]
    frac = (ref - r.start_rad) / r.amplitude_rad
    mid = np.flatnonzero((frac >= 0.25) & (frac <= 0.75))
    if len(mid) < 2 or t[mid[-1]] <= t[mid[0]]:
        return float("nan")
    return float(abs(ref[mid[-1]] - ref[mid[0]]) / (t[mid[-1]] - t[mid[0]]))


def thesis_test_differences(data: pd.DataFrame, controller: dict | None = None) -> list[str]:
    """How this rotation test differs from the thesis' (chapter 3: each joint rotated 0.5 rad at 0.083 rad/s
    under libbarrett's gains), read from the references themselves (amplitude within 0.1 %, speed within 2 %)
    and from ``controller`` (a spec's controller section: its own ``kp``/``kd``). Empty: the same test."""
    rots = find_rotations(data)
    if not rots:
        return ["no joint moves"]
    rots = [r for r in rots if r.finished]     # a move cut off mid-ramp says nothing of its size
    if not rots:
        return ["no finished move"]
    out = []
    n_arm = len(reference_joints(data))
    if n_arm != P.N_JOINTS:       # another arm (the wam4): its gains and dynamics are not the thesis' WAM's
        out.append(f"{n_arm} joints recorded, not the thesis' 7-DOF WAM")
    amps = sorted({round(abs(r.amplitude_rad), 4) for r in rots
                   if not np.isclose(abs(r.amplitude_rad), P.ROTATION_AMPLITUDE_RAD, rtol=1e-3)})
    if amps:
        out.append(f"amplitude {', '.join(f'{a:g}' for a in amps)} rad")
    speeds = sorted({round(v, 4) for v in (move_speed_rad_s(data, r) for r in rots)
                     if not np.isclose(v, P.ROTATION_VELOCITY_RAD_S, rtol=0.02)})
    if speeds:
        out.append(f"speed {', '.join(f'{v:g}' for v in speeds)} rad/s")
    for name, default in (("kp", P.KP), ("kd", P.KD)):
        gains = (controller or {}).get(name)
        if gains is not None and n_arm == P.N_JOINTS and not np.allclose(gains, default):
            out.append(f"its own {name}")
    return out
