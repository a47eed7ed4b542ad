"""Causal, per-sample processing of the gaze stream (thesis 6.2.1, 6.3.1 and 6.4.1).

Conventions
-----------
* Every stage is a small object with ``update(sample) -> output`` and ``reset()``; it sees each sample
  once, in time order, and never looks ahead.
* Point stages return a :class:`~wamctl.hmi.gaze.GazeSample` or ``None`` when they drop the sample; the
  filters only take valid points and return ``None`` (state unchanged) for anything else, so they can sit
  after the removers or on their own.
* Windows are given in seconds and turned into a number of taps with a sample rate (the nominal 30 Hz of
  the tracker unless told otherwise); the voluntary-blink threshold uses the *measured* rate.
* Angles in radians, in [0, 2 pi), 0 = right, pi/2 = up in the command frame of
  :func:`wamctl.hmi.gaze.gaze_vector_px`.
"""

from __future__ import annotations

import logging
import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass

from wamctl.hmi.gaze import NOMINAL_RATE_HZ, GazeFlag, GazeSample, gaze_angle_rad

logger = logging.getLogger(__name__)

# Thesis 6.2.1: a blink is voluntary if the eyes stay closed more than 0.7 s (Krolak and Strumillo, 2012),
# "22 samples" at the tracker's ~0.033 s period.
VOLUNTARY_BLINK_S = 0.7
# Thesis 6.3.1: moving-average windows tried for the four-directional control (300 ms retained).
FILTER_WINDOWS_S = (0.150, 0.300, 0.500)
# Thesis 6.4.1: process-noise covariances of the Kalman filter on the gaze-vector angle (0.001 retained).
KALMAN_Q = (0.001, 0.0001)
# The thesis does not give R. Its filter follows Welch and Bishop, whose worked example (and the SciPy
# cookbook port of it) uses R = 0.1 ** 2; the steady-state gain depends on Q / R only.
KALMAN_R = 0.01

_TWO_PI = 2.0 * math.pi


def window_taps(window_s: float, rate_hz: float) -> int:
    """Number of taps M of a window of ``window_s`` at ``rate_hz`` (rounded half up, at least 1).

    At 30 Hz: 150 ms -> 5, 300 ms -> 9, 500 ms -> 15.
    """
    if window_s <= 0 or rate_hz <= 0:
        raise ValueError(f"window_s and rate_hz must be > 0, got {window_s}, {rate_hz}")
    return max(1, math.floor(window_s * rate_hz + 0.5))


def wrap_angle_rad(angle_rad: float) -> float:
    """Angle folded into [0, 2 pi)."""
    return angle_rad % _TWO_PI


def angle_difference_rad(a_rad: float, b_rad: float) -> float:
    """Signed shortest difference ``a - b`` folded into [-pi, pi)."""
    return (a_rad - b_rad + math.pi) % _TWO_PI - math.pi


# --------------------------------------------------------------------------------------------------
# Sample rate, removers, blink detection


# Fractions of the period that sort the intervals of a window (see measured_period_s): shorter than
# BURST_FRACTION, the later of two stamps taken together on arrival (a burst); longer than DROP_FRACTION,
# an interval that can hold dropped lines.
BURST_FRACTION = 0.5
DROP_FRACTION = 1.5


def measured_period_s(intervals_s: Sequence[float | None], *, n_iterations: int = 5) -> float | None:
    """Sample period of a window of intervals between successive sample times, s; ``None`` if none can be used.

    ``intervals_s`` is oldest first; ``None`` marks a break (a stall or a time that went back), which splits the
    window into segments whose intervals are not comparable across it. With ``P`` the period (first the plain
    mean of the intervals, then this function's own result, until it no longer changes or ``n_iterations``
    times), in each segment:

    * an interval shorter than ``BURST_FRACTION * P`` is *short*: its later sample was stamped with the earlier
      one, in a burst, and the long interval next to it is the wait for that burst, not dropped lines;
    * the segment is used from the sample before its first long interval to the last sample that a long
      interval (or the break closing the segment) follows: from the end of a burst to the end of a burst, so a
      window that starts or ends inside a burst does not count the burst's samples without their wait (the
      newest sample is used once the next one shows where its burst ends);
    * each used interval counts as one, except one longer than ``DROP_FRACTION * P`` with no short interval on
      either side, which counts as ``round(d / P)`` intervals: the lines dropped in it.

    The period is the used time over the count of used intervals. For a steady stream, the mean interval (in
    the tracker's whole milliseconds, 33, 33, 34 ms gives 33.3 ms, where the median says 33), with dropped
    lines not lengthening it. With bursts, the time per sample between burst ends, not a burst's 0-2 ms:
    exact when each burst holds the lines that fell due in the wait before it, and off by the spread of the
    stamps within a burst over the used time otherwise (0-4 ms in 1 s at 60 Hz over 61 intervals; 0.49 %
    the worst of 400 random mixes of 1-3 lines); a latency timer that is not a whole number of periods puts
    a line more or fewer in some bursts, up to one interval over the count (2.3 % the worst seen at 30 Hz
    over 61 intervals, timers of 35-99 ms). Lines dropped next to a burst are not told from the burst's
    wait, and lengthen the period by their share of the window.
    """
    segments: list[list[float]] = [[]]
    for d_s in intervals_s:
        if d_s is None:
            segments.append([])
        else:
            segments[-1].append(d_s)
    closed = [True] * (len(segments) - 1) + [False]  # is the segment's last sample followed by a break?
    all_s = [d_s for segment in segments for d_s in segment]
    if not all_s or sum(all_s) <= 0.0:
        return None
    period_s = sum(all_s) / len(all_s)
    for _ in range(n_iterations):
        used_s, n_used = 0.0, 0
        for segment, is_closed in zip(segments, closed):
            t_s, n = _segment_time_and_count(segment, period_s, is_closed)
            used_s += t_s
            n_used += n
        if n_used == 0 or used_s <= 0.0:
            return None
        new_period_s = used_s / n_used
        if new_period_s == period_s:
            break
        period_s = new_period_s
    return period_s


def _segment_time_and_count(segment_s: Sequence[float], period_s: float, closed: bool) -> tuple[float, int]:
    """Used time, s, and count of intervals of one segment at period ``period_s`` (:func:`measured_period_s`)."""
    n = len(segment_s)
    long = [d_s >= BURST_FRACTION * period_s for d_s in segment_s]
    first = next((i for i in range(n) if long[i]), None)
    ends = [i for i in range(n) if (long[i + 1] if i + 1 < n else closed)]
    if first is None or not ends or ends[-1] < first:
        return 0.0, 0
    last = ends[-1]
    t_s, count = 0.0, 0
    for i in range(first, last + 1):
        d_s = segment_s[i]
        t_s += d_s
        alone = (i == 0 or long[i - 1]) and (i + 1 == n or long[i + 1])
        count += math.floor(d_s / period_s + 0.5) if d_s > DROP_FRACTION * period_s and alone else 1
    return t_s, count


class SampleRateEstimator:
    """Sample rate measured on the last intervals between timestamped samples: ``1 / measured_period_s``.

    The tracker runs at a fixed rate (30 or 60 Hz), but its samples' times may come as whole milliseconds
    (33, 33, 34 ms), with dropped lines (an interval of 2-3 periods), with stalls, or, when they are stamped on
    arrival, in bursts (a USB-serial adapter's latency timer hands over 2-3 lines at once, stamped 0-2 ms
    apart, then nothing for 2-3 periods). :func:`measured_period_s` gives the tracker's period in all these:
    not the median interval (33 ms for 30.0 Hz; a burst's 1 ms, 1000 Hz, with bursts) and not the plain mean
    (lengthened by dropped lines). Intervals are kept in arrival order; an interval longer than
    ``max_interval_s`` (a stall) or a time that went back breaks the window there.

    Parameters
    ----------
    nominal_rate_hz : float
        Returned until ``min_intervals`` intervals have been seen and the window gives a period.
    n_intervals : int
        Number of recent intervals (and breaks) kept.
    min_intervals : int
        Intervals needed before the measurement replaces the nominal rate.
    max_interval_s : float
        Longer intervals (stalls) are not counted: they break the window.
    """

    def __init__(self, *, nominal_rate_hz: float = NOMINAL_RATE_HZ, n_intervals: int = 61,
                 min_intervals: int = 5, max_interval_s: float = 0.5) -> None:
        self.nominal_rate_hz = nominal_rate_hz
        self.n_intervals = n_intervals
        self.min_intervals = min_intervals
        self.max_interval_s = max_interval_s
        self.reset()

    def reset(self) -> None:
        self._intervals: deque[float | None] = deque(maxlen=self.n_intervals)
        self._last_t_s: float | None = None
        self.rate_hz = self.nominal_rate_hz

    def update(self, sample: GazeSample) -> float:
        """Take the sample's time (corrupt samples are ignored); return the current rate, Hz."""
        if not sample.has_time:
            return self.rate_hz
        if self._last_t_s is not None:
            dt_s = sample.t_s - self._last_t_s
            counted = 0.0 <= dt_s <= self.max_interval_s  # 0: stamped with the previous one, in a burst
            if counted or (self._intervals and self._intervals[-1] is not None):  # one break for a run of them
                self._intervals.append(dt_s if counted else None)
            if counted and sum(d_s is not None for d_s in self._intervals) >= self.min_intervals:
                period_s = measured_period_s(self._intervals)
                if period_s is not None:
                    self.rate_hz = 1.0 / period_s
        self._last_t_s = sample.t_s
        return self.rate_hz


class BlinkRemover:
    """Drops eye-closed samples (thesis 6.2.1, Figure 6.6)."""

    def update(self, sample: GazeSample) -> GazeSample | None:
        return None if sample.flags & GazeFlag.BLINK else sample

    def reset(self) -> None:
        pass


class CorruptSampleRemover:
    """Drops corrupt and out-of-image samples (thesis 6.1.2: values outside (768, 576))."""

    def update(self, sample: GazeSample) -> GazeSample | None:
        return None if sample.flags & (GazeFlag.CORRUPT | GazeFlag.OUT_OF_RANGE) else sample

    def reset(self) -> None:
        pass


@dataclass(frozen=True, slots=True)
class BlinkEvent:
    """One blink, reported when the eye opens again.

    Attributes
    ----------
    t_start_s : float
        Time of the first eye-closed sample.
    t_end_s : float
        Time of the first valid sample after the blink (when the event is emitted).
    n_samples : int
        Number of eye-closed samples.
    duration_s : float
        ``n_samples`` over the measured sample rate.
    voluntary : bool
        True if the blink counts as a command.
    """

    t_start_s: float
    t_end_s: float
    n_samples: int
    duration_s: float
    voluntary: bool


class VoluntaryBlinkDetector:
    """Counts runs of eye-closed samples and classifies each blink when the eye opens (thesis 6.2.1).

    A blink is voluntary when its run holds at least ``threshold_s * rate_hz`` samples, rounded to the
    nearest whole sample, with the rate measured on the stream (21 samples at 30 Hz, 42 at 60 Hz; the
    thesis's 22 came from 0.7 s over a 0.033 s period, rounded up), and lasts at most ``max_duration_s``
    (longer means the tracker lost the eye, not a command). Out-of-range and corrupt samples neither
    extend nor end a blink.

    Parameters
    ----------
    threshold_s : float
        Shortest voluntary blink.
    max_duration_s : float
        Longest voluntary blink.
    nominal_rate_hz : float
        Rate assumed until enough intervals have been measured.
    """

    def __init__(self, *, threshold_s: float = VOLUNTARY_BLINK_S, max_duration_s: float = 5.0,
                 nominal_rate_hz: float = NOMINAL_RATE_HZ) -> None:
        if not 0 < threshold_s < max_duration_s:
            raise ValueError("need 0 < threshold_s < max_duration_s")
        self.threshold_s = threshold_s
        self.max_duration_s = max_duration_s
        self.rate = SampleRateEstimator(nominal_rate_hz=nominal_rate_hz)
        self.reset()

    def reset(self) -> None:
        self.rate.reset()
        self._run_start_s: float | None = None
        self._run_n = 0

    @property
    def rate_hz(self) -> float:
        """Measured sample rate, Hz."""
        return self.rate.rate_hz

    @property
    def threshold_samples(self) -> int:
        """Run length that makes a blink voluntary at the measured rate."""
        return max(1, math.floor(self.threshold_s * self.rate.rate_hz + 0.5))

    @property
    def in_blink(self) -> bool:
        """True while the eye is closed."""
        return self._run_n > 0

    def update(self, sample: GazeSample) -> BlinkEvent | None:
        """Take one sample; return the blink that ended with it, if any."""
        self.rate.update(sample)
        if sample.is_blink:
            if self._run_n == 0:
                self._run_start_s = sample.t_s
            self._run_n += 1
            return None
        if not sample.is_valid or self._run_n == 0:
            return None
        n = self._run_n
        duration_s = n / self.rate.rate_hz
        event = BlinkEvent(self._run_start_s, sample.t_s, n, duration_s,
                           n >= self.threshold_samples and duration_s <= self.max_duration_s)
        self._run_n = 0
        self._run_start_s = None
        logger.debug("blink of %d samples (%.2f s), voluntary=%s", n, duration_s, event.voluntary)
        return event


# --------------------------------------------------------------------------------------------------
# Moving averages (thesis 6.3.1)


def ma_weights(n_taps: int) -> list[float]:
    """Weights of the moving average, Eq. (6.1), oldest first."""
    return [1.0] * n_taps


def wma_weights(n_taps: int) -> list[float]:
    """Weights of the weighted moving average, Eq. (6.2), oldest first: 1, 2, ..., M (newest).

    Eq. (6.2) prints the factor M(M+1)/2; the normalisation it means is its inverse, 2 / (M(M+1)).
    """
    return [float(k) for k in range(1, n_taps + 1)]


class _WeightedPointFilter:
    """Causal FIR on the x and y of valid points; during warm-up, the newest weights over the points seen."""

    def __init__(self, weights: Sequence[float]) -> None:
        self._weights = list(weights)
        self.n_taps = len(self._weights)
        self.reset()

    def reset(self) -> None:
        self._xs: deque[float] = deque(maxlen=self.n_taps)
        self._ys: deque[float] = deque(maxlen=self.n_taps)

    def update(self, sample: GazeSample) -> GazeSample | None:
        """Filter a valid point; ``None`` (state unchanged) for anything else."""
        if not sample.is_valid:
            return None
        self._xs.append(sample.x_px)
        self._ys.append(sample.y_px)
        weights = self._weights[self.n_taps - len(self._xs):]
        total = sum(weights)
        x_px = sum(w * x for w, x in zip(weights, self._xs)) / total
        y_px = sum(w * y for w, y in zip(weights, self._ys)) / total
        return GazeSample(sample.t_s, x_px, y_px, sample.flags)


class MovingAverageFilter(_WeightedPointFilter):
    """Moving average of the gaze point over ``window_s``, Eq. (6.1) (thesis 6.3.1).

    Parameters
    ----------
    window_s : float
        Window length, s (the thesis tried 0.15, 0.3 and 0.5 s and retained 0.3 s).
    rate_hz : float
        Sample rate used to turn the window into taps (:func:`window_taps`).
    """

    def __init__(self, *, window_s: float = 0.3, rate_hz: float = NOMINAL_RATE_HZ) -> None:
        self.window_s = window_s
        self.rate_hz = rate_hz
        super().__init__(ma_weights(window_taps(window_s, rate_hz)))


class WeightedMovingAverageFilter(_WeightedPointFilter):
    """Linearly weighted moving average of the gaze point, Eq. (6.2) (thesis 6.3.1).

    Parameters
    ----------
    window_s : float
        Window length, s (the thesis tried 0.15 and 0.3 s; 0.5 s was too slow for real time).
    rate_hz : float
        Sample rate used to turn the window into taps (:func:`window_taps`).
    """

    def __init__(self, *, window_s: float = 0.15, rate_hz: float = NOMINAL_RATE_HZ) -> None:
        self.window_s = window_s
        self.rate_hz = rate_hz
        super().__init__(wma_weights(window_taps(window_s, rate_hz)))


# --------------------------------------------------------------------------------------------------
# Kalman filter on the gaze-vector angle (thesis 6.4.1)


class KalmanAngleFilter:
    """Scalar Kalman filter on the direction of the gaze vector, with the wrap-around at 2 pi.

    Random-walk model ``x_k = x_{k-1} + w``, measurement ``z_k = x_k + v`` (Welch and Bishop), ``Q`` and
    ``R`` the covariances of ``w`` and ``v``. The innovation is the shortest signed angle between the
    measurement and the prediction, and the estimate is folded back into [0, 2 pi), so a gaze direction
    crossing 0 rad (the +x axis) is tracked without a swing through pi. The first measurement initialises
    the estimate (error covariance ``R``).

    Parameters
    ----------
    q : float
        Process-noise covariance (thesis: 0.001, retained, or 0.0001, smoother and slower).
    r : float
        Measurement-noise covariance (assumed, see :data:`KALMAN_R`).

    Attributes
    ----------
    angle_rad : float or None
        Current estimate.
    p : float
        Current error covariance.
    gain : float
        Last Kalman gain.
    """

    def __init__(self, *, q: float = KALMAN_Q[0], r: float = KALMAN_R) -> None:
        if q <= 0 or r <= 0:
            raise ValueError(f"q and r must be > 0, got {q}, {r}")
        self.q = q
        self.r = r
        self.reset()

    def reset(self) -> None:
        self.angle_rad: float | None = None
        self.p = self.r
        self.gain = 1.0

    @property
    def steady_state_gain(self) -> float:
        """Gain the filter converges to: ``P- / (P- + R)`` with ``P- = (Q + sqrt(Q^2 + 4 Q R)) / 2``."""
        p_prior = 0.5 * (self.q + math.sqrt(self.q * self.q + 4.0 * self.q * self.r))
        return p_prior / (p_prior + self.r)

    def update_angle(self, angle_rad: float) -> float:
        """Filter one measured angle, rad; return the estimate in [0, 2 pi)."""
        if self.angle_rad is None:
            self.angle_rad = wrap_angle_rad(angle_rad)
            return self.angle_rad
        p_prior = self.p + self.q
        self.gain = p_prior / (p_prior + self.r)
        innovation = angle_difference_rad(angle_rad, self.angle_rad)
        self.angle_rad = wrap_angle_rad(self.angle_rad + self.gain * innovation)
        self.p = (1.0 - self.gain) * p_prior
        return self.angle_rad

    def update(self, sample: GazeSample) -> float | None:
        """Filter the angle of a valid gaze point; ``None`` (state unchanged) for anything else."""
        if not sample.is_valid:
            return None
        return self.update_angle(gaze_angle_rad(sample.x_px, sample.y_px))
