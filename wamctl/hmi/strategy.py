"""Gaze control strategies, velocity profiles, and the controller that turns gaze samples into hand commands.

Conventions
-----------
* Command frame: origin at the image centre, x right, y up, in pixels (:func:`wamctl.hmi.gaze.gaze_vector_px`);
  ``x_ratio, y_ratio`` of thesis 6.3 are the centred point over 384 px and 288 px.
* Output: a planar hand velocity ``(vx_m_s, vy_m_s)`` in that frame (+x = image right, +y = image up);
  turning it into a table-plane velocity (where the subject sits, how the scene camera sees the table) is
  the arm side's business. Zero velocity is either the user's *stop* (``Motion.STOP``) or a safety *hold*
  (``HandCommand.hold``: blink, no gaze, session ended).
* Speeds in m/s are parameters; the thesis gives the regions and the ratios between speeds, not the speeds.
* Angles in radians, [0, 2 pi), 0 = right, pi/2 = up.
* The controller is causal and driven by samples: :meth:`GazeController.update` per sample, and
  :meth:`GazeController.poll` when no sample came (stall watchdog). Times are the samples' ``t_s`` unless
  a clock value ``now_s`` is given; with the samples' clock, a serial stream and its replay give the same
  commands.
"""

from __future__ import annotations

import bisect
import enum
import logging
import math
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field, replace

from wamctl.hmi.gaze import NOMINAL_RATE_HZ, GazeSample, GazeSource, gaze_angle_rad, gaze_ratios, gaze_vector_px
from wamctl.hmi.signal import (
    KALMAN_Q,
    KALMAN_R,
    BlinkEvent,
    KalmanAngleFilter,
    MovingAverageFilter,
    VoluntaryBlinkDetector,
    WeightedMovingAverageFilter,
)

logger = logging.getLogger(__name__)

# Thesis 6.3, Table 6.1: the stop region of the four-directional control.
STOP_X_RATIO = 0.28
STOP_Y_RATIO = 0.26

# Thesis 6.3.2, Dual Velocity profile: along +x, stop 0-100 px, V1 100-200 px, V2 200-384 px; along +y,
# stop 0-75 px, V1 75-150 px, V2 150-288 px; V2 = 2.5 V1.
DUAL_X_BOUNDS_PX = (100.0, 200.0)
DUAL_Y_BOUNDS_PX = (75.0, 150.0)
DUAL_SPEED_RATIO = 2.5
# Thesis 6.3.2, Cubic Velocity profile: along +x, stop 0-100, V1 101-161, V2 162-215, V3 216-269,
# V4 270-323, V5 324-384 px; along +y, stop 0-75, V1 76-125, V2 126-161, V3 162-197, V4 198-233,
# V5 234-288 px. Upper bounds of stop, V1..V4:
CUBIC_X_BOUNDS_PX = (100.0, 161.0, 215.0, 269.0, 323.0)
CUBIC_Y_BOUNDS_PX = (75.0, 125.0, 161.0, 197.0, 233.0)
# Upper ends of V1..V5 along +x, where the cubic of 6.3.2 is sampled to quantise the speeds.
CUBIC_X_UPPER_PX = (161.0, 215.0, 269.0, 323.0, 384.0)
# Thesis 6.4.2 (Figures 6.24-6.26): the vector control uses concentric circles; the text gives no radii.
# We reuse the vertical-axis bounds of 6.3.2 so every circle fits in the 576 px high image.
SINGLE_RADII_PX = (75.0,)
DUAL_RADII_PX = DUAL_Y_BOUNDS_PX
CUBIC_RADII_PX = CUBIC_Y_BOUNDS_PX

# Our defaults (the thesis gives none): slow enough for small corrections when grasping.
DEFAULT_SINGLE_SPEED_M_S = 0.03
DEFAULT_DUAL_V1_M_S = 0.03
DEFAULT_CUBIC_VMAX_M_S = 0.075

#: Stall watchdog: hold still after this long without a usable sample (issue 7).
STALL_TIMEOUT_S = 0.2


def cubic_speed_curve(x_px: float) -> float:
    """The cubic of thesis 6.3.2 quantised into the Cubic Velocity profile (x in px along +x).

    ``y = -1.7e-7 x^3 + 9.7e-5 x^2 + 7.8e-3 x - 0.011``, printed as a second "Eq. (6.2)" and cited in the
    text as "Equation (6.3.2)"; its unit is not given (7.66 at x = 384 px), only its shape is used.
    """
    return -1.7e-7 * x_px**3 + 9.7e-5 * x_px**2 + 7.8e-3 * x_px - 0.011


def cubic_speeds_m_s(v_max_m_s: float) -> tuple[float, ...]:
    """Speeds V1..V5 of the Cubic profile: the 6.3.2 cubic at the upper end of each region, V5 = ``v_max_m_s``.

    About 0.40, 0.58, 0.76, 0.90 and 1.00 of ``v_max_m_s``.
    """
    top = cubic_speed_curve(CUBIC_X_UPPER_PX[-1])
    return tuple(v_max_m_s * cubic_speed_curve(x) / top for x in CUBIC_X_UPPER_PX)


@dataclass(frozen=True)
class VelocityProfile:
    """Speed as a function of where the gaze falls (thesis 6.3.2 rectangles, 6.4.2 circles).

    Level 0 is the profile's stop region, level k >= 1 runs at ``speeds_m_s[k - 1]``.

    Attributes
    ----------
    name : str
        "single", "dual" or "cubic".
    speeds_m_s : tuple of float
        Speeds of levels 1..n, m/s.
    x_bounds_px, y_bounds_px : tuple of float
        Upper bounds (inclusive) of levels 0..n-1 along the half-axes; the level of a point is the
        larger of its two axis levels (nested rectangles).
    radii_px : tuple of float
        Upper bounds (inclusive) of levels 0..n-1 of the gaze-vector magnitude (concentric circles).
    """

    name: str
    speeds_m_s: tuple[float, ...]
    x_bounds_px: tuple[float, ...]
    y_bounds_px: tuple[float, ...]
    radii_px: tuple[float, ...]

    def __post_init__(self) -> None:
        n = len(self.speeds_m_s)
        for label, bounds in (("x_bounds_px", self.x_bounds_px), ("y_bounds_px", self.y_bounds_px),
                              ("radii_px", self.radii_px)):
            if len(bounds) != n or any(b <= a for a, b in zip(bounds, bounds[1:])):
                raise ValueError(f"{label} must hold {n} increasing bounds, got {bounds}")
        if n == 0 or any(not (v > 0 and math.isfinite(v)) for v in self.speeds_m_s):
            raise ValueError(f"speeds_m_s must be positive, got {self.speeds_m_s}")

    @property
    def n_levels(self) -> int:
        """Number of moving levels."""
        return len(self.speeds_m_s)

    def rect_level(self, x_px: float, y_px: float) -> int:
        """Level of a centred point for the four-directional control (nested rectangles)."""
        return max(bisect.bisect_left(self.x_bounds_px, abs(x_px)), bisect.bisect_left(self.y_bounds_px, abs(y_px)))

    def circle_level(self, r_px: float) -> int:
        """Level of a gaze-vector magnitude for the vector control (concentric circles)."""
        return bisect.bisect_left(self.radii_px, r_px)

    def speed_m_s(self, level: int) -> float:
        """Speed of a level, m/s (0 for level 0)."""
        return 0.0 if level <= 0 else self.speeds_m_s[min(level, self.n_levels) - 1]


def single_profile(speed_m_s: float = DEFAULT_SINGLE_SPEED_M_S) -> VelocityProfile:
    """Single Velocity profile (thesis 6.3.2, Figure 6.14): stop, or one constant speed."""
    return VelocityProfile("single", (speed_m_s,), DUAL_X_BOUNDS_PX[:1], DUAL_Y_BOUNDS_PX[:1], SINGLE_RADII_PX)


def dual_profile(v1_m_s: float = DEFAULT_DUAL_V1_M_S) -> VelocityProfile:
    """Dual Velocity profile (thesis 6.3.2, Figure 6.15): stop, V1, and V2 = 2.5 V1 far from the centre."""
    return VelocityProfile("dual", (v1_m_s, DUAL_SPEED_RATIO * v1_m_s), DUAL_X_BOUNDS_PX, DUAL_Y_BOUNDS_PX,
                           DUAL_RADII_PX)


def cubic_profile(v_max_m_s: float = DEFAULT_CUBIC_VMAX_M_S) -> VelocityProfile:
    """Cubic Velocity profile (thesis 6.3.2, Figures 6.16-6.17): five speeds quantised from its cubic."""
    return VelocityProfile("cubic", cubic_speeds_m_s(v_max_m_s), CUBIC_X_BOUNDS_PX, CUBIC_Y_BOUNDS_PX,
                           CUBIC_RADII_PX)


PROFILES: dict[str, Callable[[float], VelocityProfile]] = {
    "single": single_profile,
    "dual": dual_profile,
    "cubic": cubic_profile,
}


# --------------------------------------------------------------------------------------------------
# Commands and events


class Motion(str, enum.Enum):
    """Instruction of the strategy (Figure 6.8 and 6.9)."""

    STOP = "stop"
    RIGHT = "right"
    LEFT = "left"
    UP = "up"
    DOWN = "down"
    VECTOR = "vector"


class Hold(str, enum.Enum):
    """Why the hand is held still regardless of the gaze."""

    NONE = "none"
    NO_GAZE = "no_gaze"  # stall watchdog: no usable sample within the timeout (or none yet)
    BLINK = "blink"  # the eyes are closed
    SESSION_ENDED = "session_ended"  # after the go-home blink sequence


class EventKind(str, enum.Enum):
    """Kinds of :class:`GazeEvent`."""

    BLINK = "blink"  # involuntary (too short, or too long to be a command)
    VOLUNTARY_BLINK = "voluntary_blink"
    GRIPPER_CLOSE = "gripper_close"
    GRIPPER_OPEN = "gripper_open"
    GO_HOME = "go_home"
    STALL = "stall"


@dataclass(frozen=True, slots=True)
class GazeEvent:
    """Something that happened in the gaze stream (for the events table and for the arm side)."""

    t_s: float
    kind: EventKind
    duration_s: float | None = None


@dataclass(frozen=True, slots=True)
class HandCommand:
    """Planar hand velocity command.

    Attributes
    ----------
    t_s : float
        Time of the sample it answers (or the clock value given to :meth:`GazeController.poll`).
    motion : Motion
        The instruction.
    level : int
        Velocity level of the profile (0 = stopped).
    vx_m_s, vy_m_s : float
        Hand velocity in the command frame, m/s.
    angle_rad : float or None
        Direction used by the vector control (filtered), None for the four-directional control.
    hold : Hold
        Safety hold overriding the gaze (velocity is then zero).
    events : tuple of GazeEvent
        Events raised by this sample (gripper toggles, go home, blinks, stall).
    """

    t_s: float
    motion: Motion
    level: int = 0
    vx_m_s: float = 0.0
    vy_m_s: float = 0.0
    angle_rad: float | None = None
    hold: Hold = Hold.NONE
    events: tuple[GazeEvent, ...] = field(default=())

    @property
    def is_moving(self) -> bool:
        return self.vx_m_s != 0.0 or self.vy_m_s != 0.0


def _held(t_s: float, hold: Hold, events: tuple[GazeEvent, ...] = ()) -> HandCommand:
    return HandCommand(t_s, Motion.STOP, hold=hold, events=events)


# --------------------------------------------------------------------------------------------------
# Strategies


def four_direction(x_ratio: float, y_ratio: float, *, stop_x_ratio: float = STOP_X_RATIO,
                   stop_y_ratio: float = STOP_Y_RATIO) -> Motion:
    """Instruction of the four-directional control, thesis Table 6.1.

    Stop when ``|x_ratio| < 0.28`` and ``|y_ratio| < 0.26``; otherwise the dominant ratio decides: right or
    left when ``|x_ratio| >= |y_ratio|``, up or down otherwise. Table 6.1 prints the comparisons without
    absolute values, which taken literally would send a point at (-0.1, -0.9) "left"; Figure 6.11's five
    zones need the magnitudes. Ties go to the horizontal.
    """
    if abs(x_ratio) < stop_x_ratio and abs(y_ratio) < stop_y_ratio:
        return Motion.STOP
    if abs(x_ratio) >= abs(y_ratio):
        return Motion.RIGHT if x_ratio > 0 else Motion.LEFT
    return Motion.UP if y_ratio > 0 else Motion.DOWN


_UNIT = {Motion.RIGHT: (1.0, 0.0), Motion.LEFT: (-1.0, 0.0), Motion.UP: (0.0, 1.0), Motion.DOWN: (0.0, -1.0)}


class FourDirectionalStrategy:
    """Four-directional control (thesis 6.3): stop, right, left, up, down at the profile's speed.

    Parameters
    ----------
    profile : VelocityProfile
        Speeds; its rectangles give the level, the stop region is Table 6.1's.
    stop_x_ratio, stop_y_ratio : float
        Half-sizes of the stop region in ratios (Table 6.1: 0.28, 0.26).
    """

    def __init__(self, *, profile: VelocityProfile, stop_x_ratio: float = STOP_X_RATIO,
                 stop_y_ratio: float = STOP_Y_RATIO) -> None:
        self.profile = profile
        self.stop_x_ratio = stop_x_ratio
        self.stop_y_ratio = stop_y_ratio

    def reset(self) -> None:
        pass

    def command(self, t_s: float, x_px: float, y_px: float) -> HandCommand:
        """Command for a (filtered) gaze point in image pixels."""
        x_ratio, y_ratio = gaze_ratios(x_px, y_px)
        motion = four_direction(x_ratio, y_ratio, stop_x_ratio=self.stop_x_ratio, stop_y_ratio=self.stop_y_ratio)
        if motion is Motion.STOP:
            return HandCommand(t_s, Motion.STOP)
        x_c, y_c = gaze_vector_px(x_px, y_px)
        # Outside Table 6.1's stop region the hand moves, at least at V1, even where the profile's
        # own stop rectangle (100 x 75 px) reaches a little further than 0.28 x 384 = 107.5 px.
        level = max(1, self.profile.rect_level(x_c, y_c))
        speed = self.profile.speed_m_s(level)
        ux, uy = _UNIT[motion]
        return HandCommand(t_s, motion, level, ux * speed, uy * speed)


class VectorStrategy:
    """Vector-directional control (thesis 6.4): direction of the gaze vector, speed from its magnitude.

    The angle goes through a Kalman filter (6.4.1; the thesis found the unfiltered angle unusable), updated
    at every valid sample, also inside the stop circle, so it is settled when the gaze leaves it.

    Parameters
    ----------
    profile : VelocityProfile
        Speeds; its concentric circles give the level (level 0 = stop).
    kalman_q : float or None
        Process-noise covariance of the angle filter (thesis: 0.001 or 0.0001); None: raw angle.
    kalman_r : float
        Measurement-noise covariance of the angle filter.
    """

    def __init__(self, *, profile: VelocityProfile, kalman_q: float | None = KALMAN_Q[0],
                 kalman_r: float = KALMAN_R) -> None:
        self.profile = profile
        self.angle_filter = None if kalman_q is None else KalmanAngleFilter(q=kalman_q, r=kalman_r)

    def reset(self) -> None:
        if self.angle_filter is not None:
            self.angle_filter.reset()

    def command(self, t_s: float, x_px: float, y_px: float) -> HandCommand:
        """Command for a (filtered) gaze point in image pixels."""
        x_c, y_c = gaze_vector_px(x_px, y_px)
        angle_rad = gaze_angle_rad(x_px, y_px)
        if self.angle_filter is not None:
            angle_rad = self.angle_filter.update_angle(angle_rad)
        level = self.profile.circle_level(math.hypot(x_c, y_c))
        if level == 0:
            return HandCommand(t_s, Motion.STOP, angle_rad=angle_rad)
        speed = self.profile.speed_m_s(level)
        return HandCommand(t_s, Motion.VECTOR, level, speed * math.cos(angle_rad), speed * math.sin(angle_rad),
                           angle_rad)


# --------------------------------------------------------------------------------------------------
# Blink sequences and the watchdog


class BlinkSequenceDetector:
    """Detects ``count`` voluntary blinks in a row (the go-home sequence of issue 7).

    In a row: each starts at most ``max_gap_s`` after the previous voluntary blink ended; involuntary
    blinks in between are ignored.
    """

    def __init__(self, *, count: int = 3, max_gap_s: float = 1.5) -> None:
        if count < 2:
            raise ValueError("count must be >= 2")
        self.count = count
        self.max_gap_s = max_gap_s
        self.reset()

    def reset(self) -> None:
        self._n = 0
        self._last_end_s: float | None = None

    def update(self, event: BlinkEvent) -> bool:
        """Take one blink; True when it completes the sequence (which then starts over)."""
        if not event.voluntary:
            return False
        in_row = self._last_end_s is not None and event.t_start_s - self._last_end_s <= self.max_gap_s
        self._n = self._n + 1 if in_row else 1
        self._last_end_s = event.t_end_s
        if self._n >= self.count:
            self.reset()
            return True
        return False


class StallWatchdog:
    """Expires when nothing was fed for more than ``timeout_s`` (or nothing ever was)."""

    def __init__(self, *, timeout_s: float = STALL_TIMEOUT_S) -> None:
        if timeout_s <= 0:
            raise ValueError("timeout_s must be > 0")
        self.timeout_s = timeout_s
        self.reset()

    def reset(self) -> None:
        self._last_s: float | None = None

    def feed(self, now_s: float) -> None:
        self._last_s = now_s

    def expired(self, now_s: float) -> bool:
        return self._last_s is None or now_s - self._last_s > self.timeout_s


# --------------------------------------------------------------------------------------------------
# The controller


PointFilter = MovingAverageFilter | WeightedMovingAverageFilter
Strategy = FourDirectionalStrategy | VectorStrategy


class GazeController:
    """Gaze samples in, hand commands out: the whole causal chain of thesis Figure 6.5.

    Per sample: corrupt and out-of-image samples are dropped (the previous command stands until the stall
    watchdog fires); eye-closed samples hold the hand still and feed the blink detector; when the eye
    opens, a voluntary blink toggles the gripper (``GRIPPER_CLOSE`` / ``GRIPPER_OPEN``, the hand starts
    open), unless it completes the go-home sequence (``GO_HOME``, then every command holds with
    ``SESSION_ENDED`` until :meth:`reset`; the first blinks of that sequence toggled the gripper, so with
    three it ends as it was). Valid points go through the point filter, then the strategy. After a gap
    in the samples longer than ``stall_timeout_s`` the filters restart, so stale points do not steer.

    Parameters
    ----------
    strategy : FourDirectionalStrategy or VectorStrategy
        Maps a gaze point to a command.
    point_filter : MovingAverageFilter, WeightedMovingAverageFilter or None
        Smoothing of the gaze point (thesis 6.3.1; the four-directional control retained MA 300 ms).
    blink_detector : VoluntaryBlinkDetector or None
        Defaults to a 0.7 s threshold on the measured rate.
    stall_timeout_s : float
        Hold still after this long without a usable (valid or eye-closed) sample.
    home_blinks, home_max_gap_s : int, float
        The go-home sequence (:class:`BlinkSequenceDetector`).
    """

    def __init__(self, strategy: Strategy, *, point_filter: PointFilter | None = None,
                 blink_detector: VoluntaryBlinkDetector | None = None, stall_timeout_s: float = STALL_TIMEOUT_S,
                 home_blinks: int = 3, home_max_gap_s: float = 1.5) -> None:
        self.strategy = strategy
        self.point_filter = point_filter
        self.blink_detector = blink_detector if blink_detector is not None else VoluntaryBlinkDetector()
        self.stall_timeout_s = stall_timeout_s
        self.sequence = BlinkSequenceDetector(count=home_blinks, max_gap_s=home_max_gap_s)
        self.watchdog = StallWatchdog(timeout_s=stall_timeout_s)
        self.reset()

    def reset(self) -> None:
        """Back to the start of a session: hand open, no gaze yet, nothing filtered."""
        self.blink_detector.reset()
        self.sequence.reset()
        self.watchdog.reset()
        self._reset_filters()
        self.gripper_closed = False
        self.session_ended = False
        self.n_dropped = 0
        self._stalled = False
        self._last_t_s: float | None = None
        self._last_now_s: float | None = None
        self._last: HandCommand | None = None

    def _reset_filters(self) -> None:
        if self.point_filter is not None:
            self.point_filter.reset()
        self.strategy.reset()

    @property
    def last_command(self) -> HandCommand | None:
        return self._last

    def update(self, sample: GazeSample, now_s: float | None = None) -> HandCommand:
        """Process one sample.

        Parameters
        ----------
        sample : GazeSample
            Next sample of the stream.
        now_s : float or None
            Clock for the stall watchdog (e.g. ``time.monotonic()`` in a live session); the sample's own
            time if None.
        """
        if sample.has_time:
            blink_event = self.blink_detector.update(sample)
            now_s = sample.t_s if now_s is None else now_s
        else:
            blink_event = None
            now_s = self._last_now_s if now_s is None else now_s
        if not (sample.is_valid or sample.is_blink):
            self.n_dropped += 1
            return _held(math.nan, Hold.NO_GAZE) if now_s is None else self.poll(now_s)

        self._last_now_s = now_s
        if self._last_t_s is not None and sample.t_s - self._last_t_s > self.stall_timeout_s:
            logger.info("gaze resumed after %.3f s without samples; filters restart", sample.t_s - self._last_t_s)
            self._reset_filters()
        self._last_t_s = sample.t_s
        self.watchdog.feed(now_s)
        self._stalled = False

        events = self._on_blink(blink_event) if blink_event is not None else ()
        if self.session_ended:
            command = _held(sample.t_s, Hold.SESSION_ENDED, events)
        elif sample.is_blink:
            command = _held(sample.t_s, Hold.BLINK, events)
        else:
            point = sample if self.point_filter is None else self.point_filter.update(sample)
            command = self.strategy.command(sample.t_s, point.x_px, point.y_px)
            if events:
                command = replace(command, events=events)
        self._last = command
        return command

    def poll(self, now_s: float) -> HandCommand:
        """Command when no sample came: the last one, or a hold once the watchdog has expired."""
        if self.session_ended:
            return _held(now_s, Hold.SESSION_ENDED)
        if self.watchdog.expired(now_s):
            events: tuple[GazeEvent, ...] = ()
            if not self._stalled:
                self._stalled = True
                events = (GazeEvent(now_s, EventKind.STALL),)
                logger.warning("no usable gaze sample for more than %.3f s: holding still", self.stall_timeout_s)
            self._last = _held(now_s, Hold.NO_GAZE)
            return _held(now_s, Hold.NO_GAZE, events)
        return replace(self._last, t_s=now_s, events=())

    def _on_blink(self, event: BlinkEvent) -> tuple[GazeEvent, ...]:
        kind = EventKind.VOLUNTARY_BLINK if event.voluntary else EventKind.BLINK
        out = [GazeEvent(event.t_end_s, kind, event.duration_s)]
        if event.voluntary and not self.session_ended:
            if self.sequence.update(event):
                self.session_ended = True
                out.append(GazeEvent(event.t_end_s, EventKind.GO_HOME))
                logger.info("%d voluntary blinks in a row at %.3f s: session ends, arm goes home",
                            self.sequence.count, event.t_end_s)
            else:
                self.gripper_closed = not self.gripper_closed
                kind = EventKind.GRIPPER_CLOSE if self.gripper_closed else EventKind.GRIPPER_OPEN
                out.append(GazeEvent(event.t_end_s, kind))
        return tuple(out)


def make_gaze_controller(*, strategy: str = "four", profile: str = "single", speed_m_s: float | None = None,
                    point_filter: str | None = None, window_s: float = 0.3, kalman_q: float | None = KALMAN_Q[0],
                    rate_hz: float = NOMINAL_RATE_HZ, stall_timeout_s: float = STALL_TIMEOUT_S) -> GazeController:
    """A controller from names, as a trial block would configure it.

    Parameters
    ----------
    strategy : {"four", "vector"}
        Four-directional (6.3) or vector-directional (6.4) control.
    profile : {"single", "dual", "cubic"}
        Velocity profile; ``speed_m_s`` is its single speed, V1, or top speed V5 (profile default if None).
    point_filter : {None, "ma", "wma"}
        Smoothing of the gaze point over ``window_s`` at ``rate_hz``.
    kalman_q : float or None
        Angle filter of the vector control.
    """
    if profile not in PROFILES:
        raise ValueError(f"profile must be one of {sorted(PROFILES)}, got {profile!r}")
    prof = PROFILES[profile]() if speed_m_s is None else PROFILES[profile](speed_m_s)
    if strategy == "four":
        strat: Strategy = FourDirectionalStrategy(profile=prof)
    elif strategy == "vector":
        strat = VectorStrategy(profile=prof, kalman_q=kalman_q)
    else:
        raise ValueError(f"strategy must be 'four' or 'vector', got {strategy!r}")
    filters = {None: None, "ma": MovingAverageFilter, "wma": WeightedMovingAverageFilter}
    if point_filter not in filters:
        raise ValueError(f"point_filter must be None, 'ma' or 'wma', got {point_filter!r}")
    pf = None if point_filter is None else filters[point_filter](window_s=window_s, rate_hz=rate_hz)
    return GazeController(strat, point_filter=pf, stall_timeout_s=stall_timeout_s)


def drive(source: GazeSource, controller: GazeController, *, clock: Callable[[], float] | None = None,
          read_timeout_s: float = 0.05) -> Iterator[tuple[GazeSample | None, HandCommand]]:
    """Run a controller on a source until it is exhausted, yielding ``(sample, command)``.

    With ``clock`` (e.g. ``time.monotonic``) the watchdog runs on it and a read that times out yields
    ``(None, controller.poll(clock()))``; without, everything runs on the samples' time and timeouts are
    skipped, so a stream and its replay give the same commands.
    """
    while True:
        sample = source.read(read_timeout_s)
        if sample is not None:
            yield sample, controller.update(sample, None if clock is None else clock())
        elif source.exhausted:
            return
        elif clock is not None:
            yield None, controller.poll(clock())

