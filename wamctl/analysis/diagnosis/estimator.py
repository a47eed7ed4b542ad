"""Model diagnosis: from a measured run to the effect the declared model lacks, with evidence (no I/O).

Method
------
1. **Torque residual.** Positions are differentiated with a centred Savitzky-Golay filter and the logged torque
   is aligned (zero-order hold) and smoothed by the same filter (:mod:`wamctl.analysis.diagnosis.signals`).
   ``y = tau - rnea(q, qd, qdd)`` with the declared rigid body (+ armature, + a declared payload) is what
   friction and any missing effect must supply. Samples where a joint sticks, and the filter's reach around
   them, are left out: there the friction torque is static and unknown.
2. **Declared model.** Per joint, classic friction per direction (Coulomb + viscous) is linear in its four
   parameters; it is fitted by least squares (unless a model file gives it).
3. **Held-out data.** Each joint's sliding samples (in time order) are cut into ``n_blocks`` contiguous
   blocks of equal size, dealt into ``n_folds`` folds (block ``b`` -> fold ``b % n_folds``). Every number
   called held-out comes from a model fitted on the other folds; every shape parameter of a candidate
   (Stribeck velocity, ripple period, delay, drift time constant) is chosen on the training folds only.
4. **Candidates.** One signature per effect name (:mod:`wamctl.analysis.diagnosis.candidates`). Each is
   tested as a nested model against the current model on the held-out residuals: an F-test whose sample
   count is deflated by the residual's integrated autocorrelation time, against the null hypothesis that the
   effect explains at most ``MIN_EFFECT`` (5 %) of the residual variance the declared model left (a
   minimum-effect test, so that very long records do not turn traces into effects), and the BIC change
   (:mod:`wamctl.analysis.diagnosis.stats`). The threshold is ``alpha / (joints x tests)`` (Bonferroni over
   every test of the run), so that a run with nothing missing reports nothing with probability at least
   about ``1 - alpha``. An effect must also be physically plausible: a breakaway between 1 and 10 times the
   Coulomb level; a ripple the same in both directions of motion; one payload for the arm (10 g to 10 kg
   within 0.5 m of the flange, fitted over every joint that shows it); one delay for the arm (longer than
   one sample period, inside the range searched, seen alike at half the joints or more); a dead band of at
   least two encoder steps. Forward selection: the best passing candidate (largest held-out gain) is added,
   the rest are tested again against the augmented model, until none passes; from the second step on, the
   minimum effect is a share of the declared model's residual, so that the imperfections of a strong
   effect's model are not named as further effects. Friction levels are fitted non-negative.
5. **Onsets.** Backlash (and Stribeck, when the joint sticks and slips so that few sliding samples remain)
   shows where a joint starts to move: the link travel the model predicts before the measurement moved, and
   the breakaway level the joint withstood (:mod:`wamctl.analysis.diagnosis.backlash`), tested the same way
   on held-out onsets.
6. **After.** All parameters (friction and the kept effects) are refitted; the held-out torque RMS and the
   residual whiteness (Ljung-Box on one sample per filter window) are reported before and after.

The closed-loop position check and the model file are in :mod:`wamctl.analysis.diagnosis.augmented`.
"""

from __future__ import annotations

import logging
from contextlib import contextmanager
from dataclasses import dataclass, field

import numpy as np

from wamctl.analysis.diagnosis.backlash import (
    MIN_ONSETS,
    MIN_REVERSALS,
    breakaway_ratio,
    find_onsets,
    hidden_travel,
    onset_test,
    resolution_rad,
)
from wamctl.analysis.diagnosis.candidates import (
    D7_M,
    DELAY_GRID_S,
    DRIFT_T_GRID_FRACTION,
    EFFECT_NAMES,
    RIPPLE_PERIOD_MAX_RAD,
    RIPPLE_PERIOD_MIN_RAD,
    STRIBECK_VS_GRID_RAD_S,
    JointData,
    ripple_columns,
    stribeck_columns,
)
from wamctl.analysis.diagnosis.signals import prepare_signals, savgol_gain
from wamctl.analysis.diagnosis.stats import (
    MIN_EFFECT,
    lstsq,
    lstsq_bounded,
    nested_test,
    orth_basis,
    projection_gain,
    whiteness_p,
)
from wamctl.model import params as P
from wamctl.model.dynamics import Payload, WamDynamics
from wamctl.model.friction import FrictionModel, classic_friction_columns

log = logging.getLogger(__name__)

N7 = P.N_JOINTS
DECLARED_MODEL = "wam7 rigid body + armature + classic friction (Coulomb + viscous, per direction)"
TEST_NAME = "nested F-test on held-out folds"
N_COLUMNS = {"stribeck": 2, "position_ripple": 2, "payload": 10, "delay": 0, "friction_drift": 2,
             "backlash": 1}
HAS_GRID = {"stribeck": True, "position_ripple": True, "payload": False, "delay": True,
            "friction_drift": True, "backlash": False}
MAX_SAMPLES_PER_JOINT = 8000      # decimation above this (smoothed signals: little information is lost)
MIN_DECLARED_R2 = 0.25            # below: the data are not this arm under this model (garbage in)
# a wrist payload the WAM can carry (its rated payload is about 4 kg; PayloadEffect allows up to 5 kg), held
# within half a metre of the flange
PAYLOAD_MASS_RANGE_KG = (0.01, 10.0)
PAYLOAD_MAX_COM_M = 0.5
MAX_BREAKAWAY_RATIO = 10.0        # Stribeck breakaway / Coulomb (the plant's own bound, specs.StribeckEffect)


@dataclass
class DeclaredModel:
    """What the user declares: friction (None = fit it), a payload known to the model, effects from a model
    file (a PlantSpec ``effects`` mapping) and the file's sensors, if any."""

    friction: FrictionModel | None = None
    payload: Payload | None = None
    effects: dict = field(default_factory=dict)
    sensors: dict | None = None
    source: str | None = None

    @property
    def fitted(self) -> bool:
        return self.friction is None


@dataclass
class JointResult:
    """Diagnosis of one joint (0-based ``j``)."""

    j: int
    kept: list[dict] = field(default_factory=list)           # name, h_fold, h_all, coef, evidence, gain
    candidates: dict = field(default_factory=dict)           # name -> test dict + kept + reason
    theta_before: np.ndarray | None = None                   # classic friction fitted on all data
    theta_after: np.ndarray | None = None                    # all coefficients of the final model
    columns_after: list[tuple[str, int]] = field(default_factory=list)   # (term name, n columns)
    e_before: np.ndarray | None = None                        # held-out residuals (JointData order)
    e_base: np.ndarray | None = None                          # held-out residual of the fitted declared model
    stall_before: np.ndarray | None = None                    # torque residual at stalls (set-valued friction)
    stall_after: np.ndarray | None = None
    stall_t: np.ndarray | None = None                         # their times, s
    e_after: np.ndarray | None = None
    torque_rms_before_Nm: float = float("nan")
    torque_rms_after_Nm: float = float("nan")
    whiteness_p_before: float = float("nan")
    whiteness_p_after: float = float("nan")
    position_rms_before_rad: float = float("nan")
    position_rms_after_rad: float = float("nan")
    effects: list[dict] = field(default_factory=list)         # report-ready: name, params, evidence


@contextmanager
def _single_threaded_blas():
    """The diagnosis multiplies tall, thin matrices: one BLAS thread is fastest, and several threads on a
    shared machine are ten times slower (OpenBLAS spin-waits). threadpoolctl is optional."""
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:
        yield
        return
    with threadpool_limits(limits=1, user_api="blas"):
        yield


class ModelDiagnosis:
    """Find what the declared model of the WAM lacks in a measured run.

    Parameters
    ----------
    alpha : family-wise false-alarm level of the whole run (Bonferroni over joints x candidates).
    n_blocks, n_folds : contiguous time blocks and the folds they are dealt into.
    candidates : effect names to test (default: all of the vocabulary).
    declared : the declared model (default: classic friction fitted from the data).
    max_steps : effects kept per joint at most.
    window_s, gauss_s : Savitzky-Golay window and Gaussian pre-filter sigma of the differentiation filter.
    simulator : ``simulate_positions(plant, meta, t_s, q_ref, q0, feedforward, payload) -> (n, 7)``, the closed
        loop of a model on a simulated arm (:func:`wamctl.experiments.diagnose.simulate_positions`); given, the
        closed-loop position check runs (:mod:`wamctl.analysis.diagnosis.augmented`), None skips it.
    max_sim_samples : samples simulated per model in that check.

    Attributes (after ``fit``)
    --------------------------
    signals_ : :class:`Signals`.
    joints_ : {0-based joint: :class:`JointResult`}.
    effects_found_ : effect names kept anywhere, strongest first.
    conclusive_ : False when nothing could be concluded (reason in ``reason_``).
    threshold_ : per-test p-value threshold.
    """

    def __init__(self, *, alpha: float = 0.01, n_blocks: int = 10, n_folds: int = 5,
                 candidates: tuple[str, ...] = EFFECT_NAMES, declared: DeclaredModel | None = None,
                 max_steps: int = 3, window_s: float | None = None, gauss_s: float | None = None,
                 simulator=None, max_sim_samples: int | None = None):
        self.alpha = alpha
        self.n_blocks = n_blocks
        self.n_folds = n_folds
        self.candidates = candidates
        self.declared = declared
        self.max_steps = max_steps
        self.window_s = window_s
        self.gauss_s = gauss_s
        self.simulator = simulator
        self.max_sim_samples = max_sim_samples

    # ------------------------------------------------------------------------------------------ fit
    def fit(self, data) -> ModelDiagnosis:
        """Diagnose a :class:`wamctl.runs.measured.RunData` (a run directory or a measured run, loaded)."""
        with _single_threaded_blas():
            return self._fit(data)

    def _fit(self, data) -> ModelDiagnosis:
        declared = self.declared or DeclaredModel()
        meta = data.meta
        self.declared_ = declared
        self.meta_ = meta
        self.conclusive_ = False
        self.reason_ = None
        self.joints_ = {}
        self.effects_found_ = []
        unknown = [c for c in self.candidates if c not in EFFECT_NAMES]
        if unknown:
            raise ValueError(f"unknown candidate effects {unknown}; known: {EFFECT_NAMES}")
        payload = declared.payload
        if payload is None and meta.payload is not None and meta.payload.mass_kg > 0:
            payload = Payload(meta.payload.mass_kg, tuple(meta.payload.com_m))
        self.payload_declared_ = payload
        self.dynamics_ = WamDynamics(payload)
        kw = {} if self.window_s is None else {"window_s": self.window_s}
        if self.gauss_s is not None:
            kw["gauss_s"] = self.gauss_s
        sig = prepare_signals(data.t_s, data.col("q"), data.col("q_ref"), data.col("tau"),
                              float(meta.sample_rate_hz), [j - 1 for j in meta.experiment.joints], **kw)
        self.signals_ = sig
        if not sig.joints:
            why = "; ".join(f"joint {j + 1}: {r}" for j, r in sig.skipped.items())
            self.reason_ = ("no joint moved enough to compare the model with the data"
                            + (f" ({why})" if why else ""))
            log.warning(self.reason_)
            return self
        self.declared_effects_ = set(declared.effects or {})
        self._prepare_joint_data()
        tests = [c for c in self.candidates if c not in self.declared_effects_]
        # every test of the run: one per joint and candidate, and Stribeck twice (sliding data, breakaways)
        n_tests = len(tests) + (1 if "stribeck" in tests else 0)
        self.threshold_ = self.alpha / max(1, len(sig.joints) * max(1, n_tests))
        torque_tests = [c for c in tests if c != "backlash"]
        self._onset_tests_on = True
        for j in sig.joints:
            self.joints_[j] = self._diagnose_joint(self.jd_[j], torque_tests)
        r2 = self._declared_r2()
        if r2 < MIN_DECLARED_R2:
            self.reason_ = (f"the declared model explains only {max(r2, 0.0):.0%} of the torque of the moving "
                            f"joints (at least {MIN_DECLARED_R2:.0%} expected): the data do not look like this "
                            "arm under this model (torque units? joint order? gravity?), so no effect is named")
            log.warning(self.reason_)
            self.joints_ = {}
            return self
        self._check_delay(torque_tests)
        self._check_payload()
        self.onsets_ = {}
        if "backlash" in tests or "stribeck" in tests:
            for j in sig.joints:
                self._onset_tests(j, tests)
        strength = {}
        for res in self.joints_.values():
            for k in res.kept:
                strength[k["name"]] = max(strength.get(k["name"], 0.0), k["gain"])
        self.effects_found_ = sorted(strength, key=lambda n: -strength[n])
        self._finalise_effects()
        self.conclusive_ = True
        self.positions_ = None
        if self.simulator is not None:
            from wamctl.analysis.diagnosis.augmented import MAX_SIM_SAMPLES, position_check
            pc = position_check(self, data, self.simulator, self.max_sim_samples or MAX_SIM_SAMPLES)
            self.positions_ = pc
            for j, res in self.joints_.items():
                res.position_rms_before_rad = pc["rms_before"].get(j, float("nan"))
                res.position_rms_after_rad = pc["rms_after"].get(j, float("nan"))
        return self

    def _declared_r2(self) -> float:
        """Share of the moving joints' torque variance the fitted declared model explains (held-out)."""
        ss_res, ss_tot = 0.0, 0.0
        for j, res in self.joints_.items():
            tau = self.tau_model_[self.jd_[j].idx, j]
            ss_res += _ss(res.e_base)
            ss_tot += float(np.sum((tau - tau.mean()) ** 2))
        return 1.0 - ss_res / ss_tot if ss_tot > 0 else 0.0

    # ------------------------------------------------------------------------------------------ data
    def _prepare_joint_data(self) -> None:
        sig = self.signals_
        dec = 1
        n_mov = max(int(sig.moving[:, j].sum()) for j in sig.joints)
        if n_mov > MAX_SAMPLES_PER_JOINT:
            dec = int(np.ceil(n_mov / MAX_SAMPLES_PER_JOINT))
        self.decimation_ = dec
        keep = np.zeros(sig.n, bool)
        keep[::dec] = True
        union = np.flatnonzero(keep & sig.moving[:, sig.joints].any(axis=1))
        dyn = self.dynamics_
        q, qd, qdd = sig.q_rad, sig.qd_rad_s, sig.qdd_rad_s2
        rnea = np.empty((len(union), N7))
        want_payload = "payload" in self.candidates and "payload" not in self.declared_effects_
        reg = np.empty((len(union), N7, 10)) if want_payload else None
        for k, i in enumerate(union):
            rnea[k] = dyn.inverse_dynamics(q[i], qd[i], qdd[i])
            if want_payload:
                reg[k] = dyn.regressor_basis(q[i], qd[i], qdd[i])[:, 60:70]
        # the rigid-body torque on a uniform grid (the delay feature shifts it in time)
        stride = max(1, sig.n // 60000)
        grid = np.arange(0, sig.n, stride)
        if grid[-1] != sig.n - 1:
            grid = np.append(grid, sig.n - 1)
        rg = np.array([dyn.inverse_dynamics(q[i], qd[i], qdd[i]) for i in grid])
        self.rnea_full_ = np.column_stack([np.interp(np.arange(sig.n), grid, rg[:, j]) for j in range(N7)])
        # gravity stiffness dg_j/dq_j (backlash: the link sits w/2 away from the encoder), on a coarse grid
        coarse = union[:: max(1, len(union) // 3000)]
        dgdq_c = np.zeros((len(coarse), N7))
        eps = 1e-4
        for k, i in enumerate(coarse):
            g0 = dyn.gravity(q[i])
            for j in sig.joints:
                dq = np.zeros(N7)
                dq[j] = eps
                dgdq_c[k, j] = (dyn.gravity(q[i] + dq)[j] - g0[j]) / eps
        pos = np.searchsorted(union, np.arange(sig.n))
        self.union_ = union
        tau_full = sig.tau_Nm
        # (n, 7) torque the declared model file adds, and the part of it that is not friction (at rest, the
        # friction is what the stall analysis estimates)
        self.known_, self.known_other_ = self._declared_torque()
        delay_given = float((self.declared_.effects.get("delay") or {}).get("delay_s", 0.0))
        if delay_given > 0:
            tau_full = np.column_stack([np.interp(sig.t_s - delay_given, sig.t_s, tau_full[:, j])
                                        for j in range(N7)])
        self.tau_model_ = tau_full
        self.jd_ = {}
        t0 = sig.t_s[0]
        for j in sig.joints:
            idx = np.flatnonzero(keep & sig.moving[:, j])
            u = pos[idx]
            # the joint's own sliding samples, in time order, cut into contiguous blocks of equal size: a joint
            # that moves in one part of the run only (one joint at a time) still has every fold populated
            block = np.minimum((np.arange(len(idx)) * self.n_blocks) // max(len(idx), 1), self.n_blocks - 1)
            jfold = block % self.n_folds
            y = tau_full[idx, j] - rnea[u, j] - self.known_[idx, j]
            extra = {"t_rel": sig.t_s[idx] - t0, "block": block,
                     "dgdq_full": np.interp(sig.t_s, sig.t_s[coarse], dgdq_c[:, j])}
            if want_payload:
                extra["payload"] = reg[u, j, :]
            self.jd_[j] = JointData(j, idx, sig.t_s[idx], q[idx, j], qd[idx, j], qdd[idx, j], y, jfold, extra)

    def _declared_torque(self) -> tuple[np.ndarray, np.ndarray]:
        """(n, 7) torque of the declared model beyond the rigid body when a model file gives it (friction,
        ripple; zero when friction is fitted from the data), and its part that is not friction."""
        sig = self.signals_
        out = np.zeros((sig.n, N7))
        other = np.zeros((sig.n, N7))
        d = self.declared_
        if d.friction is None:
            return out, other
        fr = d.friction
        fx = d.effects or {}
        if fx.get("stribeck"):
            s = fx["stribeck"]
            m = np.zeros(N7, bool)
            m[[j - 1 for j in s["joints"]]] = True
            r = float(s.get("breakaway_ratio", 1.6))
            fr = fr.with_stribeck(np.where(m, fr.fc_pos_Nm * r, np.nan), np.where(m, fr.fc_neg_Nm * r, np.nan),
                                  np.where(m, float(s.get("vs_rad_s", 0.05)), np.nan), float(s.get("delta", 2.0)))
        f = fr.friction_torque(sig.qd_rad_s)
        if fx.get("friction_drift"):
            s = fx["friction_drift"]
            scale = 1 + float(s.get("fraction", -0.4)) * (
                1 - np.exp(-(sig.t_s - sig.t_s[0]) / float(s.get("time_constant_s", 20.0))))
            for jj in s["joints"]:
                f[:, jj - 1] *= scale
        out += f
        if fx.get("position_ripple"):
            s = fx["position_ripple"]
            per = float(s.get("period_rad", 0.2))
            for jj in s["joints"]:
                j = jj - 1
                gain = savgol_gain(sig.window, np.abs(sig.qd_rad_s[:, j]) * sig.dt_s / per, sig.gauss)
                rip = float(s.get("amplitude_Nm", 0.5)) * np.sin(2 * np.pi * sig.q_rad[:, j] / per
                                                                 + float(s.get("phase_rad", 0.0)))
                out[:, j] -= gain * rip
                other[:, j] -= rip
        return out, other

    # ------------------------------------------------------------------------------------------ columns
    def _grid(self, name: str, jd: JointData) -> list:
        if name == "stribeck":
            return list(STRIBECK_VS_GRID_RAD_S)
        if name == "delay":
            return list(DELAY_GRID_S)
        if name == "friction_drift":
            return list(DRIFT_T_GRID_FRACTION * max(self.signals_.duration_s, 1e-3))
        if name == "position_ripple":
            return []  # searched, see _select_ripple
        return [None]

    def _cols(self, name: str, jd: JointData, h, d: float = 0.0) -> np.ndarray:
        """Columns (m, p) of term ``name`` with shape parameter ``h`` at the joint's samples, with the state
        taken ``d`` seconds later (a delay term).

        Features that are nonlinear functions of the state are built at the full rate and smoothed by the
        same filter as the torque, so that feature and torque are averaged alike over each window."""
        cache = jd.extra.setdefault("_cache", {})
        key = (name, h if (h is None or isinstance(h, tuple)) else round(float(h), 12), round(float(d), 9))
        if key in cache:
            return cache[key]
        sig = self.signals_
        j = jd.j
        qd_f = sig.qd_rad_s[:, j]

        def sample(raw):
            """The smoothed feature at the joint's samples (shifted by d: from the smoothed full-rate one)."""
            if not d:
                return sig.smooth_at(raw, jd.idx)
            full = self._smooth(raw)
            return np.column_stack([np.interp(jd.t_s + d, sig.t_s, c) for c in full.T])

        if name == "friction":
            if d:
                full = jd.extra.get("fric_smooth")
                if full is None:
                    full = jd.extra["fric_smooth"] = self._smooth(classic_friction_columns(qd_f))
                X = np.column_stack([np.interp(jd.t_s + d, sig.t_s, c) for c in full.T])
            else:
                X = sample(classic_friction_columns(qd_f))
        elif name == "stribeck":
            X = sample(stribeck_columns(qd_f, h))
        elif name == "position_ripple":
            ph = 2 * np.pi * sig.q_rad[:, j] / h
            X = sample(np.column_stack([np.sin(ph), np.cos(ph)]))
        elif name == "payload":
            X = jd.extra["payload"]
            if isinstance(h, tuple):       # ("global", fold): the one payload of the arm, fitted without fold
                pi = self.payload_pi_[h[1]]
                X = (X @ pi)[:, None]
        elif name == "friction_drift":
            # the Coulomb and the viscous torque of the declared fit, each drifting as exp(-t / T): two
            # columns that keep the directions together (a direction seen only early in the run would
            # otherwise be extrapolated in time)
            F = self._cols("friction", jd, None, d)
            tb = self._abs_before(jd)
            X = np.column_stack([F[:, :2] @ tb[:2], F[:, 2:] @ tb[2:]]) * np.exp(-jd.extra["t_rel"] / h)[:, None]
        elif name == "backlash":
            X = sample((jd.extra["dgdq_full"] * np.sign(qd_f))[:, None])
        else:
            raise ValueError(name)
        if len(cache) > 400:
            cache.clear()
        cache[key] = X
        return X

    def _smooth(self, X: np.ndarray) -> np.ndarray:
        return self.signals_.smooth(X)

    def _shifted_target(self, jd: JointData, d: float) -> np.ndarray:
        """Target with the positions taken ``d`` later: ``y_d = tau - rnea(q(t + d))`` (a measurement ``d``
        late means ``tau(t) = model(q(t + d))``)."""
        cache = jd.extra.setdefault("_shift", {})
        key = round(float(d), 9)
        if key not in cache:
            sig = self.signals_
            model = self.rnea_full_[:, jd.j] + self.known_[:, jd.j]
            if len(cache) > 100:
                cache.clear()
            cache[key] = self.tau_model_[jd.idx, jd.j] - np.interp(jd.t_s + d, sig.t_s, model)
        return cache[key]

    def _yx(self, jd: JointData, terms: list[dict], fold: int | None) -> tuple[np.ndarray, np.ndarray]:
        """Target and design of ``friction + terms`` (a delay term shifts target and friction instead of adding
        columns); shape parameters of fold ``fold`` (None: chosen on all data)."""
        def h_of(t):
            return t["h_all"] if fold is None else t["h_fold"][fold]
        d = next((h_of(t) for t in terms if t["name"] == "delay"), None)
        if d:
            y = self._shifted_target(jd, d)
        else:
            y, d = jd.y_Nm, 0.0
        cols = [self._cols("friction", jd, None, d)]
        cols += [self._cols(t["name"], jd, h_of(t), d) for t in terms if t["name"] != "delay"]
        return y, np.hstack(cols)

    def _design(self, jd: JointData, terms: list[dict], fold: int | None) -> np.ndarray:
        return self._yx(jd, terms, fold)[1]

    def _select(self, name: str, jd: JointData, rows: np.ndarray, Xb: np.ndarray, y: np.ndarray, terms=()):
        """Shape parameter of candidate ``name`` that best explains the current residual on ``rows``
        (``terms``: the other terms, with ``h_all`` set; used by the delay, whose grid changes everything)."""
        if name == "delay":
            # coarse grid (every fourth value), then the neighbours of the best
            def ssr(d):
                yd, X = self._yx(jd, list(terms) + [{"name": "delay", "h_all": d}], None)
                th = lstsq(X[rows], yd[rows])
                r = yd[rows] - X[rows] @ th
                return float(r @ r)
            grid = DELAY_GRID_S
            coarse = list(range(0, len(grid), 4)) + [len(grid) - 1]
            scores = {i: ssr(grid[i]) for i in coarse}
            i0 = min(scores, key=scores.get)
            for i in range(max(0, i0 - 3), min(len(grid), i0 + 4)):
                if i not in scores:
                    scores[i] = ssr(grid[i])
            i0 = min(scores, key=scores.get)
            if 0 < i0 < len(grid) - 1:      # a parabola through the best three: a delay between grid points
                s0, s1, s2 = scores[i0 - 1], scores[i0], scores[i0 + 1]
                den = s0 - 2 * s1 + s2
                if den > 0:
                    step = grid[1] - grid[0]
                    d = float(grid[i0] + 0.5 * step * (s0 - s2) / den)
                    if ssr(d) < s1:
                        return d
            return float(grid[i0])
        if name == "position_ripple":
            return self._select_ripple(jd, rows, Xb, y)
        grid = self._grid(name, jd)
        if len(grid) == 1:
            return grid[0]
        d = next((t["h_all"] for t in terms if t["name"] == "delay"), 0.0) or 0.0
        U = orth_basis(Xb[rows])
        r = y[rows] - U @ (U.T @ y[rows])
        gains = [projection_gain(U, r, self._cols(name, jd, h, d)[rows]) for h in grid]
        return grid[int(np.argmax(gains))]

    def _select_ripple(self, jd: JointData, rows: np.ndarray, Xb: np.ndarray, y_all: np.ndarray) -> float:
        """Period of the strongest position-periodic component of the base residual on ``rows``.

        The residual is binned over the joint angle (bins of a tenth of the shortest period) and its
        periodogram over the angle taken by FFT (zero-padded 4x); the highest peaks are then compared by
        their exact least-squares gain (filter-attenuated sin/cos, see ``ripple_columns``)."""
        sig = self.signals_
        U = orth_basis(Xb[rows])
        y = y_all[rows]
        r = y - U @ (U.T @ y)
        q = jd.q_rad[rows]
        dq = RIPPLE_PERIOD_MIN_RAD / 10
        q0 = float(q.min())
        nb = int(np.ptp(q) / dq) + 2
        rb = np.bincount(((q - q0) / dq).astype(int), weights=r, minlength=nb)
        L = 1 << int(np.ceil(np.log2(4 * nb)))
        L = min(L, 1 << 22)
        power = np.abs(np.fft.rfft(rb, L)) ** 2
        k = np.arange(len(power)) / (L * dq)                      # cycles per rad
        band = (k >= 1 / RIPPLE_PERIOD_MAX_RAD) & (k <= 1 / RIPPLE_PERIOD_MIN_RAD)
        if not band.any():
            return RIPPLE_PERIOD_MAX_RAD
        pb = np.where(band, power, -1.0)
        peak = (pb[1:-1] >= pb[:-2]) & (pb[1:-1] >= pb[2:]) & band[1:-1]
        cand = np.flatnonzero(peak) + 1
        if len(cand) == 0:
            cand = np.array([int(np.argmax(pb))])
        cand = cand[np.argsort(pb[cand])[-8:]]
        step = 1.0 / (L * dq)
        ks = np.unique(np.concatenate([k[c] + step * np.linspace(-0.5, 0.5, 5) for c in cand]))
        ks = ks[(ks >= 1 / RIPPLE_PERIOD_MAX_RAD) & (ks <= 1 / RIPPLE_PERIOD_MIN_RAD)]
        sub = rows[:: max(1, len(rows) // 6000)]
        Us = orth_basis(Xb[sub])
        ys = y_all[sub]
        rs = ys - Us @ (Us.T @ ys)
        gains = [projection_gain(Us, rs, ripple_columns(jd.q_rad[sub], jd.qd_rad_s[sub], 1 / kk, sig.window,
                                                         sig.gauss, sig.dt_s)) for kk in ks]
        return float(1.0 / ks[int(np.argmax(gains))])

    # ------------------------------------------------------------------------------------------ CV
    def _cv(self, jd: JointData, terms: list[dict], cand: str | None = None, fixed_h=None):
        """Held-out residuals of ``friction + terms (+ cand)``; returns (residual, per-fold shape params).
        ``fixed_h`` fixes the candidate's shape parameter instead of choosing it on each fold."""
        e = np.zeros(jd.n)
        h_fold = []
        for f in range(self.n_folds):
            te = jd.fold == f
            tr = ~te
            if not te.any():
                h_fold.append(h_fold[-1] if h_fold else self._default_h(cand, jd))
                continue
            trr = np.flatnonzero(tr)
            te_i = np.flatnonzero(te)
            unpredictable = self._unpredictable(jd, trr, te_i)
            y, Xb = self._yx(jd, terms, f)
            if cand is None:
                h_fold.append(None)
                X = Xb
            elif cand == "delay":
                h = self._select("delay", jd, trr, Xb, y, [dict(t, h_all=t["h_fold"][f]) for t in terms])
                h_fold.append(h)
                y, X = self._yx(jd, terms + [{"name": "delay", "h_fold": [h] * self.n_folds}], f)
            else:
                here = [dict(t, h_all=t["h_fold"][f]) for t in terms]
                h = fixed_h if fixed_h is not None else self._select(cand, jd, trr, Xb, y, here)
                h_fold.append(h)
                d = next((t["h_all"] for t in here if t["name"] == "delay"), 0.0) or 0.0
                X = np.hstack([Xb, self._cols(cand, jd, h, d)])
            if len(trr) < X.shape[1] + 5:
                e[te] = y[te] - (np.mean(y[trr]) if len(trr) else 0.0)
                continue
            theta = self._fit_theta(X[trr], y[trr])
            e[te] = y[te] - X[te] @ theta
            e[unpredictable] = np.nan
        return e, h_fold

    def _fit_theta(self, X: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Least squares of a joint model whose first four columns are the classic friction: Coulomb levels and
        viscous coefficients are magnitudes, so they are kept >= 0 when fitted from the data (a direction seen
        at one speed only cannot tell Coulomb from viscous, and an unbounded fit trades one against the other
        to absurd values)."""
        if not self.declared_.fitted:
            return lstsq(X, y)
        lower = np.full(X.shape[1], -np.inf)
        lower[:4] = 0.0
        return lstsq_bounded(X, y, lower)

    def _cv_terms(self, jd: JointData, terms: list[dict]) -> np.ndarray:
        """Held-out residual of ``friction + terms`` with the terms' per-fold shape parameters."""
        e = np.zeros(jd.n)
        for f in range(self.n_folds):
            te = jd.fold == f
            if not te.any():
                continue
            trr, te_i = np.flatnonzero(~te), np.flatnonzero(te)
            y, X = self._yx(jd, terms, f)
            if len(trr) < X.shape[1] + 5:
                e[te] = np.nan
                continue
            e[te] = y[te] - X[te] @ self._fit_theta(X[trr], y[trr])
            e[self._unpredictable(jd, trr, te_i)] = np.nan
        return e

    @staticmethod
    def _unpredictable(jd: JointData, trr: np.ndarray, te_i: np.ndarray) -> np.ndarray:
        """Held-out samples no model of the joint fitted on ``trr`` can predict: in a direction the training
        folds never moved in, or at a speed outside the training speeds of that direction (by more than
        25 %). They test extrapolation of the friction law, not an effect, and are left out of every held-out
        figure (NaN)."""
        qd = jd.qd_rad_s
        bad = np.zeros(len(te_i), bool)
        for sgn in (1.0, -1.0):
            tr_v = np.abs(qd[trr][np.sign(qd[trr]) == sgn])
            te_m = np.sign(qd[te_i]) == sgn
            if len(tr_v) < 20:
                bad |= te_m
                continue
            v = np.abs(qd[te_i])
            bad |= te_m & ((v > 1.25 * tr_v.max()) | (v < tr_v.min() / 1.25))
        return te_i[bad]

    def _default_h(self, name, jd):
        if name is None:
            return None
        g = self._grid(name, jd)
        return g[len(g) // 2] if g else 0.2

    def _fit_all(self, jd: JointData, terms: list[dict]) -> tuple[list[dict], np.ndarray]:
        """Refit on all data: shape parameters chosen one term at a time with the others fixed."""
        terms = [dict(t) for t in terms]
        for t in terms:
            t.setdefault("h_all", self._first_h(t))
        rows = np.arange(jd.n)
        for i, t in enumerate(terms):
            if t.get("fixed_h") is not None:
                t["h_all"] = t["fixed_h"]
                continue
            others = terms[:i] + terms[i + 1:]
            y, Xb = self._yx(jd, others, None)
            t["h_all"] = self._select(t["name"], jd, rows, Xb, y, others)
        y, X = self._yx(jd, terms, None)
        return terms, self._fit_theta(X, y)

    @staticmethod
    def _first_h(t: dict):
        hs = [h for h in t["h_fold"] if h is not None]
        if not hs:
            return None
        if isinstance(hs[0], (tuple, str)):
            return hs[0]
        return float(np.median(hs))

    # ------------------------------------------------------------------------------------------ joint
    def _diagnose_joint(self, jd: JointData, tests: list[str], rejected: dict | None = None) -> JointResult:
        """Forward selection of the torque-domain candidates at one joint.

        ``rejected`` maps candidates excluded beforehand to the reason (e.g. a payload whose mass fitted over
        all joints is not positive)."""
        rejected = dict(rejected or {})
        res = JointResult(jd.j)
        e_base, _ = self._cv(jd, [])
        if self.declared_.fitted:
            e_before = e_base
        else:
            e_before = jd.y_Nm.copy()    # the given model, not refitted
        res.e_before = e_before
        res.e_base = e_base
        res.theta_before = self._fit_theta(self._cols("friction", jd, None), jd.y_Nm)
        jd.extra["theta_before"] = res.theta_before
        terms: list[dict] = []
        current = e_base
        remaining = [c for c in tests if c not in rejected]
        last = {}
        # Stribeck seen at the breakaways under the declared model: when a joint sticks and slips, few sliding
        # samples remain and a time-varying friction could explain them; the breakaways decide first
        pre = self._stribeck_at_breakaways(jd.j) if "stribeck" in remaining and self._onset_tests_on else None
        for step in range(self.max_steps):
            trial = {}
            for c in remaining:
                if c == "payload" and "payload" not in jd.extra:
                    continue
                e1, h_fold = self._cv(jd, terms, c)
                k1 = 4 + sum(_ncols(t) for t in terms) + N_COLUMNS[c]
                p_extra = N_COLUMNS[c] + (1 if HAS_GRID[c] else 0)
                # the minimum effect is a share of what the declared model left, not of what is left now:
                # after a strong effect, the traces of its imperfect model are not new effects
                share = _ss(e_base) / max(_ss(current), 1e-300)
                t = nested_test(current, e1, p_extra, k1, min(MIN_EFFECT * share, 0.9), jd.fold)
                trial[c] = (t, h_fold, e1)
                last[c] = dict(t, step=step)
            passing = sorted((c for c, (t, _, _) in trial.items()
                              if t["p_value"] < self.threshold_ and t["delta_bic"] < 0),
                             key=lambda c: trial[c][0]["ssr_ratio"])
            if step == 0 and pre is not None and "stribeck" in remaining and \
                    (not passing or passing[0] == "stribeck"
                     or pre[0]["p_value"] < min(trial[c][0]["p_value"] for c in passing)):
                # seen at the breakaways too: their levels and the slips after them pin Fs and vs better than
                # the few low-speed sliding samples a joint that sticks and slips leaves
                r, ons = pre
                vs = self._slip_vs(jd.j, ons, float(np.exp(r["coef"]))) or float(np.median(STRIBECK_VS_GRID_RAD_S))
                e1, h_fold = self._cv(jd, terms, "stribeck", vs)
                ev = {k: r[k] for k in ("p_value", "delta_bic", "F", "n", "n_eff", "ssr_ratio")}
                terms.append({"name": "stribeck", "h_fold": h_fold, "fixed_h": vs, "evidence": ev,
                              "gain": 1.0 - r["ssr_ratio"], "onset_ratio": float(np.exp(r["coef"])),
                              "onset_vs": vs, "onset_test": True})
                last["stribeck"] = dict(ev, step=step, reason="kept (seen at the breakaways)")
                current = e1 if _ss(e1) < _ss(current) else current
                remaining.remove("stribeck")
                continue
            chosen = None
            for c in passing:
                t, h_fold, e1 = trial[c]
                fitted, theta = self._fit_all(jd, terms + [{"name": c, "h_fold": h_fold}])
                ok, why = self._plausible(c, jd, fitted, theta)
                if ok:
                    chosen = (c, t, h_fold, e1)
                    break
                last[c]["reason"] = why
                remaining.remove(c)
            if chosen is None:
                break
            c, t, h_fold, e1 = chosen
            base_ssr = _ss(e_base)
            gain = (_ss(current) - _ss(e1)) / base_ssr if base_ssr > 0 else 0.0
            terms.append({"name": c, "h_fold": h_fold, "evidence": t, "gain": gain})
            current = e1
            remaining.remove(c)
        self._set_after(res, jd, terms, current)
        kept_names = {t["name"] for t in res.kept}
        for c in tests:
            if c in rejected:
                res.candidates[c] = dict(last.get(c, {"p_value": float("nan"), "delta_bic": float("nan")}),
                                         kept=False, reason=rejected[c])
                continue
            if c not in last:
                res.candidates[c] = {"p_value": float("nan"), "delta_bic": float("nan"), "kept": False,
                                     "reason": "not testable on this joint"}
                continue
            t = last[c]
            if c in kept_names:
                ev = next(k["evidence"] for k in res.kept if k["name"] == c)
                res.candidates[c] = dict(ev, kept=True, reason="kept")
                continue
            res.candidates[c] = dict(t, kept=False, reason=t.get("reason") or self._why_rejected(t))
        return res

    @staticmethod
    def _set_rms(res: JointResult) -> None:
        """Held-out torque RMS over the sliding samples and (once the onsets are analysed) the stalls."""
        for which in ("before", "after"):
            e = getattr(res, f"e_{which}")
            e = e[np.isfinite(e)]
            st = getattr(res, f"stall_{which}")
            both = np.concatenate([e, st]) if st is not None else e
            setattr(res, f"torque_rms_{which}_Nm", float(np.sqrt(np.mean(both ** 2))) if len(both) else float("nan"))

    def _why_rejected(self, t: dict) -> str:
        if t["ssr_ratio"] >= 1:
            return "does not predict held-out data better than the model without it"
        if t["p_value"] >= self.threshold_:
            return f"p = {t['p_value']:.3g} not below the threshold {self.threshold_:.3g}"
        return f"BIC does not drop (delta {t['delta_bic']:.1f})"

    def _set_after(self, res: JointResult, jd: JointData, terms: list[dict], e_after: np.ndarray) -> None:
        """Refit the final model of a joint on all data and record the held-out figures."""
        spacing = max(1, 2 * self.signals_.reach // self.decimation_)
        fitted, theta = self._fit_all(jd, terms)
        res.kept = fitted
        res.theta_after = theta
        res.columns_after = [("friction", 4)] + [(t["name"], _ncols(t)) for t in fitted]
        res.e_after = e_after
        self._set_rms(res)
        res.whiteness_p_before = whiteness_p(res.e_before, spacing)
        res.whiteness_p_after = whiteness_p(e_after, spacing)

    # ------------------------------------------------------------------------------------------ global
    def _payload_fit(self, rows_of=None) -> dict | None:
        """One payload for the whole arm, fitted over every joint that kept it (shared mass and first moment,
        each joint's other terms free, joints weighted by their residual); ``rows_of`` restricts the samples."""
        with_p = [j for j, r in self.joints_.items() if any(t["name"] == "payload" for t in r.kept)]
        if not with_p:
            return None
        blocks, ys, shared, wts = [], [], [], []
        for j in with_p:
            res, jd = self.joints_[j], self.jd_[j]
            mask = np.ones(jd.n, bool) if rows_of is None else rows_of(jd)
            sub = np.flatnonzero(mask)
            sub = sub[:: max(1, len(sub) // 5000)]
            others = [t for t in res.kept if t["name"] != "payload"]
            y_o, X_o = self._yx(jd, others, None)
            blocks.append(X_o[sub])
            shared.append(self._cols("payload", jd, None)[sub])
            ys.append(y_o[sub])
            wts.append(np.full(len(sub), 1.0 / max(res.torque_rms_after_Nm, 1e-9)))
        n_own = sum(b.shape[1] for b in blocks)
        X = np.zeros((sum(len(y) for y in ys), n_own + 10))
        r0, c0 = 0, 0
        for b, z in zip(blocks, shared):
            X[r0:r0 + len(b), c0:c0 + b.shape[1]] = b
            X[r0:r0 + len(b), n_own:] = z
            r0 += len(b)
            c0 += b.shape[1]
        w = np.concatenate(wts)
        theta = lstsq(X * w[:, None], np.concatenate(ys) * w)
        pi = theta[n_own:n_own + 10]    # mass, first moment, inertia of the link-7 addition
        m = float(pi[0])
        com = pi[1:4] / m - np.array([0.0, 0.0, D7_M]) if m > 0 else np.zeros(3)
        return {"mass_kg": m, "com_m": [float(x) for x in com], "joints_fitted": [j + 1 for j in with_p],
                "pi": pi}

    def _check_delay(self, tests: list[str]) -> None:
        """A late measurement delays every joint's positions by the same time: name a delay only where at least
        half of the diagnosed joints show it, within one sample period of their median (position noise fed back
        by the controller can mimic a lag, but not the same one at every joint)."""
        with_d = {j: next(t["h_all"] for t in r.kept if t["name"] == "delay")
                  for j, r in self.joints_.items() if any(t["name"] == "delay" for t in r.kept)}
        if not with_d:
            return
        need = int(np.ceil(len(self.joints_) / 2))
        med = float(np.median(list(with_d.values())))
        agree = {j for j, d in with_d.items() if abs(d - med) <= max(self.signals_.dt_s, 0.25 * med)}
        if len(agree) >= need:
            drop = {j: (f"delay {with_d[j] * 1e3:.1f} ms disagrees with the {med * 1e3:.1f} ms of the other "
                        "joints (a late measurement is one delay for the arm)") for j in with_d if j not in agree}
        else:
            why = (f"a consistent delay was seen at {len(agree)} of {len(self.joints_)} joints "
                   f"(delays {', '.join(f'{d * 1e3:.1f}' for d in with_d.values())} ms); a late measurement "
                   f"delays every joint alike (at least {need} joints within one sample period needed)")
            drop = dict.fromkeys(with_d, why)
        for j, why in drop.items():
            log.info("joint %d: %s", j + 1, why)
            self.joints_[j] = self._diagnose_joint(self.jd_[j], tests, {"delay": why})

    def _check_payload(self) -> None:
        """A payload is one mass for the whole arm: reject it everywhere if the mass fitted over every joint
        that kept it is not positive (and diagnose those joints again without it)."""
        self.payload_ = None
        fit = self._payload_fit()
        if fit is None:
            return
        far = float(np.linalg.norm(fit["com_m"]))
        if not (PAYLOAD_MASS_RANGE_KG[0] <= fit["mass_kg"] <= PAYLOAD_MASS_RANGE_KG[1]) or far > PAYLOAD_MAX_COM_M:
            why = (f"the payload fitted over joints {fit['joints_fitted']} is {fit['mass_kg']:.3g} kg at "
                   f"{far:.3g} m from the flange: not a wrist payload (mass {PAYLOAD_MASS_RANGE_KG[0]} to "
                   f"{PAYLOAD_MASS_RANGE_KG[1]} kg within {PAYLOAD_MAX_COM_M} m)")
            log.info(why)
            tests = [c for c in self.candidates if c not in self.declared_effects_ and c != "backlash"]
            for j in [jj - 1 for jj in fit["joints_fitted"]]:
                self.joints_[j] = self._diagnose_joint(self.jd_[j], tests, {"payload": why})
            return
        self.payload_ = {k: v for k, v in fit.items() if k != "pi"}
        # every joint now carries the same payload: one column per joint (its torque), fitted without each
        # fold for the held-out figures, and on all data for the model
        self.payload_pi_ = {None: fit["pi"]}
        for f in range(self.n_folds):
            ff = self._payload_fit(lambda jd, f=f: jd.fold != f)
            self.payload_pi_[f] = ff["pi"] if ff is not None else fit["pi"]
        for j in [jj - 1 for jj in fit["joints_fitted"]]:
            res, jd = self.joints_[j], self.jd_[j]
            terms = []
            for t in res.kept:
                if t["name"] == "payload":
                    t = dict(t, h_fold=[("global", f) for f in range(self.n_folds)], h_all=("global", None),
                             fixed_h=("global", None))
                terms.append(t)
            self._set_after(res, jd, terms, self._cv_terms(jd, terms))

    def _onsets(self, j: int, extend: int = 100, declared: bool = False) -> dict:
        """Hidden travel at the joint's onsets with the current model of the joint (see
        :mod:`wamctl.analysis.diagnosis.backlash`); with ``declared``, with the declared model fitted.

        The torque available to the joint, ``u = tau - rnea_j(q, qd, qdd with the joint's own velocity and
        acceleration zeroed)``, uses the model with its kept effects (payload in the rigid body, ripple
        added), and the friction levels are scaled by a kept drift at the onset's time."""
        sig = self.signals_
        q_raw = sig.q_raw_rad[:, j]
        quantum = resolution_rad(q_raw)
        # the measurement has moved once it left the stall value by two encoder steps (or four noise sigmas)
        tol = max(2.0 * quantum, 4.0 * float(sig.q_noise_rad[j]), 1e-6)
        ons = find_onsets(sig.t_s, q_raw, sig.qd_rad_s[:, j], float(sig.v_stick_rad_s[j]), tol, 2 * sig.reach)
        if declared:
            fr = self._levels(j, self.jd_[j].extra["theta_before"])
            kept = {}
        else:
            fr = self.friction_after(j)
            kept = {t["name"]: t for t in self.joints_[j].kept}
        stri = self.effect_params(j, "stribeck") if "stribeck" in kept else None
        fs_ratio = None
        if stri:
            fs_ratio = (stri["Fs_pos_Nm"] / max(stri["Fc_pos_Nm"], 1e-9),
                        stri["Fs_neg_Nm"] / max(stri["Fc_neg_Nm"], 1e-9))
        drift = self.effect_params(j, "friction_drift") if "friction_drift" in kept else None
        ripple = self.effect_params(j, "position_ripple") if "position_ripple" in kept else None
        dyn = self.dynamics_
        if "payload" in kept and self.payload_ is not None:
            pl = self.payload_
            decl = self.payload_declared_
            if decl is not None:
                m = decl.mass_kg + pl["mass_kg"]
                com = (decl.mass_kg * np.asarray(decl.com_m) + pl["mass_kg"] * np.asarray(pl["com_m"])) / m
                dyn = WamDynamics(Payload(m, tuple(com)))
            else:
                dyn = WamDynamics(Payload(pl["mass_kg"], tuple(pl["com_m"])))
        tau = sig.tau_raw_Nm
        t0 = sig.t_s[0]
        travel, rev, t_on, ratio, sign, windows = [], [], [], [], [], []
        tau_c = tau[:, j].copy()
        tau_c[1:] = 0.5 * (tau[1:, j] + tau[:-1, j])       # zero-order hold, as for the sliding residual
        delay_decl = float((self.declared_.effects.get("delay") or {}).get("delay_s", 0.0))
        delay = delay_decl + (self.effect_params(j, "delay")["delay_s"] if "delay" in kept else 0.0)
        tau_c_decl = tau_c
        if delay_decl > 0:
            tau_c_decl = np.interp(sig.t_s - delay_decl, sig.t_s, tau_c)
        if delay > 0:   # positions measured d late: the torque that moved the link to q_meas(t) acted at t - d
            tau_c = np.interp(sig.t_s - delay, sig.t_s, tau_c)
        for o in ons:
            ii = np.arange(o.start, min(o.end + extend, sig.n))
            b_jj = float(self.dynamics_.mass_matrix(sig.q_rad[o.end])[j, j])
            # the rigid body without the joint's own acceleration (its velocity is ~0 in a stall)
            rigid = self.rnea_full_[ii, j] - b_jj * sig.qdd_rad_s2[ii, j] + self.known_other_[ii, j]
            u_decl = tau_c_decl[ii] - rigid
            u = tau_c[ii] - rigid
            if dyn is not self.dynamics_:       # a kept payload: its torque along the window, every 10 ms
                pts = np.unique(np.r_[ii[::5], ii[-1]])
                extra_t = []
                for i in pts:
                    qd_i, qdd_i = sig.qd_rad_s[i].copy(), sig.qdd_rad_s2[i].copy()
                    qd_i[j] = qdd_i[j] = 0.0
                    extra_t.append(dyn.inverse_dynamics(sig.q_rad[i], qd_i, qdd_i)[j]
                                   - self.dynamics_.inverse_dynamics(sig.q_rad[i], qd_i, qdd_i)[j])
                u = u - np.interp(ii, pts, extra_t)
            if ripple:
                u += ripple["amplitude_Nm"] * np.sin(2 * np.pi * q_raw[ii] / ripple["period_rad"]
                                                     + ripple["phase_rad"])
            scale = 1.0
            if drift:
                scale = 1 + drift["fraction"] * (1 - np.exp(-(o.t_s - t0) / drift["time_constant_s"]))
            f = {k: max(v, 0.0) * scale for k, v in fr.items()}
            inertia = float(dyn.mass_matrix(sig.q_rad[o.end])[j, j])
            stall = o.end - o.start
            fsp = f["fc_pos_Nm"] * fs_ratio[0] if fs_ratio else None
            fsn = f["fc_neg_Nm"] * fs_ratio[1] if fs_ratio else None
            x = hidden_travel(u[:stall], sig.dt_s, inertia, f["fc_pos_Nm"], f["fc_neg_Nm"],
                              f["viscous_pos_Nm_s_rad"], f["viscous_neg_Nm_s_rad"], fsp, fsn)
            travel.append(o.sign_new * x[-1] - tol)
            rev.append(o.reversal)
            t_on.append(o.t_s)
            ratio.append(breakaway_ratio(u[:stall], sig.dt_s, inertia, max(f["fc_pos_Nm"], 1e-6),
                                         max(f["fc_neg_Nm"], 1e-6), f["viscous_pos_Nm_s_rad"],
                                         f["viscous_neg_Nm_s_rad"], tol))
            sign.append(o.sign_new)
            windows.append({"u": u, "u_declared": u_decl[:stall], "inertia": inertia, "friction": f,
                            "start": o.start, "end": o.end, "sign": o.sign_new, "q": q_raw[ii] - q_raw[o.start],
                            "reversal": o.reversal, "t_s": o.t_s})
        t_on = np.asarray(t_on)
        # onsets are dealt into the folds of the joint's blocks they fall in
        jd = self.jd_[j]
        blk = jd.extra["block"]
        starts = jd.t_s[np.r_[0, np.flatnonzero(np.diff(blk)) + 1]]
        folds = ((np.clip(np.searchsorted(starts, t_on, side="right") - 1, 0, None) + blk[0]) % self.n_folds
                 if len(t_on) else np.zeros(0, int))
        return {"travel_rad": np.asarray(travel), "reversal": np.asarray(rev, bool), "t_s": t_on,
                "fold": folds, "breakaway_ratio": np.asarray(ratio), "sign": np.asarray(sign),
                "resolution_rad": quantum, "tol_rad": tol, "windows": windows}

    def _stall_residual(self, j: int, ons: dict, after: bool) -> np.ndarray:
        """Torque residual at the samples where the measured joint stood still before an onset (m,).

        At rest, friction is set-valued: anything up to the breakaway level. The model is wrong at a stall
        sample when its link, integrated from rest through the stall with the applied torque, has already
        moved further than the measurement allows (two encoder steps; plus the dead band for a model with
        backlash); the residual there is the torque beyond the level the model holds a joint with. The
        declared model uses its Coulomb levels; the augmented one its breakaway levels, dead band, and the
        torque of its other effects. Breakaway ratio and dead band come from the onsets of the other folds.
        """
        sig, res = self.signals_, self.joints_[j]
        if not ons["windows"]:
            return np.zeros(0)
        kept = {t["name"]: t for t in res.kept} if after else {}
        fold_coef = ons.get("fold_coef", {})
        fb = self.friction_before(j)
        out = []
        res.stall_t = np.concatenate([sig.t_s[w["start"]:w["end"]] for w in ons["windows"]])
        for w, f_on in zip(ons["windows"], ons["fold"]):
            stall = w["end"] - w["start"]
            if after:
                u = w["u"][:stall]
                f = w["friction"]
                ratio = (1.0, 1.0)
                if "stribeck" in kept:
                    r = fold_coef.get("stribeck", {}).get(int(f_on))
                    p = self.effect_params(j, "stribeck")
                    ratio = (p["Fs_pos_Nm"] / max(p["Fc_pos_Nm"], 1e-9), p["Fs_neg_Nm"] / max(p["Fc_neg_Nm"], 1e-9))
                    if r is not None:
                        ratio = (float(np.exp(r)),) * 2
                    held_out = [_direction_breakaway_ratio(ons, sgn, f_on) for sgn in (1.0, -1.0)]
                    ratio = tuple(rr if h is None else h for h, rr in zip(held_out, ratio))
                band = 0.0
                if "backlash" in kept and w["reversal"]:
                    wf = fold_coef.get("backlash", {}).get(int(f_on))
                    band = max(wf if wf is not None else kept["backlash"]["width_rad"], 0.0)
            else:
                u = w["u_declared"]
                f = {k: max(v, 0.0) for k, v in fb.items()}
                ratio, band = (1.0, 1.0), 0.0
            fsp, fsn = ratio[0] * f["fc_pos_Nm"], ratio[1] * f["fc_neg_Nm"]
            x = hidden_travel(u, sig.dt_s, w["inertia"], f["fc_pos_Nm"], f["fc_neg_Nm"], f["viscous_pos_Nm_s_rad"],
                              f["viscous_neg_Nm_s_rad"], fsp, fsn)
            # the model's travel against the measured one, both counted from the sample before the model moved by
            # half the tolerance (the window opens while the joint may still settle by a count or two); travel
            # toward the new direction may use the dead band, back along the old one may not
            away = np.flatnonzero(np.abs(x) > 0.5 * ons["tol_rad"])
            k0 = max(away[0] - 1, 0) if len(away) else 0
            gap = (x - x[k0]) - (w["q"][:stall] - w["q"][k0])
            gap[:k0] = 0.0
            along = w["sign"] * gap
            allowed = ons["tol_rad"] + np.where(along > 0, band, 0.0)
            wrong = np.abs(gap) > allowed
            level = np.where(u > 0, fsp, fsn)
            out.append(np.where(wrong, np.sign(u) * np.maximum(np.abs(u) - level, 0.0), 0.0))
        return np.concatenate(out) if out else np.zeros(0)

    def _slip_vs(self, j: int, ons: dict, ratio: float) -> float | None:
        """Stribeck velocity that best reproduces the measured slips after each same-direction breakaway
        (the joint integrated open-loop from rest with the logged torque, ``Fs = ratio Fc``)."""
        sig = self.signals_
        wins = [w for w in ons["windows"] if not w["reversal"]]
        if not wins:
            return None
        best, arg = np.inf, None
        for vs in STRIBECK_VS_GRID_RAD_S:
            ssr = 0.0
            for w in wins:
                f = w["friction"]
                x = hidden_travel(w["u"], sig.dt_s, w["inertia"], f["fc_pos_Nm"], f["fc_neg_Nm"],
                                  f["viscous_pos_Nm_s_rad"], f["viscous_neg_Nm_s_rad"], ratio * f["fc_pos_Nm"],
                                  ratio * f["fc_neg_Nm"], vs_rad_s=vs)
                err = x - w["q"]
                ssr += float(err @ err)
            if ssr < best:
                best, arg = ssr, float(vs)
        return arg

    def _stribeck_at_breakaways(self, j: int):
        """(test, onsets) when the breakaway ratios under the declared model show a Stribeck effect, else
        None (see :meth:`_onset_tests`)."""
        ons = self._onsets(j, declared=True)
        ratio = ons["breakaway_ratio"]
        ok = np.isfinite(ratio)
        if ok.sum() < MIN_ONSETS:
            return None
        r = self._onset_candidate("stribeck", np.log(ratio[ok]), None, ons["fold"][ok],
                                  lambda c: 0 < c <= np.log(MAX_BREAKAWAY_RATIO), lambda c: "")
        return (r, ons) if r["kept"] else None

    def _onset_tests(self, j: int, tests: list[str]) -> None:
        """Effects seen at onsets (:mod:`wamctl.analysis.diagnosis.backlash`).

        * backlash: hidden travel ``d`` at reversals, ``d = c + w [reversal]`` against ``d = c`` (``c`` only
          when there are same-direction onsets to estimate it);
        * Stribeck at breakaway (when the torque residual did not already keep it): the log breakaway ratio
          ``l = log(rho)``, ``l = c`` against ``l = 0``, at every onset (at same-direction onsets only when
          backlash was kept: a dead band also delays the measured breakaway at reversals).
        """
        res = self.joints_[j]
        ons = self._onsets(j)
        self.onsets_[j] = ons
        d, rev, fold = ons["travel_rad"], ons["reversal"], ons["fold"]
        tol = ons["tol_rad"]
        found = []
        if "backlash" in tests:
            r = self._onset_candidate(
                "backlash", d, rev, fold, lambda coef: coef >= tol,
                lambda coef: f"fitted dead band {coef:.2g} rad is below two measurement steps ({tol:.2g} rad)")
            res.candidates["backlash"] = {k: v for k, v in r.items() if k not in ("coef", "coef_fold")}
            if r["kept"]:
                found.append(("backlash", r))
        if "stribeck" in tests and not any(t["name"] == "stribeck" for t in res.kept):
            same = np.isfinite(ons["breakaway_ratio"])
            if found:                   # backlash kept: reversals are not clean breakaways
                same &= ~rev
            ell = np.log(ons["breakaway_ratio"][same])
            r = self._onset_candidate(
                "stribeck", ell, None, fold[same], lambda coef: 0 < coef <= np.log(MAX_BREAKAWAY_RATIO),
                lambda coef: f"breakaway ratio {np.exp(coef):.2f} is not between 1 and {MAX_BREAKAWAY_RATIO:g}")
            note = {k: r[k] for k in ("p_value", "delta_bic", "reason") if k in r}
            if r["kept"]:
                found.append(("stribeck", r))
            elif "stribeck" in res.candidates:
                res.candidates["stribeck"]["onset_test"] = note
        if "stribeck" in tests and any(t["name"] == "stribeck" for t in res.kept):
            # Stribeck kept from the sliding samples: the breakaways measure its static level directly
            use = np.isfinite(ons["breakaway_ratio"]) & (~rev if found else True)
            t = next(t for t in res.kept if t["name"] == "stribeck")
            if use.sum() >= MIN_ONSETS and not t.get("onset_ratio"):
                rho = float(np.exp(np.mean(np.log(ons["breakaway_ratio"][use]))))
                if 1.0 < rho <= MAX_BREAKAWAY_RATIO:
                    t["onset_ratio"] = rho
        ons["fold_coef"] = {}
        for name, r in sorted(found, key=lambda x: x[1]["ssr_ratio"]):
            self._add_onset_effect(j, name, r, ons)
            ons["fold_coef"][name] = r.get("coef_fold", {})
        t = next((t for t in res.kept if t["name"] == "stribeck"), None)
        if t is not None:
            # the breakaway level of each direction on its own: a joint that sticks and slips one way only has
            # few sliding samples there, and a ratio shared by both directions would inherit their Coulomb fit
            use = np.isfinite(ons["breakaway_ratio"]) & (~rev if any(n == "backlash" for n, _ in found) else True)
            ons["use_breakaway"] = use
            rho = {key: _direction_breakaway_ratio(ons, sgn) for key, sgn in (("pos", 1.0), ("neg", -1.0))}
            rho = {key: r for key, r in rho.items() if r is not None}
            if rho:
                t["onset_ratio_dir"] = rho
        # the torque residual at the stalls (set-valued friction at rest) joins the sliding residual
        res.stall_before = self._stall_residual(j, ons, after=False)
        res.stall_after = self._stall_residual(j, ons, after=True)
        self._set_rms(res)

    def _onset_candidate(self, name, values, rev, fold, plausible, why_not) -> dict:
        """Nested test at onsets of one candidate: ``rev is None`` tests a common offset against zero;
        otherwise a reversal term against a common offset (or zero without same-direction onsets)."""
        n = len(values)
        if n < MIN_ONSETS or (rev is not None and rev.sum() < MIN_REVERSALS):
            what = "onsets" if rev is None else "reversals"
            have = n if rev is None else int(rev.sum())
            need = MIN_ONSETS if rev is None else MIN_REVERSALS
            return {"p_value": float("nan"), "delta_bic": float("nan"), "kept": False,
                    "reason": f"not testable: {have} {what} measured (at least {need} needed)"}
        if rev is None:
            X0, X1 = np.zeros((n, 0)), np.ones((n, 1))
        else:
            X0 = np.ones((n, 1)) if (~rev).sum() >= 2 else np.zeros((n, 0))
            X1 = np.column_stack([X0, rev.astype(float)])
        t = onset_test(values, X0, X1, fold, self.n_folds, MIN_EFFECT)
        coef = float(t["coef"][-1])
        out = {k: v for k, v in t.items() if k not in ("e0", "e1", "coef", "coef_fold")}
        out["coef"] = coef
        out["coef_fold"] = t["coef_fold"]
        kept = t["p_value"] < self.threshold_ and t["delta_bic"] < 0
        if kept and not plausible(coef):
            out.update(kept=False, reason=why_not(coef))
        else:
            out.update(kept=kept, reason="kept (seen at onsets)" if kept else self._why_rejected(t))
        return out

    def _add_onset_effect(self, j: int, name: str, r: dict, ons: dict) -> None:
        """Add an effect found at onsets to the joint's model (its torque-domain part refitted)."""
        res, jd = self.joints_[j], self.jd_[j]
        ev = {k: v for k, v in r.items() if k in ("p_value", "delta_bic", "F", "n", "n_eff", "ssr_ratio")}
        extra = {}
        if name == "backlash":
            extra["width_rad"] = float(r["coef"])
        else:
            extra["onset_ratio"] = float(np.exp(r["coef"]))
            extra["onset_vs"] = self._slip_vs(j, ons, extra["onset_ratio"])
            extra["fixed_h"] = extra["onset_vs"]
        e1, h_fold = self._cv(jd, res.kept, name, extra.get("fixed_h"))
        term = {"name": name, "h_fold": h_fold, "evidence": ev, "gain": 1.0 - r["ssr_ratio"], **extra}
        if _ss(e1) > _ss(res.e_after):
            e1 = res.e_after
        self._set_after(res, jd, res.kept + [term], e1)
        res.candidates[name] = {k: v for k, v in r.items() if k not in ("coef", "coef_fold")}

    # ------------------------------------------------------------------------------------------ params
    def _split(self, res_terms: list[dict], theta: np.ndarray) -> dict:
        """Coefficients by term name."""
        out = {"friction": theta[:4]}
        k = 4
        for t in res_terms:
            n = _ncols(t)
            out[t["name"]] = theta[k:k + n]
            k += n
        return out

    def _plausible(self, name: str, jd: JointData, terms: list[dict], theta: np.ndarray) -> tuple[bool, str]:
        c = self._split(terms, theta)
        coef = c[name]

        if name == "stribeck":
            pos, neg = (jd.qd_rad_s > 0).sum(), (jd.qd_rad_s < 0).sum()
            w = np.array([pos, neg], float)
            if (coef * w).sum() <= 0:
                return False, "fitted breakaway below the Coulomb level (not a Stribeck effect)"
            fc = c["friction"][:2]
            seen = w > 0
            ratio = (fc + coef)[seen] / np.maximum(fc[seen], 1e-9)
            if np.any(ratio > MAX_BREAKAWAY_RATIO):
                return False, (f"fitted breakaway {ratio.max():.3g} times the Coulomb level: beyond a physical "
                               f"Stribeck effect (at most {MAX_BREAKAWAY_RATIO:g})")
        if name == "position_ripple":
            # torque periodic in the angle is the same whichever way the joint turns; a periodic trace of the
            # control loop (hunting at a speed-dependent frequency) is not
            h = next(t["h_all"] for t in terms if t["name"] == "position_ripple")
            amps = []
            for m in (jd.qd_rad_s > 0, jd.qd_rad_s < 0):
                if m.sum() < 100 or np.ptp(jd.q_rad[m]) < h:
                    continue
                y, X = self._yx(jd, terms, None)
                th = self._fit_theta(X[m], y[m])
                k = 4 + sum(_ncols(t) for t in terms[: [t["name"] for t in terms].index(name)])
                amps.append(complex(th[k], th[k + 1]))
            if len(amps) == 2 and abs(amps[0] - amps[1]) > 0.5 * max(abs(amps[0]), abs(amps[1])):
                return False, (f"the ripple differs between the two directions of motion (amplitudes "
                               f"{abs(amps[0]):.3g} and {abs(amps[1]):.3g} N m): not a torque periodic in the angle")
        if name == "delay":
            h = next(t["h_all"] for t in terms if t["name"] == "delay")
            if h >= DELAY_GRID_S[-1] - 1e-12:
                return False, f"fitted delay at the end of the range searched ({h * 1e3:.1f} ms): not a delay"
            if h < self.signals_.dt_s * (1 + 1e-9):
                return False, (f"fitted delay {h * 1e3:.1f} ms is not longer than one sample period "
                               f"({self.signals_.dt_s * 1e3:.1f} ms): within the timing convention of the log")
        return True, ""

    def effect_params(self, j: int, name: str, theta: np.ndarray | None = None) -> dict:
        """Parameters of kept effect ``name`` at 0-based joint ``j`` (units in the key names); ``theta``
        overrides the coefficients fitted on all data (see :meth:`refit`)."""
        res = self.joints_[j]
        c = self._split(res.kept, res.theta_after if theta is None else theta)
        t = next(t for t in res.kept if t["name"] == name)
        h = t.get("h_all")
        fr = np.array(list(self._levels(j, c["friction"]).values()))     # absolute levels
        coef = c[name]
        if name == "stribeck":
            out = {"Fs_pos_Nm": float(fr[0] + coef[0]), "Fs_neg_Nm": float(fr[1] + coef[1]),
                   "Fc_pos_Nm": float(fr[0]), "Fc_neg_Nm": float(fr[1]), "vs_rad_s": float(h)}
            if t.get("onset_ratio"):      # found at breakaways: the level the joint withstood
                rho = t.get("onset_ratio_dir", {})
                out["Fs_pos_Nm"] = rho.get("pos", t["onset_ratio"]) * out["Fc_pos_Nm"]
                out["Fs_neg_Nm"] = rho.get("neg", t["onset_ratio"]) * out["Fc_neg_Nm"]
                if t.get("onset_vs"):
                    out["vs_rad_s"] = t["onset_vs"]
                out["Fs_from"] = "breakaways"
            return out
        if name == "position_ripple":
            a, b = -coef[0], -coef[1]          # y = friction - ripple: the plant's ripple is minus the fit
            return {"amplitude_Nm": float(np.hypot(a, b)), "period_rad": float(h),
                    "phase_rad": float(np.arctan2(b, a) % (2 * np.pi))}
        if name == "payload":
            if self.payload_ is not None and (theta is None or len(coef) == 1):
                return dict(self.payload_)
            m = float(coef[0])
            com = coef[1:4] / m - np.array([0.0, 0.0, D7_M]) if m > 0 else np.zeros(3)
            return {"mass_kg": m, "com_m": [float(x) for x in com]}
        if name == "delay":
            return {"delay_s": float(h)}
        if name == "friction_drift":
            X = self._cols("friction", self.jd_[j], None)
            tb = self._abs_before(self.jd_[j])
            dec = np.array([coef[0] * tb[0], coef[0] * tb[1], coef[1] * tb[2], coef[1] * tb[3]])
            f0 = X @ (fr + dec)                  # friction at t = 0
            f1 = X @ dec                         # the part that decays
            frac = -float(f1 @ f0 / max(f0 @ f0, 1e-300))
            t0 = fr + dec
            return {"fraction": frac, "time_constant_s": float(h),
                    "friction_t0": {"fc_pos_Nm": float(t0[0]), "fc_neg_Nm": float(t0[1]),
                                    "viscous_pos_Nm_s_rad": float(t0[2]), "viscous_neg_Nm_s_rad": float(t0[3])}}
        if name == "backlash":
            ons = self.onsets_.get(j, {})
            return {"width_rad": float(t["width_rad"]), "gravity_offset_rad": float(coef[0]),
                    "reversals": int(np.sum(ons.get("reversal", []))),
                    "same_direction_onsets": int(np.sum(~np.asarray(ons.get("reversal", []), bool)))}
        raise ValueError(name)

    def friction_after(self, j: int, theta: np.ndarray | None = None) -> dict:
        """Classic friction of 0-based joint ``j`` in the final model (at t = 0 when friction drifts)."""
        res = self.joints_[j]
        c = self._split(res.kept, res.theta_after if theta is None else theta)
        fr = np.array(c["friction"], float)
        if "friction_drift" in c:
            tb = self._abs_before(self.jd_[j])
            cd = c["friction_drift"]
            fr = fr + np.array([cd[0] * tb[0], cd[0] * tb[1], cd[1] * tb[2], cd[1] * tb[3]])
        return self._levels(j, fr)

    def friction_before(self, j: int, theta: np.ndarray | None = None) -> dict:
        """Classic friction of the declared model (fitted, or the model file's levels plus the fitted
        correction when a model file gives them)."""
        return self._levels(j, self.joints_[j].theta_before if theta is None else theta)

    def _abs_before(self, jd: JointData) -> np.ndarray:
        """(4,) absolute classic friction of the declared model of a joint (the shape a drift scales)."""
        return np.array(list(self._levels(jd.j, jd.extra["theta_before"]).values()))

    def _levels(self, j: int, fr: np.ndarray) -> dict:
        """Classic friction levels from the four fitted coefficients (absolute: a model file's levels are added
        to the correction fitted on top of them)."""
        fr = np.array(fr[:4], float)
        given = self.declared_.friction
        if given is not None:
            fr = fr + np.array([given.fc_pos_Nm[j], given.fc_neg_Nm[j], given.viscous_pos_Nm_s_rad[j],
                                given.viscous_neg_Nm_s_rad[j]])
        return {"fc_pos_Nm": float(fr[0]), "fc_neg_Nm": float(fr[1]),
                "viscous_pos_Nm_s_rad": float(fr[2]), "viscous_neg_Nm_s_rad": float(fr[3])}

    def refit(self, rows_of) -> dict:
        """Coefficients of the declared and the final model of every joint fitted on a subset of samples.

        Parameters
        ----------
        rows_of : callable ``JointData -> (m,) bool``, the samples to fit on (shape parameters are kept).

        Returns
        -------
        {joint: (theta_before, theta_after)}, and under key ``"payload"`` the payload fitted on the subset.
        """
        out = {}
        for j, res in self.joints_.items():
            jd = self.jd_[j]
            rows = np.flatnonzero(rows_of(jd))
            if len(rows) < 20:
                out[j] = (res.theta_before, res.theta_after)
                continue
            tb = self._fit_theta(self._cols("friction", jd, None)[rows], jd.y_Nm[rows])
            y, X = self._yx(jd, res.kept, None)
            out[j] = (tb, self._fit_theta(X[rows], y[rows]))
        out["payload"] = self._payload_fit(rows_of) if self.payload_ is not None else None
        return out

    def _finalise_effects(self) -> None:
        for j, res in self.joints_.items():
            res.effects = []
            for t in res.kept:
                ev = t["evidence"]
                test = TEST_NAME if t["name"] != "backlash" else \
                    "nested F-test on held-out folds (hidden travel at onsets)"
                res.effects.append({"name": t["name"], "params": self.effect_params(j, t["name"]),
                                    "evidence": {"test": test, "p_value": float(ev["p_value"]),
                                                 "delta_bic": float(ev["delta_bic"])}})

    # ------------------------------------------------------------------------------------------ output
    def to_dict(self, data_path: str = "") -> dict:
        """``diagnosis.json`` (format ``wamctl-diagnosis/1``, see docs/diagnosis-report.md)."""
        joints = {}
        for j, res in sorted(self.joints_.items()):
            joints[str(j + 1)] = {
                "effects": res.effects,
                "candidates": [{"name": c, "p_value": _num(d.get("p_value")), "delta_bic": _num(d.get("delta_bic")),
                                "kept": bool(d.get("kept")), "reason": d.get("reason", "")}
                               for c, d in res.candidates.items()],
                "torque_rms_before_Nm": _num(res.torque_rms_before_Nm),
                "torque_rms_after_Nm": _num(res.torque_rms_after_Nm),
                "position_rms_before_rad": _num(res.position_rms_before_rad),
                "position_rms_after_rad": _num(res.position_rms_after_rad),
                "residual_whiteness_p_before": _num(res.whiteness_p_before),
                "residual_whiteness_p_after": _num(res.whiteness_p_after),
                "friction_before": self.friction_before(j),
                "friction_after": self.friction_after(j),
            }
        declared = DECLARED_MODEL if self.declared_.fitted else \
            f"{DECLARED_MODEL}, parameters from {self.declared_.source}"
        out = {"format": "wamctl-diagnosis/1", "data": data_path, "declared_model": declared,
               "effects_found": list(self.effects_found_), "joints": joints,
               "conclusive": bool(self.conclusive_), "reason": self.reason_}
        sig = getattr(self, "signals_", None)
        if sig is not None:
            out["skipped_joints"] = {str(j + 1): r for j, r in sig.skipped.items()}
            out["method"] = {"test_threshold_p": _num(getattr(self, "threshold_", float("nan"))),
                             "alpha_per_run": self.alpha, "folds": self.n_folds, "blocks": self.n_blocks,
                             "savgol_window_samples": sig.window, "gauss_sigma_samples": sig.gauss,
                             "sample_rate_hz": 1.0 / sig.dt_s,
                             "samples": sig.n, "resampled": sig.resampled,
                             "decimation": getattr(self, "decimation_", 1)}
        return out


def _ncols(term: dict) -> int:
    """Columns a kept term adds (the arm's one payload, once fitted over all joints, adds one)."""
    if term["name"] == "payload" and isinstance(term.get("h_all", term.get("fixed_h")), tuple):
        return 1
    return N_COLUMNS[term["name"]]


def _direction_breakaway_ratio(ons: dict, sign: float, fold: int | None = None) -> float | None:
    """Breakaway ratio (geometric mean) of direction ``sign`` at the onsets usable for it (``ons["use_breakaway"]``),
    outside fold ``fold`` when given; None when fewer than two."""
    use = ons.get("use_breakaway")
    if use is None:
        return None
    m = use & (ons["sign"] == sign)
    if fold is not None:
        m &= ons["fold"] != fold
    if m.sum() < 2:
        return None
    return float(np.clip(np.exp(np.mean(np.log(ons["breakaway_ratio"][m]))), 1.0, MAX_BREAKAWAY_RATIO))


def _ss(e: np.ndarray) -> float:
    """Sum of squares of the finite entries (held-out residuals are NaN where no model can predict)."""
    return float(np.nansum(np.asarray(e, float) ** 2))


def _num(x):
    if x is None:
        return None
    x = float(x)
    return None if not np.isfinite(x) else x
