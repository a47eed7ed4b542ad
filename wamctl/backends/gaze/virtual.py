"""A simulated wearer of the gaze tracker: a gaze source for simulated trials, with the truth of its blinks."""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from wamctl.backends.gaze.base import RealtimePacer, SourceBase
from wamctl.hmi.gaze import (
    BLINK_SENTINEL_PX,
    CENTER_X_PX,
    CENTER_Y_PX,
    IMAGE_HEIGHT_PX,
    IMAGE_WIDTH_PX,
    NOMINAL_RATE_HZ,
    SCENE_PX_PER_DEG,
    GazeFlag,
    GazeSample,
    classify,
)


@dataclass(frozen=True, slots=True)
class BlinkTruth:
    """Ground truth of one blink produced by :class:`VirtualSubject`.

    Samples with ``t_start_s <= t_s < t_end_s`` are (-2000, -2000).
    """

    t_start_s: float
    t_end_s: float
    voluntary: bool

    @property
    def duration_s(self) -> float:
        return self.t_end_s - self.t_start_s


def _min_jerk(tau: float) -> float:
    return tau * tau * tau * (10.0 - 15.0 * tau + 6.0 * tau * tau)


class VirtualSubject(SourceBase):
    """A simulated wearer of the gaze tracker, looking where it wants the hand to go.

    The gaze follows ``target_px`` with a reaction time, by saccades (main-sequence duration, minimum-jerk
    shape, undershoot and landing error, corrective saccades), and fixates with drift, square-wave
    intrusions (the "involuntary saccades" of thesis 6.2.1), occasional glances elsewhere in the scene and
    tremor/measurement noise. It blinks involuntarily (Poisson onsets, 0.1-0.4 s) and voluntarily on
    :meth:`request_voluntary_blink` (at least ``voluntary_min_s``). The tracker adds out-of-range samples,
    notably just after a blink. Fatigue scales noise, drift, intrusions, blink rate and reaction times up
    by ``1 + fatigue_per_min * minutes``; ``skill`` in [0, 1] (1 = expert) lowers landing error,
    intrusions, glances, noise and reaction time. Everything is drawn from ``numpy.random.default_rng(seed)``.

    Parameters
    ----------
    target_px : callable
        ``target_px(t_s) -> (x_px, y_px)`` the point the subject wants to look at now, or ``None`` to keep
        looking where it looks. May be replaced between reads (attribute ``target_px``).
    seed : int
        Seed of the random generator.
    skill : float
        0 (naive) to 1 (expert).
    fatigue_per_min : float
        Relative growth of the noise terms and reaction time per minute of session.
    rate_hz : float
        Sample rate of the tracker.
    jitter_s : float
        Standard deviation of the timestamp jitter; times are rounded to whole milliseconds.
    blink_rate_hz : float
        Rate of involuntary blinks when rested (people blink about 15 times a minute).
    voluntary_min_s, voluntary_max_s : float
        Range of the durations of voluntary blinks.
    artifact_prob : float
        Probability that a sample is an out-of-range artefact.
    edge_artifact_prob : float
        Probability that the first sample after a blink is an out-of-range artefact (half-open eye).
    duration_s : float or None
        The source is exhausted after this much simulated time (None: never).
    realtime : bool
        If True, :meth:`read` paces samples on the wall clock.
    t0_s : float
        Time of the first sample.
    timeout_s : float
        Default wait of :meth:`read` (only matters when ``realtime``).
    session_start_s : float or None
        Start of the session for the fatigue clock (``t0_s`` if None): a subject simulated trial by trial
        keeps tiring over the session.
    """

    def __init__(self, target_px: Callable[[float], tuple[float, float] | None], *, seed: int = 0,
                 skill: float = 0.8, fatigue_per_min: float = 0.02, rate_hz: float = NOMINAL_RATE_HZ,
                 jitter_s: float = 0.001, blink_rate_hz: float = 0.25, voluntary_min_s: float = 0.75,
                 voluntary_max_s: float = 1.4, artifact_prob: float = 0.002, edge_artifact_prob: float = 0.15,
                 duration_s: float | None = None, realtime: bool = False, t0_s: float = 0.0,
                 timeout_s: float = 0.1, session_start_s: float | None = None) -> None:
        if not 0.0 <= skill <= 1.0:
            raise ValueError(f"skill must be in [0, 1], got {skill}")
        if rate_hz <= 0 or not 0 < voluntary_min_s <= voluntary_max_s:
            raise ValueError("rate_hz must be > 0 and 0 < voluntary_min_s <= voluntary_max_s")
        self.target_px = target_px
        self.seed = seed
        self.skill = skill
        self.fatigue_per_min = fatigue_per_min
        self.rate_hz = rate_hz
        self.jitter_s = jitter_s
        self.blink_rate_hz = blink_rate_hz
        self.voluntary_min_s = voluntary_min_s
        self.voluntary_max_s = voluntary_max_s
        self.artifact_prob = artifact_prob
        self.edge_artifact_prob = edge_artifact_prob
        self.duration_s = duration_s
        self.realtime = realtime
        self.t0_s = t0_s
        self.timeout_s = timeout_s
        self.session_start_s = t0_s if session_start_s is None else session_start_s
        #: Ground truth of every blink so far, in order.
        self.blinks: list[BlinkTruth] = []
        self._rng = np.random.default_rng(seed)
        self._pacer = RealtimePacer()
        self._k = 0
        self._last_t_s = -math.inf
        self._requests: deque[tuple[float, float]] = deque()  # (due time, duration)
        self._blink: BlinkTruth | None = None
        self._refractory_until_s = -math.inf
        self._edge_pending = False
        self._next_blink_s = t0_s + self._exp(self.blink_rate_hz)
        start = target_px(t0_s) or (CENTER_X_PX, CENTER_Y_PX)
        self._goal = (float(start[0]), float(start[1]))
        self._fix = self._goal
        self._last_pos = self._goal
        self._saccade: tuple[float, float, tuple[float, float], tuple[float, float]] | None = None
        self._saccade_due_s: float | None = None
        self._offset: tuple[float, float] = (0.0, 0.0)
        self._offset_until_s = -math.inf
        self._prev_t_s = t0_s

    # -- public ------------------------------------------------------------------------------------

    @property
    def t_s(self) -> float:
        """Time of the last sample produced (``t0_s`` before the first)."""
        return self._prev_t_s

    @property
    def exhausted(self) -> bool:
        return self.duration_s is not None and self._k / self.rate_hz >= self.duration_s

    def request_voluntary_blink(self, *, duration_s: float | None = None, at_s: float | None = None) -> None:
        """Ask the subject for a voluntary blink (to open or close the hand).

        Parameters
        ----------
        duration_s : float or None
            Eyes-closed time; drawn in [voluntary_min_s, voluntary_max_s] if None.
        at_s : float or None
            When the eyes close (at the first sample from then on, once any blink in progress has ended);
            if None, after a reaction time from now.
        """
        if duration_s is None:
            duration_s = float(self._rng.uniform(self.voluntary_min_s, self.voluntary_max_s))
        if at_s is None:
            at_s = self._prev_t_s + self._reaction_s(0.25 + 0.25 * (1.0 - self.skill))
        self._requests.append((at_s, duration_s))

    def read(self, timeout_s: float | None = None) -> GazeSample | None:
        self._check_open()
        if self.exhausted:
            return None
        if self.realtime:
            due_s = self.t0_s + self._k / self.rate_hz
            if not self._pacer.wait(due_s, self.timeout_s if timeout_s is None else timeout_s):
                return None
        return self._step()

    # -- model -------------------------------------------------------------------------------------

    def _exp(self, rate_hz: float) -> float:
        return math.inf if rate_hz <= 0 else float(self._rng.exponential(1.0 / rate_hz))

    def _fatigue(self, t_s: float) -> float:
        return 1.0 + self.fatigue_per_min * (t_s - self.session_start_s) / 60.0

    def _reaction_s(self, mean_s: float) -> float:
        return mean_s * self._fatigue(self._prev_t_s) * math.exp(0.25 * float(self._rng.standard_normal()))

    def _step(self) -> GazeSample:
        rng = self._rng
        k = self._k
        self._k += 1
        t_s = round((self.t0_s + k / self.rate_hz + self.jitter_s * float(rng.standard_normal())) * 1000.0) / 1000.0
        t_s = max(t_s, self._last_t_s + 0.001)
        self._last_t_s = t_s
        dt_s = max(t_s - self._prev_t_s, 0.0)
        self._prev_t_s = t_s
        fatigue = self._fatigue(t_s)
        lack = 1.0 - self.skill

        x_px, y_px = self._eye(t_s, dt_s, fatigue, lack)
        if self._blinking(t_s, fatigue):
            return GazeSample(t_s, BLINK_SENTINEL_PX, BLINK_SENTINEL_PX, GazeFlag.BLINK)
        noise_px = (1.5 + 3.0 * lack) * fatigue
        x_px += noise_px * float(rng.standard_normal())
        y_px += noise_px * float(rng.standard_normal())
        edge = self._edge_pending and rng.random() < self.edge_artifact_prob
        self._edge_pending = False
        if edge:  # the eye half open: the tracker has one coordinate only
            y_px = BLINK_SENTINEL_PX
        elif rng.random() < self.artifact_prob * fatigue:
            x_px = float(rng.choice([-1.0, 1.0])) * float(rng.uniform(800.0, 3000.0))
        x_px, y_px = round(x_px, 1), round(y_px, 1)
        return GazeSample(t_s, x_px, y_px, classify(x_px, y_px))

    def _blinking(self, t_s: float, fatigue: float) -> bool:
        blink = self._blink
        if blink is not None:
            if t_s < blink.t_end_s:
                return True
            self._blink = None
            self._edge_pending = True
            self._refractory_until_s = blink.t_end_s + 0.3
        if t_s < self._refractory_until_s:
            return False
        if self._requests and t_s >= self._requests[0][0]:
            _, duration_s = self._requests.popleft()
            self._start_blink(t_s, duration_s, voluntary=True)
            return True
        if t_s >= self._next_blink_s:
            # Keep involuntary blinks apart from an imminent voluntary one: the truth stays unambiguous.
            if self._requests and self._requests[0][0] - t_s < 0.8:
                self._next_blink_s = t_s + self._exp(self.blink_rate_hz * fatigue)
                return False
            duration_s = min(max(0.2 * math.exp(0.3 * float(self._rng.standard_normal())), 0.1), 0.4)
            self._start_blink(t_s, duration_s, voluntary=False)
            self._next_blink_s = t_s + duration_s + self._exp(self.blink_rate_hz * fatigue)
            return True
        return False

    def _start_blink(self, t_s: float, duration_s: float, *, voluntary: bool) -> None:
        self._blink = BlinkTruth(t_s, t_s + duration_s, voluntary)
        self.blinks.append(self._blink)

    def _eye(self, t_s: float, dt_s: float, fatigue: float, lack: float) -> tuple[float, float]:
        """Advance the oculomotor state to ``t_s``; return the true eye position, px."""
        rng = self._rng
        goal = self.target_px(t_s)
        if goal is not None:
            self._goal = (float(goal[0]), float(goal[1]))
        gx, gy = self._goal

        if self._saccade is not None:
            t0_s, dur_s, (x0, y0), (x1, y1) = self._saccade
            tau = (t_s - t0_s) / dur_s
            if tau < 1.0:
                s = _min_jerk(tau)
                self._last_pos = (x0 + (x1 - x0) * s, y0 + (y1 - y0) * s)
                return self._last_pos
            self._saccade = None
            self._fix = (x1, y1)

        # Fixation: the centre drifts as a random walk.
        drift_px = (6.0 + 10.0 * lack) * fatigue * math.sqrt(dt_s)
        fx = self._fix[0] + drift_px * float(rng.standard_normal())
        fy = self._fix[1] + drift_px * float(rng.standard_normal())
        self._fix = (fx, fy)

        error_px = math.hypot(gx - fx, gy - fy)
        if self._saccade_due_s is None and error_px > 12.0 + 15.0 * lack:
            mean_s = 0.15 if error_px < 60.0 else 0.2 + 0.15 * lack
            self._saccade_due_s = t_s + self._reaction_s(mean_s)
        if self._saccade_due_s is not None and t_s >= self._saccade_due_s:
            self._saccade_due_s = None
            self._offset_until_s = -math.inf
            self._launch_saccade(t_s, self._last_pos, (gx, gy), fatigue, lack)
            return self._last_pos

        # Square-wave intrusions and glances elsewhere in the scene, then back to the fixation.
        if t_s >= self._offset_until_s:
            self._offset = (0.0, 0.0)
            if rng.random() < (0.3 + 1.2 * lack) * fatigue * dt_s:
                amp_px = abs(float(rng.standard_normal())) * (15.0 + 25.0 * lack) * fatigue
                angle = float(rng.uniform(0.0, 2.0 * math.pi))
                self._offset = (amp_px * math.cos(angle), amp_px * math.sin(angle))
                self._offset_until_s = t_s + float(rng.uniform(0.1, 0.6))
            elif rng.random() < (0.02 + 0.08 * lack) * dt_s:
                px = (float(rng.uniform(0, IMAGE_WIDTH_PX)), float(rng.uniform(0, IMAGE_HEIGHT_PX)))
                self._offset = (px[0] - fx, px[1] - fy)
                self._offset_until_s = t_s + float(rng.uniform(0.25, 0.7))
        self._last_pos = (fx + self._offset[0], fy + self._offset[1])
        return self._last_pos

    def _launch_saccade(self, t_s: float, start: tuple[float, float], goal: tuple[float, float],
                        fatigue: float, lack: float) -> None:
        rng = self._rng
        dx, dy = goal[0] - start[0], goal[1] - start[1]
        amp_px = math.hypot(dx, dy)
        # Large saccades undershoot by a few percent; a corrective saccade follows.
        gain = float(rng.normal(0.95, 0.03 + 0.05 * lack)) if amp_px > 40.0 else float(rng.normal(1.0, 0.05))
        land_px = (2.0 + 8.0 * lack) * fatigue
        end = (start[0] + gain * dx + land_px * float(rng.standard_normal()),
               start[1] + gain * dy + land_px * float(rng.standard_normal()))
        # Main sequence: about 21 ms + 2.2 ms per degree.
        dur_s = 0.021 + 0.0022 * math.hypot(end[0] - start[0], end[1] - start[1]) / SCENE_PX_PER_DEG
        self._saccade = (t_s, dur_s, start, end)
        self._last_pos = start
