"""A friction drift against a Stribeck effect: how far apart a trajectory puts them, and the run that separates them
best (no I/O).

Both change one joint's friction: a drift scales its Coulomb and viscous torque by ``1 + c (1 - exp(-t / T))``
over the run (a warm-up), a Stribeck effect raises it at low speed, ``dF exp(-(|qd| / vs)^2)`` per direction. A run
that reaches its low speeds only at some times (a sweep whose slow passes fall early, a Fourier run) can leave the
two alike: the joint's diagnosis then reports them as an ambiguous group.

The hypotheses, each fitted to the run by the diagnosis' own columns (:func:`~wamctl.analysis.diagnosis.crossval.
fit_all`, the joint's other kept effects in the model), with the nuisance parameters it may still adjust on a
new trajectory (Coulomb and viscous per direction, an offset):

* ``H_S``: the Stribeck excess per direction (two coefficients) and its velocity ``vs`` (a grid);
* ``H_D``: the drift of the Coulomb and of the viscous torque (two coefficients) and its time constant ``T``
  (a grid of fractions of the new run's length; the drift starts again with each run, as a warm-up does).

:func:`separation`: each taken as true on a trajectory, the other refitted to its torque there; the RMS it cannot
reproduce on the joint's sliding samples, in noise floors; the smaller of the two directions (T-optimality,
Atkinson & Fedorov 1975). The natural design, the same slow and fast speeds repeated at different times, is what
wins here because of the criterion, not by construction: a Stribeck effect gives the same torque at the same speed
whenever, a drift a torque that changes with time at every speed.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from wamctl.analysis.blas import single_threaded_blas
from wamctl.analysis.diagnosis.candidates import DRIFT_T_GRID_FRACTION, STRIBECK_VS_GRID_RAD_S, stribeck_columns
from wamctl.analysis.diagnosis.design import drift_of
from wamctl.model.friction import classic_friction_columns

MIN_SPEED_RAD_S = 0.003       # a sample counts where the joint moves faster than this (the diagnosis' sweeps slide
                              # at 0.005 rad/s; slower, a joint may stick)
DESIGN_RATE_HZ = 10.0         # the criterion's samples per second
PERIODS_S = (2.0, 4.0, 8.0, 16.0, 32.0)   # base periods tried (a short one repeats the speeds within a warm-up
                                          # of seconds)
SPEED_SCALES = (1.0, 0.5, 0.25, 0.12, 0.06)   # each candidate at its largest scale within the limits and slower: the
                                              # Stribeck region is below a few tenths of a rad/s
MIN_RUN_S = 60.0              # the designed run lasts at least this, and at least as long as the run it follows
MAX_RUN_S = 600.0
NAMES = ("friction_drift", "stribeck")


@dataclass
class Hypotheses:
    """The two fitted models of joint ``j`` (0-based): the Stribeck model's friction levels ``lev_s`` (4,)
    ``[fc_pos, fc_neg, b_pos, b_neg]``, excess per direction ``c_s`` (2,) and velocity ``vs_rad_s``; the drift
    model's levels ``lev_d`` (4,), coefficients ``c_d`` (2,), time constant ``T_s`` and the declared levels ``tb``
    (4,) it scales; the run's length ``duration_s``."""

    j: int
    lev_s: np.ndarray
    c_s: np.ndarray
    vs_rad_s: float
    lev_d: np.ndarray
    c_d: np.ndarray
    T_s: float
    tb: np.ndarray
    duration_s: float


def drift_columns(qd: np.ndarray, t_s: np.ndarray, T_s: float, tb: np.ndarray) -> np.ndarray:
    """(m, 2) the drift's columns (the Coulomb and the viscous torque of the levels ``tb`` times ``1 - exp(-t /
    T)``), the diagnosis' columns (:func:`wamctl.analysis.diagnosis.design.drift_of`) unsmoothed."""
    return drift_of(classic_friction_columns(qd), tb, t_s, T_s)


def stribeck_torque(hyp: Hypotheses, qd: np.ndarray) -> np.ndarray:
    """(m,) the friction torque of ``H_S`` at speeds ``qd``."""
    return classic_friction_columns(qd) @ hyp.lev_s + stribeck_columns(qd, hyp.vs_rad_s) @ hyp.c_s


def drift_torque(hyp: Hypotheses, qd: np.ndarray, t_s: np.ndarray) -> np.ndarray:
    """(m,) the friction torque of ``H_D`` at speeds ``qd`` and times ``t_s`` from the run's start."""
    return classic_friction_columns(qd) @ hyp.lev_d + drift_columns(qd, t_s, hyp.T_s, hyp.tb) @ hyp.c_d


def _best_refit(y: np.ndarray, base: np.ndarray, extra) -> float:
    """The smallest RMS residual of ``y`` on ``[base, extra(h)]`` over the grid ``extra`` yields."""
    best = np.inf
    for X1 in extra:
        X = np.column_stack([base, X1])
        th, *_ = np.linalg.lstsq(X, y, rcond=None)
        e = y - X @ th
        best = min(best, float(np.sqrt(np.mean(e ** 2))))
    return best


def separation(hyp: Hypotheses, qd: np.ndarray, t_s: np.ndarray, noise_Nm: float,
               duration_s: float | None = None) -> dict:
    """The T-criterion of the joint's speeds ``qd`` at times ``t_s`` (from the run's start; ``duration_s`` the run's
    length, default the last time): ``"stribeck_true"`` (what a drift, friction and an offset refitted cannot
    reproduce of ``H_S``'s torque), ``"drift_true"`` (what a Stribeck effect cannot reproduce of ``H_D``'s), RMS
    per sliding sample in noise floors, and ``"separation"``, the smaller (0 with fewer than 20 sliding samples)."""
    m = np.abs(qd) > MIN_SPEED_RAD_S
    if m.sum() < 20:
        return {"stribeck_true": 0.0, "drift_true": 0.0, "separation": 0.0}
    v, t = qd[m], t_s[m]
    dur = float(duration_s if duration_s is not None else t_s.max())
    base = np.column_stack([classic_friction_columns(v), np.ones(len(v))])
    y_s, y_d = stribeck_torque(hyp, v), drift_torque(hyp, v, t)
    r_s = _best_refit(y_s, base, (drift_columns(v, t, f * dur, hyp.tb) for f in DRIFT_T_GRID_FRACTION))
    r_d = _best_refit(y_d, base, (stribeck_columns(v, vs) for vs in STRIBECK_VS_GRID_RAD_S))
    out = {"stribeck_true": r_s / noise_Nm, "drift_true": r_d / noise_Nm}
    out["separation"] = min(out.values())
    return out


def ambiguous_joints(diag) -> list[int]:
    """0-based joints whose diagnosis left ``friction_drift`` and ``stribeck`` in one ambiguous group."""
    return sorted(j for j, res in diag.joints_.items()
                  if any(set(NAMES) <= set(g["names"]) for g in res.ambiguous))


def fitted_hypotheses(des, jd, res) -> Hypotheses:
    """Both hypotheses fitted to joint ``jd.j``'s residual on the run, each beside the joint's kept effects
    (other than these two), by the diagnosis' own columns and shape grids (:func:`~wamctl.analysis.diagnosis.
    crossval.fit_all`)."""
    from wamctl.analysis.diagnosis.crossval import cv_residual, fit_all
    from wamctl.analysis.diagnosis.design import declared_levels, levels, split_coefs

    others = [t for t in res.kept if t["name"] not in NAMES]
    got = {}
    for name in NAMES:
        _, h_fold = cv_residual(des, jd, others, name)
        fitted, theta = fit_all(des, jd, others + [{"name": name, "h_fold": h_fold}])
        c = split_coefs(fitted, theta)
        got[name] = (levels(des.friction_given, jd.j, c["friction"]), np.asarray(c[name], float),
                     float(next(t["h_all"] for t in fitted if t["name"] == name)))
    (ls, cs, vs), (ld, cd, T) = got["stribeck"], got["friction_drift"]
    dur = float(des.sig.duration_s)
    return Hypotheses(jd.j, ls, cs, vs, ld, cd, T, declared_levels(des, jd), dur)


@dataclass
class NextRun:
    """The designed trajectory (:class:`~wamctl.analysis.identification.excitation.FourierTrajectory`), its
    periods, its separation (:func:`separation`) and the run's, the candidates scored ``(period s, scale, peak speed
    rad/s, separation)`` and the limits it uses."""

    trajectory: object
    periods: int
    separation: dict
    original: dict
    scored: list
    limit_use: object


def _periods(period_s: float, run_s: float) -> int:
    """Repetitions of a period: the designed run as long as the run it follows (at least :data:`MIN_RUN_S`, at
    most :data:`MAX_RUN_S`), three at least."""
    total = min(max(run_s, MIN_RUN_S), MAX_RUN_S)
    return int(min(max(3, np.ceil(total / period_s)), 100))


def trajectory_score(traj, periods: int, settle_s: float, hyp: Hypotheses, noise_Nm: float) -> dict:
    """:func:`separation` of joint ``hyp.j`` on ``periods`` repetitions of ``traj`` after ``settle_s`` at rest (the
    drift's clock starts with the run)."""
    t = np.arange(int(periods * traj.period_s * DESIGN_RATE_HZ)) / DESIGN_RATE_HZ
    _, qd, _ = traj.evaluate(t)
    dur = periods * traj.period_s + 2 * settle_s
    return separation(hyp, qd[:, hyp.j], t + settle_s, noise_Nm, dur)


@single_threaded_blas()
def design_next_run(dynamics, friction, q0_rad, hyp: Hypotheses, noise_Nm: float, run_qd: np.ndarray,
                    run_t_s: np.ndarray, limits, harmonics: int = 5, per_period: int = 2, fill: float = 0.95,
                    settle_s: float = 1.0, seed: int = 0, periods_s=PERIODS_S,
                    scales=SPEED_SCALES) -> NextRun:
    """T-optimal choice among Fourier candidates of joint ``hyp.j`` alone (excite's parametrisation): ``per_period``
    random series (seeded) per base period in ``periods_s``, each scaled to ``fill`` of its closest limit by
    excite's check on a coarse grid and then slowed by each of ``scales``, repeated over a run as long as the one it
    follows (:func:`_periods`); the best checked at the control rate (:func:`~wamctl.analysis.diagnosis.discriminate.
    best_within_limits`). The run's own separation from its joint's speeds ``run_qd`` at times ``run_t_s``. Raises
    ValueError when no candidate keeps within the limits."""
    from wamctl.analysis.diagnosis.discriminate import (
        LIMIT_CHECK_RATE_HZ,
        best_within_limits,
        candidate_scores,
        coarse_scaled,
    )
    from wamctl.analysis.identification.excitation import FourierTrajectory

    rng = np.random.default_rng(seed)
    n_per = {p: _periods(p, hyp.duration_s) for p in periods_s}

    def score(traj):
        return trajectory_score(traj, n_per[traj.period_s], settle_s, hyp, noise_Nm)

    cands, label = [], {}
    for period in periods_s:
        for _ in range(per_period):
            x = rng.normal(size=(1, 2 * (harmonics - 1))) / np.tile(np.arange(2, harmonics + 1), 2)
            got = coarse_scaled(FourierTrajectory.from_free(q0_rad, period, [hyp.j], x, harmonics), limits,
                                dynamics, friction, fill, LIMIT_CHECK_RATE_HZ)
            if got is None:
                continue
            top = got[0]
            for k in scales:
                tr = FourierTrajectory(top.q0_rad, top.period_s, top.a * k, top.b * k)
                t = np.arange(int(period * DESIGN_RATE_HZ)) / DESIGN_RATE_HZ
                peak = float(np.abs(tr.evaluate(t)[1][:, hyp.j]).max())
                label[len(cands)] = (float(period), float(k), peak)
                cands.append((score(tr)["separation"], tr, len(cands)))
    best = best_within_limits(cands, score, limits, dynamics, friction, fill)
    if best is None:
        raise ValueError("no candidate trajectory keeps within the limits")
    traj, sep, use, checked = best
    scored = [(*label[k], s) for k, _, s in candidate_scores(cands, checked)]
    orig = separation(hyp, np.asarray(run_qd, float), np.asarray(run_t_s, float), noise_Nm, hyp.duration_s)
    return NextRun(traj, n_per[traj.period_s], sep, orig, scored, use)
