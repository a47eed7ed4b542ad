"""Signals for the model diagnosis: smoothed states, the rigid-body torque residual, the masks (no I/O).

Conventions
-----------
* Arrays are (n, 7) per joint (0-based columns), time ``t_s`` (n,) uniform after :func:`uniform_grid`.
* Torque timing: a sampled controller reads ``q[k]`` at ``t[k]`` and holds ``tau[k]`` over ``[t[k], t[k+1])``
  (zero-order hold, as the simulator and libbarrett do). The torque acting *around* ``t[k]`` is therefore
  ``(tau[k-1] + tau[k]) / 2``; using it removes the half-sample lag between the logged torque and the
  positions, so that a delay found later is a real one.
* Differentiation: a short Gaussian pre-filter (sigma ``gauss_s``, 8 ms: it removes the high-frequency
  jitter that encoder quantisation causes through the controller, which a Savitzky-Golay filter's sidelobes
  let through) followed by a Savitzky-Golay filter (cubic, centred window of about ``window_s``) gives ``q``,
  ``qd`` and ``qdd`` with no phase lag; the same two filters (derivative 0) are applied to the torque and to
  every feature built from the state, so that the inertial term ``B qdd`` and the torque are smoothed alike and
  the residual is not made of filter mismatch.
* The residual ``y = tau_s - rnea(q_s, qd_s, qdd_s)`` is what friction and any missing effect must explain.
* Masks: where a joint sticks (smoothed speed below a few times the velocity noise) the friction torque is
  static and unknown, so those samples are excluded, and twice the filter's reach on either side of them
  (once because the smoothed speed leaks into the stuck stretch, once because the torque filter reaches it).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np
from scipy.ndimage import correlate1d, gaussian_filter1d, maximum_filter1d
from scipy.signal import savgol_coeffs, savgol_filter

from wamctl.errors import DataFormatError
from wamctl.model import params as P

log = logging.getLogger(__name__)

N7 = P.N_JOINTS
POLYORDER = 3
DEFAULT_WINDOW_S = 0.030       # 15 samples at 500 Hz
DEFAULT_GAUSS_S = 0.008         # 4 samples at 500 Hz: together about 10 Hz of bandwidth, low sidelobes
MIN_RATE_HZ = 50.0             # below this, accelerations cannot be estimated over a window this short
MIN_MOVING_SAMPLES = 200       # a joint needs this many sliding samples to be diagnosed
MIN_TRAVEL_RAD = 0.02
STRETCH_RATIO = 8              # Signals.smooth_at: convolve stretches covering this many times fewer positions
SMOOTH_CHUNK = 2048            # Signals.smooth_at: samples evaluated together, window by window
MAX_GAP_PERIODS = 5.5          # a step of t longer than this (5 or more samples missing) is a gap: left out
ROW_CHUNK = 1 << 16            # full-rate arithmetic on long runs in pieces of this many samples
FACTOR_PROBE = 20000           # Signals._windows: samples of a source checked for repeats (quantised signal)
FACTOR_MAX_SHARE = 0.25        # ... factorised when the distinct values are at most this share of a window set
FACTOR_AFTER_USES = 6          # ... from the source's sixth windowed feature on (the first ones evaluated directly)
KEPT_WINDOWS = 6               # Signals.smooth_at: sets of gathered windows kept for the next features


@dataclass
class Signals:
    """Smoothed, aligned signals of one run (full rate) and the per-joint analysis masks.

    Attributes
    ----------
    t_s : (n,) uniform time, s (starting where the data start).
    dt_s : sample period, s.
    window : Savitzky-Golay window length, samples (odd).
    gauss : Gaussian pre-filter sigma, samples.
    q_rad, qd_rad_s, qdd_rad_s2 : (n, 7) smoothed position and its derivatives.
    tau_Nm : (n, 7) logged torque, half-sample aligned and smoothed like ``q``.
    q_raw_rad, q_ref_rad, tau_raw_Nm : (n, 7) the data as logged (on the uniform grid).
    moving : (n, 7) bool, samples usable for the torque residual (sliding, away from stick, not at the ends, away
        from the log's gaps).
    joints : 0-based joints that moved enough to be diagnosed.
    skipped : {joint (0-based): reason} for joints that were commanded to move but cannot be diagnosed.
    v_stick_rad_s : (7,) speed threshold under which a joint counts as stuck.
    q_noise_rad : (7,) position noise (or quantisation) standard deviation.
    """

    t_s: np.ndarray
    dt_s: float
    window: int
    gauss: float
    qd_rad_s: np.ndarray
    tau_centred_Nm: np.ndarray
    q_raw_rad: np.ndarray
    q_ref_rad: np.ndarray
    tau_raw_Nm: np.ndarray
    moving: np.ndarray
    joints: list[int]
    skipped: dict[int, str] = field(default_factory=dict)
    v_stick_rad_s: np.ndarray = field(default_factory=lambda: np.zeros(N7))
    resampled: bool = False
    q_noise_rad: np.ndarray = field(default_factory=lambda: np.zeros(N7))
    time_base: str = "as logged"
    qd_raw_rad_s: np.ndarray | None = None       # measured velocities (the log's qd_* columns), when given
    valid: np.ndarray | None = None      # (n,) bool: away from the gaps of the log (None: every sample)
    gaps_s: list = field(default_factory=list)   # (t_before, t_after) s of every gap of the log
    _full: dict = field(default_factory=dict, repr=False)
    _memo: dict = field(default_factory=dict, repr=False)

    def memo(self, key, compute):
        """``compute()`` once per ``key``: a statistic of the run's signals that several steps read (a joint's
        encoder step, say), computed over the full run only once."""
        if key not in self._memo:
            self._memo[key] = compute()
        return self._memo[key]

    def statistics(self) -> dict:
        """The statistics :meth:`memo` holds now that another process could take over: those keyed by a tuple
        (a joint's encoder step, its distinct values, the inertia at its onsets), not the gathered windows and their
        counters (keyed by the ids of this process's objects)."""
        return {k: v for k, v in self._memo.items() if isinstance(k, tuple)}

    def adopt_statistics(self, statistics: dict) -> None:
        """Statistics of :meth:`statistics` computed elsewhere on the same signals, kept (one already here stays:
        the same numbers)."""
        for k, v in statistics.items():
            self._memo.setdefault(k, v)

    # The smoothed position, acceleration and torque at the full rate are computed on first use only: a long
    # run is analysed at its joints' (decimated) samples, where :meth:`at` evaluates the filter.
    @property
    def q_rad(self) -> np.ndarray:
        """(n, 7) smoothed position."""
        if "q" not in self._full:
            self._full["q"] = self.smooth(self.q_raw_rad)
        return self._full["q"]

    @property
    def qdd_rad_s2(self) -> np.ndarray:
        """(n, 7) smoothed acceleration."""
        if "qdd" not in self._full:
            self._full["qdd"] = self.smooth(self.q_raw_rad, 2) if self.qd_raw_rad_s is None else \
                self.smooth(self.qd_raw_rad_s, 1)
        return self._full["qdd"]

    @property
    def tau_Nm(self) -> np.ndarray:
        """(n, 7) logged torque, aligned to the zero-order hold and smoothed like ``q``."""
        if "tau" not in self._full:
            self._full["tau"] = self.smooth(self.tau_centred_Nm)
        return self._full["tau"]

    def at(self, what: str, idx: np.ndarray, shift: float = 0.0, joint: int | None = None) -> np.ndarray:
        """(m, 7) smoothed ``"q"``, ``"qd"``, ``"qdd"`` or ``"tau"`` at the samples ``idx`` (``shift`` samples
        later), from the full-rate array when it exists, else by the filter evaluated there; (m,) of one 0-based
        ``joint`` only."""
        key = {"q": "q", "qdd": "qdd", "tau": "tau"}.get(what)
        cols = slice(None) if joint is None else joint
        if what == "qd" or key in self._full:
            full = (self.qd_rad_s if what == "qd" else self._full[key])[:, cols]
            if not shift:
                return full[idx]
            return _interp_rows(full, idx, shift)
        raw = self.tau_centred_Nm if what == "tau" else self.q_raw_rad
        deriv = {"q": 0, "qdd": 2, "tau": 0}[what]
        if what == "qdd" and self.qd_raw_rad_s is not None:
            raw, deriv = self.qd_raw_rad_s, 1
        return self.smooth_at(raw[:, cols], idx, shift, deriv)

    @property
    def zoh_share(self) -> float:
        """See :func:`zoh_share`."""
        return zoh_share(self.dt_s)

    @property
    def n(self) -> int:
        return len(self.t_s)

    def usable(self, rows: np.ndarray | slice = slice(None)) -> np.ndarray:
        """bool per sample of ``rows``: away from the log's gaps (every sample of a log without gaps)."""
        if self.valid is None:
            return np.ones(len(self.t_s), bool)[rows]
        return self.valid[rows]

    @property
    def reach(self) -> int:
        """Samples on either side that the smoothing reaches (see :func:`filter_reach`)."""
        return filter_reach(self.window, self.gauss)

    def smooth(self, X: np.ndarray, deriv: int = 0) -> np.ndarray:
        """The analysis filter (Gaussian pre-filter, then Savitzky-Golay) along axis 0, or its derivative."""
        return smooth(X, self.window, self.gauss, deriv, self.dt_s)

    def kernel(self, deriv: int = 0) -> np.ndarray:
        """The analysis filter (or its ``deriv``-th derivative) as one FIR correlation kernel (2 r + 1 taps, the
        Gaussian truncated at 4 sigma): ``y[i] = sum_k kernel[k] x[i - r + k]``."""
        return _kernel(self.window, float(self.gauss), deriv, self.dt_s)

    def smooth_at(self, X, idx: np.ndarray, shift: float = 0.0, deriv: int = 0, source=None,
                  quantised: bool = False) -> np.ndarray:
        """The analysis filter of a full-rate feature evaluated at the samples ``idx`` only (m, p) or (m,): the
        same convolution as :meth:`smooth` away from the ends (which the masks leave out).

        ``X`` is an (n, p) / (n,) array, or a function ``pos -> values`` of full-rate sample indices (then the
        feature is only evaluated where the filter needs it: long runs are not computed at the full rate), or with
        ``source = (key, x)`` a function of the values of the full-rate signal ``x`` (n,) (its values around a
        long run's samples are then gathered once for every feature of ``x`` at those samples: ``key`` names
        ``x``, and the windows kept are told apart by ``key``, the shift and the number, first and last of the
        samples only, so one ``key`` must always come with the same samples, a joint's). ``shift``: the filtered
        feature ``shift`` samples later (fractional: linear interpolation between the two neighbouring samples, as
        ``np.interp`` of the filtered feature). ``idx`` must be increasing (stretches are found between
        neighbours). ``quantised``: the source is a measured angle (encoder counts: a few values, repeated), so a
        long run's windowed feature is evaluated once per distinct value (see :func:`_levels`).

        Sparse samples (a long run's decimated ones) are evaluated window by window, one matrix-vector product
        over the taps; runs of nearby samples (stretches around onsets) by one convolution over the stretches
        they cover; samples covering most of the run by the convolution at the full rate."""
        k = self.kernel(deriv)
        idx = np.asarray(idx, int)
        base = int(np.floor(shift))
        frac = float(shift - base)
        if source is not None:
            values_fn, x = X, source[1]
            fn, width = (lambda p: values_fn(x[p])), 1
        else:
            fn, width = _feature_fn(X)
        if frac >= 1e-12:         # two neighbouring shifts, interpolated: one kernel a tap longer
            k = np.r_[(1.0 - frac) * k, 0.0] + np.r_[0.0, frac * k]
        first = base - len(self.kernel(deriv)) // 2       # the window of sample i starts at i + first
        if len(idx) == 0:
            return _smooth_windows(fn, width, idx, k, first, self.n)
        gaps = np.flatnonzero(np.diff(idx) > len(k)) + 1    # between stretches whose windows do not touch
        starts, ends = idx[np.r_[0, gaps]], idx[np.r_[gaps - 1, len(idx) - 1]]
        covered = int(np.sum(ends - starts + len(k)))
        # a convolution costs about len(k) / STRETCH_RATIO evaluations of the feature per position it covers
        if STRETCH_RATIO * covered > len(idx) * len(k):
            if source is not None:
                wins = self._windows(source, idx, first, len(k))
                return _smooth_windows(values_fn, width, idx, k, first, self.n, wins,
                                       self._factor(source, wins) if quantised else None)
            return _smooth_windows(fn, width, idx, k, first, self.n)
        if 2 * covered > self.n:
            return _interp_rows(self.smooth(np.asarray(fn(np.arange(self.n)), float), deriv), idx, shift)
        return _smooth_stretches(fn, idx, k, first, starts, ends, self.n)

    def _windows(self, source: tuple, idx: np.ndarray, first: int, taps: int) -> list[np.ndarray]:
        """The values of ``source = (key, x)`` on the windows of the samples ``idx`` (chunks of
        :func:`_smooth_windows`), gathered once and kept for the next features (the last few sets)."""
        key = ("windows", source[0], first, taps, len(idx), int(idx[0]), int(idx[-1]))
        kept = self._memo.setdefault("windows", {})
        if key not in kept:
            if len(kept) >= KEPT_WINDOWS:
                del kept[next(iter(kept))]           # the oldest
            x = source[1]
            tap = first + np.arange(taps)[:, None]
            pos = [np.clip(idx[None, c:c + SMOOTH_CHUNK] + tap, 0, self.n - 1).ravel()
                   for c in range(0, len(idx), SMOOTH_CHUNK)]
            kept[key] = [x[p] for p in pos]
            self._memo.setdefault("windows_pos", {})[id(kept[key])] = (kept[key], pos)
            for gone in [i for i, (w, _) in self._memo["windows_pos"].items()
                         if not any(w is v for v in kept.values())]:
                del self._memo["windows_pos"][gone]
        return kept[key]

    def _factor(self, source: tuple, wins: list[np.ndarray]):
        """``(distinct values, each chunk's indices into them)`` of a quantised source's windows ``wins`` (see
        :func:`_levels`), or None: before the source's ``FACTOR_AFTER_USES``-th feature (a joint whose features
        are few would spend more on the sort than it saves), or when its values are not repeated enough."""
        factors = self._memo.setdefault("windows_factor", {})
        hit = factors.get(id(wins))
        if hit is not None and hit[0] is wins:
            return hit[1]
        uses = self._memo.setdefault("quantised_uses", {})
        uses[source[0]] = uses.get(source[0], 0) + 1
        if uses[source[0]] < FACTOR_AFTER_USES:
            return None
        levels = self.memo(("levels", source[0]), lambda: _levels(source[1]))
        factor = None
        if levels is not None and len(levels[0]) <= FACTOR_MAX_SHARE * sum(len(w) for w in wins):
            factor = levels[0], [levels[1][p] for p in self._memo["windows_pos"][id(wins)][1]]
        kept = self._memo.get("windows", {}).values()
        for gone in [i for i, (w, _) in factors.items() if not any(w is v for v in kept)]:
            del factors[gone]
        factors[id(wins)] = (wins, factor)
        return factor

    @property
    def duration_s(self) -> float:
        return float(self.t_s[-1] - self.t_s[0])


@dataclass
class GridSignal:
    """A full-rate (n, p) signal kept at a grid of its samples and interpolated linearly between them (a long run's
    rigid-body torque is not stored at every sample). ``sig[rows, j]`` reads it like an array (``rows`` sample
    indices or a slice, ``j`` one column); :meth:`at` at fractional sample positions.

    Attributes
    ----------
    grid : (g,) increasing full-rate sample indices (beyond the first and the last, the signal is held).
    values : (g, p) the signal there.
    """

    grid: np.ndarray
    values: np.ndarray

    def __post_init__(self):
        self.values = np.asfortranarray(self.values, dtype=float)     # a column is read at a time

    def at(self, pos: np.ndarray, j: int) -> np.ndarray:
        """Column ``j`` at the (fractional) sample positions ``pos`` (held at the ends)."""
        return np.interp(pos, self.grid, self.values[:, j])

    def __getitem__(self, key) -> np.ndarray:
        rows, j = key           # rows: sample indices (an array, one, or a slice of 0 .. grid[-1]); j: one column
        if isinstance(rows, slice):
            rows = np.arange(int(self.grid[-1]) + 1)[rows]
        return self.at(rows, j)


TIME_AS_LOGGED = "as logged"
TIME_RESAMPLED = "resampled from the time stamps"
TIME_TICKS = "uniform ticks (the time stamps' jitter is the logger's, not the samples')"


def uniform_grid(t_s: np.ndarray, *arrays: np.ndarray, rate_hz: float) -> tuple[np.ndarray, list, str]:
    """(n, k) arrays on a uniform grid at ``rate_hz``; the first array holds the measured positions.

    Jitter below 1 % of the period is left alone. Larger jitter is either the loop's (the samples were taken
    late or early and stamped truthfully: resample from the stamps) or the logger's (the samples were taken on
    exact ticks and stamped with jitter: keep them, on uniform ticks). Without gaps, the time base under which
    the measured positions are smoother (the smaller sum of squared second differences; a moving joint is
    smooth at the sample rate, a wrong time base is not) is taken. Returns ``(t_uniform, arrays, time_base)``.
    """
    dt = 1.0 / rate_hz
    steps = np.diff(t_s)
    if np.abs(steps - dt).max() <= 0.01 * dt:
        return t_s - 0.0, list(arrays), TIME_AS_LOGGED
    n = int(np.floor((t_s[-1] - t_s[0]) / dt)) + 1
    tu = t_s[0] + np.arange(n) * dt
    out = [interp_columns(tu, t_s, a) for a in arrays]
    if len(steps) and steps.min() > 0.5 * dt and steps.max() < 1.5 * dt:
        k = np.arange(len(t_s))
        slope, icpt = np.polyfit(k, t_s, 1)
        ticks = icpt + slope * k
        if abs(slope / dt - 1) < 0.01 and np.abs(t_s - ticks).max() < 0.5 * dt:
            q = np.asarray(arrays[0], float)
            rough_ticks = float(np.sum(np.diff(q, 2, axis=0) ** 2))
            rough_stamps = float(np.sum(np.diff(out[0], 2, axis=0) ** 2))
            if rough_ticks <= rough_stamps:
                return ticks, list(arrays), TIME_TICKS
    return tu, out, TIME_RESAMPLED


def time_gaps(t_s: np.ndarray, rate_hz: float) -> list[tuple[float, float]]:
    """``(t_before, t_after)`` s of every step of ``t_s`` longer than ``MAX_GAP_PERIODS`` sample periods (5 or more
    samples missing): samples the log lost (dropped bus frames, a paused logger). Up to 4 missing samples are
    interpolated like jitter."""
    steps = np.diff(t_s)
    return [(float(t_s[k]), float(t_s[k + 1])) for k in np.flatnonzero(steps > MAX_GAP_PERIODS / rate_hz)]


def outside_gaps(t_s: np.ndarray, gaps: list[tuple[float, float]], margin: int) -> np.ndarray:
    """(n,) bool: the samples of the uniform time ``t_s`` that are neither inside a gap nor within ``margin``
    samples of one (where a filter reaches into the interpolated stretch)."""
    ok = np.ones(len(t_s), bool)
    for a, b in gaps:
        lo, hi = np.searchsorted(t_s, a, "right"), np.searchsorted(t_s, b, "left")
        ok[max(lo - margin, 0):hi + margin] = False
    return ok


def gap_warnings(sig: Signals) -> list[str]:
    """What the log's gaps cost the diagnosis, said (empty without gaps)."""
    if not sig.gaps_s:
        return []
    a, b = max(sig.gaps_s, key=lambda g: g[1] - g[0])
    lost = int(np.count_nonzero(~sig.usable()))
    return [f"t: {len(sig.gaps_s)} gap(s) in the time stamps ({MAX_GAP_PERIODS - 0.5:.0f} or more samples missing; "
            f"the longest {b - a:.3g} s after t = {a:.6g} s): {lost * sig.dt_s:.3g} s of the run ({lost / sig.n:.1%}) "
            f"in and within {2 * sig.reach * sig.dt_s * 1e3:.0f} ms of them is left out"]


def interp_columns(x_new: np.ndarray, x: np.ndarray, Y: np.ndarray) -> np.ndarray:
    """Every column of ``Y`` (n, p), sampled at ``x`` (n,), interpolated linearly at ``x_new`` (m,): (m, p)."""
    return np.column_stack([np.interp(x_new, x, c) for c in np.asarray(Y).T])


def delayed(t_s: np.ndarray, Y: np.ndarray, delay_s: float) -> np.ndarray:
    """``Y(t - delay_s)`` on the same time axis (held at the first value before the start); ``Y`` (n,) or (n, p)."""
    if np.ndim(Y) == 1:
        return np.interp(t_s - delay_s, t_s, Y)
    return interp_columns(t_s - delay_s, t_s, Y)


def zoh_share(dt_s: float) -> float:
    """Share of the previous sample in :func:`zoh_centred` for a log at period ``dt_s``: a logged torque was set
    at its sample and held for one period of the arm's control loop (libbarrett's 500 Hz), so it acts around
    half a control period later; a log slower than the loop (every second tick at 250 Hz, ...) keeps that half
    control period, not half its own period."""
    return 0.5 * min(1.0, (1.0 / P.CONTROL_RATE_HZ) / dt_s)


def zoh_centred(tau: np.ndarray, share: float = 0.5) -> np.ndarray:
    """Torque acting around each sample of a zero-order hold, ``(1 - share) tau[k] + share tau[k-1]`` along
    axis 0 (the first sample kept; ``share`` from :func:`zoh_share`, 1/2 at the loop's own rate): (n,) or
    (n, p), a new array."""
    tau = np.asarray(tau, float)
    out = np.empty_like(tau)
    out[:1] = tau[:1]
    for a in range(1, len(tau), ROW_CHUNK):     # in pieces: no temporary the size of an hour's log
        b = min(a + ROW_CHUNK, len(tau))
        np.multiply(tau[a:b], 1.0 - share, out=out[a:b])
        out[a:b] += share * tau[a - 1:b - 1]
    return out


def filter_reach(window: int, gauss: float) -> int:
    """Samples on either side that the analysis filter reaches (Savitzky-Golay half window + 3 sigma)."""
    return window // 2 + int(np.ceil(3 * gauss))


def measured_steps(q_raw: np.ndarray) -> np.ndarray:
    """The nonzero sample-to-sample changes ``|q[k+1] - q[k]|`` of one joint's measured position (m,), rad:
    multiples of an encoder count on a quantised signal."""
    steps = np.abs(np.diff(q_raw))
    return steps[steps > 1e-12]


def window_samples(rate_hz: float, window_s: float = DEFAULT_WINDOW_S) -> int:
    """Odd Savitzky-Golay window of about ``window_s`` at ``rate_hz`` (at least POLYORDER + 4 samples)."""
    w = int(round(window_s * rate_hz))
    w = max(w, POLYORDER + 4)
    return w + 1 - w % 2


@lru_cache(maxsize=32)
def _kernel(window: int, gauss: float, deriv: int = 0, dt_s: float = 1.0) -> np.ndarray:
    r = window // 2 + int(np.ceil(4 * gauss)) + 1     # the Gaussian is truncated at 4 sigma
    imp = np.zeros(4 * r + 1)
    imp[2 * r] = 1.0
    # the impulse response, reversed: a correlation kernel (symmetric for deriv 0); its outermost taps (one
    # beyond the support on either side) are exactly zero and left out
    return _two_pass(imp, window, gauss, deriv, dt_s)[r + 1:3 * r][::-1].copy()


def _interp_rows(full: np.ndarray, idx: np.ndarray, shift: float) -> np.ndarray:
    """Rows of ``full`` (n,) or (n, p) at the fractional positions ``idx + shift`` (linear interpolation)."""
    n = len(full)
    p = np.clip(np.asarray(idx, float) + shift, 0, n - 1)
    i0 = np.minimum(np.floor(p).astype(int), n - 2)
    f = (p - i0) if full.ndim == 1 else (p - i0)[:, None]
    return full[i0] * (1.0 - f) + full[i0 + 1] * f


def _feature_fn(X) -> tuple:
    """(``pos -> values``, columns) of a full-rate feature: a function as given (one column assumed for the
    chunk size), or the rows of an (n,) / (n, p) array."""
    if callable(X):
        return X, 1
    Xa = np.asarray(X, float)
    if Xa.ndim == 1:
        return Xa.__getitem__, 1
    if Xa.flags.f_contiguous:   # column by column (a table's columns, a filter's output), column-major out

        def columns(p):
            out = np.empty((Xa.shape[1], len(p)))
            for c in range(Xa.shape[1]):
                np.take(Xa[:, c], p, out=out[c])
            return out.T
        return columns, Xa.shape[1]
    return (lambda p: np.take(Xa, p, axis=0)), Xa.shape[1]     # several times faster than fancy indexing


def _levels(x: np.ndarray):
    """``(distinct values, each sample's index into them)`` of a full-rate signal ``x`` (n,) that repeats its
    values (a quantised one: encoder counts; judged on its first ``FACTOR_PROBE`` samples), else None. A
    pointwise feature of the signal's values is then evaluated once per distinct value (the same numbers, read
    back by index)."""
    probe = np.asarray(x[:FACTOR_PROBE])
    if not len(probe) or len(np.unique(probe)) > 0.5 * len(probe):      # a continuous signal: not worth the sort
        return None
    uniq, inv = np.unique(x, return_inverse=True)
    return uniq, inv.astype(np.intp, copy=False)


def _factored_values(fn, factor, i: int, memo: dict) -> np.ndarray:
    """``fn`` of chunk ``i``'s window values: ``fn`` of the distinct values (``factor``: those values and each
    chunk's indices into them, see :func:`_levels`; computed once, kept in ``memo``) read back by index, in the
    memory layout ``fn`` gives (so the products over the taps are the same)."""
    if "U" not in memo:
        memo["U"] = np.asarray(fn(factor[0]), float)
    U, inv = memo["U"], factor[1][i]
    if U.ndim == 1:
        return np.take(U, inv)
    if U.flags.f_contiguous and not U.flags.c_contiguous:
        out = np.empty((U.shape[1], len(inv)))
        for c in range(U.shape[1]):
            np.take(U[:, c], inv, out=out[c])
        return out.T
    return np.take(U, inv, axis=0)


def _smooth_windows(fn, width: int, idx: np.ndarray, k: np.ndarray, first: int, n: int,
                    windows: list[np.ndarray] | None = None, factor=None) -> np.ndarray:
    """``sum_t k[t] fn(i + first + t)`` (m,) / (m, p) at samples ``idx`` (m,) far apart: the feature evaluated
    on each window (positions held at the ends of the run), one matrix-vector product over the taps. With
    ``windows`` (the chunks of a source's values there, see ``Signals._windows``) ``fn`` maps those values
    (pointwise; with ``factor``, see :func:`_factored_values`, it is evaluated on the distinct values only)."""
    taps = first + np.arange(len(k))[:, None]
    out = []
    memo: dict = {}
    chunk = SMOOTH_CHUNK if windows is not None else max(64, SMOOTH_CHUNK // width)   # the arrays stay in cache
    for i, c in enumerate(range(0, max(len(idx), 1), chunk)):
        ii = idx[c:c + chunk]
        if windows is not None and factor is not None and len(ii):
            vals = _factored_values(fn, factor, i, memo)
        elif windows is not None:
            vals = np.asarray(fn(windows[i]), float) if len(ii) else np.zeros(0)
        else:
            vals = np.asarray(fn(np.clip(ii[None, :] + taps, 0, n - 1).ravel()), float)
        if vals.ndim == 1:
            out.append(k @ vals.reshape(len(k), len(ii)))
        elif vals.flags.f_contiguous:          # features built column by column
            out.append((k @ vals.T.reshape(vals.shape[1], len(k), len(ii))).T)
        else:
            out.append((k @ vals.reshape(len(k), -1)).reshape(len(ii), vals.shape[1]))
    return out[0] if len(out) == 1 else np.concatenate(out)


def _smooth_stretches(fn, idx: np.ndarray, k: np.ndarray, first: int, starts: np.ndarray, ends: np.ndarray,
                      n: int) -> np.ndarray:
    """:func:`_smooth_windows` for samples ``idx`` that come in stretches ``[starts, ends]`` (inclusive, in
    order, their windows apart): the feature evaluated once on each stretch's span, one convolution over the
    spans laid end to end (each output reads its own span only)."""
    lengths = ends - starts + len(k)
    offsets = np.r_[0, np.cumsum(lengths)[:-1]]
    within = np.arange(int(lengths.sum())) - np.repeat(offsets, lengths)
    pos = np.clip(np.repeat(starts + first, lengths) + within, 0, n - 1)
    vals = np.asarray(fn(pos), float)
    conv = correlate1d(vals, k, axis=0, mode="nearest")      # conv[c + L // 2] = sum_t k[t] vals[c + t]
    stretch = np.searchsorted(starts, idx, side="right") - 1
    return conv[offsets[stretch] + (idx - starts[stretch]) + len(k) // 2]


GAIN_TABLE_STEPS = 4096          # per cycle/sample: the table's step is a power of two, so indexing it is exact


@lru_cache(maxsize=16)
def _gain_table(window: int) -> tuple[np.ndarray, np.ndarray]:
    f = np.arange(GAIN_TABLE_STEPS // 2 + 2) / GAIN_TABLE_STEPS        # 0 to 0.5, and one step beyond
    c = savgol_coeffs(window, POLYORDER)
    k = np.arange(window) - window // 2
    return f, np.cos(2 * np.pi * np.outer(f, k)) @ c


def savgol_gain(window: int, f_cycles_per_sample: np.ndarray, gauss: float = 0.0) -> np.ndarray:
    """Amplitude response of the smoothing filter (real, zero phase) at normalised frequencies (cycles/sample);
    frequencies above Nyquist are folded back (aliasing). ``gauss``: the Gaussian pre-filter's sigma."""
    f = np.abs(np.asarray(f_cycles_per_sample, float)) % 1.0
    f = np.minimum(f, 1.0 - f)
    _, gt = _gain_table(window)
    # linear interpolation in the table (uniform steps: the index is computed, not searched)
    x = f * GAIN_TABLE_STEPS
    i = x.astype(np.intp)
    g = gt[i] + (gt[i + 1] - gt[i]) * (x - i)
    return g * np.exp(-0.5 * (2 * np.pi * f * gauss) ** 2)


def _two_pass(X: np.ndarray, window: int, gauss: float, deriv: int = 0, dt_s: float = 1.0) -> np.ndarray:
    """Gaussian pre-filter (sigma ``gauss`` samples, edges held) then Savitzky-Golay (cubic) along axis 0."""
    Y = gaussian_filter1d(np.asarray(X, float), gauss, axis=0, mode="nearest") if gauss > 0 else X
    return savgol_filter(Y, window, POLYORDER, deriv=deriv, delta=dt_s, axis=0)


def smooth(X: np.ndarray, window: int, gauss: float, deriv: int = 0, dt_s: float = 1.0) -> np.ndarray:
    """The analysis filter along axis 0: a Gaussian pre-filter (sigma ``gauss`` samples) then a cubic
    Savitzky-Golay filter of ``window`` samples (its ``deriv``-th derivative), applied as one FIR kernel (the
    two filters composed; the ends held)."""
    X = np.asarray(X, float)
    if len(X) < 4 * window + 8 * int(np.ceil(gauss)) + 4:
        return _two_pass(X, window, gauss, deriv, dt_s)
    k = _kernel(window, float(gauss), deriv, dt_s)
    if X.ndim == 1:
        return correlate1d(X, k, mode="nearest")
    return correlate1d(np.ascontiguousarray(X.T), k, axis=1, mode="nearest").T


def derivative_noise_gain(window: int, gauss: float, dt_s: float) -> float:
    """Standard deviation of the filtered velocity per unit of white position noise."""
    n = 4 * window + 8 * int(np.ceil(gauss)) + 1
    imp = np.zeros(n)
    imp[n // 2] = 1.0
    return float(np.sqrt(np.sum(smooth(imp, window, gauss, 1, dt_s) ** 2)))


def _spread_chunks(x: np.ndarray, n_max: int = 200_000, chunks: int = 20) -> np.ndarray:
    """``x`` (n, ...) itself, or for a long run ``chunks`` contiguous pieces spread over it, ``n_max`` samples
    together (noise statistics need not read an hour of data)."""
    n = len(x)
    if n <= n_max:
        return x
    L = n_max // chunks
    starts = np.linspace(0, n - L, chunks).astype(int)
    return np.concatenate([x[s:s + L] for s in starts])


def position_noise_rad(q_raw: np.ndarray) -> np.ndarray:
    """(7,) standard deviation of the measured positions about the motion: position noise, or quantisation.

    Estimated from the part of ``q`` a short cubic fit does not explain (robust MAD); quantised signals whose
    high-pass is mostly zero get the smallest step over root 12 instead."""
    q_raw = _spread_chunks(q_raw)
    short = 7 if len(q_raw) > 7 else POLYORDER + 2
    short += 1 - short % 2
    hf = q_raw - savgol_filter(q_raw, short, POLYORDER, axis=0)
    sig_q = 1.4826 * np.median(np.abs(hf - np.median(hf, axis=0)), axis=0)
    for j in range(q_raw.shape[1]):
        nz = measured_steps(q_raw[:, j])
        if len(nz):
            sig_q[j] = max(sig_q[j], np.percentile(nz, 5) / np.sqrt(12))
    return sig_q


def velocity_noise_rad_s(q_raw: np.ndarray, dt_s: float, window: int, gauss: float = 0.0) -> np.ndarray:
    """(7,) standard deviation of the smoothed velocity caused by position noise/quantisation: the position
    noise (:func:`position_noise_rad`) through the derivative filter's noise gain."""
    return position_noise_rad(q_raw) * derivative_noise_gain(window, gauss, dt_s)


def prepare_signals(t_s: np.ndarray, q_rad: np.ndarray, q_ref_rad: np.ndarray, tau_Nm: np.ndarray,
                    rate_hz: float, joints_hint: list[int] | None = None,
                    window_s: float = DEFAULT_WINDOW_S, gauss_s: float = DEFAULT_GAUSS_S,
                    qd_rad_s: np.ndarray | None = None) -> Signals:
    """Align, smooth and mask a run's samples.

    Parameters
    ----------
    t_s : (n,) time stamps, s (strictly increasing). A step longer than ``MAX_GAP_PERIODS`` periods is a gap
        (:func:`time_gaps`): the grid interpolates across it and the samples within twice the filters' reach of
        it are left out of every fit (:attr:`Signals.valid`).
    q_rad, q_ref_rad, tau_Nm : (n, 7) measured positions, reference, logged torque.
    rate_hz : nominal sample rate.
    joints_hint : 0-based joints the metadata says moved (others are also diagnosed if they moved).
    qd_rad_s : (n, 7) measured velocities, when the log has them: smoothed (and differentiated once for the
        acceleration) instead of differentiating the positions.

    Raises
    ------
    DataFormatError
        Non-finite samples, a sample rate too low to differentiate, or too few samples (away from the gaps).
    """
    for name, a in (("t", t_s), ("q", q_rad), ("q_ref", q_ref_rad), ("tau", tau_Nm)):
        if not np.isfinite(a).all():
            bad = np.argwhere(~np.isfinite(np.atleast_2d(a.T).T))[0]
            raise DataFormatError(f"{name}: non-finite value at data row {int(bad[0]) + 1}; "
                                  "the diagnosis needs complete samples")
    if rate_hz < MIN_RATE_HZ:
        raise DataFormatError(f"sample_rate_hz is {rate_hz:g}; the diagnosis differentiates positions twice "
                              f"and needs at least {MIN_RATE_HZ:g} Hz")
    gaps = time_gaps(np.asarray(t_s, float), rate_hz)
    arrays = [q_rad, q_ref_rad, tau_Nm] + ([qd_rad_s] if qd_rad_s is not None else [])
    t, out, time_base = uniform_grid(np.asarray(t_s, float), *arrays, rate_hz=rate_hz)
    q, q_ref, tau = out[:3]
    qd_meas = out[3] if qd_rad_s is not None else None
    dt = 1.0 / rate_hz
    w = window_samples(rate_hz, window_s)
    gs = gauss_s * rate_hz
    if len(t) < 4 * w:
        raise DataFormatError(f"only {len(t)} samples; the diagnosis needs at least {4 * w} "
                              f"({4 * w * dt:.2f} s at {rate_hz:g} Hz)")
    tau_c = zoh_centred(tau, zoh_share(1.0 / rate_hz))
    qd = smooth(q, w, gs, 1, dt) if qd_meas is None else smooth(qd_meas, w, gs)

    valid = outside_gaps(t, gaps, 2 * filter_reach(w, gs))
    if valid.sum() < 4 * w:
        raise DataFormatError(f"only {int(valid.sum())} samples away from the gaps in t ({len(gaps)} gaps of "
                              f"{MAX_GAP_PERIODS - 0.5:.0f} or more missing samples); the diagnosis needs at least "
                              f"{4 * w}")
    q_noise = position_noise_rad(q if valid.all() else q[valid])     # (a log without gaps: no copy of it)
    v_noise = q_noise * derivative_noise_gain(w, gs, dt)
    # stuck: slower than 4 sigma of the velocity noise, and never faster than a floor of 1 mrad/s
    v_stick = np.maximum(4.0 * v_noise, 1e-3)
    stuck = np.empty(qd.shape, bool)
    for a in range(0, len(qd), ROW_CHUNK):      # in pieces: no temporary the size of an hour's log
        np.less(np.abs(qd[a:a + ROW_CHUNK]), v_stick[None, :], out=stuck[a:a + ROW_CHUNK])
    reach = filter_reach(w, gs)
    moving = maximum_filter1d(stuck.view(np.uint8), 4 * reach + 1, axis=0, mode="constant") == 0
    edge = 2 * reach  # the filter's edge samples are extrapolations
    moving[:edge] = False
    moving[-edge:] = False
    moving &= valid[:, None]

    hint = set(joints_hint or [])
    joints, skipped = [], {}
    for j in range(q.shape[1]):
        travel = float(np.ptp(q[:, j]))
        n_mov = int(moving[:, j].sum())
        commanded = j in hint or np.ptp(q_ref[:, j]) > MIN_TRAVEL_RAD
        if travel < MIN_TRAVEL_RAD or n_mov < MIN_MOVING_SAMPLES:
            if commanded:
                why = (f"moved {travel:.4f} rad with {n_mov} sliding samples; at least {MIN_TRAVEL_RAD} rad and "
                       f"{MIN_MOVING_SAMPLES} samples are needed")
                if travel >= MIN_TRAVEL_RAD:
                    why += (f" (it stopped again within {4 * reach * dt * 1e3:.0f} ms every time it moved: "
                            "steps, or stick-slip throughout; too short for a sliding residual)")
                skipped[j] = why
            continue
        joints.append(j)
    return Signals(t, dt, w, gs, qd, tau_c, q, q_ref, tau, moving, joints, skipped, v_stick,
                   time_base == TIME_RESAMPLED, q_noise, time_base, qd_meas, valid=valid, gaps_s=gaps)


def refuse_joints(sig: Signals, refused: dict[int, str]) -> dict[int, str]:
    """Leave out of ``sig``, in place, the joints of ``refused`` ({0-based joint: why}, e.g. a controller-torque
    log's joints whose gravity torque varies, :func:`wamctl.model.controller_torque.constant_gravity`) that move or
    were commanded to: off ``sig.joints``, into ``sig.skipped`` with the reason (joint order). Returns those."""
    refused = {j: why for j, why in refused.items() if j in sig.joints or j in sig.skipped}
    if refused:
        sig.joints = [j for j in sig.joints if j not in refused]
        skipped = {**sig.skipped, **refused}
        sig.skipped = {j: skipped[j] for j in sorted(skipped)}
    return refused
