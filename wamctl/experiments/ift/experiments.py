"""The experiments of an IFT iteration: the first on the plant (the spec's backend or a recorded run), the second
on the model, and the safeguard check of a proposal on the model. :class:`IftExperiments` holds what they share
(the model, the initial gains, the counts of experiments and of plant time); the tuner builds on it."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from wamctl.analysis import ift as A
from wamctl.backends import make_backend
from wamctl.control.controllers import JointController
from wamctl.control.trajectory import Reference
from wamctl.errors import DataFormatError, SafetyLimitError, WamctlError
from wamctl.experiments.common import declared_dynamics
from wamctl.experiments.engine import LoopRecorder, data_columns, run_loop
from wamctl.experiments.ift.planning import DT_S, model_plant_spec, returns_to_start, task_reference
from wamctl.experiments.ift.state import IterationTables
from wamctl.io import resolve_path
from wamctl.model import params as P
from wamctl.model.plant import Plant
from wamctl.runs.store import RunDir
from wamctl.specs.ift import IftSpec, initial_gains

_COLUMNS = data_columns(True)
#: First column of each 7-wide block of the engine's rows: reference, measured and true position, torque.
Q_REF = _COLUMNS.index("q_ref_1_rad")
Q_MEAS = _COLUMNS.index("q_1_rad")
TAU = _COLUMNS.index("tau_1_Nm")
Q_TRUE = _COLUMNS.index("q_true_1_rad")


@dataclass
class CheckResult:
    ok: bool
    reason: str
    J_model: float
    rows: np.ndarray | None = None


def lowpass(y: np.ndarray, cutoff_hz: float) -> np.ndarray:
    """Zero-phase 2nd-order Butterworth low-pass at the control rate (``objective_signal: filtered``)."""
    from scipy.signal import butter, filtfilt
    b, a = butter(2, cutoff_hz / (P.CONTROL_RATE_HZ / 2))
    return filtfilt(b, a, y) if len(y) > 3 * max(len(a), len(b)) else y


def with_joint_gains(gains: np.ndarray, joint: int, rho: np.ndarray) -> np.ndarray:
    """A copy of the (7, 3) ``gains`` with ``joint`` (1-based) at ``rho``."""
    g = gains.copy()
    g[joint - 1] = rho
    return g


def check_frame(joint: int, attempt: int, gamma: float, rho: np.ndarray, res: CheckResult) -> pd.DataFrame:
    """The model simulation of a proposal, for ``iter-NNN-check.parquet``."""
    j0 = joint - 1
    return pd.DataFrame({
        "joint": joint, "attempt": attempt, "gamma": gamma, "kp": rho[0], "kd": rho[1], "ki": rho[2],
        "accepted": res.ok, "t_s": np.arange(len(res.rows)) * DT_S, "q_ref_rad": res.rows[:, Q_REF + j0],
        "q_rad": res.rows[:, Q_MEAS + j0], "tau_Nm": res.rows[:, TAU + j0]})


class IftExperiments:
    """The experiments of one tuning of ``spec`` into ``run``; counts them and the plant's arm time."""

    def __init__(self, spec: IftSpec, run: RunDir, base_dir: Path | None = None, progress=None):
        self.spec = spec
        self.s = spec.ift
        self.run = run
        self.base_dir = base_dir
        self.progress = progress
        mspec, mdir = model_plant_spec(spec, base_dir)
        self.model = Plant(mspec, mdir)
        self.g0 = initial_gains(spec)
        self.gravity = declared_dynamics(spec).gravity_view if spec.controller.gravity_compensation else None
        self.with_return = returns_to_start(spec)
        self.plant_experiments = 0
        self.model_experiments = 0
        self.plant_time_s = 0.0
        self.last_plant_rows = None     # (joint, rows, columns) of the last plant experiment, even a failed one
        self._baseline: dict[int, tuple[np.ndarray, np.ndarray]] = {}   # joint -> (rho, model y at rho)
        self._measured_cache: dict[int, object] = {}

    # ------------------------------------------------------------------ closed loops
    def _controller(self, gains: np.ndarray, ff: np.ndarray | None = None) -> JointController:
        return JointController(gains[:, 0], gains[:, 1], gains[:, 2], DT_S, gravity=self.gravity,
                               feedforward_Nm=ff)

    def _plant_seed(self, k: int, joint: int, salt: int = 0) -> int:
        return int(np.random.SeedSequence([self.spec.seed, k, joint, salt]).generate_state(1)[0])

    def _model_seed(self, joint: int) -> int:
        return self._plant_seed(1_000_000, joint, 7)

    def _run_backend(self, joint: int, gains: np.ndarray, ref: Reference, seed: int,
                     ff: np.ndarray | None = None) -> tuple[np.ndarray, list[str], str | None]:
        """One experiment on the spec's backend. Returns (rows, columns, failure reason or None); rows hold every
        sample recorded, also when a safety limit stopped it."""
        q0 = ref.q_rad[0]
        backend = make_backend(self.spec, self.base_dir, q0_rad=q0, seed=seed)
        rec = None
        reason = None
        try:
            with backend:
                truth = hasattr(backend, "truth")
                rec = LoopRecorder(len(ref), truth)
                run_loop(backend, self._controller(gains, ff), ref, rec)
        except SafetyLimitError as exc:
            reason = f"safety limit: {exc}"
        finally:
            self.plant_experiments += 1
            cols = rec.columns if rec is not None else data_columns(False)
            rows = rec.result() if rec is not None else np.empty((0, len(cols)))
            self.last_plant_rows = (joint, rows, cols)   # kept for the tables if an interruption propagates
            if rec is not None:
                self.plant_time_s += rec.n * DT_S
        return rows, cols, reason

    def _run_model(self, gains: np.ndarray, q_ref: np.ndarray, seed: int) -> tuple[np.ndarray, str | None]:
        """The model's closed loop on ``q_ref`` (n, 7) from rest at ``q_ref[0]``; rows as data_columns(True)."""
        from wamctl.backends.sim import SimBackend
        ref = Reference(np.arange(len(q_ref)) * DT_S, q_ref, np.zeros_like(q_ref), np.zeros_like(q_ref), [])
        backend = SimBackend(self.model, q_ref[0], np.random.default_rng(seed),
                             self.spec.backend.physics_substeps if self.spec.backend.kind == "sim" else 2)
        rec = LoopRecorder(len(ref), True)
        reason = None
        self.model_experiments += 1
        try:
            with backend:
                run_loop(backend, self._controller(gains), ref, rec)
        except SafetyLimitError as exc:
            reason = f"unstable on the model ({exc})"
        return rec.result(), reason

    # ------------------------------------------------------------------ first experiment
    def first_experiment(self, k: int, joint: int, rho: np.ndarray, gains: np.ndarray,
                         tables: IterationTables) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Returns (r, y1 used for J, full reference (n, 7), rho actually run) of ``joint`` at iteration k."""
        if self.s.plant.source == "measured":
            r, y, qref, rho_run, df = self._measured_experiment(k, joint, rho)
        else:
            r, y, qref, df = self._plant_experiment(k, joint, with_joint_gains(gains, joint, rho), tables)
            rho_run = rho
        tables.exp1.append(df)
        if self.s.objective_signal == "filtered":
            y = lowpass(y, self.s.filter_cutoff_hz)
        return r, y, qref, rho_run

    def _plant_experiment(self, k: int, joint: int, gains: np.ndarray, tables: IterationTables):
        """The task on the backend: (r, y, reference (n, 7), the experiment's table). A safety stop and an
        interruption leave their samples in ``tables`` and propagate."""
        j0 = joint - 1
        ref, n_task = task_reference(self.spec, joint, self.with_return)
        self.last_plant_rows = None
        try:
            rows, cols, reason = self._run_backend(joint, gains, ref, self._plant_seed(k, joint))
        except BaseException:      # Ctrl-C, a device error: the samples so far still reach the table
            if self.last_plant_rows is not None:
                _, rows, cols = self.last_plant_rows
                tables.exp1.append(pd.DataFrame(rows, columns=cols).assign(joint=joint))
            raise
        df = pd.DataFrame(rows, columns=cols)
        df.insert(0, "joint", joint)
        if reason is not None:
            tables.exp1.append(df)
            raise SafetyLimitError(f"joint {joint}, iteration {k}: the first experiment stopped: {reason}")
        return rows[:n_task, Q_REF + j0], rows[:n_task, Q_MEAS + j0], ref.q_rad[:n_task], df

    def _measured_experiment(self, k: int, joint: int, rho: np.ndarray):
        """The task from recorded run ``k``, resampled to the control period: (r, y, reference (n, 7), the gains
        the run used, its table)."""
        from wamctl.analysis.rotation import find_rotations
        from wamctl.runs.measured import load_run_data
        runs = self.s.plant.runs
        path = resolve_path(runs[k], self.base_dir)
        rd = self._measured_cache.get(k)
        if rd is None:
            rd = self._measured_cache[k] = load_run_data(path, reader="tune-ift")
        data = rd.data
        rot = [r for r in find_rotations(data) if r.joint == joint]
        if not rot:
            raise DataFormatError(f"{path}: joint {joint} does not move in this run")
        rot = rot[0]
        t = self.s.task
        i0 = max(0, rot.i_start - int(round(t.settle_s * rd.meta.sample_rate_hz)))
        sl = data.iloc[i0: rot.i_final + 1]
        t_in = sl["t_s"].to_numpy() - sl["t_s"].to_numpy()[0]
        t_out = np.arange(0.0, t_in[-1] + 1e-12, DT_S)   # resampled to the control period (the IFT filters)
        qref = np.stack([np.interp(t_out, t_in, sl[f"q_ref_{i}_rad"].to_numpy()) for i in range(1, 8)], 1)
        y = np.interp(t_out, t_in, sl[f"q_{joint}_rad"].to_numpy())
        c = rd.meta.controller
        rho_run = np.array([c.kp[joint - 1], c.kd[joint - 1], (c.ki or [0.0] * 7)[joint - 1]], float)
        if not np.allclose(rho_run, rho, rtol=1e-6, atol=1e-12):
            self.run.event(self.plant_time_s, "ift_measured_gains", joint,
                           f"iteration {k}: {path.name} ran kp={rho_run[0]:g} kd={rho_run[1]:g} ki={rho_run[2]:g}"
                           f" (expected {rho[0]:g}, {rho[1]:g}, {rho[2]:g}); its gains are used")
        df = sl.copy()
        df.insert(0, "joint", joint)
        self.plant_experiments += 1
        self.plant_time_s += float(t_in[-1])
        return qref[:, joint - 1], y, qref, rho_run, df.reset_index(drop=True)

    # ------------------------------------------------------------------ second experiment
    def _model_position(self, gains: np.ndarray, q_ref: np.ndarray, joint: int, failure: str) -> np.ndarray:
        """The model's true position of ``joint`` on ``q_ref`` (no quantisation); WamctlError if unstable."""
        rows, reason = self._run_model(gains, q_ref, self._model_seed(joint))
        if reason is not None:
            raise WamctlError(f"joint {joint}: {failure}: {reason}")
        return rows[:, Q_TRUE + joint - 1]

    def estimate(self, k: int, joint: int, rho: np.ndarray, gains: np.ndarray, r: np.ndarray, y1: np.ndarray,
                 qref: np.ndarray, tables: IterationTables) -> A.IftEstimate:
        """The second experiment on the model and the IFT quantities at ``rho``."""
        j0 = joint - 1
        g = with_joint_gains(gains, joint, rho)
        eps = self.s.perturbation
        r2 = eps * (r - y1)                       # the second experiment's reference (about r or q0)
        unstable = "the second experiment is unstable on the model"
        if self.s.second_experiment == "incremental":
            base = self._baseline.get(joint)
            if base is not None and np.array_equal(base[0], rho) and len(base[1]) == len(r):
                y_base = base[1]
            else:
                y_base = self._model_position(g, qref, joint, "the model is unstable at the accepted gains")
            q2 = qref.copy()
            q2[:, j0] = qref[:, j0] + r2
            y2 = (self._model_position(g, q2, joint, unstable) - y_base) / eps
        else:
            q2 = np.tile(qref[0], (len(r), 1))
            q2[:, j0] = qref[0, j0] + r2
            y2 = (self._model_position(g, q2, joint, unstable) - qref[0, j0]) / eps
        est = A.ift_estimate(rho, y1 - r, y2, DT_S)
        tables.exp2.append(pd.DataFrame({
            "joint": joint, "t_s": np.arange(len(r)) * DT_S, "r_rad": r, "y1_rad": y1, "y_tilde_rad": y1 - r,
            "r2_rad": r2, "y2_rad": y2, "psi_kp": est.psi[:, 0], "psi_kd": est.psi[:, 1], "psi_ki": est.psi[:, 2]}))
        return est

    # ------------------------------------------------------------------ safeguards
    def check(self, joint: int, rho: np.ndarray, gains: np.ndarray, qref: np.ndarray, J_ref: float) -> CheckResult:
        """Simulate ``rho`` on the model; accept only a stable proposal inside the torque limits whose model J
        decreases below ``J_ref``."""
        j0 = joint - 1
        sg = self.s.safeguards
        rows, reason = self._run_model(with_joint_gains(gains, joint, rho), qref, self._model_seed(joint))
        if reason is not None:
            return CheckResult(False, reason, float("inf"), rows)
        if not np.all(np.isfinite(rows)):
            return CheckResult(False, "unstable on the model (non-finite state)", float("inf"), rows)
        e = rows[:, Q_REF + j0] - rows[:, Q_MEAS + j0]
        tau = rows[:, TAU:TAU + P.N_JOINTS]
        J = A.objective(-e)
        emax = float(np.abs(e).max())
        if emax > sg.max_error_rad:
            return CheckResult(False, f"diverging error on the model (|e| = {emax:.4g} rad > {sg.max_error_rad:g})",
                               J, rows)
        frac = np.abs(tau) / P.TAU_MAX_NM
        if frac.max() >= sg.torque_fraction:
            jj = int(np.argmax(frac.max(axis=0)))
            return CheckResult(False, f"torque limit on the model (joint {jj + 1} reaches "
                                      f"{frac.max() * 100:.0f} % of {P.TAU_MAX_NM[jj]:g} N m)", J, rows)
        if sg.require_model_decrease and np.isfinite(J_ref) and not A.decreased(J, J_ref, self.s.stop_digits):
            return CheckResult(False, f"J does not decrease on the model ({J:.4e} vs {J_ref:.4e} rad^2)", J, rows)
        self._baseline[joint] = (np.asarray(rho, float).copy(), rows[:, Q_TRUE + j0].copy())
        return CheckResult(True, "ok", J, rows)
