"""The friction-velocity map: one row per move of each joint, with the mean velocity and friction torque of its
constant-velocity stage, their spread and confidence intervals, or why the move was left out."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pandas as pd

from wamctl.analysis.friction_id.segments import (
    Move,
    Stage,
    constant_velocity_stage,
    detect_moves,
    moves_from_reference,
    spread,
)
from wamctl.analysis.friction_id.signals import (
    batch_mean_se,
    fit_line,
    position_noise_rad,
    quantisation_step_rad,
    savgol_derivative,
    t975,
)

MAP_COLUMNS = ["joint", "move", "direction", "v_cmd_rad_s", "t_start_s", "t_end_s", "n_samples",
               "velocity_rad_s", "velocity_std_rad_s", "velocity_ci95_rad_s", "friction_Nm", "friction_std_Nm",
               "friction_se_Nm", "friction_ci95_Nm", "timing_shift_Nm", "stick_fraction", "accepted", "reason"]

# The instant whose rigid-body torque a logged torque balances, relative to its position sample: the torque is
# held over the control period that follows the sample while the arm moves on, so that instant lies somewhere in
# the period (a quarter period on the simulator at 2 physics sub-steps, whose steps take gravity at the period's
# start and middle; half a period with continuous physics; later still with a read latency). A constant-velocity
# sweep cannot tell it: shifting the rigid body by dt changes a stage's friction by its rate of change times dt,
# which is v times the gravity stiffness along the move, a viscous coefficient. The map's friction takes the
# rigid body at the sample; ``timing_shift_Nm`` is each stage's change for a shift of TIMING_SE_PERIODS control
# periods (one standard error, the same unknown shift for every stage), which the fits carry into their
# standard errors (:meth:`wamctl.analysis.friction_id.models._LsqFriction.fit`).
TIMING_SE_PERIODS = 0.5


@dataclass
class MapOptions:
    """Settings of segment detection (defaults suit 500 Hz WAM data)."""

    use_reference: bool = True      # take move windows (and commanded speeds) from q_ref when present
    min_stage_s: float = 0.2
    guard_s: float = 0.02
    consistency: float = 0.05
    band_sigmas: float = 4.0
    # Savitzky-Golay window of qd, qdd for the inverse dynamics; short, because a longer one smooths away the
    # decaying oscillation after a blend and biases the inertial correction of short, fast stages
    derivative_window_s: float = 0.04
    stick_fraction_max: float = 0.1   # reject stages where the joint stands still more than this
    velocity_tolerance: float = 0.03  # with a commanded speed: reject stages off it by more (not steady)
    max_moves: int | None = None      # per joint at most this many moves, evenly spread over the run (long runs)
    max_stage_samples: int | None = None   # the friction of a stage from at most this many of its samples


def friction_samples(t_s: np.ndarray, q: np.ndarray, tau: np.ndarray, rows: np.ndarray, dynamics,
                     window_s: float = 0.04) -> np.ndarray:
    """Friction torque at the samples ``rows``: ``tau - inverse_dynamics(q, qd, qdd)``, all joints.

    Parameters
    ----------
    t_s : (n,); q, tau : (n, 7) measured position and logged (applied) torque.
    rows : (m,) sample indices. dynamics : a :class:`~wamctl.model.dynamics.WamDynamics` (the declared model).

    Returns
    -------
    (m, 7) friction torque, N m (the torque the motor supplied beyond the rigid body's needs).
    """
    dt = float(np.median(np.diff(t_s)))
    qd = savgol_derivative(q, dt, window_s, 2, 1)
    qdd = savgol_derivative(q, dt, window_s, 2, 2)
    if hasattr(dynamics, "inverse_dynamics_many"):        # a WamDynamics: the batch helper
        return tau[rows] - dynamics.inverse_dynamics_many(q[rows], qd[rows], qdd[rows])
    return tau[rows] - np.array([dynamics.inverse_dynamics(q[i], qd[i], qdd[i]) for i in rows])


def friction_map(t_s: np.ndarray, q: np.ndarray, tau: np.ndarray, q_ref: np.ndarray | None, joints,
                 dynamics, options: MapOptions | None = None) -> pd.DataFrame:
    """The friction-velocity map: one row per move of each joint (columns :data:`MAP_COLUMNS`).

    Parameters
    ----------
    t_s : (n,) time; q, tau : (n, 7) measured positions and logged torques; q_ref : (n, 7) reference or None.
    joints : 1-based joint numbers to analyse. dynamics : the declared rigid-body model.
    """
    o = options or MapOptions()
    t_s = np.asarray(t_s, float)
    dt = float(np.median(np.diff(t_s)))
    rows = []
    stage_rows: list[np.ndarray] = []
    for j in joints:
        x = q[:, j - 1]
        sig = position_noise_rad(x)
        step = quantisation_step_rad(x)
        if q_ref is not None and o.use_reference:
            moves = moves_from_reference(t_s, q_ref[:, j - 1], max_moves=o.max_moves)
        else:
            moves = detect_moves(t_s, x, sig)
            moves = [moves[i] for i in spread(len(moves), o.max_moves)]
        v_fine = savgol_derivative(x, dt, 0.05, 1)
        for k, m in enumerate(moves):
            st = constant_velocity_stage(t_s, x, m.i0, m.i1, sig, step, o.min_stage_s, o.guard_s,
                                         o.consistency, o.band_sigmas)
            row = {"joint": j, "move": k, "direction": m.direction, "v_cmd_rad_s": m.v_cmd_rad_s,
                   "t_start_s": float(t_s[st.s0]) if st.s0 < len(t_s) else float("nan"),
                   "t_end_s": float(t_s[st.s1 - 1]) if st.s1 > st.s0 else float("nan"),
                   "n_samples": st.s1 - st.s0, "accepted": st.ok, "reason": st.reason}
            if st.ok:
                row.update(_stage_velocity(t_s, x, v_fine, m, st, o))
                rows_k = np.arange(st.s0, st.s1)
                if o.max_stage_samples is not None and len(rows_k) > o.max_stage_samples:
                    rows_k = rows_k[np.linspace(0, len(rows_k) - 1, o.max_stage_samples).round().astype(int)]
                    row["n_samples"] = len(rows_k)
                stage_rows.append(rows_k)
            rows.append(row)
    df = pd.DataFrame(rows, columns=MAP_COLUMNS)
    if not len(df):
        return df
    if stage_rows:
        _add_stage_friction(df, t_s, q, tau, np.concatenate(stage_rows), dynamics, o.derivative_window_s,
                            TIMING_SE_PERIODS * dt)
    df["accepted"] = df["accepted"].astype(bool)
    return df


def _stage_velocity(t_s: np.ndarray, x: np.ndarray, v_fine: np.ndarray, m: Move, st: Stage,
                    o: MapOptions) -> dict:
    """The velocity columns of one stage of joint position ``x``, and its rejection when it was not in steady
    motion (against the commanded direction, off the commanded speed, or stick-slip)."""
    sl = slice(st.s0, st.s1)
    _, v, _ = fit_line(t_s[sl], x[sl])
    # velocity spread and the CI of the mean velocity from block slopes
    nb = min(10, (st.s1 - st.s0) // 25)
    if nb >= 3:
        # np.array_split's blocks, read as slices (views, not copies of the samples)
        blocks = np.array_split(np.arange(st.s0, st.s1), nb)
        bv = np.array([fit_line(t_s[b[0]:b[-1] + 1], x[b[0]:b[-1] + 1])[1] for b in blocks])
        v_ci = float(t975(nb - 1) * bv.std(ddof=1) / math.sqrt(nb))
    else:
        v_ci = float("nan")
    vf = v_fine[sl]
    still = float(np.mean(np.abs(vf) < 0.1 * abs(v)))
    row = dict(velocity_rad_s=v, velocity_std_rad_s=float(np.std(vf)), velocity_ci95_rad_s=v_ci,
               stick_fraction=still)
    if np.sign(v) != m.direction:
        row.update(accepted=False, reason="moved against the commanded direction")
    elif np.isfinite(m.v_cmd_rad_s) and abs(v / m.v_cmd_rad_s - 1) > o.velocity_tolerance:
        off = abs(v / m.v_cmd_rad_s - 1)
        row.update(accepted=False, reason=f"mean velocity {v:.4g} rad/s is {off:.0%} off the commanded "
                                          f"{m.v_cmd_rad_s:.4g}: not in steady state")
    elif still > o.stick_fraction_max:
        row.update(accepted=False, reason=f"stands still {still:.0%} of the stage (stick-slip)")
    return row


def _add_stage_friction(df: pd.DataFrame, t_s: np.ndarray, q: np.ndarray, tau: np.ndarray,
                        all_rows: np.ndarray, dynamics, window_s: float, timing_se_s: float = 0.0) -> None:
    """Fill the friction columns of ``df`` in place: the friction torque of every stage, in one pass of inverse
    dynamics over ``all_rows`` (the stages' samples, concatenated in the order of the map's rows), and its
    ``timing_shift_Nm`` (:func:`_timing_shifts`)."""
    if not len(all_rows):
        return
    f = friction_samples(t_s, q, tau, all_rows, dynamics, window_s)
    pos = 0
    rows = df.index[(df["n_samples"] > 0) & df["velocity_rad_s"].notna()]
    stats_, stages = [], []     # (mean, std, se, ci95) per stage, written to the table at once
    for n, joint in zip(df.loc[rows, "n_samples"].astype(int), df.loc[rows, "joint"].astype(int)):
        fj = f[pos:pos + n, joint - 1]
        stages.append((all_rows[pos:pos + n], joint))
        pos += n
        stats_.append((float(fj.mean()), float(fj.std(ddof=1)), *batch_mean_se(fj)))
    if stats_:
        df.loc[rows, ["friction_Nm", "friction_std_Nm", "friction_se_Nm", "friction_ci95_Nm"]] = stats_
        df.loc[rows, "timing_shift_Nm"] = _timing_shifts(t_s, q, stages, dynamics, window_s, timing_se_s)


def _timing_shifts(t_s: np.ndarray, q: np.ndarray, stages: list, dynamics, window_s: float, timing_se_s: float,
                   per_stage: int = 50) -> np.ndarray:
    """Per stage ``(rows, joint)``: the change of its mean friction when the rigid body is taken ``timing_se_s``
    later (:data:`TIMING_SE_PERIODS`), N m: the rate of change of the joint's quasi-static rigid-body torque
    (gravity, Coriolis and centrifugal: inverse dynamics without acceleration, at ``per_stage`` samples spread
    over the stage; a line through them) times ``timing_se_s``. The inertial term is left out: its mean over a
    stage is zero and its rate is the ringing after a blend, noise that would only blur the estimate."""
    if timing_se_s == 0.0 or not stages:
        return np.zeros(len(stages))
    picks = [rk[np.unique(np.linspace(0, len(rk) - 1, min(per_stage, len(rk))).round().astype(int))]
             for rk, _ in stages]
    sub = np.concatenate(picks)
    dt = float(np.median(np.diff(t_s)))
    qd = savgol_derivative(q, dt, window_s, 2, 1)[sub]
    if hasattr(dynamics, "inverse_dynamics_many"):        # a WamDynamics: the batch helper
        quasi = dynamics.inverse_dynamics_many(q[sub], qd, np.zeros_like(qd))
    else:
        quasi = np.array([dynamics.inverse_dynamics(q[i], qd[k], np.zeros(q.shape[1])) for k, i in enumerate(sub)])
    out, pos = np.zeros(len(stages)), 0
    for k, (rk_sub, (_, joint)) in enumerate(zip(picks, stages)):
        n = len(rk_sub)
        out[k] = fit_line(t_s[rk_sub], quasi[pos:pos + n, joint - 1])[1] * timing_se_s if n >= 2 else 0.0
        pos += n
    return out
