"""The tuning itself: per iteration and joint, the first experiment, acceptance on the plant, the second
experiment, and the next proposal (backtracked on the model); the state saved after every iteration."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import yaml

from wamctl.analysis import ift as A
from wamctl.errors import DataFormatError
from wamctl.experiments.ift.comparison import compare_strategies
from wamctl.experiments.ift.experiments import CheckResult, IftExperiments, check_frame
from wamctl.experiments.ift.state import (
    STATE_FILE,
    STATE_FORMAT,
    IterationTables,
    JointState,
    iteration_row,
    iterations_frame,
    write_parquet,
)
from wamctl.report.ift import ITERATIONS_TABLE
from wamctl.runs.store import RunDir, atomic_write, atomic_write_text, signals_deferred, utc_now
from wamctl.specs.ift import IftSpec, gain_bounds


class IftTuner(IftExperiments):
    """Runs the tuning of :class:`IftSpec` into a run directory; resumable from ``ift_state.json``."""

    def __init__(self, spec: IftSpec, run: RunDir, base_dir: Path | None = None, progress=None):
        super().__init__(spec, run, base_dir, progress)
        self.lo, self.hi = gain_bounds(spec)
        self.joints: dict[int, JointState] = {}
        self.iteration = -1                 # last completed iteration
        self.phase = "tuning"
        self.rows: list[dict] = []          # the iteration table

    # ------------------------------------------------------------------ state
    def state_dict(self) -> dict:
        return {"format": STATE_FORMAT, "last_completed_iteration": self.iteration, "phase": self.phase,
                "plant_experiments": self.plant_experiments, "model_experiments": self.model_experiments,
                "plant_time_s": self.plant_time_s, "saved_utc": utc_now(),
                "joints": {str(j): st.to_dict() for j, st in self.joints.items()}}

    def save_state(self) -> None:
        # The state, its tables and the manifest agree whenever Ctrl-C comes (issue 32). SIGKILL cannot be held
        # back: the tables are written first and the state file last, so that a death between two writes leaves a
        # state that names only iterations whose rows are on disk (load_state drops rows of later ones).
        with signals_deferred():
            df = iterations_frame(self.rows)
            write_parquet(self.run.path / f"{ITERATIONS_TABLE}.parquet", df)
            atomic_write(self.run.path / f"{ITERATIONS_TABLE}.csv", lambda tmp: df.to_csv(tmp, index=False))
            self.run.flush_events()
            atomic_write_text(self.run.path / STATE_FILE, json.dumps(self.state_dict(), indent=2))
            self.run.update_manifest(ift={"last_completed_iteration": self.iteration, "phase": self.phase,
                                          "plant_experiments": self.plant_experiments,
                                          "model_experiments": self.model_experiments})

    def load_state(self) -> None:
        path = self.run.path / STATE_FILE
        if not path.is_file():
            return  # interrupted before the first iteration completed: start again
        d = json.loads(path.read_text())
        if d.get("format") != STATE_FORMAT:
            raise DataFormatError(f"{path}: not an IFT state file ({d.get('format')!r})")
        self.iteration = int(d["last_completed_iteration"])
        self.phase = d["phase"]
        self.plant_experiments = int(d["plant_experiments"])
        self.model_experiments = int(d["model_experiments"])
        self.plant_time_s = float(d["plant_time_s"])
        self.joints = {int(k): JointState.from_dict(v) for k, v in d["joints"].items()}
        it = self.run.path / f"{ITERATIONS_TABLE}.parquet"
        if it.is_file():
            df = pd.read_parquet(it)
            df = df[df["iteration"] <= self.iteration]
            self.rows = df.to_dict("records")

    # ------------------------------------------------------------------ hooks
    def _after_iteration(self, k: int) -> None:
        """Called after iteration ``k`` is saved (a seam for tests that interrupt a tuning)."""

    # ------------------------------------------------------------------ gains
    def gains_matrix(self) -> np.ndarray:
        """(7, 3) the accepted gains of every joint (initial gains for joints not tuned): the tuned PID."""
        g = self.g0.copy()
        for j, st in self.joints.items():
            g[j - 1] = st.rho
        return g

    def tuned_gains(self) -> np.ndarray:
        return self.gains_matrix()

    def write_gains(self) -> None:
        g = self.tuned_gains()
        out = {"controller": {"kind": "pid", "kp": g[:, 0].tolist(), "kd": g[:, 1].tolist(), "ki": g[:, 2].tolist(),
                              "gravity_compensation": self.spec.controller.gravity_compensation},
               "iteration": self.iteration, "joints": self.s.joints}
        nxt = {j: st.pending["rho"] for j, st in self.joints.items() if st.pending}
        if nxt:
            out["next"] = {"note": "proposals passed on the model, not yet run on the plant",
                           "joints": {int(j): {"kp": v[0], "kd": v[1], "ki": v[2]} for j, v in nxt.items()}}
        (self.run.path / "tuned_gains.yaml").write_text(yaml.safe_dump(out, sort_keys=False))

    # ------------------------------------------------------------------ proposals
    def propose(self, k: int, st: JointState, gains: np.ndarray, qref: np.ndarray,
                tables: IterationTables) -> None:
        """Find a proposal for ``st`` that passes the model check (backtracking gamma, then later stages); sets
        ``st.pending`` or marks the joint done."""
        sg = self.s.safeguards
        joint = st.joint
        lo, hi = self.lo[joint - 1], self.hi[joint - 1]
        tried: dict[tuple, CheckResult] = {}   # (method, gamma) already simulated from these gains
        while st.stage < len(self.s.schedule):
            stage = self.s.schedule[st.stage]
            if stage.method == "bfgs":
                if st.bfgs_B is None:
                    st.bfgs_B = st.gauss_newton.copy()     # B0: the Gauss-Newton estimate (see the package doc)
                R = st.bfgs_B
            else:
                R = st.gauss_newton
            gamma = stage.gamma
            for attempt in range(sg.backtracking + 1):
                new = A.ift_update(st.rho, st.gradient, R, gamma, lo, hi)
                if np.allclose(new, st.rho, rtol=1e-9, atol=0):
                    self.run.event(self.plant_time_s, "ift_stalled", joint,
                                   f"iteration {k}: {stage.method} gamma={gamma:g}: no change (gains at bounds or "
                                   f"zero gradient)")
                    break
                key = (stage.method, float(np.float32(gamma)), st.stage if stage.method == "bfgs" else -1)
                if key in tried:        # a later stage repeating a step already rejected from these gains
                    gamma *= sg.backtrack_factor
                    continue
                res = tried[key] = self.check(joint, new, gains, qref, st.J_model)
                if res.rows is not None:
                    tables.check.append(check_frame(joint, attempt, gamma, new, res))
                if res.ok:
                    st.pending = {"rho": new.tolist(), "method": stage.method, "gamma": gamma,
                                  "J_model": res.J_model, "stage": st.stage}
                    return
                self.run.event(self.plant_time_s, "ift_rejected", joint,
                               f"iteration {k}: {stage.method} gamma={gamma:g} kp={new[0]:.6g} kd={new[1]:.6g} "
                               f"ki={new[2]:.6g}: {res.reason}")
                self.rows.append(iteration_row(k, joint, stage.method, gamma, new, float("nan"), res.J_model,
                                               "model_rejected", st.stage, res.reason))
                gamma *= sg.backtrack_factor
            self._next_stage(k, st, f"{stage.method} gamma={stage.gamma:g}: no acceptable proposal on the model")
        if not st.done:
            st.done, st.done_reason = True, "schedule finished"

    def _next_stage(self, k: int, st: JointState, why: str) -> None:
        st.stage += 1
        st.stage_accepted = 0
        if st.stage < len(self.s.schedule):
            nxt = self.s.schedule[st.stage]
            self.run.event(self.plant_time_s, "ift_stage", st.joint,
                           f"iteration {k}: {why}; next {nxt.method} gamma={nxt.gamma:g}")
        else:
            st.done, st.done_reason = True, why
            self.run.event(self.plant_time_s, "ift_done", st.joint, f"iteration {k}: {why}; schedule finished")

    # ------------------------------------------------------------------ iteration
    def iterate(self, k: int) -> None:
        """Iteration ``k`` for every active joint: first experiment on the plant at the pending proposal (the
        initial gains at k = 0), acceptance, second experiment, next proposal."""
        tables = IterationTables()
        try:
            # The other joints hold with their initial gains during the tuning, so that each joint's J depends on its
            # own gains only (decentralised tuning; the order of the joints does not matter). The comparison runs
            # every joint with its tuned gains.
            gains = self.g0.copy()
            active = [j for j in self.s.joints if k == 0 or (not self.joints[j].done and self.joints[j].pending)]
            for n, joint in enumerate(active):
                if self.progress:
                    self.progress(n, len(active), f"IFT iteration {k}: joint {joint}")
                self._iterate_joint(k, joint, gains, tables)
        finally:  # also an interrupted iteration's experiments reach the tables (resume redoes it)
            tables.write(self.run.path, k)

    def _iterate_joint(self, k: int, joint: int, gains: np.ndarray, tables: IterationTables) -> None:
        if k == 0:
            rho = self.g0[joint - 1].copy()
            st = self.joints[joint] = JointState(joint, rho)
        else:
            st = self.joints[joint]
            rho = np.asarray(st.pending["rho"], float)
        r, y1, qref, rho = self.first_experiment(k, joint, rho, gains, tables)
        J = A.objective(y1 - r)
        accepted = self._take_initial(st, rho, J, gains, qref) if k == 0 else self._judge_on_plant(k, st, rho, J)
        if accepted:
            self._learn(k, st, gains, r, y1, qref, tables)
        if not st.done and k >= self.s.max_iterations:
            st.done, st.done_reason = True, f"max_iterations ({self.s.max_iterations})"
            self.run.event(self.plant_time_s, "ift_done", joint, f"iteration {k}: max_iterations reached")
        if not st.done:
            # with measured runs, a proposal is made even after the last run: it is what to record next
            self.propose(k, st, gains, qref, tables)

    def _take_initial(self, st: JointState, rho: np.ndarray, J: float, gains: np.ndarray,
                      qref: np.ndarray) -> bool:
        """Iteration 0: the initial gains are accepted as they are; the model check only warns."""
        st.rho, st.J, st.iteration = rho, J, 0
        res = self.check(st.joint, rho, gains, qref, float("nan"))
        st.J_model = res.J_model
        if not res.ok:
            self.run.event(self.plant_time_s, "ift_warning", st.joint,
                           f"the initial gains fail the model check: {res.reason}")
        self.rows.append(iteration_row(0, st.joint, "initial", float("nan"), rho, J, st.J_model, "initial", 0, ""))
        return True

    def _judge_on_plant(self, k: int, st: JointState, rho: np.ndarray, J: float) -> bool:
        """The pending proposal is accepted when its plant J decreased at ``stop_digits``; else the previous
        gains stay and the schedule moves on."""
        p = st.pending
        accepted = A.decreased(J, st.J, self.s.stop_digits)
        self.rows.append(iteration_row(k, st.joint, p["method"], p["gamma"], rho, J, p["J_model"],
                                       "accepted" if accepted else "plant_rejected", p["stage"],
                                       "" if accepted else f"J {J:.4e} did not decrease below {st.J:.4e}"))
        st.pending = None
        if accepted:
            st.prev_rho, st.prev_gradient = st.rho.copy(), st.gradient.copy()
            st.rho, st.J, st.J_model, st.iteration = rho, J, p["J_model"], k
            st.stage_accepted += 1
        else:
            self.run.event(self.plant_time_s, "ift_no_decrease", st.joint,
                           f"iteration {k}: J = {J:.4e} on the plant, not below {st.J:.4e}: previous gains kept")
            self._next_stage(k, st, "J stopped decreasing on the plant")
        return accepted

    def _learn(self, k: int, st: JointState, gains: np.ndarray, r: np.ndarray, y1: np.ndarray, qref: np.ndarray,
               tables: IterationTables) -> None:
        """At newly accepted gains: the second experiment (gradient, Gauss-Newton Hessian), the BFGS update, and
        the end of a stage whose iterations are used up."""
        est = self.estimate(k, st.joint, st.rho, gains, r, y1, qref, tables)
        st.gradient, st.gauss_newton = est.gradient, est.gauss_newton
        if (k > 0 and st.bfgs_B is not None and st.prev_rho is not None
                and self.s.schedule[min(st.stage, len(self.s.schedule) - 1)].method == "bfgs"):
            st.bfgs_B, updated = A.bfgs_update(st.bfgs_B, st.rho - st.prev_rho, st.gradient - st.prev_gradient)
            if not updated:
                self.run.event(self.plant_time_s, "ift_bfgs_skip", st.joint,
                               f"iteration {k}: z^T s <= 0, B kept (eq. 2.17)")
        stage = self.s.schedule[st.stage] if st.stage < len(self.s.schedule) else None
        if stage is not None and stage.iterations is not None and st.stage_accepted >= stage.iterations:
            self._next_stage(k, st, f"{stage.method} gamma={stage.gamma:g}: {stage.iterations} iteration(s)")

    def active(self) -> bool:
        return any(not st.done and st.pending for st in self.joints.values())

    # ------------------------------------------------------------------ main loop
    def execute(self) -> None:
        if self.phase == "tuning":
            k = self.iteration + 1
            while k == 0 or self.active():
                if self.s.plant.source == "measured" and k >= len(self.s.plant.runs):
                    self.run.event(self.plant_time_s, "ift_awaiting_measured_run", None,
                                   f"iteration {k}: no measured run {k + 1}; record the proposed gains "
                                   f"(tuned_gains.yaml: next) and resume")
                    break
                self.iterate(k)
                self.iteration = k
                self.write_gains()
                self.save_state()
                self._after_iteration(k)
                k += 1
            if not self.active():
                self.phase = "comparison"
                self.save_state()
        if self.phase == "comparison":
            if self.s.comparison.enabled and self.s.plant.source == "backend":
                self.comparison()
            self.phase = "done"
            self.save_state()

    def comparison(self) -> None:
        """The strategy comparison of thesis 5.4 with the tuned gains (:mod:`.comparison`)."""
        compare_strategies(self, self.tuned_gains())

