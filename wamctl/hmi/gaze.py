"""Gaze samples, their classification and the image geometry of the gaze HMI; what a gaze source offers.

Conventions
-----------
* Pixels of the ASL Mobile Eye scene image, 768 x 576, origin at the upper-left corner, x to the right,
  y downward (thesis section 6.1.2 and 6.3). Names carry ``_px``.
* Times in seconds on the tracker's clock (``t_s``). The tracker streams at about 30 Hz (thesis 6.1.2).
* An eye closed (pupil or corneal reflections lost) is the pair (-2000, -2000) (thesis 6.1.2 and 6.2.1).
* Every sample is classified, never rejected with an exception: ``GazeSample.flags`` is empty for a
  valid gaze point, ``BLINK`` for (-2000, -2000), ``OUT_OF_RANGE`` for a parsed point outside the image,
  ``CORRUPT`` for anything that cannot be trusted at all (t_s, x_px, y_px are then NaN).
* The *command frame* used by the strategies (:mod:`wamctl.hmi.strategy`) has its origin at the image
  centre (384, 288) px, x to the right and y **up**; see :func:`gaze_vector_px`.

Sources
-------
Every source follows :class:`GazeSource`: ``read(timeout_s) -> GazeSample | None`` (``None`` when nothing
arrived in time, or when the source is ``exhausted``), iteration (blocking, until exhausted), context
manager, ``close()`` safe to call twice. The sources themselves are devices and live in
:mod:`wamctl.backends.gaze` (serial tracker and its line format, replay of recorded files, virtual subject).
"""

from __future__ import annotations

import enum
import math
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

# Thesis 6.1.2: scene image of the Mobile Eye, 768 x 576 px, streamed at 30 Hz; (-2000, -2000) = eye closed.
IMAGE_WIDTH_PX = 768
IMAGE_HEIGHT_PX = 576
NOMINAL_RATE_HZ = 30.0
BLINK_SENTINEL_PX = -2000.0
# Thesis 6.3, Figure 6.10: the control space is centred on (384, 288) px.
CENTER_X_PX = IMAGE_WIDTH_PX / 2
CENTER_Y_PX = IMAGE_HEIGHT_PX / 2
#: Scene-camera resolution assumed for saccade durations and the scene camera's focal length (not from the
#: thesis: ~64 deg over 768 px).
SCENE_PX_PER_DEG = 12.0

_TWO_PI = 2.0 * math.pi


class GazeFlag(enum.IntFlag):
    """Classification of a gaze sample; no flag set means a valid gaze point."""

    BLINK = 1
    """(-2000, -2000): the eye is closed or the tracker lost the pupil."""
    OUT_OF_RANGE = 2
    """Parsed, but outside the 768 x 576 image (thesis 6.1.2: corrupted data)."""
    CORRUPT = 4
    """Unparseable, non-finite, or a time that does not increase."""


VALID = GazeFlag(0)


@dataclass(frozen=True, slots=True)
class GazeSample:
    """One gaze sample.

    Attributes
    ----------
    t_s : float
        Tracker time, s (NaN for a corrupt line).
    x_px, y_px : float
        Gaze point in scene-image pixels, origin upper-left, y downward (NaN for a corrupt line).
    flags : GazeFlag
        Empty for a valid point; see :class:`GazeFlag`.
    """

    t_s: float
    x_px: float
    y_px: float
    flags: GazeFlag = VALID

    @property
    def is_valid(self) -> bool:
        """True for a gaze point inside the image."""
        return not self.flags

    @property
    def is_blink(self) -> bool:
        """True for an eye-closed sample."""
        return bool(self.flags & GazeFlag.BLINK)

    @property
    def has_time(self) -> bool:
        """True when ``t_s`` can be trusted (every flag but ``CORRUPT``)."""
        return not self.flags & GazeFlag.CORRUPT


#: The sample of a line or frame that cannot be trusted at all.
CORRUPT_SAMPLE = GazeSample(math.nan, math.nan, math.nan, GazeFlag.CORRUPT)


# --------------------------------------------------------------------------------------------------
# Geometry of the image (thesis 6.3, Figure 6.10)


def classify(x_px: float, y_px: float) -> GazeFlag:
    """Classify a gaze point: blink sentinel, inside the image, outside it, or not finite."""
    if x_px == BLINK_SENTINEL_PX and y_px == BLINK_SENTINEL_PX:
        return GazeFlag.BLINK
    if not (math.isfinite(x_px) and math.isfinite(y_px)):
        return GazeFlag.CORRUPT
    if 0.0 <= x_px <= IMAGE_WIDTH_PX and 0.0 <= y_px <= IMAGE_HEIGHT_PX:
        return VALID
    return GazeFlag.OUT_OF_RANGE


def gaze_vector_px(x_px: float, y_px: float) -> tuple[float, float]:
    """Gaze point in the command frame: origin at the image centre, x right, y up, px.

    The thesis (6.3, Figure 6.10) prints ``y = y_gt - 288`` with the image origin at the upper-left
    corner; with image rows growing downward that would put "Up" (``y_ratio > 0``, Table 6.1) in the lower
    half of the image. We take the Cartesian reading of Figure 6.10 (y up), so looking at the upper part
    of the image commands "Up".
    """
    return x_px - CENTER_X_PX, CENTER_Y_PX - y_px


def image_point_px(x_px: float, y_px: float) -> tuple[float, float]:
    """Inverse of :func:`gaze_vector_px`: a point of the command frame (x right, y up) in image pixels."""
    return CENTER_X_PX + x_px, CENTER_Y_PX - y_px


def gaze_ratios(x_px: float, y_px: float) -> tuple[float, float]:
    """``(x_ratio, y_ratio)`` of thesis 6.3: the centred point over the half-width 384 and half-height 288."""
    x, y = gaze_vector_px(x_px, y_px)
    return x / CENTER_X_PX, y / CENTER_Y_PX


def gaze_angle_rad(x_px: float, y_px: float) -> float:
    """Direction of the gaze vector in the command frame, rad in [0, 2 pi), 0 = right, pi/2 = up."""
    x, y = gaze_vector_px(x_px, y_px)
    return math.atan2(y, x) % _TWO_PI


# --------------------------------------------------------------------------------------------------
# What a source offers


@runtime_checkable
class GazeSource(Protocol):
    """What every gaze source offers."""

    @property
    def exhausted(self) -> bool:
        """True once the source will never produce another sample."""

    def read(self, timeout_s: float | None = None) -> GazeSample | None:
        """Next sample, or ``None`` if none came within ``timeout_s`` or the source is exhausted."""

    def close(self) -> None:
        """Release the source; safe to call twice."""

    def __iter__(self) -> Iterator[GazeSample]: ...

    def __enter__(self) -> GazeSource: ...

    def __exit__(self, *exc_info: object) -> None: ...
