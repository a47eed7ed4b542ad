"""Model diagnosis: from a measured run to the effect the declared model lacks, with evidence (no I/O).

Method
------
1. **Torque residual.** Positions are differentiated with a centred Savitzky-Golay filter and the logged torque
   is aligned (zero-order hold) and smoothed by the same filter (:mod:`wamctl.analysis.diagnosis_signals`).
   ``y = tau - rnea(q, qd, qdd)`` with the declared rigid body (+ armature, + a declared payload) is what
   friction and any missing effect must supply. Samples where a joint sticks, and the filter's reach around
   them, are left out: there the friction torque is static and unknown.
2. **Declared model.** Per joint, classic friction per direction (Coulomb + viscous) is linear in its four
   parameters; it is fitted by least squares (unless a model file gives it).
3. **Held-out data.** The run is cut into ``n_blocks`` contiguous time blocks, dealt into ``n_folds`` folds
   (block ``b`` -> fold ``b % n_folds``). Every number called held-out comes from a model fitted on the other
   folds; every shape parameter of a candidate (Stribeck velocity, ripple period, delay, drift time
   constant) is chosen on the training folds only.
4. **Candidates.** One signature per effect name (:mod:`wamctl.analysis.diagnosis_candidates`). Each is
   tested as a nested model against the current model: an F-test and a BIC change on the held-out
   residuals, with the sample count deflated by the residual's integrated autocorrelation time
   (:mod:`wamctl.analysis.diagnosis_stats`). The threshold is ``alpha / (joints x candidates)``
   (Bonferroni over every test of the run), so that a run with nothing missing reports nothing with
   probability about ``1 - alpha``. An effect must also be physically plausible (breakaway above Coulomb, a
   positive mass, a positive delay). Forward selection: the best passing candidate (largest held-out gain)
   is added, the rest are tested again against the augmented model, until none passes.
5. **After.** All parameters (friction and the kept effects) are refitted; the held-out torque RMS and the
   residual whiteness (Ljung-Box on one sample per filter window) are reported before and after.

The closed-loop position check and the model file are in :mod:`wamctl.analysis.diagnosis_sim`.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np

from wamctl.analysis.diagnosis_candidates import (
    BACKLASH_TIME_CONSTANTS_S, D7_M, DELAY_GRID_S, DRIFT_T_GRID_FRACTION, EFFECT_NAMES, RIPPLE_PERIOD_MAX_RAD,
    RIPPLE_PERIOD_MIN_RAD, STRIBECK_VS_GRID_RAD_S, JointData, backlash_columns, drift_columns,
    friction_columns, reversal_times, ripple_columns, stribeck_columns)
from wamctl.analysis.diagnosis_signals import Signals, prepare_signals, savgol_gain
from wamctl.analysis.diagnosis_stats import lstsq, nested_test, orth_basis, projection_gain, whiteness_p
from wamctl.errors import DataFormatError
from wamctl.model import params as P
from wamctl.model.dynamics import Payload, WamDynamics
from wamctl.model.friction import FrictionModel

log = logging.getLogger(__name__)

N7 = P.N_JOINTS
DECLARED_MODEL = "wam7 rigid body + armature + classic friction (Coulomb + viscous, per direction)"
TEST_NAME = "nested F-test on held-out folds"
N_COLUMNS = {"stribeck": 2, "position_ripple": 2, "payload": 4, "delay": 1, "friction_drift": 4,
             "backlash": len(BACKLASH_TIME_CONSTANTS_S) + 1}
HAS_GRID = {"stribeck": True, "position_ripple": True, "payload": False, "delay": True,
            "friction_drift": True, "backlash": False}
MAX_SAMPLES_PER_JOINT = 30000     # decimation above this (smoothed signals: little information is lost)


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
    e_after: np.ndarray | None = None
    torque_rms_before_Nm: float = float("nan")
    torque_rms_after_Nm: float = float("nan")
    whiteness_p_before: float = float("nan")
    whiteness_p_after: float = float("nan")
    position_rms_before_rad: float = float("nan")
    position_rms_after_rad: float = float("nan")
    effects: list[dict] = field(default_factory=list)         # report-ready: name, params, evidence


def fold_of(t_s: np.ndarray, n_blocks: int, n_folds: int) -> np.ndarray:
    """Fold number of each sample: contiguous time blocks dealt round-robin into folds."""
    t0, t1 = float(t_s[0]), float(t_s[-1])
    block = np.minimum(((t_s - t0) / max(t1 - t0, 1e-12) * n_blocks).astype(int), n_blocks - 1)
    return block % n_folds


class ModelDiagnosis:
    """Find what the declared model of the WAM lacks in a measured run.

    Parameters
    ----------
    alpha : family-wise false-alarm level of the whole run (Bonferroni over joints x candidates).
    n_blocks, n_folds : contiguous time blocks and the folds they are dealt into.
    candidates : effect names to test (default: all of the vocabulary).
    declared : the declared model (default: classic friction fitted from the data).
    max_steps : effects kept per joint at most.
    window_s : smoothing window of the differentiation filter.

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
                 max_steps: int = 3, window_s: float | None = None):
        self.alpha = alpha
        self.n_blocks = n_blocks
        self.n_folds = n_folds
        self.candidates = candidates
        self.declared = declared
        self.max_steps = max_steps
        self.window_s = window_s

    # ------------------------------------------------------------------------------------------ fit
    def fit(self, data) -> "ModelDiagnosis":
        """Diagnose a :class:`wamctl.measured.RunData` (a run directory or a measured run, loaded)."""
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
        self.threshold_ = self.alpha / max(1, len(sig.joints) * max(1, len(tests)))
        for j in sig.joints:
            self.joints_[j] = self._diagnose_joint(self.jd_[j], tests)
        strength = {}
        for res in self.joints_.values():
            for k in res.kept:
                strength[k["name"]] = max(strength.get(k["name"], 0.0), k["gain"])
        self.effects_found_ = sorted(strength, key=lambda n: -strength[n])
        self._finalise_effects()
        self.conclusive_ = True
        return self

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
        reg = np.empty((len(union), N7, 4)) if want_payload else None
        for k, i in enumerate(union):
            rnea[k] = dyn.inverse_dynamics(q[i], qd[i], qdd[i])
            if want_payload:
                reg[k] = dyn.regressor_basis(q[i], qd[i], qdd[i])[:, 60:64]
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
        known = self._declared_torque()                      # (n, 7) torque the declared model file adds
        delay_given = float((self.declared_.effects.get("delay") or {}).get("delay_s", 0.0))
        folds = fold_of(sig.t_s, self.n_blocks, self.n_folds)
        self.jd_ = {}
        t0 = sig.t_s[0]
        for j in sig.joints:
            idx = np.flatnonzero(keep & sig.moving[:, j])
            u = pos[idx]
            tau_j = tau_full[:, j]
            if delay_given > 0:
                tau_now = np.interp(sig.t_s[idx] - delay_given, sig.t_s, tau_j)
            else:
                tau_now = tau_j[idx]
            y = tau_now - rnea[u, j] - known[idx, j]
            extra = {"tau_now": tau_now, "tau_full": tau_j, "t_rel": sig.t_s[idx] - t0,
                     "dgdq": np.interp(sig.t_s[idx], sig.t_s[coarse], dgdq_c[:, j])}
            if want_payload:
                extra["payload"] = reg[u, j, :]
            ev_t, ev_s = reversal_times(sig.t_s, sig.qd_rad_s[:, j], sig.moving[:, j])
            extra["reversals"] = (ev_t, ev_s)
            self.jd_[j] = JointData(j, idx, sig.t_s[idx], q[idx, j], qd[idx, j], qdd[idx, j], y, folds[idx], extra)

    def _declared_torque(self) -> np.ndarray:
        """(n, 7) torque of the declared model beyond the rigid body when a model file gives it (friction,
        ripple); zero when friction is fitted from the data."""
        sig = self.signals_
        out = np.zeros((sig.n, N7))
        d = self.declared_
        if d.friction is None:
            return out
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
                gain = savgol_gain(sig.window, np.abs(sig.qd_rad_s[:, j]) * sig.dt_s / per)
                out[:, j] -= gain * float(s.get("amplitude_Nm", 0.5)) * np.sin(
                    2 * np.pi * sig.q_rad[:, j] / per + float(s.get("phase_rad", 0.0)))
        return out

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

    def _cols(self, name: str, jd: JointData, h) -> np.ndarray:
        cache = jd.extra.setdefault("_cache", {})
        key = (name, None if h is None else round(float(h), 12))
        if key in cache:
            return cache[key]
        sig = self.signals_
        if name == "friction":
            X = friction_columns(jd.qd_rad_s)
        elif name == "stribeck":
            X = stribeck_columns(jd.qd_rad_s, h)
        elif name == "position_ripple":
            X = ripple_columns(jd.q_rad, jd.qd_rad_s, h, sig.window, sig.dt_s)
        elif name == "payload":
            X = jd.extra["payload"]
        elif name == "delay":
            X = (jd.extra["tau_now"] - np.interp(jd.t_s - h, sig.t_s, jd.extra["tau_full"]))[:, None]
        elif name == "friction_drift":
            X = drift_columns(jd.qd_rad_s, jd.extra["t_rel"], h)
        elif name == "backlash":
            ev_t, ev_s = jd.extra["reversals"]
            X = backlash_columns(jd.t_s, jd.qd_rad_s, ev_t, ev_s, jd.extra["dgdq"])
        else:
            raise ValueError(name)
        if len(cache) > 400:
            cache.clear()
        cache[key] = X
        return X

    def _design(self, jd: JointData, terms: list[dict], fold: int | None) -> np.ndarray:
        cols = [self._cols("friction", jd, None)]
        for t in terms:
            h = t["h_all"] if fold is None else t["h_fold"][fold]
            cols.append(self._cols(t["name"], jd, h))
        return np.hstack(cols)

    # ------------------------------------------------------------------------------------------ selection
    def _select(self, name: str, jd: JointData, rows: np.ndarray, Xb: np.ndarray):
        """Shape parameter of candidate ``name`` that best explains the base residual on ``rows``."""
        grid = self._grid(name, jd)
        if name == "position_ripple":
            return self._select_ripple(jd, rows, Xb)
        if len(grid) == 1:
            return grid[0]
        U = orth_basis(Xb[rows])
        r = jd.y_Nm[rows] - U @ (U.T @ jd.y_Nm[rows])
        gains = [projection_gain(U, r, self._cols(name, jd, h)[rows]) for h in grid]
        return grid[int(np.argmax(gains))]

    def _select_ripple(self, jd: JointData, rows: np.ndarray, Xb: np.ndarray) -> float:
        """Period of the strongest position-periodic component of the base residual (coarse scan of
        2 pi / period, then a local refinement); the columns are the filter-attenuated sin/cos."""
        sig = self.signals_
        sub = rows[:: max(1, len(rows) // 4000)]
        U = orth_basis(Xb[sub])
        y = jd.y_Nm[sub]
        r = y - U @ (U.T @ y)
        q, qd = jd.q_rad[sub], jd.qd_rad_s[sub]
        span = max(float(np.ptp(jd.q_rad)), 0.05)
        k_lo, k_hi = 1.0 / RIPPLE_PERIOD_MAX_RAD, 1.0 / RIPPLE_PERIOD_MIN_RAD
        step = 1.0 / (4.0 * span)
        n_k = int((k_hi - k_lo) / step) + 1
        if n_k > 3000:
            n_k = 3000
        ks = np.linspace(k_lo, k_hi, n_k)
        f_tab = np.linspace(0.0, 0.5, 1025)
        g_tab = savgol_gain(sig.window, f_tab)
        speed = np.abs(qd) * sig.dt_s

        def scores(kk):
            out = np.empty(len(kk))
            for c0 in range(0, len(kk), 256):
                kc = kk[c0:c0 + 256]
                g = np.interp(np.minimum(np.outer(speed, kc), 0.5), f_tab, g_tab)
                ph = 2 * np.pi * np.outer(q, kc)
                S, C = g * np.sin(ph), g * np.cos(ph)
                S = S - U @ (U.T @ S)
                C = C - U @ (U.T @ C)
                a, b = S.T @ r, C.T @ r
                ss, cc, sc = (S * S).sum(0), (C * C).sum(0), (S * C).sum(0)
                det = ss * cc - sc ** 2
                ok = det > 1e-12 * (ss * cc + 1e-300)
                val = np.where(ok, (a * a * cc - 2 * a * b * sc + b * b * ss) / np.where(ok, det, 1.0), 0.0)
                out[c0:c0 + 256] = val
            return out

        s = scores(ks)
        best_k = ks[int(np.argmax(s))]
        top = ks[np.argsort(s)[-3:]]
        fine = np.unique(np.concatenate([np.linspace(k - step, k + step, 17) for k in top]))
        fine = fine[(fine >= k_lo) & (fine <= k_hi)]
        if len(fine):
            sf = scores(fine)
            if sf.max() > s.max():
                best_k = fine[int(np.argmax(sf))]
        return float(1.0 / best_k)

    # ------------------------------------------------------------------------------------------ CV
    def _cv(self, jd: JointData, terms: list[dict], cand: str | None = None):
        """Held-out residuals of ``friction + terms (+ cand)``; returns (residual, per-fold shape params)."""
        e = np.zeros(jd.n)
        h_fold = []
        for f in range(self.n_folds):
            te = jd.fold == f
            tr = ~te
            if not te.any():
                h_fold.append(None)
                continue
            Xb = self._design(jd, terms, f)
            trr = np.flatnonzero(tr)
            if cand is not None:
                h = self._select(cand, jd, trr, Xb)
                h_fold.append(h)
                X = np.hstack([Xb, self._cols(cand, jd, h)])
            else:
                h_fold.append(None)
                X = Xb
            if len(trr) < X.shape[1] + 5:
                e[te] = jd.y_Nm[te] - np.mean(jd.y_Nm[trr]) if len(trr) else jd.y_Nm[te]
                continue
            theta = lstsq(X[trr], jd.y_Nm[trr])
            e[te] = jd.y_Nm[te] - X[te] @ theta
        return e, h_fold

    def _fit_all(self, jd: JointData, terms: list[dict]) -> tuple[list[dict], np.ndarray]:
        """Refit on all data: shape parameters chosen one term at a time with the others fixed."""
        terms = [dict(t) for t in terms]
        rows = np.arange(jd.n)
        for i, t in enumerate(terms):
            others = terms[:i] + terms[i + 1:]
            for o in others:
                o.setdefault("h_all", self._first_h(o))
            Xb = self._design(jd, others, None)
            t["h_all"] = self._select(t["name"], jd, rows, Xb)
        X = self._design(jd, terms, None)
        return terms, lstsq(X, jd.y_Nm)

    @staticmethod
    def _first_h(t: dict):
        hs = [h for h in t["h_fold"] if h is not None]
        return float(np.median(hs)) if hs and not isinstance(hs[0], str) else (hs[0] if hs else None)

    # ------------------------------------------------------------------------------------------ joint
    def _diagnose_joint(self, jd: JointData, tests: list[str]) -> JointResult:
        res = JointResult(jd.j)
        spacing = max(1, self.signals_.window // self.decimation_)
        e_base, _ = self._cv(jd, [])
        if self.declared_.fitted:
            e_before = e_base
        else:
            e_before = jd.y_Nm.copy()    # the given model, not refitted
        res.e_before = e_before
        res.theta_before = lstsq(self._cols("friction", jd, None), jd.y_Nm)
        terms: list[dict] = []
        current = e_base
        remaining = list(tests)
        last = {}
        for step in range(self.max_steps):
            trial = {}
            for c in remaining:
                if c == "payload" and "payload" not in jd.extra:
                    continue
                e1, h_fold = self._cv(jd, terms, c)
                k1 = 4 + sum(N_COLUMNS[t["name"]] for t in terms) + N_COLUMNS[c]
                p_extra = N_COLUMNS[c] + (1 if HAS_GRID[c] else 0)
                t = nested_test(current, e1, p_extra, k1)
                trial[c] = (t, h_fold, e1)
                last[c] = dict(t, step=step)
            passing = sorted((c for c, (t, _, _) in trial.items()
                              if t["p_value"] < self.threshold_ and t["delta_bic"] < 0),
                             key=lambda c: trial[c][0]["ssr_ratio"])
            chosen = None
            for c in passing:
                t, h_fold, e1 = trial[c]
                cand_terms = terms + [{"name": c, "h_fold": h_fold}]
                fitted, theta = self._fit_all(jd, cand_terms)
                ok, why = self._plausible(c, jd, fitted, theta)
                if ok:
                    chosen = (c, t, h_fold, e1)
                    break
                last[c]["reason"] = why
                remaining.remove(c)
            if chosen is None:
                break
            c, t, h_fold, e1 = chosen
            terms.append({"name": c, "h_fold": h_fold, "evidence": t,
                          "gain": 1.0 - t["ssr_ratio"] if step == 0 else
                          (1.0 - t["ssr_ratio"]) * float(current @ current) / float(e_base @ e_base)})
            current = e1
            remaining.remove(c)
        fitted, theta = self._fit_all(jd, terms)
        res.kept = fitted
        res.theta_after = theta
        res.columns_after = [("friction", 4)] + [(t["name"], N_COLUMNS[t["name"]]) for t in fitted]
        res.e_after = current
        res.torque_rms_before_Nm = float(np.sqrt(np.mean(e_before ** 2)))
        res.torque_rms_after_Nm = float(np.sqrt(np.mean(current ** 2)))
        res.whiteness_p_before = whiteness_p(e_before, spacing)
        res.whiteness_p_after = whiteness_p(current, spacing)
        kept_names = {t["name"] for t in fitted}
        for c in tests:
            if c not in last:
                res.candidates[c] = {"p_value": float("nan"), "delta_bic": float("nan"), "kept": False,
                                     "reason": "not testable on this joint (no regressor)"}
                continue
            t = last[c]
            if c in kept_names:
                ev = next(k["evidence"] for k in fitted if k["name"] == c)
                res.candidates[c] = dict(ev, kept=True, reason="kept")
                continue
            reason = t.get("reason")
            if reason is None:
                if t["p_value"] >= self.threshold_:
                    reason = f"p = {t['p_value']:.3g} not below the threshold {self.threshold_:.3g}"
                else:
                    reason = f"BIC does not drop (delta {t['delta_bic']:.1f})"
                if t["ssr_ratio"] >= 1:
                    reason = "does not predict held-out data better than the model without it"
            res.candidates[c] = dict(t, kept=False, reason=reason)
        return res

    # ------------------------------------------------------------------------------------------ params
    def _split(self, res_terms: list[dict], theta: np.ndarray) -> dict:
        """Coefficients by term name."""
        out = {"friction": theta[:4]}
        k = 4
        for t in res_terms:
            n = N_COLUMNS[t["name"]]
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
        if name == "payload" and coef[0] <= 0:
            return False, f"fitted payload mass {coef[0]:.3g} kg is not positive"
        if name == "delay":
            h = next(t["h_all"] for t in terms if t["name"] == "delay")
            if coef[0] <= 0:
                return False, "the torque leads the positions (negative delay)"
            if coef[0] * h > 2 * DELAY_GRID_S[-1]:
                return False, f"fitted delay {coef[0] * h * 1e3:.1f} ms outside the range searched"
        return True, ""

    def effect_params(self, j: int, name: str) -> dict:
        """Parameters of kept effect ``name`` at 0-based joint ``j`` (units in the key names)."""
        res = self.joints_[j]
        c = self._split(res.kept, res.theta_after)
        t = next(t for t in res.kept if t["name"] == name)
        h = t["h_all"]
        fr = c["friction"]
        coef = c[name]
        if name == "stribeck":
            return {"Fs_pos_Nm": float(fr[0] + coef[0]), "Fs_neg_Nm": float(fr[1] + coef[1]),
                    "Fc_pos_Nm": float(fr[0]), "Fc_neg_Nm": float(fr[1]), "vs_rad_s": float(h)}
        if name == "position_ripple":
            a, b = -coef[0], -coef[1]          # y = friction - ripple: the plant's ripple is minus the fit
            return {"amplitude_Nm": float(np.hypot(a, b)), "period_rad": float(h),
                    "phase_rad": float(np.arctan2(b, a) % (2 * np.pi))}
        if name == "payload":
            m = float(coef[0])
            com = coef[1:4] / m - np.array([0.0, 0.0, D7_M]) if m > 0 else np.zeros(3)
            return {"mass_kg": m, "com_m": [float(x) for x in com]}
        if name == "delay":
            return {"delay_s": float(coef[0] * h), "grid_delay_s": float(h), "scale": float(coef[0])}
        if name == "friction_drift":
            jd = self.jd_[j]
            X = friction_columns(jd.qd_rad_s)
            f0 = X @ (fr + coef)                # friction at t = 0
            f1 = X @ coef                        # the part that decays
            frac = -float(f1 @ f0 / max(f0 @ f0, 1e-300))
            return {"fraction": frac, "time_constant_s": float(h),
                    "friction_t0": {"fc_pos_Nm": float(fr[0] + coef[0]), "fc_neg_Nm": float(fr[1] + coef[1]),
                                    "viscous_pos_Nm_s_rad": float(fr[2] + coef[2]),
                                    "viscous_neg_Nm_s_rad": float(fr[3] + coef[3])}}
        if name == "backlash":
            return {"width_rad": float(2 * abs(coef[-1])),
                    "reversal_terms_Nm": [float(x) for x in coef[:-1]],
                    "time_constants_s": list(BACKLASH_TIME_CONSTANTS_S)}
        raise ValueError(name)

    def friction_after(self, j: int) -> dict:
        """Classic friction of 0-based joint ``j`` in the final model (at t = 0 when friction drifts)."""
        res = self.joints_[j]
        c = self._split(res.kept, res.theta_after)
        fr = np.array(c["friction"], float)
        if "friction_drift" in c:
            fr = fr + c["friction_drift"]
        return {"fc_pos_Nm": float(fr[0]), "fc_neg_Nm": float(fr[1]),
                "viscous_pos_Nm_s_rad": float(fr[2]), "viscous_neg_Nm_s_rad": float(fr[3])}

    def friction_before(self, j: int) -> dict:
        fr = self.joints_[j].theta_before
        return {"fc_pos_Nm": float(fr[0]), "fc_neg_Nm": float(fr[1]),
                "viscous_pos_Nm_s_rad": float(fr[2]), "viscous_neg_Nm_s_rad": float(fr[3])}

    def _finalise_effects(self) -> None:
        for j, res in self.joints_.items():
            res.effects = []
            for t in res.kept:
                ev = t["evidence"]
                res.effects.append({"name": t["name"], "params": self.effect_params(j, t["name"]),
                                    "evidence": {"test": TEST_NAME, "p_value": float(ev["p_value"]),
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
                             "savgol_window_samples": sig.window, "sample_rate_hz": 1.0 / sig.dt_s,
                             "samples": sig.n, "resampled": sig.resampled,
                             "decimation": getattr(self, "decimation_", 1)}
        return out


def _num(x):
    if x is None:
        return None
    x = float(x)
    return None if not np.isfinite(x) else x
