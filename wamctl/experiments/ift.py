"""Iterative feedback tuning of the joint PIDs (thesis chapter 5) and the strategy comparison of section 5.4.

The procedure (thesis section 5.2, per joint, decentralised: each joint's PID is tuned on its own move while the
other joints hold with their current gains):

1. **First experiment, on the plant** (the simulated arm of ``plant:`` with its friction and effects, the CAN arm
   of ``backend:``, or a recorded measured run): the joint moves ``amplitude_rad`` at ``velocity_rad_s`` (LSPB)
   and holds; ``y_tilde = y1 - r`` and ``J = 1/(2N) sum y_tilde^2`` (eq. 2.13) over settle + move + hold.
2. **Second experiment, on the model** (``ift.model``; default the rigid body with the declared friction model
   ``ift.identified_friction`` and ideal sensors): the closed loop driven by ``r - y1``. Two forms:

   * ``incremental`` (default): the model runs the task reference ``r`` and ``r + eps (r - y1)``; the second
     output is ``y2 = (y_model(r + eps (r - y1)) - y_model(r)) / eps``. For a linear loop this *is* the response
     to ``r - y1``; for the arm it is the response of the loop linearised along the task trajectory, which is
     what the sensitivity ``d y / d rho`` is. With Coulomb friction a direct experiment from rest (next item)
     mostly sticks and underestimates the gradient several-fold; the incremental form matches a
     finite-difference gradient of J on the model within a few per cent (tests/experiments/test_ift.py).
   * ``direct``: the thesis' literal form, the model at rest driven by ``q0 + eps (r - y1)``.

   ``y2`` filtered through ``(1/C) dC/drho`` of the discrete libbarrett PID gives ``psi = d y_tilde/d rho``,
   the gradient (eq. 2.15) and the Gauss-Newton Hessian (eq. 2.16): :mod:`wamctl.analysis.ift`.
3. **Update** ``rho+ = rho - gamma R^-1 dJ/drho`` (eq. 2.14) with R from the stage's method (``bfgs``: eq. 2.17,
   started from the Gauss-Newton estimate because ``B0 = I`` is not scale free with gains from 0.05 to 1e4;
   ``gauss_newton``: eq. 2.16), gains kept inside ``ift.bounds`` (projected step: gains held at a bound by the
   descent direction are left out of the solve).
4. **Safeguards, before a proposal touches the plant**: it is simulated on the model and rejected if unstable
   (safety fault of the simulated arm: velocity or position limit, non-finite torque), if the error diverges
   (``|e| > max_error_rad``), if a torque reaches ``torque_fraction`` of the WAM limit, or if J does not decrease
   on the model; a rejected proposal is retried with ``gamma * backtrack_factor`` (``backtracking`` times) and
   listed in the events (``ift_rejected``). The previous gains stay the fallback.
5. **Acceptance on the plant**: the proposal's first experiment gives its J; it is accepted when J decreased at
   ``stop_digits`` significant digits (the thesis compared "using 4 digits"), otherwise the previous gains are
   kept and the schedule moves to its next stage (BFGS gamma 0.5 -> Gauss-Newton 0.5 -> 0.1 in the thesis). A
   joint is done when its stages are used up or after ``max_iterations``.

Which positions J uses (``objective_signal``): ``measured`` (default) uses the encoder positions, as the arm
reports them and as the controller regulates them. The quantisation (one count is 3.7e-5 rad on joint 1 to
1.0e-4 rad on joint 7 through J2MP at 4096 counts/rev) is zero-mean and almost independent of the gains: it adds
a floor of about ``count^2 / 24`` (6e-11 to 4e-10 rad^2) to J, below the tuned J (1e-9 to 1e-7 rad^2 on the
simulated arm), so it does not change which gains are better, and filtering would also smooth away the
high-frequency oscillation that J must penalise. ``filtered`` applies a zero-phase 2nd-order Butterworth
low-pass (``filter_cutoff_hz``) to the measured positions before J and before forming ``r - y1``.

Run directory: ``iter-NNN-exp1.parquet`` (the plant experiments of iteration NNN, every data column plus
``joint``), ``iter-NNN-exp2.parquet`` (per joint: the second experiment's reference and output, ``psi``),
``iter-NNN-check.parquet`` (the model simulations of the proposals), ``iterations.parquet/.csv`` (one row per
joint and iteration: gains, J on the plant and the model, method, gamma, accepted), ``ift_state.json`` (written
after every completed iteration; ``--resume`` continues from it), ``tuned_gains.yaml``, and for the strategy
comparison ``compare-{pd_g,pd_g_ff,pid}.parquet``.
"""

from __future__ import annotations

import json
import logging
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd
import yaml
from pydantic import ValidationError

from wamctl.analysis import ift as A
from wamctl.backends import make_backend
from wamctl.control.controllers import JointController, friction_feedforward_Nm
from wamctl.control.trajectory import Reference, ReferenceBuilder
from wamctl.errors import DataFormatError, SafetyLimitError, SpecError, WamctlError
from wamctl.experiments.common import Plan, declared_dynamics
from wamctl.experiments.engine import LoopRecorder, data_columns, run_loop
from wamctl.model import params as P
from wamctl.model.plant import Plant, resolve_friction
from wamctl.runs.store import RunDir, read_events, utc_now
from wamctl.specs import PayloadEffect, PlantSpec, SensorSpec, format_validation_error, load_model_file
from wamctl.specs.ift import IftSpec, gain_bounds, initial_gains  # noqa: F401

log = logging.getLogger(__name__)

DT_S = 1.0 / P.CONTROL_RATE_HZ
STATE_FILE = "ift_state.json"
STATE_FORMAT = "wamctl-ift-state/1"
STRATEGIES = ("pd_g", "pd_g_ff", "pid")   # the comparison of thesis section 5.4


# ============================================================================================== plan
def task_reference(spec: IftSpec, joint: int, with_return: bool) -> tuple[Reference, int]:
    """The first experiment's reference for ``joint`` (1-based) and the number of samples J covers."""
    t = spec.ift.task

    def build(back: bool) -> Reference:
        b = ReferenceBuilder(spec.q0_rad, DT_S)
        b.hold(t.settle_s, f"settle joint {joint}")
        b.move({joint - 1: t.amplitude_rad}, t.velocity_rad_s, t.tc_s, f"move joint {joint}")
        b.hold(t.hold_s, f"hold joint {joint}")
        if back:
            b.move({joint - 1: -t.amplitude_rad}, t.velocity_rad_s, t.tc_s, f"return joint {joint}")
        return b.build()
    task = build(False)
    return (build(True) if with_return else task), len(task)


def returns_to_start(spec: IftSpec) -> bool:
    r = spec.ift.task.return_to_start
    return (spec.backend.kind != "sim") if r is None else bool(r)


def model_plant_spec(spec: IftSpec, base_dir: Path | None) -> tuple[PlantSpec, Path | None]:
    """The model of the second experiment and of the safeguards, and the folder its friction path is relative to.

    A declared payload (``controller.declared_payload``) is part of the model unless the model has its own."""
    m = spec.ift.model
    model_dir = base_dir
    if m is None:
        ps = PlantSpec(friction=spec.ift.identified_friction, sensors=SensorSpec(encoder_counts_per_rev=0))
    elif isinstance(m, str):
        path = Path(m)
        if not path.is_absolute() and base_dir is not None and not path.exists():
            path = base_dir / path
        try:
            ps = PlantSpec(**load_model_file(path))
        except ValidationError as exc:
            raise SpecError(format_validation_error(exc, f"ift.model {path}")) from None
        model_dir = path.parent
    else:
        ps = m
    dp = spec.controller.declared_payload
    if dp is not None and ps.effects.payload is None:
        fx = ps.effects.model_copy(update={"payload": PayloadEffect(mass_kg=dp.mass_kg, com_m=list(dp.com_m))})
        ps = ps.model_copy(update={"effects": fx})
    return ps, model_dir


def plan(spec: IftSpec, base_dir: Path | None = None) -> Plan:
    s = spec.ift
    ret = returns_to_start(spec)
    refs = [task_reference(spec, j, ret)[0] for j in s.joints]
    q = np.concatenate([r.q_rad for r in refs])   # every joint's experiment once, for the limit checks
    ref = Reference(np.arange(len(q)) * DT_S, q, np.concatenate([r.qd_rad_s for r in refs]),
                    np.concatenate([r.qdd_rad_s2 for r in refs]), [])
    # the model and the measured runs must resolve now (a dry run names a missing file)
    mspec, mdir = model_plant_spec(spec, base_dir)
    Plant(mspec, mdir)
    friction = resolve_friction(s.identified_friction, base_dir)
    ff = None
    if s.comparison.enabled and s.plant.source == "backend":
        inertia = np.diag(declared_dynamics(spec).mass_matrix(np.asarray(spec.q0_rad))) \
            if s.comparison.ff_inertia else None
        ff = friction_feedforward_Nm(ref.qd_rad_s, ref.qdd_rad_s2, friction, inertia)
    if s.plant.source == "measured":
        for r in s.plant.runs:
            p = _resolve(r, base_dir)
            if not p.is_dir():
                raise SpecError(f"ift.plant.runs: {r}: no such directory")
    lo, hi = gain_bounds(spec)
    g0 = initial_gains(spec)
    n_task = task_reference(spec, s.joints[0], False)[1]
    summary = [
        f"IFT of the PIDs of joints {s.joints}: per joint {s.task.amplitude_rad} rad at {s.task.velocity_rad_s} "
        f"rad/s (LSPB, t_c = {s.task.tc_s} s), settle {s.task.settle_s} s, hold {s.task.hold_s} s: "
        f"{n_task} samples = {n_task * DT_S:.1f} s of arm time per experiment",
        "first experiment: " + (f"backend {spec.backend.kind}" + (
            f", plant friction {spec.plant.friction if isinstance(spec.plant.friction, str) else 'inline'}, "
            f"effects: {', '.join(spec.plant.effects.names()) or 'none'}" if spec.backend.kind == "sim" else "")
            if s.plant.source == "backend" else f"{len(s.plant.runs)} measured run(s)"),
        f"second experiment ({s.second_experiment}, eps = {s.perturbation}) on the model: friction "
        f"{mspec.friction if isinstance(mspec.friction, str) else 'inline'}, effects: "
        f"{', '.join(mspec.effects.names()) or 'none'}",
        "schedule: " + ", ".join(f"{st.method} gamma={st.gamma}" + (f" x{st.iterations}" if st.iterations else "")
                                 for st in s.schedule) + f"; at most {s.max_iterations} iterations; J compared at "
        f"{s.stop_digits} digits; objective on {s.objective_signal} positions",
        f"gravity compensation: {spec.controller.gravity_compensation}",
    ]
    for j in s.joints:
        summary.append(f"  joint {j}: initial kp={g0[j - 1, 0]:g} kd={g0[j - 1, 1]:g} ki={g0[j - 1, 2]:g}; bounds "
                       f"kp [{lo[j - 1, 0]:g}, {hi[j - 1, 0]:g}] kd [{lo[j - 1, 1]:g}, {hi[j - 1, 1]:g}] "
                       f"ki [{lo[j - 1, 2]:g}, {hi[j - 1, 2]:g}]")
    if s.comparison.enabled and s.plant.source == "backend":
        summary.append(f"then the comparison (thesis 5.4): PD+g, PD+g+ff ({s.identified_friction}), tuned PID")
    return Plan(ref, summary, ff)


def _resolve(p: str, base_dir: Path | None) -> Path:
    path = Path(p)
    if not path.is_absolute() and base_dir is not None and not path.exists():
        path = base_dir / path
    return path


# ============================================================================================== state
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
class CheckResult:
    ok: bool
    reason: str
    J_model: float
    rows: np.ndarray | None = None


@dataclass
class _Tables:
    """Rows of the per-iteration tables, written when the iteration completes."""

    exp1: list[pd.DataFrame] = field(default_factory=list)
    exp2: list[pd.DataFrame] = field(default_factory=list)
    check: list[pd.DataFrame] = field(default_factory=list)


def _write_parquet(path: Path, df: pd.DataFrame) -> None:
    tmp = path.with_name("." + path.name + ".tmp")
    df.to_parquet(tmp, index=False)
    os.replace(tmp, path)


def _lowpass(y: np.ndarray, cutoff_hz: float) -> np.ndarray:
    from scipy.signal import butter, filtfilt
    b, a = butter(2, cutoff_hz / (P.CONTROL_RATE_HZ / 2))
    return filtfilt(b, a, y) if len(y) > 3 * max(len(a), len(b)) else y


# ============================================================================================== tuner
class IftTuner:
    """Runs the tuning of :class:`IftSpec` into a run directory; resumable from ``ift_state.json``."""

    def __init__(self, spec: IftSpec, run: RunDir, base_dir: Path | None = None, progress=None):
        self.spec = spec
        self.s = spec.ift
        self.run = run
        self.base_dir = base_dir
        self.progress = progress
        mspec, mdir = model_plant_spec(spec, base_dir)
        self.model = Plant(mspec, mdir)
        self.lo, self.hi = gain_bounds(spec)
        self.g0 = initial_gains(spec)
        self.gravity = declared_dynamics(spec).gravity_view if spec.controller.gravity_compensation else None
        self.with_return = returns_to_start(spec)
        self.joints: dict[int, JointState] = {}
        self.iteration = -1                 # last completed iteration
        self.plant_experiments = 0
        self.model_experiments = 0
        self.plant_time_s = 0.0
        self.phase = "tuning"
        self.rows: list[dict] = []          # the iteration table
        self._baseline: dict[int, tuple[np.ndarray, np.ndarray]] = {}   # joint -> (rho, model y at rho)
        self._measured_cache: dict[int, object] = {}

    # ------------------------------------------------------------------ state
    def state_dict(self) -> dict:
        return {"format": STATE_FORMAT, "last_completed_iteration": self.iteration, "phase": self.phase,
                "plant_experiments": self.plant_experiments, "model_experiments": self.model_experiments,
                "plant_time_s": self.plant_time_s, "saved_utc": utc_now(),
                "joints": {str(j): st.to_dict() for j, st in self.joints.items()}}

    def save_state(self) -> None:
        path = self.run.path / STATE_FILE
        tmp = path.with_name("." + STATE_FILE + ".tmp")
        tmp.write_text(json.dumps(self.state_dict(), indent=2))
        os.replace(tmp, path)
        df = iterations_frame(self.rows)
        _write_parquet(self.run.path / "iterations.parquet", df)
        df.to_csv(self.run.path / "iterations.csv", index=False)
        self.run.flush_events()
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
        it = self.run.path / "iterations.parquet"
        if it.is_file():
            df = pd.read_parquet(it)
            df = df[df["iteration"] <= self.iteration]
            self.rows = df.to_dict("records")

    # ------------------------------------------------------------------ hooks
    def _after_iteration(self, k: int) -> None:
        """Called after iteration ``k`` is saved (a seam for tests that interrupt a tuning)."""

    # ------------------------------------------------------------------ experiments
    def gains_matrix(self) -> np.ndarray:
        """(7, 3) the accepted gains of every joint (initial gains for joints not tuned): the tuned PID."""
        g = self.g0.copy()
        for j, st in self.joints.items():
            g[j - 1] = st.rho
        return g

    def _controller(self, gains: np.ndarray, ff: np.ndarray | None = None) -> JointController:
        return JointController(gains[:, 0], gains[:, 1], gains[:, 2], DT_S, gravity=self.gravity,
                               feedforward_Nm=ff)

    def _plant_seed(self, k: int, joint: int, salt: int = 0) -> int:
        return int(np.random.SeedSequence([self.spec.seed, k, joint, salt]).generate_state(1)[0])

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

    def _model_seed(self, joint: int) -> int:
        return self._plant_seed(1_000_000, joint, 7)

    # ------------------------------------------------------------------ first experiment
    def first_experiment(self, k: int, joint: int, rho: np.ndarray, gains: np.ndarray,
                         tables: _Tables) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Returns (r, y1 used for J, full reference (n, 7), rho actually run) of ``joint`` at iteration k."""
        j0 = joint - 1
        g = gains.copy()
        g[j0] = rho
        if self.s.plant.source == "measured":
            r, y, qref, rho_run, df = self._measured_experiment(k, joint, rho)
        else:
            ref, n_task = task_reference(self.spec, joint, self.with_return)
            self.last_plant_rows = None
            try:
                rows, cols, reason = self._run_backend(joint, g, ref, self._plant_seed(k, joint))
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
            r = rows[:n_task, 1 + j0]
            y = rows[:n_task, 8 + j0]
            qref = ref.q_rad[:n_task]
            rho_run = rho
        tables.exp1.append(df)
        if self.s.objective_signal == "filtered":
            y = _lowpass(y, self.s.filter_cutoff_hz)
        return r, y, qref, rho_run

    def _measured_experiment(self, k: int, joint: int, rho: np.ndarray):
        from wamctl.analysis.rotation import find_rotations
        from wamctl.runs.measured import load_run_data
        runs = self.s.plant.runs
        path = _resolve(runs[k], self.base_dir)
        rd = self._measured_cache.get(k)
        if rd is None:
            rd = self._measured_cache[k] = load_run_data(path)
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
    def estimate(self, k: int, joint: int, rho: np.ndarray, gains: np.ndarray, r: np.ndarray, y1: np.ndarray,
                 qref: np.ndarray, tables: _Tables) -> A.IftEstimate:
        """The second experiment on the model and the IFT quantities at ``rho``."""
        j0 = joint - 1
        g = gains.copy()
        g[j0] = rho
        eps = self.s.perturbation
        seed = self._model_seed(joint)
        r2 = eps * (r - y1)                       # the second experiment's reference (about r or q0)
        if self.s.second_experiment == "incremental":
            base = self._baseline.get(joint)
            if base is not None and np.array_equal(base[0], rho) and len(base[1]) == len(r):
                y_base = base[1]
            else:
                rows, reason = self._run_model(g, qref, seed)
                if reason is not None:
                    raise WamctlError(f"joint {joint}: the model is unstable at the accepted gains: {reason}")
                y_base = rows[:, 22 + j0]
            q2 = qref.copy()
            q2[:, j0] = qref[:, j0] + r2
            rows, reason = self._run_model(g, q2, seed)
            if reason is not None:
                raise WamctlError(f"joint {joint}: the second experiment is unstable on the model: {reason}")
            y2 = (rows[:, 22 + j0] - y_base) / eps   # the model's true positions: no quantisation in y2
        else:
            q2 = np.tile(qref[0], (len(r), 1))
            q2[:, j0] = qref[0, j0] + r2
            rows, reason = self._run_model(g, q2, seed)
            if reason is not None:
                raise WamctlError(f"joint {joint}: the second experiment is unstable on the model: {reason}")
            y_base = None
            y2 = (rows[:, 22 + j0] - qref[0, j0]) / eps
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
        g = gains.copy()
        g[j0] = rho
        sg = self.s.safeguards
        rows, reason = self._run_model(g, qref, self._model_seed(joint))
        if reason is not None:
            return CheckResult(False, reason, float("inf"), rows)
        if not np.all(np.isfinite(rows)):
            return CheckResult(False, "unstable on the model (non-finite state)", float("inf"), rows)
        e = rows[:, 1 + j0] - rows[:, 8 + j0]
        tau = rows[:, 15:22]
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
        self._baseline[joint] = (np.asarray(rho, float).copy(), rows[:, 22 + j0].copy())
        return CheckResult(True, "ok", J, rows)

    def propose(self, k: int, st: JointState, gains: np.ndarray, qref: np.ndarray, tables: _Tables) -> None:
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
                    st.bfgs_B = st.gauss_newton.copy()     # B0: the Gauss-Newton estimate (see module doc)
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
                    tables.check.append(pd.DataFrame({
                        "joint": joint, "attempt": attempt, "gamma": gamma, "kp": new[0], "kd": new[1],
                        "ki": new[2], "accepted": res.ok, "t_s": np.arange(len(res.rows)) * DT_S,
                        "q_ref_rad": res.rows[:, 1 + joint - 1], "q_rad": res.rows[:, 8 + joint - 1],
                        "tau_Nm": res.rows[:, 15 + joint - 1]}))
                if res.ok:
                    st.pending = {"rho": new.tolist(), "method": stage.method, "gamma": gamma,
                                  "J_model": res.J_model, "stage": st.stage}
                    return
                self.run.event(self.plant_time_s, "ift_rejected", joint,
                               f"iteration {k}: {stage.method} gamma={gamma:g} kp={new[0]:.6g} kd={new[1]:.6g} "
                               f"ki={new[2]:.6g}: {res.reason}")
                self.rows.append(_row(k, joint, stage.method, gamma, new, float("nan"), res.J_model, "model_rejected",
                                      st.stage, res.reason))
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
        tables = _Tables()
        try:
            # The other joints hold with their initial gains during the tuning, so that each joint's J depends on its
            # own gains only (decentralised tuning; the order of the joints does not matter). The comparison runs
            # every joint with its tuned gains.
            gains = self.g0.copy()
            active = [j for j in self.s.joints if k == 0 or (not self.joints[j].done and self.joints[j].pending)]
            for n, joint in enumerate(active):
                if self.progress:
                    self.progress(n, len(active), f"IFT iteration {k}: joint {joint}")
                if k == 0:
                    rho = self.g0[joint - 1].copy()
                    st = self.joints[joint] = JointState(joint, rho)
                else:
                    st = self.joints[joint]
                    rho = np.asarray(st.pending["rho"], float)
                r, y1, qref, rho = self.first_experiment(k, joint, rho, gains, tables)
                J = A.objective(y1 - r)
                if k == 0:
                    st.rho, st.J, st.iteration = rho, J, 0
                    res = self.check(joint, rho, gains, qref, float("nan"))
                    st.J_model = res.J_model
                    if not res.ok:
                        self.run.event(self.plant_time_s, "ift_warning", joint,
                                       f"the initial gains fail the model check: {res.reason}")
                    self.rows.append(_row(0, joint, "initial", float("nan"), rho, J, st.J_model, "initial", 0, ""))
                    accepted = True
                else:
                    p = st.pending
                    accepted = A.decreased(J, st.J, self.s.stop_digits)
                    self.rows.append(_row(k, joint, p["method"], p["gamma"], rho, J, p["J_model"],
                                          "accepted" if accepted else "plant_rejected", p["stage"],
                                          "" if accepted else f"J {J:.4e} did not decrease below {st.J:.4e}"))
                    st.pending = None
                    if accepted:
                        st.prev_rho, st.prev_gradient = st.rho.copy(), st.gradient.copy()
                        st.rho, st.J, st.J_model, st.iteration = rho, J, p["J_model"], k
                        st.stage_accepted += 1
                    else:
                        self.run.event(self.plant_time_s, "ift_no_decrease", joint,
                                       f"iteration {k}: J = {J:.4e} on the plant, not below {st.J:.4e}: previous gains "
                                       f"kept")
                        self._next_stage(k, st, "J stopped decreasing on the plant")
                if accepted:
                    est = self.estimate(k, joint, st.rho, gains, r, y1, qref, tables)
                    st.gradient, st.gauss_newton = est.gradient, est.gauss_newton
                    if (k > 0 and st.bfgs_B is not None and st.prev_rho is not None
                            and self.s.schedule[min(st.stage, len(self.s.schedule) - 1)].method == "bfgs"):
                        st.bfgs_B, updated = A.bfgs_update(st.bfgs_B, st.rho - st.prev_rho,
                                                           st.gradient - st.prev_gradient)
                        if not updated:
                            self.run.event(self.plant_time_s, "ift_bfgs_skip", joint,
                                           f"iteration {k}: z^T s <= 0, B kept (eq. 2.17)")
                    stage = self.s.schedule[st.stage] if st.stage < len(self.s.schedule) else None
                    if stage is not None and stage.iterations is not None and st.stage_accepted >= stage.iterations:
                        self._next_stage(k, st, f"{stage.method} gamma={stage.gamma:g}: "
                                                f"{stage.iterations} iteration(s)")
                if not st.done and k >= self.s.max_iterations:
                    st.done, st.done_reason = True, f"max_iterations ({self.s.max_iterations})"
                    self.run.event(self.plant_time_s, "ift_done", joint, f"iteration {k}: max_iterations reached")
                if not st.done:
                    # with measured runs, a proposal is made even after the last run: it is what to record next
                    self.propose(k, st, gains, qref, tables)
        finally:  # also an interrupted iteration's experiments reach the tables (resume redoes it)
            self._write_tables(k, tables)

    def _write_tables(self, k: int, tables: _Tables) -> None:
        for name, parts in (("exp1", tables.exp1), ("exp2", tables.exp2), ("check", tables.check)):
            if parts:
                _write_parquet(self.run.path / f"iter-{k:03d}-{name}.parquet", pd.concat(parts, ignore_index=True))

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

    # ------------------------------------------------------------------ comparison (thesis 5.4)
    def comparison(self) -> None:
        """The task on the plant under PD + gravity, PD + gravity + feed-forward friction, and the tuned PID."""
        friction = resolve_friction(self.s.identified_friction, self.base_dir)
        inertia = np.diag(declared_dynamics(self.spec).mass_matrix(np.asarray(self.spec.q0_rad))) \
            if self.s.comparison.ff_inertia else None
        tuned = self.tuned_gains()
        pd_gains = self.g0.copy()
        pd_gains[:, 2] = 0.0
        for strategy in STRATEGIES:
            parts = []
            for n, joint in enumerate(self.s.joints):
                if self.progress:
                    self.progress(n, len(self.s.joints), f"comparison {strategy}: joint {joint}")
                ref, n_task = task_reference(self.spec, joint, self.with_return)
                ff = friction_feedforward_Nm(ref.qd_rad_s, ref.qdd_rad_s2, friction, inertia) \
                    if strategy == "pd_g_ff" else None
                gains = tuned if strategy == "pid" else pd_gains
                rows, cols, reason = self._run_backend(joint, gains, ref, self._plant_seed(10_000, joint,
                                                                                           STRATEGIES.index(strategy)),
                                                       ff)
                df = pd.DataFrame(rows[:n_task], columns=cols)
                df.insert(0, "joint", joint)
                parts.append(df)
                if reason is not None:
                    self.run.event(self.plant_time_s, "comparison_failed", joint, f"{strategy}: {reason}")
            _write_parquet(self.run.path / f"compare-{strategy}.parquet", pd.concat(parts, ignore_index=True))
            self.run.event(self.plant_time_s, "comparison", None, f"{strategy} done")


def _row(k, joint, method, gamma, rho, J, J_model, status, stage, note) -> dict:
    return {"iteration": int(k), "joint": int(joint), "method": method, "gamma": float(gamma),
            "kp": float(rho[0]), "kd": float(rho[1]), "ki": float(rho[2]), "J": float(J), "J_model": float(J_model),
            "status": status, "stage": int(stage), "note": note}


ITERATION_COLUMNS = ["iteration", "joint", "method", "gamma", "kp", "kd", "ki", "J", "J_model", "status", "stage",
                     "note"]


def iterations_frame(rows: list[dict]) -> pd.DataFrame:
    return pd.DataFrame(rows, columns=ITERATION_COLUMNS)


# ============================================================================================== runner API
def execute(spec: IftSpec, plan: Plan, run: RunDir, progress=None, base_dir: Path | None = None) -> None:
    tuner = IftTuner(spec, run, base_dir, progress)
    run.update_manifest(backend={"name": spec.backend.kind if spec.ift.plant.source == "backend" else "measured"},
                        ift={"phase": "tuning"})
    tuner.execute()


def resume(run_path: str | Path, spec: IftSpec, base_dir: Path | None = None, progress=None):
    """Continue an interrupted tuning in ``run_path`` from its last completed iteration.

    ``spec`` must equal the run's ``spec.yaml`` except for ``ift.plant.runs`` (more measured runs may be given).
    Returns a :class:`wamctl.experiments.runner.RunOutcome`; raises RunInterrupted if interrupted again.
    """
    from wamctl.experiments.runner import record_outcome
    from wamctl.runs.store import open_run
    run_path = Path(run_path)
    manifest, stored = open_run(run_path)
    if manifest.get("kind") != "ift":
        raise SpecError(f"{run_path}: --resume needs an ift run directory, not a {manifest.get('kind')!r} run")
    new = spec.model_dump(mode="json")
    diff = _spec_differences(stored, new)
    if diff:
        raise SpecError(f"{run_path}: the spec differs from the run's spec.yaml in {', '.join(diff)}; resume with "
                        f"the same spec (only ift.plant.runs may grow)")
    if new["ift"]["plant"]["runs"] != stored["ift"]["plant"]["runs"]:
        (run_path / "spec.yaml").write_text(yaml.safe_dump(new, sort_keys=False))
    p = plan(spec, base_dir)
    p.check_limits()
    run = RunDir(run_path)
    ev = read_events(run_path)
    run._events = [{"t_s": float(r.t_s), "kind": r.kind, "joint": None if pd.isna(r.joint) else int(r.joint),
                    "detail": "" if pd.isna(r.detail) else str(r.detail)} for r in ev.itertuples()]
    tuner = IftTuner(spec, run, base_dir, progress)
    tuner.load_state()
    run.event(tuner.plant_time_s, "ift_resumed", None,
              f"resumed after iteration {tuner.iteration} (phase {tuner.phase}), previous status "
              f"{manifest.get('status')}")
    run.update_manifest(status="running", reason=None, end_utc=None,
                        resumed=list(manifest.get("resumed") or []) + [utc_now()])
    return record_outcome(run, lambda: tuner.execute(), resume_hint=True)


def _spec_differences(old, new, prefix="") -> list[str]:
    out = []
    if isinstance(old, dict) and isinstance(new, dict):
        for k in sorted(set(old) | set(new)):
            path = f"{prefix}.{k}" if prefix else str(k)
            if path in ("ift.plant.runs", "out_dir"):
                continue
            out += _spec_differences(old.get(k), new.get(k), path)
        return out
    if isinstance(old, list) and isinstance(new, list) and len(old) == len(new):
        for i, (a, b) in enumerate(zip(old, new)):
            out += _spec_differences(a, b, f"{prefix}[{i}]")
        return out
    if isinstance(old, (int, float)) and isinstance(new, (int, float)) and not isinstance(old, bool):
        return [] if np.isclose(float(old), float(new), rtol=1e-12, atol=0) else [prefix]
    return [] if old == new else [prefix]
