"""The tables of an ``hmi_block`` run directory: their names and columns, the codes of the trajectory's
categorical columns, and reading and writing them (each file appears whole or not at all)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from wamctl.errors import DataFormatError
from wamctl.hmi.strategy import Hold, Motion
from wamctl.model import params as P
from wamctl.runs.store import atomic_write, remove_chunks, signals_deferred

MOTION_CODES: tuple[str, ...] = tuple(m.value for m in Motion)
HOLD_CODES: tuple[str, ...] = tuple(h.value for h in Hold)
ARM_HOLD_CODES: tuple[str, ...] = ("", "stop", "blink", "no_gaze", "stall", "gripper", "not_started", "session_ended")

TRIALS_TABLE = "trials"
EVENTS_FILE = "hmi_events.csv"
TRAJECTORY_TABLE = "trajectory"
TRIAL_TABLE_COLUMNS = ["trial", "subject", "condition", "strategy", "filter", "profile", "location", "attempt", "hit",
                       "time_s", "outcome", "error_m", "target_x_m", "target_y_m", "hand_x_m", "hand_y_m",
                       "t_start_s", "n_blinks", "n_voluntary_blinks", "n_stalls", "path_m", "max_tilt_deg",
                       "subject_seed"]
EVENT_COLUMNS = ["trial", "location", "attempt", "t_s", "t_trial_s", "kind", "detail"]
TRAJECTORY_COLUMNS = (["trial", "t_s", "t_trial_s", "gaze_t_s", "gaze_x_px", "gaze_y_px", "gaze_flags", "motion",
                       "level", "vx_cmd_m_s", "vy_cmd_m_s", "hold", "arm_hold", "hand_x_m", "hand_y_m", "hand_z_m",
                       "tilt_deg", "ref_x_m", "ref_y_m", "gripper"]
                      + [f"q_{j}_rad" for j in range(1, P.N_JOINTS + 1)])


def read_done(run_path: Path) -> tuple[list[dict], list[dict]]:
    """(trial rows, event rows) already in a run directory (resume); events of unfinished trials are dropped."""
    trial_rows: list[dict] = []
    event_rows: list[dict] = []
    if (run_path / f"{TRIALS_TABLE}.csv").is_file():
        df = pd.read_csv(run_path / f"{TRIALS_TABLE}.csv")
        missing = [c for c in TRIAL_TABLE_COLUMNS if c not in df.columns]
        if missing:
            raise DataFormatError(f"{run_path / (TRIALS_TABLE + '.csv')}: missing column(s) {missing}")
        trial_rows = df[TRIAL_TABLE_COLUMNS].to_dict("records")
    done = {int(r["trial"]) for r in trial_rows}
    if (run_path / EVENTS_FILE).is_file():
        ev = pd.read_csv(run_path / EVENTS_FILE, keep_default_na=False, na_values={"t_trial_s": [""]})
        keep = ev["trial"].isin(list(done) + [0])
        event_rows = ev[keep].to_dict("records")
    return trial_rows, event_rows


def write_tables(run_path: Path, trial_rows: list[dict], event_rows: list[dict]) -> None:
    """``trials.csv/.parquet`` (in trial order) and ``hmi_events.csv``."""
    trials = pd.DataFrame(trial_rows, columns=TRIAL_TABLE_COLUMNS).sort_values("trial")
    events = pd.DataFrame(event_rows, columns=EVENT_COLUMNS)
    # The three files agree whenever Ctrl-C comes (issue 32). SIGKILL cannot be held back: trials.csv, which
    # read_done takes as the trials done, is written last, so that a death between two writes leaves no trial
    # counted done without its events.
    with signals_deferred():
        atomic_write(run_path / EVENTS_FILE, lambda p: events.to_csv(p, index=False))
        atomic_write(run_path / f"{TRIALS_TABLE}.parquet", lambda p: trials.to_parquet(p, index=False))
        atomic_write(run_path / f"{TRIALS_TABLE}.csv", lambda p: trials.to_csv(p, index=False))


def write_trajectory_part(run_path: Path, number: int, rows: list[list[float]]) -> None:
    """One trial's trajectory: ``trajectory/part-NNNNN.parquet``."""
    d = run_path / TRAJECTORY_TABLE
    d.mkdir(exist_ok=True)
    df = pd.DataFrame(np.array(rows, float).reshape(-1, len(TRAJECTORY_COLUMNS)), columns=TRAJECTORY_COLUMNS)
    atomic_write(d / f"part-{number:05d}.parquet", lambda p: df.to_parquet(p, index=False))


def consolidate_trajectory(run_path: Path, complete: bool) -> None:
    """Every trial's part into ``trajectory.parquet/.csv``. The parts stay while trials remain (a resume adds
    to them); once the block is ``complete`` they are removed, the consolidated table holding their rows."""
    d = run_path / TRAJECTORY_TABLE
    parts = sorted(d.glob("part-*.parquet")) if d.is_dir() else []
    if not parts:
        return
    df = pd.concat([pd.read_parquet(p) for p in parts], ignore_index=True)
    with signals_deferred():    # never a half-written file (issue 32), nor after a SIGKILL
        atomic_write(run_path / f"{TRAJECTORY_TABLE}.parquet", lambda p: df.to_parquet(p, index=False))
        atomic_write(run_path / f"{TRAJECTORY_TABLE}.csv", lambda p: df.to_csv(p, index=False))
    if complete:
        remove_chunks(run_path, TRAJECTORY_TABLE, len(df))
