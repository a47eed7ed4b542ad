"""Where a virtual subject looks to steer the hand onto a target: the closed loop of a simulated trial.

The subject sees the hand and the object through the scene camera (:class:`~wamctl.hmi.scene.SceneCamera`) and
knows the control it is using: looking away from the image centre moves the hand that way (command frame: image
right / image up), at a speed set by how far it looks (the profile's regions). :class:`ReachPolicy` is the
``target_px(t_s)`` callable of a :class:`~wamctl.backends.gaze.virtual.VirtualSubject`; the subject's eye then gets
there with its own reaction times, saccades, drift, intrusions, glances and blinks.

The policy, per gaze sample (all choices are ours; the thesis describes the task, not the subjects' strategy):

* **Start**: the subject looks at the image centre for a reaction time after the trial starts.
* **Perception**: the hand is seen with a bias drawn once per trial, ``N(0, sigma)`` along the line of sight
  (depth, misjudged most when looking from the side: ``sigma = 4 mm + 25 mm (1 - skill)``) and across it
  (``3 mm + 8 mm (1 - skill)``). The error *direction* is taken in the image (projected object minus projected
  hand); distances are judged in metres.
* **Glimpses**: to see where the hand and the object are, the subject glances at one of them (in the image) now
  and then (``0.2 + 0.6 (1 - skill)`` per second while reaching, half that while settling, 0.15-0.35 s each).
  With the gaze as the command, a glimpse is itself a command: the filters damp it, the hand may still drift.
* **Pauses**: less skilled subjects stop now and then to think (``0.3 (1 - skill)`` per second, 0.5-1.5 s times
  ``1 + (1 - skill)``, looking at the centre).
* **Four-directional control**: one axis at a time, the one with the larger image error; the subject keeps it until
  its error along that axis is within ``tol / sqrt(2)``, then turns to the other axis.
* **Vector control**: the direction of the image error.
* **Speed**: the fastest level whose speed ``v`` lets the hand stop in time: ``d - tol / 2 >= v * lead``, where
  ``d`` is the remaining distance (along the axis, or in total) and ``lead`` the subject's estimate of the delay
  from its decision to the hand stopping (saccade latency + filter lag + the ramp), misjudged per trial more
  for low skill. When even level 1 is too fast it looks at the centre (the stop region). The gaze point is the
  middle of that level's band along the axis (rectangles) or on the ray (circles), so small fixation errors
  keep the level.
* **Grasp**: within the tolerance ``tol = 8 mm + 20 mm (1 - skill)`` the subject looks at the centre, waits until
  the hand has been still for a dwell (``0.3 s + 0.5 s (1 - skill)``) and asks for a voluntary blink (the grasp).
  If the hand drifts out of the tolerance before the blink, it reaches again; if the hand has not closed 3 s
  after the blink (a blink the detector missed), it blinks again.
* **Nudges**: when the remaining distance is too short for even level 1 but beyond the tolerance, the subject
  looks at level 1 while the hand is still and back at the centre as soon as it moves.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable

import numpy as np

from wamctl.hmi.gaze import CENTER_X_PX, CENTER_Y_PX, image_point_px
from wamctl.hmi.scene import CommandMapping, SceneCamera
from wamctl.hmi.strategy import STOP_X_RATIO, STOP_Y_RATIO, VelocityProfile

logger = logging.getLogger(__name__)

#: Keep the gaze this far inside the image edges, px.
EDGE_MARGIN_PX = 12.0
#: Hand speed under which the subject sees it still, m/s.
STILL_M_S = 0.004
#: The subject blinks again when the hand has not closed this long after its grasp blink, s.
REPEAT_BLINK_S = 3.0


def band_middle_px(bounds_px: tuple[float, ...], level: int, inner_px: float, outer_px: float) -> float:
    """Middle of the region of ``level`` (1-based) along a half-axis or ray.

    Parameters
    ----------
    bounds_px : tuple of float
        Upper bounds of levels 0..n-1 (as :class:`~wamctl.hmi.strategy.VelocityProfile`).
    level : int
        1..n.
    inner_px : float
        Smallest distance that moves at all (the stop region's edge on this axis), px.
    outer_px : float
        Largest usable distance (the image edge minus a margin), px.
    """
    lo = max(bounds_px[level - 1], inner_px)
    hi = bounds_px[level] if level < len(bounds_px) else outer_px
    hi = min(hi, outer_px)
    return 0.5 * (lo + hi) if hi > lo else lo


class ReachPolicy:
    """``target_px(t_s)`` of a virtual subject steering the hand onto ``target_xy_m``.

    Parameters
    ----------
    hand_xy : callable
        ``hand_xy() -> (x_m, y_m)``: the true tool-point position on the table now.
    target_xy_m : (2,) sequence
        The object, m (frame 0).
    z_m : float
        Height of the tool point and of the grasped part of the object (for the projection), m.
    camera : SceneCamera
        The subject's scene camera.
    mapping : CommandMapping
        Command frame -> table plane (the subject knows it).
    strategy : {"four", "vector"}
        The control in use.
    profile : VelocityProfile
        Its speed regions.
    skill : float
        0 (naive) to 1 (expert).
    lag_s : float
        Nominal delay from a decision to the hand stopping (saccade latency, filter lag, ramp), s.
    rng : numpy.random.Generator
        For the per-trial perception bias and misjudgements.
    request_blink : callable or None
        Called once to ask the subject for the grasp blink (``VirtualSubject.request_voluntary_blink``); may be
        set after construction (attribute ``request_blink``).
    t0_s : float
        Start of the trial: the subject looks at the image centre until it has taken in the scene, a reaction
        time of ``0.5 s + 0.5 s (1 - skill)`` (times a per-trial log-normal factor) later.
    """

    def __init__(self, hand_xy: Callable[[], tuple[float, float]], target_xy_m, *, z_m: float, camera: SceneCamera,
                 mapping: CommandMapping, strategy: str, profile: VelocityProfile, skill: float, lag_s: float,
                 rng: np.random.Generator, request_blink: Callable[[], None] | None = None,
                 t0_s: float = 0.0) -> None:
        if strategy not in ("four", "vector"):
            raise ValueError(f"strategy must be 'four' or 'vector', got {strategy!r}")
        self.hand_xy = hand_xy
        self.target_xy_m = (float(target_xy_m[0]), float(target_xy_m[1]))
        self.z_m = float(z_m)
        self.camera = camera
        self.mapping = mapping
        self.strategy = strategy
        self.profile = profile
        self.skill = float(skill)
        self.request_blink = request_blink
        lack = 1.0 - self.skill
        self.rng = rng
        fwd, right = np.array(mapping.forward_xy), np.array(mapping.right_xy)
        self.bias_m = (rng.normal(0.0, 0.004 + 0.025 * lack) * fwd + rng.normal(0.0, 0.003 + 0.008 * lack) * right)
        self.tol_m = 0.008 + 0.020 * lack
        self.glimpse_rate_hz = 0.2 + 0.6 * lack
        self.pause_rate_hz = 0.3 * lack
        self._glimpse: tuple[float, float] | None = None
        self._glimpse_until_s = -math.inf
        self._pause_until_s = -math.inf
        self._last_call_s: float | None = None
        self.lead_s = lag_s * math.exp(0.35 * lack * float(rng.standard_normal()))
        self.dwell_s = 0.3 + 0.5 * lack
        self.go_s = t0_s + (0.5 + 0.5 * lack) * math.exp(0.25 * float(rng.standard_normal()))
        self.phase = "reach"
        self.axis: int | None = None
        self.level = 0
        self.grasp_requested_s: float | None = None
        self._prev: tuple[float, float, float] | None = None
        self._speed_m_s = 0.0
        self._still_since_s: float | None = None
        self._target_px = camera.project((*self.target_xy_m, self.z_m))

    # -- perception ---------------------------------------------------------------------------------

    def _perceive(self, t_s: float) -> tuple[np.ndarray, float]:
        x, y = self.hand_xy()
        if self._prev is not None and t_s > self._prev[0]:
            dt = t_s - self._prev[0]
            v = math.hypot(x - self._prev[1], y - self._prev[2]) / dt
            self._speed_m_s += 0.5 * (v - self._speed_m_s)
        self._prev = (t_s, x, y)
        seen = np.array([x, y]) + self.bias_m
        return seen, self._speed_m_s

    def _image_error(self, seen_xy: np.ndarray) -> tuple[float, float]:
        """Object minus hand in the image, command-frame orientation (x right, y up), px."""
        u, v = self.camera.project((seen_xy[0], seen_xy[1], self.z_m))
        return self._target_px[0] - u, -(self._target_px[1] - v)

    # -- decisions ----------------------------------------------------------------------------------

    def _level_for(self, d_m: float, tol_m: float) -> int:
        level = 0
        for k, v in enumerate(self.profile.speeds_m_s, start=1):
            if d_m - 0.5 * tol_m >= v * self.lead_s:
                level = k
        return level

    def _axis_point(self, axis: int, sign: float, level: int) -> tuple[float, float]:
        if axis == 0:
            r = band_middle_px(self.profile.x_bounds_px, level, STOP_X_RATIO * CENTER_X_PX,
                               CENTER_X_PX - EDGE_MARGIN_PX)
            return image_point_px(sign * r, 0.0)
        r = band_middle_px(self.profile.y_bounds_px, level, STOP_Y_RATIO * CENTER_Y_PX, CENTER_Y_PX - EDGE_MARGIN_PX)
        return image_point_px(0.0, sign * r)

    def _ray_point(self, ex_px: float, ey_px: float, level: int) -> tuple[float, float]:
        angle = math.atan2(ey_px, ex_px)
        c, s = math.cos(angle), math.sin(angle)
        outer = min(CENTER_X_PX / abs(c) if abs(c) > 1e-9 else math.inf,
                    CENTER_Y_PX / abs(s) if abs(s) > 1e-9 else math.inf) - EDGE_MARGIN_PX
        r = band_middle_px(self.profile.radii_px, level, self.profile.radii_px[0], outer)
        return image_point_px(r * c, r * s)

    def __call__(self, t_s: float) -> tuple[float, float]:
        seen, speed = self._perceive(t_s)
        e_m = np.array(self.target_xy_m) - seen
        dist_m = float(math.hypot(e_m[0], e_m[1]))
        centre = (CENTER_X_PX, CENTER_Y_PX)
        if t_s < self.go_s:
            return centre
        dt = 0.0 if self._last_call_s is None else max(t_s - self._last_call_s, 0.0)
        self._last_call_s = t_s
        if t_s < self._glimpse_until_s:
            return self._glimpse
        if self.phase in ("reach", "settle"):
            rate = self.glimpse_rate_hz * (1.0 if self.phase == "reach" else 0.5)
            if self.rng.random() < rate * dt:
                x, y = self.hand_xy() if self.rng.random() < 0.5 else self.target_xy_m
                self._glimpse = self.camera.project((x, y, self.z_m))
                self._glimpse_until_s = t_s + float(self.rng.uniform(0.15, 0.35))
                return self._glimpse
        if self.phase == "reach":
            if t_s < self._pause_until_s:
                return centre
            if self.rng.random() < self.pause_rate_hz * dt:
                self._pause_until_s = t_s + float(self.rng.uniform(0.5, 1.5)) * (2.0 - self.skill)
                return centre
        if self.phase == "grasp":
            if t_s - self.grasp_requested_s > REPEAT_BLINK_S and self.request_blink is not None:
                self.grasp_requested_s = t_s  # the hand did not close: blink again
                self.request_blink()
            return centre
        if self.phase == "settle":
            if dist_m > 1.2 * self.tol_m:
                self.phase, self.axis = "reach", None
            else:
                if speed < STILL_M_S:
                    if self._still_since_s is None:
                        self._still_since_s = t_s
                    if t_s - self._still_since_s >= self.dwell_s:
                        self.phase = "grasp"
                        self.grasp_requested_s = t_s
                        if self.request_blink is not None:
                            self.request_blink()
                else:
                    self._still_since_s = None
                return centre

        ex_px, ey_px = self._image_error(seen)
        if self.strategy == "vector":
            if dist_m <= self.tol_m:
                self._settle()
                return centre
            level = self._level_for(dist_m, self.tol_m)
            if level == 0 and speed < STILL_M_S:
                level = 1  # a nudge: look out briefly, back to the centre once the hand moves
            self.level = level
            return centre if level == 0 else self._ray_point(ex_px, ey_px, level)

        comp = self.mapping.to_command(float(e_m[0]), float(e_m[1]))  # metres along image right / up
        tol_axis = self.tol_m / math.sqrt(2.0)
        if self.axis is not None and abs(comp[self.axis]) < tol_axis:
            self.axis = None
        if self.axis is None:
            open_axes = [a for a in (0, 1) if abs(comp[a]) >= tol_axis]
            if not open_axes:
                self._settle()
                return centre
            img = (abs(ex_px), abs(ey_px))
            self.axis = max(open_axes, key=lambda a: img[a])
        d = abs(comp[self.axis])
        level = self._level_for(d, tol_axis)
        if level == 0 and speed < STILL_M_S:
            level = 1  # too close for even the slowest speed: a nudge, back to the centre once the hand moves
        self.level = level
        if level == 0:
            return centre
        return self._axis_point(self.axis, math.copysign(1.0, comp[self.axis]), level)

    def _settle(self) -> None:
        if self.phase != "settle":
            self.phase = "settle"
            self._still_since_s = None
            self.level = 0
