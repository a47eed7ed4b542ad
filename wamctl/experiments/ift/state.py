"""What an IFT run keeps between iterations: each joint's tuning state (``ift_state.json``), the iteration table
(``iterations.parquet/.csv``, thesis Table 5.1) and the per-iteration experiment tables (``iter-NNN-*.parquet``)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from wamctl.report.ift import STATE_FILE as STATE_FILE  # named with the run directory's other files there
from wamctl.report.ift import iteration_file
from wamctl.runs.store import atomic_write

STATE_FORMAT = "wamctl-ift-state/1"
ITERATION_COLUMNS = ["iteration", "joint", "method", "gamma", "kp", "kd", "ki", "J", "J_model", "status", "stage",
                     "note"]


@dataclass
class JointState:
    """One joint's tuning state (what ``ift_state.json`` holds per joint)."""

    joint: int
    rho: np.ndarray                 # (3,) accepted gains
    J: float = float("nan")         # plant J at rho
    J_model: float = float("nan")   # model J at rho
    iteration: int = 0              # iteration whose first experiment gave J
    gradient: np.ndarray | None = None
    gauss_newton: np.ndarray | None = None
    bfgs_B: np.ndarray | None = None
    prev_rho: np.ndarray | None = None        # the previously accepted gains and their gradient (for BFGS)
    prev_gradient: np.ndarray | None = None
    stage: int = 0
    stage_accepted: int = 0
    done: bool = False
    done_reason: str = ""
    pending: dict | None = None     # proposal awaiting its plant experiment: rho, method, gamma, J_model, stage

    def to_dict(self) -> dict:
        def arr(x):
            return None if x is None else np.asarray(x, float).tolist()
        return {"joint": self.joint, "rho": arr(self.rho), "J": self.J, "J_model": self.J_model,
                "iteration": self.iteration, "gradient": arr(self.gradient),
                "gauss_newton": arr(self.gauss_newton), "bfgs_B": arr(self.bfgs_B), "prev_rho": arr(self.prev_rho),
                "prev_gradient": arr(self.prev_gradient), "stage": self.stage, "stage_accepted": self.stage_accepted,
                "done": self.done, "done_reason": self.done_reason, "pending": self.pending}

    @classmethod
    def from_dict(cls, d: dict) -> JointState:
        def arr(x):
            return None if x is None else np.asarray(x, float)
        return cls(int(d["joint"]), arr(d["rho"]), float(d["J"]), float(d["J_model"]), int(d["iteration"]),
                   arr(d.get("gradient")), arr(d.get("gauss_newton")), arr(d.get("bfgs_B")), arr(d.get("prev_rho")),
                   arr(d.get("prev_gradient")), int(d["stage"]), int(d["stage_accepted"]), bool(d["done"]),
                   d.get("done_reason", ""), d.get("pending"))


@dataclass
class IterationTables:
    """Rows of the per-iteration tables, written when the iteration completes (or is interrupted)."""

    exp1: list[pd.DataFrame] = field(default_factory=list)
    exp2: list[pd.DataFrame] = field(default_factory=list)
    check: list[pd.DataFrame] = field(default_factory=list)

    def write(self, run_path: Path, k: int) -> None:
        """``iter-NNN-{exp1,exp2,check}.parquet`` of iteration ``k``, each only if it has rows."""
        for name, parts in (("exp1", self.exp1), ("exp2", self.exp2), ("check", self.check)):
            if parts:
                write_parquet(run_path / iteration_file(k, name), pd.concat(parts, ignore_index=True))


def write_parquet(path: Path, df: pd.DataFrame) -> None:
    """Write a table so that readers see the old or the new file, never a half-written one."""
    atomic_write(path, lambda tmp: df.to_parquet(tmp, index=False))


def iteration_row(k, joint, method, gamma, rho, J, J_model, status, stage, note) -> dict:
    """One row of the iteration table: gains ``rho`` tried at iteration ``k`` and what became of them."""
    return {"iteration": int(k), "joint": int(joint), "method": method, "gamma": float(gamma),
            "kp": float(rho[0]), "kd": float(rho[1]), "ki": float(rho[2]), "J": float(J), "J_model": float(J_model),
            "status": status, "stage": int(stage), "note": note}


def iterations_frame(rows: list[dict]) -> pd.DataFrame:
    return pd.DataFrame(rows, columns=ITERATION_COLUMNS)
