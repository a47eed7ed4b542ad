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

from wamctl.analysis.blas import single_threaded_blas
from wamctl.analysis.diagnosis.stats import DECIDED_FLOORS, excess_floors
from wamctl.model.friction import classic_friction_columns

MAX_DELAY_S = 0.02                # a longer delay makes libbarrett's PD loop unstable
DELAY_GRID_S = np.r_[0.0, np.linspace(0.5e-3, MAX_DELAY_S, 40)]
MIN_SPEED_RAD_S = 0.01            # a joint's sample counts where it moves faster than this
DESIGN_TARGET_FLOORS = 2.0        # the predicted separation the design asks for
MAX_ROWS = 4000                   # a run's samples the check uses at most (an hour's log: evenly spread)


@dataclass
class StateSource:
    """States of a trajectory at its sample times ``shift_s`` later: ``states(shift_s) -> (q, qd, qdd)`` (n, 7);
    ``joints``: the 0-based joints that move; ``sliding``: {j: (n,) bool} the samples where the diagnosis fits
    joint ``j``'s torque (a run's: :attr:`~wamctl.analysis.diagnosis.signals.Signals.moving`; None: every sample
    faster than :data:`MIN_SPEED_RAD_S`)."""

    states: object
    joints: list
    sliding: dict | None = None
    rigid_states: object = None       # states(shift_s) of the rigid body when not ``states`` (None: the same)


def fourier_source(traj, t_s: np.ndarray) -> StateSource:
    """:class:`StateSource` of a designed trajectory (:class:`~wamctl.analysis.identification.excitation.
    FourierTrajectory`) at the times ``t_s``."""
    return StateSource(lambda s: traj.evaluate(t_s + s), list(traj.moving))


def signals_source(sig, idx: np.ndarray, joints: list, rigid_shift_s: float = 0.0) -> StateSource:
    """:class:`StateSource` of a run's smoothed signals (:class:`~wamctl.analysis.diagnosis.signals.Signals`) at
    the samples ``idx`` (a shift between samples interpolated). Each joint's rows are its sliding samples
    (``sig.moving``, as every other fit of the diagnosis): where a joint sticks, reverses or has just broken away
    its friction is static and unknown, and the smoothed Coulomb switch is not the model's sign; counted there
    (every sample of the run where another joint moves), that torque was the largest part of the residual on a
    fast run (joint 2 of the loop's designed run on an exact plant: a floor of 0.085 N m, 0.042 on its sliding
    samples) and fitted as an inertia error of 0.013 kg m^2 (0.002 on its sliding samples). ``rigid_shift_s``: the
    rigid body's states are taken this much later (the run's zero-order hold, :mod:`~wamctl.analysis.diagnosis.
    timing`), the speeds of the friction at the samples."""
    def states(s):
        k = s / sig.dt_s
        return sig.at("q", idx, k), sig.at("qd", idx, k), sig.at("qdd", idx, k)

    rigid = None if not rigid_shift_s else (lambda s: states(s + rigid_shift_s))
    return StateSource(states, sorted(joints), {j: sig.moving[idx, j] for j in joints}, rigid)


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
    """:class:`Rows` of ``src`` under the declared rigid body ``dynamics`` (one inverse dynamics per grid shift),
    on each joint's samples faster than :data:`MIN_SPEED_RAD_S` and among the source's ``sliding`` ones."""
    q0, qd0, qdd0 = src.states(0.0)
    mask = {j: (np.abs(qd0[:, j]) > MIN_SPEED_RAD_S) & (True if src.sliding is None else src.sliding[j])
            for j in src.joints}
    moving = [j for j in src.joints if mask[j].sum() >= 10]
    mask = {j: mask[j] for j in moving}
    R, QD = [], []
    for d in DELAY_GRID_S:
        q, qd, qdd = (q0, qd0, qdd0) if d == 0 else src.states(float(d))
        tau = dynamics.inverse_dynamics_many(*((q, qd, qdd) if src.rigid_states is None else
                                              src.rigid_states(float(d))))
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
    excess = excess_floors(other, best)
    outcome = ("delay" if r_d <= r_i else "inertia") if excess >= DECIDED_FLOORS else "ambiguous"

    def pooled(per):
        n = {j: len(y[j]) for j in rows.joints}
        return float(np.sqrt(sum(n[j] * per[j] ** 2 for j in rows.joints) / max(sum(n.values()), 1)))

    return {"outcome": outcome, "rms_delay_Nm": pooled(per_d), "rms_inertia_Nm": pooled(per_i),
            "rms_delay_noise_floors": r_d, "rms_inertia_noise_floors": r_i, "rms_neither_noise_floors": r_0,
            "delay_s": d, "inertia_error_kg_m2": {int(j) + 1: float(v) for j, v in da.items()},
            "excess_noise_floors": excess, "floor_Nm": {int(j) + 1: float(floor[j]) for j in rows.joints},
            "effect_noise_floors": excess_floors(r_0, best)}


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


@single_threaded_blas()     # small dense products: threads only contend on a shared machine
def design_next_run(dynamics, friction, q0_rad, hyp: Hypotheses, noise_Nm: float, rows_run: Rows, limits,
                    joint_sets: list[list[int]], harmonics: int = 5, per_set: int = 2, fill: float = 0.95,
                    seed: int = 0, periods_s=PERIODS_S) -> NextRun:
    """T-optimal choice among Fourier candidates (excite's parametrisation): ``per_set`` random series (seeded)
    per base period in ``periods_s`` on each of ``joint_sets`` (0-based), each scaled to ``fill`` of its closest
    limit by excite's limit check on a coarse grid (:func:`~wamctl.analysis.diagnosis.discriminate.coarse_scaled`)
    and scored there; the best checked at the control rate, shrunk where a peak between the coarse samples crosses
    ``fill``, and scored again, until no unchecked candidate's coarse score beats the best checked one
    (:func:`~wamctl.analysis.diagnosis.discriminate.best_within_limits`): the candidate whose smaller separation is
    largest wins. ``scored``: each candidate's separation (after the control rate's check where it was checked).
    Raises ValueError when no candidate keeps within the limits."""
    from wamctl.analysis.diagnosis.discriminate import best_within_limits, candidate_scores, coarse_scaled
    from wamctl.analysis.identification.excitation import FourierTrajectory

    rng = np.random.default_rng(seed)

    def score(traj):
        t = np.arange(int(traj.period_s * DESIGN_RATE_HZ)) / DESIGN_RATE_HZ
        return separation(rows_of(dynamics, fourier_source(traj, t)), hyp, noise_Nm)

    cands, label = [], {}
    for js in joint_sets:
        for period in periods_s:
            for _ in range(per_set):
                x = rng.normal(size=(len(js), 2 * (harmonics - 1))) / np.tile(np.arange(2, harmonics + 1), 2)
                got = coarse_scaled(FourierTrajectory.from_free(q0_rad, period, js, x, harmonics), limits,
                                    dynamics, friction, fill, rate_hz=LIMIT_CHECK_RATE_HZ)
                if got is None:
                    continue
                label[len(cands)] = ([j + 1 for j in js], float(period))
                cands.append((score(got[0])["separation"], got[0], len(cands)))
    best = best_within_limits(cands, score, limits, dynamics, friction, fill)
    if best is None:
        raise ValueError("no candidate trajectory keeps within the limits")
    traj, sep, use, checked = best
    scored = [(*label[k], s) for k, _, s in candidate_scores(cands, checked)]
    return NextRun(traj, sep, separation(rows_run, hyp, noise_Nm), scored, use)


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
    y: dict | None = None

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
    shift = float(getattr(getattr(diag, "design_", None), "rigid_shift_s", 0.0))
    rows = rows_of(dynamics, signals_source(sig, idx, list(diag.joints_), shift))
    tau = sig.at("tau", idx)
    y = {j: tau[rows.mask[j], j] - rows.R[0][j] for j in rows.joints}
    dec = decide(rows, y)
    if not rows.joints or dec["effect_noise_floors"] < DECIDED_FLOORS:
        return RunCheck(rows, dec, None, None, y=y)
    levels = {j: np.array(list(diag.friction_before(j).values()), float) for j in rows.joints}
    hyp = fitted_hypotheses(rows, dec["delay_s"], levels)
    floors = joint_floors({j - 1: v for j, v in dec["floor_Nm"].items()})
    return RunCheck(rows, dec, hyp, separation(rows, hyp, floors), floors, y)


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


def leaves_room(diag, unexplained: bool = True) -> bool:
    """A fitted diagnosis leaves room for a delay or an inertia error: a delay named, a delay in an ambiguous
    group, or (``unexplained``) a structured residual left unexplained at a joint. (A residual a payload or link
    errors explain is none of these: the check's friction-only model would take it for an inertia error.)"""
    return ("delay" in diag.effects_found_ or any("delay" in g for g in diag.ambiguous_)
            or unexplained and any(r.unexplained for r in diag.joints_.values()))


# ------------------------------------------------------------------------------------------------- runs pooled
N_BOOT = 200                   # block-bootstrap replicates of the pooled estimates' intervals


@dataclass
class RunPart:
    """One run's share of the pooled check (:func:`decide_pooled`): its rows (:class:`Rows`), its measured residual
    ``y`` ({j: (m_j,)}), its own decision (:func:`decide`, whose ``floor_Nm`` weighs each joint's residual) and
    ``label``."""

    label: str
    rows: Rows
    y: dict
    decision: dict
    named: str | None = None        # "delay" (or "inertia") when the run's own diagnosis named it, else None


def _solve(A: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Stacked normal equations ``A x = b`` (..., p, p), (..., p); a column no sample excites (a direction a
    resample never ran) held at zero by a vanishing ridge."""
    lam = 1e-10 * np.maximum(np.trace(A, axis1=-2, axis2=-1), 1e-300)[..., None, None]
    return np.linalg.solve(A + lam * np.eye(A.shape[-1]), b[..., None])[..., 0]


def _block_sums(X: np.ndarray, t: np.ndarray, blk: np.ndarray, nb: int):
    """Per time block: ``X'X`` (nb, p, p), ``X't`` (nb, p), ``t't`` (nb,) of the rows ``X`` (m, p), ``t`` (m,)."""
    XtX = np.zeros((nb, X.shape[1], X.shape[1]))
    Xt, tt = np.zeros((nb, X.shape[1])), np.zeros(nb)
    for b in range(nb):
        m = blk == b
        XtX[b], Xt[b], tt[b] = X[m].T @ X[m], X[m].T @ t[m], t[m] @ t[m]
    return XtX, Xt, tt


class _Pool:
    """The runs' rows as sufficient statistics per time block, so that a fit on any weighting of the blocks (all,
    without a fold, a bootstrap resample) is a sum and a small solve. Keys ``(r, j)``: run ``r``, 0-based joint
    ``j``; each joint's residual weighed by one over its noise floor in that run."""

    def __init__(self, parts: list[RunPart], n_blocks: int):
        self.parts, self.nb = parts, n_blocks
        self.keys = [(r, j) for r, p in enumerate(parts) for j in p.rows.joints]
        self.w = {(r, j): 1.0 / parts[r].decision["floor_Nm"][j + 1] for r, j in self.keys}
        self.blk, self.Xd, self.td, self.Xi, self.sd, self.si = {}, {}, {}, {}, {}, {}
        K = len(DELAY_GRID_S)
        for r, j in self.keys:
            rows, y = parts[r].rows, parts[r].y[j]
            m_all = len(rows.mask[j])
            blk_all = np.minimum((np.arange(m_all) * n_blocks) // max(m_all, 1), n_blocks - 1)
            blk = self.blk[(r, j)] = blk_all[rows.mask[j]]       # the run's time blocks, the joint's rows
            self.Xd[(r, j)] = np.stack([_nuisance(rows.qd[k][j]) for k in range(K)])
            self.td[(r, j)] = np.stack([y - (rows.R[k][j] - rows.R[0][j]) for k in range(K)])
            self.Xi[(r, j)] = np.column_stack([rows.qdd[j], _nuisance(rows.qd[0][j])])
            sums = [_block_sums(self.Xd[(r, j)][k], self.td[(r, j)][k], blk, n_blocks) for k in range(K)]
            self.sd[(r, j)] = tuple(np.stack([s[i] for s in sums]) for i in range(3))     # (K, nb, ...)
            self.si[(r, j)] = _block_sums(self.Xi[(r, j)], y, blk, n_blocks)

    def fit_delay(self, c: np.ndarray):
        """One delay for all runs (the grid point of the smallest weighted SSR), friction and offset per (run,
        joint), on the blocks weighted ``c`` (s, runs, nb): ((s,) grid index, {key: (s, 5)})."""
        ssr, th = 0.0, {}
        for r, j in self.keys:
            XtX, Xt, tt = self.sd[(r, j)]
            A = np.einsum("sb,kbpq->skpq", c[:, r], XtX)
            b = np.einsum("sb,kbp->skp", c[:, r], Xt)
            x = _solve(A, b)
            ssr = ssr + self.w[(r, j)] ** 2 * (np.einsum("sb,kb->sk", c[:, r], tt) - (x * b).sum(-1))
            th[(r, j)] = x
        k = np.argmin(ssr, axis=1)
        s = np.arange(len(k))
        return k, {key: x[s, k] for key, x in th.items()}

    def fit_inertia(self, c: np.ndarray, neither: bool = False):
        """An inertia error per joint shared by the runs (``neither``: none), friction and offset per (run,
        joint), on the blocks weighted ``c``: ({j: (s,)}, {key: (s, 6)} inertia error then the five nuisance)."""
        da, th = {}, {}
        for j in sorted({j for _, j in self.keys}):
            rs = [r for r, jj in self.keys if jj == j]
            P = 1 + 5 * len(rs)
            A, b = np.zeros((len(c), P, P)), np.zeros((len(c), P))
            ix = {r: np.r_[0, 1 + 5 * n + np.arange(5)] for n, r in enumerate(rs)}
            for r in rs:
                XtX, Xt, _ = self.si[(r, j)]
                w2 = self.w[(r, j)] ** 2
                A[:, ix[r][:, None], ix[r][None, :]] += w2 * np.einsum("sb,bpq->spq", c[:, r], XtX)
                b[:, ix[r]] += w2 * np.einsum("sb,bp->sp", c[:, r], Xt)
            if neither:                 # the inertia column out: its row and column zero, its value zero
                A[:, 0, :], A[:, :, 0], b[:, 0] = 0.0, 0.0, 0.0
                A[:, 0, 0] = 1.0
            x = _solve(A, b)
            da[j] = x[:, 0]
            for r in rs:
                th[(r, j)] = x[:, ix[r]]
        return da, th

    def residuals(self, rows_of_key: dict, k: int, th_d: dict, th_i: dict, th_0: dict) -> dict:
        """{hypothesis: {key: residual (m,) at the rows ``rows_of_key[key]``}} of the three fits (one replicate)."""
        out = {"delay": {}, "inertia": {}, "neither": {}}
        for key in self.keys:
            m = rows_of_key[key]
            y = self.parts[key[0]].y[key[1]][m]
            out["delay"][key] = self.td[key][k][m] - self.Xd[key][k][m] @ th_d[key]
            out["inertia"][key] = y - self.Xi[key][m] @ th_i[key]
            out["neither"][key] = y - self.Xi[key][m] @ th_0[key]
        return out


def decide_pooled(parts: list[RunPart], n_blocks: int = 10, n_folds: int = 5, n_boot: int = N_BOOT,
                  seed: int = 0) -> dict:
    """A delay against inertia errors decided on several runs of one arm at once: the delay one for all runs
    (``H_D``), the inertia error of each joint one for all runs (``H_I``), each (run, joint) with its own friction
    and offset (a friction that drifted between runs, each run's own gains and start state do not enter the
    inverse-dynamics residual). Each joint's residual in units of its noise floor in its run (:func:`decide` on
    that run alone).

    The pooled winner is the hypothesis with the smaller weighted residual over all runs. With both fitted on all
    runs, each run's excess (the loser's weighted RMS beyond the winner's, ``sqrt(rms_lose^2 - rms_win^2) /
    rms_win``, in noise floors, as :func:`decide`): ``outcome`` is the winner when some run's excess is at least
    :data:`DECIDED_FLOORS` and no run prefers the loser by as much, else ``"ambiguous"``; ``decided_by`` are the
    runs whose excess reaches it, ``added_nothing`` the others. A name a run's own diagnosis made (``RunPart.named``)
    is not lost to the pooling unless the evidence contradicts it: when the pooled winner is that name and no run
    prefers the loser by :data:`DECIDED_FLOORS`, the outcome is the winner even where no run's excess reaches it
    (a run added below its design's target, or one that does not excite the effect, weighs its own evidence and no
    more; ``named_by`` lists those runs, counted among ``decided_by``). Held-out torque RMS (N m) per run and pooled:
    friction and offset only (before), each hypothesis (after), fitted without each fold of every run's time
    blocks at once. The winner's estimate with its 95 % interval (a bootstrap of each run's time blocks): the
    delay (s, on :data:`DELAY_GRID_S`) or the inertia errors (kg m^2 per 1-based joint). ``test``: the winner's
    held-out residual against friction only (:func:`~wamctl.analysis.diagnosis.stats.nested_test`)."""
    from wamctl.analysis.diagnosis.stats import nested_test
    from wamctl.analysis.diagnosis.uncertainty import percentile_ci

    pool = _Pool(parts, n_blocks)
    R = len(parts)
    ones = np.ones((1, R, n_blocks))
    k_all, th_d = pool.fit_delay(ones)
    da_all, th_i = pool.fit_inertia(ones)
    _, th_0 = pool.fit_inertia(ones, neither=True)
    allrows = {key: np.ones(len(pool.blk[key]), bool) for key in pool.keys}
    res = pool.residuals(allrows, int(k_all[0]), {k: v[0] for k, v in th_d.items()},
                         {k: v[0] for k, v in th_i.items()}, {k: v[0] for k, v in th_0.items()})

    def wrms(h, keys):
        n = sum(len(res[h][k]) for k in keys)
        return float(np.sqrt(sum(pool.w[k] ** 2 * float(res[h][k] @ res[h][k]) for k in keys) / max(n, 1)))

    hyps = ("delay", "inertia", "neither")
    pooled_rms = {h: wrms(h, pool.keys) for h in hyps}
    win = "delay" if pooled_rms["delay"] <= pooled_rms["inertia"] else "inertia"
    lose = "inertia" if win == "delay" else "delay"

    # held out: every fold of every run's blocks left out at once
    fold_of_block = np.arange(n_blocks) % n_folds
    held = {h: {key: np.full(len(pool.blk[key]), np.nan) for key in pool.keys} for h in hyps}
    for f in range(n_folds):
        c = np.broadcast_to((fold_of_block != f).astype(float), (1, R, n_blocks))
        k_f, td_f = pool.fit_delay(c)
        _, ti_f = pool.fit_inertia(c)
        _, t0_f = pool.fit_inertia(c, neither=True)
        test = {key: fold_of_block[pool.blk[key]] == f for key in pool.keys}
        e = pool.residuals(test, int(k_f[0]), {k: v[0] for k, v in td_f.items()},
                           {k: v[0] for k, v in ti_f.items()}, {k: v[0] for k, v in t0_f.items()})
        for h in hyps:
            for key in pool.keys:
                held[h][key][test[key]] = e[h][key]

    def held_rms(h, keys):
        e = np.concatenate([held[h][k] for k in keys])
        return float(np.sqrt(np.nanmean(e ** 2)))

    per_run = []
    for r, p in enumerate(parts):
        keys = [k for k in pool.keys if k[0] == r]
        rr = {h: wrms(h, keys) for h in hyps}
        excess, against = excess_floors(rr[lose], rr[win]), excess_floors(rr[win], rr[lose])
        per_run.append({
            "label": p.label, "joints": [j + 1 for _, j in keys],
            "rms_noise_floors": rr, "excess_noise_floors": excess, "against_noise_floors": against,
            "held_out_rms_Nm": {h: held_rms(h, keys) for h in hyps},
            "held_out_rms_per_joint_Nm": {j + 1: {h: held_rms(h, [(r, j)]) for h in hyps} for _, j in keys},
            "alone": {"outcome": p.decision["outcome"], "excess_noise_floors": p.decision["excess_noise_floors"],
                      "delay_s": p.decision["delay_s"]}})
    decided = [p["label"] for p in per_run if p["excess_noise_floors"] >= DECIDED_FLOORS]
    contra = [p["label"] for p in per_run if p["against_noise_floors"] >= DECIDED_FLOORS]
    named_by = [p.label for p in parts if p.named == win]
    outcome = win if (decided or named_by) and not contra else "ambiguous"

    # the winner's estimate, 95 % interval by a bootstrap of each run's time blocks
    rng = np.random.default_rng(seed)
    cb = np.stack([rng.multinomial(n_blocks, np.full(n_blocks, 1.0 / n_blocks), size=n_boot)
                   for _ in range(R)], axis=1).astype(float)
    n_groups = R * n_blocks
    delay_s = float(DELAY_GRID_S[k_all[0]])
    if win == "delay":
        kb, _ = pool.fit_delay(cb)
        lo, hi = percentile_ci(DELAY_GRID_S[kb], center=delay_s, n_groups=n_groups)
        half = float(np.diff(DELAY_GRID_S[1:]).max()) / 2     # the grid's own resolution: half a step each side
        est = {"delay_s": delay_s, "delay_ci_s": [max(lo - half, 0.0), min(hi + half, MAX_DELAY_S)]}
    else:
        dab, _ = pool.fit_inertia(cb)
        est = {"inertia_error_kg_m2": {j + 1: float(v[0]) for j, v in da_all.items()},
               "inertia_error_ci_kg_m2": {j + 1: percentile_ci(dab[j], center=float(da_all[j][0]),
                                                                n_groups=n_groups) for j in da_all}}
    w_all = np.concatenate([np.full(len(pool.blk[k]), pool.w[k]) for k in pool.keys])
    groups = np.concatenate([fold_of_block[pool.blk[k]] + 100 * i for i, k in enumerate(pool.keys)])
    e0 = np.concatenate([held["neither"][k] for k in pool.keys]) * w_all
    e1 = np.concatenate([held[win][k] for k in pool.keys]) * w_all
    p_extra = 1 if win == "delay" else len(da_all)
    test = nested_test(e0, e1, p_extra, 5 * len(pool.keys) + p_extra, groups=groups)
    return {"outcome": outcome, "winner": win, "rms_noise_floors": pooled_rms,
            "excess_noise_floors": excess_floors(pooled_rms[lose], pooled_rms[win]),
            "per_run": per_run, "named_by": named_by,
            "decided_by": decided + [x for x in named_by if x not in decided] if outcome != "ambiguous" else [],
            "contradicted_by": contra,
            "added_nothing": [p["label"] for p in per_run if p["label"] not in decided + named_by],
            "held_out_rms_Nm": {h: held_rms(h, pool.keys) for h in hyps},
            "fitted_delay_s": delay_s, **est,
            "test": {k: float(test[k]) for k in ("p_value", "delta_bic", "F", "n", "n_eff", "ssr_ratio")}}
