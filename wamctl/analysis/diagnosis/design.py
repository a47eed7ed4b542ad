"""Design matrices of the torque residual: a joint's samples, the run's arrays, each term's columns (no I/O).

A joint's model is ``y = X theta`` on its sliding samples: the classic friction first (four columns,
:func:`wamctl.model.friction.classic_friction_columns`), then one block of columns per term. A *term* is a
dict ``{"name", "h_fold", "h_all", ...}``: the effect name, its shape parameter chosen without each fold
(``h_fold[f]``) and on all data (``h_all``). A delay term adds no column: it shifts the target and the
friction columns in time.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from wamctl.analysis.diagnosis.candidates import ripple_basis, stribeck_columns
from wamctl.analysis.diagnosis.signals import GridSignal, Signals
from wamctl.analysis.diagnosis.stats import lstsq, lstsq_bounded
from wamctl.model.friction import FrictionModel, classic_friction_columns, stribeck_decay

N_FRICTION = 4                    # classic friction: Coulomb and viscous, per direction
N_COLUMNS = {"stribeck": 2, "position_ripple": 2, "payload": 10, "delay": 0, "friction_drift": 2,
             "backlash": 1, "link_parameters": 1}     # a ripple: 2 per harmonic (its term says how many)
FRICTION_KEYS = ("fc_pos_Nm", "fc_neg_Nm", "viscous_pos_Nm_s_rad", "viscous_neg_Nm_s_rad")


@dataclass
class JointData:
    """The samples of one joint that the torque residual uses (decimated, sliding only).

    Attributes
    ----------
    j : 0-based joint.
    idx : (m,) indices into the full-rate signals.
    t_s, q_rad, qd_rad_s, qdd_rad_s2, y_Nm : (m,) the joint's samples; ``y`` = tau - rnea.
    fold : (m,) fold number of each sample (contiguous time blocks).
    extra : per-run precomputed arrays keyed by name (payload regressor rows, shifted torques, ...).
    """

    j: int
    idx: np.ndarray
    t_s: np.ndarray
    q_rad: np.ndarray
    qd_rad_s: np.ndarray
    qdd_rad_s2: np.ndarray
    y_Nm: np.ndarray
    fold: np.ndarray
    extra: dict = field(default_factory=dict)

    @property
    def n(self) -> int:
        return len(self.idx)


@dataclass
class Design:
    """The run's arrays every joint's design is built from (full rate unless said otherwise).

    Attributes
    ----------
    sig : the prepared signals.
    rnea_Nm : (n, 7) rigid-body torque of the declared model (a declared payload included), a
        :class:`~wamctl.analysis.diagnosis.signals.GridSignal`.
    known_Nm : (n, 7) torque a declared model file adds beyond the rigid body (zero when friction is fitted).
    known_other_Nm : (n, 7) its part that is not friction (ripple).
    tau_Nm : unused (None): each joint's smoothed torque is in ``JointData.extra["tau"]``.
    friction_given : the declared friction, or None when it is fitted from the data.
    n_folds : folds of the held-out figures.
    decimation : the joints' sliding samples are taken every ``decimation`` samples.
    union : (u,) full-rate samples where some diagnosed joint slides (decimated).
    payload_pi : {fold (None: all data): (10,) inertial parameters of the arm's one payload fitted without
        that fold}, once a payload is kept.
    links_beta, links_cols : {fold: the arm's link refit fitted without it} and the base columns it changes, once
        ``link_parameters`` is named (:mod:`wamctl.analysis.diagnosis.links`).
    rigid_shift_s : the rigid body is taken at the states this much later than the samples (the zero-order hold
        of the run's physics, :mod:`wamctl.analysis.diagnosis.timing`; 0 for continuous physics).
    """

    sig: Signals
    rnea_Nm: GridSignal
    known_Nm: np.ndarray
    known_other_Nm: np.ndarray
    tau_Nm: np.ndarray
    friction_given: FrictionModel | None
    n_folds: int
    decimation: int = 1
    union: np.ndarray = field(default_factory=lambda: np.zeros(0, int))
    payload_pi: dict = field(default_factory=dict)
    links_beta: dict = field(default_factory=dict)
    links_cols: np.ndarray | None = None
    rigid_shift_s: float = 0.0

    @property
    def bounded(self) -> bool:
        """Friction is fitted from the data, so its levels are magnitudes (kept >= 0)."""
        return self.friction_given is None


# ---------------------------------------------------------------------------------------------- terms
def ncols(term: dict) -> int:
    """Columns a term adds (the arm's one payload, once fitted over all joints, adds one; a Stribeck effect whose
    shape was measured elsewhere adds none: it shapes the friction columns)."""
    h = term.get("h_all", term.get("fixed_h"))
    if term["name"] == "payload" and isinstance(h, tuple):
        return 1
    if term["name"] == "stribeck" and isinstance(term.get("fixed_h"), tuple):
        return 0
    if term["name"] == "backlash" and term.get("encoder_side") == "motor":
        return 0      # a gap on the motor side: seen at the onsets only (:mod:`.onset_tests`)
    if term["name"] == "position_ripple":
        return 2 * ripple_harmonics_of(term)
    return N_COLUMNS[term["name"]]


def ripple_harmonics_of(term: dict) -> int:
    """Harmonics of a ripple term (shape ``(period, H)``): on all data, or before the refit the most of any fold."""
    h = term.get("h_all")
    if h is not None:
        return int(h[1])
    return max([int(x[1]) for x in term.get("h_fold", []) if x is not None] or [1])


def split_coefs(terms: list[dict], theta: np.ndarray) -> dict:
    """Coefficients ``theta`` (p,) of ``friction + terms`` by term name."""
    out = {"friction": theta[:N_FRICTION]}
    k = N_FRICTION
    for t in terms:
        n = ncols(t)
        out[t["name"]] = theta[k:k + n]
        k += n
    return out


def shape_of(term: dict, fold: int | None):
    """The term's shape parameter fitted without ``fold`` (None: on all data)."""
    return term["h_all"] if fold is None else term["h_fold"][fold]


def at_fold(terms: list[dict], fold: int) -> list[dict]:
    """Copies of ``terms`` whose ``h_all`` is their shape parameter fitted without ``fold``."""
    return [dict(t, h_all=t["h_fold"][fold]) for t in terms]


def delay_of(terms: list[dict], fold: int | None = None) -> float:
    """The delay (s) among ``terms`` (see :func:`shape_of`), 0 without one."""
    return next((shape_of(t, fold) for t in terms if t["name"] == "delay"), 0.0) or 0.0


# ---------------------------------------------------------------------------------------------- friction
def levels(friction_given: FrictionModel | None, j: int, theta: np.ndarray) -> np.ndarray:
    """(4,) absolute classic friction ``[fc_pos, fc_neg, b_pos, b_neg]`` of 0-based joint ``j`` from the
    four fitted coefficients ``theta[:4]`` (a model file's levels plus the correction fitted on top)."""
    fr = np.array(theta[:N_FRICTION], float)
    if friction_given is not None:
        fr = fr + model_levels(friction_given, j)
    return fr


def model_levels(friction: FrictionModel, j: int) -> np.ndarray:
    """(4,) classic friction ``[fc_pos, fc_neg, b_pos, b_neg]`` of 0-based joint ``j`` of a friction model."""
    return np.array([friction.fc_pos_Nm[j], friction.fc_neg_Nm[j], friction.viscous_pos_Nm_s_rad[j],
                     friction.viscous_neg_Nm_s_rad[j]])


def levels_dict(fr: np.ndarray) -> dict:
    """Classic friction levels (4,) by name (units in the keys)."""
    return {k: float(v) for k, v in zip(FRICTION_KEYS, fr)}


def drift_offset(coef: np.ndarray, tb: np.ndarray) -> np.ndarray:
    """(4,) the change a drift makes to the friction levels from the start of the run to its end value (t ->
    infinity): the declared levels ``tb`` (4,), the Coulomb pair scaled by ``coef[0]`` and the viscous pair by
    ``coef[1]`` (the drift's two columns)."""
    return np.array([coef[0] * tb[0], coef[0] * tb[1], coef[1] * tb[2], coef[1] * tb[3]])


def declared_levels(des: Design, jd: JointData) -> np.ndarray:
    """(4,) absolute classic friction of the joint's declared model (the shape a drift scales)."""
    return levels(des.friction_given, jd.j, jd.extra["theta_before"])


def fit_theta(X: np.ndarray, y: np.ndarray, bounded: bool) -> np.ndarray:
    """Least squares of a joint model ``y ~ X theta`` whose first four columns are the classic friction.

    ``bounded``: Coulomb levels and viscous coefficients are magnitudes, kept >= 0 when fitted from the data
    (a direction seen at one speed only cannot tell Coulomb from viscous, and an unbounded fit trades one
    against the other to absurd values)."""
    if not bounded:
        return lstsq(X, y)
    lower = np.full(X.shape[1], -np.inf)
    lower[:N_FRICTION] = 0.0
    return lstsq_bounded(X, y, lower)


# ---------------------------------------------------------------------------------------------- columns
def columns(des: Design, name: str, jd: JointData, h, d: float = 0.0) -> np.ndarray:
    """Columns (m, p) of term ``name`` with shape parameter ``h`` at the joint's samples, with the state
    taken ``d`` seconds later (a delay term).

    Features that are nonlinear functions of the state are built at the full rate and smoothed by the
    same filter as the torque, so that feature and torque are averaged alike over each window. A fractional
    shift is the linear interpolation between the two whole-sample shifts around it (each built once)."""
    shift = float(d) / des.sig.dt_s
    k0 = int(np.floor(shift + 1e-9))
    frac = shift - k0
    if frac < 1e-9 or name == "payload":
        return _columns_at(des, name, jd, h, k0)
    return (1.0 - frac) * _columns_at(des, name, jd, h, k0) + frac * _columns_at(des, name, jd, h, k0 + 1)


def _columns_at(des: Design, name: str, jd: JointData, h, k: int) -> np.ndarray:
    """:func:`columns` with the state ``k`` whole samples later (cached per joint)."""
    cache = jd.extra.setdefault("_cache", {})
    key = (name, h if (h is None or isinstance(h, tuple)) else round(float(h), 12), int(k))
    if key in cache:
        return cache[key]
    X = _build_columns(des, name, jd, h, k * des.sig.dt_s)
    if len(cache) > 400:
        cache.clear()
    cache[key] = X
    return X


def _build_columns(des: Design, name: str, jd: JointData, h, d: float) -> np.ndarray:
    sig = des.sig
    j = jd.j
    qd_f = sig.qd_rad_s[:, j]
    shift = d / sig.dt_s

    def sample(fn):
        """The smoothed feature ``fn(full-rate indices)`` at the joint's samples (``d`` seconds later)."""
        return sig.smooth_at(fn, jd.idx, shift)

    def of_speed(fn):
        """The smoothed feature ``fn(speeds)`` of the joint's velocity at its samples (``d`` seconds later)."""
        return sig.smooth_at(fn, jd.idx, shift, source=(("qd", j), qd_f))

    if name == "friction":
        return of_speed(lambda v: friction_columns(v, h))
    if name == "stribeck":
        return of_speed(lambda v: stribeck_columns(v, h))
    if name == "position_ripple":        # h = (period, harmonics): sin, cos of each harmonic in turn
        q_f = sig.q_raw_rad[:, j]          # the angle as measured (the filter then smooths the feature)
        period, nh = float(h[0]), int(h[1])
        return sig.smooth_at(lambda q: ripple_basis(q, period, nh), jd.idx, shift, source=(("q", j), q_f),
                             quantised=True)
    if name == "payload":
        X = jd.extra["payload"]
        if isinstance(h, tuple):       # ("global", fold): the one payload of the arm, fitted without fold
            return (X @ des.payload_pi[h[1]])[:, None]
        return X @ jd.extra["payload_basis"] if "payload_basis" in jd.extra else X
    if name == "link_parameters":       # ("links", fold): the arm's one refit, fitted without fold
        return (jd.extra["links_base"][:, des.links_cols] @ des.links_beta[h[1]])[:, None]
    if name == "friction_drift":
        # the Coulomb and the viscous torque of the declared fit, each changing as 1 - exp(-t / T): two columns
        # that keep the directions together (a direction seen only early in the run would otherwise be
        # extrapolated in time). They are zero at the start of the run, so the friction columns are the levels
        # there, which the fit keeps non-negative; a time constant far beyond the run is a linear drift
        return drift_of(columns(des, "friction", jd, None, d), declared_levels(des, jd), jd.extra["t_rel"], h)
    if name == "backlash":
        dg = jd.extra["dgdq_full"]
        return sample(lambda p: (dg[p, 0] * np.sign(qd_f[p]))[:, None])
    raise ValueError(name)


def drift_of(F: np.ndarray, tb: np.ndarray, t_s: np.ndarray, T_s: float) -> np.ndarray:
    """(m, 2) a friction drift's columns: the Coulomb and the viscous torque of the declared levels ``tb`` (4,) on
    the friction columns ``F`` (m, 4), each times ``1 - exp(-t / T)`` at times ``t_s`` (m,) from the run's start."""
    ramp = -np.expm1(-np.asarray(t_s, float) / T_s)
    return np.column_stack([F[:, :2] @ tb[:2], F[:, 2:] @ tb[2:]]) * ramp[:, None]


def friction_columns(qd: np.ndarray, shape=None) -> np.ndarray:
    """The classic friction regressor (m, 4) at speeds ``qd`` (m,); with ``shape = (ratio_pos, ratio_neg, vs,
    delta)`` (a Stribeck effect whose shape was measured elsewhere: at the breakaways or on the friction map of
    steady segments) the Coulomb columns carry it, ``Fc (1 + (ratio - 1) exp(-|qd / vs|^delta))``, so that the
    model stays linear in the four classic levels."""
    F = classic_friction_columns(qd)
    if shape is not None:
        rp, rn, vs, delta = shape
        e = stribeck_decay(np.asarray(qd, float), vs, delta)
        F[:, 0] *= 1.0 + (rp - 1.0) * e
        F[:, 1] *= 1.0 + (rn - 1.0) * e
    return F


def at_shift(x: np.ndarray, idx: np.ndarray, shift: float) -> np.ndarray:
    """Full-rate samples ``x`` (n,) at the fractional sample positions ``idx + shift`` (linear interpolation; the
    time grid is uniform)."""
    p = np.clip(np.asarray(idx, float) + shift, 0, len(x) - 1)
    i0 = np.minimum(np.floor(p).astype(int), len(x) - 2)
    f = p - i0
    return x[i0] * (1.0 - f) + x[i0 + 1] * f


def shifted_target(des: Design, jd: JointData, d: float) -> np.ndarray:
    """Target (m,) with the positions taken ``d`` later: ``y_d = tau - rnea(q(t + d))`` (a measurement ``d``
    late means ``tau(t) = model(q(t + d))``)."""
    cache = jd.extra.setdefault("_shift", {})
    key = round(float(d), 9)
    if key not in cache:
        shift = d / des.sig.dt_s
        model = des.rnea_Nm.at(np.clip(jd.idx + shift, 0, des.sig.n - 1), jd.j)
        if des.friction_given is not None:
            model += at_shift(des.known_Nm[:, jd.j], jd.idx, shift)
        if len(cache) > 100:
            cache.clear()
        cache[key] = jd.extra["tau"] - model
    return cache[key]


def friction_shape(terms: list[dict], fold: int | None = None):
    """The Stribeck shape ``(ratio_pos, ratio_neg, vs, delta)`` a term among ``terms`` gives the friction
    columns (a Stribeck effect measured elsewhere), or None."""
    for t in terms:
        if t["name"] == "stribeck" and isinstance(t.get("fixed_h"), tuple):
            return t["fixed_h"]
    return None


def target_and_design(des: Design, jd: JointData, terms: list[dict],
                      fold: int | None) -> tuple[np.ndarray, np.ndarray]:
    """Target (m,) and design (m, p) of ``friction + terms`` with the terms' shape parameters of ``fold``
    (None: chosen on all data); a delay term shifts target and friction instead of adding columns."""
    d = delay_of(terms, fold)
    y = shifted_target(des, jd, d) if d else jd.y_Nm
    cols = [columns(des, "friction", jd, friction_shape(terms, fold), d)]
    cols += [columns(des, t["name"], jd, shape_of(t, fold), d) for t in terms if ncols(t) > 0]
    return y, np.hstack(cols)


def block_of(jd: JointData, t_s: np.ndarray) -> np.ndarray:
    """(m,) the joint's time block each time ``t_s`` (m,) falls in (before the first: the first)."""
    blk = jd.extra["block"]
    starts = jd.t_s[np.r_[0, np.flatnonzero(np.diff(blk)) + 1]]
    return np.clip(np.searchsorted(starts, t_s, side="right") - 1, 0, None) + blk[0]
