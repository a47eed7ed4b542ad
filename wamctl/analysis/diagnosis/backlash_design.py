"""The run that shows backlash behind a motor-side encoder: slow crossings of the pose where the joint's gravity
torque changes sign (no I/O).

With the encoder on the motor and a gap ``2 b`` between motor and link, the link hangs ``b`` from the motor on the
side gravity pulls it to: ``q_link = q_motor - b sgn(g_j)``. The torque the motor gives is the gravity of the link
where it is, and the model evaluates it where the encoder says: the residual is ``g_j(q_link) - g_j(q_motor) ~
-b sgn(g_j) dg_j/dq_j``. Where ``g_j`` keeps one sign over a run this is a constant, which the fitted friction's
offset absorbs (the run cannot tell the gap from nothing); where ``g_j`` changes sign the link falls through the
gap and the residual steps by ``2 b |dg_j/dq_j|``, which no friction (tied to the velocity's sign) or offset
reproduces. The design puts the crossing in the middle of a slow back-and-forth motion of the joint alone.

:func:`signature`: that residual on a trajectory's sliding samples; :func:`separation`: what the nuisance fit
(Coulomb per direction, viscous, offset) leaves of it, RMS in noise floors; :func:`design_crossing`: the pose with
the steepest gravity crossing within the joint's range (the other joints at the run's pose, or a few poses of the
shoulder and elbow) and the slow two-harmonic motion about it, scaled within excite's limits.

Where gravity is small (the wrist) that step stays near the floor even for a large gap, and the same slow motion
shows the gap another way: at each of its reversals, where the link comes to rest held only by its own friction
(the torque the rigid link needs there, ``rnea_j - armature_j qdd_j``, is below the link's share of the joint's
Coulomb friction), the link stays put while the motor turns round and crosses the gap with only its own inertia:
the measurement leads the link by the gap, which the backlash onset test
(:mod:`wamctl.analysis.diagnosis.backlash`) sees against its resolution (``MIN_BAND_TOLERANCES`` detection
tolerances). :func:`reversal_leads` predicts those leads, :func:`reversal_separation` their RMS over a
trajectory's reversals in units of that resolution; the design is scored on both and says which.

That figure is the lead at one reversal: it does not grow with their number, so it cannot say whether a run will
decide. What decides is the diagnosis' backlash decision on the designed run's onsets
(:func:`~wamctl.analysis.diagnosis.onset_tests.backlash_decision`: a nested test on held-out onsets at the
diagnosis' threshold, its BIC, the lead's sign and ``MIN_BAND_TOLERANCES``), and a motor-side gap found there is
named pooled as the run named it (:mod:`wamctl.analysis.diagnosis.pooled`: an effect seen at the onsets only is not
tested again). :func:`reversal_power` predicts that decision's power and median test statistic for a run's onsets
by Monte Carlo (the leads :func:`reversal_leads` predicts, the log travel scattered as the first run's onsets were:
:func:`onset_scatter`); :func:`size_reversal_run` takes the fewest periods that reach ``POWER_TARGET`` within
``MAX_RUN_S``, or says none does. The link-side friction share is bounded by the first run's reversals where it
can be (:func:`link_share_from_run`), else ``LINK_FRICTION_SHARE`` is assumed. The prediction is conservative
where the designed run repeats one motion: its onsets scatter less than the first run's.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from wamctl.analysis.diagnosis.backlash import MIN_BAND_TOLERANCES, log_travel
from wamctl.model.friction import classic_friction_columns

MIN_SPEED_RAD_S = 0.005          # sliding samples (a slow crossing)
CROSSING_PERIOD_S = 16.0         # slow: the link falls through the gap while the motor barely moves
CROSSING_AMPLITUDE_RAD = 0.25    # the motion about the crossing pose
FD_STEP_RAD = 1e-4
GRAVITY_ZERO_NM = 1e-9           # a gravity torque below this is none (a joint whose axis stays vertical)
# the share of a joint's Coulomb friction assumed on the link side of a gap (bearings and seals after the gear):
# not known from one run; a low share makes fewer reversals count as crossings (a conservative prediction)
LINK_FRICTION_SHARE = 0.2
CROSSING_PERIODS = 8             # periods of the designed run: two reversals each, sixteen in all
# the reversal run's size: the power asked for, the longest run proposed, the draws of the power's Monte Carlo
POWER_TARGET = 0.9
MAX_RUN_S = 120.0
MIN_PERIODS = 2
POWER_DRAWS = 1000
# the scatter of the onset test's log travel (``sign(d) log(1 + |d| / tol)``) assumed where the run has too few
# onsets to measure it (fewer than ``MIN_SCATTER_ONSETS``), and the least assumed where it has: a handful of onsets
# says little about their spread
DEFAULT_LOG_SD = 0.7
MIN_LOG_SD = 0.3
MIN_SCATTER_ONSETS = 3


def gravity_and_slope(dynamics, q: np.ndarray, j: int) -> tuple[np.ndarray, np.ndarray]:
    """(n,) joint ``j``'s gravity torque at the poses ``q`` (n, 7) and its derivative along ``q_j`` (central
    difference)."""
    dq = np.zeros(q.shape[1])
    dq[j] = FD_STEP_RAD
    g = dynamics.gravity_many(q)[:, j]
    s = (dynamics.gravity_many(q + dq)[:, j] - dynamics.gravity_many(q - dq)[:, j]) / (2 * FD_STEP_RAD)
    return g, s


def signature(dynamics, q: np.ndarray, qd: np.ndarray, j: int, gap_rad: float) -> tuple[np.ndarray, np.ndarray]:
    """(m,) the residual a total gap ``gap_rad`` behind the encoder gives at joint ``j``'s sliding samples, and
    (m,) their speeds."""
    m = np.abs(qd[:, j]) > MIN_SPEED_RAD_S
    g, s = gravity_and_slope(dynamics, q[m], j)
    return -0.5 * gap_rad * np.sign(g) * s, qd[m, j]


def separation(dynamics, q: np.ndarray, qd: np.ndarray, j: int, gap_rad: float, noise_Nm: float) -> float:
    """What friction and an offset refitted cannot reproduce of the gap's residual (:func:`signature`) on a
    trajectory, RMS in units of the noise floor ``noise_Nm`` (0 when the joint does not slide)."""
    y, v = signature(dynamics, q, qd, j, gap_rad)
    if len(y) < 10:
        return 0.0
    X = np.column_stack([classic_friction_columns(v), np.ones(len(v))])
    th, *_ = np.linalg.lstsq(X, y, rcond=None)
    return float(np.sqrt(np.mean((y - X @ th) ** 2)) / noise_Nm)


def reversal_leads(dynamics, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray, j: int, gap_rad: float,
                   fc_Nm: float, share: float = LINK_FRICTION_SHARE) -> np.ndarray:
    """(k,) the lead (rad) a total gap ``gap_rad`` behind a motor-side encoder gives at each of the k reversals of
    joint ``j`` along a trajectory sampled as ``q, qd, qdd`` (n, 7): ``gap_rad`` where the torque the rigid link
    needs at the turning point, ``rnea_j - armature_j qdd_j``, is below ``share x fc_Nm`` (the link comes to rest
    on its own friction and the motor crosses the gap to drive it back), else 0 (the drive keeps pressing the
    link on one flank through the turn). A reversal: the joint's velocity changes sign between samples faster than
    ``MIN_SPEED_RAD_S`` (a dwell at rest, or a measured joint's noise at rest, is not one); its turning point the
    slower of the two samples about the change."""
    v = qd[:, j]
    keep = np.flatnonzero(np.abs(v) > MIN_SPEED_RAD_S)
    if len(keep) < 2:
        return np.zeros(0)
    s = np.sign(v[keep])
    ch = np.flatnonzero(s[1:] != s[:-1])
    if not len(ch):
        return np.zeros(0)
    a, b = keep[ch], keep[ch + 1]
    k = np.where(np.abs(v[a]) <= np.abs(v[b]), a, b)
    need = dynamics.inverse_dynamics_many(q[k], qd[k], qdd[k])[:, j] - dynamics.armature_kg_m2[j] * qdd[k, j]
    return np.where(np.abs(need) < share * max(float(fc_Nm), 0.0), float(gap_rad), 0.0)


def reversal_separation(dynamics, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray, j: int, gap_rad: float,
                        fc_Nm: float, tol_rad: float, share: float = LINK_FRICTION_SHARE) -> tuple[float, int, int]:
    """(separation, crossings, reversals): the RMS over joint ``j``'s reversals of the leads
    :func:`reversal_leads` predicts, in units of the backlash onset test's resolution (``MIN_BAND_TOLERANCES``
    detection tolerances ``tol_rad``: without a gap a light joint's measurement may lead by up to about four), with
    the number of reversals where the gap is crossed and of reversals (0, 0, 0 without reversals)."""
    lead = reversal_leads(dynamics, q, qd, qdd, j, gap_rad, fc_Nm, share)
    if not len(lead) or tol_rad <= 0:
        return 0.0, 0, int(len(lead))
    return (float(np.sqrt(np.mean(lead ** 2)) / (MIN_BAND_TOLERANCES * tol_rad)), int(np.count_nonzero(lead)),
            int(len(lead)))


def onset_pattern(qd_j: np.ndarray) -> np.ndarray:
    """(m,) whether each onset of a joint moving with velocity ``qd_j`` (n,) (one period of a periodic motion, or a
    whole run) is a reversal, in time order: the velocity changes sign between samples faster than
    ``MIN_SPEED_RAD_S`` (a reversal, as :func:`reversal_leads` counts them) or dips below it and goes on the same
    way (a same-direction onset: the two-harmonic series' dwell at its ends)."""
    v = np.asarray(qd_j, float)
    keep = np.flatnonzero(np.abs(v) > MIN_SPEED_RAD_S)
    if len(keep) < 2:
        return np.zeros(0, bool)
    s = np.sign(v[keep])
    turn = s[1:] != s[:-1]
    stall = (np.diff(keep) > 1) & ~turn
    return turn[turn | stall]


def onset_folds(n: int, n_blocks: int = 10, n_folds: int = 5) -> np.ndarray:
    """(n,) the folds of ``n`` onsets spread evenly over a run cut into ``n_blocks`` time blocks dealt into
    ``n_folds`` folds (block modulo folds, as the diagnosis deals them)."""
    return (np.arange(n) * n_blocks // max(n, 1)) % n_folds


@dataclass
class OnsetScatter:
    """The spread of the backlash test's values (log travel, ``sign(d) log(1 + |d| / tol)``) a run's onsets show:
    ``same_log_sd`` where no gap is crossed (same-direction onsets), ``lead_log_sd`` among the leads at reversals
    (their larger half, as :func:`~wamctl.analysis.diagnosis.backlash.band_width` takes them), each with the number
    of onsets it rests on (fewer than ``MIN_SCATTER_ONSETS``: ``DEFAULT_LOG_SD`` assumed)."""

    same_log_sd: float = DEFAULT_LOG_SD
    lead_log_sd: float = DEFAULT_LOG_SD
    n_same: int = 0
    n_lead: int = 0


def onset_scatter(travel_rad: np.ndarray, reversal: np.ndarray, tol_rad: float) -> OnsetScatter:
    """:class:`OnsetScatter` of a run's onsets: signed hidden travel ``travel_rad`` (k,) (NaN: the model's link
    never moved; left out) and ``reversal`` (k,), with the detection tolerance ``tol_rad``."""
    d, rev = np.asarray(travel_rad, float), np.asarray(reversal, bool)
    ok = np.isfinite(d)
    lv = log_travel(d[ok], tol_rad)
    same = lv[~rev[ok]]
    leads = np.sort(lv[rev[ok]])[: (int(rev[ok].sum()) + 1) // 2]

    def sd(x):
        return max(float(np.std(x, ddof=1)), MIN_LOG_SD) if len(x) >= MIN_SCATTER_ONSETS else DEFAULT_LOG_SD

    return OnsetScatter(sd(same), sd(leads), int(len(same)), int(len(leads)))


def reversal_power(rev: np.ndarray, lead_rad: np.ndarray, tol_rad: float, scatter: OnsetScatter, threshold: float,
                   n_folds: int = 5, draws: int = POWER_DRAWS, seed: int = 0) -> dict:
    """The power of the diagnosis' backlash decision (:func:`~wamctl.analysis.diagnosis.onset_tests.
    backlash_decision`: the nested test on held-out onsets at ``threshold``, its BIC, the lead's sign and its
    ``MIN_BAND_TOLERANCES`` detection tolerances) on a run whose onsets are ``rev`` (m,) (reversal or not, in time
    order) with the predicted leads ``lead_rad`` (m,) (0 where no gap is crossed): Monte Carlo over ``draws`` runs,
    each onset's log travel drawn about its prediction with ``scatter``'s spread. ``{"power", "power_se" (its Monte
    Carlo standard error), "t_median" (the median test statistic, the root of the F statistic: the reversals'
    lead in standard errors), "onsets", "reversals", "crossing"}``."""
    from wamctl.analysis.diagnosis.onset_tests import backlash_decision_many

    rev = np.asarray(rev, bool)
    lead = np.asarray(lead_rad, float)
    m = len(rev)
    out = {"onsets": m, "reversals": int(rev.sum()), "crossing": int(np.count_nonzero(lead[rev] > 0))}
    if m == 0 or tol_rad <= 0:
        return dict(out, power=0.0, power_se=0.0, t_median=0.0)
    rng = np.random.default_rng(seed)
    mean = np.where(lead > 0, -np.log1p(lead / tol_rad), 0.0)
    sd = np.where(lead > 0, scatter.lead_log_sd, scatter.same_log_sd)
    lv = mean + sd * rng.standard_normal((draws, m))
    got = backlash_decision_many(np.sign(lv) * tol_rad * np.expm1(np.abs(lv)), rev,
                                 onset_folds(m, n_blocks=2 * n_folds, n_folds=n_folds), tol_rad, n_folds, threshold)
    kept = got["kept"] & got["motor"]
    p = float(kept.mean())
    t = np.where(got["motor"], np.sqrt(got["F"]), 0.0)
    return dict(out, power=p, power_se=float(np.sqrt(max(p * (1 - p), 1.0 / draws) / draws)),
                t_median=float(np.median(t)))


def size_reversal_run(rev_period: np.ndarray, lead_period: np.ndarray, period_s: float, tol_rad: float,
                      scatter: OnsetScatter, threshold: float, n_folds: int = 5, target: float = POWER_TARGET,
                      max_run_s: float = MAX_RUN_S, seed: int = 0) -> dict:
    """The fewest periods of a periodic run (one period's onsets ``rev_period`` (m,), their predicted leads
    ``lead_period`` (m,), ``period_s``) whose backlash decision reaches the power ``target``
    (:func:`reversal_power`; the smaller of the powers with and without the same-direction onsets, whose stalls
    the measurement may not resolve), from ``MIN_PERIODS`` up to the longest run within ``max_run_s``; the last
    onset (the run's end at rest) is not one. ``{"periods", "duration_s", "reached", "power", "power_se", "t_median",
    "onsets", "reversals", "crossing", "curve": [(periods, power, t_median), ...]}``: ``reached`` False with the
    longest run's figures when no run within ``max_run_s`` reaches the target (or no period fits)."""
    rev_period, lead_period = np.asarray(rev_period, bool), np.asarray(lead_period, float)
    top = int(max_run_s // period_s)
    curve, got = [], None
    for n in range(MIN_PERIODS, top + 1):
        k = n * len(rev_period) - (0 if len(rev_period) and rev_period[-1] else 1)
        rev, lead = np.tile(rev_period, n)[:k], np.tile(lead_period, n)[:k]
        r = reversal_power(rev, lead, tol_rad, scatter, threshold, n_folds, seed=seed)
        if not rev.all():
            # whether a dwell's stall is measured as an onset depends on how long the position stays within a
            # tolerance of it: the run without them too, and the smaller power of the two
            r2 = reversal_power(rev[rev], lead[rev], tol_rad, scatter, threshold, n_folds, seed=seed)
            r = min(r, r2, key=lambda x: (x["power"], x["t_median"]))
        curve.append((n, r["power"], r["t_median"]))
        got = dict(r, periods=n, duration_s=n * period_s, reached=r["power"] >= target)
        if got["reached"]:
            break
    if got is None:
        return {"periods": 0, "duration_s": 0.0, "reached": False, "power": 0.0, "power_se": 0.0, "t_median": 0.0,
                "onsets": 0, "reversals": 0, "crossing": 0, "curve": []}
    return dict(got, curve=curve)


def link_share_bounds(need_Nm: np.ndarray, lead_rad: np.ndarray, fc_Nm: float, tol_rad: float) -> dict:
    """The link-side share of the joint's Coulomb friction ``fc_Nm`` that a run's reversals bound: at each, the
    torque the rigid link needed at the turning point ``need_Nm`` (k,) and the measured lead ``lead_rad`` (k,)
    (positive: the measurement led). A reversal whose measurement led by at least ``MIN_BAND_TOLERANCES`` detection
    tolerances ``tol_rad`` had its link rest on its own friction: the share is above ``|need| / fc`` there; one
    that led by less than a tolerance did not: below. ``{"low", "high", "crossed", "held"}``: ``low`` 0 and ``high``
    None where no reversal bounds them (high below low: the reversals disagree, the bounds are not used)."""
    need = np.abs(np.asarray(need_Nm, float)) / max(float(fc_Nm), 1e-9)
    lead = np.asarray(lead_rad, float)
    ok = np.isfinite(need) & np.isfinite(lead)
    crossed = ok & (lead >= MIN_BAND_TOLERANCES * tol_rad)
    held = ok & (lead < tol_rad)
    low = float(need[crossed].max()) if crossed.any() else 0.0
    high = float(need[held].min()) if held.any() else None
    return {"low": low, "high": high, "crossed": int(crossed.sum()), "held": int(held.sum())}


def link_share_from_run(dynamics, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray, j: int, lead_rad: np.ndarray,
                        fc_Nm: float, tol_rad: float, assumed: float = LINK_FRICTION_SHARE) -> dict:
    """The link-side friction share a run's reversals bound (:func:`link_share_bounds`), with the state ``q, qd,
    qdd`` (k, 7) at their turning points and the measured leads ``lead_rad`` (k,), and the share a design uses:
    the lower bound where a reversal crossed the gap (the fewest crossings the run allows: a conservative
    prediction), else ``assumed`` (reversals where the link held bound it only if there is a gap, which the
    designed run is to test: reported, not used). ``{"low", "high", "crossed", "held", "share", "estimated"}``."""
    need = dynamics.inverse_dynamics_many(q, qd, qdd)[:, j] - dynamics.armature_kg_m2[j] * qdd[:, j]
    b = link_share_bounds(need, lead_rad, fc_Nm, tol_rad)
    consistent = b["high"] is None or b["high"] > b["low"]
    if b["crossed"] and consistent and b["low"] > 0:
        return dict(b, share=float(b["low"]), estimated=True)
    # held reversals bound the share only if there is a gap, the hypothesis the designed run tests: not used
    return dict(b, share=float(assumed), estimated=False)


def crossing_poses(dynamics, q0_rad: np.ndarray, j: int, q_min: np.ndarray, q_max: np.ndarray,
                   margin_rad: float = CROSSING_AMPLITUDE_RAD + 0.05) -> list[tuple[np.ndarray, float]]:
    """Poses (7,) at which joint ``j``'s gravity torque changes sign with ``q_j`` at least ``margin_rad`` inside
    its range, with ``|dg_j/dq_j|`` there; the other joints at ``q0_rad``, or the shoulder (joint 2) and elbow
    (joint 4) moved to a few poses within their ranges. Steepest first."""
    others = [np.asarray(q0_rad, float)]
    for q2 in (-1.0, 0.0, 1.0):
        for q4 in (0.5, 1.5, 2.5):
            p = np.asarray(q0_rad, float).copy()
            if j != 1:
                p[1] = np.clip(q2, q_min[1], q_max[1])
            if j != 3:
                p[3] = np.clip(q4, q_min[3], q_max[3])
            others.append(p)
    grid = np.linspace(q_min[j] + margin_rad, q_max[j] - margin_rad, 181)
    out = []
    for p in others:
        Q = np.tile(p, (len(grid), 1))
        Q[:, j] = grid
        g, _ = gravity_and_slope(dynamics, Q, j)
        for k in np.flatnonzero(np.sign(g[:-1]) * np.sign(g[1:]) < 0):
            qz = grid[k] - g[k] * (grid[k + 1] - grid[k]) / (g[k + 1] - g[k])
            pose = p.copy()
            pose[j] = qz
            _, s = gravity_and_slope(dynamics, pose[None, :], j)
            out.append((pose, float(abs(s[0]))))
    return sorted(out, key=lambda x: -x[1])


def level_poses(dynamics, q0_rad: np.ndarray, j: int, q_min: np.ndarray, q_max: np.ndarray,
                amplitude_rad: float = CROSSING_AMPLITUDE_RAD, margin_rad: float = CROSSING_AMPLITUDE_RAD + 0.05,
                n: int = 3) -> list[np.ndarray]:
    """Poses (7,) about which joint ``j`` can move back and forth with the least gravity torque at its ends (where
    the link must rest on its own friction for a gap to be crossed): ``q_j`` on a grid ``margin_rad`` inside its
    range, the other joints at ``q0_rad`` or the shoulder (joint 2) and elbow (joint 4) moved to a few poses
    (as :func:`crossing_poses`); the ``n`` whose largest ``|g_j|`` over ``q_j +- 1.3 amplitude_rad`` (the
    two-harmonic series' ends) is smallest, smallest first; among poses without any (below ``GRAVITY_ZERO_NM``:
    joint 1), those nearest ``q0_rad`` first."""
    q0_rad = np.asarray(q0_rad, float)
    others = [q0_rad]
    for q2 in (-1.0, 0.0, 1.0):
        for q4 in (0.5, 1.5, 2.5):
            p = q0_rad.copy()
            if j != 1:
                p[1] = np.clip(q2, q_min[1], q_max[1])
            if j != 3:
                p[3] = np.clip(q4, q_min[3], q_max[3])
            others.append(p)
    lo, hi = q_min[j] + margin_rad, q_max[j] - margin_rad
    if hi < lo:
        return []
    grid = np.r_[np.clip(q0_rad[j], lo, hi), np.linspace(lo, hi, 7)]
    ends = 1.3 * amplitude_rad * np.array([-1.0, -0.5, 0.0, 0.5, 1.0])
    scored = []
    for p in others:
        for v in grid:
            Q = np.tile(p, (len(ends), 1))
            Q[:, j] = v + ends
            pose = p.copy()
            pose[j] = v
            g = float(np.abs(dynamics.gravity_many(Q)[:, j]).max())
            # a joint whose axis stays vertical (joint 1) has no gravity torque anywhere: every pose ties, and the
            # run's own pose of the others is kept first (a shoulder and elbow moved for nothing may hold more
            # gravity than their torque limits allow: no candidate then keeps within them)
            scored.append((g if g > GRAVITY_ZERO_NM else 0.0, float(np.abs(pose - q0_rad).sum()), pose))
    scored.sort(key=lambda x: (x[0], x[1]))
    return [pose for _, _, pose in scored[:n]]


def periodic_onsets(traj, j: int, gap_rad: float, fc_Nm: float, dynamics, share: float, rate_hz: float = 25.0,
                    ) -> tuple[np.ndarray, np.ndarray]:
    """(rev, lead_rad), each (m,): one period's onsets of joint ``j`` along the periodic trajectory ``traj`` as they
    repeat in a run of several periods (:func:`onset_pattern` over three periods, the first period's share; the
    two-harmonic series: two reversals and the dwell at its end), and the lead :func:`reversal_leads` predicts at
    each (0 at same-direction onsets)."""
    t = np.arange(int(round(3 * traj.period_s * rate_hz))) / rate_hz
    q, qd, qdd = traj.evaluate(t)
    pat = onset_pattern(qd[:, j])
    leads = reversal_leads(dynamics, q, qd, qdd, j, gap_rad, fc_Nm, share)
    lead = np.zeros(len(pat))
    lead[pat] = leads[: int(pat.sum())]
    m = (len(pat) + 1) // 3
    return pat[:m], lead[:m]


@dataclass
class CrossingRun:
    """The designed trajectory (a :class:`~wamctl.analysis.identification.excitation.FourierTrajectory`), its
    separation and the run's (noise floors; the larger of the two ways the gap shows, ``seen_by``), the gravity
    slope at the crossing (N m/rad, 0 about a pose where gravity need not change sign), the limits it uses, and
    per way: the gravity step's separation (``torque_separation``, ``torque_original``) and the reversals' leads
    (``reversals``, ``reversals_original``: :func:`reversal_separation`'s (separation, crossings, reversals), the
    designed run's over its ``periods``; None when no detection tolerance was given), and with the run's onset
    scatter and the diagnosis' threshold, ``size``: :func:`size_reversal_run`'s figures for the reversals (the
    predicted power of the decision, its median test statistic, the periods and duration), ``separation`` then that
    median statistic (the reversals' lead in standard errors of the test, growing with their number)."""

    trajectory: object
    separation: float
    original: float
    slope_Nm_rad: float
    limit_use: object
    torque_separation: float = 0.0
    torque_original: float = 0.0
    reversals: tuple | None = None
    reversals_original: tuple | None = None
    seen_by: str = "torque"
    size: dict | None = None
    periods: int = CROSSING_PERIODS


def design_crossing(dynamics, friction, q0_rad, j: int, gap_rad: float, noise_Nm: float, limits,
                    run_q: np.ndarray, run_qd: np.ndarray, period_s: float = CROSSING_PERIOD_S,
                    amplitude_rad: float = CROSSING_AMPLITUDE_RAD, fill: float = 0.95, n_poses: int = 4,
                    rate_hz: float = 25.0, tol_rad: float | None = None, fc_Nm: float | None = None,
                    run_qdd: np.ndarray | None = None, scatter: OnsetScatter | None = None,
                    threshold: float | None = None, n_folds: int = 5, share: float = LINK_FRICTION_SHARE,
                    target: float = POWER_TARGET, max_run_s: float = MAX_RUN_S) -> CrossingRun:
    """Joint ``j`` alone moving slowly about the steepest gravity crossings (:func:`crossing_poses`, the first
    ``n_poses``): ``q_j = q* + A (sin wt - sin 2wt / 2)`` (excite's two-harmonic series, at rest at its ends),
    scaled to ``fill`` of its closest limit by excite's check; the pose whose separation is largest wins. The run's
    own separation from ``run_q, run_qd`` (n, 7).

    With the joint's detection tolerance ``tol_rad`` and Coulomb level ``fc_Nm`` (and the run's ``run_qdd``), the
    reversals' leads are scored too (:func:`reversal_separation`, the link resting on ``share`` of ``fc_Nm``), each
    candidate's separation is the larger of the two, and poses where gravity need not change sign
    (:func:`level_poses`) are candidates as well: a wrist whose gravity is too small for the step, or whose
    crossing lies outside its range, still shows the gap at its reversals. With the run's onset ``scatter`` and
    the diagnosis' ``threshold`` as well, each reversal candidate is sized to the power ``target`` within
    ``max_run_s`` (:func:`size_reversal_run`; the period stays ``period_s``: a run of half that period on the
    wrist also showed a breakaway above the Coulomb level, named Stribeck beside the gap, and pooled first ahead of
    it): the shortest run that reaches it wins; where
    none does, a gravity step of 2 noise floors, else the reversal run of the largest power, said in ``size``.
    Raises ValueError when no pose is a candidate (the joint's gravity never changes sign within its range and no
    tolerance was given) or no candidate keeps within the limits."""
    from wamctl.analysis.diagnosis.discriminate import scaled_to_limits
    from wamctl.analysis.identification.excitation import FourierTrajectory

    leads = tol_rad is not None and fc_Nm is not None
    sized = leads and scatter is not None and threshold is not None
    poses = crossing_poses(dynamics, q0_rad, j, limits.q_min_rad, limits.q_max_rad)[:n_poses]
    if leads:
        poses += [(p, 0.0) for p in level_poses(dynamics, q0_rad, j, limits.q_min_rad, limits.q_max_rad,
                                                amplitude_rad)]
    if not poses:
        raise ValueError(f"joint {j + 1}'s gravity torque does not change sign within its range")
    cands = []
    w = 2 * np.pi / period_s
    t = np.arange(int(period_s * rate_hz)) / rate_hz
    for pose, slope in poses:
        a = np.zeros((len(pose), 2))
        b = np.zeros((len(pose), 2))
        a[j] = [amplitude_rad * w, -amplitude_rad * w]        # q_j - q* = A (sin wt - sin 2wt / 2)
        got = scaled_to_limits(FourierTrajectory(pose, period_s, a, b), limits, dynamics, friction, fill)
        if got is None:
            continue
        traj, use = got
        q, qd, qdd = traj.evaluate(t)
        sep = separation(dynamics, q, qd, j, gap_rad, noise_Nm)
        cand = CrossingRun(traj, sep, 0.0, slope, use, torque_separation=sep)
        if leads:
            rs, nc, nr = reversal_separation(dynamics, q, qd, qdd, j, gap_rad, fc_Nm, tol_rad, share)
            cand.reversals = (rs, nc * CROSSING_PERIODS, nr * CROSSING_PERIODS)
            if rs > sep:
                cand.separation, cand.seen_by = rs, "reversals"
        if sized:
            rev, lead = periodic_onsets(traj, j, gap_rad, fc_Nm, dynamics, share, rate_hz)
            cand.size = size_reversal_run(rev, lead, period_s, tol_rad, scatter, threshold, n_folds, target, max_run_s)
        cands.append(cand)
    if not cands:
        raise ValueError("no crossing trajectory keeps within the limits")
    best = _pick(cands) if sized else max(cands, key=lambda c: c.separation)
    best.torque_original = separation(dynamics, run_q, run_qd, j, gap_rad, noise_Nm)
    best.original = best.torque_original
    if leads and run_qdd is not None:
        best.reversals_original = reversal_separation(dynamics, run_q, run_qd, run_qdd, j, gap_rad, fc_Nm, tol_rad,
                                                      share)
        if best.seen_by == "reversals":
            best.original = best.reversals_original[0]
    return best


TORQUE_TARGET_FLOORS = 2.0      # a gravity step the design takes instead of a reversal run short of its power


def _pick(cands: list[CrossingRun]) -> CrossingRun:
    """The sized design among candidates: the shortest reversal run reaching its power (the larger power on a tie),
    else the largest gravity step when it reaches ``TORQUE_TARGET_FLOORS``, else the reversal run of the largest
    power, then median test statistic (the predicted power is a lower bound: it takes the first run's onset scatter,
    larger than a designed run's repeated motion shows), the gravity step only where no reversal run leads at all.
    The winner's figures are its reversals' (``seen_by`` "reversals": ``separation`` the median test statistic,
    ``reversals`` over its periods) or its step's (with
    ``size`` the reversals' power over its own three periods: the diagnosis names a motor-side gap from the leads
    at reversals only, so a step alone does not decide it)."""
    ok = [c for c in cands if c.size and c.size["reached"]]
    torque = max(cands, key=lambda c: c.torque_separation)
    step = False
    if ok:
        best = min(ok, key=lambda c: (c.size["duration_s"], -c.size["power"]))
    elif torque.torque_separation >= TORQUE_TARGET_FLOORS:
        best, step = torque, True
    else:
        best = max(cands, key=lambda c: (c.size["power"] if c.size else 0.0, c.size["t_median"] if c.size else 0.0))
        if not best.size or (best.size["power"] <= 0 and best.size["t_median"] <= 0):
            # a step alone never names a motor-side gap: it is taken only where no reversal run leads at all
            best, step = torque, True
    # taken for its step (not merely the candidate of the largest step too: without gravity every step is 0, and
    # the reversal run of the largest power was cut to a step's three periods)
    if step:          # (no candidate reached its power: a reached one is always the pick)
        best.separation, best.seen_by = best.torque_separation, "torque"
        best.periods = 3
        if best.size:
            # what decides a gap behind a motor-side encoder is the reversals' lead, not the step: the power of
            # that decision on this run's own periods (short of the target, or it would have been the pick)
            at = {n: (p, t) for n, p, t in best.size["curve"]}.get(best.periods)
            if at is not None:
                best.size = dict(best.size, periods=best.periods, power=at[0], t_median=at[1], reached=False,
                                 duration_s=best.periods * best.trajectory.period_s)
        return best
    sz = best.size
    best.seen_by, best.separation, best.periods = "reversals", float(sz["t_median"]), int(sz["periods"])
    best.reversals = (float(best.reversals[0]) if best.reversals else 0.0, int(sz["crossing"]), int(sz["reversals"]))
    return best
