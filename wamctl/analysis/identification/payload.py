"""A payload at the wrist identified as its own job (``wamctl identify --payload``; issue 29 item 1).

Dynamic variant (:func:`identify_payload`)
------------------------------------------
One designed trajectory is run loaded and bare in the order loaded-bare-bare-loaded (ABBA, ``wamctl excite
SPEC --payload-schedule``). Each run goes through the identification's rows (:func:`.data.run_rows`: the
diagnosis' filter, the second, parallel filter over the torque and every regressor column alike; the regressor
from the smoothed position's own derivatives, :func:`.data.smoothed_derivatives`: with the filter's
second-derivative kernel the rows' acceleration was short of the smoothed torque's and the payload's inertia made
up for it, I_xx, I_yy +0.55 standard errors without noise). At every
kept sample the *mean over the loaded runs* minus the *mean over the bare runs* of the torque residual
``tau - Y pi_declared`` (the declared arm without payload: links, armature, friction) is

    d = Y7 p + e,

``Y7`` the link-7 columns of the standard regressor (:meth:`wamctl.model.dynamics.WamDynamics.torque_regressor`)
averaged over the loaded runs, ``p`` the payload's ten standard parameters about the joint-7 frame's origin
(``m, m c_x, m c_y, m c_z, I_xx, I_xy, I_yy, I_xz, I_yz, I_zz``). The arm's own error (links, friction) is the
same in the loaded and bare runs of one trajectory and cancels; what the declared arm predicts differently
because the loaded motion differs a little from the bare one is in ``Y pi_declared``. A friction that changes
linearly in time over the schedule (warming up) cancels in the ABBA means: the loaded runs' mean time equals the
bare runs'. In any other order it does not, and it leaks into ``p`` (the tests show it).

The arm's friction in ``pi_declared`` is fitted on the bare runs (:func:`bare_friction`), not taken from the
declaration. The loaded arm tracks a little differently (the payload's torque moves it), so the friction the
declared arm predicts differs between the loaded and the bare motion, ``F(qd_L) - F(qd_B)``; when the arm's
friction is not the declared one (a warming-up arm: the ABBA schedule's mean; a real arm: Table 4.1 off by tens
of per cent), the difference keeps ``(F_true - F_declared)(qd_L) - (...)(qd_B)``, and that follows the payload's
own effect (it is what moves the motion) and leaks into ``p``. On the simulated ABBA schedule of the tests
(friction 1.0, 0.9, 0.8, 0.7 of Table 4.1, mean 0.85) it biased the mass by +1.3 and the COM's x by +1.7 standard
errors on average over 60 seeds (noise-free: +0.15 g and +0.061 mm), and the 95 % intervals held the truth in
48/60 (mass) and 33/60 (COM x) seeds; with the friction fitted on the bare runs' sliding rows (per joint, the
classic four-parameter model, declared links; in ABBA the bare runs' mean friction is the loaded runs' mean)
58/60 and 55/60 (COM y, z: 56/60, 58/60), mean errors 0.2-0.4 standard errors
(``benchmarks/bench_payload_coverage.py``). The bare runs' *mean* friction still leaked: the loaded runs' own
frictions (1.0 and 0.7 of Table 4.1) differ from it, each times its run's motion, and the loaded runs' motions
differ by what that friction difference moves (noise-free: I_xx -0.46, I_xy +0.44 standard errors once the rows
were consistent). With the runs' start times (``starts``; the CLI reads them from the manifests) the friction is
fitted as drifting linearly over the schedule (:func:`bare_friction`: level and change per schedule position, on
every bare run's own rows) and each run, loaded ones included, gets its own (noise-free, these and the rows'
fix together: every error within 0.10 standard errors, as with each run's true friction). Without start times the
mean is used and that is said (``arm_friction``'s source). The declared links still enter: their error times the
tracking difference leaks alike (not removed; on the simulator the arm is the declared one).
``fit_friction=False`` keeps the declared friction (the comparison).

The torque's timing is estimated with the payload (:func:`timing_column`). The rows take the logged torque as
acting half a control period after its sample (the zero-order hold, :func:`wamctl.analysis.diagnosis.signals.
zoh_centred`); if the arm's motion answers it ``delta`` seconds later than that (a real arm: the bus latency
between reading the encoders and the torque taking effect; the simulator: its semi-implicit Euler, whose
positions lead the held torque by half a physics step, 0.5 ms), every residual holds ``-delta`` times the
torque's time derivative, and in the loaded-minus-bare difference that is the derivative of the payload's own
torque (mostly joint 2's gravity term), which is not orthogonal to the inertia columns: with the timing assumed it
biased I_xy about the COM by +1.7 standard errors on average (its 95 % interval held the truth in 36/60 seeds)
and the mass by -0.03 g in noise-free runs. The column ``-d/dt`` of the model's loaded-minus-bare torque (the
payload estimated in a first pass) is fitted beside the ten parameters; its coefficient is ``delta`` (0.500 ms
on the simulator over 60 seeds, sd 0.038 ms; its 95 % interval in ``payload.json``'s ``torque_timing``); I_xy's
interval then holds the truth in 55/60 seeds. ``fit_timing=False`` assumes the zero-order hold's timing (the
comparison).

Fit: least squares on the usable rows (every run's joint sliding there), each joint's rows weighted by ``1 /
sigma_j`` (its residual RMS). Which of the ten parameters the trajectory determines: those whose unit vector lies
in the weighted regressor's row space (columns scaled to unit norm, singular values above ``RANK_TOL`` of the
largest); the others are ``not identified``, never printed as numbers. Intervals: 95 %, from the
heteroskedasticity- and autocorrelation-consistent covariance (Newey-West over the per-sample scores,
:func:`.estimator.hac_lags` of the rows' filter reach) of the residuals leverage-adjusted per lag window
(:func:`.estimator.leverage_adjusted`, CR2, as the arm's fit), mapped to mass, centre of mass (link-7 frame, DH
frame 7, as :class:`wamctl.model.dynamics.Payload`) and inertia about the centre of mass by the delta method,
each with Student's t of its own effective number of independent blocks less one
(:func:`.estimator.effective_blocks` of that quantity's influence; 20-30 on a 32 s trajectory).
Over seeds 30-89 of the benchmark (not looked at while developing; seeds 0-29 were) the intervals hold the truth
in 54-59 of 60 seeds for every quantity (564/600), mean errors within 0.29 standard errors; mass within 0.021 %
and COM within 0.11 mm on every seed. What is left: the errors' spread is 1.04-1.20 standard errors (the
intervals up to a sixth too narrow: I_xy 54/60, I_xx 1.16), and on seeds 0-29 I_xx, I_xy, I_yz were -0.56, +0.53,
-0.46 standard errors off on average (noise-free -0.10, +0.10, +0.02: noise-dependent, cause not found; the
reference as instrument, :func:`instrument_rows`, did not remove it).

Static variant (:func:`identify_payload_static`)
------------------------------------------------
A few held poses: segments where the reference rests for at least ``MIN_HOLD_S``, the torque averaged over the
last half of each (the loop settled). At rest the torque is gravity (plus the joints' stick friction, which the
controller's residual error leaves unknown: approaching each pose the same way in the loaded and bare runs makes
it alike), so ``d`` is the gravity rows of ``Y7``: mass and first moment only (inertia needs motion: said). Its
intervals are weighted least squares' over the poses (one average per pose and joint, independent; each joint
weighted by its residual RMS), widened by Student's t.

The payload file (``wamctl-payload/1``, :func:`payload_file`; documented in docs/payload.md) is what
``plant.effects.payload`` and ``controller.declared_payload`` accept as a path, and ``diagnose --payload``.

No I/O.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import stats

from wamctl.analysis.identification.base import (
    FRICTION_PARAMETER_NAMES,
    FRICTION_SLICE,
    standard_vector,
)
from wamctl.analysis.identification.data import RunRows, run_rows
from wamctl.analysis.identification.estimator import (
    effective_blocks,
    hac_lags,
    hac_score_covariance,
    leverage_adjusted,
    ols_residual_rms_per_joint,
)
from wamctl.errors import DataFormatError
from wamctl.model import params as P

N7 = P.N_JOINTS
LINK7 = slice(60, 70)                   # link 7's standard inertial parameters in the standard regressor
PARAMETER_NAMES = ("m", "mc_x", "mc_y", "mc_z", "I_xx", "I_xy", "I_yy", "I_xz", "I_yz", "I_zz")
INERTIA_NAMES = ("I_xx", "I_yy", "I_zz", "I_xy", "I_xz", "I_yz")     # about the COM, link-7 frame
_INERTIA_INDEX = {"I_xx": (0, 0), "I_yy": (1, 1), "I_zz": (2, 2), "I_xy": (0, 1), "I_xz": (0, 2), "I_yz": (1, 2)}
_O_INDEX = {(0, 0): 4, (0, 1): 5, (1, 1): 6, (0, 2): 7, (1, 2): 8, (2, 2): 9}
PAYLOAD_FILE_FORMAT = "wamctl-payload/1"
RANK_TOL = 1e-6             # singular values below this share of the largest: directions the data do not see
DETERMINED_TOL = 1e-3       # a parameter's unit vector may leave the row space by this much and count as determined
REFERENCE_TOL_RAD = 1e-6    # runs of one trajectory: references equal to this
MIN_ROWS = 50
TIMING_PASSES = 2           # the timing column built from the payload estimated before it (it converges in one)
MIN_HOLD_S = 1.0            # static variant: a rest of the reference at least this long is a held pose
HOLD_SPEED_RAD_S = 1e-9     # the reference at rest
# rows_cache keys: a run's source and how its rows' derivatives were taken (``run_rows(derivatives=...)``), so that
# a cache written by another version (benchmarks/bench_payload_coverage.py keeps one on disk) is never misread
ROWS_KEY = {True: "#smoothed", False: "#kernel"}


@dataclass
class PayloadEstimate:
    """The identified payload.

    Attributes
    ----------
    method : "dynamic" or "static".
    p : (10,) standard parameters about the joint-7 frame's origin (NaN where not determined).
    cov : (10, 10) their covariance (NaN rows/columns where not determined).
    determined : (10,) bool.
    mass_kg, mass_ci_kg : the mass and its 95 % interval (None: not identified).
    com_m, com_ci_m : (3,) centre of mass in the link-7 frame and intervals (None per axis: not identified).
    inertia_kg_m2, inertia_ci_kg_m2 : {name: value / interval} about the COM, link-7 axes (None: not identified).
    n_rows : rows fitted. hac_lags : Newey-West lags (dynamic). sigma_Nm : (7,) per-joint residual RMS.
    residual_rms_Nm : of the weighted fit, in N m. order : the loaded/bare order statement.
    arm_friction : the arm's friction the difference was formed with (dynamic): ``source`` and, per joint fitted
        on the bare runs, its classic parameters (:func:`bare_friction`).
    timing : the torque's timing (dynamic): ``source`` and, estimated, ``offset_s`` (how much later than the
        zero-order hold's half period the torque acts on the measured motion) and its 95 % interval.
    dof : {quantity: degrees of freedom of its interval's Student's t} (``mass``, ``com_x``, ..., the inertia
        names; infinite: the normal).
    """

    method: str
    p: np.ndarray
    cov: np.ndarray
    determined: np.ndarray
    mass_kg: float | None
    mass_ci_kg: tuple | None
    com_m: list
    com_ci_m: list
    inertia_kg_m2: dict
    inertia_ci_kg_m2: dict
    n_rows: int
    sigma_Nm: np.ndarray
    residual_rms_Nm: float
    hac_lags: list = field(default_factory=list)
    order: str = ""
    sources: dict = field(default_factory=dict)
    arm_friction: dict = field(default_factory=dict)
    timing: dict = field(default_factory=dict)
    dof: dict = field(default_factory=dict)

    @property
    def not_identified(self) -> list[str]:
        """Names of the quantities the data cannot determine."""
        out = [] if self.mass_kg is not None else ["mass"]
        out += [f"com_{a}" for a, v in zip("xyz", self.com_m) if v is None]
        out += [k for k, v in self.inertia_kg_m2.items() if v is None]
        return out

    def table(self):
        """One row per quantity: value, 95 % interval, status (identified / not identified)."""
        import pandas as pd

        rows = [("mass_kg", self.mass_kg, self.mass_ci_kg)]
        rows += [(f"com_{a}_m", v, ci) for a, v, ci in zip("xyz", self.com_m, self.com_ci_m)]
        rows += [(f"{k}_kg_m2", self.inertia_kg_m2[k], self.inertia_ci_kg_m2[k]) for k in INERTIA_NAMES]
        return pd.DataFrame([{"quantity": n, "value": v, "ci95_low": ci[0] if ci else None,
                              "ci95_high": ci[1] if ci else None,
                              "status": "identified" if v is not None else "not identified"} for n, v, ci in rows])

    def to_dict(self) -> dict:
        return {"method": self.method, "mass_kg": self.mass_kg, "mass_ci95_kg": _lst(self.mass_ci_kg),
                "com_m": self.com_m, "com_ci95_m": [_lst(c) for c in self.com_ci_m],
                "inertia_about_com_kg_m2": self.inertia_kg_m2,
                "inertia_ci95_kg_m2": {k: _lst(v) for k, v in self.inertia_ci_kg_m2.items()},
                "not_identified": self.not_identified,
                "standard_parameters": {n: (None if not d else float(v))
                                        for n, v, d in zip(PARAMETER_NAMES, self.p, self.determined)},
                "n_rows": self.n_rows, "sigma_Nm": [None if not np.isfinite(s) else float(s) for s in self.sigma_Nm],
                "residual_rms_Nm": self.residual_rms_Nm, "hac_lags": list(self.hac_lags), "order": self.order,
                "sources": self.sources, "arm_friction": self.arm_friction, "torque_timing": self.timing,
                "degrees_of_freedom": {k: (None if not np.isfinite(v) else v) for k, v in self.dof.items()}}


def _lst(ci):
    return None if ci is None else [float(ci[0]), float(ci[1])]


# ------------------------------------------------------------------------------------------- checks
def check_same_trajectory(datas, labels) -> None:
    """Raise DataFormatError (one line, naming the runs) unless every run follows one reference."""
    first, name0 = datas[0], labels[0]
    r0 = first.col("q_ref")
    for d, name in zip(datas[1:], labels[1:]):
        r = d.col("q_ref")
        if r.shape != r0.shape or abs(float(d.meta.sample_rate_hz) - float(first.meta.sample_rate_hz)) > 1e-9:
            raise DataFormatError(f"{name} and {name0} are runs of different trajectories ({len(r)} and {len(r0)} "
                                  f"samples at {d.meta.sample_rate_hz:g} and {first.meta.sample_rate_hz:g} Hz): the "
                                  "payload is identified from one trajectory run loaded and bare")
        both = np.isfinite(r) & np.isfinite(r0)
        dev = np.where(both, np.abs(r - r0), 0.0)
        if float(dev.max(initial=0.0)) > REFERENCE_TOL_RAD:
            k, j = np.unravel_index(int(np.argmax(dev)), dev.shape)
            raise DataFormatError(f"{name} and {name0} are runs of different trajectories (references differ by "
                                  f"{dev[k, j]:.3g} rad at joint {j + 1}, t = {d.t_s[k]:.3f} s): the payload is "
                                  "identified from one trajectory run loaded and bare")


def order_statement(starts: list[tuple[str, str]]) -> str:
    """The loaded (A) / bare (B) order of runs given as (role, start time) and whether it balances a linear drift
    (the loaded runs' mean position in the schedule equals the bare runs')."""
    if not starts or any(s is None for _, s in starts):
        return "order unknown (start times not recorded): a linear friction drift cancels only in an ABBA order"
    roles = [r for r, _ in sorted(starts, key=lambda x: x[1])]
    seq = "".join("A" if r == "loaded" else "B" for r in roles)
    pos = np.arange(len(roles))
    a = pos[[r == "loaded" for r in roles]].mean()
    b = pos[[r == "bare" for r in roles]].mean()
    if abs(a - b) < 1e-9:
        return f"order {seq} (A loaded, B bare): balanced, a friction drift linear in time cancels"
    return (f"order {seq} (A loaded, B bare): NOT balanced (loaded mean position {a:.1f}, bare {b:.1f}): a friction "
            "drift between runs biases the estimate; run loaded-bare-bare-loaded")


# ------------------------------------------------------------------------------------------- frame
def _frame(dynamics_cls):
    """(R, o): a point ``c`` of the link-7 frame sits at ``R c + o`` in the joint-7 frame (probed through the
    model's own placement of a payload, so that the file means what ``Payload`` means)."""
    from wamctl.model.dynamics import Payload

    base = dynamics_cls().standard_parameters()[LINK7]
    o = dynamics_cls(Payload(1.0, (0.0, 0.0, 0.0))).standard_parameters()[LINK7][1:4] - base[1:4]
    R = np.column_stack([dynamics_cls(Payload(1.0, tuple(np.eye(3)[i]))).standard_parameters()[LINK7][1:4]
                         - base[1:4] - o for i in range(3)])
    return R, o


def payload_standard(mass_kg: float, com_m, inertia_kg_m2: dict | None = None) -> np.ndarray:
    """(10,) standard parameters about the joint-7 origin of a payload (mass, COM and inertia about the COM in
    the link-7 frame)."""
    from wamctl.model.dynamics import WamDynamics

    R, o = _frame(WamDynamics)
    c = R @ np.asarray(com_m, float) + o
    Ic = np.zeros((3, 3))
    for k, (a, b) in _INERTIA_INDEX.items():
        Ic[a, b] = Ic[b, a] = float((inertia_kg_m2 or {}).get(k, 0.0))
    Io = R @ Ic @ R.T + mass_kg * (c @ c * np.eye(3) - np.outer(c, c))
    return np.array([mass_kg, *(mass_kg * c)] + [Io[a, b] for (a, b) in _O_INDEX])


def _physical(p: np.ndarray, R: np.ndarray, o: np.ndarray) -> np.ndarray:
    """(10,) -> mass, COM (3, link-7 frame), inertia about the COM (6, INERTIA_NAMES, link-7 axes)."""
    m = p[0]
    c = p[1:4] / m
    Io = np.zeros((3, 3))
    for (a, b), i in _O_INDEX.items():
        Io[a, b] = Io[b, a] = p[i]
    Ic = R.T @ (Io - m * (c @ c * np.eye(3) - np.outer(c, c))) @ R
    return np.concatenate([[m], R.T @ (c - o), [Ic[_INERTIA_INDEX[k]] for k in INERTIA_NAMES]])


def _dependencies(R: np.ndarray) -> list[np.ndarray]:
    """For each of the 10 physical outputs, the standard parameters it depends on (through R's pattern)."""
    rot = np.abs(R) > 1e-12
    first = np.arange(1, 4)
    deps = [np.array([0])]
    for i in range(3):
        deps.append(np.concatenate([[0], first[rot[:, i]]]))
    for k in INERTIA_NAMES:
        a, b = _INERTIA_INDEX[k]
        rows = np.flatnonzero(rot[:, a] | rot[:, b])
        inertia = [_O_INDEX[tuple(sorted((x, y)))] for x in rows for y in rows]
        deps.append(np.unique(np.concatenate([[0, 1, 2, 3], inertia])))
    return deps


def _estimate(method, p, cov, determined, alpha, **kw) -> PayloadEstimate:
    """Mass, COM, inertia about the COM and their intervals (delta method) from the standard parameters."""
    from wamctl.model.dynamics import WamDynamics

    R, o = _frame(WamDynamics)
    dof = kw.pop("dof", None)
    influence = kw.pop("influence", None)
    z = float(stats.t.ppf(1 - alpha / 2, dof) if dof is not None else stats.norm.ppf(1 - alpha / 2))
    dofs = np.full(10, np.nan if influence is not None else (np.inf if dof is None else float(dof)))
    deps = _dependencies(R)
    known = np.array([bool(determined[d].all()) for d in deps])
    if not determined[0] or not p[0] > 0:
        known[:] = False
    vals = np.full(10, np.nan)
    cis: list = [None] * 10
    if known.any():
        q = np.where(determined, p, 0.0)
        y0 = _physical(q, R, o)
        idx = np.flatnonzero(determined)
        J = np.zeros((10, len(idx)))
        for n, i in enumerate(idx):
            h = 1e-6 * max(abs(q[i]), 1e-3)
            dq = q.copy()
            dq[i] += h
            J[:, n] = (_physical(dq, R, o) - y0) / h
        C = J @ cov[np.ix_(idx, idx)] @ J.T
        if influence is not None:       # each quantity's own effective blocks, Student's t with that many less one
            infl, block = influence
            dofs = effective_blocks(infl @ J.T, block) - 1.0
        for i in np.flatnonzero(known):
            vals[i] = y0[i]
            zi = z if influence is None else float(stats.t.ppf(1 - alpha / 2, max(dofs[i], 1.0)))
            half = zi * np.sqrt(max(C[i, i], 0.0))
            cis[i] = (y0[i] - half, y0[i] + half)
    if cis[0] is not None and cis[0][0] <= 0.0:     # a mass the data cannot tell from none: nothing to place
        vals[1:], cis[1:] = np.nan, [None] * 9
    f = [None if np.isnan(v) else float(v) for v in vals]
    names = ["mass"] + [f"com_{a}" for a in "xyz"] + list(INERTIA_NAMES)
    kw["dof"] = {n: float(v) for n, v, c in zip(names, dofs, cis) if c is not None}
    return PayloadEstimate(method, np.where(determined, p, np.nan), cov, determined, f[0], cis[0], f[1:4], cis[1:4],
                           dict(zip(INERTIA_NAMES, f[4:])), dict(zip(INERTIA_NAMES, cis[4:])), **kw)


def _determined(X: np.ndarray) -> np.ndarray:
    scale = np.linalg.norm(X, axis=0)
    scale[scale == 0] = 1.0
    # Vt whole (the null space's rows) without U: full_matrices only when there are fewer rows than columns (a
    # full U of the dynamic variant's ~15000 rows was 1.8 GB and 90 s of a fit taking 1 s without it)
    _, s, Vt = np.linalg.svd(X / scale, full_matrices=X.shape[0] < X.shape[1])
    keep = np.zeros(Vt.shape[0], bool)
    if len(s) and s[0] > 0:
        keep[:len(s)] = s > RANK_TOL * s[0]
    null = Vt[~keep]
    return np.linalg.norm(null, axis=0) < DETERMINED_TOL if len(null) else np.ones(X.shape[1], bool)


def _weights(X, d, jrow, determined):
    return ols_residual_rms_per_joint(X[:, determined], d, jrow, floor=1e-9)


# ------------------------------------------------------------------------------------------- dynamic
def schedule_positions(starts, n_loaded: int, n_bare: int) -> np.ndarray | None:
    """(n_loaded + n_bare,) each run's position in the schedule (0, 1, ...: rank of its start time), loaded runs
    first, from ``starts`` [(role, start time)] in that order (as ``identify_payload`` takes them); None when a
    start time is missing."""
    if not starts or len(starts) != n_loaded + n_bare or any(s is None for _, s in starts):
        return None
    order = sorted(range(len(starts)), key=lambda i: starts[i][1])
    pos = np.empty(len(starts))
    pos[order] = np.arange(len(starts))
    return pos


def bare_friction(bare: list[RunRows], pi_declared: np.ndarray, positions=None) -> tuple[np.ndarray, np.ndarray,
                                                                                        dict]:
    """``(pi, slope, fitted)``: ``pi_declared`` with each joint's friction replaced by the classic per-direction
    model (``fc_pos, fc_neg, b_pos, b_neg``) fitted by least squares on the bare runs: ``tau - Y pi`` without its
    friction part, on the samples where every bare run's joint slides (see the module doc for why). With the bare
    runs' schedule ``positions`` (two or more distinct), the friction drifts linearly over the schedule: ``pi``
    is the friction at the bare runs' mean position and ``slope`` (105,; zero outside the friction) its change
    per schedule position, both fitted on every bare run's own rows; without, ``slope`` is zero and ``pi`` the bare
    runs' mean friction. A direction a joint never slides in keeps its declared parameters; a joint with fewer
    than ``MIN_ROWS`` such rows keeps all four. ``fitted``: {joint (1-based): {parameter: value}} (with the
    drift also ``{parameter}_per_run``)."""
    n = min(len(r.t_s) for r in bare)
    f0 = FRICTION_SLICE.start
    levels = [r.tau_Nm[:n] - r.Y[:n, :, :f0] @ pi_declared[:f0] for r in bare]
    Yfs = [r.Y[:n, :, FRICTION_SLICE] for r in bare]
    usable = np.all([r.usable[:n] for r in bare], axis=0)
    pos = None if positions is None else np.asarray(positions, float)
    drift = pos is not None and len(np.unique(pos)) > 1
    dpos = pos - pos.mean() if drift else np.zeros(len(bare))
    pi = pi_declared.copy()
    slope = np.zeros_like(pi_declared)
    fitted = {}
    for j in range(N7):
        k = np.flatnonzero(usable[:, j])
        if len(k) < MIN_ROWS:
            continue
        cols = slice(4 * j, 4 * j + 4)
        A = np.mean([Yf[k, j, cols] for Yf in Yfs], axis=0)
        norm = np.linalg.norm(A, axis=0)
        on = norm > 1e-9 * norm.max()
        idx = f0 + 4 * j + np.flatnonzero(on)
        if drift:
            A2 = np.vstack([np.hstack([Yf[k, j, cols][:, on], dp * Yf[k, j, cols][:, on]])
                            for Yf, dp in zip(Yfs, dpos)])
            sol, *_ = np.linalg.lstsq(A2, np.concatenate([lv[k, j] for lv in levels]), rcond=None)
            pi[idx], slope[idx] = sol[:on.sum()], sol[on.sum():]
        else:
            sol, *_ = np.linalg.lstsq(A[:, on], np.mean([lv[k, j] for lv in levels], axis=0), rcond=None)
            pi[idx] = sol
        fitted[j + 1] = {name: float(pi[f0 + 4 * j + i]) for i, name in enumerate(FRICTION_PARAMETER_NAMES)}
        if drift:
            fitted[j + 1].update({f"{name}_per_run": float(slope[f0 + 4 * j + i])
                                  for i, name in enumerate(FRICTION_PARAMETER_NAMES)})
    return pi, slope, fitted


def difference_rows(loaded: list[RunRows], bare: list[RunRows], pi_declared: np.ndarray, pi_runs=None):
    """(X (r, 10), d (r,), joint (r,), sample (r,)): the rows where every run's joint slides, in time order.
    ``pi_runs``: each run's own parameters (loaded runs first; a drifting friction), else ``pi_declared`` for
    all."""
    n = min(len(r.t_s) for r in loaded + bare)
    usable = np.ones((n, N7), bool)
    for r in loaded + bare:
        usable &= r.usable[:n]
    pis = list(pi_runs) if pi_runs is not None else [pi_declared] * (len(loaded) + len(bare))

    def mean_residual(rows, p):
        return np.mean([r.tau_Nm[:n] - r.Y[:n] @ pr for r, pr in zip(rows, p)], axis=0)

    D = mean_residual(loaded, pis[:len(loaded)]) - mean_residual(bare, pis[len(loaded):])
    Y7 = np.mean([r.Y[:n, :, LINK7] for r in loaded], axis=0)
    k, j = np.nonzero(usable)
    return Y7[k, j, :], D[k, j], j, k


def identify_payload(loaded, bare, dynamics=None, friction=None, alpha: float = 0.05, labels=None,
                     starts=None, rows_cache: dict | None = None, fit_friction: bool = True,
                     fit_timing: bool = True, consistent: bool = True, instruments: bool = False) -> PayloadEstimate:
    """The payload from runs of one trajectory, loaded and bare (:class:`wamctl.runs.measured.RunData`); see the
    module doc. ``dynamics``/``friction``: the declared arm without payload (datasheet, Table 4.1 by default).
    ``labels``: {"loaded": [...], "bare": [...]} names for messages; ``starts``: [(role, start time)], loaded
    runs first, for the order statement and the friction's drift over the schedule (:func:`bare_friction`);
    ``rows_cache``: {run source: RunRows}, filled and reused (one run in several comparisons); ``fit_friction``:
    the arm's friction fitted on the bare runs (False: the declared friction, biased when it is not the arm's);
    ``fit_timing``: the torque's timing offset estimated with the payload (False: the zero-order hold's timing
    assumed, biased when the arm's differs); ``consistent``: the regressor built from the smoothed position's
    own derivatives (:func:`.data.smoothed_derivatives`; False: the filter's derivative kernels, the comparison);
    ``instruments``: the reference's regressor instruments the rows of joints that track it (two-stage least
    squares, :func:`instrument_rows`; tried, not the default: see there).
    Raises DataFormatError for runs of different trajectories or too few rows."""
    from wamctl.model.dynamics import WamDynamics
    from wamctl.model.friction import FrictionModel

    if not loaded or not bare:
        raise DataFormatError("identify --payload: give at least one --loaded and one --bare run")
    labels = labels or {"loaded": [f"loaded run {i + 1}" for i in range(len(loaded))],
                        "bare": [f"bare run {i + 1}" for i in range(len(bare))]}
    check_same_trajectory(list(loaded) + list(bare), list(labels["loaded"]) + list(labels["bare"]))
    dyn = dynamics if dynamics is not None else WamDynamics()
    fr = friction if friction is not None else FrictionModel.table_4_1()
    pi = standard_vector(dyn, fr)
    cache = rows_cache if rows_cache is not None else {}

    def rows_of(d):
        key = str(d.source) + ROWS_KEY[bool(consistent)]
        if key not in cache:
            cache[key] = run_rows(d, dyn, derivatives="smoothed" if consistent else "kernel")
        return cache[key]

    lrows = [rows_of(d) for d in loaded]
    brows = [rows_of(d) for d in bare]
    pos = schedule_positions(starts, len(loaded), len(bare))
    pi_runs = None
    if fit_friction:
        pi, slope, fitted = bare_friction(brows, pi, None if pos is None else pos[len(loaded):])
        if slope.any():
            centre = float(np.mean(pos[len(loaded):]))
            pi_runs = [pi + (t - centre) * slope for t in pos]
            source = ("fitted on the bare runs' sliding rows (declared links), drifting linearly over the schedule "
                      "(each run's friction at its position; the values at the bare runs' mean position)")
        else:
            source = "fitted on the bare runs' sliding rows (declared links)" + (
                "; start times unknown: the bare runs' mean, no drift between runs modelled" if pos is None else "")
        arm_friction = {"source": source, "joints": {str(j): v for j, v in fitted.items()}}
    else:
        arm_friction = {"source": "declared"}
    X, d, jrow, k = difference_rows(lrows, brows, pi, pi_runs)
    if len(d) < MIN_ROWS:
        raise DataFormatError(f"only {len(d)} rows where every run's joints slide; the payload needs at least "
                              f"{MIN_ROWS}: do the runs move?")
    det = _determined(X)
    reach = max(r.reach_s / r.dt_s for r in lrows + brows)
    tracks = instrument_rows(lrows + brows, jrow) if instruments else np.zeros(len(jrow), bool)
    W = X.copy()
    if tracks.any():
        n = min(len(r.t_s) for r in lrows + brows)
        W[tracks] = np.mean([r.Z[:n, :, LINK7] for r in lrows], axis=0)[k[tracks], jrow[tracks]]
    fit = _wls_hac(X[:, det], d, jrow, k, reach, W[:, det])
    timing = {"source": "assumed: the zero-order hold's (torque acting half a control period after its sample)"}
    if fit_timing:
        tfit = fit
        for _ in range(TIMING_PASSES):      # the column is the torque's derivative with the payload estimated
            p = np.zeros(10)
            p[det] = tfit.beta[:int(det.sum())]
            col = timing_column(lrows, brows, pi, p, k, jrow, pi_runs)
            wcol = col.copy()
            if tracks.any():
                wcol[tracks] = timing_column(lrows, brows, pi, p, k, jrow, pi_runs, "Z")[tracks]
            tfit = _wls_hac(np.column_stack([X[:, det], col]), d, jrow, k, reach, np.column_stack([W[:, det], wcol]))
        dl, se = float(tfit.beta[-1]), float(np.sqrt(tfit.cov[-1, -1]))
        q = float(stats.t.ppf(1 - alpha / 2, max(tfit.dof[-1] - 1.0, 1.0)))
        period_s = 1.0 / P.CONTROL_RATE_HZ
        if abs(dl) <= period_s:
            fit = tfit
            timing = {"source": "estimated with the payload (the loaded-minus-bare torque's derivative as a "
                                "column)", "offset_s": dl, "offset_ci95_s": [dl - q * se, dl + q * se]}
        else:       # not the arm's timing: something else follows the torque's derivative
            timing = {"source": f"assumed: the zero-order hold's; estimated {1e3 * dl:.3g} ms, beyond one control "
                                f"period ({1e3 * period_s:g} ms), which is not the arm's timing (another effect "
                                "follows the torque's derivative, e.g. a friction drift an unbalanced order leaves)"}
    nd = int(det.sum())
    p = np.zeros(10)
    p[det] = fit.beta[:nd]
    cov = np.full((10, 10), np.nan)
    cov[np.ix_(det, det)] = fit.cov[:nd, :nd]
    rms = float(np.sqrt(np.mean(fit.resid ** 2)))
    return _estimate("dynamic", p, cov, det, alpha, influence=(fit.influence[:, :nd], fit.block), n_rows=len(d),
                     sigma_Nm=fit.sig, residual_rms_Nm=rms, hac_lags=[fit.lags], order=order_statement(starts or []),
                     sources=labels, arm_friction=arm_friction, timing=timing)


@dataclass
class _Fit:
    beta: np.ndarray
    cov: np.ndarray
    sig: np.ndarray
    lags: int
    resid: np.ndarray
    influence: np.ndarray
    block: np.ndarray
    dof: np.ndarray


def instrument_rows(rows: list[RunRows], jrow: np.ndarray) -> np.ndarray:
    """(r,) bool: the rows of joints whose motion tracks the reference in every run (``RunRows.reference_tracks``:
    tracking error at most :data:`.data.TRACKING_SHARE` of the motion), instrumented by the reference's regressor.
    Tried against what is left of the bias with noise (the tests' case, the rows and friction fixed, seeds 0-29:
    I_xx -0.56, I_xy +0.53, I_yz -0.46 standard errors on average, noise-free -0.10, +0.10, +0.02): if the
    actuation noise the loop feeds back into the motion were its cause, the reference (free of it, as the arm's
    fit uses it, :mod:`.data`) would remove it; it did not (-0.61, +0.60, -0.58, the errors larger), so least
    squares is the default and the cause is not known (docs/payload.md)."""
    tracks = np.all([r.reference_tracks for r in rows], axis=0)
    return tracks[jrow]


def _wls_hac(A, d, jrow, k, reach, W=None) -> _Fit:
    """Weighted least squares of ``d`` on ``A`` (each joint's rows weighted by ``1 / sigma_j``, its residual RMS)
    with the Newey-West covariance over the per-sample scores of the leverage-adjusted residuals (per lag window,
    :func:`.estimator.leverage_adjusted`, as the arm's fit) and, per column, the effective number of independent
    blocks that covariance rests on (:func:`.estimator.effective_blocks`, blocks of two thirds of the lag).
    ``W``: instruments (rows as ``A``): two-stage least squares, ``A`` projected on their span (as the arm's
    fit)."""
    sig = ols_residual_rms_per_joint(A, d, jrow, floor=1e-9)
    w = 1.0 / sig[jrow]
    Aw, dw = A * w[:, None], d * w
    Ah = Aw
    if W is not None:
        Qw, _ = np.linalg.qr(W * w[:, None])
        Ah = Qw @ (Qw.T @ Aw)
    Q, Rq = np.linalg.qr(Ah)
    beta = np.linalg.solve(Rq, Q.T @ dw)
    e = dw - Aw @ beta
    lags = hac_lags(len(np.unique(k)), reach)
    e_adj = leverage_adjusted(Q, e, k, lags + 1)
    S, lags = hac_score_covariance(Q * e_adj[:, None], k, reach)
    Ri = np.linalg.inv(Rq)
    influence = Q @ Ri.T
    block = (k - k.min()) // max(1, int(round(2 * lags / 3)))
    return _Fit(beta, Ri @ S @ Ri.T, sig, lags, d - A @ beta, influence, block, effective_blocks(influence, block))


def timing_column(loaded: list[RunRows], bare: list[RunRows], pi: np.ndarray, p: np.ndarray, k: np.ndarray,
                  jrow: np.ndarray, pi_runs=None, regressor: str = "Y") -> np.ndarray:
    """At the rows ``(k, jrow)``: ``-d/dt`` of the model's loaded-minus-bare torque (``pi`` with the payload ``p``
    in link 7 for the loaded runs, ``pi`` for the bare ones; ``pi_runs``: each run's own, loaded first), the column
    whose coefficient is the offset, s, by which the torque acts later than the zero-order hold's timing says (see
    the module doc). ``regressor="Z"``: the reference's (the column's instrument)."""
    n = min(len(r.t_s) for r in loaded + bare)
    pis = list(pi_runs) if pi_runs is not None else [pi] * (len(loaded) + len(bare))
    add = np.zeros_like(pi)
    add[LINK7] = p
    diff = (np.mean([getattr(r, regressor)[:n] @ (pr + add) for r, pr in zip(loaded, pis)], axis=0)
            - np.mean([getattr(r, regressor)[:n] @ pr for r, pr in zip(bare, pis[len(loaded):])], axis=0))
    return -np.gradient(diff, loaded[0].dt_s, axis=0)[k, jrow]


# ------------------------------------------------------------------------------------------- static
def held_poses(data, min_hold_s: float = MIN_HOLD_S) -> list[tuple[np.ndarray, np.ndarray]]:
    """[(q_ref (7,), mean torque (7,))] over the last half of each rest of the reference at least ``min_hold_s``
    long."""
    t, qr, tau = data.t_s, data.col("q_ref"), data.col("tau")
    qr0 = np.where(np.isfinite(qr), qr, 0.0)
    still = np.r_[False, np.all(np.abs(np.diff(qr0, axis=0)) <= HOLD_SPEED_RAD_S, axis=1)]
    out = []
    edges = np.flatnonzero(np.diff(np.r_[0, still.astype(int), 0]))
    for a, b in zip(edges[::2], edges[1::2]):
        if t[b - 1] - t[max(a - 1, 0)] >= min_hold_s:
            half = slice(a + (b - a) // 2, b)
            out.append((qr0[b - 1], np.nanmean(tau[half], axis=0)))
    return out


def identify_payload_static(loaded, bare, alpha: float = 0.05, labels=None,
                            min_hold_s: float = MIN_HOLD_S) -> PayloadEstimate:
    """Mass and centre of mass from held poses (see the module doc): the runs' rests, loaded minus bare at each
    pose, gravity rows of the link-7 regressor. Inertia is not identified (no motion)."""
    from wamctl.model.dynamics import WamDynamics

    if not loaded or not bare:
        raise DataFormatError("identify --payload --static: give at least one --loaded and one --bare run")
    labels = labels or {"loaded": [f"loaded run {i + 1}" for i in range(len(loaded))],
                        "bare": [f"bare run {i + 1}" for i in range(len(bare))]}
    joints = sorted({j - 1 for d in list(loaded) + list(bare) for j in d.meta.logged_joints})
    pairs = []          # (loaded poses, bare poses) of runs that follow one reference
    for dl, nl in zip(loaded, labels["loaded"]):
        match = []
        for db, nb in zip(bare, labels["bare"]):
            try:
                check_same_trajectory([dl, db], [nl, nb])
            except DataFormatError:
                continue
            match.append(db)
        if not match:
            raise DataFormatError(f"{nl}: no --bare run follows its reference; each loaded run of held poses needs a "
                                  "bare run of the same poses")
        pl = held_poses(dl, min_hold_s)
        pb = [held_poses(db, min_hold_s) for db in match]
        n = min(len(x) for x in [pl] + pb)
        pairs += [(pl[i][0], pl[i][1], np.mean([x[i][1] for x in pb], axis=0)) for i in range(n)]
    if not pairs:
        raise DataFormatError(f"identify --payload --static: no held pose (the reference at rest >= {min_hold_s:g} s) "
                              "in the runs")
    n = len(pairs)
    dyn = WamDynamics()
    X, d, jrow = [], [], []
    z = np.zeros(N7)
    for q, tl, tb in pairs:
        G = dyn.torque_regressor(q, z, z)[0][:, LINK7][:, :4]
        for j in joints:
            X.append(G[j])
            d.append(tl[j] - tb[j])
            jrow.append(j)
    X, d, jrow = np.array(X), np.array(d), np.array(jrow)
    det = np.zeros(10, bool)
    det[:4] = _determined(X)
    Xd = X[:, det[:4]]
    dof = len(d) - Xd.shape[1]
    if dof < 1:
        raise DataFormatError(f"identify --payload --static: {n} held pose(s) give {len(d)} rows for "
                              f"{Xd.shape[1]} parameters; hold more poses")
    sig0 = _weights(X, d, jrow, det[:4])       # per joint: the held torque's spread differs by an order
    w = 1.0 / sig0[jrow]
    Xw = Xd * w[:, None]
    beta, *_ = np.linalg.lstsq(Xw, d * w, rcond=None)
    e = d - Xd @ beta
    s2 = float((e * w) @ (e * w)) / dof
    cov_d = s2 * np.linalg.inv(Xw.T @ Xw)
    p = np.zeros(10)
    p[det] = beta
    cov = np.full((10, 10), np.nan)
    cov[np.ix_(det, det)] = cov_d
    sig = np.full(N7, np.nan)
    for j in joints:
        sig[j] = float(np.sqrt(np.mean(e[jrow == j] ** 2)))
    return _estimate("static", p, cov, det, alpha, dof=dof, n_rows=len(d), sigma_Nm=sig,
                     residual_rms_Nm=float(np.sqrt(np.mean(e ** 2))), order=f"{n} held poses", sources=labels)


# ------------------------------------------------------------------------------------------- file
def payload_file(est: PayloadEstimate, provenance: dict) -> dict:
    """The payload file (``wamctl-payload/1``): ``mass_kg`` and ``com_m`` (what the model uses: a point mass in
    the link-7 frame; a COM axis the data do not determine is written as 0 and named under ``not_identified``),
    the intervals, the inertia about the COM where determined, and the provenance."""
    if est.mass_kg is None:
        raise DataFormatError("the data do not determine the payload's mass; no payload file can be written")
    return {"format": PAYLOAD_FILE_FORMAT, "mass_kg": est.mass_kg,
            "com_m": [0.0 if v is None else v for v in est.com_m],
            "mass_ci95_kg": _lst(est.mass_ci_kg), "com_ci95_m": [_lst(c) for c in est.com_ci_m],
            "inertia_about_com_kg_m2": est.inertia_kg_m2,
            "inertia_ci95_kg_m2": {k: _lst(v) for k, v in est.inertia_ci_kg_m2.items()},
            "not_identified": est.not_identified, "method": est.method, "order": est.order,
            "provenance": provenance}
