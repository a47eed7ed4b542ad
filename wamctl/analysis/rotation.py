"""Rotation-test metrics (thesis chapter 3), computed from the data alone (no events needed).

For each joint whose reference moves: the *target* is the reference value farthest from its start; the
*final sample* is the last sample of the first hold at the target (before any return move). Then

    RPE = |q_ref_final - q_final| / |target - start| * 100 %          (thesis eq. 3.2)

with the move amplitude as the "desired joint position" (the rotation asked for). Errors are
``e = q_ref - q`` (measured position). Input tables use the run columns ``q_ref_{j}_rad`` and ``q_{j}_rad``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from wamctl.model import params as P

MOVE_TOL_RAD = 1e-9


@dataclass
class JointRotation:
    joint: int
    start_rad: float
    target_rad: float
    i_start: int        # first sample where the reference leaves its start
    i_final: int        # last sample of the hold at the target

    @property
    def amplitude_rad(self) -> float:
        return self.target_rad - self.start_rad


def find_rotations(data: pd.DataFrame) -> list[JointRotation]:
    """The move of each joint whose reference changes."""
    out = []
    for j in range(1, P.N_JOINTS + 1):
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
        out.append(JointRotation(j, float(ref[0]), float(target), i_start, i_final))
    return out


def rotation_metrics(data: pd.DataFrame) -> pd.DataFrame:
    """Per moved joint: amplitude, final error, RPE, max and mean absolute error during the move.

    Returns
    -------
    DataFrame indexed by joint with columns ``amplitude_rad, final_error_rad, rpe_pct, max_abs_error_rad,
    mean_abs_error_rad``.
    """
    rows = []
    for r in find_rotations(data):
        e = (data[f"q_ref_{r.joint}_rad"] - data[f"q_{r.joint}_rad"]).to_numpy()
        window = e[r.i_start: r.i_final + 1]
        rows.append({"joint": r.joint, "amplitude_rad": r.amplitude_rad, "final_error_rad": e[r.i_final],
                     "rpe_pct": abs(e[r.i_final] / r.amplitude_rad) * 100.0,
                     "max_abs_error_rad": float(np.abs(window).max()),
                     "mean_abs_error_rad": float(np.abs(window).mean())})
    cols = ["amplitude_rad", "final_error_rad", "rpe_pct", "max_abs_error_rad", "mean_abs_error_rad"]
    if not rows:
        return pd.DataFrame(columns=cols, index=pd.Index([], name="joint"))
    return pd.DataFrame(rows).set_index("joint")[cols]
