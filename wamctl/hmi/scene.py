"""Where the hand works and how the subject sees it: the table plane, the workspace box, the head-mounted scene
camera and the mapping of gaze commands onto the table.

Frames and conventions
----------------------
* Positions are in frame 0 of :mod:`wamctl.model.dynamics` (origin at the shoulder, z up, x forward, y to the
  arm's left) and refer to the tool point (:mod:`wamctl.hmi.kinematics`).
* **Table plane**: the horizontal plane ``z = table_z_m`` (frame 0). Positions on the table are frame-0
  ``(x_m, y_m)``; the hand moves at a constant height above it.
* **Command frame -> table plane**: a :class:`~wamctl.hmi.strategy.HandCommand` velocity is in the command frame
  of the scene image (+x image right, +y image up). The head-mounted scene camera (:class:`SceneCamera`) looks
  at the table from the subject's seat; image right is the camera's right vector projected on the table
  (``right_xy``), image up is its horizontal viewing direction (``forward_xy``: away from the subject, as a point
  further away on the table appears higher in the image). So ``v_table = vx * right_xy + vy * forward_xy``. With
  the default seat (the subject at the arm's left, +y side, looking along -y, thesis 6.5.1) image right is -x0
  (towards the arm's base) and image up is -y0.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from wamctl.hmi.gaze import CENTER_X_PX, CENTER_Y_PX, IMAGE_HEIGHT_PX, IMAGE_WIDTH_PX, SCENE_PX_PER_DEG

#: Table top in frame 0. The WAM stands on a pedestal beside the table with its shoulder 5 cm above the table top.
#: Why so high: with the 20 N m joint-2 torque limit of :mod:`wamctl.model.params`, a palm-down hand near the
#: table can be held only within about 0.5 m of the shoulder axis (gravity on joint 2: ~16 N m at 0.45 m with the
#: hand at shoulder height, ~19 N m at 0.45 m and 25 cm lower); with the arm bolted on the table (shoulder 0.346 m
#: above it) joint 2 saturates over most of the table and the arm sags. The BarrettHand's own 1.2 kg are not in
#: the model (add them as a plant payload and keep the spots closer).
TABLE_Z_M = -0.05
#: Height of the grasp centre above the table while reaching (a small object grasped about 5 cm up).
GRASP_HEIGHT_M = 0.05
#: Focal length of the scene camera in pixels, from gaze.SCENE_PX_PER_DEG (12 px/deg, ~64 deg over 768 px).
SCENE_FOCAL_PX = SCENE_PX_PER_DEG * 180.0 / math.pi


@dataclass(frozen=True)
class CommandMapping:
    """Command frame (+x image right, +y image up) to table-plane directions; unit vectors (2,) in frame 0.

    ``v_table = vx * right_xy + vy * forward_xy``.
    """

    right_xy: tuple[float, float]
    forward_xy: tuple[float, float]

    def to_table(self, vx: float, vy: float) -> tuple[float, float]:
        """Command-frame vector -> table-plane vector (same units)."""
        r, f = self.right_xy, self.forward_xy
        return vx * r[0] + vy * f[0], vx * r[1] + vy * f[1]

    def to_command(self, dx: float, dy: float) -> tuple[float, float]:
        """Table-plane vector -> command-frame components (along image right, along image up)."""
        r, f = self.right_xy, self.forward_xy
        return dx * r[0] + dy * r[1], dx * f[0] + dy * f[1]


@dataclass(frozen=True)
class SceneCamera:
    """Pinhole model of the head-mounted scene camera (thesis 6.1.2: 768 x 576 px).

    Parameters
    ----------
    position_m : (3,) sequence
        Camera (the subject's eyes) in frame 0, m.
    look_at_m : (3,) sequence
        Point in frame 0 at the image centre (the subject keeps the head still, looking at the workspace).
    focal_px : float
        Focal length in pixels (principal point at the image centre, square pixels, no distortion).

    Notes
    -----
    Image coordinates are those of the tracker: origin upper-left, u right, v down. The camera has no roll: its
    right vector is horizontal.
    """

    position_m: tuple[float, float, float]
    look_at_m: tuple[float, float, float]
    focal_px: float = SCENE_FOCAL_PX

    def __post_init__(self) -> None:
        d = np.asarray(self.look_at_m, float) - np.asarray(self.position_m, float)
        if np.hypot(d[0], d[1]) < 1e-6:
            raise ValueError("the scene camera must not look straight down (its image right would be undefined)")
        fwd = d / np.linalg.norm(d)
        right = np.cross(fwd, [0.0, 0.0, 1.0])
        right /= np.linalg.norm(right)
        down = np.cross(fwd, right)  # image v axis
        object.__setattr__(self, "_rdf", tuple(tuple(float(c) for c in v) for v in (right, down, fwd)))

    def _axes(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return tuple(np.array(v) for v in self._rdf)

    def project(self, p_m: Sequence[float]) -> tuple[float, float]:
        """Image pixels ``(u, v)`` of a point (3,) in frame 0 (NaN behind the camera)."""
        (r0, r1, r2), (d0, d1, d2), (f0, f1, f2) = self._rdf
        c = self.position_m
        x, y, z = float(p_m[0]) - c[0], float(p_m[1]) - c[1], float(p_m[2]) - c[2]
        depth = x * f0 + y * f1 + z * f2
        if depth <= 1e-6:
            return math.nan, math.nan
        return (CENTER_X_PX + self.focal_px * (x * r0 + y * r1 + z * r2) / depth,
                CENTER_Y_PX + self.focal_px * (x * d0 + y * d1 + z * d2) / depth)

    def in_image(self, p_m: Sequence[float], margin_px: float = 0.0) -> bool:
        """True when the point projects inside the image (with a margin)."""
        u, v = self.project(p_m)
        return margin_px <= u <= IMAGE_WIDTH_PX - margin_px and margin_px <= v <= IMAGE_HEIGHT_PX - margin_px

    def mapping(self) -> CommandMapping:
        """The command-frame mapping this camera implies (see the module docstring)."""
        right, _, fwd = self._axes()
        f = np.array([fwd[0], fwd[1]])
        f /= np.linalg.norm(f)
        return CommandMapping((float(right[0]), float(right[1])), (float(f[0]), float(f[1])))


@dataclass(frozen=True)
class Workspace:
    """Box of allowed tool-point positions on the table plane, m (frame 0)."""

    x_m: tuple[float, float]
    y_m: tuple[float, float]

    def __post_init__(self) -> None:
        if not (self.x_m[0] < self.x_m[1] and self.y_m[0] < self.y_m[1]):
            raise ValueError(f"workspace bounds must be increasing, got x {self.x_m}, y {self.y_m}")

    def contains(self, x_m: float, y_m: float, margin_m: float = 0.0) -> bool:
        return (self.x_m[0] + margin_m <= x_m <= self.x_m[1] - margin_m
                and self.y_m[0] + margin_m <= y_m <= self.y_m[1] - margin_m)

    def clamp(self, x_m: float, y_m: float) -> tuple[float, float, bool]:
        """``(x, y, clamped)``: the point moved into the box."""
        cx = min(max(x_m, self.x_m[0]), self.x_m[1])
        cy = min(max(y_m, self.y_m[0]), self.y_m[1])
        return cx, cy, (cx != x_m or cy != y_m)

