"""Identify the WAM's base parameters from measured runs, physically consistent, with their uncertainty.

Method (``InertialIdentification(...).fit(runs)``)
------------------------------------------------------
1. Rows: every run through the diagnosis' filter (:mod:`.data`): sliding (sample, joint) rows of the standard
   regressor (rigid body + armature + classic per-direction friction) and the filtered torque.
2. Weighted least squares on the base regressor (:mod:`.base`): ordinary least squares first, then each
   joint's rows weighted by ``1 / sigma_j`` with ``sigma_j`` the RMS of that joint's residual (per-joint noise:
   the joints' torque noise differs by two orders of magnitude).
3. What the data determine (:func:`.base.identifiability` on the weighted rows): undetermined base
   parameters are reported as such, never as numbers; the fit uses the determined ones plus an independent
   subset of the others (so the determined ones are estimated without bias).
4. Uncertainty: the residuals of filtered signals are correlated in time (the filter's reach and any model
   error), so the covariance is a heteroskedasticity- and autocorrelation-consistent sandwich (Newey-West,
   statsmodels' ``S_hac_simple``) over each run's per-sample scores (the joints of one sample summed: their
   errors are correlated too), with ``nlags`` covering four filter reaches (at least Newey and West's rule).
   95 % intervals are ``+-1.96`` standard errors.
5. A physically consistent estimate: standard parameters ``pi(theta)`` with every link's pseudo-inertia
   positive definite by construction (log-Cholesky, :mod:`.consistency`), armature positive (log) and friction
   levels non-negative (bounds), found by scipy's ``least_squares`` minimising the WLS misfit of the base
   parameters ``(beta(theta) - beta_wls)^T A (beta(theta) - beta_wls)`` (``A`` the weighted information
   matrix) plus a weak prior pulling towards the declared arm (log-Cholesky coordinates: 0.5 on logs,
   0.1 m on lengths; 0.5 on log armature; 5 N m on friction). The prior decides only where the data say
   nothing (undetermined directions, and the split of each base parameter into standard ones); on determined
   directions the data outweigh it by orders of magnitude. Started from the declared arm and from the WLS
   solution projected onto consistent bodies; the better end is kept.
6. The nominal model for comparison: the declared links (datasheet + payload) with friction fitted by WLS on
   the same rows (so that "identified vs nominal" measures the inertial parameters, not friction).
"""

from __future__ import annotations

import logging
import warnings
from contextlib import contextmanager

import numpy as np
import pandas as pd
from statsmodels.stats.sandwich_covariance import S_hac_simple

from wamctl.analysis.identification.base import (
    ARMATURE_SLICE,
    FRICTION_SLICE,
    N_STANDARD,
    base_parameters,
    identifiability,
    split_standard,
    standard_vector,
)
from wamctl.analysis.identification.consistency import PSEUDO_BASIS, consistency_margin, pseudo_inertia
from wamctl.analysis.identification.data import RunRows, run_rows
from wamctl.errors import DataFormatError
from wamctl.model import params as P
from wamctl.model.friction import FrictionModel

log = logging.getLogger(__name__)
N7 = P.N_JOINTS
Z95 = 1.959963984540054
MIN_ROWS = 50
HAC_REACHES = 4.0       # Newey-West lags: this many filter reaches (at least Newey and West's rule)
PRIOR_WEIGHT = 1e-2      # the declared arm as a prior, ten times wider than prior_scale (see there)
PD_MARGIN = 1e-7         # each pseudo-inertia >= this share of the declared one's largest eigenvalue


def prior_scale(pi0: np.ndarray) -> np.ndarray:
    """(105,) scale of each standard parameter around the declared arm: 30 % of its declared magnitude, at
    least 0.1 kg, 0.01 kg m, 1e-3 kg m^2 (inertia, armature), 1 N m / N m s/rad (friction). With PRIOR_WEIGHT the
    prior's standard deviation is ten times this."""
    floors = np.concatenate([np.tile([0.1, 0.01, 0.01, 0.01] + [1e-3] * 6, N7), np.full(N7, 1e-3),
                             np.full(4 * N7, 1.0)])
    return np.maximum(0.3 * np.abs(pi0), floors)


class InertialIdentification:
    """Base parameters of the WAM from measured runs (see the module doc).

    Parameters (keyword-only, stored as given)
    ----------
    dynamics : the declared arm (a WamDynamics: links, armature, payload), the prior; default the datasheet.
    friction : the declared friction (prior where the data say nothing); default Table 4.1.
    row_rate_hz : rate the filtered rows are decimated to.
    alpha : 1 - confidence of the intervals (0.05: 95 %).

    Fitted attributes
    -----------------
    rows_ : list of :class:`.data.RunRows`. base_ : the BaseParameters. identifiability_ : on the weighted rows.
    sigma_Nm_ : (7,) per-joint residual RMS used as weights (NaN: joint without rows).
    beta_wls_, se_ : (nb,) WLS estimate and HAC standard errors (NaN where undetermined).
    cov_ : (nb, nb) HAC covariance (NaN rows/columns where undetermined).
    beta_ : (nb,) the consistent estimate's base parameters. pi_ : (105,) its standard parameters.
    links_ : LinkParameters, friction_ : FrictionModel of ``pi_``. margin_ : (7,) pseudo-inertia margins.
    pi_nominal_ : (105,) the nominal model (declared links, friction fitted on the rows).
    pi_declared_ : (105,) the declared arm and friction. hac_lags_ : lags of the Newey-West sandwich.
    """

    def __init__(self, *, dynamics=None, friction: FrictionModel | None = None, row_rate_hz: float = 100.0,
                 alpha: float = 0.05, window_s: float | str | None = "auto", gauss_s: float | None = None):
        self.dynamics = dynamics
        self.friction = friction
        self.row_rate_hz = row_rate_hz
        self.alpha = alpha
        self.window_s = window_s
        self.gauss_s = gauss_s

    # ------------------------------------------------------------------------------------------- fit
    def fit(self, runs) -> InertialIdentification:
        """Fit on measured runs (:class:`wamctl.runs.measured.RunData`, or ready :class:`RunRows`)."""
        from wamctl.model.dynamics import WamDynamics

        dyn = self.dynamics if self.dynamics is not None else WamDynamics()
        friction = self.friction if self.friction is not None else FrictionModel.table_4_1()
        self.dynamics_ = dyn
        self.rows_ = [r if isinstance(r, RunRows) else run_rows(r, dyn, self.row_rate_hz, self.window_s, self.gauss_s)
                      for r in runs]
        Y, y, jrow, groups = self._stack(self.rows_)
        Zs = np.vstack([rr.instruments() for rr in self.rows_]) if self.rows_ else np.zeros((0, N_STANDARD))
        self.instrumented_ = any(rr.reference_tracks for rr in self.rows_)
        if len(y) < MIN_ROWS:
            raise DataFormatError(f"only {len(y)} usable (sliding) rows in the data; the identification needs "
                                  f"at least {MIN_ROWS}: did any joint move?")
        self.base_ = base = base_parameters()
        self.pi_declared_ = standard_vector(dyn, friction)
        with _single_threaded_blas():
            Xb = base.regressor(Y)
            self.sigma_Nm_ = self._noise(Xb, y, jrow)
            w = 1.0 / self.sigma_Nm_[jrow]
            Xw, yw = Xb * w[:, None], y * w
            self.identifiability_ = identifiability(Xw, base)
            self._wls(Xw, yw, groups, base.regressor(Zs) * w[:, None] if self.instrumented_ else None)
            self._consistent()
            self.pi_nominal_ = self._nominal(Y, y, w)
        self.n_rows_ = len(y)
        return self

    @staticmethod
    def _stack(rows: list[RunRows]):
        Ys, ys, js, gs = [], [], [], []
        for r_i, rr in enumerate(rows):
            Y, y, j, k = rr.stacked()
            Ys.append(Y)
            ys.append(y)
            js.append(j)
            gs.append(np.column_stack([np.full(len(k), r_i), k]))
        if not Ys:
            return np.zeros((0, N_STANDARD)), np.zeros(0), np.zeros(0, int), np.zeros((0, 2), int)
        return np.vstack(Ys), np.concatenate(ys), np.concatenate(js), np.vstack(gs)

    @staticmethod
    def _noise(Xb, y, jrow) -> np.ndarray:
        """Per-joint residual RMS of the ordinary least squares (the WLS weights)."""
        beta = np.linalg.lstsq(Xb, y, rcond=None)[0]
        e = y - Xb @ beta
        sig = np.full(N7, np.nan)
        for j in range(N7):
            ej = e[jrow == j]
            if len(ej):
                sig[j] = max(float(np.sqrt(np.mean(ej ** 2))), 1e-6)
        return sig

    def _wls(self, Xw, yw, groups, Zw=None) -> None:
        """WLS on the determined columns plus an independent subset of the undetermined ones; HAC covariance."""
        nb = Xw.shape[1]
        ident = self.identifiability_
        D = np.flatnonzero(ident.identified)
        U = np.flatnonzero(~ident.identified)
        cols = np.concatenate([D, _independent_subset(Xw[:, U], U)]) if len(U) else D
        Xc = Xw[:, cols]
        if Zw is None:
            gamma = np.linalg.lstsq(Xc, yw, rcond=None)[0]
            Zc = Xc
        else:
            Zc = Zw[:, cols]
            gamma = np.linalg.solve(Zc.T @ Xc, Zc.T @ yw)
        e = yw - Xc @ gamma
        H_inv = np.linalg.pinv(Zc.T @ Xc)
        scores = Zc * e[:, None]
        reach_rows = max(rr.reach_s / rr.dt_s for rr in self.rows_)
        S = np.zeros((len(cols), len(cols)))
        lags = []
        for r_i in np.unique(groups[:, 0]):
            sel = groups[:, 0] == r_i
            k = groups[sel, 1]
            per_sample = np.zeros((k.max() + 1, len(cols)))
            np.add.at(per_sample, k, scores[sel])
            per_sample = per_sample[np.unique(k)]
            n = len(per_sample)
            rule = int(np.floor(4 * (n / 100.0) ** (2.0 / 9.0)))             # Newey and West's
            nlags = min(n - 1, max(rule, int(np.ceil(HAC_REACHES * reach_rows))))
            lags.append(nlags)
            S += S_hac_simple(per_sample, nlags)
        cov_c = H_inv @ S @ H_inv.T
        self.hac_lags_ = lags
        self.beta_wls_ = np.full(nb, np.nan)
        self.cov_ = np.full((nb, nb), np.nan)
        nD = len(D)
        self.beta_wls_[D] = gamma[:nD]
        self.cov_[np.ix_(D, D)] = cov_c[:nD, :nD]
        self.se_ = np.sqrt(np.diag(self.cov_))
        self._beta_any = np.linalg.lstsq(Xw, yw, rcond=None)[0]      # any solution: the same fitted torque
        self._beta_any[cols] = gamma
        self.residual_rms_wls_ = float(np.sqrt(np.mean(e ** 2)))

    # ------------------------------------------------------------------------------------------- consistent
    def _consistent(self) -> None:
        """The physically consistent estimate (see the module doc, step 5) and its posterior covariance."""
        import cvxpy as cp

        base = self.base_
        K = base.matrix
        D = np.flatnonzero(self.identified_)
        C = self.cov_[np.ix_(D, D)]
        ev, V = np.linalg.eigh(0.5 * (C + C.T))
        ev = np.maximum(ev, ev.max() * 1e-14)
        W = (V / np.sqrt(ev)).T                  # whitening: W (beta_D - beta_hat_D) ~ N(0, 1)
        pi0 = self.pi_declared_
        s = prior_scale(pi0)
        Rs = (W @ K[D]) * s                      # in units of the prior: delta = (pi - pi0) / s
        r0 = W @ (K[D] @ pi0 - self.beta_wls_[D])
        # the prior: weak (PRIOR_WEIGHT) along the standard directions that move a base parameter, full along
        # those that move none (they only split the base parameters into links: the declared arm decides)
        _, sv, Vt = np.linalg.svd(K * s, full_matrices=True)
        r = int(np.sum(sv > 1e-10 * sv[0]))
        Pw = np.vstack([np.sqrt(PRIOR_WEIGHT) * Vt[:r], Vt[r:]])     # prior precision = Pw^T Pw
        norm = np.sqrt(max(float(np.sum(r0 ** 2)), 1.0))               # objective of order one for the solver
        delta = cp.Variable(N_STANDARD)
        pi = pi0 + cp.multiply(s, delta)
        objective = (cp.sum_squares(Rs @ delta + r0) + cp.sum_squares(Pw @ delta)) / norm ** 2
        cons = [pi[ARMATURE_SLICE] >= 0, pi[FRICTION_SLICE] >= 0]
        for i in range(N7):
            eps = PD_MARGIN * np.linalg.eigvalsh(pseudo_inertia(pi0[10 * i:10 * i + 10]))[-1]
            J = sum(pi[10 * i + k] * PSEUDO_BASIS[k] for k in range(10))
            cons.append(J - eps * np.eye(4) >> 0)
        prob = cp.Problem(cp.Minimize(objective), cons)
        try:
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                prob.solve(solver=cp.CLARABEL)
        except cp.error.SolverError as exc:
            raise DataFormatError(f"the physically consistent fit failed: {exc}") from None
        for w in caught:
            log.info("consistent fit: %s", w.message)
        if prob.status not in ("optimal", "optimal_inaccurate") or delta.value is None:
            raise DataFormatError(f"the physically consistent fit did not converge ({prob.status})")
        self.opt_ = {"solver": "clarabel", "status": prob.status, "objective": float(prob.value * norm ** 2)}
        self.pi_ = pi0 + s * delta.value
        self.pi_[ARMATURE_SLICE] = np.maximum(self.pi_[ARMATURE_SLICE], 0.0)
        self.pi_[FRICTION_SLICE] = np.maximum(self.pi_[FRICTION_SLICE], 0.0)
        self.beta_ = base.of(self.pi_)
        # posterior covariance (Gaussian, constraints inactive): precision = data + prior, in delta units
        P_inv = np.linalg.inv(Rs.T @ Rs + Pw.T @ Pw)
        Ks = K * s
        self.cov_post_ = Ks @ P_inv @ Ks.T
        self.se_post_ = np.sqrt(np.diag(self.cov_post_))
        with np.errstate(invalid="ignore", divide="ignore"):
            share = (self.se_post_ / self.se_) ** 2
        self.data_share_ = np.where(self.identified_, 1.0 - np.clip(np.nan_to_num(share, nan=1.0), 0, 1), 0.0)
        from wamctl.model.dynamics import links_from_standard

        inertial, armature, self.friction_ = split_standard(self.pi_)
        self.links_ = links_from_standard(inertial, armature)
        self.margin_ = consistency_margin(inertial)

    def _nominal(self, Y, y, w) -> np.ndarray:
        """The declared rigid body with friction fitted by WLS on the rows (joints without rows keep theirs)."""
        pi = self.pi_declared_.copy()
        fcols = np.arange(FRICTION_SLICE.start, FRICTION_SLICE.stop)
        rest = np.setdiff1d(np.arange(N_STANDARD), fcols)
        r = (y - Y[:, rest] @ pi[rest]) * w
        Xf = Y[:, fcols] * w[:, None]
        used = np.abs(Xf).sum(axis=0) > 0
        f = np.linalg.lstsq(Xf[:, used], r, rcond=None)[0]
        pi[fcols[used]] = np.maximum(f, 0.0)
        return pi

    # ------------------------------------------------------------------------------------------- use
    @property
    def identified_(self) -> np.ndarray:
        """(nb,) bool: the base parameters the data determine."""
        return self.identifiability_.identified

    def intervals(self, which: str = "identified") -> tuple[np.ndarray, np.ndarray]:
        """(low, high) ``1 - alpha`` intervals of the base parameters: of the consistent estimate with its
        posterior standard errors (``identified``), or of the data-only estimate (``wls``); NaN where the data
        do not determine the parameter."""
        from scipy.stats import norm

        b, se = (self.beta_, self.se_post_) if which == "identified" else (self.beta_wls_, self.se_)
        z = norm.ppf(1 - self.alpha / 2)
        se = np.where(self.identified_, se, np.nan)
        return b - z * se, b + z * se

    def predict(self, rows: RunRows, which: str = "identified", mask: np.ndarray | None = None) -> tuple:
        """Torque of the ``identified``, ``nominal`` (declared links, fitted friction) or ``declared`` model at
        a run's usable rows: ``(predicted (r,), measured (r,), joint (r,), sample (r,))``."""
        pi = {"identified": self.pi_, "nominal": self.pi_nominal_, "declared": self.pi_declared_}[which]
        Y, y, j, k = rows.stacked(mask)
        return Y @ pi, y, j, k

    def rms_by_joint(self, rows: list[RunRows], which: str = "identified", pi: np.ndarray | None = None,
                     masks: list | None = None) -> np.ndarray:
        """(7,) RMS of measured - predicted torque per joint over ``rows`` (NaN: no rows for the joint);
        ``pi`` overrides the model (e.g. the truth, for a noise floor)."""
        sq, cnt = np.zeros(N7), np.zeros(N7)
        for i, rr in enumerate(rows):
            Y, y, j, _ = rr.stacked(None if masks is None else masks[i])
            p = Y @ (pi if pi is not None else
                     {"identified": self.pi_, "nominal": self.pi_nominal_, "declared": self.pi_declared_}[which])
            np.add.at(sq, j, (y - p) ** 2)
            np.add.at(cnt, j, 1)
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(cnt > 0, np.sqrt(sq / np.maximum(cnt, 1)), np.nan)

    def status(self) -> np.ndarray:
        """(nb,) per base parameter: ``identified``, ``weak`` (the data give less than half of the posterior's
        information: the declared arm weighs more) or ``not identified`` (the data do not determine it)."""
        return np.where(~self.identified_, "not identified",
                        np.where(self.data_share_ >= 0.5, "identified", "weak"))

    def table(self) -> pd.DataFrame:
        """One row per base parameter: expression, unit, declared value, consistent estimate with its posterior
        standard error and interval, the data-only (IV) estimate and its standard error, how far the estimate
        moved from the declared value (in standard errors), the data's share of the information, status.
        Numbers are NaN where the data do not determine the parameter."""
        base = self.base_
        beta_decl = base.of(self.pi_declared_)
        lo, hi = self.intervals()
        ident = self.identified_
        with np.errstate(invalid="ignore", divide="ignore"):
            moved = (self.beta_ - beta_decl) / self.se_post_
        return pd.DataFrame({
            "parameter": base.names, "unit": base.units,
            "expression": [base.expression(k) for k in range(base.n_base)], "declared": beta_decl,
            "estimate": np.where(ident, self.beta_, np.nan), "se": np.where(ident, self.se_post_, np.nan),
            "ci_low": lo, "ci_high": hi, "moved_se": np.where(ident, moved, np.nan),
            "data_only": np.where(ident, self.beta_wls_, np.nan), "data_only_se": np.where(ident, self.se_, np.nan),
            "data_share": np.where(ident, self.data_share_, np.nan), "status": self.status()})

    def to_dict(self) -> dict:
        return {"n_rows": int(self.n_rows_), "sigma_Nm": _floats(self.sigma_Nm_),
                "identifiability": self.identifiability_.to_dict(), "hac_lags": [int(x) for x in self.hac_lags_],
                "instruments": "reference" if self.instrumented_ else "none (least squares)",
                "consistent": bool((self.margin_ > 0).all()), "pseudo_inertia_margin": _floats(self.margin_),
                "optimiser": self.opt_, "links": self.links_.to_mapping(),
                "base": self.table().replace({np.nan: None}).to_dict("records")}


def _floats(a) -> list:
    return [None if not np.isfinite(v) else float(v) for v in np.asarray(a, float)]


def _independent_subset(X: np.ndarray, idx: np.ndarray, rel_tol: float = 1e-8) -> np.ndarray:
    """The columns ``idx`` of which ``X`` (m, len(idx)) has an independent subset (pivoted QR, equilibrated)."""
    import scipy.linalg

    norms = np.linalg.norm(X, axis=0)
    ok = norms > 1e-10 * max(norms.max(), 1e-300)
    if not ok.any():
        return np.zeros(0, int)
    Xs = X[:, ok] / norms[ok]
    _, R, piv = scipy.linalg.qr(Xs, mode="economic", pivoting=True)
    d = np.abs(np.diag(R))
    r = int(np.sum(d > rel_tol * d[0]))
    return np.sort(idx[ok][piv[:r]])


@contextmanager
def _single_threaded_blas():
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:
        yield
        return
    with threadpool_limits(limits=1, user_api="blas"):
        yield
