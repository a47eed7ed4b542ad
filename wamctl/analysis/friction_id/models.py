"""Friction models of the identification as scikit-learn style estimators (``fit(map) -> self``, fitted
attributes end in ``_``): :class:`ClassicFriction` (thesis eq. 4.1, per direction or symmetric) and
:class:`StribeckFriction` (eq. 2.8), least squares with an optional robust loss and parameter standard errors.

The model formulas are the ones of :mod:`wamctl.model.friction` (the classic regressor,
:func:`~wamctl.model.friction.classic_friction_columns`, and the Stribeck shape,
:func:`~wamctl.model.friction.stribeck_decay`): what is identified here is what the simulator runs.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pandas as pd
from scipy.optimize import least_squares

from wamctl.model.friction import classic_friction_columns, stribeck_decay

MODEL_NAMES = ("classic", "classic_symmetric", "stribeck")

# classic_friction_columns gives [fc_pos, fc_neg, b_pos, b_neg]; the estimator keeps Table 4.1's order
_TABLE_4_1_ORDER = [0, 2, 1, 3]   # -> fc_pos, sigma2_pos, fc_neg, sigma2_neg


def as_vf(data) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(velocity, friction, sigma) arrays from a map DataFrame (accepted rows; ``sigma_Nm`` if present, else
    ones) or a ``(v, F)`` / ``(v, F, sigma)`` tuple."""
    if isinstance(data, pd.DataFrame):
        d = data[data["accepted"].astype(bool)] if "accepted" in data else data
        s = d["sigma_Nm"].to_numpy(float) if "sigma_Nm" in d else np.ones(len(d))
        return d["velocity_rad_s"].to_numpy(float), d["friction_Nm"].to_numpy(float), s
    v, f, *rest = data
    v, f = np.asarray(v, float), np.asarray(f, float)
    s = np.asarray(rest[0], float) if rest and rest[0] is not None else np.ones(len(v))
    return v, f, s


@dataclass
class _Solution:
    """A least-squares solution in the shape of scipy's result: ``x``, ``jac`` (of the weighted residuals)."""

    x: np.ndarray
    jac: np.ndarray
    cost: float = 0.0


class _LsqFriction:
    """Base of the friction estimators: a least-squares fit of ``F(v)`` with parameter standard errors."""

    name = "base"
    param_names: tuple[str, ...] = ()

    def __init__(self, loss: str = "linear", f_scale: float | None = None):
        self.loss = loss
        self.f_scale = f_scale

    # subclasses: _predict(p, v), _jac(p, v) and fit(data)
    def _predict(self, p, v):  # pragma: no cover - abstract
        raise NotImplementedError

    @property
    def n_params(self) -> int:
        return len(self.param_names)

    def _check(self, v, f, s):
        if len(v) != len(f) or len(s) != len(v) or not np.all(np.isfinite(v)) or not np.all(np.isfinite(f)):
            raise ValueError("velocity and friction must be finite arrays of one length")
        if not np.all(np.isfinite(s)) or (s <= 0).any():
            raise ValueError("sigma must be positive and finite")
        for side, m in (("positive", v > 0), ("negative", v < 0)):
            if m.sum() < self._min_per_side:
                raise ValueError(f"{self.name}: needs {self._min_per_side} points at {side} velocity, "
                                 f"got {int(m.sum())}")

    _min_per_side = 2

    def _jac(self, p, v):  # pragma: no cover - abstract
        """(n, k) derivative of F(v) with respect to the parameters."""
        raise NotImplementedError

    def _solve(self, v, f, s, x0, bounds):
        """Minimise sum(rho(((F(v) - f) / s)^2)) from ``x0`` (analytic Jacobian)."""
        scale = self.f_scale
        if self.loss != "linear" and scale is None:
            z0 = (self._predict(np.asarray(x0, float), v) - f) / s
            scale = max(1.4826 * float(np.median(np.abs(z0 - np.median(z0)))), 1e-9)
        return least_squares(lambda p: (self._predict(p, v) - f) / s, x0,
                             jac=lambda p: self._jac(p, v) / s[:, None], bounds=bounds, loss=self.loss,
                             f_scale=scale if scale else 1.0, method="trf", x_scale="jac", max_nfev=500)

    def _finish(self, res, v, f, s):
        """Fitted attributes; the covariance scales (J^T J)^-1 by the reduced chi-square (the weights are
        relative, as ``scipy.optimize.curve_fit`` with ``absolute_sigma=False``)."""
        self.params_ = np.asarray(res.x, float)
        r = self._predict(self.params_, v) - f
        z = r / s
        self.residuals_ = r
        self.n_points_ = len(v)
        dof = max(len(v) - self.n_params, 1)
        self.chi2_ = float(np.sum(z ** 2))
        scale2 = self.chi2_ / dof
        jac = np.asarray(res.jac, float)
        jtj = jac.T @ jac
        self.cov_ = np.linalg.pinv(jtj) * scale2
        self.params_std_ = np.sqrt(np.clip(np.diag(self.cov_), 0, None))
        if np.linalg.matrix_rank(jac) < self.n_params:   # a parameter the data do not determine
            self.params_std_ = np.where(np.diag(jtj) > 1e-12 * max(np.diag(jtj).max(), 1e-300),
                                        self.params_std_, np.inf)
        self.rss_ = float(np.sum(r ** 2))
        self.sigma_ = float(np.sqrt(self.rss_ / dof))
        return self

    def _add_point_errors(self, jac, s, se_Nm=None, shift_Nm=None) -> None:
        """What the scatter of the points about the fit cannot show, carried into the standard errors. The fit
        moves the parameters by ``L df`` for a change ``df`` of the points (``L = J^+ / s``, ``J`` its weighted
        Jacobian), so:

        * ``se_Nm`` (n,), each point's own standard error (a stage's batch means): the parameters' standard
          error is at least ``sqrt(diag(L diag(se^2) L^T))`` (``params_std_points_``). The weights' relative
          floor and the reduced chi-square scale the fit's to the scatter about the line, which a point of high
          leverage hides: the fastest stage of a sweep has the fewest samples and the largest error and carries
          the viscous slope, and the line passes close to it whatever its error.
        * ``shift_Nm`` (n,), each point's change for one standard error of an error every point shares (the
          map's ``timing_shift_Nm``: the rigid body's timing, :data:`wamctl.analysis.friction_id.velocity_map.
          TIMING_SE_PERIODS`): ``d = L shift`` is added in quadrature (``params_std_timing_``). A shift in
          proportion to the velocity is a viscous coefficient: no scatter shows it.

        ``cov_`` keeps the fit's correlations with the standard errors so found, plus ``d d^T``."""
        n = len(s)
        se = np.zeros(n) if se_Nm is None else np.asarray(se_Nm, float)
        shift = np.zeros(n) if shift_Nm is None else np.asarray(shift_Nm, float)
        for name, x in (("standard errors", se), ("systematic shift", shift)):
            if x.shape != (n,) or not np.isfinite(x).all():
                raise ValueError(f"the points' {name} must be a finite array of their length")
        lin = np.linalg.pinv(np.asarray(jac, float)) / s[None, :]
        self.params_std_points_ = np.sqrt((lin ** 2) @ se ** 2)
        d = lin @ shift
        self.params_std_timing_ = np.abs(d)
        sd0 = np.sqrt(np.clip(np.diag(self.cov_), 0, None))
        stat = np.fmax(self.params_std_, self.params_std_points_)
        with np.errstate(invalid="ignore", divide="ignore"):
            corr = np.where(np.outer(sd0, sd0) > 0, self.cov_ / np.outer(sd0, sd0), 0.0)
        np.fill_diagonal(corr, 1.0)
        scale = np.where(np.isfinite(stat), stat, sd0)
        self.cov_ = corr * np.outer(scale, scale) + np.outer(d, d)
        self.params_std_ = np.sqrt(stat ** 2 + d ** 2)

    def predict(self, v) -> np.ndarray:
        """F(v), N m, same shape as ``v``."""
        return self._predict(self.params_, np.asarray(v, float))

    def information_criteria(self, known_sigma: bool = True) -> dict:
        """In-sample Gaussian AIC and BIC: with the points' sigma known, ``chi2 + 2k`` and ``chi2 + k ln n``;
        otherwise (sigma estimated from the residuals) ``n ln(chi2 / n) + 2k`` and ``+ k ln n``."""
        n, k = self.n_points_, self.n_params
        ll = self.chi2_ if known_sigma else n * math.log(max(self.chi2_ / n, 1e-300))
        return {"aic": ll + 2 * k, "bic": ll + k * math.log(n)}

    def params(self) -> dict:
        return {n: float(x) for n, x in zip(self.param_names, self.params_)}

    def params_std(self) -> dict:
        return {n: float(x) for n, x in zip(self.param_names, self.params_std_)}

    def to_dict(self) -> dict:
        return {"model": self.name, "loss": self.loss, "params": self.params(), "std": self.params_std(),
                "n_points": self.n_points_, "rmse_Nm": math.sqrt(self.rss_ / self.n_points_),
                **self.information_criteria()}



def _classic_joint_params(est) -> dict:
    """The classic part of a fit in friction-model-file terms (magnitudes; viscous as fitted, clipped at 0)."""
    return {"fc_pos_Nm": max(est.fc_pos_, 0.0), "fc_neg_Nm": max(est.fc_neg_, 0.0),
            "viscous_pos_Nm_s_rad": max(est.sigma2_pos_, 0.0),
            "viscous_neg_Nm_s_rad": max(est.sigma2_neg_, 0.0)}


class ClassicFriction(_LsqFriction):
    """Classic model (thesis eq. 4.1) per direction, Table 4.1 layout:
    ``F = fc_pos + sigma2_pos v`` (v > 0), ``F = -fc_neg + sigma2_neg v`` (v < 0); with
    ``symmetric=True`` one ``fc`` and one ``sigma2``.

    Fitted attributes: ``params_`` (fc_pos, sigma2_pos, fc_neg, sigma2_neg) or (fc, sigma2), ``params_std_``,
    ``cov_``, ``residuals_``, ``sigma_``; the Table 4.1 view ``fc_pos_``, ``fc_neg_``, ``sigma2_pos_``,
    ``sigma2_neg_`` and their ``*_std_``.
    """

    def __init__(self, symmetric: bool = False, loss: str = "linear", f_scale: float | None = None):
        super().__init__(loss, f_scale)
        self.symmetric = symmetric
        self.name = "classic_symmetric" if symmetric else "classic"
        self.param_names = ("fc", "sigma2") if symmetric else ("fc_pos", "sigma2_pos", "fc_neg", "sigma2_neg")
        self._min_per_side = 1 if symmetric else 2

    def _design(self, v):
        """(n, k) design matrix: the classic model is linear, F = A(v) p."""
        if self.symmetric:
            return np.column_stack([np.sign(v), v])
        # C order, as the matrix products of the fit expect (bit for bit the same sums)
        return np.ascontiguousarray(classic_friction_columns(v)[:, _TABLE_4_1_ORDER])

    def _predict(self, p, v):
        return self._design(np.asarray(v, float)) @ np.asarray(p, float)

    def _jac(self, p, v):
        return self._design(v)

    def _estimate(self, v, f, s):
        """The least-squares solution on the points ``v, f, s``."""
        # linear least squares; it starts the fit when the loss is robust
        a = self._design(v) / s[:, None]
        x0 = np.linalg.lstsq(a, f / s, rcond=None)[0]
        if self.loss == "linear":
            return _Solution(x0, a)
        return self._solve(v, f, s, x0, (-np.inf, np.inf))

    def fit(self, data, se_Nm=None, shift_Nm=None) -> ClassicFriction:
        """Fit on a map (DataFrame with ``velocity_rad_s``, ``friction_Nm`` [, ``sigma_Nm``, ``accepted``]) or
        a ``(v, F[, sigma])`` tuple of (n,) arrays; returns self.

        ``params_std_`` is the larger of the fit's standard error (``params_std_fit_``, the Jacobian scaled by the
        reduced chi-square: the points' scatter) and the jackknife's over the points (``params_std_jackknife_``,
        each point left out in turn): it says when one stage is off by more than the scatter (the fastest stage
        of a sweep carries the viscous slope; a few mN m off there put the viscous coefficient 6-14 of the fit's
        standard errors from the truth, on our simulator and on another generator); at least what the points' own
        standard errors ``se_Nm`` carry through the fit, and with ``shift_Nm`` (the map's ``timing_shift_Nm``)
        the error all points share added in quadrature (:meth:`_add_point_errors`)."""
        v, f, s = as_vf(data)
        self._check(v, f, s)
        sol = self._estimate(v, f, s)
        self._finish(sol, v, f, s)
        self.params_std_fit_ = self.params_std_.copy()
        self.params_std_jackknife_ = self._jackknife_std(v, f, s)
        self.params_std_ = np.fmax(self.params_std_fit_, self.params_std_jackknife_)
        self._add_point_errors(sol.jac, s, se_Nm, shift_Nm)
        p, s = self.params_, self.params_std_
        if self.symmetric:
            self.fc_pos_ = self.fc_neg_ = float(p[0])
            self.sigma2_pos_ = self.sigma2_neg_ = float(p[1])
            self.fc_pos_std_ = self.fc_neg_std_ = float(s[0])
            self.sigma2_pos_std_ = self.sigma2_neg_std_ = float(s[1])
        else:
            self.fc_pos_, self.sigma2_pos_, self.fc_neg_, self.sigma2_neg_ = map(float, p)
            self.fc_pos_std_, self.sigma2_pos_std_, self.fc_neg_std_, self.sigma2_neg_std_ = map(float, s)
        return self

    def _jackknife_std(self, v, f, s) -> np.ndarray:
        """(k,) jackknife standard error of the parameters over the points, each left out in turn. The per-direction
        model's two sides are separate fits: a side's parameters take the replicates that left out one of its own
        points. A replicate is skipped when the side it leaves could not be fitted any more; NaN for a parameter
        with fewer than 3 replicates."""
        side_of = np.sign(v)
        reps, dropped = [], []
        for i in range(len(v)):
            keep = np.arange(len(v)) != i
            if (keep & (side_of == side_of[i])).sum() < self._min_per_side or keep.sum() <= self.n_params:
                continue
            reps.append(self._estimate(v[keep], f[keep], s[keep]).x)
            dropped.append(side_of[i])
        reps, dropped = np.asarray(reps).reshape(-1, self.n_params), np.asarray(dropped)
        out = np.full(self.n_params, np.nan)
        for k in range(self.n_params):
            use = np.ones(len(reps), bool) if self.symmetric else dropped == (1.0 if k < 2 else -1.0)
            r = reps[use, k]
            if len(r) >= 3:
                out[k] = np.sqrt((len(r) - 1) / len(r) * np.sum((r - r.mean()) ** 2))
        return out

    def joint_params(self) -> dict:
        """This fit in friction-model-file terms (magnitudes; viscous as fitted, clipped at 0)."""
        return _classic_joint_params(self)


def _stribeck_linear_columns(v: np.ndarray, e: np.ndarray) -> list[np.ndarray]:
    """The columns of (fc, dfs, sigma2) per direction, positive then negative, given the Stribeck shape
    ``e = exp(-|v / vs|^delta)``: for fixed vs and delta the Stribeck model is linear in them."""
    pos, neg = (v > 0).astype(float), (v < 0).astype(float)
    return [pos, pos * e, pos * v, -neg, -neg * e, neg * v]


def _level_sum_std(cov: np.ndarray, sd: np.ndarray, i: int, k: int) -> float:
    """Standard error of ``p[i] + p[k]`` (the breakaway level fc + dfs) by the delta method; inf when either
    parameter is undetermined."""
    if not (np.isfinite(sd[i]) and np.isfinite(sd[k])):
        return float("inf")
    return float(np.sqrt(max(cov[i, i] + cov[k, k] + 2 * cov[i, k], 0.0)))


class StribeckFriction(_LsqFriction):
    """Stribeck model (thesis eq. 2.8) per direction with shared ``vs`` and ``delta``:
    ``F = s (fc_s + (fs_s - fc_s) exp(-|v / vs|^delta)) + sigma2_s v`` with s the sign of v.

    The breakaway level is at least the Coulomb level (``fs = fc + dfs``, ``dfs >= 0``: the Stribeck effect
    is friction rising towards rest); ``vs`` lies between a fifth of the slowest and half the fastest speed
    measured (beyond the data it would only bend the viscous line); ``delta`` in [0.5, 4] (``fit_delta=False``
    keeps ``delta``). Non-linear least squares started from a (vs, delta) grid.

    Fitted attributes as :class:`ClassicFriction`, plus ``fs_pos_``, ``fs_neg_``, ``vs_``, ``delta_`` and
    their ``*_std_`` (``fs`` by the delta method).
    """

    name = "stribeck"

    def __init__(self, loss: str = "linear", f_scale: float | None = None, fit_delta: bool = True,
                 delta: float = 2.0):
        super().__init__(loss, f_scale)
        self.fit_delta = fit_delta
        self.delta = delta
        self.param_names = ("fc_pos", "dfs_pos", "sigma2_pos", "fc_neg", "dfs_neg", "sigma2_neg", "vs") + \
            (("delta",) if fit_delta else ())
        self._min_per_side = 3

    def _unpack(self, p):
        d = p[7] if self.fit_delta else self.delta
        return p[0], p[1], p[2], p[3], p[4], p[5], p[6], d

    def _predict(self, p, v):
        fcp, dfp, bp, fcn, dfn, bn, vs, d = self._unpack(p)
        e = stribeck_decay(v, vs, d)
        return np.where(v > 0, fcp + dfp * e + bp * v, np.where(v < 0, -(fcn + dfn * e) + bn * v, 0.0))

    def _jac(self, p, v):
        fcp, dfp, bp, fcn, dfn, bn, vs, d = self._unpack(p)
        pos, neg = (v > 0).astype(float), (v < 0).astype(float)
        e = stribeck_decay(v, vs, d)
        x = np.abs(v) / vs
        xd = x ** d
        de_dvs = e * d * xd / vs
        de_dd = -e * xd * np.log(np.where(x > 0, x, 1.0))
        df = pos * dfp - neg * dfn          # the signed level of the Stribeck term
        cols = _stribeck_linear_columns(v, e) + [df * de_dvs]
        if self.fit_delta:
            cols.append(df * de_dd)
        return np.column_stack(cols)

    def _linear_part(self, v, f, s, vs, d):
        """Given vs and delta the model is linear in (fc, dfs, sigma2) per direction: the least-squares
        solution (levels clipped at 0) and its weighted cost (variable projection)."""
        a = np.column_stack(_stribeck_linear_columns(v, stribeck_decay(v, vs, d))) / s[:, None]
        x = np.linalg.lstsq(a, f / s, rcond=None)[0]
        x[[0, 1, 3, 4]] = np.maximum(x[[0, 1, 3, 4]], 0.0)
        r = a @ x - f / s
        return x, float(r @ r)

    def _bounds(self, v):
        """(lower, upper) bounds of the parameters; vs within the measured speeds (see the class)."""
        vmin = max(np.abs(v[v != 0]).min(), 1e-4)
        vmax = 0.5 * min(np.abs(v[v > 0]).max(), np.abs(v[v < 0]).max())
        vs_lo, vs_hi = 0.2 * vmin, max(vmax, 2 * vmin)
        lo = [0, 0, -np.inf, 0, 0, -np.inf, vs_lo] + ([0.5] if self.fit_delta else [])
        hi = [np.inf, np.inf, np.inf, np.inf, np.inf, np.inf, vs_hi] + ([4.0] if self.fit_delta else [])
        return lo, hi

    def fit(self, data, se_Nm=None, shift_Nm=None) -> StribeckFriction:
        """As :meth:`ClassicFriction.fit` (standard errors: the fit's, at least the points' ``se_Nm`` carried
        through it, with ``shift_Nm``'s shared error; no jackknife).
        Starts from the best point of a (vs, delta) grid where the rest of the parameters are solved linearly,
        then refines all of them together."""
        v, f, s = as_vf(data)
        self._check(v, f, s)
        lo, hi = self._bounds(v)
        vs_lo, vs_hi = lo[6], hi[6]
        deltas = (0.5, 1.0, 1.5, 2.0, 3.0, 4.0) if self.fit_delta else (self.delta,)
        grid = [(self._linear_part(v, f, s, vs, d), vs, d)
                for vs in np.geomspace(vs_lo * 1.01, vs_hi * 0.99, 24) for d in deltas]
        starts = sorted(grid, key=lambda g: g[0][1])[:2]
        best = None
        for (x_lin, _), vs0, d0 in starts:
            x0 = np.concatenate([x_lin, [vs0], [d0] if self.fit_delta else []])
            x0 = np.clip(x0, np.array(lo, float) + 1e-12, np.array(hi, float) - 1e-12)
            try:
                res = self._solve(v, f, s, x0, (lo, hi))
            except (ValueError, np.linalg.LinAlgError):
                continue
            if best is None or res.cost < best.cost:
                best = res
        if best is None:
            raise ValueError("stribeck: the fit did not converge")
        self._finish(best, v, f, s)
        self._add_point_errors(best.jac, s, se_Nm, shift_Nm)
        p, sd, cov = self.params_, self.params_std_, self.cov_
        self.fc_pos_, self.sigma2_pos_, self.fc_neg_, self.sigma2_neg_, self.vs_ = map(float, p[[0, 2, 3, 5, 6]])
        self.fs_pos_, self.fs_neg_ = float(p[0] + p[1]), float(p[3] + p[4])
        (self.fc_pos_std_, self.sigma2_pos_std_, self.fc_neg_std_, self.sigma2_neg_std_,
         self.vs_std_) = map(float, sd[[0, 2, 3, 5, 6]])
        self.fs_pos_std_ = _level_sum_std(cov, sd, 0, 1)
        self.fs_neg_std_ = _level_sum_std(cov, sd, 3, 4)
        self.delta_ = float(p[7]) if self.fit_delta else float(self.delta)
        self.delta_std_ = float(sd[7]) if self.fit_delta else 0.0
        return self

    def params(self) -> dict:
        out = super().params()
        out.update(fs_pos=self.fs_pos_, fs_neg=self.fs_neg_)
        return out

    def params_std(self) -> dict:
        out = super().params_std()
        out.update(fs_pos=self.fs_pos_std_, fs_neg=self.fs_neg_std_)
        return out

    def joint_params(self) -> dict:
        return {**_classic_joint_params(self),
                "fs_pos_Nm": self.fs_pos_, "fs_neg_Nm": self.fs_neg_, "vs_rad_s": self.vs_,
                "stribeck_delta": self.delta_}


def make_estimator(name: str, loss: str = "linear"):
    """A fresh estimator by model name (:data:`MODEL_NAMES`)."""
    if name == "classic":
        return ClassicFriction(False, loss)
    if name == "classic_symmetric":
        return ClassicFriction(True, loss)
    if name == "stribeck":
        return StribeckFriction(loss)
    raise ValueError(f"unknown friction model {name!r}; choose from {', '.join(MODEL_NAMES)}")
