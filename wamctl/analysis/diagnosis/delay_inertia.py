"""A measurement delay against a joint inertia error: how far apart a trajectory puts them, the run that separates
them best, and which one a run's data prefer (no I/O).

A delay ``d`` of the measured positions makes the torque residual ``y = tau - rnea(q)`` the model's torque at the
positions ``d`` later minus at the positions now: ``R(t + d) - R(t) + F(qd(t + d)) f``. On a sweep at one speed
(one frequency ``w``) its viscous part ``b qd(t + d) ~ b qd + b d qdd`` is an inertia ``b d``, and its inertial
part ``M qdd(t + d) ~ M qdd - M d w^2 qd`` a (negative) viscous friction, which the fitted friction absorbs: a
joint inertia error ``da qdd`` with refitted friction reproduces the delay. At two speeds (two frequencies) the
friction cannot absorb both ``M d w1^2`` and ``M d w2^2``, and the Coulomb switch at a reversal moves with the
delay: the two hypotheses' fitted models part.

The hypotheses, each with the nuisance parameters it may still adjust (per moving joint: Coulomb per direction,
viscous, an offset):

* ``H_D``: one delay of the arm, ``0 <= d <= MAX_DELAY_S`` (a grid, the smallest residual);
* ``H_I``: an inertia error ``da_j`` of each moving joint (the armature and the link's own inertia about its
  axis as one number; unbounded: the worst case for telling them apart).

:func:`separation`: each taken as true on a trajectory, the other refitted to its torque there; the RMS it cannot
reproduce, per sample over the moving joints, in units of the noise floor; the smaller of the two directions
(T-optimality, Atkinson & Fedorov 1975). :func:`decide` compares the two fitted to a run's measured residual.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from wamctl.model.friction import classic_friction_columns

MAX_DELAY_S = 0.02                # a longer delay makes libbarrett's PD loop unstable
DELAY_GRID_S = np.r_[0.0, np.linspace(0.5e-3, MAX_DELAY_S, 40)]
MIN_SPEED_RAD_S = 0.01            # a joint's sample counts where it moves faster than this
DECIDED_FLOORS = 1.0              # the losing hypothesis' excess residual (RMS, noise floors) that decides
DESIGN_TARGET_FLOORS = 2.0        # the predicted separation the design asks for
MAX_ROWS = 4000                   # a run's samples the check uses at most (an hour's log: evenly spread)


@dataclass
class StateSource:
    """States of a trajectory at its sample times ``shift_s`` later: ``states(shift_s) -> (q, qd, qdd)`` (n, 7);
    ``joints``: the 0-based joints that move."""

    states: object
    joints: list


def fourier_source(traj, t_s: np.ndarray) -> StateSource:
    """:class:`StateSource` of a designed trajectory (:class:`~wamctl.analysis.identification.excitation.
    FourierTrajectory`) at the times ``t_s``."""
    return StateSource(lambda s: traj.evaluate(t_s + s), list(traj.moving))


def signals_source(sig, idx: np.ndarray, joints: list) -> StateSource:
    """:class:`StateSource` of a run's smoothed signals (:class:`~wamctl.analysis.diagnosis.signals.Signals`) at
    the samples ``idx`` (a shift between samples interpolated)."""
    def states(s):
        k = s / sig.dt_s
        return sig.at("q", idx, k), sig.at("qd", idx, k), sig.at("qdd", idx, k)

    return StateSource(states, sorted(joints))


@dataclass
class Rows:
    """What both hypotheses need on one trajectory, per moving joint ``j``: the rigid-body torque ``R[s][j]``
    (m_j,) at each grid shift ``s`` (index into :data:`DELAY_GRID_S`), the speeds ``qd[s][j]`` and the
    acceleration now ``qdd[j]``, on the samples ``mask[j]`` where the joint moves."""

    R: list
    qd: list
    qdd: dict
    joints: list
    mask: dict


def rows_of(dynamics, src: StateSource) -> Rows:
    """:class:`Rows` of ``src`` under the declared rigid body ``dynamics`` (one inverse dynamics per grid shift)."""
    q0, qd0, qdd0 = src.states(0.0)
    moving = [j for j in src.joints if (np.abs(qd0[:, j]) > MIN_SPEED_RAD_S).sum() >= 10]
    mask = {j: np.abs(qd0[:, j]) > MIN_SPEED_RAD_S for j in moving}
    R, QD = [], []
    for d in DELAY_GRID_S:
        q, qd, qdd = (q0, qd0, qdd0) if d == 0 else src.states(float(d))
        tau = dynamics.inverse_dynamics_many(q, qd, qdd)
        R.append({j: tau[mask[j], j] for j in moving})
        QD.append({j: qd[mask[j], j] for j in moving})
    return Rows(R, QD, {j: qdd0[mask[j], j] for j in moving}, moving, mask)


def _nuisance(qd: np.ndarray) -> np.ndarray:
    """(m, 5) Coulomb per direction, viscous per direction, offset at speeds ``qd``."""
    return np.column_stack([classic_friction_columns(qd), np.ones(len(qd))])


def delay_torque(rows: Rows, k: int, levels: dict) -> dict:
    """{j: (m_j,)} the residual a delay ``DELAY_GRID_S[k]`` makes with friction ``levels[j]`` (4,)."""
    return {j: rows.R[k][j] - rows.R[0][j] + classic_friction_columns(rows.qd[k][j]) @ levels[j]
            for j in rows.joints}


def inertia_torque(rows: Rows, da: dict, levels: dict) -> dict:
    """{j: (m_j,)} the residual inertia errors ``da[j]`` make with friction ``levels[j]`` (4,)."""
    return {j: da[j] * rows.qdd[j] + classic_friction_columns(rows.qd[0][j]) @ levels[j] for j in rows.joints}


def _w(w, j) -> float:
    return 1.0 if w is None else float(w[j])


def fit_inertia(rows: Rows, y: dict, w: dict | None = None) -> tuple[float, dict, dict]:
    """``H_I`` fitted to ``y`` ({j: (m_j,)}): (pooled RMS residual, {j: da_j}, {j: RMS residual of j}); ``w``
    {j: weight} scales each joint's residual in the pooled RMS (the joints' fits are separate)."""
    ss, n, da, per = 0.0, 0, {}, {}
    for j in rows.joints:
        X = np.column_stack([rows.qdd[j], _nuisance(rows.qd[0][j])])
        th, *_ = np.linalg.lstsq(X, y[j], rcond=None)
        e = y[j] - X @ th
        ss, n, da[j] = ss + _w(w, j) ** 2 * float(e @ e), n + len(e), float(th[0])
        per[j] = float(np.sqrt(np.mean(e ** 2)))
    return float(np.sqrt(ss / max(n, 1))), da, per


def fit_delay(rows: Rows, y: dict, w: dict | None = None) -> tuple[float, float, dict]:
    """``H_D`` fitted to ``y``: one delay for all moving joints on the grid (the smallest pooled residual,
    weighted by ``w`` as in :func:`fit_inertia`), friction and offset per joint refitted at each; (pooled RMS
    residual, delay s, {j: RMS residual of j})."""
    best = None
    for k, d in enumerate(DELAY_GRID_S):
        ss, n, per = 0.0, 0, {}
        for j in rows.joints:
            t = y[j] - (rows.R[k][j] - rows.R[0][j])
            X = _nuisance(rows.qd[k][j])
            th, *_ = np.linalg.lstsq(X, t, rcond=None)
            e = t - X @ th
            ss, n, per[j] = ss + _w(w, j) ** 2 * float(e @ e), n + len(e), float(np.sqrt(np.mean(e ** 2)))
        rms = float(np.sqrt(ss / max(n, 1)))
        if best is None or rms < best[0]:
            best = (rms, float(d), per)
    return best


def fit_none(rows: Rows, y: dict, w: dict | None = None) -> float:
    """Neither: friction and offset per joint only; the pooled RMS residual (weighted as in :func:`fit_inertia`)."""
    ss, n = 0.0, 0
    for j in rows.joints:
        X = _nuisance(rows.qd[0][j])
        th, *_ = np.linalg.lstsq(X, y[j], rcond=None)
        e = y[j] - X @ th
        ss, n = ss + _w(w, j) ** 2 * float(e @ e), n + len(e)
    return float(np.sqrt(ss / max(n, 1)))


def nearest_k(delay_s: float) -> int:
    """The grid shift closest to ``delay_s``."""
    return int(np.argmin(np.abs(DELAY_GRID_S - delay_s)))


@dataclass
class Hypotheses:
    """The two fitted models: a delay ``delay_s`` and inertia errors ``da`` ({j: kg m^2}), each with the
    friction levels ``levels`` ({j: (4,) [fc_pos, fc_neg, b_pos, b_neg]})."""

    delay_s: float
    da: dict
    levels: dict


def fitted_hypotheses(rows_run: Rows, delay_s: float, levels: dict) -> Hypotheses:
    """The delay's model and the inertia errors that best reproduce it on the run ``rows_run``."""
    y = delay_torque(rows_run, nearest_k(delay_s), levels)
    _, da, _ = fit_inertia(rows_run, y)
    return Hypotheses(float(DELAY_GRID_S[nearest_k(delay_s)]), da, levels)


def joint_floors(noise_Nm: dict) -> dict:
    """{j: torque noise floor, N m} for every joint from the floors measured at some (``noise_Nm``): a joint the
    run did not move gets the smallest measured floor scaled by its torque limit over that joint's (an
    assumption: the floor grows with the torques a joint carries)."""
    from wamctl.model import params as P

    j0 = min(noise_Nm, key=noise_Nm.get)
    return {j: float(noise_Nm.get(j, noise_Nm[j0] * P.TAU_MAX_NM[j] / P.TAU_MAX_NM[j0]))
            for j in range(len(P.TAU_MAX_NM))}


def separation(rows: Rows, hyp: Hypotheses, noise_Nm: dict) -> dict:
    """The T-criterion of a trajectory: ``"delay_true"`` (what inertia errors cannot reproduce of the delay's
    torque), ``"inertia_true"`` (what a delay cannot reproduce of the inertia errors'), RMS per sample over the
    moving joints of each joint's residual in units of its noise floor (``noise_Nm`` {j: N m}, see
    :func:`joint_floors`), and ``"separation"``, the smaller."""
    levels = {j: hyp.levels.get(j, np.zeros(4)) for j in rows.joints}
    w = {j: 1.0 / noise_Nm[j] for j in rows.joints}
    r_d, _, _ = fit_inertia(rows, delay_torque(rows, nearest_k(hyp.delay_s), levels), w)
    da = {j: hyp.da.get(j, 0.0) for j in rows.joints}
    r_i, _, _ = fit_delay(rows, inertia_torque(rows, da, levels), w)
    out = {"delay_true": r_d, "inertia_true": r_i}
    out["separation"] = min(out.values())
    return out


def decide(rows: Rows, y: dict) -> dict:
    """Which of the two a run's measured residual ``y`` ({j: (m_j,)}, ``tau - rnea(q)`` at the rows' samples)
    prefers. Both fitted; each joint's noise floor is the smaller of its two residuals' RMS, and each joint's
    residual is then counted in units of its floor (a joint that carries large torques, and so a large floor,
    does not drown a small joint's evidence; the delay, one for the arm, is chosen on this weighted residual).
    ``outcome`` ``"delay"`` or ``"inertia"`` when the other's excess (``sqrt(rms_other^2 - rms_best^2)``, in
    noise floors) is at least :data:`DECIDED_FLOORS`, else ``"ambiguous"``. Returns the outcome, both fits (RMS in
    N m over the joints and in noise floors, the delay, the inertia errors), neither's, the floors, the excess and
    ``effect_noise_floors``, what the better explains beyond friction."""
    _, _, per_i = fit_inertia(rows, y)
    _, _, per_d = fit_delay(rows, y)
    floor = {j: max(min(per_i[j], per_d[j]), 1e-12) for j in rows.joints}
    w = {j: 1.0 / floor[j] for j in rows.joints}
    r_i, da, per_i = fit_inertia(rows, y, w)
    r_d, d, per_d = fit_delay(rows, y, w)
    r_0 = fit_none(rows, y, w)
    best, other = (r_d, r_i) if r_d <= r_i else (r_i, r_d)
    excess = float(np.sqrt(max(other ** 2 - best ** 2, 0.0)) / max(best, 1e-12))
    outcome = ("delay" if r_d <= r_i else "inertia") if excess >= DECIDED_FLOORS else "ambiguous"

    def pooled(per):
        n = {j: len(y[j]) for j in rows.joints}
        return float(np.sqrt(sum(n[j] * per[j] ** 2 for j in rows.joints) / max(sum(n.values()), 1)))

    return {"outcome": outcome, "rms_delay_Nm": pooled(per_d), "rms_inertia_Nm": pooled(per_i),
            "rms_delay_noise_floors": r_d, "rms_inertia_noise_floors": r_i, "rms_neither_noise_floors": r_0,
            "delay_s": d, "inertia_error_kg_m2": {int(j) + 1: float(v) for j, v in da.items()},
            "excess_noise_floors": excess, "floor_Nm": {int(j) + 1: float(floor[j]) for j in rows.joints},
            "effect_noise_floors": float(np.sqrt(max(r_0 ** 2 - best ** 2, 0.0)) / max(best, 1e-12))}


# ------------------------------------------------------------------------------------------------- the design
DESIGN_RATE_HZ = 50.0          # the criterion's samples per second (the delay grid needs ms; the limits are
                               # checked at the control rate by excite's own check)
LIMIT_CHECK_RATE_HZ = 50.0     # the candidates' scaling checked on this grid, the chosen scale at the control rate
PERIODS_S = (2.0, 4.0, 8.0)    # base periods tried: the harmonics then span the speeds (frequencies) that part them


@dataclass
class NextRun:
    """The designed trajectory, its separation (:func:`separation`) and the run's, the candidates scored
    ``(1-based joints, period s, separation)`` and the limits it uses (:class:`~wamctl.analysis.identification.
    excitation.LimitUse`)."""

    trajectory: object
    separation: dict
    original: dict
    scored: list
    limit_use: object


def design_next_run(dynamics, friction, q0_rad, hyp: Hypotheses, noise_Nm: float, rows_run: Rows, limits,
                    joint_sets: list[list[int]], harmonics: int = 5, per_set: int = 2, fill: float = 0.95,
                    seed: int = 0, periods_s=PERIODS_S) -> NextRun:
    """T-optimal choice among Fourier candidates (excite's parametrisation): ``per_set`` random series (seeded)
    per base period in ``periods_s`` on each of ``joint_sets`` (0-based), each scaled to ``fill`` of its closest
    limit by excite's limit check (:func:`~wamctl.analysis.diagnosis.discriminate.scaled_to_limits`); the
    candidate whose smaller separation is largest wins. Raises ValueError when no candidate keeps within the
    limits."""
    from wamctl.analysis.diagnosis.discriminate import scaled_to_limits
    from wamctl.analysis.identification.excitation import FourierTrajectory

    rng = np.random.default_rng(seed)
    scored, best = [], None
    for js in joint_sets:
        for period in periods_s:
            t = np.arange(int(period * DESIGN_RATE_HZ)) / DESIGN_RATE_HZ
            for _ in range(per_set):
                x = rng.normal(size=(len(js), 2 * (harmonics - 1))) / np.tile(np.arange(2, harmonics + 1), 2)
                got = scaled_to_limits(FourierTrajectory.from_free(q0_rad, period, js, x, harmonics), limits,
                                       dynamics, friction, fill, rate_hz=LIMIT_CHECK_RATE_HZ)
                if got is None:
                    continue
                traj, use = got
                sep = separation(rows_of(dynamics, fourier_source(traj, t)), hyp, noise_Nm)
                scored.append(([j + 1 for j in js], float(period), sep["separation"]))
                if best is None or sep["separation"] > best[1]["separation"]:
                    best = (traj, sep, use)
    if best is None:
        raise ValueError("no candidate trajectory keeps within the limits")
    return NextRun(best[0], best[1], separation(rows_run, hyp, noise_Nm), scored, best[2])


# ------------------------------------------------------------------------------------------------- on a run
@dataclass
class RunCheck:
    """A run's delay-or-inertia check: the rows (:class:`Rows`), the decision (:func:`decide`), the fitted
    hypotheses and the run's separation (None when the residual holds no such effect)."""

    rows: Rows
    decision: dict
    hyp: Hypotheses | None
    original: dict | None
    floors: dict | None = None

    @property
    def suspected(self) -> bool:
        """The better of the two explains at least the noise floor beyond friction (:data:`DECIDED_FLOORS`)."""
        return self.decision["effect_noise_floors"] >= DECIDED_FLOORS


def check_run(diag, dynamics, rate_hz: float = DESIGN_RATE_HZ) -> RunCheck:
    """Both hypotheses fitted to a diagnosed run's measured residual ``tau - rnea(q)`` (the diagnosed joints'
    sliding samples, every ``1 / rate_hz`` s, at most :data:`MAX_ROWS` of them; ``diag`` a fitted
    :class:`~wamctl.analysis.diagnosis.estimator.ModelDiagnosis`, ``dynamics`` its declared rigid body)."""
    sig = diag.signals_
    idx = np.unique(np.concatenate([diag.jd_[j].idx for j in diag.joints_]))
    idx = idx[:: max(1, int(round(1.0 / (sig.dt_s * rate_hz))), -(-len(idx) // MAX_ROWS))]
    rows = rows_of(dynamics, signals_source(sig, idx, list(diag.joints_)))
    tau = sig.at("tau", idx)
    y = {j: tau[rows.mask[j], j] - rows.R[0][j] for j in rows.joints}
    dec = decide(rows, y)
    if not rows.joints or dec["effect_noise_floors"] < DECIDED_FLOORS:
        return RunCheck(rows, dec, None, None)
    levels = {j: np.array(list(diag.friction_before(j).values()), float) for j in rows.joints}
    hyp = fitted_hypotheses(rows, dec["delay_s"], levels)
    floors = joint_floors({j - 1: v for j, v in dec["floor_Nm"].items()})
    return RunCheck(rows, dec, hyp, separation(rows, hyp, floors), floors)


def decision_line(dec: dict) -> str:
    """The decision in words (one sentence, the figures it rests on)."""
    d_ms = dec["delay_s"] * 1e3
    inert = ", ".join(f"joint {j} {v:+.2g} kg m^2" for j, v in dec["inertia_error_kg_m2"].items())
    fits = (f"a {d_ms:.1f} ms delay leaves {dec['rms_delay_noise_floors']:.3g} noise floors RMS, inertia errors "
            f"({inert}) {dec['rms_inertia_noise_floors']:.3g}, neither {dec['rms_neither_noise_floors']:.3g}")
    if dec["outcome"] == "ambiguous":
        return (f"delay or inertia: ambiguous on this run ({fits}; the worse exceeds the better by "
                f"{dec['excess_noise_floors']:.2g} noise floors, {DECIDED_FLOORS:g} needed)")
    return (f"delay or inertia: {dec['outcome']} ({fits}; the other exceeds it by {dec['excess_noise_floors']:.2g} "
            "noise floors)")
