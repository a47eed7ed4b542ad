"""The run that can tell: T-optimal discrimination between a wrist payload and the arm's own link errors (no I/O).

When one run cannot tell a payload from link errors within the declared accuracy (the payload-or-links decision
``ambiguous``, or link errors that explain a payload's torque on a sweep of one joint), the next run should be
the one on which the two hypotheses' fitted models predict torques that differ most, after each hypothesis refits
its own parameters to that run (Atkinson & Fedorov's T-optimality, 1975). Here:

* ``H_P``, a wrist payload: the base-parameter change ``P mh`` of its mass and first moment ``mh`` (the payload
  fitted on the run, :func:`~wamctl.analysis.diagnosis.candidates.payload_from_pi`);
* ``H_L``, link errors: ``G l``, ``G`` the plausible link map (:func:`~wamctl.analysis.diagnosis.rigid.
  plausible_link_map`), ``|l| <= bound`` (1: the declared accuracy); its fitted model is the ``l`` that
  best reproduces ``H_P``'s torque on the run that could not tell them apart;
* nuisance parameters of every moving joint (Coulomb per direction, viscous, offset) refitted with each.

:func:`separation` of a trajectory: for each hypothesis taken as true, the other refitted (bounded least squares,
:func:`scipy.optimize.lsq_linear`) to its torque on the trajectory; the RMS of what it cannot reproduce over the
moving joints' samples, in units of the noise floor (the run's held-out torque residual RMS); the smaller of the
two directions is the trajectory's separation. Below 1 the run cannot tell the hypotheses apart sample by
sample; the design asks for more than 2.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import lsq_linear

from wamctl.analysis.blas import single_threaded_blas
from wamctl.analysis.diagnosis.candidates import D7_M
from wamctl.analysis.diagnosis.prepare import link_base_rows
from wamctl.analysis.diagnosis.rigid import payload_cone, payload_map

MIN_SPEED_RAD_S = 0.01        # a joint's sample counts where it moves faster than this


@dataclass
class Rows:
    """A trajectory's rigid-body base rows per moving joint: ``Z[j]`` (m_j, nb), and nuisance columns ``N[j]``
    (m_j, 4): Coulomb per direction, viscous, offset."""

    Z: dict
    N: dict

    @property
    def joints(self) -> list[int]:
        return sorted(self.Z)


def trajectory_rows(dynamics, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray, stride: int = 1) -> Rows:
    """:class:`Rows` of the states ``q, qd, qdd`` (n, 7) every ``stride`` samples, for the joints that move."""
    q, qd, qdd = q[::stride], qd[::stride], qdd[::stride]
    reg = dynamics.torque_regressor(q, qd, qdd)
    Z, N = {}, {}
    for j in range(q.shape[1]):
        m = np.abs(qd[:, j]) > MIN_SPEED_RAD_S
        if m.sum() < 10:
            continue
        v = qd[m, j]
        Z[j] = link_base_rows(reg[m, j, :], qdd[m, j], j)
        N[j] = np.column_stack([(v > 0).astype(float), -(v < 0).astype(float), v, np.ones(m.sum())])
    return Rows(Z, N)


def payload_delta(mass_kg: float, com_m) -> np.ndarray:
    """(nb,) base-parameter change of a point payload (mass, centre in the flange frame)."""
    mh = np.r_[mass_kg, mass_kg * (np.asarray(com_m, float) + [0.0, 0.0, D7_M])]
    return payload_map()[:, :4] @ mh


def _stack(rows: Rows, A: np.ndarray):
    """The stacked design [Z A | blockdiag(N)] over the moving joints."""
    js = rows.joints
    m = [len(rows.Z[j]) for j in js]
    X = np.zeros((sum(m), A.shape[1] + 4 * len(js)))
    r = 0
    for k, j in enumerate(js):
        X[r:r + m[k], :A.shape[1]] = rows.Z[j] @ A
        X[r:r + m[k], A.shape[1] + 4 * k:A.shape[1] + 4 * k + 4] = rows.N[j]
        r += m[k]
    return X


def refit_residual(rows: Rows, delta_true: np.ndarray, A: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> tuple:
    """What the hypothesis ``A x`` (``lo <= x <= hi``, with free nuisance parameters) cannot reproduce of the
    torque of ``delta_true`` on ``rows``: (RMS N m, x)."""
    y = np.concatenate([rows.Z[j] @ delta_true for j in rows.joints])
    X = _stack(rows, A)
    lo_all = np.r_[lo, np.full(X.shape[1] - A.shape[1], -np.inf)]
    hi_all = np.r_[hi, np.full(X.shape[1] - A.shape[1], np.inf)]
    scale = np.sqrt((X ** 2).sum(axis=0))
    live = scale > 1e-9 * scale.max()            # columns the trajectory does not excite change nothing
    Xs = X[:, live] / scale[live]
    # the same minimiser on p rows instead of m (the residual off Q is fixed): R and Q'y from the triangular
    # factor of [Xs y] alone (Q itself, m x p, is never formed)
    Ra = np.linalg.qr(np.column_stack([Xs, y]), mode="r")
    p = Xs.shape[1]
    R, qty = Ra[:p, :p], Ra[:p, p]
    res = lsq_linear(R, qty, bounds=(lo_all[live] * scale[live], hi_all[live] * scale[live]), method="bvls",
                     tol=1e-12)
    x = np.zeros(X.shape[1])
    x[live] = res.x / scale[live]
    e = y - X @ x
    return float(np.sqrt(np.mean(e ** 2))), x[:A.shape[1]]


@dataclass
class Hypotheses:
    """The two fitted models: ``delta_payload`` and ``delta_links`` (nb,), the link map ``G`` with its bound."""

    delta_payload: np.ndarray
    delta_links: np.ndarray
    G: np.ndarray
    bound: float
    com_box_m: float


def fitted_hypotheses(rows_run: Rows, mass_kg: float, com_m, G: np.ndarray, bound: float = 1.0,
                      com_box_m: float = 0.15) -> Hypotheses:
    """The payload's model and the link errors' model that best reproduces it on the run ``rows_run``."""
    dp = payload_delta(mass_kg, com_m)
    lim = np.full(G.shape[1], bound)
    _, l_hat = refit_residual(rows_run, dp, G, -lim, lim)
    return Hypotheses(dp, G @ l_hat, G, bound, com_box_m)


def separation(rows: Rows, hyp: Hypotheses, noise_Nm: float) -> dict:
    """The T-criterion of a trajectory: ``{"payload_true", "links_true"}`` (each: RMS the other cannot reproduce,
    in noise-floor units) and ``"separation"``, the smaller."""
    lim = np.full(hyp.G.shape[1], hyp.bound)
    r_p, _ = refit_residual(rows, hyp.delta_payload, hyp.G, -lim, lim)
    cone, _ = payload_cone(hyp.com_box_m)
    r_l, _ = refit_residual(rows, hyp.delta_links, cone, np.zeros(cone.shape[1]), np.full(cone.shape[1], np.inf))
    out = {"payload_true": r_p / noise_Nm, "links_true": r_l / noise_Nm}
    out["separation"] = min(out.values())
    return out


# ------------------------------------------------------------------------------------------------- the design
DESIGN_RATE_HZ = 12.5          # the criterion's samples per second (the limits are checked at the control rate)


@dataclass
class NextRun:
    """The designed trajectory, its separation (:func:`separation`) and the original run's, the candidates
    scored (joints, separation) and the limits it uses (:class:`~wamctl.analysis.identification.excitation.
    LimitUse`)."""

    trajectory: object
    separation: dict
    original: dict
    scored: list
    limit_use: object


def _at_scale(traj, k: float, limits, dynamics, friction, **kw):
    """``traj`` with its coefficients scaled by ``k`` (about q0) and its :class:`~wamctl.analysis.identification.
    excitation.LimitUse` by excite's own check (``rate_hz`` in ``kw``: on that grid; default the control rate)."""
    from wamctl.analysis.identification.excitation import FourierTrajectory, sampled_limit_use

    tr = FourierTrajectory(traj.q0_rad, traj.period_s, traj.a * k, traj.b * k)
    return tr, sampled_limit_use(tr, limits, dynamics, friction, **kw)


def coarse_scaled(traj, limits, dynamics, friction, fill: float, rate_hz: float | None = None):
    """``traj`` scaled as far as its closest limit stays within ``fill`` of it on the grid ``rate_hz`` (None: the
    control rate), by bisection on the scale (at most 1): ``(trajectory, LimitUse, scale)``, or None when a
    hundredth of it already crosses ``fill``. A peak between the samples of a coarse grid is not seen here:
    :func:`at_control_rate` checks it."""
    kw = {} if rate_hz is None else {"rate_hz": rate_hz}
    lo, hi = 0.01, 1.0
    best = _at_scale(traj, lo, limits, dynamics, friction, **kw)
    if best[1].worst[2] > fill:
        return None
    top = _at_scale(traj, hi, limits, dynamics, friction, **kw)
    if top[1].worst[2] <= fill:
        return top[0], top[1], hi
    for _ in range(8):
        mid = np.sqrt(lo * hi)
        got = _at_scale(traj, mid, limits, dynamics, friction, **kw)
        if got[1].worst[2] <= fill:
            lo, best = mid, got
        else:
            hi = mid
    return best[0], best[1], lo


def at_control_rate(traj, limits, dynamics, friction, fill: float):
    """``traj`` checked at the control rate by excite's own check and shrunk (3 % a step) until it keeps within
    ``fill`` there: ``(trajectory, LimitUse)``, or None when no shrink down to a sixth of it does."""
    k = 1.0
    for _ in range(60):
        got = _at_scale(traj, k, limits, dynamics, friction)
        if got[1].worst[2] <= fill:
            return got
        k *= 0.97
    return None


def scaled_to_limits(traj, limits, dynamics, friction, fill: float, rate_hz: float | None = None):
    """``traj`` scaled (its coefficients, about q0) as far as its closest limit stays within ``fill`` of it, by
    excite's own check (:func:`~wamctl.analysis.identification.excitation.sampled_limit_use`; bisection on the
    scale, at most 1); None when a hundredth of it already crosses ``fill``. ``rate_hz``: the bisection's check
    on this coarser grid, the result then checked at the control rate and shrunk (3 % a step) until it keeps
    within ``fill`` there too (None: every check at the control rate)."""
    got = coarse_scaled(traj, limits, dynamics, friction, fill, rate_hz)
    if got is None:
        return None
    if rate_hz is None:
        return got[0], got[1]
    return at_control_rate(got[0], limits, dynamics, friction, fill)


def best_within_limits(candidates: list, score, limits, dynamics, friction, fill: float):
    """The T-optimal candidate that keeps within the limits at the control rate, with one full check for few of
    them: ``candidates`` are ``(coarse score, trajectory scaled on a coarse grid, label)``; in order of coarse
    score, each is checked at the control rate (:func:`at_control_rate`, shrunk where a peak between the coarse
    samples crosses ``fill``) and scored again (``score(trajectory) -> dict`` with ``"separation"``), until the
    best verified score is at least the next candidate's coarse score (shrinking a trajectory does not raise its
    separation, assumed: the hypotheses' torques grow with its motion). Returns ``(trajectory, score dict, LimitUse,
    checked)``, ``checked`` {label: separation after the control rate's check, None where none kept within it} of
    the candidates checked there, or None when none keeps within the limits."""
    best, checked = None, {}
    for sep, traj, label in sorted(candidates, key=lambda c: -c[0]):
        if best is not None and best[1]["separation"] >= sep:
            break
        got = at_control_rate(traj, limits, dynamics, friction, fill)
        checked[label] = None
        if got is None:
            continue
        sc = score(got[0])
        checked[label] = float(sc["separation"])
        if best is None or sc["separation"] > best[1]["separation"]:
            best = (got[0], sc, got[1])
    return None if best is None else (*best, checked)


def candidate_scores(candidates: list, checked: dict) -> list[tuple]:
    """``(label, trajectory, separation)`` of the ``candidates`` of :func:`best_within_limits` not found outside
    the limits at the control rate: the separation after that check where it was made (``checked``), else the
    coarse one."""
    return [(k, tr, float(s if checked.get(k) is None else checked[k]))
            for s, tr, k in candidates if not (k in checked and checked[k] is None)]


LIMIT_CHECK_RATE_HZ = 50.0     # the candidates' scaling checked on this grid, the winner's at the control rate


@single_threaded_blas()     # small dense products: threads only contend on a shared machine
def design_next_run(dynamics, friction, q0_rad, hyp: Hypotheses, noise_Nm: float, rows_run: Rows, limits,
                    joint_sets: list[list[int]], period_s: float = 8.0, harmonics: int = 5, per_set: int = 2,
                    fill: float = 0.95, seed: int = 0) -> NextRun:
    """T-optimal choice among Fourier candidates (excite's parametrisation, :class:`~wamctl.analysis.
    identification.excitation.FourierTrajectory`): ``per_set`` random series (seeded) on each of ``joint_sets``
    (0-based), each scaled to ``fill`` of its closest limit by excite's limit check on a coarse grid
    (:func:`coarse_scaled`), scored there, and the best checked at the control rate (:func:`best_within_limits`);
    the candidate whose smaller separation is largest wins. ``scored``: each candidate's separation, at the control
    rate's scale where it was checked there, else at the coarse grid's. Raises ValueError when no candidate keeps
    within the limits."""
    from wamctl.analysis.identification.excitation import FourierTrajectory

    rng = np.random.default_rng(seed)
    t = np.arange(int(period_s * DESIGN_RATE_HZ)) / DESIGN_RATE_HZ

    def score(traj):
        return separation(trajectory_rows(dynamics, *traj.evaluate(t)), hyp, noise_Nm)

    cands = []
    for js in joint_sets:
        for _ in range(per_set):
            x = rng.normal(size=(len(js), 2 * (harmonics - 1))) / np.tile(np.arange(2, harmonics + 1), 2)
            got = coarse_scaled(FourierTrajectory.from_free(q0_rad, period_s, js, x, harmonics), limits,
                                dynamics, friction, fill, LIMIT_CHECK_RATE_HZ)
            if got is not None:
                cands.append((score(got[0])["separation"], got[0], len(cands)))
    best = best_within_limits(cands, score, limits, dynamics, friction, fill)
    if best is None:
        raise ValueError("no candidate trajectory keeps within the limits")
    traj, sep, use, checked = best
    scored = [([j + 1 for j in tr.moving], s) for _, tr, s in candidate_scores(cands, checked)]
    return NextRun(traj, sep, separation(rows_run, hyp, noise_Nm), scored, use)
