"""The WAM as four capsules, and its distances to itself, a table plane and a workspace box.

Capsules (segments with a radius) along the arm's DH geometry (:mod:`wamctl.model.params`), in the DH frames
:meth:`wamctl.model.dynamics.WamDynamics.joint_frames` gives:

* ``shoulder`` (links 1-2): a sphere at the shoulder (frame 0's origin), or, with a table, the column from the
  shoulder down to the table (the base stands on it). Fixed.
* ``upper arm`` (link 3): frame 2's origin to the elbow on joint 3's axis (``d3`` = 0.55 m along z2).
* ``forearm`` (link 4): frame 4's origin to the wrist centre (``d5`` = 0.30 m along z4).
* ``wrist and hand`` (links 5-7 and a tool): the wrist centre to the flange (``d7`` = 0.0609 m along z7) and on
  by the tool's length along z7.

Adjacent capsules (shoulder-upper arm, upper arm-forearm, forearm-wrist) touch at their joints by construction
and are excepted; the pairs checked are shoulder-forearm, shoulder-wrist and upper arm-wrist. The radii
(:data:`RADIUS_M`) are the largest that keep the arm's rest pose (``HOME_Q_RAD``: elbow folded at 3.13 rad, the
forearm against the upper arm, the two axes 2 x 0.045 m apart) clear of itself: upper arm + wrist 0.085 m <
0.09 m. They are a model of the arm's outline, not its housing; a spec can set others.

Between two samples ``dt`` apart, no point of the arm moves more than ``dt x sum_j |qd_j| x lever_j`` (lever_j:
the farthest a capsule point can be from joint j's axis, from the DH lengths, the tool and the radius), so a
distance sampled every ``dt`` is never more than that bound above the smallest distance between the samples
(twice it for a pair of links: both move). :func:`motion_bound_m` gives it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from wamctl.model import params as P
from wamctl.model.robots import WAM4

CAPSULES = ("shoulder", "upper arm", "forearm", "wrist and hand")
LINKS = {"shoulder": "links 1-2 (shoulder)", "upper arm": "link 3 (upper arm)", "forearm": "link 4 (forearm)",
         "wrist and hand": "links 5-7 (wrist and hand)"}
RADIUS_M = {"shoulder": 0.10, "upper arm": 0.045, "forearm": 0.045, "wrist and hand": 0.04}
SELF_PAIRS = (("shoulder", "forearm"), ("shoulder", "wrist and hand"), ("upper arm", "wrist and hand"))
MOVING = ("upper arm", "forearm", "wrist and hand")
# the wam4 (no wrist): three capsules, the forearm from frame 4's origin to the tool plate (``flange_d_m`` along
# z4) and on by the tool; the one pair not adjacent is shoulder-forearm
PAIRS = {"wam7": SELF_PAIRS, "wam4": (("shoulder", "forearm"),)}
MOVING_OF = {"wam7": MOVING, "wam4": ("upper arm", "forearm")}


@dataclass
class ArmGeometry:
    """The capsules' radii (m), the tool's length along z7 beyond the flange (m) and, when the arm stands on a
    table, the table's height in frame 0 (the shoulder column reaches down to it)."""

    radius_m: dict
    tool_length_m: float = 0.0
    table_z_m: float | None = None
    robot: str = "wam7"          # the wam4: no wrist capsule, the tool beyond the tool plate along z4

    @classmethod
    def default(cls, tool_length_m: float = 0.0, table_z_m: float | None = None, radius_m: dict | None = None,
                robot: str = "wam7"):
        r = dict(RADIUS_M)
        if robot == "wam4":
            r.pop("wrist and hand")
        r.update(radius_m or {})
        return cls(r, float(tool_length_m), table_z_m, robot)

    def segments(self, frames: np.ndarray) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """Each capsule's end points (n, 3), (n, 3) in frame 0, from DH frames ``frames`` (n, 8, 4, 4)."""
        frames = np.asarray(frames, float)
        n = len(frames)
        o = frames[:, :, :3, 3]                                    # (n, 8, 3) origins
        z = frames[:, :, :3, 2]                                    # (n, 8, 3) z axes
        low = 0.0 if self.table_z_m is None else min(0.0, self.table_z_m)
        if self.robot == "wam4":
            return {"shoulder": (np.zeros((n, 3)), np.tile([0.0, 0.0, low], (n, 1))),
                    "upper arm": (o[:, 2], o[:, 2] + WAM4.dh_d_m[2] * z[:, 2]),
                    "forearm": (o[:, 4], o[:, 4] + (WAM4.flange_d_m + self.tool_length_m) * z[:, 4])}
        return {
            "shoulder": (np.zeros((n, 3)), np.tile([0.0, 0.0, low], (n, 1))),
            "upper arm": (o[:, 2], o[:, 2] + P.DH_D_M[2] * z[:, 2]),
            "forearm": (o[:, 4], o[:, 4] + P.DH_D_M[4] * z[:, 4]),
            "wrist and hand": (o[:, 5], o[:, 7] + self.tool_length_m * z[:, 7]),
        }

    def levers_m(self) -> np.ndarray:
        """(7,) the farthest a capsule point can be from joint j's axis: the DH lengths beyond it, the tool and
        the largest radius."""
        if self.robot == "wam4":
            lengths = np.abs(WAM4.dh_a_m) + np.abs(WAM4.dh_d_m)
            return np.array([lengths[j:].sum() for j in range(WAM4.n_joints)]) + WAM4.flange_d_m + \
                self.tool_length_m + max(self.radius_m.values())
        lengths = np.abs(P.DH_A_M) + np.abs(P.DH_D_M)
        return np.array([lengths[j:].sum() for j in range(P.N_JOINTS)]) + self.tool_length_m + max(
            self.radius_m.values())


def segment_distance(p1: np.ndarray, q1: np.ndarray, p2: np.ndarray, q2: np.ndarray) -> np.ndarray:
    """Smallest distance between segments ``p1 q1`` and ``p2 q2`` ((n, 3) each): (n,). Closest points by
    clamping (Ericson, Real-Time Collision Detection, 5.1.9), degenerate segments (points) included."""
    p1, q1, p2, q2 = (np.atleast_2d(np.asarray(v, float)) for v in (p1, q1, p2, q2))
    d1, d2, r = q1 - p1, q2 - p2, p1 - p2
    a = np.einsum("ij,ij->i", d1, d1)
    e = np.einsum("ij,ij->i", d2, d2)
    f = np.einsum("ij,ij->i", d2, r)
    c = np.einsum("ij,ij->i", d1, r)
    b = np.einsum("ij,ij->i", d1, d2)
    eps = 1e-14
    denom = a * e - b * b
    with np.errstate(invalid="ignore", divide="ignore"):
        s = np.where(denom > eps * np.maximum(a * e, eps), np.clip((b * f - c * e) / denom, 0.0, 1.0), 0.0)
        s = np.where(a <= eps, 0.0, s)
        t = np.where(e <= eps, 0.0, (b * s + f) / np.where(e <= eps, 1.0, e))
        # t outside [0, 1]: clamp it and recompute s for the clamped t
        t_c = np.clip(t, 0.0, 1.0)
        s = np.where((t != t_c) & (a > eps), np.clip((t_c * b - c) / np.where(a <= eps, 1.0, a), 0.0, 1.0), s)
    c1 = p1 + s[:, None] * d1
    c2 = p2 + t_c[:, None] * d2
    return np.linalg.norm(c1 - c2, axis=1)


@dataclass
class Clearance:
    """The smallest distance of one kind over a set of samples: ``distance_m`` (surface to surface, negative
    when they overlap), what it is between (``between``), at which sample (``index``)."""

    kind: str
    distance_m: float
    between: str
    index: int

    def to_dict(self) -> dict:
        return {"distance_m": self.distance_m, "between": self.between, "sample": self.index}


def distances(frames: np.ndarray, geometry: ArmGeometry, table_z_m: float | None = None,
              box_min_m=None, box_max_m=None, self_collision: bool = True) -> dict[str, dict[str, np.ndarray]]:
    """Per kind (``self``, ``table``, ``box``), per pair or capsule: the surface distance (n,) at each of the
    states ``frames`` (n, 8, 4, 4). Table: the capsule above the plane ``z = table_z_m``; box: the capsule inside
    the box (a negative distance: outside by that much)."""
    seg = geometry.segments(frames)
    r = geometry.radius_m
    out: dict[str, dict[str, np.ndarray]] = {}
    if self_collision:
        out["self"] = {f"{LINKS[a]} / {LINKS[b]}": segment_distance(*seg[a], *seg[b]) - r[a] - r[b]
                       for a, b in PAIRS[geometry.robot]}
    moving = MOVING_OF[geometry.robot]
    if table_z_m is not None:
        out["table"] = {LINKS[c]: np.minimum(seg[c][0][:, 2], seg[c][1][:, 2]) - table_z_m - r[c] for c in moving}
    if box_min_m is not None:
        lo, hi = np.asarray(box_min_m, float), np.asarray(box_max_m, float)
        out["box"] = {}
        for c in moving:   # a segment is inside a convex box iff both ends are
            ends = np.stack(seg[c], axis=1)                        # (n, 2, 3)
            inside = np.minimum(ends - lo, hi - ends).min(axis=(1, 2))
            out["box"][LINKS[c]] = inside - r[c]
    return out


def smallest(dist: dict[str, dict[str, np.ndarray]]) -> dict[str, Clearance]:
    """The smallest distance of each kind, and between what."""
    out = {}
    for kind, per in dist.items():
        best = None
        for name, d in per.items():
            k = int(np.argmin(d))
            if best is None or d[k] < best.distance_m:
                best = Clearance(kind, float(d[k]), name, k)
        out[kind] = best
    return out


def motion_bound_m(qd: np.ndarray, geometry: ArmGeometry, dt_s: float) -> float:
    """How far any point of the arm can move in ``dt_s`` at the largest of the joint speeds ``qd`` (n, 7):
    ``dt x max_t sum_j |qd_j(t)| lever_j``."""
    return float(dt_s * np.max(np.abs(np.atleast_2d(qd)) @ geometry.levers_m()))
