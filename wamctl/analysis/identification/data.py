"""From a measured run to the identification's rows: states, torque, the standard regressor, the mask.

Filtering (two stages, one filter: :func:`wamctl.analysis.diagnosis.signals.smooth`)
-------------------------------------------------------------------------------------
1. The diagnosis' signals (:func:`wamctl.analysis.diagnosis.signals.prepare_signals`, its default filter of
   about 10 Hz, zero phase): the logged torque half-sample aligned (the zero-order hold's delay,
   ``(tau[k-1] + tau[k]) / 2``), ``q, qd, qdd`` and the torque smoothed alike. Any sample rate the diagnosis
   accepts (>= 50 Hz; jittered time stamps are resampled) works here. The result is decimated to about
   ``rate_hz`` (100 Hz; the signals hold nothing above the filter's band) and the standard regressor ``Y`` is
   built there (its velocity and acceleration: see "Derivatives").
2. A second, narrower pass of the same filter over the torque *and every column of* ``Y`` (parallel
   filtering): ``S[tau] = S[Y] pi`` holds exactly because ``tau = Y pi`` is linear in ``pi``, so the filter
   distorts nothing (not the gravity's curvature, not the friction's jump at a reversal) while it averages the
   noise away. Its band follows the commanded motion (:func:`auto_filter`: three times the band holding 99 % of
   the reference's acceleration energy; of its position's where the measurement stands in for a reference not
   logged, whose acceleration is noise). ``window_s=None`` skips it (the residuals then compare with
   ``wamctl diagnose``'s).

Derivatives
-----------
The torque is the smoothing kernel's output. ``derivatives="kernel"`` (identify's default) takes the rows' velocity
and acceleration from the filter's own derivative kernels (Savitzky-Golay, cubic), which are not the smoothing
kernel differentiated: the second-derivative kernel attenuates the acceleration more than the smoothing kernel the
torque (the relative error growing with the frequency squared), so the rows' inertial torque falls short of the
torque's and an identification makes up for it with inertia (noise-free, a wam4 on harmonics of 0.5-2.5 Hz: an
apparent armature of +2.7e-4 to +2.3e-3 kg m^2, tests/analysis/test_identification_rows.py).
``derivatives="smoothed"`` takes the smoothed position's own derivatives (:func:`smoothed_derivatives`: a quintic
spline interpolating it at the kept samples, differentiated; a measured velocity, when logged, smoothed alike is
the velocity and its spline gives the acceleration): where the torque is linear in the motion the filtered torque
is exactly what they predict (apparent armature within 5e-5 there). ``identify --payload`` uses these (its inertia
bias, docs/payload.md). ``identify`` does not, by measurement (docs/identify.md, "The rows' derivatives"): on the
simulated wam7 (every seed's joints 2-4) and on the real 7-DOF log at 40 % held out the held-out RMS got worse
and two identification tests failed (cause not established; a suspect: the derivative kernels also attenuate the
position noise's high frequencies more). The reference's regressor (the instruments) is built the same way as the
rows'. The diagnosis keeps its own signals.

Rows
----
A row (sample k, joint j) is usable when joint j slides at every sample the second filter reaches from k:
the diagnosis' ``moving`` mask (away from stick and from the record's ends) and at least ``MIN_SPEED_RAD_S``
(0.02 rad/s; the classic friction model describes friction "at medium low and medium high velocities", thesis
ch. 3: below, Stribeck and stick-slip take over). A stuck joint's friction is static and unknown, so its rows
cannot be used; what only acts on joints that never slide is then undetermined (and said so:
:func:`wamctl.analysis.identification.base.identifiability`).

Arms and torques
----------------
Any arm of :mod:`wamctl.model.robots`: the rows have the joints of the model (``dynamics``), which must be the
arm the run names (``robot:``). A run whose torque is the controller's output (``torque: controller``: gravity
compensation added downstream and not logged) keeps only the joints whose gravity torque under the declared arm
is constant over the run (:func:`wamctl.model.controller_torque.constant_gravity`: zero on a vertical axis, or
held constant because the joints beyond it keep still), the declared gravity added back to their torque; the
others are left out with the reason (:attr:`RunRows.skipped`), and no joint left is an error naming each joint's
reason.

Instruments
-----------
``Z``: the standard regressor of the reference ``q_ref`` through the same two filters. The reference is
exogenous (free of the measurement's noise and of the actuation noise the closed loop feeds back into the
motion) and close to the motion, so it is the instrument of the estimator's instrumental-variable fit, per
joint: a joint's rows are instrumented when its tracking error is at most ``TRACKING_SHARE`` of its motion
(:func:`tracking_shares`), else fitted by least squares, and the estimator says which and why. Until issue 32 one
joint over the threshold turned the instruments off for the whole run, unsaid: on the shipped excitation joint 7
(40 % under kp = 8) made every joint least squares; per joint, the perturbed arm of the identification tests
gives held-out RMS 1.00-1.09x the floor and 76/76 intervals holding the truth (least squares everywhere:
1.00-1.13x, 68/76; instruments on every joint, threshold 0.6: 1.00-1.07x, 76/76), so the threshold was kept.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.interpolate import make_interp_spline
from scipy.ndimage import binary_dilation

from wamctl.analysis.diagnosis.signals import (
    DEFAULT_GAUSS_S,
    DEFAULT_WINDOW_S,
    filter_reach,
    prepare_signals,
    refuse_joints,
    savgol_gain,
    smooth,
    window_samples,
)
from wamctl.analysis.identification.base import standard_regressor
from wamctl.errors import DataFormatError
from wamctl.model import params as P
from wamctl.model.controller_torque import constant_gravity

N7 = P.N_JOINTS
ROW_RATE_HZ = 100.0
SIGNAL_SHARE = 0.99     # of the reference's acceleration energy that sets the signal band
BAND_MARGIN = 3.0       # the second filter's cut-off at least this many times the signal band
TRACKING_SHARE = 0.2    # a joint whose reference is further from its motion is fitted by least squares
MIN_SPEED_RAD_S = 0.02  # slower sliding is left out (see the module doc)
HELD_RANGE_RAD = 0.05   # a joint without sliding rows whose position spans less than this is held (at rest)
WINDOWS_S = (0.06, 0.08, 0.1, 0.15, 0.2, 0.3, 0.4)     # candidate Savitzky-Golay windows (Gaussian: a quarter)


@dataclass
class RunRows:
    """One run's identification rows, at the decimated samples.

    Attributes
    ----------
    source : where the run came from.
    t_s : (m,) time of each kept sample, s.
    q_rad, qd_rad_s : (m, n) states (first filter); n the arm's joints (7 on the wam7).
    tau_Nm : (m, n) torque through both filters.
    usable : (m, n) bool, rows (sample, joint) where the joint slides over the second filter's reach.
    Y : (m, 7, 105) standard regressor (:func:`~wamctl.analysis.identification.base.standard_regressor`)
        through the second filter.
    Z : (m, 7, 105) the reference's, likewise: instruments.
    joints : 0-based joints with usable rows.
    skipped : {0-based joint: why} for joints commanded to move that yield no rows.
    dt_s : period of the kept samples. reach_s : the filters' reach on either side, s.
    tracking_share : (7,) tracking error RMS / motion RMS per joint (:func:`tracking_shares`).
    accounting : where the candidate rows (kept sample, joint commanded to move) went (:func:`row_accounting`).
    window_s, gauss_s : the second filter (None: none).
    """

    source: str
    t_s: np.ndarray
    q_rad: np.ndarray
    qd_rad_s: np.ndarray
    tau_Nm: np.ndarray
    usable: np.ndarray
    Y: np.ndarray
    Z: np.ndarray
    joints: list[int]
    skipped: dict[int, str]
    dt_s: float
    reach_s: float
    window_s: float | None
    gauss_s: float | None
    tracking_share: np.ndarray | None = None
    accounting: dict | None = None
    torque_kind: str = "total"
    reference_logged: bool = True   # False: the log held none, the measurement stood in (no instruments then)

    @property
    def n_joints(self) -> int:
        return int(self.usable.shape[1])

    @property
    def reference_tracks(self) -> np.ndarray:
        """(n,) bool per joint: its rows are instrumented by the reference (:func:`tracking_shares` at most
        ``TRACKING_SHARE``); joints without rows are False."""
        n = self.n_joints
        if self.tracking_share is None:
            return np.isin(np.arange(n), self.joints)
        with np.errstate(invalid="ignore"):
            return np.asarray(self.tracking_share <= TRACKING_SHARE) & np.isin(np.arange(n), self.joints)

    @property
    def n_rows(self) -> int:
        return int(self.usable.sum())

    def stacked(self, mask: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Usable rows in time order (joints interleaved): ``(Y (r, 105), tau (r,), joint (r,), sample (r,))``;
        ``mask`` (m,) bool restricts the samples (e.g. a held-out block)."""
        use = self.usable if mask is None else self.usable & np.asarray(mask, bool)[:, None]
        k, j = np.nonzero(use)
        return self.Y[k, j, :], self.tau_Nm[k, j], j, k

    def restricted(self, mask: np.ndarray) -> RunRows:
        """A copy whose usable rows are limited to the samples ``mask`` (m,) bool (e.g. a fitting block); the rows
        left out count as ``held_out`` in the accounting."""
        usable = self.usable & np.asarray(mask, bool)[:, None]
        acc = self.accounting
        if acc is not None:
            used = int(usable[:, self.joints].sum()) if self.joints else 0
            acc = dict(acc, used=used, held_out=acc.get("held_out", 0) + acc["used"] - used)
        return replace(self, usable=usable, accounting=acc)

    def instruments(self) -> np.ndarray:
        """The instruments' rows (r, 105), in the order of :meth:`stacked` (no mask): for the rows of a joint
        whose reference follows its motion (:attr:`reference_tracks`) the reference's regressor, for the others
        the regressor itself (least squares on that joint's rows)."""
        k, j = np.nonzero(self.usable)
        return np.where(self.reference_tracks[j][:, None], self.Z[k, j, :], self.Y[k, j, :])


def signal_band_hz(t_s: np.ndarray, q_ref_rad: np.ndarray, share: float = SIGNAL_SHARE, order: int = 2) -> float:
    """Frequency below which ``share`` of the reference's acceleration energy lies (all joints together), Hz:
    where the commanded motion ends and only noise and the loop's own dynamics remain. ``order``: of the
    derivative whose energy is counted (2: the acceleration; 0: the position, for a measured stand-in, see
    :func:`auto_filter`)."""
    dt = float(np.median(np.diff(t_s)))
    qdd = np.diff(q_ref_rad, order, axis=0) / dt ** order
    qdd = qdd - qdd.mean(axis=0)
    if not np.any(qdd):
        return 0.0
    p = np.sum(np.abs(np.fft.rfft(qdd, axis=0)) ** 2, axis=1)
    f = np.fft.rfftfreq(len(qdd), dt)
    c = np.cumsum(p) / p.sum()
    return float(f[min(int(np.searchsorted(c, share)), len(f) - 1)])


def cutoff_hz(rate_hz: float, window_s: float, gauss_s: float) -> float:
    """Half-power frequency of the analysis filter (Gaussian + Savitzky-Golay) at ``rate_hz``, Hz."""
    f = np.linspace(0.0, 0.5, 4001)
    gain = savgol_gain(window_samples(rate_hz, window_s), f, gauss_s * rate_hz)
    below = np.flatnonzero(gain < np.sqrt(0.5))
    return float(f[below[0]] * rate_hz) if len(below) else rate_hz / 2


def auto_filter(t_s: np.ndarray, q_ref_rad: np.ndarray, rate_hz: float = ROW_RATE_HZ,
                stand_in: bool = False) -> tuple[float, float] | None:
    """(window_s, gauss_s) of the second filter: the narrowest whose cut-off is at least ``BAND_MARGIN`` times
    :func:`signal_band_hz`, or None when no candidate is narrower than the first filter (fast motion).

    ``stand_in``: the "reference" is the measured position (none was logged). Its acceleration's energy is then
    the sensor's noise, which second differences raise as f^4: on the three real logs without a reference
    (alberta slax, zeus, the 7-DOF) 99 % of it lies at 123.5-124.6 Hz, the Nyquist frequency, so no second filter
    was chosen and the fit and its held-out check ran on that noise (issue H10: slax's false `worse`). The band
    is then the position's (0.82 / 1.03 / 0.50 Hz there), which the noise hardly touches."""
    band = signal_band_hz(t_s, q_ref_rad, order=0 if stand_in else 2) * BAND_MARGIN
    first = cutoff_hz(rate_hz, DEFAULT_WINDOW_S, DEFAULT_GAUSS_S)
    best = None
    for w in WINDOWS_S:
        g = w / 4.0
        if band <= cutoff_hz(rate_hz, w, g) < first:
            best = (w, g)
    return best


def tracking_shares(q_rad: np.ndarray, q_ref_rad: np.ndarray, joints: list[int]) -> np.ndarray:
    """(n,) per joint: the RMS of its tracking error ``q - q_ref`` over the RMS of its motion (about its mean);
    NaN for joints not in ``joints`` or that do not move."""
    out = np.full(np.shape(q_rad)[1], np.nan)
    for j in joints:
        motion = float(np.std(q_rad[:, j]))
        if motion > 0:
            out[j] = float(np.sqrt(np.mean((q_rad[:, j] - q_ref_rad[:, j]) ** 2))) / motion
    return out


def row_accounting(moving: np.ndarray, fast: np.ndarray, usable: np.ndarray, joints: list[int],
                   reach2_s: float) -> dict:
    """Where the candidate rows (kept sample, joint commanded to move) went: ``near_stop`` (within the first
    filter's reach of a stop or of the record's ends: the diagnosis' ``moving`` mask), ``slow`` (below
    ``MIN_SPEED_RAD_S``), ``filter_reach`` (sliding, but within the second filter's reach of such a sample),
    ``used``."""
    j = list(joints)
    mv, fa, us = moving[:, j], fast[:, j], usable[:, j]
    return {"candidates": int(mv.size), "near_stop": int((~mv).sum()), "slow": int((mv & ~fa).sum()),
            "filter_reach": int((mv & fa & ~us).sum()), "used": int(us.sum()), "second_filter_reach_s":
            float(reach2_s), "min_speed_rad_s": MIN_SPEED_RAD_S}


def _dilate(mask: np.ndarray, reach: int) -> np.ndarray:
    return binary_dilation(mask, structure=np.ones((2 * reach + 1, 1), bool)) if reach > 0 else mask


def smoothed_derivatives(t_s: np.ndarray, q_rad: np.ndarray,
                         qd_rad_s: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """``(qd (m, n), qdd (m, n))`` at the samples ``t_s`` (m,): the derivatives of the smoothed position ``q_rad``
    itself, those of the quintic spline interpolating it (see "Derivatives" in the module doc). ``qd_rad_s``: the
    smoothed *measured* velocity, when the log has one: it is the velocity, and the spline through it gives the
    acceleration."""
    if qd_rad_s is None:
        spline = make_interp_spline(t_s, q_rad, k=5, axis=0)
        return spline.derivative(1)(t_s), spline.derivative(2)(t_s)
    qd = np.array(qd_rad_s, float)
    return qd, make_interp_spline(t_s, qd, k=5, axis=0).derivative(1)(t_s)


def run_rows(data, dynamics, rate_hz: float = ROW_RATE_HZ, window_s: float | str | None = "auto",
             gauss_s: float | None = None, derivatives: str = "kernel") -> RunRows:
    """The identification rows of one run (:class:`wamctl.runs.measured.RunData`).

    ``dynamics`` (a WamDynamics) supplies the kinematics of the regressor. ``window_s``: ``"auto"``
    (:func:`auto_filter`), None (no second filter: residuals comparable with ``wamctl diagnose``'s), or seconds
    (with ``gauss_s``, default a quarter of it). ``derivatives``: the regressor's velocity and acceleration from
    the first filter's derivative kernels (``"kernel"``, identify's) or the smoothed position's own
    (``"smoothed"``, the payload's; see "Derivatives" in the module doc). Raises DataFormatError (from the
    diagnosis' signal preparation) for data that cannot be differentiated, for a run of another arm than
    ``dynamics``', and for a ``torque: controller`` run without a joint whose gravity torque is constant (see the
    module doc)."""
    meta = data.meta
    nj = int(getattr(dynamics, "n_joints", N7))
    robot = getattr(meta, "robot", "wam7")
    dyn_robot = getattr(getattr(dynamics, "robot", None), "name", "wam7")
    if robot != dyn_robot:
        raise DataFormatError(f"{data.source}: the run is of a {robot}, the declared model of a {dyn_robot}")
    q_raw, q_ref_raw, tau_raw = (data.col(c)[:, :nj] for c in ("q", "q_ref", "tau"))
    torque_kind = getattr(meta, "torque_kind", "total")
    gravity_refused: dict[int, str] = {}
    if torque_kind == "controller":
        tau_raw, gravity_refused = _add_constant_gravity(dynamics, q_raw, tau_raw)
    # the diagnosis' signal preparation takes the wam7's seven columns: a smaller arm's are padded with joints at
    # rest (zero travel: never diagnosed) and cut off again below
    pad = N7 - nj
    if pad > 0:
        q_raw, q_ref_raw, tau_raw = (np.pad(a, ((0, 0), (0, pad))) for a in (q_raw, q_ref_raw, tau_raw))
    sig = prepare_signals(data.t_s, q_raw, q_ref_raw, tau_raw, float(meta.sample_rate_hz),
                          [j - 1 for j in meta.experiment.joints])
    if pad > 0:
        sig = _cut(sig, nj)
    # refused: the joints that move (or were commanded to) whose gravity torque varies
    gravity_refused = refuse_joints(sig, gravity_refused)
    if gravity_refused and not sig.joints:
        raise DataFormatError(f"{data.source}: no joint left to identify (" + "; ".join(
            f"joint {j + 1}: {why}" for j, why in sorted(gravity_refused.items())) + ")")
    step = max(1, int(round(1.0 / (sig.dt_s * rate_hz))))
    keep = np.arange(0, sig.n, step)
    dt = sig.dt_s * step
    if window_s == "auto":
        auto = auto_filter(sig.t_s, sig.q_ref_rad, 1.0 / dt, stand_in=getattr(meta, "reference", None) == "measured")
        window_s, gauss_s = auto if auto else (None, None)
    sliding = sig.moving & (np.abs(sig.qd_rad_s) >= MIN_SPEED_RAD_S)
    sliding[:, [j for j in range(nj) if j not in sig.joints]] = False
    sliding = sliding[keep]
    # a joint that never slides, and never reaches MIN_SPEED_RAD_S or spans less than HELD_RANGE_RAD, is held:
    # its speed and acceleration are the sensors' noise (on a real log with
    # a noisy or missing reference, that noise made 48 of 76 base parameters look determined from two moving
    # joints); at rest in both regressors, what only it could show stays undetermined, at the declared arm
    held = ~sliding.any(axis=0) & ((np.abs(sig.qd_rad_s[keep]).max(axis=0) < MIN_SPEED_RAD_S)
                                   | (np.ptp(sig.q_rad, axis=0) < HELD_RANGE_RAD))
    t = sig.t_s[keep]
    q, q_ref = sig.q_rad[keep].copy(), sig.smooth(sig.q_ref_rad)[keep]
    if derivatives not in ("kernel", "smoothed"):
        raise ValueError(f"derivatives: {derivatives!r}, not 'kernel' or 'smoothed'")
    if derivatives == "kernel":
        qd, qdd = sig.qd_rad_s[keep].copy(), sig.qdd_rad_s2[keep].copy()
        qd_ref, qdd_ref = (sig.smooth(sig.q_ref_rad, d)[keep] for d in (1, 2))
    else:
        qd, qdd = smoothed_derivatives(t, q, None if sig.qd_raw_rad_s is None else sig.qd_rad_s[keep])
        qd_ref, qdd_ref = smoothed_derivatives(t, q_ref)
    for a in (qd, qdd, qd_ref, qdd_ref):
        a[:, held] = 0.0
    for a in (q, q_ref):        # at its median position (its noise would separate columns that rest joins)
        a[:, held] = np.median(a[:, held], axis=0)
    Y = standard_regressor(dynamics, q, qd, qdd)
    Z = standard_regressor(dynamics, q_ref, qd_ref, qdd_ref)
    tau = sig.tau_Nm[keep]
    reach2 = 0
    if window_s is not None:
        gauss_s = window_s / 4.0 if gauss_s is None else gauss_s
        w2 = window_samples(1.0 / dt, window_s)
        if len(keep) < 2 * w2:
            window_s = gauss_s = None
        else:
            g2 = gauss_s / dt
            m = len(keep)
            Y = smooth(Y.reshape(m, -1), w2, g2).reshape(m, nj, 15 * nj)
            Z = smooth(Z.reshape(m, -1), w2, g2).reshape(m, nj, 15 * nj)
            tau = smooth(tau, w2, g2)
            reach2 = filter_reach(w2, g2)
    usable = ~_dilate(~sliding, reach2)
    if reach2:
        usable[:reach2] = usable[-reach2:] = False
    joints = [j for j in sig.joints if usable[:, j].any()]
    # a reference that is the measurement itself (none logged) is no instrument: least squares on every joint
    logged = getattr(meta, "reference", None) != "measured"
    shares = tracking_shares(sig.q_raw_rad, sig.q_ref_rad, joints) if logged else np.full(nj, np.nan)
    accounting = row_accounting(sig.moving[keep], np.abs(sig.qd_rad_s[keep]) >= MIN_SPEED_RAD_S, usable,
                                list(sig.joints), reach2 * dt)
    return RunRows(str(data.source), sig.t_s[keep], sig.q_rad[keep], sig.qd_rad_s[keep], tau, usable, Y, Z,
                   joints, dict(sig.skipped), dt, sig.reach * sig.dt_s + reach2 * dt, window_s, gauss_s,
                   shares, accounting, torque_kind, logged)


def _add_constant_gravity(dynamics, q_rad: np.ndarray, tau_Nm: np.ndarray) -> tuple[np.ndarray, dict]:
    """A ``torque: controller`` run: the declared gravity added to the joints whose gravity torque is constant over
    the run, the others refused ``{0-based joint: why}`` (:func:`wamctl.model.controller_torque.constant_gravity`)."""
    g, refused = constant_gravity(dynamics, q_rad)
    tau = tau_Nm.copy()
    for j in range(q_rad.shape[1]):
        if j not in refused:
            tau[:, j] = tau[:, j] + g[:, j]
    return tau, refused


def _cut(sig, n: int):
    """The diagnosis' signals of a padded run cut back to its ``n`` joints (every per-joint array, cached ones
    included)."""
    for name, value in list(vars(sig).items()):
        if isinstance(value, np.ndarray) and value.ndim >= 1 and value.shape[-1] == N7 and name != "t_s":
            setattr(sig, name, value[..., :n])
    sig._full = {k: v[..., :n] for k, v in sig._full.items()}
    sig._memo.clear()
    sig.joints = [j for j in sig.joints if j < n]
    sig.skipped = {j: w for j, w in sig.skipped.items() if j < n}
    return sig



